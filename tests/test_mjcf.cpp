// MJCF read with MuJoCo's own parser (ukdyn/robot_files/mjcf.hpp) into a chain, derived by ukdyn:
// its M and C q̇ + G against MuJoCo's own mj_fullM and qfrc_bias (both exact there: MuJoCo's
// recursive Newton–Euler and composite-rigid-body algorithms) at 100 random states.
#include <gtest/gtest.h>

#include <random>

#include "ukdyn/robot_files/mjcf.hpp"
#include "ukdyn/symbolic/chain.hpp"
#include "ukdyn/symbolic/definitions.hpp"

#ifdef UKDYN_TEST_HAVE_MUJOCO
#include <mujoco/mujoco.h>
#endif

namespace {

namespace sym = ukdyn::symbolic;
using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;

const std::string kFile = std::string(UKDYN_SOURCE_DIR) + "/tests/mjcf/open_chain.xml";

TEST(Mjcf, WithoutMuJoCoTheErrorSaysSo) {
  if (sym::mjcf_supported()) GTEST_SKIP() << "built with MuJoCo";
  sym::ChainDef c("m", {"a"});
  try {
    sym::append_mjcf(c, kFile);
    FAIL() << "no error";
  } catch (const sym::DefinitionError& e) {
    EXPECT_NE(std::string(e.what()).find("without MuJoCo"), std::string::npos) << e.what();
  }
}

#ifdef UKDYN_TEST_HAVE_MUJOCO
TEST(Mjcf, MassMatrixAndBiasForcesMatchMuJoCo) {
  ASSERT_TRUE(sym::mjcf_supported());
  const std::vector<std::string> q = {"x", "h1", "h2", "s2", "h3", "sw"};
  sym::ChainDef c("open_chain", q);
  sym::append_mjcf(c, kFile, /*gravity=*/true);
  const auto sub = sym::make_subsystem(sym::build_chain(c).def);
  ASSERT_EQ(sub->dof(), 6);

  char err[1000] = "";
  mjModel* m = mj_loadXML(kFile.c_str(), nullptr, err, sizeof err);
  ASSERT_NE(m, nullptr) << err;
  mjData* d = mj_makeData(m);
  ASSERT_EQ(m->nv, 6);
  std::mt19937 rng(11u);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  double worst_M = 0.0, worst_b = 0.0;
  Mat M(6, 6), Mmj(6, 6);
  Vec Cqd(6), G(6);
  for (int k = 0; k < 100; ++k) {
    Vec qv(6), qd(6);
    for (Index i = 0; i < 6; ++i) {
      qv[i] = 2.0 * u(rng);
      qd[i] = 2.0 * u(rng);
    }
    for (int i = 0; i < 6; ++i) {
      d->qpos[i] = qv[i];
      d->qvel[i] = qd[i];
    }
    mj_forward(m, d);
    std::vector<mjtNum> full(36);
    mj_fullM(m, full.data(), d->qM);
    for (int i = 0; i < 6; ++i)
      for (int j = 0; j < 6; ++j) Mmj(i, j) = full[static_cast<std::size_t>(6 * i + j)];
    sub->mass({}, qv, M);
    sub->coriolis_times_qd({}, qv, qd, Cqd);
    sub->gravity({}, qv, G);
    Vec bias(6);
    for (int i = 0; i < 6; ++i) bias[i] = d->qfrc_bias[i];
    worst_M = std::max(worst_M, (M - Mmj).norm() / Mmj.norm());
    worst_b = std::max(worst_b, (Cqd + G - bias).norm() / std::max(bias.norm(), 1e-300));
  }
  mj_deleteData(d);
  mj_deleteModel(m);
  EXPECT_LE(worst_M, 1e-10);
  EXPECT_LE(worst_b, 1e-10);
  RecordProperty("worst_M_rel", ::testing::PrintToString(worst_M));
  RecordProperty("worst_bias_rel", ::testing::PrintToString(worst_b));
}

// Free and ball joints: ukdyn's coordinates are MuJoCo's qpos (quaternions w, x, y, z), MuJoCo's
// velocities qvel (free: world linear velocity, body angular velocity; ball: body angular
// velocity). With q̇ = H(q) v (H: identity on positions and hinges, ½ q ⊗ (0, ω) on a quaternion),
// MuJoCo's M_v = Hᵀ M H and bias_v = Hᵀ (M Ḣ v + C q̇ + G) (Ḣ v = ½ q̇ ⊗ (0, ω)). Hᵀ removes
// the radial (off |q| = 1) parts of ukdyn's quaternion-coordinate M and C, which the unit-norm
// rows absorb.
TEST(Mjcf, FreeAndBallJointsMatchMuJoCo) {
  ASSERT_TRUE(sym::mjcf_supported());
  const std::string file = std::string(UKDYN_SOURCE_DIR) + "/tests/mjcf/ball_free.xml";
  const std::vector<std::string> names = {"x",  "y",  "z",  "qw", "qx", "qy", "qz", "sw",
                                          "sx", "sy", "sz", "pw", "px", "py", "pz", "el"};
  sym::ChainDef c("ball_free", names);
  sym::append_mjcf(c, file, /*gravity=*/true);
  const auto model = sym::build_chain(c);
  ASSERT_EQ(model.quaternions.size(), 3U);
  const auto sub = sym::make_subsystem(model.def);
  char err[1000] = "";
  mjModel* m = mj_loadXML(file.c_str(), nullptr, err, sizeof err);
  ASSERT_NE(m, nullptr) << err;
  mjData* d = mj_makeData(m);
  const int nq = m->nq, nv = m->nv;
  ASSERT_EQ(nq, 16);
  ASSERT_EQ(nv, 13);
  // Quaternion blocks: (qpos address, qvel address).
  std::vector<std::pair<int, int>> quats;
  for (int j = 0; j < m->njnt; ++j) {
    if (m->jnt_type[j] == mjJNT_FREE)
      quats.emplace_back(m->jnt_qposadr[j] + 3, m->jnt_dofadr[j] + 3);
    if (m->jnt_type[j] == mjJNT_BALL) quats.emplace_back(m->jnt_qposadr[j], m->jnt_dofadr[j]);
  }
  auto qmat = [](const Vec& q4) {  // ½ q ⊗ (0, ω) = Q ω
    Mat Q(4, 3);
    Q << -q4(1), -q4(2), -q4(3), q4(0), -q4(3), q4(2), q4(3), q4(0), -q4(1), -q4(2), q4(1), q4(0);
    return Mat(0.5 * Q);
  };
  std::mt19937 rng(13u);
  std::normal_distribution<double> nd;
  double worst_M = 0.0, worst_b = 0.0;
  Mat M(nq, nq), Mmj(nv, nv);
  Vec Cqd(nq), G(nq);
  for (int k = 0; k < 100; ++k) {
    Vec qv(nq), v(nv);
    for (int i = 0; i < nq; ++i) qv[i] = nd(rng);
    for (int i = 0; i < nv; ++i) v[i] = nd(rng);
    for (const auto& [qa, va] : quats) qv.segment(qa, 4).normalize();
    // H and Ḣ v: hinges and the free joint's position map one to one (qpos and qvel in order).
    Mat H = Mat::Zero(nq, nv);
    Vec Hdv = Vec::Zero(nq);
    {
      int qi = 0, vi = 0;
      for (int j = 0; j < m->njnt; ++j) {
        const int t = m->jnt_type[j];
        if (t == mjJNT_FREE) {
          H.block(qi, vi, 3, 3).setIdentity();
          qi += 3;
          vi += 3;
        }
        if (t == mjJNT_FREE || t == mjJNT_BALL) {
          H.block(qi, vi, 4, 3) = qmat(qv.segment(qi, 4));
          qi += 4;
          vi += 3;
        } else if (t == mjJNT_HINGE || t == mjJNT_SLIDE) {
          H(qi++, vi++) = 1.0;
        }
      }
    }
    const Vec qd = H * v;
    for (const auto& [qa, va] : quats)
      Hdv.segment(qa, 4) = qmat(qd.segment(qa, 4)) * v.segment(va, 3);
    for (int i = 0; i < nq; ++i) d->qpos[i] = qv[i];
    for (int i = 0; i < nv; ++i) d->qvel[i] = v[i];
    mj_forward(m, d);
    std::vector<mjtNum> full(static_cast<std::size_t>(nv * nv));
    mj_fullM(m, full.data(), d->qM);
    for (int i = 0; i < nv; ++i)
      for (int j = 0; j < nv; ++j) Mmj(i, j) = full[static_cast<std::size_t>(nv * i + j)];
    sub->mass({}, qv, M);
    sub->coriolis_times_qd({}, qv, qd, Cqd);
    sub->gravity({}, qv, G);
    Vec bias(nv);
    for (int i = 0; i < nv; ++i) bias[i] = d->qfrc_bias[i];
    const Mat Mv = H.transpose() * M * H;
    const Vec bv = H.transpose() * (M * Hdv + Cqd + G);
    worst_M = std::max(worst_M, (Mv - Mmj).norm() / Mmj.norm());
    worst_b = std::max(worst_b, (bv - bias).norm() / std::max(bias.norm(), 1e-300));
  }
  mj_deleteData(d);
  mj_deleteModel(m);
  EXPECT_LE(worst_M, 1e-10);
  EXPECT_LE(worst_b, 1e-10);
  std::printf("MJCF free + ball + hinge vs MuJoCo (100 states): M %.3g, bias %.3g (relative)\n",
              worst_M, worst_b);
}

TEST(Mjcf, UnsupportedJointsAndCountsAreNamed) {
  sym::ChainDef c("m", {"a", "b"});
  try {
    sym::append_mjcf(c, kFile);
    FAIL() << "no error";
  } catch (const sym::DefinitionError& e) {
    EXPECT_NE(std::string(e.what()).find("6 qpos coordinates"), std::string::npos) << e.what();
  }
  sym::ChainDef c2("m", {"a"});
  try {
    sym::append_mjcf(c2, kFile + ".missing");
    FAIL() << "no error";
  } catch (const sym::DefinitionError& e) {
    EXPECT_NE(std::string(e.what()).find("open_chain.xml.missing: no such MJCF file"),
              std::string::npos)
        << e.what();
  }
}
#endif

}  // namespace
