// The paper's constraints between and on the two mobile manipulators.
#pragma once

#include <array>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "ukdyn/model/constraint.hpp"
#include "ukdyn/model/time_function.hpp"
#include "ukdyn/paper_robot/mobile_manipulator.hpp"

namespace ukdyn {

/// Closure of the load cut at its centre, paper Eq. (12), with A, b from Eqs. (15)–(16):
///   x1 = x2, y1 = y2, l_r1 + ρ̂1 = l_r2 + ρ̂2 + Δz, δ1 − δ2 = yaw_offset (π), θ3 = load1, θ6 = load2.
/// Row names: <prefix>_x, _y, _z, _yaw, _load1, _load2.
class ClosureConstraint final : public Constraint {
 public:
  struct Options {
    double dz = 0.0;
    double yaw_offset = 3.141592653589793;
    double load_pitch1 = 0.0;
    double load_pitch2 = 0.0;
    std::string prefix = "closure";
  };
  ClosureConstraint(std::shared_ptr<const MobileManipulator> left, Index left_offset,
                    std::shared_ptr<const MobileManipulator> right, Index right_offset,
                    Options options);

  [[nodiscard]] Index rows() const override { return 6; }
  [[nodiscard]] const std::vector<std::string>& row_names() const override { return names_; }
  /// With the data slots: the arms' sin/cos from their slots (MobileManipulator::kSlotSize); the
  /// evaluations without slots recompute them.
  void evaluate(const ConstraintContext& ctx, CVecRef q, CVecRef qd, MatRef A,
                VecRef b) const override;
  void position_residual(const ConstraintContext& ctx, CVecRef q, VecRef phi) const override;
  void velocity_residual(const ConstraintContext& ctx, CVecRef q, CVecRef qd,
                         VecRef phid) const override;
  /// Exact derivatives (docs/derivatives.md): rows 1–3 from the arms' dJ, dc (the cut-point
  /// kinematics on dual numbers, MobileManipulator::cut_point_jacobian_tangent); rows 4–6 are
  /// constant (A fixed, b = 0), their tangents 0.
  [[nodiscard]] bool has_derivatives() const override { return true; }
  bool tangent(const ConstraintContext& ctx, CVecRef q, CVecRef qd, CVecRef qdd, CVecRef lambda,
               CVecRef dq, CVecRef dqd, VecRef d_residual, VecRef d_force) const override;
  /// A and b do not depend on t: ∂/∂t is 0 (exact).
  bool time_tangent(const ConstraintContext&, CVecRef, CVecRef, CVecRef, CVecRef, VecRef d_residual,
                    VecRef) const override {
    d_residual.setZero();
    return true;
  }

 private:
  std::shared_ptr<const MobileManipulator> left_, right_;
  Index lo_, ro_;
  Options opt_;
  std::vector<std::string> names_;
};

/// The cut point of one arm follows a trajectory along chosen axes, paper Eq. (19) rows 1–3, with
/// A, b from Eq. (20):  p_axis(q) = origin_axis + f_axis(t). Unused axes are skipped.
class CutPointTrajectory final : public Constraint {
 public:
  CutPointTrajectory(std::shared_ptr<const MobileManipulator> arm, Index offset,
                     std::array<std::optional<TimeFunction>, 3> axes, Vec3 origin,
                     std::string prefix);

  [[nodiscard]] Index rows() const override { return static_cast<Index>(axis_.size()); }
  [[nodiscard]] const std::vector<std::string>& row_names() const override { return names_; }
  /// With the data slots: the arms' sin/cos from their slots (MobileManipulator::kSlotSize); the
  /// evaluations without slots recompute them.
  void evaluate(const ConstraintContext& ctx, CVecRef q, CVecRef qd, MatRef A,
                VecRef b) const override;
  void position_residual(const ConstraintContext& ctx, CVecRef q, VecRef phi) const override;
  void velocity_residual(const ConstraintContext& ctx, CVecRef q, CVecRef qd,
                         VecRef phid) const override;
  /// Exact derivatives (docs/derivatives.md) with respect to (q, q̇) at fixed t: b = f̈(t) − c, so
  /// d(A q̈ − b) = dJ q̈ + dc on the chosen axes, from MobileManipulator::cut_point_jacobian_tangent.
  [[nodiscard]] bool has_derivatives() const override { return true; }
  bool tangent(const ConstraintContext& ctx, CVecRef q, CVecRef qd, CVecRef qdd, CVecRef lambda,
               CVecRef dq, CVecRef dqd, VecRef d_residual, VecRef d_force) const override;
  /// A = J_axis(q) does not depend on t and b = f̈(t) − c_axis(q, q̇): ∂(A q̈ − b)/∂t = −f⃛(t)
  /// (TimeFunction::eval, d = 3), ∂(Aᵀλ)/∂t = 0.
  bool time_tangent(const ConstraintContext& ctx, CVecRef q, CVecRef qd, CVecRef qdd,
                    CVecRef lambda, VecRef d_residual, VecRef d_force) const override;

 private:
  std::shared_ptr<const MobileManipulator> arm_;
  Index offset_;
  std::vector<int> axis_;
  std::vector<TimeFunction> f_;
  Vec3 origin_;
  std::vector<std::string> names_;
};

/// One generalized coordinate follows a function of time: q_j = f(t) (paper Eq. (19) rows 4–6 with
/// f constant, Eq. (20): q̈_j = 0).
class CoordinateConstraint final : public Constraint {
 public:
  CoordinateConstraint(Index coordinate, TimeFunction f, std::string name);
  [[nodiscard]] Index rows() const override { return 1; }
  [[nodiscard]] const std::vector<std::string>& row_names() const override { return names_; }
  /// A = e_jᵀ: column j alone (a row on a free body's z is then one of its own rows, which the
  /// singular solve and the derivatives' augmentation count alike, ukdyn/core/uk_singular.hpp).
  [[nodiscard]] std::vector<std::vector<Index>> row_columns() const override { return {{j_}}; }
  void evaluate(const ConstraintContext& ctx, CVecRef q, CVecRef qd, MatRef A,
                VecRef b) const override;
  void position_residual(const ConstraintContext& ctx, CVecRef q, VecRef phi) const override;
  void velocity_residual(const ConstraintContext& ctx, CVecRef q, CVecRef qd,
                         VecRef phid) const override;
  /// q_j = f(t): A = e_jᵀ is constant and b = f̈(t) depends on t alone, so A q̈ − b and Aᵀλ do
  /// not change with (q, q̇): both tangents are 0 (exact).
  [[nodiscard]] bool has_derivatives() const override { return true; }
  bool tangent(const ConstraintContext&, CVecRef, CVecRef, CVecRef, CVecRef, CVecRef, CVecRef,
               VecRef d_residual, VecRef) const override {
    d_residual.setZero();
    return true;
  }
  /// ∂(A q̈ − b)/∂t = −f⃛(t) (TimeFunction::eval, d = 3); A is constant: ∂(Aᵀλ)/∂t = 0.
  bool time_tangent(const ConstraintContext& ctx, CVecRef, CVecRef, CVecRef, CVecRef,
                    VecRef d_residual, VecRef) const override {
    d_residual(0) = -f_.eval(ctx.t, 3);
    return true;
  }

 private:
  Index j_;
  TimeFunction f_;
  std::vector<std::string> names_;
};

}  // namespace ukdyn
