// The time column of the linearisation (docs/derivatives.md, "Time"): ∂q̈/∂t, ∂Qc/∂t at fixed
// (q, q̇, τ) from the components' exact time tangents and one more right-hand side of the KKT
// factorisation, against Richardson-extrapolated central differences in t of forward() (an
// independent path: the U-K solve, no KKT, no tangents) at random states of systems whose
// trajectory rows, forces and masses depend on t; exactly 0 where nothing does; the dense, Schur
// and arrow solves against one another; and a component without an exact ∂/∂t refusing the time
// column only. Also the time column of linearize_parameters(), and the minimal model's
// D = ∂(A_R q̇ + Φ_t)/∂q of rheonomic rows (exact) against differences and a closed form.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <random>
#include <sstream>
#include <string>

#include "moving_state.hpp"
#include "ukdyn/model/linearize.hpp"
#include "ukdyn/model/minimal_linearize.hpp"
#include "ukdyn/model/parameter_sensitivity.hpp"
#include "ukdyn/output/control_output.hpp"
#include "ukdyn/run/closed_loop_derivatives.hpp"
#include "ukdyn/scenario/scenario.hpp"
#ifdef UKDYN_CLI
#include <nlohmann/json.hpp>

#include "cli_run.hpp"
#endif

namespace {

using namespace ukdyn;
const std::filesystem::path kSource = UKDYN_SOURCE_DIR;

struct TimeDifferences {
  Vec qdd, Qc;
};

// d/dt of forward()'s q̈ and Qc at fixed (q, q̇, τ): (4 D(h/2) − D(h)) / 3 of central differences
// (error O(h⁴)), h = 1e-3.
TimeDifferences time_differences(const Scenario& sc, double t, const Vec& q, const Vec& qd,
                                 const Vec& tau) {
  const System& sys = *sc.system;
  ForwardData fd(sys);
  auto central = [&](double h) {
    forward(sys, fd, t + h, q, qd, tau, sc.sim.uk);
    const Vec qdd = fd.qdd, Qc = fd.Qc;
    forward(sys, fd, t - h, q, qd, tau, sc.sim.uk);
    return TimeDifferences{(qdd - fd.qdd) / (2 * h), (Qc - fd.Qc) / (2 * h)};
  };
  const TimeDifferences a = central(5e-4), b = central(1e-3);
  return {(4 * a.qdd - b.qdd) / 3, (4 * a.Qc - b.Qc) / 3};
}

// |exact − differences|∞ over |differences|∞ (1e-9 absolute below it: the differences' round-off).
double rel_error(const Vec& exact, const Vec& diff) {
  return (exact - diff).cwiseAbs().maxCoeff() / (diff.cwiseAbs().maxCoeff() + 1e-9);
}

// At `states` random states near the scenario's moving state (q, q̇ perturbed by up to 0.05, t in
// [0.1, 1.6]): ∂q̈/∂t and ∂Qc/∂t against the differences to `tol` relative; returns the largest
// |∂q̈/∂t|∞ seen (a check that the time column is not trivially 0). The worst relative errors are
// printed and recorded as test properties (docs/derivatives.md quotes them).
double expect_time_column_matches(const Scenario& sc, int states, double tol) {
  const System& sys = *sc.system;
  const test::State s0 = test::moving_state(sc);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  double largest = 0.0, worst_qdd = 0.0, worst_Qc = 0.0;
  LinearizeData d(sys);
  for (int k = 0; k < states; ++k) {
    Vec q = s0.q, qd = s0.qd;
    for (Index i = 0; i < q.size(); ++i) {
      q(i) += 0.05 * u(rng);
      qd(i) += 0.05 * u(rng);
    }
    const double t = 0.85 + 0.75 * u(rng);
    linearize(sys, d, t, q, qd, s0.tau, sc.sim.uk);
    const Linearization& lin = d.lin;
    if (lin.dqdd_dt.size() != sys.dof()) {
      ADD_FAILURE() << "no time column: " << lin.time_message;
      return largest;
    }
    EXPECT_TRUE(lin.time_message.empty()) << lin.time_message;
    EXPECT_EQ(lin.dQc_dt.size(), sys.dof());
    EXPECT_EQ(lin.dmu_dt.size(), lin.rank);
    EXPECT_TRUE(lin.trusted) << lin.message;
    const TimeDifferences c = time_differences(sc, t, q, qd, s0.tau);
    EXPECT_LE(rel_error(lin.dqdd_dt, c.qdd), tol) << sc.name << " state " << k << " t " << t;
    EXPECT_LE(rel_error(lin.dQc_dt, c.Qc), tol) << sc.name << " state " << k << " t " << t;
    worst_qdd = std::max(worst_qdd, rel_error(lin.dqdd_dt, c.qdd));
    worst_Qc = std::max(worst_Qc, rel_error(lin.dQc_dt, c.Qc));
    largest = std::max(largest, lin.dqdd_dt.cwiseAbs().maxCoeff());
  }
  std::cout << "[ time ] " << sc.name << ": dqdd_dt " << worst_qdd << ", dQc_dt " << worst_Qc
            << " relative to the differences (largest |dqdd_dt| " << largest << ")\n";
  ::testing::Test::RecordProperty("worst_dqdd_dt_" + sc.name, std::to_string(worst_qdd));
  ::testing::Test::RecordProperty("worst_dQc_dt_" + sc.name, std::to_string(worst_Qc));
  return largest;
}

// A planar double pendulum of definitions (absolute angles) named `name`, with `more` appended
// (forces, constraints) and its own `mass2` for the second body. Its initial state need not be on
// the trajectory rows (initial_tolerance: 1, its largest): the derivatives are those of the equations at any
// state, and the states checked are random ones anyway.
std::string double_pendulum(const std::string& name, const std::string& mass2,
                            const std::string& more) {
  return R"(
ukdyn: 1
name: )" +
         name + R"(
gravity: 9.81
subsystems:
  - name: arm
    type: definitions
    coordinates: [th1, th2]
    parameters: {l1: 0.7, l2: 0.5, m1: 1.5, m2: 0.8}
    bodies:
      - {name: b1, mass: m1, com: [l1/2*sin(th1), 0, -l1/2*cos(th1)]}
      - {name: b2, mass: )" +
         mass2 + R"(, com: [l1*sin(th1) + l2*sin(th2), 0, -l1*cos(th1) - l2*cos(th2)]}
initial:
  q: [0.4, -0.3]
  qd: [0.5, 0.4]
)" + more +
         R"(
simulation:
  t_end: 2
  sample_dt: 0.01
  initial_tolerance: 1
)";
}

// D = ∂(A_R q̇ + Φ_t)/∂q at fixed q̇ by (4 D(h/2) − D(h)) / 3 of central differences of the kept
// rows' velocity residuals (error O(h⁴), h = 1e-3 (1 + |q|∞)): the reference for the exact D of
// minimal_model() (an independent path: velocity_residual(), no tangents).
Mat velocity_residual_differences(const System& sys, double t, const Vec& q, const Vec& qd,
                                  const std::vector<Index>& kept) {
  const Index n = sys.dof(), r = static_cast<Index>(kept.size());
  Vec phid(sys.rows());
  auto kept_rows = [&](const Vec& x) {
    velocity_residuals(sys, t, x, qd, phid);
    Vec out(r);
    for (Index k = 0; k < r; ++k) out(k) = phid(kept[static_cast<std::size_t>(k)]);
    return out;
  };
  const double h = 1e-3 * (1.0 + q.cwiseAbs().maxCoeff());
  Mat D(r, n);
  for (Index j = 0; j < n; ++j) {
    auto central = [&](double step) {
      Vec xp = q, xm = q;
      xp(j) += step;
      xm(j) -= step;
      return Vec((kept_rows(xp) - kept_rows(xm)) / (2.0 * step));
    };
    D.col(j) = (4.0 * central(h / 2) - central(h)) / 3.0;
  }
  return D;
}

// At `states` random states near the scenario's moving state (as expect_time_column_matches, and
// at rest): the minimal model's D against velocity_residual_differences() to `tol` of 1 + |D|;
// the model says its rows are rheonomic. Returns the largest |D| seen.
double expect_minimal_d_matches(const Scenario& sc, int states, double tol) {
  const System& sys = *sc.system;
  const test::State s0 = test::moving_state(sc);
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  double largest = 0.0, worst = 0.0;
  for (int k = 0; k < states; ++k) {
    Vec q = s0.q, qd = k == 0 ? Vec(Vec::Zero(sys.dof())) : s0.qd;
    for (Index i = 0; i < q.size(); ++i) {
      q(i) += 0.05 * u(rng);
      if (k > 0) qd(i) += 0.05 * u(rng);
    }
    const double t = 0.85 + 0.75 * u(rng);
    const Linearization lin = linearize(sys, t, q, qd, s0.tau, sc.sim.uk);
    const MinimalModel mm = minimal_model(sys, t, q, qd, s0.tau, lin);
    EXPECT_TRUE(mm.rheonomic) << sc.name;
    EXPECT_NE(mm.note.find("rheonomic rows"), std::string::npos) << mm.note;
    EXPECT_EQ(mm.note.find("Richardson"), std::string::npos) << mm.note;
    const Mat ref = velocity_residual_differences(sys, t, q, qd, lin.kept_rows);
    if (mm.D.rows() != ref.rows() || mm.D.cols() != ref.cols()) {
      ADD_FAILURE() << "D is " << mm.D.rows() << " x " << mm.D.cols();
      return largest;
    }
    const double err = (mm.D - ref).cwiseAbs().maxCoeff() / (1.0 + ref.cwiseAbs().maxCoeff());
    EXPECT_LE(err, tol) << sc.name << " state " << k << " t " << t;
    worst = std::max(worst, err);
    largest = std::max(largest, mm.D.cwiseAbs().maxCoeff());
  }
  std::cout << "[ minimal D ] " << sc.name << ": " << worst
            << " of 1 + |D| from the differences (largest |D| " << largest << ")\n";
  return largest;
}

}  // namespace

// The paper's system: the cut point of the left arm on x = const, y, z of 0.5 − 0.5 cos(πt)
// (CutPointTrajectory, f⃛ of the cosine), the closure and the `coordinate` rows (constant values).
TEST(TimeDerivatives, PaperCutPointTrajectoryMatchesDifferences) {
  const Scenario sc = load_scenario(kSource / "scenarios" / "paper.yaml");
  EXPECT_GT(expect_time_column_matches(sc, 4, 1e-7), 1e-2);
}

// `coordinate` rows with time functions (CoordinateConstraint: b = f̈(t), ∂b/∂t = f⃛(t)): a
// polynomial of degree 4 on th2 and, in a second system, a cosine.
TEST(TimeDerivatives, CoordinateRowOfTimeMatchesDifferences) {
  const std::pair<const char*, const char*> kinds[] = {
      {"coordinate_polynomial", "{type: polynomial, coefficients: [-0.3, 0.2, -0.4, 0.5, -0.25]}"},
      {"coordinate_cosine", "{type: cosine, mean: -0.3, amplitude: 0.4, omega: 2.5, phase: 0.3}"}};
  for (const auto& [name, value] : kinds) {
    const std::string row =
        std::string("constraints:\n  - {type: coordinate, name: drive, coordinate: th2, value: ") +
        value + "}\n";
    const Scenario sc = load_scenario_text(double_pendulum(name, "m2", row), "coordinate.yaml");
    EXPECT_GT(expect_time_column_matches(sc, 4, 1e-7), 1e-2) << value;
  }
}

// A point_trajectory of the tip along a cubic spline in x (the tape's spline op: exact piecewise,
// its third derivative constant on each piece) and an expression of t in z.
TEST(TimeDerivatives, SplinePointTrajectoryMatchesDifferences) {
  const Scenario sc = load_scenario_text(double_pendulum("spline_of_t", "m2", R"(constraints:
  - type: point_trajectory
    name: traj
    point: [0.7*sin(th1) + 0.5*sin(th2), 0, -0.7*cos(th1) - 0.5*cos(th2)]
    origin: initial
    x: {type: spline, times: [0, 0.5, 1.0, 1.5, 2.0], values: [0, 0.05, -0.02, 0.04, 0], end: natural}
)"),
                                         "spline_of_t.yaml");
  EXPECT_GT(expect_time_column_matches(sc, 5, 1e-7), 1e-2);
}

// forces.generalized expressions of t and a spring-damper whose end moves with t (forward mode on
// the force tapes along dt = 1).
TEST(TimeDerivatives, ForcesOfTimeMatchDifferences) {
  const Scenario sc = load_scenario_text(double_pendulum("forces_of_t", "m2", R"(forces:
  parameters: {k: 40, c: 1.5}
  generalized:
    th1: 0.7*sin(3*t)*th1_dot + 0.4*cos(2*t)*th2
    th2: -0.3*t^2*sin(th1)
  elements:
    - {type: spring_damper, name: s, a: [0.7*sin(th1) + 0.5*sin(th2), 0,
       -0.7*cos(th1) - 0.5*cos(th2)], b: [1 + 0.2*sin(2*t), 0, 0.5], stiffness: k, damping: c,
       rest_length: 0.3}
)"),
                                         "forces_of_t.yaml");
  EXPECT_GT(expect_time_column_matches(sc, 4, 1e-7), 1e-2);
}

// A mass of t in the definitions (∂M/∂t q̈, the (∂M/∂t) q̇ term's own ∂/∂t and ∂G/∂t), with a
// `coordinate` row holding th2 so that the constraint force depends on it too.
TEST(TimeDerivatives, MassOfTimeMatchesDifferences) {
  const Scenario free = load_scenario_text(
      double_pendulum("mass_of_t", "m2*(1 + 0.3*sin(4*t))", ""), "mass_of_t.yaml");
  ASSERT_TRUE(free.system->subsystems()[0]->time_varying());
  EXPECT_GT(expect_time_column_matches(free, 4, 1e-7), 1e-2);
  const Scenario held = load_scenario_text(
      double_pendulum("mass_of_t_held", "m2*(1 + 0.3*sin(4*t))",
                      "constraints:\n  - {type: coordinate, name: hold, coordinate: th2}\n"),
      "mass_of_t_held.yaml");
  EXPECT_GT(expect_time_column_matches(held, 4, 1e-7), 1e-2);
}

// Nothing depends on t: ∂q̈/∂t, ∂Qc/∂t and ∂μ/∂t exactly 0 (trees welded to a free body, numeric
// frame rows; and the definitions pendulum), at a moving state.
TEST(TimeDerivatives, TimeIndependentSystemsGiveExactZero) {
  const auto expect_zero = [](const Scenario& sc) {
    const test::State s = test::moving_state(sc);
    const Linearization lin = linearize(*sc.system, 0.37, s.q, s.qd, s.tau, sc.sim.uk);
    ASSERT_EQ(lin.dqdd_dt.size(), sc.system->dof()) << lin.time_message;
    EXPECT_EQ(lin.dqdd_dt.cwiseAbs().maxCoeff(), 0.0) << sc.name;
    EXPECT_EQ(lin.dQc_dt.cwiseAbs().maxCoeff(), 0.0) << sc.name;
    if (lin.dmu_dt.size() > 0) {
      EXPECT_EQ(lin.dmu_dt.cwiseAbs().maxCoeff(), 0.0) << sc.name;
    }
  };
  expect_zero(load_scenario(kSource / "scenarios" / "n_robots_3_weld.yaml"));
  expect_zero(load_scenario_text(double_pendulum("pendulum", "m2", ""), "pendulum.yaml"));
}

namespace {

// scenarios/n_robots_3_weld.yaml with the load's z on a cosine of t (a `coordinate` row on the
// free body alone), its initial state off that row (initial_tolerance: 1, see double_pendulum()).
Scenario lifted_load() {
  std::ifstream in(kSource / "scenarios" / "n_robots_3_weld.yaml");
  std::stringstream text;
  text << in.rdbuf();
  std::string yaml = text.str();
  const std::string anchor = "initial:\n";
  const auto at = yaml.find(anchor);
  EXPECT_NE(at, std::string::npos);
  yaml.insert(at,
              "  - {type: coordinate, name: lift, coordinate: load_z, value: {type: cosine, mean: "
              "0, amplitude: 0.05, omega: 3}}\n");
  const std::string sim = "simulation:\n";  // the state off the lift row: see double_pendulum()
  const auto st = yaml.find(sim);
  EXPECT_NE(st, std::string::npos);
  yaml.insert(st + sim.size(), "  initial_tolerance: 1\n");
  return load_scenario_text(yaml, "n_robots_3_weld_lift.yaml");
}

}  // namespace

// The time column from the three solves of the one KKT system: the arrow blocks (three robots
// welded to a free-body load, the load's z on a cosine of t: a row on the load alone), the Schur
// complement and the dense LU (the reference), with every other part of the linearisation; and
// the arrow one against differences.
TEST(TimeDerivatives, ArrowSchurAndDenseSolvesAgree) {
  const Scenario sc = lifted_load();
  const System& sys = *sc.system;
  const test::State s = test::moving_state(sc);
  const double t = 0.4;
  LinearizeData arrow(sys), schur(sys), dense(sys);
  dense.allow_arrow = false;
  schur.allow_arrow = true;
  linearize(sys, arrow, t, s.q, s.qd, s.tau, sc.sim.uk);
  linearize(sys, dense, t, s.q, s.qd, s.tau, sc.sim.uk);
  EXPECT_TRUE(arrow.used_arrow);
  EXPECT_FALSE(dense.used_arrow);
  EXPECT_FALSE(dense.used_schur);
  // Schur: the dense row choice with the Schur solve (no arrow blocks).
  schur.arrow = ArrowKktWorkspace();
  linearize(sys, schur, t, s.q, s.qd, s.tau, sc.sim.uk);
  EXPECT_FALSE(schur.used_arrow);
  EXPECT_TRUE(schur.used_schur);
  const auto rel = [](const Vec& a, const Vec& b) {
    return (a - b).cwiseAbs().maxCoeff() / (1.0 + b.cwiseAbs().maxCoeff());
  };
  for (const LinearizeData* d : {&arrow, &schur}) {
    ASSERT_EQ(d->lin.dqdd_dt.size(), sys.dof()) << d->lin.time_message;
    EXPECT_LE(rel(d->lin.dqdd_dt, dense.lin.dqdd_dt), 1e-9);
    EXPECT_LE(rel(d->lin.dQc_dt, dense.lin.dQc_dt), 1e-9);
    EXPECT_LE(rel(d->lin.dmu_dt, dense.lin.dmu_dt), 1e-9);
    test::expect_same_linearization(d->lin, dense.lin, 1e-9);
  }
  const TimeDifferences c = time_differences(sc, t, s.q, s.qd, s.tau);
  EXPECT_GT(c.qdd.cwiseAbs().maxCoeff(), 1e-2);
  EXPECT_LE(rel_error(arrow.lin.dqdd_dt, c.qdd), 1e-7);
  EXPECT_LE(rel_error(arrow.lin.dQc_dt, c.Qc), 1e-7);
}

namespace {

// A constraint with exact state tangents but no time tangent (the default): th2 = 0.3 sin t, its
// A constant and b = −0.3 sin t.
class NoTimeTangent final : public Constraint {
 public:
  [[nodiscard]] Index rows() const override { return 1; }
  [[nodiscard]] const std::vector<std::string>& row_names() const override { return names_; }
  void evaluate(const ConstraintContext& c, CVecRef, CVecRef, MatRef A, VecRef b) const override {
    zero_rows(A);
    A(0, 1) = 1.0;
    b(0) = -0.3 * std::sin(c.t);
  }
  void position_residual(const ConstraintContext& c, CVecRef q, VecRef phi) const override {
    phi(0) = q(1) - 0.3 * std::sin(c.t);
  }
  void velocity_residual(const ConstraintContext& c, CVecRef, CVecRef qd,
                         VecRef phid) const override {
    phid(0) = qd(1) - 0.3 * std::cos(c.t);
  }
  [[nodiscard]] bool has_derivatives() const override { return true; }
  bool tangent(const ConstraintContext&, CVecRef, CVecRef, CVecRef, CVecRef, CVecRef, CVecRef,
               VecRef d_residual, VecRef) const override {
    d_residual.setZero();
    return true;
  }

 private:
  std::vector<std::string> names_{"no_time"};
};

}  // namespace

// Without an exact ∂/∂t of one component the time column is refused (empty, time_message naming
// it) and everything else is given as before; with LinearizeParts::time off, it is not computed.
TEST(TimeDerivatives, ComponentWithoutTimeTangentRefusesTheTimeColumnOnly) {
  const Scenario sc =
      load_scenario_text(double_pendulum("pendulum_no_time", "m2", ""), "pendulum.yaml");
  System sys;
  sys.add_subsystem(sc.system->subsystems()[0]);
  sys.add_constraint(std::make_shared<NoTimeTangent>());
  const Vec q = sc.q0, qd = sc.qd0, tau = Vec::Zero(2);
  LinearizeData d(sys);
  linearize(sys, d, 0.2, q, qd, tau);
  EXPECT_TRUE(d.lin.trusted) << d.lin.message;
  EXPECT_EQ(d.lin.dqdd_dt.size(), 0);
  EXPECT_EQ(d.lin.dQc_dt.size(), 0);
  EXPECT_NE(d.lin.time_message.find("no exact d/dt for constraint of row 'no_time'"),
            std::string::npos)
      << d.lin.time_message;
  EXPECT_EQ(d.lin.dqdd_dq.rows(), 2);
  EXPECT_EQ(d.lin.dqdd_dtau.rows(), 2);
  LinearizeParts parts;
  parts.time = false;
  LinearizeData plain(*sc.system);
  linearize(*sc.system, plain, 0.2, q, qd, tau, {}, parts);
  EXPECT_EQ(plain.lin.dqdd_dt.size(), 0);
  EXPECT_TRUE(plain.lin.time_message.empty());
}

#ifdef UKDYN_CLI
// `ukdyn linearize`: the JSON's derivatives.dqdd_dt and dQc_dt are the library's (the shortest
// round-trip decimals: the same doubles), with an empty time_message.
TEST(LinearizeCli, TheJsonHoldsTheTimeColumn) {
  const std::filesystem::path scratch = ukdyn_test::process_scratch("ukdyn_time_column");
  const std::filesystem::path scen = kSource / "scenarios" / "paper.yaml";
  const auto r =
      ukdyn_test::run_cli(UKDYN_CLI, scratch, "linearize " + ukdyn_test::sh(scen.string()));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(r.out)["derivatives"];
  const Scenario sc = load_scenario(scen);
  const Linearization lin = linearize(*sc.system, sc.sim.t0, sc.q0, sc.qd0, sc.tau, sc.sim.uk);
  ASSERT_EQ(j["dqdd_dt"].size(), static_cast<std::size_t>(sc.system->dof()));
  for (Index i = 0; i < sc.system->dof(); ++i) {
    EXPECT_EQ(j["dqdd_dt"][static_cast<std::size_t>(i)].get<double>(), lin.dqdd_dt(i)) << i;
    EXPECT_EQ(j["dQc_dt"][static_cast<std::size_t>(i)].get<double>(), lin.dQc_dt(i)) << i;
  }
  EXPECT_EQ(j["time_message"].get<std::string>(), "");
}
#endif

namespace {

// A constraint that forwards everything, derivatives included, to `inner` but declares no
// sparsity (row_columns() empty).
class Undeclared final : public Constraint {
 public:
  explicit Undeclared(std::shared_ptr<const Constraint> inner) : inner_(std::move(inner)) {}
  [[nodiscard]] Index rows() const override { return inner_->rows(); }
  [[nodiscard]] const std::vector<std::string>& row_names() const override {
    return inner_->row_names();
  }
  [[nodiscard]] Index slot_size() const override { return inner_->slot_size(); }
  void evaluate(const ConstraintContext& c, CVecRef q, CVecRef qd, MatRef A,
                VecRef b) const override {
    inner_->evaluate(c, q, qd, A, b);
  }
  void position_residual(const ConstraintContext& c, CVecRef q, VecRef phi) const override {
    inner_->position_residual(c, q, phi);
  }
  void velocity_residual(const ConstraintContext& c, CVecRef q, CVecRef qd,
                         VecRef phid) const override {
    inner_->velocity_residual(c, q, qd, phid);
  }
  [[nodiscard]] bool has_derivatives() const override { return inner_->has_derivatives(); }
  bool tangent(const ConstraintContext& c, CVecRef q, CVecRef qd, CVecRef qdd, CVecRef lambda,
               CVecRef dq, CVecRef dqd, VecRef d_residual, VecRef d_force) const override {
    return inner_->tangent(c, q, qd, qdd, lambda, dq, dqd, d_residual, d_force);
  }
  bool time_tangent(const ConstraintContext& c, CVecRef q, CVecRef qd, CVecRef qdd, CVecRef lambda,
                    VecRef d_residual, VecRef d_force) const override {
    return inner_->time_tangent(c, q, qd, qdd, lambda, d_residual, d_force);
  }

 private:
  std::shared_ptr<const Constraint> inner_;
};

}  // namespace

// The lifted load with its `lift` row declaring no sparsity: forward() augments the load's
// singular block with that row (it lies on the load alone at the state) but it is not one of the
// load's declared own rows, so the Schur solve, which augments its right-hand sides by the own
// rows, would lose its share of the multipliers (dQc_dt was 97 % off the differences, dQc_dq 0.9
// off the LU's): linearize() takes the LU there, and matches the differences.
TEST(TimeDerivatives, AnUndeclaredRowOnAFreeBodyKeepsTheLuSolve) {
  Scenario sc = lifted_load();
  auto twin = std::make_shared<System>();
  for (const auto& sub : sc.system->subsystems()) twin->add_subsystem(sub);
  for (const auto& con : sc.system->constraints()) {
    std::shared_ptr<const Constraint> c = con;
    if (con->row_names().front() == "lift") c = std::make_shared<Undeclared>(con);
    twin->add_constraint(c);
  }
  sc.system = twin;
  sc.sim.t0 = 0.4;  // (the differences of expect_columns_match_differences() are taken at t0)
  const test::State s = test::moving_state(sc);
  const double t = sc.sim.t0;
  LinearizeData d(*twin);
  linearize(*twin, d, t, s.q, s.qd, s.tau, sc.sim.uk);
  EXPECT_FALSE(d.used_arrow);
  EXPECT_FALSE(d.used_schur);
  ASSERT_EQ(d.lin.dqdd_dt.size(), twin->dof()) << d.lin.time_message;
  const TimeDifferences c = time_differences(sc, t, s.q, s.qd, s.tau);
  EXPECT_LE(rel_error(d.lin.dqdd_dt, c.qdd), 1e-7);
  EXPECT_LE(rel_error(d.lin.dQc_dt, c.Qc), 1e-7);
  test::expect_columns_match_differences(sc, s, d.lin.dqdd_dq, d.lin.dqdd_dqd);
}

// The closed loop's time column (paper_control: the servo law's reference moves with t):
// d/dt q̈(t, q, q̇, τ(t, q, q̇)) = ∂q̈/∂t + ∂q̈/∂τ ∂τ/∂t against differences in t of forward() of
// the plant under the law's τ at each time (the law's own ∂τ/∂t is a difference quotient: 1e-6).
TEST(TimeDerivatives, ClosedLoopAddsTheLawsTimeDerivative) {
  const Scenario sc = load_scenario(kSource / "scenarios" / "paper_control.yaml");
  const auto run = make_control_run(sc);
  ASSERT_TRUE(run);
  const Vec q = run->q0, qd = run->qd0;
  const double t = 0.6;
  const ClosedLoopLinearization cl = closed_loop_linearization(sc, t, q, qd);
  ASSERT_EQ(cl.lin.dqdd_dt.size(), q.size()) << cl.lin.time_message;
  ForwardData fd(*run->plant);
  auto closed_qdd = [&](double at) {
    const Vec tau = law_derivatives(*run, at, q, qd).tau;
    forward(*run->plant, fd, at, q, qd, tau, sc.sim.uk);
    return Vec(fd.qdd);
  };
  auto central = [&](double h) { return Vec((closed_qdd(t + h) - closed_qdd(t - h)) / (2 * h)); };
  const Vec c = (4 * central(5e-4) - central(1e-3)) / 3;
  const Linearization plant = linearize(*run->plant, t, q, qd, cl.law.tau, sc.sim.uk);
  std::cout << "[ time ] paper_control closed loop: " << rel_error(cl.lin.dqdd_dt, c)
            << " (the plant's alone: " << rel_error(plant.dqdd_dt, c) << ")\n";
  EXPECT_GT(rel_error(plant.dqdd_dt, c), 1e-3);  // the law's share matters here
  EXPECT_LE(rel_error(cl.lin.dqdd_dt, c), 1e-6);
}

// linearize_parameters() with with_time carries the time column as linearize() does: against the
// differences of forward() in t and equal to linearize()'s; not asked for, it is not computed and
// time_message says so.
TEST(TimeDerivatives, ParameterLinearizationCarriesTheTimeColumn) {
  const Scenario sc = load_scenario(kSource / "scenarios" / "paper.yaml");
  const System& sys = *sc.system;
  const test::State s = test::moving_state(sc);
  const double t = 0.6;
  const Index n = sys.dof(), m = sys.rows();
  const std::vector<ModelParameterDerivative> dp = {
      {Mat::Zero(n, n), Vec::Zero(n), Mat::Zero(m, n), Vec::Zero(m)}};
  const ParameterLinearization pl =
      linearize_parameters(sys, t, s.q, s.qd, s.tau, dp, sc.sim.uk, true, true);
  ASSERT_EQ(pl.lin.dqdd_dt.size(), n) << pl.lin.time_message;
  EXPECT_TRUE(pl.lin.time_message.empty()) << pl.lin.time_message;
  EXPECT_EQ(pl.lin.dQc_dt.size(), n);
  EXPECT_EQ(pl.lin.dmu_dt.size(), pl.lin.rank);
  const TimeDifferences c = time_differences(sc, t, s.q, s.qd, s.tau);
  EXPECT_LE(rel_error(pl.lin.dqdd_dt, c.qdd), 1e-7);
  EXPECT_LE(rel_error(pl.lin.dQc_dt, c.Qc), 1e-7);
  EXPECT_GT(c.qdd.cwiseAbs().maxCoeff(), 1e-2);
  const Linearization lin = linearize(sys, t, s.q, s.qd, s.tau, sc.sim.uk);
  EXPECT_LE((pl.lin.dqdd_dt - lin.dqdd_dt).cwiseAbs().maxCoeff(),
            1e-12 * (1.0 + lin.dqdd_dt.cwiseAbs().maxCoeff()));
  EXPECT_LE(pl.dqdd_dp.cwiseAbs().maxCoeff(), 0.0);  // a zero parameter derivative
  // Not asked for (the default, what the run's variational equations take), or without the
  // state columns: empty, and time_message says so.
  for (const bool with_state : {true, false}) {
    const ParameterLinearization bare =
        linearize_parameters(sys, t, s.q, s.qd, s.tau, dp, sc.sim.uk, with_state);
    EXPECT_EQ(bare.lin.dqdd_dt.size(), 0);
    EXPECT_EQ(bare.lin.dQc_dt.size(), 0);
    EXPECT_NE(bare.lin.time_message.find("not computed"), std::string::npos);
    EXPECT_EQ(bare.lin.dqdd_dq.rows(), with_state ? n : 0);
  }
}

// The minimal model's D = ∂(A_R q̇ + Φ_t)/∂q = ½ ∂(A_R q̈ − b_R)/∂q̇ (exact, from the rows'
// tangents along q̇) against differences of the velocity residuals at random states, at rest and
// moving: the paper's cut-point trajectory rows (and its closure and `coordinate` rows), and a
// `coordinate` row of t (q_j = f(t): A constant, Φ_t = −ḟ(t) independent of q, so D = 0).
TEST(MinimalRheonomic, DMatchesDifferencesOnTrajectoryRows) {
  const Scenario paper = load_scenario(kSource / "scenarios" / "paper.yaml");
  EXPECT_GT(expect_minimal_d_matches(paper, 4, 1e-8), 1e-2);
  const Scenario coord = load_scenario_text(
      double_pendulum("coordinate_cosine", "m2",
                      "constraints:\n  - {type: coordinate, name: drive, coordinate: th2, value: "
                      "{type: cosine, mean: -0.3, amplitude: 0.4, omega: 2.5, phase: 0.3}}\n"),
      "coordinate.yaml");
  EXPECT_EQ(expect_minimal_d_matches(coord, 4, 1e-8), 0.0);
}

// A point mass in the x-y plane held on a circle of radius R whose centre goes round,
// c(t) = a (cos ωt, sin ωt): Φ = |p − c|² − R², A = 2 (p − c)ᵀ, Φ_t = −2 (p − c)·ċ, so
// D = ∂(A q̇ + Φ_t)/∂q = 2 (q̇ − ċ)ᵀ with ċ = a ω (−sin ωt, cos ωt), on or off the circle, at rest
// (D = −2 ċᵀ: the ∂Φ_t/∂q part alone) and moving; and x = T z keeps the linearised velocity
// constraint, [D, A_R] T = 0.
TEST(MinimalRheonomic, PointOnAMovingCircleHasTheClosedFormD) {
  const Scenario sc = load_scenario_text(R"(
ukdyn: 1
name: moving_circle
gravity: 9.81
subsystems:
  - name: point
    type: definitions
    coordinates: [x, y]
    parameters: {m: 1.3}
    bodies:
      - {name: p, mass: m, com: [x, y, 0]}
constraints:
  - type: expression
    name: circle
    parameters: {a: 0.4, w: 1.7, R: 0.9}
    rows: {r: (x - a*cos(w*t))^2 + (y - a*sin(w*t))^2 - R^2}
initial:
  q: [1.3, 0]
  qd: [0, 0.5]
simulation: {t_end: 1, sample_dt: 0.01, initial_tolerance: 1}
)",
                                         "moving_circle.yaml");
  const System& sys = *sc.system;
  const double a = 0.4, w = 1.7;
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int k = 0; k < 6; ++k) {
    const double t = 2.0 * u(rng);
    Vec q(2), qd(2), tau = Vec::Zero(2);
    q << 1.3 + 0.2 * u(rng), 0.3 * u(rng);
    qd << (k == 0 ? 0.0 : u(rng)), (k == 0 ? 0.0 : u(rng));
    const Linearization lin = linearize(sys, t, q, qd, tau, sc.sim.uk);
    const MinimalModel mm = minimal_model(sys, t, q, qd, tau, lin);
    Vec cdot(2);
    cdot << -a * w * std::sin(w * t), a * w * std::cos(w * t);
    const Vec expect = 2.0 * (qd - cdot);
    ASSERT_EQ(mm.D.rows(), 1);
    EXPECT_LE((mm.D.transpose() - expect).cwiseAbs().maxCoeff(), 1e-14 * (1.0 + expect.norm()))
        << "t " << t << " state " << k;
    EXPECT_TRUE(mm.rheonomic);
    Mat DA(1, 4);
    DA << mm.D, mm.AR;
    EXPECT_LE((DA * mm.T).cwiseAbs().maxCoeff(), 1e-13);
  }
}
