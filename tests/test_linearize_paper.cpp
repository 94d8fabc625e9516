// Exact derivatives of the paper's closed-form robot (MobileManipulator) and its cooperative
// constraints (closure, cut-point trajectory): each component's dual-number tangent against central
// differences of its own double evaluation, and linearize() of scenarios/paper.yaml and
// paper_free.yaml against central differences of forward() and against the definitions twin
// (scenarios/paper_generic.yaml, the same robot and coordinates).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <functional>
#include <random>

#include "helpers.hpp"
#include "ukdyn/model/linearize.hpp"
#include "ukdyn/paper_robot/cooperative_constraints.hpp"
#include "ukdyn/paper_robot/mobile_manipulator.hpp"
#ifdef UKDYN_HAVE_IO
#include "ukdyn/scenario/scenario.hpp"
#endif

namespace {

using namespace ukdyn;
using uktest::random_vec;
using uktest::uniform;

constexpr int kStates = 8;
constexpr double kComponentTol = 1e-7;

// max |a − b| / max(1, max |b|) (a floor of 1: ∂q̈/∂τ of the fully prescribed paper.yaml is 0).
double rel_to(const Eigen::Ref<const Mat>& a, const Eigen::Ref<const Mat>& b) {
  return (a - b).cwiseAbs().maxCoeff() / std::max(1.0, b.cwiseAbs().maxCoeff());
}

// The largest error a test saw, recorded as a property of the test (--gtest_output=xml:FILE shows
// it): the measured numbers of docs/derivatives.md.
struct WorstError {
  const char* key;
  double worst = 0.0;
  void see(double e) { worst = std::max(worst, e); }
  ~WorstError() {
    char text[32];
    std::snprintf(text, sizeof text, "%.2e", worst);
    ::testing::Test::RecordProperty(key, text);
  }
};

// The derivative at s = 0 of f(x + s dx) by central differences, Richardson-extrapolated (error
// O(h⁴), h = 1e-3): the reference the exact tangents are checked against.
Vec directional_difference(const std::function<Vec(double)>& f) {
  auto central = [&](double h) { return Vec((f(h) - f(-h)) / (2 * h)); };
  return (4 * central(5e-4) - central(1e-3)) / 3;
}

// A state of the two-arm system: each arm random (helpers' ranges), the second offset along x.
void random_state(std::mt19937_64& rng, Vec& q, Vec& qd) {
  q.resize(12);
  qd.resize(12);
  q << uktest::random_q(rng), uktest::random_q(rng);
  qd << uktest::random_qd(rng), uktest::random_qd(rng);
}

// ID(q, q̇) = M q̈ + C q̇ + G at fixed q̈ through the arm's double evaluation.
Vec inverse_dynamics(const MobileManipulator& arm, const Vec& q, const Vec& qd, const Vec& qdd) {
  Mat M(6, 6);
  Vec Cqd(6), G(6);
  arm.mass({}, q, M);
  arm.coriolis_times_qd({}, q, qd, Cqd);
  arm.gravity({}, q, G);
  return M * qdd + Cqd + G;
}

TEST(PaperDerivatives, ArmInverseDynamicsTangentMatchesDifferences) {
  std::mt19937_64 rng(7102);
  WorstError worst{"max_rel_err_vs_differences"};
  for (const auto& p : {MobileManipulatorParams{}, uktest::random_params(rng)}) {
    const auto arm = uktest::make_arm(1, p);
    ASSERT_TRUE(arm->has_derivatives());
    for (int s = 0; s < kStates; ++s) {
      const Vec q = uktest::random_q(rng), qd = uktest::random_qd(rng);
      const Vec qdd = random_vec(rng, 6, -3, 3), dq = random_vec(rng, 6, -1, 1),
                dqd = random_vec(rng, 6, -1, 1);
      Vec exact(6);
      ASSERT_TRUE(arm->inverse_dynamics_tangent({}, q, qd, qdd, dq, dqd, exact));
      const Vec fd = directional_difference(
          [&](double h) { return inverse_dynamics(*arm, q + h * dq, qd + h * dqd, qdd); });
      worst.see(rel_to(exact, fd));
      EXPECT_LE(rel_to(exact, fd), kComponentTol) << "state " << s;
      // Linear in the direction: the columns e_j give the same as their combination.
      Vec sum = Vec::Zero(6), col(6);
      for (Index j = 0; j < 6; ++j) {
        Vec e = Vec::Zero(6);
        e(j) = 1.0;
        ASSERT_TRUE(arm->inverse_dynamics_tangent({}, q, qd, qdd, e, Vec::Zero(6), col));
        sum += dq(j) * col;
        ASSERT_TRUE(arm->inverse_dynamics_tangent({}, q, qd, qdd, Vec::Zero(6), e, col));
        sum += dqd(j) * col;
      }
      EXPECT_LE(rel_to(sum, exact), 1e-13) << "state " << s;
    }
  }
}

// A constraint's residual A q̈ − b and force Aᵀλ through evaluate(), at fixed q̈, λ, t.
struct ResidualAndForce {
  Vec residual, force;
};
ResidualAndForce residual_and_force(const Constraint& c, double t, const Vec& q, const Vec& qd,
                                    const Vec& qdd, const Vec& lambda) {
  Mat A(c.rows(), q.size());
  Vec b(c.rows());
  c.evaluate({t}, q, qd, A, b);
  return {A * qdd - b, A.transpose() * lambda};
}

void check_constraint_tangent(const Constraint& c, std::mt19937_64& rng, double t, const Vec& q,
                              const Vec& qd, WorstError& worst) {
  ASSERT_TRUE(c.has_derivatives());
  const Index n = q.size(), m = c.rows();
  const Vec qdd = random_vec(rng, n, -3, 3), lambda = random_vec(rng, m, -20, 20);
  const Vec dq = random_vec(rng, n, -1, 1), dqd = random_vec(rng, n, -1, 1);
  Vec d_res(m), d_force = Vec::Zero(n);
  ASSERT_TRUE(c.tangent({t}, q, qd, qdd, lambda, dq, dqd, d_res, d_force));
  const Vec fd_res = directional_difference([&](double h) {
    return residual_and_force(c, t, q + h * dq, qd + h * dqd, qdd, lambda).residual;
  });
  const Vec fd_force = directional_difference([&](double h) {
    return residual_and_force(c, t, q + h * dq, qd + h * dqd, qdd, lambda).force;
  });
  worst.see(rel_to(d_res, fd_res));
  worst.see(rel_to(d_force, fd_force));
  EXPECT_LE(rel_to(d_res, fd_res), kComponentTol);
  EXPECT_LE(rel_to(d_force, fd_force), kComponentTol);
  // d_force accumulates (the contract): a second call adds the same again.
  Vec twice = d_force;
  ASSERT_TRUE(c.tangent({t}, q, qd, qdd, lambda, dq, dqd, d_res, twice));
  EXPECT_LE(rel_to(twice, 2 * d_force), 1e-15);
}

TEST(PaperDerivatives, ClosureTangentMatchesDifferences) {
  std::mt19937_64 rng(7103);
  uktest::TwoArms arms({}, uktest::random_params(rng));
  ClosureConstraint::Options o;
  o.dz = 0.1;
  const auto closure = arms.add_closure(o);
  WorstError worst{"max_rel_err_vs_differences"};
  for (int s = 0; s < kStates; ++s) {
    Vec q, qd;
    random_state(rng, q, qd);
    SCOPED_TRACE("state " + std::to_string(s));
    check_constraint_tangent(*closure, rng, 0.0, q, qd, worst);
  }
}

TEST(PaperDerivatives, TrajectoryTangentMatchesDifferences) {
  std::mt19937_64 rng(7104);
  uktest::TwoArms arms;
  const Vec q0 = uktest::paper_q0();
  arms.add_paper_trajectory(q0);
  // All three axes (the paper's), and y alone on the second arm (a subset of the rows).
  const auto& all = *arms.system->constraints()[0];
  std::array<std::optional<TimeFunction>, 3> y_only{
      std::nullopt, TimeFunction::make_cosine(0.2, 0.3, 2.0), std::nullopt};
  const CutPointTrajectory y(arms.right, 6, y_only, Vec3(0.1, 0.2, 0.3), "y");
  WorstError worst{"max_rel_err_vs_differences"};
  for (int s = 0; s < kStates; ++s) {
    Vec q, qd;
    random_state(rng, q, qd);
    const double t = uniform(rng, 0.0, 4.0);  // b depends on t; the tangent is at fixed t
    SCOPED_TRACE("state " + std::to_string(s));
    check_constraint_tangent(all, rng, t, q, qd, worst);
    check_constraint_tangent(y, rng, t, q, qd, worst);
  }
}

TEST(PaperDerivatives, ClosedFormSystemsAreAccepted) {
  uktest::TwoArms arms;
  arms.add_closure();
  arms.add_paper_trajectory(uktest::paper_q0());
  EXPECT_TRUE(components_without_derivatives(*arms.system).empty());
}

#ifdef UKDYN_HAVE_IO
const std::string kDir = std::string(UKDYN_SOURCE_DIR) + "/scenarios/";

// ∂q̈/∂x_j (x = q, q̇ or τ: which = 0, 1, 2) by central differences of forward(),
// Richardson-extrapolated, with a step scaled to the column's value.
Vec forward_difference_column(const System& sys, double t, const Vec& q, const Vec& qd,
                              const Vec& tau, int which, Index j) {
  ForwardData d(sys);
  const Vec* x0[3] = {&q, &qd, &tau};
  const double scale = std::max(1.0, std::abs((*x0[which])(j)));
  return directional_difference([&](double h) {
    Vec x[3] = {q, qd, tau};
    x[which](j) += h * scale;
    forward(sys, d, t, x[0], x[1], x[2]);
    return Vec(d.qdd / scale);
  });
}

void check_against_forward(const System& sys, double t, const Vec& q, const Vec& qd, const Vec& tau,
                           WorstError& worst) {
  const Linearization lin = linearize(sys, t, q, qd, tau);
  EXPECT_TRUE(lin.trusted) << lin.message;
  EXPECT_LE(lin.kkt_agreement, 1e-10);
  const Index n = sys.dof();
  for (int which = 0; which < 3; ++which) {
    const Mat& exact = which == 0 ? lin.dqdd_dq : which == 1 ? lin.dqdd_dqd : lin.dqdd_dtau;
    for (Index j = 0; j < n; ++j) {
      const Vec fd = forward_difference_column(sys, t, q, qd, tau, which, j);
      worst.see(rel_to(exact.col(j), fd));
      EXPECT_LE(rel_to(exact.col(j), fd), 1e-6) << "which " << which << " column " << j;
    }
  }
}

Vec some_tau(Index n) {
  Vec tau(n);
  for (Index i = 0; i < n; ++i) tau(i) = 0.3 * std::sin(1.7 * static_cast<double>(i) + 0.4);
  return tau;
}

// The initial state (at rest) and a moving state near it; t = 0.7 s is inside the trajectory's
// motion. Off the constraint manifold the KKT solution is still defined (A has full row rank).
TEST(PaperDerivatives, LinearizeScenariosMatchForwardDifferences) {
  for (const char* name : {"paper.yaml", "paper_free.yaml"}) {
    SCOPED_TRACE(name);
    WorstError worst{name};
    const Scenario sc = load_scenario(kDir + name);
    ASSERT_TRUE(components_without_derivatives(*sc.system).empty());
    const Index n = sc.system->dof();
    const Vec tau = some_tau(n);
    check_against_forward(*sc.system, 0.7, sc.q0, sc.qd0, tau, worst);
    std::mt19937_64 rng(7105);
    const Vec q = sc.q0 + random_vec(rng, n, -0.05, 0.05);
    const Vec qd = random_vec(rng, n, -0.5, 0.5);
    check_against_forward(*sc.system, 0.7, q, qd, tau, worst);
  }
}

// paper_generic.yaml is the same robot and constraints written as definitions (same coordinate
// order, same parameters): its tape derivatives and the closed form's dual numbers must agree.
TEST(PaperDerivatives, ClosedFormMatchesDefinitionsTwin) {
  const Scenario closed = load_scenario(kDir + "paper.yaml");
  const Scenario generic = load_scenario(kDir + "paper_generic.yaml");
  const Index n = closed.system->dof();
  ASSERT_EQ(generic.system->dof(), n);
  ASSERT_EQ(closed.system->coordinate_names(), generic.system->coordinate_names());
  std::mt19937_64 rng(7106);
  const Vec tau = some_tau(n);
  const Vec q = closed.q0 + random_vec(rng, n, -0.05, 0.05);
  const Vec qd = random_vec(rng, n, -0.5, 0.5);
  WorstError worst{"max_rel_difference"};
  for (const auto& [qs, qds] : {std::pair{closed.q0, closed.qd0}, std::pair{q, qd}}) {
    const Linearization a = linearize(*closed.system, 0.7, qs, qds, tau);
    const Linearization b = linearize(*generic.system, 0.7, qs, qds, tau);
    EXPECT_TRUE(a.trusted) << a.message;
    EXPECT_TRUE(b.trusted) << b.message;
    const std::pair<const Mat*, const Mat*> pairs[] = {
        {&a.dqdd_dq, &b.dqdd_dq}, {&a.dqdd_dqd, &b.dqdd_dqd}, {&a.dqdd_dtau, &b.dqdd_dtau},
        {&a.dQc_dq, &b.dQc_dq},   {&a.dQc_dqd, &b.dQc_dqd},   {&a.dQc_dtau, &b.dQc_dtau}};
    worst.see(rel_to(a.qdd, b.qdd));
    EXPECT_LE(rel_to(a.qdd, b.qdd), 1e-9);
    for (const auto& [x, y] : pairs) {
      worst.see(rel_to(*x, *y));
      EXPECT_LE(rel_to(*x, *y), 1e-9);
    }
  }
}
#endif  // UKDYN_HAVE_IO

}  // namespace
