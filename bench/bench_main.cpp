// ukdyn_bench: Google Benchmark runner with a reporter that also collects the results, so that the
// ratios (textbook / Cholesky, MuJoCo / ukdyn, Simbody / ukdyn) and the constraint-violation table
// are computed from the SAME run and printed at the end.
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
#ifdef UKDYN_BENCH_HAVE_SIMBODY
#include "paper_model.hpp"
#endif

namespace ukbench {

#ifdef UKDYN_BENCH_HAVE_SIMBODY
namespace {

PaperMechanism::Arm arm_of(const ukdyn::MobileManipulator& m) {
  const ukdyn::MobileManipulatorParams& p = m.params();
  return {p.platform_mass, p.base_mass,    p.base_inertia, p.base_length,
          p.link_mass,     p.link_inertia, p.link_length};
}

std::array<double, 12> to_array(const ukdyn::Vec& v) {
  std::array<double, 12> a{};
  for (std::size_t i = 0; i < a.size(); ++i) a[i] = v[static_cast<ukdyn::Index>(i)];
  return a;
}

double max_closure_residual(double t, const std::array<double, 12>& q) {
  const PaperModel& pm = paper_model();
  thread_local ukdyn::Vec phi(pm.closure.rows());
  ukdyn::position_residuals(pm.closure, t, Eigen::Map<const ukdyn::Vec>(q.data(), 12), phi);
  return max_abs(phi);
}

PaperMechanism make_paper_mechanism() {
  const PaperModel& pm = paper_model();
  PaperMechanism m;
  m.arm = {arm_of(*pm.left), arm_of(*pm.right)};
  m.gravity = pm.left->params().gravity;
  m.q0 = to_array(pm.q0);
  m.qd0_spatial = to_array(pm.qd0_spatial);
  ukdyn::ForwardData data(pm.closure);
  const ukdyn::Vec tau = ukdyn::Vec::Zero(pm.closure.dof());
  ukdyn::forward(pm.closure, data, 0.0, pm.q0, pm.qd0_spatial, tau);
  m.qdd_spatial = to_array(data.qdd);
  m.max_closure_residual = &max_closure_residual;
  return m;
}

}  // namespace

const PaperMechanism& paper_mechanism() {
  static const PaperMechanism m = make_paper_mechanism();
  return m;
}
#endif

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
    std::printf("  %-64s n/a (not run)\n", label.c_str());
    return;
  }
  const double r = a->median / b->median;
  std::printf("  %-64s %8.1fx", label.c_str(), r);
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
#ifdef UKDYN_BENCH_HAVE_SIMBODY
  print_ratio(ts, "forward: Simbody realize(Acceleration) / ukdyn forward (closure)",
              "simbody/realize_acceleration", "forward/closure");
#endif
  print_ratio(ts, "forward: closure+trajectory / closure", "forward/closure+trajectory",
              "forward/closure");
  print_ratio(ts, "forward: from definitions / closed form (closure)",
              "forward/closure_definitions", "forward/closure");
  if (const Timing* d = find(ts, "forward/closure_definitions"))
    if (const Timing* f = find(ts, "forward/closure"))
      std::printf("  %-64s %8.2fx (target <= 3x: %s)\n",
                  "forward from definitions, cost relative to the closed form",
                  d->median / f->median, d->median <= 3.0 * f->median ? "met" : "NOT met");
  print_ratio(ts, "model only, one arm: M, C qd, G from definitions / closed form",
              "Symbolic_DynamicsDerived", "Symbolic_DynamicsClosedForm");
  print_ratio(ts, "model only: closure A, b from definitions / closed form",
              "Symbolic_ClosureDerived", "Symbolic_ClosureClosedForm");

  for (const std::string robot : {"panda", "ur5e"}) {
    print_ratio(ts, robot + ": mj_forward / ukdyn tree forward (same MJCF)",
                "mujoco/" + robot + "_mj_forward", "tree/" + robot + "_forward", 2.0);
  }
  print_ratio(ts, "two Pandas on platforms welded to a plate: mj_forward / ukdyn forward",
              "mujoco/two_pandas_weld_mj_forward", "scenario/two_pandas_weld_forward", 3.0);
  // Exact derivatives (∂q̈ and ∂Qc w.r.t. q, q̇, τ): cost in forward calls (target <= 8) and
  // speed-up over central differences of forward() (q̈ only; target >= 10).
  for (const std::string sc : {"paper_chain", "two_ur5e_load", "four_panda_plate",
                               "n_robots_4_weld", "two_pandas_weld", "panda_arm", "iiwa_arm"}) {
    const Timing* l = find(ts, "derivatives/" + sc + "_linearize");
    const Timing* f = find(ts, "scenario/" + sc + "_forward");
    if (l != nullptr && f != nullptr)
      std::printf("  %-64s %8.1fx (target <= 8x: %s)\n",
                  (sc + ": derivatives / one forward call").c_str(), l->median / f->median,
                  l->median <= 8.0 * f->median ? "met" : "NOT met");
    print_ratio(ts, sc + ": central differences / exact derivatives",
                "derivatives/" + sc + "_central_differences", "derivatives/" + sc + "_linearize",
                10.0);
    for (const std::string v : {"_linearize_workspace", "_linearize_dqdd_dx"}) {
      const Timing* w = find(ts, "derivatives/" + sc + v);
      if (w != nullptr && f != nullptr)
        std::printf("  %-64s %8.1fx (target <= 8x: %s)\n",
                    (sc + ": derivatives (" + v.substr(11) + ") / one forward call").c_str(),
                    w->median / f->median, w->median <= 8.0 * f->median ? "met" : "NOT met");
      print_ratio(ts, sc + ": central differences / exact derivatives (" + v.substr(11) + ")",
                  "derivatives/" + sc + "_central_differences", "derivatives/" + sc + v, 10.0);
    }
  }
  print_ratio(ts, "two Pandas welded: MuJoCo mjd_transitionFD / ukdyn exact derivatives",
              "mujoco/two_pandas_weld_mjd_transitionFD", "derivatives/two_pandas_weld_linearize");
  for (const std::string n : {"15", "30", "60"}) {
    print_ratio(ts, "chain " + n + " / 7 links: M (CRBA)", "tree/chain_" + n + "_mass",
                "tree/chain_7_mass");
    print_ratio(ts, "chain " + n + " / 7 links: C qd + G (RNEA)", "tree/chain_" + n + "_bias",
                "tree/chain_7_bias");
  }
  if (const Timing* f = find(ts, "forward/closure"))
    std::printf("  %-64s %s (target <= 1 us: %s)\n", "ukdyn forward (closure), absolute",
                fmt_time(f->median).c_str(), f->median <= 1e3 ? "met" : "NOT met");
  if (const Timing* p = find(ts, "simulate/paper_4s_dopri5_1e-12"))
    std::printf("  %-64s %s (target <= 20 ms: %s)\n", "paper 4 s scenario, dopri5 1e-12, absolute",
                fmt_time(p->median).c_str(), p->median <= 20e6 ? "met" : "NOT met");
  if (const Timing* r = find(ts, "simulate/free_10s_rk4_1kHz")) {
    const double per_step = r->median / 10000.0;
    std::printf("  %-64s %s\n", "ukdyn RK4 step (10 s run / 10000 steps, incl. output)",
                fmt_time(per_step).c_str());
    if (const Timing* m = find(ts, "mujoco/mj_step_rk4"))
      std::printf("  %-64s %8.1fx\n", "step: mj_step (RK4) / ukdyn RK4 step", m->median / per_step);
  }
}

void print_violation_table() {
  std::printf(
      "\nConstraint violation held over the same 4 s of free motion (closure only, tau = 0, from\n"
      "the paper's q0; MuJoCo measured every step, ukdyn and Simbody every 1 ms).\n"
      "gap = max |cut point 1 - cut point 2|; |Phi| = max over the 6 closure rows of ukdyn's\n"
      "position residuals (MuJoCo's and Simbody's states mapped to the paper's coordinates);\n"
      "dq(0.5 s) = max |q - q_ref| at t = 0.5 s against ukdyn dopri5 1e-12;\n"
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
#ifdef UKDYN_BENCH_HAVE_SIMBODY
    std::vector<ViolationRow> sb = simbody_violation_rows(spatial, q_ref);
    rows.insert(rows.end(), sb.begin(), sb.end());
#endif
    for (const ViolationRow& r : rows) {
      char dq[32] = "ref";
      if (r.q_diff > 0) std::snprintf(dq, sizeof dq, "%.2e", r.q_diff);
      if (r.q_diff < 0) std::snprintf(dq, sizeof dq, "n/a");
      std::printf("  %-12s %-44s %-11s %7.2f ms %11.2e %11.2e %11s\n", r.engine.c_str(),
                  r.setup.c_str(), r.start.c_str(), r.wall_ms, r.max_gap, r.max_phi, dq);
    }
  }
#ifndef UKDYN_BENCH_HAVE_MUJOCO
  std::printf("  (MuJoCo not found at configure time: no MuJoCo rows)\n");
#endif
#ifndef UKDYN_BENCH_HAVE_SIMBODY
  std::printf("  (Simbody not found at configure time: no Simbody rows)\n");
#endif
}

#ifdef UKDYN_BENCH_HAVE_SIMBODY
/// Simbody's u̇ at the benchmarked state against ukdyn's q̈ (same model, same state): not timed.
void print_simbody_model_check() {
  const SimbodyModelCheck c = simbody_model_check();
  std::printf(
      "\nSimbody model check at (q0, spatial qd0), realize(Acceleration) vs ukdyn forward():\n");
  if (!c.error.empty()) {
    std::printf("  failed: %s\n", c.error.c_str());
    return;
  }
  std::printf("  max |qdd_Simbody - qdd_ukdyn| = %.2e (max |qdd_ukdyn| = %.2e)\n", c.qdd_diff,
              c.qdd_max);
  std::printf(
      "  Simbody's %d constraint rows: max |position err| = %.1e, |velocity err| = %.1e, "
      "|acceleration err| = %.1e\n",
      c.rows, c.q_err, c.u_err, c.udot_err);
}
#endif

}  // namespace
}  // namespace ukbench

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;

  ukbench::register_ukdyn_benchmarks();
  ukbench::register_tree_benchmarks();
#ifdef UKDYN_BENCH_HAVE_MUJOCO
  ukbench::register_mujoco_benchmarks();
#endif
#ifdef UKDYN_BENCH_HAVE_SIMBODY
  ukbench::register_simbody_benchmarks();
#endif

  ukbench::CollectingReporter reporter;
  const std::size_t ran = benchmark::RunSpecifiedBenchmarks(&reporter);
  if (ran > 0) {
    ukbench::print_summary(reporter.results());
#ifdef UKDYN_BENCH_HAVE_SIMBODY
    ukbench::print_simbody_model_check();
#endif
#if defined(UKDYN_BENCH_HAVE_MUJOCO) && defined(UKDYN_BENCH_HAVE_IO)
    ukbench::print_two_pandas_weld_check();
#endif
    ukbench::print_violation_table();
  }
  std::fflush(stdout);
  benchmark::Shutdown();
  return 0;
}
