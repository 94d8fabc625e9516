#include "ukdyn/paper_robot/cooperative_constraints.hpp"

#include <cmath>

namespace ukdyn {

namespace {
using Jac36 = Eigen::Matrix<double, 3, 6>;
const char* const kAxis[3] = {"x", "y", "z"};
}  // namespace

// ---------------------------------------------------------------- closure, Eqs. (12), (15), (16)

ClosureConstraint::ClosureConstraint(std::shared_ptr<const MobileManipulator> left,
                                     Index left_offset,
                                     std::shared_ptr<const MobileManipulator> right,
                                     Index right_offset, Options options)
    : left_(std::move(left)),
      right_(std::move(right)),
      lo_(left_offset),
      ro_(right_offset),
      opt_(std::move(options)) {
  if (!left_ || !right_) throw Error("closure constraint: both arms are required");
  if (lo_ == ro_)
    throw Error("closure constraint '" + opt_.prefix + "': an arm cannot close on itself");
  for (const char* s : {"_x", "_y", "_z", "_yaw", "_load1", "_load2"})
    names_.push_back(opt_.prefix + s);
}

void ClosureConstraint::evaluate(const ConstraintContext& ctx, CVecRef q, CVecRef qd, MatRef A,
                                 VecRef b) const {
  Jac36 J1, J2;
  Vec3 c1, c2;
  left_->cut_point_jacobian(q.segment(lo_, 6), qd.segment(lo_, 6), J1, c1,
                            ctx.slots.subsystem(lo_));
  right_->cut_point_jacobian(q.segment(ro_, 6), qd.segment(ro_, 6), J2, c2,
                             ctx.slots.subsystem(ro_));
  // Rows 1–3 of Eq. (15): the two cut points coincide; b from Eq. (16): b = −(J̇1 q̇1 − J̇2 q̇2).
  zero_rows(A);
  A.block(0, lo_, 3, 6) = J1;
  A.block(0, ro_, 3, 6) = -J2;
  b.head<3>() = c2 - c1;
  // Rows 4–6: δ1 − δ2 = π, θ3 = 0, θ6 = 0 (Eq. (12)); second derivatives have no velocity terms.
  A(3, lo_ + 2) = 1.0;
  A(3, ro_ + 2) = -1.0;
  A(4, lo_ + 5) = 1.0;
  A(5, ro_ + 5) = 1.0;
  b.tail<3>().setZero();
}

void ClosureConstraint::position_residual(const ConstraintContext& ctx, CVecRef q,
                                          VecRef phi) const {
  const Vec3 p1 = left_->cut_point(q.segment(lo_, 6), ctx.slots.subsystem(lo_));
  const Vec3 p2 = right_->cut_point(q.segment(ro_, 6), ctx.slots.subsystem(ro_));
  phi(0) = p1(0) - p2(0);
  phi(1) = p1(1) - p2(1);
  // l_r1 + ρ̂1 = l_r2 + ρ̂2 + Δz  (Eq. (12) row 3)
  phi(2) = p1(2) - p2(2) - opt_.dz;
  phi(3) = q(lo_ + 2) - q(ro_ + 2) - opt_.yaw_offset;
  phi(4) = q(lo_ + 5) - opt_.load_pitch1;
  phi(5) = q(ro_ + 5) - opt_.load_pitch2;
}

void ClosureConstraint::velocity_residual(const ConstraintContext& ctx, CVecRef q, CVecRef qd,
                                          VecRef phid) const {
  Jac36 J1, J2;
  Vec3 c1, c2;
  left_->cut_point_jacobian(q.segment(lo_, 6), qd.segment(lo_, 6), J1, c1,
                            ctx.slots.subsystem(lo_));
  right_->cut_point_jacobian(q.segment(ro_, 6), qd.segment(ro_, 6), J2, c2,
                             ctx.slots.subsystem(ro_));
  phid.head<3>() = J1 * qd.segment(lo_, 6) - J2 * qd.segment(ro_, 6);
  phid(3) = qd(lo_ + 2) - qd(ro_ + 2);
  phid(4) = qd(lo_ + 5);
  phid(5) = qd(ro_ + 5);
}

// Rows 1–3: A = [J1, −J2], b = c2 − c1, so along (dq, dq̇) at fixed q̈, λ:
//   d(A q̈ − b) = dJ1 q̈1 − dJ2 q̈2 + dc1 − dc2,   d(Aᵀλ) = (dJ1ᵀ λ_xyz, −dJ2ᵀ λ_xyz)
// at the arms' coordinates. Rows 4–6 have constant A and b = 0: their tangents are 0.
bool ClosureConstraint::tangent(const ConstraintContext& /*ctx*/, CVecRef q, CVecRef qd,
                                CVecRef qdd, CVecRef lambda, CVecRef dq, CVecRef dqd,
                                VecRef d_residual, VecRef d_force) const {
  Jac36 dJ1, dJ2;
  Vec3 dc1, dc2;
  left_->cut_point_jacobian_tangent(q.segment(lo_, 6), qd.segment(lo_, 6), dq.segment(lo_, 6),
                                    dqd.segment(lo_, 6), dJ1, dc1);
  right_->cut_point_jacobian_tangent(q.segment(ro_, 6), qd.segment(ro_, 6), dq.segment(ro_, 6),
                                     dqd.segment(ro_, 6), dJ2, dc2);
  d_residual.head<3>() = dJ1 * qdd.segment(lo_, 6) - dJ2 * qdd.segment(ro_, 6) + dc1 - dc2;
  d_residual.tail<3>().setZero();
  const Vec3 l = lambda.head<3>();
  d_force.segment(lo_, 6) += dJ1.transpose() * l;
  d_force.segment(ro_, 6) -= dJ2.transpose() * l;
  return true;
}

// ------------------------------------------------------- cut-point trajectory, Eqs. (19), (20)

CutPointTrajectory::CutPointTrajectory(std::shared_ptr<const MobileManipulator> arm, Index offset,
                                       std::array<std::optional<TimeFunction>, 3> axes, Vec3 origin,
                                       std::string prefix)
    : arm_(std::move(arm)), offset_(offset), origin_(origin) {
  if (!arm_) throw Error("trajectory constraint '" + prefix + "': arm is required");
  for (int a = 0; a < 3; ++a) {
    if (axes[static_cast<std::size_t>(a)]) {
      axis_.push_back(a);
      f_.push_back(*axes[static_cast<std::size_t>(a)]);
      names_.push_back(prefix + "_" + kAxis[a]);
    }
  }
  if (axis_.empty()) throw Error("trajectory constraint '" + prefix + "': no axis given");
}

void CutPointTrajectory::evaluate(const ConstraintContext& ctx, CVecRef q, CVecRef qd, MatRef A,
                                  VecRef b) const {
  Jac36 J;
  Vec3 c;
  arm_->cut_point_jacobian(q.segment(offset_, 6), qd.segment(offset_, 6), J, c,
                           ctx.slots.subsystem(offset_));
  zero_rows(A);
  for (std::size_t i = 0; i < axis_.size(); ++i) {
    const auto r = static_cast<Index>(i);
    // p̈_axis = J q̈ + c = f''(t)  ⇒  A = J_axis, b = f''(t) − c_axis  (Eq. (20)).
    A.block(r, offset_, 1, 6) = J.row(axis_[i]);
    b(r) = f_[i].eval(ctx.t, 2) - c(axis_[i]);
  }
}

void CutPointTrajectory::position_residual(const ConstraintContext& ctx, CVecRef q,
                                           VecRef phi) const {
  const Vec3 p = arm_->cut_point(q.segment(offset_, 6), ctx.slots.subsystem(offset_));
  for (std::size_t i = 0; i < axis_.size(); ++i) {
    const int a = axis_[i];
    phi(static_cast<Index>(i)) = p(a) - origin_(a) - f_[i].eval(ctx.t, 0);
  }
}

void CutPointTrajectory::velocity_residual(const ConstraintContext& ctx, CVecRef q, CVecRef qd,
                                           VecRef phid) const {
  Jac36 J;
  Vec3 c;
  arm_->cut_point_jacobian(q.segment(offset_, 6), qd.segment(offset_, 6), J, c,
                           ctx.slots.subsystem(offset_));
  const Vec3 v = J * qd.segment(offset_, 6);
  for (std::size_t i = 0; i < axis_.size(); ++i) {
    phid(static_cast<Index>(i)) = v(axis_[i]) - f_[i].eval(ctx.t, 1);
  }
}

// Row i (axis a): A = J_a, b = f̈(t) − c_a, so at fixed t, q̈, λ: d(A q̈ − b) = dJ_a q̈ + dc_a and
// d(Aᵀλ) = dJ_aᵀ λ_i at the arm's coordinates.
bool CutPointTrajectory::tangent(const ConstraintContext& /*ctx*/, CVecRef q, CVecRef qd,
                                 CVecRef qdd, CVecRef lambda, CVecRef dq, CVecRef dqd,
                                 VecRef d_residual, VecRef d_force) const {
  Jac36 dJ;
  Vec3 dc;
  arm_->cut_point_jacobian_tangent(q.segment(offset_, 6), qd.segment(offset_, 6),
                                   dq.segment(offset_, 6), dqd.segment(offset_, 6), dJ, dc);
  for (std::size_t i = 0; i < axis_.size(); ++i) {
    const auto r = static_cast<Index>(i);
    const int a = axis_[i];
    d_residual(r) = dJ.row(a).dot(qdd.segment(offset_, 6)) + dc(a);
    d_force.segment(offset_, 6) += lambda(r) * dJ.row(a).transpose();
  }
  return true;
}

bool CutPointTrajectory::time_tangent(const ConstraintContext& ctx, CVecRef /*q*/, CVecRef /*qd*/,
                                      CVecRef /*qdd*/, CVecRef /*lambda*/, VecRef d_residual,
                                      VecRef /*d_force*/) const {
  for (std::size_t i = 0; i < axis_.size(); ++i)
    d_residual(static_cast<Index>(i)) = -f_[i].eval(ctx.t, 3);
  return true;
}

// ------------------------------------------------------------------- coordinate = f(t)

CoordinateConstraint::CoordinateConstraint(Index coordinate, TimeFunction f, std::string name)
    : j_(coordinate), f_(f), names_{std::move(name)} {
  if (j_ < 0) throw Error("coordinate constraint '" + names_[0] + "': negative coordinate index");
}

void CoordinateConstraint::evaluate(const ConstraintContext& ctx, CVecRef /*q*/, CVecRef /*qd*/,
                                    MatRef A, VecRef b) const {
  zero_rows(A);
  A(0, j_) = 1.0;
  b(0) = f_.eval(ctx.t, 2);
}

void CoordinateConstraint::position_residual(const ConstraintContext& ctx, CVecRef q,
                                             VecRef phi) const {
  phi(0) = q(j_) - f_.eval(ctx.t, 0);
}

void CoordinateConstraint::velocity_residual(const ConstraintContext& ctx, CVecRef /*q*/,
                                             CVecRef qd, VecRef phid) const {
  phid(0) = qd(j_) - f_.eval(ctx.t, 1);
}

}  // namespace ukdyn
