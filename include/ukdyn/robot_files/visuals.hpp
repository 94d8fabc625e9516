// The shapes a robot file gives its links, for the replay page only (docs/replay.md): URDF
// <visual> geometries (box, cylinder, sphere; mesh) and MJCF geoms (box, sphere, capsule, cylinder,
// ellipsoid; mesh, plane, ...). The dynamics never read them (inertia comes from <inertial> and
// MuJoCo's compiled body inertias); URDF meshes are listed, not loaded; MJCF meshes become their
// bounding boxes (MuJoCo has loaded their vertices).
#pragma once

#include <array>
#include <string>
#include <vector>

namespace ukdyn::symbolic {

struct LinkVisual {
  /// The link it is fixed to (URDF link, MJCF body = the chain's link of that name); empty: the
  /// chain's root frame (MJCF's world body).
  std::string link;
  /// box, sphere, cylinder, capsule, ellipsoid; or what the page does not draw: mesh (with the
  /// mesh's file name in `detail`), plane, hfield, sdf.
  std::string shape;
  std::string detail;
  /// The extents of the shape along its own axes (m): a box's edges; a sphere's or an ellipsoid's
  /// diameters; a cylinder's or a capsule's (2 r, 2 r, full length along its z axis, a capsule's
  /// end caps included).
  std::array<double, 3> size{0, 0, 0};
  std::array<double, 3> xyz{0, 0, 0};      ///< the shape's centre in the link frame
  std::array<double, 4> quat{1, 0, 0, 0};  ///< (w, x, y, z): shape axes → link frame
  /// A mesh drawn as its bounding box (shape box; the mesh's name in `detail`): an MJCF mesh geom,
  /// whose vertices MuJoCo's compiled model holds.
  bool bounding_box = false;
};

/// The <visual> elements of every link of the URDF file, by link name. Throws
/// DefinitionError naming the file if it cannot be read (or ukdyn was built without urdfdom).
std::vector<LinkVisual> urdf_visuals(const std::string& path);

/// The geoms of the MJCF model, as MuJoCo compiles them (fromto, defaults and half-sizes
/// resolved), in geom order. Throws DefinitionError naming the file if MuJoCo cannot load it (or
/// ukdyn was built without MuJoCo).
std::vector<LinkVisual> mjcf_visuals(const std::string& path);

}  // namespace ukdyn::symbolic
