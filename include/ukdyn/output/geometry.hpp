// What the 3D replay page draws (docs/replay.md): named points of a system as functions of q, in
// the world frame, and segments between them. Built by io from a loaded scenario (nothing is kept
// in the models): the paper's mobile manipulators (platform, joint frames, cut point), serial
// chains and URDF robots (link frame origins, their named points), definitions bodies (CoM) and
// free bodies (a solid posed by their coordinates).
// Constant after construction; evaluate() writes into caller-owned storage.
#pragma once

#include <array>
#include <functional>
#include <string>
#include <vector>

#include "ukdyn/core/types.hpp"
#include "ukdyn/model/subsystem.hpp"

namespace ukdyn {

struct Scenario;

struct GeometryPoint {
  std::string name;  ///< "left.platform", "left.j1", "left.cut", "arm.link2", ...
  /// platform, joint, cut, grasp, com, point: how the page draws it.
  std::string kind;
};

struct GeometrySegment {
  std::size_t a = 0, b = 0;  ///< indices into Geometry::points
  std::string kind;          ///< link, load, base
};

/// A solid drawn at one of the points (its centre), turned by an orientation of q: a free body's
/// inertia-equivalent box or its `shape:`, a robot file's shape on a link (URDF <visual>, MJCF
/// geom).
struct GeometrySolid {
  std::string name;  ///< "load": the free body's; "arm.link2.visual0": a link's
  /// box, sphere, ellipsoid, cylinder, capsule (the last two along the solid's own z)
  std::string shape;
  /// Extents along the solid's own axes (m): a box's edges, a sphere's or ellipsoid's diameters,
  /// a cylinder's or capsule's (2 r, 2 r, full length with a capsule's caps).
  Vec3 size = Vec3::Zero();
  std::size_t point = 0;      ///< index into Geometry::points of its centre
  std::string kind = "load";  ///< load (a free body), link (a robot file's shape)
};

class Geometry {
 public:
  /// Writes the world positions of this part's points (in order) from the system's q.
  using PartFunction = std::function<void(CVecRef q, std::vector<Vec3>& out, std::size_t first)>;

  /// Appends points (and segments between them, indices local to this part); returns the index
  /// of the part's first point.
  std::size_t add_part(std::vector<GeometryPoint> points, std::vector<GeometrySegment> segments,
                       PartFunction positions);
  void add_segment(GeometrySegment s) { segments_.push_back(std::move(s)); }
  /// Its orientation at q: the unit quaternion (w, x, y, z) of the rotation solid → world.
  using OrientationFunction = std::function<std::array<double, 4>(CVecRef q)>;
  void add_solid(GeometrySolid s, OrientationFunction orientation);

  [[nodiscard]] const std::vector<GeometryPoint>& points() const { return points_; }
  [[nodiscard]] const std::vector<GeometrySegment>& segments() const { return segments_; }
  [[nodiscard]] const std::vector<GeometrySolid>& solids() const { return solids_; }
  [[nodiscard]] bool empty() const { return points_.empty(); }
  /// Index of the point `name`, or −1.
  [[nodiscard]] long find(const std::string& name) const;

  /// World positions of every point at q (out is resized to points().size()).
  void evaluate(CVecRef q, std::vector<Vec3>& out) const;
  /// The orientation of every solid at q (out is resized to solids().size()).
  void evaluate_orientations(CVecRef q, std::vector<std::array<double, 4>>& out) const;

 private:
  struct Part {
    std::size_t first = 0, count = 0;
    PartFunction f;
  };
  std::vector<GeometryPoint> points_;
  std::vector<GeometrySegment> segments_;
  std::vector<Part> parts_;
  std::vector<GeometrySolid> solids_;
  std::vector<OrientationFunction> orientations_;
};

/// The geometry of a scenario's system: every subsystem it knows how to draw (mobile_manipulator,
/// serial_chain / URDF, definitions bodies, free bodies); the others are left out and named in
/// `left_out`.
/// For the paper's closure the two cut points are joined as the load.
Geometry build_geometry(const Scenario& scenario, std::vector<std::string>* left_out = nullptr);

}  // namespace ukdyn
