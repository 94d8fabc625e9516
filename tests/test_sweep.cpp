// `ukdyn sweep` (docs/sweeps.md): the counter-based random streams against their closed-form
// moments; byte-identical tables at 1 and 2 threads and as 4 merged shards; --extract re-running
// to the same numbers through `ukdyn simulate`; failing samples recorded; a killed sweep resuming
// to the same table; bad sweep files named by file:line:key. Also initial.q expressions and the
// progress lines of `simulate` when stderr is not a terminal (issue 13, item 4).
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <nlohmann/json.hpp>
#include <numbers>
#include <set>
#include <thread>

#include "cli_run.hpp"
#include "output/csv_reader.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/sweep/sweep.hpp"

namespace {

namespace fs = std::filesystem;
using ukdyn_test::run_cli;
using ukdyn_test::ScratchDir;
using ukdyn_test::sh;
using ukdyn_test::slurp;

const fs::path kSource = UKDYN_SOURCE_DIR;

std::vector<std::string> lines(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream is(text);
  std::string l;
  while (std::getline(is, l)) out.push_back(l);
  return out;
}

std::vector<std::string> cells(const std::string& line) {
  return ukdyn::io_detail::split_csv_line(line);
}

std::size_t column(const std::vector<std::string>& header, const std::string& name) {
  const auto it = std::find(header.begin(), header.end(), name);
  EXPECT_NE(it, header.end()) << name;
  return static_cast<std::size_t>(it - header.begin());
}

// The paper's free motion, shortened (t_end 0.1 s, tolerances 1e-10): a few ms per sample.
std::string random_sweep(const fs::path& base, long samples, const std::string& t_end = "0.1") {
  return fmt::format(R"(ukdyn_sweep: 1
name: mc_test
base: {}
mode: random
seed: 12345
samples: {}
parameters:
  - name: platform_mass
    path: ["subsystems[left].params.platform_mass", "subsystems[right].params.platform_mass"]
    distribution: {{type: truncated_normal, mean: 50, sd: 5, low: 45, high: 60}}
  - name: link2_mass
    path: subsystems[left].params.link_mass[1]
    distribution: {{type: uniform, low: 3, high: 5}}
  - name: link3_mass
    path: subsystems[right].params.link_mass[2]
    distribution: {{type: normal, mean: 1, sd: 0.1}}
set:
  simulation.t_end: {}
  simulation.abs_tol: 1e-10
  simulation.rel_tol: 1e-10
metrics:
  - max_residual
  - energy_drift
  - max_abs_Qc
  - final_state
  - {{column: E, stats: [min, max, rms]}}
  - {{column: res_closure_x, stats: [max_abs]}}
)",
                     base.string(), samples, t_end);
}

fs::path write(const fs::path& p, const std::string& text) {
  std::ofstream(p, std::ios::binary) << text;
  return p;
}

// ---- the random streams: closed-form moments, independent of ukdyn's own outputs

TEST(SweepRandom, UniformAndNormalMoments) {
  const int n = 200000;
  double s = 0, s2 = 0, z1 = 0, z2 = 0, z4 = 0;
  for (int k = 0; k < n; ++k) {
    const double u = ukdyn::sweep_uniform(7, k, 3, 0);
    ASSERT_GE(u, 0.0);
    ASSERT_LT(u, 1.0);
    s += u;
    s2 += u * u;
    const double z = ukdyn::sweep_normal(7, k, 1);
    z1 += z;
    z2 += z * z;
    z4 += z * z * z * z;
  }
  // Uniform: mean 1/2, variance 1/12; normal: mean 0, variance 1, fourth moment 3 (5σ bounds).
  EXPECT_NEAR(s / n, 0.5, 5 * std::sqrt(1.0 / 12 / n));
  EXPECT_NEAR(s2 / n - (s / n) * (s / n), 1.0 / 12, 5 * std::sqrt(1.0 / 180 / n));
  EXPECT_NEAR(z1 / n, 0.0, 5 / std::sqrt(n));
  EXPECT_NEAR(z2 / n, 1.0, 5 * std::sqrt(2.0 / n));
  EXPECT_NEAR(z4 / n, 3.0, 5 * std::sqrt(96.0 / n));
  // Streams of different seeds, samples and parameters differ; the same key gives the same draw.
  EXPECT_EQ(ukdyn::sweep_uniform(1, 5, 0, 0), ukdyn::sweep_uniform(1, 5, 0, 0));
  EXPECT_NE(ukdyn::sweep_uniform(1, 5, 0, 0), ukdyn::sweep_uniform(2, 5, 0, 0));
  EXPECT_NE(ukdyn::sweep_uniform(1, 5, 0, 0), ukdyn::sweep_uniform(1, 6, 0, 0));
  EXPECT_NE(ukdyn::sweep_uniform(1, 5, 0, 0), ukdyn::sweep_uniform(1, 5, 1, 0));
}

TEST(SweepRandom, TruncatedNormalMeanMatchesClosedForm) {
  ScratchDir dir("ukdyn_sweep_tn");
  const fs::path base = kSource / "scenarios" / "paper_free.yaml";
  const fs::path f = write(dir.path / "s.yaml", random_sweep(base, 20000));
  const ukdyn::Sweep sw = ukdyn::load_sweep(f);
  // platform_mass ~ N(50, 5) restricted to [45, 60]: a = -1, b = 2 in standard units.
  const double a = -1, b = 2;
  const auto phi = [](double x) {
    return std::exp(-0.5 * x * x) / std::sqrt(2 * std::numbers::pi);
  };
  const auto Phi = [](double x) { return 0.5 * std::erfc(-x / std::sqrt(2.0)); };
  const double mass = Phi(b) - Phi(a);
  const double mean = 50 + 5 * (phi(a) - phi(b)) / mass;
  const double var =
      25 * (1 + (a * phi(a) - b * phi(b)) / mass - std::pow((phi(a) - phi(b)) / mass, 2));
  double s = 0, lo = 1e9, hi = -1e9;
  for (long k = 0; k < sw.samples; ++k) {
    const double v = ukdyn::sample_values(sw, k)[0];
    s += v;
    lo = std::min(lo, v);
    hi = std::max(hi, v);
  }
  const double n = static_cast<double>(sw.samples);
  EXPECT_NEAR(s / n, mean, 5 * std::sqrt(var / n));
  EXPECT_GE(lo, 45.0);
  EXPECT_LE(hi, 60.0);
  EXPECT_LT(lo, 45.1);  // the whole interval is reached
  EXPECT_GT(hi, 59.5);
}

#ifdef UKDYN_CLI
const fs::path kCli = UKDYN_CLI;

// ---- one table whatever the spread

TEST(SweepCli, ThreadsAndShardsGiveTheSameBytes) {
  ScratchDir dir("ukdyn_sweep_same");
  const fs::path f = write(dir.path / "s.yaml",
                           random_sweep(kSource / "scenarios" / "paper_free.yaml", 200, "0.05"));
  const auto d = [&](const std::string& n) { return (dir.path / n).string(); };
  auto r1 =
      run_cli(kCli, dir.path, "sweep " + sh(f) + " --no-figures --threads 1 -o " + sh(d("t1")));
  ASSERT_EQ(r1.exit_code, 0) << r1.err;
  auto r2 =
      run_cli(kCli, dir.path, "sweep " + sh(f) + " --no-figures --threads 2 -o " + sh(d("t2")));
  ASSERT_EQ(r2.exit_code, 0) << r2.err;
  std::string shard_dirs;
  for (int i = 0; i < 4; ++i) {
    auto r = run_cli(kCli, dir.path,
                     fmt::format("sweep {} --no-figures --threads 2 --shard {}/4 -o {}",
                                 sh(f.string()), i, sh(d("s" + std::to_string(i)))));
    ASSERT_EQ(r.exit_code, 0) << r.err;
    shard_dirs += " " + sh(d("s" + std::to_string(i)));
  }
  auto rm = run_cli(kCli, dir.path, "sweep merge " + sh(f) + " -o " + sh(d("merged")) + shard_dirs);
  ASSERT_EQ(rm.exit_code, 0) << rm.err;

  const std::string t1 = slurp(dir.path / "t1" / "results.csv");
  EXPECT_EQ(t1, slurp(dir.path / "t2" / "results.csv"));
  EXPECT_EQ(t1, slurp(dir.path / "merged" / "results.csv"));
  EXPECT_EQ(slurp(dir.path / "t1" / "summary.json"), slurp(dir.path / "t2" / "summary.json"));
  // A shard holds a quarter of the rows.
  EXPECT_EQ(lines(slurp(dir.path / "s1" / "results.csv")).size(), 1u + 50u);

  // The table: 200 completed rows; the physics of each row checked on its own terms.
  const auto ls = lines(t1);
  ASSERT_EQ(ls.size(), 201u);
  const auto h = cells(ls[0]);
  const auto st = column(h, "status"), pm = column(h, "platform_mass"),
             ed = column(h, "energy_drift"), mr = column(h, "max_residual"),
             emin = column(h, "min_E"), emax = column(h, "max_E");
  for (std::size_t i = 1; i < ls.size(); ++i) {
    const auto c = cells(ls[i]);
    ASSERT_EQ(c.size(), h.size());
    EXPECT_EQ(c[0], std::to_string(i - 1));
    EXPECT_EQ(c[st], "completed") << ls[i];
    const double m = std::stod(c[pm]);
    EXPECT_GE(m, 45.0);
    EXPECT_LE(m, 60.0);
    // No applied force: energy is conserved, so the drift is integration error only, and
    // max E - min E can not exceed twice the drift from E0.
    EXPECT_LT(std::stod(c[ed]), 1e-6);
    EXPECT_LE(std::stod(c[emax]) - std::stod(c[emin]), 2 * std::stod(c[ed]) + 1e-15);
    EXPECT_LT(std::stod(c[mr]), 1e-8);
  }
  const auto js = nlohmann::json::parse(slurp(dir.path / "t1" / "summary.json"));
  EXPECT_EQ(js["completed"], 200);
  EXPECT_EQ(js["failed"], 0);
  const auto& p = js["statistics_of_completed_samples"]["link2_mass"];
  EXPECT_LE(p["p05"].get<double>(), p["p50"].get<double>());
  EXPECT_LE(p["p50"].get<double>(), p["p95"].get<double>());
  EXPECT_NEAR(p["p50"].get<double>(), 4.0, 0.25);  // the median of U(3, 5), 200 draws
}

TEST(SweepCli, ExtractedSamplesRerunToTheSameNumbers) {
  ScratchDir dir("ukdyn_sweep_extract");
  const fs::path f =
      write(dir.path / "s.yaml", random_sweep(kSource / "scenarios" / "paper_free.yaml", 12));
  auto r = run_cli(kCli, dir.path,
                   "sweep " + sh(f) + " --no-figures -o " + sh((dir.path / "o").string()));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto ls = lines(slurp(dir.path / "o" / "results.csv"));
  const auto h = cells(ls[0]);
  for (long k : {0L, 5L, 11L}) {
    auto e = run_cli(kCli, dir.path, fmt::format("sweep {} --extract {}", sh(f.string()), k));
    ASSERT_EQ(e.exit_code, 0) << e.err;
    // The extracted scenario lives beside the base one (relative paths in it stay valid).
    const fs::path sc = write(dir.path / fmt::format("sample{}.yaml", k), e.out);
    const fs::path out = dir.path / fmt::format("run{}", k);
    auto s = run_cli(kCli, dir.path,
                     "simulate " + sh(sc.string()) + " --no-figures -q -o " + sh(out.string()));
    ASSERT_EQ(s.exit_code, 0) << s.err;
    // trajectory.csv prints each number in its shortest round-trip form: the same double.
    const auto tl = lines(slurp(out / "trajectory.csv"));
    const auto th = cells(tl[0]);
    const auto last = cells(tl.back());
    const auto row = cells(ls[static_cast<std::size_t>(k) + 1]);
    for (const char* q : {"dx1", "theta2", "theta5", "delta2"}) {
      EXPECT_EQ(fmt::format("{}", std::stod(last[column(th, q)])),
                row[column(h, std::string("final_") + q)])
          << "sample " << k << " " << q;
      const std::string v = std::string(q) + "_dot";
      EXPECT_EQ(fmt::format("{}", std::stod(last[column(th, v)])), row[column(h, "final_" + v)]);
    }
    double emax = -1e300, rmax = 0;
    for (std::size_t i = 1; i < tl.size(); ++i) {
      const auto c = cells(tl[i]);
      emax = std::max(emax, std::stod(c[column(th, "E")]));
      rmax = std::max(rmax, std::abs(std::stod(c[column(th, "res_closure_x")])));
    }
    EXPECT_EQ(fmt::format("{}", emax), row[column(h, "max_E")]);
    EXPECT_EQ(fmt::format("{}", rmax), row[column(h, "max_abs_res_closure_x")]);
    const auto js = nlohmann::json::parse(slurp(out / "summary.json"));
    EXPECT_EQ(fmt::format("{}", js["steps"].get<long>()), row[column(h, "steps")]);
  }
}

TEST(SweepCli, FailingSamplesAreRecordedAndTheSweepCompletes) {
  ScratchDir dir("ukdyn_sweep_fail");
  const fs::path f =
      write(dir.path / "s.yaml", fmt::format(R"(ukdyn_sweep: 1
name: failing
base: {}
mode: list
parameters:
  - name: platform_mass
    path: subsystems[left].params.platform_mass
    values: [50, -1, 50, 50]
  - name: theta1
    path: initial.q[3]
    values: [pi/2, pi/2, 1.0, pi/2]
  - name: abs_tol
    path: simulation.abs_tol
    values: [1e-10, 1e-10, 1e-10, 1e-10]
set:
  simulation.t_end: 0.05
metrics: [max_residual]
)",
                                             (kSource / "scenarios" / "paper_free.yaml").string()));
  auto r = run_cli(kCli, dir.path, "sweep " + sh(f) + " -o " + sh((dir.path / "o").string()));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("2 failed"), std::string::npos) << r.out;
  const auto ls = lines(slurp(dir.path / "o" / "results.csv"));
  ASSERT_EQ(ls.size(), 5u);
  const auto h = cells(ls[0]);
  const auto st = column(h, "status"), why = column(h, "reason");
  EXPECT_EQ(cells(ls[1])[st], "completed");
  EXPECT_EQ(cells(ls[2])[st], "invalid_scenario");
  EXPECT_NE(cells(ls[2])[why].find("platform_mass"), std::string::npos) << ls[2];
  EXPECT_EQ(cells(ls[3])[st], "inconsistent_initial");
  EXPECT_EQ(cells(ls[4])[st], "completed");
  const auto js = nlohmann::json::parse(slurp(dir.path / "o" / "summary.json"));
  EXPECT_EQ(js["failed"], 2);
  EXPECT_EQ(js["failures"][0]["sample"], 1);
  EXPECT_EQ(js["failures"][1]["status"], "inconsistent_initial");
  // The percentiles are over the completed samples only.
  EXPECT_EQ(js["statistics_of_completed_samples"]["max_residual"]["count"], 2);
}

TEST(SweepCli, KilledSweepResumesToTheSameTable) {
  ScratchDir dir("ukdyn_sweep_resume");
  // 60 samples of 1 s of motion each (~10 ms of CPU each) on one thread.
  const fs::path f =
      write(dir.path / "s.yaml", random_sweep(kSource / "scenarios" / "paper_free.yaml", 60, "1"));
  const std::string full = (dir.path / "full").string(), part = (dir.path / "part").string();
  auto r = run_cli(kCli, dir.path, "sweep " + sh(f) + " --no-figures --threads 2 -o " + sh(full));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const fs::path pidfile = dir.path / "pid";
  const std::string cmd = sh(kCli.string()) + " sweep " + sh(f.string()) +
                          " --no-figures --threads 1 -q -o " + sh(part) +
                          " > /dev/null 2>&1 & echo $! > " + sh(pidfile.string());
  ASSERT_EQ(std::system(cmd.c_str()), 0);
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  const long pid = std::stol(slurp(pidfile));
  // Wait until at least 10 rows are journalled, then kill -9 (no chance to tidy up).
  const auto t0 = std::chrono::steady_clock::now();
  std::size_t journalled = 0;
  while (std::chrono::steady_clock::now() - t0 < std::chrono::seconds(20)) {
    journalled = lines(slurp(fs::path(part) / "journal.csv")).size();
    if (journalled > 11) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  ASSERT_EQ(std::system(fmt::format("kill -9 {}", pid).c_str()), 0);
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  ASSERT_GT(journalled, 11u);
  EXPECT_FALSE(fs::exists(fs::path(part) / "results.csv"));  // it did not finish
  auto again =
      run_cli(kCli, dir.path, "sweep " + sh(f) + " --no-figures --threads 2 -o " + sh(part));
  ASSERT_EQ(again.exit_code, 0) << again.err;
  // Some rows came from the journal, the others were computed now.
  long computed = -1, resumed = -1;
  const auto pos = again.out.find("samples ");
  ASSERT_NE(pos, std::string::npos) << again.out;
  ASSERT_EQ(std::sscanf(again.out.c_str() + pos, "samples %*d (%ld computed, %ld from the journal)",
                        &computed, &resumed),
            2)
      << again.out;
  EXPECT_GE(resumed, 10);
  EXPECT_LT(resumed, 60);
  EXPECT_EQ(computed + resumed, 60);
  EXPECT_EQ(slurp(fs::path(full) / "results.csv"), slurp(fs::path(part) / "results.csv"));
  EXPECT_EQ(slurp(fs::path(full) / "summary.json"), slurp(fs::path(part) / "summary.json"));
}

TEST(SweepCli, GridWritesHeatMaps) {
  ScratchDir dir("ukdyn_sweep_grid");
  const fs::path f =
      write(dir.path / "s.yaml", fmt::format(R"(ukdyn_sweep: 1
name: grid
base: {}
mode: grid
parameters:
  - name: load_mass
    path: ["subsystems[left].params.link_mass[2]", "subsystems[right].params.link_mass[2]"]
    range: {{from: 0.5, to: 2, count: 3}}
  - name: lift
    path:
      - {{path: "constraints[traj].y.mean", scale: 0.5}}
      - {{path: "constraints[traj].y.amplitude", scale: -0.5}}
    values: [0.5, 1]
set:
  simulation.t_end: 0.2
  simulation.abs_tol: 1e-10
  simulation.rel_tol: 1e-10
metrics: [max_residual, {{column: Qc_theta2, stats: [max_abs]}}]
)",
                                             (kSource / "scenarios" / "paper.yaml").string()));
  auto r = run_cli(kCli, dir.path, "sweep " + sh(f) + " -o " + sh((dir.path / "o").string()));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto ls = lines(slurp(dir.path / "o" / "results.csv"));
  ASSERT_EQ(ls.size(), 7u);
  // Row-major: the last parameter fastest.
  EXPECT_EQ(cells(ls[1])[1] + "," + cells(ls[1])[2], "0.5,0.5");
  EXPECT_EQ(cells(ls[2])[1] + "," + cells(ls[2])[2], "0.5,1");
  EXPECT_EQ(cells(ls[6])[1] + "," + cells(ls[6])[2], "2,1");
  // A heavier load at the same lift needs a larger torque at the shoulder.
  const auto h = cells(ls[0]);
  const auto qc = column(h, "max_abs_Qc_theta2");
  EXPECT_GT(std::stod(cells(ls[5])[qc]), std::stod(cells(ls[1])[qc]));
  if (r.out.find("figures in") != std::string::npos) {
    EXPECT_TRUE(fs::exists(dir.path / "o" / "figures" / "heat_max_abs_Qc_theta2.png"));
    EXPECT_TRUE(fs::exists(dir.path / "o" / "figures" / "hist_max_residual.png"));
  }
}

// A sweep of a control scenario (docs/sweeps.md, "Control scenarios"): each sample runs the
// closed loop, the `plant.` paths perturb the plant only (the load's mass and its CoM, through
// control.plant_set), and every control metric of a row equals the one that `ukdyn simulate`
// reports for the extracted sample (summary.json → control, trajectory.csv), number for number.
TEST(SweepCli, ControlSweepRowsEqualTheExtractedSamplesRuns) {
  ScratchDir dir("ukdyn_sweep_control");
  // The base and its plant file side by side in the scratch folder (the extracted samples are
  // saved beside them, so that `plant:` resolves).
  for (const char* f : {"paper_control.yaml", "paper_generic_exact_inertia.yaml"})
    write(dir.path / f, slurp(kSource / "scenarios" / f));
  const fs::path f = write(dir.path / "s.yaml", R"(ukdyn_sweep: 1
name: control_test
base: paper_control.yaml
mode: random
seed: 7
samples: 3
parameters:
  - name: load_mass
    path: ["plant.subsystems[left].parameters.m3", "plant.subsystems[right].parameters.m3"]
    distribution: {type: uniform, low: 0.8, high: 1.2}
  - name: load_length
    path: "plant.subsystems[left].parameters.l3"
    distribution: {type: uniform, low: 0.38, high: 0.42}
set:
  simulation.t_end: 0.2
  simulation.abs_tol: 1e-9
  simulation.rel_tol: 1e-9
metrics:
  - max_residual
  - control
  - squeeze_force
  - final_state
  - {column: u_theta2, stats: [max_abs]}
)");
  auto r =
      run_cli(kCli, dir.path,
              "sweep " + sh(f) + " --threads 2 --no-figures -o " + sh((dir.path / "o").string()));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto ls = lines(slurp(dir.path / "o" / "results.csv"));
  ASSERT_EQ(ls.size(), 4u);
  const auto h = cells(ls[0]);
  std::set<std::string> distinct_u;
  for (long k = 0; k < 3; ++k) {
    const auto row = cells(ls[static_cast<std::size_t>(k) + 1]);
    ASSERT_EQ(row[column(h, "status")], "completed") << ls[static_cast<std::size_t>(k) + 1];
    auto e = run_cli(kCli, dir.path, fmt::format("sweep {} --extract {}", sh(f.string()), k));
    ASSERT_EQ(e.exit_code, 0) << e.err;
    // The perturbation goes to the plant (control.plant_set), the model keeps its load.
    EXPECT_NE(e.out.find("plant_set"), std::string::npos) << e.out;
    const fs::path sc = write(dir.path / fmt::format("sample{}.yaml", k), e.out);
    const auto loaded = ukdyn::load_scenario(sc);
    ASSERT_TRUE(loaded.control && loaded.control->plant);
    const auto base = ukdyn::load_scenario(dir.path / "paper_control.yaml");
    EXPECT_EQ(loaded.system->coordinate_names(), base.system->coordinate_names());
    const fs::path out = dir.path / fmt::format("run{}", k);
    auto s = run_cli(kCli, dir.path,
                     "simulate " + sh(sc.string()) + " --no-figures -q -o " + sh(out.string()));
    ASSERT_EQ(s.exit_code, 0) << s.err;
    const auto js = nlohmann::json::parse(slurp(out / "summary.json"));
    const auto& c = js["control"];
    for (const char* m : {"max_abs_e", "max_abs_e_second_half", "max_abs_u", "max_abs_udot",
                          "max_closure_force", "max_squeeze_force"}) {
      ASSERT_TRUE(c.contains(m)) << m;
      EXPECT_EQ(fmt::format("{}", c[m].get<double>()), row[column(h, m)]) << "sample " << k << m;
    }
    EXPECT_FALSE(c["saturated"].get<bool>());
    EXPECT_EQ(row[column(h, "saturation_time")], "0");
    EXPECT_EQ(fmt::format("{}", js["steps"].get<long>()), row[column(h, "steps")]);
    EXPECT_EQ(fmt::format("{}", js["max_abs_position_residual_all"].get<double>()),
              row[column(h, "max_residual")]);
    const auto tl = lines(slurp(out / "trajectory.csv"));
    const auto th = cells(tl[0]);
    const auto last = cells(tl.back());
    for (const char* q : {"dx1", "theta2", "theta6", "dy2"}) {
      EXPECT_EQ(fmt::format("{}", std::stod(last[column(th, q)])),
                row[column(h, std::string("final_") + q)])
          << "sample " << k << " " << q;
    }
    double umax = 0;
    for (std::size_t i = 1; i < tl.size(); ++i)
      umax = std::max(umax, std::abs(std::stod(cells(tl[i])[column(th, "u_theta2")])));
    EXPECT_EQ(fmt::format("{}", umax), row[column(h, "max_abs_u_theta2")]);
    distinct_u.insert(row[column(h, "max_abs_e_second_half")]);
  }
  EXPECT_EQ(distinct_u.size(), 3u);  // the plant perturbation reaches the closed loop
}

TEST(SweepCli, BadSweepFilesNameFileLineAndKey) {
  ScratchDir dir("ukdyn_sweep_bad");
  const std::string base = (kSource / "scenarios" / "paper_free.yaml").string();
  struct Case {
    std::string text, expect;
  };
  const std::vector<Case> cases = {
      {"ukdyn_sweep: 1\nname: b\nbase: " + base +
           "\nmode: grid\nparameters:\n  - name: m\n    path: subsystems[left].params.mass\n"
           "    values: [1]\n",
       ":7:11: key 'parameters[0].path': 'subsystems[left].params.mass': 'subsystems[left].params' "
       "has no key 'mass'"},
      {"ukdyn_sweep: 1\nname: b\nbase: " + base + "\nmode: grid\ncolour: red\nparameters: []\n",
       ":5:1: key 'colour': unknown key"},
      {"ukdyn_sweep: 1\nname: b\nbase: " + base +
           "\nmode: random\nseed: 1\nsamples: 3\nparameters:\n  - name: m\n"
           "    path: gravity\n    distribution: {type: gamma, low: 1}\n",
       ":10:26: key 'parameters[0].distribution.type': unknown distribution 'gamma'"},
      // A control scenario's plant: a `plant.` path must exist in the plant's tree.
      {"ukdyn_sweep: 1\nname: b\nbase: " + (kSource / "scenarios" / "paper_control.yaml").string() +
           "\nmode: grid\nparameters:\n  - name: m\n"
           "    path: plant.subsystems[left].parameters.mass\n    values: [1]\n",
       ":7:11: key 'parameters[0].path': 'plant.subsystems[left].parameters.mass': in the plant: "
       "'subsystems[left].parameters' has no key 'mass'"},
      // ... and needs a control scenario; so do the control metrics.
      {"ukdyn_sweep: 1\nname: b\nbase: " + base +
           "\nmode: grid\nparameters:\n  - name: m\n    path: plant.gravity\n    values: [1]\n",
       ":7:11: key 'parameters[0].path': 'plant.gravity': a 'plant.' path needs a base scenario "
       "with a control: section"},
      {"ukdyn_sweep: 1\nname: b\nbase: " + base +
           "\nmode: grid\nparameters:\n  - name: m\n    path: gravity\n    values: [1]\n"
           "metrics: [control]\n",
       ":9:10: key 'metrics': the metrics control and squeeze_force need a base scenario with a "
       "control: section"},
  };
  for (std::size_t i = 0; i < cases.size(); ++i) {
    const fs::path f = write(dir.path / fmt::format("b{}.yaml", i), cases[i].text);
    auto r = run_cli(kCli, dir.path, "sweep " + sh(f) + " -o " + sh((dir.path / "o").string()));
    EXPECT_EQ(r.exit_code, 2) << i;
    EXPECT_NE(r.err.find(f.string() + cases[i].expect), std::string::npos) << r.err;
  }
}

// ---- issue 13, item 4

TEST(InitialExpressions, SqrtAndParametersAreAccepted) {
  ScratchDir dir("ukdyn_initial_expr");
  std::string text = slurp(kSource / "scenarios" / "paper_free.yaml");
  const std::string from = "  q: [0, 0, 0, pi/2, -pi/3, 0, 1.6, 0, -pi, pi/2, -pi/3, 0]";
  const auto pos = text.find(from);
  ASSERT_NE(pos, std::string::npos);
  text.replace(pos, from.size(),
               "  parameters: {half: 1/2, gap: 0.8}\n"
               "  q: [0, sqrt(0.09) - 0.3, 0, pi*half, -pi/3, 0, 2*gap, 0, -pi, acos(0), "
               "-asin(sqrt(3)/2), 0]");
  const ukdyn::Scenario sc = ukdyn::load_scenario_text(text, dir.path / "x.yaml");
  EXPECT_EQ(sc.q0(1), 0.0);
  EXPECT_NEAR(sc.q0(3), std::numbers::pi / 2, 1e-15);
  EXPECT_NEAR(sc.q0(6), 1.6, 1e-15);
  EXPECT_NEAR(sc.q0(9), std::numbers::pi / 2, 1e-15);
  EXPECT_NEAR(sc.q0(10), -std::numbers::pi / 3, 1e-15);
  // A name that is not a parameter is refused at its key.
  std::string bad = text;
  bad.replace(bad.find("2*gap"), 5, "2*gapp");
  try {
    ukdyn::load_scenario_text(bad, dir.path / "x.yaml");
    ADD_FAILURE() << "accepted an unknown name";
  } catch (const ukdyn::ScenarioError& e) {
    EXPECT_NE(std::string(e.what()).find("key 'initial.q[6]'"), std::string::npos) << e.what();
  }
}

TEST(SimulateProgress, LinesWhenStderrIsNotATerminal) {
  ScratchDir dir("ukdyn_progress_lines");
  auto r = run_cli(kCli, dir.path,
                   "simulate " + sh((kSource / "scenarios" / "paper_free.yaml").string()) +
                       " --no-figures --progress-every 0.02 -o " + sh((dir.path / "o").string()));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("ukdyn: t = "), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find('\r'), std::string::npos);  // whole lines, no bar
}
#endif  // UKDYN_CLI

}  // namespace

// "i/N" exactly: decimal digits, 0 <= i < N, nothing around them (a shard option with trailing
// garbage used to be cut at the garbage and run as if it were not there).
TEST(Sweep, ShardTextIsParsedWhole) {
  int i = -1, n = -1;
  EXPECT_TRUE(ukdyn::parse_shard("0/1", i, n));
  EXPECT_EQ(i, 0);
  EXPECT_EQ(n, 1);
  EXPECT_TRUE(ukdyn::parse_shard("3/4", i, n));
  EXPECT_EQ(i, 3);
  EXPECT_EQ(n, 4);
  for (const char* bad : {"1/2junk", " 1/2", "1/2 ", "+1/2", "-1/2", "2/2", "1/0", "1/", "/2", "1",
                          "", "1//2", "1/2/3", "0x1/2", "99999999999/2"}) {
    EXPECT_FALSE(ukdyn::parse_shard(bad, i, n)) << "'" << bad << "'";
  }
}
