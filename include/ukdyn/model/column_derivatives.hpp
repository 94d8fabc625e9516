// Optional interfaces of the components whose exact derivatives come for every direction in one
// call (docs/derivatives.md, "Cost"): linearize() asks a subsystem or a constraint for them and
// otherwise runs its one-direction tangent (Subsystem::inverse_dynamics_tangent,
// Constraint::tangent) once per direction. The values are those of the one-direction tangents.
#pragma once

#include "ukdyn/core/types.hpp"
#include "ukdyn/model/constraint.hpp"

namespace ukdyn {

/// A subsystem that gives every column of its inverse dynamics' derivatives in one call.
class SubsystemColumns {
 public:
  virtual ~SubsystemColumns() = default;
  /// dID_dq = ∂ID/∂q and dID_dqd = ∂ID/∂q̇ (dof × dof each) of ID(q, q̇, q̈) = M q̈ + C q̇ + G at
  /// fixed q̈ (and t), exact: column j is inverse_dynamics_tangent() along e_j. `c` as there.
  /// False when there is no such pass (then the caller runs the tangent per direction).
  virtual bool inverse_dynamics_jacobian(const EvalContext& c, CVecRef q, CVecRef qd, CVecRef qdd,
                                         MatRef dID_dq, MatRef dID_dqd) const = 0;
};

/// A constraint that gives its tangents along every direction in one call.
class ConstraintColumns {
 public:
  virtual ~ConstraintColumns() = default;
  /// Constraint::tangent() along every direction of (q, q̇): column j of d_residual (rows() × 2n)
  /// and of d_force (n × 2n) along e_j of q, n + j along e_j of q̇; d_residual written (with
  /// c.structural_only may be its row_columns()' directions alone), d_force added to. False: no
  /// such pass at present (then the caller runs tangent() per direction).
  virtual bool tangent_columns(const ConstraintContext& c, CVecRef q, CVecRef qd, CVecRef qdd,
                               CVecRef lambda, MatRef d_residual, MatRef d_force) const = 0;
};

}  // namespace ukdyn
