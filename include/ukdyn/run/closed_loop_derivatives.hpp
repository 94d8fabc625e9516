// Derivatives of a control scenario's closed loop (docs/derivatives.md, "Controlled runs"): the
// law's ∂τ/∂(q, q̇) at a state, and the closed-loop state-space model of the plant under the law.
//
// The plant is integrated as ẋ = f(t, x) = (q̇, q̈_plant(t, q, q̇, τ(t, q, q̇))), τ = τ_plant +
// B sat(u(t, q, q̇)) + τ_d (ukdyn/simulate/control.hpp). Its Jacobian is
//   ∂q̈/∂x|closed = ∂q̈_plant/∂x + ∂q̈_plant/∂τ ∂τ/∂x,
// ∂q̈_plant/∂(q, q̇, τ) exact (linearize()), ∂τ/∂(q, q̇) exact too: composed from the KKT
// derivatives of the model's U-K solve with the law's corrected right-hand side, the derivative of
// the least-squares actuation solve (a pseudo-inverse of constant rank) and the saturation
// (run/law_jacobian.hpp); ∂τ/∂t exact too, t one more direction of the same composition (the
// components' time tangents). Where a part cannot be made exact (`method`, `dtau_dt_method` say
// why), Richardson-extrapolated central differences of the law (error O(h⁴); [Richardson1911]). At a kink of the law (the robust law's boundary layer
// ‖μ‖ = ε, an actuator at its limit) `kinks` names the law and the cause.
#pragma once

#include <string>
#include <vector>

#include "ukdyn/model/linearize.hpp"
#include "ukdyn/output/control_output.hpp"
#include "ukdyn/scenario/scenario.hpp"

namespace ukdyn {

/// τ of the closed loop at (t, q, q̇) (the plant's applied generalized forces) and its derivatives.
struct LawDerivatives {
  Vec tau;                ///< n: τ_plant + B sat(u) + τ_d
  Vec u;                  ///< k: the law's u after saturation
  Mat dtau_dq, dtau_dqd;  ///< n × n each
  /// n: ∂τ/∂t at fixed (q, q̇) (a moving reference, the servo rows' own time; step law_step(t)):
  /// the affine term of the closed loop's linear time-varying model, not part of F
  Vec dtau_dt;
  /// Empty, or why the law is not differentiable inside the probes ("robust law: the boundary
  /// layer |mu| = epsilon", "actuator 'fx' at its limit"), one entry per cause.
  std::vector<std::string> kinks;
  /// How ∂τ/∂(q, q̇) was taken: "exact", or "differences: " and why not exact.
  std::string method;
  /// How ∂τ/∂t was taken: "exact", or "differences: " and why not exact (a component of the
  /// law's model without an exact ∂/∂t, or as `method`).
  std::string dtau_dt_method;
};

/// The step of the law's differences along coordinate x_j: 1e-6 max(1, |x_j|) (small against the
/// robust law's boundary layer, large against round-off: docs/derivatives.md).
double law_step(double x);

/// τ, ∂τ/∂(q, q̇) (exact where it can, see `method`) and ∂τ/∂t (exact where it can, see
/// `dtau_dt_method`; else differences: 4 more evaluations of the loop) of the run's loop at
/// (t, q, q̇) (it is left evaluated at the state: the caller's run is a workspace).
LawDerivatives law_derivatives(ControlRun& run, double t, CVecRef q, CVecRef qd);

/// law_derivatives() with ∂τ/∂(q, q̇) and ∂τ/∂t by Richardson differences of the law whatever
/// the law (8n + 5 evaluations of the loop): the fallback, and the exact path's reference in the
/// tests.
LawDerivatives law_derivatives_by_differences(ControlRun& run, double t, CVecRef q, CVecRef qd);

/// ∂τ/∂x · (dq, dq̇): the law's derivative along one direction, by the same Richardson differences
/// (4 evaluations; 0 for a zero direction). Adds the causes of a kink to `kinks` (no repeats).
Vec law_direction(ControlRun& run, double t, CVecRef q, CVecRef qd, CVecRef dq, CVecRef dqd,
                  std::vector<std::string>& kinks);

/// Why the law's ∂τ/∂(q, q̇) cannot be exact at any state (the loop runs a user's law, the law's
/// model has a component without tangents, a servo row is velocity-level); empty when it can.
std::string law_jacobian_gap(const ControlRun& run);

/// The buffers of law_jacobian() for one run: the law's model's linearisation (LinearizeData,
/// allocated once), and why the last call was not exact.
struct LawJacobianWorkspace {
  explicit LawJacobianWorkspace(const ControlRun& run) : ld(*run.model.system) {}
  LinearizeData ld;
  std::vector<std::string> kinks;  ///< the kinks of the last call (no derivative given there)
  std::string why_not;             ///< why the last call gave none (a kink, or not exact)
};

/// The loop evaluated at (t, q, q̇) and the law's exact ∂τ/∂(q, q̇) there (dtau_dq, dtau_dqd:
/// n × n, resized): one evaluation of the loop, one linearize_corrected() of the law's model, the
/// actuation solve's derivative (run/law_jacobian.hpp). False, with ws.why_not, where it is not
/// exact at this state: law_jacobian_gap(), the model's KKT derivatives not vouched for, or a kink
/// of the law within 1e-6 (relative) of the state (ws.kinks; the exact derivative there would be
/// that of one side only). The caller then takes differences. The loop is left at the state.
bool law_jacobian(const ControlRun& run, LawJacobianWorkspace& ws, double t, CVecRef q, CVecRef qd,
                  Mat& dtau_dq, Mat& dtau_dqd);

/// SimulationSettings::tau_jacobian for a run of run's loop (docs/derivatives.md, "Exact Jacobians
/// in the implicit integrators"): law_jacobian() into a workspace of its own. Where that gives no
/// exact derivative it throws ukdyn::Error (with ws.why_not): the integrator's exact Jacobian then
/// builds that one Jacobian by differences of f and counts it (SimulationStats::
/// jacobian_fallbacks). References run (it must outlive the function); the function's copies share
/// one workspace (one run at a time). Set it only when law_jacobian_gap(run) is empty.
ForceJacobian law_force_jacobian(const ControlRun& run);

/// The closed loop at one state of the plant.
struct ClosedLoopLinearization {
  LawDerivatives law;
  /// linearize() of the plant (physical rows only) at τ = law.tau, with ∂q̈/∂(q, q̇), ∂Qc/∂(q, q̇)
  /// and ∂/∂t (q̈, Qc, μ) those of the closed loop (the law's chain rule added; its ∂τ/∂t as
  /// law.dtau_dt_method says); ∂/∂τ stay the plant's.
  Linearization lin;
};

/// Throws ukdyn::Error when the scenario has no control: section or a plant component has no
/// exact derivatives.
ClosedLoopLinearization closed_loop_linearization(const Scenario& sc, double t, CVecRef q,
                                                  CVecRef qd);

}  // namespace ukdyn
