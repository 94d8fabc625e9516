// Time integration of the constrained equations of motion q̈ = M^{-1}(Q + Qc), paper Eq. (18), with
// drift control, diagnostics and consistent initial conditions.
#pragma once

#include <atomic>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "ukdyn/model/coordinate_limits.hpp"
#include "ukdyn/model/system.hpp"

namespace ukdyn {

/// rk4: classical Runge–Kutta 4, fixed step. dopri5: Dormand–Prince 5(4) [Dormand1980], adaptive
/// with dense output. rkf78: Runge–Kutta–Fehlberg 7(8) [Fehlberg1968], adaptive, stepping exactly
/// onto the sample times. All from Boost.Odeint. dopri5 and rkf78 can also run with a fixed step
/// (adaptive = false). bdf: SUNDIALS CVODE's variable-order BDF (implicit, for stiff problems;
/// always adaptive), available when ukdyn was built with SUNDIALS (bdf_available()).
enum class IntegratorKind { rk4, dopri5, rkf78, bdf, esdirk };
bool bdf_available();
/// True if the esdirk integrator (SUNDIALS ARKODE) is available.
bool esdirk_available();
std::string to_string(IntegratorKind kind);

/// Acceleration-level constraints drift (A q̈ = b only holds Φ̈ = 0). Choices:
///  none:       integrate as is;
///  baumgarte:  A q̈ = b − 2α Φ̇ − β² Φ (Baumgarte 1972), pulls Φ back with time constants 1/α, 1/β;
///  projection: after every step (coordinate projection, [Eich1993], [Ascher1995] in
///              docs/references.md), Gauss–Newton on Φ(q) = 0 in the metric of M, then q̇ onto
///              Φ̇ = A q̇ + Φ_t = 0 in the same metric (each is one U-K solve with Q = 0).
enum class DriftControl { none, baumgarte, projection };
std::string to_string(DriftControl kind);

struct DriftSettings {
  DriftControl kind = DriftControl::projection;
  double alpha = 10.0;              ///< baumgarte: velocity gain [1/s]
  double beta = 10.0;               ///< baumgarte: position gain [1/s]
  double position_tol = 1e-15;      ///< projection: stop iterating once max|Φ| is under this
  int max_iterations = 4;           ///< projection: Gauss–Newton iterations per step at most
  double failure_threshold = 1e-6;  ///< projection: max|Φ| left above this ends the run
  /// projection: a position correction max|Δq| above branch_factor · (abs_tol + rel_tol · max|x|)
  /// (adaptive runs; fixed steps: branch_factor · 1e-9 · (1 + max|q|)) is more than the integration
  /// error explains: warning branch_switch (or the run stops, with stop_on_branch_switch).
  double branch_factor = 1e3;
  bool stop_on_branch_switch = false;
};

/// bdf, esdirk: the Jacobian ∂f/∂x of the Newton iterations (docs/derivatives.md, "Exact
/// Jacobians in the implicit integrators"). exact: from linearize() (∂q̈/∂q, ∂q̈/∂q̇, chained with
/// ∂q̈/∂τ · ∂τ/∂x of SimulationSettings::tau_jacobian); simulate() throws ukdyn::Error when a term
/// of f has no exact derivative. difference: SUNDIALS's difference quotients. automatic: exact
/// when it covers every term of f, else difference quotients (SimulationStats::jacobian_note
/// says why).
enum class JacobianKind { automatic, exact, difference };
std::string to_string(JacobianKind kind);

/// ∂τ/∂q and ∂τ/∂q̇ (n × n each, already sized) of a ForceFunction at (t, q, q̇).
using ForceJacobian =
    std::function<void(double t, CVecRef q, CVecRef qd, Mat& dtau_dq, Mat& dtau_dqd)>;
/// The ForceJacobian of a τ(t) that does not depend on (q, q̇): zeros.
void zero_force_jacobian(double t, CVecRef q, CVecRef qd, Mat& dtau_dq, Mat& dtau_dqd);

struct SimulationSettings {
  double t0 = 0.0;
  double t_end = 1.0;
  double sample_dt = 0.01;  ///< output sample step
  IntegratorKind integrator = IntegratorKind::dopri5;
  bool adaptive = true;    ///< error-controlled steps (dopri5, rkf78); rk4 is always fixed-step
  double abs_tol = 1e-12;  ///< adaptive: absolute tolerance
  double rel_tol = 1e-12;  ///< adaptive: relative tolerance
  double step = 1e-3;      ///< fixed step (must divide sample_dt); adaptive: initial step
  DriftSettings drift;
  UkSettings uk;
  /// A sample whose σ_min/σ_max (pivot estimate) falls under this raises a near-singular warning.
  double near_singular_ratio = 1e-6;
  /// If set and it becomes true (a SIGINT/SIGTERM handler), the run stops after the current step
  /// (status `stopped`), whatever the sample step.
  const std::atomic<bool>* cancel = nullptr;
  /// Integrate the work W(t) = ∫ ((τ + Q_nc + Qc)ᵀ q̇ − ∂L/∂t) dt of τ, of the non-conservative
  /// applied forces and of the constraint forces as one more state of the same stepper (same order
  /// and error control; ∂L/∂t ≠ 0 only with a mass of t); samples get it in ForwardData::work, and
  /// E − W stays constant.
  bool energy_balance = false;
  /// The `sigma_min` output column: false (default) takes the solve's own estimate (the square root
  /// of the smallest kept pivot of its factorisation, UkResult::sigma_min_kept: no extra work);
  /// true computes the exact smallest kept singular value of A M^{-1/2} by an SVD at each sample
  /// (scenario key simulation.sigma_min: svd).
  bool sigma_min_svd = false;
  /// Per coordinate (empty: none; else system.dof() entries), the robot files' limits
  /// (Scenario::coordinate_limits()): the first sample at which a coordinate is outside
  /// [lower, upper] or |q̇| exceeds its velocity limit raises a warning of kind joint_limit for
  /// that coordinate (once per coordinate, with the time and the value); the run goes on.
  std::vector<CoordinateLimits> limits;
  /// bdf, esdirk: which Jacobian the Newton iterations use (JacobianKind).
  JacobianKind jacobian = JacobianKind::automatic;
  /// The ForceFunction's ∂τ/∂q, ∂τ/∂q̇ for the exact Jacobian. Empty with a non-empty
  /// ForceFunction: τ is taken to depend on (q, q̇) without known derivatives (no exact Jacobian).
  ForceJacobian tau_jacobian;
};

/// True if the steps are error-controlled (bdf; dopri5 / rkf78 with adaptive), false for a fixed
/// step.
inline bool adaptive_steps(const SimulationSettings& s) {
  return s.integrator == IntegratorKind::bdf ||
         s.integrator == IntegratorKind::esdirk ||  // bdf, esdirk: always adaptive
         (s.integrator != IntegratorKind::rk4 && s.adaptive);
}

enum class RunStatus {
  completed,
  non_finite,
  inconsistent_constraints,
  step_failure,
  stopped,
  branch_switch
};
std::string to_string(RunStatus status);

/// A warning raised once per kind (joint_limit: once per coordinate) during a run, with the time it first happened.
struct RunWarning {
  double t = 0.0;
  /// fully_prescribed, near_singular, rank_change, inconsistent_constraints, ... (once per
  /// kind); joint_limit (once per coordinate)
  std::string kind;
  std::string message;
};

struct SimulationStats {
  RunStatus status = RunStatus::completed;
  std::string message;                   ///< why the run stopped early (empty if completed)
  double t_reached = 0.0;                ///< last time written
  long steps = 0;                        ///< accepted steps
  long rejected_steps = 0;               ///< steps rejected by the error control
  long rhs_evaluations = 0;              ///< forward() calls by the integrator
  long samples = 0;                      ///< observer calls
  long projections = 0;                  ///< Gauss–Newton iterations done by the projection
  double max_position_correction = 0.0;  ///< largest max|Δq| of one step's projection
  double max_velocity_correction = 0.0;  ///< largest max|Δq̇| of one step's projection
  double max_correction_ratio = 0.0;     ///< largest max|Δq| / the branch bound (≥ 1: warned)
  double min_step = 0.0;                 ///< adaptive dopri5: smallest accepted step (0: none)
  double min_step_t = 0.0;               ///< the time it ended
  /// bdf, esdirk: the Jacobian used, "exact" or "difference" (empty for the explicit integrators).
  std::string jacobian;
  /// Why the difference-quotient Jacobian was used under JacobianKind::automatic, or what the
  /// exact one leaves out (the energy-balance state's row); empty otherwise.
  std::string jacobian_note;
  long jacobian_evaluations = 0;  ///< bdf, esdirk: Jacobian evaluations (either kind)
  /// exact: evaluations at states where linearize() was not trusted (a rank change near, a damped
  /// solve), which used forward differences of f instead (the run goes on).
  long jacobian_fallbacks = 0;
  /// Rows redundant around the motion (found at the start: the rank the exact solve misses at q0
  /// and at two nearby configurations on the manifold; 0 for a start at a singular position whose
  /// rank comes back nearby). The adaptive solve does not damp them (UkSettings).
  int structural_redundancy = 0;
  std::vector<RunWarning> warnings;
};

/// Called at every output sample with the state and a ForwardData evaluated at it (q̈, Qc, A, b, …).
/// Return false to stop the run (status `stopped`).
using SampleObserver =
    std::function<bool(double t, CVecRef q, CVecRef qd, const ForwardData& data)>;

/// Applied generalized forces τ(t, q, q̇) written into tau (size n). Must not allocate.
using ForceFunction = std::function<void(double t, CVecRef q, CVecRef qd, VecRef tau)>;

/// The integrator's right-hand side exactly as simulate() hands it to Boost.Odeint (the same
/// internal type, built the same way): x = [q; q̇] ↦ ẋ = [q̇; q̈], with q̈ from forward() (and the
/// Baumgarte terms in b when settings.drift says so), every buffer owned by this object. Exposed so
/// that tests check the real thing (tests/test_no_alloc.cpp: no allocation per call).
class IntegratorRhs {
 public:
  /// system, tau and settings are referenced, not copied: they must outlive this object.
  IntegratorRhs(const System& system, const ForceFunction& tau, const SimulationSettings& settings);
  ~IntegratorRhs();
  IntegratorRhs(const IntegratorRhs&) = delete;
  IntegratorRhs& operator=(const IntegratorRhs&) = delete;
  /// x and dxdt have 2n entries.
  void operator()(const std::vector<double>& x, std::vector<double>& dxdt, double t);
  /// The ForwardData of the last call (q̈, Qc, A, b, diagnostics).
  [[nodiscard]] const ForwardData& data() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Integrates from (q0, qd0). Never throws for numerical trouble: a NaN/Inf state, a failed step, a
/// failed projection or an inconsistent constraint set ends the run with a status, after the
/// samples written so far. Throws ukdyn::Error for invalid settings (sizes, non-positive steps).
SimulationStats simulate(const System& system, const Vec& q0, const Vec& qd0,
                         const ForceFunction& tau, const SimulationSettings& settings,
                         const SampleObserver& observer);

/// Consistent initial conditions (assembly, [Nikravesh1988]): the q nearest to q_guess
/// (minimum-norm Gauss–Newton steps over the coordinates not held) with Φ(q, t) = 0, then the q̇
/// nearest to qd_guess with A q̇ + Φ_t = 0.
struct AssemblyResult {
  Vec q, qd;  ///< n each (system.dof()): the assembled state
  bool success = false;
  int iterations = 0;
  double max_position_residual = 0.0;  ///< max |Φ(q, t)| over the m rows
  double max_velocity_residual = 0.0;  ///< max |Φ̇(q, q̇, t)| over the m rows
  std::vector<Index> unmet_rows;       ///< rows still violated (|Φ| > tol) if !success
  std::string message;
};
AssemblyResult assemble(const System& system, double t, const Vec& q_guess, const Vec& qd_guess,
                        const std::vector<bool>& held, double tol = 1e-14, int max_iterations = 50);

}  // namespace ukdyn
