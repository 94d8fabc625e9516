// No silent wrong answer from files, sweeps and messages (docs/scenario-format.md, "Files ukdyn
// reads"; docs/sweeps.md): the one reader of input files against the file types and sizes it must
// refuse; the YAML alias limits counted exactly on both sides of the bound; plants that name
// themselves; a sweep's rows checked against the sweep file (values recomputed from it, not taken
// from the row); a path into an expression refused; the spline of no numbers; --threads bounded;
// a run folder's summary.json not trusted for the file it names; a refused re-run that leaves no
// earlier summary behind.
#include <fcntl.h>
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <yaml-cpp/yaml.h>

#include <nlohmann/json.hpp>
#include <string>

#include "cli_run.hpp"
#include "control_systems.hpp"
#include "core/input_file.hpp"
#include "scenario/yaml_loader.hpp"
#include "scenario/yaml_paths.hpp"
#include "sweep/journal.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/scenario/scenario_file.hpp"
#include "ukdyn/sweep/sweep.hpp"
#include "ukdyn/symbolic/spline.hpp"

namespace {

namespace fs = std::filesystem;
using ukdyn_test::run_cli;
using ukdyn_test::ScratchDir;
using ukdyn_test::sh;
using ukdyn_test::slurp;

fs::path write(const fs::path& p, const std::string& text) {
  std::ofstream(p, std::ios::binary) << text;
  return p;
}

// The message of the ukdyn::Error that f throws ("" if it throws none).
template <class F>
std::string error_of(F&& f) {
  try {
    f();
  } catch (const ukdyn::Error& e) {
    return e.what();
  }
  return {};
}

// The servo pendulum of tests/control_systems.hpp, a short run, with `control` appended.
std::string servo(const std::string& control) {
  return uktest::pendulum_servo_yaml(1.0, control, "{t_end: 0.2, sample_dt: 0.01}");
}

std::string list_sweep(const std::string& base, const std::string& extra = "") {
  return "ukdyn_sweep: 1\nname: trust\nbase: " + base +
         "\nmode: list\nparameters:\n  - name: m\n    path: subsystems[bob].parameters.m\n"
         "    values: [1, 1.5, 2]\n" +
         extra;
}

// ---- the one reader of input files

TEST(InputFile, RegularFileIsReadWhole) {
  ScratchDir dir("ukdyn_input_file_ok");
  std::string text(200000, 'a');
  for (std::size_t i = 0; i < text.size(); i += 7) text[i] = static_cast<char>('0' + i % 10);
  write(dir.path / "f.txt", text);
  EXPECT_EQ(ukdyn::detail::read_input_file(dir.path / "f.txt", {"test file"}), text);
  ukdyn::detail::InputStream in(dir.path / "f.txt", {"test file"});
  std::ostringstream os;
  os << in.rdbuf();
  EXPECT_EQ(os.str(), text);
}

TEST(InputFile, EveryOtherKindIsNamedAndNeverBlocks) {
  ScratchDir dir("ukdyn_input_file_kinds");
  const fs::path fifo = dir.path / "pipe";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  const ukdyn::detail::InputFileSpec spec{"test file", 1024};
  EXPECT_NE(error_of([&] {
              ukdyn::detail::read_input_file(fifo, spec);
            }).find("pipe: is a FIFO (named pipe), not a test file"),
            std::string::npos);
  EXPECT_NE(error_of([&] {
              ukdyn::detail::read_input_file(dir.path, spec);
            }).find(": is a folder, not a test file"),
            std::string::npos);
  EXPECT_NE(error_of([&] {
              ukdyn::detail::read_input_file("/dev/zero", spec);
            }).find("/dev/zero: is a device, not a test file"),
            std::string::npos);
  try {
    ukdyn::detail::read_input_file(dir.path / "none", spec);
    ADD_FAILURE() << "a missing file was read";
  } catch (const ukdyn::detail::InputFileError& e) {
    EXPECT_TRUE(e.missing());
    EXPECT_NE(std::string(e.what()).find("none: no such test file"), std::string::npos);
  }
  // One byte over the limit, from the size (a sparse file: nothing is read).
  write(dir.path / "big", "");
  fs::resize_file(dir.path / "big", 1025);
  EXPECT_NE(error_of([&] {
              ukdyn::detail::read_input_file(dir.path / "big", spec);
            }).find("big: larger than 1024 bytes, not a readable test file"),
            std::string::npos)
      << "(the limit is 1024 bytes; one more is refused)";
  write(dir.path / "just", std::string(1024, 'x'));
  EXPECT_EQ(ukdyn::detail::read_input_file(dir.path / "just", spec).size(), 1024u);
}

TEST(InputFile, InsideAFolderALinkIsNotFollowed) {
  ScratchDir dir("ukdyn_input_file_link");
  write(dir.path / "target", "secret");
  fs::create_symlink(dir.path / "target", dir.path / "link");
  const int fd = ::open(dir.path.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  ASSERT_GE(fd, 0);
  const std::string e = error_of([&] {
    ukdyn::detail::read_input_file("link", {"journal", 1024, "link", fd});
  });
  EXPECT_NE(e.find("link: is a symbolic link, not a journal"), std::string::npos) << e;
  EXPECT_EQ(ukdyn::detail::read_input_file("target", {"journal", 1024, "target", fd}), "secret");
  ::close(fd);
}

// ---- YAML: aliases counted as written out, on both sides of the bound

// `a: &x [0 × n]` and `b: [*x × k]`: 1 (root) + 1 (a) + (1 + n) + 1 (b) + 1 (its list) +
// k (1 + n) nodes once written out.
std::string aliased(int n, int k) {
  std::string s = "a: &x [";
  for (int i = 0; i < n; ++i) s += i ? ", 0" : "0";
  s += "]\nb: [";
  for (int i = 0; i < k; ++i) s += i ? ", *x" : "*x";
  return s + "]\n";
}

TEST(YamlLimits, AliasesAreCountedWrittenOutOnBothSidesOfTheBound) {
  ASSERT_EQ(ukdyn::io_detail::kMaxYamlNodes, 1'000'000u);
  // n = 999: 1004 + 1000 k nodes; k = 998 gives 999,004 (in), k = 999 gives 1,000,004 (out).
  YAML::Mark at;
  EXPECT_EQ(ukdyn::io_detail::yaml_expansion_problem(YAML::Load(aliased(999, 998)), at), "");
  const std::string why =
      ukdyn::io_detail::yaml_expansion_problem(YAML::Load(aliased(999, 999)), at);
  EXPECT_NE(why.find("more than 1000000 nodes"), std::string::npos) << why;
  // Through the parser every loader uses: file:line:column of the node where the count ran out
  // (a node of the anchored list, line 1: an alias shares the nodes of its anchor).
  const std::string e =
      error_of([&] { ukdyn::io_detail::parse_scenario_yaml(aliased(999, 999), "bomb.yaml"); });
  EXPECT_EQ(e.rfind("bomb.yaml:1:", 0), 0u) << e;
}

TEST(YamlLimits, DepthIsCountedThroughAliases) {
  // Two anchors of 300 levels each: each is under the parser's limit, together 600 > 500.
  const std::string a = std::string(300, '[') + "x" + std::string(300, ']');
  const std::string b = std::string(300, '[') + "*a" + std::string(300, ']');
  const std::string text = "p: &a " + a + "\nq: " + b + "\n";
  const std::string e = error_of([&] { ukdyn::io_detail::parse_scenario_yaml(text, "deep.yaml"); });
  EXPECT_NE(e.find("nested more than 500 levels"), std::string::npos) << e;
  const std::string shallow = "p: &a " + a + "\nq: *a\n";  // 301 levels: fine
  EXPECT_EQ(error_of([&] { ukdyn::io_detail::parse_scenario_yaml(shallow, "ok.yaml"); }), "");
}

// ---- plants

TEST(Plants, APlantThatNamesItselfOrItsNamerIsRefusedAtOnce) {
  ScratchDir dir("ukdyn_plant_cycle");
  write(dir.path / "self.yaml", servo("control:\n  law: stabilized\n  plant: self.yaml\n"));
  write(dir.path / "a.yaml", servo("control:\n  law: stabilized\n  plant: b.yaml\n"));
  write(dir.path / "b.yaml", servo("control:\n  law: stabilized\n  plant: a.yaml\n"));
  for (const char* f : {"self.yaml", "a.yaml"}) {
    const std::string e = error_of([&] { ukdyn::load_scenario(dir.path / f); });
    EXPECT_NE(e.find("key 'control.plant': the plant scenario must not have a control section"),
              std::string::npos)
        << e;
  }
  // A plant without control loads (the check refuses only what it must).
  write(dir.path / "plant.yaml", servo(""));
  write(dir.path / "ok.yaml", servo("control:\n  law: stabilized\n  plant: plant.yaml\n"));
  EXPECT_EQ(error_of([&] { ukdyn::load_scenario(dir.path / "ok.yaml"); }), "");
}

TEST(Plants, PlantSetValueIntoAnExpressionIsRefused) {
  ScratchDir dir("ukdyn_plant_set_expr");
  write(dir.path / "s.yaml", servo("control:\n  law: stabilized\n  plant_set:\n"
                                   "    - {path: \"constraints[swing].let.th\", value: 2}\n"));
  const std::string e = error_of([&] { ukdyn::load_scenario(dir.path / "s.yaml"); });
  EXPECT_NE(e.find("holds '0.3*(1 - cos(2*t))', not a number"), std::string::npos) << e;
  // An expression may still go there, and a value where a number is.
  write(dir.path / "x.yaml",
        servo("control:\n  law: stabilized\n  plant_set:\n"
              "    - {path: \"constraints[swing].let.th\", expression: 0.2*(1 - cos(2*t))}\n"
              "    - {path: \"subsystems[bob].parameters.m\", value: 2}\n"));
  EXPECT_EQ(error_of([&] { ukdyn::load_scenario(dir.path / "x.yaml"); }), "");
}

// ---- sweeps

TEST(SweepFile, PathIntoAnExpressionIsRefused) {
  ScratchDir dir("ukdyn_sweep_expr_path");
  write(dir.path / "base.yaml", servo(""));
  write(dir.path / "s.yaml",
        "ukdyn_sweep: 1\nname: t\nbase: base.yaml\nmode: list\nparameters:\n  - name: th\n"
        "    path: \"constraints[swing].let.th\"\n    values: [1, 2]\n");
  const std::string e = error_of([&] { ukdyn::load_sweep(dir.path / "s.yaml"); });
  EXPECT_NE(e.find("s.yaml:7:"), std::string::npos) << e;
  EXPECT_NE(e.find("key 'parameters[0].path'"), std::string::npos) << e;
  EXPECT_NE(e.find("not a number: a number put there would replace it"), std::string::npos) << e;
}

TEST(SweepFile, MetricColumnErrorNamesItsKey) {
  ScratchDir dir("ukdyn_sweep_metric_key");
  write(dir.path / "base.yaml", servo(""));
  write(dir.path / "s.yaml",
        list_sweep("base.yaml", "metrics:\n  - max_residual\n  - {column: nope, stats: [max]}\n"));
  const std::string e = error_of([&] { ukdyn::load_sweep(dir.path / "s.yaml"); });
  EXPECT_NE(e.find("s.yaml:11:"), std::string::npos) << e;
  EXPECT_NE(e.find("key 'metrics[1].column': no column named 'nope'"), std::string::npos) << e;
}

// A sweep runs no shadow per sample (docs/accuracy.md): a base that asks for the error estimate is
// refused at its base: key rather than run without it.
TEST(SweepFile, ABaseAskingForTheErrorEstimateIsRefused) {
  ScratchDir dir("ukdyn_sweep_error_estimate");
  std::string base = servo("");
  const std::string sim = "simulation: {t_end: 0.2, sample_dt: 0.01}";
  const auto pos = base.find(sim);
  ASSERT_NE(pos, std::string::npos);
  base.replace(pos, sim.size(),
               "simulation: {t_end: 0.2, sample_dt: 0.01, error_estimate: shadow}");
  write(dir.path / "base.yaml", base);
  write(dir.path / "s.yaml", list_sweep("base.yaml"));
  const std::string e = error_of([&] { ukdyn::load_sweep(dir.path / "s.yaml"); });
  EXPECT_NE(e.find("key 'base'"), std::string::npos) << e;
  EXPECT_NE(e.find("error_estimate: shadow, which a sweep does not run per sample"),
            std::string::npos)
      << e;
}

TEST(SweepRows, EveryCellIsCheckedAgainstTheSweepFile) {
  ScratchDir dir("ukdyn_sweep_rows");
  write(dir.path / "base.yaml", servo(""));
  const ukdyn::Sweep sw = ukdyn::load_sweep(write(dir.path / "s.yaml", list_sweep("base.yaml")));
  const std::vector<std::string> h{"sample",    "m",     "status",      "reason",
                                   "t_reached", "steps", "max_residual"};
  long k = -1;
  EXPECT_EQ(ukdyn::sweep_detail::row_problem(sw, h, "1,1.5,completed,,0.2,40,1e-15", k), "");
  EXPECT_EQ(k, 1);
  EXPECT_EQ(ukdyn::sweep_detail::row_problem(sw, h, "2,2,step_failure,\"a, b\",0.1,7,nan", k), "");
  const struct {
    const char* row;
    const char* why;
  } bad[] = {
      {"1,1.5,completed,,0.2,40", "column 7: 6 cells, the sweep's table has 7"},
      {"3,1.5,completed,,0.2,40,0",
       "column 1 (sample): sample 3, but the sweep file has samples 0..2"},
      {"-1,1,completed,,0.2,40,0", "column 1 (sample): '-1' is not a sample index"},
      {"1x,1,completed,,0.2,40,0", "column 1 (sample): '1x' is not a sample index"},
      {"1,2,completed,,0.2,40,0",
       "column 2 (m): '2', but the sweep file gives sample 1 the value 1.5"},
      {"1,1.5000001,completed,,0.2,40,0", "column 2 (m)"},
      {"1,1.5,fine,,0.2,40,0", "column 3 (status): 'fine' is not a status of a sample"},
      {"1,1.5,completed,,0.2,40,1e-15x", "column 7 (max_residual): '1e-15x' is not a number"},
      {"1,1.5,completed,,soon,40,0", "column 5 (t_reached): 'soon' is not a number"},
  };
  for (const auto& b : bad) {
    const std::string why = ukdyn::sweep_detail::row_problem(sw, h, b.row, k);
    EXPECT_NE(why.find(b.why), std::string::npos) << b.row << " -> " << why;
  }
}

TEST(SweepOptions, ThreadsAreBounded) {
  EXPECT_GE(ukdyn::max_sweep_threads(), 16);
  EXPECT_LE(ukdyn::max_sweep_threads(), 256);
  ScratchDir dir("ukdyn_sweep_threads");
  write(dir.path / "base.yaml", servo(""));
  const ukdyn::Sweep sw = ukdyn::load_sweep(write(dir.path / "s.yaml", list_sweep("base.yaml")));
  ukdyn::SweepOptions opt;
  opt.threads = ukdyn::max_sweep_threads() + 1;
  const std::string e = error_of([&] { ukdyn::run_sweep(sw, dir.path / "out", opt); });
  EXPECT_NE(e.find("--threads: expected 1 to"), std::string::npos) << e;
  EXPECT_FALSE(fs::exists(dir.path / "out")) << "refused before anything was written";
}

// ---- splines

TEST(SplineNumbers, ASplineOfNoNumbersIsRefusedWhereItIsWritten) {
  using ukdyn::symbolic::CubicSpline;
  const std::string close = error_of([] { CubicSpline({0, 1e-300, 1}, {0, 1, 2}); });
  EXPECT_NE(close.find("no finite polynomial between points 1 and 2"), std::string::npos) << close;
  const std::string big = error_of([] { CubicSpline({0, 1, 2}, {0, 1e308, -1e308}); });
  EXPECT_NE(big.find("no finite polynomial"), std::string::npos) << big;
  // Close but representable knots are fine, and the spline still interpolates its points.
  const CubicSpline s({0, 1e-6, 1}, {0, 1e-6, 1});
  EXPECT_DOUBLE_EQ(s.eval(1e-6, 0), 1e-6);
}

#ifdef UKDYN_CLI
const fs::path kCli = UKDYN_CLI;

// ---- the CLI: folders, resumes, merges, replays

TEST(TrustCli, ThreadsAndShardAreRefusedAtTheFlag) {
  ScratchDir dir("ukdyn_trust_cli_flags");
  write(dir.path / "base.yaml", servo(""));
  const fs::path f = write(dir.path / "s.yaml", list_sweep("base.yaml"));
  for (const char* flag :
       {"--threads 4096", "--threads 0", "--shard 1/2junk", "--shard 2/2", "--shard ' 1/2'"}) {
    const auto r = run_cli(
        kCli, dir.path,
        "sweep " + sh(f) + " " + std::string(flag) + " -o " + sh((dir.path / "o").string()));
    EXPECT_EQ(r.exit_code, 2) << flag << ": " << r.err;
    EXPECT_FALSE(fs::exists(dir.path / "o")) << flag;
  }
}

TEST(TrustCli, TamperedJournalAndShardRowsAreRefusedWithFileLineAndColumn) {
  ScratchDir dir("ukdyn_trust_cli_rows");
  write(dir.path / "base.yaml", servo(""));
  const fs::path f = write(dir.path / "s.yaml", list_sweep("base.yaml"));
  const std::string o = (dir.path / "o").string();
  ASSERT_EQ(run_cli(kCli, dir.path, "sweep " + sh(f) + " -q --no-figures -o " + sh(o)).exit_code,
            0);
  // A journal row whose m is not the sweep file's: refused, naming the line and column; no
  // summary is left that says complete.
  std::string journal = slurp(fs::path(o) / "journal.csv");
  const auto at = journal.find("\n1,1.5,");
  ASSERT_NE(at, std::string::npos) << journal;
  journal.replace(at, 7, "\n1,1.25,");
  write(fs::path(o) / "journal.csv", journal);
  auto r = run_cli(kCli, dir.path, "sweep " + sh(f) + " -q --no-figures -o " + sh(o));
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_NE(r.err.find("journal.csv:"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find(": column 2 (m): '1.25', but the sweep file gives sample 1 the value 1.5"),
            std::string::npos)
      << r.err;
  EXPECT_FALSE(fs::exists(fs::path(o) / "summary.json"));
  // --fresh starts over and completes.
  ASSERT_EQ(
      run_cli(kCli, dir.path, "sweep " + sh(f) + " -q --no-figures --fresh -o " + sh(o)).exit_code,
      0);

  // Shards: a merged row must be this shard's, in range, once, with the sweep file's values.
  const std::string s0 = (dir.path / "s0").string(), s1 = (dir.path / "s1").string(),
                    m = (dir.path / "m").string();
  for (const auto& [sh_, d] : {std::pair{"0/2", s0}, std::pair{"1/2", s1}})
    ASSERT_EQ(run_cli(kCli, dir.path,
                      fmt::format("sweep {} -q --no-figures --shard {} -o {}", sh(f.string()), sh_,
                                  sh(d)))
                  .exit_code,
              0);
  const auto merge = [&] {
    return run_cli(kCli, dir.path,
                   "sweep merge " + sh(f) + " -q -o " + sh(m) + " " + sh(s0) + " " + sh(s1));
  };
  ASSERT_EQ(merge().exit_code, 0);
  const std::string table = slurp(fs::path(s1) / "results.csv");
  write(fs::path(s1) / "results.csv", table + "0,1,completed,,0.2,40,0\n");
  r = merge();
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_NE(r.err.find("results.csv:3: column 1: sample 0 belongs to shard 0/2, not to shard 1/2"),
            std::string::npos)
      << r.err;
  EXPECT_FALSE(fs::exists(fs::path(m) / "summary.json")) << "the earlier merge's summary is gone";
  std::string bad = table;
  bad.replace(bad.find("\n1,1.5,"), 7, "\n1,9,");
  write(fs::path(s1) / "results.csv", bad);
  r = merge();
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_NE(r.err.find("results.csv:2: column 2 (m): '9'"), std::string::npos) << r.err;
  write(fs::path(s1) / "results.csv", table);
  EXPECT_EQ(merge().exit_code, 0);
  r = run_cli(kCli, dir.path,
              "sweep merge " + sh(f) + " -q -o " + sh(s0) + " " + sh(s0) + " " + sh(s1));
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_NE(r.err.find("the merge's output folder is one of the shards'"), std::string::npos);
  EXPECT_TRUE(fs::exists(fs::path(s0) / "summary.json")) << "a shard's own files are untouched";
}

TEST(TrustCli, ARefusedRerunLeavesNoEarlierSummary) {
  ScratchDir dir("ukdyn_trust_cli_rerun");
  const fs::path s = write(dir.path / "s.yaml", servo(""));
  const fs::path o = dir.path / "o";
  ASSERT_EQ(run_cli(kCli, dir.path, "simulate " + sh(s) + " -q --no-figures -o " + sh(o.string()))
                .exit_code,
            0);
  ASSERT_TRUE(fs::exists(o / "summary.json"));
  fs::remove(o / "trajectory.csv");
  ASSERT_EQ(::mkfifo((o / "trajectory.csv").c_str(), 0600), 0);
  const auto r =
      run_cli(kCli, dir.path, "simulate " + sh(s) + " -q --no-figures -o " + sh(o.string()), "",
              "timeout 60 ");
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_NE(r.err.find("trajectory.csv is a FIFO"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(o / "summary.json")) << "the earlier run's complete summary was left";
}

TEST(TrustCli, ReplayReadsOnlyTheScenarioWhoseHashTheSummaryRecords) {
  ScratchDir dir("ukdyn_trust_cli_replay");
  const fs::path s = write(dir.path / "s.yaml", servo(""));
  const fs::path o = dir.path / "o";
  ASSERT_EQ(run_cli(kCli, dir.path, "simulate " + sh(s) + " -q --no-figures -o " + sh(o.string()))
                .exit_code,
            0);
  auto j = nlohmann::json::parse(slurp(o / "summary.json"));
  // The summary now names another file (a secret one, say): not read, not quoted.
  const fs::path secret = write(dir.path / "secret.txt", "ukdyn: 1\nname: SECRET_CONTENT\n");
  j["scenario"]["path"] = secret.string();
  write(o / "summary.json", j.dump());
  auto r = run_cli(kCli, dir.path, "replay " + sh(o.string()));
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_NE(r.err.find("is not the run's (its hash differs from summary.json's)"),
            std::string::npos)
      << r.err;
  EXPECT_EQ(r.err.find("SECRET_CONTENT"), std::string::npos) << r.err;
  // A FIFO named there is refused without blocking.
  ASSERT_EQ(::mkfifo((dir.path / "pipe.yaml").c_str(), 0600), 0);
  j["scenario"]["path"] = (dir.path / "pipe.yaml").string();
  write(o / "summary.json", j.dump());
  r = run_cli(kCli, dir.path, "replay " + sh(o.string()), "", "timeout 60 ");
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_NE(r.err.find("is a FIFO (named pipe)"), std::string::npos) << r.err;
}

TEST(TrustCli, AControlLawOfNoNumberIsNamedAndItsPeakIsNotZero) {
  ScratchDir dir("ukdyn_trust_cli_nan_law");
  const fs::path s = write(
      dir.path / "s.yaml",
      servo(
          "control:\n  law: stabilized\n  omega: 1e200\n  initial_offset: {swing_angle: 0.02}\n"));
  const fs::path o = dir.path / "o";
  const auto r =
      run_cli(kCli, dir.path, "simulate " + sh(s) + " -q --no-figures -o " + sh(o.string()));
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_NE(r.err.find("the input force tau of coordinate 'x' is NaN"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("clipped"), std::string::npos) << "a NaN is not a clipped u: " << r.err;
  const auto j = nlohmann::json::parse(slurp(o / "summary.json"));
  ASSERT_TRUE(j.contains("control")) << j.dump(1);
  EXPECT_TRUE(j["control"]["max_abs_u"].is_null()) << j["control"].dump();
}
TEST(TrustCli, AnImplicitSolversStepFailureNamesTheSingularMassMatrix) {
  // M = [[z^2, x z], [x z, x^2 + 1]] loses rank at z = 0 (det M = z^2), reached at t = 1.
  ScratchDir dir("ukdyn_trust_cli_singular_esdirk");
  const fs::path s = write(dir.path / "s.yaml", R"(ukdyn: 1
name: singular
gravity: 0
subsystems:
  - name: b
    type: definitions
    coordinates: [x, z]
    bodies:
      - {name: b, mass: 1, com: [x*z, 0, z]}
initial:
  q: [0.5, 1]
  qd: [0, -1]
simulation: {t_end: 2, sample_dt: 0.01, integrator: esdirk}
)");
  const auto r = run_cli(
      kCli, dir.path, "simulate " + sh(s) + " -q --no-figures -o " + sh((dir.path / "o").string()));
  if (r.err.find("built without SUNDIALS") != std::string::npos) GTEST_SKIP() << r.err;
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_NE(r.err.find("the mass matrix is singular and no constraint fixes the direction in "
                       "coordinates [x]"),
            std::string::npos)
      << r.err;
}
#endif  // UKDYN_CLI

}  // namespace
