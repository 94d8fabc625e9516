// Sensitivities of a scenario's dynamics to the numbers of its file (masses, lengths, inertias,
// spring constants, forces.tau entries, the initial state's parameters): at a state, ∂q̈/∂p and
// ∂Qc/∂p; over a run, dq(t)/dp and dq̇(t)/dp by the variational equations
// (docs/derivatives.md, "Sensitivities to parameters").
//
// A parameter is a number of the scenario file, named by its path (the paths of sweeps,
// docs/sweeps.md: `subsystems[left].params.link_mass[2]`, `forces.tau[3]`) or, for a key of a
// `parameters:` / `params:` map, by its key alone (`m1`) when that key names one number of the file
// (the places an alias repeats it included). ∂M, ∂Q, ∂A, ∂b at a state are the central differences
// of the model re-loaded with p ± h and p ± h/2, Richardson-extrapolated (error O(h⁴), h = 1e-3 |p|);
// everything else (the solve's derivative, ∂q̈/∂q and ∂q̈/∂q̇ of the variational equations) is exact
// (ukdyn/model/parameter_sensitivity.hpp, linearize.hpp).
#pragma once

#include <array>
#include <atomic>
#include <filesystem>
#include <iosfwd>
#include <memory>
#include <string>
#include <vector>

#include "ukdyn/model/parameter_sensitivity.hpp"
#include "ukdyn/scenario/scenario.hpp"

namespace ukdyn {

/// One parameter of a scenario file and the scenario re-loaded around its value.
struct ScenarioParameter {
  std::string name;                ///< as given
  std::vector<std::string> paths;  ///< the places written (several for a key repeated by an alias)
  int line = 0;                    ///< 1-based line of its number in the file
  double value = 0.0;
  double step = 0.0;  ///< h = 1e-3 |p| (1e-3 for p = 0)
  /// "FILE:LINE:COL: key 'outputs.sensitivities[i]'" when the scenario asked for it (errors are
  /// then reported there), empty otherwise.
  std::string asked_at = {};
  /// The scenario re-loaded with p + h, p − h, p + h/2, p − h/2 (initial state not checked).
  std::array<std::shared_ptr<const Scenario>, 4> perturbed;
};

/// The parameters `names` of the scenario `sc` (re-read from sc.path). Throws ScenarioError naming
/// the file and the parameter (and its line when it has one) when a name is not a number of the
/// file, names several numbers, changes the number of coordinates or rows, or changes none of M,
/// Q, A, b and the initial state (at the initial state and at two states near it; in a control
/// scenario also the law's τ and the closed loop's start): a parameter the dynamics does not use.
std::vector<ScenarioParameter> scenario_parameters(const Scenario& sc,
                                                   const std::vector<std::string>& names);

/// The parameters of the scenario's `outputs: {sensitivities: [...]}` (none without it), resolved
/// as scenario_parameters() does; errors name the list entry's line, column and key.
std::vector<ScenarioParameter> requested_parameters(const Scenario& sc);

/// ∂M, ∂Q, ∂A, ∂b at (t, q, q̇, τ) for each parameter (Q with τ + (τ_p − τ_scenario): a parameter
/// of forces.tau counts). Richardson-extrapolated central differences of the re-loaded models.
std::vector<ModelParameterDerivative> model_parameter_derivatives(
    const Scenario& sc, const std::vector<ScenarioParameter>& ps, double t, CVecRef q, CVecRef qd,
    CVecRef tau);

/// d(q0, q̇0)/dp of the initial state (n × P each): nonzero when initial.q uses a parameter.
void initial_state_derivatives(const Scenario& sc, const std::vector<ScenarioParameter>& ps,
                               Mat& dq0, Mat& dqd0);

/// ∂q̈/∂p, ∂Qc/∂p at (t, q, q̇, τ) (with_state: the state columns too, see linearize_parameters).
ParameterLinearization state_sensitivities(const Scenario& sc,
                                           const std::vector<ScenarioParameter>& ps, double t,
                                           CVecRef q, CVecRef qd, CVecRef tau,
                                           bool with_state = false);

/// The sensitivities of a run from the scenario's initial state over [t0, t_end] at its samples.
struct RunSensitivities {
  std::vector<std::string> parameters;  ///< the names, in order
  std::vector<double> t;
  Mat q, qd;                       ///< samples × n
  std::vector<Mat> dq_dp, dqd_dp;  ///< one per parameter, samples × n
  long steps = 0;                  ///< accepted steps
  long rhs_evaluations = 0;
  /// False when a state of the run could not be vouched for (linearize_parameters), message says
  /// where and why; or when the run stopped before t_end (not finite).
  bool trusted = true;
  std::string message;
  /// One line per parameter that moves the constraints away from the initial state
  /// (max |dΦ(q0, t0)/dp| or max |dΦ̇(q0, q̇0, t0)/dp| above 1e-8): its perturbed runs start off
  /// the constraints, so dq/dp is that of the ODE from the file's q0, not of a consistent motion.
  std::vector<std::string> warnings;
  /// A control scenario: how the law's term ∂τ/∂x · s_j was taken ("exact at N of N right-hand
  /// sides", or with the number by directional differences and why the first was); else empty.
  std::string law_derivative;
};

/// Integrates x = (q, q̇) with the variational equations s' = (∂f/∂x) s + ∂f/∂p, s(t0) = dx0/dp,
/// by Dormand–Prince 5(4) at the scenario's abs_tol / rel_tol, with no drift control (the
/// sensitivities are those of the exact constrained motion). A scenario with a `control:` section:
/// the plant's closed loop from its start (the offset start), with the law's ∂τ/∂x
/// (ukdyn/run/closed_loop_derivatives.hpp) in ∂f/∂x and ∂f/∂p of the re-loaded closed loops (a
/// gain is a parameter); `warnings` name the law and the first time where it is not
/// differentiable. Throws ukdyn::Error for a component without exact tangents. `cancel` (may be
/// null) is read at every right-hand side: once true the run stops where it is, the samples so far
/// are returned, `trusted` is false and `message` says it was interrupted (Python's Ctrl-C).
RunSensitivities run_sensitivities(const Scenario& sc, const std::vector<ScenarioParameter>& ps,
                                   const std::atomic<bool>* cancel = nullptr);

/// The CSV header of a RunSensitivities: t, the coordinates, their `_dot`, then per parameter p
/// `dq_<coord>/d<p>` for every coordinate and `dqd_<coord>/d<p>` for every coordinate.
std::vector<std::string> sensitivity_columns(const Scenario& sc, const RunSensitivities& rs);

/// Row k of the table sensitivity_columns() heads.
std::vector<double> sensitivity_row(const RunSensitivities& rs, Index k);

/// `ukdyn sensitivities` (and `ukdyn simulate` of a scenario with outputs.sensitivities):
/// run_sensitivities() written to OUT_DIR/sensitivities.csv (the output folder's rules,
/// ukdyn/output/output_dir.hpp), and one line of JSON on `report` (file, parameters, samples,
/// steps, trusted, message, warnings). Returns trusted.
bool write_run_sensitivities(const Scenario& sc, const std::vector<ScenarioParameter>& ps,
                             const std::filesystem::path& out_dir, std::ostream& report);

}  // namespace ukdyn
