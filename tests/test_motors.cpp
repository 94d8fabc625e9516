// Motors and gearboxes behind actuators (docs/motors.md, ukdyn/model/motor.hpp): the reflected
// rotor inertia n² J_m in M, the motor friction, the electrical side and its energy balance,
// against closed forms, MuJoCo's `armature` / `damping`, and an energy balance.
#include <gtest/gtest.h>

#include <cmath>
#include <nlohmann/json.hpp>
#include <random>
#include <string>

#include "ukdyn/model/linearize.hpp"
#include "ukdyn/model/motor.hpp"
#include "ukdyn/robot_files/mjcf.hpp"
#include "ukdyn/run/run.hpp"
#include "ukdyn/scenario/scenario.hpp"

#ifdef UKDYN_TEST_HAVE_MUJOCO
#include <mujoco/mujoco.h>
#endif

namespace {

using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;

// One link about y (CoM at l = 0.4 m on x, I_yy = 0.03 about the CoM, m = 2 kg) behind a motor:
// gear n = 50, J_m = 2e-5, b_m = 1e-4, c_m = 5e-3 (ω_s = 1 rad/s).
constexpr double kMass = 2.0, kL = 0.4, kIyy = 0.03, kG = 9.81;
constexpr double kN = 50.0, kJm = 2e-5, kBm = 1e-4, kCm = 5e-3, kWs = 1.0;

std::string pendulum_yaml(const std::string& motor, const std::string& constraints = "",
                          const std::string& sim = "{t_end: 1, sample_dt: 0.01}",
                          const std::string& qd0 = "0.3") {
  return "ukdyn: 1\nname: motor_pendulum\ngravity: 9.81\nsubsystems:\n"
         "  - name: arm\n    type: serial_chain\n    coordinates: [a]\n    joints:\n"
         "      - {name: j1, type: revolute, axis: [0, 1, 0], coordinate: a, mass: 2,\n"
         "         com: [0.4, 0, 0], inertia: [0.01, 0.03, 0.02]}\n" +
         constraints + "actuators:\n  - name: shoulder\n    coordinate: a\n" + motor +
         "initial: {q: [0], qd: [" + qd0 + "]}\nsimulation: " + sim + "\n";
}

const std::string kMotor =
    "    motor: {ratio: 50, efficiency: 0.8, rotor_inertia: 2e-5, viscous: 1e-4, coulomb: 5e-3,\n"
    "            coulomb_speed: 1, torque_constant: 0.05, resistance: 0.6, stall_torque: 1.0,\n"
    "            no_load_speed: 600, continuous_torque: 0.3, peak_torque: 0.9}\n";

// The hand-written model: (I_yy + m l² + n² J_m) θ̈ = τ + m g l cos θ − n² b_m θ̇
// − n c_m tanh(n θ̇ / ω_s) (the CoM at R_y(θ)(l, 0, 0), height −l sin θ, gravity along −z).
double closed_form_qdd(double th, double thd, double tau, bool motor) {
  const double I = kIyy + kMass * kL * kL + (motor ? kN * kN * kJm : 0.0);
  double f = tau + kMass * kG * kL * std::cos(th);
  if (motor) f -= kN * (kBm * kN * thd + kCm * std::tanh(kN * thd / kWs));
  return f / I;
}

TEST(Motors, PendulumMatchesTheClosedFormWithReflectedInertia) {
  for (const bool motor : {false, true}) {
    const auto sc = ukdyn::load_scenario_text(pendulum_yaml(motor ? kMotor : ""), "m.yaml");
    ukdyn::ForwardData d(*sc.system);
    std::mt19937 rng(5u);
    std::uniform_real_distribution<double> u(-2.0, 2.0);
    double worst = 0.0;
    for (int k = 0; k < 50; ++k) {
      Vec q(1), qd(1), tau(1);
      q << u(rng);
      qd << 0.2 * u(rng);  // |n θ̇/ω_s| up to 20: both sides of the Coulomb smoothing
      tau << 5.0 * u(rng);
      ukdyn::forward(*sc.system, d, 0.0, q, qd, tau);
      const double ref = closed_form_qdd(q(0), qd(0), tau(0), motor);
      worst = std::max(worst, std::abs(d.qdd(0) - ref) / std::max(1.0, std::abs(ref)));
    }
    EXPECT_LE(worst, 1e-12) << (motor ? "with" : "without") << " the motor";
    std::cout << (motor ? "with" : "without")
              << " the motor: max |qdd - closed form| / max(1, |qdd|) = " << worst << "\n";
  }
}

// Exact derivatives of the motor's terms (a constant in M, the friction's tangent) against
// central differences of forward().
TEST(Motors, LinearizeMatchesCentralDifferences) {
  const auto sc = ukdyn::load_scenario_text(pendulum_yaml(kMotor), "m.yaml");
  const ukdyn::System& sys = *sc.system;
  Vec q(1), qd(1), tau(1);
  q << 0.7;
  qd << 0.013;  // n θ̇ / ω_s = 0.65: inside the Coulomb smoothing, where its slope is large
  tau << 1.5;
  const auto lin = ukdyn::linearize(sys, 0.0, q, qd, tau);
  ukdyn::ForwardData d(sys);
  auto qdd = [&](const Vec& qq, const Vec& vv) {
    ukdyn::forward(sys, d, 0.0, qq, vv, tau);
    return d.qdd(0);
  };
  const double h = 1e-6;
  const Vec e = Vec::Ones(1);
  const double fq = (qdd(q + h * e, qd) - qdd(q - h * e, qd)) / (2 * h);
  const double fv = (qdd(q, qd + h * e) - qdd(q, qd - h * e)) / (2 * h);
  EXPECT_NEAR(lin.dqdd_dq(0, 0), fq, 1e-7 * std::max(1.0, std::abs(fq)));
  EXPECT_NEAR(lin.dqdd_dqd(0, 0), fv, 1e-7 * std::max(1.0, std::abs(fv)));
  // and the analytic value of ∂q̈/∂θ̇ = −n²(b_m + c_m (1 − tanh²)/ω_s) / I_total
  const double th = std::tanh(kN * qd(0) / kWs);
  const double I = kIyy + kMass * kL * kL + kN * kN * kJm;
  EXPECT_NEAR(lin.dqdd_dqd(0, 0), -kN * kN * (kBm + kCm * (1 - th * th) / kWs) / I, 1e-12);
  std::cout << "dqdd/dq " << lin.dqdd_dq(0, 0) << " (differences " << fq << "), dqdd/dqd "
            << lin.dqdd_dqd(0, 0) << " (differences " << fv << ", closed form "
            << -kN * kN * (kBm + kCm * (1 - th * th) / kWs) / I << ")\n";
}

// An actuator over two coordinates of one subsystem, τ = b u: the rotor turns at n bᵀq̇, its
// energy ½ J_m n² (bᵀq̇)², so M gains n² J_m b bᵀ (off-diagonal terms too).
TEST(Motors, GainsActuatorAddsTheOuterProduct) {
  const std::string base =
      "ukdyn: 1\nname: two\ngravity: 9.81\nsubsystems:\n"
      "  - name: arm\n    type: serial_chain\n    coordinates: [a, b]\n    joints:\n"
      "      - {name: j1, type: revolute, axis: [0, 1, 0], coordinate: a, mass: 1, com: [0.3, 0, "
      "0]}\n"
      "      - {name: j2, type: revolute, axis: [0, 1, 0], coordinate: b, mass: 1, com: [0.3, 0, "
      "0], origin: {xyz: [0.6, 0, 0]}}\n"
      "initial: {q: [0.2, 0.4]}\nsimulation: {t_end: 1, sample_dt: 0.1}\n";
  const std::string act =
      "actuators:\n  - name: diff\n    gains: {a: 1, b: -0.5}\n"
      "    motor: {ratio: 20, rotor_inertia: 1e-3, torque_constant: 0.1}\n";
  const auto plain = ukdyn::load_scenario_text(base, "a.yaml");
  const auto with = ukdyn::load_scenario_text(base + act, "b.yaml");
  ukdyn::ForwardData d0(*plain.system), d1(*with.system);
  Vec q(2), qd(2), tau = Vec::Zero(2);
  q << 0.2, 0.4;
  qd << 0.1, -0.3;
  ukdyn::forward(*plain.system, d0, 0.0, q, qd, tau);
  ukdyn::forward(*with.system, d1, 0.0, q, qd, tau);
  Vec b(2);
  b << 1.0, -0.5;
  const Mat expected = 400.0 * 1e-3 * b * b.transpose();
  EXPECT_LE((d1.M - d0.M - expected).cwiseAbs().maxCoeff(), 1e-15);
}

TEST(Motors, ActuatorOverTwoSubsystemsIsRefused) {
  const std::string text =
      "ukdyn: 1\nname: two\ngravity: 9.81\nsubsystems:\n"
      "  - name: left\n    type: serial_chain\n    coordinates: [a]\n    joints:\n"
      "      - {name: j1, type: revolute, axis: [0, 1, 0], coordinate: a, mass: 1, com: [0.3, 0, "
      "0]}\n"
      "  - name: right\n    type: serial_chain\n    coordinates: [b]\n    joints:\n"
      "      - {name: j2, type: revolute, axis: [0, 1, 0], coordinate: b, mass: 1, com: [0.3, 0, "
      "0]}\n"
      "actuators:\n  - name: both\n    gains: {a: 1, b: 1}\n"
      "    motor: {ratio: 20, rotor_inertia: 1e-3, torque_constant: 0.1}\n"
      "initial: {q: [0.2, 0.4]}\nsimulation: {t_end: 1, sample_dt: 0.1}\n";
  try {
    (void)ukdyn::load_scenario_text(text, "two.yaml");
    FAIL() << "no error";
  } catch (const std::exception& e) {
    const std::string w = e.what();
    EXPECT_NE(w.find("actuators[0].motor"), std::string::npos) << w;
    EXPECT_NE(w.find("two subsystems"), std::string::npos) << w;
  }
}

// The operating point against the formulas written out (motoring and braking).
TEST(Motors, OperatingPointFormulas) {
  ukdyn::MotorSpec m;
  m.ratio = 10.0;
  m.efficiency = 0.8;
  m.torque_constant = 0.05;
  m.resistance = 2.0;
  m.stall_torque = 1.0;
  m.no_load_speed = 100.0;
  m.peak_torque = 0.8;
  const auto p = ukdyn::motor_point(m, 4.0, 3.0);  // motoring: τ_m = 4 / (10 · 0.8) = 0.5
  EXPECT_DOUBLE_EQ(p.torque, 0.5);
  EXPECT_DOUBLE_EQ(p.omega_m, 30.0);
  EXPECT_DOUBLE_EQ(p.current, 10.0);
  EXPECT_NEAR(p.p_elec, (2.0 * 10.0 + 0.05 * 30.0) * 10.0, 1e-12);
  EXPECT_NEAR(p.p_gear, 0.5 * 30.0 - 12.0, 1e-12);
  // available min(0.8, 1 · (1 − 0.3)) = 0.7; margin (0.7 − 0.5) / 0.8
  EXPECT_NEAR(p.margin, 0.25, 1e-15);
  const auto r = ukdyn::motor_point(m, -4.0, 3.0);  // braking: τ_m = −4 · 0.8 / 10
  EXPECT_DOUBLE_EQ(r.torque, -0.32);
  EXPECT_NEAR(r.p_gear, -0.32 * 30.0 + 12.0, 1e-12);
  EXPECT_GT(r.p_gear, 0.0);
}

// ∫P_el = ΔE_mech + E_friction + E_copper + E_gear on a servo-driven swing θ = 0.8 sin 3t (motoring
// and braking, both signs of the speed), the electrical energy from V i alone.
TEST(MotorEnergy, ElectricalEnergyBalancesMechanicalAndLosses) {
  const std::string cons =
      "constraints:\n  - {type: expression, name: swing, role: servo, rows: {track: a - "
      "0.8*sin(3*t)}}\n";
  const auto sc = ukdyn::load_scenario_text(
      pendulum_yaml(kMotor, cons,
                    "{t_end: 2, sample_dt: 0.001, abs_tol: 1e-12, rel_tol: 1e-12, "
                    "integrator: dopri5}",
                    "2.4"),
      "e.yaml");
  const auto run = ukdyn::run_scenario_in_memory(sc);
  ASSERT_TRUE(run.report.complete());
  const auto j = nlohmann::json::parse(run.summary_json);
  ASSERT_TRUE(j.contains("motors")) << run.summary_json;
  const auto& m = j["motors"]["shoulder"];
  const std::size_t cols = run.header.size();
  std::size_t iE = cols;
  for (std::size_t c = 0; c < cols; ++c)
    if (run.header[c] == "E") iE = c;
  ASSERT_LT(iE, cols);
  const double dE = run.values[run.values.size() - cols + iE] - run.values[iE];
  const double el = m["energy_electrical"], f = m["energy_friction"], cu = m["energy_copper"],
               gear = m["energy_gear"];
  const double lost = f + cu + gear;
  EXPECT_GT(f, 0.0);
  EXPECT_GT(cu, 0.0);
  EXPECT_GT(gear, 0.0);
  const double err = std::abs(el - (dE + lost));
  EXPECT_LE(err, 1e-9 * lost) << "E_el " << el << " dE " << dE << " losses " << lost;
  RecordProperty("balance_error_over_losses", std::to_string(err / lost));
  std::cout << "energy balance: E_el = " << el << " J, dE = " << dE << " J, friction " << f
            << ", copper " << cu << ", gear " << gear << ": |error| / losses = " << err / lost
            << "\n";
}

#ifdef UKDYN_TEST_HAVE_MUJOCO
// MuJoCo's `armature` (rotor inertia reflected, added to M's diagonal) and `damping` (viscous,
// qfrc_passive) against ukdyn's motor with J_m n² and b_m n² on the same joints of an open chain.
TEST(Motors, ArmatureAndDampingMatchMuJoCo) {
  ASSERT_TRUE(ukdyn::symbolic::mjcf_supported());
  const std::string file = std::string(UKDYN_SOURCE_DIR) + "/tests/mjcf/open_chain.xml";
  const std::vector<std::string> names = {"x", "h1", "h2", "s2", "h3", "sw"};
  // actuated coordinates, gear ratios, rotor inertias, viscous frictions
  const std::vector<int> idx = {0, 1, 2, 5};
  const std::vector<double> n = {12.0, 50.0, 30.0, 100.0}, J = {1e-4, 2e-5, 3e-5, 5e-6},
                            b = {2e-3, 1e-4, 3e-4, 2e-5};
  std::string acts = "actuators:\n";
  for (std::size_t k = 0; k < idx.size(); ++k)
    acts += "  - {name: m" + std::to_string(k) +
            ", coordinate: " + names[static_cast<std::size_t>(idx[k])] +
            ", motor: {ratio: " + std::to_string(n[k]) +
            ", rotor_inertia: " + std::to_string(J[k]) + ", viscous: " + std::to_string(b[k]) +
            ", torque_constant: 0.1}}\n";
  const std::string text =
      "ukdyn: 1\nname: open_chain_motors\ngravity: 9.81\nsubsystems:\n  - name: m\n    type: "
      "serial_chain\n"
      "    coordinates: [x, h1, h2, s2, h3, sw]\n    mjcf: " +
      file + "\n" + acts +
      "initial: {q: [0, 0, 0, 0, 0, 0]}\nsimulation: {t_end: 1, sample_dt: 0.1}\n";
  const auto sc = ukdyn::load_scenario_text(text, "mj.yaml");
  char err[1000] = "";
  mjModel* m = mj_loadXML(file.c_str(), nullptr, err, sizeof err);
  ASSERT_NE(m, nullptr) << err;
  // The scenario's gravity (the chain reads the MJCF's bodies, not its <option gravity>).
  m->opt.gravity[0] = 0.0;
  m->opt.gravity[1] = 0.0;
  m->opt.gravity[2] = -9.81;
  for (std::size_t k = 0; k < idx.size(); ++k) {
    m->dof_armature[idx[k]] = std::stod(std::to_string(J[k])) * std::stod(std::to_string(n[k])) *
                              std::stod(std::to_string(n[k]));
    m->dof_damping[idx[k]] = std::stod(std::to_string(b[k])) * std::stod(std::to_string(n[k])) *
                             std::stod(std::to_string(n[k]));
  }
  mjData* d = mj_makeData(m);
  ukdyn::ForwardData fd(*sc.system);
  std::mt19937 rng(17u);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  double worst = 0.0;
  for (int k = 0; k < 50; ++k) {
    Vec q(6), qd(6), tau = Vec::Zero(6);
    for (Index i = 0; i < 6; ++i) {
      q[i] = 2.0 * u(rng);
      qd[i] = 2.0 * u(rng);
      d->qpos[i] = q[i];
      d->qvel[i] = qd[i];
    }
    mj_forward(m, d);
    ukdyn::forward(*sc.system, fd, 0.0, q, qd, tau);
    Vec qacc(6);
    for (int i = 0; i < 6; ++i) qacc[i] = d->qacc[i];
    worst = std::max(worst, (fd.qdd - qacc).cwiseAbs().maxCoeff() / std::max(1.0, qacc.norm()));
  }
  mj_deleteData(d);
  mj_deleteModel(m);
  EXPECT_LE(worst, 1e-10);
  std::cout << "max |qdd_ukdyn - qacc_MuJoCo| / max(1, |qacc|) = " << worst << "\n";
}
#endif

}  // namespace

namespace {

// scenarios/paper_motors.yaml: the paper's motion is prescribed by its constraints, so adding the
// motors leaves q(t) as in paper.yaml and the kinetic energy must grow by exactly
// ½ Σ_j n² J_m θ̇_j² over the eight motorised joints (the closed-form mobile manipulator's M with
// the rotors added); the run completes and every motor stays within its envelope.
TEST(MotorScenario, PaperMotorsAddsTheRotorsKineticEnergy) {
  const std::string dir = std::string(UKDYN_SOURCE_DIR) + "/scenarios/";
  const auto with = ukdyn::load_scenario(dir + "paper_motors.yaml");
  const auto without = ukdyn::load_scenario(dir + "paper.yaml");
  const auto a = ukdyn::run_scenario_in_memory(with);
  ASSERT_TRUE(a.report.complete());
  auto column = [&a](const std::string& name) {
    for (std::size_t c = 0; c < a.header.size(); ++c)
      if (a.header[c] == name) return c;
    ADD_FAILURE() << "no column " << name;
    return std::size_t{0};
  };
  const ukdyn::System& paper = *without.system;
  const auto& names = paper.coordinate_names();
  const std::vector<std::string> joints = {"delta1", "theta1", "theta2", "theta3",
                                           "delta2", "theta4", "theta5", "theta6"};
  const double reflected = 100.0 * 100.0 * 1.2e-5;  // n² J_m of the scenario's gearmotor
  const std::size_t cols = a.header.size();
  ukdyn::ForwardData d(paper);
  Vec q(12), qd(12);
  double worst = 0.0, max_rotors = 0.0;
  for (long r = 0; r < a.report.csv_rows; ++r) {
    const double* row = a.values.data() + static_cast<std::size_t>(r) * cols;
    for (Index i = 0; i < 12; ++i) {
      q(i) = row[column(names[static_cast<std::size_t>(i)])];
      qd(i) = row[column(names[static_cast<std::size_t>(i)] + "_dot")];
    }
    ukdyn::evaluate_dynamics(paper, d, row[0], q, qd);  // the paper's M at the same state
    double rotors = 0.0;
    for (const auto& j : joints) {
      const double w = row[column(j + "_dot")];
      rotors += 0.5 * reflected * w * w;
    }
    max_rotors = std::max(max_rotors, rotors);
    const double dT = row[column("T")] - ukdyn::kinetic_energy(d, qd);
    worst = std::max(worst, std::abs(dT - rotors) / std::max(1.0, row[column("T")]));
  }
  EXPECT_GT(max_rotors, 1.0);  // the rotors' share is not negligible
  EXPECT_LE(worst, 1e-13);
  const auto j = nlohmann::json::parse(a.summary_json);
  for (const auto& [name, m] : j["motors"].items()) {
    EXPECT_TRUE(m["within_envelope"].get<bool>()) << name;
    const double el = m["energy_electrical"], joint = m["energy_joint"], gear = m["energy_gear"],
                 cu = m["energy_copper"];
    EXPECT_NEAR(el, joint + gear + cu, 1e-12 * std::max(1.0, std::abs(el))) << name;
  }
  std::cout << "max |T_motors - T_paper - 1/2 sum n^2 J_m w^2| / max(1, T) = " << worst
            << " (rotors up to " << max_rotors << " J)\n";
}

}  // namespace
