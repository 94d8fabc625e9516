// Drift control (docs/drift-control.md): the Baumgarte stabilisation of the acceleration-level
// constraints and the projection onto the constraint manifold, with the branch check that bounds
// the projection's correction (docs/singular-positions.md). Internal to simulate(): the public
// settings are DriftSettings in simulate.hpp.
#pragma once

#include <string>

#include "ukdyn/model/system.hpp"
#include "ukdyn/simulate/simulate.hpp"

namespace ukdyn::detail {

/// Baumgarte [Baumgarte1972]: Φ̈ + 2α Φ̇ + β² Φ = 0, i.e. A q̈ = b − 2α Φ̇ − β² Φ. Adjusts data.b
/// (written by evaluate_constraints at (t, q, q̇)); phi and phid are scratch of m entries.
void baumgarte_adjust_b(const System& system, ForwardData& data, const DriftSettings& ds, double t,
                        CVecRef q, CVecRef qd, Vec& phi, Vec& phid);

/// Projection onto the constraint manifold in the metric of M: each correction is the U-K solve
/// with Q = 0 and b = −Φ (positions) or b = −Φ̇ (velocities): Δ = M^{-1}Aᵀ(A M^{-1}Aᵀ)^+ (−r), the
/// smallest change in the kinetic-energy norm that removes the residual r to first order. Owns its
/// buffers (allocated once); project() allocates nothing.
struct Projector {
  const System& system;
  const DriftSettings& ds;
  const UkSettings& uk;
  ForwardData data;
  Vec phi, zero_Q, delta, Qc_scratch;
  Index n;
  double last_dq = 0.0, last_dqd = 0.0;  ///< Σ max|Δq| and max|Δq̇| of the last project()

  Projector(const System& sys, const DriftSettings& d, const UkSettings& u);

  /// Projects x = [q; q̇] in place; returns max|Φ| after projecting; counts Gauss–Newton iterations.
  /// at_x: null, or a ForwardData of the same system whose last evaluation (forward(), or the
  /// stages with the same UkSettings) was at exactly this t and these bytes of q — the integrator's
  /// last stage at an accepted state. Its M and A, functions of (t, q) alone, then serve the first
  /// Gauss–Newton iteration instead of a second evaluation of the same bytes; its solve workspace
  /// (and result flags) are overwritten.
  double project(double t, double* x, long& iterations, ForwardData* at_x = nullptr);
};

/// The branch check (issue 9 item 2): the projection only removes integration error (and, for a
/// damped solve, the constraint error the damping admitted), so its correction must stay within
/// what the error control allows per step, × branch_factor; a larger one means the state was
/// carried somewhere else, e.g. onto another assembly branch near a singular position.
struct BranchCheck {
  double ratio = 0.0;  ///< correction / allowance (> 1: a branch switch is reported)
  double bound_q = 0.0, bound_qd = 0.0;  ///< the allowances for Δq and Δq̇
};
/// xmax = max|x|; h the step; damped = the largest UkResult::damped_acceleration over the step;
/// fixed: a fixed-step integrator (allowance branch_factor · 1e-9 (1 + xmax)).
BranchCheck check_branch(const SimulationSettings& s, bool fixed, double xmax, double h,
                         double damped, double dq, double dqd);

}  // namespace ukdyn::detail
