// Internal to ukdyn::simulate: the exact Jacobian ∂f/∂x of the integrators' right-hand side
// f(t, x) = [q̇; q̈(t, q, q̇, τ(t, q, q̇))] for the Newton iterations of bdf and esdirk
// (docs/derivatives.md, "Exact Jacobians in the implicit integrators"):
//   ∂f/∂x = [[0, I], [∂q̈/∂q + ∂q̈/∂τ ∂τ/∂q, ∂q̈/∂q̇ + ∂q̈/∂τ ∂τ/∂q̇]],
// ∂q̈/∂(q, q̇, τ) from linearize() (model/linearize.hpp), ∂τ/∂(q, q̇) from
// SimulationSettings::tau_jacobian.
//
// The energy-balance state W (SimulationSettings::energy_balance, Ẇ = (τ + Q_nc + Qc)ᵀ q̇ − ∂L/∂t)
// is a quadrature: no component of f depends on W. Its row of the Jacobian is left zero (its
// column is zero exactly). The Newton matrix I − γJ is block lower triangular, so the iterates of
// (q, q̇) are those of the exact Jacobian, and W's update W = W_pred + γ Ẇ(x_k) solves its equation
// for the current (q, q̇) iterate: W converges with (q, q̇), one iteration behind. CVODES keeps
// quadratures out of the Newton system altogether for this reason (Serban & Hindmarsh, "CVODES:
// the sensitivity-enabled ODE solver in SUNDIALS", ASME IDETC 2005; its quadrature variables).
// The run's summary says so (SimulationStats::jacobian_note).
#pragma once

#include <string>

#include "ukdyn/model/linearize.hpp"
#include "ukdyn/simulate/simulate.hpp"

namespace ukdyn::detail {

/// Why the exact Jacobian does not cover every term of f for this system, force function and
/// settings (a component without derivatives, τ(t, q, q̇) without ∂τ/∂x, Baumgarte's terms, a
/// damped solve); empty when it does. The energy-balance state is no gap (a quadrature, above).
std::string exact_jacobian_gap(const System& system, const ForceFunction& tau,
                               const SimulationSettings& settings);

/// The exact ∂f/∂x at a state. References system, tau and settings (they must outlive it); its
/// buffers are allocated once: linearize() runs into its LinearizeData and computes ∂q̈/∂(q, q̇)
/// alone (∂q̈/∂τ too with a force function; never ∂Qc).
class ExactJacobian {
 public:
  ExactJacobian(const System& system, const ForceFunction& tau, const SimulationSettings& settings);
  /// J: column-major (2n + 1 with the energy balance) squared, zeroed by the caller. False (J
  /// unspecified) when linearize() is not trusted at the state (Linearization::trusted: a rank
  /// change near, a damped solve) or fails, or when SimulationSettings::tau_jacobian throws (a
  /// control law with no exact ∂τ/∂x at this state: a kink, run/closed_loop_derivatives.hpp).
  bool operator()(double t, const double* x, double* J);

 private:
  const System& system_;
  const ForceFunction& tau_fn_;
  const SimulationSettings& s_;
  Index n_, size_;
  Vec tau_;
  Mat dtau_dq_, dtau_dqd_;
  LinearizeData lin_;
};

}  // namespace ukdyn::detail
