// Integrators, drift control, diagnostics and assembly (issue 4), on the paper's system.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/simulate/simulate.hpp"

namespace {

using namespace ukdyn;
const std::filesystem::path kSource = UKDYN_SOURCE_DIR;

Scenario free_scenario(const char* file = "paper_free_spatial.yaml") {
  return load_scenario(kSource / "scenarios" / file);
}

// Final state of a run.
Vec final_state(const Scenario& sc, const SimulationSettings& s, SimulationStats* stats = nullptr) {
  Vec out(2 * sc.system->dof());
  const ForceFunction tau;
  const auto st = simulate(*sc.system, sc.q0, sc.qd0, tau, s,
                           [&](double, CVecRef q, CVecRef qd, const ForwardData&) {
                             out << q, qd;
                             return true;
                           });
  EXPECT_EQ(st.status, RunStatus::completed) << st.message;
  if (stats) *stats = st;
  return out;
}

struct OrderCase {
  IntegratorKind kind;
  double h;
  double order;
};
void PrintTo(const OrderCase& c, std::ostream* os) { *os << to_string(c.kind) << " h=" << c.h; }

class ConvergenceOrder : public ::testing::TestWithParam<OrderCase> {};

// Error at step h and h/2 against a much finer reference: log2(e(h)/e(h/2)) ≈ the method's order.
TEST_P(ConvergenceOrder, MatchesTheMethodsOrder) {
  const OrderCase c = GetParam();
  const Scenario sc = free_scenario();
  SimulationSettings s = sc.sim;
  s.t_end = 0.4;
  s.sample_dt = 0.4;
  s.drift.kind = DriftControl::none;  // the integrator alone
  s.adaptive = false;
  SimulationSettings ref = s;
  ref.integrator = IntegratorKind::rkf78;
  ref.step = c.h / 32;
  const Vec x_ref = final_state(sc, ref);
  s.integrator = c.kind;
  s.step = c.h;
  const double e1 = (final_state(sc, s) - x_ref).norm();
  s.step = c.h / 2;
  const double e2 = (final_state(sc, s) - x_ref).norm();
  const double observed = std::log2(e1 / e2);
  // At least the method's order; up to one more where the next error term still dominates at these
  // steps (Dormand–Prince's 5th-order error constant is small: its observed rate here is ~5.8).
  EXPECT_GE(observed, c.order - 0.3) << "e(h) = " << e1 << ", e(h/2) = " << e2;
  EXPECT_LE(observed, c.order + 1.0) << "e(h) = " << e1 << ", e(h/2) = " << e2;
}

INSTANTIATE_TEST_SUITE_P(Integrators, ConvergenceOrder,
                         ::testing::Values(OrderCase{IntegratorKind::rk4, 0.02, 4.0},
                                           OrderCase{IntegratorKind::dopri5, 0.01, 5.0},
                                           OrderCase{IntegratorKind::rkf78, 0.04, 8.0}),
                         [](const auto& i) { return to_string(i.param.kind); });

TEST(AdaptiveIntegrators, ErrorFollowsTheTolerance) {
  const Scenario sc = free_scenario();
  SimulationSettings ref = sc.sim;
  ref.t_end = 1.0;
  ref.sample_dt = 1.0;
  ref.drift.kind = DriftControl::none;
  ref.integrator = IntegratorKind::rkf78;
  ref.abs_tol = ref.rel_tol = 1e-15;
  const Vec x_ref = final_state(sc, ref);
  for (auto kind : {IntegratorKind::dopri5, IntegratorKind::rkf78}) {
    SimulationSettings s = ref;
    s.integrator = kind;
    SimulationStats st;
    s.abs_tol = s.rel_tol = 1e-8;
    const double loose = (final_state(sc, s, &st) - x_ref).norm();
    const long loose_steps = st.steps;
    s.abs_tol = s.rel_tol = 1e-12;
    const double tight = (final_state(sc, s, &st) - x_ref).norm();
    EXPECT_LT(tight, loose / 100) << to_string(kind);
    EXPECT_LT(tight, 1e-9) << to_string(kind);
    EXPECT_GT(st.steps, loose_steps) << to_string(kind);
  }
}

TEST(DriftControl, ProjectionHoldsTheClosureAtRoundOffWhereNoneDrifts) {
  const Scenario sc = free_scenario("paper_free.yaml");
  double res[3] = {0, 0, 0};
  const DriftControl kinds[3] = {DriftControl::none, DriftControl::baumgarte,
                                 DriftControl::projection};
  Vec phi(sc.system->rows());
  for (int k = 0; k < 3; ++k) {
    SimulationSettings s = sc.sim;
    s.t_end = 20.0;
    s.sample_dt = 0.05;
    s.integrator = IntegratorKind::rk4;
    s.step = 1e-3;
    s.drift.kind = kinds[k];
    const ForceFunction tau;
    const auto st = simulate(*sc.system, sc.q0, sc.qd0, tau, s,
                             [&](double t, CVecRef q, CVecRef, const ForwardData&) {
                               position_residuals(*sc.system, t, q, phi);
                               res[k] = std::max(res[k], phi.cwiseAbs().maxCoeff());
                               return true;
                             });
    ASSERT_EQ(st.status, RunStatus::completed) << to_string(kinds[k]) << ": " << st.message;
  }
  EXPECT_LE(res[2], 1e-13);         // projection: round-off
  EXPECT_GT(res[0], 100 * res[2]);  // none: visible drift with RK4 at 1 kHz
  EXPECT_LT(res[1], res[0]);        // Baumgarte: better than none
}

TEST(Diagnostics, FullyPrescribedMotionIsReported) {
  const Scenario sc = load_scenario(kSource / "scenarios" / "paper.yaml");
  SimulationSettings s = sc.sim;
  s.t_end = 0.1;
  const ForceFunction tau;
  const auto st = simulate(*sc.system, sc.q0, sc.qd0, tau, s, nullptr);
  ASSERT_EQ(st.status, RunStatus::completed);
  ASSERT_EQ(st.warnings.size(), 1u);
  EXPECT_EQ(st.warnings[0].kind, "fully_prescribed");
  EXPECT_EQ(st.warnings[0].t, 0.0);
}

TEST(Diagnostics, NonFiniteForcesStopTheRunCleanly) {
  const Scenario sc = free_scenario();
  SimulationSettings s = sc.sim;
  s.t_end = 1.0;
  s.integrator = IntegratorKind::rk4;
  s.step = 1e-3;
  long samples = 0;
  double last_t = -1;
  const ForceFunction tau = [](double t, CVecRef, CVecRef, VecRef out) {
    out.setZero();
    if (t > 0.5) out(3) = std::numeric_limits<double>::quiet_NaN();
  };
  const auto st = simulate(*sc.system, sc.q0, sc.qd0, tau, s,
                           [&](double t, CVecRef, CVecRef, const ForwardData&) {
                             ++samples;
                             last_t = t;
                             return true;
                           });
  EXPECT_EQ(st.status, RunStatus::non_finite);
  EXPECT_NE(st.message.find("t = 0.50"), std::string::npos) << st.message;
  EXPECT_LE(last_t, 0.5 + 1e-12);
  EXPECT_GE(samples, 50);
}

TEST(Diagnostics, InconsistentConstraintsStopTheRun) {
  // theta1 held at its initial value and, at the same time, pushed by 0.1 t²: consistent at the
  // position level at t = 0, contradictory at the acceleration level.
  std::string text = R"(ukdyn: 1
name: contradiction
subsystems:
  - {name: left, type: mobile_manipulator, coordinates: [dx1, dy1, delta1, theta1, theta2, theta3]}
constraints:
  - {type: coordinate, name: a, coordinate: theta1, value: initial}
  - {type: coordinate, name: b, coordinate: theta1, value: {type: polynomial, coefficients: [1.5707963267948966, 0, 0.1]}}
initial:
  q: [0, 0, 0, pi/2, -pi/3, 0]
simulation: {t_end: 1, sample_dt: 0.1}
)";
  const Scenario sc = load_scenario_text(text, "contradiction.yaml");
  const ForceFunction tau;
  const auto st = simulate(*sc.system, sc.q0, sc.qd0, tau, sc.sim, nullptr);
  EXPECT_EQ(st.status, RunStatus::inconsistent_constraints);
  EXPECT_EQ(st.t_reached, 0.0);
}

TEST(Assembly, RepairsAPerturbedStateAndKeepsHeldCoordinates) {
  const Scenario sc = load_scenario(kSource / "scenarios" / "paper_free.yaml");
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1e-2, 1e-2);
  Vec q = sc.q0;
  for (Index i = 0; i < q.size(); ++i) q(i) += u(rng);
  std::vector<bool> held(12, false);
  held[0] = held[1] = true;  // keep platform 1 where it is
  const Vec qd = Vec::Constant(12, 0.1);
  const AssemblyResult a = assemble(*sc.system, 0.0, q, qd, held);
  ASSERT_TRUE(a.success) << a.message;
  Vec phi(6), phid(6);
  position_residuals(*sc.system, 0.0, a.q, phi);
  velocity_residuals(*sc.system, 0.0, a.q, a.qd, phid);
  EXPECT_LE(phi.cwiseAbs().maxCoeff(), 1e-14);
  EXPECT_LE(phid.cwiseAbs().maxCoeff(), 1e-13);
  EXPECT_EQ(a.q(0), q(0));
  EXPECT_EQ(a.q(1), q(1));
  EXPECT_LE((a.q - q).norm(), 0.1);  // near the guess
}

TEST(Assembly, NamesTheConstraintsThatCannotBeMet) {
  const Scenario sc = load_scenario(kSource / "scenarios" / "paper_free.yaml");
  Vec q = sc.q0;
  q(5) = 0.3;  // theta3 off the closure's theta3 = 0 ...
  std::vector<bool> held(12, false);
  held[5] = true;  // ... and held there
  const AssemblyResult a = assemble(*sc.system, 0.0, q, sc.qd0, held);
  EXPECT_FALSE(a.success);
  ASSERT_EQ(a.unmet_rows.size(), 1u);
  EXPECT_EQ(sc.system->constraint_row_names()[static_cast<std::size_t>(a.unmet_rows[0])],
            "closure_load1");
}

}  // namespace
