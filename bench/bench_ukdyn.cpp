// ukdyn benchmarks: the U-K solve alone (textbook / Cholesky block-diagonal / Cholesky single block
// / KKT), the paper model's forward dynamics, and whole simulations.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "bench_common.hpp"
#include "paper_model.hpp"
#include "ukdyn/core/uk_solve.hpp"
#include "ukdyn/simulate/simulate.hpp"

namespace ukbench {
namespace {

using ukdyn::BlockLayout;
using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;

// ------------------------------------------------------------------------------------------------
// Solve problems: the paper's M (block-diagonal 6+6, SPD) at q0 with the spatial q̇0, and
//   m6     : the 6 closure rows at q0 (full rank),
//   m12r12 : the 12 rows of the paper's scenario at q0 (full rank 12),
//   m12r10 : 12 rows of rank 10 (10 random rows, 2 rows that are combinations of them), b in range(A).
struct SolveProblem {
  Mat M, A;
  Vec b, Q;
};

SolveProblem paper_problem(bool with_trajectory) {
  const PaperModel& pm = paper_model();
  const ukdyn::System& sys = with_trajectory ? pm.full : pm.closure;
  ukdyn::ForwardData data(sys);
  const Vec tau = Vec::Zero(sys.dof());
  ukdyn::forward(sys, data, 0.0, pm.q0, pm.qd0_spatial, tau);
  return {data.M, data.A, data.b, data.Q};
}

SolveProblem rank_deficient_problem() {
  SolveProblem p = paper_problem(false);
  std::mt19937 rng(20220801u);
  std::normal_distribution<double> normal(0.0, 1.0);
  Mat A(12, 12);
  for (Index i = 0; i < 10; ++i)
    for (Index j = 0; j < 12; ++j) A(i, j) = normal(rng);
  A.row(10) = 0.5 * A.row(0) - 1.5 * A.row(3) + A.row(7);
  A.row(11) = 2.0 * A.row(2) + 0.25 * A.row(9);
  Vec x(12);
  for (Index j = 0; j < 12; ++j) x(j) = normal(rng);
  p.A = A;
  p.b = A * x;  // consistent: the redundant rows agree
  return p;
}

const SolveProblem& problem(const std::string& key) {
  static const SolveProblem m6 = paper_problem(false);
  static const SolveProblem m12r12 = paper_problem(true);
  static const SolveProblem m12r10 = rank_deficient_problem();
  if (key == "m6") return m6;
  if (key == "m12r12") return m12r12;
  return m12r10;
}

BlockLayout two_blocks() { return BlockLayout{{0, 6}, {6, 6}}; }

void bm_textbook(benchmark::State& state, const std::string& key) {
  const SolveProblem& p = problem(key);
  Vec qdd(12), Qc(12);
  ukdyn::UkResult r;
  for (auto _ : state) {
    r = ukdyn::uk_solve_textbook(p.M, p.A, p.b, p.Q, qdd, Qc);
    benchmark::DoNotOptimize(qdd.data());
    benchmark::DoNotOptimize(Qc.data());
    benchmark::ClobberMemory();
  }
  state.counters["rank"] = r.rank;
  state.counters["residual"] = r.residual;
}

void bm_cholesky(benchmark::State& state, const std::string& key, bool blocks) {
  const SolveProblem& p = problem(key);
  ukdyn::UkWorkspace ws(blocks ? two_blocks() : BlockLayout::single(12), p.A.rows());
  Vec qdd(12), Qc(12);
  ukdyn::UkResult r;
  for (auto _ : state) {
    r = ukdyn::uk_solve(p.M, p.A, p.b, p.Q, ws, qdd, Qc);
    benchmark::DoNotOptimize(qdd.data());
    benchmark::DoNotOptimize(Qc.data());
    benchmark::ClobberMemory();
  }
  state.counters["rank"] = r.rank;
  state.counters["residual"] = r.residual;
}

void bm_kkt(benchmark::State& state, const std::string& key) {
  const SolveProblem& p = problem(key);
  Vec qdd(12), Qc(12);
  for (auto _ : state) {
    ukdyn::kkt_solve(p.M, p.A, p.b, p.Q, qdd, Qc);
    benchmark::DoNotOptimize(qdd.data());
    benchmark::DoNotOptimize(Qc.data());
    benchmark::ClobberMemory();
  }
  const Vec res = p.A * qdd - p.b;
  state.counters["residual"] = max_abs(res);
}

// ------------------------------------------------------------------------------------------------
// Heap bytes held by a ForwardData (every buffer forward() writes, allocated once by its
// constructor; tests/test_no_alloc.cpp shows forward() itself allocates nothing).
double forward_data_bytes(const ukdyn::ForwardData& d) {
  const auto& w = d.uk;
  const Index doubles = d.M.size() + d.Cqd.size() + d.G.size() + d.Q.size() + d.A.size() +
                        d.b.size() + d.Qc.size() + d.qdd.size() + w.L.size() + w.inv_diag.size() +
                        w.Linv_Q.size() + w.A_Linvt.size() + w.A_Minv_At.size() + w.r.size() +
                        w.lambda.size() + w.tmp_m.size();
  return static_cast<double>(doubles) * sizeof(double) +
         static_cast<double>(w.piv.size() * sizeof(Index) +
                             (w.layout.start.size() + w.layout.size.size()) * sizeof(Index));
}

// Forward dynamics of the paper model at (t = 0, q0, spatial q̇0, τ = 0).
void bm_forward(benchmark::State& state, bool with_trajectory) {
  const PaperModel& pm = paper_model();
  const ukdyn::System& sys = with_trajectory ? pm.full : pm.closure;
  ukdyn::ForwardData data(sys);
  const Vec tau = Vec::Zero(sys.dof());
  for (auto _ : state) {
    ukdyn::forward(sys, data, 0.0, pm.q0, pm.qd0_spatial, tau);
    benchmark::DoNotOptimize(data.qdd.data());
    benchmark::ClobberMemory();
  }
  state.counters["rank"] = data.result.rank;
  state.counters["residual"] = data.result.residual;
  state.counters["bytes"] = forward_data_bytes(data);
}

// ------------------------------------------------------------------------------------------------
// Whole simulations.
void zero_tau(double, ukdyn::CVecRef, ukdyn::CVecRef, ukdyn::VecRef tau) { tau.setZero(); }

ukdyn::SimulationSettings paper_settings() {
  ukdyn::SimulationSettings s;
  s.t_end = 4.0;
  s.sample_dt = 0.01;
  s.integrator = ukdyn::IntegratorKind::dopri5;
  s.abs_tol = 1e-12;
  s.rel_tol = 1e-12;
  return s;
}

ukdyn::SimulationSettings rk4_settings(double t_end, double sample_dt) {
  ukdyn::SimulationSettings s;
  s.t_end = t_end;
  s.sample_dt = sample_dt;
  s.integrator = ukdyn::IntegratorKind::rk4;
  s.step = 1e-3;
  return s;
}

/// Max |Φ| over all rows at the samples of one run (outside the timed loop).
struct ResidualCheck {
  double max_phi = 0.0;
  double max_gap = 0.0;  // norm of the first three rows (the closure's cut-point rows)
  ukdyn::SimulationStats stats;
};

ResidualCheck check_run(const ukdyn::System& sys, const Vec& q0, const Vec& qd0,
                        const ukdyn::SimulationSettings& s, double t_probe = -1.0,
                        std::vector<double>* q_probe = nullptr) {
  ResidualCheck c;
  Vec phi(sys.rows());
  c.stats =
      ukdyn::simulate(sys, q0, qd0, zero_tau, s,
                      [&](double t, ukdyn::CVecRef q, ukdyn::CVecRef, const ukdyn::ForwardData&) {
                        ukdyn::position_residuals(sys, t, q, phi);
                        c.max_phi = std::max(c.max_phi, max_abs(phi));
                        c.max_gap = std::max(c.max_gap, phi.head(3).norm());
                        if (q_probe != nullptr && std::abs(t - t_probe) < 1e-9)
                          q_probe->assign(q.data(), q.data() + q.size());
                        return true;
                      });
  return c;
}

void bm_simulate(benchmark::State& state, bool paper_scenario) {
  const PaperModel& pm = paper_model();
  const ukdyn::System& sys = paper_scenario ? pm.full : pm.closure;
  const Vec& qd0 = paper_scenario ? pm.qd0_zero : pm.qd0_spatial;
  const ukdyn::SimulationSettings s = paper_scenario ? paper_settings() : rk4_settings(10.0, 0.01);
  const ResidualCheck check = check_run(sys, pm.q0, qd0, s);
  if (check.stats.status != ukdyn::RunStatus::completed) {
    state.SkipWithError(("simulation did not complete: " + check.stats.message).c_str());
    return;
  }
  long samples = 0;
  for (auto _ : state) {
    const ukdyn::SimulationStats st = ukdyn::simulate(
        sys, pm.q0, qd0, zero_tau, s,
        [&samples](double, ukdyn::CVecRef, ukdyn::CVecRef, const ukdyn::ForwardData&) {
          ++samples;
          return true;
        });
    benchmark::DoNotOptimize(st.steps);
  }
  benchmark::DoNotOptimize(samples);
  state.counters["steps"] = static_cast<double>(check.stats.steps);
  state.counters["rhs"] = static_cast<double>(check.stats.rhs_evaluations);
  state.counters["max_res"] = check.max_phi;
}

double median_wall_ms(int runs, const std::function<void()>& f) {
  std::vector<double> ms;
  for (int i = 0; i < runs; ++i) {
    const auto t0 = std::chrono::steady_clock::now();
    f();
    const auto t1 = std::chrono::steady_clock::now();
    ms.push_back(std::chrono::duration<double, std::milli>(t1 - t0).count());
  }
  std::sort(ms.begin(), ms.end());
  return ms[ms.size() / 2];
}

}  // namespace

void register_ukdyn_benchmarks() {
  using benchmark::RegisterBenchmark;
  for (const std::string key : {"m6", "m12r12", "m12r10"}) {
    with_min_max(RegisterBenchmark(("solve/textbook/" + key).c_str(), bm_textbook, key))
        ->Unit(benchmark::kNanosecond);
    with_min_max(RegisterBenchmark(("solve/cholesky_6+6/" + key).c_str(), bm_cholesky, key, true))
        ->Unit(benchmark::kNanosecond);
    with_min_max(RegisterBenchmark(("solve/cholesky_1x12/" + key).c_str(), bm_cholesky, key, false))
        ->Unit(benchmark::kNanosecond);
    if (key != "m12r10")  // the KKT matrix is singular for rank-deficient A
      with_min_max(RegisterBenchmark(("solve/kkt/" + key).c_str(), bm_kkt, key))
          ->Unit(benchmark::kNanosecond);
  }
  with_min_max(RegisterBenchmark("forward/closure", bm_forward, false))
      ->Unit(benchmark::kNanosecond);
  with_min_max(RegisterBenchmark("forward/closure+trajectory", bm_forward, true))
      ->Unit(benchmark::kNanosecond);
  with_min_max(RegisterBenchmark("simulate/paper_4s_dopri5_1e-12", bm_simulate, true))
      ->Unit(benchmark::kMillisecond);
  with_min_max(RegisterBenchmark("simulate/free_10s_rk4_1kHz", bm_simulate, false))
      ->Unit(benchmark::kMillisecond);
}

std::vector<ViolationRow> ukdyn_violation_rows(bool spatial, std::vector<double>& q_ref_05) {
  const PaperModel& pm = paper_model();
  const Vec& qd0 = spatial ? pm.qd0_spatial : pm.qd0_zero;
  const std::string start = spatial ? "spatial qd0" : "qd0 = 0";
  std::vector<ViolationRow> rows;

  // Reference: dopri5 at 1e-12, measured at every 1 ms (the same instants as the fixed-step runs).
  ukdyn::SimulationSettings dp = paper_settings();
  dp.sample_dt = 1e-3;
  std::vector<double> q05;
  const ResidualCheck cd = check_run(pm.closure, pm.q0, qd0, dp, 0.5, &q05);
  q_ref_05 = q05;
  ukdyn::SimulationSettings dp_timed = paper_settings();
  const double wall_dp = median_wall_ms(3, [&] {
    ukdyn::simulate(
        pm.closure, pm.q0, qd0, zero_tau, dp_timed,
        [](double, ukdyn::CVecRef, ukdyn::CVecRef, const ukdyn::ForwardData&) { return true; });
  });
  rows.push_back({"ukdyn", "dopri5 tol 1e-12, drift control projection", start, wall_dp, cd.max_gap,
                  cd.max_phi, 0.0});
  if (cd.stats.status != ukdyn::RunStatus::completed)
    rows.back().setup += " (" + cd.stats.message + ")";

  // RK4 at 1 kHz with the default drift control (projection onto Φ = 0, Φ̇ = 0 after each step)
  // and without any: the second row shows what exact acceleration-level enforcement alone holds.
  for (const auto drift : {ukdyn::DriftControl::projection, ukdyn::DriftControl::none}) {
    ukdyn::SimulationSettings check = rk4_settings(4.0, 1e-3);
    ukdyn::SimulationSettings timed = rk4_settings(4.0, 0.01);
    check.drift.kind = timed.drift.kind = drift;
    std::vector<double> q05_rk4;
    const ResidualCheck cr = check_run(pm.closure, pm.q0, qd0, check, 0.5, &q05_rk4);
    const double wall_rk = median_wall_ms(3, [&] {
      ukdyn::simulate(
          pm.closure, pm.q0, qd0, zero_tau, timed,
          [](double, ukdyn::CVecRef, ukdyn::CVecRef, const ukdyn::ForwardData&) { return true; });
    });
    double dq = -1.0;
    if (q05_rk4.size() == q05.size() && !q05.empty()) {
      dq = 0.0;
      for (std::size_t i = 0; i < q05.size(); ++i) dq = std::max(dq, std::abs(q05_rk4[i] - q05[i]));
    }
    rows.push_back({"ukdyn", "rk4 dt 1e-3, drift control " + ukdyn::to_string(drift), start,
                    wall_rk, cr.max_gap, cr.max_phi, dq});
    if (cr.stats.status != ukdyn::RunStatus::completed)
      rows.back().setup += " (" + cr.stats.message + ")";
  }
  return rows;
}

}  // namespace ukbench
