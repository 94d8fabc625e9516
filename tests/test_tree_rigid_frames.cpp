// A frame's state on a rigid tree as the weld rows read it (TreeSubsystem::frame_twists: the
// twist columns written per movable ancestor, Ṙ and R̈ by column cross products, identity offsets
// skipped) against frame_state (∂p/∂q and ∂R/∂q column by column, Ṙ and R̈ as 3 × 3 products):
// every link of the Panda and of a tree with a prismatic joint, a branch and a turned mount, with
// an identity and a turned offset, at random states. Columns of coordinates that do not move the
// frame must come out zero.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <random>
#include <string>
#include <vector>

#include "ukdyn/robot_files/urdf.hpp"
#include "ukdyn/symbolic/chain_tree.hpp"
#include "ukdyn/tree/tree.hpp"

namespace {

namespace sym = ukdyn::symbolic;
namespace tree = ukdyn::tree;
using ukdyn::Index;
using ukdyn::Vec;

Eigen::Matrix3d skew(const Eigen::Vector3d& w) {
  Eigen::Matrix3d K;
  K << 0, -w.z(), w.y(), w.z(), 0, -w.x(), -w.y(), w.x(), 0;
  return K;
}

// The largest difference between frame_twists and frame_state over every link, both offsets and
// `states` random states, relative to max(1, |x|) per field.
double twists_vs_state(const tree::Model& model, int states, unsigned seed) {
  const tree::TreeSubsystem t(model);
  const Index n = t.dof();
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-2.0, 2.0);
  const Eigen::Matrix3d turned =
      Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, -2, 3).normalized()).toRotationMatrix();
  std::vector<double> dp(static_cast<std::size_t>(3 * n)), dR(static_cast<std::size_t>(9 * n)),
      dp2(dp.size()), dR2(dR.size()), twists(static_cast<std::size_t>(7 * n), 7.0);
  double worst = 0.0;
  const auto rel = [&](const auto& a, const auto& b) {
    worst = std::max(worst, (a - b).cwiseAbs().maxCoeff() / std::max(1.0, a.cwiseAbs().maxCoeff()));
  };
  Vec q(n), qd(n);
  for (int s = 0; s < states; ++s) {
    for (Index i = 0; i < n; ++i) {
      q[i] = u(rng);
      qd[i] = u(rng);
    }
    for (const tree::Link& L : model.links) {
      const int link = t.link_index(L.name);
      for (const Eigen::Matrix3d& Ro : {Eigen::Matrix3d(Eigen::Matrix3d::Identity()), turned}) {
        const Eigen::Vector3d xo(0.05, -0.1, 0.2);
        tree::FrameState ref(dp.data(), dR.data(), n), out(dp2.data(), dR2.data(), n);
        t.frame_state(q, qd, link, Ro, xo, {}, ref);
        std::fill(twists.begin(), twists.end(), 7.0);  // every entry must be written
        t.frame_twists(q, qd, link, Ro, xo, {}, {}, out, twists.data());
        rel(ref.p, out.p);
        rel(ref.R, out.R);
        rel(ref.pd, out.pd);
        rel(ref.Rd, out.Rd);
        rel(ref.pdd, out.pdd);
        rel(ref.Rdd, out.Rdd);
        for (Index j = 0; j < n; ++j) {
          const double* c = twists.data() + 7 * j;
          const Eigen::Vector3d v(c[0], c[1], c[2]), w(c[3], c[4], c[5]);
          EXPECT_EQ(c[6], 0.0);  // no scale without ball joints
          rel(Eigen::Vector3d(ref.dp.col(j)), v);
          const Eigen::Matrix3d dRj = skew(w) * ref.R;
          for (int r = 0; r < 9; ++r) {
            const double a = ref.dR(r, j), b = dRj(r / 3, r % 3);
            worst = std::max(worst, std::abs(a - b) / std::max(1.0, std::abs(a)));
          }
        }
      }
    }
  }
  return worst;
}

TEST(TreeRigidFrames, FrameTwistsMatchFrameStateOnThePanda) {
  if (!sym::urdf_supported()) GTEST_SKIP() << "no URDF support";
  std::vector<std::string> q;
  for (int i = 1; i <= 7; ++i) q.push_back("q" + std::to_string(i));
  sym::ChainDef c("panda", q);
  c.gravity = {0, 0, GiNaC::numeric(-981, 100)};
  sym::append_urdf(c, std::string(UKDYN_SOURCE_DIR) + "/robots/panda.urdf");
  sym::ChainTree ct = sym::chain_tree(c);
  ASSERT_TRUE(ct.model) << ct.reason;
  EXPECT_LE(twists_vs_state(*ct.model, 10, 3u), 1e-13);
}

tree::Link link(const std::string& name, int parent, tree::JointType type, Index coordinate) {
  tree::Link L;
  L.name = name;
  L.joint = name + "_joint";
  L.parent = parent;
  L.type = type;
  if (type != tree::JointType::fixed) L.terms.push_back({coordinate, 1.0});
  L.mass = 1.0;
  L.com = {0.05, 0.02, -0.03};
  L.inertia = Eigen::Vector3d(0.02, 0.03, 0.04).asDiagonal();
  return L;
}

// A prismatic joint at the root (massless, as a platform's x), a branch of two links on it (so
// that a frame's columns of the other branch are zero), axes x, y, z and a general one, turned and
// permuted origins, a fixed tip, a turned mount.
TEST(TreeRigidFrames, FrameTwistsMatchFrameStateOnABranchedTree) {
  tree::Model m;
  m.name = "branched";
  m.coordinates = {"s", "a", "b", "c", "d"};
  m.gravity = {0.0, 0.0, -9.81};
  m.root_rotation = Eigen::AngleAxisd(0.4, Eigen::Vector3d(0, 0.6, 0.8)).toRotationMatrix();
  m.root_translation = {0.3, -0.1, 0.2};
  tree::Link base = link("base", -1, tree::JointType::prismatic, 0);
  base.axis = {1, 0, 0};
  base.mass = 0.0;
  base.com.setZero();
  base.inertia.setZero();
  tree::Link l1 = link("l1", 0, tree::JointType::revolute, 1);
  l1.axis = {0, 0, 1};
  l1.origin_translation = {0.0, 0.0, 0.3};
  l1.origin_rotation = Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitX()).toRotationMatrix();
  tree::Link l2 = link("l2", 1, tree::JointType::revolute, 2);
  l2.axis = Eigen::Vector3d(1, 2, 2) / 3.0;
  l2.origin_translation = {0.2, 0.1, 0.0};
  tree::Link l3 = link("l3", 1, tree::JointType::revolute, 3);  // the other branch
  l3.axis = {1, 0, 0};
  l3.origin_translation = {-0.1, 0.2, 0.05};
  l3.origin_rotation = Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitY()).toRotationMatrix();
  tree::Link l4 = link("l4", 3, tree::JointType::revolute, 4);
  l4.axis = {0, 1, 0};
  l4.origin_translation = {0.0, 0.25, 0.0};
  tree::Link tip = link("tip", 4, tree::JointType::fixed, 0);
  tip.origin_translation = {0.1, 0.0, 0.0};
  m.links = {base, l1, l2, l3, l4, tip};
  EXPECT_LE(twists_vs_state(m, 10, 5u), 1e-13);
}

}  // namespace
