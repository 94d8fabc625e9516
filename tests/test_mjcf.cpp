// MJCF read with MuJoCo's own parser (ukdyn/symbolic/mjcf.hpp) into a chain, derived by ukdyn:
// its M and C q̇ + G against MuJoCo's own mj_fullM and qfrc_bias (both exact there: MuJoCo's
// recursive Newton–Euler and composite-rigid-body algorithms) at 100 random states.
#include <gtest/gtest.h>

#include <random>

#include "ukdyn/symbolic/chain.hpp"
#include "ukdyn/symbolic/definitions.hpp"
#include "ukdyn/symbolic/mjcf.hpp"

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
    sub->mass(qv, M);
    sub->coriolis_times_qd(qv, qd, Cqd);
    sub->gravity(qv, G);
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

TEST(Mjcf, UnsupportedJointsAndCountsAreNamed) {
  sym::ChainDef c("m", {"a", "b"});
  try {
    sym::append_mjcf(c, kFile);
    FAIL() << "no error";
  } catch (const sym::DefinitionError& e) {
    EXPECT_NE(std::string(e.what()).find("6 hinge/slide joints"), std::string::npos) << e.what();
  }
  sym::ChainDef c2("m", {"a"});
  try {
    sym::append_mjcf(c2, kFile + ".missing");
    FAIL() << "no error";
  } catch (const sym::DefinitionError& e) {
    EXPECT_NE(std::string(e.what()).find("MuJoCo could not load"), std::string::npos) << e.what();
  }
}
#endif

}  // namespace
