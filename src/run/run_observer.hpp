// Internal to ukdyn::io: what every output sample of a run contributes, written once for
// run_scenario(), run_scenario_in_memory() (src/run/run.cpp) and the rows of `ukdyn sweep`
// (src/sweep/sample.cpp): the trajectory.csv row (the columns of trajectory_header()) and the
// extrema of the run report (residuals, energy drift, energy balance, rank, smallest kept singular
// value).
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "ukdyn/model/system.hpp"
#include "ukdyn/output/constraint_force_output.hpp"
#include "ukdyn/output/control_output.hpp"
#include "ukdyn/run/run.hpp"
#include "ukdyn/tree/tree.hpp"

namespace ukdyn::io_detail {

/// max that keeps a NaN: a sample with a NaN is the least trustworthy one, it must show.
inline double nanmax(double a, double b) {
  return std::isnan(a) || std::isnan(b) ? std::numeric_limits<double>::quiet_NaN() : std::max(a, b);
}

/// The columns of a run's trajectory.csv (`ukdyn simulate`, the sweep's column metrics):
/// trajectory_header(), the frame constraints' forces (`forces`; null for a control run), then
/// the control and motor columns.
/// The applied forces τ(t, q, q̇) of a run of `sc`: the closed loop's (ctl, docs/control.md) or the
/// scenario's constant forces.tau (which must outlive the function). `settings` gets ∂τ/∂(q, q̇)
/// for the exact Jacobian of bdf / esdirk: 0 for the constant τ; the law's exact one
/// (law_force_jacobian(), differences at the states where it has none, counted) unless its model
/// has no exact derivatives at all (law_jacobian_gap(): then none, difference quotients, said in
/// the stats' jacobian_note).
ForceFunction run_forces(const Scenario& sc, const ControlRun* ctl, SimulationSettings& settings);

std::vector<std::string> run_csv_header(const System& sys, bool balance,
                                        const ConstraintForceColumns* forces,
                                        const ControlColumns& control_columns);

class SampleRecorder {
 public:
  /// What a caller needs beyond the report's extrema (all on for the trajectory.csv of a run).
  struct Needs {
    bool row = true;                 ///< fill row() with the trajectory_header() columns
    bool velocity_residuals = true;  ///< rep.max_abs_velocity_residual
    bool sigma_svd = false;  ///< the sigma_min column by an SVD per sample (row only); else the
                             ///< solve's pivot estimate
  };
  /// Prepares `rep` (extrema reset, energy_balance set) and the buffers; `row_size` ≥ the
  /// trajectory_header(system, balance) size (more: room for the caller's own columns after it).
  SampleRecorder(const System& system, RunReport& rep, bool balance, std::size_t row_size,
                 Needs needs);
  SampleRecorder(const System& system, RunReport& rep, bool balance, std::size_t row_size)
      : SampleRecorder(system, rep, balance, row_size, Needs{}) {}

  /// One output sample: updates the report's extrema and (Needs::row) fills the row; returns the
  /// index of the first column after the trajectory_header() columns.
  std::size_t record(double t, CVecRef q, CVecRef qd, const ForwardData& d);
  /// V at the sample: a tree's from the links the sample's forward() placed in d's slot when they
  /// are of this q (TreeSubsystem::potential with `placed`), every other V in this recorder's slots.
  double potential(double t, CVecRef q, const ForwardData& d);

  [[nodiscard]] std::vector<double>& row() { return row_; }
  [[nodiscard]] const Vec& phi() const { return phi_; }
  [[nodiscard]] long samples() const { return count_; }

 private:
  const System& sys_;
  RunReport& rep_;
  bool balance_;
  Needs needs_;
  std::vector<double> row_;
  ForwardData scratch_;  // the slots Φ, Φ̇ and V are evaluated in (not the run's: no allocation)
  std::vector<const tree::TreeSubsystem*> trees_;  // per subsystem: the tree, or null
  std::vector<bool> vel_;  // per constraint row: velocity-level (its column is B q̇ + c)
  bool any_vel_ = false;
  Vec phi_, phid_;
  double balance0_ = 0.0;
  long count_ = 0;
};

}  // namespace ukdyn::io_detail
