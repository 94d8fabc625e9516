// Same input → same output bytes in every process. GiNaC orders the terms of sums
// and products by hash values seeded from addresses (ginac/hash_seed.h), so with address-space
// randomisation a compiled tape used to add the same terms in a different order in each process
// (ukdyn/symbolic/canonical.hpp). Every scenario shipped in scenarios/ (benchmarks/ included) is
// run twice, in two processes, with `ukdyn simulate` (trajectory.csv) and `ukdyn eval` (stdout),
// on a short horizon; the bytes must be identical. One test per scenario
// (Shipped/Reproducibility.SameBytesInTwoProcesses/<scenario>). DeriveCli.SameBytesInTwoProcesses
// does the same for the printed derivations (`ukdyn derive`, every format).
#include <gtest/gtest.h>

#include <algorithm>
#include <cctype>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "cli_run.hpp"
#include "ukdyn/scenario/scenario.hpp"

#ifdef UKDYN_CLI

namespace {

namespace fs = std::filesystem;
using ukdyn_test::shell;
using ukdyn_test::slurp;
const fs::path kSource = UKDYN_SOURCE_DIR;

// Every scenario shipped in scenarios/ (benchmarks/ included; sweep files, optimisation problems and
// sizing files not: docs/sweeps.md, docs/optimization.md, docs/sizing.md), as
// paths relative to scenarios/, sorted (one ctest entry each, in a stable order).
std::vector<std::string> shipped_scenarios() {
  std::vector<std::string> list;
  const fs::path root = kSource / "scenarios";
  for (const auto& e : fs::recursive_directory_iterator(root)) {
    if (e.path().extension() != ".yaml") continue;
    const fs::path folder = e.path().parent_path().filename();
    if (folder == "sweeps" || folder == "optimize" || folder == "sizing") continue;
    list.push_back(fs::relative(e.path(), root).generic_string());
  }
  std::sort(list.begin(), list.end());
  return list;
}

// The scenario tree copied (URDF files and all, which scenarios name by relative path, and the
// robots/ folder beside it, which scenarios name as ../robots/) into a folder of this test's own,
// with the t_end of `scenario` shortened; returns the path of the scenarios' copy.
fs::path short_copy(const std::string& scenario, const std::string& tag) {
  const fs::path root =
      fs::temp_directory_path() / ("ukdyn_repro_" + std::to_string(::getpid()) + "_" + tag);
  fs::remove_all(root);
  const fs::path dir = root / "scenarios";
  fs::create_directories(root);
  fs::copy(kSource / "scenarios", dir, fs::copy_options::recursive);
  fs::copy(kSource / "robots", root / "robots", fs::copy_options::recursive);
  const fs::path file = dir / scenario;
  const ukdyn::Scenario sc = ukdyn::load_scenario(file);
  const double span = std::min(sc.sim.t_end - sc.sim.t0, std::max(0.05, 3 * sc.sim.sample_dt));
  std::ostringstream t_end;
  t_end.precision(17);
  t_end << "t_end: " << sc.sim.t0 + span;
  const std::string text = std::regex_replace(slurp(file), std::regex("t_end:[^\\n#]*"),
                                              t_end.str(), std::regex_constants::format_first_only);
  std::ofstream(file, std::ios::binary) << text;
  return dir;
}

// A gtest name for a scenario path: benchmarks/n_four_bar_N40.yaml → benchmarks_n_four_bar_N40.
std::string test_name(const ::testing::TestParamInfo<std::string>& info) {
  std::string n = fs::path(info.param).replace_extension().generic_string();
  for (char& c : n) {
    if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
  }
  return n;
}

// {"t", "q", "qd"} of the last row of a trajectory.csv (t, q..., qd...).
std::string last_state_json(const fs::path& csv, Eigen::Index n) {
  std::istringstream in(slurp(csv));
  std::string line, last;
  while (std::getline(in, line)) {
    if (!line.empty()) last = line;
  }
  std::vector<std::string> cells;
  std::stringstream ss(last);
  for (std::string c; std::getline(ss, c, ',');) cells.push_back(c);
  std::string json = "{\"t\": " + cells.at(0) + ", \"q\": [";
  for (Eigen::Index i = 0; i < n; ++i)
    json += (i ? "," : "") + cells.at(static_cast<std::size_t>(1 + i));
  json += "], \"qd\": [";
  for (Eigen::Index i = 0; i < n; ++i)
    json += (i ? "," : "") + cells.at(static_cast<std::size_t>(1 + n + i));
  return json + "]}\n";
}

// One ctest entry per scenario (they run in parallel under ctest -j, and each has its own time
// limit: the sanitizer build, make sanitize, runs every process 10-20x slower).
class Reproducibility : public ::testing::TestWithParam<std::string> {};

TEST_P(Reproducibility, SameBytesInTwoProcesses) {
  if (slurp("/proc/sys/kernel/randomize_va_space").rfind('0', 0) == 0)
    GTEST_SKIP() << "address-space randomisation is off: two processes would not differ anyway";
  const std::string stem = test_name({GetParam(), 0});
  const fs::path dir = short_copy(GetParam(), stem);
  const fs::path file = dir / GetParam();
  const ukdyn::Scenario sc = ukdyn::load_scenario(file);
  std::string csv[2], eval[2];
  for (int k = 0; k < 2; ++k) {
    const fs::path out = dir / "out" / (stem + "_" + std::to_string(k));
    const int rc = shell("'" + std::string(UKDYN_CLI) + "' simulate --quiet --no-figures '" +
                         file.string() + "' --out '" + out.string() + "' > /dev/null 2>&1");
    ASSERT_EQ(rc, 0) << stem << ": simulate failed";
    csv[k] = slurp(out / "trajectory.csv");
    ASSERT_FALSE(csv[k].empty()) << stem;
  }
  EXPECT_TRUE(csv[0] == csv[1]) << stem << ": trajectory.csv differs between two processes";
  const fs::path in = dir / "out" / (stem + "_eval_in.jsonl");
  {
    // The state of the last sample (velocities nonzero).
    std::ofstream(in) << last_state_json(dir / "out" / (stem + "_0") / "trajectory.csv",
                                         sc.system->dof());
  }
  for (int k = 0; k < 2; ++k) {
    const fs::path out = dir / "out" / (stem + "_eval_" + std::to_string(k) + ".jsonl");
    const int rc = shell("'" + std::string(UKDYN_CLI) + "' eval '" + file.string() + "' < '" +
                         in.string() + "' > '" + out.string() + "' 2>/dev/null");
    ASSERT_EQ(rc, 0) << stem << ": eval failed";
    eval[k] = slurp(out);
  }
  EXPECT_TRUE(eval[0] == eval[1]) << stem << ": eval output differs between two processes";
  fs::remove_all(dir.parent_path());
}

INSTANTIATE_TEST_SUITE_P(Shipped, Reproducibility, ::testing::ValuesIn(shipped_scenarios()),
                         test_name);

// The list above is the shipped tree, not an empty directory walk.
TEST(ReproducibilityList, CoversTheShippedScenarios) {
  const auto list = shipped_scenarios();
  EXPECT_GE(list.size(), 10u);
  EXPECT_NE(std::find(list.begin(), list.end(), "paper.yaml"), list.end());
  EXPECT_TRUE(std::any_of(list.begin(), list.end(),
                          [](const std::string& s) { return s.rfind("benchmarks/", 0) == 0; }));
}

}  // namespace

#endif  // UKDYN_CLI

#ifdef UKDYN_CLI

namespace {

namespace fs = std::filesystem;

// `ukdyn derive` in every format, twice, in two processes: the same bytes. GiNaC's printers list
// the terms of a sum in GiNaC's operand order, which differs between processes; the printers of
// src/symbolic/canonical_print.cpp use an order of their own. A scenario by definitions (both arms
// of the paper, five constraint blocks) and one by serial chains with a weld to a load
// (paper_chain.yaml: frame constraints derived from the chains' link poses).
TEST(DeriveCli, SameBytesInTwoProcesses) {
  if (ukdyn_test::slurp("/proc/sys/kernel/randomize_va_space").rfind('0', 0) == 0)
    GTEST_SKIP() << "address-space randomisation is off: two processes would not differ anyway";
  const ukdyn_test::ScratchDir dir("ukdyn_derive_repro");
  for (const std::string scenario : {"paper_generic.yaml", "paper_chain.yaml"}) {
    for (const std::string format : {"latex", "c", "matlab", "text"}) {
      std::string out[2];
      for (int k = 0; k < 2; ++k) {
        const fs::path file = dir.path / (format + "_" + std::to_string(k) + ".txt");
        const int rc = ukdyn_test::shell(
            ukdyn_test::sh(UKDYN_CLI) + " derive -f " + format + " " +
            ukdyn_test::sh((fs::path(UKDYN_SOURCE_DIR) / "scenarios" / scenario).string()) + " > " +
            ukdyn_test::sh(file.string()) + " 2>&1");
        ASSERT_EQ(rc, 0) << scenario << " " << format << ": " << ukdyn_test::slurp(file);
        out[k] = ukdyn_test::slurp(file);
        ASSERT_GT(out[k].size(), 1000u) << scenario << " " << format;
      }
      EXPECT_TRUE(out[0] == out[1])
          << scenario << ", --format " << format << ": the output differs between two processes";
    }
  }
}

}  // namespace

#endif  // UKDYN_CLI
