// `ukdyn size` (docs/sizing.md): the choice against a closed form (a link held still by a servo
// row: u = −m g l, τ_m = |u| / (n η), so a candidate holds iff |u| / (n η) ≤ (1 − margin) T_ref);
// a gearbox limit that no candidate meets (found false, the shortfall); on the shipped example, the
// chosen motors re-run independently (the sample written out as text by the sweep's --extract path,
// the candidate's motor block written from the catalogue by this test) keep the margin at every
// output sample, and the next smaller candidate of each actuator leaves it at the reported sample
// and time; bad catalogue and sizing files named by file:line:key; the CLI's exit codes.
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>

#include "cli_run.hpp"
#include "ukdyn/run/run.hpp"
#include "ukdyn/scenario/scenario_file.hpp"
#include "ukdyn/sweep/sizing.hpp"

namespace {

namespace fs = std::filesystem;
using ukdyn_test::ScratchDir;

const fs::path kSource = UKDYN_SOURCE_DIR;

void write(const fs::path& p, const std::string& text) { std::ofstream(p) << text; }

// One link (m = 2 kg, CoM at 0.4 m) held horizontal by a servo row: u = −m g l = −7.848 N·m at
// rest, whatever the motor (no speed: no friction torque, the rotor's inertia sees no q̈).
constexpr double kHold = 2.0 * 9.81 * 0.4;

// Its scenario, shared with python/tests/test_size.py.
const std::string kLink = ukdyn_test::slurp(kSource / "tests" / "sizing" / "held_link.yaml");

// Three motors × two gearboxes, masses chosen so that the order by mass interleaves them.
std::string catalogue(const std::string& g50_extra = "") {
  return R"(ukdyn_catalogue: 1
name: test
motors:
  - {name: A, mass: 0.1, torque_constant: 0.02, stall_torque: 0.2, peak_torque: 0.05}
  - {name: B, mass: 0.2, torque_constant: 0.03, stall_torque: 0.4, peak_torque: 0.1}
  - {name: C, mass: 0.4, torque_constant: 0.05, stall_torque: 1.0, peak_torque: 0.3}
gearboxes:
  - {name: g10, mass: 0.05, ratio: 10, efficiency: 0.9}
  - {name: g50, mass: 0.1, ratio: 50, efficiency: 0.8)" +
         g50_extra + "}\n";
}

const char* kSizing = R"(ukdyn_sizing: 1
name: held
catalogue: cat.yaml
scenario: link.yaml
actuators: [shoulder]
margin: 0.1
)";

struct Part {
  const char* motor;
  double mass, peak;
  const char* gear;
  double gmass, n, eta;
};

TEST(Sizing, HeldLinkChoiceMatchesTheClosedForm) {
  ScratchDir dir("ukdyn_sizing_held");
  write(dir.path / "link.yaml", kLink);
  write(dir.path / "cat.yaml", catalogue());
  write(dir.path / "s.yaml", kSizing);
  const ukdyn::SizingFile f = ukdyn::load_sizing_file(dir.path / "s.yaml");
  EXPECT_EQ(f.order_by, "mass");
  // The test's own list, ascending by mass, and the closed form of each one's margin.
  const std::vector<Part> parts = {
      {"A", 0.1, 0.05, "g10", 0.05, 10, 0.9}, {"A", 0.1, 0.05, "g50", 0.1, 50, 0.8},
      {"B", 0.2, 0.1, "g10", 0.05, 10, 0.9},  {"B", 0.2, 0.1, "g50", 0.1, 50, 0.8},
      {"C", 0.4, 0.3, "g10", 0.05, 10, 0.9},  {"C", 0.4, 0.3, "g50", 0.1, 50, 0.8}};
  ASSERT_EQ(f.actuators.size(), 1u);
  ASSERT_EQ(f.actuators[0].candidates.size(), parts.size());
  std::size_t expected = parts.size();
  for (std::size_t i = 0; i < parts.size(); ++i) {
    EXPECT_EQ(ukdyn::candidate_name(f.catalogue, f.actuators[0].candidates[i]),
              std::string(parts[i].motor) + " + " + parts[i].gear);
    const double margin = 1.0 - kHold / (parts[i].n * parts[i].eta) / parts[i].peak;
    if (expected == parts.size() && margin >= 0.1) expected = i;
  }
  ASSERT_EQ(expected, 5u);  // C + g50 (margin 0.346); C + g10 keeps −1.91
  const ukdyn::SizingResult r = ukdyn::run_sizing(f);
  ASSERT_TRUE(r.converged);
  ASSERT_TRUE(r.all_found());
  const ukdyn::SizingChoice& c = r.choices[0];
  EXPECT_EQ(c.candidate, expected);
  const double m_choice = 1.0 - kHold / (50 * 0.8) / 0.3,
               m_smaller = 1.0 - kHold / (10 * 0.9) / 0.3;
  EXPECT_NEAR(c.binding.margin, m_choice, 1e-6);
  EXPECT_EQ(c.binding.limit, "peak torque");
  ASSERT_TRUE(c.has_smaller);
  EXPECT_EQ(c.smaller, expected - 1);
  EXPECT_NEAR(c.smaller_fails.margin, m_smaller, 1e-6);
  EXPECT_NEAR(c.binding.u, -kHold, 1e-6);
  std::printf("held link: choice margin %.9f (closed form %.9f), next smaller %.9f (%.9f)\n",
              c.binding.margin, m_choice, c.smaller_fails.margin, m_smaller);
}

// The gearbox g50 rated for 8 N·m at its output: |u| = 7.848 keeps 1.9 %, below the 10 % asked;
// g10 is too weak a ratio for every motor: no candidate holds, and the best is C + g50 at 1.9 %.
TEST(Sizing, GearboxLimitThatNoCandidateMeets) {
  ScratchDir dir("ukdyn_sizing_gear");
  write(dir.path / "link.yaml", kLink);
  write(dir.path / "cat.yaml", catalogue(", peak_torque: 8"));
  write(dir.path / "s.yaml", kSizing);
  const ukdyn::SizingFile f = ukdyn::load_sizing_file(dir.path / "s.yaml");
  const ukdyn::SizingResult r = ukdyn::run_sizing(f);
  ASSERT_FALSE(r.all_found());
  const ukdyn::SizingChoice& c = r.choices[0];
  EXPECT_NEAR(c.best_margin, 1.0 - kHold / 8.0, 1e-6);
  EXPECT_EQ(ukdyn::candidate_name(f.catalogue, f.actuators[0].candidates[c.best_candidate]),
            "C + g50");
  const auto j = nlohmann::json::parse(ukdyn::sizing_json(f, r));
  EXPECT_FALSE(j["all_found"].get<bool>());
  EXPECT_NEAR(j["actuators"][0]["shortfall"].get<double>(), 0.1 - (1.0 - kHold / 8.0), 1e-6);
}

// Without a mass on every entry the default order is the motor's continuous torque (then, for one
// motor, the gearboxes by their rated output torque); the reason is stated.
TEST(Sizing, OrderWithoutMassesIsByContinuousTorque) {
  ScratchDir dir("ukdyn_sizing_order");
  write(dir.path / "link.yaml", kLink);
  write(dir.path / "cat.yaml", R"(ukdyn_catalogue: 1
name: test
motors:
  - {name: big, torque_constant: 0.05, peak_torque: 0.3, continuous_torque: 0.2}
  - {name: small, mass: 0.1, torque_constant: 0.02, peak_torque: 0.05, continuous_torque: 0.02}
gearboxes:
  - {name: strong, ratio: 50, continuous_torque: 40}
  - {name: weak, ratio: 10, continuous_torque: 5}
)");
  write(dir.path / "s.yaml", kSizing);
  const ukdyn::SizingFile f = ukdyn::load_sizing_file(dir.path / "s.yaml");
  EXPECT_EQ(f.order_by, "continuous_torque");
  EXPECT_NE(f.order_reason.find("no mass"), std::string::npos) << f.order_reason;
  std::vector<std::string> names;
  for (const auto& c : f.actuators[0].candidates)
    names.push_back(ukdyn::candidate_name(f.catalogue, c));
  EXPECT_EQ(names, (std::vector<std::string>{"small + weak", "small + strong", "big + weak",
                                             "big + strong"}));
}

// The shipped example's choices, checked by runs this test sets up itself.
struct Columns {
  std::size_t u, margin;
};

ukdyn::MemoryRun run_with(const ukdyn::SizingFile& f, long k,
                          const std::vector<std::size_t>& cand) {
  YAML::Node doc = YAML::Load(ukdyn::sample_scenario_text(f.sweep, k));
  for (std::size_t a = 0; a < f.actuators.size(); ++a) {
    const auto& c = f.actuators[a].candidates[cand[a]];
    const auto& m = f.catalogue.motors[c.motor].spec;
    const auto& g = f.catalogue.gearboxes[c.gearbox];
    YAML::Node b(YAML::NodeType::Map);
    b["ratio"] = g.ratio;
    b["efficiency"] = g.efficiency;
    b["rotor_inertia"] = m.rotor_inertia + g.inertia;
    b["viscous"] = m.viscous;
    b["coulomb"] = m.coulomb;
    b["coulomb_speed"] = m.coulomb_speed;
    b["torque_constant"] = m.torque_constant;
    b["resistance"] = m.resistance;
    for (const auto& [key, v] : {std::pair{"stall_torque", m.stall_torque},
                                 {"no_load_speed", m.no_load_speed},
                                 {"continuous_torque", m.continuous_torque},
                                 {"peak_torque", m.peak_torque}})
      if (std::isfinite(v)) b[key] = v;
    for (YAML::Node e : doc["actuators"])
      if (e["name"].Scalar() == f.actuators[a].name) e["motor"] = b;
  }
  YAML::Emitter out;
  out.SetDoublePrecision(17);
  out << doc;
  const auto sc = ukdyn::load_scenario_text(out.c_str(), f.sweep.base_path);
  return ukdyn::run_scenario_in_memory(sc);
}

std::size_t col(const ukdyn::MemoryRun& run, const std::string& name) {
  const auto it = std::find(run.header.begin(), run.header.end(), name);
  EXPECT_NE(it, run.header.end()) << name;
  return static_cast<std::size_t>(it - run.header.begin());
}

// The smallest margin of actuator a over a run, every limit of its candidate (the envelope from
// the motor_margin_ column, the gearbox's peak output torque and input speed, the RMS limits).
double run_margin(const ukdyn::SizingFile& f, const ukdyn::MemoryRun& run, std::size_t a,
                  std::size_t cand, double* at_t = nullptr, double t = 0.0) {
  const auto& c = f.actuators[a].candidates[cand];
  const auto& g = f.catalogue.gearboxes[c.gearbox];
  const std::string& name = f.actuators[a].name;
  const std::size_t w = run.header.size(), cu = col(run, "u_" + name),
                    cm = col(run, "motor_margin_" + name), cs = col(run, "motor_speed_" + name);
  double worst = INFINITY, u2 = 0.0;
  for (long r = 0; r < run.report.csv_rows; ++r) {
    const double* row = run.values.data() + static_cast<std::size_t>(r) * w;
    const double m = std::min({row[cm], 1.0 - std::abs(row[cu]) / g.peak_torque,
                               1.0 - std::abs(row[cs]) / g.max_input_speed});
    worst = std::min(worst, m);
    u2 += row[cu] * row[cu];
    if (at_t && std::abs(row[0] - t) < 1e-9) *at_t = m;
  }
  const auto j = nlohmann::json::parse(run.summary_json)["motors"][name];
  if (f.continuous && j.contains("rms_margin"))
    worst = std::min(worst, j["rms_margin"].get<double>());
  // The gearbox's RMS limit by the plain mean of squares (the report uses Simpson's rule: the two
  // agree to O(h²) on these smooth runs; the margins below are far from it).
  if (f.continuous && std::isfinite(g.continuous_torque))
    worst = std::min(worst, 1.0 - std::sqrt(u2 / static_cast<double>(run.report.csv_rows)) /
                                      g.continuous_torque);
  return worst;
}

TEST(SizingExample, ChoiceHoldsEverywhereAndNextSmallerFailsWhereReported) {
  const ukdyn::SizingFile f =
      ukdyn::load_sizing_file(kSource / "scenarios" / "sizing" / "paper_motors.yaml");
  const ukdyn::SizingResult r = ukdyn::run_sizing(f);
  ASSERT_TRUE(r.converged);
  ASSERT_TRUE(r.all_found());
  std::vector<std::size_t> choice;
  for (const auto& c : r.choices) choice.push_back(c.candidate);
  double lowest = INFINITY;
  for (long k = 0; k < f.sweep.samples; ++k) {
    const auto run = run_with(f, k, choice);
    ASSERT_TRUE(run.report.complete()) << k;
    for (std::size_t a = 0; a < choice.size(); ++a) {
      const double m = run_margin(f, run, a, choice[a]);
      EXPECT_GE(m, f.margin - 1e-6) << f.actuators[a].name << " sample " << k;
      lowest = std::min(lowest, m);
    }
  }
  int smaller_checked = 0;
  for (std::size_t a = 0; a < choice.size(); ++a) {
    const auto& c = r.choices[a];
    if (!c.has_smaller) {
      EXPECT_EQ(c.candidate, 0u) << f.actuators[a].name;
      continue;
    }
    std::vector<std::size_t> lower = choice;
    lower[a] = c.smaller;
    const auto run = run_with(f, c.smaller_fails.sample, lower);
    ASSERT_TRUE(run.report.complete());
    double at_t = NAN;
    const double m = run_margin(f, run, a, c.smaller, &at_t, c.smaller_fails.t);
    EXPECT_LT(m, f.margin) << f.actuators[a].name;
    if (!std::isnan(c.smaller_fails.t)) {  // a point limit: the reported time is where it fails
      EXPECT_LT(at_t, f.margin) << f.actuators[a].name;
      EXPECT_NEAR(at_t, c.smaller_fails.margin, 1e-6) << f.actuators[a].name;
    }
    ++smaller_checked;
  }
  EXPECT_GT(smaller_checked, 0);
  std::printf(
      "shipped sizing: %d configurations, %ld runs; lowest margin of the choices %.4f; "
      "%d next-smaller candidates re-run and failing\n",
      r.configurations, r.runs, lowest, smaller_checked);
}

// A sample that cannot run (a negative mass in the sweep) makes every candidate fail, with the
// sample and the loader's reason: nothing is vouched for on a sample that did not run.
TEST(Sizing, FailedSampleFailsEveryCandidate) {
  ScratchDir dir("ukdyn_sizing_failed");
  write(dir.path / "link.yaml", kLink);
  write(dir.path / "cat.yaml", catalogue());
  write(dir.path / "sw.yaml", R"(ukdyn_sweep: 1
name: masses
base: link.yaml
mode: list
parameters:
  - {name: mass, path: "subsystems[arm].joints[j1].mass", values: [2, -1]}
)");
  std::string s = kSizing;
  s.replace(s.find("scenario: link.yaml"), 19, "sweep: sw.yaml");
  write(dir.path / "s.yaml", s);
  const ukdyn::SizingFile f = ukdyn::load_sizing_file(dir.path / "s.yaml");
  ASSERT_EQ(f.sweep.samples, 2);
  const ukdyn::SizingResult r = ukdyn::run_sizing(f);
  ASSERT_FALSE(r.all_found());
  const ukdyn::SizingChoice& c = r.choices[0];
  EXPECT_EQ(c.binding.sample, 1);
  EXPECT_NE(c.binding.failure.find("sample 1: invalid scenario"), std::string::npos)
      << c.binding.failure;
  EXPECT_NE(c.binding.failure.find("mass"), std::string::npos) << c.binding.failure;
}

// A scenario with nothing that drives its actuators (no servo rows, no control: u ≡ 0): refused
// at the sizing file's key, not sized on zero inputs.
TEST(Sizing, NoInputsToSizeByIsRefused) {
  ScratchDir dir("ukdyn_sizing_no_u");
  std::string link = kLink;
  link.erase(link.find("constraints:"),
             link.find("actuators:") - link.find("constraints:"));  // no servo row
  write(dir.path / "link.yaml", link);
  write(dir.path / "cat.yaml", catalogue());
  write(dir.path / "s.yaml", kSizing);
  try {
    (void)ukdyn::load_sizing_file(dir.path / "s.yaml");
    ADD_FAILURE() << "accepted a scenario without inputs";
  } catch (const ukdyn::ScenarioError& e) {
    EXPECT_NE(std::string(e.what()).find("s.yaml:4:11: key 'scenario': the scenario has no servo "
                                         "constraint rows and no control: section"),
              std::string::npos)
        << e.what();
  }
}

// Bad catalogue and sizing files: the error names the file, the line and the key.
TEST(Sizing, BadFilesNameFileLineAndKey) {
  ScratchDir dir("ukdyn_sizing_bad");
  write(dir.path / "link.yaml", kLink);
  const auto expect_error = [&](const std::string& cat, const std::string& sizing,
                                const std::string& where) {
    write(dir.path / "cat.yaml", cat);
    write(dir.path / "s.yaml", sizing);
    try {
      (void)ukdyn::load_sizing_file(dir.path / "s.yaml");
      ADD_FAILURE() << "accepted: " << where;
    } catch (const ukdyn::ScenarioError& e) {
      EXPECT_NE(std::string(e.what()).find(where), std::string::npos) << e.what();
    }
  };
  const std::string cat = catalogue(), s = kSizing;
  const auto replace = [](std::string t, const std::string& a, const std::string& b) {
    const auto i = t.find(a);
    EXPECT_NE(i, std::string::npos) << a;
    return t.replace(i, a.size(), b);
  };
  expect_error(replace(cat, "ratio: 50", "ratio: 0"), s,
               "cat.yaml:9:35: key 'gearboxes[1].ratio': ratio must be > 0");
  expect_error(replace(cat, "efficiency: 0.9", "efficiency: 1.5"), s,
               "key 'gearboxes[0].efficiency': efficiency must be in (0, 1]");
  expect_error(replace(cat, "name: B,", "name: A,"), s, "cat.yaml:5:12: key 'motors[1].name'");
  expect_error(replace(cat, "torque_constant: 0.03,", "kt: 0.03,"), s,
               "key 'motors[1].kt': unknown key");
  expect_error(replace(cat, "ukdyn_catalogue: 1", "ukdyn_catalogue: 2"), s,
               "cat.yaml:1:18: key 'ukdyn_catalogue'");
  expect_error(cat, replace(s, "[shoulder]", "[shoulder, elbow]"),
               "s.yaml:5:23: key 'actuators[1]': the scenario has no actuator named 'elbow'");
  expect_error(cat, replace(s, "margin: 0.1", "margin: 1.5"), "s.yaml:6:9: key 'margin'");
  expect_error(cat, s + "sweep: x.yaml\n", "s.yaml");
  expect_error(cat, replace(s, "cat.yaml", "missing.yaml"), "key 'catalogue'");
  expect_error(replace(cat, "{name: g10, mass: 0.05,", "{name: g10,"), s + "order_by: mass\n",
               "key 'order_by': order_by: mass needs a mass");
  expect_error(cat, replace(s, "[shoulder]", "[{name: shoulder, motors: [Z]}]"),
               "key 'actuators[0].motors[0]': the catalogue has no entry named 'Z'");
}

#ifdef UKDYN_TEST_HAVE_CLI
// The CLI: exit 0 with sizing.json and candidates.csv (the same bytes with one thread); exit 1 when
// no candidate holds, the actuator and the shortfall on stderr; exit 2 for a bad sizing file.
TEST(SizingCli, ExitCodesAndOutputs) {
  const fs::path scratch = ukdyn_test::process_scratch("ukdyn_sizing_cli");
  write(scratch / "link.yaml", kLink);
  write(scratch / "cat.yaml", catalogue());
  write(scratch / "s.yaml", kSizing);
  const auto sh = ukdyn_test::sh;
  auto r = ukdyn_test::run_cli(
      UKDYN_CLI, scratch,
      "size " + sh((scratch / "s.yaml").string()) + " --out " + sh((scratch / "out").string()));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("C + g50"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("next smaller C + g10 fails"), std::string::npos) << r.out;
  // One worker thread: the same bytes (no wall time in the files; samples reduced in order).
  const auto r1 = ukdyn_test::run_cli(UKDYN_CLI, scratch,
                                      "size -q -j 1 " + sh((scratch / "s.yaml").string()) +
                                          " --out " + sh((scratch / "out1").string()));
  ASSERT_EQ(r1.exit_code, 0) << r1.err;
  for (const char* name : {"sizing.json", "candidates.csv"})
    EXPECT_EQ(ukdyn_test::slurp(scratch / "out" / name), ukdyn_test::slurp(scratch / "out1" / name))
        << name;
  const auto j = nlohmann::json::parse(ukdyn_test::slurp(scratch / "out" / "sizing.json"));
  EXPECT_EQ(j["actuators"][0]["choice"]["motor"], "C");
  const std::string csv = ukdyn_test::slurp(scratch / "out" / "candidates.csv");
  EXPECT_EQ(csv.rfind("actuator,candidate,motor,gearbox,size,holds,worst_margin", 0), 0u) << csv;
  write(scratch / "cat.yaml", catalogue(", peak_torque: 8"));
  r = ukdyn_test::run_cli(
      UKDYN_CLI, scratch,
      "size -q " + sh((scratch / "s.yaml").string()) + " --out " + sh((scratch / "out2").string()));
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_NE(r.err.find("actuator 'shoulder': no catalogue entry keeps the margin 10 %"),
            std::string::npos)
      << r.err;
  write(scratch / "cat.yaml", "ukdyn_catalogue: 1\nname: x\nmotors: []\n");
  r = ukdyn_test::run_cli(UKDYN_CLI, scratch, "size " + sh((scratch / "s.yaml").string()));
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("cat.yaml:3:9: key 'motors'"), std::string::npos) << r.err;
}
#endif

}  // namespace
