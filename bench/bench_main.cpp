// ukdyn_bench: Google Benchmark runner with a reporter that also collects the results, so that the
// ratios (textbook / Cholesky, MuJoCo / ukdyn) and the constraint-violation table are computed from
// the SAME run and printed at the end.
//
//   build/bench/bench/ukdyn_bench --benchmark_min_time=0.2
//   build/bench/bench/ukdyn_bench --benchmark_repetitions=5 --benchmark_report_aggregates_only=true
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cstdio>
#include <iostream>
#include <string>
#include <vector>

#include "bench_common.hpp"

namespace ukbench {
namespace {

double to_ns(double value, benchmark::TimeUnit unit) {
  switch (unit) {
    case benchmark::kNanosecond:
      return value;
    case benchmark::kMicrosecond:
      return value * 1e3;
    case benchmark::kMillisecond:
      return value * 1e6;
    case benchmark::kSecond:
      return value * 1e9;
  }
  return value;
}

/// The console output as usual, plus every real time kept for the summary.
class CollectingReporter : public benchmark::ConsoleReporter {
 public:
  void ReportRuns(const std::vector<Run>& runs) override {
    ConsoleReporter::ReportRuns(runs);
    for (const Run& run : runs) {
      if (run.error_occurred) continue;
      Timing& t = timings_[run.run_name.function_name];
      // CPU time: on a shared machine the wall time of a few-microsecond loop also counts the time
      // the thread was preempted (seen here: real 46 us vs CPU 31 us for one solve while another
      // build ran).
      const double ns = to_ns(run.GetAdjustedCPUTime(), run.time_unit);
      if (run.run_type == Run::RT_Iteration) {
        t.repetitions.push_back(ns);
      } else if (run.aggregate_unit == benchmark::kTime) {
        if (run.aggregate_name == "median") t.median = ns;
        if (run.aggregate_name == "min") t.min = ns;
        if (run.aggregate_name == "max") t.max = ns;
      }
    }
  }

  /// Aggregates, or (without --benchmark_report_aggregates_only) computed from the repetitions.
  Timings results() const {
    Timings out = timings_;
    for (auto& [name, t] : out) {
      if (t.median > 0 || t.repetitions.empty()) continue;
      std::vector<double> v = t.repetitions;
      std::sort(v.begin(), v.end());
      const std::size_t n = v.size();
      t.median = n % 2 == 1 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
      t.min = v.front();
      t.max = v.back();
    }
    return out;
  }

 private:
  Timings timings_;
};

std::string fmt_time(double ns) {
  char buf[64];
  if (ns < 0) return "n/a";
  if (ns < 1e3)
    std::snprintf(buf, sizeof buf, "%.0f ns", ns);
  else if (ns < 1e6)
    std::snprintf(buf, sizeof buf, "%.2f us", ns / 1e3);
  else
    std::snprintf(buf, sizeof buf, "%.2f ms", ns / 1e6);
  return buf;
}

std::string fmt_range(const Timing& t) {
  if (!t.valid()) return "n/a";
  std::string s = fmt_time(t.median);
  if (t.min > 0 && t.max > 0 && t.min != t.max)
    s += " [" + fmt_time(t.min) + " .. " + fmt_time(t.max) + "]";
  return s;
}

const Timing* find(const Timings& ts, const std::string& name) {
  const auto it = ts.find(name);
  return it == ts.end() || !it->second.valid() ? nullptr : &it->second;
}

void print_ratio(const Timings& ts, const std::string& label, const std::string& slow,
                 const std::string& fast, double target = 0.0) {
  const Timing* a = find(ts, slow);
  const Timing* b = find(ts, fast);
  if (a == nullptr || b == nullptr) {
    std::printf("  %-58s n/a (not run)\n", label.c_str());
    return;
  }
  const double r = a->median / b->median;
  std::printf("  %-58s %8.1fx", label.c_str(), r);
  if (target > 0) std::printf("   (target >= %.0fx: %s)", target, r >= target ? "met" : "NOT met");
  std::printf("\n");
}

void print_summary(const Timings& ts) {
  std::printf(
      "\n==================== ukdyn_bench summary (medians of this run) ====================\n");
  std::printf("Median CPU time per iteration [min .. max over repetitions, if any]:\n");
  for (const auto& [name, t] : ts) std::printf("  %-40s %s\n", name.c_str(), fmt_range(t).c_str());

  std::printf("\nRatios (median / median, same run):\n");
  for (const std::string key : {"m6", "m12r12", "m12r10"}) {
    print_ratio(ts, "U-K solve " + key + ": textbook / cholesky_6+6", "solve/textbook/" + key,
                "solve/cholesky_6+6/" + key, key == "m12r10" ? 35.0 : 0.0);
    print_ratio(ts, "U-K solve " + key + ": textbook / cholesky_1x12", "solve/textbook/" + key,
                "solve/cholesky_1x12/" + key);
    if (key != "m12r10")
      print_ratio(ts, "U-K solve " + key + ": kkt / cholesky_6+6", "solve/kkt/" + key,
                  "solve/cholesky_6+6/" + key);
  }
  print_ratio(ts, "forward: mj_forward / ukdyn forward (closure)", "mujoco/mj_forward",
              "forward/closure", 5.0);
  print_ratio(ts, "forward: closure+trajectory / closure", "forward/closure+trajectory",
              "forward/closure");

  if (const Timing* f = find(ts, "forward/closure"))
    std::printf("  %-58s %s (target <= 1 us: %s)\n", "ukdyn forward (closure), absolute",
                fmt_time(f->median).c_str(), f->median <= 1e3 ? "met" : "NOT met");
  if (const Timing* p = find(ts, "simulate/paper_4s_dopri5_1e-12"))
    std::printf("  %-58s %s (target <= 20 ms: %s)\n", "paper 4 s scenario, dopri5 1e-12, absolute",
                fmt_time(p->median).c_str(), p->median <= 20e6 ? "met" : "NOT met");
  if (const Timing* r = find(ts, "simulate/free_10s_rk4_1kHz")) {
    const double per_step = r->median / 10000.0;
    std::printf("  %-58s %s\n", "ukdyn RK4 step (10 s run / 10000 steps, incl. output)",
                fmt_time(per_step).c_str());
    if (const Timing* m = find(ts, "mujoco/mj_step_rk4"))
      std::printf("  %-58s %8.1fx\n", "step: mj_step (RK4) / ukdyn RK4 step", m->median / per_step);
  }
}

void print_violation_table() {
  std::printf(
      "\nConstraint violation held over the same 4 s of free motion (closure only, tau = 0, from "
      "the\n"
      "paper's q0; MuJoCo measured every step, ukdyn every 1 ms). gap = max |cut point 1 - cut "
      "point 2|;\n"
      "|Phi| = max over the 6 closure rows of ukdyn's position residuals (MuJoCo's state mapped to "
      "the\n"
      "paper's coordinates); dq(0.5 s) = max |q - q_ref| at t = 0.5 s against ukdyn dopri5 1e-12;\n"
      "wall = median of 3 runs of the 4 s, without measuring.\n");
  std::printf("  %-12s %-44s %-11s %10s %11s %11s %11s\n", "engine", "setup", "start", "wall",
              "max gap [m]", "max |Phi|", "dq(0.5 s)");
  for (const bool spatial : {false, true}) {
    std::vector<double> q_ref;
    std::vector<ViolationRow> rows = ukdyn_violation_rows(spatial, q_ref);
#ifdef UKDYN_BENCH_HAVE_MUJOCO
    std::vector<ViolationRow> mj = mujoco_violation_rows(spatial, q_ref);
    rows.insert(rows.end(), mj.begin(), mj.end());
#endif
    for (const ViolationRow& r : rows) {
      char dq[32] = "ref";
      if (r.q_diff > 0) std::snprintf(dq, sizeof dq, "%.2e", r.q_diff);
      std::printf("  %-12s %-44s %-11s %7.2f ms %11.2e %11.2e %11s\n", r.engine.c_str(),
                  r.setup.c_str(), r.start.c_str(), r.wall_ms, r.max_gap, r.max_phi, dq);
    }
  }
#ifndef UKDYN_BENCH_HAVE_MUJOCO
  std::printf("  (MuJoCo not found at configure time: no MuJoCo rows)\n");
#endif
}

}  // namespace
}  // namespace ukbench

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;

  ukbench::register_ukdyn_benchmarks();
#ifdef UKDYN_BENCH_HAVE_MUJOCO
  ukbench::register_mujoco_benchmarks();
#endif

  ukbench::CollectingReporter reporter;
  const std::size_t ran = benchmark::RunSpecifiedBenchmarks(&reporter);
  if (ran > 0) {
    ukbench::print_summary(reporter.results());
    ukbench::print_violation_table();
  }
  std::fflush(stdout);
  benchmark::Shutdown();
  return 0;
}
