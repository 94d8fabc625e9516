// Exact derivatives on the shipped scenarios (docs/derivatives.md): the paper's system written three
// ways — serial chains on the tree algorithms, the same chains derived symbolically into tapes, and
// the hand-written definitions with the same exact inertias — must give the same ∂q̈ and ∂Qc
// (trees against tapes), and they must match Richardson-extrapolated central differences of
// forward().
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <filesystem>

#include "ukdyn/model/linearize.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/tree/tree.hpp"

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

namespace {

// The first tree subsystem of a scenario (a URDF arm on its platform).
std::shared_ptr<const tree::TreeSubsystem> first_tree(const System& sys) {
  for (const auto& s : sys.subsystems()) {
    if (auto t = std::dynamic_pointer_cast<const tree::TreeSubsystem>(s)) return t;
  }
  return nullptr;
}

// Everything frame_state_tangent returns, from frame_state alone: p, R, ṗ, Ṙ, the acceleration
// at q̈ (frame_state's at q̈ = 0 plus Σ_c ∂x/∂q_c q̈_c) and the columns, as one vector.
Vec frame_quantities(const tree::TreeSubsystem& tr, const Vec& q, const Vec& qd, const Vec& qdd,
                     int link, const Eigen::Matrix3d& Ro, const Eigen::Vector3d& po) {
  const Index n = tr.dof();
  std::vector<double> buf(static_cast<std::size_t>(12 * n));
  tree::FrameState s(buf.data(), buf.data() + 3 * n, n);
  tr.frame_state(q, qd, link, Ro, po, {}, s);
  const Eigen::Vector3d pdd = s.pdd + s.dp * qdd;
  Eigen::Matrix3d Rdd = s.Rdd;
  for (Index c = 0; c < n; ++c)
    for (int r = 0; r < 9; ++r) Rdd(r / 3, r % 3) += s.dR(r, c) * qdd(c);
  Vec out(36 + 12 * n);
  out << s.p, s.R.reshaped(), s.pd, s.Rd.reshaped(), pdd, Rdd.reshaped(), s.dp.reshaped(),
      s.dR.reshaped();
  return out;
}

Vec tangent_quantities(const tree::FrameState& s) {
  const Index n = s.dp.cols();
  Vec out(36 + 12 * n);
  out << s.p, s.R.reshaped(), s.pd, s.Rd.reshaped(), s.pdd, s.Rdd.reshaped(), s.dp.reshaped(),
      s.dR.reshaped();
  return out;
}

}  // namespace

// frame_state_tangent (dual numbers through the recursive pass) against Richardson-extrapolated
// central differences of frame_state (doubles), for the flange of a real arm on its platform, at
// random states and directions.
TEST(DerivativeScenarios, TreeFrameTangentMatchesDifferencesOfFrameState) {
  const Scenario sc = load_scenario(kSource / "scenarios" / "two_ur5e_load.yaml");
  const auto tr = first_tree(*sc.system);
  ASSERT_TRUE(tr);
  const Index n = tr->dof();
  const int link = tr->link_index("tool0");
  ASSERT_GE(link, 0);
  const Eigen::Matrix3d Ro = Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized()).matrix();
  const Eigen::Vector3d po(0.05, -0.02, 0.1);
  std::srand(7);
  for (int trial = 0; trial < 5; ++trial) {
    const Vec q = Vec::Random(n), qd = Vec::Random(n), qdd = Vec::Random(n), dq = Vec::Random(n),
              dqd = Vec::Random(n);
    std::vector<double> vb(static_cast<std::size_t>(12 * n)), tb(vb.size());
    tree::FrameState v(vb.data(), vb.data() + 3 * n, n), t(tb.data(), tb.data() + 3 * n, n);
    tr->frame_state_tangent(q, qd, qdd, dq, dqd, link, Ro, po, {}, v, t);
    const Vec value = frame_quantities(*tr, q, qd, qdd, link, Ro, po);
    EXPECT_LE((tangent_quantities(v) - value).cwiseAbs().maxCoeff(), 1e-13);
    auto central = [&](double h) {
      return Vec((frame_quantities(*tr, q + h * dq, qd + h * dqd, qdd, link, Ro, po) -
                  frame_quantities(*tr, q - h * dq, qd - h * dqd, qdd, link, Ro, po)) /
                 (2 * h));
    };
    const Vec d = (4 * central(5e-4) - central(1e-3)) / 3;
    EXPECT_LE((tangent_quantities(t) - d).cwiseAbs().maxCoeff(),
              1e-7 * (1.0 + d.cwiseAbs().maxCoeff()))
        << "trial " << trial;
  }
}

// Real arms welded to a free-body load (numeric frame constraints on trees, the quaternion load):
// exact derivatives against differences of forward() at a state moving along the constraints.
TEST(DerivativeScenarios, ArmsWeldedToALoadMatchDifferencesOfForward) {
  for (const char* name : {"two_ur5e_load.yaml", "four_panda_plate.yaml"}) {
    SCOPED_TRACE(name);
    const Scenario sc = load_scenario(kSource / "scenarios" / name);
    ASSERT_TRUE(components_without_derivatives(*sc.system).empty());
    const Index n = sc.system->dof();
    const Vec tau = some_tau(n);
    // A velocity along the constraints (in the null space of A at q0), so that the terms of q̇
    // are exercised.
    ForwardData fd(*sc.system);
    forward(*sc.system, fd, 0.0, sc.q0, sc.qd0, tau);
    Eigen::JacobiSVD<Mat> svd(fd.A, Eigen::ComputeFullV);
    Index rank = 0;
    while (rank < svd.singularValues().size() && svd.singularValues()(rank) > 1e-9) ++rank;
    Vec qd = sc.qd0;
    for (Index k = rank; k < n; ++k)
      qd += 0.3 * std::cos(1.3 * static_cast<double>(k)) * svd.matrixV().col(k);
    const Linearization l = linearize(*sc.system, 0.0, sc.q0, qd, tau);
    EXPECT_TRUE(l.trusted) << l.message;
    EXPECT_LE(l.kkt_agreement, 1e-9);
    for (int which = 0; which < 3; ++which) {
      const Mat& exact = which == 0 ? l.dqdd_dq : which == 1 ? l.dqdd_dqd : l.dqdd_dtau;
      for (Index j = 0; j < n; ++j) {
        const Vec d = difference_column(*sc.system, 0.0, sc.q0, qd, tau, which, j);
        EXPECT_LE((exact.col(j) - d).cwiseAbs().maxCoeff(), 1e-6 * (1.0 + d.cwiseAbs().maxCoeff()))
            << "which " << which << " column " << j;
      }
    }
  }
}
