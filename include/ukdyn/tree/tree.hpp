// Rigid-body trees of numbers: the recursive algorithms of Featherstone, "Rigid Body Dynamics
// Algorithms" (Springer 2008) — the composite-rigid-body algorithm for M(q) (§6.2) and the
// recursive Newton–Euler algorithm for C(q, q̇) q̇ (§5.3) — over a tree of revolute, prismatic and
// fixed joints. A serial_chain, URDF or MJCF arm whose numbers are all known goes here instead of
// the symbolic derivation (docs/tree-algorithms.md): O(n) to O(n²) per evaluation, no derivation.
//
// Spatial vectors are written in world coordinates about the world origin (Featherstone §2.9,
// "absolute coordinates"): a motion vector (ω, v_O) with v_O the velocity of the body point at the
// world origin, a force vector (n_O, f). Joint k's motion axis is S_k = (z_k, p_k × z_k) for a
// revolute joint about the world axis z_k through p_k, S_k = (0, z_k) for a prismatic one.
//
// Joint variables: each revolute or prismatic joint's variable is affine in the subsystem's
// coordinates, θ_k = offset_k + Σ_j c_kj q_j (a coordinate, or the paper's relative angle θ2 − θ1),
// θ = T q + c. Lagrange's equations in q are Tᵀ times those in θ, so M_q = Tᵀ M_θ T,
// (C q̇)_q = Tᵀ (C θ̇)_θ, G_q = Tᵀ G_θ (T constant).
//
// Ball and floating joints take unit-quaternion coordinates with the symbolic chain's conventions
// (symbolic/chain.hpp, free_body.hpp; docs/tree-algorithms.md, "Quaternion joints"): a ball joint
// turns its link by R(u), the homogeneous quaternion matrix of u = (qw, qx, qy, qz), about the
// joint origin; a floating joint first moves it by (x, y, z) along the joint frame's axes. R(u) is
// |u|² times a rotation, so off |u| = 1 the link poses below (link_pose, frame_state) are scaled as
// the symbolic link poses are; M, C q̇, G equal the symbolic ones on |u| = 1.
#pragma once

#include <Eigen/Core>
#include <memory>
#include <string>
#include <vector>

#include "ukdyn/model/column_derivatives.hpp"
#include "ukdyn/model/subsystem.hpp"

namespace ukdyn::tree {

struct ForwardPlan;  // src/tree/tree.cpp: what the forward passes know of each link in advance

/// floating: 7 terms (x, y, z, qw, qx, qy, qz), ball: 4 terms (qw, qx, qy, qz), one coordinate each
/// with coefficient 1; their axis and offset are not used.
enum class JointType { revolute, prismatic, fixed, floating, ball };

/// One term c · q_coordinate of a joint variable.
struct Term {
  Index coordinate = 0;
  double coefficient = 1.0;
};

/// A joint and the link it moves (its child).
struct Link {
  std::string name;   ///< the link's name (unique in the model)
  std::string joint;  ///< the joint's name
  int parent = -1;    ///< index of the parent link in Model::links (earlier), −1: the root frame
  JointType type = JointType::fixed;
  /// Parent link frame → joint frame: x_joint = origin_rotation x + origin_translation.
  Eigen::Matrix3d origin_rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d origin_translation = Eigen::Vector3d::Zero();
  Eigen::Vector3d axis{0.0, 0.0, 1.0};  ///< unit, in the joint frame
  double offset = 0.0;                  ///< θ = offset + Σ terms
  std::vector<Term> terms;              ///< empty for a fixed joint
  double mass = 0.0;
  Eigen::Vector3d com = Eigen::Vector3d::Zero();      ///< in the link frame
  Eigen::Matrix3d inertia = Eigen::Matrix3d::Zero();  ///< about the CoM, in the link frame
};

/// A named point fixed in a link (a chain's `points:` and `end`).
struct Point {
  std::string name;
  int link = -1;                                  ///< index in Model::links, −1: the root frame
  Eigen::Vector3d xyz = Eigen::Vector3d::Zero();  ///< in the link frame
};

/// A tree: constant after make_subsystem().
struct Model {
  std::string name;
  std::vector<std::string> coordinates;
  std::string root_name = "root";
  /// World → root frame (the mount).
  Eigen::Matrix3d root_rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d root_translation = Eigen::Vector3d::Zero();
  Eigen::Vector3d gravity = Eigen::Vector3d::Zero();  ///< gravitational acceleration (0, 0, −9.81)
  std::vector<Link> links;                            ///< a parent before its children
  std::vector<Point> points;
};

/// Throws ukdyn::Error naming the link at fault: a parent that is not an earlier link, a
/// non-unit axis, a term naming no coordinate, a movable joint without terms, a negative or
/// non-finite mass, an inertia that is not symmetric positive semi-definite, a non-finite number.
void validate(const Model& model);

/// What a frame fixed in a link does at (q, q̇) (the numeric frame constraints,
/// docs/frame-constraints.md): its origin p and rotation R (frame → world), their rates, their
/// accelerations at q̈ = 0 (the velocity-product terms J̇ q̇), and their derivatives by each of the
/// subsystem's coordinates (dp: 3 × dof; dR: 9 × dof, R row-major).
/// dp and dR are views of the caller's storage (3 × cols and 9 × cols doubles, column-major).
struct FrameState {
  FrameState(double* dp_data, double* dR_data, Index cols)
      : dp(dp_data, 3, cols), dR(dR_data, 9, cols) {}
  Eigen::Vector3d p, pd, pdd;
  Eigen::Matrix3d R, Rd, Rdd;
  Eigen::Map<Eigen::Matrix<double, 3, Eigen::Dynamic>> dp;
  Eigen::Map<Eigen::Matrix<double, 9, Eigen::Dynamic>> dR;
};

/// The subsystem of a tree (validated first). Slot: its workspace, so that forward() allocates
/// nothing.
///
/// Fixed joints are merged at construction (merge_fixed, the default; as Pinocchio, RBDL and
/// MuJoCo do): the mass, CoM and inertia of a link on a fixed joint are lumped into its nearest
/// ancestor on a movable joint (parallel-axis theorem, the inertia rotated into that link's frame),
/// or, if every joint above it is fixed, into a constant potential; the recursive passes run on the
/// movable links only. Its frame stays usable by name: link_index, link_pose(s) and frame_state
/// place it as its ancestor's pose times the constant transform between them. model() is the
/// tree as given.
class TreeSubsystem : public Subsystem, public SubsystemColumns {
 public:
  explicit TreeSubsystem(Model model, bool merge_fixed = true);
  [[nodiscard]] Index dof() const override { return static_cast<Index>(model_.coordinates.size()); }
  [[nodiscard]] const std::string& name() const override { return model_.name; }
  [[nodiscard]] const std::vector<std::string>& coordinate_names() const override {
    return model_.coordinates;
  }
  [[nodiscard]] Index slot_size() const override { return slot_size_; }
  void mass(const EvalContext& c, CVecRef q, MatRef M) const override;
  /// The Christoffel matrix C_ij = Σ_k ½(∂M_ij/∂q_k + ∂M_ik/∂q_j − ∂M_jk/∂q_i) q̇_k (Ṁ − 2C
  /// skew-symmetric), with ∂M/∂θ_k by forward-mode automatic differentiation of the
  /// composite-rigid-body algorithm (Eigen's AutoDiffScalar): one pass per joint, allocates.
  /// With ball joints, ∂M/∂q along each quaternion's radial direction is the symbolic chain's
  /// (docs/tree-algorithms.md, "Quaternion joints"), so C is the symbolic C on |u| = 1.
  void coriolis(const EvalContext& c, CVecRef q, CVecRef qd, MatRef C) const override;
  void coriolis_times_qd(const EvalContext& c, CVecRef q, CVecRef qd, VecRef Cqd) const override;
  void gravity(const EvalContext& c, CVecRef q, VecRef G) const override;
  /// V(q) from the links placed in c.slot when this subsystem placed them there at q (dynamics()
  /// at the same q, say), else placed anew in c.slot.
  [[nodiscard]] double potential(const EvalContext& c, CVecRef q) const override;
  /// The same with the placement looked for in `placed` (this subsystem's data slot as an earlier
  /// evaluation left it: dynamics() in the forward() of an output sample) and, when it is not of
  /// this q (the slot keeps the joint variables it belongs to), made in `scratch` (slot_size()
  /// doubles; none: a buffer of its own). Bitwise the same value either way.
  [[nodiscard]] double potential(CVecRef q, ConstSlot placed, Slot scratch) const;
  double dynamics(const EvalContext& c, CVecRef q, CVecRef qd, MatRef M, VecRef Cqd,
                  VecRef G) const override;
  [[nodiscard]] bool has_derivatives() const override { return true; }
  /// The RNEA with q̈ run once on dual numbers (forward-mode automatic differentiation).
  bool inverse_dynamics_tangent(const EvalContext& c, CVecRef q, CVecRef qd, CVecRef qdd,
                                CVecRef dq, CVecRef dqd, VecRef dID) const override;
  /// Every column at once: the analytic derivatives of the RNEA (one forward and one backward
  /// recursion, then products of motion and force vectors; with ball and floating joints on
  /// their similarity motions and with the correction terms of the symbolic body rate;
  /// docs/tree-algorithms.md, "Derivatives").
  bool inverse_dynamics_jacobian(const EvalContext& c, CVecRef q, CVecRef qd, CVecRef qdd,
                                 MatRef dID_dq, MatRef dID_dqd) const override;

  [[nodiscard]] const Model& model() const { return model_; }
  /// Index of a link by name (−1: the root frame), or −2 if there is none.
  [[nodiscard]] int link_index(const std::string& name) const;
  /// World pose of link `link` (−1: the root frame) at q: x_world = R x_link + p.
  void link_pose(CVecRef q, int link, Eigen::Matrix3d& R, Eigen::Vector3d& p) const;
  /// World poses of every link at q (R[i], p[i] for Model::links[i]).
  void link_poses(CVecRef q, std::vector<Eigen::Matrix3d>& R,
                  std::vector<Eigen::Vector3d>& p) const;
  /// The state of the frame (R_offset, x_offset) of link `link` (−1: the root frame) at (q, q̇):
  /// p = p_link + R_link x_offset, R = R_link R_offset. `scratch`: slot_size() doubles (none:
  /// a buffer of its own); `out.dp`, `out.dR` have dof() columns.
  void frame_state(CVecRef q, CVecRef qd, int link, const Eigen::Matrix3d& R_offset,
                   const Eigen::Vector3d& x_offset, Slot scratch, FrameState& out) const;
  /// frame_state and its exact directional derivative along (dq, dq̇) at fixed q̈ (the same
  /// recursive pass run on dual numbers: forward-mode automatic differentiation). `value` is the
  /// frame's state except that pdd, Rdd are the acceleration AT q̈ (frame_state gives it at
  /// q̈ = 0); `tangent` holds the derivative of every field of `value` (p, R, pd, Rd, pdd, Rdd,
  /// dp, dR). `scratch`: slot_size() doubles (none: a buffer of its own).
  void frame_state_tangent(CVecRef q, CVecRef qd, CVecRef qdd, CVecRef dq, CVecRef dqd, int link,
                           const Eigen::Matrix3d& R_offset, const Eigen::Vector3d& x_offset,
                           Slot scratch, FrameState& value, FrameState& tangent) const;
  /// frame_state's p, R, their rates and accelerations at q̈ = 0 in `out` (out.dp, out.dR are
  /// not written), and its columns as twists, 7 × dof column-major in `twists`: column j is
  /// (v_j, ω_j, s_j) with ∂p/∂q_j = v_j and ∂R/∂q_j = ([ω_j]× + s_j) R (s_j ≠ 0 only below a ball
  /// joint, off |u| = 1). `placed`: this subsystem's data slot as dynamics() left it; its link
  /// placements and motions are reused when they were computed at the same (q, q̇) (the slot keeps
  /// the joint variables they belong to), otherwise the pass is run again in `scratch`
  /// (slot_size() doubles; none: a buffer of its own). Same values either way.
  void frame_twists(CVecRef q, CVecRef qd, int link, const Eigen::Matrix3d& R_offset,
                    const Eigen::Vector3d& x_offset, ConstSlot placed, Slot scratch,
                    FrameState& out, double* twists) const;
  /// frame_state_tangent along every direction at once (analytic, as inverse_dynamics_jacobian):
  /// `value` as
  /// there, and J (frame_jacobian_rows() × 2 dof()) whose column j is the tangent along e_j of q,
  /// column dof() + j along e_j of q̇, of the fields stacked as p, R, pd, Rd, pdd, Rdd (3 or 9
  /// entries each, R(i, k) at 3 i + k), then dp and dR column by column (12 per coordinate).
  /// `placed`: this subsystem's data slot as inverse_dynamics_jacobian() left it; without ball
  /// joints the links it placed and moved there are reused when they are of the same (q, q̇, q̈)
  /// (the slot keeps the joint variables they belong to), otherwise the pass is run in `scratch`
  /// (slot_size() doubles; none: a buffer of its own).
  void frame_state_jacobian(CVecRef q, CVecRef qd, CVecRef qdd, int link,
                            const Eigen::Matrix3d& R_offset, const Eigen::Vector3d& x_offset,
                            ConstSlot placed, Slot scratch, FrameState& value, MatRef J) const;
  /// The rows of frame_state_jacobian's J: 36 + 12 dof().
  [[nodiscard]] Index frame_jacobian_rows() const { return 36 + 12 * dof(); }
  /// Number of joint variables θ (one per revolute or prismatic joint, four per ball joint, seven
  /// per floating joint).
  [[nodiscard]] Index joint_variables() const { return n_theta_; }
  /// Number of links the recursive passes run on (model().links less the merged fixed ones).
  [[nodiscard]] std::size_t pass_links() const { return merged_.links.size(); }

  /// Where a link of model() is in the merged tree: its link there (−1: the root frame) and its
  /// frame in that link's frame (x_parent = R x + p).
  struct Placement {
    int link = -1;
    Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
    Eigen::Vector3d p = Eigen::Vector3d::Zero();
  };

 private:
  Model model_;                       // as given: names, points, link_index
  Model merged_;                      // what the passes run on (model_ itself if not merged)
  std::vector<Placement> placement_;  // per link of model_
  double potential0_ = 0.0;           // V of the masses fixed to the root frame (merged away)
  std::vector<int> theta_index_;  // per link of merged_: its (first) joint variable, −1: fixed
  std::vector<std::vector<Term>> theta_terms_;  // per joint variable: θ = Σ terms (+ offset)
  std::vector<double> theta_offset_;            // per joint variable
  bool quaternions_ = false;                    // merged_ has ball joints (floating ones split)
  std::shared_ptr<const ForwardPlan> plan_;     // per link of merged_ (tree.cpp)
  Index n_theta_ = 0;
  Index slot_size_ = 0;
};

/// The tree's subsystem (validate() first).
std::shared_ptr<const TreeSubsystem> make_subsystem(Model model);

}  // namespace ukdyn::tree
