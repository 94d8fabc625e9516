// Same input → same output bytes in every process (issue 9, item 3). GiNaC orders the terms of sums
// and products by hash values seeded from addresses (ginac/hash_seed.h), so with address-space
// randomisation a compiled tape used to add the same terms in a different order in each process
// (ukdyn/symbolic/canonical.hpp). Every scenario shipped in scenarios/ (benchmarks/ included) is
// run twice, in two processes, with `ukdyn simulate` (trajectory.csv) and `ukdyn eval` (stdout),
// on a short horizon; the bytes must be identical.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>

#include "cli_run.hpp"
#include "ukdyn/io/scenario.hpp"

#ifdef UKDYN_CLI

namespace {

namespace fs = std::filesystem;
using ukdyn_test::shell;
using ukdyn_test::slurp;
const fs::path kSource = UKDYN_SOURCE_DIR;

// The scenario tree copied (URDF files and all) with every t_end shortened.
fs::path short_copy() {
  const fs::path dir = fs::temp_directory_path() / ("ukdyn_repro_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::copy(kSource / "scenarios", dir, fs::copy_options::recursive);
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    if (e.path().extension() != ".yaml") continue;
    if (e.path().parent_path().filename() == "sweeps") continue;  // sweep files (docs/sweeps.md)
    const ukdyn::Scenario sc = ukdyn::load_scenario(e.path());
    const double span = std::min(sc.sim.t_end - sc.sim.t0, std::max(0.05, 3 * sc.sim.sample_dt));
    std::ostringstream t_end;
    t_end.precision(17);
    t_end << "t_end: " << sc.sim.t0 + span;
    const std::string text =
        std::regex_replace(slurp(e.path()), std::regex("t_end:[^\\n#]*"), t_end.str(),
                           std::regex_constants::format_first_only);
    std::ofstream(e.path(), std::ios::binary) << text;
  }
  return dir;
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

TEST(Reproducibility, EveryScenarioGivesTheSameBytesInTwoProcesses) {
  if (slurp("/proc/sys/kernel/randomize_va_space").rfind('0', 0) == 0)
    GTEST_SKIP() << "address-space randomisation is off: two processes would not differ anyway";
  const fs::path dir = short_copy();
  int scenarios = 0;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    if (e.path().extension() != ".yaml") continue;
    if (e.path().parent_path().filename() == "sweeps") continue;  // sweep files (docs/sweeps.md)
    ++scenarios;
    const ukdyn::Scenario sc = ukdyn::load_scenario(e.path());
    const std::string stem = fs::relative(e.path(), dir).replace_extension().string();
    std::string csv[2], eval[2];
    for (int k = 0; k < 2; ++k) {
      const fs::path out = dir / "out" / (stem + "_" + std::to_string(k));
      const int rc = shell("'" + std::string(UKDYN_CLI) + "' simulate --quiet --no-figures '" +
                        e.path().string() + "' --out '" + out.string() + "' > /dev/null 2>&1");
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
      const int rc = shell("'" + std::string(UKDYN_CLI) + "' eval '" + e.path().string() + "' < '" +
                        in.string() + "' > '" + out.string() + "' 2>/dev/null");
      ASSERT_EQ(rc, 0) << stem << ": eval failed";
      eval[k] = slurp(out);
    }
    EXPECT_TRUE(eval[0] == eval[1]) << stem << ": eval output differs between two processes";
  }
  EXPECT_GE(scenarios, 10);
  fs::remove_all(dir);
}

}  // namespace

#endif  // UKDYN_CLI
