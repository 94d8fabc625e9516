// Derivations (src/symbolic/definitions.cpp) of textbook subsystems and constraints, checked
// against hand-written formulas and finite differences that do not use the derivation code.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

#include "helpers.hpp"
#include "ukdyn/symbolic/definitions.hpp"

namespace {

namespace sym = ukdyn::symbolic;
using GiNaC::ex;
using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;

// ------------------------------------------------------------------------------------ subsystems

// Double pendulum (point masses): textbook M, C q̇ and G, written by hand here.
TEST(SymbolicSubsystem, DoublePendulumMatchesTextbook) {
  sym::SubsystemDef d("double_pendulum", {"dp_a", "dp_b"});
  d.parameter("m1", 1.3);
  d.parameter("m2", 0.7);
  d.parameter("l1", 0.9);
  d.parameter("l2", 1.1);
  d.let("x1", d.parse("l1*sin(dp_a)"));
  d.let("z1", d.parse("-l1*cos(dp_a)"));
  auto& b1 = d.add_body("bob1");
  b1.mass = d.parse("m1");
  b1.com = {d.parse("x1"), 0, d.parse("z1")};
  auto& b2 = d.add_body("bob2");
  b2.mass = d.parse("m2");
  b2.com = {d.parse("x1 + l2*sin(dp_b)"), 0, d.parse("z1 - l2*cos(dp_b)")};
  d.gravity = {0, 0, d.parse("-9.81")};
  auto sub = sym::make_subsystem(d);
  const double m1 = 1.3, m2 = 0.7, l1 = 0.9, l2 = 1.1, g = 9.81;
  std::mt19937_64 rng(5);
  for (int k = 0; k < 100; ++k) {
    Vec q(2), qd(2);
    q << uktest::uniform(rng, -3, 3), uktest::uniform(rng, -3, 3);
    qd << uktest::uniform(rng, -3, 3), uktest::uniform(rng, -3, 3);
    const double c12 = std::cos(q(0) - q(1)), s12 = std::sin(q(0) - q(1));
    Mat Mref(2, 2);
    Mref << (m1 + m2) * l1 * l1, m2 * l1 * l2 * c12, m2 * l1 * l2 * c12, m2 * l2 * l2;
    Vec cref(2), gref(2);
    cref << m2 * l1 * l2 * s12 * qd(1) * qd(1), -m2 * l1 * l2 * s12 * qd(0) * qd(0);
    gref << (m1 + m2) * g * l1 * std::sin(q(0)), m2 * g * l2 * std::sin(q(1));
    Mat M(2, 2);
    Vec c(2), G(2);
    sub->mass({}, q, M);
    sub->coriolis_times_qd({}, q, qd, c);
    sub->gravity({}, q, G);
    EXPECT_LT((M - Mref).norm(), 1e-13);
    EXPECT_LT((c - cref).norm(), 1e-13);
    EXPECT_LT((G - gref).norm(), 1e-13);
    EXPECT_NEAR(sub->kinetic({}, q, qd), 0.5 * qd.dot(Mref * qd), 1e-13);
    // dynamics() (one combined tape, used by forward()) writes every entry and agrees with the
    // three separate tapes and with the textbook.
    Mat M3 = Mat::Constant(2, 2, 123.0);
    Vec c3 = Vec::Constant(2, 123.0), G3 = Vec::Constant(2, 123.0);
    sub->dynamics({}, q, qd, M3, c3, G3);
    EXPECT_LE((M3 - M).norm(), 1e-15 * (1.0 + M.norm()));
    EXPECT_LE((c3 - c).norm(), 1e-15 * (1.0 + c.norm()));
    EXPECT_LE((G3 - G).norm(), 1e-15 * (1.0 + G.norm()));
    EXPECT_LT((M3 - Mref).norm(), 1e-13);
    EXPECT_LT((c3 - cref).norm(), 1e-13);
  }
}

// A slender rod yawing by psi and pitching by th, inertia from a rotation matrix and a full tensor:
// T_rot = ½ I (th_dot² + cos² th psi_dot²) (the exact rigid body; the paper's scalar model would
// give ½ I (th_dot² + psi_dot²)).
TEST(SymbolicSubsystem, RotationMatrixGivesExactRigidBodyInertia) {
  for (sym::Frame frame : {sym::Frame::body, sym::Frame::world}) {
    sym::SubsystemDef d("rod", {"rod_psi", "rod_th"});
    d.parameter("I", 0.3);
    d.let("cp", d.parse("cos(rod_psi)"));
    d.let("sp", d.parse("sin(rod_psi)"));
    d.let("ct", d.parse("cos(rod_th)"));
    d.let("st", d.parse("sin(rod_th)"));
    auto& b = d.add_body("rod");
    b.mass = 0;
    b.com = {0, 0, 0};
    // R = Rz(psi) Ry(-th): body x along the rod, pitched up by th.
    b.rotation =
        std::array<ex, 9>{d.parse("cp*ct"), d.parse("-sp"),    d.parse("-cp*st"), d.parse("sp*ct"),
                          d.parse("cp"),    d.parse("-sp*st"), d.parse("st"),     0,
                          d.parse("ct")};
    b.inertia_kind = sym::BodyDef::InertiaKind::tensor;
    b.inertia_frame = sym::Frame::body;
    b.inertia_tensor = {0, 0, 0, 0, d.parse("I"), 0, 0, 0, d.parse("I")};
    if (frame == sym::Frame::world) {
      // The same rod with a world-frame tensor is only right for a spherical inertia: use I·1 and
      // compare with ½ I |ω|² = ½ I (th_dot² + psi_dot²).
      b.inertia_frame = sym::Frame::world;
      b.inertia_tensor = {d.parse("I"), 0, 0, 0, d.parse("I"), 0, 0, 0, d.parse("I")};
    }
    auto sub = sym::make_subsystem(d);
    Vec q(2);
    q << 0.4, 0.7;
    Mat M(2, 2);
    sub->mass({}, q, M);
    const double expect = frame == sym::Frame::body ? 0.3 * std::cos(0.7) * std::cos(0.7) : 0.3;
    EXPECT_NEAR(M(0, 0), expect, 1e-14);
    EXPECT_NEAR(M(1, 1), 0.3, 1e-14);
    EXPECT_NEAR(M(0, 1), 0.0, 1e-14);
  }
}

// C q̇ from the Christoffel code against the Lagrangian identity C q̇ = Ṁ q̇ − ∂T/∂q, with Ṁ and ∂T/∂q
// by central differences of the M tape and of the separate kinetic-energy tape; G against −∂V/∂q...
// by differences of V; and Ṁ − 2C skew-symmetric.
TEST(SymbolicSubsystem, ChristoffelTermsAgreeWithFiniteDifferences) {
  // A 3-DOF arm on a sliding base, with a spring potential: everything couples.
  sym::SubsystemDef d("fd_arm", {"fd_x", "fd_a", "fd_b"});
  d.parameter("l", 0.8);
  d.parameter("k", 3.0);
  auto& base = d.add_body("base");
  base.mass = 5;
  base.com = {d.parse("fd_x"), 0, 0};
  auto& l1 = d.add_body("l1");
  l1.mass = 2;
  l1.com = {d.parse("fd_x + l/2*cos(fd_a)"), 0, d.parse("l/2*sin(fd_a)")};
  l1.inertia_kind = sym::BodyDef::InertiaKind::scalar;
  l1.inertia_scalar = d.parse("0.1");
  l1.angular_velocity = std::array<ex, 3>{0, d.parse("fd_a_dot"), 0};
  auto& l2 = d.add_body("l2");
  l2.mass = 1;
  l2.com = {d.parse("fd_x + l*cos(fd_a) + l/2*cos(fd_a + fd_b)"), d.parse("0.1*sin(fd_b)"),
            d.parse("l*sin(fd_a) + l/2*sin(fd_a + fd_b)")};
  l2.inertia_kind = sym::BodyDef::InertiaKind::scalar;
  l2.inertia_scalar = d.parse("0.05");
  l2.angular_velocity = std::array<ex, 3>{0, d.parse("fd_a_dot + fd_b_dot"), 0};
  d.gravity = {0, 0, -9.8};
  d.extra_potential = d.parse("k/2*fd_x^2");
  auto sub = sym::make_subsystem(d);
  std::mt19937_64 rng(11);
  const double h = 1e-5;
  for (int k = 0; k < 30; ++k) {
    Vec q(3), qd(3);
    for (int i = 0; i < 3; ++i) {
      q(i) = uktest::uniform(rng, -2, 2);
      qd(i) = uktest::uniform(rng, -2, 2);
    }
    Mat Mp(3, 3), Mm(3, 3), Mdot(3, 3), C(3, 3);
    sub->mass({}, q + h * qd, Mp);
    sub->mass({}, q - h * qd, Mm);
    Mdot = (Mp - Mm) / (2 * h);
    Vec dTdq(3), dVdq(3);
    for (int i = 0; i < 3; ++i) {
      Vec e = Vec::Zero(3);
      e(i) = h;
      dTdq(i) = (sub->kinetic({}, q + e, qd) - sub->kinetic({}, q - e, qd)) / (2 * h);
      dVdq(i) = (sub->potential({}, q + e) - sub->potential({}, q - e)) / (2 * h);
    }
    Vec cqd(3), G(3);
    sub->coriolis_times_qd({}, q, qd, cqd);
    sub->gravity({}, q, G);
    sub->coriolis({}, q, qd, C);
    EXPECT_LT((cqd - (Mdot * qd - dTdq)).norm(), 1e-7 * (1 + cqd.norm()));
    EXPECT_LT((C * qd - cqd).norm(), 1e-12 * (1 + cqd.norm()));
    EXPECT_LT((G - dVdq).norm(), 1e-7 * (1 + G.norm()));
    const Mat S = Mdot - 2 * C;
    EXPECT_LT((S + S.transpose()).norm(), 1e-7 * (1 + C.norm()));
  }
}

TEST(SymbolicSubsystem, DefinitionErrorsAreSpecific) {
  {
    sym::SubsystemDef d("s", {"e_x", "e_y"});
    auto& b = d.add_body("b");
    b.mass = 1;
    b.com = {d.parse("e_x"), 0, 0};
    try {
      (void)sym::make_subsystem(d);
      FAIL() << "a coordinate in no body must be an error";
    } catch (const sym::DefinitionError& e) {
      EXPECT_EQ(e.coordinate, 1);
      EXPECT_NE(std::string(e.what()).find("'e_y' appears in no body"), std::string::npos)
          << e.what();
    }
  }
  {
    sym::SubsystemDef d("s", {"e_x"});
    auto& b = d.add_body("b");
    b.mass = 1;
    b.com = {d.parse("e_x_dot"), 0, 0};
    EXPECT_THROW((void)sym::make_subsystem(d), sym::DefinitionError);
  }
  {
    sym::SubsystemDef d("s", {"e_x"});
    auto& b = d.add_body("b");
    b.mass = 1;
    b.com = {d.parse("e_x"), 0, 0};
    b.inertia_kind = sym::BodyDef::InertiaKind::scalar;
    b.inertia_scalar = 1;
    b.angular_velocity = std::array<ex, 3>{d.parse("e_x_dot^2"), 0, 0};  // not linear in velocities
    EXPECT_THROW((void)sym::make_subsystem(d), sym::DefinitionError);
  }
  {
    sym::SubsystemDef d("s", {"e_x"});
    auto& b = d.add_body("b");
    b.mass = 1;
    b.com = {d.parse("e_x"), 0, 0};
    b.inertia_kind = sym::BodyDef::InertiaKind::tensor;
    b.inertia_tensor = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    b.rotation = std::array<ex, 9>{d.parse("cos(e_x)"), 0, 0, 0, 1, 0, 0, 0, 1};  // not a rotation
    EXPECT_THROW((void)sym::make_subsystem(d), sym::DefinitionError);
  }
  // M singular at a configuration: a point mass on a circle of radius x (x = 0 leaves the angle
  // free).
  {
    sym::SubsystemDef d("s", {"e_r", "e_phi"});
    auto& b = d.add_body("b");
    b.mass = 1;
    b.com = {d.parse("e_r*cos(e_phi)"), d.parse("e_r*sin(e_phi)"), 0};
    auto sub = sym::make_subsystem(d);
    Vec q(2);
    q << 1.0, 0.3;
    EXPECT_EQ(sym::mass_matrix_problem(*sub, q), "");
    q << 0.0, 0.3;
    const std::string msg = sym::mass_matrix_problem(*sub, q);
    EXPECT_NE(msg.find("'e_phi'"), std::string::npos) << msg;
    EXPECT_EQ(msg.find("'e_r'"), std::string::npos) << msg;
  }
}

// ------------------------------------------------------------------------------------ constraints

// b against a finite difference of the velocity residual along q(t+h) = q + h q̇ (q̈ = 0):
// b = −d/dt(A q̇ + Φ_t)|_{q̈=0}. Independent of the derivation of b.
void check_b_by_differences(const ukdyn::Constraint& c, Index n, std::mt19937_64& rng) {
  const double h = 1e-5;
  const Index m = c.rows();
  for (int k = 0; k < 20; ++k) {
    Vec q(n), qd(n);
    for (Index i = 0; i < n; ++i) {
      q(i) = uktest::uniform(rng, -2, 2);
      qd(i) = uktest::uniform(rng, -2, 2);
    }
    const double t = uktest::uniform(rng, 0, 3);
    Mat A(m, n);
    Vec b(m), vp(m), vm(m), phid(m), pp(m), pm(m);
    c.evaluate({t}, q, qd, A, b);
    c.velocity_residual({t + h}, q + h * qd, qd, vp);
    c.velocity_residual({t - h}, q - h * qd, qd, vm);
    EXPECT_LT((b + (vp - vm) / (2 * h)).norm(), 1e-6 * (1 + b.norm()));
    c.velocity_residual({t}, q, qd, phid);
    // Holonomic rows: Φ̇ = dΦ/dt along the path.
    c.position_residual({t + h}, q + h * qd, pp);
    c.position_residual({t - h}, q - h * qd, pm);
    (void)pp;
    (void)pm;
  }
}

TEST(SymbolicConstraint, HolonomicWithTimeMatchesHandDerivation) {
  const std::vector<std::string> coords = {"hc_x", "hc_y"};
  sym::ConstraintDef d("circle", sym::ConstraintDef::Kind::holonomic, coords);
  d.parameter("L", 1.5);
  // A point on a circle whose radius breathes: x² + y² − (L + 0.1 sin 2t)² = 0.
  d.add_row("circle", d.parse("hc_x^2 + hc_y^2 - (L + 0.1*sin(2*t))^2"));
  auto c = sym::make_constraint(d);
  std::mt19937_64 rng(8);
  for (int k = 0; k < 20; ++k) {
    Vec q(2), qd(2);
    q << uktest::uniform(rng, -2, 2), uktest::uniform(rng, -2, 2);
    qd << uktest::uniform(rng, -2, 2), uktest::uniform(rng, -2, 2);
    const double t = uktest::uniform(rng, 0, 3);
    Mat A(1, 2);
    Vec b(1), phi(1), phid(1);
    c->evaluate({t}, q, qd, A, b);
    c->position_residual({t}, q, phi);
    c->velocity_residual({t}, q, qd, phid);
    const double r = 1.5 + 0.1 * std::sin(2 * t), rd = 0.2 * std::cos(2 * t),
                 rdd = -0.4 * std::sin(2 * t);
    // Φ̈ = 2(ẋ² + ẏ² + x ẍ + y ÿ) − 2(ṙ² + r r̈) = 0 ⇒ A = 2[x y], b = −2(ẋ² + ẏ²) + 2(ṙ² + r r̈).
    EXPECT_NEAR(A(0, 0), 2 * q(0), 1e-13);
    EXPECT_NEAR(A(0, 1), 2 * q(1), 1e-13);
    EXPECT_NEAR(b(0), -2 * qd.squaredNorm() + 2 * (rd * rd + r * rdd), 1e-12);
    EXPECT_NEAR(phi(0), q.squaredNorm() - r * r, 1e-13);
    EXPECT_NEAR(phid(0), 2 * q.dot(qd) - 2 * r * rd, 1e-13);
  }
  check_b_by_differences(*c, 2, rng);
}

TEST(SymbolicConstraint, NonholonomicKnifeEdge) {
  const std::vector<std::string> coords = {"ke_x", "ke_y", "ke_th"};
  sym::ConstraintDef d("knife", sym::ConstraintDef::Kind::nonholonomic, coords);
  d.add_row("knife", d.parse("sin(ke_th)*ke_x_dot - cos(ke_th)*ke_y_dot"));
  auto c = sym::make_constraint(d);
  std::mt19937_64 rng(9);
  for (int k = 0; k < 20; ++k) {
    Vec q(3), qd(3);
    for (int i = 0; i < 3; ++i) {
      q(i) = uktest::uniform(rng, -2, 2);
      qd(i) = uktest::uniform(rng, -2, 2);
    }
    Mat A(1, 3);
    Vec b(1);
    c->evaluate({}, q, qd, A, b);
    EXPECT_NEAR(A(0, 0), std::sin(q(2)), 1e-15);
    EXPECT_NEAR(A(0, 1), -std::cos(q(2)), 1e-15);
    EXPECT_NEAR(A(0, 2), 0.0, 1e-15);
    EXPECT_NEAR(b(0), -(std::cos(q(2)) * qd(0) + std::sin(q(2)) * qd(1)) * qd(2), 1e-13);
  }
  check_b_by_differences(*c, 3, rng);
}

TEST(SymbolicConstraint, DefinitionErrors) {
  const std::vector<std::string> coords = {"ce_x", "ce_y"};
  {
    sym::ConstraintDef d("c", sym::ConstraintDef::Kind::holonomic, coords);
    d.add_row("ok", d.parse("ce_x - ce_y"));
    d.add_row("vel", d.parse("ce_x_dot"));
    try {
      (void)sym::make_constraint(d);
      FAIL();
    } catch (const sym::DefinitionError& e) {
      EXPECT_EQ(e.row, 1);
    }
  }
  {
    sym::ConstraintDef d("c", sym::ConstraintDef::Kind::nonholonomic, coords);
    d.add_row("sq", d.parse("ce_x_dot^2 + ce_y_dot"));
    EXPECT_THROW((void)sym::make_constraint(d), sym::DefinitionError);
  }
  {
    sym::ConstraintDef d("c", sym::ConstraintDef::Kind::holonomic, coords);
    d.add_row("none", d.parse("sin(t) - 1"));
    EXPECT_THROW((void)sym::make_constraint(d), sym::DefinitionError);
  }
  {
    sym::ConstraintDef d("c", sym::ConstraintDef::Kind::holonomic, coords);
    EXPECT_THROW((void)sym::make_constraint(d), sym::DefinitionError);  // no rows
  }
}

}  // namespace
