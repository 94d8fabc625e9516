// Standard robots without trigonometry by hand: a serial chain (or a tree) of revolute, prismatic
// and fixed joints on an optional omnidirectional mobile base, turned into a SubsystemDef.
//
//   world ─ mount (xyz, rpy) ─ base [x, y translation, optional yaw] ─ joint 1 ─ link 1 ─ ...
//
// Each joint has a fixed origin transform from its parent link frame (xyz, then roll-pitch-yaw as
// in URDF: R = Rz(yaw) Ry(pitch) Rx(roll)), an axis in that frame, and a joint variable: a
// coordinate of the chain, or any expression of the coordinates (the paper's absolute link angles:
// the joint between links 1 and 2 turns by theta2 − theta1). Link frames are composed as
// homogeneous transforms of GiNaC expressions; each link with mass becomes a body with its centre
// of mass p = p_link + R_link c, the exact rigid-body inertia (3×3 about the CoM in the link frame,
// optionally rotated by the inertial rpy) and its angular velocity ω_body = R_linkᵀ Σ (axis_k in
// world) q̇_k.
//
//   symbolic::ChainDef c("arm", {"x", "y", "q1", "q2"});
//   c.base.enabled = true; c.base.x = "x"; c.base.y = "y"; c.base.inertial.mass = 50;
//   auto& j = c.add_joint("j1", JointDef::Type::revolute, "link1");
//   j.coordinate = "q1"; j.axis = {0, 0, 1};
//   j.inertial.mass = 3; j.inertial.com = {0.35, 0, 0}; j.inertial.inertia = {...};
//   c.add_point("end", "link2", {0.8, 0, 0});
//   auto model = symbolic::build_chain(c);          // SubsystemDef + named points
//   auto sub = symbolic::make_subsystem(model.def);
#pragma once

#include <array>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "ukdyn/model/coordinate_limits.hpp"
#include "ukdyn/symbolic/definitions.hpp"

namespace ukdyn::symbolic {

using Vec3Ex = std::array<GiNaC::ex, 3>;
using Mat3Ex = std::array<GiNaC::ex, 9>;  ///< row-major

struct OriginDef {
  Vec3Ex xyz{0, 0, 0};
  Vec3Ex rpy{0, 0, 0};  ///< roll, pitch, yaw (fixed axes x, y, z): R = Rz(yaw) Ry(pitch) Rx(roll)
};

struct InertialDef {
  GiNaC::ex mass = 0;
  Vec3Ex com{0, 0, 0};                        ///< CoM in the link frame
  Vec3Ex rpy{0, 0, 0};                        ///< orientation of the inertia frame
  Mat3Ex inertia{0, 0, 0, 0, 0, 0, 0, 0, 0};  ///< about the CoM, in the inertia frame
};

/// A joint's limits on its value θ (not on a coordinate), as its file states them: URDF <limit
/// lower upper velocity effort>, MJCF range (on qpos, stored here on θ = qpos − qpos0) and the
/// force ranges of the actuators on the joint; ±inf when absent. ChainDef::coordinate_limits maps
/// them to the coordinates.
using JointLimits = CoordinateLimits;

struct JointDef {
  /// floating: 6 DoF in position + unit quaternion (docs/free-bodies.md, "Floating joints"):
  /// `coordinates` (7: x, y, z, qw, qx, qy, qz), the translation in the joint frame and the
  /// rotation joint → child link; ball: the rotation only (4: qw, qx, qy, qz). Their unit-norm
  /// rows are added by the scenario (ChainModel::quaternions).
  enum class Type { revolute, prismatic, fixed, floating, ball };
  std::string name;
  Type type = Type::revolute;
  std::string parent;  ///< parent link; empty = the child link of the previous joint (or the base)
  std::string link;    ///< child link name (unique)
  OriginDef origin;    ///< parent link frame → joint frame
  Vec3Ex axis{0, 0, 1};
  std::string coordinate;                ///< the joint variable is this coordinate ...
  std::optional<GiNaC::ex> value;        ///< ... or this expression of the coordinates
  std::vector<std::string> coordinates;  ///< floating: x, y, z, qw, qx, qy, qz; ball: qw .. qz
  InertialDef inertial;                  ///< of the child link (mass 0: no body)
  JointLimits limits;                    ///< on the joint's value θ (URDF, MJCF); ±inf: none
  /// URDF mimic: the joint whose value this one follows (θ = multiplier · other + offset). Its
  /// limits stay here and are not mapped to a coordinate.
  std::string mimic;
};

struct MobileBaseDef {
  bool enabled = false;
  std::string link = "base";  ///< name of the platform link
  std::string x, y;           ///< coordinates of the translation along world x and y
  std::string yaw;            ///< optional coordinate of a rotation about world z (empty: none)
  InertialDef inertial;       ///< of the platform (mass 0: no body)
};

struct PointDef {
  std::string name;
  std::string link;
  Vec3Ex xyz{0, 0, 0};  ///< in the link frame
};

/// A constraint between two links of a chain, as an MJCF file's <equality> weld and connect give
/// them (append_mjcf): frame a is link_a's frame moved by offset_a, frame b is link_b's moved by
/// offset_b; weld: the two frames coincide (6 rows), ball: their origins (3 rows).
/// The scenario adds them as frame constraints named SUBSYSTEM_NAME (docs/frame-constraints.md).
struct LinkConstraintDef {
  enum class Kind { weld, ball };
  Kind kind = Kind::weld;
  std::string name;
  std::string link_a, link_b;
  OriginDef offset_a, offset_b;
};

class ChainDef : public SubsystemDef {
 public:
  ChainDef(std::string name, std::vector<std::string> coordinates,
           std::shared_ptr<SymbolTable> symbols = nullptr)
      : SubsystemDef(std::move(name), std::move(coordinates), std::move(symbols)) {}
  JointDef& add_joint(std::string name, JointDef::Type type, std::string link);
  void add_point(std::string name, std::string link, Vec3Ex xyz);

  OriginDef mount;  ///< world → base (or → the first joint's parent frame)
  MobileBaseDef base;
  std::vector<JointDef> joints;
  std::vector<PointDef> points;
  /// Name of the root link when there is no mobile base.
  std::string root_link = "root";
  /// A URDF's root link on a floating joint (append_urdf): its 7 coordinates (x, y, z, qw, qx, qy,
  /// qz); empty = the root is fixed (or on the mobile base).
  std::vector<std::string> floating_root;
  /// Constraints between its links (from an MJCF file's equalities).
  std::vector<LinkConstraintDef> link_constraints;
  /// What the file readers noted and left out (meshes; ignored limits), one line each, for
  /// `ukdyn check` and `ukdyn simulate` to print.
  std::vector<std::string> notes;

  /// The limits of each of coordinates() (in their order), from the joints' limits: a joint whose
  /// value is c · q + offset (one coordinate q, c and offset numbers once the parameters are
  /// substituted; not a mimic joint) gives q the range ((lower − offset) / c, (upper − offset) / c)
  /// (ends swapped when c < 0), the velocity limit velocity / |c| and the effort limit
  /// effort · |c|. Two joints on one coordinate: the tighter of each. ±inf where nothing applies.
  [[nodiscard]] std::vector<CoordinateLimits> coordinate_limits() const;
};

struct LinkPose {
  Vec3Ex position;  ///< origin of the link frame in the world
  Mat3Ex rotation;  ///< link → world
};

/// The subsystem definition of a chain and its named points in the world frame.
struct ChainModel {
  SubsystemDef def;  ///< the bodies of every link with mass; parameters of the chain
  std::map<std::string, LinkPose> links;
  /// Named points: every link's frame origin (by the link's name), the chain's points, and `end`
  /// (the last joint's child link origin unless a point named `end` is given). Parameters are
  /// symbols of `def`; world_point substitutes their values.
  std::map<std::string, Vec3Ex> points;
  /// A named point with the parameter values substituted (usable in any ConstraintDef). Throws
  /// DefinitionError listing the known names if there is no such point.
  [[nodiscard]] Vec3Ex world_point(const std::string& name) const;
  /// Per floating or ball joint: its name and its quaternion coordinates (qw, qx, qy, qz), whose unit-norm
  /// row (free_body_norm_constraint) the system needs.
  std::vector<std::pair<std::string, std::vector<std::string>>> quaternions;
};

/// Builds the link poses and bodies. Throws DefinitionError for unknown links or coordinates,
/// joints whose value depends on t or velocities, a zero axis, duplicate names.
ChainModel build_chain(const ChainDef& chain);
/// The same within `deadline` (throws DerivationTimeout once it is spent), e.g. one budget for the
/// chain and the derivation of its dynamics (make_subsystem(model.def, deadline)).
ChainModel build_chain(const ChainDef& chain, const Deadline& deadline);

/// Rotation about a unit (normalized here) axis by angle q (Rodrigues), row-major.
Mat3Ex axis_rotation(const Vec3Ex& axis, const GiNaC::ex& q);
/// R = Rz(yaw) Ry(pitch) Rx(roll), row-major.
Mat3Ex rpy_rotation(const Vec3Ex& rpy);

}  // namespace ukdyn::symbolic
