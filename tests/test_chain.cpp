// Serial chains and trees (src/symbolic/chain.cpp) against closed forms; definition errors.
// (Split from the former grab-bag test_chain.cpp: constraint kinds → test_constraint_kinds.cpp,
// splines → test_spline.cpp, chain / URDF scenarios → test_chain_scenarios.cpp.)
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>

#include "helpers.hpp"
#include "ukdyn/symbolic/chain.hpp"
#include "ukdyn/symbolic/constraint_kinds.hpp"

namespace {

using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;
namespace sym = ukdyn::symbolic;
using JT = sym::JointDef::Type;

using uktest::random_vec;
using uktest::rel;

// A planar double pendulum in the x-z plane, joints about y, point masses at the link ends;
// q2 relative to link 1 (a standard robot's joint angle).
TEST(Chain, DoublePendulumMatchesClosedForm) {
  const double m1 = 1.3, m2 = 0.7, l1 = 0.9, l2 = 0.6, g = 9.81;
  sym::ChainDef c("pendulum", {"q1", "q2"});
  c.gravity = {0, 0, -sym::exact_number(g)};
  auto L1 = c.parameter("l1", l1), L2 = c.parameter("l2", l2);
  auto& j1 = c.add_joint("j1", JT::revolute, "link1");
  j1.axis = {0, 1, 0};
  j1.coordinate = "q1";
  j1.inertial.mass = c.parameter("m1", m1);
  j1.inertial.com = {0, 0, -L1};
  auto& j2 = c.add_joint("j2", JT::revolute, "link2");
  j2.origin.xyz = {0, 0, -L1};
  j2.axis = {0, 1, 0};
  j2.coordinate = "q2";
  j2.inertial.mass = c.parameter("m2", m2);
  j2.inertial.com = {0, 0, -L2};
  c.add_point("tip", "link2", {0, 0, -L2});
  const sym::ChainModel model = sym::build_chain(c);
  const auto sub = sym::make_subsystem(model.def);
  std::mt19937_64 rng(3);
  double worst = 0;
  for (int k = 0; k < 200; ++k) {
    const Vec q = random_vec(rng, 2, -3.2, 3.2), qd = random_vec(rng, 2, -3, 3);
    Mat M(2, 2), Mr(2, 2);
    Vec cqd(2), G(2), cqdr(2), Gr(2);
    sub->mass({}, q, M);
    sub->coriolis_times_qd({}, q, qd, cqd);
    sub->gravity({}, q, G);
    const double c2 = std::cos(q(1)), s2 = std::sin(q(1)), h = -m2 * l1 * l2 * s2;
    Mr << m1 * l1 * l1 + m2 * (l1 * l1 + l2 * l2 + 2 * l1 * l2 * c2), m2 * (l2 * l2 + l1 * l2 * c2),
        m2 * (l2 * l2 + l1 * l2 * c2), m2 * l2 * l2;
    cqdr << h * (2 * qd(0) * qd(1) + qd(1) * qd(1)), -h * qd(0) * qd(0);
    Gr << (m1 + m2) * g * l1 * std::sin(q(0)) + m2 * g * l2 * std::sin(q(0) + q(1)),
        m2 * g * l2 * std::sin(q(0) + q(1));
    worst = std::max({worst, rel(M, Mr), rel(cqd, cqdr), rel(G, Gr)});
  }
  EXPECT_LE(worst, 1e-13);
  // Named points: link frame origins, `end`, and the tip.
  const auto tip = model.world_point("tip");
  GiNaC::exmap at{{sym::coordinate_symbol(c.symbols(), "q1"), 0},
                  {sym::coordinate_symbol(c.symbols(), "q2"), 0}};
  EXPECT_NEAR(GiNaC::ex_to<GiNaC::numeric>(tip[2].subs(at).evalf()).to_double(), -(l1 + l2), 1e-15);
  EXPECT_TRUE(model.points.count("end"));
  EXPECT_TRUE(model.points.count("link1"));
  EXPECT_THROW((void)model.world_point("nowhere"), sym::DefinitionError);
}

// A physical pendulum: a slender rod with its inertia tensor, M = m l²/3, G = m g l/2 sin q.
TEST(Chain, RodPendulumWithInertiaTensor) {
  sym::ChainDef c("rod", {"q"});
  c.gravity = {0, 0, -10};
  auto& j = c.add_joint("j", JT::revolute, "rod");
  j.axis = {0, 2, 0};  // normalized
  j.coordinate = "q";
  j.inertial.mass = 3;
  j.inertial.com = {0, 0, GiNaC::numeric(-1, 2)};
  j.inertial.inertia = {GiNaC::numeric(1, 4), 0, 0, 0, GiNaC::numeric(1, 4), 0, 0, 0, 0};
  const auto sub = sym::make_subsystem(sym::build_chain(c).def);
  Mat M(1, 1);
  Vec G(1), q(1);
  q << 0.4;
  sub->mass({}, q, M);
  sub->gravity({}, q, G);
  EXPECT_NEAR(M(0, 0), 1.0, 1e-15);
  EXPECT_NEAR(G(0), 3 * 10 * 0.5 * std::sin(0.4), 1e-14);
}

// Mobile base with yaw, then a prismatic joint along the base's x axis carrying a point mass:
// polar coordinates on a moving platform.
TEST(Chain, MobileBaseWithYawAndPrismaticJoint) {
  const double M0 = 5, Izz = 0.8, m = 2;
  sym::ChainDef c("cart", {"x", "y", "psi", "r"});
  c.base.enabled = true;
  c.base.x = "x";
  c.base.y = "y";
  c.base.yaw = "psi";
  c.base.inertial.mass = 5;
  c.base.inertial.inertia = {1, 0, 0, 0, 1, 0, 0, 0, sym::exact_number(Izz)};
  auto& j = c.add_joint("slide", JT::prismatic, "slider");
  j.axis = {1, 0, 0};
  j.coordinate = "r";
  j.inertial.mass = 2;
  const auto sub = sym::make_subsystem(sym::build_chain(c).def);
  std::mt19937_64 rng(5);
  double worst = 0;
  for (int k = 0; k < 100; ++k) {
    const Vec q = random_vec(rng, 4, -2, 2), qd = random_vec(rng, 4, -2, 2);
    Mat Ms(4, 4), Mr(4, 4);
    sub->mass({}, q, Ms);
    const double s = std::sin(q(2)), co = std::cos(q(2)), r = q(3);
    Mr << M0 + m, 0, -m * r * s, m * co,  //
        0, M0 + m, m * r * co, m * s,     //
        -m * r * s, m * r * co, Izz + m * r * r, 0, m * co, m * s, 0, m;
    worst = std::max(worst, rel(Ms, Mr));
    // Energy check of C q̇: d/dt T along q̈ = 0 equals q̇ᵀ(½ Ṁ q̇) ... use the identity q̇ᵀ C q̇ = ½ q̇ᵀ Ṁ
    // q̇.
    Vec cqd(4);
    sub->coriolis_times_qd({}, q, qd, cqd);
    const double eps = 1e-6;
    Mat Mp(4, 4), Mm(4, 4);
    sub->mass({}, q + eps * qd, Mp);
    sub->mass({}, q - eps * qd, Mm);
    const double half = 0.5 * qd.dot((Mp - Mm) / (2 * eps) * qd);
    EXPECT_NEAR(qd.dot(cqd), half, 1e-7 * (1 + std::abs(half)));
  }
  EXPECT_LE(worst, 1e-13);
}

// A tree: two pendulums hanging from one root (parent: root) do not couple.
TEST(Chain, TreeBranchesAreIndependent) {
  sym::ChainDef c("tree", {"a", "b"});
  c.gravity = {0, 0, -10};
  for (const char* q : {"a", "b"}) {
    auto& j = c.add_joint(std::string("j") + q, JT::revolute, std::string("l") + q);
    j.parent = "root";
    j.origin.xyz = {q[0] == 'a' ? 1 : -1, 0, 0};
    j.axis = {0, 1, 0};
    j.coordinate = q;
    j.inertial.mass = q[0] == 'a' ? 1 : 2;
    j.inertial.com = {0, 0, -1};
  }
  const auto model = sym::build_chain(c);
  const auto sub = sym::make_subsystem(model.def);
  Vec q(2);
  q << 0.3, -0.7;
  Mat M(2, 2);
  Vec G(2);
  sub->mass({}, q, M);
  sub->gravity({}, q, G);
  EXPECT_NEAR(M(0, 1), 0.0, 1e-15);
  EXPECT_NEAR(M(0, 0), 1.0, 1e-15);
  EXPECT_NEAR(M(1, 1), 2.0, 1e-15);
  EXPECT_NEAR(G(0), 10 * std::sin(0.3), 1e-14);
  EXPECT_NEAR(G(1), 20 * std::sin(-0.7), 1e-14);
  EXPECT_TRUE(model.points.count("la") && model.points.count("lb"));
}

TEST(Chain, DefinitionErrors) {
  sym::ChainDef c("bad", {"a"});
  auto& j = c.add_joint("j", JT::revolute, "l");
  j.coordinate = "b";
  j.inertial.mass = 1;
  j.inertial.com = {1, 0, 0};
  try {
    (void)sym::build_chain(c);
    ADD_FAILURE();
  } catch (const sym::DefinitionError& e) {
    EXPECT_NE(std::string(e.what()).find("joint 'j': 'b' is not a coordinate"), std::string::npos)
        << e.what();
  }
  c.joints[0].coordinate = "a";
  c.joints[0].axis = {0, 0, 0};
  EXPECT_THROW((void)sym::build_chain(c), sym::DefinitionError);
  c.joints[0].axis = {0, 0, 1};
  c.joints[0].parent = "nowhere";
  EXPECT_THROW((void)sym::build_chain(c), sym::DefinitionError);
}

}  // namespace
