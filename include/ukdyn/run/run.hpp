// Runs a scenario and writes its outputs into an output folder: trajectory.csv, summary.json,
// figures/ (docs/scenario-format.md, "Outputs" and "Output safety"), and reports the run.
#pragma once

#include <atomic>
#include <filesystem>
#include <iosfwd>
#include <memory>
#include <string>
#include <vector>

#include "ukdyn/output/output_dir.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/version.hpp"

namespace ukdyn {

class ControlLaw;  // ukdyn/simulate/control.hpp

struct RunOptions {
  bool figures = true;
  std::ostream* progress = nullptr;  ///< a progress line is drawn here if set (a terminal)
  /// progress is not a terminal: instead of a bar, one line every progress_every seconds of
  /// wall time (none for a run shorter than that).
  bool progress_lines = false;
  double progress_every = 5.0;
  /// If set and it becomes true (e.g. from a SIGINT handler), the run stops after the current
  /// integration step and its results so far are kept (status `stopped`).
  const std::atomic<bool>* cancel = nullptr;
};

/// simulation.error_estimate: shadow (docs/accuracy.md): the run's positions against those of a
/// second run of the same scenario at tighter settings (tolerances / 100, a fixed step / 4), at
/// the same output samples.
struct ErrorEstimate {
  bool requested = false;
  double max_abs_q = 0.0;  ///< max over the samples compared and coordinates of |q − q_shadow|
  double t = 0.0;          ///< where it is largest
  std::string coordinate;  ///< and in which coordinate
  long samples_compared = 0;
  long stride = 1;  ///< every stride-th sample is compared (at most ~2e6 numbers kept)
  std::string shadow_status;
  double shadow_t_reached = 0.0;
  double shadow_abs_tol = 0.0, shadow_rel_tol = 0.0;
  double shadow_step = 0.0;  ///< a fixed-step run's shadow step (0: error-controlled)
  double shadow_regularization = 0.0;
  double shadow_seconds = 0.0;
  std::string note;  ///< why the estimate is partial or missing (empty: complete)
  /// false when the run (or its shadow) damped the constraint force near a singular position, or
  /// used the regularized solve throughout: both runs then carry the damping's error, and the
  /// difference is not the run's error in either direction (docs/accuracy.md); `note` says so.
  bool reliable = true;
};

struct RunReport {
  SimulationStats stats;
  std::filesystem::path out_dir;
  std::filesystem::path csv;      ///< trajectory.csv, trajectory.incomplete.csv, or empty (none)
  std::filesystem::path summary;  ///< summary.json (empty if it could not be written at all)
  long csv_rows = 0;              ///< data rows in the CSV
  std::vector<std::filesystem::path> figures;
  std::string figure_error;
  std::vector<std::string> figure_notes;  ///< figures or curves left out (caps)
  std::string write_error;                ///< a failed write: the run is incomplete
  double wall_seconds = 0.0;
  std::vector<double> max_abs_residual;  ///< per constraint row, position level
  std::vector<double> max_abs_velocity_residual;
  double max_acc_residual = 0.0;  ///< max ‖A q̈ − b‖ over samples
  double E0 = 0.0, max_energy_drift = 0.0, max_T = 0.0;
  /// With SimulationSettings::energy_balance: max |(E − W) − (E − W)(t0)| and the final W.
  double energy_balance_drift = 0.0, work_final = 0.0;
  bool energy_balance = false;  ///< the run integrated W (SimulationSettings::energy_balance)
  int rank_min = 0, rank_max = 0;
  double sigma_min = 0.0;  ///< smallest kept singular value seen (pivot estimate)
  /// A control run (docs/control.md): the system integrated (the plant, physical rows only), whose
  /// rows the residuals above belong to; null otherwise (the scenario's system).
  std::shared_ptr<const System> plant;
  /// The worst margin of the motors to their envelopes (docs/motors.md); empty without motors.
  std::string motors_line;
  ErrorEstimate error_estimate;  ///< with simulation.error_estimate: shadow

  /// The integration reached t_end and every output was written.
  [[nodiscard]] bool complete() const {
    return stats.status == RunStatus::completed && write_error.empty();
  }
};

/// The largest position-level residual of a run and the constraint row it belongs to ("-" if the
/// system has no constraint rows).
struct WorstResidual {
  double value = 0.0;
  std::string row = "-";
};
/// (Position-level rows only: a velocity-level row has no position residual.)
WorstResidual worst_position_residual(const System& system, const RunReport& report);
/// The largest velocity residual |B q̇ + c| of the velocity-level (nonholonomic) rows ("-" if the
/// system has none).
WorstResidual worst_velocity_residual(const System& system, const RunReport& report);

/// For each constraint row: true if it is velocity-level (nonholonomic, B(q, t) q̇ + c(q, t) = 0:
/// a `type: nonholonomic` block, the rolling rows of wheeled platforms), false if it is
/// position-level (Φ(q, t) = 0).
std::vector<bool> velocity_level_rows(const System& system);

/// The CSV header for a system: t, q names, <name>_dot, <name>_ddot, Qc_<name>, res_<row> (Φ of a
/// position-level row) or vres_<row> (B q̇ + c of a velocity-level row), T, V, E, diagnostics, and
/// with `energy_balance` W and E_balance = E − W at the end.
std::vector<std::string> trajectory_header(const System& system, bool energy_balance = false);

/// Simulates the scenario into out_dir (created if needed; see output_dir.hpp for what ukdyn
/// refuses and touches there). Throws OutputRefused for an output folder it will not use (nothing
/// is written then) and WriteFailed if not even the first summary could be written; any later
/// write failure ends the run as incomplete (RunReport.write_error, summary.json says so). Never
/// throws for numerical trouble (see RunReport.stats.status).
RunReport run_scenario(const Scenario& scenario, const std::filesystem::path& out_dir,
                       const RunOptions& options);

/// run_scenario_in_memory(): what replaces the file outputs.
struct MemoryRunOptions {
  /// The applied generalized forces τ(t, q, q̇) of the run; if empty, the scenario's constant
  /// forces.tau (as run_scenario()).
  ForceFunction tau;
  const std::atomic<bool>* cancel = nullptr;  ///< as RunOptions::cancel
  /// A scenario with `control:` (docs/control.md): if set, this law computes u in place of the
  /// scenario's built-in one (same plant, model, offset start, limits and disturbance); the
  /// summary's control.law is then "user" and the act_residual column NaN (no actuation solve of
  /// ukdyn's). Ignored without `control:` (run_scenario_in_memory() refuses it then).
  ControlLaw* law = nullptr;
};

/// A run kept in memory: the rows of trajectory.csv as numbers, exactly (not rounded to text).
struct MemoryRun {
  RunReport report;                 ///< out_dir, csv, summary, figures empty
  std::vector<std::string> header;  ///< trajectory_header(system, energy_balance)
  std::vector<double> values;       ///< row-major: report.csv_rows rows of header.size() values
  std::string summary_json;         ///< summary.json as run_scenario() writes it (no outputs)
};

/// Simulates the scenario as run_scenario() does (same samples, same columns, same summary), but
/// writes nothing: the trajectory is returned (the Python module's simulate()). A scenario with
/// `control:` runs its closed loop as run_scenario() does (the plant integrated, the columns of
/// trajectory.csv, the summary's control section); options.tau is refused for it (the plant's τ is
/// the loop's). Throws ukdyn::Error for invalid settings; never for numerical trouble
/// (report.stats.status).
MemoryRun run_scenario_in_memory(const Scenario& scenario, const MemoryRunOptions& options = {});

/// What assembly changed, on `os`; if it failed, also an error naming the unmet constraints on
/// `err`. Returns a.success.
bool print_assembly_report(std::ostream& os, std::ostream& err, const Scenario& scenario,
                           const AssemblyResult& a);

/// The assembled (q0, q̇0) as an `initial:` section of a scenario (q, qd and the held coordinates;
/// every number in its shortest form that reads back as the same double), ready to paste.
void print_assembled_initial(std::ostream& os, const Scenario& scenario, const AssemblyResult& a);

/// The console report of a run (what `ukdyn simulate` prints on stdout).
void print_run_report(std::ostream& os, const Scenario& scenario, const RunReport& report);
/// Its warnings and, for an incomplete run, why (what `ukdyn simulate` prints on stderr).
void print_run_warnings(std::ostream& os, const Scenario& scenario, const RunReport& report);

}  // namespace ukdyn
