// Internal to ukdyn::simulate: the implicit (stiff) integrator, SUNDIALS CVODE's variable-order
// BDF method (Hindmarsh et al., ACM TOMS 31 (2005) 363–396) with a dense direct linear solver and
// an exact Jacobian (ImplicitProblem::jacobian) or CVODE's difference-quotient one, and the drift projection as CVODE's projection function
// (CVodeSetProjFn) after every step. Built when SUNDIALS is found (UKDYN_HAVE_CVODE).
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "ukdyn/simulate/simulate.hpp"

namespace ukdyn::detail {

/// True if this ukdyn was built with SUNDIALS CVODE.
bool cvode_available();
/// True if this ukdyn was built with SUNDIALS ARKODE (integrator esdirk).
bool arkode_available();

struct ImplicitProblem {
  std::size_t size = 0;                                              ///< state size
  std::function<void(double t, const double* x, double* dxdt)> rhs;  ///< allocation-free
  std::function<void(double t, double* x)> project;                  ///< may be empty
  std::function<bool(double t, std::vector<double>& x)> observe;     ///< false ends the run
  std::function<double(long)> sample_time;
  /// The exact Jacobian ∂f/∂x at (t, x) into J (column-major, size × size, zeroed by the caller);
  /// false: not trusted at this state (J is then built from forward differences of rhs). Empty:
  /// SUNDIALS's own difference-quotient Jacobian.
  std::function<bool(double t, const double* x, double* J)> jacobian;
  long total_samples = 0;
};

struct ImplicitResult {
  bool failed = false;
  std::string message;
  long steps = 0, error_test_failures = 0, nonlinear_failures = 0, jacobians = 0;
  long jacobian_fallbacks = 0;  ///< exact: calls that fell back to forward differences
};

/// Integrates from x (size `size`) at `t0`, observing at sample_time(1..total_samples−1) (the
/// caller observed t0). Tolerances: settings.rel_tol, settings.abs_tol; initial step settings.step.
ImplicitResult integrate_bdf(const ImplicitProblem& problem, std::vector<double>& x, double t0,
                             const SimulationSettings& settings);

/// The same problem with SUNDIALS ARKODE's ARKStep, a fully implicit ESDIRK method (Kennedy &
/// Carpenter), adaptive, steps ending on the samples, the drift projection after every step.
ImplicitResult integrate_esdirk(const ImplicitProblem& problem, std::vector<double>& x, double t0,
                                const SimulationSettings& settings);

}  // namespace ukdyn::detail
