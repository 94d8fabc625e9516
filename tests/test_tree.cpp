// The recursive tree algorithms (src/tree/tree.cpp) against the symbolic derivation of the same
// chain (src/symbolic/chain.cpp: Lagrange's equations of T and V expanded exactly), two
// formulations that share no code but the chain definition; Ṁ − 2C skew-symmetric against central
// differences of M; a closed form; and the errors a bad tree gets.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "helpers.hpp"
#include "ukdyn/symbolic/chain.hpp"
#include "ukdyn/symbolic/chain_tree.hpp"
#include "ukdyn/symbolic/constraint_kinds.hpp"
#include "ukdyn/tree/tree.hpp"

namespace {

using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;
namespace sym = ukdyn::symbolic;
namespace tree = ukdyn::tree;
using JT = sym::JointDef::Type;

using uktest::random_vec;

// A spatial arm on a mobile base with yaw: revolute joints about alternating axes, a prismatic
// joint, a fixed joint with a turned origin, inertias turned by their rpy, offsets on every axis,
// a joint whose value is affine in two coordinates (the paper's relative angle), a parameter.
sym::ChainDef spatial_arm() {
  sym::ChainDef c("arm", {"x", "y", "yaw", "q1", "q2", "q3", "d4"});
  c.gravity = {0, 0, -sym::exact_number(9.81)};
  c.mount.xyz = {0.1, -0.2, 0.3};
  c.mount.rpy = {0, 0, 0.2};
  c.base.enabled = true;
  c.base.x = "x";
  c.base.y = "y";
  c.base.yaw = "yaw";
  c.base.inertial.mass = 20;
  c.base.inertial.com = {0.05, 0.02, 0.1};
  c.base.inertial.inertia = {1.2, 0.01, 0, 0.01, 1.5, 0.02, 0, 0.02, 2.0};
  auto L2 = c.parameter("l2", 0.45);
  auto& j1 = c.add_joint("j1", JT::revolute, "l1");
  j1.origin.xyz = {0.2, 0.1, 0.4};
  j1.axis = {0, 0, 1};
  j1.coordinate = "q1";
  j1.inertial.mass = 3.1;
  j1.inertial.com = {0.01, 0.02, 0.1};
  j1.inertial.inertia = {0.03, 0.001, 0.002, 0.001, 0.04, 0.003, 0.002, 0.003, 0.02};
  auto& j2 = c.add_joint("j2", JT::revolute, "l2");
  j2.origin.xyz = {0, 0.05, 0.2};
  j2.origin.rpy = {0.3, 0, 0};
  j2.axis = {0, 1, 0};
  j2.coordinate = "q2";
  j2.inertial.mass = 2.4;
  j2.inertial.com = {L2 / 2, 0, 0.01};
  j2.inertial.inertia = {0.01, 0, 0, 0, 0.05, 0, 0, 0, 0.05};
  j2.inertial.rpy = {0.1, 0.2, 0.3};
  auto& j3 = c.add_joint("j3", JT::revolute, "l3");
  j3.origin.xyz = {L2, 0, 0};
  j3.axis = {1, 2, 2};  // normalised: (1, 2, 2)/3
  j3.value = c.q("q3") - c.q("q2") + 0.1;
  j3.inertial.mass = 1.7;
  j3.inertial.com = {0.1, 0.03, -0.02};
  j3.inertial.inertia = {0.02, 0.001, 0, 0.001, 0.03, 0, 0, 0, 0.01};
  auto& j4 = c.add_joint("j4", JT::prismatic, "l4");
  j4.origin.xyz = {0.3, 0, 0};
  j4.axis = {1, 0, 0};
  j4.coordinate = "d4";
  j4.inertial.mass = 0.9;
  j4.inertial.com = {0.05, 0, 0};
  j4.inertial.inertia = {0.002, 0, 0, 0, 0.004, 0, 0, 0, 0.004};
  auto& jf = c.add_joint("jf", JT::fixed, "flange");
  jf.origin.xyz = {0.1, 0.02, 0};
  jf.origin.rpy = {0, 1.5707963267948966, 0.4};
  jf.inertial.mass = 0.3;
  jf.inertial.com = {0, 0, 0.02};
  jf.inertial.inertia = {0.0003, 0, 0, 0, 0.0003, 0, 0, 0, 0.0002};
  return c;
}

double rel(const Mat& a, const Mat& b) { return (a - b).norm() / std::max(1.0, b.norm()); }

TEST(Tree, MatchesTheSymbolicDerivation) {
  const sym::ChainDef c = spatial_arm();
  const auto symbolic = sym::make_subsystem(sym::build_chain(c).def);
  sym::ChainTree t = sym::chain_tree(c);
  ASSERT_TRUE(t.model) << t.reason;
  const auto tr = tree::make_subsystem(std::move(*t.model));
  const Index n = tr->dof();
  ASSERT_EQ(n, 7);
  std::mt19937_64 rng(11);
  double worst_M = 0, worst_C = 0, worst_Cqd = 0, worst_G = 0, worst_V = 0;
  std::vector<double> slot(static_cast<std::size_t>(tr->slot_size()));
  for (int k = 0; k < 50; ++k) {
    const Vec q = random_vec(rng, n, -3, 3), qd = random_vec(rng, n, -2, 2);
    Mat Ms(n, n), Mt(n, n), Cs(n, n), Ct(n, n);
    Vec cs(n), ct(n), Gs(n), Gt(n), ct2(n), Gt2(n);
    symbolic->mass({}, q, Ms);
    symbolic->coriolis({}, q, qd, Cs);
    symbolic->coriolis_times_qd({}, q, qd, cs);
    symbolic->gravity({}, q, Gs);
    tr->mass({}, q, Mt);
    tr->coriolis({}, q, qd, Ct);
    tr->coriolis_times_qd({}, q, qd, ct);
    tr->gravity({}, q, Gt);
    worst_M = std::max(worst_M, rel(Mt, Ms));
    worst_C = std::max(worst_C, rel(Ct, Cs));
    worst_Cqd = std::max(worst_Cqd, rel(ct, cs));
    worst_G = std::max(worst_G, rel(Gt, Gs));
    worst_V = std::max(worst_V, std::abs(tr->potential({}, q) - symbolic->potential({}, q)) /
                                    std::max(1.0, std::abs(symbolic->potential({}, q))));
    // dynamics() with the caller's slot: the same values as the three calls.
    Mat M2(n, n);
    tr->dynamics({0.0, ukdyn::Slot(slot)}, q, qd, M2, ct2, Gt2);
    EXPECT_EQ(M2, Mt);
    EXPECT_EQ(ct2, ct);
    EXPECT_EQ(Gt2, Gt);
  }
  EXPECT_LE(worst_M, 1e-12);
  EXPECT_LE(worst_C, 1e-12);
  EXPECT_LE(worst_Cqd, 1e-12);
  EXPECT_LE(worst_G, 1e-12);
  EXPECT_LE(worst_V, 1e-12);
}

// Ṁ − 2C is skew-symmetric, Ṁ by central differences of M along q̇; C q̇ = coriolis_times_qd.
TEST(Tree, ChristoffelMatrixIsConsistent) {
  sym::ChainTree t = sym::chain_tree(spatial_arm());
  ASSERT_TRUE(t.model);
  const auto tr = tree::make_subsystem(std::move(*t.model));
  const Index n = tr->dof();
  std::mt19937_64 rng(5);
  for (int k = 0; k < 10; ++k) {
    const Vec q = random_vec(rng, n, -3, 3), qd = random_vec(rng, n, -2, 2);
    const double h = 1e-6;
    Mat Mp(n, n), Mm(n, n), C(n, n);
    tr->mass({}, q + h * qd, Mp);
    tr->mass({}, q - h * qd, Mm);
    const Mat Md = (Mp - Mm) / (2 * h);
    tr->coriolis({}, q, qd, C);
    const Mat N = Md - 2 * C;
    EXPECT_LE((N + N.transpose()).norm(), 1e-6 * std::max(1.0, Md.norm()));
    Vec cqd(n);
    tr->coriolis_times_qd({}, q, qd, cqd);
    EXPECT_LE((C * qd - cqd).norm(), 1e-12 * std::max(1.0, cqd.norm()));
  }
}

// A chain of 11 joint variables (more than one pass of the lanes that differentiate M in
// coriolis()): C is the Christoffel matrix of its definition, C_ij = Σ_k ½ (∂M_ij/∂q_k +
// ∂M_ik/∂q_j − ∂M_jk/∂q_i) q̇_k, ∂M/∂q_k by central differences of mass() (doubles only: no
// code of the lanes), and Ṁ − 2C is skew-symmetric.
TEST(Tree, ChristoffelMatrixOfALongChainMatchesItsDefinition) {
  const int joints = 11;
  std::vector<std::string> names;
  for (int k = 0; k < joints; ++k) names.push_back("q" + std::to_string(k));
  sym::ChainDef c("long", names);
  c.gravity = {0, 0, -sym::exact_number(9.81)};
  for (int k = 0; k < joints; ++k) {
    auto& j = c.add_joint("j" + std::to_string(k), k == 4 ? JT::prismatic : JT::revolute,
                          "l" + std::to_string(k));
    j.origin.xyz = {0.2 + 0.01 * k, 0.03, k % 2 ? 0.05 : -0.02};
    j.origin.rpy = {0.1 * (k % 3), 0, 0.2};
    j.axis = {k % 3 == 0 ? 1.0 : 0.0, k % 3 == 1 ? 1.0 : 0.0, k % 3 == 2 ? 1.0 : 0.0};
    j.coordinate = names[static_cast<std::size_t>(k)];
    j.inertial.mass = 1.0 + 0.1 * k;
    j.inertial.com = {0.1, 0.01 * k, -0.02};
    j.inertial.inertia = {0.02, 0.001, 0, 0.001, 0.03, 0.002, 0, 0.002, 0.01};
  }
  sym::ChainTree t = sym::chain_tree(c);
  ASSERT_TRUE(t.model) << t.reason;
  const auto tr = tree::make_subsystem(std::move(*t.model));
  const Index n = tr->dof();
  ASSERT_EQ(n, joints);
  std::vector<double> slot(static_cast<std::size_t>(tr->slot_size()));
  std::mt19937_64 rng(23);
  double worst = 0, worst_skew = 0;
  for (int s = 0; s < 5; ++s) {
    const Vec q = random_vec(rng, n, -2, 2), qd = random_vec(rng, n, -2, 2);
    const double h = 1e-5;
    std::vector<Mat> dM(static_cast<std::size_t>(n), Mat(n, n));
    Mat Mp(n, n), Mm(n, n), C(n, n), C_slot(n, n), Cd = Mat::Zero(n, n);
    for (Index k = 0; k < n; ++k) {
      tr->mass({}, q + h * Vec::Unit(n, k), Mp);
      tr->mass({}, q - h * Vec::Unit(n, k), Mm);
      dM[static_cast<std::size_t>(k)] = (Mp - Mm) / (2 * h);
    }
    auto d = [&](Index i, Index j, Index k) { return dM[static_cast<std::size_t>(k)](i, j); };
    for (Index i = 0; i < n; ++i)
      for (Index j = 0; j < n; ++j)
        for (Index k = 0; k < n; ++k)
          Cd(i, j) += 0.5 * (d(i, j, k) + d(i, k, j) - d(j, k, i)) * qd(k);
    tr->coriolis({}, q, qd, C);
    tr->coriolis({0.0, ukdyn::Slot(slot)}, q, qd, C_slot);
    EXPECT_EQ(C_slot, C);
    worst = std::max(worst, rel(C, Cd));
    Mat Md = Mat::Zero(n, n);
    for (Index k = 0; k < n; ++k) Md += dM[static_cast<std::size_t>(k)] * qd(k);
    const Mat N = Md - 2 * C;
    worst_skew = std::max(worst_skew, (N + N.transpose()).norm() / std::max(1.0, Md.norm()));
  }
  EXPECT_LE(worst, 1e-7);
  EXPECT_LE(worst_skew, 1e-7);
  std::printf("11 joints: C vs its definition (central differences) %.3g, Mdot - 2C skew %.3g\n",
              worst, worst_skew);
}

// A planar double pendulum in closed form (the textbook M, C q̇, G).
TEST(Tree, DoublePendulumClosedForm) {
  const double m1 = 1.3, m2 = 0.7, l1 = 0.9, l2 = 0.6, g = 9.81;
  tree::Model m;
  m.name = "pendulum";
  m.coordinates = {"q1", "q2"};
  m.gravity = {0, 0, -g};
  tree::Link a, b;
  a.name = "link1";
  a.joint = "j1";
  a.type = tree::JointType::revolute;
  a.axis = {0, 1, 0};
  a.terms = {{0, 1.0}};
  a.mass = m1;
  a.com = {0, 0, -l1};
  b.name = "link2";
  b.joint = "j2";
  b.parent = 0;
  b.type = tree::JointType::revolute;
  b.axis = {0, 1, 0};
  b.origin_translation = {0, 0, -l1};
  b.terms = {{1, 1.0}};
  b.mass = m2;
  b.com = {0, 0, -l2};
  m.links = {a, b};
  const auto tr = tree::make_subsystem(m);
  std::mt19937_64 rng(3);
  for (int k = 0; k < 100; ++k) {
    const Vec q = random_vec(rng, 2, -3.2, 3.2), qd = random_vec(rng, 2, -3, 3);
    Mat M(2, 2), Mr(2, 2);
    Vec cqd(2), G(2), cqdr(2), Gr(2);
    tr->mass({}, q, M);
    tr->coriolis_times_qd({}, q, qd, cqd);
    tr->gravity({}, q, G);
    const double c2 = std::cos(q(1)), s2 = std::sin(q(1)), h = -m2 * l1 * l2 * s2;
    Mr << m1 * l1 * l1 + m2 * (l1 * l1 + l2 * l2 + 2 * l1 * l2 * c2), m2 * (l2 * l2 + l1 * l2 * c2),
        m2 * (l2 * l2 + l1 * l2 * c2), m2 * l2 * l2;
    cqdr << h * (2 * qd(0) * qd(1) + qd(1) * qd(1)), -h * qd(0) * qd(0);
    Gr << (m1 + m2) * g * l1 * std::sin(q(0)) + m2 * g * l2 * std::sin(q(0) + q(1)),
        m2 * g * l2 * std::sin(q(0) + q(1));
    EXPECT_LE((M - Mr).norm(), 1e-13);
    EXPECT_LE((cqd - cqdr).norm(), 1e-13 * std::max(1.0, cqdr.norm()));
    EXPECT_LE((G - Gr).norm(), 1e-13 * std::max(1.0, Gr.norm()));
  }
  // The pose of link 2's frame: Ry(q1) (0, 0, −l1) = (−l1 sin q1, 0, −l1 cos q1).
  Eigen::Matrix3d R;
  Eigen::Vector3d p;
  tr->link_pose(Vec::Constant(2, 0.3), tr->link_index("link2"), R, p);
  EXPECT_NEAR(p.x(), -l1 * std::sin(0.3), 1e-15);
  EXPECT_NEAR(p.z(), -l1 * std::cos(0.3), 1e-15);
}

// A branched tree: a revolute base with two branches (revolute, prismatic, revolute; revolute,
// massless frame, revolute), turned origins and axes, a joint coupled to two coordinates.
tree::Model branched_tree() {
  tree::Model m;
  m.name = "branched";
  m.coordinates = {"q0", "q1", "q2", "q3", "q4", "q5", "q6"};
  m.gravity = {0.3, -0.2, -9.81};
  m.root_rotation = Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 0, 1).normalized()).matrix();
  m.root_translation = {0.1, 0.2, -0.3};
  const auto link = [&](const char* name, int parent, tree::JointType type, Eigen::Vector3d axis,
                        std::vector<tree::Term> terms, double mass, int k) {
    tree::Link L;
    L.name = name;
    L.joint = std::string("j_") + name;
    L.parent = parent;
    L.type = type;
    L.axis = axis.normalized();
    L.terms = std::move(terms);
    L.offset = 0.1 * k;
    L.origin_rotation = Eigen::AngleAxisd(0.2 * k, Eigen::Vector3d(k, 1, 2).normalized()).matrix();
    L.origin_translation = {0.3, -0.1 * k, 0.2};
    L.mass = mass;
    L.com = {0.05 * k, 0.1, -0.02};
    const Eigen::Matrix3d A =
        Eigen::AngleAxisd(0.5 * k, Eigen::Vector3d(1, 2, 3).normalized()).matrix();
    L.inertia = mass * A * Eigen::Vector3d(0.02, 0.03, 0.04).asDiagonal() * A.transpose();
    m.links.push_back(L);
  };
  using TJ = tree::JointType;
  link("base", -1, TJ::revolute, {0, 0, 1}, {{0, 1.0}}, 4.0, 1);
  link("a1", 0, TJ::revolute, {0, 1, 0}, {{1, 1.0}}, 2.0, 2);
  link("a2", 1, TJ::prismatic, {1, 0, 1}, {{2, 1.0}}, 1.5, 3);
  link("a3", 2, TJ::revolute, {1, 2, 2}, {{3, 1.0}, {1, -0.5}}, 1.0, 4);
  link("b1", 0, TJ::revolute, {1, 0, 0}, {{4, 1.0}}, 2.5, 5);
  link("b2", 4, TJ::fixed, {0, 0, 1}, {}, 0.0, 6);
  link("b3", 5, TJ::revolute, {0, 1, 1}, {{5, 2.0}}, 0.8, 7);
  link("b4", 6, TJ::prismatic, {0, 0, 1}, {{6, 1.0}}, 0.5, 8);
  return m;
}

using TreeCases = std::vector<std::pair<std::string, std::shared_ptr<const tree::TreeSubsystem>>>;

// The spatial arm (a mobile base, a prismatic joint, a joint affine in two coordinates, a fixed
// link merged or kept) and a branched tree (merged or not).
TreeCases analytic_cases() {
  sym::ChainTree t = sym::chain_tree(spatial_arm());
  EXPECT_TRUE(t.model) << t.reason;
  if (!t.model) return {};
  return {
      {"spatial arm", std::make_shared<tree::TreeSubsystem>(*t.model)},
      {"spatial arm, fixed link kept", std::make_shared<tree::TreeSubsystem>(*t.model, false)},
      {"branched", std::make_shared<tree::TreeSubsystem>(branched_tree())},
      {"branched, fixed link kept", std::make_shared<tree::TreeSubsystem>(branched_tree(), false)}};
}

// inverse_dynamics_jacobian() (on these trees the analytic pass of Carpentier & Mansard) against
// the one-direction tangents (the RNEA on dual numbers, forward-mode AD), column by column, at
// random states with and without a slot.
TEST(Tree, AnalyticDerivativesMatchTheOneDirectionTangents) {
  const auto cases = analytic_cases();
  std::mt19937_64 rng(23);
  for (const auto& [name, tr] : cases) {
    const Index n = tr->dof();
    std::vector<double> slot(static_cast<std::size_t>(tr->slot_size()));
    double worst = 0.0;
    for (int k = 0; k < 10; ++k) {
      const Vec q = random_vec(rng, n, -3, 3), qd = random_vec(rng, n, -2, 2),
                qdd = random_vec(rng, n, -2, 2);
      const ukdyn::Slot s = k % 2 ? ukdyn::Slot(slot) : ukdyn::Slot{};
      Mat Jq(n, n), Jqd(n, n);
      ASSERT_TRUE(tr->inverse_dynamics_jacobian({0.0, s}, q, qd, qdd, Jq, Jqd));
      for (Index j = 0; j < 2 * n; ++j) {
        Vec dq = Vec::Zero(n), dqd = Vec::Zero(n), one(n);
        (j < n ? dq : dqd)(j % n) = 1.0;
        ASSERT_TRUE(tr->inverse_dynamics_tangent({}, q, qd, qdd, dq, dqd, one));
        const Vec col = j < n ? Vec(Jq.col(j)) : Vec(Jqd.col(j - n));
        worst = std::max(
            worst, (col - one).cwiseAbs().maxCoeff() / std::max(1.0, one.cwiseAbs().maxCoeff()));
      }
    }
    EXPECT_LE(worst, 1e-12) << name;
    std::printf("%s: analytic dID/d(q, qd) vs one-direction tangents: %.3g\n", name.c_str(), worst);
  }
}

// A frame's state as frame_state_jacobian() stacks its tangents: p, R, pd, Rd, pdd, Rdd (R(i, k)
// at 3 i + k), then dp and dR column by column.
Vec stacked_frame(const tree::FrameState& s, Index n) {
  Vec x(36 + 12 * n);
  x << s.p, s.R.transpose().reshaped(), s.pd, s.Rd.transpose().reshaped(), s.pdd,
      s.Rdd.transpose().reshaped(), Vec::Zero(12 * n);
  for (Index c = 0; c < n; ++c) {
    x.segment(36 + 12 * c, 3) = s.dp.col(c);
    x.segment(39 + 12 * c, 9) = s.dR.col(c);
  }
  return x;
}

// frame_state_jacobian() (on these trees the analytic columns) against frame_state_tangent (the
// pass on dual numbers) along each e_j of q and of q̇, for a frame on every link and on the root.
TEST(Tree, AnalyticFrameDerivativesMatchTheOneDirectionTangents) {
  std::mt19937_64 rng(29);
  const Eigen::Matrix3d Ro = Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, 2, 3).normalized()).matrix();
  const Eigen::Vector3d xo(0.1, -0.2, 0.3);
  for (const auto& [name, tr] : analytic_cases()) {
    const Index n = tr->dof(), rows = tr->frame_jacobian_rows();
    std::vector<double> slot(static_cast<std::size_t>(tr->slot_size()));
    std::vector<double> b0(12 * static_cast<std::size_t>(n)), b1(b0), b2(b0);
    tree::FrameState value(b0.data(), b0.data() + 3 * n, n), v1(b1.data(), b1.data() + 3 * n, n),
        t1(b2.data(), b2.data() + 3 * n, n);
    double worst = 0.0;
    for (int k = 0; k < 4; ++k) {
      const Vec q = random_vec(rng, n, -3, 3), qd = random_vec(rng, n, -2, 2),
                qdd = random_vec(rng, n, -2, 2);
      const ukdyn::Slot s = k % 2 ? ukdyn::Slot(slot) : ukdyn::Slot{};
      for (int link = -1; link < static_cast<int>(tr->model().links.size()); ++link) {
        Mat J(rows, 2 * n);
        tr->frame_state_jacobian(q, qd, qdd, link, Ro, xo, {}, s, value, J);
        for (Index j = 0; j < 2 * n; ++j) {
          Vec dq = Vec::Zero(n), dqd = Vec::Zero(n);
          (j < n ? dq : dqd)(j % n) = 1.0;
          tr->frame_state_tangent(q, qd, qdd, dq, dqd, link, Ro, xo, {}, v1, t1);
          const Vec ref = stacked_frame(t1, n), val = stacked_frame(v1, n);
          const double scale = std::max(1.0, ref.cwiseAbs().maxCoeff());
          worst = std::max(worst, (J.col(j) - ref).cwiseAbs().maxCoeff() / scale);
          worst = std::max(worst, (stacked_frame(value, n) - val).cwiseAbs().maxCoeff() /
                                      std::max(1.0, val.cwiseAbs().maxCoeff()));
        }
      }
    }
    EXPECT_LE(worst, 1e-12) << name;
    std::printf("%s: analytic frame columns vs one-direction tangents: %.3g\n", name.c_str(),
                worst);
  }
}

// frame_state_jacobian() reads the links inverse_dynamics_jacobian() left in the subsystem's slot
// only at their state: after the analytic pass at one state, the frame pass at the same state (a
// frame on every link and on the root) matches the pass run on its own, and after any change —
// one coordinate of q, of q̇ or of q̈ moved by 1e-12 (a change of the joint variables: the links
// depend on q only through them, so one ulp of q can leave θ and the links as they were), the
// Christoffel matrix run in the slot
// since (its lanes overwrite the links), another subsystem of the same tree — it is bitwise the
// pass run on its own (no stale placement or motion reused), with the slot also as its scratch.
TEST(Tree, FramePassReusesTheInverseDynamicsLinksAtTheirStateOnly) {
  std::mt19937_64 rng(31);
  const Eigen::Matrix3d Ro = Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, 2, 3).normalized()).matrix();
  const Eigen::Vector3d xo(0.1, -0.2, 0.3);
  for (const auto& [name, tr] : analytic_cases()) {
    SCOPED_TRACE(name);
    const Index n = tr->dof(), rows = tr->frame_jacobian_rows();
    const tree::TreeSubsystem twin(tr->model());
    std::vector<double> slot(static_cast<std::size_t>(tr->slot_size())), scratch(slot);
    std::vector<double> b0(12 * static_cast<std::size_t>(n)), b1(b0);
    tree::FrameState value(b0.data(), b0.data() + 3 * n, n), alone(b1.data(), b1.data() + 3 * n, n);
    const ukdyn::Slot s(slot), x(scratch);
    const Vec q = random_vec(rng, n, -3, 3), qd = random_vec(rng, n, -2, 2),
              qdd = random_vec(rng, n, -2, 2);
    Mat Jq(n, n), Jqd(n, n), J(rows, 2 * n), J_alone(rows, 2 * n), C(n, n);
    double worst = 0.0;
    for (int link = -1; link < static_cast<int>(tr->model().links.size()); ++link) {
      ASSERT_TRUE(tr->inverse_dynamics_jacobian({0.0, s}, q, qd, qdd, Jq, Jqd));
      tr->frame_state_jacobian(q, qd, qdd, link, Ro, xo, s, x, value, J);
      tr->frame_state_jacobian(q, qd, qdd, link, Ro, xo, {}, {}, alone, J_alone);
      const double scale = std::max(1.0, J_alone.cwiseAbs().maxCoeff());
      worst = std::max(worst, (J - J_alone).cwiseAbs().maxCoeff() / scale);
      worst = std::max(worst,
                       (stacked_frame(value, n) - stacked_frame(alone, n)).cwiseAbs().maxCoeff());
    }
    EXPECT_LE(worst, 1e-13);
    const int tip = static_cast<int>(tr->model().links.size()) - 1;
    // Each change: what it does after the analytic pass at (q, q̇, q̈), and the state the frame
    // pass then runs at.
    for (int change = 0; change < 5; ++change) {
      Vec q1 = q, qd1 = qd, qdd1 = qdd;
      const Index j = change % n;
      if (change == 0) q1(j) += 1e-12;
      if (change == 1) qd1(j) += 1e-12;
      if (change == 2) qdd1(j) += 1e-12;
      for (const bool own_scratch : {true, false}) {
        ASSERT_TRUE(tr->inverse_dynamics_jacobian({0.0, s}, q, qd, qdd, Jq, Jqd));
        if (change == 3) tr->coriolis({0.0, s}, q, qd, C);
        const tree::TreeSubsystem& by = change == 4 ? twin : *tr;
        by.frame_state_jacobian(q1, qd1, qdd1, tip, Ro, xo, s, own_scratch ? x : s, value, J);
        by.frame_state_jacobian(q1, qd1, qdd1, tip, Ro, xo, {}, {}, alone, J_alone);
        EXPECT_EQ(J, J_alone) << "change " << change;
        EXPECT_EQ(stacked_frame(value, n), stacked_frame(alone, n)) << "change " << change;
      }
    }
    std::printf("%s: frame pass on the inverse dynamics' links vs on its own: %.3g\n", name.c_str(),
                worst);
  }
}

TEST(Tree, BadTreesAreRefusedNamingTheLink) {
  tree::Model m;
  m.name = "bad";
  m.coordinates = {"q"};
  tree::Link a;
  a.name = "l1";
  a.joint = "j1";
  a.type = tree::JointType::revolute;
  a.terms = {{0, 1.0}};
  a.mass = 1;
  auto refused = [](tree::Model mm, const std::string& what) {
    try {
      tree::validate(mm);
    } catch (const ukdyn::Error& e) {
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("'l1'"), std::string::npos) << e.what();
      return;
    }
    ADD_FAILURE() << "accepted: " << what;
  };
  tree::Model ok = m;
  ok.links = {a};
  EXPECT_NO_THROW(tree::validate(ok));
  tree::Link b = a;
  b.mass = -1;
  m.links = {b};
  refused(m, "negative mass");
  b = a;
  b.inertia = Eigen::Vector3d(1, 1, -1).asDiagonal();
  m.links = {b};
  refused(m, "positive semi-definite");
  b = a;
  b.inertia(0, 1) = 0.5;
  m.links = {b};
  refused(m, "not symmetric");
  b = a;
  b.axis = {0, 0, 2};
  m.links = {b};
  refused(m, "unit");
  b = a;
  b.terms = {{3, 1.0}};
  m.links = {b};
  refused(m, "no coordinate");
  b = a;
  b.parent = 0;
  m.links = {b};
  refused(m, "parent");
  b = a;
  b.com.x() = std::nan("");
  m.links = {b};
  refused(m, "not finite");
}

// What the tree algorithms do not take goes to the symbolic derivation, with the reason.
TEST(Tree, ChainsTheTreeDoesNotTake) {
  sym::ChainDef c = spatial_arm();
  c.extra_potential = c.q("q1") * c.q("q1");
  EXPECT_FALSE(sym::chain_tree(c).model);
  sym::ChainDef d = spatial_arm();
  d.joints[2].value = d.q("q3") * d.q("q2");
  const sym::ChainTree t = sym::chain_tree(d);
  EXPECT_FALSE(t.model);
  EXPECT_NE(t.reason.find("not affine"), std::string::npos) << t.reason;
  sym::ChainDef e = spatial_arm();
  e.joints[0].inertial.mass = GiNaC::sin(sym::time_symbol(e.symbols()));
  EXPECT_FALSE(sym::chain_tree(e).model);
  sym::ChainDef f = spatial_arm();
  f.joints[1].name = "j1";
  EXPECT_THROW((void)sym::chain_tree(f), sym::DefinitionError);
}

}  // namespace

#ifdef UKDYN_HAVE_IO
#include <chrono>

#include "ukdyn/output/geometry.hpp"
#include "ukdyn/scenario/scenario.hpp"

namespace {

// A chain of n revolute joints about alternating z / y axes, 0.3 m apart along x.
std::string chain_scenario(int n, const std::string& extra = "") {
  std::string coords, q0, joints;
  for (int i = 1; i <= n; ++i) {
    const std::string k = std::to_string(i);
    coords += (i > 1 ? ", q" : "q") + k;
    q0 += i > 1 ? ", 0.1" : "0.1";
    joints += "      - {name: j" + k + ", type: revolute, link: l" + k +
              ", axis: " + (i % 2 ? "[0, 0, 1]" : "[0, 1, 0]") + ", origin: {xyz: [" +
              (i > 1 ? "0.3" : "0") + ", 0, 0]}, coordinate: q" + k +
              ", mass: 1, com: [0.15, 0, 0], inertia: [0.01, 0.02, 0.02]}\n";
  }
  return "ukdyn: 1\nname: chain\nsubsystems:\n  - name: arm\n    type: serial_chain\n"
         "    coordinates: [" +
         coords + "]\n" + extra + "    joints:\n" + joints + "initial: {q: [" + q0 +
         "]}\nsimulation: {t_end: 1, sample_dt: 0.01}\n";
}

// A 40-link spatial chain loads at once: the symbolic kinematics (expanded link poses, minutes for
// such a chain) are built only when a constraint needs them; the replay page draws the chain from
// the tree's link poses.
TEST(TreeScenario, LongChainLoadsWithoutSymbolicKinematics) {
  const auto t0 = std::chrono::steady_clock::now();
  const ukdyn::Scenario sc = ukdyn::load_scenario_text(chain_scenario(40), "chain40.yaml");
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_LT(seconds, 30.0);  // a hang guard, not a timing: the symbolic path does not end
  ASSERT_EQ(sc.system->dof(), 40);
  const auto tr = std::dynamic_pointer_cast<const tree::TreeSubsystem>(sc.system->subsystems()[0]);
  ASSERT_TRUE(tr);
  const ukdyn::Geometry g = ukdyn::build_geometry(sc);
  const long end = g.find("arm.end"), l40 = g.find("arm.l40"), com = g.find("arm.l40.com");
  ASSERT_GE(end, 0);
  ASSERT_GE(l40, 0);
  ASSERT_GE(com, 0);
  std::vector<ukdyn::Vec3> out;
  const Vec q = Vec::Constant(40, 0.1);
  g.evaluate(q, out);
  Eigen::Matrix3d R;
  Eigen::Vector3d p;
  tr->link_pose(q, tr->link_index("l40"), R, p);
  EXPECT_LE((out[static_cast<std::size_t>(end)] - p).norm(), 1e-15);
  EXPECT_LE((out[static_cast<std::size_t>(com)] - (p + R * Eigen::Vector3d(0.15, 0, 0))).norm(),
            1e-14);
}

// dynamics: tree on what the tree cannot take is refused with the reason; symbolic derives.
TEST(TreeScenario, DynamicsKey) {
  const std::string s = chain_scenario(3, "    dynamics: symbolic\n");
  const ukdyn::Scenario sym_sc = ukdyn::load_scenario_text(s, "c.yaml");
  EXPECT_FALSE(
      std::dynamic_pointer_cast<const tree::TreeSubsystem>(sym_sc.system->subsystems()[0]));
  std::string bad = chain_scenario(3, "    dynamics: tree\n    potential: q1^2\n");
  try {
    (void)ukdyn::load_scenario_text(bad, "c.yaml");
    ADD_FAILURE() << "accepted";
  } catch (const ukdyn::Error& e) {
    EXPECT_NE(std::string(e.what()).find("extra potential"), std::string::npos) << e.what();
  }
  std::string wrong = chain_scenario(3, "    dynamics: fast\n");
  EXPECT_THROW((void)ukdyn::load_scenario_text(wrong, "c.yaml"), ukdyn::Error);
  // The same chain on both paths: the same M, C q̇, G.
  const ukdyn::Scenario tree_sc = ukdyn::load_scenario_text(chain_scenario(3), "c.yaml");
  const auto& a = *tree_sc.system->subsystems()[0];
  const auto& b = *sym_sc.system->subsystems()[0];
  const Vec q = Vec::LinSpaced(3, -1, 2), qd = Vec::LinSpaced(3, 0.5, -1);
  Mat Ma(3, 3), Mb(3, 3);
  Vec ca(3), cb(3), Ga(3), Gb(3);
  a.dynamics({}, q, qd, Ma, ca, Ga);
  b.dynamics({}, q, qd, Mb, cb, Gb);
  EXPECT_LE((Ma - Mb).norm(), 1e-13);
  EXPECT_LE((ca - cb).norm(), 1e-13);
  EXPECT_LE((Ga - Gb).norm(), 1e-12);
}

}  // namespace
#endif

#ifdef UKDYN_HAVE_IO
#include "moving_state.hpp"
#include "symbolic/numeric_frame_lanes.hpp"
#include "ukdyn/model/column_derivatives.hpp"
#include "ukdyn/symbolic/frame_constraints.hpp"

namespace {

// A chain on a platform, a free body and every kind of frame constraint between their frames
// (`extra`: more constraint lines); `dyn` is the chain's dynamics line ("" for the tree).
std::string frames_scenario(const std::string& dyn, const std::string& extra) {
  const std::string chain =
      "  - name: arm\n    type: serial_chain\n    coordinates: [x, y, yaw, q1, q2, q3, d4]\n"
      "    DYNAMICS"
      "    mount: {xyz: [0.1, -0.2, 0.3], rpy: [0, 0, 0.2]}\n"
      "    base: {x: x, y: y, yaw: yaw, mass: 20, inertia: [1, 1.5, 2]}\n"
      "    joints:\n"
      "      - {name: j1, type: revolute, link: l1, axis: [0, 0, 1], origin: {xyz: [0.2, 0.1, "
      "0.4]},"
      " coordinate: q1, mass: 3, com: [0.01, 0.02, 0.1], inertia: [0.03, 0.04, 0.02]}\n"
      "      - {name: j2, type: revolute, link: l2, axis: [0, 1, 0], origin: {xyz: [0, 0.05, 0.2], "
      "rpy: [0.3, 0, 0]}, coordinate: q2, mass: 2, com: [0.2, 0, 0], inertia: [0.01, 0.05, 0.05]}\n"
      "      - {name: j3, type: revolute, link: l3, axis: [1, 2, 2], origin: {xyz: [0.45, 0, 0]},"
      " value: q3 - q2, mass: 1.5, com: [0.1, 0, 0], inertia: [0.02, 0.03, 0.01]}\n"
      "      - {name: j4, type: prismatic, link: l4, axis: [1, 0, 0], origin: {xyz: [0.3, 0, 0]},"
      " coordinate: d4, mass: 0.9, inertia: [0.002, 0.004, 0.004]}\n"
      "    points:\n      tip: {link: l4, xyz: [0.1, 0.02, 0]}\n";
  const std::string rest =
      "  - name: body\n    type: free_body\n    mass: 2\n    inertia: [0.1, 0.2, 0.3]\n"
      "constraints:\n"
      "  - {type: weld, name: w, a: {frame: arm.tip, xyz: [0.01, 0.02, 0.03], rpy: [0.1, 0.2, "
      "0.3]},"
      " b: {frame: body.body, xyz: [0.2, 0, 0], rpy: [0, 0, 3.0]}}\n"
      "  - {type: ball, name: bl, a: arm.l3, b: {frame: world, xyz: [1, 2, 3]}}\n"
      "  - {type: hinge, name: h, a: arm.l3, b: body.body, axis: [0, 1, 1]}\n"
      "  - {type: level, name: lh, a: arm.l2, axis: [1, 0, 0]}\n"
      "  - {type: level, name: lv, a: arm.l4, axis: [0, 0, 1], orientation: vertical}\n"
      "  - {type: distance, name: dd, a: arm.tip, b: body.body, length: 0.7}\n"
      "  - {type: weld, name: ww, a: arm.l1, b: {frame: arm.l4, rpy: [0.5, 0, 0]}}\n" +
      extra +
      "initial: {q: [0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 1, 0, 0, 0]}\n"
      "simulation: {t_end: 1, sample_dt: 0.1}\n";
  std::string c = chain;
  c.replace(c.find("    DYNAMICS"), 12, dyn);
  return "ukdyn: 1\nname: frames\nsubsystems:\n" + c + rest;
}

// Constraints whose other end is a fixed frame of the world (turned and offset).
const std::string kFixedEnds =
    "  - {type: hinge, name: hw, a: arm.tip, b: {frame: world, xyz: [0, 0, 1]}, axis: [1, 0, 0]}\n"
    "  - {type: hinge, name: hr, a: arm.l3, b: {frame: world, xyz: [0.3, 0, 1], rpy: [0.4, -0.2, "
    "1.1]}, axis: [0, 1, 2]}\n"
    "  - {type: weld, name: wr, a: arm.l4, b: {frame: world, xyz: [1, 0, 0], rpy: [0.2, 0.5, "
    "3.1]}}\n"
    "  - {type: distance, name: dw, a: arm.l4, b: {frame: world, xyz: [0, 1, 0]}, length: 1.2}\n";

// Every kind of frame constraint on the frames of a chain, evaluated in numbers on the tree
// (symbolic/numeric_frame_constraint.cpp) against the same constraint derived from the chain's
// symbolic link poses (dynamics: symbolic): Φ, Φ̇, A, b, the wrench maps G and the frames' twist
// Jacobians, at random states off the constraint manifold (the free body's quaternion not unit).
TEST(TreeScenario, NumericFrameConstraintsMatchTheDerivedOnes) {
  const auto text = [](const std::string& dyn) { return frames_scenario(dyn, kFixedEnds); };
  ukdyn::LoadOptions opt;
  opt.check_initial = false;
  const ukdyn::Scenario num = ukdyn::load_scenario_text(text(""), "n.yaml", opt);
  const ukdyn::Scenario sym_sc =
      ukdyn::load_scenario_text(text("    dynamics: symbolic\n"), "s.yaml", opt);
  const auto& cn = num.system->constraints();
  const auto& cs = sym_sc.system->constraints();
  ASSERT_EQ(cn.size(), cs.size());
  const Index n = num.system->dof();
  std::mt19937_64 rng(17);
  double worst = 0.0;
  for (int k = 0; k < 20; ++k) {
    const Vec q = random_vec(rng, n, -1.5, 1.5), qd = random_vec(rng, n, -2, 2);
    for (std::size_t c = 0; c < cn.size(); ++c) {
      const auto* fn = dynamic_cast<const sym::FrameConstraint*>(cn[c].get());
      const auto* fs = dynamic_cast<const sym::FrameConstraint*>(cs[c].get());
      ASSERT_EQ(fn == nullptr, fs == nullptr);
      if (fn == nullptr) continue;        // the free body's unit-norm row
      EXPECT_EQ(fn->derived(), nullptr);  // the numeric rows
      ASSERT_NE(fs->derived(), nullptr);  // the derived ones
      ASSERT_EQ(cn[c]->row_names(), cs[c]->row_names());
      const Index m = cn[c]->rows();
      Mat An(m, n), Asym(m, n);
      Vec bn(m), bs(m), pn(m), ps(m), vn(m), vs(m);
      cn[c]->evaluate({}, q, qd, An, bn);
      cs[c]->evaluate({}, q, qd, Asym, bs);
      cn[c]->position_residual({}, q, pn);
      cs[c]->position_residual({}, q, ps);
      cn[c]->velocity_residual({}, q, qd, vn);
      cs[c]->velocity_residual({}, q, qd, vs);
      Mat Gan, Gbn, Gas, Gbs, Jan, Jbn, Jas, Jbs;
      fn->wrench().maps(q, Gan, Gbn);
      fs->wrench().maps(q, Gas, Gbs);
      fn->wrench().jacobians(q, Jan, Jbn);
      fs->wrench().jacobians(q, Jas, Jbs);
      const double e = std::max({rel(An, Asym), rel(bn, bs), rel(pn, ps), rel(vn, vs),
                                 rel(Gan, Gas), rel(Gbn, Gbs), rel(Jan, Jas), rel(Jbn, Jbs)});
      EXPECT_LE(e, 1e-11) << cn[c]->row_names()[0];
      worst = std::max(worst, e);
    }
  }
  RecordProperty("worst_rel", ::testing::PrintToString(worst));
}

// The all-directions pass of the numeric frame rows (ConstraintColumns::tangent_columns, lanes
// over the ends' frame_state_jacobian) against the one-direction tangent() it stands for, column by
// column, for every kind and for ends fixed in the world (turned and offset), at random states.
TEST(TreeScenario, NumericFrameColumnsMatchTheOneDirectionTangents) {
  ukdyn::LoadOptions opt;
  opt.check_initial = false;
  const ukdyn::Scenario sc =
      ukdyn::load_scenario_text(frames_scenario("", kFixedEnds), "n.yaml", opt);
  const Index n = sc.system->dof();
  std::mt19937_64 rng(23);
  double worst = 0.0;
  for (int k = 0; k < 10; ++k) {
    const Vec q = random_vec(rng, n, -1.5, 1.5), qd = random_vec(rng, n, -2, 2),
              qdd = random_vec(rng, n, -3, 3);
    for (const auto& c : sc.system->constraints()) {
      const auto* cols = dynamic_cast<const ukdyn::ConstraintColumns*>(c.get());
      if (cols == nullptr) continue;
      const Index m = c->rows();
      const Vec lambda = random_vec(rng, m, -2, 2);
      Mat dres(m, 2 * n), dforce = Mat::Zero(n, 2 * n);
      if (!cols->tangent_columns({}, q, qd, qdd, lambda, dres, dforce)) continue;  // none here
      for (Index j = 0; j < 2 * n; ++j) {
        Vec dq = Vec::Zero(n), dqd = Vec::Zero(n), r1(m), f1 = Vec::Zero(n);
        (j < n ? dq(j) : dqd(j - n)) = 1.0;
        ASSERT_TRUE(c->tangent({}, q, qd, qdd, lambda, dq, dqd, r1, f1));
        Vec fd(m);  // and central differences of A q̈ − b
        {
          const double h = 1e-6;
          Mat Ap(m, n), Am(m, n);
          Vec bp(m), bm(m);
          c->evaluate({}, q + h * dq, qd + h * dqd, Ap, bp);
          c->evaluate({}, q - h * dq, qd - h * dqd, Am, bm);
          fd = ((Ap * qdd - bp) - (Am * qdd - bm)) / (2 * h);
        }
        const double e = std::max(rel(Vec(dres.col(j)), r1), rel(Vec(dforce.col(j)), f1));
        ASSERT_TRUE(std::isfinite(e)) << c->row_names()[0] << " column " << j;
        EXPECT_LE(e, 1e-12) << c->row_names()[0] << " column " << j;
        EXPECT_LE(rel(fd, r1), 1e-7) << c->row_names()[0] << " column " << j;
        worst = std::max(worst, e);
      }
    }
  }
  RecordProperty("worst_rel", ::testing::PrintToString(worst));
}

// The doubles pass of the numeric frame rows' tangent_columns() (each row's tangent linear in the
// ends' J columns, through the rows' constant Hessians) against the same columns computed on lanes
// (the rows lifted to dual numbers of eight directions, numeric_frame_columns_on_lanes): every
// kind, tree ends (both ends of `ww` on one tree), a free body's frame and frames fixed in the
// world, at random states; then the welds of two UR5e to a free-body load (an expressions end) and
// of two Pandas to their plate at a state moving along the constraints, with the forward data's
// slots. Relative to the largest entry of each matrix, bound 1e-12.
TEST(TreeScenario, NumericFrameColumnsOnDoublesMatchTheLanes) {
  const auto max_rel = [](const Mat& a, const Mat& b) {
    return (a - b).cwiseAbs().maxCoeff() / std::max(b.cwiseAbs().maxCoeff(), 1e-300);
  };
  double worst = 0.0;
  int compared = 0;
  const auto check = [&](const ukdyn::System& sys, ukdyn::ForwardData* fd, const Vec& q,
                         const Vec& qd, const Vec& qdd, std::mt19937_64& rng) {
    const Index n = sys.dof();
    for (std::size_t c = 0; c < sys.constraints().size(); ++c) {
      const auto* f = dynamic_cast<const sym::FrameConstraint*>(sys.constraints()[c].get());
      if (f == nullptr || f->derived() != nullptr) continue;
      const Index m = f->rows();
      const Vec lambda = random_vec(rng, m, -2, 2);
      const ukdyn::ConstraintContext ctx{
          0.0, fd != nullptr ? fd->constraint_slots(c) : ukdyn::ConstraintSlots{}};
      Mat dres(m, 2 * n), dforce = Mat::Constant(n, 2 * n, 0.25);
      Mat lres(m, 2 * n), lforce = dforce;
      ASSERT_TRUE(f->tangent_columns(ctx, q, qd, qdd, lambda, dres, dforce));
      ASSERT_TRUE(sym::numeric_frame_columns_on_lanes(*f, ctx, q, qd, qdd, lambda, lres, lforce));
      ASSERT_GT(lres.cwiseAbs().maxCoeff(), 0.0) << f->row_names()[0];
      const double e = std::max(max_rel(dres, lres), max_rel(dforce, lforce));
      ASSERT_TRUE(std::isfinite(e)) << f->row_names()[0];
      EXPECT_LE(e, 1e-12) << f->row_names()[0];
      worst = std::max(worst, e);
      ++compared;
    }
  };
  ukdyn::LoadOptions opt;
  opt.check_initial = false;
  const ukdyn::Scenario sc =
      ukdyn::load_scenario_text(frames_scenario("", kFixedEnds), "n.yaml", opt);
  const Index n = sc.system->dof();
  std::mt19937_64 rng(29);
  for (int k = 0; k < 10; ++k) {
    const Vec q = random_vec(rng, n, -1.5, 1.5), qd = random_vec(rng, n, -2, 2),
              qdd = random_vec(rng, n, -3, 3);
    check(*sc.system, nullptr, q, qd, qdd, rng);
  }
  EXPECT_GE(compared, 10 * 11);  // the 11 numeric constraints above, every state
  for (const char* name : {"two_ur5e_load.yaml", "two_pandas_weld.yaml"}) {
    const ukdyn::Scenario robots =
        ukdyn::load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/" + name);
    const ukdyn::test::State s = ukdyn::test::moving_state(robots);
    ukdyn::ForwardData fd(*robots.system);
    ukdyn::forward(*robots.system, fd, robots.sim.t0, s.q, s.qd, s.tau);
    const int before = compared;
    check(*robots.system, &fd, s.q, s.qd, fd.qdd, rng);
    EXPECT_GE(compared - before, 2) << name;
  }
  RecordProperty("worst_rel", ::testing::PrintToString(worst));
  std::printf("numeric frame columns, doubles against lanes: %d constraints, worst %.2g\n",
              compared, worst);
}

}  // namespace
#endif
