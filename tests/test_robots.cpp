// The real arms of robots/ (the UR5e, the Franka Panda and the KUKA LBR iiwa 14 from their published
// parameters, robots/README.md) on the recursive tree algorithms (docs/tree-algorithms.md):
// - from their MJCF files, against MuJoCo's own mj_fullM and qfrc_bias on the same file (MuJoCo's
//   composite-rigid-body and recursive Newton–Euler algorithms, written independently of ukdyn's);
// - from their URDF files (read by urdfdom), against the MJCF twin: the same robot written twice,
//   equal up to MuJoCo's rounding of `fullinertia` into principal axes (robots/README.md).
#include <gtest/gtest.h>

#include <random>

#include "ukdyn/robot_files/mjcf.hpp"
#include "ukdyn/robot_files/urdf.hpp"
#include "ukdyn/symbolic/canonical.hpp"
#include "ukdyn/symbolic/chain_tree.hpp"
#include "ukdyn/tree/tree.hpp"

#ifdef UKDYN_TEST_HAVE_MUJOCO
#include <mujoco/mujoco.h>
#endif

namespace {

namespace sym = ukdyn::symbolic;
namespace tree = ukdyn::tree;
using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;

struct Robot {
  const char* name;
  int dof;
  double twin_tol;  // URDF against MJCF, relative (UrdfAndMjcfTwinsAgree)
};
// The UR5e's and the Panda's full tensors go through MuJoCo's principal axes (about 1e-7); the
// iiwa's are diagonal (diaginertia), so its twins agree to round-off.
const Robot kRobots[] = {{"ur5e", 6, 1e-6}, {"panda", 7, 1e-6}, {"iiwa14", 7, 1e-12}};

std::string robot_file(const Robot& r, const char* ext) {
  return std::string(UKDYN_SOURCE_DIR) + "/robots/" + r.name + "." + ext;
}

std::vector<std::string> coordinates(const Robot& r) {
  std::vector<std::string> c;
  for (int i = 1; i <= r.dof; ++i) c.push_back("q" + std::to_string(i));
  return c;
}

std::shared_ptr<const tree::TreeSubsystem> tree_of(sym::ChainDef& c) {
  sym::ChainTree t = sym::chain_tree(c);
  if (!t.model) throw ukdyn::Error("not a tree: " + t.reason);
  return tree::make_subsystem(std::move(*t.model));
}

#ifdef UKDYN_TEST_HAVE_MUJOCO
TEST(Robots, MjcfOnTheTreeMatchesMuJoCo) {
  for (const Robot& r : kRobots) {
    SCOPED_TRACE(r.name);
    const std::string file = robot_file(r, "xml");
    sym::ChainDef c(r.name, coordinates(r));
    sym::append_mjcf(c, file, /*gravity=*/true);
    const auto t = tree_of(c);
    ASSERT_EQ(t->dof(), r.dof);
    char err[1000] = "";
    mjModel* m = mj_loadXML(file.c_str(), nullptr, err, sizeof err);
    ASSERT_NE(m, nullptr) << err;
    mjData* d = mj_makeData(m);
    ASSERT_EQ(m->nv, r.dof);
    std::mt19937 rng(7u);
    std::uniform_real_distribution<double> u(-3.0, 3.0);
    double worst_M = 0.0, worst_b = 0.0;
    const Index n = r.dof;
    Mat M(n, n), Mmj(n, n);
    Vec Cqd(n), G(n), q(n), qd(n), bias(n);
    for (int k = 0; k < 100; ++k) {
      for (Index i = 0; i < n; ++i) {
        q[i] = u(rng);
        qd[i] = u(rng);
        d->qpos[i] = q[i];
        d->qvel[i] = qd[i];
      }
      mj_forward(m, d);
      std::vector<mjtNum> full(static_cast<std::size_t>(n * n));
      mj_fullM(m, full.data(), d->qM);
      for (Index i = 0; i < n; ++i) {
        bias[i] = d->qfrc_bias[i];
        for (Index j = 0; j < n; ++j) Mmj(i, j) = full[static_cast<std::size_t>(n * i + j)];
      }
      t->dynamics({}, q, qd, M, Cqd, G);
      worst_M = std::max(worst_M, (M - Mmj).norm() / Mmj.norm());
      worst_b = std::max(worst_b, (Cqd + G - bias).norm() / bias.norm());
    }
    mj_deleteData(d);
    mj_deleteModel(m);
    EXPECT_LE(worst_M, 1e-12);
    EXPECT_LE(worst_b, 1e-12);
    RecordProperty(std::string(r.name) + "_worst_M_rel", ::testing::PrintToString(worst_M));
    RecordProperty(std::string(r.name) + "_worst_bias_rel", ::testing::PrintToString(worst_b));
  }
}

// The frames' kinematics the numeric frame constraints use (TreeSubsystem::frame_state: the pose,
// and the twist Jacobian from ∂p/∂q and ∂R/∂q Rᵀ) against MuJoCo's xpos / xmat and mj_jac, for
// every body of both arms and a point offset in it, at 20 random states.
TEST(Robots, FrameJacobiansMatchMuJoCo) {
  for (const Robot& r : kRobots) {
    SCOPED_TRACE(r.name);
    const std::string file = robot_file(r, "xml");
    sym::ChainDef c(r.name, coordinates(r));
    sym::append_mjcf(c, file, /*gravity=*/true);
    const auto t = tree_of(c);
    char err[1000] = "";
    mjModel* m = mj_loadXML(file.c_str(), nullptr, err, sizeof err);
    ASSERT_NE(m, nullptr) << err;
    mjData* d = mj_makeData(m);
    const Index n = r.dof;
    std::mt19937 rng(9u);
    std::uniform_real_distribution<double> u(-3.0, 3.0);
    std::vector<double> dp(static_cast<std::size_t>(3 * n)), dR(static_cast<std::size_t>(9 * n));
    std::vector<mjtNum> jp(static_cast<std::size_t>(3 * n)), jr(static_cast<std::size_t>(3 * n));
    double worst = 0.0;
    int bodies = 0;
    for (int k = 0; k < 20; ++k) {
      Vec q(n), qd = Vec::Zero(n);
      for (Index i = 0; i < n; ++i) d->qpos[i] = q[i] = u(rng);
      mj_forward(m, d);
      for (int b = 1; b < m->nbody; ++b) {
        const int link = t->link_index(mj_id2name(m, mjOBJ_BODY, b));
        if (link == -2) continue;  // a body the tree holds as its root frame
        ++bodies;
        const Eigen::Vector3d off(0.03, -0.02, 0.05);
        tree::FrameState fs(dp.data(), dR.data(), n);
        t->frame_state(q, qd, link, Eigen::Matrix3d::Identity(), off, {}, fs);
        Eigen::Matrix3d Rm;
        for (int i = 0; i < 9; ++i) Rm(i / 3, i % 3) = d->xmat[9 * b + i];
        const Eigen::Vector3d pm = Eigen::Vector3d(d->xpos + 3 * b) + Rm * off;
        worst = std::max({worst, (fs.p - pm).norm(), (fs.R - Rm).norm()});
        mj_jac(m, d, jp.data(), jr.data(), pm.data(), b);
        for (Index j = 0; j < n; ++j) {
          Eigen::Matrix3d dRj;
          for (int i = 0; i < 9; ++i) dRj(i / 3, i % 3) = fs.dR(i, j);
          const Eigen::Matrix3d W = dRj * fs.R.transpose();  // [ω_j]×
          const Eigen::Vector3d w(W(2, 1), W(0, 2), W(1, 0));
          for (int i = 0; i < 3; ++i) {
            worst =
                std::max(worst, std::abs(fs.dp(i, j) - jp[static_cast<std::size_t>(i * n + j)]));
            worst = std::max(worst, std::abs(w(i) - jr[static_cast<std::size_t>(i * n + j)]));
          }
        }
      }
    }
    mj_deleteData(d);
    mj_deleteModel(m);
    EXPECT_GT(bodies, 20 * (r.dof - 1));
    EXPECT_LE(worst, 1e-13);
    RecordProperty(std::string(r.name) + "_frame_worst", ::testing::PrintToString(worst));
  }
}
#endif

TEST(Robots, UrdfAndMjcfTwinsAgree) {
  if (!sym::urdf_supported() || !sym::mjcf_supported()) GTEST_SKIP() << "needs urdfdom and MuJoCo";
  for (const Robot& r : kRobots) {
    SCOPED_TRACE(r.name);
    sym::ChainDef cu(r.name, coordinates(r)), cm(r.name, coordinates(r));
    sym::append_urdf(cu, robot_file(r, "urdf"));
    cu.gravity = {0, 0, sym::exact_rational(-9.81)};
    sym::append_mjcf(cm, robot_file(r, "xml"), /*gravity=*/true);
    const auto tu = tree_of(cu), tm = tree_of(cm);
    std::mt19937 rng(3u);
    std::uniform_real_distribution<double> u(-3.0, 3.0);
    const Index n = r.dof;
    double worst = 0.0;
    for (int k = 0; k < 50; ++k) {
      Vec q(n), qd(n);
      for (Index i = 0; i < n; ++i) {
        q[i] = u(rng);
        qd[i] = u(rng);
      }
      Mat Mu(n, n), Mm(n, n);
      Vec cu_(n), cm_(n), Gu(n), Gm(n);
      tu->dynamics({}, q, qd, Mu, cu_, Gu);
      tm->dynamics({}, q, qd, Mm, cm_, Gm);
      worst = std::max(
          {worst, (Mu - Mm).norm() / Mm.norm(), (cu_ + Gu - cm_ - Gm).norm() / (cm_ + Gm).norm()});
    }
    // MuJoCo turns fullinertia into principal moments and axes to about 1e-7 relative
    // (robots/README.md); the kinematics, masses and centres of mass are the same numbers.
    EXPECT_LE(worst, r.twin_tol);
    RecordProperty(std::string(r.name) + "_urdf_vs_mjcf", ::testing::PrintToString(worst));
  }
}

}  // namespace
