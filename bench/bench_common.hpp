// Shared pieces of the benchmark binary: registration helpers, the collecting reporter's results
// and the end-of-run comparison rows.
#pragma once

#include <benchmark/benchmark.h>

#include <algorithm>
#include <map>
#include <string>
#include <vector>

namespace ukbench {

/// Adds min and max to the statistics Google Benchmark computes over --benchmark_repetitions.
inline benchmark::internal::Benchmark* with_min_max(benchmark::internal::Benchmark* b) {
  return b
      ->ComputeStatistics(
          "min", [](const std::vector<double>& v) { return *std::min_element(v.begin(), v.end()); })
      ->ComputeStatistics("max", [](const std::vector<double>& v) {
        return *std::max_element(v.begin(), v.end());
      });
}

/// CPU time per iteration of one benchmark, in nanoseconds.
struct Timing {
  std::vector<double> repetitions;  ///< per-repetition times, when the reporter saw them
  double median = -1, min = -1,
         max = -1;  ///< aggregates (or computed from repetitions); −1 if absent
  [[nodiscard]] bool valid() const { return median > 0; }
};
using Timings = std::map<std::string, Timing>;

/// One row of the "constraint violation held over the same 4 s" table.
struct ViolationRow {
  std::string engine;  ///< "ukdyn" / "MuJoCo 2.2.2"
  std::string setup;   ///< integrator, step, tolerance
  std::string start;   ///< "qd0 = 0" or "spatial qd0"
  double wall_ms = 0;  ///< wall time of the 4 s run (median of a few runs, no measuring)
  double max_gap = 0;  ///< max distance between the two cut points [m]
  double max_phi = 0;  ///< max |Φ| over the 6 closure rows (ukdyn's residuals) [m or rad]
  double q_diff = -1;  ///< max |q − q_ref(0.5 s)| against ukdyn dopri5 1e-12 (−1: not computed)
};

/// ukdyn benchmarks (bench_ukdyn.cpp).
void register_ukdyn_benchmarks();
/// Runs the 4 s closure-only free motions of ukdyn; also fills the reference state at t = 0.5 s.
std::vector<ViolationRow> ukdyn_violation_rows(bool spatial, std::vector<double>& q_ref_05);

#ifdef UKDYN_BENCH_HAVE_MUJOCO
/// MuJoCo benchmarks (bench_mujoco.cpp). Returns false if the MJCF cannot be loaded.
bool register_mujoco_benchmarks();
/// The same 4 s runs in MuJoCo (Euler and RK4, default and stiff solref).
std::vector<ViolationRow> mujoco_violation_rows(bool spatial, const std::vector<double>& q_ref_05);
#endif

}  // namespace ukbench
