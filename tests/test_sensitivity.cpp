// Sensitivities to the numbers of a scenario file (ukdyn/run/sensitivity.hpp, docs/derivatives.md,
// "Sensitivities to parameters"), against independent evidence: central differences of forward()
// on the scenario text edited here by hand (not through the parameter paths), closed forms
// (q̈ is linear in g at rest; q̈ and Qc are homogeneous of degrees 0 and 1 in the masses), and
// differences of whole runs of simulate() for the variational equations.
#include <gtest/gtest.h>

#include <array>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>

#include "ukdyn/run/sensitivity.hpp"
#include "ukdyn/scenario/scenario.hpp"

namespace {

using namespace ukdyn;
const std::filesystem::path kSource = UKDYN_SOURCE_DIR;

std::string read_text(const std::filesystem::path& p) {
  std::ifstream f(p);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

// The scenario's text with every `before value after` (at least one) written with v in place of
// value: a parameter the file writes in several places changes in all of them.
std::string with_value(const std::string& text, const std::string& before, double value,
                       const std::string& after, double v, const std::string& written = "") {
  auto shortest = [](double x) {  // the shortest text that reads back as x ("0.4", not 0.400…02)
    std::array<char, 32> buf{};
    const auto r = std::to_chars(buf.data(), buf.data() + buf.size(), x);
    return std::string(buf.data(), r.ptr);
  };
  const std::string o = before + (written.empty() ? shortest(value) : written) + after;
  const std::string n = before + shortest(v) + after;
  std::string out = text;
  std::size_t count = 0;
  for (auto at = out.find(o); at != std::string::npos; at = out.find(o, at + n.size())) {
    out.replace(at, o.size(), n);
    ++count;
  }
  EXPECT_GT(count, 0u) << o;
  return out;
}

struct Edit {
  std::string name;  // the parameter as ukdyn is asked for it
  std::string before;
  double value;
  std::string after;
  std::string written = "";  // the value as the file writes it, if not its shortest form
};

Scenario load_edited(const std::filesystem::path& path, const std::string& text) {
  LoadOptions opt;
  opt.check_initial = false;
  return load_scenario_text(text, path, opt);
}

// q̈ and Qc stacked (2n) at the state for the scenario text.
Vec qdd_qc(const Scenario& sc, double t, const Vec& q, const Vec& qd, const Vec& tau) {
  ForwardData d(*sc.system);
  forward(*sc.system, d, t, q, qd, tau, sc.sim.uk);
  Vec out(2 * q.size());
  out << d.qdd, d.Qc;
  return out;
}

double rel(const Mat& a, const Mat& b) {
  return (a - b).cwiseAbs().maxCoeff() / b.cwiseAbs().maxCoeff();
}

// Compares ∂q̈/∂p, ∂Qc/∂p with Richardson-extrapolated central differences of forward() on the
// hand-edited text (steps 2e-3 |p| and 1e-3 |p|, other than the ones ukdyn takes), at (q0, q̇, τ)
// with a nonzero torque and a nonzero velocity (moving) or none (redundant rows stay consistent
// only with a velocity along the constraints). An edit named "A+B" is compared with the sum of
// the columns of A and B (a number an alias repeats, edited in the text once, asked by its
// paths). Returns the worst relative difference.
double state_check(const std::string& file, const std::vector<Edit>& edits, bool moving = true) {
  const auto path = kSource / "scenarios" / file;
  const std::string text = read_text(path);
  const Scenario sc = load_scenario(path);
  const Index n = sc.system->dof();
  Vec qd(n), tau(n);
  for (Index i = 0; i < n; ++i) {
    qd(i) = moving ? 0.2 * std::cos(0.9 * static_cast<double>(i) + 0.3) : 0.0;
    tau(i) = 0.3 * std::sin(1.7 * static_cast<double>(i) + 0.4);
  }
  const double t = sc.sim.t0 + 0.3;
  std::vector<std::string> names;
  std::vector<std::vector<Index>> columns;  // per edit, the parameters summed
  for (const auto& e : edits) {
    columns.emplace_back();
    std::stringstream parts(e.name);
    for (std::string part; std::getline(parts, part, '+');) {
      columns.back().push_back(static_cast<Index>(names.size()));
      names.push_back(part);
    }
  }
  const auto ps = scenario_parameters(sc, names);
  const ParameterLinearization pl = state_sensitivities(sc, ps, t, sc.q0, qd, tau);
  EXPECT_TRUE(pl.lin.trusted) << pl.lin.message;
  double worst = 0.0;
  for (std::size_t j = 0; j < edits.size(); ++j) {
    const Edit& e = edits[j];
    auto at = [&](double h) {
      return qdd_qc(
          load_edited(path, with_value(text, e.before, e.value, e.after, e.value + h, e.written)),
          t, sc.q0, qd, tau);
    };
    auto central = [&](double h) { return Vec((at(h) - at(-h)) / (2 * h)); };
    const double h = 2e-3 * std::abs(e.value);
    const Vec fd = (4 * central(h / 2) - central(h)) / 3;
    Vec ours = Vec::Zero(2 * n);
    for (Index c : columns[j]) {
      ours.head(n) += pl.dqdd_dp.col(c);
      ours.tail(n) += pl.dQc_dp.col(c);
    }
    const double r = rel(ours, fd);
    std::cout << "[ sensitivity ] " << file << " " << e.name << ": max |d(qdd, Qc)/dp| "
              << fd.cwiseAbs().maxCoeff() << ", relative difference to forward() differences " << r
              << "\n";
    EXPECT_LT(r, 1e-6) << file << " " << e.name;
    worst = std::max(worst, r);
  }
  return worst;
}

}  // namespace

TEST(ParameterSensitivity, StateMatchesDifferencesOfForwardOnEditedFiles) {
  // Definitions (derived, tapes), 2 closure rows.
  state_check("five_bar_redundant.yaml", {{"m1", "m1: ", 1.0, ",", "1.0"},
                                          {"l2", "l2: ", 0.4, ","},
                                          {"gravity", "gravity: ", 9.81, "\n"}});
  // The paper's system by definitions (12 rows, rank 12) and in closed form.
  state_check("paper_generic.yaml", {{"m2", "m2: ", 4, "\n"}, {"l2", "l2: ", 0.8, ""}});
  state_check("paper.yaml",
              {{"platform_mass", "platform_mass: ", 50, "\n"},
               {"subsystems[left].params.link_length[1]+subsystems[right].params.link_length[1]",
                "link_length: [0.7, ", 0.8, ", 0.4]"}});
  // Bricard's mechanism: a serial chain on the tree algorithms, 5 rows of rank 4 (redundant).
  state_check("benchmarks/bricard.yaml",
              {{"m", "m: ", 1, "\n"}, {"subsystems[chain].gravity[1]", "[0, ", -9.81, ", 0]"}},
              false);
}

TEST(ParameterSensitivity, ClosedFormsGravityAndMassScaling) {
  // five_bar at rest, τ = 0, scleronomic rows: q̈ and Qc are linear in g (∂/∂g = value / g); the
  // kinetic and potential energies scale with the masses, so q̈ is homogeneous of degree 0 and Qc
  // of degree 1 in (m1, m2): m1 ∂/∂m1 + m2 ∂/∂m2 gives 0 and Qc (Euler's theorem).
  const Scenario sc = load_scenario(kSource / "scenarios" / "five_bar_redundant.yaml");
  const Index n = sc.system->dof();
  const auto ps = scenario_parameters(sc, {"gravity", "m1", "m2"});
  const auto pl = state_sensitivities(sc, ps, 0.0, sc.q0, sc.qd0, Vec::Zero(n));
  const Vec& qdd = pl.lin.qdd;
  const Vec& Qc = pl.lin.Qc;
  EXPECT_LT((pl.dqdd_dp.col(0) - qdd / 9.81).cwiseAbs().maxCoeff(),
            1e-9 * qdd.cwiseAbs().maxCoeff());
  EXPECT_LT((pl.dQc_dp.col(0) - Qc / 9.81).cwiseAbs().maxCoeff(), 1e-9 * Qc.cwiseAbs().maxCoeff());
  const Vec euler_qdd = 1.0 * pl.dqdd_dp.col(1) + 0.8 * pl.dqdd_dp.col(2);
  const Vec euler_Qc = 1.0 * pl.dQc_dp.col(1) + 0.8 * pl.dQc_dp.col(2);
  EXPECT_LT(euler_qdd.cwiseAbs().maxCoeff(), 1e-9 * qdd.cwiseAbs().maxCoeff());
  EXPECT_LT((euler_Qc - Qc).cwiseAbs().maxCoeff(), 1e-9 * Qc.cwiseAbs().maxCoeff());

  // A torque of forces.tau as a parameter: its column is the exact ∂q̈/∂τ_j and ∂Qc/∂τ_j of
  // linearize() (the state columns, another formulation), at a moving state.
  const auto pt = scenario_parameters(sc, {"forces.tau[1]"});
  Vec qd(n);
  qd << 0.1, -0.2, 0.3, 0.05;
  const auto lt = state_sensitivities(sc, pt, 0.2, sc.q0, qd, sc.tau, true);
  const double r_tau = (lt.dqdd_dp.col(0) - lt.lin.dqdd_dtau.col(1)).cwiseAbs().maxCoeff() /
                       lt.lin.dqdd_dtau.col(1).cwiseAbs().maxCoeff();
  const double r_tau_qc = (lt.dQc_dp.col(0) - lt.lin.dQc_dtau.col(1)).cwiseAbs().maxCoeff() /
                          lt.lin.dQc_dtau.col(1).cwiseAbs().maxCoeff();
  std::cout << "[ sensitivity ] five_bar forces.tau[1] against dqdd_dtau, dQc_dtau: " << r_tau
            << ", " << r_tau_qc << "\n";
  EXPECT_LT(r_tau, 1e-9);
  EXPECT_LT(r_tau_qc, 1e-9);

  // Bricard (redundant rows): every rod has mass m and inertias ∝ m, so ∂q̈/∂m = 0 and
  // m ∂Qc/∂m = Qc, with a velocity.
  const Scenario br = load_scenario(kSource / "scenarios" / "benchmarks" / "bricard.yaml");
  const auto pb = scenario_parameters(br, {"m"});
  const Vec rest = Vec::Zero(br.system->dof());
  const auto lb = state_sensitivities(br, pb, 0.0, br.q0, rest, rest);
  EXPECT_LT(lb.lin.rank, br.system->rows());
  EXPECT_LT(lb.dqdd_dp.cwiseAbs().maxCoeff(), 1e-9 * lb.lin.qdd.cwiseAbs().maxCoeff());
  EXPECT_LT((lb.dQc_dp.col(0) - lb.lin.Qc).cwiseAbs().maxCoeff(),
            1e-9 * lb.lin.Qc.cwiseAbs().maxCoeff());
}

namespace {

// The scenario file with t_end set, written to a temporary file (scenario_parameters re-reads it).
std::filesystem::path with_t_end(const std::string& file, const std::string& t_end_was,
                                 double t_end, std::string& text) {
  text =
      with_value(read_text(kSource / "scenarios" / file), "t_end: ", 0.0, "\n", t_end, t_end_was);
  const auto tmp =
      std::filesystem::path(testing::TempDir()) /
      ("sens_" + std::to_string(t_end) + "_" + std::filesystem::path(file).filename().string());
  std::ofstream(tmp) << text;
  return tmp;
}

// dq/dp of a run by the variational equations against Richardson-extrapolated central differences
// of four whole simulate() runs on the hand-edited file (steps h and h/2, no drift control,
// tolerance 1e-14), over every sample: the worst relative difference.
RunSensitivities run_check(const std::filesystem::path& tmp, const std::string& text,
                           const std::vector<Edit>& edits, double h_rel) {
  const Scenario sc = load_scenario(tmp);
  std::vector<std::string> names;
  for (const auto& e : edits) names.push_back(e.name);
  const RunSensitivities rs = run_sensitivities(sc, scenario_parameters(sc, names));
  const auto T = static_cast<Index>(rs.t.size());
  EXPECT_EQ(rs.t.back(), sc.sim.t_end) << rs.message;
  for (std::size_t j = 0; j < edits.size(); ++j) {
    const Edit& e = edits[j];
    auto run = [&](double h) {
      const Scenario s =
          load_edited(tmp, with_value(text, e.before, e.value, e.after, e.value + h, e.written));
      SimulationSettings set = s.sim;
      set.drift.kind = DriftControl::none;
      set.abs_tol = set.rel_tol = 1e-14;
      Mat q(T, s.system->dof());
      Index k = 0;
      const Vec tau = s.tau;
      simulate(
          *s.system, s.q0, s.qd0, [&](double, CVecRef, CVecRef, VecRef out) { out = tau; }, set,
          [&](double, CVecRef qk, CVecRef, const ForwardData&) {
            if (k < q.rows()) q.row(k++) = qk.transpose();
            return true;
          });
      EXPECT_EQ(k, T);
      return q;
    };
    const double h = h_rel * std::abs(e.value);
    const Mat d1 = (run(h) - run(-h)) / (2 * h), d2 = (run(h / 2) - run(-h / 2)) / h;
    const Mat fd = (4 * d2 - d1) / 3;
    const double r = rel(rs.dq_dp[j], fd);
    std::cout << "[ sensitivity ] " << tmp.filename().string() << " run to t = " << rs.t.back()
              << ", " << e.name << ": max |dq/dp| " << fd.cwiseAbs().maxCoeff()
              << ", relative difference to whole-run differences " << r << "; steps " << rs.steps
              << ", rhs evaluations " << rs.rhs_evaluations << "\n";
    EXPECT_LT(r, 1e-6) << e.name;
  }
  return rs;
}

}  // namespace

TEST(ParameterSensitivity, RunMatchesDifferencesOfWholeRuns) {
  // Bricard's mechanism (redundant rows) for 2 s, the five-bar for 1 s (after 1.5 s its motion
  // amplifies every error: differences of whole runs no longer converge there, see the closed
  // forms below).
  std::string text;
  const auto bricard = with_t_end("benchmarks/bricard.yaml", "10", 2.0, text);
  run_check(bricard, text, {{"subsystems[chain].gravity[1]", "[0, ", -9.81, ", 0]"}}, 1e-3);
  const auto five_bar = with_t_end("five_bar_redundant.yaml", "3", 1.0, text);
  const auto rs =
      run_check(five_bar, text, {{"m1", "m1: ", 1.0, ",", "1.0"}, {"l2", "l2: ", 0.4, ","}}, 1e-3);
  // l2 moves the closure away from the file's q0 (m1 does not): said, once, by name.
  ASSERT_EQ(rs.warnings.size(), 1u);
  EXPECT_NE(rs.warnings[0].find("parameter 'l2' moves the constraints"), std::string::npos);
}

TEST(ParameterSensitivity, RunClosedFormsTimeScalingAndMassScaling) {
  // The five-bar released at rest under gravity alone (τ = 0, scleronomic rows) for 2 s: the
  // motion at gravity g is the one at g0 run faster, q(t; g) = q(t √(g/g0); g0), so
  // dq/dg = q̇ t / (2 g); and it does not change when every mass scales, so
  // m1 dq/dm1 + m2 dq/dm2 = 0 at every sample.
  std::string text;
  const auto tmp = with_t_end("five_bar_redundant.yaml", "3", 2.0, text);
  const Scenario sc = load_scenario(tmp);
  const RunSensitivities rs =
      run_sensitivities(sc, scenario_parameters(sc, {"gravity", "m1", "m2"}));
  ASSERT_EQ(rs.t.size(), 201u);
  Mat scaling(rs.q.rows(), rs.q.cols());
  for (Index k = 0; k < rs.q.rows(); ++k)
    scaling.row(k) = rs.qd.row(k) * rs.t[static_cast<std::size_t>(k)] / (2 * 9.81);
  const double r_time = rel(rs.dq_dp[0], scaling);
  const double r_mass = (1.0 * rs.dq_dp[1] + 0.8 * rs.dq_dp[2]).cwiseAbs().maxCoeff() /
                        rs.dq_dp[1].cwiseAbs().maxCoeff();
  std::cout << "[ sensitivity ] five_bar 2 s run: dq/dg against q' t / 2g " << r_time
            << ", m1 dq/dm1 + m2 dq/dm2 (relative to max |dq/dm1|) " << r_mass << "\n";
  EXPECT_LT(r_time, 1e-6);
  EXPECT_LT(r_mass, 1e-6);
  // The masses do not move the closure, so the perturbed motions stay on it: Φ(q(t; m1)) = 0
  // gives A(q) dq/dm1 = 0 at every sample (an invariant the integration does not impose).
  ForwardData d(*sc.system);
  double worst = 0.0;
  for (Index k = 0; k < rs.q.rows(); ++k) {
    const Vec q = rs.q.row(k).transpose(), qd = rs.qd.row(k).transpose();
    forward(*sc.system, d, rs.t[static_cast<std::size_t>(k)], q, qd, sc.tau, sc.sim.uk);
    worst = std::max(worst, (d.A * rs.dq_dp[1].row(k).transpose()).cwiseAbs().maxCoeff());
  }
  const double r_manifold = worst / rs.dq_dp[1].cwiseAbs().maxCoeff();
  std::cout << "[ sensitivity ] five_bar 2 s run: max |A dq/dm1| / max |dq/dm1| " << r_manifold
            << "\n";
  EXPECT_LT(r_manifold, 1e-6);
}

TEST(ParameterSensitivity, RefusesWhatIsNotAParameterItUses) {
  const auto path = kSource / "scenarios" / "five_bar_redundant.yaml";
  const Scenario sc = load_scenario(path);
  auto message = [&](const std::vector<std::string>& names) {
    try {
      scenario_parameters(sc, names);
    } catch (const ScenarioError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  const std::string unknown = message({"m9"});
  EXPECT_NE(unknown.find("five_bar_redundant.yaml: parameter 'm9': no key 'm9'"), std::string::npos)
      << unknown;
  const std::string unused = message({"simulation.t_end"});
  EXPECT_NE(unused.find("five_bar_redundant.yaml:55: parameter 'simulation.t_end': the scenario's "
                        "dynamics does not use it"),
            std::string::npos)
      << unused;
  const std::string expression = message({"subsystems[left_arm].bodies[0].mass"});
  EXPECT_NE(expression.find("holds 'm1', not a number"), std::string::npos) << expression;
  EXPECT_NE(message({"m1", "m1"}).find("named twice"), std::string::npos);
  // One number named twice in two spellings (its key and a path through the alias to it): two
  // equal columns, refused as a name given twice.
  const std::string spelled_twice = message({"m1", "subsystems[left_arm].parameters.m1"});
  EXPECT_NE(spelled_twice.find("parameter 'subsystems[left_arm].parameters.m1': names the number "
                               "at 'subsystems[left_arm].parameters.m1', as parameter 'm1' does"),
            std::string::npos)
      << spelled_twice;
  // A name from the command line (not checked by the loader) as the list's are, and not quoted
  // whole: a 100 000-character name gives a short message.
  const std::string huge = message({std::string(100000, 'a')});
  EXPECT_NE(huge.find("a parameter is a key or a path: 1 to 200 characters"), std::string::npos)
      << huge.substr(0, 300);
  EXPECT_LT(huge.size(), 400u);
  EXPECT_NE(message({"m1*2"}).find("1 to 200 characters"), std::string::npos);
  // A number the file does not load with once moved: refused naming the parameter.
  const std::string version = message({"ukdyn"});
  EXPECT_NE(version.find("parameter 'ukdyn': the file does not load with it changed to 1.001"),
            std::string::npos)
      << version;

  // The same key written twice with different numbers: ambiguous, the paths named.
  std::string text = read_text(path);
  const std::string alias = "    parameters: *five_bar\n    let:\n      px: d + l1*cos(b1)";
  const auto at = text.find(alias);
  ASSERT_NE(at, std::string::npos);
  text.replace(at, alias.size(),
               "    parameters: {d: 0.25, l1: 0.3, l2: 0.4, m1: 1.5, m2: 0.8}\n    let:\n      px: "
               "d + l1*cos(b1)");
  const auto tmp = std::filesystem::path(testing::TempDir()) / "five_bar_two_maps.yaml";
  std::ofstream(tmp) << text;
  const Scenario two = load_scenario(tmp);
  try {
    scenario_parameters(two, {"m1"});
    ADD_FAILURE() << "no error";
  } catch (const ScenarioError& e) {
    EXPECT_NE(std::string(e.what()).find("names different numbers of the file "
                                         "(subsystems[left_arm].parameters.m1, "
                                         "subsystems[right_arm].parameters.m1"),
              std::string::npos)
        << e.what();
  }
  // A path names one place: the left arm's m1 alone is used, and differs from the shared m1.
  const auto left = scenario_parameters(two, {"subsystems[left_arm].parameters.m1"});
  EXPECT_EQ(left.front().paths.size(), 1u);

  // A controlled scenario: a gain is a parameter (the law's tau changes with it), a run setting
  // is still refused, saying what was compared (tests/test_control_sensitivity.cpp runs them).
  const Scenario ctl = load_scenario(kSource / "scenarios" / "paper_control.yaml");
  EXPECT_EQ(scenario_parameters(ctl, {"control.kappa"}).front().value, 5.0);
  try {
    scenario_parameters(ctl, {"simulation.sample_dt"});
    ADD_FAILURE() << "no error";
  } catch (const ScenarioError& e) {
    EXPECT_NE(std::string(e.what()).find("it changes none of M, Q, A, b, the control law's tau"),
              std::string::npos)
        << e.what();
  }
}
