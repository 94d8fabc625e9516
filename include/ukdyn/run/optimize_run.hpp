// `ukdyn optimize`: solve a problem file and write the optimal trajectory as a run folder
// (trajectory.csv, summary.json; docs/optimization.md), then check it against the true dynamics.
#pragma once

#include <filesystem>
#include <string>

#include "ukdyn/scenario/optimization_file.hpp"

namespace ukdyn {

/// The optimal u(t) applied open loop to the continuous dynamics (ukdyn's integrator, the
/// scenario's settings) from the start: how far the integrated motion leaves the collocated one.
struct ReplayCheck {
  bool done = false;
  std::string status;                  ///< the run's status ("complete", ...)
  double max_q_deviation = 0.0;        ///< max |q_integrated − q_collocated| over the points
  double max_position_residual = 0.0;  ///< max |Φ| along the integrated motion
};

struct OptimizeReport {
  TrajectorySolution solution;
  ReplayCheck replay;
  double wall_seconds = 0.0;  ///< IPOPT's solve (console only: not in summary.json)
  /// Why replay.yaml's servo rows cannot be vouched for (empty: they fix q along the path).
  std::string replay_scenario_note;
};

/// u(t) of the solution between its points: linear (trapezoidal) or the quadratic through the
/// interval's knots and midpoint (Hermite–Simpson), as the collocation assumes. Writes k entries.
void interpolate_u(const TrajectorySolution& s, CollocationMethod method, double t, VecRef u);

/// Solves, writes `out`/trajectory.csv and `out`/summary.json, and (if file.verify) runs the
/// replay check. Throws ukdyn::Error for a bad problem, OutputRefused / WriteFailed for the folder.
OptimizeReport run_optimization(const OptimizationFile& file, const std::filesystem::path& out);

}  // namespace ukdyn
