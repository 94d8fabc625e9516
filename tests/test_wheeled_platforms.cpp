// Wheeled platforms (docs/wheeled-platforms.md): subsystems of type mecanum, omni and
// differential_drive, generated as definitions with exact nonholonomic rolling rows. Checked by
// evidence that does not come from the generator:
// - the textbook inverse kinematics of an X-layout Mecanum platform ([Taheri2015], wheels FL, FR,
//   RL, RR; diagonal wheels share a roller angle) and of a three-wheel omni (kiwi) platform;
// - the power balance Σ τ_i φ̇_i = dE/dt and its integral E − E0 = Σ τ_i (φ_i − φ_i0) under
//   constant torques (the rolling rows are ideal: their force does no work);
// - a second formulation: d'Alembert's principle in the platform's own twist ν = (u, w, ω)
//   (as in [Zeidis2019]), (diag(m, m, I) + J Hᵀ H) ν̇ + m (−ω w, ω u, 0) = Hᵀ τ with
//   φ̇ = H ν written here from the layout, at random states of a five-wheel layout;
// - the special motions of the X layout (pure translation forward and sideways, pure rotation
//   about the centre) against their closed forms;
// - the differential drive (unicycle) against its closed form (a spiral for equal torques) and a
//   quadrature of ∫ u (cos ψ, sin ψ) dt for unequal ones;
// - linearize(): exact ∂q̈/∂q, ∂q̈/∂q̇ against central differences of forward().
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "ukdyn/core/force_split.hpp"
#include "ukdyn/model/linearize.hpp"
#include "ukdyn/run/run.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/simulate/simulate.hpp"

namespace {

using ukdyn::CVecRef;
using ukdyn::Mat;
using ukdyn::Vec;
using ukdyn::VecRef;

// The X layout of scenarios/mecanum_platform.yaml: front-left, front-right, rear-left, rear-right
// at (±lx, ±ly), rollers at −45°, +45°, +45°, −45° from the axle.
constexpr double kMass = 50.0, kYaw = 4.17, kRadius = 0.1, kSpin = 0.0075, kLx = 0.3, kLy = 0.25;

// Shortest exact text of a double (the scenario reads it back to the same double).
std::string num(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

std::string mecanum_yaml(const std::string& torques, const std::string& q0, double t_end) {
  return "ukdyn: 1\nname: mecanum\nsubsystems:\n"
         "  - name: base\n    type: mecanum\n    mass: 50\n    yaw_inertia: 4.17\n"
         "    wheel_radius: 0.1\n    wheel_inertia: 0.0075\n    wheels:\n"
         "      - {position: [0.3, 0.25], roller_angle: -pi/4}\n"
         "      - {position: [0.3, -0.25], roller_angle: pi/4}\n"
         "      - {position: [-0.3, 0.25], roller_angle: pi/4}\n"
         "      - {position: [-0.3, -0.25], roller_angle: -pi/4}\n"
         "initial: {q: " +
         q0 + ", qd: zeros}\nforces:\n" + torques + "simulation: {t_end: " + std::to_string(t_end) +
         ", sample_dt: 0.01, abs_tol: 1e-13, rel_tol: 1e-13}\n";
}

std::string constant_torques(double t1, double t2, double t3, double t4) {
  return "  tau: [0, 0, 0, " + num(t1) + ", " + num(t2) + ", " + num(t3) + ", " + num(t4) + "]\n";
}

struct Sample {
  double t;
  Vec q, qd, qdd, Qc;
};

// Runs the scenario; every sample with q̈ from an independent forward() call.
std::vector<Sample> run(const ukdyn::Scenario& sc) {
  std::vector<Sample> out;
  ukdyn::ForwardData d(*sc.system);
  const ukdyn::ForceFunction tau = [&](double, CVecRef, CVecRef, VecRef o) { o = sc.tau; };
  const auto stats =
      ukdyn::simulate(*sc.system, sc.q0, sc.qd0, tau, sc.sim,
                      [&](double t, CVecRef q, CVecRef qd, const ukdyn::ForwardData&) {
                        ukdyn::forward(*sc.system, d, t, q, qd, sc.tau);
                        out.push_back({t, q, qd, d.qdd, d.Qc});
                        return true;
                      });
  EXPECT_EQ(stats.status, ukdyn::RunStatus::completed) << stats.message;
  return out;
}

// Body-frame twist (u forward, w left, ω) of the platform.
std::array<double, 3> twist(const Vec& q, const Vec& qd) {
  const double c = std::cos(q(2)), s = std::sin(q(2));
  return {c * qd(0) + s * qd(1), -s * qd(0) + c * qd(1), qd(2)};
}

// Textbook Mecanum inverse kinematics of the X layout ([Taheri2015]; written here, not taken from
// the generator):
//   φ̇_FL = (u − w − (lx + ly) ω)/r,  φ̇_FR = (u + w + (lx + ly) ω)/r,
//   φ̇_RL = (u + w − (lx + ly) ω)/r,  φ̇_RR = (u − w + (lx + ly) ω)/r.
std::array<double, 4> mecanum_ik(const std::array<double, 3>& v) {
  const double L = kLx + kLy;
  const auto [u, w, om] = v;
  return {(u - w - L * om) / kRadius, (u + w + L * om) / kRadius, (u + w - L * om) / kRadius,
          (u - w + L * om) / kRadius};
}

TEST(WheeledPlatforms, MecanumWheelRatesMatchTheClosedFormInverseKinematics) {
  const std::string torques =
      "  elements:\n"
      "    - {type: torque, name: a, coordinate: base_phi1, value: 0.4 - 0.3*cos(t)}\n"
      "    - {type: torque, name: b, coordinate: base_phi2, value: 0.4 + 0.3*cos(t)}\n"
      "    - {type: torque, name: c, coordinate: base_phi3, value: 0.1 - 0.3*cos(t)}\n"
      "    - {type: torque, name: d, coordinate: base_phi4, value: 0.7 + 0.3*cos(t)}\n";
  const auto sc = ukdyn::load_scenario_text(
      mecanum_yaml(torques, "[0.5, -0.2, 0.3, 0, 0, 0, 0]", 6.0), "ik.yaml");
  const auto samples = run(sc);
  double worst = 0.0, max_rate = 0.0, yaw_span = 0.0, max_w = 0.0;
  for (const auto& s : samples) {
    const auto v = twist(s.q, s.qd);
    const auto ik = mecanum_ik(v);
    for (int i = 0; i < 4; ++i) {
      worst = std::max(worst, std::abs(s.qd(3 + i) - ik[static_cast<std::size_t>(i)]));
      max_rate = std::max(max_rate, std::abs(s.qd(3 + i)));
    }
    yaw_span = std::max(yaw_span, std::abs(s.q(2) - 0.3));
    max_w = std::max(max_w, std::abs(v[1]));
  }
  // The motion exercises every term: it turns, and slides sideways in its own frame.
  EXPECT_GT(yaw_span, 0.1);
  EXPECT_GT(max_w, 0.01);
  EXPECT_GT(max_rate, 5.0);
  EXPECT_LE(worst, 1e-12) << "max |phi_dot - IK| = " << worst << " rad/s, max rate " << max_rate;
  std::printf(
      "[ measured ] Mecanum IK: max |phi_dot - closed form| = %.3g rad/s (rates up to %.3g)\n",
      worst, max_rate);
}

// Three omni wheels at 90°, 210°, 330° on a circle of radius R, rolling tangentially (heading
// θ_i + 90°): φ̇_i = (−sin θ_i u + cos θ_i w + R ω)/r (the kiwi drive).
TEST(WheeledPlatforms, OmniWheelRatesMatchTheKiwiInverseKinematics) {
  const double R = 0.2, r = 0.05;
  std::string wheels;
  const double th[3] = {std::numbers::pi / 2, 7 * std::numbers::pi / 6, 11 * std::numbers::pi / 6};
  for (double a : th) {
    char buf[160];
    std::snprintf(buf, sizeof buf, "      - {position: [%.17g, %.17g], heading: %.17g}\n",
                  R * std::cos(a), R * std::sin(a), a + std::numbers::pi / 2);
    wheels += buf;
  }
  const std::string yaml =
      "ukdyn: 1\nname: kiwi\nsubsystems:\n  - name: k\n    type: omni\n    mass: 8\n"
      "    yaw_inertia: 0.2\n    wheel_radius: 0.05\n    wheel_inertia: 0.001\n    wheels:\n" +
      wheels +
      "initial: {q: [0, 0, 0, 0, 0, 0], qd: zeros}\n"
      "forces: {tau: [0, 0, 0, 0.05, -0.02, 0.01]}\n"
      "simulation: {t_end: 3, sample_dt: 0.01, abs_tol: 1e-13, rel_tol: 1e-13}\n";
  const auto sc = ukdyn::load_scenario_text(yaml, "kiwi.yaml");
  double worst = 0.0, yaw_span = 0.0;
  for (const auto& s : run(sc)) {
    const auto [u, w, om] = twist(s.q, s.qd);
    for (int i = 0; i < 3; ++i) {
      const double ik = (-std::sin(th[i]) * u + std::cos(th[i]) * w + R * om) / r;
      worst = std::max(worst, std::abs(s.qd(3 + i) - ik));
    }
    yaw_span = std::max(yaw_span, std::abs(s.q(2)));
  }
  EXPECT_GT(yaw_span, 0.1);
  EXPECT_LE(worst, 1e-12);
  std::printf("[ measured ] kiwi IK: max |phi_dot - closed form| = %.3g rad/s\n", worst);
}

// Constant torques, generic (no special motion): dE/dt = q̇ᵀ M q̈ equals Σ τ_i φ̇_i at every sample,
// and E(t) − E(0) = Σ τ_i (φ_i(t) − φ_i(0)) (the torques are constant, E = T: the floor is flat).
TEST(WheeledPlatforms, MecanumPowerBalanceUnderConstantWheelTorques) {
  const double tau[4] = {0.7, -0.2, 0.5, 0.3};
  const auto sc =
      ukdyn::load_scenario_text(mecanum_yaml(constant_torques(tau[0], tau[1], tau[2], tau[3]),
                                             "[0, 0, 0.4, 0.1, 0.2, 0.3, 0.4]", 5.0),
                                "power.yaml");
  const auto samples = run(sc);
  ukdyn::ForwardData d(*sc.system);
  ukdyn::forward(*sc.system, d, 0.0, sc.q0, sc.qd0, sc.tau);
  const Mat M = d.M;  // constant: T = ½ m (ẋ² + ẏ²) + ½ I ψ̇² + ½ J Σ φ̇²
  double worst_power = 0.0, max_power = 0.0, worst_energy = 0.0, max_energy = 0.0;
  for (const auto& s : samples) {
    double power = 0.0, work = 0.0;
    for (int i = 0; i < 4; ++i) {
      power += tau[i] * s.qd(3 + i);
      work += tau[i] * (s.q(3 + i) - sc.q0(3 + i));
    }
    const double dEdt = s.qd.dot(M * s.qdd);
    const double E = 0.5 * s.qd.dot(M * s.qd);
    worst_power = std::max(worst_power, std::abs(dEdt - power));
    max_power = std::max(max_power, std::abs(power));
    worst_energy = std::max(worst_energy, std::abs(E - work));
    max_energy = std::max(max_energy, std::abs(E));
  }
  EXPECT_GT(max_energy, 1.0);
  EXPECT_LE(worst_power, 1e-9 * max_power);
  EXPECT_LE(worst_energy, 1e-9 * max_energy);
  std::printf(
      "[ measured ] power balance: max |dE/dt - sum tau phi_dot| = %.3g W (of %.3g W); "
      "max |E - sum tau dphi| = %.3g J (of %.3g J)\n",
      worst_power, max_power, worst_energy, max_energy);
}

// A second formulation at random states of an asymmetric five-wheel layout (headings 0):
// φ̇_i = H_i ν, H_i = (1, cot γ_i, a_i cot γ_i − b_i)/r, and d'Alembert's principle with the
// virtual twists δπ (δφ = H δπ): m (u̇ − ω w) δπ_u + m (ẇ + ω u) δπ_w + I ω̇ δπ_ω
// + J (H ν̇)ᵀ H δπ = τᵀ H δπ (φ̈ = H ν̇: H is constant in the platform frame).
TEST(WheeledPlatforms, MecanumAccelerationsMatchTheReducedEquationsInTheTwist) {
  const double a[5] = {0.4, 0.35, -0.3, -0.25, 0.05};
  const double b[5] = {0.3, -0.2, 0.25, -0.3, 0.4};
  const double g[5] = {std::numbers::pi / 4, -std::numbers::pi / 4, std::numbers::pi / 3,
                       -std::numbers::pi / 6, std::numbers::pi / 2};
  const char* gs[5] = {"pi/4", "-pi/4", "pi/3", "-pi/6", "pi/2"};
  const double m = 30, I = 2.5, J = 0.01, r = 0.08;
  std::string yaml =
      "ukdyn: 1\nname: five\nsubsystems:\n  - name: p\n    type: mecanum\n    mass: 30\n"
      "    yaw_inertia: 2.5\n    wheel_radius: 0.08\n    wheel_inertia: 0.01\n    wheels:\n";
  for (int i = 0; i < 5; ++i) {
    yaml +=
        "      - {position: [" + num(a[i]) + ", " + num(b[i]) + "], roller_angle: " + gs[i] + "}\n";
  }
  yaml +=
      "initial: {q: [0, 0, 0, 0, 0, 0, 0, 0], qd: zeros}\n"
      "simulation: {t_end: 1, sample_dt: 0.1}\n";
  const auto sc = ukdyn::load_scenario_text(yaml, "five.yaml");
  Mat H(5, 3);
  for (int i = 0; i < 5; ++i) {
    const double cot = std::cos(g[i]) / std::sin(g[i]);
    H.row(i) << 1 / r, cot / r, (a[i] * cot - b[i]) / r;
  }
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  ukdyn::ForwardData d(*sc.system);
  double worst = 0.0, worst_wheel = 0.0;
  for (int trial = 0; trial < 50; ++trial) {
    Vec q(8), qd(8), tau = Vec::Zero(8);
    for (int i = 0; i < 8; ++i) q(i) = 3 * U(rng);
    const Vec nu = Vec{{U(rng), U(rng), 2 * U(rng)}};
    const double c = std::cos(q(2)), s = std::sin(q(2));
    qd(0) = c * nu(0) - s * nu(1);
    qd(1) = s * nu(0) + c * nu(1);
    qd(2) = nu(2);
    qd.tail(5) = H * nu;
    for (int i = 3; i < 8; ++i) tau(i) = U(rng);
    ukdyn::forward(*sc.system, d, 0.0, q, qd, tau);
    const double u = nu(0), w = nu(1), om = nu(2);
    const Vec nud{
        {c * d.qdd(0) + s * d.qdd(1) + om * w, -s * d.qdd(0) + c * d.qdd(1) - om * u, d.qdd(2)}};
    Mat Mr = J * H.transpose() * H;
    Mr(0, 0) += m;
    Mr(1, 1) += m;
    Mr(2, 2) += I;
    const Vec lhs = Mr * nud + Vec{{-m * om * w, m * om * u, 0.0}};
    const Vec rhs = H.transpose() * tau.tail(5);
    worst = std::max(worst, (lhs - rhs).cwiseAbs().maxCoeff() / (1 + rhs.cwiseAbs().maxCoeff()));
    worst_wheel = std::max(worst_wheel, (d.qdd.tail(5) - H * nud).cwiseAbs().maxCoeff());
  }
  EXPECT_LE(worst, 1e-12);
  EXPECT_LE(worst_wheel, 1e-11);
  std::printf("[ measured ] reduced equations: max residual %.3g (relative), wheel accel. %.3g\n",
              worst, worst_wheel);
}

// The special motions of the X layout from rest (cf. [Zeidis2019]): with κ = 4 J / r²,
// equal torques τ0 drive it straight ahead with a = (4 τ0 / r) / (m + κ); the pattern
// (−1, +1, +1, −1) τ0 sideways with the same a; the pattern (−1, +1, −1, +1) τ0 turns it about
// its centre with α = (4 L τ0 / r) / (I + κ L²), L = lx + ly, the centre at rest.
TEST(WheeledPlatforms, MecanumSpecialMotionsMatchTheirClosedForms) {
  const double tau0 = 0.6, psi0 = 0.3, kappa = 4 * kSpin / (kRadius * kRadius), L = kLx + kLy;
  const double acc = (4 * tau0 / kRadius) / (kMass + kappa);
  const double alpha = (4 * L * tau0 / kRadius) / (kYaw + kappa * L * L);
  const std::string q0 = "[0, 0, " + num(psi0) + ", 0, 0, 0, 0]";
  const double p0 = psi0;
  struct Case {
    double s[4];
    double ax, ay, al;  // acceleration in the platform frame, angular acceleration
  } cases[3] = {
      {{1, 1, 1, 1}, acc, 0, 0}, {{-1, 1, 1, -1}, 0, acc, 0}, {{-1, 1, -1, 1}, 0, 0, alpha}};
  for (const auto& k : cases) {
    const auto sc = ukdyn::load_scenario_text(
        mecanum_yaml(constant_torques(k.s[0] * tau0, k.s[1] * tau0, k.s[2] * tau0, k.s[3] * tau0),
                     q0, 3.0),
        "special.yaml");
    double worst = 0.0, scale = 0.0;
    for (const auto& s : run(sc)) {
      const double t = s.t, h = 0.5 * t * t;
      const double X = h * (std::cos(p0) * k.ax - std::sin(p0) * k.ay);
      const double Y = h * (std::sin(p0) * k.ax + std::cos(p0) * k.ay);
      const double P = p0 + h * k.al;
      worst = std::max({worst, std::abs(s.q(0) - X), std::abs(s.q(1) - Y), std::abs(s.q(2) - P)});
      scale = std::max({scale, std::abs(X), std::abs(Y), std::abs(P - p0)});
    }
    EXPECT_GT(scale, 1.0);
    EXPECT_LE(worst, 1e-10) << "pattern " << k.s[0] << k.s[1] << k.s[2] << k.s[3];
    std::printf("[ measured ] special motion (%g, %g, %g, %g): max error %.3g (motion %.3g)\n",
                k.s[0], k.s[1], k.s[2], k.s[3], worst, scale);
  }
}

std::string diff_yaml(double tl, double tr, const std::string& q0, const std::string& qd0) {
  return "ukdyn: 1\nname: diff\nsubsystems:\n  - name: dd\n    type: differential_drive\n"
         "    mass: 20\n    yaw_inertia: 0.8\n    wheel_radius: 0.1\n    wheel_inertia: 0.004\n"
         "    track_width: 0.5\n"
         "initial: {q: " +
         q0 + ", qd: " + qd0 + "}\nforces: {tau: [0, 0, 0, " + num(tl) + ", " + num(tr) +
         "]}\nsimulation: {t_end: 4, sample_dt: 0.01, abs_tol: 1e-13, rel_tol: 1e-13}\n";
}

// The unicycle with its centre of mass on the axle: (m + 2J/r²) u̇ = (τL + τR)/r,
// (I + J W²/(2r²)) ω̇ = (τR − τL) W/(2r) (d'Alembert with δφ_L,R = (δu ∓ δω W/2)/r).
// Equal torques from (u0, ω0): ψ = ψ0 + ω0 t, u = u0 + a t, and
//   x = x0 + ((u0 + a t) sin ψ − u0 sin ψ0)/ω0 + a (cos ψ − cos ψ0)/ω0²,
//   y = y0 − ((u0 + a t) cos ψ − u0 cos ψ0)/ω0 + a (sin ψ − sin ψ0)/ω0².
TEST(WheeledPlatforms, DifferentialDriveMatchesTheUnicycleClosedForm) {
  const double m = 20, J = 0.004, r = 0.1, W = 0.5, tau = 0.3;  // (I: ω stays ω0)
  const double u0 = 0.4, w0 = 0.9, psi0 = 0.2;
  const double a = (2 * tau / r) / (m + 2 * J / (r * r));
  const std::string qd0 = "[" + num(u0 * std::cos(psi0)) + ", " + num(u0 * std::sin(psi0)) +
                          ", 0.9, " + num((u0 - w0 * W / 2) / r) + ", " +
                          num((u0 + w0 * W / 2) / r) + "]";
  const auto sc =
      ukdyn::load_scenario_text(diff_yaml(tau, tau, "[0, 0, 0.2, 0, 0]", qd0), "dd.yaml");
  const double U0 = std::hypot(sc.qd0(0), sc.qd0(1));
  double worst = 0.0;
  for (const auto& s : run(sc)) {
    const double t = s.t, psi = psi0 + w0 * t, ut = U0 + a * t;
    const double x = (ut * std::sin(psi) - U0 * std::sin(psi0)) / w0 +
                     a * (std::cos(psi) - std::cos(psi0)) / (w0 * w0);
    const double y = -(ut * std::cos(psi) - U0 * std::cos(psi0)) / w0 +
                     a * (std::sin(psi) - std::sin(psi0)) / (w0 * w0);
    worst = std::max({worst, std::abs(s.q(0) - x), std::abs(s.q(1) - y), std::abs(s.q(2) - psi),
                      std::abs(twist(s.q, s.qd)[0] - ut), std::abs(twist(s.q, s.qd)[1])});
  }
  EXPECT_LE(worst, 1e-10);
  std::printf("[ measured ] unicycle, equal torques: max error %.3g\n", worst);
}

// Unequal torques from rest: u = a t, ψ = ψ0 + α t²/2 exactly; x, y against a composite Simpson
// quadrature (20000 intervals) of ∫ u (cos ψ, sin ψ) dt.
TEST(WheeledPlatforms, DifferentialDriveUnequalTorquesMatchTheUnicycle) {
  const double m = 20, I = 0.8, J = 0.004, r = 0.1, W = 0.5, tl = 0.1, tr = 0.35, psi0 = -0.4;
  const double a = ((tl + tr) / r) / (m + 2 * J / (r * r));
  const double alpha = ((tr - tl) * W / (2 * r)) / (I + J * W * W / (2 * r * r));
  const auto sc =
      ukdyn::load_scenario_text(diff_yaml(tl, tr, "[1, 2, -0.4, 0, 0]", "zeros"), "dd2.yaml");
  const auto samples = run(sc);
  double worst_u = 0.0;
  for (const auto& s : samples) {
    const double t = s.t;
    worst_u = std::max({worst_u, std::abs(twist(s.q, s.qd)[0] - a * t),
                        std::abs(s.q(2) - (psi0 + 0.5 * alpha * t * t))});
  }
  const double T = samples.back().t;
  const int N = 20000;
  double X = 0.0, Y = 0.0;
  for (int k = 0; k <= N; ++k) {
    const double t = T * k / N, wgt = (k == 0 || k == N) ? 1 : (k % 2 ? 4 : 2);
    const double psi = psi0 + 0.5 * alpha * t * t;
    X += wgt * a * t * std::cos(psi);
    Y += wgt * a * t * std::sin(psi);
  }
  X *= T / (3 * N);
  Y *= T / (3 * N);
  const double err = std::hypot(samples.back().q(0) - 1 - X, samples.back().q(1) - 2 - Y);
  EXPECT_GT(alpha * T * T / 2, 1.0);  // it turns by more than a radian
  EXPECT_LE(worst_u, 1e-10);
  EXPECT_LE(err, 1e-10);
  std::printf(
      "[ measured ] unicycle, unequal torques: u, psi %.3g; position vs quadrature %.3g m\n",
      worst_u, err);
}

// linearize() on a platform: trusted, and its ∂q̈/∂q, ∂q̈/∂q̇ equal central differences of
// forward() (h = 1e-6) at a moving state.
TEST(WheeledPlatforms, LinearizeMatchesCentralDifferencesOnAMecanumPlatform) {
  const auto sc = ukdyn::load_scenario_text(
      mecanum_yaml(constant_torques(0.7, -0.2, 0.5, 0.3), "[0, 0, 0, 0, 0, 0, 0]", 1.0),
      "lin.yaml");
  Vec q{{0.3, -0.2, 0.7, 1.0, 2.0, 3.0, 4.0}}, qd(7);
  const std::array<double, 3> nu{0.5, -0.3, 0.8};
  const double c = std::cos(q(2)), s = std::sin(q(2));
  qd << c * nu[0] - s * nu[1], s * nu[0] + c * nu[1], nu[2], 0, 0, 0, 0;
  const auto ik = mecanum_ik(nu);
  for (int i = 0; i < 4; ++i) qd(3 + i) = ik[static_cast<std::size_t>(i)];
  const auto lin = ukdyn::linearize(*sc.system, 0.0, q, qd, sc.tau);
  EXPECT_TRUE(lin.trusted) << lin.message;
  ukdyn::ForwardData d(*sc.system);
  const double h = 1e-6;
  double worst = 0.0, scale = 0.0;
  for (int j = 0; j < 7; ++j) {
    for (int which = 0; which < 2; ++which) {
      Vec qp = q, qm = q, qdp = qd, qdm = qd;
      (which == 0 ? qp : qdp)(j) += h;
      (which == 0 ? qm : qdm)(j) -= h;
      ukdyn::forward(*sc.system, d, 0.0, qp, qdp, sc.tau);
      const Vec ap = d.qdd;
      ukdyn::forward(*sc.system, d, 0.0, qm, qdm, sc.tau);
      const Vec fd = (ap - d.qdd) / (2 * h);
      const Vec ex = (which == 0 ? lin.dqdd_dq : lin.dqdd_dqd).col(j);
      worst = std::max(worst, (fd - ex).cwiseAbs().maxCoeff());
      scale = std::max(scale, ex.cwiseAbs().maxCoeff());
    }
  }
  EXPECT_GT(scale, 0.1);
  EXPECT_LE(worst, 1e-7 * (1 + scale));
  std::printf("[ measured ] linearize vs central differences: %.3g (entries up to %.3g)\n", worst,
              scale);
}

// Bad input is named at its key.
TEST(WheeledPlatforms, ErrorsNameTheKey) {
  const auto message = [](const std::string& yaml) {
    try {
      (void)ukdyn::load_scenario_text(yaml, "bad.yaml");
    } catch (const ukdyn::ScenarioError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  std::string y = mecanum_yaml(constant_torques(0, 0, 0, 0), "[0, 0, 0, 0, 0, 0, 0]", 1.0);
  std::string bad = y;
  bad.replace(bad.find("roller_angle: pi/4"), 18, "roller_angle: 0");
  EXPECT_NE(message(bad).find("subsystems[0].wheels[1].roller_angle"), std::string::npos)
      << message(bad);
  bad = y;
  bad.replace(bad.find("wheel_radius: 0.1"), 17, "wheel_radius: 0");
  EXPECT_NE(message(bad).find("subsystems[0].wheel_radius': must be > 0"), std::string::npos)
      << message(bad);
  // Inconsistent initial wheel rates: the rolling row is violated.
  bad = y;
  bad.replace(bad.find("qd: zeros"), 9, "qd: [1, 0, 0, 0, 0, 0, 0]");
  EXPECT_NE(message(bad).find("base_wheel1"), std::string::npos) << message(bad);
}

// The platform as the mobile base of a serial chain (x, y, yaw), its wheels revolute joints about
// their axles with their mass and full inertia [J_d, J, J_d] (the tree algorithms, a 3D rigid-body
// model), and `type: rolling_wheels` on those coordinates: the same motion as `type: mecanum` with
// m = m_b + 4 m_w, I = I_b + 4 (J_d + m_w (a² + b²)) — which checks the generator's split of the
// wheels' kinetic energy (no cross term between spin and yaw) against a second formulation.
std::string chain_platform_yaml(const std::string& arm) {
  std::string wheels, rows;
  const char* names[4] = {"fl", "fr", "rl", "rr"};
  const double a[4] = {0.3, 0.3, -0.3, -0.3}, b[4] = {0.25, -0.25, 0.25, -0.25};
  const char* g[4] = {"-pi/4", "pi/4", "pi/4", "-pi/4"};
  for (int i = 0; i < 4; ++i) {
    wheels += std::string("      - {name: ") + names[i] +
              ", type: revolute, parent: platform, link: w_" + names[i] + ", origin: {xyz: [" +
              num(a[i]) + ", " + num(b[i]) + ", 0.1]}, axis: [0, 1, 0], coordinate: w" +
              std::to_string(i + 1) + ", mass: 1.5, inertia: [0.0041, 0.0075, 0.0041]}\n";
    rows += "      - {coordinate: w" + std::to_string(i + 1) + ", position: [" + num(a[i]) + ", " +
            num(b[i]) + "], roller_angle: " + g[i] + "}\n";
  }
  return "ukdyn: 1\nname: chain_platform\nsubsystems:\n  - name: robot\n    type: serial_chain\n"
         "    coordinates: [x, y, psi, w1, w2, w3, w4" +
         std::string(arm.empty() ? "" : ", delta, theta1") +
         "]\n"
         "    base: {type: omnidirectional, link: platform, x: x, y: y, yaw: psi, mass: 44, "
         "inertia: [2, 3, 3.5]}\n    joints:\n" +
         wheels + arm +
         "constraints:\n  - type: rolling_wheels\n    name: floor\n    x: x\n    y: y\n    yaw: "
         "psi\n"
         "    wheel_radius: 0.1\n    wheels:\n" +
         rows + "initial: {q: " +
         std::string(arm.empty() ? "[0, 0, 0, 0, 0, 0, 0]" : "[0, 0, 0, 0, 0, 0, 0, 0, 0.8]") +
         ", qd: zeros}\nsimulation: {t_end: 4, sample_dt: 0.01, abs_tol: 1e-13, rel_tol: 1e-13}\n";
}

TEST(WheeledPlatforms, ChainBasePlatformMatchesTheMecanumKind) {
  const auto chain = ukdyn::load_scenario_text(chain_platform_yaml(""), "chain.yaml");
  const double I = 3.5 + 4 * (0.0041 + 1.5 * (kLx * kLx + kLy * kLy));
  std::string y = mecanum_yaml(constant_torques(0, 0, 0, 0), "[0, 0, 0, 0, 0, 0, 0]", 1.0);
  y.replace(y.find("yaw_inertia: 4.17"), 17, "yaw_inertia: " + num(I));
  const auto kind = ukdyn::load_scenario_text(y, "kind.yaml");
  ukdyn::ForwardData dc(*chain.system), dk(*kind.system);
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  double worst = 0.0, scale = 0.0;
  for (int trial = 0; trial < 40; ++trial) {
    Vec q(7), qd(7), tau = Vec::Zero(7);
    for (int i = 0; i < 7; ++i) q(i) = 3 * U(rng);
    const std::array<double, 3> nu{U(rng), U(rng), 2 * U(rng)};
    const double c = std::cos(q(2)), s = std::sin(q(2));
    qd << c * nu[0] - s * nu[1], s * nu[0] + c * nu[1], nu[2], 0, 0, 0, 0;
    const auto ik = mecanum_ik(nu);
    for (int i = 0; i < 4; ++i) qd(3 + i) = ik[static_cast<std::size_t>(i)];
    for (int i = 3; i < 7; ++i) tau(i) = U(rng);
    ukdyn::forward(*chain.system, dc, 0.0, q, qd, tau);
    ukdyn::forward(*kind.system, dk, 0.0, q, qd, tau);
    worst = std::max(worst, (dc.qdd - dk.qdd).cwiseAbs().maxCoeff());
    scale = std::max(scale, dk.qdd.cwiseAbs().maxCoeff());
  }
  EXPECT_GT(scale, 1.0);
  EXPECT_LE(worst, 1e-12 * scale);
  std::printf(
      "[ measured ] chain base vs mecanum kind: max |qdd difference| %.3g (qdd up to %.3g)\n",
      worst, scale);
}

// An arm (a turret and a link) on the chain-base platform, free under gravity, with constant wheel
// torques: the wheel rates keep the textbook inverse kinematics of the platform twist, and
// E(t) − E(0) = Σ τ_i (φ_i(t) − φ_i(0)) (gravity in E; the rolling rows do no work).
TEST(WheeledPlatforms, ArmOnATurningPlatformKeepsRollingAndBalancesEnergy) {
  const std::string arm =
      "      - {name: turret, type: revolute, parent: platform, link: turret, origin: {xyz: [0.1, "
      "0, 0.2]}, axis: [0, 0, 1], coordinate: delta, mass: 2, com: [0, 0, 0.25], inertia: [0.05, "
      "0.05, 0.0625]}\n"
      "      - {name: j1, type: revolute, link: link1, origin: {xyz: [0, 0, 0.5]}, axis: [0, -1, "
      "0], "
      "coordinate: theta1, mass: 3, com: [0.35, 0, 0], inertia: [0.005, 0.1225, 0.1225]}\n";
  std::string y = chain_platform_yaml(arm);
  y.replace(y.find("simulation:"), 0, "forces: {tau: [0, 0, 0, 0.2, 0.9, -0.3, 0.5, 0.4, 0]}\n");
  const auto sc = ukdyn::load_scenario_text(y, "arm.yaml");
  const auto samples = run(sc);
  ukdyn::ForwardData d(*sc.system);
  double worst_ik = 0.0, worst_e = 0.0, max_e = 0.0, yaw_span = 0.0, swing = 0.0;
  double E0 = 0.0;
  for (const auto& s : samples) {
    const auto ik = mecanum_ik(twist(s.q, s.qd));
    for (int i = 0; i < 4; ++i)
      worst_ik = std::max(worst_ik, std::abs(s.qd(3 + i) - ik[static_cast<std::size_t>(i)]));
    ukdyn::forward(*sc.system, d, s.t, s.q, s.qd, sc.tau);
    const double E = 0.5 * s.qd.dot(d.M * s.qd) + sc.system->subsystems()[0]->potential({}, s.q);
    if (&s == &samples.front()) E0 = E;
    const double work = sc.tau.dot(s.q - sc.q0);
    worst_e = std::max(worst_e, std::abs(E - E0 - work));
    max_e = std::max(max_e, std::abs(work));
    yaw_span = std::max(yaw_span, std::abs(s.q(2)));
    swing = std::max(swing, std::abs(s.q(8) - 0.8));
  }
  EXPECT_GT(yaw_span, 0.1);
  EXPECT_GT(swing, 0.5);
  EXPECT_LE(worst_ik, 1e-12);
  EXPECT_LE(worst_e, 1e-9 * max_e);
  std::printf(
      "[ measured ] arm on the platform: IK %.3g rad/s; |E - E0 - W| %.3g J (W up to %.3g J); "
      "yaw %.3g rad, swing %.3g rad\n",
      worst_ik, worst_e, max_e, yaw_span, swing);
}

// Wheel torques as actuators (docs/control.md): servo rows prescribe x = 0.25 t², y = 0.1 sin t,
// ψ = 0.5 t + 0.2 t²; the constrained inverse dynamics gives wheel torques u (τ = B u, B the unit
// columns of the wheel angles) that realise the servo force against the rolling rows. Applied open
// loop to the platform alone (no servo rows), they reproduce the prescribed accelerations, and
// their generalized force Hᵀ u equals the reduced equations' left side at the prescribed motion.
// Three wheels are driven (the rear-right one rolls freely): u is then unique. With all four the
// actuation is redundant, and solve_actuation's rank-deficient solve is not reliable
// (docs/wheeled-platforms.md, "Limits").
TEST(WheeledPlatforms, WheelTorquesAsActuatorsRealiseAPrescribedMotion) {
  std::string servo = mecanum_yaml(constant_torques(0, 0, 0, 0), "[0, 0, 0, 0, 0, 0, 0]", 1.0);
  servo.replace(servo.find("initial:"), 0,
                "constraints:\n"
                "  - {type: expression, name: go, role: servo, rows: {x: base_x - 0.25*t^2, "
                "y: base_y - 0.1*sin(t), yaw: base_yaw - 0.5*t - 0.2*t^2}}\n");
  {  // q̇(0) on the prescribed motion: ẏ = 0.1, ψ̇ = 0.5, the wheel rates from the rows
    const auto w0 = mecanum_ik({0.0, 0.1, 0.5});
    servo.replace(servo.find("qd: zeros"), 9,
                  "qd: [0, 0.1, 0.5, " + num(w0[0]) + ", " + num(w0[1]) + ", " + num(w0[2]) + ", " +
                      num(w0[3]) + "]");
  }
  const auto sc = ukdyn::load_scenario_text(servo, "servo.yaml");
  const auto plant = ukdyn::load_scenario_text(
      mecanum_yaml(constant_torques(0, 0, 0, 0), "[0, 0, 0, 0, 0, 0, 0]", 1.0), "plant.yaml");
  ukdyn::ForwardData d(*sc.system), dp(*plant.system);
  Mat B = Mat::Zero(7, 3);
  for (int i = 0; i < 3; ++i) B(3 + i, i) = 1.0;
  const double kappa = 4 * kSpin / (kRadius * kRadius), L = kLx + kLy;
  double worst_plant = 0.0, worst_reduced = 0.0, worst_res = 0.0;
  for (double t : {0.3, 1.1, 2.5}) {
    // The prescribed state: x, y, ψ and their rates; the wheel rates from the rolling rows.
    const double psi = 0.5 * t + 0.2 * t * t, om = 0.5 + 0.4 * t;
    Vec q(7), qd(7);
    q << 0.25 * t * t, 0.1 * std::sin(t), psi, 0.1, 0.2, 0.3, 0.4;
    qd << 0.5 * t, 0.1 * std::cos(t), om, 0, 0, 0, 0;
    const auto nu = twist(q, qd);
    const auto ik = mecanum_ik(nu);
    for (int i = 0; i < 4; ++i) qd(3 + i) = ik[static_cast<std::size_t>(i)];
    ukdyn::forward(*sc.system, d, t, q, qd, sc.tau);
    const auto act = ukdyn::solve_actuation(B, Mat(d.A.topRows(4)), d.Qc);
    EXPECT_FALSE(act.underactuated);
    worst_res = std::max(worst_res, act.residual);
    ukdyn::forward(*plant.system, dp, t, q, qd, B * act.u);
    worst_plant = std::max(worst_plant, (dp.qdd - d.qdd).cwiseAbs().maxCoeff());
    // Reduced equations: (m + κ)(u̇ − ω w) + κ ω w = F_u, ... with the prescribed ν̇.
    const double c = std::cos(psi), s = std::sin(psi);
    const double xdd = 0.5, ydd = -0.1 * std::sin(t), psidd = 0.4;
    const double ud = c * xdd + s * ydd + om * nu[1], wd = -s * xdd + c * ydd - om * nu[0];
    const double Fu = (kMass + kappa) * ud - kMass * om * nu[1];
    const double Fw = (kMass + kappa) * wd + kMass * om * nu[0];
    const double Fo = (kYaw + kappa * L * L) * psidd;
    const Vec u{{act.u(0), act.u(1), act.u(2), 0.0}};  // the rear-right wheel is not driven
    const double Hu = (u(0) + u(1) + u(2) + u(3)) / kRadius;
    const double Hw = (-u(0) + u(1) + u(2) - u(3)) / kRadius;
    const double Ho = L * (-u(0) + u(1) - u(2) + u(3)) / kRadius;
    worst_reduced =
        std::max({worst_reduced, std::abs(Hu - Fu), std::abs(Hw - Fw), std::abs(Ho - Fo)});
  }
  EXPECT_LE(worst_res, 1e-10);
  EXPECT_LE(worst_plant, 1e-10);
  EXPECT_LE(worst_reduced, 1e-10);
  std::printf(
      "[ measured ] wheel actuators: residual %.3g, plant qdd vs servo qdd %.3g, H^T u vs reduced "
      "equations %.3g\n",
      worst_res, worst_plant, worst_reduced);
}

// `instances:` of a platform: two copies (one with its own prefix, mass and yaw inertia) under
// equal torques τ0 drive straight ahead, each with its own a = (4 τ0 / r) / (m + 4 J / r²).
TEST(WheeledPlatforms, InstancesOfAPlatformMoveWithTheirOwnMass) {
  std::string y = mecanum_yaml(constant_torques(0, 0, 0, 0), "[0, 0, 0, 0, 0, 0, 0]", 2.0);
  y.replace(y.find("initial:"), 0,
            "    instances:\n      - {name: p1}\n"
            "      - {name: p2, prefix: q_, parameters: {mass: 80, yaw_inertia: 6}}\n");
  y.replace(y.find("[0, 0, 0, 0, 0, 0, 0]"), 21, "[0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]");
  y.replace(y.find("  tau: ["), y.find("]\n", y.find("  tau: [")) - y.find("  tau: [") + 1,
            "  tau: [0, 0, 0, 0.6, 0.6, 0.6, 0.6, 0, 0, 0, 0.6, 0.6, 0.6, 0.6]");
  const auto sc = ukdyn::load_scenario_text(y, "instances.yaml");
  const auto& names = sc.system->coordinate_names();
  ASSERT_EQ(names.size(), 14u);
  EXPECT_EQ(names[0], "p1_x");
  EXPECT_EQ(names[7], "q_x");
  EXPECT_EQ(names[13], "q_phi4");
  const double kappa = 4 * kSpin / (kRadius * kRadius);
  const double a1 = (4 * 0.6 / kRadius) / (kMass + kappa), a2 = (4 * 0.6 / kRadius) / (80 + kappa);
  double worst = 0.0;
  for (const auto& s : run(sc)) {
    const double h = 0.5 * s.t * s.t;
    worst = std::max({worst, std::abs(s.q(0) - a1 * h), std::abs(s.q(7) - a2 * h), std::abs(s.q(1)),
                      std::abs(s.q(8)), std::abs(s.q(2)), std::abs(s.q(9))});
  }
  EXPECT_LE(worst, 1e-10);
  std::printf("[ measured ] instances: max error %.3g (a1 %.4g, a2 %.4g m/s^2)\n", worst, a1, a2);
}

}  // namespace

namespace {

// The paper's system on four-Mecanum-wheel platforms with the yaw held (scenarios/paper_mecanum.yaml)
// against scenarios/paper_chain.yaml (the same arms, load and task on the paper's abstract
// platforms): the task prescribes every motion in both, so the platform and joint coordinates must
// agree sample by sample, and the wheels turn as the Mecanum inverse kinematics of the platform's
// sideways motion says: φ̇ = s v_y / r with s = (−1, +1, +1, −1) for (fl, fr, rl, rr), rollers at
// ∓45° (the platforms' x and yaw are held).
TEST(WheeledPaper, ReproducesThePapersRunWithTheYawHeld) {
  const std::filesystem::path root = std::filesystem::path(UKDYN_SOURCE_DIR) / "scenarios";
  const ukdyn::Scenario wheels = ukdyn::load_scenario(root / "paper_mecanum.yaml");
  const ukdyn::Scenario paper = ukdyn::load_scenario(root / "paper_chain.yaml");
  auto run = [](const ukdyn::Scenario& sc, std::vector<ukdyn::Vec>& q,
                std::vector<ukdyn::Vec>& qd) {
    ukdyn::SimulationSettings set = sc.sim;
    set.t_end = 1.0;
    const ukdyn::Vec tau = sc.tau;
    ukdyn::simulate(
        *sc.system, sc.q0, sc.qd0,
        [&](double, ukdyn::CVecRef, ukdyn::CVecRef, ukdyn::VecRef out) { out = tau; }, set,
        [&](double, ukdyn::CVecRef x, ukdyn::CVecRef v, const ukdyn::ForwardData&) {
          q.emplace_back(x);
          qd.emplace_back(v);
          return true;
        });
  };
  std::vector<ukdyn::Vec> qw, qdw, qp, qdp;
  run(wheels, qw, qdw);
  run(paper, qp, qdp);
  ASSERT_EQ(qw.size(), 101u);
  ASSERT_EQ(qp.size(), 101u);
  // The paper_chain coordinates inside paper_mecanum's: robot k's (x, y) then (δ, θ1..θ3).
  const std::vector<std::pair<int, int>> map = {{0, 0},  {1, 1},  {7, 2},   {8, 3},
                                                {9, 4},  {10, 5}, {11, 6},  {12, 7},
                                                {18, 8}, {19, 9}, {20, 10}, {21, 11}};
  double worst = 0, worst_ik = 0;
  const double s[4] = {-1, 1, 1, -1}, r = 0.1;
  for (std::size_t i = 0; i < qw.size(); ++i) {
    for (const auto& [w, p] : map) worst = std::max(worst, std::abs(qw[i](w) - qp[i](p)));
    for (int robot = 0; robot < 2; ++robot) {
      const int base = 11 * robot;
      for (int k = 0; k < 4; ++k)
        worst_ik = std::max(worst_ik, std::abs(qdw[i](base + 3 + k) - s[k] * qdw[i](base + 1) / r));
    }
  }
  EXPECT_LT(worst, 1e-10);     // measured 2.8e-15
  EXPECT_LT(worst_ik, 1e-10);  // the wheels' rates up to 15.7 rad/s
}

// Hᵀ τ for the X layout: the wheel torques τ (FL, FR, RL, RR) as the platform force (F_u, F_w, M_z)
// in the platform frame; H is mecanum_ik's matrix, φ̇ = H ν, and virtual work gives Hᵀ.
std::array<double, 3> mecanum_wrench(const std::array<double, 4>& tau) {
  const double L = kLx + kLy;
  return {(tau[0] + tau[1] + tau[2] + tau[3]) / kRadius,
          (-tau[0] + tau[1] + tau[2] - tau[3]) / kRadius,
          L * (-tau[0] + tau[1] - tau[2] + tau[3]) / kRadius};
}

// The paper's platform force carried by the wheels instead. In paper_mecanum.yaml only the rolling
// rows act on the wheel angles, so Qc at a wheel angle is the torque the floor puts on that wheel
// through its row, and the rows' force on the platform is −Hᵀ of it. Moving the platform's whole
// constraint force F onto the wheels as torques τ with Hᵀ τ = F (least norm: τ = H (HᵀH)⁻¹ F)
// changes the generalized force by a combination of the rolling rows, so the platform with the
// rolling rows only, driven by those torques and by the other coordinates' Qc, must move as the
// run does ([Muir1987]: the wheel forces' resultant on the platform is the transpose of the
// inverse kinematics).
TEST(WheeledPaper, WheelTorquesCarryThePapersPlatformForce) {
  const std::filesystem::path root = std::filesystem::path(UKDYN_SOURCE_DIR) / "scenarios";
  ukdyn::Scenario wheels = ukdyn::load_scenario(root / "paper_mecanum.yaml");
  ukdyn::Scenario paper = ukdyn::load_scenario(root / "paper_chain.yaml");
  wheels.sim.t_end = paper.sim.t_end = 1.0;
  const std::vector<Sample> sw = run(wheels), sp = run(paper);
  ASSERT_EQ(sw.size(), sp.size());
  // The same scenario with the rolling rows only: every other row's force becomes an applied one.
  std::ifstream in(root / "paper_mecanum.yaml");
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const auto cut = text.find("  # Eq. (12)"), end = text.find("\ninitial:");
  ASSERT_NE(cut, std::string::npos);
  ASSERT_NE(end, std::string::npos);
  text.erase(cut, end + 1 - cut);
  const ukdyn::Scenario rolling = ukdyn::load_scenario_text(text, "rolling_only.yaml");
  ASSERT_EQ(rolling.system->dof(), wheels.system->dof());
  ukdyn::ForwardData d(*rolling.system);
  const double L = kLx + kLy;
  double err_f = 0, f_max = 0, err_spin = 0, spin_max = 0, err_qdd = 0, qdd_max = 0, tau_max = 0;
  double err_map = 0;
  for (std::size_t i = 0; i < sw.size(); ++i) {
    const Sample &w = sw[i], &p = sp[i];
    Vec applied = w.Qc;
    for (int robot = 0; robot < 2; ++robot) {
      const int base = 11 * robot, pb = 6 * robot;
      for (int k = 0; k < 2; ++k) {  // the platform's total force is the paper's
        err_f = std::max(err_f, std::abs(w.Qc(base + k) - p.Qc(pb + k)));
        f_max = std::max(f_max, std::abs(p.Qc(pb + k)));
      }
      std::array<double, 4> floor{}, tau_w{};
      for (int k = 0; k < 4; ++k) {  // passive wheels: the floor spins each one up, J φ̈
        floor[k] = w.Qc(base + 3 + k);
        err_spin = std::max(err_spin, std::abs(floor[k] - kSpin * w.qdd(base + 3 + k)));
        spin_max = std::max(spin_max, std::abs(floor[k]));
      }
      const double c = std::cos(w.q(base + 2)), s = std::sin(w.q(base + 2));
      const double fx = w.Qc(base), fy = w.Qc(base + 1), mz = w.Qc(base + 2);
      const std::array<double, 3> f = {c * fx + s * fy, -s * fx + c * fy, mz};
      const double h = kRadius * kRadius / 4;
      const std::array<double, 4> tau = mecanum_ik({h * f[0], h * f[1], h * f[2] / (L * L)});
      for (int k = 0; k < 4; ++k) {
        tau_w[k] = floor[k] + tau[k];
        applied(base + 3 + k) = tau_w[k];
        tau_max = std::max(tau_max, std::abs(tau_w[k]));
      }
      for (int k = 0; k < 3; ++k) applied(base + k) = 0;
      // Hᵀ τ_w = F + Hᵀ J φ̈: the paper's force plus the wheels' own spin-up.
      const auto mapped = mecanum_wrench(tau_w), spinup = mecanum_wrench(floor);
      for (int k = 0; k < 3; ++k)
        err_map = std::max(err_map, std::abs(mapped[k] - f[k] - spinup[k]));
    }
    ukdyn::forward(*rolling.system, d, w.t, w.q, w.qd, applied);
    err_qdd = std::max(err_qdd, (d.qdd - w.qdd).lpNorm<Eigen::Infinity>());
    qdd_max = std::max(qdd_max, w.qdd.lpNorm<Eigen::Infinity>());
  }
  std::printf(
      "[ measured ] paper_mecanum: platform force up to %.4g N (vs paper_chain %.2g), "
      "floor torque on the passive wheels up to %.3g N m (vs J phi'' %.2g), wheel torques "
      "up to %.4g N m (H^T tau - F - spin-up %.2g N), q'' with the rolling rows only %.2g "
      "of %.3g\n",
      f_max, err_f, spin_max, err_spin, tau_max, err_map, err_qdd, qdd_max);
  EXPECT_LT(err_f, 1e-9 * f_max);
  EXPECT_LT(err_spin, 1e-9 * spin_max);
  EXPECT_LT(err_map, 1e-9 * f_max);
  EXPECT_LT(err_qdd, 1e-9 * qdd_max);
}

// scenarios/paper_mecanum_wheels.yaml: the task servo-controlled through the wheel and joint
// torques alone (law stabilized, ω = 5, the plant is the model). Evidence: the yaw row started
// 0.02 rad off obeys ë + 2ωė + ω²e = 0 from (e0, 0), e = e0 (1 + ωt) e^{−ωt}; the other servo rows
// stay at 0; the actuation is exact (no residual); and the four wheels of each platform carry no
// share along null(Hᵀ) = (1, 1, −1, −1) (FL, FR, RL, RR: torques that only strain the platform
// against the floor), as the least-norm solution of the redundant actuation must.
TEST(WheeledPaper, WheelsServoTheTask) {
  const std::filesystem::path root = std::filesystem::path(UKDYN_SOURCE_DIR) / "scenarios";
  ukdyn::Scenario sc = ukdyn::load_scenario(root / "paper_mecanum_wheels.yaml");
  sc.sim.t_end = 2.0;
  const ukdyn::MemoryRun run = ukdyn::run_scenario_in_memory(sc);
  ASSERT_TRUE(run.report.complete()) << run.report.stats.message;
  const std::size_t cols = run.header.size();
  auto col = [&](const std::string& name) {
    const auto it = std::find(run.header.begin(), run.header.end(), name);
    EXPECT_NE(it, run.header.end()) << name;
    return static_cast<std::size_t>(it - run.header.begin());
  };
  const std::size_t t_col = col("t"), psi_e = col("e_hold_psi1"), res = col("act_residual");
  std::vector<std::size_t> others;
  for (const char* n : {"e_traj_x", "e_traj_y", "e_traj_z", "e_hold_dx1", "e_hold_dx2",
                        "e_hold_delta1", "e_hold_psi2"})
    others.push_back(col(n));
  const std::size_t w1 = col("u_w1fl"), w2 = col("u_w2fl");
  ASSERT_EQ(w1 + 3, col("u_w1rr"));
  ASSERT_EQ(w2 + 3, col("u_w2rr"));
  const double omega = 5, e0 = 0.02;
  double err_psi = 0, err_other = 0, worst_res = 0, strain = 0, u_max = 0;
  for (std::size_t r = 0; r * cols < run.values.size(); ++r) {
    const double* row = run.values.data() + r * cols;
    const double t = row[t_col];
    err_psi = std::max(err_psi, std::abs(row[psi_e] - e0 * (1 + omega * t) * std::exp(-omega * t)));
    for (const std::size_t c : others) err_other = std::max(err_other, std::abs(row[c]));
    worst_res = std::max(worst_res, row[res]);
    for (const std::size_t w : {w1, w2}) {
      strain = std::max(strain, std::abs(row[w] + row[w + 1] - row[w + 2] - row[w + 3]));
      for (int k = 0; k < 4; ++k) u_max = std::max(u_max, std::abs(row[w + k]));
    }
  }
  std::printf(
      "[ measured ] paper_mecanum_wheels: yaw error vs closed form %.2g rad, other servo "
      "rows %.2g, actuation residual %.2g, wheel torques up to %.4g N m, share along "
      "null(H^T) %.2g N m\n",
      err_psi, err_other, worst_res, u_max, strain);
  EXPECT_LT(err_psi, 1e-8);
  EXPECT_LT(err_other, 1e-8);
  EXPECT_LT(worst_res, 1e-8);
  EXPECT_GT(u_max, 0.1);
  EXPECT_LT(strain, 1e-9 * u_max);
}

}  // namespace
