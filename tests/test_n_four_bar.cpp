// The N-four-bar benchmark (scenarios/benchmarks/n_four_bar_N*.yaml, MBS benchmark library A02)
// against its exact parallelogram-branch motion (NFourBarReference, tools/benchmark_reference.hpp),
// and the behaviour of
// the solve at its singular (flat) positions (docs/singular-positions.md).
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "tools/benchmark_reference.hpp"
#include "ukdyn/simulate/simulate.hpp"

#ifdef UKDYN_HAVE_IO
#include "ukdyn/scenario/scenario.hpp"
#endif

namespace {

using ukdyn_bench::NFourBarReference;

// φ(t) and φ̇(t) of the reference (θ = φ + π/2 of its pendulum, so θ̇ = φ̇).
void phi_of(const NFourBarReference& ref, double t, double& p, double& pd) {
  p = ref.phi(t);
  pd = ref.pendulum.theta_dot(t);
}

// The closed form is checked on its own: φ(t) must satisfy the pendulum ODE J φ̈ = −g K cos φ and
// φ̇ (from the energy integral) must be its derivative, both by central differences of φ(t).
TEST(NFourBar, ExactSolutionSatisfiesItsOde) {
  for (int windows : {2, 40}) {
    for (double v0 : {0.5, 1.0, 3.0}) {
      const NFourBarReference ex(windows, v0);
      const double J = (windows + 1) / 3.0 + windows, K = (windows + 1) / 2.0 + windows;
      double p0 = 0, pd0 = 0;
      phi_of(ex, 0.0, p0, pd0);
      EXPECT_NEAR(p0, M_PI / 2, 1e-14);
      EXPECT_NEAR(-std::sin(p0) * pd0, v0, 1e-14);  // dx(B0)/dt
      const double h = 1e-4;
      for (double t = 0.013; t < 20.0; t += 0.377) {
        double pm = 0, pdm = 0, p = 0, pd = 0, pp = 0, pdp = 0;
        phi_of(ex, t - h, pm, pdm);
        phi_of(ex, t, p, pd);
        phi_of(ex, t + h, pp, pdp);
        EXPECT_NEAR((pp - pm) / (2 * h), pd, 1e-6 * (1 + std::abs(pd))) << t;
        EXPECT_NEAR((pp - 2 * p + pm) / (h * h), -9.81 * K / J * std::cos(p), 1e-4) << t;
      }
    }
  }
}

#ifdef UKDYN_HAVE_IO
struct RunResult {
  ukdyn::SimulationStats stats;
  double max_b0_error = 0, max_energy_drift = 0, max_branch = 0;
};

// speed: dx(B0)/dt at t = 0 (the scenarios' q̇0 is for 1 m/s).
RunResult run(const std::string& file, double t_end, const ukdyn::UkSettings* uk = nullptr,
              double speed = 1.0) {
  using namespace ukdyn;
  const Scenario sc = load_scenario(std::string(UKDYN_SOURCE_DIR) + "/" + file);
  SimulationSettings s = sc.sim;
  s.t_end = t_end;
  if (uk) s.uk = *uk;
  const Index n = sc.system->dof();
  const int windows = static_cast<int>((n - 1) / 2);
  const NFourBarReference ex(windows, speed);
  RunResult res;
  double E0 = std::nan("");
  res.stats =
      simulate(*sc.system, sc.q0, Vec(sc.qd0 * speed), ForceFunction{}, s,
               [&](double t, CVecRef q, CVecRef qd, const ForwardData& d) {
                 const double E = kinetic_energy(d, qd) + potential_energy(*sc.system, q);
                 if (std::isnan(E0)) E0 = E;
                 res.max_energy_drift = std::max(res.max_energy_drift, std::abs(E - E0));
                 double x = 0, y = 0;
                 ex.point_B0(t, x, y);
                 res.max_b0_error =
                     std::max(res.max_b0_error, std::hypot(std::cos(q(0)) - x, std::sin(q(0)) - y));
                 for (int i = 1; i <= windows; ++i) {
                   res.max_branch =
                       std::max(res.max_branch, std::abs(std::remainder(q(i) - q(0), 2 * M_PI)));
                 }
                 return true;
               });
  return res;
}

// Up to just before the first flat position (t ≈ 0.714 s) the mechanism is regular: the model
// written in definitions must follow the closed form to the integration tolerance.
TEST(NFourBar, MatchesExactSolutionBeforeTheFirstSingularPosition) {
  for (const char* file :
       {"scenarios/benchmarks/n_four_bar_N2.yaml", "scenarios/benchmarks/n_four_bar_N40.yaml"}) {
    const RunResult r = run(file, 0.6);
    EXPECT_EQ(r.stats.status, ukdyn::RunStatus::completed) << file << ": " << r.stats.message;
    EXPECT_LT(r.max_b0_error, 1e-9) << file;
    EXPECT_LT(r.max_energy_drift, 1e-9) << file;
    EXPECT_LT(r.max_branch, 1e-12) << file;
    for (const auto& w : r.stats.warnings) EXPECT_NE(w.kind, "branch_switch") << file;
  }
}

// Across the flat positions (issue 9 item 1), default settings (the adaptive solve): the run
// completes over the benchmark's 10 s on the parallelogram branch, within 1e-6 m of the closed form
// and 1e-6 J of the initial energy, with no branch_switch false alarm; that the solve was damped
// near the flat positions is said (damped_solve).
TEST(NFourBar, DefaultSolvePassesTheFlatPositions) {
  const RunResult r = run("scenarios/benchmarks/n_four_bar_N2.yaml", 10.0);
  ASSERT_EQ(r.stats.status, ukdyn::RunStatus::completed) << r.stats.message;
  EXPECT_LT(r.max_b0_error, 1e-6);
  EXPECT_LT(r.max_energy_drift, 1e-6);
  EXPECT_LT(r.max_branch, 1e-9);
  bool damped = false;
  for (const auto& w : r.stats.warnings) {
    EXPECT_NE(w.kind, "branch_switch") << w.message;
    damped = damped || w.kind == "damped_solve";
  }
  EXPECT_TRUE(damped);
  EXPECT_LT(r.stats.max_correction_ratio, 1.0);
}

// The default damping scale of the adaptive solve (1e-5) keeps the run within the benchmark's 1e-6 m
// at other speeds too: at the scale 1e-6 (the default for a while) the half-speed run ended
// 3.3e-6 m from the exact motion (docs/accuracy.md, "The default damping scale").
TEST(NFourBar, DefaultSolveMeetsTheTargetAtHalfAndDoubleSpeed) {
  for (const double speed : {0.5, 2.0}) {
    const RunResult r = run("scenarios/benchmarks/n_four_bar_N2.yaml", 10.0, nullptr, speed);
    ASSERT_EQ(r.stats.status, ukdyn::RunStatus::completed) << speed << ": " << r.stats.message;
    EXPECT_LT(r.max_b0_error, 1e-6) << speed;
    EXPECT_LT(r.max_energy_drift, 1e-6) << speed;
    EXPECT_LT(r.max_branch, 1e-9) << speed;
  }
}

// The exact solve (the old default) still fails loudly at the first flat position.
TEST(NFourBar, ExactSolveFailsLoudlyAtTheFlatPosition) {
  ukdyn::UkSettings uk;
  uk.method = ukdyn::UkMethod::exact;
  const RunResult r = run("scenarios/benchmarks/n_four_bar_N2.yaml", 2.0, &uk);
  if (r.stats.status == ukdyn::RunStatus::completed) {
    EXPECT_LT(r.max_b0_error, 1e-6);
    EXPECT_LT(r.max_branch, 1e-6);
  } else {
    EXPECT_FALSE(r.stats.message.empty());
  }
}

// The damped (regularized) solve stays on the parallelogram branch through the flat positions;
// its constraint error is removed by the projection, and the branch check allows for it (the
// damping's acceleration error over the step): no branch_switch false alarm on a correct run.
TEST(NFourBar, RegularizedSolveStaysOnBranchWithoutFalseAlarm) {
  ukdyn::UkSettings uk;
  uk.method = ukdyn::UkMethod::regularized;
  uk.regularization = 1e-4;
  const RunResult r = run("scenarios/benchmarks/n_four_bar_N2.yaml", 2.0, &uk);
  ASSERT_EQ(r.stats.status, ukdyn::RunStatus::completed) << r.stats.message;
  EXPECT_LT(r.max_branch, 1e-9);
  EXPECT_LT(r.max_b0_error, 1e-5);
  EXPECT_LT(r.max_energy_drift, 1e-5);
  for (const auto& w : r.stats.warnings) EXPECT_NE(w.kind, "branch_switch") << w.message;
  EXPECT_LT(r.stats.max_correction_ratio, 1.0);
  EXPECT_GT(r.stats.max_position_correction, 0.0);  // the projection did work
}

// The provoked wrong-branch run (issue 9): exact solve with a tiny rank_tol. Whether it turns onto
// another branch depends on round-off (docs/singular-positions.md), but it must never do so
// silently: off the branch, a branch_switch or step_collapse warning must be there.
TEST(NFourBar, WrongBranchIsNeverSilent) {
  ukdyn::UkSettings uk;
  uk.method = ukdyn::UkMethod::exact;
  uk.rank_rel_tol = 1e-14;
  const RunResult r = run("scenarios/benchmarks/n_four_bar_N2.yaml", 10.0, &uk);
  bool warned = false;
  for (const auto& w : r.stats.warnings) {
    warned = warned || w.kind == "branch_switch" || w.kind == "step_collapse";
  }
  if (r.max_branch > 1e-6) {
    EXPECT_TRUE(warned || r.stats.status != ukdyn::RunStatus::completed)
        << "silent branch switch, max |phi_i - phi_0| = " << r.max_branch;
  } else if (r.stats.status == ukdyn::RunStatus::completed) {
    EXPECT_LT(r.max_b0_error, 1e-6);
  }
}

// on_branch_switch: stop ends the run with status branch_switch at the first correction beyond
// the allowance (here made tiny, branch_factor 1e-9, so that the projection's ordinary work
// exceeds it: the stop path, not the detection, is under test; detection: test_adaptive_solve).
TEST(NFourBar, BranchSwitchCanStopTheRun) {
  using namespace ukdyn;
  const Scenario sc =
      load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/benchmarks/n_four_bar_N2.yaml");
  SimulationSettings s = sc.sim;
  s.t_end = 2.0;
  s.uk.method = UkMethod::regularized;
  s.uk.regularization = 1e-4;
  s.drift.branch_factor = 1e-9;
  s.drift.stop_on_branch_switch = true;
  const auto st = simulate(*sc.system, sc.q0, sc.qd0, ForceFunction{}, s, nullptr);
  EXPECT_EQ(st.status, RunStatus::branch_switch);
  EXPECT_NE(st.message.find("branch switch"), std::string::npos) << st.message;
  EXPECT_LT(st.t_reached, 2.0);
}
#endif

}  // namespace
