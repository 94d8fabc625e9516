// Applied forces as definitions (forces.generalized / forces.elements, ukdyn/symbolic/forces.hpp)
// against independent evidence: closed-form solutions (a damped spring-mass, a driven rotor), the
// same force written twice (an element and a hand-derived `generalized` expression), and the energy
// balance E − W, which must stay constant.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/symbolic/definitions.hpp"
#include "ukdyn/symbolic/forces.hpp"

#ifdef UKDYN_HAVE_IO

namespace {

using ukdyn::Index;
using ukdyn::Vec;

ukdyn::Scenario load(const std::string& text) {
  return ukdyn::load_scenario_text(text, "test_forces.yaml");
}

struct Sample {
  double t;
  Vec q, qd;
  double E, W;
};

// Runs a scenario, recording every sample (energy from the library's own functions).
std::vector<Sample> run(const ukdyn::Scenario& sc, ukdyn::SimulationStats* stats = nullptr) {
  std::vector<Sample> out;
  const ukdyn::System& sys = *sc.system;
  const ukdyn::ForceFunction tau = [&sc](double, ukdyn::CVecRef, ukdyn::CVecRef, ukdyn::VecRef f) {
    f = sc.tau;
  };
  const auto st = ukdyn::simulate(
      sys, sc.q0, sc.qd0, tau, sc.sim,
      [&](double t, ukdyn::CVecRef q, ukdyn::CVecRef qd, const ukdyn::ForwardData& d) {
        const double E = ukdyn::kinetic_energy(d, qd) + ukdyn::potential_energy(sys, q);
        out.push_back({t, q, qd, E, d.work});
        return true;
      });
  EXPECT_EQ(st.status, ukdyn::RunStatus::completed) << st.message;
  if (stats) *stats = st;
  return out;
}

const char* kOscillator = R"(
ukdyn: 1
name: damped_oscillator
gravity: 0
subsystems:
  - name: cart
    type: definitions
    coordinates: [x]
    parameters: {m: 2}
    bodies:
      - {name: mass, mass: m, com: [x, 0, 0]}
initial:
  q: [1.3]
  qd: [0.4]
forces:
  parameters: {k: 50, c: 0.8}
  elements:
    - {type: spring_damper, name: s, a: [x, 0, 0], b: [0, 0, 0], stiffness: k, damping: c, rest_length: 1}
simulation:
  t_end: 3
  sample_dt: 0.01
)";

// m ü + c u̇ + k u = 0 (u = x − L0): u = e^{−ζω t}(u0 cos ω_d t + (v0 + ζω u0)/ω_d sin ω_d t).
TEST(Forces, SpringDamperElementMatchesTheDampedOscillatorClosedForm) {
  const auto sc = load(kOscillator);
  EXPECT_TRUE(sc.sim.energy_balance);  // on by default with state-dependent forces
  const double m = 2, k = 50, c = 0.8, u0 = 0.3, v0 = 0.4;
  const double w = std::sqrt(k / m), zeta = c / (2 * std::sqrt(k * m));
  const double wd = w * std::sqrt(1 - zeta * zeta);
  double worst = 0, worst_v = 0;
  const auto samples = run(sc);
  ASSERT_EQ(samples.size(), 301u);
  for (const auto& s : samples) {
    const double e = std::exp(-zeta * w * s.t), B = (v0 + zeta * w * u0) / wd;
    const double u = e * (u0 * std::cos(wd * s.t) + B * std::sin(wd * s.t));
    const double v = -zeta * w * u + e * wd * (-u0 * std::sin(wd * s.t) + B * std::cos(wd * s.t));
    worst = std::max(worst, std::abs(s.q(0) - 1.0 - u));
    worst_v = std::max(worst_v, std::abs(s.qd(0) - v));
  }
  EXPECT_LT(worst, 1e-9);
  EXPECT_LT(worst_v, 1e-8);
  // Energy: E includes the spring's potential ½ k u²; W is the damper's (negative) work.
  const double E0 = 0.5 * m * v0 * v0 + 0.5 * k * u0 * u0;
  EXPECT_NEAR(samples.front().E, E0, 1e-12);
  EXPECT_LT(samples.back().W, -0.1 * E0);  // a good part of the energy is dissipated
  for (const auto& s : samples) EXPECT_NEAR(s.E - s.W, E0, 1e-9 * E0) << "t = " << s.t;
}

// A planar double pendulum (absolute angles) with a spring-damper from its tip to a fixed point:
// the element, and the same force written by hand as `generalized` expressions
// Q_i = −(k (L − L0) + c L̇) ∂L/∂θ_i with ∂L/∂θ_i = d·∂p/∂θ_i / L.
std::string double_pendulum(const std::string& forces) {
  return R"(
ukdyn: 1
name: double_pendulum_spring
gravity: 9.81
subsystems:
  - name: arm
    type: definitions
    coordinates: [th1, th2]
    parameters: {l1: 0.7, l2: 0.5, m1: 1.5, m2: 0.8}
    bodies:
      - {name: b1, mass: m1, com: [l1/2*sin(th1), 0, -l1/2*cos(th1)]}
      - {name: b2, mass: m2, com: [l1*sin(th1) + l2*sin(th2), 0, -l1*cos(th1) - l2*cos(th2)]}
initial:
  q: [0.4, -0.3]
  qd: [0.5, 1.2]
)" + forces +
         R"(
simulation:
  t_end: 2
  sample_dt: 0.01
)";
}

const char* kElement = R"(
forces:
  parameters: {k: 40, c: 1.5, L0: 0.3}
  elements:
    - {type: spring_damper, name: s, a: [0.7*sin(th1) + 0.5*sin(th2), 0, -0.7*cos(th1) - 0.5*cos(th2)],
       b: [1, 0, 0.5], stiffness: k, damping: c, rest_length: L0}
)";

const char* kByHand = R"(
forces:
  parameters: {k: 40, c: 1.5, L0: 0.3, l1: 0.7, l2: 0.5}
  generalized:
    th1: -(k*(sqrt(dx^2 + dz^2) - L0) + c*(dx*(l1*cos(th1)*th1_dot + l2*cos(th2)*th2_dot) + dz*(l1*sin(th1)*th1_dot + l2*sin(th2)*th2_dot))/sqrt(dx^2 + dz^2)) * (dx*l1*cos(th1) + dz*l1*sin(th1))/sqrt(dx^2 + dz^2)
    th2: -(k*(sqrt(dx^2 + dz^2) - L0) + c*(dx*(l1*cos(th1)*th1_dot + l2*cos(th2)*th2_dot) + dz*(l1*sin(th1)*th1_dot + l2*sin(th2)*th2_dot))/sqrt(dx^2 + dz^2)) * (dx*l2*cos(th2) + dz*l2*sin(th2))/sqrt(dx^2 + dz^2)
)";

std::string by_hand() {
  // dx, dz: the tip minus the anchor [1, 0, 0.5], substituted textually.
  std::string s = kByHand;
  const std::string dx = "(l1*sin(th1) + l2*sin(th2) - 1)";
  const std::string dz = "(-l1*cos(th1) - l2*cos(th2) - 0.5)";
  for (std::size_t p; (p = s.find("dx")) != std::string::npos;) s.replace(p, 2, dx);
  for (std::size_t p; (p = s.find("dz")) != std::string::npos;) s.replace(p, 2, dz);
  return s;
}

TEST(Forces, SpringDamperElementEqualsTheSameForceWrittenAsAnExpression) {
  const auto a = load(double_pendulum(kElement));
  const auto b = load(double_pendulum(by_hand()));
  ukdyn::ForwardData da(*a.system), db(*b.system);
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> U(-2.0, 2.0);
  for (int k = 0; k < 50; ++k) {
    const Vec q = Vec::NullaryExpr(2, [&] { return U(rng); });
    const Vec qd = Vec::NullaryExpr(2, [&] { return U(rng); });
    ukdyn::forward(*a.system, da, 0.0, q, qd, a.tau);
    ukdyn::forward(*b.system, db, 0.0, q, qd, b.tau);
    for (Index i = 0; i < 2; ++i)
      EXPECT_NEAR(da.Q(i), db.Q(i), 1e-12 * (1 + std::abs(db.Q(i)))) << "i = " << i;
    // The element's spring is a potential: its power is not counted as non-conservative.
    EXPECT_LE(da.applied_power, 1e-12);  // the damper only dissipates
  }
  // Both runs close their energy balance; the trajectories agree.
  const auto ra = run(a), rb = run(b);
  ASSERT_EQ(ra.size(), rb.size());
  for (std::size_t s = 0; s < ra.size(); ++s) {
    EXPECT_NEAR(ra[s].q(0), rb[s].q(0), 1e-9);
    EXPECT_NEAR(ra[s].q(1), rb[s].q(1), 1e-9);
    EXPECT_NEAR(ra[s].E - ra[s].W, ra[0].E - ra[0].W, 1e-8);
    EXPECT_NEAR(rb[s].E - rb[s].W, rb[0].E - rb[0].W, 1e-8);
  }
  // Element: E includes ½ k (L − L0)² and W is the damper's work only; by hand: the spring's work
  // is in W. The two energies differ by the spring potential, the two balances by a constant.
  EXPECT_LT(ra.back().W, 0.0);
}

// A rotor I φ̈ = τ(t) with τ = 0.5 sin(2t) (an expression) + 0.03 t (a polynomial time function)
// + 0.03 t (a spline): φ = φ0 + ω0 t + (0.25/I)(t − sin(2t)/2) + 0.01 t³/I.
const char* kRotor = R"(
ukdyn: 1
name: rotor
gravity: 0
subsystems:
  - name: r
    type: definitions
    coordinates: [phi]
    parameters: {I: 0.2}
    bodies:
      - {name: disc, mass: 1, com: [0, 0, 0], inertia: I, angular_velocity: [0, 0, phi_dot]}
initial:
  q: [0.1]
  qd: [0.3]
forces:
  elements:
    - {type: torque, name: drive, coordinate: phi, value: 0.5*sin(2*t)}
    - {type: torque, name: ramp, coordinate: phi, value: {type: polynomial, coefficients: [0, 0.03]}}
    - {type: torque, name: table, coordinate: phi,   # a natural spline through linear data: 0.03 t
       value: {type: spline, times: [0, 1, 2, 3], values: [0, 0.03, 0.06, 0.09]}}
simulation:
  t_end: 3
  sample_dt: 0.01
)";

TEST(Forces, TimeVaryingTorquesMatchTheClosedForm) {
  const auto sc = load(kRotor);
  const double I = 0.2;
  double worst = 0;
  const auto samples = run(sc);
  for (const auto& s : samples) {
    const double t = s.t;
    // 0.5 sin 2t and the ramp 0.06 t: φ = φ0 + ω0 t + (0.25/I)(t − sin(2t)/2) + 0.01 t³/I.
    const double phi = 0.1 + 0.3 * t + 0.25 / I * (t - std::sin(2 * t) / 2) + 0.01 * t * t * t / I;
    worst = std::max(worst, std::abs(s.q(0) - phi));
    // The torques' work is the kinetic energy gained.
    EXPECT_NEAR(s.E - s.W, samples.front().E, 1e-10);
  }
  EXPECT_LT(worst, 1e-9);
}

// Joint friction (viscous + smoothed Coulomb) on a pendulum: the closed form of the friction
// torque, and the energy balance E − W constant while the friction dissipates the energy.
const char* kPendulum = R"(
ukdyn: 1
name: damped_pendulum
gravity: 9.81
subsystems:
  - name: p
    type: definitions
    coordinates: [phi]
    parameters: {l: 0.8, m: 1.2}
    bodies:
      - {name: bob, mass: m, com: [l*sin(phi), 0, -l*cos(phi)]}
initial:
  q: [1.0]
  qd: [0]
forces:
  elements:
    - {type: joint_friction, name: hinge, coordinate: phi, viscous: 0.1, coulomb: 0.2, velocity_scale: 1e-3}
simulation:
  t_end: 4
  sample_dt: 0.01
)";

TEST(Forces, JointFrictionTorqueAndEnergyBalance) {
  const auto sc = load(kPendulum);
  ukdyn::ForwardData d(*sc.system);
  for (const double v : {-1.0, -1e-3, 0.0, 2e-4, 0.7}) {
    const Vec q = Vec::Constant(1, 0.3), qd = Vec::Constant(1, v);
    ukdyn::forward(*sc.system, d, 0.0, q, qd, sc.tau);
    const double friction = -0.1 * v - 0.2 * std::tanh(v / 1e-3);
    EXPECT_NEAR(d.Q(0) + d.G(0), friction, 1e-15);
    EXPECT_NEAR(d.applied_power, friction * v, 1e-15);
  }
  const auto samples = run(sc);
  const double E0 = samples.front().E;
  double dissipated = 0;
  for (const auto& s : samples) {
    EXPECT_NEAR(s.E - s.W, E0, 1e-9) << "t = " << s.t;
    dissipated = -s.W;
  }
  EXPECT_GT(dissipated, 1.0);  // most of the energy m g l (1 − cos 1) ≈ 4.3 J
}

// The same force through the C++ API: a viscous damper −c φ̇ as a ForceDef on a derived pendulum.
TEST(Forces, CppApiAddsTheForceInForward) {
  namespace sym = ukdyn::symbolic;
  sym::SubsystemDef def("p", {"phi"});
  auto& bob = def.add_body("bob");
  bob.mass = 2;
  bob.com = {sin(def.q("phi")), 0, -cos(def.q("phi"))};
  def.gravity = {0, 0, -9.81};
  ukdyn::System sys;
  sys.add_subsystem(sym::make_subsystem(def));
  sym::ForceDef f({"phi"});
  f.add_joint_friction("hinge", "phi", f.parameter("c", 0.5), 0, 0);
  f.add_generalized("phi", f.parse("0.25*sin(t)"));
  sys.add_applied_force(sym::make_applied_force(f));
  ukdyn::ForwardData d(sys);
  const Vec q = Vec::Constant(1, 0.4), qd = Vec::Constant(1, -0.9), tau = Vec::Constant(1, 0.1);
  ukdyn::forward(sys, d, 1.5, q, qd, tau);
  EXPECT_NEAR(d.Q(0), 0.1 - 0.5 * -0.9 + 0.25 * std::sin(1.5) - 2 * 9.81 * std::sin(0.4), 1e-14);
  EXPECT_NEAR(d.qdd(0), d.Q(0) / 2.0, 1e-14);
  EXPECT_THROW(f.add_torque("x", "psi", 1), sym::DefinitionError);
}

TEST(Forces, BadInputNamesTheKey) {
  auto expect_error = [](const std::string& forces, const std::string& needle) {
    try {
      load(double_pendulum(forces));
      ADD_FAILURE() << "no error for " << forces;
    } catch (const ukdyn::ScenarioError& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("test_forces.yaml:"), std::string::npos) << e.what();
    }
  };
  expect_error("forces:\n  generalized:\n    psi: 1\n", "no coordinate named 'psi'");
  expect_error("forces:\n  generalized:\n    th1: foo*th1\n", "forces.generalized.th1");
  expect_error("forces:\n  elements:\n    - {type: spring, name: s}\n", "unknown force element");
  expect_error(
      "forces:\n  elements:\n    - {type: spring_damper, name: s, a: [th1_dot, 0, 0], "
      "b: [0, 0, 0], stiffness: 1}\n",
      "velocities");
  expect_error(
      "forces:\n  elements:\n    - {type: spring_damper, name: s, a: [th1, 0, 0], "
      "b: [0, 0, 0], stiffness: -1}\n",
      "stiffness must be >= 0");
  expect_error(
      "forces:\n  elements:\n    - {type: joint_friction, name: f, coordinate: th1, "
      "coulomb: 0.1, velocity_scale: 0}\n",
      "velocity_scale must be > 0");
}

}  // namespace

#endif  // UKDYN_HAVE_IO
