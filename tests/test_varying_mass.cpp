// Time-varying masses in definitions subsystems (docs/definitions.md, "Time-varying masses"):
// L(q, q̇, t) = T − V with T = ½ q̇ᵀ M(q, t) q̇, Lagrange's equations d/dt ∂T/∂q̇ − ∂T/∂q + ∂V/∂q = Q
// (mass exchanged with a medium at rest: d(m v)/dt = F for a point mass). Checked against a
// closed form, an RK4 of the 1-DoF ODE written here, finite differences of a hand-written
// Lagrangian, the energy balance dE/dt = (τ + Q_nc + Qc)ᵀ q̇ − ∂L/∂t, and a closed loop whose plant
// has the load mass m(1 + 0.2 sin 10t) (docs/control.md).
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>

#include "control_systems.hpp"
#include "helpers.hpp"
#include "ukdyn/output/control_output.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/simulate/control.hpp"
#include "ukdyn/simulate/simulate.hpp"
#include "ukdyn/symbolic/definitions.hpp"

namespace {

namespace sym = ukdyn::symbolic;
using ukdyn::CVecRef;
using ukdyn::Mat;
using ukdyn::Vec;
using ukdyn::VecRef;

// A point mass m(t) = m0 (1 + 0.2 sin 10t) on a vertical line z, gravity g, a spring k z²/2.
std::string point_mass_yaml(double k, double t_end) {
  return "ukdyn: 1\nname: varying_point_mass\ngravity: 9.8\nsubsystems:\n"
         "  - name: body\n    type: definitions\n    coordinates: [z]\n"
         "    parameters: {m0: 2, k: " +
         std::to_string(k) +
         "}\n"
         "    bodies:\n      - {name: p, mass: m0*(1 + 0.2*sin(10*t)), com: [0, 0, z]}\n"
         "    potential: k*z^2/2\n"
         "initial: {q: [1], qd: [0.5]}\n"
         "simulation: {t_end: " +
         std::to_string(t_end) + ", sample_dt: 0.01, abs_tol: 1e-13, rel_tol: 1e-13}\n";
}

struct Traj {
  std::vector<double> t, z, v;
  ukdyn::SimulationStats stats;
};

Traj run(const ukdyn::Scenario& sc) {
  Traj r;
  const ukdyn::ForceFunction tau = [&](double, CVecRef, CVecRef, VecRef out) { out = sc.tau; };
  r.stats = ukdyn::simulate(*sc.system, sc.q0, sc.qd0, tau, sc.sim,
                            [&](double t, CVecRef q, CVecRef qd, const ukdyn::ForwardData&) {
                              r.t.push_back(t);
                              r.z.push_back(q(0));
                              r.v.push_back(qd(0));
                              return true;
                            });
  return r;
}

// (a) Free fall: d(m v)/dt = −m g, so m(t) v(t) = m(0) v0 − g ∫₀ᵗ m, with
// ∫₀ᵗ m = m0 (t + 0.02 (1 − cos 10t)): v(t) = (v0 − g (t + 0.02 (1 − cos 10t))) / (1 + 0.2 sin
// 10t).
TEST(VaryingMass, FallingPointMassMatchesMomentumClosedForm) {
  const auto sc = ukdyn::load_scenario_text(point_mass_yaml(0.0, 3.0), "fall.yaml");
  ASSERT_TRUE(sc.system->subsystems()[0]->time_varying());
  const Traj r = run(sc);
  ASSERT_EQ(r.stats.status, ukdyn::RunStatus::completed) << r.stats.message;
  const double g = 9.8, v0 = 0.5;
  double worst = 0.0, naive_gap = 0.0;
  for (std::size_t i = 0; i < r.t.size(); ++i) {
    const double t = r.t[i];
    const double v = (v0 - g * (t + 0.02 * (1 - std::cos(10 * t)))) / (1 + 0.2 * std::sin(10 * t));
    worst = std::max(worst, std::abs(r.v[i] - v));
    naive_gap = std::max(naive_gap, std::abs(v - (v0 - g * t)));  // m v̇ = F would give v0 − g t
  }
  EXPECT_LT(worst, 1e-10);
  EXPECT_GT(naive_gap, 0.1);  // the closed form is not the constant-mass fall: the test can fail
  std::printf("falling m(t): max |v - closed form| = %.3e over %zu samples (vs m vdot = F: %.3f)\n",
              worst, r.t.size(), naive_gap);
}

// (a) On a spring: m z̈ = −k z − m g − ṁ ż, an RK4 of that ODE written here (step 1e-4).
TEST(VaryingMass, PointMassOnASpringMatchesAnIndependentRk4) {
  const double k = 30.0, g = 9.8, m0 = 2.0;
  const auto sc = ukdyn::load_scenario_text(point_mass_yaml(k, 3.0), "spring.yaml");
  const Traj r = run(sc);
  ASSERT_EQ(r.stats.status, ukdyn::RunStatus::completed) << r.stats.message;
  auto f = [&](double t, double z, double v, double& dz, double& dv) {
    const double m = m0 * (1 + 0.2 * std::sin(10 * t)), md = m0 * 2.0 * std::cos(10 * t);
    dz = v;
    dv = (-k * z - m * g - md * v) / m;
  };
  double z = 1.0, v = 0.5, t = 0.0, worst = 0.0;
  const double h = 1e-4;
  std::size_t i = 0;
  while (i < r.t.size()) {
    if (std::abs(t - r.t[i]) < 1e-9) {
      worst = std::max({worst, std::abs(r.z[i] - z), std::abs(r.v[i] - v)});
      ++i;
      if (i == r.t.size()) break;
    }
    double k1z, k1v, k2z, k2v, k3z, k3v, k4z, k4v;
    f(t, z, v, k1z, k1v);
    f(t + h / 2, z + h / 2 * k1z, v + h / 2 * k1v, k2z, k2v);
    f(t + h / 2, z + h / 2 * k2z, v + h / 2 * k2v, k3z, k3v);
    f(t + h, z + h * k3z, v + h * k3v, k4z, k4v);
    z += h / 6 * (k1z + 2 * k2z + 2 * k3z + k4z);
    v += h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v);
    t += h;
  }
  EXPECT_EQ(i, r.t.size());
  EXPECT_LT(worst, 1e-9);
  std::printf("spring m(t): max |(z, v) - RK4| = %.3e over %zu samples\n", worst, r.t.size());
}

// (b) A double pendulum with m1(t), m2(t) and a rotational inertia I(t) on link 2: M q̈ + C q̇ + G
// from dynamics() against d/dt ∂L/∂q̇ − ∂L/∂q by finite differences of the Lagrangian written
// by hand here (∂/∂q̇ by central differences, exact for T quadratic in q̇; d/dt along the path
// q + s q̇ + s²/2 q̈, h = 1e-4), and ∂L/∂t against a central difference in t.
TEST(VaryingMass, LagrangeTermsMatchFiniteDifferencesOfTheLagrangian) {
  sym::SubsystemDef d("vm_pendulum", {"a", "b"});
  d.parameter("l1", 0.9);
  d.parameter("l2", 1.1);
  d.let("x1", d.parse("l1*sin(a)"));
  d.let("z1", d.parse("-l1*cos(a)"));
  auto& b1 = d.add_body("bob1");
  b1.mass = d.parse("1.3*(1 + 0.3*sin(2*t))");
  b1.com = {d.parse("x1"), 0, d.parse("z1")};
  auto& b2 = d.add_body("link2");
  b2.mass = d.parse("0.7 + 0.1*t^2");
  b2.com = {d.parse("x1 + l2*sin(b)"), 0, d.parse("z1 - l2*cos(b)")};
  b2.inertia_kind = sym::BodyDef::InertiaKind::scalar;
  b2.inertia_scalar = d.parse("0.05*(1 + 0.5*cos(3*t))");
  b2.angular_velocity = std::array<GiNaC::ex, 3>{0, d.parse("b_dot"), 0};
  d.gravity = {0, 0, d.parse("-9.81")};
  const auto sub = sym::make_subsystem(d);
  ASSERT_TRUE(sub->time_varying());
  const double l1 = 0.9, l2 = 1.1, g = 9.81;
  auto T = [&](const Vec& q, const Vec& qd, double t) {
    const double m1 = 1.3 * (1 + 0.3 * std::sin(2 * t)), m2 = 0.7 + 0.1 * t * t,
                 I = 0.05 * (1 + 0.5 * std::cos(3 * t));
    return 0.5 * m1 * l1 * l1 * qd(0) * qd(0) +
           0.5 * m2 *
               (l1 * l1 * qd(0) * qd(0) + l2 * l2 * qd(1) * qd(1) +
                2 * l1 * l2 * std::cos(q(0) - q(1)) * qd(0) * qd(1)) +
           0.5 * I * qd(1) * qd(1);
  };
  auto V = [&](const Vec& q, double t) {
    const double m1 = 1.3 * (1 + 0.3 * std::sin(2 * t)), m2 = 0.7 + 0.1 * t * t;
    return -m1 * g * l1 * std::cos(q(0)) - m2 * g * (l1 * std::cos(q(0)) + l2 * std::cos(q(1)));
  };
  auto dTdqd = [&](const Vec& q, const Vec& qd, double t) {
    Vec p(2);
    for (int i = 0; i < 2; ++i) {
      Vec e = Vec::Zero(2);
      e(i) = 1e-3;
      p(i) = (T(q, qd + e, t) - T(q, qd - e, t)) / 2e-3;
    }
    return p;
  };
  std::mt19937_64 rng(12);
  double worst_eq = 0.0, worst_lt = 0.0, worst_e = 0.0, mt_size = 0.0;
  for (int k = 0; k < 50; ++k) {
    Vec q(2), qd(2), qdd(2);
    q << uktest::uniform(rng, -3, 3), uktest::uniform(rng, -3, 3);
    qd << uktest::uniform(rng, -3, 3), uktest::uniform(rng, -3, 3);
    qdd << uktest::uniform(rng, -3, 3), uktest::uniform(rng, -3, 3);
    const double t = uktest::uniform(rng, 0, 4), h = 1e-4;
    // d/dt ∂T/∂q̇ along the path, − ∂T/∂q + ∂V/∂q.
    const Vec qp = q + h * qd + h * h / 2 * qdd, qm = q - h * qd + h * h / 2 * qdd;
    const Vec ddt = (dTdqd(qp, qd + h * qdd, t + h) - dTdqd(qm, qd - h * qdd, t - h)) / (2 * h);
    Vec lhs = ddt;
    for (int i = 0; i < 2; ++i) {
      Vec e = Vec::Zero(2);
      e(i) = 1e-6;
      lhs(i) += -(T(q + e, qd, t) - T(q - e, qd, t)) / 2e-6 + (V(q + e, t) - V(q - e, t)) / 2e-6;
    }
    Mat M(2, 2);
    Vec Cqd(2), G(2);
    double Lt = 0.0;
    Lt = sub->dynamics({t}, q, qd, M, Cqd, G);
    const Vec ours = M * qdd + Cqd + G;
    worst_eq = std::max(worst_eq, (ours - lhs).norm() / (1 + lhs.norm()));
    const double LtFd =
        ((T(q, qd, t + 1e-5) - V(q, t + 1e-5)) - (T(q, qd, t - 1e-5) - V(q, t - 1e-5))) / 2e-5;
    worst_lt = std::max(worst_lt, std::abs(Lt - LtFd) / (1 + std::abs(LtFd)));
    worst_e = std::max({worst_e, std::abs(sub->kinetic({t}, q, qd) - T(q, qd, t)),
                        std::abs(sub->potential({t}, q) - V(q, t))});
    // ∂M/∂t q̇ by a difference of M in t (the part a constant-mass derivation would miss).
    Mat Mp(2, 2), Mm(2, 2);
    Vec c(2), gg(2);
    sub->dynamics({t + 1e-5}, q, qd, Mp, c, gg);
    sub->dynamics({t - 1e-5}, q, qd, Mm, c, gg);
    mt_size = std::max(mt_size, (((Mp - Mm) / 2e-5) * qd).norm());
  }
  EXPECT_LT(worst_eq, 1e-6);
  EXPECT_LT(worst_lt, 1e-8);
  EXPECT_LT(worst_e, 1e-12);
  EXPECT_GT(mt_size, 0.5);  // the explicit-time term is large enough for worst_eq to see it
  // A default context is t = 0.
  Vec q(2), qd(2);
  q << 0.3, -0.7;
  qd << 1.1, 0.4;
  Mat M(2, 2), M0(2, 2);
  Vec c(2), g0(2), c0(2), gg0(2);
  sub->dynamics({}, q, qd, M, c, g0);
  sub->dynamics({0.0}, q, qd, M0, c0, gg0);
  EXPECT_EQ(M, M0);
  EXPECT_EQ(c, c0);
  std::printf(
      "m(t) double pendulum: Lagrange residual %.2e, dL/dt %.2e, T/V %.2e, |dM/dt qd| %.2f\n",
      worst_eq, worst_lt, worst_e, mt_size);
}

// (c) A pendulum (a bob on a rod, x and z with the rod as a constraint) whose bob has
// m(t) = 1 + 0.2 sin 10t: E = T + V is not conserved, E − W is (W = ∫ (Qcᵀq̇ − ∂L/∂t) dt).
TEST(VaryingMass, EnergyBalanceHoldsOnAVaryingMassPendulum) {
  const std::string yaml = R"(ukdyn: 1
name: varying_pendulum
gravity: 9.8
subsystems:
  - name: bob
    type: definitions
    coordinates: [x, z]
    parameters: {m: 1}
    bodies:
      - {name: bob, mass: m*(1 + 0.2*sin(10*t)), com: [x, 0, z]}
constraints:
  - type: expression
    name: rod
    rows: {circle: (x^2 + z^2 - 1)/2}
initial:
  q: [0.8, -0.6]
  qd: [1.2, 1.6]
simulation: {t_end: 4, sample_dt: 0.01, abs_tol: 1e-12, rel_tol: 1e-12, energy_balance: true}
)";
  const auto sc = ukdyn::load_scenario_text(yaml, "vp.yaml");
  ASSERT_TRUE(sc.sim.energy_balance);
  const ukdyn::System& sys = *sc.system;
  double E0 = 0.0, B0 = 0.0, drift = 0.0, dE = 0.0, res = 0.0;
  bool first = true;
  Vec phi(sys.rows());
  const ukdyn::ForceFunction tau = [&](double, CVecRef, CVecRef, VecRef out) { out = sc.tau; };
  const auto stats = ukdyn::simulate(
      sys, sc.q0, sc.qd0, tau, sc.sim,
      [&](double t, CVecRef q, CVecRef qd, const ukdyn::ForwardData& d) {
        const double E = ukdyn::kinetic_energy(d, qd) + ukdyn::potential_energy(sys, t, q);
        if (first) {
          E0 = E;
          B0 = E - d.work;
          first = false;
        }
        drift = std::max(drift, std::abs(E - d.work - B0));
        dE = std::max(dE, std::abs(E - E0));
        ukdyn::position_residuals(sys, t, q, phi);
        res = std::max(res, phi.cwiseAbs().maxCoeff());
        return true;
      });
  ASSERT_EQ(stats.status, ukdyn::RunStatus::completed) << stats.message;
  EXPECT_LT(drift, 1e-9);
  EXPECT_GT(dE, 0.1);  // E itself changes: the balance's −∂L/∂t term is doing the work
  std::printf("m(t) pendulum: max |E - W - (E0 - W0)| = %.3e, max |E - E0| = %.3f, rod %.1e\n",
              drift, dE, res);
}

// (d) A mass that is constant (even written with t that cancels) derives the time-invariant
// subsystem: not time_varying(), the same M, C q̇, G at any t.
TEST(VaryingMass, ConstantMassIsNotTimeVarying) {
  sym::SubsystemDef a("c1", {"u"}), b("c2", {"u"});
  auto& ba = a.add_body("p");
  ba.mass = a.parse("2");
  ba.com = {a.parse("sin(u)"), 0, a.parse("-cos(u)")};
  auto& bb = b.add_body("p");
  bb.mass = b.parse("2 + 0*t + sin(t)^2 + cos(t)^2 - 1");
  bb.com = {b.parse("sin(u)"), 0, b.parse("-cos(u)")};
  const auto sa = sym::make_subsystem(a), sb = sym::make_subsystem(b);
  EXPECT_FALSE(sa->time_varying());
  EXPECT_FALSE(sb->time_varying());
  Vec q(1), qd(1);
  q << 0.4;
  qd << -1.3;
  Mat Ma(1, 1), Mb(1, 1);
  Vec ca(1), cb(1), ga(1), gb(1);
  double la = 1.0, lb = 1.0;
  la = sa->dynamics({2.5}, q, qd, Ma, ca, ga);
  lb = sb->dynamics({2.5}, q, qd, Mb, cb, gb);
  EXPECT_EQ(Ma, Mb);
  EXPECT_EQ(ca, cb);
  EXPECT_EQ(ga, gb);
  EXPECT_EQ(la, 0.0);
  EXPECT_EQ(lb, 0.0);
}

// Bad input: a mass or inertia of a coordinate or velocity, a position of t: the error names the
// file, line and body.
TEST(VaryingMass, MassOfACoordinateIsRefusedWithTheBody) {
  const auto bad = [](const std::string& body, const std::string& expect) {
    const std::string yaml =
        "ukdyn: 1\nname: bad\ngravity: 9.8\nsubsystems:\n"
        "  - name: s\n    type: definitions\n    coordinates: [z]\n    bodies:\n      - " +
        body + "\ninitial: {q: [1]}\nsimulation: {t_end: 1}\n";
    try {
      (void)ukdyn::load_scenario_text(yaml, "bad.yaml");
      ADD_FAILURE() << "accepted: " << body;
    } catch (const ukdyn::ScenarioError& e) {
      EXPECT_NE(std::string(e.what()).find(expect), std::string::npos) << e.what();
    }
  };
  bad("{name: p, mass: 1 + z^2, com: [0, 0, z]}",
      "bad.yaml:9:9: key 'subsystems[0].bodies[0]': body 'p': the mass must be a constant or a "
      "function of t only");
  bad("{name: p, mass: 1 + z_dot, com: [0, 0, z]}", "body 'p': the mass must be a constant or a");
  bad("{name: p, mass: 1, com: [0, 0, z], inertia: z, angular_velocity: [0, z_dot, 0]}",
      "body 'p': the inertia must be constant or a function of t only");
  bad("{name: p, mass: 1, com: [0, 0, z + t]}", "body 'p': the position may not depend on time t");
  bad("{name: p, mass: sin(10*t) - 0.5, com: [0, 0, z]}",
      "body 'p': the mass must be a number >= 0 at t = 0");
}

// A mass of t that turns negative after t = 0 (derive() checks t = 0 only): negative_mass() finds
// the first sample where it is < 0, and the scenario loader refuses the run whose time span
// reaches it, naming the file, line, subsystem, body and time; the same model with a span that
// stays positive loads.
TEST(VaryingMass, MassOfTThatTurnsNegativeIsRefusedOverTheRun) {
  sym::SubsystemDef def("s", {"z"});
  def.parameter("m0", 2.0);
  auto& fixed = def.add_body("fixed");
  fixed.mass = def.parse("1");
  fixed.com = {0, 0, def.parse("z")};
  auto& shrinking = def.add_body("shrinking");
  shrinking.mass = def.parse("m0*(1 - t)");  // 0 at t = 1, negative after
  shrinking.com = {0, 0, def.parse("z")};
  const auto sub = sym::make_subsystem(def);
  ASSERT_TRUE(sub->time_varying());
  EXPECT_EQ(sub->negative_mass(0.0, 0.9, 91), "");
  EXPECT_EQ(sub->negative_mass(0.0, 1.0, 101), "");  // m(1) = 0 is allowed
  const std::string why = sub->negative_mass(0.0, 2.0, 201);
  EXPECT_NE(why.find("body 'shrinking'"), std::string::npos) << why;
  EXPECT_NE(why.find("at t = 1.01"), std::string::npos) << why;  // the first sample past t = 1

  const auto yaml = [](const std::string& t_end) {
    return "ukdyn: 1\nname: shrink\ngravity: 9.8\nsubsystems:\n"
           "  - name: s\n    type: definitions\n    coordinates: [z]\n"
           "    parameters: {m0: 2}\n"
           "    bodies:\n      - {name: p, mass: m0*(1 - 0.5*t), com: [0, 0, z]}\n"
           "initial: {q: [1]}\nsimulation: {t_end: " +
           t_end + ", sample_dt: 0.5}\n";
  };
  EXPECT_NO_THROW((void)ukdyn::load_scenario_text(yaml("2"), "shrink.yaml"));
  try {
    (void)ukdyn::load_scenario_text(yaml("2.5"), "shrink.yaml");
    ADD_FAILURE() << "accepted a mass that is negative for t > 2";
  } catch (const ukdyn::ScenarioError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("shrink.yaml:5:5: key 'subsystems[0]'"), std::string::npos) << what;
    EXPECT_NE(what.find("subsystem 's', body 'p'"), std::string::npos) << what;
    EXPECT_NE(what.find("a mass of t must stay >= 0"), std::string::npos) << what;
  }
}

// The closed loop of docs/control.md with a plant whose bob has m(t) = m (1 + 0.2 sin 10t)
// (control.plant_set with an expression), the model keeping 1 kg, robust law (rho = 2,
// eps = 0.01, lambda = kappa = 5), start 0.02 rad off: the run completes and its tracking error
// after the transient, max |e| over [2, 4] s, is reported against the constant-mass plants (1 kg,
// the model itself; 1.2 kg, the heaviest m(t)).
struct Loop {
  ukdyn::SimulationStats stats;
  std::vector<double> t, e;
  double max_e(double from, double to) const {
    double m = 0;
    for (std::size_t i = 0; i < t.size(); ++i)
      if (t[i] >= from - 1e-12 && t[i] <= to + 1e-12) m = std::max(m, std::abs(e[i]));
    return m;
  }
};

Loop run_loop(const ukdyn::Scenario& sc, double t_end) {
  const auto run = ukdyn::make_control_run(sc);
  EXPECT_TRUE(run);
  ukdyn::SimulationSettings sim = sc.sim;
  sim.t_end = t_end;
  sim.abs_tol = sim.rel_tol = 1e-10;
  Loop r;
  Vec e, ed;
  r.stats = ukdyn::simulate(*run->plant, run->q0, run->qd0, run->loop->force_function(), sim,
                            [&](double t, CVecRef q, CVecRef qd, const ukdyn::ForwardData&) {
                              ukdyn::servo_errors(run->model, t, q, qd, e, ed);
                              r.t.push_back(t);
                              r.e.push_back(e(0));
                              return true;
                            });
  return r;
}

TEST(VaryingMass, ClosedLoopOnATimeVaryingLoadMass) {
  const std::string law =
      "control:\n  law: robust\n  lambda: 5\n  kappa: 5\n  rho: 2\n  epsilon: 0.01\n"
      "  initial_offset: {swing_angle: 0.02}\n";
  const std::string varying = law +
                              "  plant_set:\n    - {path: \"subsystems[bob].bodies[bob].mass\", "
                              "expression: \"m*(1 + 0.2*sin(10*t))\"}\n";
  const std::string heavy =
      law + "  plant_set:\n    - {path: \"subsystems[bob].parameters.m\", scale: 1.2}\n";
  const auto sv = ukdyn::load_scenario_text(uktest::pendulum_servo_yaml(1.0, varying), "v.yaml");
  ASSERT_TRUE(sv.control && sv.control->plant);
  EXPECT_TRUE(sv.control->plant->system->subsystems()[0]->time_varying());
  EXPECT_FALSE(sv.system->subsystems()[0]->time_varying());  // the model keeps its 1 kg
  const Loop v = run_loop(sv, 4.0);
  const Loop c =
      run_loop(ukdyn::load_scenario_text(uktest::pendulum_servo_yaml(1.0, law), "c.yaml"), 4.0);
  const Loop h =
      run_loop(ukdyn::load_scenario_text(uktest::pendulum_servo_yaml(1.0, heavy), "h.yaml"), 4.0);
  ASSERT_EQ(v.stats.status, ukdyn::RunStatus::completed) << v.stats.message;
  ASSERT_EQ(c.stats.status, ukdyn::RunStatus::completed) << c.stats.message;
  ASSERT_EQ(h.stats.status, ukdyn::RunStatus::completed) << h.stats.message;
  const double ev = v.max_e(2, 4), ec = c.max_e(2, 4), eh = h.max_e(2, 4);
  EXPECT_LT(ev, 1e-3);
  EXPECT_GT(ev, 2 * ec);  // the plant's m(t) is felt (the model-exact plant tracks much better)
  std::printf(
      "closed loop, max |e| over [2, 4] s: m(t) plant %.3e, 1 kg plant %.3e, 1.2 kg plant "
      "%.3e\n",
      ev, ec, eh);
  // A bad expression in plant_set is the plant's error, with the key.
  try {
    (void)ukdyn::load_scenario_text(
        uktest::pendulum_servo_yaml(
            1.0, law + "  plant_set:\n    - {path: \"subsystems[bob].bodies[bob].mass\", "
                       "expression: \"m*x\"}\n"),
        "b.yaml");
    ADD_FAILURE() << "a mass of x was accepted";
  } catch (const ukdyn::ScenarioError& e) {
    EXPECT_NE(std::string(e.what()).find("the mass must be a constant or a function of t only"),
              std::string::npos)
        << e.what();
    EXPECT_NE(std::string(e.what()).find("control.plant_set"), std::string::npos) << e.what();
  }
}

}  // namespace

// (e) The C matrix of a mass of t at time t is that of the same body with the constant mass
// m(t) (C is the Christoffel matrix of M(q, t) at fixed t), given the time; the overload without
// a time refuses a time-varying system rather than answer at t = 0.
TEST(VaryingMass, CoriolisMatrixIsTakenAtTheGivenTime) {
  const auto body = [](const std::string& mass) {
    return "ukdyn: 1\nname: c_of_t\ngravity: 9.8\nsubsystems:\n"
           "  - name: body\n    type: definitions\n    coordinates: [x, z]\n"
           "    bodies:\n      - {name: p, mass: " +
           mass +
           ", com: [x, 0, x*z]}\n"
           "initial: {q: [0.3, -0.7], qd: [1.1, 0.4]}\n"
           "simulation: {t_end: 1, sample_dt: 0.1}\n";
  };
  const auto varying = ukdyn::load_scenario_text(body("2*(1 + 0.2*sin(10*t))"), "v.yaml");
  const double t = 0.37;
  std::ostringstream m;
  m.precision(17);
  m << 2 * (1 + 0.2 * std::sin(10 * t));
  const auto fixed = ukdyn::load_scenario_text(body(m.str()), "f.yaml");
  const Vec q = varying.q0, qd = varying.qd0;
  ukdyn::ForwardData dv(*varying.system), df(*fixed.system);
  Mat Cv(2, 2), Cf(2, 2);
  ukdyn::coriolis_matrix(*varying.system, dv, t, q, qd, Cv);
  ukdyn::coriolis_matrix(*fixed.system, df, t, q, qd, Cf);
  EXPECT_GT(Cf.cwiseAbs().maxCoeff(), 0.1);
  EXPECT_LT((Cv - Cf).cwiseAbs().maxCoeff(), 1e-13 * Cf.cwiseAbs().maxCoeff());
  EXPECT_THROW(ukdyn::coriolis_matrix(*varying.system, q, qd, Cv), std::invalid_argument);
}
