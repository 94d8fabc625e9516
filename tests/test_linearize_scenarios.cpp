// Exact derivatives on the shipped scenarios (docs/derivatives.md): the paper's system written three
// ways — serial chains on the tree algorithms, the same chains derived symbolically into tapes, and
// the hand-written definitions with the same exact inertias — must give the same ∂q̈ and ∂Qc
// (trees against tapes), and they must match Richardson-extrapolated central differences of
// forward().
#include <gtest/gtest.h>

#include <filesystem>

#include "ukdyn/model/linearize.hpp"
#include "ukdyn/scenario/scenario.hpp"

namespace {

using namespace ukdyn;
const std::filesystem::path kSource = UKDYN_SOURCE_DIR;

double rel(const Mat& a, const Mat& b) {
  return (a - b).cwiseAbs().maxCoeff() / (1.0 + b.cwiseAbs().maxCoeff());
}

// A state on the constraints (the scenario's initial one) with some velocity along them: q̇ of a
// short free run is not needed; the derivatives are taken at (q0, q̇0) with a nonzero τ.
Vec some_tau(Index n) {
  Vec tau(n);
  for (Index i = 0; i < n; ++i) tau(i) = 0.3 * std::sin(1.7 * static_cast<double>(i) + 0.4);
  return tau;
}

// ∂q̈/∂q_j by central differences of forward(), Richardson-extrapolated.
Vec difference_column(const System& sys, double t, const Vec& q, const Vec& qd, const Vec& tau,
                      int which, Index j) {
  ForwardData d(sys);
  auto central = [&](double h) {
    Vec x[3] = {q, qd, tau}, y[3] = {q, qd, tau};
    x[which](j) += h;
    y[which](j) -= h;
    forward(sys, d, t, x[0], x[1], x[2]);
    const Vec p = d.qdd;
    forward(sys, d, t, y[0], y[1], y[2]);
    return Vec((p - d.qdd) / (2 * h));
  };
  return (4 * central(5e-4) - central(1e-3)) / 3;
}

}  // namespace

TEST(DerivativeScenarios, PaperTreesTapesAndDefinitionsAgree) {
  const Scenario trees = load_scenario(kSource / "scenarios" / "paper_chain.yaml");
  LoadOptions symbolic;
  symbolic.symbolic_chains = true;
  const Scenario tapes = load_scenario(kSource / "scenarios" / "paper_chain.yaml", symbolic);
  const Scenario defs = load_scenario(kSource / "scenarios" / "paper_generic_exact_inertia.yaml");
  const Index n = trees.system->dof();
  ASSERT_EQ(tapes.system->dof(), n);
  ASSERT_EQ(defs.system->dof(), n);
  const Vec tau = some_tau(n);
  const double t = 0.7;  // inside the trajectory's motion
  const Linearization a = linearize(*trees.system, t, trees.q0, trees.qd0, tau);
  const Linearization b = linearize(*tapes.system, t, trees.q0, trees.qd0, tau);
  const Linearization c = linearize(*defs.system, t, trees.q0, trees.qd0, tau);
  for (const Linearization* l : {&a, &b, &c}) {
    EXPECT_TRUE(l->trusted) << l->message;
    EXPECT_LE(l->kkt_agreement, 1e-10);
  }
  for (const Linearization* l : {&b, &c}) {
    EXPECT_LE(rel(l->dqdd_dq, a.dqdd_dq), 1e-9);
    EXPECT_LE(rel(l->dqdd_dqd, a.dqdd_dqd), 1e-9);
    EXPECT_LE(rel(l->dqdd_dtau, a.dqdd_dtau), 1e-9);
    EXPECT_LE(rel(l->dQc_dq, a.dQc_dq), 1e-9);
    EXPECT_LE(rel(l->dQc_dqd, a.dQc_dqd), 1e-9);
  }
  // And against differences of the trees' forward().
  for (int which = 0; which < 3; ++which) {
    const Mat& exact = which == 0 ? a.dqdd_dq : which == 1 ? a.dqdd_dqd : a.dqdd_dtau;
    for (Index j = 0; j < n; ++j) {
      const Vec d = difference_column(*trees.system, t, trees.q0, trees.qd0, tau, which, j);
      EXPECT_LE((exact.col(j) - d).cwiseAbs().maxCoeff(), 1e-6 * (1.0 + d.cwiseAbs().maxCoeff()))
          << "which " << which << " column " << j;
    }
  }
}
