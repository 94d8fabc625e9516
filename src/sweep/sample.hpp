// Internal to the sweep (src/sweep/): the run of one sample in memory, its row of results.csv.
// One SampleRunner serves every thread of a sweep (sample.cpp says what it locks).
#pragma once

#include <atomic>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "ukdyn/output/control_output.hpp"
#include "ukdyn/sweep/sweep.hpp"

namespace ukdyn::sweep_detail {

/// The loaded scenarios of the sweep, by the values that shape the model (bounded).
struct ModelCache {
  struct Entry {
    std::shared_ptr<const Scenario> sc;
    std::string error;
  };
  std::mutex mu;
  std::map<std::string, Entry> entries;
};

struct SampleObserver;

class SampleRunner {
 public:
  SampleRunner(const Sweep& sw, const Scenario& base);

  /// The row of sample k (without the final newline); empty if cancelled (not recorded: it is
  /// computed again on resume).
  std::string row(long k, const std::atomic<bool>* cancel);

  [[nodiscard]] const std::vector<std::string>& header() const { return header_; }

 private:
  struct SampleOutcome;

  bool prepare_initial_state(Scenario& sc, SampleOutcome& out) const;
  std::vector<std::vector<std::size_t>> metric_column_indices(const std::vector<std::string>& th,
                                                              bool& need_sigma) const;
  [[nodiscard]] bool needs_force_columns(const std::vector<std::string>& th) const;
  void simulate_sample(const Scenario& sc, std::unique_ptr<ControlRun>& ctl,
                       const std::atomic<bool>* cancel, SampleOutcome& out);
  std::vector<std::string> metric_cells(const SampleObserver& o) const;
  Scenario scenario_for(long k, const std::vector<double>& vals, std::string& status,
                        std::string& reason);

  const Sweep& sw_;
  const Scenario& base_;
  std::string base_hash_ = base_.hash;  // Scenario::hash of every sample: the base scenario's
  bool share_state_ = false;
  std::vector<std::string> header_;
  ModelCache cache_;
  std::mutex build_mu_;  // model building and release (GiNaC), see row()
};

}  // namespace ukdyn::sweep_detail
