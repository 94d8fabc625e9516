// Runs a scenario and writes its outputs: trajectory.csv, summary.json, figures/.
#pragma once

#include <atomic>
#include <filesystem>
#include <iosfwd>
#include <string>
#include <vector>

#include "ukdyn/io/scenario.hpp"

namespace ukdyn {

struct RunOptions {
  bool figures = true;
  std::ostream* progress = nullptr;  ///< a progress line is drawn here if set (a terminal)
  /// If set and it becomes true (e.g. from a SIGINT handler), the run stops at the next sample and
  /// its results so far are kept (status `stopped`).
  const std::atomic<bool>* cancel = nullptr;
};

struct RunReport {
  SimulationStats stats;
  std::filesystem::path csv;      ///< trajectory.csv, or trajectory.incomplete.csv
  std::filesystem::path summary;  ///< summary.json
  std::vector<std::filesystem::path> figures;
  std::string figure_error;
  double wall_seconds = 0.0;
  std::vector<double> max_abs_residual;  ///< per constraint row, position level
  std::vector<double> max_abs_velocity_residual;
  double max_acc_residual = 0.0;  ///< max ‖A q̈ − b‖ over samples
  double E0 = 0.0, max_energy_drift = 0.0, max_T = 0.0;
  /// With SimulationSettings::energy_balance: max |(E − W) − (E − W)(t0)| and the final W.
  double energy_balance_drift = 0.0, work_final = 0.0;
  int rank_min = 0, rank_max = 0;
  double sigma_min = 0.0;  ///< smallest kept singular value seen (pivot estimate)
};

/// The CSV header for a system: t, q names, <name>_dot, <name>_ddot, Qc_<name>, res_<row>, T, V, E,
/// diagnostics, and with `energy_balance` W and E_balance = E − W at the end.
std::vector<std::string> trajectory_header(const System& system, bool energy_balance = false);

/// Simulates the scenario into out_dir (created if needed). Old outputs there are removed first.
/// Never throws for numerical trouble (see RunReport.stats.status); throws ukdyn::Error for I/O.
RunReport run_scenario(const Scenario& scenario, const std::filesystem::path& out_dir,
                       const RunOptions& options);

}  // namespace ukdyn
