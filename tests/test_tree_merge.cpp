// Fixed joints merged in the tree algorithms (ukdyn/tree/tree.hpp, TreeSubsystem): M, C q̇, G, V
// and every link's frame state (the merged links' by name) of the merged tree against the unmerged
// one, on the real arms of robots/ (URDF and MJCF) and on a synthetic tree whose fixed links carry
// mass; and one lumped inertia worked out by hand.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <random>

#include "ukdyn/robot_files/mjcf.hpp"
#include "ukdyn/robot_files/urdf.hpp"
#include "ukdyn/symbolic/chain_tree.hpp"
#include "ukdyn/tree/tree.hpp"

namespace {

namespace sym = ukdyn::symbolic;
namespace tree = ukdyn::tree;
using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;

// M, C q̇, G, V and every link's frame state (with an offset) of the merged tree against the
// unmerged one at random states; returns the largest difference relative to the largest entry.
double merged_vs_unmerged(const tree::Model& model, unsigned seed) {
  const tree::TreeSubsystem merged(model, true), plain(model, false);
  const Index n = plain.dof();
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-2.0, 2.0);
  Mat M1(n, n), M2(n, n);
  Vec q(n), qd(n), C1(n), C2(n), G1(n), G2(n);
  const Eigen::Matrix3d Ro =
      Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  const Eigen::Vector3d xo(0.1, -0.2, 0.3);
  std::vector<double> dp1(static_cast<std::size_t>(3 * n)), dR1(static_cast<std::size_t>(9 * n)),
      dp2(dp1.size()), dR2(dR1.size());
  double worst = 0.0;
  auto rel = [](const auto& a, const auto& b) {
    return (a - b).cwiseAbs().maxCoeff() / std::max(1.0, a.cwiseAbs().maxCoeff());
  };
  for (int k = 0; k < 20; ++k) {
    for (Index i = 0; i < n; ++i) {
      q[i] = u(rng);
      qd[i] = u(rng);
    }
    merged.dynamics({}, q, qd, M1, C1, G1);
    plain.dynamics({}, q, qd, M2, C2, G2);
    worst = std::max({worst, rel(M1, M2), rel(C1, C2), rel(G1, G2)});
    const double V1 = merged.potential({}, q), V2 = plain.potential({}, q);
    worst = std::max(worst, std::abs(V1 - V2) / std::max(1.0, std::abs(V2)));
    for (const tree::Link& L : model.links) {
      const int i1 = merged.link_index(L.name), i2 = plain.link_index(L.name);
      EXPECT_GE(i1, 0) << L.name;
      tree::FrameState f1(dp1.data(), dR1.data(), n), f2(dp2.data(), dR2.data(), n);
      merged.frame_state(q, qd, i1, Ro, xo, {}, f1);
      plain.frame_state(q, qd, i2, Ro, xo, {}, f2);
      worst = std::max({worst, rel(f1.p, f2.p), rel(f1.pd, f2.pd), rel(f1.pdd, f2.pdd),
                        rel(f1.R, f2.R), rel(f1.Rd, f2.Rd), rel(f1.Rdd, f2.Rdd),
                        rel(Mat(f1.dp), Mat(f2.dp)), rel(Mat(f1.dR), Mat(f2.dR))});
      Eigen::Matrix3d R1, R2;
      Eigen::Vector3d p1, p2;
      merged.link_pose(q, i1, R1, p1);
      plain.link_pose(q, i2, R2, p2);
      worst = std::max({worst, rel(R1, R2), rel(p1, p2)});
    }
  }
  return worst;
}

tree::Model robot_tree(const std::string& robot, const char* ext, int dof) {
  std::vector<std::string> q;
  for (int i = 1; i <= dof; ++i) q.push_back("q" + std::to_string(i));
  sym::ChainDef c(robot, q);
  const std::string file = std::string(UKDYN_SOURCE_DIR) + "/robots/" + robot + "." + ext;
  if (std::string(ext) == "xml") {
    sym::append_mjcf(c, file, /*gravity=*/true);
  } else {
    c.gravity = {0, 0, GiNaC::numeric(-981, 100)};
    sym::append_urdf(c, file);
  }
  sym::ChainTree t = sym::chain_tree(c);
  if (!t.model) throw ukdyn::Error(robot + ": " + t.reason);
  return std::move(*t.model);
}

TEST(TreeMergeFixed, RealArmsUnchanged) {
  const struct {
    const char* robot;
    int dof;
  } robots[] = {{"ur5e", 6}, {"panda", 7}};
  for (const auto& r : robots) {
    for (const char* ext : {"urdf", "xml"}) {
      if (std::string(ext) == "urdf" && !sym::urdf_supported()) continue;
      if (std::string(ext) == "xml" && !sym::mjcf_supported()) continue;
      SCOPED_TRACE(std::string(r.robot) + "." + ext);
      const tree::Model m = robot_tree(r.robot, ext, r.dof);
      const tree::TreeSubsystem t(m);
      EXPECT_EQ(t.pass_links(), static_cast<std::size_t>(r.dof));  // the movable links only
      EXPECT_LT(t.pass_links(), m.links.size());
      EXPECT_LE(merged_vs_unmerged(m, 11u), 1e-13);
    }
  }
}

tree::Link link(const std::string& name, int parent, tree::JointType type) {
  tree::Link L;
  L.name = name;
  L.joint = name + "_joint";
  L.parent = parent;
  L.type = type;
  if (type != tree::JointType::fixed) L.terms.push_back({parent < 0 ? 0 : 1, 1.0});
  return L;
}

// A tree whose fixed links carry mass: one fixed to the root (a constant potential), a fixed link
// between two movable ones (turned origin, rotated inertia with products), a chain of two fixed
// links at the tip, a prismatic joint on a fixed link.
TEST(TreeMergeFixed, SyntheticTreeWithHeavyFixedLinksUnchanged) {
  tree::Model m;
  m.name = "synthetic";
  m.coordinates = {"a", "b", "c"};
  m.gravity = {0.3, -0.2, -9.81};
  m.root_rotation = Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitX()).toRotationMatrix();
  m.root_translation = {0.1, 0.2, 0.3};
  Eigen::Matrix3d I;
  I << 0.3, 0.01, -0.02, 0.01, 0.2, 0.03, -0.02, 0.03, 0.25;
  auto turned = [](double a, const Eigen::Vector3d& axis) {
    return Eigen::AngleAxisd(a, axis.normalized()).toRotationMatrix();
  };
  tree::Link w = link("pedestal", -1, tree::JointType::fixed);  // 0, fixed in the world
  w.mass = 5.0;
  w.com = {0.0, 0.1, 0.2};
  w.inertia = I;
  w.origin_translation = {0, 0, 0.5};
  tree::Link l1 = link("l1", 0, tree::JointType::revolute);  // 1, q = a
  l1.terms = {{0, 1.0}};
  l1.axis = Eigen::Vector3d(0.2, 0.3, 1.0).normalized();
  l1.mass = 2.0;
  l1.com = {0.2, 0.0, 0.0};
  l1.inertia = I * 0.5;
  tree::Link f1 = link("bracket", 1, tree::JointType::fixed);  // 2
  f1.origin_translation = {0.4, 0.1, 0.0};
  f1.origin_rotation = turned(0.7, {1, 1, 0});
  f1.mass = 1.5;
  f1.com = {0.05, -0.02, 0.1};
  f1.inertia = I;
  tree::Link l2 = link("l2", 2, tree::JointType::revolute);  // 3, θ = b − a
  l2.terms = {{1, 1.0}, {0, -1.0}};
  l2.axis = {0, 1, 0};
  l2.origin_translation = {0.0, 0.0, 0.3};
  l2.origin_rotation = turned(-0.4, {0, 0, 1});
  l2.mass = 1.0;
  l2.com = {0.3, 0, 0};
  l2.inertia = I * 0.2;
  tree::Link f2 = link("flange", 3, tree::JointType::fixed);  // 4
  f2.origin_translation = {0.6, 0, 0};
  f2.origin_rotation = turned(1.1, {0, 1, 1});
  f2.mass = 0.7;
  f2.com = {0, 0, 0.05};
  f2.inertia = I * 0.1;
  tree::Link f3 = link("tool", 4, tree::JointType::fixed);  // 5
  f3.origin_translation = {0, 0.1, 0.2};
  f3.origin_rotation = turned(0.3, {1, 0, 0});
  f3.mass = 0.4;
  f3.com = {0.01, 0.02, 0.03};
  f3.inertia = I * 0.05;
  tree::Link p = link("slider", 2, tree::JointType::prismatic);  // 6, on the bracket, q = c
  p.terms = {{2, 1.0}};
  p.axis = {1, 0, 0};
  p.origin_translation = {0, -0.2, 0};
  p.mass = 0.9;
  p.com = {0.0, 0.05, 0.0};
  p.inertia = I * 0.3;
  m.links = {w, l1, f1, l2, f2, f3, p};
  const tree::TreeSubsystem t(m);
  EXPECT_EQ(t.pass_links(), 3u);
  EXPECT_LE(merged_vs_unmerged(m, 5u), 1e-13);
}

// By hand: a massless link on a revolute joint about z carrying, on a fixed joint 0.5 m out along
// x, a body of 2 kg with I_zz = 0.1 about its CoM 0.1 m further out: M = 0.1 + 2 · 0.6² = 0.82.
TEST(TreeMergeFixed, LumpedInertiaByHand) {
  tree::Model m;
  m.name = "hand";
  m.coordinates = {"a"};
  tree::Link arm = link("arm", -1, tree::JointType::revolute);
  tree::Link tip = link("tip", 0, tree::JointType::fixed);
  tip.origin_translation = {0.5, 0, 0};
  tip.origin_rotation = Eigen::AngleAxisd(0.9, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  tip.mass = 2.0;
  tip.com = tip.origin_rotation.transpose() * Eigen::Vector3d(0.1, 0, 0);  // 0.1 m along arm x
  tip.inertia = Eigen::Vector3d(0.3, 0.2, 0.1).asDiagonal();
  m.links = {arm, tip};
  const tree::TreeSubsystem t(m);
  EXPECT_EQ(t.pass_links(), 1u);
  Mat M(1, 1);
  Vec q(1);
  q << 0.4;
  t.mass({}, q, M);
  EXPECT_NEAR(M(0, 0), 0.82, 1e-15);
  EXPECT_EQ(t.model().links[0].mass, 0.0);  // model() is the tree as given
  // The tip's frame, by name: at R_z(0.4) (0.5, 0, 0), turned by 0.4 + 0.9.
  Eigen::Matrix3d R;
  Eigen::Vector3d p;
  t.link_pose(q, t.link_index("tip"), R, p);
  EXPECT_NEAR(p.x(), 0.5 * std::cos(0.4), 1e-15);
  EXPECT_NEAR(p.y(), 0.5 * std::sin(0.4), 1e-15);
  EXPECT_NEAR(R(1, 0), std::sin(1.3), 1e-15);
}

}  // namespace
