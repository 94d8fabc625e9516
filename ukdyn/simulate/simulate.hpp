// Time integration of the constrained equations of motion q̈ = M^{-1}(Q + Qc), paper Eq. (18).
#pragma once

#include <functional>
#include <string>

#include "ukdyn/model/system.hpp"

namespace ukdyn {

enum class IntegratorKind { dopri5, rk4 };

struct SimulationSettings {
  double t0 = 0.0;
  double t_end = 1.0;
  double sample_dt = 0.01;  ///< output sample step
  IntegratorKind integrator = IntegratorKind::dopri5;
  double abs_tol = 1e-12;  ///< dopri5 absolute tolerance
  double rel_tol = 1e-12;  ///< dopri5 relative tolerance
  double step = 1e-3;      ///< rk4 fixed step (must divide sample_dt); dopri5 initial step
  UkSettings uk;
};

enum class RunStatus { completed, non_finite, inconsistent_constraints, step_failure, stopped };
std::string to_string(RunStatus status);

struct SimulationStats {
  RunStatus status = RunStatus::completed;
  std::string message;       ///< why the run stopped early (empty if completed)
  double t_reached = 0.0;    ///< last time written
  long steps = 0;            ///< accepted steps
  long rhs_evaluations = 0;  ///< forward() calls by the integrator
  long samples = 0;          ///< observer calls
};

/// Called at every output sample with the state and a ForwardData evaluated at it (q̈, Qc, A, b, …).
/// Return false to stop the run (status `stopped`).
using SampleObserver =
    std::function<bool(double t, CVecRef q, CVecRef qd, const ForwardData& data)>;

/// Applied generalized forces τ(t, q, q̇) written into tau (size n). Must not allocate.
using ForceFunction = std::function<void(double t, CVecRef q, CVecRef qd, VecRef tau)>;

/// Integrates from (q0, qd0). Never throws for numerical trouble: a NaN/Inf state, a failed step or
/// an inconsistent constraint set ends the run with a status, after the samples written so far.
/// Throws ukdyn::Error for invalid settings (sizes, non-positive steps).
SimulationStats simulate(const System& system, const Vec& q0, const Vec& qd0,
                         const ForceFunction& tau, const SimulationSettings& settings,
                         const SampleObserver& observer);

}  // namespace ukdyn
