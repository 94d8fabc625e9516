// Constraint roles, the force split by role, actuators and servo control (docs/control.md).
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include "control_systems.hpp"
#include "model/solve_stages.hpp"
#include "ukdyn/core/force_split.hpp"
#include "ukdyn/core/uk_solve.hpp"
#include "ukdyn/output/control_output.hpp"
#include "ukdyn/run/run.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/simulate/control.hpp"

namespace {

using ukdyn::ConstraintRole;
using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;

Mat random_spd(std::mt19937_64& rng, Index n) {
  std::normal_distribution<double> g;
  Mat X(n, n);
  for (Index i = 0; i < n; ++i)
    for (Index j = 0; j < n; ++j) X(i, j) = g(rng);
  return X * X.transpose() + Mat::Identity(n, n);
}

Mat random_mat(std::mt19937_64& rng, Index r, Index c) {
  std::normal_distribution<double> g;
  Mat X(r, c);
  for (Index i = 0; i < r; ++i)
    for (Index j = 0; j < c; ++j) X(i, j) = g(rng);
  return X;
}

// The split of the U-K force against the multipliers of an independent KKT solve
// [M Aᵀ; A 0][q̈; −λ] = [Q; b] (full-pivot LU): Qp = A_pᵀλ_p, Qs = A_sᵀλ_s.
TEST(ForceSplit, MatchesKktMultipliers) {
  std::mt19937_64 rng(12);
  for (int trial = 0; trial < 20; ++trial) {
    const Index n = 9, m = 6;
    const Mat M = random_spd(rng, n), A = random_mat(rng, m, n);
    const Vec b = random_mat(rng, m, 1), Q = random_mat(rng, n, 1);
    ukdyn::UkWorkspace ws(ukdyn::BlockLayout::single(n), m);
    Vec qdd(n), Qc(n);
    ukdyn::uk_solve(M, A, b, Q, ws, qdd, Qc);
    Mat K = Mat::Zero(n + m, n + m);
    K.topLeftCorner(n, n) = M;
    K.topRightCorner(n, m) = A.transpose();
    K.bottomLeftCorner(m, n) = A;
    Vec rhs(n + m);
    rhs << Q, b;
    const Vec sol = K.fullPivLu().solve(rhs);
    const Vec lambda = -sol.tail(m);
    std::vector<bool> servo = {false, false, true, false, true, true};
    Vec Qp = Vec::Zero(n), Qs = Vec::Zero(n);
    for (Index i = 0; i < m; ++i)
      (servo[static_cast<std::size_t>(i)] ? Qs : Qp) += A.row(i).transpose() * lambda(i);
    const auto s = ukdyn::split_by_role(A, Qc, servo);
    ASSERT_TRUE(s.unique);
    const double scale = Qc.norm() + 1.0;
    EXPECT_LT((s.Qp - Qp).norm(), 1e-10 * scale);
    EXPECT_LT((s.Qs - Qs).norm(), 1e-10 * scale);
    EXPECT_LT((s.Qp + s.Qs - Qc).norm(), 1e-12 * scale);
  }
}

// A repeated row: the split is not unique, the rows of the dependency are named, the total holds,
// and the least-norm choice gives the two copies half each.
TEST(ForceSplit, RedundantRowsAreNamedAndSplitByLeastNorm) {
  std::mt19937_64 rng(3);
  const Index n = 5;
  Mat A = random_mat(rng, 3, n);
  A.row(2) = A.row(0);  // row 2 (servo) repeats row 0 (physical)
  const Vec lam_true = (Vec(3) << 2.0, -1.0, 0.0).finished();
  const Vec Qc = A.transpose() * lam_true;
  const auto s = ukdyn::split_by_role(A, Qc, {false, false, true});
  EXPECT_FALSE(s.unique);
  EXPECT_EQ(s.rank, 2);
  EXPECT_EQ(s.redundant_rows, (std::vector<Index>{0, 2}));
  EXPECT_NEAR(s.lambda(0), 1.0, 1e-12);
  EXPECT_NEAR(s.lambda(2), 1.0, 1e-12);
  EXPECT_LT((s.Qp + s.Qs - Qc).norm(), 1e-12 * Qc.norm());
}

// Roles by type: paper.yaml's closure is physical, its cut-point trajectory and coordinate rows are
// servo; an expression is servo iff it depends on t; `role:` overrides; a bad role names
// file:line:column and the key.
TEST(ForceSplit, RolesFromTheScenario) {
  const auto paper = ukdyn::load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/paper.yaml");
  ASSERT_EQ(paper.constraint_roles.size(), paper.system->constraints().size());
  EXPECT_EQ(paper.constraint_roles.front(), ConstraintRole::physical);
  for (std::size_t c = 1; c < paper.constraint_roles.size(); ++c)
    EXPECT_EQ(paper.constraint_roles[c], ConstraintRole::servo) << c;
  const auto pend = ukdyn::load_scenario_text(uktest::pendulum_servo_yaml(), "p.yaml");
  EXPECT_EQ(pend.constraint_roles,
            (std::vector<ConstraintRole>{ConstraintRole::physical, ConstraintRole::servo}));
  std::string text = uktest::pendulum_servo_yaml();
  text.replace(text.find("    name: rod\n"), 14, "    name: rod\n    role: servo\n");
  const auto both = ukdyn::load_scenario_text(text, "p.yaml");
  EXPECT_EQ(both.constraint_roles.front(), ConstraintRole::servo);
  std::string bad = uktest::pendulum_servo_yaml();
  bad.replace(bad.find("    name: rod\n"), 14, "    name: rod\n    role: brake\n");
  try {
    (void)ukdyn::load_scenario_text(bad, "bad.yaml");
    FAIL() << "accepted role: brake";
  } catch (const ukdyn::ScenarioError& e) {
    EXPECT_NE(std::string(e.what()).find("bad.yaml:14:11: key 'constraints[0].role'"),
              std::string::npos)
        << e.what();
  }
}

double theta_r(double t) { return 0.3 * (1 - std::cos(2 * t)); }
double theta_r_dot(double t) { return 0.6 * std::sin(2 * t); }
double theta_r_ddot(double t) { return 1.2 * std::cos(2 * t); }

ukdyn::ControlModel model_of(const ukdyn::Scenario& sc) {
  return {sc.system, ukdyn::servo_row_flags(*sc.system, sc.constraint_roles), sc.actuators, sc.tau,
          sc.sim.uk};
}

// Inverse dynamics against the closed form: along θr the horizontal push is
// u = m (θ̈r + g sin θr) / cos θr (tangential balance of the bob on its rod of length 1).
TEST(Actuation, MatchesClosedFormOnThePendulum) {
  const auto sc = ukdyn::load_scenario_text(uktest::pendulum_servo_yaml(1.7), "p.yaml");
  const auto model = model_of(sc);
  ukdyn::ForwardData d(*sc.system);
  for (double t : {0.0, 0.3, 0.9, 1.4, 2.2}) {
    const double th = theta_r(t), w = theta_r_dot(t);
    const Vec q = (Vec(2) << std::sin(th), -std::cos(th)).finished();
    const Vec qd = (Vec(2) << w * std::cos(th), w * std::sin(th)).finished();
    ukdyn::forward(*sc.system, d, t, q, qd, Vec::Zero(2), sc.sim.uk);
    const auto a = ukdyn::actuation_for(model, d);
    const double u = 1.7 * (theta_r_ddot(t) + 9.8 * std::sin(th)) / std::cos(th);
    EXPECT_NEAR(a.u(0), u, 1e-10 * (1 + std::abs(u))) << t;
    EXPECT_FALSE(a.underactuated);
  }
}

// A vertical push cannot turn the bob at the bottom: underactuated, with the residual.
TEST(Actuation, UnderactuationIsReported) {
  std::string text = uktest::pendulum_servo_yaml();
  text.replace(text.find("coordinate: x}"), 14, "coordinate: z}");
  const auto sc = ukdyn::load_scenario_text(text, "p.yaml");
  ukdyn::ForwardData d(*sc.system);
  const Vec q = (Vec(2) << 0.0, -1.0).finished();
  ukdyn::forward(*sc.system, d, 0.0, q, Vec::Zero(2), Vec::Zero(2), sc.sim.uk);
  const auto a = ukdyn::actuation_for(model_of(sc), d);
  EXPECT_TRUE(a.underactuated);
  EXPECT_NEAR(a.residual, 1.2, 1e-9);  // the whole tangential force m θ̈r(0) = 1.2 N
}

// u(t) from the inverse dynamics along the reference, applied open loop (τ = B u, a function of t
// only) to the plant with only its physical rod: the servo trajectory is reproduced.
TEST(Actuation, OpenLoopInputsReproduceTheServoTrajectory) {
  const auto sc = ukdyn::load_scenario_text(uktest::pendulum_servo_yaml(), "p.yaml");
  const auto model = model_of(sc);
  const auto plant = ukdyn::physical_system(*sc.system, sc.constraint_roles);
  ASSERT_EQ(plant->rows(), 1);
  ukdyn::ForwardData d(*sc.system);
  const ukdyn::ForceFunction open_loop = [&](double t, ukdyn::CVecRef, ukdyn::CVecRef,
                                             ukdyn::VecRef tau) {
    const double th = theta_r(t), w = theta_r_dot(t);
    const Vec q = (Vec(2) << std::sin(th), -std::cos(th)).finished();
    const Vec qd = (Vec(2) << w * std::cos(th), w * std::sin(th)).finished();
    ukdyn::forward(*sc.system, d, t, q, qd, Vec::Zero(2), sc.sim.uk);
    tau = sc.actuators.B * ukdyn::actuation_for(model, d).u;
  };
  double max_servo = 0, max_rod = 0;
  long samples = 0;
  const auto stats = ukdyn::simulate(
      *plant, sc.q0, sc.qd0, open_loop, sc.sim,
      [&](double t, ukdyn::CVecRef q, ukdyn::CVecRef, const ukdyn::ForwardData&) {
        const double th = theta_r(t);
        max_servo = std::max(max_servo, std::abs(q(0) * std::cos(th) + q(1) * std::sin(th)));
        max_rod = std::max(max_rod, std::abs(0.5 * (q.squaredNorm() - 1)));
        ++samples;
        return true;
      });
  ASSERT_EQ(stats.status, ukdyn::RunStatus::completed) << stats.message;
  EXPECT_EQ(samples, 401);
  EXPECT_LT(max_servo, 1e-8);
  EXPECT_LT(max_rod, 1e-12);
  RecordProperty("max_servo_error", std::to_string(max_servo));
  std::printf("open loop over 4 s: max |servo| = %.3e, max |rod| = %.3e\n", max_servo, max_rod);
}

// ---- closed loop (a pendulum model and plant; docs/control.md)

std::string control_yaml(const std::string& law) {
  return "control:\n" + law + "  initial_offset: {swing_angle: 0.02}\n";
}

struct LoopResult {
  ukdyn::SimulationStats stats;
  std::vector<double> t, e;
  double max_e(double from, double to) const {
    double m = 0;
    for (std::size_t i = 0; i < t.size(); ++i)
      if (t[i] >= from - 1e-12 && t[i] <= to + 1e-12) m = std::max(m, std::abs(e[i]));
    return m;
  }
};

LoopResult run_loop(const ukdyn::Scenario& sc, double t_end, double tol) {
  const auto run = ukdyn::make_control_run(sc);
  EXPECT_TRUE(run);
  ukdyn::SimulationSettings sim = sc.sim;
  sim.t_end = t_end;
  sim.abs_tol = sim.rel_tol = tol;
  LoopResult r;
  Vec e, ed;
  r.stats = ukdyn::simulate(
      *run->plant, run->q0, run->qd0, run->loop->force_function(), sim,
      [&](double t, ukdyn::CVecRef q, ukdyn::CVecRef qd, const ukdyn::ForwardData&) {
        ukdyn::servo_errors(run->model, t, q, qd, e, ed);
        r.t.push_back(t);
        r.e.push_back(e(0));
        return true;
      });
  return r;
}

std::filesystem::path temp_dir(const std::string& name) {
  const auto d = std::filesystem::temp_directory_path() /
                 ("ukdyn_control_" + name + "_" + std::to_string(::getpid()));
  std::filesystem::create_directories(d);
  return d;
}

// Exact model (the plant is the scenario itself) and the stabilised servo law from an offset start
// at rest: e(t) = (1 + ωt) e^{−ωt} e(0), ω = 5 (the error ODE ë + 2ωė + ω²e = 0, ė(0) = 0).
TEST(Control, StabilizedServoErrorIsCriticallyDamped) {
  const auto sc = ukdyn::load_scenario_text(
      uktest::pendulum_servo_yaml(1.0, control_yaml("  law: stabilized\n  omega: 5\n")), "p.yaml");
  const auto r = run_loop(sc, 4.0, 1e-13);
  ASSERT_EQ(r.stats.status, ukdyn::RunStatus::completed) << r.stats.message;
  const double e0 = r.e.front(), w = 5.0;
  EXPECT_NEAR(e0, 0.02, 1e-14);
  double worst = 0;
  for (std::size_t i = 0; i < r.t.size(); ++i) {
    const double exact = (1 + w * r.t[i]) * std::exp(-w * r.t[i]) * e0;
    worst = std::max(worst, std::abs(r.e[i] - exact) / std::abs(e0));
  }
  EXPECT_LT(worst, 1e-6);
  std::printf("stabilized, exact model: max |e - (1+wt)e^-wt e0| / |e0| = %.3e\n", worst);
}

// Perturbed plant (the load mass x1.2): the feedback-only baseline (rho = 0) against the robust
// term (rho = 2, eps = 0.01): max|e| over [2, 10] s <= 1e-3 and >= 10x below the baseline; eps/10
// shrinks the final error (max over [9, 10] s) >= 3x.
TEST(Control, RobustTermBeatsFeedbackOnlyOnAHeavierLoad) {
  const auto dir = temp_dir("robust");
  { std::ofstream(dir / "plant.yaml") << uktest::pendulum_servo_yaml(1.2); }
  auto scenario = [&](double rho, double eps) {
    return ukdyn::load_scenario_text(
        uktest::pendulum_servo_yaml(
            1.0,
            control_yaml("  law: robust\n  lambda: 5\n  kappa: 5\n  rho: " + std::to_string(rho) +
                         "\n  epsilon: " + std::to_string(eps) + "\n  plant: plant.yaml\n")),
        dir / "model.yaml");
  };
  const auto base = run_loop(scenario(0.0, 0.01), 10.0, 1e-10);
  const auto robust = run_loop(scenario(2.0, 0.01), 10.0, 1e-10);
  const auto tight = run_loop(scenario(2.0, 0.001), 10.0, 1e-10);
  for (const auto* r : {&base, &robust, &tight})
    ASSERT_EQ(r->stats.status, ukdyn::RunStatus::completed) << r->stats.message;
  const double b = base.max_e(2, 10), rb = robust.max_e(2, 10);
  const double f1 = robust.max_e(9, 10), f2 = tight.max_e(9, 10);
  std::printf(
      "max|e| [2,10] s: feedback only %.3e, robust %.3e (ratio %.1f); final [9,10] s: "
      "eps 0.01 %.3e, eps 0.001 %.3e (ratio %.1f)\n",
      b, rb, b / rb, f1, f2, f1 / f2);
  EXPECT_LE(rb, 1e-3);
  EXPECT_GE(b / rb, 10.0);
  EXPECT_GE(f1 / f2, 3.0);
  std::filesystem::remove_all(dir);
}

// Through run_scenario: the e_/ed_/u_ columns, the control summary, and saturation flagged.
TEST(Control, RunWritesErrorsInputsAndFlagsSaturation) {
  std::string text = uktest::pendulum_servo_yaml(1.0, control_yaml("  law: stabilized\n"));
  text.replace(text.find("coordinate: x}"), 14, "coordinate: x, limit: 3}");
  const auto dir = temp_dir("run");
  const auto sc = ukdyn::load_scenario_text(text, dir / "p.yaml");
  ukdyn::RunOptions o;
  o.figures = false;
  const auto rep = ukdyn::run_scenario(sc, dir / "out", o);
  ASSERT_TRUE(rep.complete()) << rep.stats.message;
  std::ifstream csv(dir / "out" / "trajectory.csv");
  std::string header;
  std::getline(csv, header);
  for (const char* col : {"Qp_x", "Qs_z", "role_split_unique", "u_fx", "act_residual",
                          "e_swing_angle", "ed_swing_angle"})
    EXPECT_NE(header.find(col), std::string::npos) << col;
  bool warned = false;
  for (const auto& w : rep.stats.warnings) warned = warned || w.kind == "saturation";
  EXPECT_TRUE(warned);
  std::ifstream js(dir / "out" / "summary.json");
  std::stringstream ss;
  ss << js.rdbuf();
  EXPECT_NE(ss.str().find("\"max_abs_e_second_half\""), std::string::npos);
  EXPECT_NE(ss.str().find("\"saturation_max_over_limit\""), std::string::npos);
  std::filesystem::remove_all(dir);
}

// Bad control input names file:line:column and the key; the paper's control scenario loads with
// its plant, 12 actuators and the closure as its only physical block.
TEST(Control, ScenarioKeysAndThePaperControlScenario) {
  const auto bad = [](const std::string& extra, const std::string& expect) {
    try {
      (void)ukdyn::load_scenario_text(uktest::pendulum_servo_yaml(1.0, extra), "c.yaml");
      ADD_FAILURE() << "accepted: " << extra;
    } catch (const ukdyn::ScenarioError& e) {
      EXPECT_NE(std::string(e.what()).find(expect), std::string::npos) << e.what();
    }
  };
  bad("control:\n  law: pid\n", "c.yaml:25:8: key 'control.law': unknown law 'pid'");
  bad("control:\n  law: stabilized\n  plant: missing.yaml\n",
      "key 'control.plant': the plant scenario");
  bad("control:\n  law: stabilized\n  initial_offset: {rod_circle: 0.1}\n",
      "key 'control.initial_offset.rod_circle': row 'rod_circle' is not a servo row");
  const auto sc =
      ukdyn::load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/paper_control.yaml");
  ASSERT_TRUE(sc.control && sc.control->plant);
  EXPECT_EQ(sc.actuators.count(), 12);
  EXPECT_EQ(sc.control->plant->name, "paper_generic_exact_inertia");
  const auto plant =
      ukdyn::physical_system(*sc.control->plant->system, sc.control->plant->constraint_roles);
  EXPECT_EQ(plant->rows(), 6);  // the closure only
  EXPECT_EQ(sc.control->law.kind, ukdyn::ControlLawKind::robust);
}

// control.plant_set: the plant as this scenario with values changed. {path, scale} and
// {path, value} give the same plant as a separate plant file with the heavier bob, so the same
// closed loop bit for bit; bad entries name the key.
TEST(Control, PlantSetEqualsTheSamePlantWrittenAsAFile) {
  const auto dir = temp_dir("plant_set");
  { std::ofstream(dir / "plant.yaml") << uktest::pendulum_servo_yaml(1.2); }
  const std::string law = "  law: robust\n  lambda: 5\n  kappa: 5\n  rho: 2\n  epsilon: 0.01\n";
  const auto file = ukdyn::load_scenario_text(
      uktest::pendulum_servo_yaml(1.0, control_yaml(law + "  plant: plant.yaml\n")),
      dir / "model.yaml");
  const auto scaled = ukdyn::load_scenario_text(
      uktest::pendulum_servo_yaml(
          1.0, control_yaml(law + "  plant_set:\n    - {path: \"subsystems[bob].parameters.m\", "
                                  "scale: 1.2}\n")),
      dir / "model.yaml");
  const auto valued = ukdyn::load_scenario_text(
      uktest::pendulum_servo_yaml(
          1.0, control_yaml(law + "  plant_set:\n    - {path: \"subsystems[bob].parameters.m\", "
                                  "value: 1.2}\n")),
      dir / "model.yaml");
  ASSERT_TRUE(scaled.control && scaled.control->plant);
  EXPECT_FALSE(scaled.control->plant->control);  // the plant has no controller of its own
  const auto a = run_loop(file, 2.0, 1e-10), b = run_loop(scaled, 2.0, 1e-10),
             c = run_loop(valued, 2.0, 1e-10);
  ASSERT_EQ(a.stats.status, ukdyn::RunStatus::completed) << a.stats.message;
  EXPECT_EQ(a.e, b.e);
  EXPECT_EQ(a.e, c.e);
  // The model's own bob (1 kg) is not the plant's: the loop without plant_set differs.
  const auto exact =
      run_loop(ukdyn::load_scenario_text(uktest::pendulum_servo_yaml(1.0, control_yaml(law)),
                                         dir / "model.yaml"),
               2.0, 1e-10);
  EXPECT_NE(a.e, exact.e);
  const auto bad = [&](const std::string& set, const std::string& expect) {
    try {
      (void)ukdyn::load_scenario_text(
          uktest::pendulum_servo_yaml(1.0, control_yaml(law + "  plant_set:\n" + set)), "c.yaml");
      ADD_FAILURE() << "accepted: " << set;
    } catch (const ukdyn::ScenarioError& e) {
      EXPECT_NE(std::string(e.what()).find(expect), std::string::npos) << e.what();
    }
  };
  bad("    - {path: \"subsystems[bob].parameters.mass\", scale: 2}\n",
      "key 'control.plant_set[0].path': 'subsystems[bob].parameters.mass': "
      "'subsystems[bob].parameters' has no key 'mass'");
  bad("    - {path: \"subsystems[bob].parameters.m\", scale: 2, value: 3}\n",
      "key 'control.plant_set[0]': give exactly one of 'value' and 'scale'");
  bad("    - {path: \"subsystems[bob].bodies[bob].mass\", scale: 2}\n",
      "'subsystems[bob].bodies[bob].mass' holds 'm', not a number: 'scale' needs one");
  bad("    - {path: gravity, value: -1e999}\n", "key 'control.plant_set[0].value'");
  std::filesystem::remove_all(dir);
}

// A row the file marks `role: servo` whose kind is physical by default (a scleronomic expression)
// stays a servo row in a plant_set plant made from the same file: the plant is read from the
// document as written, `role:` included.
TEST(Control, PlantSetKeepsTheRolesAsWritten) {
  std::string yaml = uktest::pendulum_servo_yaml(
      1.0, control_yaml("  law: stabilized\n  omega: 5\n  plant_set:\n"
                        "    - {path: \"subsystems[bob].parameters.m\", scale: 1.1}\n"));
  const std::string swing =
      "    let: {th: 0.3*(1 - cos(2*t))}\n    rows: {angle: x*cos(th) + z*sin(th)}\n";
  const auto at = yaml.find(swing);
  ASSERT_NE(at, std::string::npos);
  yaml.replace(at, swing.size(), "    role: servo\n    rows: {angle: x}\n");
  const auto sc = ukdyn::load_scenario_text(yaml, "model.yaml");
  ASSERT_EQ(sc.constraint_roles.size(), 2U);
  EXPECT_EQ(sc.constraint_roles[1], ukdyn::ConstraintRole::servo);
  ASSERT_TRUE(sc.control && sc.control->plant);
  EXPECT_EQ(sc.control->plant->constraint_roles, sc.constraint_roles);
}

// A Monte Carlo over the plant (issue 12): 50 seeded draws of the bob's mass, 0.8 to 1.4 times
// the model's, under the robust law. Every run completes; the tracking error after the transient
// (max |e| over [1.5, 3] s) is reported as p50 / p99 / max and bounded by 1e-3.
TEST(Control, MonteCarloOverThePlantMass) {
  const std::string law = "  law: robust\n  lambda: 5\n  kappa: 5\n  rho: 2\n  epsilon: 0.01\n";
  std::mt19937_64 rng(20261202);
  std::uniform_real_distribution<double> factor(0.8, 1.4);
  std::vector<double> err;
  for (int k = 0; k < 50; ++k) {
    const double f = factor(rng);
    const auto sc = ukdyn::load_scenario_text(
        uktest::pendulum_servo_yaml(
            1.0, control_yaml(law +
                              "  plant_set:\n    - {path: \"subsystems[bob].parameters.m\", "
                              "scale: " +
                              fmt::format("{}", f) + "}\n")),
        "mc.yaml");
    const auto r = run_loop(sc, 3.0, 1e-9);
    ASSERT_EQ(r.stats.status, ukdyn::RunStatus::completed)
        << "draw " << k << ": " << r.stats.message;
    err.push_back(r.max_e(1.5, 3.0));
  }
  std::vector<double> sorted = err;
  std::sort(sorted.begin(), sorted.end());
  const auto pct = [&](double p) {
    return sorted[static_cast<std::size_t>(
        std::lround(p * static_cast<double>(sorted.size() - 1)))];
  };
  std::printf(
      "Monte Carlo, 50 plants (bob mass x U[0.8, 1.4]), max|e| over [1.5, 3] s: p50 %.3e, "
      "p99 %.3e, max %.3e\n",
      pct(0.5), pct(0.99), sorted.back());
  EXPECT_LE(sorted.back(), 1e-3);
}

}  // namespace

namespace {

// The pendulum's model (bob 1 kg) under the robust law ρ = 2, ε = 0.01 against a plant whose bob
// weighs `plant_mass` (tests/control_systems.hpp): plant.yaml and model.yaml in `dir`.
ukdyn::Scenario robust_pendulum(const std::filesystem::path& dir, double plant_mass,
                                const std::string& gains = "") {
  { std::ofstream(dir / "plant.yaml") << uktest::pendulum_servo_yaml(plant_mass); }
  return ukdyn::load_scenario_text(
      uktest::pendulum_servo_yaml(1.0,
                                  control_yaml("  law: robust\n" + gains +
                                               "  rho: 2\n  epsilon: 0.01\n  plant: plant.yaml\n")),
      dir / "model.yaml");
}

// The pendulum's closed loop (tests/control_systems.hpp) with the robust law ρ = 2, ε = 0.01 and
// the plant's bob of mass `plant_mass` (the model's is 1 kg), through run_scenario.
struct RhoRun {
  nlohmann::json control;
  std::vector<ukdyn::RunWarning> warnings;
};
RhoRun run_rho(double plant_mass, const std::string& name) {
  const auto dir = temp_dir(name);
  const auto sc = robust_pendulum(dir, plant_mass, "  lambda: 5\n  kappa: 5\n");
  ukdyn::RunOptions o;
  o.figures = false;
  const auto rep = ukdyn::run_scenario(sc, dir / "out", o);
  EXPECT_TRUE(rep.complete()) << rep.stats.message;
  std::ifstream js(dir / "out" / "summary.json");
  RhoRun r{nlohmann::json::parse(js)["control"], rep.stats.warnings};
  std::filesystem::remove_all(dir);
  return r;
}

bool has_warning(const std::vector<ukdyn::RunWarning>& w, const std::string& kind) {
  return std::any_of(w.begin(), w.end(), [&](const auto& x) { return x.kind == kind; });
}

}  // namespace

// The uncertainty the robust term must dominate (docs/control.md "The uncertainty bound ρ"):
// δ = A_s q̈_plant − (b_s + v). At one state it equals A_s (q̈_plant − q̈_model), both accelerations
// from forward() of the physical systems (plant: bob 1.2 kg, model: 1 kg) under the same applied
// τ = B u, with A_s = [cos θr, sin θr] written by hand (Φ_s = x cos θr + z sin θr).
TEST(Control, UncertaintyEqualsPlantMinusModelAcceleration) {
  const auto dir = temp_dir("delta");
  const auto sc = robust_pendulum(dir, 1.2);
  const auto run = ukdyn::make_control_run(sc);
  ASSERT_TRUE(run);
  const double t = 0.7, th = 0.35, w = 0.4;
  Vec q(2), qd(2);
  q << std::sin(th), -std::cos(th);
  qd << w * std::cos(th), w * std::sin(th);  // tangent to the rod
  run->loop->evaluate(t, q, qd);
  Vec tau(2);
  run->loop->plant_tau(tau);
  ukdyn::ForwardData pd(*run->plant);
  ukdyn::forward(*run->plant, pd, t, q, qd, tau);
  const double delta = run->law->servo_uncertainty(run->model, pd.qdd);
  // The model's physical system (its rod only) under the same u: its own τ + B u.
  const auto model_phys = ukdyn::physical_system(*sc.system, sc.constraint_roles);
  ukdyn::ForwardData md(*model_phys);
  const Vec tau_m = sc.tau + sc.actuators.B * run->loop->u;
  ukdyn::forward(*model_phys, md, t, q, qd, tau_m);
  const double thr = 0.3 * (1 - std::cos(2 * t));
  const double indep =
      std::abs(std::cos(thr) * (pd.qdd(0) - md.qdd(0)) + std::sin(thr) * (pd.qdd(1) - md.qdd(1)));
  std::printf("delta = %.17g, independent A_s (qdd_plant - qdd_model) = %.17g, diff %.2e\n", delta,
              indep, std::abs(delta - indep));
  EXPECT_GT(indep, 0.1);  // a real mismatch (the plant is 20 % heavier)
  EXPECT_NEAR(delta, indep, 1e-12);
  std::filesystem::remove_all(dir);
}

// The run's check of the assumption: a plant within the bound (bob 1.2 kg, ρ = 2) gives no warning
// and a ratio < 1; bob mass × 3 with the same ρ gives `rho_bound_exceeded` and a ratio > 1.
TEST(Control, RhoBoundCheckedAtRunTime) {
  const auto in = run_rho(1.2, "rho_in"), out = run_rho(3.0, "rho_out");
  for (const auto* r : {&in, &out})
    for (const char* k : {"max_uncertainty", "max_uncertainty_t", "rho", "uncertainty_over_rho",
                          "rho_bound_exceeded"})
      EXPECT_TRUE(r->control.contains(k)) << k;
  const double ri = in.control["uncertainty_over_rho"], ro = out.control["uncertainty_over_rho"];
  std::printf(
      "max ||delta|| / rho: bob x1.2 %.4f (max %.4f at t = %.3f s), bob x3 %.4f (max %.4f "
      "at t = %.3f s)\n",
      ri, double(in.control["max_uncertainty"]), double(in.control["max_uncertainty_t"]), ro,
      double(out.control["max_uncertainty"]), double(out.control["max_uncertainty_t"]));
  EXPECT_LT(ri, 1.0);
  EXPECT_FALSE(in.control["rho_bound_exceeded"]);
  EXPECT_FALSE(has_warning(in.warnings, "rho_bound_exceeded"));
  EXPECT_GT(ro, 1.0);
  EXPECT_TRUE(out.control["rho_bound_exceeded"]);
  EXPECT_TRUE(has_warning(out.warnings, "rho_bound_exceeded"));
  EXPECT_DOUBLE_EQ(double(out.control["rho"]), 2.0);
}

// The allocation-free actuation solve (ActuationWorkspace) gives the same bits as
// solve_actuation(): fully, under- and redundantly actuated, rank-deficient physical rows, no
// physical rows; one workspace reused across calls.
TEST(Actuation, WorkspaceSolveIsBitIdentical) {
  std::mt19937_64 rng(7);
  struct Case {
    Index n, k, mp;
    bool deficient;
  };
  for (const Case c : {Case{6, 6, 2, false}, Case{6, 3, 2, false}, Case{6, 9, 3, false},
                       Case{5, 5, 3, true}, Case{4, 2, 0, false}, Case{12, 12, 6, false}}) {
    ukdyn::ActuationWorkspace ws(c.n, c.k, c.mp);
    for (int trial = 0; trial < 5; ++trial) {
      const Mat B = random_mat(rng, c.n, c.k);
      Mat Ap = random_mat(rng, c.mp, c.n);
      if (c.deficient) Ap.row(2) = Ap.row(0) + 0.5 * Ap.row(1);
      const Vec Qc = random_mat(rng, c.n, 1);
      const ukdyn::Actuation ref = ukdyn::solve_actuation(B, Ap, Qc);
      ws.Ap = Ap;
      ukdyn::solve_actuation(B, Qc, ws);
      EXPECT_EQ(ws.result.u, ref.u) << c.n << " " << c.k << " " << c.mp;
      EXPECT_EQ(ws.result.mu, ref.mu);
      EXPECT_EQ(ws.result.residual, ref.residual);
      EXPECT_EQ(ws.result.scale, ref.scale);
      EXPECT_EQ(ws.result.underactuated, ref.underactuated);
    }
  }
}

namespace {
// The built-in law as it was written before it got its workspace (select_rows() and the
// allocating solve_actuation() at every call): the closed loop must be the same bit for bit.
class AllocatingServoLaw : public ukdyn::ControlLaw {
 public:
  AllocatingServoLaw(const ukdyn::ControlModel& m, ukdyn::ServoLawSettings s)
      : s_(s), work_(*m.system), phi_(m.system->rows()), phid_(m.system->rows()) {}
  void control(const ukdyn::ControlModel& model, double t, ukdyn::CVecRef q, ukdyn::CVecRef qd,
               const ukdyn::ForwardData& md, ukdyn::VecRef u) override {
    const ukdyn::System& sys = *model.system;
    Vec b = md.b;
    ukdyn::position_residuals(sys, work_, t, q, phi_);
    ukdyn::velocity_residuals(sys, work_, t, q, qd, phid_);
    double mu2 = 0.0;
    for (Index i = 0; i < sys.rows(); ++i)
      if (model.row_servo[static_cast<std::size_t>(i)]) {
        const double beta = phid_(i) + s_.lambda * phi_(i);
        mu2 += s_.rho * s_.rho * beta * beta;
      }
    const double mn = std::sqrt(mu2), gamma = mn > s_.epsilon ? 1.0 / mn : 1.0 / s_.epsilon;
    for (Index i = 0; i < sys.rows(); ++i) {
      if (!model.row_servo[static_cast<std::size_t>(i)]) continue;
      const double e = phi_(i), ed = phid_(i), beta = ed + s_.lambda * e, mu = s_.rho * beta;
      b(i) += -s_.lambda * ed - s_.kappa * beta - s_.rho * gamma * mu;
    }
    work_.M = md.M;
    work_.A = md.A;
    work_.Q = md.Q;
    ukdyn::uk_solve_dispatch(work_, b, work_.Q, work_.qdd, work_.Qc, model.uk);
    u = ukdyn::solve_actuation(model.actuators.B,
                               ukdyn::select_rows(work_.A, model.row_servo, false), work_.Qc)
            .u;
  }

 private:
  ukdyn::ServoLawSettings s_;
  ukdyn::ForwardData work_;
  Vec phi_, phid_;
};
}  // namespace

TEST(Control, WorkspaceLawIsBitIdenticalToTheAllocatingOne) {
  const auto dir = temp_dir("bits");
  const auto sc = robust_pendulum(dir, 1.2);
  const auto a = run_loop(sc, 2.0, 1e-10);
  const auto run = ukdyn::make_control_run(sc);
  AllocatingServoLaw old(run->model, sc.control->law);
  ukdyn::ClosedLoop loop(run->model, old, sc.control->plant->tau);
  std::vector<double> e_old;
  Vec e, ed;
  ukdyn::SimulationSettings sim = sc.sim;
  sim.t_end = 2.0;
  sim.abs_tol = sim.rel_tol = 1e-10;
  const auto st = ukdyn::simulate(
      *run->plant, run->q0, run->qd0, loop.force_function(), sim,
      [&](double t, ukdyn::CVecRef q, ukdyn::CVecRef qd, const ukdyn::ForwardData&) {
        ukdyn::servo_errors(run->model, t, q, qd, e, ed);
        e_old.push_back(e(0));
        return true;
      });
  ASSERT_EQ(st.status, ukdyn::RunStatus::completed);
  ASSERT_EQ(a.e.size(), e_old.size());
  EXPECT_EQ(a.e, e_old);  // bit for bit over 2 s (201 samples)
  std::filesystem::remove_all(dir);
}

// The sign of the squeeze force, from statics (docs/control.md, "The squeeze force"). The paper's
// plant (exact inertia, closure only) at rest, held by applied forces τ = G − A_cᵀλ0 with λ0 the
// force F0 = −P n at robot 1's cut point (n: platform 1 → platform 2): the platforms are pushed
// towards each other with P (τ_dx1 = +P n_x, τ_dx2 = −P n_x) and the joints hold. Statics: q̈ = 0,
// and the closure must carry exactly F0, so the reported squeeze is +P (compression), and −P when
// the platforms pull apart. Independent of how the sign was derived in control_forces.cpp.
TEST(Control, SqueezeSignFromAStaticHold) {
  const auto sc =
      ukdyn::load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/paper_control.yaml");
  const auto run = ukdyn::make_control_run(sc);
  ASSERT_TRUE(run);
  const ukdyn::System& plant = *run->plant;
  const auto& rows = plant.constraint_row_names();
  const auto& names = plant.coordinate_names();
  const auto at = [](const auto& v, const char* n) {
    const auto it = std::find(v.begin(), v.end(), n);
    EXPECT_NE(it, v.end()) << n;
    return static_cast<Index>(it - v.begin());
  };
  const Index cx = at(rows, "closure_x"), cy = at(rows, "closure_y");
  const Index dx1 = at(names, "dx1"), dy1 = at(names, "dy1"), dx2 = at(names, "dx2"),
              dy2 = at(names, "dy2");
  const Vec q = run->q0, qd = Vec::Zero(q.size());
  const double nx0 = q(dx2) - q(dx1), ny0 = q(dy2) - q(dy1), l = std::hypot(nx0, ny0);
  const double nx = nx0 / l, ny = ny0 / l;
  ukdyn::ForwardData d(plant);
  const Vec zero = Vec::Zero(q.size());
  ukdyn::forward(plant, d, 0.0, q, qd, zero);
  const Vec G = -d.Q;  // at rest with τ = 0: Q = −G
  for (const double P : {7.5, -4.0}) {
    Vec lambda0 = Vec::Zero(plant.rows());
    lambda0(cx) = -P * nx;
    lambda0(cy) = -P * ny;
    const Vec tau = G - d.A.transpose() * lambda0;
    EXPECT_NEAR(tau(dx1), P * nx, 1e-12);  // the platforms push towards each other with P
    EXPECT_NEAR(tau(dx2), -P * nx, 1e-12);
    ukdyn::ForwardData h(plant);
    ukdyn::forward(plant, h, 0.0, q, qd, tau);
    EXPECT_LT(h.qdd.cwiseAbs().maxCoeff(), 1e-11) << "not a static hold";
    ukdyn::ControlColumns cols(sc, run->loop.get());
    cols.set_plant(plant);
    ASSERT_TRUE(cols.peaks().closure);
    std::vector<double> out(cols.header().size());
    cols.fill(0.0, q, qd, h, out.data());
    std::printf("platforms pushed together with P = %+.2f N: squeeze %+.15f N\n", P,
                cols.peaks().max_squeeze_force);
    EXPECT_NEAR(cols.peaks().max_squeeze_force, P, 1e-9 * std::abs(P));
    EXPECT_NEAR(cols.peaks().max_closure_force, std::abs(P), 1e-9 * std::abs(P));
  }
}
