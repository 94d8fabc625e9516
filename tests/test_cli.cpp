// The command-line tool on good and bad input: exit codes, messages naming file:line:key, no output
// that looks complete after a failure, and `eval` agreeing with the library.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "ukdyn/scenario/scenario.hpp"

#ifdef UKDYN_CLI

namespace {

namespace fs = std::filesystem;
const fs::path kSource = UKDYN_SOURCE_DIR;

struct Result {
  int exit_code = -1;
  std::string out, err;
};

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::ostringstream os;
  os << in.rdbuf();
  return os.str();
}

fs::path scratch() {
  static const fs::path dir = [] {
    auto d = fs::temp_directory_path() / ("ukdyn_cli_test_" + std::to_string(::getpid()));
    fs::create_directories(d);
    return d;
  }();
  return dir;
}

Result run(const std::string& args, const std::string& stdin_text = "",
           const std::string& prefix = "") {
  const fs::path in = scratch() / "stdin.txt", out = scratch() / "stdout.txt",
                 err = scratch() / "stderr.txt";
  std::ofstream(in) << stdin_text;
  const std::string cmd = prefix + std::string("'") + UKDYN_CLI + "' " + args + " < '" +
                          in.string() + "' > '" + out.string() + "' 2> '" + err.string() + "'";
  const int rc = std::system(cmd.c_str());
  Result r;
  r.exit_code = WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
  r.out = slurp(out);
  r.err = slurp(err);
  return r;
}

// Writes the paper scenario with one textual substitution (which must apply).
fs::path variant(const std::string& name, const std::string& from, const std::string& to) {
  std::string text = slurp(kSource / "scenarios" / "paper.yaml");
  const auto pos = text.find(from);
  EXPECT_NE(pos, std::string::npos) << "substitution not found: " << from;
  if (pos != std::string::npos) text.replace(pos, from.size(), to);
  const fs::path p = scratch() / (name + ".yaml");
  std::ofstream(p) << text;
  return p;
}

struct BadCase {
  const char* name;
  const char* from;
  const char* to;
  const char* expect_in_message;  // key or constraint that must be named
  bool check_line;                // the message must give the line of the substituted text
};

void PrintTo(const BadCase& c, std::ostream* os) { *os << c.name; }

// 1-based line of the first occurrence of `needle` in `text`.
int line_of(const std::string& text, const std::string& needle) {
  const auto pos = text.find(needle);
  return pos == std::string::npos
             ? 0
             : 1 + static_cast<int>(
                       std::count(text.begin(), text.begin() + static_cast<long>(pos), '\n'));
}

class BadInput : public ::testing::TestWithParam<BadCase> {};

TEST_P(BadInput, ClearErrorNonZeroExitNoOutput) {
  const BadCase& c = GetParam();
  const fs::path file = variant(c.name, c.from, c.to);
  const fs::path out = scratch() / (std::string("out_") + c.name);
  fs::remove_all(out);
  const Result r =
      run("simulate '" + file.string() + "' --out '" + out.string() + "' --no-figures");
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_NE(r.err.find(file.string()), std::string::npos) << r.err;
  EXPECT_NE(r.err.find(c.expect_in_message), std::string::npos) << r.err;
  if (c.check_line) {
    const int line = line_of(slurp(file), c.to);
    ASSERT_GT(line, 0);
    EXPECT_NE(r.err.find(file.string() + ":" + std::to_string(line) + ":"), std::string::npos)
        << r.err;
  }
  EXPECT_FALSE(fs::exists(out / "trajectory.csv"));
}

INSTANTIATE_TEST_SUITE_P(
    Scenario, BadInput,
    ::testing::Values(
        BadCase{"missing_t_end", "  t_end: 4\n", "", "simulation.t_end", false},
        BadCase{"mistyped_key", "  sample_dt: 0.01", "  sampel_dt: 0.01", "simulation.sampel_dt",
                true},
        BadCase{"short_link_mass", "link_mass: [3, 4, 1]", "link_mass: [3, 4]", "link_mass", true},
        BadCase{"not_a_number", "base_length: 0.5", "base_length: half", "base_length", true},
        BadCase{"negative_mass", "platform_mass: 50", "platform_mass: -50", "platform_mass", true},
        BadCase{"zero_length", "link_length: [0.7, 0.8, 0.4]", "link_length: [0.7, 0, 0.4]",
                "link_length[1]", true},
        BadCase{"short_q0", "q: [0, 0, 0, pi/2", "q: [0, 0, pi/2", "initial.q", false},
        BadCase{"q0_violates_closure", "1.6, 0, -pi", "1.7, 0, -pi", "closure_x", false},
        BadCase{"qd0_violates_closure", "qd: zeros", "qd: [1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]",
                "closure_x", false},
        BadCase{"unknown_arm", "arm: left", "arm: lefty", "no subsystem named 'lefty'", false},
        BadCase{"unknown_coordinate", "coordinate: dx2,", "coordinate: dx3,", "dx3", false},
        BadCase{"nan_tolerance", "abs_tol: 1e-13", "abs_tol: .nan", "simulation.abs_tol", true},
        BadCase{"negative_duration", "t_end: 4", "t_end: -4", "simulation.t_end", false},
        BadCase{"yaml_syntax", "name: paper", "name: [paper", "YAML syntax error", false},
        BadCase{"bad_integrator", "integrator: dopri5", "integrator: euler",
                "simulation.integrator", true},
        BadCase{"inf_in_tau", "tau: [0, 0,", "tau: [.inf, 0,", "forces.tau[0]", true}),
    [](const ::testing::TestParamInfo<BadCase>& i) { return std::string(i.param.name); });

TEST(Cli, MissingScenarioFileIsAnError) {
  const Result r = run("check /nonexistent/scenario.yaml");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("/nonexistent/scenario.yaml"), std::string::npos);
}

TEST(Cli, CheckAcceptsTheShippedScenarios) {
  for (const char* s : {"paper.yaml", "paper_free.yaml", "paper_free_spatial.yaml"}) {
    const Result r = run("check '" + (kSource / "scenarios" / s).string() + "'");
    EXPECT_EQ(r.exit_code, 0) << s << ": " << r.err;
  }
}

TEST(Cli, EvalAgreesWithTheLibraryAndReportsBadLines) {
  const fs::path paper = kSource / "scenarios" / "paper_free.yaml";
  const std::string good =
      R"({"t": 0.0, "q": [0,0,0,1.5707963267948966,-1.0471975511965976,0,1.6,0,-3.141592653589793,1.5707963267948966,-1.0471975511965976,0], "qd": [0,0,0,0,0,0,0,0,0,0,0,0]})";
  const std::string input = good + "\n" + R"({"q": [1, 2]})" + "\nnot json\n";
  const Result r = run("eval '" + paper.string() + "'", input);
  EXPECT_EQ(r.exit_code, 1);  // two bad lines
  std::istringstream lines(r.out);
  std::string l1, l2, l3;
  std::getline(lines, l1);
  std::getline(lines, l2);
  std::getline(lines, l3);
  const auto j = nlohmann::json::parse(l1);
  ASSERT_TRUE(j.contains("M"));
  EXPECT_EQ(j["M"].size(), 12u);
  EXPECT_EQ(j["A"].size(), 6u);
  EXPECT_EQ(j["rank"], 6);
  EXPECT_EQ(j["line"], 1);  // every answer names its input line
  // In-process reference.
  const ukdyn::Scenario sc = ukdyn::load_scenario(paper);
  ukdyn::ForwardData d(*sc.system);
  ukdyn::forward(*sc.system, d, 0.0, sc.q0, sc.qd0, sc.tau);
  for (int i = 0; i < 12; ++i) {
    EXPECT_NEAR(j["qdd"][static_cast<std::size_t>(i)].get<double>(), d.qdd(i),
                1e-12 * (1 + std::abs(d.qdd(i))));
    EXPECT_NEAR(j["Qc"][static_cast<std::size_t>(i)].get<double>(), d.Qc(i),
                1e-10 * (1 + std::abs(d.Qc(i))));
  }
  EXPECT_NE(nlohmann::json::parse(l2)["error"].get<std::string>().find("stdin:2"),
            std::string::npos);
  EXPECT_NE(nlohmann::json::parse(l3)["error"].get<std::string>().find("invalid JSON"),
            std::string::npos);
}

TEST(Cli, SimulateWritesCsvSummaryAndFigures) {
  const fs::path out = scratch() / "out_free";
  const Result r = run("simulate '" + (kSource / "scenarios" / "paper_free_spatial.yaml").string() +
                       "' --out '" + out.string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(fs::exists(out / "trajectory.csv"));
  EXPECT_FALSE(fs::exists(out / "trajectory.csv.part"));
  const auto summary = nlohmann::json::parse(slurp(out / "summary.json"));
  EXPECT_EQ(summary["status"], "complete");
  EXPECT_TRUE(fs::exists(out / "figures" / "residuals_closure.png"));
  EXPECT_TRUE(fs::exists(out / "figures" / "energy.png"));
}

// bdf's Jacobian in the summary and on the console (docs/derivatives.md, "Exact Jacobians in the
// implicit integrators"): the governor (spring-dampers, energy balance) runs with the exact one and
// the note on W; with Baumgarte's terms the difference quotients, and the reason, once.
TEST(Cli, BdfReportsWhichJacobianItUsed) {
  if (!ukdyn::bdf_available()) GTEST_SKIP() << "built without SUNDIALS CVODE";
  std::string text = slurp(kSource / "scenarios" / "benchmarks" / "flyball_governor.yaml");
  const auto at = text.find("  t_end: 10");
  ASSERT_NE(at, std::string::npos);
  text.replace(at, std::string("  t_end: 10").size(), "  t_end: 0.05");
  const fs::path exact = scratch() / "governor_short.yaml";
  std::ofstream(exact) << text;
  const fs::path out = scratch() / "out_governor_jac";
  const Result r =
      run("simulate '" + exact.string() + "' --out '" + out.string() + "' --no-figures");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto summary = nlohmann::json::parse(slurp(out / "summary.json"));
  EXPECT_EQ(summary["jacobian"]["kind"], "exact");
  EXPECT_GT(summary["jacobian"]["evaluations"].get<long>(), 0);
  EXPECT_EQ(summary["jacobian"]["fallbacks"].get<long>(), 0);
  EXPECT_NE(summary["jacobian"]["note"].get<std::string>().find("quadrature"), std::string::npos);
  EXPECT_NE(r.out.find("jacobian            exact ("), std::string::npos) << r.out;

  text.replace(text.find("  integrator: bdf"), std::string("  integrator: bdf").size(),
               "  integrator: bdf\n  drift: {method: baumgarte}");
  const fs::path baum = scratch() / "governor_baumgarte.yaml";
  std::ofstream(baum) << text;
  const fs::path out2 = scratch() / "out_governor_baum";
  const Result b =
      run("simulate '" + baum.string() + "' --out '" + out2.string() + "' --no-figures");
  ASSERT_EQ(b.exit_code, 0) << b.err;
  const auto s2 = nlohmann::json::parse(slurp(out2 / "summary.json"));
  EXPECT_EQ(s2["jacobian"]["kind"], "difference");
  EXPECT_NE(s2["jacobian"]["note"].get<std::string>().find("Baumgarte"), std::string::npos);
  EXPECT_NE(b.out.find("jacobian            difference ("), std::string::npos) << b.out;
}

TEST(Cli, InterruptKeepsWhatWasComputedAndSaysSo) {
  // A long fixed-step run interrupted after 2 s: exit 1, the rows so far in
  // trajectory.incomplete.csv, summary.json "incomplete" with the reason, no trajectory.csv.
  const fs::path file = variant("long_run", "  t_end: 4\n", "  t_end: 100000\n");
  std::string text = slurp(file);
  text.replace(text.find("integrator: dopri5"), 18, "integrator: rk4\n  step: 1e-4");
  std::ofstream(file) << text;
  const fs::path out = scratch() / "out_interrupted";
  fs::remove_all(out);
  const Result r = run("simulate '" + file.string() + "' --out '" + out.string() + "' --no-figures",
                       "", "timeout --preserve-status -s INT 2 ");
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_FALSE(fs::exists(out / "trajectory.csv"));
  ASSERT_TRUE(fs::exists(out / "trajectory.incomplete.csv"));
  std::ifstream in(out / "trajectory.incomplete.csv");
  long lines = 0;
  for (std::string l; std::getline(in, l);) ++lines;
  EXPECT_GT(lines, 2);
  const auto summary = nlohmann::json::parse(slurp(out / "summary.json"));
  EXPECT_EQ(summary["status"], "incomplete");
  EXPECT_NE(summary["stop_reason"].get<std::string>().find("interrupted"), std::string::npos);
  EXPECT_EQ(summary["samples"].get<long>(), lines - 1);
}

}  // namespace

#endif  // UKDYN_CLI
