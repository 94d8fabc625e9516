// Short horizons of the IFToMM benchmark problems in scenarios/benchmarks/ (the full durations are
// `make benchmarks`, tools/benchmarks.cpp, docs/benchmarks.md), against references that do not
// come from ukdyn: the exact pendulum (tools/benchmark_reference.hpp, itself checked here against
// its differential equation, its energy and an AGM value of K), a second formulation of Bricard's
// mechanism, and the invariants (energy, constraint residuals, the rank of A).
#ifdef UKDYN_HAVE_IO
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <numbers>
#include <sstream>
#include <string>
#include <vector>

#include "model/slot_energy.hpp"
#include "tools/benchmark_reference.hpp"
#include "ukdyn/model/linearize.hpp"
#include "ukdyn/run/run.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/simulate/diagnostics.hpp"
#include "ukdyn/simulate/simulate.hpp"

namespace {

using ukdyn::CVecRef;
using ukdyn::ForwardData;
using ukdyn::Index;
using ukdyn::Vec;
using ukdyn_bench::ExactPendulum;

const std::filesystem::path kBench =
    std::filesystem::path(UKDYN_SOURCE_DIR) / "scenarios/benchmarks";

std::string read_file(const std::filesystem::path& p) {
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

/// Samples of a run: t, q, and the invariants.
struct Trace {
  ukdyn::SimulationStats stats;
  std::vector<double> t;
  std::vector<Vec> q;
  double max_residual = 0, max_dE = 0, E0 = std::nan("");
  int rank_min = 1 << 30, rank_max = -1;
};

Trace run(const ukdyn::Scenario& sc, double t_end, double sample_dt) {
  Trace tr;
  ukdyn::SimulationSettings s = sc.sim;
  s.t_end = t_end;
  s.sample_dt = sample_dt;
  Vec phi(sc.system->rows());
  tr.stats = ukdyn::simulate(
      *sc.system, sc.q0, sc.qd0, {}, s, [&](double t, CVecRef q, CVecRef qd, const ForwardData& d) {
        const double E = ukdyn::kinetic_energy(d, qd) + ukdyn::potential_energy(*sc.system, q);
        if (std::isnan(tr.E0)) tr.E0 = E;
        tr.max_dE = std::max(tr.max_dE, std::abs(E - tr.E0));
        ukdyn::position_residuals(*sc.system, t, q, phi);
        tr.max_residual = std::max(tr.max_residual, phi.cwiseAbs().maxCoeff());
        tr.rank_min = std::min(tr.rank_min, d.result.rank);
        tr.rank_max = std::max(tr.rank_max, d.result.rank);
        tr.t.push_back(t);
        tr.q.emplace_back(q);
        return true;
      });
  return tr;
}

/// K(k) by the arithmetic-geometric mean, K = π / (2 AGM(1, √(1 − k²))) (DLMF 19.8.5): independent
/// of Boost's ellint_1.
double agm_K(double k) {
  double a = 1, b = std::sqrt(1 - k * k);
  for (int i = 0; i < 40 && std::abs(a - b) > 1e-17; ++i) {
    const double an = (a + b) / 2;
    b = std::sqrt(a * b);
    a = an;
  }
  return std::numbers::pi / (2 * a);
}

// ---- the reference itself ---------------------------------------------------------------------

// The closed form satisfies θ̈ = −ω² sin θ (central differences at h = 1e-4: truncation h²/12 |θ⁗|
// and rounding 1e-14/h² both ≈ 1e-6 here; bound 1e-5 ω²), its energy ½θ̇² − ω² cos θ is constant (θ̇
// from the closed form, ≤ 1e-12), it starts at (θ0, θ̇0), and the libration period is 4K/ω with K
// from an independent AGM.
TEST(BenchmarkReference, ExactPendulumSolvesItsEquation) {
  const double w = 3.0;
  struct Start {
    double th0, thd0;
  };
  for (const Start s : {Start{std::numbers::pi / 2, 0.0}, Start{0.3, -1.2}, Start{-2.0, 0.7},
                        Start{std::numbers::pi, -1.0}, Start{0.5, 9.0}, Start{1.0, -8.0}}) {
    const ExactPendulum p(w, s.th0, s.thd0);
    EXPECT_NEAR(p.theta(0.0), s.th0, 1e-13);
    EXPECT_NEAR(p.theta_dot(0.0), s.thd0, 1e-12 * (1 + std::abs(s.thd0)));
    const double e0 = 0.5 * s.thd0 * s.thd0 - w * w * std::cos(s.th0);
    const double h = 1e-4;
    for (double t = 0.05; t < 5.0; t += 0.173) {
      const double th = p.theta(t), thd = p.theta_dot(t);
      const double acc = (p.theta(t + h) - 2 * th + p.theta(t - h)) / (h * h);
      EXPECT_NEAR(acc, -w * w * std::sin(th), 1e-5 * w * w) << "t = " << t;
      EXPECT_NEAR((p.theta(t + h) - p.theta(t - h)) / (2 * h), thd, 1e-5 * (1 + std::abs(thd)));
      EXPECT_NEAR(0.5 * thd * thd - w * w * std::cos(th), e0, 1e-11 * (1 + std::abs(e0)));
    }
  }
  // Released at rest from the horizontal: k = sin(π/4), period 4K/ω, back at θ0 after one period.
  const ExactPendulum p(w, std::numbers::pi / 2, 0.0);
  EXPECT_FALSE(p.circulating());
  EXPECT_NEAR(p.period(), 4 * agm_K(std::sin(std::numbers::pi / 4)) / w, 1e-14);
  EXPECT_NEAR(p.theta(p.period()), std::numbers::pi / 2, 1e-12);
  EXPECT_NEAR(p.theta(p.period() / 2), -std::numbers::pi / 2, 1e-12);
  EXPECT_NEAR(p.theta(p.period() / 4), 0.0, 1e-12);
  // Circulating: one turn (θ − 2π) after period().
  const ExactPendulum c(w, std::numbers::pi, -1.0);
  EXPECT_TRUE(c.circulating());
  EXPECT_NEAR(c.theta(c.period()), -std::numbers::pi, 1e-11);
}

// The N-four-bar reference: J, G of the parallelogram branch and its initial state (cranks
// vertical, ẋ_B0 = 1 m/s): B0(0) = (0, 1), and B0 moves along +x at 1 m/s.
TEST(BenchmarkReference, NFourBarBranchStartsAsSpecified) {
  for (const int N : {2, 40}) {
    const ukdyn_bench::NFourBarReference ref(N);
    EXPECT_DOUBLE_EQ(ref.J, (N + 1) / 3.0 + N);
    EXPECT_DOUBLE_EQ(ref.G, ((N + 1) / 2.0 + N) * 9.81);
    double x = 0, y = 0, x1 = 0, y1 = 0;
    ref.point_B0(0.0, x, y);
    EXPECT_NEAR(x, 0.0, 1e-15);
    EXPECT_NEAR(y, 1.0, 1e-15);
    const double h = 1e-6;
    ref.point_B0(h, x1, y1);
    EXPECT_NEAR((x1 - x) / h, 1.0, 1e-5);
    EXPECT_NEAR(ref.energy(), 0.5 * ref.J + ref.G, 1e-12 * ref.G);
  }
}

// ---- A01 simple pendulum ----------------------------------------------------------------------

double pendulum_max_error(const Trace& tr, const ukdyn_bench::SimplePendulumReference& ref) {
  double e = 0;
  for (std::size_t i = 0; i < tr.t.size(); ++i) {
    double x = 0, y = 0;
    ref.point(tr.t[i], x, y);
    e = std::max(e, std::hypot(tr.q[i](0) - x, tr.q[i](1) - y));
  }
  return e;
}

// 3 s (more than one period, 2.37 s) at the scenario's settings (dopri5, tolerances 1e-12, drift
// projection to 1e-15). Bounds: ~1000 accepted steps of local error ≤ 1e-12 give a global error of
// at most about 1e-9, so the position error must stay under 1e-8 (a change of g in the 4th digit
// shifts P1 by 1e-3, checked below: the test fails on a wrong model); max|Φ| under 1e-12 (the
// projection's tolerance, with margin); energy drift under 1e-8 J of the 9.81 J exchanged.
TEST(Benchmarks, SimplePendulumAgainstTheExactSolution) {
  const auto sc = ukdyn::load_scenario(kBench / "simple_pendulum.yaml");
  ASSERT_EQ(sc.system->coordinate_names(), (std::vector<std::string>{"x", "y"}));
  const Trace tr = run(sc, 3.0, 0.01);
  ASSERT_EQ(tr.stats.status, ukdyn::RunStatus::completed) << tr.stats.message;
  const ukdyn_bench::SimplePendulumReference ref;
  const double err = pendulum_max_error(tr, ref);
  EXPECT_LT(err, 1e-8);
  EXPECT_LT(tr.max_residual, 1e-12);
  EXPECT_LT(tr.max_dE, 1e-8);
  EXPECT_EQ(tr.rank_min, 1);
  EXPECT_EQ(tr.rank_max, 1);

  // The same measure on a wrong model (g = 9.80 instead of 9.81) is far over the bound.
  std::string text = read_file(kBench / "simple_pendulum.yaml");
  const auto pos = text.find("gravity: [0, -9.81, 0]");
  ASSERT_NE(pos, std::string::npos);
  text.replace(pos, 22, "gravity: [0, -9.80, 0]");
  const auto wrong = ukdyn::load_scenario_text(text, "wrong_g.yaml");
  const Trace tw = run(wrong, 3.0, 0.01);
  EXPECT_GT(pendulum_max_error(tw, ref), 1e-3);
}

// simulation.error_estimate: shadow against the true error (the exact pendulum): at tolerance 1e-7
// over 3 s the run's error is ~1e-7 m, the shadow's (at 1e-9) a hundredth of it, so the estimate
// max |q − q_shadow| must be the true max |q − q_exact| within a few per cent (bounds: a factor 1.5).
TEST(Benchmarks, ShadowErrorEstimateMatchesTheTrueError) {
  auto sc = ukdyn::load_scenario(kBench / "simple_pendulum.yaml");
  sc.sim.t_end = 3.0;
  sc.sim.sample_dt = 0.01;
  sc.sim.abs_tol = sc.sim.rel_tol = 1e-7;
  sc.error_estimate = true;
  const ukdyn::MemoryRun run = ukdyn::run_scenario_in_memory(sc);
  ASSERT_TRUE(run.report.complete()) << run.report.stats.message;
  const std::size_t cols = run.header.size();
  ASSERT_GE(cols, 3u);
  ASSERT_EQ(run.header[1], "x");
  ASSERT_EQ(run.header[2], "y");
  const ukdyn_bench::SimplePendulumReference ref;
  double err = 0;
  for (std::size_t r = 0; r * cols < run.values.size(); ++r) {
    const double* row = run.values.data() + r * cols;
    double x = 0, y = 0;
    ref.point(row[0], x, y);
    err = std::max({err, std::abs(row[1] - x), std::abs(row[2] - y)});
  }
  const ukdyn::ErrorEstimate& e = run.report.error_estimate;
  ASSERT_TRUE(e.requested);
  EXPECT_EQ(e.shadow_status, ukdyn::to_string(ukdyn::RunStatus::completed)) << e.note;
  EXPECT_EQ(e.samples_compared, static_cast<long>(run.values.size() / cols));
  EXPECT_GT(err, 1e-9);  // there is an error to estimate
  EXPECT_GT(e.max_abs_q, err / 1.5) << err;
  EXPECT_LT(e.max_abs_q, err * 1.5) << err;
  EXPECT_NE(run.summary_json.find("\"error_estimate\""), std::string::npos);
  EXPECT_TRUE(e.reliable) << e.note;  // no singular position: nothing damped
  EXPECT_NE(run.summary_json.find("\"reliable\": true"), std::string::npos);
  // Off by default: nothing is computed or reported.
  sc.error_estimate = false;
  const ukdyn::MemoryRun plain = ukdyn::run_scenario_in_memory(sc);
  EXPECT_FALSE(plain.report.error_estimate.requested);
  EXPECT_EQ(plain.summary_json.find("\"error_estimate\""), std::string::npos);
}

// Through a singular position the damped solve acts in the run and in its shadow alike, so the
// difference is not the run's error (docs/accuracy.md): the estimate says it is not reliable, in
// the report and the summary. The N = 2 four-bar passes its flat position at t ≈ 0.71 s; the
// regularized solve damps everywhere.
TEST(Benchmarks, ShadowErrorEstimateIsNotVouchedForThroughDamping) {
  auto fb = ukdyn::load_scenario(kBench / "n_four_bar_N2.yaml");
  fb.sim.t_end = 1.0;
  fb.error_estimate = true;
  const ukdyn::MemoryRun run = ukdyn::run_scenario_in_memory(fb);
  ASSERT_TRUE(run.report.complete()) << run.report.stats.message;
  bool damped = false;
  for (const auto& w : run.report.stats.warnings) damped = damped || w.kind == "damped_solve";
  ASSERT_TRUE(damped);  // the premise: the run was damped near the flat position
  const ukdyn::ErrorEstimate& e = run.report.error_estimate;
  EXPECT_FALSE(e.reliable);
  EXPECT_NE(e.note.find("not reliable"), std::string::npos) << e.note;
  EXPECT_NE(run.summary_json.find("\"reliable\": false"), std::string::npos);

  auto pendulum = ukdyn::load_scenario(kBench / "simple_pendulum.yaml");
  pendulum.sim.t_end = 0.5;
  pendulum.sim.uk.method = ukdyn::UkMethod::regularized;
  pendulum.error_estimate = true;
  const ukdyn::MemoryRun reg = ukdyn::run_scenario_in_memory(pendulum);
  ASSERT_TRUE(reg.report.complete()) << reg.report.stats.message;
  EXPECT_FALSE(reg.report.error_estimate.reliable);
  EXPECT_NE(reg.report.error_estimate.note.find("regularized"), std::string::npos);
}

// ---- A04 Bricard's mechanism ------------------------------------------------------------------

std::array<double, 3> bricard_p3(double a, double b) {  // as tools/benchmarks.cpp
  const double u = 1 + std::sin(b), v = -std::cos(b);
  return {std::cos(a) * u, v, -std::sin(a) * u};
}

// 2 s of both formulations (serial chain O1..O2 closed at O2; two chains closed at J4). They share
// no constraint equation and only the first two joint angles, so P3 must agree to the integration
// error (bound 1e-8 as above). Both: 5 coordinates, 5 rows, rank 4 at every sample (one redundant
// row, 1 DOF where Grübler counts 0); max|Φ| ≤ 1e-12; energy drift ≤ 1e-8 J.
TEST(Benchmarks, BricardTwoFormulationsAgreeAndTheRedundancyIsDetected) {
  const auto a = ukdyn::load_scenario(kBench / "bricard.yaml");
  const auto b = ukdyn::load_scenario(kBench / "bricard_cut_at_j4.yaml");
  for (const auto* sc : {&a, &b}) {
    EXPECT_EQ(sc->system->dof(), 5);
    EXPECT_EQ(sc->system->rows(), 5);  // Grübler: 5 − 5 = 0 degrees of freedom
  }
  const Trace ta = run(a, 2.0, 0.01), tb = run(b, 2.0, 0.01);
  ASSERT_EQ(ta.stats.status, ukdyn::RunStatus::completed) << ta.stats.message;
  ASSERT_EQ(tb.stats.status, ukdyn::RunStatus::completed) << tb.stats.message;
  ASSERT_EQ(ta.t.size(), tb.t.size());
  double err = 0, travel = 0;
  const auto p0 = bricard_p3(0, 0);
  for (std::size_t i = 0; i < ta.t.size(); ++i) {
    const auto pa = bricard_p3(ta.q[i](0), ta.q[i](1));
    const auto pb = bricard_p3(tb.q[i](0), tb.q[i](1));
    err = std::max(err, std::hypot(pa[0] - pb[0], pa[1] - pb[1], pa[2] - pb[2]));
    travel = std::max(travel, std::hypot(pa[0] - p0[0], pa[1] - p0[1], pa[2] - p0[2]));
  }
  EXPECT_LT(err, 1e-8);
  EXPECT_GT(travel, 0.5);  // the mechanism does move (it is not locked by the 5 rows)
  for (const Trace* tr : {&ta, &tb}) {
    EXPECT_EQ(tr->rank_min, 4);
    EXPECT_EQ(tr->rank_max, 4);
    EXPECT_LT(tr->max_residual, 1e-12);
    EXPECT_LT(tr->max_dE, 1e-8);
    // No warning: the redundant row is found at the start (structural_redundancy 1), so the
    // adaptive solve neither damps it nor reads its drift as a singular position.
    for (const auto& w : tr->stats.warnings) ADD_FAILURE() << w.kind << ": " << w.message;
    EXPECT_EQ(tr->stats.structural_redundancy, 1);
  }
  // Released at rest: E0 = V0 = −g Σ m y_CoM = −9.81 (0 + 0.5 + 1 + 1 + 0.5) J.
  EXPECT_NEAR(ta.E0, -3 * 9.81, 1e-12);
  EXPECT_NEAR(tb.E0, -3 * 9.81, 1e-12);
}

// The loop closed at O2 by a ball and a vertical level (bricard_numeric.yaml: rows evaluated in
// numbers from the tree's link poses, docs/frame-constraints.md) against the two points_coincide of
// bricard.yaml (tapes of the chain's symbolic kinematics): the same mechanism by another path, so
// over 2 s at the files' tolerance 1e-12 the joint angles agree to the integration error (bound
// 1e-10; P3 and all five q), with rank 4 of 5 at every sample and no warning in either.
TEST(Benchmarks, BricardNumericRowsAgreeWithThePointRows) {
  const auto a = ukdyn::load_scenario(kBench / "bricard.yaml");
  const auto h = ukdyn::load_scenario(kBench / "bricard_numeric.yaml");
  ASSERT_EQ(h.system->dof(), 5);
  ASSERT_EQ(h.system->rows(), 5);
  ASSERT_EQ(h.sim.abs_tol, a.sim.abs_tol);
  const Trace ta = run(a, 2.0, 0.01), th = run(h, 2.0, 0.01);
  ASSERT_EQ(ta.stats.status, ukdyn::RunStatus::completed) << ta.stats.message;
  ASSERT_EQ(th.stats.status, ukdyn::RunStatus::completed) << th.stats.message;
  ASSERT_EQ(ta.t.size(), th.t.size());
  double err_p3 = 0, err_q = 0, travel = 0;
  for (std::size_t i = 0; i < ta.t.size(); ++i) {
    const auto pa = bricard_p3(ta.q[i](0), ta.q[i](1));
    const auto ph = bricard_p3(th.q[i](0), th.q[i](1));
    err_p3 = std::max(err_p3, std::hypot(pa[0] - ph[0], pa[1] - ph[1], pa[2] - ph[2]));
    err_q = std::max(err_q, (ta.q[i] - th.q[i]).cwiseAbs().maxCoeff());
    travel = std::max(travel, th.q[i].cwiseAbs().maxCoeff());
  }
  std::cout << "[ bricard ] numeric against point rows over 2 s: P3 " << err_p3 << " m, q " << err_q
            << " rad; steps " << th.stats.steps << " / " << ta.stats.steps << "\n";
  EXPECT_LT(err_p3, 1e-10);
  EXPECT_LT(err_q, 1e-10);
  EXPECT_GT(travel, 0.5);  // it moves
  EXPECT_EQ(th.rank_min, 4);
  EXPECT_EQ(th.rank_max, 4);
  EXPECT_LT(th.max_residual, 1e-12);
  EXPECT_LT(th.max_dE, 1e-8);
  EXPECT_NEAR(th.E0, -3 * 9.81, 1e-12);
  for (const auto& w : th.stats.warnings) ADD_FAILURE() << w.kind << ": " << w.message;
  EXPECT_EQ(th.stats.structural_redundancy, 1);
  // The exact derivatives (linearize(), which the run sensitivities integrate) at the state of
  // t = 1 s: along the motion, dq̈ = ∂q̈/∂q q̇ + ∂q̈/∂q̇ q̈ is the jerk, the same for every
  // formulation of the same loop (a hinge for the ball and level gives the same rows and motion
  // but a jerk off by 0.5 here: its all-directions derivative pass is wrong with a fixed end).
  Vec q1s, qd1s;
  ukdyn::SimulationSettings s1 = a.sim;
  s1.t_end = 1.0;
  s1.sample_dt = 0.5;
  ukdyn::simulate(*a.system, a.q0, a.qd0, {}, s1,
                  [&](double t, CVecRef q, CVecRef qd, const ForwardData&) {
                    if (t == 1.0) q1s = q, qd1s = qd;
                    return true;
                  });
  ASSERT_EQ(q1s.size(), 5);
  const Vec zero = Vec::Zero(5);
  const auto la = ukdyn::linearize(*a.system, 1.0, q1s, qd1s, zero, a.sim.uk);
  const auto lh = ukdyn::linearize(*h.system, 1.0, q1s, qd1s, zero, h.sim.uk);
  const Vec jerk_a = la.dqdd_dq * qd1s + la.dqdd_dqd * la.qdd;
  const Vec jerk_h = lh.dqdd_dq * qd1s + lh.dqdd_dqd * lh.qdd;
  std::cout << "[ bricard ] jerk at t = 1 s: " << jerk_a.transpose() << " / " << jerk_h.transpose()
            << "\n";
  EXPECT_GT(jerk_a.cwiseAbs().maxCoeff(), 1.0);
  EXPECT_LT((jerk_a - jerk_h).cwiseAbs().maxCoeff(), 1e-8 * jerk_a.cwiseAbs().maxCoeff());
  // Without a ForwardData (as the benchmark tool's samples call them) the rows and the energy
  // evaluate in buffers of their own, the forward workspace only: the same bytes as in the slots.
  ukdyn::ForwardData d(*h.system);
  Vec phi_own(5), phi_slot(5);
  for (std::size_t i = 0; i < th.q.size(); i += 37) {
    const Vec& q = th.q[i];
    ukdyn::position_residuals(*h.system, 0.0, q, phi_own);
    ukdyn::position_residuals(*h.system, d, 0.0, q, phi_slot);
    EXPECT_EQ(std::memcmp(phi_own.data(), phi_slot.data(), 5 * sizeof(double)), 0);
    const double V_own = ukdyn::potential_energy(*h.system, q);
    const double V_slot = ukdyn::detail::potential_energy_in_slots(*h.system, d, 0.0, q);
    EXPECT_EQ(std::memcmp(&V_own, &V_slot, sizeof V_own), 0);
  }
}

// The mobility is Bricard's geometry, not an artefact of the formulation: tilt one joint axis (J5
// about z → (0, 0.6, 0.8), the start position still closes the loop) and the same 5 rows have rank
// 5, no free DOF, and the loop stays where it is.
TEST(Benchmarks, BricardWithATiltedAxisIsLocked) {
  std::string text = read_file(kBench / "bricard.yaml");
  const std::string j5 = "axis: [0, 0, 1],\n         coordinate: q5";
  const auto pos = text.find(j5);
  ASSERT_NE(pos, std::string::npos);
  text.replace(pos, j5.size(), "axis: [0, 3, 4],\n         coordinate: q5");
  const auto sc = ukdyn::load_scenario_text(text, "bricard_tilted.yaml");
  const Trace tr = run(sc, 1.0, 0.01);
  ASSERT_EQ(tr.stats.status, ukdyn::RunStatus::completed) << tr.stats.message;
  EXPECT_EQ(tr.rank_min, 5);
  double travel = 0;
  for (const Vec& q : tr.q) travel = std::max(travel, q.cwiseAbs().maxCoeff());
  EXPECT_LT(travel, 1e-9);
}

// The constant redundancy of Bricard's mechanism against the rank lost at a singular position:
// the N-four-bar (N = 2) started on its flat position, where the exact solve finds rank 2 of 4
// (the x rows vanish), has no structural redundancy (the rank comes back nearby); Bricard's
// 5 rows have one, in both formulations.
TEST(Benchmarks, StructuralRedundancyIsToldFromASingularStart) {
  for (const char* f : {"bricard.yaml", "bricard_cut_at_j4.yaml"}) {
    const auto sc = ukdyn::load_scenario(kBench / f);
    EXPECT_EQ(ukdyn::detail::structural_redundancy(*sc.system, 0.0, sc.q0, sc.qd0, sc.sim.uk), 1)
        << f;
  }
  std::string text = read_file(kBench / "n_four_bar_N2.yaml");
  const std::string q0 = "q: [pi/2, pi/2, pi/2, 0, 0]";
  const auto pos = text.find(q0);
  ASSERT_NE(pos, std::string::npos);
  text.replace(pos, q0.size(), "q: [0, 0, 0, 0, 0]");
  const auto flat = ukdyn::load_scenario_text(text, "n_four_bar_flat.yaml");
  ForwardData d(*flat.system);
  ukdyn::UkSettings exact;
  ukdyn::forward(*flat.system, d, 0.0, flat.q0, flat.qd0, Vec::Zero(5), exact);
  EXPECT_EQ(d.result.rank, 2);  // singular there: the test below is not vacuous
  EXPECT_EQ(ukdyn::detail::structural_redundancy(*flat.system, 0.0, flat.q0, flat.qd0, exact), 0);
}

// A 3 s Bricard run with the given solve and tolerance (abs and rel), samples every 0.01 s.
Trace bricard_run(const ukdyn::Scenario& base, ukdyn::UkMethod method, double tol) {
  ukdyn::Scenario sc = base;
  sc.sim.uk.method = method;
  sc.sim.abs_tol = sc.sim.rel_tol = tol;
  return run(sc, 3.0, 0.01);
}

// The largest distance between P3 of two Bricard runs over their common samples.
double bricard_p3_distance(const Trace& tr, const Trace& ref) {
  double e = 0;
  for (std::size_t i = 0; i < tr.t.size() && i < ref.t.size(); ++i) {
    const auto a = bricard_p3(tr.q[i](0), tr.q[i](1));
    const auto b = bricard_p3(ref.q[i](0), ref.q[i](1));
    e = std::max(e, std::hypot(a[0] - b[0], a[1] - b[1], a[2] - b[2]));
  }
  return e;
}

// The adaptive solve (the scenarios' default) on Bricard at loose tolerances: with the redundancy
// known it keeps the accuracy and the cost of the exact one instead of damping at every stage
// that drift lifts the redundant direction (before: 1.2e-4 m at tolerance 1e-9, 3 338 rejected
// steps of 3 838 at 1e-6). P3 over 3 s against the exact solve at 1e-12.
TEST(Benchmarks, BricardAdaptiveSolveAtLooseTolerances) {
  const auto base = ukdyn::load_scenario(kBench / "bricard.yaml");
  auto with = [&](ukdyn::UkMethod method, double tol) { return bricard_run(base, method, tol); };
  const Trace ref = with(ukdyn::UkMethod::exact, 1e-12);
  ASSERT_EQ(ref.stats.status, ukdyn::RunStatus::completed) << ref.stats.message;
  auto p3_error = [&](const Trace& tr) { return bricard_p3_distance(tr, ref); };
  for (const double tol : {1e-6, 1e-9}) {
    const Trace ad = with(ukdyn::UkMethod::adaptive, tol);
    const Trace ex = with(ukdyn::UkMethod::exact, tol);
    ASSERT_EQ(ad.stats.status, ukdyn::RunStatus::completed) << ad.stats.message;
    ASSERT_EQ(ad.t.size(), ref.t.size());
    for (const auto& w : ad.stats.warnings) ADD_FAILURE() << tol << " " << w.kind;
    // The error the tolerance buys (1e-6: a few 1e-6 m over 3 s; 1e-9: as the exact solve's).
    EXPECT_LT(p3_error(ad), tol == 1e-6 ? 2e-5 : 10 * std::max(p3_error(ex), 1e-9)) << tol;
    EXPECT_LE(ad.stats.rhs_evaluations, 1.2 * static_cast<double>(ex.stats.rhs_evaluations)) << tol;
    EXPECT_LT(ad.max_residual, 1e-12);
  }
}

// The error of the default (adaptive) solve of the redundant formulation against a formulation with
// no redundancy at all: the same loop closed by 4 independent rows (O2's axis held by its y row
// only, rank 4 of 4), exact solve, the same tolerance. The redundancy must cost no accuracy and no
// work: P3 within 3× of the 4-row run's error (measured 1.5× at 1e-6 over 10 s) with at most 1.2×
// its evaluations. The exact solve of the 5 rows is not the yardstick: at 1e-6 the drift lifts the
// redundant direction above its rank cut-off, its 1/σ force makes nine steps in ten fail, and the
// small steps that follow make its error an accident of the rejections (docs/benchmarks.md, "A04 at
// loose tolerances"). Damping the redundant row (the adaptive rule without the structural
// redundancy) gave 4.2e-2 m at 1e-6: 10⁴ times the 4-row error.
TEST(Benchmarks, BricardRedundancyCostsNeitherAccuracyNorWork) {
  const auto base = ukdyn::load_scenario(kBench / "bricard.yaml");
  std::string text = read_file(kBench / "bricard.yaml");
  const std::string two_rows = "axes: [y, z]";
  const auto at = text.find(two_rows);
  ASSERT_NE(at, std::string::npos);
  text.replace(at, two_rows.size(), "axes: [y]");
  const auto four = ukdyn::load_scenario_text(text, "bricard_4_rows.yaml");
  ASSERT_EQ(four.system->rows(), 4);
  const auto with = bricard_run;
  const Trace ref = with(four, ukdyn::UkMethod::exact, 1e-12);
  ASSERT_EQ(ref.stats.status, ukdyn::RunStatus::completed) << ref.stats.message;
  EXPECT_EQ(ref.rank_min, 4);
  auto p3_error = [&](const Trace& tr) { return bricard_p3_distance(tr, ref); };
  for (const double tol : {1e-6, 1e-8}) {
    const Trace red = with(base, ukdyn::UkMethod::adaptive, tol);
    const Trace ind = with(four, ukdyn::UkMethod::exact, tol);
    ASSERT_EQ(red.stats.status, ukdyn::RunStatus::completed) << red.stats.message;
    ASSERT_EQ(red.t.size(), ref.t.size());
    EXPECT_EQ(red.stats.structural_redundancy, 1);
    const double e_red = p3_error(red), e_ind = p3_error(ind);
    EXPECT_GT(e_ind, 0.0) << tol;
    EXPECT_LT(e_red, 3.0 * e_ind) << tol << ": " << e_red << " against " << e_ind;
    EXPECT_LE(red.stats.rhs_evaluations, 1.2 * static_cast<double>(ind.stats.rhs_evaluations))
        << tol;
  }
}

// ---- A02 N-four-bar ---------------------------------------------------------------------------

// The reference against an independent model of N = 2 written here (absolute crank angles p0..p2,
// coupler angles s1, s2, 4 closure rows; every link a uniform 1 m / 1 kg rod), over 0.6 s: before
// the first flat position (t = 0.714 s), where the mechanism is singular. B0 = (cos p0, sin p0)
// within 1e-8 (dopri5 at 1e-12, as above) and the model's initial energy equal to the branch's.
TEST(Benchmarks, NFourBarReferenceAgainstAnIndependentModel) {
  const std::string text = R"(ukdyn: 1
name: n_four_bar_2_check
gravity: 9.81
subsystems:
  - name: m
    type: definitions
    coordinates: [p0, p1, p2, s1, s2]
    parameters: {L: 1, m: 1, I: 1/12}
    gravity: [0, -9.81, 0]
    bodies:
      - {name: c0, mass: m, com: [L/2*cos(p0), L/2*sin(p0), 0], inertia: I,
         angular_velocity: [0, 0, p0_dot]}
      - {name: c1, mass: m, com: [L + L/2*cos(p1), L/2*sin(p1), 0], inertia: I,
         angular_velocity: [0, 0, p1_dot]}
      - {name: c2, mass: m, com: [2*L + L/2*cos(p2), L/2*sin(p2), 0], inertia: I,
         angular_velocity: [0, 0, p2_dot]}
      - {name: k1, mass: m, com: [L*cos(p0) + L/2*cos(s1), L*sin(p0) + L/2*sin(s1), 0],
         inertia: I, angular_velocity: [0, 0, s1_dot]}
      - {name: k2, mass: m, com: [L + L*cos(p1) + L/2*cos(s2), L*sin(p1) + L/2*sin(s2), 0],
         inertia: I, angular_velocity: [0, 0, s2_dot]}
constraints:
  - type: expression
    name: w
    parameters: {L: 1}
    rows:
      x1: L*cos(p0) + L*cos(s1) - (L + L*cos(p1))
      y1: L*sin(p0) + L*sin(s1) - L*sin(p1)
      x2: L + L*cos(p1) + L*cos(s2) - (2*L + L*cos(p2))
      y2: L*sin(p1) + L*sin(s2) - L*sin(p2)
initial:
  q: [pi/2, pi/2, pi/2, 0, 0]
  qd: [-1, -1, -1, 0, 0]
simulation:
  t_end: 1
  sample_dt: 0.01
  abs_tol: 1e-12
  rel_tol: 1e-12
)";
  const auto sc = ukdyn::load_scenario_text(text, "n_four_bar_2_check.yaml");
  const ukdyn_bench::NFourBarReference ref(2);
  const Trace tr = run(sc, 0.6, 0.01);
  ASSERT_EQ(tr.stats.status, ukdyn::RunStatus::completed) << tr.stats.message;
  EXPECT_NEAR(tr.E0, ref.energy(), 1e-12 * ref.G);
  double err = 0, travel = 0;
  for (std::size_t i = 0; i < tr.t.size(); ++i) {
    double x = 0, y = 0;
    ref.point_B0(tr.t[i], x, y);
    err = std::max(err, std::hypot(std::cos(tr.q[i](0)) - x, std::sin(tr.q[i](0)) - y));
    travel = std::max(travel, std::hypot(x, y - 1));
  }
  EXPECT_LT(err, 1e-8);
  EXPECT_GT(travel, 1.0);  // B0 has turned most of the quarter to the flat position
  EXPECT_EQ(tr.rank_min, 4);
}

// The N-four-bar scenarios of the library (tools/n_four_bar.py; skipped if absent).

// Coordinate-free: on the parallelogram branch V = G sin φ and T = ½ J φ̇², so the scenario's
// initial energy must be the reference's, and V(t)/G = sin φ(t) = y_B0(t) over a short run (2 s,
// one flat crossing for N = 2: φ passes 0 near t ≈ 1.2 s).
TEST(Benchmarks, NFourBarFollowsTheParallelogramBranch) {
  const auto file = kBench / "n_four_bar_N2.yaml";
  if (!std::filesystem::exists(file)) GTEST_SKIP() << file << " is not in this tree";
  const auto sc = ukdyn::load_scenario(file);
  const ukdyn_bench::NFourBarReference ref(2);
  ukdyn::SimulationSettings s = sc.sim;
  s.t_end = 2.0;
  s.sample_dt = 0.01;
  // Default solver settings (the adaptive solve, docs/singular-positions.md): it crosses the flat
  // position on the branch.
  double err = 0, E0 = std::nan("");
  const auto st = ukdyn::simulate(*sc.system, sc.q0, sc.qd0, {}, s,
                                  [&](double t, CVecRef q, CVecRef qd, const ForwardData& d) {
                                    const double V = ukdyn::potential_energy(*sc.system, q);
                                    if (std::isnan(E0)) E0 = ukdyn::kinetic_energy(d, qd) + V;
                                    double x = 0, y = 0;
                                    ref.point_B0(t, x, y);
                                    err = std::max(err, std::abs(V / ref.G - y));
                                    return true;
                                  });
  EXPECT_NEAR(E0, ref.energy(), 1e-9 * ref.G);
  ASSERT_EQ(st.status, ukdyn::RunStatus::completed) << st.message;
  EXPECT_LT(err, 1e-6);
}

}  // namespace
#endif  // UKDYN_HAVE_IO
