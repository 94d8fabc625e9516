// A run's global error, estimated by a shadow run (scenario key simulation.error_estimate: shadow,
// docs/accuracy.md): the same scenario integrated again at tighter settings, its positions kept at
// the output samples, and the run's own samples compared with them as they come. Private to the
// run layer.
#pragma once

#include <atomic>
#include <string>
#include <vector>

#include "ukdyn/run/run.hpp"

namespace ukdyn::io_detail {

/// The shadow's settings: tolerances / 100 (at least 1e-16), a fixed step / 4; no joint-limit
/// warnings.
SimulationSettings shadow_settings(const SimulationSettings& s);

/// The shadow run's positions at every stride-th output sample, then the comparison.
class ShadowEstimate {
 public:
  /// Integrates the scenario at shadow_settings() (a control scenario: a fresh closed loop of its
  /// own, so that nothing of it is shared with the run), keeping q at every stride-th sample
  /// (stride: at most ~2e6 numbers kept).
  ShadowEstimate(const Scenario& sc, const std::atomic<bool>* cancel);

  /// A sample of the run: compared with the shadow's when it has one (allocation-free).
  void compare(double t, CVecRef q);

  /// What summary.json and the console report (ErrorEstimate).
  [[nodiscard]] ErrorEstimate result(const System& system, const SimulationStats& run) const;

 private:
  SimulationSettings settings_;
  Index n_ = 0;
  long stride_ = 1, sample_ = 0, compared_ = 0;
  std::vector<double> q_;  ///< n_ per kept sample
  std::vector<double> t_;
  SimulationStats shadow_stats_;
  double shadow_seconds_ = 0.0;
  double max_ = 0.0, max_t_ = 0.0;
  Index max_coordinate_ = -1;
};

}  // namespace ukdyn::io_detail
