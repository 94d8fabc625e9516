// Trajectory optimisation by direct collocation (ukdyn/optimize/trajectory.hpp,
// docs/optimization.md): the NLP's exact derivatives against central differences, and optima
// against closed forms of problems whose optimum is known by reduction to one coordinate.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>

#include "cli_run.hpp"
#include "optimize/transcription.hpp"
#include "output/csv_reader.hpp"
#include "ukdyn/core/constraint_forces.hpp"
#include "ukdyn/model/motor.hpp"
#include "ukdyn/optimize/trajectory.hpp"
#include "ukdyn/robot_files/urdf.hpp"
#include "ukdyn/run/optimize_run.hpp"
#include "ukdyn/scenario/optimization_file.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/simulate/simulate.hpp"

namespace ukdyn {
namespace {

// A point mass m in the vertical x-z plane held on a circle of radius R (a closed chain in two
// Cartesian coordinates: one holonomic row, nonlinear), pushed by two force actuators.
std::string circle_text(double gravity) {
  return R"(ukdyn: 1
name: circle
gravity: )" +
         std::to_string(gravity) +
         R"(
subsystems:
  - name: bead
    type: definitions
    coordinates: [x, z]
    parameters: {m: 2}
    bodies:
      - {name: mass, mass: m, com: [x, 0, z]}
constraints:
  - {type: expression, name: ring, rows: {r: x^2 + z^2 - 0.64}}
actuators:
  - {name: fx, coordinate: x}
  - {name: fz, coordinate: z}
initial:
  q: [0, -0.8]
  qd: [0, 0]
simulation:
  t_end: 1
  sample_dt: 0.01
)";
}

// A point mass m = 2 in the horizontal plane on a straight rail at 30° (a linear closure row).
const char* kRail = R"(ukdyn: 1
name: rail
gravity: 0
subsystems:
  - name: slider
    type: definitions
    coordinates: [x, y]
    parameters: {m: 2}
    bodies:
      - {name: mass, mass: m, com: [x, y, 0]}
constraints:
  - {type: expression, name: rail, rows: {r: 0.5*x - 0.8660254037844386*y}}
actuators:
  - {name: fx, coordinate: x}
  - {name: fy, coordinate: y}
initial:
  q: [0, 0]
  qd: [0, 0]
simulation:
  t_end: 1
  sample_dt: 0.01
)";

TrajectoryProblem problem_for(const Scenario& sc, CollocationMethod method, Index intervals,
                              double duration, const Vec& q_end) {
  TrajectoryProblem p;
  p.system = sc.system;
  p.B = sc.actuators.B;
  p.actuator_names = sc.actuators.names;
  p.tau = sc.tau;
  p.method = method;
  p.intervals = intervals;
  p.duration = duration;
  p.q_start = sc.q0;
  p.qd_start = sc.qd0;
  p.q_end = q_end;
  p.qd_end = Vec::Zero(sc.q0.size());
  p.costs.effort = Vec::Ones(p.B.cols());
  return p;
}

Vec on_circle(double theta) {
  Vec q(2);
  q << 0.8 * std::sin(theta), -0.8 * std::cos(theta);
  return q;
}

// Assembles a dense Jacobian from the sink calls.
class DenseSink final : public optimize::JacobianSink {
 public:
  explicit DenseSink(Mat& J) : J_(J) {}
  void dense(Index r, Index c, const Mat& b) override { J_.block(r, c, b.rows(), b.cols()) += b; }
  void identity(Index r, Index c, Index size, double s) override {
    for (Index i = 0; i < size; ++i) J_(r + i, c + i) += s;
  }
  void column(Index r, Index c, const Vec& v) override { J_.block(r, c, v.size(), 1) += v; }

 private:
  Mat& J_;
};

// The worst relative errors of the constraint Jacobian and of the cost gradient at x against
// central differences; checks that the declared structure covers every non-zero.
std::pair<double, double> derivative_errors(optimize::Transcription& tr, const Vec& x) {
  const Index nv = tr.variables(), ng = tr.constraints();
  Mat J = Mat::Zero(ng, nv);
  DenseSink sink(J);
  tr.jacobian(x, sink);
  Vec grad;
  tr.cost_gradient(x, grad);
  double worst_j = 0, worst_g = 0;
  Vec gp, gm;
  for (Index i = 0; i < nv; ++i) {
    const double h = 1e-6 * (1.0 + std::abs(x(i)));
    Vec xp = x, xm = x;
    xp(i) += h;
    xm(i) -= h;
    tr.constraint_values(xp, gp);
    tr.constraint_values(xm, gm);
    const Vec col = (gp - gm) / (2 * h);
    worst_j = std::max(worst_j,
                       (col - J.col(i)).cwiseAbs().maxCoeff() / (1.0 + col.cwiseAbs().maxCoeff()));
    const double dc = (tr.cost(xp) - tr.cost(xm)) / (2 * h);
    worst_g = std::max(worst_g, std::abs(dc - grad(i)) / (1.0 + std::abs(dc)));
  }
  Index nnz = 0;
  for (Index i = 0; i < J.size(); ++i) nnz += J.data()[i] != 0.0;
  EXPECT_LE(nnz, tr.jacobian_nonzeros());  // the declared structure covers every non-zero
  return {worst_j, worst_g};
}

// Every entry of the constraint Jacobian and of the cost gradient against central differences,
// at a point off the guess (random u, γ, perturbed states), both methods, free duration, every
// cost term on: the derivatives of a (the U-K acceleration), of A_R(q)ᵀγ and of A_R v included.
// A waypoint: a body's point through (0.5, 0, -0.3) (off the ring: only the derivatives are
// checked), a ball constraint against the world frame, built as a problem file builds it. Its rows
// are functions of q alone, so the body is the bead's with y = x z (the bead's own y is 0 for
// every q, a row the loader refuses as involving no coordinate).
Waypoint bead_waypoint(double t, double fraction = std::nan("")) {
  LoadOptions opt;
  opt.check_initial = false;
  std::string text = circle_text(9.81);
  text.replace(text.find("com: [x, 0, z]"), 14, "com: [x, x*z, z]");
  text.insert(text.find("actuators:"),
              "  - {type: ball, name: wp, a: bead.mass, b: {frame: world, xyz: [0.5, 0, -0.3]}}\n");
  const auto with = load_scenario_text(text, "circle.yaml", opt);
  return {"wp", with.system->constraints().back(), t, fraction};
}

// With `waypoint`: one at a knot (t = 0.6 of 1.2 s, knot 2 of 4) with a fixed duration, and
// (`off_knot`) one between knots at 0.3 of a free duration, on the method's interpolant.
void check_derivatives(CollocationMethod method, bool waypoint = false, bool off_knot = false) {
  const auto sc = load_scenario_text(circle_text(9.81), "circle.yaml");
  TrajectoryProblem p = problem_for(sc, method, 4, 1.2, on_circle(1.0));
  if (waypoint) p.waypoints.push_back(off_knot ? bead_waypoint(0.0, 0.3) : bead_waypoint(0.6));
  p.free_duration = !waypoint || off_knot;
  p.min_duration = 0.5;
  p.max_duration = 3.0;
  p.costs.power = 0.3;
  p.costs.constraint_force = 0.01;
  p.costs.smoothness = 0.2;
  p.costs.duration = 1.5;
  p.envelopes.push_back({0, 40.0, 5.0});
  p.costs.multiplier = Vec::Constant(1, 0.02);
  p.multiplier_lower = Vec::Constant(1, -30.0);
  p.multiplier_upper = Vec::Constant(1, 30.0);
  optimize::Transcription tr(p);
  Vec x = tr.initial_guess();
  std::srand(7);
  x += 0.05 * Vec::Random(x.size());
  if (p.free_duration) x(tr.time_index()) = 1.3;
  const auto [worst_j, worst_g] = derivative_errors(tr, x);
  EXPECT_LT(worst_j, 1e-6) << to_string(method);
  EXPECT_LT(worst_g, 1e-6) << to_string(method);
}

TEST(Optimize, TrapezoidalDerivativesMatchCentralDifferences) {
  check_derivatives(CollocationMethod::trapezoidal);
}

TEST(Optimize, HermiteSimpsonDerivativesMatchCentralDifferences) {
  check_derivatives(CollocationMethod::hermite_simpson);
}

TEST(Optimize, WaypointDerivativesMatchCentralDifferences) {
  check_derivatives(CollocationMethod::hermite_simpson, true);
  check_derivatives(CollocationMethod::trapezoidal, true);
}

TEST(Optimize, WaypointBetweenKnotsDerivativesMatchCentralDifferences) {
  check_derivatives(CollocationMethod::hermite_simpson, true, true);
  check_derivatives(CollocationMethod::trapezoidal, true, true);
}

TEST(Optimize, RefusesBadProblemsNamingWhatIsWrong) {
  const auto sc = load_scenario_text(circle_text(9.81), "circle.yaml");
  auto expect_error = [](const TrajectoryProblem& p, const std::string& what) {
    try {
      validate(p);
      ADD_FAILURE() << "accepted; expected: " << what;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
    }
  };
  TrajectoryProblem p = problem_for(sc, CollocationMethod::trapezoidal, 10, 1.0, on_circle(1.0));
  auto bad = p;
  bad.q_end(0) += 0.1;
  expect_error(bad, "the end q violates constraint row 'ring_r'");
  bad = p;
  bad.duration = -1;
  expect_error(bad, "duration must be finite and positive");
  bad = p;
  bad.u_lower = Vec::Constant(2, 1.0);
  bad.u_upper = Vec::Constant(2, -1.0);
  expect_error(bad, "u bounds of entry 0 are empty");
  bad = p;
  bad.q_upper = Vec::Constant(2, -1.0);
  expect_error(bad, "the start q entry 0");
  bad = p;
  bad.costs.effort = Vec::Ones(3);
  expect_error(bad, "costs.effort has 3 entries, 2 expected");
  bad = p;
  bad.waypoints.push_back(bead_waypoint(1.5));
  expect_error(bad, "waypoint 'wp': t = 1.5 is not in (0, duration]");
  bad.waypoints.back() = bead_waypoint(0.0, 1.5);
  expect_error(bad, "waypoint 'wp': fraction = 1.5 is not in (0, 1]");
  bad.waypoints.back() = bead_waypoint(0.5);
  bad.free_duration = true;
  bad.min_duration = 0.5;
  bad.max_duration = 2.0;
  expect_error(bad, "waypoint 'wp': with a free duration give its time as a fraction");
}

// Closed form: a mass m moved rest to rest a distance D in time T at minimum ∫|u|² needs only the
// force along its path (the constraint takes the rest), m s̈ = u_t, so the optimum is the cubic
// s(t) = D(3τ² − 2τ³), τ = t/T, of cost 12 m² D² / T³ — on the straight rail and on the circle
// (arc length D = R Δθ, no gravity) alike.
TEST(Optimize, RestToRestOnARailMatchesTheCubicClosedForm) {
  if (!ipopt_available()) GTEST_SKIP() << "built without IPOPT";
  const auto sc = load_scenario_text(kRail, "rail.yaml");
  Vec q_end(2);
  q_end << 0.8660254037844386 * 1.5, 0.5 * 1.5;  // D = 1.5 along the rail
  const double m = 2, D = 1.5, T = 2.0, exact = 12 * m * m * D * D / (T * T * T);
  const auto s =
      optimize_trajectory(problem_for(sc, CollocationMethod::hermite_simpson, 10, T, q_end));
  ASSERT_TRUE(s.converged) << s.status << " " << s.message;
  EXPECT_LT(std::abs(s.cost - exact) / exact, 1e-6) << s.cost << " vs " << exact;
  EXPECT_LT(s.max_position_residual, 1e-10);
  EXPECT_LT(s.max_velocity_residual, 1e-10);
  EXPECT_TRUE(s.trusted) << s.message;
}

// ∫ s̈² dt of the cubic from (0, v0) to (ds, v1) in a time L (a beam's bending energy).
double cubic_cost(double L, double ds, double v0, double v1) {
  return 4.0 / L * (v0 * v0 + v0 * v1 + v1 * v1) - 12.0 * ds * (v0 + v1) / (L * L) +
         12.0 * ds * ds / (L * L * L);
}

// The least ∫ s̈² dt from rest at s = 0 to rest at s = D in time T through s = d at t_w: the
// clamped cubic spline (two cubics meeting at t_w with the speed v there that minimises the sum, a
// quadratic in v: its three values at −1, 0, 1 give the minimiser).
double spline_cost(double T, double tw, double d, double D) {
  auto J = [&](double v) { return cubic_cost(tw, d, 0, v) + cubic_cost(T - tw, D - d, v, 0); };
  const double a = 0.5 * (J(1) + J(-1) - 2 * J(0)), b = 0.5 * (J(1) - J(-1));
  return J(-b / (2 * a));
}

// The rail of kRail with a waypoint: the slider through x = d cos 30° (s = d along the rail), an
// expression row on x.
Waypoint rail_waypoint(double d, double t, double fraction) {
  LoadOptions opt;
  opt.check_initial = false;
  std::string text = kRail;
  char x[40];
  std::snprintf(x, sizeof x, "%.17g", d * 0.8660254037844386);
  text.insert(text.find("actuators:"),
              std::string("  - {type: expression, name: wp, rows: {x: x - ") + x + "}}\n");
  const auto with = load_scenario_text(text, "rail.yaml", opt);
  return {"wp", with.system->constraints().back(), t, fraction};
}

// x of the Hermite–Simpson state interpolant (the cubic Hermite through the knots' q, q̇) at t.
double hermite_x(const TrajectorySolution& s, double t) {
  const Index P = s.t.size();
  Index a = 0;
  while (a + 2 < P - 1 && s.t(a + 2) <= t) a += 2;
  const Index b = a + 2;
  const double h = s.t(b) - s.t(a), w = (t - s.t(a)) / h;
  return (2 * w * w * w - 3 * w * w + 1) * s.q(a, 0) +
         (w * w * w - 2 * w * w + w) * h * s.qd(a, 0) + (-2 * w * w * w + 3 * w * w) * s.q(b, 0) +
         (w * w * w - w * w) * h * s.qd(b, 0);
}

// Closed form: rest to rest along the rail at minimum ∫|u|² through a waypoint, m s̈ = u along
// the rail, is m² times the clamped spline's ∫ s̈². At a knot Hermite–Simpson holds the piecewise
// cubic exactly; between knots the optimum's u has its kink inside an interval, and the error
// shrinks as the mesh is refined. The interpolant passes through the waypoint at t_w.
TEST(Optimize, WaypointBetweenKnotsMatchesTheSplineClosedForm) {
  if (!ipopt_available()) GTEST_SKIP() << "built without IPOPT";
  const auto sc = load_scenario_text(kRail, "rail.yaml");
  const double m = 2, D = 1.5, T = 2.0, d = 1.2;
  Vec q_end(2);
  q_end << 0.8660254037844386 * D, 0.5 * D;
  auto solve = [&](Index N, double tw) {
    TrajectoryProblem p = problem_for(sc, CollocationMethod::hermite_simpson, N, T, q_end);
    p.waypoints.push_back(rail_waypoint(d, tw, std::nan("")));
    const auto s = optimize_trajectory(p);
    EXPECT_TRUE(s.converged) << s.status << " " << s.message;
    EXPECT_LT(s.max_waypoint_residual, 1e-9);
    EXPECT_NEAR(hermite_x(s, tw), d * 0.8660254037844386, 1e-9) << N << " " << tw;
    const double exact = m * m * spline_cost(T, tw, d, D);
    return std::abs(s.cost - exact) / exact;
  };
  EXPECT_LT(solve(10, 0.8), 1e-6);  // knot 4: exact
  // t_w = 0.73: at 3.65, 7.3 and 14.6 steps, never on a knot
  const double e10 = solve(10, 0.73), e20 = solve(20, 0.73), e40 = solve(40, 0.73);
  std::printf("waypoint between knots: relative cost error %.3g (N = 10), %.3g (20), %.3g (40)\n",
              e10, e20, e40);
  EXPECT_LT(e10, 5e-3);  // measured 1.3e-3, 1.3e-4, 2.2e-5
  EXPECT_GT(e10 / e20, 3.0);
  EXPECT_GT(e20 / e40, 3.0);
}

// A free duration with a weight w on T and the waypoint at a fraction φ of it: the spline scales
// as ∫ s̈² = S₁/T³ (S₁ the cost in unit time), so J(T) = w T + m² S₁/T³ is least at
// T* = (3 m² S₁/w)^¼. With φ on a knot Hermite–Simpson finds T* and J* exactly.
TEST(Optimize, WaypointAtAFractionOfAFreeDurationMatchesTheClosedForm) {
  if (!ipopt_available()) GTEST_SKIP() << "built without IPOPT";
  const auto sc = load_scenario_text(kRail, "rail.yaml");
  const double m = 2, D = 1.5, d = 1.2;
  Vec q_end(2);
  q_end << 0.8660254037844386 * D, 0.5 * D;
  auto solve = [&](double fraction, double& T_error) {
    const double S1 = spline_cost(1.0, fraction, d, D), w = 3 * m * m * S1 / 16;  // T* = 2
    TrajectoryProblem p = problem_for(sc, CollocationMethod::hermite_simpson, 10, 1.5, q_end);
    p.free_duration = true;
    p.min_duration = 0.5;
    p.max_duration = 5.0;
    p.costs.duration = w;
    p.waypoints.push_back(rail_waypoint(d, 0.0, fraction));
    const auto s = optimize_trajectory(p);
    EXPECT_TRUE(s.converged) << s.status << " " << s.message;
    EXPECT_LT(s.max_waypoint_residual, 1e-9);
    EXPECT_NEAR(hermite_x(s, fraction * s.duration), d * 0.8660254037844386, 1e-9);
    const double T_star = 2.0, J_star = w * T_star + m * m * S1 / (T_star * T_star * T_star);
    T_error = std::abs(s.duration - T_star) / T_star;
    return std::abs(s.cost - J_star) / J_star;
  };
  double T_knot = 0, T_off = 0;
  EXPECT_LT(solve(0.4, T_knot), 1e-6);  // knot 4 of 10
  EXPECT_LT(T_knot, 1e-6);
  const double J_off = solve(0.35, T_off);  // between knots 3 and 4
  std::printf("free duration, waypoint at 0.35 T: relative error of J %.3g, of T %.3g\n", J_off,
              T_off);
  EXPECT_LT(J_off, 1e-2);
  EXPECT_LT(T_off, 1e-2);
}

// A rheonomic row: a point mass m = 2 in the vertical x-z plane under gravity on a rail of slope
// 30° that rises by f(t) = c (3τ² − 2τ³), τ = t/2 (c = 0.3 m in T = 2 s, at rest at both ends),
// z = x tan 30° + f(t), pushed by a horizontal force only.
const char* kMovingRail = R"(ukdyn: 1
name: moving_rail
gravity: 9.81
subsystems:
  - name: slider
    type: definitions
    coordinates: [x, z]
    parameters: {m: 2}
    bodies:
      - {name: mass, mass: m, com: [x, 0, z]}
constraints:
  - {type: expression, name: rail, rows: {r: z - 0.5773502691896258*x - 0.3*(0.75*t*t - 0.25*t*t*t)}}
actuators:
  - {name: fx, coordinate: x}
initial:
  q: [0, 0]
  qd: [0, 0]
simulation:
  t_end: 2
  sample_dt: 0.01
)";

double moving_rail_f(double t) { return 0.3 * (0.75 * t * t - 0.25 * t * t * t); }
double moving_rail_fdot(double t) { return 0.3 * (1.5 * t - 0.75 * t * t); }

// The rows at the knots at their own time (position and velocity level, Φ_t included), and the
// collocation's Jacobian with the rheonomic row against central differences.
TEST(Optimize, RheonomicRowDerivativesMatchCentralDifferences) {
  const auto sc = load_scenario_text(kMovingRail, "moving_rail.yaml");
  const double X = 1.0, tan30 = 0.5773502691896258;
  Vec q_end(2);
  q_end << X, X * tan30 + moving_rail_f(2.0);
  for (const auto method : {CollocationMethod::hermite_simpson, CollocationMethod::trapezoidal}) {
    TrajectoryProblem p = problem_for(sc, method, 4, 2.0, q_end);
    p.costs.constraint_force = 0.01;
    optimize::Transcription tr(p);
    Vec x = tr.initial_guess();
    std::srand(11);
    x += 0.05 * Vec::Random(x.size());
    const auto [worst_j, worst_g] = derivative_errors(tr, x);
    EXPECT_LT(worst_j, 1e-6) << to_string(method);
    EXPECT_LT(worst_g, 1e-6) << to_string(method);
  }
}

// Closed form: along the rail the horizontal force does the work, u = m (ẍ sec²α + (f̈ + g) tan α)
// (Newton's law projected on the rail's direction (1, tan α): the rail's force is normal to it),
// so ∫u² = m² sec⁴α ∫ (ẍ + w)² dt, w = (f̈ + g) sin α cos α. Rest to rest from x = 0 to X, the
// least is at ẍ + w = a + b t, with ∫₀ᵀ w = sc g T and ∫₀ᵀ (T − t) w = sc (f(T) + g T²/2) (sc =
// sin α cos α, ḟ = 0 at both ends): T a + T²/2 b = sc g T, T²/2 a + T³/6 b = X + sc (f(T) +
// g T²/2), cost m² sec⁴α (a² T + a b T² + b² T³/3). The rail's motion f enters the cost; x, z and
// u are polynomials of degree 3, so Hermite–Simpson is exact. At every knot the row holds at the
// knot's own time, at position and at velocity level (ż − ẋ tan α − ḟ(t) = 0).
TEST(Optimize, RheonomicRailMatchesTheClosedForm) {
  if (!ipopt_available()) GTEST_SKIP() << "built without IPOPT";
  const auto sc = load_scenario_text(kMovingRail, "moving_rail.yaml");
  const double m = 2, g = 9.81, T = 2.0, X = 1.0, alpha = std::atan(0.5773502691896258);
  const double sc_ = std::sin(alpha) * std::cos(alpha), sec = 1.0 / std::cos(alpha);
  // The least cost for a rail that rises by fT in T (Cramer's rule on the 2 × 2 system).
  auto closed_form = [&](double fT) {
    const double k11 = T, k12 = T * T / 2, k22 = T * T * T / 6, det = k11 * k22 - k12 * k12;
    const double r1 = sc_ * g * T, r2 = X + sc_ * (fT + g * T * T / 2);
    const double a = (r1 * k22 - k12 * r2) / det, b = (k11 * r2 - k12 * r1) / det;
    return m * m * std::pow(sec, 4) * (a * a * T + a * b * T * T + b * b * T * T * T / 3);
  };
  const double exact = closed_form(moving_rail_f(T));
  Vec q_end(2);
  q_end << X, X * std::tan(alpha) + moving_rail_f(T);
  const auto s =
      optimize_trajectory(problem_for(sc, CollocationMethod::hermite_simpson, 10, T, q_end));
  ASSERT_TRUE(s.converged) << s.status << " " << s.message;
  EXPECT_TRUE(s.trusted) << s.message;
  EXPECT_LT(std::abs(s.cost - exact) / exact, 1e-6) << s.cost << " vs " << exact;
  for (Index p = 0; p < s.t.size(); p += 2) {
    const double t = s.t(p);
    EXPECT_NEAR(s.q(p, 1) - std::tan(alpha) * s.q(p, 0), moving_rail_f(t), 1e-10) << t;
    EXPECT_NEAR(s.qd(p, 1) - std::tan(alpha) * s.qd(p, 0), moving_rail_fdot(t), 1e-10) << t;
  }
  // The same rail held still costs otherwise: the rail's motion is in the optimum.
  const double still = closed_form(0.0);
  EXPECT_GT(std::abs(exact - still), 1e-3 * exact);
  std::printf("moving rail: cost %.9g, closed form %.9g (still rail %.6g)\n", s.cost, exact, still);
}

// A bound on the ring's force (the row's multiplier μ, Qc = A_Rᵀ μ): the bead swung quickly needs
// a large centripetal force; bounded, the optimum keeps |μ| within the bound at every point, pays
// more effort than without it, and μ is the multiplier of the constraint force it reports.
TEST(Optimize, ABoundOnAConstraintForceHoldsAndCosts) {
  if (!ipopt_available()) GTEST_SKIP() << "built without IPOPT";
  const auto sc = load_scenario_text(circle_text(0.0), "circle.yaml");
  TrajectoryProblem p =
      problem_for(sc, CollocationMethod::hermite_simpson, 20, 1.0, on_circle(2.0));
  const auto free = optimize_trajectory(p);
  ASSERT_TRUE(free.converged) << free.status;
  // Unbounded, the optimum is the cubic along the arc (peak speed 1.5 RΔθ/T at t = T/2, a knot)
  // and the ring carries the centripetal force m v²/R = |Qc| = |2 q μ| = 2R|μ|.
  const double peak = free.mu.cwiseAbs().maxCoeff(), v = 1.5 * 0.8 * 2.0 / 1.0;
  EXPECT_NEAR(peak, 2.0 * v * v / 0.8 / (2 * 0.8), 1e-5 * peak);  // measured 6.2e-6 (N = 20)
  p.multiplier_lower = Vec::Constant(1, -0.5 * peak);
  p.multiplier_upper = Vec::Constant(1, 0.5 * peak);
  const auto bound = optimize_trajectory(p);
  ASSERT_TRUE(bound.converged) << bound.status;
  EXPECT_LE(bound.mu.cwiseAbs().maxCoeff(), 0.5 * peak * (1 + 1e-8));
  EXPECT_GT(bound.cost, free.cost * 1.001);
  for (Index i = 0; i < bound.t.size(); ++i) {  // Qc = A_Rᵀ μ, A = ∂(x² + z² − R²)/∂q = 2 (x, z)
    const Vec Qc = 2.0 * bound.q.row(i).transpose() * bound.mu(i, 0);
    EXPECT_LT((Qc - bound.Qc.row(i).transpose()).cwiseAbs().maxCoeff(), 1e-9);
  }
  std::printf("ring force: peak %.4g free, %.4g bounded; cost %.6g -> %.6g\n", peak,
              bound.mu.cwiseAbs().maxCoeff(), free.cost, bound.cost);
}

TEST(Optimize, RestToRestOnACircleMatchesTheClosedFormAtTheMethodsOrder) {
  if (!ipopt_available()) GTEST_SKIP() << "built without IPOPT";
  const auto sc = load_scenario_text(circle_text(0.0), "circle.yaml");
  const double m = 2, D = 0.8 * 1.2, T = 1.5, exact = 12 * m * m * D * D / (T * T * T);
  auto error = [&](CollocationMethod method, Index N) {
    const auto s = optimize_trajectory(problem_for(sc, method, N, T, on_circle(1.2)));
    EXPECT_TRUE(s.converged) << s.status << " " << s.message;
    EXPECT_LT(s.max_position_residual, 1e-10);
    EXPECT_LT(s.max_velocity_residual, 1e-10);
    return std::abs(s.cost - exact) / exact;
  };
  // Measured (relative cost error, N = 5, 10, 20, 40, 80): Hermite–Simpson 1.3e-4, 2.4e-6,
  // 3.2e-7, 2.3e-8, 1.5e-9; trapezoidal 2.1e-1, 5.0e-2, 1.3e-2, 3.2e-3, 7.9e-4.
  const double hs20 = error(CollocationMethod::hermite_simpson, 20);
  const double hs40 = error(CollocationMethod::hermite_simpson, 40);
  const double tr20 = error(CollocationMethod::trapezoidal, 20);
  const double tr40 = error(CollocationMethod::trapezoidal, 40);
  EXPECT_LT(hs20, 1e-6);
  // Order: halving h divides the error by about 2^4 (Hermite–Simpson) and 2^2 (trapezoidal).
  EXPECT_GT(hs20 / hs40, 10.0) << hs20 << " " << hs40;
  EXPECT_GT(tr20 / tr40, 3.5) << tr20 << " " << tr40;
  EXPECT_LT(tr20 / tr40, 4.5) << tr20 << " " << tr40;
}

namespace fs = std::filesystem;

// One edit of a good problem file (the text `from` replaced by `to`) and the error it must give.
struct EditCase {
  const char* from;
  const char* to;
  const char* expect;
};

// Each edit of `good` is refused with its message, located in the edited file.
void expect_refused(const std::string& good, const std::vector<EditCase>& cases,
                    const fs::path& dir) {
  for (const auto& c : cases) {
    std::string text = good;
    const auto at = text.find(c.from);
    ASSERT_NE(at, std::string::npos) << c.from;
    text.replace(at, std::string(c.from).size(), c.to);
    try {
      load_optimization_text(text, dir / "bad.yaml");
      ADD_FAILURE() << "accepted: " << c.to;
    } catch (const ScenarioError& e) {
      EXPECT_NE(std::string(e.what()).find(c.expect), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("bad.yaml:"), std::string::npos) << e.what();
    }
  }
}

// The problem-file errors name the key (and the line) where the problem is.
TEST(OptimizeFile, ErrorsNameTheKey) {
  const fs::path dir = fs::path(UKDYN_SOURCE_DIR) / "scenarios" / "optimize";
  const std::string good = ukdyn_test::slurp(dir / "paper_lift.yaml");
  const std::vector<EditCase> cases = {
      {"method: hermite_simpson", "method: simpson",
       "key 'method': expected hermite_simpson or trapezoidal"},
      {"intervals: 50", "intervals: 2.5", "key 'intervals': expected a whole number"},
      {"duration: 1", "duration: -1", "key 'duration': must be > 0"},
      {"  qd: zeros", "  qd: {nope: 1}", "key 'end.qd.nope': no coordinate named 'nope'"},
      {"  q: [0, 1, 0, 2.0223032201924793", "  q: [0.5, 1, 0, 2.0223032201924793",
       "key 'end': optimize: the end q violates constraint row 'closure_"},
      {"  effort: 1e-4", "  effort: -1", "key 'costs.effort': effort weights must be >= 0"},
      {"  effort: 1e-4", "  effort: {dx9: 1}", "key 'costs.effort.dx9': no actuator named 'dx9'"},
      {"scenario: ../paper_free.yaml", "scenario: ../nothing.yaml",
       "key 'scenario': the scenario: "},
      {"costs:", "cost:", "key 'cost': unknown key"},
      {"  effort: 1e-4", "  constraint_rows: {nope: 1}",
       "key 'costs.constraint_rows.nope': no constraint row or block named 'nope'"},
      {"costs:", "actuated: [dx1, dx1]\ncosts:",
       "key 'actuated[1]': coordinate 'dx1' is listed twice"},
      {"costs:", "max_correction: 0\ncosts:", "key 'max_correction': must be > 0"},
      {"costs:", "bounds:\n  internal_wrench: {load: left.cut, force: 1}\ncosts:",
       "key 'bounds.internal_wrench.load': 'left.cut' is held by 0 weld(s)"},
      {"costs:", "bounds:\n  internal_wrench: {load: left.cut}\ncosts:",
       "key 'bounds.internal_wrench': expected force, torque or both"},
  };
  expect_refused(good, cases, dir);
}

// The left robot's cut point of the paper's chains by hand (scenarios/paper_chain.yaml: base at
// (dx1, dy1), the arm turned by delta1, joints lifting in its vertical plane from z = lr = 0.5,
// links 0.7, 0.8, 0.4 at the absolute angles theta1..3): independent of the frame machinery.
Vec3 left_cut(const Mat& q, Index row) {
  const double reach =
      0.7 * std::cos(q(row, 3)) + 0.8 * std::cos(q(row, 4)) + 0.4 * std::cos(q(row, 5));
  return {q(row, 0) + std::cos(q(row, 2)) * reach, q(row, 1) + std::sin(q(row, 2)) * reach,
          0.5 + 0.7 * std::sin(q(row, 3)) + 0.8 * std::sin(q(row, 4)) + 0.4 * std::sin(q(row, 5))};
}

// A waypoint of a chain's point: the optimum passes through it at its knot (the cut point by
// hand), which the optimum without it does not (it lags 0.42 m below), and it costs more.
TEST(OptimizeFile, AWaypointIsPassedAndCosts) {
  if (!ipopt_available()) GTEST_SKIP() << "built without IPOPT";
  const fs::path dir = fs::path(UKDYN_SOURCE_DIR) / "scenarios" / "optimize";
  const OptimizationFile f = load_optimization_file(dir / "paper_lift_waypoint.yaml");
  ASSERT_EQ(f.problem.waypoints.size(), 1u);
  const auto with = optimize_trajectory(f.problem, f.ipopt);
  ASSERT_TRUE(with.converged) << with.status;
  EXPECT_TRUE(with.trusted) << with.message;
  TrajectoryProblem free = f.problem;
  free.waypoints.clear();
  const auto without = optimize_trajectory(free, f.ipopt);
  ASSERT_TRUE(without.converged) << without.status;
  const Index mid = 20;  // t = 0.5: knot 10 of 20, Hermite–Simpson point 20
  ASSERT_NEAR(with.t(mid), 0.5, 1e-12);
  const Vec3 target(0.8, 0.5, 1.0);
  EXPECT_LT((left_cut(with.q, mid) - target).norm(), 1e-9) << left_cut(with.q, mid).transpose();
  EXPECT_GT((left_cut(without.q, mid) - target).norm(), 0.3);
  EXPECT_LT(with.max_waypoint_residual, 1e-9);
  EXPECT_GT(with.cost, without.cost * 1.001);
  std::printf("waypoint: cost %.6g without, %.6g with; cut at t = 0.5 z %.4f -> %.4f\n",
              without.cost, with.cost, left_cut(without.q, mid)(2), left_cut(with.q, mid)(2));
}

TEST(OptimizeFile, WaypointErrorsNameTheKey) {
  const fs::path dir = fs::path(UKDYN_SOURCE_DIR) / "scenarios" / "optimize";
  const std::string good = ukdyn_test::slurp(dir / "paper_lift_waypoint.yaml");
  const std::vector<EditCase> cases = {
      // Errors of the frame or the numbers, found when the scenario is loaded with the waypoints'
      // rows, are said at the waypoint's own key and line, not at the text ukdyn wrote.
      {"frame: left.cut", "frame: left.nope", "bad.yaml:20:28: key 'waypoints[0].frame': no frame"},
      {"frame: left.cut", "frame: ''", "key 'waypoints[0].frame': expected SUBSYSTEM.FRAME"},
      {"frame: left.cut", "frame: {frame: left.cut, xyz: [.nan, 0, 0]}",
       "key 'waypoints[0].frame.xyz[0]': malformed number"},
      {"frame: left.cut", "frame: {xyz: [0, 0, 0]}",
       "key 'waypoints[0].frame': missing required key 'waypoints[0].frame.frame'"},
      {"name: halfway", "name: closure", "key 'waypoints[0]': duplicate constraint row name"},
      {"position: [0.8, 0.5, 1.0]}",
       "position: [0.8, 0.5, 1.0]}\n  - {frame: left.cut, t: 0.5, "
       "position: [0.8, 0.5, 1.0], name: halfway}",
       "key 'waypoints[1].name': waypoint 'halfway' twice"},
      {"t: 0.5,", "t: 1.52,",
       "key 'waypoints': optimize: waypoint 'halfway': t = 1.52 is not in (0, duration]"},
      {"t: 0.5,", "t: 0.5, fraction: 0.5,",
       "key 'waypoints[0]': expected one of t (from the start) or fraction"},
      {"t: 0.5,", "fraction: 1.5,",
       "key 'waypoints': optimize: waypoint 'halfway': fraction = 1.5 is not in (0, 1]"},
      {"duration: 1", "duration: {initial: 1, min: 0.5, max: 2}",
       "key 'waypoints': optimize: waypoint 'halfway': with a free duration give its time as a "
       "fraction"},
      {"position: [0.8, 0.5, 1.0]", "position: [0.8, 0.5]", "key 'waypoints[0].position'"},
      {"name: halfway", "colour: red", "key 'waypoints[0].colour': unknown key"},
  };
  expect_refused(good, cases, dir);
}

// Each waypoint gets its own rows, also when one's name is another's with a suffix (rows a_x.. and
// a_b_x..: a match on the prefix "a_" would give waypoint a the rows of a_b).
TEST(OptimizeFile, EachWaypointGetsItsOwnRows) {
  const fs::path dir = fs::path(UKDYN_SOURCE_DIR) / "scenarios" / "optimize";
  std::string text = ukdyn_test::slurp(dir / "paper_lift_waypoint.yaml");
  const std::string from =
      "  - {name: halfway, frame: left.cut, t: 0.5, position: [0.8, 0.5, 1.0]}";
  const auto at = text.find(from);
  ASSERT_NE(at, std::string::npos);
  text.replace(at, from.size(),
               "  - {name: a, frame: left.cut, t: 0.5, position: [0.8, 0.5, 1.0]}\n"
               "  - {name: a_b, frame: right.cut, t: 0.25, position: [0.8, 0.5, 1.0]}");
  const OptimizationFile f = load_optimization_text(text, dir / "two.yaml");
  ASSERT_EQ(f.problem.waypoints.size(), 2u);
  EXPECT_EQ(f.problem.waypoints[0].rows->row_names().front(), "a_x");
  EXPECT_EQ(f.problem.waypoints[1].rows->row_names().front(), "a_b_x");
}

// ∂w_int/∂q at fixed λ of a bound (walker_dq: the welds' wrench derivatives and Walker's projection
// differentiated) against central differences of walker (w_int alone) at q off the manifold and
// multipliers that squeeze; the relative error of the whole 12 × n block.
double internal_wrench_dq_error(const InternalWrenchBound& b, const Vec& q, const Vec& lambda) {
  const Index n = q.size(), rows = 6 * b.grasps;
  Vec w(rows), w_dq(rows), wp(rows), wm(rows);
  Mat d;
  b.walker(q, lambda, w);
  b.walker_dq(q, lambda, w_dq, d);
  EXPECT_LT((w - w_dq).norm(), 1e-14 * (1.0 + w.norm()));
  Mat fd(rows, n);
  Vec qp = q, qm = q;
  for (Index j = 0; j < n; ++j) {
    const double h = 1e-6 * (1.0 + std::abs(q(j)));
    qp(j) = q(j) + h;
    qm(j) = q(j) - h;
    b.walker(qp, lambda, wp);
    b.walker(qm, lambda, wm);
    fd.col(j) = (wp - wm) / (2.0 * h);
    qp(j) = qm(j) = q(j);
  }
  EXPECT_GT(fd.cwiseAbs().maxCoeff(), 1.0);  // the block is not trivially zero
  return (d - fd).cwiseAbs().maxCoeff() / fd.cwiseAbs().maxCoeff();
}

// Two scenarios: load_squeeze's free bodies (roll-pitch-yaw coordinates, symbolic frames) and two
// UR5e arms welded to a free-body bar (its quaternion among the coordinates).
TEST(OptimizeFile, InternalWrenchQDerivativeIsExact) {
  const fs::path dir = fs::path(UKDYN_SOURCE_DIR) / "scenarios" / "optimize";
  const OptimizationFile f = load_optimization_file(dir / "load_squeeze.yaml");
  EXPECT_TRUE(f.problem.internal_wrench_bounds.front().differenced.empty());
  std::srand(7);
  for (int trial = 0; trial < 3; ++trial) {
    const Vec q = f.problem.q_start + 0.3 * Vec::Random(f.problem.q_start.size());
    const Vec lambda = 10.0 * Vec::Random(f.problem.system->rows());
    EXPECT_LT(internal_wrench_dq_error(f.problem.internal_wrench_bounds.front(), q, lambda), 1e-6);
  }
  const OptimizationFile u = load_optimization_text(
      "ukdyn: 1\nname: ur\nscenario: ../two_ur5e_load.yaml\nintervals: 1\nduration: 1\n"
      "end:\n  q: [0, 0, 0, 0, -1.2, 1.6, -1.97, -1.5707963267948966, 0, 0, 0, 0, 0, -1.2, 1.6, "
      "-1.97, -1.5707963267948966, 0, 1.1, 0, 0.7062073754895476, 1, 0, 0, 0]\n"
      "costs:\n  effort: 1\nbounds:\n  internal_wrench: {load: load.load, force: 1}\n",
      dir / "ur.yaml");
  // The bar's quaternion columns exact too (none differenced), off the unit sphere as well (a
  // random step of 0.1 takes |u| off 1).
  EXPECT_TRUE(u.problem.internal_wrench_bounds.front().differenced.empty());
  const OptimizationFile plate = load_optimization_file(dir / "four_robot_plate.yaml");
  EXPECT_TRUE(plate.problem.internal_wrench_bounds.front().differenced.empty());
  for (const OptimizationFile* o : {&u, &plate}) {
    const Vec q = o->problem.q_start + 0.1 * Vec::Random(o->problem.q_start.size());
    const Vec lambda = 10.0 * Vec::Random(o->problem.system->rows());
    const double e = internal_wrench_dq_error(o->problem.internal_wrench_bounds.front(), q, lambda);
    EXPECT_LT(e, 1e-6) << o->name;
    std::printf("%s: dw_int/dq against central differences %.3g (relative, whole block)\n",
                o->name.c_str(), e);
  }
}

// Walker's projection differentiated (points and wrenches moving together) against central
// differences, three grasps; with the points held (dG = 0) it is off, so dG's terms are tested.
TEST(OptimizeFile, WalkerProjectionDerivativeMatchesCentralDifferences) {
  std::srand(5);
  const std::vector<Vec3> p0 = {Vec3::Random(), Vec3::Random(), Vec3::Random()};
  const Vec w0 = 10.0 * Vec::Random(18);
  const Mat dp = Mat::Random(9, 4), dw = Mat::Random(18, 4);
  auto at = [&](Index j, double s) {
    std::vector<Vec3> p = p0;
    for (std::size_t k = 0; k < 3; ++k) p[k] += s * dp.block<3, 1>(3 * static_cast<Index>(k), j);
    return internal_wrench_walker(grasp_matrix(p, p.front()), Vec(w0 + s * dw.col(j)));
  };
  const Mat d = internal_wrench_walker_derivative(p0, w0, dp, dw);
  const Mat held = internal_wrench_walker_derivative(p0, w0, Mat::Zero(9, 4), dw);
  for (Index j = 0; j < 4; ++j) {
    const double h = 1e-6;
    const Vec fd = (at(j, h) - at(j, -h)) / (2.0 * h);
    EXPECT_LT((d.col(j) - fd).norm(), 1e-7 * fd.norm()) << j;
    EXPECT_GT((held.col(j) - fd).norm(), 1e-2 * fd.norm()) << j;
  }
}

// The internal-wrench rows' Jacobian (∂/∂μ exact through dμ/dx, ∂/∂q at fixed μ by walker_dq)
// against central differences of the rows, off the guess.
TEST(OptimizeFile, InternalWrenchDerivativesMatchCentralDifferences) {
  const fs::path dir = fs::path(UKDYN_SOURCE_DIR) / "scenarios" / "optimize";
  OptimizationFile f = load_optimization_file(dir / "load_squeeze.yaml");
  f.problem.intervals = 1;  // (each column re-evaluates every point: kept small)
  f.problem.method = CollocationMethod::trapezoidal;
  f.problem.internal_wrench_bounds.front().max_torque = 1.0;
  optimize::Transcription tr(f.problem);
  Vec x = tr.initial_guess();
  std::srand(11);
  x += 0.05 * Vec::Random(x.size());
  for (Index p = 0; p < tr.points(); ++p)  // forces that squeeze: internal wrenches of O(10 N)
    x.segment(tr.u_of(p), 12) += 20.0 * Vec::Random(12);
  const auto [worst_j, worst_g] = derivative_errors(tr, x);
  EXPECT_LT(worst_j, 1e-6);
  EXPECT_LT(worst_g, 1e-6);
}

// replay.yaml's tracked coordinate must fix q with the constraints along the whole path: the bead
// swung past the ring's side (θ = 2 rad) passes x's turning point (θ = π/2, where the ring's row
// and x are dependent), which the run names.
TEST(OptimizeFile, ReplayWarnsWhereTheTrackedCoordinatesDoNotFixQ) {
  if (!ipopt_available()) GTEST_SKIP() << "built without IPOPT";
  const fs::path dir =
      fs::temp_directory_path() / ("ukdyn_replay_warn_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  std::ofstream(dir / "circle.yaml") << circle_text(0.0);
  char end[96];
  std::snprintf(end, sizeof end, "[%.17g, %.17g]", on_circle(2.0)(0), on_circle(2.0)(1));
  const OptimizationFile f = load_optimization_text(
      std::string("ukdyn: 1\nname: past_the_side\nscenario: circle.yaml\nintervals: 10\n"
                  "duration: 1\nend:\n  q: ") +
          end + "\ncosts:\n  effort: 0.01\n",
      dir / "p.yaml");
  const OptimizeReport rep = run_optimization(f, dir / "out");
  ASSERT_TRUE(rep.solution.converged) << rep.solution.status;
  EXPECT_NE(rep.replay_scenario_note.find("do not fix q at t ="), std::string::npos)
      << rep.replay_scenario_note;
  const auto j = nlohmann::json::parse(ukdyn_test::slurp(dir / "out" / "summary.json"));
  EXPECT_EQ(j["replay_scenario"]["warning"].get<std::string>(), rep.replay_scenario_note);
  fs::remove_all(dir);
}

// The largest |f_int,k| of Walker's internal force over the points and grasps of a solution, from
// its multipliers and the bound's own map.
// Over the points of s, by the bound's own Walker function at the solution's q and multipliers:
// the largest internal force |f_int,k| and moment |m_int,k| of any grasp, and the largest
// |Σ_k f_int,k| (0 for an internal wrench: G w_int = 0).
struct InternalPeaks {
  double force = 0.0, moment = 0.0, net_force = 0.0;
};
InternalPeaks internal_peaks(const TrajectoryProblem& p, const TrajectorySolution& s) {
  const InternalWrenchBound& b = p.internal_wrench_bounds.front();
  Vec lambda = Vec::Zero(p.system->rows()), w(6 * b.grasps);
  InternalPeaks peaks;
  for (Index i = 0; i < s.t.size(); ++i) {
    for (std::size_t r = 0; r < s.kept_rows.size(); ++r)
      lambda(s.kept_rows[r]) = s.mu(i, static_cast<Index>(r));
    b.walker(s.q.row(i).transpose(), lambda, w);
    Vec3 net = Vec3::Zero();
    for (Index k = 0; k < b.grasps; ++k) {
      peaks.force = std::max(peaks.force, w.segment<3>(6 * k).norm());
      peaks.moment = std::max(peaks.moment, w.segment<3>(6 * k + 3).norm());
      net += w.segment<3>(6 * k);
    }
    peaks.net_force = std::max(peaks.net_force, net.norm());
  }
  return peaks;
}

double peak_internal_force(const TrajectoryProblem& p, const TrajectorySolution& s) {
  return internal_peaks(p, s).force;
}

// A bound on the squeeze: two agents of unequal mass carry a load; at minimum effort the grasps
// squeeze it (Walker's internal force up to 10.3 N); bounded at 2 N, the run's Wint_walker_ columns
// stay within it at every point, they are the internal part (G w_int = 0: the two grasps' internal
// forces cancel), and the effort rises.
TEST(OptimizeFile, AnInternalWrenchBoundHoldsAndCosts) {
  if (!ipopt_available()) GTEST_SKIP() << "built without IPOPT";
  const fs::path dir = fs::path(UKDYN_SOURCE_DIR) / "scenarios" / "optimize";
  const OptimizationFile f = load_optimization_file(dir / "load_squeeze.yaml");
  ASSERT_EQ(f.problem.internal_wrench_bounds.size(), 1u);
  const double bound = f.problem.internal_wrench_bounds.front().max_force;
  TrajectoryProblem free = f.problem;
  free.internal_wrench_bounds.clear();
  const auto unbounded = optimize_trajectory(free, f.ipopt);
  ASSERT_TRUE(unbounded.converged) << unbounded.status;
  const double free_peak = peak_internal_force(f.problem, unbounded);
  EXPECT_GT(free_peak, 1.2 * bound);
  const fs::path out = fs::temp_directory_path() / ("ukdyn_squeeze_" + std::to_string(::getpid()));
  const OptimizeReport rep = run_optimization(f, out);
  ASSERT_TRUE(rep.solution.converged) << rep.solution.status;
  EXPECT_TRUE(rep.solution.trusted) << rep.solution.message;
  EXPECT_GT(rep.solution.cost, unbounded.cost * 1.001);
  std::ifstream in(out / "trajectory.csv");
  io_detail::CsvLines lines(in);
  std::string line;
  ASSERT_TRUE(lines.next(line));
  const auto header = io_detail::split_csv_line(line);
  auto col = [&](const std::string& name) {
    const auto it = std::find(header.begin(), header.end(), name);
    EXPECT_NE(it, header.end()) << name;
    return static_cast<std::size_t>(it - header.begin());
  };
  double peak = 0.0, net = 0.0;
  Index rows = 0;
  while (lines.next(line)) {
    const auto cells = io_detail::split_csv_line(line);
    Vec3 sum = Vec3::Zero();
    for (const char* g : {"grip_left", "grip_right"}) {
      const std::string pre = std::string("Wint_walker_") + g + "_f";
      Vec3 fk;
      for (Index i = 0; i < 3; ++i) fk(i) = std::stod(cells[col(pre + static_cast<char>('x' + i))]);
      peak = std::max(peak, fk.norm());
      sum += fk;
    }
    net = std::max(net, sum.norm());
    ++rows;
  }
  EXPECT_EQ(rows, rep.solution.t.size());
  EXPECT_LE(peak, bound * (1 + 1e-6));
  EXPECT_LT(net, 1e-9);
  EXPECT_NEAR(peak, peak_internal_force(f.problem, rep.solution), 1e-9 * peak);
  std::printf(
      "squeeze: peak internal force %.4g N free, %.4g N bounded (%.3g); cost %.6g -> %.6g\n",
      free_peak, peak, bound, unbounded.cost, rep.solution.cost);
  fs::remove_all(out);
}

// The shipped four-robot plate (scenarios/optimize/four_robot_plate.yaml: a free-body plate, its
// quaternion among the coordinates, welded to four robots): from the straight-line guess the
// optimum converges, ends at the given pose at rest, keeps the squeeze within both bounds at every
// point (the Walker function at the solution's q and μ, not the NLP's rows), the internal forces
// of the four grasps cancel, and bounding the squeeze costs effort.
TEST(OptimizeFile, FourRobotPlateKeepsTheSqueezeBound) {
  if (!ipopt_available()) GTEST_SKIP() << "built without IPOPT";
  const fs::path dir = fs::path(UKDYN_SOURCE_DIR) / "scenarios" / "optimize";
  const OptimizationFile f = load_optimization_file(dir / "four_robot_plate.yaml");
  ASSERT_EQ(f.problem.internal_wrench_bounds.size(), 1u);
  const InternalWrenchBound& b = f.problem.internal_wrench_bounds.front();
  ASSERT_EQ(b.grasps, 4);
  const auto s = optimize_trajectory(f.problem, f.ipopt);
  ASSERT_TRUE(s.converged) << s.status;
  EXPECT_TRUE(s.trusted) << s.message;
  const InternalPeaks bounded = internal_peaks(f.problem, s);
  EXPECT_LE(bounded.force, b.max_force * (1 + 1e-6));
  EXPECT_LE(bounded.moment, b.max_torque * (1 + 1e-6));
  EXPECT_LT(bounded.net_force, 1e-9);
  const Index last = s.t.size() - 1;
  for (Index i = 0; i < f.problem.q_end.size(); ++i) {
    if (std::isfinite(f.problem.q_end(i))) {
      EXPECT_NEAR(s.q(last, i), f.problem.q_end(i), 1e-9);
    }
    EXPECT_NEAR(s.qd(last, i), 0.0, 1e-9);
  }
  TrajectoryProblem free = f.problem;
  free.internal_wrench_bounds.clear();
  const auto unbounded = optimize_trajectory(free, f.ipopt);
  ASSERT_TRUE(unbounded.converged) << unbounded.status;
  EXPECT_GT(s.cost, unbounded.cost * (1 + 1e-4));
  const InternalPeaks free_peaks = internal_peaks(f.problem, unbounded);  // both bounds bite
  EXPECT_GT(free_peaks.force, 1.2 * b.max_force);
  EXPECT_GT(free_peaks.moment, 1.2 * b.max_torque);
  std::printf("four robots: squeeze %.4g N, %.4g N m bounded; cost %.6g -> %.6g, %d iterations\n",
              bounded.force, bounded.moment, unbounded.cost, s.cost, s.iterations);
}

// IPOPT converged to its KKT tolerance, the result vouched for, the closure held at every knot.
void expect_converged_on_the_manifold(const TrajectorySolution& s) {
  ASSERT_TRUE(s.converged) << s.status;
  EXPECT_TRUE(s.trusted) << s.message;
  EXPECT_LE(s.dual_infeasibility, 1e-8);
  EXPECT_LE(s.max_position_residual, 1e-10);
  EXPECT_LE(s.max_velocity_residual, 1e-10);
}

// The paper's lift at minimum effort against the paper's own cosine path between the same rest
// states in the same time: along a given path q(t) the least ∫‖τ‖² is that of τ = P h, h = M q̈ +
// C q̇ + G and P the projector onto null(A_closure) (any τ with τ − h ∈ range(A_closureᵀ) drives
// the path; the closure force takes the rest). The optimum must not cost more; the optimal
// trajectory stays on the closure, and the open-loop replay follows it.
TEST(OptimizeFile, PaperLiftBeatsThePapersCosinePath) {
  if (!ipopt_available()) GTEST_SKIP() << "built without IPOPT";
  const fs::path root = fs::path(UKDYN_SOURCE_DIR) / "scenarios";
  const OptimizationFile f = load_optimization_file(root / "optimize" / "paper_lift.yaml");
  const TrajectorySolution s = optimize_trajectory(f.problem, f.ipopt);
  ASSERT_NO_FATAL_FAILURE(expect_converged_on_the_manifold(s));
  const double optimum = s.cost / 1e-4;  // the file's effort weight

  const Scenario paper = load_scenario(root / "paper.yaml");
  const System& free = *f.problem.system;
  SimulationSettings set = paper.sim;
  set.t_end = 1.0;
  ForwardData d(free);
  const Index n = free.dof();
  std::vector<double> power;
  const SampleObserver obs = [&](double t, CVecRef q, CVecRef qd, const ForwardData& pd) {
    evaluate_dynamics(free, d, t, q, qd);
    evaluate_constraints(free, d, t, q, qd);
    const Vec h = d.M * pd.qdd + d.Cqd + d.G;
    const Vec tau = h - d.A.transpose() * (d.A * d.A.transpose()).ldlt().solve(d.A * h);
    power.push_back(tau.squaredNorm());
    return true;
  };
  simulate(
      *paper.system, paper.q0, paper.qd0,
      [](double, CVecRef, CVecRef, VecRef tau) { tau.setZero(); }, set, obs);
  ASSERT_EQ(power.size(), 101u);
  double path = 0;  // Simpson over the 100 sample steps
  for (std::size_t i = 0; i < power.size(); ++i)
    path += (i == 0 || i + 1 == power.size() ? 1 : (i % 2 ? 4 : 2)) * power[i] * 0.01 / 3;
  std::printf("paper lift, integral of |tau|^2: cosine path %.6g, optimum %.6g (%.1f %% less)\n",
              path, optimum, 100 * (1 - optimum / path));
  EXPECT_LT(optimum, path);
  (void)n;
}

// The shipped traverse (scenarios/optimize/paper_traverse.yaml): both platforms 1 m along x in
// 1 s, rest to rest. Against the rigid cosine traverse written here in closed form (every joint
// held, dx1 = dx2 = 0.5 - 0.5 cos(pi t): on the closure at every t, since the whole system
// translates), with the least tau that drives it (tau = P (M q'' + C q' + G), as above), by
// Simpson's rule on 100 steps: the optimum must not cost more, and its load (the left cut point,
// by hand) ends 1 m further along x at the start's height.
TEST(OptimizeFile, PaperTraverseBeatsTheRigidCosineTraverse) {
  if (!ipopt_available()) GTEST_SKIP() << "built without IPOPT";
  const fs::path root = fs::path(UKDYN_SOURCE_DIR) / "scenarios";
  const OptimizationFile f = load_optimization_file(root / "optimize" / "paper_traverse.yaml");
  const TrajectorySolution s = optimize_trajectory(f.problem, f.ipopt);
  ASSERT_NO_FATAL_FAILURE(expect_converged_on_the_manifold(s));
  const Index last = s.q.rows() - 1;
  const Vec3 moved = left_cut(s.q, last) - left_cut(s.q, 0);
  EXPECT_LT((moved - Vec3(1, 0, 0)).norm(), 1e-9) << moved.transpose();
  const double optimum = s.cost / 1e-4;  // the file's effort weight

  const System& free = *f.problem.system;
  ForwardData d(free);
  const Index n = free.dof();
  const Vec q0 = s.q.row(0).transpose();
  Vec dir = Vec::Zero(n);
  dir(0) = dir(6) = 1.0;  // dx1, dx2
  double path = 0;
  const int steps = 100;
  for (int i = 0; i <= steps; ++i) {
    const double t = static_cast<double>(i) / steps, pi = std::acos(-1.0);
    const Vec q = q0 + 0.5 * (1 - std::cos(pi * t)) * dir;
    const Vec qd = 0.5 * pi * std::sin(pi * t) * dir;
    const Vec qdd = 0.5 * pi * pi * std::cos(pi * t) * dir;
    evaluate_dynamics(free, d, t, q, qd);
    evaluate_constraints(free, d, t, q, qd);
    ASSERT_LT((d.A * qdd - d.b).norm(), 1e-9) << "the rigid traverse leaves the closure at " << t;
    const Vec h = d.M * qdd + d.Cqd + d.G;
    const Vec tau = h - d.A.transpose() * (d.A * d.A.transpose()).ldlt().solve(d.A * h);
    path += (i == 0 || i == steps ? 1 : (i % 2 ? 4 : 2)) * tau.squaredNorm() / (3.0 * steps);
  }
  std::printf(
      "paper traverse, integral of |tau|^2: rigid cosine %.6g, optimum %.6g (%.1f %% less)\n", path,
      optimum, 100 * (1 - optimum / path));
  EXPECT_LT(optimum, path);
}

// A warm start from a previous run's trajectory.csv (`guess:`): from the same problem's optimum
// IPOPT stops at once (the run's CSV holds every point to 17 digits); from the trapezoidal
// solution on 20 intervals (another method and mesh: interpolated in time) it reaches the same
// optimum as from the straight line.
TEST(OptimizeFile, WarmStartFromAPreviousRun) {
  if (!ipopt_available()) GTEST_SKIP() << "built without IPOPT";
  const fs::path dir = fs::path(UKDYN_SOURCE_DIR) / "scenarios" / "optimize";
  const fs::path scratch = ukdyn_test::process_scratch("ukdyn_optimize_guess");
  std::string text = ukdyn_test::slurp(dir / "paper_lift.yaml");
  auto replace = [](std::string t, const std::string& from, const std::string& to) {
    const auto at = t.find(from);
    EXPECT_NE(at, std::string::npos) << from;
    return t.replace(at, from.size(), to);
  };
  const std::string fine = replace(text, "intervals: 50", "intervals: 40");
  const std::string coarse =
      replace(replace(fine, "method: hermite_simpson", "method: trapezoidal"), "intervals: 40",
              "intervals: 20");
  run_optimization(load_optimization_text(coarse, dir / "coarse.yaml"), scratch / "coarse");
  const OptimizationFile cold = load_optimization_text(fine, dir / "fine.yaml");
  const OptimizeReport a = run_optimization(cold, scratch / "cold");
  auto guessed = [&](const char* run) {
    const std::string g = "guess: " + (scratch / run / "trajectory.csv").string() + "\n";
    const OptimizationFile f = load_optimization_text(fine + g, dir / "fine.yaml");
    return optimize_trajectory(f.problem, f.ipopt);
  };
  const auto self = guessed("cold"), refined = guessed("coarse");
  ASSERT_TRUE(a.solution.converged && self.converged && refined.converged);
  EXPECT_LT(std::abs(self.cost - a.solution.cost), 1e-9 * a.solution.cost);
  EXPECT_LT(std::abs(refined.cost - a.solution.cost), 1e-7 * a.solution.cost);
  EXPECT_LE(self.iterations, 3);
  std::printf("iterations: straight line %d, own optimum %d, coarse trapezoidal %d\n",
              a.solution.iterations, self.iterations, refined.iterations);
  // A guess file without the columns the problem needs is refused at `guess`.
  std::ofstream(scratch / "bad.csv") << "t,dx1\n0,0\n1,0\n";
  try {
    load_optimization_text(fine + "guess: " + (scratch / "bad.csv").string() + "\n",
                           dir / "fine.yaml");
    ADD_FAILURE() << "accepted a guess without its columns";
  } catch (const ScenarioError& e) {
    EXPECT_NE(std::string(e.what()).find("key 'guess': the guess file has no column 'dy1'"),
              std::string::npos)
        << e.what();
  }
}

// `envelopes: motors`: every motor's operating point at the optimum, computed by the motor model
// itself (motor_point: τ_m = u/(nη) motoring, uη/n braking, against min(T_p, T_s(1 − |ω_m|/ω_0))),
// stays inside its envelope up to IPOPT's bound relaxation (1e-8 of the bound), and the lift in
// 0.6 s puts some motor on it (the constraint is active, so it was not vacuous).
TEST(OptimizeFile, MotorEnvelopesHoldAtTheOptimum) {
  if (!ipopt_available()) GTEST_SKIP() << "built without IPOPT";
  const fs::path dir = fs::path(UKDYN_SOURCE_DIR) / "scenarios" / "optimize";
  const OptimizationFile f = load_optimization_file(dir / "paper_lift_motors.yaml");
  EXPECT_EQ(f.problem.envelopes.size(),
            8u);  // the gearmotors of the two robots' base and arm joints
  const auto s = optimize_trajectory(f.problem, f.ipopt);
  ASSERT_TRUE(s.converged && s.trusted) << s.status << " " << s.message;
  const auto& motors = f.scenario->actuators.motors;
  double lowest = 1e9;
  for (Index p = 0; p < s.t.size(); ++p)
    for (Index j = 0; j < s.u.cols(); ++j) {
      const auto& m = motors[static_cast<std::size_t>(j)];
      if (!m) continue;
      const double omega_j = f.problem.B.col(j).dot(s.qd.row(p).transpose());
      lowest = std::min(lowest, motor_point(*m, s.u(p, j), omega_j).margin);
    }
  EXPECT_GT(lowest, -1e-7);
  EXPECT_LT(lowest, 1e-4);
  std::printf("lowest motor margin at the optimum: %.3g\n", lowest);
}

#ifdef UKDYN_TEST_HAVE_CLI
// Same problem file, two processes: the same bytes (trajectory.csv and summary.json), exit 0.
TEST(OptimizeCli, SameBytesInTwoProcesses) {
  if (!ipopt_available()) GTEST_SKIP() << "built without IPOPT";
  const fs::path scratch = ukdyn_test::process_scratch("ukdyn_optimize_cli");
  const std::string file =
      (fs::path(UKDYN_SOURCE_DIR) / "scenarios" / "optimize" / "paper_lift.yaml").string();
  for (const char* out : {"a", "b"}) {
    const auto r = ukdyn_test::run_cli(
        UKDYN_CLI, scratch,
        "optimize " + ukdyn_test::sh(file) + " --out " + ukdyn_test::sh((scratch / out).string()));
    ASSERT_EQ(r.exit_code, 0) << r.err;
    EXPECT_NE(r.out.find("Solve_Succeeded"), std::string::npos) << r.out;
  }
  for (const char* name :
       {"trajectory.csv", "summary.json", "replay.yaml", "replay_open_loop.yaml"})
    EXPECT_EQ(ukdyn_test::slurp(scratch / "a" / name), ukdyn_test::slurp(scratch / "b" / name))
        << name;
  const auto j = nlohmann::json::parse(ukdyn_test::slurp(scratch / "a" / "summary.json"));
  EXPECT_TRUE(j["trusted"].get<bool>());
  EXPECT_LT(j["replay"]["max_q_deviation"].get<double>(), 1e-4);
  // A problem file that does not exist: exit 2, the path named.
  const auto bad = ukdyn_test::run_cli(UKDYN_CLI, scratch, "optimize /nonexistent/p.yaml");
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_NE(bad.err.find("/nonexistent/p.yaml"), std::string::npos) << bad.err;
}

// Max |q − q_opt| of a simulate run's trajectory.csv at the optimum's points (its rows at the same
// times: sample_dt is their spacing).
double tracking_error(const fs::path& run, const fs::path& optimum,
                      const std::vector<std::string>& columns = {"x", "z"}) {
  auto read = [](const fs::path& file, std::vector<std::string>& header) {
    std::ifstream in(file);
    io_detail::CsvLines lines(in);
    std::string line;
    std::vector<std::vector<double>> rows;
    if (!lines.next(line)) return rows;
    header = io_detail::split_csv_line(line);
    while (lines.next(line)) {
      std::vector<double> r;
      for (const auto& c : io_detail::split_csv_line(line)) {
        double v = std::nan("");
        io_detail::parse_csv_number(c, v);
        r.push_back(v);
      }
      rows.push_back(std::move(r));
    }
    return rows;
  };
  std::vector<std::string> hs, ho;
  const auto sim = read(run / "trajectory.csv", hs), opt = read(optimum / "trajectory.csv", ho);
  double worst = 0.0;
  Index compared = 0;
  for (const auto& o : opt)
    for (const auto& r : sim)
      if (std::abs(r[0] - o[0]) < 1e-9) {
        for (const auto& c : columns) {
          const auto is = std::find(hs.begin(), hs.end(), c) - hs.begin();
          const auto io = std::find(ho.begin(), ho.end(), c) - ho.begin();
          worst = std::max(
              worst, std::abs(r[static_cast<std::size_t>(is)] - o[static_cast<std::size_t>(io)]));
        }
        ++compared;
      }
  EXPECT_EQ(compared, static_cast<Index>(opt.size())) << run;
  return worst;
}

// The replay scenarios `ukdyn optimize` writes, run by `ukdyn simulate` on a plant whose bead is 5 %
// heavier than the model's: the optimal u(t) as feedforward plus the stabilised servo on the
// optimal path tracks it closely; the feedforward alone (replay_open_loop.yaml, the same plant)
// falls away under the unmodelled weight.
TEST(OptimizeCli, ReplayScenarioTracksAPerturbedPlant) {
  if (!ipopt_available()) GTEST_SKIP() << "built without IPOPT";
  const fs::path scratch = ukdyn_test::process_scratch("ukdyn_optimize_replay");
  std::ofstream(scratch / "circle.yaml") << circle_text(9.81);
  std::ofstream(scratch / "swing.yaml") << R"(ukdyn: 1
name: swing
scenario: circle.yaml
intervals: 10
duration: 1
end:
  q: [0.6731767878463172, -0.43224184447562804]
costs:
  effort: 0.01
)";  // θ = 1 rad on the ring of radius 0.8
  auto run = [&](const std::string& args) {
    const auto r = ukdyn_test::run_cli(UKDYN_CLI, scratch, args);
    EXPECT_EQ(r.exit_code, 0) << args << "\n" << r.err;
    return r;
  };
  const auto at_scratch = [&](const std::string& name) {
    return ukdyn_test::sh((scratch / name).string());
  };
  run("optimize " + at_scratch("swing.yaml") + " --out " + at_scratch("opt"));
  std::string closed = ukdyn_test::slurp(scratch / "opt" / "replay.yaml");
  ASSERT_NE(closed.find("law: stabilized"), std::string::npos) << closed;
  ASSERT_NE(closed.find("track_x"), std::string::npos) << closed;  // x and the ring fix z
  closed += "  plant_set:\n    - {path: \"subsystems[bead].parameters.m\", scale: 1.05}\n";
  std::ofstream(scratch / "opt" / "closed.yaml") << closed;
  std::string open = ukdyn_test::slurp(scratch / "opt" / "replay_open_loop.yaml");
  const auto at = open.find("parameters: {m: 2}");
  ASSERT_NE(at, std::string::npos) << open;
  open.replace(at, 18, "parameters: {m: 2.1}");
  std::ofstream(scratch / "opt" / "open.yaml") << open;
  for (const char* name : {"replay", "closed", "open"})
    run("simulate " + at_scratch(std::string("opt/") + name + ".yaml") + " --out " +
        at_scratch(name));
  const double nominal = tracking_error(scratch / "replay", scratch / "opt");
  const double fb = tracking_error(scratch / "closed", scratch / "opt");
  const double ff = tracking_error(scratch / "open", scratch / "opt");
  std::printf(
      "replay on the model %.3g m; on the 5 %% heavier plant: servo %.3g m, "
      "feedforward only %.3g m\n",
      nominal, fb, ff);
  EXPECT_LT(nominal, 1e-4);
  EXPECT_LT(fb, 5e-3);
  EXPECT_GT(ff, 5.0 * fb);
}
// The replay scenarios name the robot file of their scenario relative to themselves: a scenario
// whose `urdf:` is relative to its own folder, optimised from that folder into another, replays
// with `ukdyn simulate` from a third working directory, and again after its folder is moved.
TEST(OptimizeCli, ReplayScenariosRunFromAnotherDirectory) {
  if (!ipopt_available()) GTEST_SKIP() << "built without IPOPT";
  if (!symbolic::urdf_supported()) GTEST_SKIP() << "built without urdfdom";
  const fs::path scratch = ukdyn_test::process_scratch("ukdyn_optimize_paths");
  for (const char* d : {"robots", "model", "elsewhere", "runs"})
    fs::create_directories(scratch / d);
  std::ofstream(scratch / "robots" / "pendulum.urdf") << R"(<robot name="p"><link name="base"/>
    <joint name="j" type="continuous"><parent link="base"/><child link="arm"/>
      <origin xyz="0 0 0" rpy="0 0 0"/><axis xyz="0 1 0"/></joint>
    <link name="arm"><inertial><origin xyz="0 0 -0.5" rpy="0 0 0"/><mass value="1"/>
      <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
  </robot>)";
  std::ofstream(scratch / "model" / "pendulum.yaml") << R"(ukdyn: 1
name: pendulum
gravity: 9.81
subsystems:
  - {name: arm, type: serial_chain, coordinates: [a], urdf: ../robots/pendulum.urdf}
initial: {q: [0], qd: [0]}
simulation: {t_end: 1, sample_dt: 0.1}
)";
  std::ofstream(scratch / "model" / "swing.yaml") << R"(ukdyn: 1
name: swing
scenario: pendulum.yaml
intervals: 10
duration: 1
end: {q: [1]}
costs: {effort: 0.01}
)";
  auto run = [&](const std::string& cwd, const std::string& args) {
    const auto r = ukdyn_test::run_cli(UKDYN_CLI, scratch, args, "",
                                       "cd " + ukdyn_test::sh((scratch / cwd).string()) + " && ");
    EXPECT_EQ(r.exit_code, 0) << args << "\n" << r.err;
  };
  run("model", "optimize swing.yaml --out ../runs/opt");
  for (const char* name : {"replay", "replay_open_loop"})
    run("elsewhere", std::string("simulate ../runs/opt/") + name + ".yaml --out ../runs/" + name);
  EXPECT_LT(tracking_error(scratch / "runs" / "replay", scratch / "runs" / "opt", {"a"}), 1e-3);
  EXPECT_LT(tracking_error(scratch / "runs" / "replay_open_loop", scratch / "runs" / "opt", {"a"}),
            1e-3);
  fs::rename(scratch / "runs", scratch / "moved");  // the same depth: the relative path holds
  run("robots", "simulate ../moved/opt/replay.yaml --out ../moved/again");
  EXPECT_LT(tracking_error(scratch / "moved" / "again", scratch / "moved" / "opt", {"a"}), 1e-3);
}

// Ctrl-C in the middle of a solve: IPOPT stops after its current iteration, the folder holds that
// iterate marked untrusted (status User_Requested_Stop, "interrupted"), the exit code is 1 and no
// replay is claimed. The signal is sent once the run's output folder is locked (the solve has
// started: the handler is in place by then), so no timing decides the outcome: 300 intervals of
// the paper's lift take tens of iterations of about a second each.
TEST(OptimizeCli, CtrlCStopsTheSolveAndMarksTheFolderUntrusted) {
  if (!ipopt_available()) GTEST_SKIP() << "built without IPOPT";
  const fs::path scratch = ukdyn_test::process_scratch("ukdyn_optimize_cli");
  const fs::path src = fs::path(UKDYN_SOURCE_DIR) / "scenarios";
  const fs::path problem = scratch / "long_lift.yaml", out = scratch / "long_lift";
  std::string text = ukdyn_test::slurp(src / "optimize" / "paper_lift.yaml");
  text.replace(text.find("intervals: 50"), 13, "intervals: 300");
  text.replace(text.find("../paper_free.yaml"), 18, (src / "paper_free.yaml").string());
  std::ofstream(problem) << text;
  fs::remove_all(out);
  const std::string cmd =
      ukdyn_test::sh(UKDYN_CLI) + " optimize " + ukdyn_test::sh(problem.string()) + " --out " +
      ukdyn_test::sh(out.string()) + " > " + ukdyn_test::sh((scratch / "ctrl_c.out").string()) +
      " 2> " + ukdyn_test::sh((scratch / "ctrl_c.err").string()) + " & pid=$!; n=0; while [ ! -e " +
      ukdyn_test::sh((out / ".ukdyn.lock").string()) +
      " ] && [ $n -lt 3000 ]; do sleep 0.1; n=$((n+1)); done; kill -INT $pid; wait $pid";
  const int rc = ukdyn_test::shell(cmd);
  const std::string err = ukdyn_test::slurp(scratch / "ctrl_c.err");
  EXPECT_EQ(rc, 1) << err;
  EXPECT_NE(err.find("interrupted"), std::string::npos) << err;
  const auto j = nlohmann::json::parse(ukdyn_test::slurp(out / "summary.json"));
  EXPECT_FALSE(j["trusted"].get<bool>());
  EXPECT_EQ(j["ipopt"]["status"], "User_Requested_Stop");
  EXPECT_NE(j["message"].get<std::string>().find("interrupted"), std::string::npos);
  EXPECT_FALSE(j.contains("replay"));  // no open-loop replay of an iterate that is no optimum
  EXPECT_FALSE(fs::exists(out / ".ukdyn.lock"));
}

// IPOPT reads ./ipopt.opt when it is initialised without a file: an input no problem file names.
// ukdyn initialises it with none, so a stray options file in the working directory (here one that
// would stop IPOPT after 1 iteration) changes nothing: the same bytes as from elsewhere.
TEST(OptimizeCli, AnIpoptOptFileInTheWorkingDirectoryIsNotRead) {
  if (!ipopt_available()) GTEST_SKIP() << "built without IPOPT";
  const fs::path scratch = ukdyn_test::process_scratch("ukdyn_optimize_cli");
  const fs::path cwd = scratch / "with_ipopt_opt", problem = scratch / "rail_problem.yaml";
  fs::create_directories(cwd);
  std::ofstream(cwd / "ipopt.opt") << "max_iter 1\n";
  std::ofstream(scratch / "rail_scenario.yaml") << kRail;
  std::ofstream(problem) << "ukdyn: 1\nname: rail\nscenario: rail_scenario.yaml\nintervals: 8\n"
                            "duration: 1\nend:\n  q: [0.8660254037844386, 0.5]\ncosts:\n"
                            "  effort: 1\n";
  const std::string args = "optimize " + ukdyn_test::sh(problem.string()) + " --out ";
  const auto a =
      ukdyn_test::run_cli(UKDYN_CLI, scratch, args + ukdyn_test::sh((cwd / "a").string()), "",
                          "cd " + ukdyn_test::sh(cwd.string()) + " && ");
  ASSERT_EQ(a.exit_code, 0) << a.err;
  const auto b =
      ukdyn_test::run_cli(UKDYN_CLI, scratch, args + ukdyn_test::sh((scratch / "b").string()));
  ASSERT_EQ(b.exit_code, 0) << b.err;
  EXPECT_EQ(ukdyn_test::slurp(cwd / "a" / "summary.json"),
            ukdyn_test::slurp(scratch / "b" / "summary.json"));
}
#endif

}  // namespace
}  // namespace ukdyn
