// Ball and floating joints on the recursive tree algorithms (src/tree/tree.cpp,
// docs/tree-algorithms.md, "Quaternion joints") against the symbolic derivation of the same chains
// (src/symbolic/chain.cpp: T and V expanded, Lagrange's equations by GiNaC), two formulations
// sharing only the chain definition: M, C q̇, G, V at random states (unit quaternions, velocities
// with radial quaternion rates), q̈ of the constrained forward(); the exact derivatives against
// central differences; the frames against the symbolic link poses; momentum and energy in free
// flight; and, on an MJCF file with free and ball joints, MuJoCo's M and bias mapped to its qvel.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "ukdyn/model/linearize.hpp"
#include "ukdyn/model/system.hpp"
#include "ukdyn/robot_files/mjcf.hpp"
#include "ukdyn/simulate/simulate.hpp"
#include "ukdyn/symbolic/chain.hpp"
#include "ukdyn/symbolic/chain_tree.hpp"
#include "ukdyn/symbolic/constraint_kinds.hpp"
#include "ukdyn/symbolic/free_body.hpp"
#include "ukdyn/tree/tree.hpp"
#ifdef UKDYN_TEST_HAVE_MUJOCO
#include <mujoco/mujoco.h>
#endif

namespace {

using ukdyn::CVecRef;
using ukdyn::ForwardData;
using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::System;
using ukdyn::Vec;
namespace sym = ukdyn::symbolic;
namespace tree = ukdyn::tree;
using JT = sym::JointDef::Type;
using M3 = Eigen::Matrix3d;
using V3 = Eigen::Vector3d;

sym::Mat3Ex ex_mat(const M3& m) {
  sym::Mat3Ex r;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) r[static_cast<std::size_t>(3 * i + j)] = m(i, j);
  return r;
}
sym::Vec3Ex ex_vec(const V3& v) { return {v(0), v(1), v(2)}; }

// A full inertia about the CoM: diagonal d turned by rpy r (symmetric positive definite).
M3 inertia(const V3& d, const V3& r) {
  const M3 R = (Eigen::AngleAxisd(r(2), V3::UnitZ()) * Eigen::AngleAxisd(r(1), V3::UnitY()) *
                Eigen::AngleAxisd(r(0), V3::UnitX()))
                   .toRotationMatrix();
  const M3 J = R * d.asDiagonal() * R.transpose();
  return 0.5 * (J + J.transpose());  // exactly symmetric, as the symbolic path requires
}

void set_inertial(sym::JointDef& j, double m, const V3& c, const M3& J, const V3& rpy) {
  j.inertial.mass = m;
  j.inertial.com = ex_vec(c);
  j.inertial.inertia = ex_mat(J);
  j.inertial.rpy = ex_vec(rpy);
}

// A floating root (a body with an off-origin CoM and a full inertia) and three revolute links;
// gravity not along an axis. (Skew axes, turned inertias and origins expand the symbolic T past
// its bound.)
sym::ChainDef floating_arm(double g) {
  sym::ChainDef c("fa", {"x", "y", "z", "qw", "qx", "qy", "qz", "t1", "t2", "t3"});
  c.gravity = {0.3 * g, -0.2 * g, -g};
  c.mount.xyz = {0.1, -0.2, 0.3};
  auto& f = c.add_joint("float", JT::floating, "body");
  f.coordinates = {"x", "y", "z", "qw", "qx", "qy", "qz"};
  f.origin.xyz = {0.05, 0.0, -0.1};
  set_inertial(f, 3.0, {0.02, -0.01, 0.03}, inertia({0.1, 0.12, 0.15}, {0.2, 0.1, 0.0}),
               V3::Zero());
  auto& j1 = c.add_joint("j1", JT::revolute, "l1");
  j1.origin.xyz = {0.1, 0.05, 0.0};
  j1.axis = {0, 0, 1};
  j1.coordinate = "t1";
  set_inertial(j1, 1.2, {0.2, 0.0, 0.01}, M3(V3(0.002, 0.02, 0.021).asDiagonal()), V3::Zero());
  auto& j2 = c.add_joint("j2", JT::revolute, "l2");
  j2.origin.xyz = {0.4, 0.0, 0.0};
  j2.axis = {0, 1, 0};
  j2.coordinate = "t2";
  set_inertial(j2, 0.8, {0.15, 0.02, 0.0}, M3(V3(0.001, 0.01, 0.011).asDiagonal()), V3::Zero());
  auto& j3 = c.add_joint("j3", JT::revolute, "l3");
  j3.origin.xyz = {0.3, 0.0, 0.0};
  j3.axis = {1, 0, 0};
  j3.coordinate = "t3";
  set_inertial(j3, 0.5, {0.05, 0.0, 0.0}, M3(V3(0.002, 0.003, 0.001).asDiagonal()), V3::Zero());
  return c;
}

// A ball joint between two revolute joints on a fixed base, with a massive fixed tip (merged
// into the last link) and a ball joint's link of full inertia.
sym::ChainDef ball_arm(double g) {
  sym::ChainDef c("ba", {"t1", "bw", "bx", "by", "bz", "t2"});
  c.gravity = {0, 0, -g};
  auto& j1 = c.add_joint("j1", JT::revolute, "l1");
  j1.origin.xyz = {0.0, 0.0, 0.3};
  j1.axis = {0, 0, 1};
  j1.coordinate = "t1";
  set_inertial(j1, 2.0, {0.1, 0.02, 0.05}, inertia({0.03, 0.04, 0.02}, {0.1, 0.0, 0.0}),
               V3::Zero());
  auto& b = c.add_joint("wrist", JT::ball, "l2");
  b.coordinates = {"bw", "bx", "by", "bz"};
  b.origin.xyz = {0.3, 0.0, 0.1};
  b.origin.rpy = {0.0, 0.0, 0.5};
  set_inertial(b, 1.1, {0.12, -0.03, 0.02}, inertia({0.01, 0.02, 0.025}, {0.2, 0.3, 0.1}),
               {0.0, 0.1, 0.0});
  auto& j2 = c.add_joint("j2", JT::revolute, "l3");
  j2.origin.xyz = {0.25, 0.02, 0.0};
  j2.axis = {0, 1, 0};
  j2.coordinate = "t2";
  set_inertial(j2, 0.6, {0.1, 0.0, 0.01}, inertia({0.001, 0.004, 0.004}, {0.0, 0.0, 0.0}),
               V3::Zero());
  auto& tip = c.add_joint("tip", JT::fixed, "tool");
  tip.origin.xyz = {0.2, 0.0, 0.0};
  tip.origin.rpy = {0.4, 0.0, 0.0};
  set_inertial(tip, 0.3, {0.02, 0.01, 0.0}, inertia({0.0003, 0.0004, 0.0002}, {0, 0, 0}),
               V3::Zero());
  return c;
}

struct Pair {
  sym::ChainModel model;
  std::shared_ptr<sym::DerivedSubsystem> symbolic;
  std::shared_ptr<const tree::TreeSubsystem> tree;
  std::vector<Index> quaternions;  // the first coordinate (qw) of each quaternion
};

// derive false: the symbolic link poses only (no Lagrange's equations).
Pair make_pair(const sym::ChainDef& c, bool derive = true) {
  Pair p{sym::build_chain(c), nullptr, nullptr, {}};
  if (derive) p.symbolic = sym::make_subsystem(p.model.def);
  sym::ChainTree t = sym::chain_tree(c);
  EXPECT_TRUE(t.model) << t.reason;
  if (t.model) p.tree = tree::make_subsystem(std::move(*t.model));
  const auto& names = c.coordinates();
  for (const auto& [joint, quat] : p.model.quaternions) {
    const auto it = std::find(names.begin(), names.end(), quat[0]);
    p.quaternions.push_back(static_cast<Index>(it - names.begin()));
  }
  return p;
}

// A random state: normal coordinates with unit quaternions; the velocity normal too (its
// quaternion rates have radial parts), or tangent to |q| = 1.
void random_state(std::mt19937_64& rng, const std::vector<Index>& quats, Index n, Vec& q, Vec& qd,
                  bool tangent) {
  std::normal_distribution<double> nd;
  q.resize(n);
  qd.resize(n);
  for (Index i = 0; i < n; ++i) {
    q(i) = nd(rng);
    qd(i) = nd(rng);
  }
  for (const Index a : quats) {
    q.segment(a, 4).normalize();
    if (tangent) qd.segment(a, 4) -= q.segment(a, 4).dot(qd.segment(a, 4)) * q.segment(a, 4);
  }
}

double rel(const Mat& a, const Mat& b) { return (a - b).norm() / std::max(1.0, b.norm()); }

struct Worst {
  double M = 0, Cqd = 0, G = 0, V = 0;
};

Worst compare_dynamics(const Pair& p, int states, unsigned seed) {
  std::mt19937_64 rng(seed);
  const Index n = p.tree->dof();
  Worst w;
  std::vector<double> slot(static_cast<std::size_t>(p.tree->slot_size()));
  for (int k = 0; k < states; ++k) {
    Vec q, qd;
    random_state(rng, p.quaternions, n, q, qd, false);
    Mat Ms(n, n), Mt(n, n);
    Vec cs(n), ct(n), Gs(n), Gt(n);
    p.symbolic->dynamics({}, q, qd, Ms, cs, Gs);
    p.tree->dynamics({0.0, ukdyn::Slot(slot)}, q, qd, Mt, ct, Gt);
    w.M = std::max(w.M, rel(Mt, Ms));
    w.Cqd = std::max(w.Cqd, rel(ct, cs));
    w.G = std::max(w.G, rel(Gt, Gs));
    const double Vs = p.symbolic->potential({}, q);
    w.V = std::max(w.V, std::abs(p.tree->potential({}, q) - Vs) / std::max(1.0, std::abs(Vs)));
    // The single calls give the same values as dynamics().
    Mat M2(n, n);
    Vec c2(n), G2(n);
    p.tree->mass({}, q, M2);
    p.tree->coriolis_times_qd({}, q, qd, c2);
    p.tree->gravity({}, q, G2);
    EXPECT_LE(rel(M2, Mt) + rel(c2, ct) + rel(G2, Gt), 1e-15);
  }
  return w;
}

void expect_agreement(const char* what, const Worst& w, int states) {
  EXPECT_LE(w.M, 1e-10);
  EXPECT_LE(w.Cqd, 1e-10);
  EXPECT_LE(w.G, 1e-10);
  EXPECT_LE(w.V, 1e-10);
  std::printf(
      "%s, tree vs symbolic (%d states, radial quaternion rates): M %.3g, C qd %.3g, "
      "G %.3g, V %.3g (relative)\n",
      what, states, w.M, w.Cqd, w.G, w.V);
}

std::shared_ptr<System> with_norm_rows(const std::shared_ptr<const ukdyn::Subsystem>& sub,
                                       const sym::ChainModel& model) {
  auto s = std::make_shared<System>();
  s->add_subsystem(sub);
  for (const auto& [joint, quat] : model.quaternions)
    s->add_constraint(
        sym::make_constraint(sym::free_body_norm_constraint(joint, quat, s->coordinate_names())));
  return s;
}

// q̈ of the constrained forward() on the tree and on the symbolic derivation, at consistent
// states (tangent velocities) and at states whose quaternion rates have radial parts.
double compare_forward(const Pair& p, int states, unsigned seed) {
  const auto a = with_norm_rows(p.tree, p.model), b = with_norm_rows(p.symbolic, p.model);
  std::mt19937_64 rng(seed);
  const Index n = a->dof();
  double worst = 0;
  for (int k = 0; k < states; ++k) {
    Vec q, qd;
    random_state(rng, p.quaternions, n, q, qd, k % 2 == 0);
    const Vec tau = 0.3 * Vec::Ones(n);
    ForwardData da(*a), db(*b);
    ukdyn::forward(*a, da, 0.0, q, qd, tau);
    ukdyn::forward(*b, db, 0.0, q, qd, tau);
    EXPECT_TRUE(da.result.finite && db.result.finite);
    worst = std::max(worst, (da.qdd - db.qdd).norm() / std::max(1.0, db.qdd.norm()));
  }
  return worst;
}

}  // namespace

TEST(TreeQuaternion, FloatingArmMatchesTheSymbolicDerivation) {
  const Pair p = make_pair(floating_arm(9.81));
  ASSERT_TRUE(p.tree);
  EXPECT_EQ(p.tree->joint_variables(), 10);
  EXPECT_EQ(p.tree->pass_links(), 7U);  // the floating joint: three prismatic links and a ball
  expect_agreement("floating root + 3 revolute", compare_dynamics(p, 25, 3), 25);
  const double dqdd = compare_forward(p, 20, 4);
  EXPECT_LE(dqdd, 1e-10);
  std::printf("floating root + 3 revolute, constrained forward() qdd, tree vs symbolic: %.3g\n",
              dqdd);
}

TEST(TreeQuaternion, BallJointInTheMiddleMatchesTheSymbolicDerivation) {
  const Pair p = make_pair(ball_arm(9.81));
  ASSERT_TRUE(p.tree);
  expect_agreement("revolute, ball, revolute, fixed tip", compare_dynamics(p, 25, 5), 25);
  const double dqdd = compare_forward(p, 20, 6);
  EXPECT_LE(dqdd, 1e-10);
  std::printf("ball in the middle, constrained forward() qdd, tree vs symbolic: %.3g\n", dqdd);
}

// The exact derivative of ID(q, q̇, q̈) = M q̈ + C q̇ + G (dual numbers through the RNEA) against
// Richardson-extrapolated central differences of the tree's own M, C q̇ and G, along random
// directions (with radial components), at unit and non-unit quaternions.
TEST(TreeQuaternion, InverseDynamicsTangentMatchesDifferences) {
  for (const auto& c : {floating_arm(9.81), ball_arm(9.81)}) {
    const Pair p = make_pair(c, false);
    ASSERT_TRUE(p.tree);
    const auto& tr = *p.tree;
    const Index n = tr.dof();
    auto id = [&](const Vec& q, const Vec& qd, const Vec& qdd) {
      Mat M(n, n);
      Vec C(n), G(n);
      tr.dynamics({}, q, qd, M, C, G);
      return Vec(M * qdd + C + G);
    };
    std::mt19937_64 rng(9);
    std::normal_distribution<double> nd;
    double worst = 0;
    for (int k = 0; k < 10; ++k) {
      Vec q, qd;
      random_state(rng, p.quaternions, n, q, qd, false);
      if (k % 2) q *= 1.1;  // off |q| = 1: a smooth function there too
      Vec qdd(n), dq(n), dqd(n);
      for (Index i = 0; i < n; ++i) {
        qdd(i) = nd(rng);
        dq(i) = nd(rng);
        dqd(i) = nd(rng);
      }
      Vec exact(n);
      ASSERT_TRUE(tr.inverse_dynamics_tangent({}, q, qd, qdd, dq, dqd, exact));
      auto central = [&](double h) {
        return Vec((id(q + h * dq, qd + h * dqd, qdd) - id(q - h * dq, qd - h * dqd, qdd)) /
                   (2 * h));
      };
      const Vec d = (4 * central(5e-4) - central(1e-3)) / 3;
      worst = std::max(worst, (exact - d).norm() / std::max(1.0, d.norm()));
    }
    EXPECT_LE(worst, 1e-8);
    std::printf("%s: inverse_dynamics_tangent vs central differences (10 states): %.3g\n",
                c.name().c_str(), worst);
  }
}

namespace {

// A frame's state stacked as frame_state_jacobian() stacks its tangents: p, R, pd, Rd, pdd, Rdd
// (R(i, k) at 3 i + k), then dp and dR column by column.
Vec stacked(const tree::FrameState& s, Index n) {
  Vec x(36 + 12 * n);
  for (int i = 0; i < 3; ++i) {
    x(i) = s.p(i);
    x(12 + i) = s.pd(i);
    x(24 + i) = s.pdd(i);
  }
  for (int r = 0; r < 9; ++r) {
    x(3 + r) = s.R(r / 3, r % 3);
    x(15 + r) = s.Rd(r / 3, r % 3);
    x(27 + r) = s.Rdd(r / 3, r % 3);
  }
  for (Index c = 0; c < n; ++c) {
    for (int i = 0; i < 3; ++i) x(36 + 12 * c + i) = s.dp(i, c);
    for (int r = 0; r < 9; ++r) x(36 + 12 * c + 3 + r) = s.dR(r, c);
  }
  return x;
}

double max_rel(const Vec& a, const Vec& b) {
  return (a - b).cwiseAbs().maxCoeff() / std::max(1.0, b.cwiseAbs().maxCoeff());
}

struct TreeCase {
  std::string name;
  std::shared_ptr<const tree::TreeSubsystem> tree;
};

// robots/ROBOT.xml with a free joint on its base (given a mass and an inertia off its origin), in
// the test's temporary directory: the arm on a floating base.
std::string floating_mjcf(const std::string& robot) {
  std::ifstream in(std::string(UKDYN_SOURCE_DIR) + "/robots/" + robot + ".xml");
  std::stringstream text;
  text << in.rdbuf();
  std::string xml = text.str();
  const std::string base = "<body name=\"base_link\">";
  const std::size_t at = xml.find(base);
  EXPECT_NE(at, std::string::npos) << robot;
  if (at == std::string::npos) return {};
  xml.insert(at + base.size(),
             "<freejoint name=\"root\"/><inertial pos=\"0.02 -0.01 0.05\" mass=\"4\" "
             "fullinertia=\"0.03 0.04 0.035 0.002 -0.001 0.003\"/>");
  const std::string path = ::testing::TempDir() + "/floating_" + robot + ".xml";
  std::ofstream(path) << xml;
  return path;
}

// The floating root with three revolute links, the ball joint in the middle of a chain and, with
// MuJoCo, the UR5e and the Panda of robots/ (their MJCF files), fixed and on a free joint.
std::vector<TreeCase> jacobian_cases() {
  std::vector<TreeCase> out;
  for (const auto& c : {floating_arm(9.81), ball_arm(9.81)})
    out.push_back({c.name(), make_pair(c, false).tree});
  if (!sym::mjcf_supported()) return out;
  for (const auto& [robot, dof] : {std::pair{"ur5e", 6}, std::pair{"panda", 7}}) {
    for (const bool floating : {false, true}) {
      std::vector<std::string> coords;
      if (floating) coords = {"x", "y", "z", "qw", "qx", "qy", "qz"};
      for (int i = 1; i <= dof; ++i) coords.push_back("q" + std::to_string(i));
      const std::string name = std::string(floating ? "floating_" : "") + robot;
      sym::ChainDef c(name, coords);
      sym::append_mjcf(c,
                       floating ? floating_mjcf(robot)
                                : std::string(UKDYN_SOURCE_DIR) + "/robots/" + robot + ".xml",
                       true);
      out.push_back({name, make_pair(c, false).tree});
    }
  }
  return out;
}

}  // namespace

// Every column at once (inverse_dynamics_jacobian, frame_state_jacobian: dual numbers of several
// lanes, the placement shared by the directions of q̇) against the one-direction passes they
// replace in linearize() (inverse_dynamics_tangent, frame_state_tangent along each e_j of q and
// of q̇), at random states off |u| = 1 (the quaternion joints' correction terms included), with
// and without a slot.
TEST(TreeQuaternion, AllColumnsAtOnceMatchOneDirectionAtATime) {
  std::mt19937_64 rng(11);
  std::normal_distribution<double> nd;
  for (const TreeCase& tc : jacobian_cases()) {
    ASSERT_TRUE(tc.tree) << tc.name;
    const tree::TreeSubsystem& tr = *tc.tree;
    const Index n = tr.dof(), rows = tr.frame_jacobian_rows();
    std::vector<double> slot(static_cast<std::size_t>(tr.slot_size()));
    std::vector<double> b0(12 * static_cast<std::size_t>(n)), b1(b0), b2(b0);
    tree::FrameState value(b0.data(), b0.data() + 3 * n, n), v1(b1.data(), b1.data() + 3 * n, n),
        t1(b2.data(), b2.data() + 3 * n, n);
    const int link = static_cast<int>(tr.model().links.size()) - 1;
    const M3 Ro = Eigen::AngleAxisd(0.4, V3(1, 2, 3).normalized()).toRotationMatrix();
    const V3 xo(0.1, -0.2, 0.3);
    double worst_id = 0.0, worst_frame = 0.0;
    for (int k = 0; k < 6; ++k) {
      Vec q(n), qd(n), qdd(n);
      for (Index i = 0; i < n; ++i) {
        q(i) = nd(rng);
        qd(i) = nd(rng);
        qdd(i) = nd(rng);
      }
      const ukdyn::Slot s = k % 2 ? ukdyn::Slot(slot) : ukdyn::Slot{};
      Mat Jq(n, n), Jqd(n, n), J(rows, 2 * n);
      ASSERT_TRUE(tr.inverse_dynamics_jacobian({0.0, s}, q, qd, qdd, Jq, Jqd));
      tr.frame_state_jacobian(q, qd, qdd, link, Ro, xo, s, s, value, J);
      for (Index j = 0; j < 2 * n; ++j) {
        Vec dq = Vec::Zero(n), dqd = Vec::Zero(n), one(n);
        (j < n ? dq : dqd)(j % n) = 1.0;
        ASSERT_TRUE(tr.inverse_dynamics_tangent({}, q, qd, qdd, dq, dqd, one));
        worst_id = std::max(worst_id, max_rel(j < n ? Vec(Jq.col(j)) : Vec(Jqd.col(j - n)), one));
        tr.frame_state_tangent(q, qd, qdd, dq, dqd, link, Ro, xo, {}, v1, t1);
        worst_frame = std::max(worst_frame, max_rel(Vec(J.col(j)), stacked(t1, n)));
        worst_frame = std::max(worst_frame, max_rel(stacked(value, n), stacked(v1, n)));
      }
    }
    EXPECT_LE(worst_id, 1e-12) << tc.name;
    EXPECT_LE(worst_frame, 1e-12) << tc.name;
    std::printf("%s: all columns at once vs one direction at a time: ID %.3g, frame %.3g\n",
                tc.name.c_str(), worst_id, worst_frame);
  }
}

namespace {

double number(const GiNaC::ex& e, const GiNaC::exmap& at) {
  return GiNaC::ex_to<GiNaC::numeric>(e.subs(at).evalf()).to_double();
}

// Every link's frame from the symbolic chain (build_chain's expressions of q) at q.
void symbolic_pose(const sym::ChainDef& c, const sym::ChainModel& model, const std::string& link,
                   const Vec& q, M3& R, V3& p) {
  GiNaC::exmap at = model.def.parameter_values();
  for (std::size_t i = 0; i < c.coordinates().size(); ++i)
    at[sym::coordinate_symbol(c.symbols(), c.coordinates()[i])] = q(static_cast<Index>(i));
  const sym::LinkPose& pose = model.links.at(link);
  for (int i = 0; i < 3; ++i) {
    p(i) = number(pose.position[static_cast<std::size_t>(i)], at);
    for (int j = 0; j < 3; ++j)
      R(i, j) = number(pose.rotation[static_cast<std::size_t>(3 * i + j)], at);
  }
}

}  // namespace

// The frames the constraints see (frame_state) against the symbolic chain's link poses (at unit
// and non-unit quaternions: both place links by the homogeneous R(q)); their columns ∂p/∂q, ∂R/∂q
// against central differences of the pose, ṗ = ∂p/∂q q̇, p̈ against a difference of ṗ along the
// motion q(t) = q + t q̇ + t² q̈ / 2 at q̈ = 0; and frame_state_tangent against differences of
// frame_state.
TEST(TreeQuaternion, FramesMatchTheSymbolicKinematics) {
  for (const auto& c : {floating_arm(9.81), ball_arm(9.81)}) {
    const Pair p = make_pair(c, false);
    ASSERT_TRUE(p.tree);
    const auto& tr = *p.tree;
    const Index n = tr.dof();
    std::mt19937_64 rng(17);
    double pose = 0, cols = 0, rates = 0, acc = 0, tangent = 0;
    const M3 Ro = Eigen::AngleAxisd(0.3, V3(1, 2, 3).normalized()).toRotationMatrix();
    const V3 po(0.05, -0.02, 0.1);
    std::vector<double> b1(static_cast<std::size_t>(12 * n)), b2(b1.size()), b3(b1.size());
    tree::FrameState s(b1.data(), b1.data() + 3 * n, n), s2(b2.data(), b2.data() + 3 * n, n),
        s3(b3.data(), b3.data() + 3 * n, n);
    for (int k = 0; k < 20; ++k) {
      Vec q, qd;
      random_state(rng, p.quaternions, n, q, qd, false);
      if (k % 4 == 3) q *= 0.9;
      for (const tree::Link& L : tr.model().links) {
        const int li = tr.link_index(L.name);
        M3 Rs;
        V3 ps;
        symbolic_pose(c, p.model, L.name, q, Rs, ps);
        tr.frame_state(q, qd, li, M3::Identity(), V3::Zero(), {}, s);
        pose = std::max(pose, (s.p - ps).norm() + (s.R - Rs).norm());
      }
      const int li = tr.link_index(tr.model().links.back().name);
      tr.frame_state(q, qd, li, Ro, po, {}, s);
      const double h = 1e-6;
      for (Index j = 0; j < n; ++j) {
        const Vec e = Vec::Unit(n, j);
        tr.frame_state(q + h * e, qd, li, Ro, po, {}, s2);
        tr.frame_state(q - h * e, qd, li, Ro, po, {}, s3);
        const V3 dp = (s2.p - s3.p) / (2 * h);
        const M3 dR = (s2.R - s3.R) / (2 * h);
        double e2 = (s.dp.col(j) - dp).norm();
        for (int r = 0; r < 9; ++r) e2 += std::abs(s.dR(r, j) - dR(r / 3, r % 3));
        cols = std::max(cols, e2);
      }
      rates = std::max(rates, (s.pd - s.dp * qd).norm());
      // Richardson-extrapolated central differences, (4 D(h/2) − D(h)) / 3.
      auto rate = [&](double hh) {
        tr.frame_state(q + hh * qd, qd, li, Ro, po, {}, s2);
        tr.frame_state(q - hh * qd, qd, li, Ro, po, {}, s3);
        Vec d(12);
        d << (s2.pd - s3.pd) / (2 * hh), (s2.Rd - s3.Rd).reshaped() / (2 * hh);
        return d;
      };
      Vec a(12);
      a << s.pdd, s.Rdd.reshaped();
      acc = std::max(acc, (a - (4 * rate(5e-4) - rate(1e-3)) / 3).norm());
      // frame_state_tangent along (dq, dq̇) at q̈ = 0 against differences of frame_state.
      const Vec dq = Vec::Random(n), dqd = Vec::Random(n), zero = Vec::Zero(n);
      std::vector<double> vb(b1.size()), tb(b1.size());
      tree::FrameState v(vb.data(), vb.data() + 3 * n, n), t(tb.data(), tb.data() + 3 * n, n);
      tr.frame_state_tangent(q, qd, zero, dq, dqd, li, Ro, po, {}, v, t);
      auto all = [&](const tree::FrameState& f) {
        Vec x(36 + 12 * n);
        x << f.p, f.R.reshaped(), f.pd, f.Rd.reshaped(), f.pdd, f.Rdd.reshaped(), f.dp.reshaped(),
            f.dR.reshaped();
        return x;
      };
      auto central = [&](double hh) {
        tr.frame_state(q + hh * dq, qd + hh * dqd, li, Ro, po, {}, s2);
        tr.frame_state(q - hh * dq, qd - hh * dqd, li, Ro, po, {}, s3);
        return Vec((all(s2) - all(s3)) / (2 * hh));
      };
      tangent = std::max(tangent, (all(t) - (4 * central(5e-4) - central(1e-3)) / 3).norm());
    }
    EXPECT_LE(pose, 1e-13);
    EXPECT_LE(cols, 1e-8);
    EXPECT_LE(rates, 1e-13);
    EXPECT_LE(acc, 1e-8);
    EXPECT_LE(tangent, 1e-8);
    std::printf(
        "%s frames (20 states): pose vs symbolic %.3g, columns vs differences %.3g, "
        "pd - dp qd %.3g, acceleration %.3g, tangent %.3g\n",
        c.name().c_str(), pose, cols, rates, acc, tangent);
  }
}

// Free flight without gravity of a floating body carrying a revolute, a ball and a revolute joint:
// the linear momentum Σ m ċ (each link's CoM velocity from frame_state) and the energy ½ q̇ᵀ M q̇
// stay constant (the unit-norm rows hold the quaternions).
TEST(TreeQuaternion, FreeFlightKeepsMomentumAndEnergy) {
  sym::ChainDef c = floating_arm(0.0);
  c.gravity = {0, 0, 0};
  const Pair p = make_pair(c, false);
  ASSERT_TRUE(p.tree);
  const auto system = with_norm_rows(p.tree, p.model);
  const Index n = system->dof();
  Vec q0(n), qd0(n);
  q0 << 0.1, -0.2, 0.3, std::cos(0.4), 0.6 * std::sin(0.4), 0.0, 0.8 * std::sin(0.4), 0.4, -0.7,
      0.2;
  qd0 << 0.3, -0.1, 0.2, 0, 0, 0, 0, 2.0, -3.0, 1.5;
  const Eigen::Quaterniond u(q0(3), q0(4), q0(5), q0(6));
  const Eigen::Quaterniond r = u * Eigen::Quaterniond(0, 0.5, -1.0, 0.8);
  qd0.segment(3, 4) << 0.5 * r.w(), 0.5 * r.x(), 0.5 * r.y(), 0.5 * r.z();  // ½ q ⊗ (0, ω)
  const auto& tr = *p.tree;
  std::vector<double> buf(static_cast<std::size_t>(12 * n));
  tree::FrameState s(buf.data(), buf.data() + 3 * n, n);
  auto invariants = [&](CVecRef q, CVecRef qd, V3& P, double& T) {
    P.setZero();
    for (const tree::Link& L : tr.model().links) {
      tr.frame_state(q, qd, tr.link_index(L.name), M3::Identity(), L.com, {}, s);
      P += L.mass * s.pd;
    }
    Mat M(n, n);
    tr.mass({}, q, M);
    T = 0.5 * qd.dot(M * qd);
  };
  V3 P0;
  double T0 = 0;
  invariants(q0, qd0, P0, T0);
  ukdyn::SimulationSettings st;
  st.t_end = 1.0;
  st.sample_dt = 0.05;
  st.integrator = ukdyn::IntegratorKind::rkf78;
  st.abs_tol = 1e-13;
  st.rel_tol = 1e-13;
  double dP = 0, dT = 0;
  const auto run = ukdyn::simulate(*system, q0, qd0, nullptr, st,
                                   [&](double, CVecRef q, CVecRef qd, const ForwardData&) {
                                     V3 P;
                                     double T = 0;
                                     invariants(q, qd, P, T);
                                     dP = std::max(dP, (P - P0).norm() / P0.norm());
                                     dT = std::max(dT, std::abs(T - T0) / T0);
                                     return true;
                                   });
  ASSERT_EQ(run.status, ukdyn::RunStatus::completed) << run.message;
  EXPECT_LE(dP, 1e-10);
  EXPECT_LE(dT, 1e-10);
  std::printf(
      "floating arm on the tree, 1 s free flight, rkf78 1e-13: max |dP|/|P| %.3g, "
      "max |dT|/T %.3g\n",
      dP, dT);
}

// An MJCF file with a free joint (a ball joint below it) and a ball joint from the world
// (tests/mjcf/ball_free.xml): the tree against the symbolic derivation, and against MuJoCo's
// mj_fullM and qfrc_bias mapped to its 6-D free / 3-D ball velocities (q̇ = H v, M_v = Hᵀ M H,
// bias_v = Hᵀ (M Ḣ v + C q̇ + G), as tests/test_mjcf.cpp does for the symbolic path).
#ifdef UKDYN_TEST_HAVE_MUJOCO
TEST(TreeQuaternion, MjcfFreeAndBallJoints) {
  ASSERT_TRUE(sym::mjcf_supported());
  const std::string file = std::string(UKDYN_SOURCE_DIR) + "/tests/mjcf/ball_free.xml";
  sym::ChainDef c("ball_free", {"x", "y", "z", "qw", "qx", "qy", "qz", "sw", "sx", "sy", "sz", "pw",
                                "px", "py", "pz", "el"});
  sym::append_mjcf(c, file, /*gravity=*/true);
  const Pair p = make_pair(c);
  ASSERT_TRUE(p.tree);
  ASSERT_EQ(p.quaternions.size(), 3U);
  expect_agreement("MJCF free + ball + hinge", compare_dynamics(p, 25, 7), 25);
  const double dqdd = compare_forward(p, 20, 8);
  EXPECT_LE(dqdd, 1e-10);
  std::printf("MJCF free + ball + hinge, constrained forward() qdd, tree vs symbolic: %.3g\n",
              dqdd);
  char err[1000] = "";
  mjModel* m = mj_loadXML(file.c_str(), nullptr, err, sizeof err);
  ASSERT_NE(m, nullptr) << err;
  mjData* d = mj_makeData(m);
  const int nq = m->nq, nv = m->nv;
  auto qmat = [](const Vec& q4) {  // ½ q ⊗ (0, ω) = Q ω
    Mat Q(4, 3);
    Q << -q4(1), -q4(2), -q4(3), q4(0), -q4(3), q4(2), q4(3), q4(0), -q4(1), -q4(2), q4(1), q4(0);
    return Mat(0.5 * Q);
  };
  std::mt19937_64 rng(21);
  std::normal_distribution<double> nd;
  double worst_M = 0, worst_b = 0;
  for (int k = 0; k < 50; ++k) {
    Vec qv(nq), v(nv);
    for (int i = 0; i < nq; ++i) qv[i] = nd(rng);
    for (int i = 0; i < nv; ++i) v[i] = nd(rng);
    Mat H = Mat::Zero(nq, nv);
    std::vector<std::pair<int, int>> quats;
    for (int j = 0, qi = 0, vi = 0; j < m->njnt; ++j) {
      const int t = m->jnt_type[j];
      if (t == mjJNT_FREE) {
        H.block(qi, vi, 3, 3).setIdentity();
        qi += 3;
        vi += 3;
      }
      if (t == mjJNT_FREE || t == mjJNT_BALL) {
        qv.segment(qi, 4).normalize();
        H.block(qi, vi, 4, 3) = qmat(qv.segment(qi, 4));
        quats.emplace_back(qi, vi);
        qi += 4;
        vi += 3;
      } else if (t == mjJNT_HINGE || t == mjJNT_SLIDE) {
        H(qi++, vi++) = 1.0;
      }
    }
    const Vec qd = H * v;
    Vec Hdv = Vec::Zero(nq);
    for (const auto& [qa, va] : quats)
      Hdv.segment(qa, 4) = qmat(qd.segment(qa, 4)) * v.segment(va, 3);
    for (int i = 0; i < nq; ++i) d->qpos[i] = qv[i];
    for (int i = 0; i < nv; ++i) d->qvel[i] = v[i];
    mj_forward(m, d);
    std::vector<mjtNum> full(static_cast<std::size_t>(nv * nv));
    mj_fullM(m, full.data(), d->qM);
    Mat Mmj(nv, nv), M(nq, nq);
    for (int i = 0; i < nv; ++i)
      for (int j = 0; j < nv; ++j) Mmj(i, j) = full[static_cast<std::size_t>(nv * i + j)];
    Vec Cqd(nq), G(nq), bias(nv);
    p.tree->dynamics({}, qv, qd, M, Cqd, G);
    for (int i = 0; i < nv; ++i) bias[i] = d->qfrc_bias[i];
    worst_M = std::max(worst_M, (H.transpose() * M * H - Mmj).norm() / Mmj.norm());
    worst_b = std::max(worst_b, (H.transpose() * (M * Hdv + Cqd + G) - bias).norm() /
                                    std::max(bias.norm(), 1e-300));
  }
  mj_deleteData(d);
  mj_deleteModel(m);
  EXPECT_LE(worst_M, 1e-10);
  EXPECT_LE(worst_b, 1e-10);
  std::printf("MJCF free + ball + hinge, tree vs MuJoCo (50 states): M %.3g, bias %.3g\n", worst_M,
              worst_b);
}
#endif

// The Christoffel matrix (System::coriolis) against the symbolic derivation's, C q̇ against
// coriolis_times_qd (the RNEA), and Ṁ − 2C skew-symmetric for tangent velocities (Ṁ by central
// differences of the tree's M along q̇, which off |u| = 1 is the tree's, not the symbolic M).
TEST(TreeQuaternion, ChristoffelMatrixMatchesTheSymbolicDerivation) {
  for (const auto& c : {floating_arm(9.81), ball_arm(9.81)}) {
    const Pair p = make_pair(c);
    ASSERT_TRUE(p.tree);
    const Index n = p.tree->dof();
    std::mt19937_64 rng(23);
    double dC = 0, dCqd = 0, skew = 0;
    for (int k = 0; k < 20; ++k) {
      Vec q, qd;
      random_state(rng, p.quaternions, n, q, qd, k % 2 == 0);
      Mat Cs(n, n), Ct(n, n);
      Vec cq(n);
      p.symbolic->coriolis({}, q, qd, Cs);
      p.tree->coriolis({}, q, qd, Ct);
      p.tree->coriolis_times_qd({}, q, qd, cq);
      dC = std::max(dC, rel(Ct, Cs));
      dCqd = std::max(dCqd, (Ct * qd - cq).norm() / std::max(1.0, cq.norm()));
      if (k % 2 == 0) {
        const double h = 1e-6;
        Mat Mp(n, n), Mm(n, n);
        p.tree->mass({}, q + h * qd, Mp);
        p.tree->mass({}, q - h * qd, Mm);
        const Mat N = (Mp - Mm) / (2 * h) - 2 * Ct;
        skew = std::max(skew, (N + N.transpose()).norm() / std::max(1.0, Ct.norm()));
      }
    }
    EXPECT_LE(dC, 1e-10);
    EXPECT_LE(dCqd, 1e-12);
    EXPECT_LE(skew, 1e-7);
    std::printf("%s: Christoffel C tree vs symbolic %.3g, C qd vs RNEA %.3g, Mdot - 2C skew %.3g\n",
                c.name().c_str(), dC, dCqd, skew);
  }
}

// The exact derivatives of q̈ of the constrained system (ukdyn::linearize: the tree's
// inverse_dynamics_tangent and the norm rows' tapes) against Richardson-extrapolated central
// differences of forward(), every column of ∂q̈/∂q (radial quaternion directions included),
// ∂q̈/∂q̇ and ∂q̈/∂τ, at a state moving along the constraints.
TEST(TreeQuaternion, LinearizationMatchesDifferencesOfForward) {
  for (const auto& c : {floating_arm(9.81), ball_arm(9.81)}) {
    const Pair p = make_pair(c, false);
    ASSERT_TRUE(p.tree);
    const auto sys = with_norm_rows(p.tree, p.model);
    ASSERT_TRUE(ukdyn::components_without_derivatives(*sys).empty());
    const Index n = sys->dof();
    std::mt19937_64 rng(31);
    Vec q, qd;
    random_state(rng, p.quaternions, n, q, qd, true);
    const Vec tau = Vec::LinSpaced(n, -0.5, 0.7);
    const ukdyn::Linearization l = ukdyn::linearize(*sys, 0.0, q, qd, tau);
    EXPECT_TRUE(l.trusted) << l.message;
    ForwardData d(*sys);
    double worst = 0;
    for (int which = 0; which < 3; ++which) {
      const Mat& exact = which == 0 ? l.dqdd_dq : which == 1 ? l.dqdd_dqd : l.dqdd_dtau;
      for (Index j = 0; j < n; ++j) {
        auto central = [&](double h) {
          Vec x[3] = {q, qd, tau}, y[3] = {q, qd, tau};
          x[which](j) += h;
          y[which](j) -= h;
          ukdyn::forward(*sys, d, 0.0, x[0], x[1], x[2]);
          const Vec a = d.qdd;
          ukdyn::forward(*sys, d, 0.0, y[0], y[1], y[2]);
          return Vec((a - d.qdd) / (2 * h));
        };
        const Vec diff = (4 * central(5e-4) - central(1e-3)) / 3;
        worst = std::max(worst, (exact.col(j) - diff).cwiseAbs().maxCoeff() /
                                    (1.0 + diff.cwiseAbs().maxCoeff()));
      }
    }
    EXPECT_LE(worst, 1e-6);
    std::printf("%s: linearize() vs central differences of forward(), all columns: %.3g\n",
                c.name().c_str(), worst);
  }
}

// A tree's floating or ball joint with the wrong number of coordinates, or a variable that is not
// one coordinate, is refused naming the link (tree::validate).
TEST(TreeQuaternion, BadQuaternionJointsAreRefusedNamingTheLink) {
  tree::Model m;
  m.name = "t";
  m.coordinates = {"x", "y", "z", "qw", "qx", "qy", "qz"};
  tree::Link L;
  L.name = "body";
  L.joint = "float";
  L.type = tree::JointType::floating;
  L.mass = 1.0;
  L.inertia = M3::Identity();
  for (Index k = 0; k < 6; ++k) L.terms.push_back({k, 1.0});
  m.links.push_back(L);
  auto message = [](const tree::Model& model) {
    try {
      tree::validate(model);
    } catch (const ukdyn::Error& e) {
      return std::string(e.what());
    }
    return std::string("accepted");
  };
  EXPECT_NE(message(m).find("link 'body': a floating joint has 7 coordinates, got 6"),
            std::string::npos)
      << message(m);
  m.links[0].terms.push_back({6, 2.0});
  EXPECT_NE(message(m).find("link 'body': its variables must be coordinates"), std::string::npos)
      << message(m);
  m.links[0].terms.back().coefficient = 1.0;
  EXPECT_EQ(message(m), "accepted");
  m.links[0].type = tree::JointType::ball;
  EXPECT_NE(message(m).find("a ball joint has 4 coordinates, got 7"), std::string::npos)
      << message(m);
}
