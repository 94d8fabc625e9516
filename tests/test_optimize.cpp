// Trajectory optimisation by direct collocation (ukdyn/optimize/trajectory.hpp,
// docs/optimization.md): the NLP's exact derivatives against central differences, and optima
// against closed forms of problems whose optimum is known by reduction to one coordinate.
#include <gtest/gtest.h>

#include <cmath>

#include "optimize/transcription.hpp"
#include "ukdyn/optimize/trajectory.hpp"
#include "ukdyn/scenario/scenario.hpp"

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

// Every entry of the constraint Jacobian and of the cost gradient against central differences,
// at a point off the guess (random u, γ, perturbed states), both methods, free duration, every
// cost term on: the derivatives of a (the U-K acceleration), of A_R(q)ᵀγ and of A_R v included.
void check_derivatives(CollocationMethod method) {
  const auto sc = load_scenario_text(circle_text(9.81), "circle.yaml");
  TrajectoryProblem p = problem_for(sc, method, 4, 1.2, on_circle(1.0));
  p.free_duration = true;
  p.min_duration = 0.5;
  p.max_duration = 3.0;
  p.costs.power = 0.3;
  p.costs.constraint_force = 0.01;
  p.costs.smoothness = 0.2;
  p.costs.duration = 1.5;
  p.envelopes.push_back({0, 40.0, 5.0});
  optimize::Transcription tr(p);
  Vec x = tr.initial_guess();
  std::srand(7);
  x += 0.05 * Vec::Random(x.size());
  x(tr.time_index()) = 1.3;
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
  EXPECT_LT(worst_j, 1e-6) << to_string(method);
  EXPECT_LT(worst_g, 1e-6) << to_string(method);
  Index nnz = 0;
  for (Index i = 0; i < J.size(); ++i) nnz += J.data()[i] != 0.0;
  EXPECT_LE(nnz, tr.jacobian_nonzeros());  // the declared structure covers every non-zero
}

TEST(Optimize, TrapezoidalDerivativesMatchCentralDifferences) {
  check_derivatives(CollocationMethod::trapezoidal);
}

TEST(Optimize, HermiteSimpsonDerivativesMatchCentralDifferences) {
  check_derivatives(CollocationMethod::hermite_simpson);
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

}  // namespace
}  // namespace ukdyn
