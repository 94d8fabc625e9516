// Ready-made constraint kinds (src/symbolic/constraint_kinds.cpp) against hand-written Φ.
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

// The constraint kinds in C++: a pendulum tip held on a moving point and a linear angle relation.
TEST(ChainConstraints, KindsGiveTheHandWrittenRows) {
  sym::ChainDef c("arm", {"a1", "a2"});
  auto& j1 = c.add_joint("j1", JT::revolute, "l1");
  j1.coordinate = "a1";
  j1.inertial.mass = 1;
  j1.inertial.com = {1, 0, 0};
  auto& j2 = c.add_joint("j2", JT::revolute, "l2");
  j2.origin.xyz = {1, 0, 0};
  j2.coordinate = "a2";
  j2.inertial.mass = 1;
  j2.inertial.com = {1, 0, 0};
  c.add_point("tip", "l2", {1, 0, 0});
  const auto model = sym::build_chain(c);
  const std::vector<std::string> coords{"a1", "a2"};
  // The chain's table: the tip is an expression of the chain's coordinate symbols.
  sym::ConstraintDef kinds("k", sym::ConstraintDef::Kind::holonomic, coords, c.symbol_table());
  const auto tip = model.world_point("tip");
  sym::add_point_trajectory(kinds, "p", tip,
                            {sym::time_expression(ukdyn::TimeFunction::make_cosine(0.5, 0.25, 2.0),
                                                  kinds.symbols().time()),
                             std::nullopt, std::nullopt},
                            {0.5, 0, 0});
  sym::add_angle_relation(kinds, "rel", {{"a1", 2}, {"a2", -1}}, GiNaC::Pi / 3);
  sym::ConstraintDef hand("h", sym::ConstraintDef::Kind::holonomic, coords);
  hand.add_row("p_x", hand.parse("cos(a1) + cos(a1 + a2) - 0.5 - (0.5 + 0.25*cos(2*t))"));
  hand.add_row("rel", hand.parse("2*a1 - a2 - pi/3"));
  const auto ck = sym::make_constraint(kinds), ch = sym::make_constraint(hand);
  EXPECT_EQ(ck->row_names(), (std::vector<std::string>{"p_x", "rel"}));
  std::mt19937_64 rng(9);
  double worst = 0;
  for (int k = 0; k < 100; ++k) {
    const Vec q = random_vec(rng, 2, -3, 3), qd = random_vec(rng, 2, -3, 3);
    const double t = uktest::uniform(rng, 0, 5);
    Mat A1(2, 2), A2(2, 2);
    Vec b1(2), b2(2);
    ck->evaluate({t}, q, qd, A1, b1);
    ch->evaluate({t}, q, qd, A2, b2);
    worst = std::max({worst, rel(A1, A2), rel(b1, b2)});
  }
  EXPECT_LE(worst, 1e-13);
  sym::ConstraintDef bad("b", sym::ConstraintDef::Kind::holonomic, coords);
  EXPECT_THROW(sym::add_angle_relation(bad, "r", {{"zz", 1}}, 0), sym::DefinitionError);
  EXPECT_THROW(sym::add_angle_relation(bad, "r", {{"a1", 0}}, 0), sym::DefinitionError);
}

}  // namespace
