// Constraints between frames (docs/frame-constraints.md): weld, ball, hinge, level and distance,
// written as rows Φ(q) = 0 of a ConstraintDef, so that A = ∂Φ/∂q and b follow exactly from the
// existing derivation (definitions.hpp).
//
// A frame is a position p(q) and a rotation R(q) (frame → world) of GiNaC expressions. Frames come
// from serial chains (every link, every named point with its link's rotation) and from definition
// bodies (the CoM `com` and, when given, `rotation`): FrameTable names them
// "<subsystem>.<link-or-body-or-point>", and "world" is the fixed world frame. An offset (xyz, rpy
// in the frame's axes, as a URDF origin) moves a frame on its body: p' = p + R xyz, R' = R Rz(yaw)
// Ry(pitch) Rx(roll).
//
//   weld      6 rows  p_a − p_b (world x, y, z) and the vector part of the relative rotation
//                     R_rel = R_aᵀ R_b: ½ vee(R_rel − R_relᵀ) = sin θ · u (θ, u: angle, axis of
//                     R_rel). Regular (rank 3) for θ < 90°, see docs/frame-constraints.md.
//   ball      3 rows  p_a − p_b
//   hinge     5 rows  p_a − p_b and (R_a u)·(R_b n1), (R_a u)·(R_b n2), u the axis in the frames'
//                     axes, n1, n2 ⊥ u
//   level     1 row   (R_a u)·up = 0 (axis horizontal), or 2 rows (R_a u)·e1 = (R_a u)·e2 = 0
//                     (axis vertical), e1, e2 ⊥ up (up = world z by default)
//   distance  1 row   ½ (|p_a − p_b|² − L²)
//
// FrameWrenchMap turns the multipliers λ_k of one such block into the wrench (force, moment about
// the frame origin, in world and in the frame's own axes) that the constraint applies to each of
// its two frames: Φ̇ = G_a [v_a; ω_a] + G_b [v_b; ω_b] (world twists), so
//   A_kᵀλ_k = J_aᵀ (G_aᵀλ_k) + J_bᵀ (G_bᵀλ_k)  and  w_a = G_aᵀλ_k, w_b = G_bᵀλ_k.
#pragma once

#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "ukdyn/core/types.hpp"
#include "ukdyn/model/column_derivatives.hpp"
#include "ukdyn/symbolic/chain.hpp"
#include "ukdyn/symbolic/definitions.hpp"
#include "ukdyn/symbolic/tape.hpp"

namespace ukdyn::symbolic {

struct FramePose {
  Vec3Ex position{0, 0, 0};
  Mat3Ex rotation{1, 0, 0, 0, 1, 0, 0, 0, 1};  ///< frame → world, row-major
  bool has_rotation = true;  ///< false: a point of a body without `rotation` (ball, distance only)
};

/// p + R xyz, R Rz(yaw) Ry(pitch) Rx(roll).
FramePose offset_frame(const FramePose& frame, const OriginDef& offset);

/// Named frames "<subsystem>.<name>" with parameter values substituted.
class FrameTable {
 public:
  void add(const std::string& subsystem, const std::string& name, FramePose pose);
  /// Every link of a chain and, if `def` is given, its named points (rotation of their link).
  void add_chain(const std::string& subsystem, const ChainModel& model,
                 const ChainDef* def = nullptr);
  /// Every body of a definitions subsystem: its CoM and, if given, its rotation.
  void add_bodies(const SubsystemDef& def);
  /// "world" (the origin, identity rotation) or a frame added. Throws DefinitionError naming the
  /// frame and listing the known ones.
  [[nodiscard]] const FramePose& find(const std::string& ref) const;
  [[nodiscard]] std::vector<std::string> names() const;

 private:
  std::map<std::string, FramePose> frames_;
  FramePose world_;  // "world": the origin, identity rotation
};

struct FrameConstraintDef {
  enum class Kind { weld, ball, hinge, level, distance };
  Kind kind = Kind::weld;
  std::string name;              ///< row prefix
  std::string frame_a, frame_b;  ///< names (for messages and the wrench CSV columns)
  FramePose a, b;                ///< with offsets applied
  Vec3Ex axis{0, 0, 1};          ///< hinge: in both frames' axes; level: in frame a's axes
  Vec3Ex up{0, 0, 1};            ///< level: the world vertical
  bool vertical = false;         ///< level: axis vertical (2 rows) instead of horizontal (1 row)
  GiNaC::ex length = 0;          ///< distance
};

const char* to_string(FrameConstraintDef::Kind kind);

/// The rows (name, Φ) of a frame constraint for the poses a and b. Throws DefinitionError (a frame
/// without rotation where one is needed, a zero axis, a non-positive length).
std::vector<std::pair<std::string, GiNaC::ex>> frame_rows(const FrameConstraintDef& f,
                                                          const GiNaC::exmap& values = {});

/// Adds frame_rows(f) to def (parameter values of def substituted in axes and length).
void add_frame_constraint(ConstraintDef& def, const FrameConstraintDef& f);

/// The wrench the constraint applies to each frame (force, moment about the frame's origin).
struct FrameWrench {
  Vec3 force_a, moment_a, force_b, moment_b;  ///< world axes
  Vec3 force_b_local, moment_b_local;         ///< frame b's axes (the grasp frame on a load)
  Vec3 force_a_local, moment_a_local;         ///< frame a's axes
  Vec3 position_a, position_b;
  Eigen::Matrix3d rotation_a, rotation_b;
};

/// What the output needs of a frame constraint block: G_a, G_b (rows × 6: Φ̇ = G_a [v_a; ω_a] +
/// G_b [v_b; ω_b], world twists), the frames' poses and twist Jacobians J (6 × n: [v; ω] = J q̇),
/// and from them the wrench its multipliers λ apply to each frame. Two implementations: compiled
/// from the frames' expressions (FrameWrenchMap), and numeric on the recursive tree algorithms
/// (numeric_frame_constraint.cpp, frames of chains that run on trees).
class FrameWrenches {
 public:
  virtual ~FrameWrenches() = default;
  [[nodiscard]] const std::string& name() const { return name_; }
  [[nodiscard]] const std::string& frame_a() const { return frame_a_; }
  [[nodiscard]] const std::string& frame_b() const { return frame_b_; }
  [[nodiscard]] FrameConstraintDef::Kind kind() const { return kind_; }
  [[nodiscard]] Index rows() const { return m_; }
  [[nodiscard]] bool has_b() const { return has_b_; }
  /// The buffers of evaluate() (an implementation's outputs and work, G_a, G_b).
  struct Workspace {
    std::vector<double> out, work;
    Mat Ga, Gb;
  };
  [[nodiscard]] virtual Workspace workspace() const = 0;
  /// w = G_aᵀλ, G_bᵀλ at q for the multipliers λ (rows()) of this block, with the buffers of ws
  /// (from workspace()): no heap allocation.
  virtual void evaluate(CVecRef q, const Vec& lambda, Workspace& ws, FrameWrench& w) const = 0;
  /// The same, allocating its buffers.
  [[nodiscard]] FrameWrench evaluate(const Vec& q, const Vec& lambda) const;
  /// G_a, G_b (m × 6 each) at q.
  virtual void maps(const Vec& q, Mat& Ga, Mat& Gb) const = 0;
  /// Twist Jacobians of the frames a and b (6 × n) at q.
  virtual void jacobians(const Vec& q, Mat& Ja, Mat& Jb) const = 0;
  /// The same into Ja, Jb already sized 6 × n, with the buffers of ws (from workspace()): no heap
  /// allocation.
  virtual void jacobians(CVecRef q, Workspace& ws, Mat& Ja, Mat& Jb) const = 0;

 protected:
  FrameWrenches(std::string name, std::string frame_a, std::string frame_b,
                FrameConstraintDef::Kind kind, Index rows)
      : name_(std::move(name)),
        frame_a_(std::move(frame_a)),
        frame_b_(std::move(frame_b)),
        kind_(kind),
        m_(rows),
        has_b_(kind != FrameConstraintDef::Kind::level) {}

 private:
  std::string name_, frame_a_, frame_b_;
  FrameConstraintDef::Kind kind_;
  Index m_ = 0;
  bool has_b_ = true;
};

/// w from G_a, G_b, λ and the poses already in w: w_a = G_aᵀλ, w_b = G_bᵀλ (force, moment about
/// the frame origin; in world axes and in the frame's own).
void wrench_from_maps(const Mat& Ga, const Mat& Gb, const Vec& lambda, FrameWrench& w);

/// FrameWrenches compiled from the frames' expressions over the system coordinates.
class FrameWrenchMap final : public FrameWrenches {
 public:
  /// `symbols`: the table of the frames' expressions (their coordinates).
  FrameWrenchMap(const FrameConstraintDef& f, const std::vector<std::string>& system_coordinates,
                 SymbolTable& symbols, const GiNaC::exmap& values = {});
  using FrameWrenches::evaluate;
  [[nodiscard]] Workspace workspace() const override;
  void evaluate(CVecRef q, const Vec& lambda, Workspace& ws, FrameWrench& w) const override;
  void maps(const Vec& q, Mat& Ga, Mat& Gb) const override;
  void jacobians(const Vec& q, Mat& Ja, Mat& Jb) const override;
  void jacobians(CVecRef q, Workspace& ws, Mat& Ja, Mat& Jb) const override;

 private:
  Index n_ = 0;
  Tape tape_;  // Ga (m×6), Gb (m×6), pa, Ra, pb, Rb, Ja (6×n), Jb (6×n)
};

/// A constraint block between two frames that also knows the wrenches on its frames (what the
/// io layer's constraint_force_output writes). Its rows are a DerivedConstraint's (derived from
/// the frames' expressions) or the numeric ones of frames on trees; every evaluation is theirs.
class FrameConstraint final : public Constraint, public ConstraintColumns {
 public:
  /// `derived`: the derivation of the rows, if they were derived (for `ukdyn derive`), else null.
  FrameConstraint(std::shared_ptr<const Constraint> rows,
                  std::shared_ptr<const FrameWrenches> wrench,
                  std::shared_ptr<const DerivedConstraint> derived = nullptr)
      : c_(std::move(rows)), w_(std::move(wrench)), d_(std::move(derived)) {}
  [[nodiscard]] Index rows() const override { return c_->rows(); }
  [[nodiscard]] const std::vector<std::string>& row_names() const override {
    return c_->row_names();
  }
  [[nodiscard]] Index slot_size() const override { return c_->slot_size(); }
  [[nodiscard]] Index shared_slot_size() const override { return c_->shared_slot_size(); }
  [[nodiscard]] std::vector<std::vector<Index>> row_columns() const override {
    return c_->row_columns();
  }
  void evaluate(const ConstraintContext& ctx, CVecRef q, CVecRef qd, MatRef A,
                VecRef b) const override {
    c_->evaluate(ctx, q, qd, A, b);
  }
  void position_residual(const ConstraintContext& ctx, CVecRef q, VecRef phi) const override {
    c_->position_residual(ctx, q, phi);
  }
  void velocity_residual(const ConstraintContext& ctx, CVecRef q, CVecRef qd,
                         VecRef phid) const override {
    c_->velocity_residual(ctx, q, qd, phid);
  }
  void residuals(const ConstraintContext& ctx, CVecRef q, CVecRef qd, VecRef phi,
                 VecRef phid) const override {
    c_->residuals(ctx, q, qd, phi, phid);
  }
  [[nodiscard]] bool has_derivatives() const override { return c_->has_derivatives(); }
  bool tangent(const ConstraintContext& ctx, CVecRef q, CVecRef qd, CVecRef qdd, CVecRef lambda,
               CVecRef dq, CVecRef dqd, VecRef d_residual, VecRef d_force) const override {
    return c_->tangent(ctx, q, qd, qdd, lambda, dq, dqd, d_residual, d_force);
  }
  bool time_tangent(const ConstraintContext& ctx, CVecRef q, CVecRef qd, CVecRef qdd,
                    CVecRef lambda, VecRef d_residual, VecRef d_force) const override {
    return c_->time_tangent(ctx, q, qd, qdd, lambda, d_residual, d_force);
  }
  /// The rows' tangent_columns() where they have one (the numeric rows of frames on trees).
  bool tangent_columns(const ConstraintContext& ctx, CVecRef q, CVecRef qd, CVecRef qdd,
                       CVecRef lambda, MatRef d_residual, MatRef d_force) const override {
    const auto* all = dynamic_cast<const ConstraintColumns*>(c_.get());
    return all != nullptr && all->tangent_columns(ctx, q, qd, qdd, lambda, d_residual, d_force);
  }
  /// The derivation of the rows (null for the numeric rows of frames on trees).
  [[nodiscard]] const DerivedConstraint* derived() const { return d_.get(); }
  [[nodiscard]] const FrameWrenches& wrench() const { return *w_; }

 private:
  std::shared_ptr<const Constraint> c_;
  std::shared_ptr<const FrameWrenches> w_;
  std::shared_ptr<const DerivedConstraint> d_;
};

/// make_constraint(def) (def holding the rows of f, add_frame_constraint) with f's wrench map.
std::shared_ptr<FrameConstraint> make_frame_constraint(const ConstraintDef& def,
                                                       const FrameConstraintDef& f);

}  // namespace ukdyn::symbolic
