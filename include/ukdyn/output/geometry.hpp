// What the 3D replay page draws (docs/replay.md): named points of a system as functions of q, in
// the world frame, and segments between them. Built by io from a loaded scenario (nothing is kept
// in the models): the paper's mobile manipulators (platform, joint frames, cut point), serial
// chains and URDF robots (link frame origins, their named points) and definitions bodies (CoM).
// Constant after construction; evaluate() writes into caller-owned storage.
#pragma once

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

class Geometry {
 public:
  /// Writes the world positions of this part's points (in order) from the system's q.
  using PartFunction = std::function<void(CVecRef q, std::vector<Vec3>& out, std::size_t first)>;

  /// Appends points (and segments between them, indices local to this part); returns the index
  /// of the part's first point.
  std::size_t add_part(std::vector<GeometryPoint> points, std::vector<GeometrySegment> segments,
                       PartFunction positions);
  void add_segment(GeometrySegment s) { segments_.push_back(std::move(s)); }

  [[nodiscard]] const std::vector<GeometryPoint>& points() const { return points_; }
  [[nodiscard]] const std::vector<GeometrySegment>& segments() const { return segments_; }
  [[nodiscard]] bool empty() const { return points_.empty(); }
  /// Index of the point `name`, or −1.
  [[nodiscard]] long find(const std::string& name) const;

  /// World positions of every point at q (out is resized to points().size()).
  void evaluate(CVecRef q, std::vector<Vec3>& out) const;

 private:
  struct Part {
    std::size_t first = 0, count = 0;
    PartFunction f;
  };
  std::vector<GeometryPoint> points_;
  std::vector<GeometrySegment> segments_;
  std::vector<Part> parts_;
};

/// The geometry of a scenario's system: every subsystem it knows how to draw (mobile_manipulator,
/// serial_chain / URDF, definitions bodies); the others are left out and named in `left_out`.
/// For the paper's closure the two cut points are joined as the load.
Geometry build_geometry(const Scenario& scenario, std::vector<std::string>* left_out = nullptr);

}  // namespace ukdyn
