// A free body's M, C q̇ and G in closed form (src/symbolic/free_body_dynamics.hpp, docs/free-bodies.md
// "The closed form"): against the derivation's own dynamics tape (the other formulation: GiNaC's
// M = ∂²T/∂q̇², Christoffel C q̇ and G = ∂V/∂q, compiled) at random states off |u| = 1 with a full
// inertia tensor, and the cases where the closed form must not be taken.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "symbolic/free_body_dynamics.hpp"
#include "ukdyn/model/system.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/symbolic/definitions.hpp"
#include "ukdyn/symbolic/free_body.hpp"

namespace {

using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;
namespace sym = ukdyn::symbolic;

// A full (non-diagonal) positive-definite inertia tensor, row-major.
constexpr std::array<double, 9> kInertia = {0.27,  0.013,  -0.021, 0.013, 0.31,
                                            0.017, -0.021, 0.017,  0.53};

struct Values {
  Mat M = Mat::Zero(7, 7);
  Vec Cqd = Vec::Zero(7), G = Vec::Zero(7);
};

// M, C q̇, G from the dynamics tape's outputs (M's upper triangle row by row, C q̇, G).
Values from_tape(const sym::DerivedSubsystem& s, const Vec& q, const Vec& qd) {
  const sym::Tape& tape = s.dynamics_tape();
  std::vector<double> out(tape.outputs());
  tape.eval(0.0, q.data(), qd.data(), out.data());
  Values v;
  std::size_t k = 0;
  for (Index i = 0; i < 7; ++i) {
    for (Index j = i; j < 7; ++j) {
      v.M(i, j) = out[k];
      v.M(j, i) = out[k++];
    }
  }
  for (Index i = 0; i < 7; ++i) v.Cqd(i) = out[k++];
  for (Index i = 0; i < 7; ++i) v.G(i) = out[k++];
  return v;
}

Values from_dynamics(const sym::DerivedSubsystem& s, const Vec& q, const Vec& qd) {
  Values v;
  const ukdyn::EvalContext ctx{0.0};
  s.dynamics(ctx, q, qd, v.M, v.Cqd, v.G);
  return v;
}

// max |a − b| / max |b| (0 for b = 0 only if a = 0 too).
double relative(const Mat& a, const Mat& b) {
  const double scale = b.cwiseAbs().maxCoeff();
  const double diff = (a - b).cwiseAbs().maxCoeff();
  return scale > 0.0 ? diff / scale : diff;
}

// The worst relative difference of M, C q̇, G between the closed form and the tape at 200 random
// states: p, q̇ arbitrary, u of norm 0.3 … 2 (not unit: the identities hold for any u).
double worst_against_tape(const sym::DerivedSubsystem& s) {
  std::mt19937_64 rng(20100405);
  std::uniform_real_distribution<double> U(-1.0, 1.0), norm(0.3, 2.0);
  double worst = 0.0;
  for (int k = 0; k < 200; ++k) {
    Vec q(7), qd(7);
    for (Index i = 0; i < 7; ++i) {
      q(i) = 3.0 * U(rng);
      qd(i) = 4.0 * U(rng);
    }
    q.tail(4) *= norm(rng) / q.tail(4).norm();
    const Values c = from_dynamics(s, q, qd), t = from_tape(s, q, qd);
    worst = std::max({worst, relative(c.M, t.M), relative(c.Cqd, t.Cqd), relative(c.G, t.G)});
  }
  return worst;
}

TEST(FreeBodyClosedForm, EqualsTheTapeOffTheUnitSphereWithAFullInertia) {
  const auto sub =
      sym::make_subsystem(sym::free_body_definition("b", 5.0, kInertia, {0.4, -1.3, -9.81}));
  ASSERT_NE(sub->closed_form(), nullptr);
  const double worst = worst_against_tape(*sub);
  std::printf("closed form vs tape, 200 states: max relative difference %.3g\n", worst);
  EXPECT_LE(worst, 1e-14);
}

TEST(FreeBodyClosedForm, EveryValuePathAgreesWithDynamics) {
  const auto sub = sym::make_subsystem(sym::free_body_definition("b", 2.5, kInertia, {0, 0, -3}));
  ASSERT_NE(sub->closed_form(), nullptr);
  Vec q(7), qd(7);
  q << 0.1, -0.2, 0.3, 0.9, -0.3, 0.5, 0.2;
  qd << 0.4, 0.1, -0.7, 0.3, -1.1, 0.6, 0.8;
  const Values v = from_dynamics(*sub, q, qd);
  const ukdyn::EvalContext ctx{0.0};
  Mat M(7, 7);
  Vec Cqd(7), G(7);
  sub->mass(ctx, q, M);
  sub->coriolis_times_qd(ctx, q, qd, Cqd);
  sub->gravity(ctx, q, G);
  EXPECT_EQ(M, v.M);
  EXPECT_EQ(Cqd, v.Cqd);
  EXPECT_EQ(G, v.G);
  // G = −m g exactly on the position rows, 0 on the quaternion's.
  EXPECT_EQ(G(2), 2.5 * 3.0);
  EXPECT_EQ(G.tail(4), Vec::Zero(4));
  // dynamics_tangent()'s values are dynamics()'s, its tangents the tape's.
  Mat dM(7, 7), M2(7, 7);
  Vec dC(7), dG(7), C2(7), G2(7);
  const Vec dq = Vec::LinSpaced(7, -0.3, 0.5), dqd = Vec::LinSpaced(7, 0.2, -0.4);
  sub->dynamics_tangent(ctx, q, qd, dq, dqd, M2, C2, G2, dM, dC, dG);
  EXPECT_EQ(M2, v.M);
  EXPECT_EQ(C2, v.Cqd);
  EXPECT_EQ(G2, v.G);
  // The tangent against a central difference of the closed form (an O(h²) check).
  const double h = 1e-5;
  const Values p = from_dynamics(*sub, q + h * dq, qd + h * dqd);
  const Values m = from_dynamics(*sub, q - h * dq, qd - h * dqd);
  EXPECT_LE(relative((p.M - m.M) / (2 * h), dM), 1e-8);
  EXPECT_LE(relative((p.Cqd - m.Cqd) / (2 * h), dC), 1e-8);
}

// A free body built by hand from a definition with a parameter mass and a potential linear in p
// (a constant force): recognised from its energies, with the parameter's value and the force in G.
TEST(FreeBodyClosedForm, RecognisedFromTheEnergiesWithParametersAndALinearPotential) {
  sym::SubsystemDef def("c", {"a", "b", "e", "s0", "s1", "s2", "s3"});
  const GiNaC::ex m = def.parameter("mc", 3.25);
  def.gravity = {0, 0, -9.81};
  def.extra_potential = def.parse("2*a - 0.5*e");
  sym::add_free_body(def, m,
                     {def.parse("27/100"), def.parse("13/1000"), def.parse("-21/1000"),
                      def.parse("13/1000"), def.parse("31/100"), def.parse("17/1000"),
                      def.parse("-21/1000"), def.parse("17/1000"), def.parse("53/100")});
  const auto sub = sym::make_subsystem(def);
  ASSERT_NE(sub->closed_form(), nullptr);
  EXPECT_DOUBLE_EQ(sub->closed_form()->mass, 3.25);
  EXPECT_DOUBLE_EQ(sub->closed_form()->inertia4[1], 4 * 0.013);
  EXPECT_DOUBLE_EQ(sub->closed_form()->gravity_force[0], 2.0);
  EXPECT_DOUBLE_EQ(sub->closed_form()->gravity_force[2], 3.25 * 9.81 - 0.5);
  EXPECT_LE(worst_against_tape(*sub), 1e-14);
}

// Where the closed form is not the derivation, the tapes stay.
TEST(FreeBodyClosedForm, NotTakenWhereItIsNotTheDerivation) {
  const auto none = [](sym::SubsystemDef& def) {
    return sym::make_subsystem(def)->closed_form() == nullptr;
  };
  {  // a potential of the quaternion (a torque)
    auto def = sym::free_body_definition("b", 1.0, kInertia, {0, 0, -9.81});
    def.extra_potential = def.parse("b_qx^2");
    EXPECT_TRUE(none(def));
  }
  {  // a potential quadratic in p (a spring): G not constant
    auto def = sym::free_body_definition("b", 1.0, kInertia, {0, 0, -9.81});
    def.extra_potential = def.parse("b_x^2");
    EXPECT_TRUE(none(def));
  }
  {  // the CoM off the coordinates' point: T has cross terms
    sym::SubsystemDef def("b", sym::free_body_coordinates("b"));
    auto& body = sym::add_free_body(def, 1, {1, 0, 0, 0, 2, 0, 0, 0, 3});
    body.com[0] = body.com[0] + def.parse("b_qx/5");
    EXPECT_TRUE(none(def));
  }
  {  // a second body on the same coordinates
    auto def = sym::free_body_definition("b", 1.0, kInertia, {0, 0, -9.81});
    auto& extra = def.add_body("bead");
    extra.mass = 1;
    extra.com = {def.parse("b_x"), def.parse("b_qy"), 0};
    EXPECT_TRUE(none(def));
  }
  {  // a mass of t
    sym::SubsystemDef def("b", sym::free_body_coordinates("b"));
    sym::add_free_body(def, def.parse("2 + t"), {1, 0, 0, 0, 2, 0, 0, 0, 3});
    EXPECT_TRUE(none(def));
  }
  {  // 7 coordinates, not a free body: seven point masses on a line
    sym::SubsystemDef def("c", {"c1", "c2", "c3", "c4", "c5", "c6", "c7"});
    for (const char* c : {"c1", "c2", "c3", "c4", "c5", "c6", "c7"}) {
      auto& b = def.add_body(std::string("m") + c);
      b.mass = 1;
      b.com = {def.parse(c), 0, 0};
    }
    EXPECT_TRUE(none(def));
  }
}

// The scenarios' free bodies (the plate of two_pandas_weld.yaml, the heavy top, the tumbling
// body) take the closed form, and it agrees with their tapes.
TEST(FreeBodyClosedForm, ScenarioFreeBodiesTakeIt) {
  for (const char* file : {"two_pandas_weld", "heavy_top", "free_body_dzhanibekov"}) {
    const auto sc =
        ukdyn::load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/" + file + ".yaml");
    int found = 0;
    for (const auto& s : sc.system->subsystems()) {
      const auto* d = dynamic_cast<const sym::DerivedSubsystem*>(s.get());
      if (d == nullptr || d->dof() != 7) continue;
      ASSERT_NE(d->closed_form(), nullptr) << file << ": " << d->name();
      EXPECT_LE(worst_against_tape(*d), 1e-14) << file;
      ++found;
    }
    EXPECT_EQ(found, 1) << file;
  }
}

}  // namespace
