// Derivatives of controlled runs (ukdyn/run/closed_loop_derivatives.hpp, docs/derivatives.md,
// "Controlled runs"): the law's ∂τ/∂(q, q̇) against plain central differences, the closed loop's
// eigenvalues against the closed forms of the servo laws and against those identified from a
// nonlinear run, and the run sensitivities of a controlled run against a closed form (the
// pendulum's error dynamics) and against differences of whole closed-loop runs (paper_control).
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cmath>
#include <complex>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "control_systems.hpp"
#include "simulate/exact_jacobian.hpp"
#include "ukdyn/model/minimal_linearize.hpp"
#include "ukdyn/run/closed_loop_derivatives.hpp"
#include "ukdyn/run/run.hpp"
#include "ukdyn/run/sensitivity.hpp"
#include "ukdyn/scenario/scenario.hpp"

namespace {

using namespace ukdyn;
const std::filesystem::path kSource = UKDYN_SOURCE_DIR;
constexpr double kTheta = 0.3;  // the held angle of the pendulum

// A bob on a rod of length 1 held at the angle 0.3 (the servo row x cos 0.3 + z sin 0.3 =
// sin(θ − 0.3), θ the angle from the downward vertical), pushed by a horizontal force. `law` is
// the control section's law keys; `extra` more keys of the control section.
std::string hold_yaml(const std::string& law, const std::string& extra = "", double offset = 1e-3,
                      double t_end = 2.0) {
  std::ostringstream s;
  s.precision(17);
  s << "ukdyn: 1\nname: pendulum_hold\ngravity: 9.8\nsubsystems:\n  - name: bob\n"
       "    type: definitions\n    coordinates: [x, z]\n    parameters: {m: 1}\n"
       "    bodies:\n      - {name: bob, mass: m, com: [x, 0, z]}\nconstraints:\n"
       "  - {type: expression, name: rod, rows: {circle: (x^2 + z^2 - 1)/2}}\n"
       "  - {type: expression, name: swing, role: servo, rows: {angle: x*cos(0.3) + z*sin(0.3)}}\n"
       "actuators:\n  - {name: fx, coordinate: x}\ncontrol:\n"
    << law << extra << "  initial_offset: {swing_angle: " << offset << "}\n"
    << "initial:\n  q: [" << std::sin(kTheta) << ", " << -std::cos(kTheta) << "]\n"
    << "simulation: {t_end: " << t_end << ", sample_dt: 0.01, abs_tol: 1e-12, rel_tol: 1e-12}\n";
  return s.str();
}

std::filesystem::path write_temp(const std::string& name, const std::string& text) {
  const auto p = std::filesystem::path(testing::TempDir()) / name;
  std::ofstream(p) << text;
  return p;
}

// max |a − b| / max |b|
double rel(const Mat& a, const Mat& b) {
  const double s = b.cwiseAbs().maxCoeff();
  return (a - b).cwiseAbs().maxCoeff() / (s > 0.0 ? s : 1.0);
}

// The eigenvalues of the closed loop's minimal F at (t, q, q̇), sorted by real, then imaginary part.
std::vector<std::complex<double>> closed_loop_eigenvalues(const Scenario& sc, double t,
                                                          const Vec& q, const Vec& qd) {
  const ClosedLoopLinearization cl = closed_loop_linearization(sc, t, q, qd);
  const auto run = make_control_run(sc);
  const MinimalModel mm = minimal_model(*run->plant, t, q, qd, cl.law.tau, cl.lin);
  const Eigen::EigenSolver<Mat> es(mm.F_min, false);
  std::vector<std::complex<double>> ev(es.eigenvalues().begin(), es.eigenvalues().end());
  std::sort(ev.begin(), ev.end(), [](auto a, auto b) {
    return a.real() != b.real() ? a.real() < b.real() : a.imag() < b.imag();
  });
  return ev;
}

// ∂τ/∂(q, q̇) and ∂τ/∂t of law_derivatives() against plain central differences of the loop's τ
// with a step of 1e-7 max(1, |x_j|): the worst column, relative to the largest entry.
double law_check(const Scenario& sc, double t, const Vec& q, const Vec& qd) {
  const auto run = make_control_run(sc);
  const LawDerivatives ld = law_derivatives(*run, t, q, qd);
  EXPECT_TRUE(ld.kinks.empty());
  const Index n = q.size();
  Mat dq(n, n), dqd(n, n);
  Vec tp(n), tm(n);
  for (Index j = 0; j < n; ++j) {
    for (int which = 0; which < 2; ++which) {
      Vec a = which == 0 ? q : qd;
      const double h = 1e-7 * std::max(1.0, std::abs(a(j)));
      a(j) += h;
      run->loop->evaluate(t, which == 0 ? a : q, which == 0 ? qd : a);
      run->loop->plant_tau(tp);
      a(j) -= 2 * h;
      run->loop->evaluate(t, which == 0 ? a : q, which == 0 ? qd : a);
      run->loop->plant_tau(tm);
      (which == 0 ? dq : dqd).col(j) = (tp - tm) / (2 * h);
    }
  }
  const double ht = 1e-7 * std::max(1.0, std::abs(t));
  run->loop->evaluate(t + ht, q, qd);
  run->loop->plant_tau(tp);
  run->loop->evaluate(t - ht, q, qd);
  run->loop->plant_tau(tm);
  Mat both(n, 2 * n + 1), ref(n, 2 * n + 1);
  both << ld.dtau_dq, ld.dtau_dqd, ld.dtau_dt;
  ref << dq, dqd, (tp - tm) / (2 * ht);
  return rel(both, ref);
}

// A bob on a rod in space (x, y, z) with two servo rows, x = 0.3 and y = 0.2 sin x, and one
// actuator on x: the actuators cannot realise the servo force (the actuation solve's residual
// P (Qc − B u) is not 0: the term of the pseudo-inverse's derivative that vanishes otherwise).
std::string underactuated_yaml() {
  const double x = 0.3, y = 0.2 * std::sin(x), z = -std::sqrt(1.0 - x * x - y * y);
  std::ostringstream s;
  s.precision(17);
  s << "ukdyn: 1\nname: underactuated\ngravity: 9.8\nsubsystems:\n  - name: bob\n"
       "    type: definitions\n    coordinates: [x, y, z]\n    parameters: {m: 1}\n"
       "    bodies:\n      - {name: bob, mass: m, com: [x, y, z]}\nconstraints:\n"
       "  - {type: expression, name: rod, rows: {circle: (x^2 + y^2 + z^2 - 1)/2}}\n"
       "  - {type: expression, name: sx, role: servo, rows: {x: x - 0.3}}\n"
       "  - {type: expression, name: sy, role: servo, rows: {y: y - 0.2*sin(x)}}\n"
       "actuators:\n  - {name: fx, coordinate: x}\ncontrol:\n  law: feedforward\n"
       "initial:\n  q: ["
    << x << ", " << y << ", " << z << "]\nsimulation: {t_end: 1, sample_dt: 0.01}\n";
  return s.str();
}

// ∂τ/∂(q, q̇) of the loop by Richardson's extrapolation of central differences with the step
// 1e-4 max(1, |x_j|) ([Richardson1911]; error O(h⁴), round-off ≈ 1e-16 |τ| / h): larger than
// law_derivatives_by_differences()'s 1e-6, whose round-off on paper_control (|τ| ≈ 200 against
// |∂τ/∂q| ≈ 30) reaches 1e-7 of the largest entry; smaller than 1e-3, whose truncation error near
// the servo rows reaches 5e-6 for the robust term −ρ β/‖β‖ (curvature ρ/‖β‖²).
// Column 2n: ∂τ/∂t at fixed (q, q̇), the same way in t.
Mat richardson_jacobian(ControlRun& run, double t, const Vec& q, const Vec& qd) {
  const Index n = q.size();
  Mat D(n, 2 * n + 1);
  std::array<Vec, 4> tau;
  for (Index j = 0; j <= 2 * n; ++j) {
    const double h = 1e-4 * std::max(1.0, std::abs(j < n ? q(j) : j < 2 * n ? qd(j - n) : t));
    const std::array<double, 4> at = {h, -h, h / 2, -h / 2};
    for (std::size_t k = 0; k < 4; ++k) {
      Vec a = q, b = qd;
      double tk = t;
      (j < n ? a(j) : j < 2 * n ? b(j - n) : tk) += at[k];
      tau[k].resize(n);
      run.loop->evaluate(tk, a, b);
      run.loop->plant_tau(tau[k]);
    }
    D.col(j) = ((4.0 / h) * (tau[2] - tau[3]) - (0.5 / h) * (tau[0] - tau[1])) / 3.0;
  }
  return D;
}

// The exact ∂τ/∂(q, q̇) of law_derivatives() (method "exact") against richardson_jacobian() and
// against the fallback law_derivatives_by_differences() at a random state near the scenario's
// start, with `law` in place of the scenario's: the worst entry relative to the largest, each.
std::pair<double, double> exact_against_differences(Scenario sc, const ServoLawSettings& law,
                                                    unsigned seed) {
  auto spec = std::make_shared<ControlSpec>(*sc.control);
  spec->law = law;
  sc.control = spec;
  const auto run = make_control_run(sc);
  std::srand(seed);
  const Index n = run->q0.size();
  const Vec q = run->q0 + 1e-2 * Vec::Random(n), qd = run->qd0 + 0.1 * Vec::Random(n);
  const double t = 0.1 + 0.5 * (1.0 + Vec::Random(1)(0));
  const LawDerivatives exact = law_derivatives(*run, t, q, qd);
  EXPECT_EQ(exact.method, "exact") << sc.name;
  EXPECT_EQ(exact.dtau_dt_method, "exact") << sc.name;
  EXPECT_TRUE(exact.kinks.empty()) << sc.name;
  const LawDerivatives diff = law_derivatives_by_differences(*run, t, q, qd);
  EXPECT_EQ(diff.method, "differences: asked for");
  EXPECT_EQ(diff.dtau_dt_method, "differences: asked for");
  Mat a(n, 2 * n + 1), b(n, 2 * n + 1);
  a << exact.dtau_dq, exact.dtau_dqd, exact.dtau_dt;
  b << diff.dtau_dq, diff.dtau_dqd, diff.dtau_dt;
  const Mat ref = richardson_jacobian(*run, t, q, qd);
  EXPECT_GT(ref.cwiseAbs().maxCoeff(), 0.0);
  // ∂τ/∂t on its own scale (it is 0 where nothing depends on t, tiny against ∂τ/∂x elsewhere)
  const double dt_scale = std::max(ref.col(2 * n).cwiseAbs().maxCoeff(), 1e-3);
  const double dt_err = (a.col(2 * n) - ref.col(2 * n)).cwiseAbs().maxCoeff() / dt_scale;
  EXPECT_LT(dt_err, 1e-7) << sc.name << ": d tau/dt " << a.col(2 * n).transpose() << " against "
                          << ref.col(2 * n).transpose();
  return {std::max(rel(a, ref), dt_err), rel(a, b)};
}

}  // namespace

// The law's derivatives against central differences: the three built-in laws on the pendulum at
// a moving state off the servo row, and the paper's robust law at its start (outside the layer).
TEST(ControlDerivatives, LawDerivativesMatchCentralDifferences) {
  const Vec q = (Vec(2) << std::sin(0.35), -std::cos(0.35)).finished();
  const Vec qd = (Vec(2) << 0.2 * std::cos(0.35), 0.2 * std::sin(0.35)).finished();
  for (const std::string law :
       {"  law: feedforward\n", "  law: stabilized\n  omega: 4\n",
        "  law: robust\n  lambda: 2\n  kappa: 5\n  rho: 2\n  epsilon: 0.01\n"}) {
    const Scenario sc = load_scenario_text(hold_yaml(law), "pendulum_hold.yaml");
    const double r = law_check(sc, 0.4, q, qd);
    std::cout << "[ control ] pendulum, " << law.substr(7, law.find('\n') - 7)
              << ": d tau/dx against central differences " << r << "\n";
    EXPECT_LT(r, 1e-7) << law;
  }
  // the moving reference θr(t) = 0.3 (1 − cos 2t) of tests/control_systems.hpp: ∂τ/∂t ≠ 0
  const Scenario moving = load_scenario_text(
      uktest::pendulum_servo_yaml(
          1.0, "control:\n  law: robust\n  lambda: 2\n  kappa: 5\n  rho: 2\n  epsilon: 0.01\n"),
      "pendulum_servo.yaml");
  const double rm = law_check(moving, 0.4, q, qd);
  std::cout << "[ control ] moving reference, robust: d tau/d(x, t) against central differences "
            << rm << "\n";
  EXPECT_LT(rm, 1e-7);
  const Scenario paper = load_scenario(kSource / "scenarios" / "paper_control.yaml");
  const auto run = make_control_run(paper);
  const double r = law_check(paper, 0.0, run->q0, run->qd0);
  std::cout << "[ control ] paper_control at its start: d tau/dx against central differences " << r
            << "\n";
  EXPECT_LT(r, 1e-7);
}

// Each law kind (the robust law outside and inside its boundary layer, and without its robust
// term) on paper_control.yaml, paper_mecanum_wheels.yaml, the held pendulum (one actuator, one
// physical row: the actuation solve's projector and pseudo-inverse move with q) and the pendulum
// with a moving reference (A of the servo row depends on t): exact against differences.
TEST(ControlDerivatives, ExactLawJacobianMatchesDifferences) {
  ServoLawSettings ff, st, ro, inside, fb;
  ff.kind = ControlLawKind::feedforward;
  st.kind = ControlLawKind::stabilized;
  st.omega = 4.0;
  ro.kind = inside.kind = fb.kind = ControlLawKind::robust;
  ro.lambda = inside.lambda = fb.lambda = 2.0;
  ro.kappa = inside.kappa = fb.kappa = 5.0;
  ro.rho = inside.rho = 2.0;
  ro.epsilon = 1e-3;
  inside.epsilon = 1e3;
  fb.rho = 0.0;
  const std::vector<std::pair<std::string, Scenario>> scenarios = {
      {"paper_control", load_scenario(kSource / "scenarios" / "paper_control.yaml")},
      {"paper_mecanum_wheels", load_scenario(kSource / "scenarios" / "paper_mecanum_wheels.yaml")},
      {"held pendulum", load_scenario_text(hold_yaml("  law: feedforward\n"), "hold.yaml")},
      {"moving reference",
       load_scenario_text(uktest::pendulum_servo_yaml(1.0, "control:\n  law: feedforward\n"),
                          "pendulum_servo.yaml")},
      {"underactuated bob", load_scenario_text(underactuated_yaml(), "underactuated.yaml")}};
  const std::vector<std::pair<std::string, ServoLawSettings>> laws = {
      {"feedforward", ff},
      {"stabilized", st},
      {"robust outside the layer", ro},
      {"robust inside the layer", inside},
      {"robust, rho 0", fb}};
  for (const auto& [sname, sc] : scenarios) {
    double worst = 0.0, worst_fallback = 0.0;
    for (const auto& [lname, law] : laws) {
      for (unsigned seed = 1; seed <= 3; ++seed) {
        const auto [r, r_fallback] = exact_against_differences(sc, law, seed);
        EXPECT_LT(r, 1e-7) << sname << ", " << lname << ", seed " << seed;
        EXPECT_LT(r_fallback, 1e-6) << sname << ", " << lname << ", seed " << seed;
        worst = std::max(worst, r);
        worst_fallback = std::max(worst_fallback, r_fallback);
      }
    }
    std::cout << "[ control ] " << sname << ", five laws at three random states: exact "
              << "d tau/d(x, t) against Richardson (step 1e-4) " << worst
              << ", against the fallback (step 1e-6) " << worst_fallback << "\n";
  }
}

// At the held equilibrium on the exact model, the servo error obeys a linear ODE whose roots are
// known: feedback-only robust law (ρ = 0): ë + (λ + κ)ė + κλ e = 0, roots −λ, −κ; inside the
// robust term's boundary layer (γ = 1/ε): β̇ = −(κ + ρ²/ε) β, roots −λ, −(κ + ρ²/ε); stabilized:
// (s + ω)², trace −2ω and determinant ω² (a double root, itself sensitive to round-off).
TEST(ControlDerivatives, ClosedLoopEigenvaluesClosedForms) {
  const Vec q = (Vec(2) << std::sin(kTheta), -std::cos(kTheta)).finished();
  const Vec qd = Vec::Zero(2);
  auto check = [&](const std::string& law, double r1, double r2) {
    const Scenario sc = load_scenario_text(hold_yaml(law), "pendulum_hold.yaml");
    const auto ev = closed_loop_eigenvalues(sc, 0.0, q, qd);
    ASSERT_EQ(ev.size(), 2u);
    const double e =
        std::max(std::abs(ev[0] - r1) / std::abs(r1), std::abs(ev[1] - r2) / std::abs(r2));
    std::cout << "[ control ] held pendulum: eigenvalues " << ev[0] << ", " << ev[1] << " against "
              << r1 << ", " << r2 << ": relative " << e << "\n";
    EXPECT_LT(e, 1e-8) << law;
  };
  check("  law: robust\n  lambda: 2\n  kappa: 5\n  rho: 0\n", -5.0, -2.0);
  check("  law: robust\n  lambda: 2\n  kappa: 5\n  rho: 0.5\n  epsilon: 0.1\n", -7.5, -2.0);
  const Scenario sc = load_scenario_text(hold_yaml("  law: stabilized\n  omega: 4\n"), "p.yaml");
  const ClosedLoopLinearization cl = closed_loop_linearization(sc, 0.0, q, qd);
  const MinimalModel mm =
      minimal_model(*make_control_run(sc)->plant, 0.0, q, qd, cl.law.tau, cl.lin);
  std::cout << "[ control ] stabilized, omega 4: trace " << mm.F_min.trace() << ", det "
            << mm.F_min.determinant() << "\n";
  EXPECT_NEAR(mm.F_min.trace(), -8.0, 1e-8);
  EXPECT_NEAR(mm.F_min.determinant(), 16.0, 1e-7);
}

// A heavier plant (bob 1.5 kg, the model 1 kg): no closed form. The closed loop settles at an
// equilibrium off the servo row; the linearisation there against the eigenvalues identified from a
// nonlinear run started 1e-4 away from it: θ_k sampled every 0.01 s fits the second-order
// recurrence δθ_{k+2} = a δθ_{k+1} + b δθ_k (least squares), whose roots are e^{s h}.
TEST(ControlDerivatives, ClosedLoopEigenvaluesMatchANonlinearRun) {
  const std::string law =
      "  law: robust\n  lambda: 2\n  kappa: 5\n  rho: 0\n"
      "  plant_set:\n    - {path: \"subsystems[bob].parameters.m\", value: 1.5}\n";
  // 1. the equilibrium: a long run from the offset start.
  const Scenario settle = load_scenario_text(hold_yaml(law, "", 1e-3, 20.0), "settle.yaml");
  const MemoryRun long_run = run_scenario_in_memory(settle, {});
  const std::size_t cols = long_run.header.size(), rows = long_run.values.size() / cols;
  auto at = [&](const MemoryRun& m, std::size_t r, const std::string& c) {
    const auto it = std::find(m.header.begin(), m.header.end(), c);
    EXPECT_NE(it, m.header.end()) << c;
    return m.values[r * cols + static_cast<std::size_t>(it - m.header.begin())];
  };
  const Vec q_eq = (Vec(2) << at(long_run, rows - 1, "x"), at(long_run, rows - 1, "z")).finished();
  const double e_eq = at(long_run, rows - 1, "e_swing_angle");
  EXPECT_LT(std::abs(at(long_run, rows - 1, "x_dot")), 1e-9);
  // 2. the closed loop's eigenvalues there.
  const auto ev = closed_loop_eigenvalues(settle, 0.0, q_eq, Vec::Zero(2));
  // 3. a nonlinear run from 1e-4 off the equilibrium (the offset start at e_eq + 1e-4, at rest).
  const Scenario near = load_scenario_text(hold_yaml(law, "", e_eq + 1e-4, 3.0), "near.yaml");
  const MemoryRun r = run_scenario_in_memory(near, {});
  const std::size_t n_rows = r.values.size() / cols;
  const double theta_eq = std::atan2(q_eq(0), -q_eq(1));
  Vec d(static_cast<Index>(n_rows));
  for (std::size_t k = 0; k < n_rows; ++k)
    d(static_cast<Index>(k)) = std::atan2(at(r, k, "x"), -at(r, k, "z")) - theta_eq;
  const Index K = d.size() - 2;
  Mat X(K, 2);
  X << d.segment(1, K), d.segment(0, K);
  const Eigen::Vector2d ab = X.colPivHouseholderQr().solve(d.segment(2, K));
  const std::complex<double> disc = std::sqrt(std::complex<double>(ab(0) * ab(0) + 4 * ab(1)));
  std::vector<std::complex<double>> id = {std::log((ab(0) + disc) / 2.0) / 0.01,
                                          std::log((ab(0) - disc) / 2.0) / 0.01};
  std::sort(id.begin(), id.end(), [](auto a, auto b) {
    return a.real() != b.real() ? a.real() < b.real() : a.imag() < b.imag();
  });
  ASSERT_EQ(ev.size(), 2u);
  const double e = std::max(std::abs(ev[0] - id[0]) / std::abs(id[0]),
                            std::abs(ev[1] - id[1]) / std::abs(id[1]));
  std::cout << "[ control ] plant 1.5 kg, model 1 kg: closed-loop eigenvalues " << ev[0] << ", "
            << ev[1] << "; identified from the run " << id[0] << ", " << id[1] << ": relative " << e
            << "\n";
  EXPECT_LT(e, 1e-3);
  EXPECT_GT(std::abs(ev[0] + 5.0), 1e-2);  // not the exact model's roots
}

// The pendulum held by the feedback-only robust law on its exact model: e = sin(θ − 0.3) obeys
// ë + (λ + κ)ė + κλ e = 0 from e0 (the offset), ė0 = 0, so
// e(t) = e0 (κ e^{−λt} − λ e^{−κt}) / (κ − λ), and dq/dκ, dq/dλ follow from θ = 0.3 + asin e,
// q = (sin θ, −cos θ); dq/dm = 0 (the plant is the model: the error dynamics do not see m).
TEST(ControlRunSensitivity, ClosedFormOfThePendulumServo) {
  const double lambda = 2.0, kappa = 5.0, e0 = 1e-3;
  const auto path =
      write_temp("hold_sens.yaml", hold_yaml("  law: robust\n  lambda: 2\n  kappa: 5\n  rho: 0\n"));
  const Scenario sc = load_scenario(path);
  const RunSensitivities rs =
      run_sensitivities(sc, scenario_parameters(sc, {"m", "control.kappa", "control.lambda"}));
  ASSERT_TRUE(rs.trusted) << rs.message;
  EXPECT_TRUE(rs.warnings.empty());
  const auto T = static_cast<Index>(rs.t.size());
  Mat dk(T, 2), dl(T, 2);
  for (Index k = 0; k < T; ++k) {
    const double t = rs.t[static_cast<std::size_t>(k)];
    const double a = std::exp(-lambda * t), b = std::exp(-kappa * t), D = kappa - lambda;
    const double e = e0 * (kappa * a - lambda * b) / D;
    const double de_dk = e0 * ((a + lambda * t * b) / D - (kappa * a - lambda * b) / (D * D));
    const double de_dl = e0 * ((-kappa * t * a - b) / D + (kappa * a - lambda * b) / (D * D));
    const double th = kTheta + std::asin(e), dth = 1.0 / std::sqrt(1.0 - e * e);
    dk.row(k) << std::cos(th) * dth * de_dk, std::sin(th) * dth * de_dk;
    dl.row(k) << std::cos(th) * dth * de_dl, std::sin(th) * dth * de_dl;
  }
  const double rk = rel(rs.dq_dp[1], dk), rl = rel(rs.dq_dp[2], dl);
  const double rm = rs.dq_dp[0].cwiseAbs().maxCoeff() / dk.cwiseAbs().maxCoeff();
  std::cout << "[ control ] pendulum servo, 2 s: dq/dkappa " << rk << ", dq/dlambda " << rl
            << " relative to the closed form; max |dq/dm| / max |dq/dkappa| " << rm << "; steps "
            << rs.steps << "\n";
  EXPECT_LT(rk, 1e-6);
  EXPECT_LT(rl, 1e-6);
  EXPECT_LT(rm, 1e-6);
  // the law's ∂τ/∂x exact at every right-hand side (no kink: ρ = 0, no limit)
  EXPECT_EQ(rs.law_derivative.rfind("exact at ", 0), 0u) << rs.law_derivative;
  EXPECT_EQ(rs.law_derivative.find("differences"), std::string::npos) << rs.law_derivative;
}

// paper_control.yaml over 2 s (0.3 s under a sanitizer; tolerance 1e-10 for the variational run): dq/dp for a mass of the
// controller's model (m3, both halves of the load) and for the gain κ, against Richardson
// differences of four whole closed-loop runs of the hand-edited file (simulate() of the plant
// under the loop, no drift control, tolerance 1e-13), over every sample.
TEST(ControlRunSensitivity, PaperControlMatchesWholeRuns) {
  std::ifstream f(kSource / "scenarios" / "paper_control.yaml");
  std::stringstream ss;
  ss << f.rdbuf();
  std::string text = ss.str();
  auto replace = [](std::string s, const std::string& a, const std::string& b) {
    const auto at = s.find(a);
    EXPECT_NE(at, std::string::npos) << a;
    return at == std::string::npos ? s : s.replace(at, a.size(), b);
  };
  const std::string plant = (kSource / "scenarios" / "paper_generic_exact_inertia.yaml").string();
  text = replace(text, "plant: paper_generic_exact_inertia.yaml", "plant: " + plant);
#ifdef UKDYN_TEST_SANITIZED
  // 10-20 times slower under a sanitizer: the same code paths over 0.3 s (the layer is crossed
  // at t = 0.065 s)
  text = replace(text, "t_end: 4", "t_end: 0.3");
#else
  text = replace(text, "t_end: 4", "t_end: 2");
#endif
  text = replace(text, "abs_tol: 1e-13", "abs_tol: 1e-10");
  text = replace(text, "rel_tol: 1e-13", "rel_tol: 1e-10");
  const auto path = write_temp("paper_control_2s.yaml", text);
  const Scenario sc = load_scenario(path);
  const RunSensitivities rs =
      run_sensitivities(sc, scenario_parameters(sc, {"m3", "control.kappa"}));
  ASSERT_TRUE(rs.trusted) << rs.message;
  const auto T = static_cast<Index>(rs.t.size());
  struct Edit {
    std::string before;
    double value;
  };
  const std::vector<Edit> edits = {{"      m3: 1\n", 1.0}, {"  kappa: 5\n", 5.0}};
  for (std::size_t j = 0; j < edits.size(); ++j) {
    auto run = [&](double h) {
      const std::string key = edits[j].before.substr(0, edits[j].before.find(':') + 2);
      std::ostringstream v;
      v.precision(17);
      v << key << edits[j].value + h << "\n";
      const Scenario s = load_scenario_text(replace(text, edits[j].before, v.str()), path);
      const auto cr = make_control_run(s);
      SimulationSettings set = s.sim;
      set.drift.kind = DriftControl::none;
      set.energy_balance = false;
      set.abs_tol = set.rel_tol = 1e-13;
      Mat q(T, cr->plant->dof());
      Index k = 0;
      simulate(*cr->plant, cr->q0, cr->qd0, cr->loop->force_function(), set,
               [&](double, CVecRef qk, CVecRef, const ForwardData&) {
                 if (k < q.rows()) q.row(k++) = qk.transpose();
                 return true;
               });
      EXPECT_EQ(k, T);
      return q;
    };
    const double h = 1e-3 * edits[j].value;
    const Mat fd = (4 * (run(h / 2) - run(-h / 2)) / h - (run(h) - run(-h)) / (2 * h)) / 3;
    const double r = rel(rs.dq_dp[j], fd);
    std::cout << "[ control ] paper_control, 2 s, " << rs.parameters[j] << ": max |dq/dp| "
              << fd.cwiseAbs().maxCoeff() << ", relative difference to whole-run differences " << r
              << "; steps " << rs.steps << ", rhs evaluations " << rs.rhs_evaluations << "\n";
    // 2e-6: max |dq/dκ| is 4.6e-4, so the run's absolute tolerance (1e-10) is already 2e-7 of it
    // per step, and the run crosses the boundary layer; changes of the model at round-off (q̈ the
    // same to 4e-15) moved this error between 2.5e-7 and 1.03e-6 (docs/derivatives.md).
    EXPECT_LT(r, 2e-6) << rs.parameters[j];
  }
  std::cout << "[ control ] the law's d tau/dx: " << rs.law_derivative << "\n";
  EXPECT_EQ(rs.law_derivative.rfind("exact at ", 0), 0u) << rs.law_derivative;
  // the robust law crosses its boundary layer in this run: said, with the law and the time
  ASSERT_FALSE(rs.warnings.empty());
  EXPECT_NE(rs.warnings[0].find("the robust control law is not differentiable at t = "),
            std::string::npos);
  for (const auto& w : rs.warnings) std::cout << "[ control ] warning: " << w << "\n";
}

// An actuator limit: started 0.05 rad off, the law's u reaches its limit 3.2 during the run; the
// gain κ is still a parameter (u before saturation changes with it), the run says where the
// clipping makes the law non-differentiable, and the law's derivatives at a state on the limit
// name it (not at a sample before it).
TEST(ControlRunSensitivity, SaturationIsNamed) {
  const std::string law = "  law: robust\n  lambda: 2\n  kappa: 5\n  rho: 0\n";
  std::string text = hold_yaml(law, "", 0.05);
  const std::string act = "  - {name: fx, coordinate: x}";
  text.replace(text.find(act), act.size(), "  - {name: fx, coordinate: x, limit: 3.2}");
  const auto path = write_temp("hold_saturated.yaml", text);
  const Scenario sc = load_scenario(path);
  const RunSensitivities rs = run_sensitivities(sc, scenario_parameters(sc, {"control.kappa"}));
  ASSERT_FALSE(rs.warnings.empty());
  EXPECT_NE(rs.warnings[0].find("actuator 'fx' at its limit 3.2"), std::string::npos)
      << rs.warnings[0];
  std::cout << "[ control ] saturated run: " << rs.warnings[0] << "\n";
  // a state whose u is at the limit: between the first two samples of the run on either side of
  // it, by bisection on the segment joining them (t, q, q̇ interpolated linearly)
  const auto run = make_control_run(sc);
  auto state = [&](std::size_t k, double s) {
    const auto i = static_cast<Index>(k);
    Vec x(5);
    x << (1 - s) * rs.t[k] + s * rs.t[k + 1],
        ((1 - s) * rs.q.row(i) + s * rs.q.row(i + 1)).transpose(),
        ((1 - s) * rs.qd.row(i) + s * rs.qd.row(i + 1)).transpose();
    return x;
  };
  auto over = [&](const Vec& x) {
    run->loop->evaluate(x(0), x.segment(1, 2), x.segment(3, 2));
    return std::abs(run->loop->u_raw(0)) - 3.2;
  };
  std::size_t k = 0;
  while (k + 1 < rs.t.size() && (over(state(k, 0.0)) > 0.0) == (over(state(k, 1.0)) > 0.0)) ++k;
  ASSERT_LT(k + 1, rs.t.size()) << "the run never reaches the limit";
  const bool starts_over = over(state(k, 0.0)) > 0.0;
  double lo = 0.0, hi = 1.0;
  for (int it = 0; it < 200 && hi - lo > 1e-15; ++it) {
    const double mid = 0.5 * (lo + hi);
    ((over(state(k, mid)) > 0.0) == starts_over ? lo : hi) = mid;
  }
  const Vec edge = state(k, hi), before = state(k, 0.0);
  std::cout << "[ control ] u at the limit at t = " << edge(0) << "\n";
  const ClosedLoopLinearization cl =
      closed_loop_linearization(sc, edge(0), edge.segment(1, 2), edge.segment(3, 2));
  ASSERT_EQ(cl.law.kinks.size(), 1u);
  EXPECT_EQ(cl.law.kinks[0], "actuator 'fx' at its limit 3.2");
  const ClosedLoopLinearization away =
      closed_loop_linearization(sc, before(0), before.segment(1, 2), before.segment(3, 2));
  EXPECT_TRUE(away.law.kinks.empty());
  // beyond the limit the exact ∂τ/∂(q, q̇) is 0 (u = ±limit), inside it is not
  const Vec beyond = state(k, starts_over ? 0.0 : 1.0), inside = state(k, starts_over ? 1.0 : 0.0);
  for (const bool over_limit : {true, false}) {
    const Vec& x = over_limit ? beyond : inside;
    const ClosedLoopLinearization c =
        closed_loop_linearization(sc, x(0), x.segment(1, 2), x.segment(3, 2));
    EXPECT_EQ(c.law.method, "exact");
    EXPECT_TRUE(c.law.kinks.empty());
    const double size =
        std::max(c.law.dtau_dq.cwiseAbs().maxCoeff(), c.law.dtau_dqd.cwiseAbs().maxCoeff());
    std::cout << "[ control ] " << (over_limit ? "beyond" : "inside")
              << " the limit: max |d tau/dx| " << size << "\n";
    if (over_limit) {
      EXPECT_EQ(size, 0.0);
    } else {
      EXPECT_GT(size, 1.0);
    }
  }
}

#ifdef UKDYN_TEST_HAVE_CLI
#include <nlohmann/json.hpp>

#include "cli_run.hpp"

// `ukdyn linearize --closed-loop` at the held equilibrium (--state) gives the closed forms' roots
// in closed_loop.eigenvalues; without --state it linearises at the closed loop's start; a scenario
// without control: and --param with it are refused (exit 2); `ukdyn sensitivities` takes a gain.
TEST(ControlCli, LinearizeClosedLoopAndGainSensitivities) {
  namespace fs = std::filesystem;
  const fs::path dir = ukdyn_test::process_scratch("control_cli");
  const fs::path sc = dir / "hold.yaml";
  std::ofstream(sc) << hold_yaml("  law: robust\n  lambda: 2\n  kappa: 5\n  rho: 0\n");
  std::ostringstream state;
  state.precision(17);
  state << R"({"q": [)" << std::sin(kTheta) << ", " << -std::cos(kTheta) << R"(], "qd": [0, 0]})";
  std::ofstream(dir / "eq.json") << state.str();
  auto run = [&](const std::string& args) { return ukdyn_test::run_cli(UKDYN_CLI, dir, args); };
  const auto r = run("linearize " + ukdyn_test::sh(sc.string()) + " --closed-loop --state " +
                     ukdyn_test::sh((dir / "eq.json").string()));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  std::vector<double> re;
  for (const auto& e : j["closed_loop"]["eigenvalues"]) re.push_back(e[0].get<double>());
  std::sort(re.begin(), re.end());
  ASSERT_EQ(re.size(), 2u);
  EXPECT_NEAR(re[0], -5.0, 1e-8);
  EXPECT_NEAR(re[1], -2.0, 1e-8);
  EXPECT_EQ(j["closed_loop"]["law"], "robust");
  EXPECT_EQ(j["closed_loop"]["dtau_method"], "exact");
  EXPECT_EQ(j["F"].size(), 4u);
  const auto start = run("linearize " + ukdyn_test::sh(sc.string()) + " --closed-loop");
  ASSERT_EQ(start.exit_code, 0) << start.err;
  // the start: 1e-3 off the servo row (sin(θ − 0.3) = 1e-3), at rest
  const auto js = nlohmann::json::parse(start.out);
  const double th = std::atan2(js["q"][0].get<double>(), -js["q"][1].get<double>());
  EXPECT_NEAR(std::sin(th - kTheta), 1e-3, 1e-12);
  const auto no_control =
      run("linearize " + ukdyn_test::sh((kSource / "scenarios" / "paper.yaml").string()) +
          " --closed-loop");
  EXPECT_EQ(no_control.exit_code, 2);
  EXPECT_NE(no_control.err.find("--closed-loop: the scenario has no control: section"),
            std::string::npos)
      << no_control.err;
  const auto with_param = run("linearize " + ukdyn_test::sh(sc.string()) + " --closed-loop -p m");
  EXPECT_EQ(with_param.exit_code, 2);
  EXPECT_NE(with_param.err.find("does not take parameters"), std::string::npos) << with_param.err;
  const auto sens = run("sensitivities " + ukdyn_test::sh(sc.string()) + " -p control.kappa -o " +
                        ukdyn_test::sh((dir / "out").string()));
  ASSERT_EQ(sens.exit_code, 0) << sens.err;
  EXPECT_NE(ukdyn_test::slurp(dir / "out" / "sensitivities.csv").find("dq_x/dcontrol.kappa"),
            std::string::npos);
}
#endif

namespace {

// paper_control.yaml (the plant under the robust law) for `t_end` s at tolerance `tol`, its plant
// path made absolute.
Scenario paper_control(double t_end, double tol) {
  Scenario sc = load_scenario(kSource / "scenarios" / "paper_control.yaml");
  sc.sim.t_end = t_end;
  sc.sim.abs_tol = sc.sim.rel_tol = tol;
  return sc;
}

struct LoopEnd {
  SimulationStats stats;
  Vec q, qd;
};

// The plant of `sc` under its loop from the offset start, as run_scenario() runs it (run_forces():
// the law's exact ∂τ/∂(q, q̇) as SimulationSettings::tau_jacobian).
LoopEnd run_loop(const Scenario& sc, IntegratorKind kind, JacobianKind jac) {
  const auto run = make_control_run(sc);
  SimulationSettings s = sc.sim;
  s.integrator = kind;
  s.jacobian = jac;
  EXPECT_EQ(law_jacobian_gap(*run), "");
  s.tau_jacobian = law_force_jacobian(*run);
  LoopEnd e;
  e.stats = simulate(*run->plant, run->q0, run->qd0, run->loop->force_function(), s,
                     [&e](double, CVecRef q, CVecRef qd, const ForwardData&) {
                       e.q = q;
                       e.qd = qd;
                       return true;
                     });
  return e;
}

}  // namespace

// The implicit integrators' exact ∂f/∂x on a controlled run (docs/derivatives.md, "Exact
// Jacobians in the implicit integrators"): the law's ∂τ/∂(q, q̇) chained through ∂q̈/∂τ equals
// central differences of the integrators' own right-hand side (the plant under the loop) at states
// off the start; and at a state on the robust law's boundary layer the law gives none (the kink
// named) and the exact Jacobian declines that call (the integrator then takes differences).
TEST(ControlDerivatives, ExactJacobianOfTheClosedLoopEqualsDifferencesOfF) {
  const Scenario sc = paper_control(0.1, 1e-10);
  const auto run = make_control_run(sc);
  SimulationSettings s = sc.sim;
  s.integrator = IntegratorKind::bdf;
  s.energy_balance = false;
  s.tau_jacobian = law_force_jacobian(*run);
  const ForceFunction tau = run->loop->force_function();
  const System& plant = *run->plant;
  EXPECT_EQ(detail::exact_jacobian_gap(plant, tau, s), "");
  const Index n = plant.dof();
  std::srand(7);
  double worst = 0.0;
  for (int trial = 0; trial < 3; ++trial) {
    std::vector<double> x(static_cast<std::size_t>(2 * n));
    const Vec q = run->q0 + 1e-2 * Vec::Random(n), qd = run->qd0 + 0.1 * Vec::Random(n);
    for (Index i = 0; i < n; ++i) {
      x[static_cast<std::size_t>(i)] = q(i);
      x[static_cast<std::size_t>(n + i)] = qd(i);
    }
    const double t = 0.05 + 0.1 * trial;
    detail::ExactJacobian jac(plant, tau, s);
    Mat J = Mat::Zero(2 * n, 2 * n);
    ASSERT_TRUE(jac(t, x.data(), J.data())) << "trial " << trial;
    IntegratorRhs f(plant, tau, s);
    Mat D(2 * n, 2 * n);
    std::array<std::vector<double>, 4> fx;
    for (std::size_t j = 0; j < x.size(); ++j) {  // Richardson, step 1e-4 (richardson_jacobian)
      const double h = 1e-4 * std::max(std::abs(x[j]), 1.0);
      const std::array<double, 4> at = {h, -h, h / 2, -h / 2};
      for (std::size_t k = 0; k < 4; ++k) {
        std::vector<double> xk = x;
        xk[j] += at[k];
        fx[k].resize(x.size());
        f(xk, fx[k], t);
      }
      for (std::size_t i = 0; i < x.size(); ++i) {
        D(static_cast<Index>(i), static_cast<Index>(j)) =
            ((4.0 / h) * (fx[2][i] - fx[3][i]) - (0.5 / h) * (fx[0][i] - fx[1][i])) / 3.0;
      }
    }
    worst = std::max(worst, rel(J, D));
  }
  std::cout << "[ control ] paper_control: exact df/dx of the closed loop against Richardson "
               "differences of f, three random states: "
            << worst << "\n";
  EXPECT_LT(worst, 1e-7);

  // On the boundary layer: the held pendulum at e = 0 moving with ė = ε/ρ (‖μ‖ = ρ|ė| = ε).
  const double rho = 2.0, eps = 0.01;
  const Scenario hold = load_scenario_text(
      hold_yaml("  law: robust\n  lambda: 2\n  kappa: 5\n  rho: 2\n  epsilon: 0.01\n"),
      "hold.yaml");
  const auto hr = make_control_run(hold);
  const Vec hq = (Vec(2) << std::sin(kTheta), -std::cos(kTheta)).finished();
  const Vec on = (eps / rho) * (Vec(2) << std::cos(kTheta), std::sin(kTheta)).finished();
  LawJacobianWorkspace ws(*hr);
  Mat a, b;
  EXPECT_FALSE(law_jacobian(*hr, ws, 0.0, hq, on, a, b));
  ASSERT_EQ(ws.kinks.size(), 1u);
  EXPECT_NE(ws.why_not.find("boundary layer"), std::string::npos) << ws.why_not;
  EXPECT_TRUE(law_jacobian(*hr, ws, 0.0, hq, 1.5 * on, a, b)) << ws.why_not;  // off the layer
  SimulationSettings hs = hold.sim;
  hs.integrator = IntegratorKind::bdf;
  hs.energy_balance = false;
  hs.tau_jacobian = law_force_jacobian(*hr);
  const ForceFunction htau = hr->loop->force_function();
  detail::ExactJacobian hjac(*hr->plant, htau, hs);
  const std::vector<double> hx = {hq(0), hq(1), on(0), on(1)};
  Mat HJ = Mat::Zero(4, 4);
  EXPECT_FALSE(hjac(0.0, hx.data(), HJ.data()));
}

// bdf and esdirk on paper_control.yaml with the law's exact Jacobian: the same end state as rkf78
// at 1e-13 and as their difference-quotient twins, to the tolerance; bdf with fewer evaluations
// of f (no 2n per Jacobian); the run's summary says "exact" (jacobian auto).
TEST(ControlDerivatives, ImplicitIntegratorsOnAControlledRunTakeTheExactJacobian) {
  if (!bdf_available() || !esdirk_available()) GTEST_SKIP() << "built without SUNDIALS";
#ifdef UKDYN_TEST_SANITIZED
  const Scenario sc = paper_control(0.1, 1e-10);  // 10-20 times slower: the same paths, 0.1 s
#else
  const Scenario sc = paper_control(0.5, 1e-10);
#endif
  const LoopEnd ref = run_loop(sc, IntegratorKind::rkf78, JacobianKind::automatic);
  ASSERT_EQ(ref.stats.status, RunStatus::completed) << ref.stats.message;
  for (auto kind : {IntegratorKind::bdf, IntegratorKind::esdirk}) {
    const std::string name = to_string(kind);
    const LoopEnd ex = run_loop(sc, kind, JacobianKind::exact);
    const LoopEnd dq = run_loop(sc, kind, JacobianKind::difference);
    ASSERT_EQ(ex.stats.status, RunStatus::completed) << name << ex.stats.message;
    ASSERT_EQ(dq.stats.status, RunStatus::completed) << name << dq.stats.message;
    EXPECT_EQ(ex.stats.jacobian, "exact") << name;
    EXPECT_EQ(dq.stats.jacobian, "difference") << name;
    std::cout << "[ control ] paper_control 0.5 s, " << name << ": f evaluations "
              << ex.stats.rhs_evaluations << " exact, " << dq.stats.rhs_evaluations
              << " difference; Jacobians " << ex.stats.jacobian_evaluations << " ("
              << ex.stats.jacobian_fallbacks << " fallbacks), " << dq.stats.jacobian_evaluations
              << "; max |q - q_ref| " << (ex.q - ref.q).cwiseAbs().maxCoeff() << ", "
              << (dq.q - ref.q).cwiseAbs().maxCoeff() << "\n";
    if (kind == IntegratorKind::bdf) {
      EXPECT_LT(ex.stats.rhs_evaluations, dq.stats.rhs_evaluations) << name;
    }
    const double tol = 1e-7;  // the runs' 1e-10 over 0.5 s, with the global error's growth
    for (Index i = 0; i < ref.q.size(); ++i) {
      EXPECT_NEAR(ex.q(i), ref.q(i), tol) << name << " q" << i;
      EXPECT_NEAR(ex.q(i), dq.q(i), tol) << name << " q" << i;
      EXPECT_NEAR(ex.qd(i), ref.qd(i), 10 * tol) << name << " qd" << i;
    }
  }
  // run_scenario_in_memory (as `ukdyn simulate`): jacobian auto takes the exact one, said in the
  // summary
  Scenario bdf = sc;
  bdf.sim.integrator = IntegratorKind::bdf;
  const MemoryRun mr = run_scenario_in_memory(bdf, {});
  const auto summary = nlohmann::json::parse(mr.summary_json);
  EXPECT_EQ(summary["jacobian"]["kind"], "exact") << summary["jacobian"].dump();
  EXPECT_GT(summary["jacobian"]["evaluations"].get<long>(), 0);
}

// A loop built by hand with a disturbance of t (make_control_run()'s is constant): the exact
// ∂τ/∂t would miss ∂τ_d/∂t, so the time column falls back to differences and says why; with
// the differences it matches the Richardson reference, which the exact column without τ_d's
// share (0.7 cos 3t on every coordinate) would not.
TEST(ControlDerivatives, ADisturbanceOfTimeTakesTheDifferencesForDtauDt) {
  const Scenario sc = load_scenario(kSource / "scenarios" / "paper_control.yaml");
  const auto run = make_control_run(sc);
  run->loop->disturbance = [](double t, VecRef d) { d.setConstant(0.7 * std::sin(3.0 * t)); };
  const double t = 0.4;
  const LawDerivatives out = law_derivatives(*run, t, run->q0, run->qd0);
  EXPECT_EQ(out.method, "exact");
  EXPECT_EQ(out.dtau_dt_method, "differences: the loop's disturbance tau_d(t) depends on t");
  const Index n = run->q0.size();
  const Mat ref = richardson_jacobian(*run, t, run->q0, run->qd0);
  const double err = (out.dtau_dt - ref.col(2 * n)).cwiseAbs().maxCoeff();
  EXPECT_LT(err, 1e-7 * ref.col(2 * n).cwiseAbs().maxCoeff());
  // A constant disturbance keeps the exact column, which lacks exactly τ_d's share 2.1 cos 3t.
  run->loop->disturbance = [](double, VecRef d) { d.setConstant(0.7); };
  const LawDerivatives still = law_derivatives(*run, t, run->q0, run->qd0);
  EXPECT_EQ(still.dtau_dt_method, "exact");
  const Vec share = Vec::Constant(n, 2.1 * std::cos(3.0 * t));
  EXPECT_LT((out.dtau_dt - still.dtau_dt - share).cwiseAbs().maxCoeff(),
            1e-7 * ref.col(2 * n).cwiseAbs().maxCoeff());
  std::cout << "[ control ] d tau_d/dt share " << share(0) << ", scale "
            << ref.col(2 * n).cwiseAbs().maxCoeff() << "\n";
}
