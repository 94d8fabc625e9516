// SlotConstraint: the forwarding from the evaluations without data to those with data slots,
// written once for every constraint that uses slots (docs/architecture.md, "Data slots").
#pragma once

#include "ukdyn/model/constraint.hpp"

namespace ukdyn {

/// A constraint written once, with the data slots: it implements the three `…_with` evaluations,
/// and the versions without data call them with no slots (`ConstraintSlots{}`, where every slot is
/// empty, so the implementation must then compute what it would read from a slot). The one place
/// where that forwarding is written (closed-form models and derived constraints alike).
class SlotConstraint : public Constraint {
 public:
  void evaluate(double t, CVecRef q, CVecRef qd, MatRef A, VecRef b) const final {
    evaluate_with(ConstraintSlots{}, t, q, qd, A, b);
  }
  void position_residual(double t, CVecRef q, VecRef phi) const final {
    position_residual_with(ConstraintSlots{}, t, q, phi);
  }
  void velocity_residual(double t, CVecRef q, CVecRef qd, VecRef phid) const final {
    velocity_residual_with(ConstraintSlots{}, t, q, qd, phid);
  }
  void evaluate_with(const ConstraintSlots& slots, double t, CVecRef q, CVecRef qd, MatRef A,
                     VecRef b) const override = 0;
  void position_residual_with(const ConstraintSlots& slots, double t, CVecRef q,
                              VecRef phi) const override = 0;
  void velocity_residual_with(const ConstraintSlots& slots, double t, CVecRef q, CVecRef qd,
                              VecRef phid) const override = 0;
};

}  // namespace ukdyn
