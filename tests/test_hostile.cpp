// Hostile input (issue 4, item 6): every scenario in tests/hostile/ and a few generated at test
// time (too big to commit) is run through `ukdyn simulate` under `timeout`. Each must end with its
// own clear error naming the file (exit 2), or, where the problem only shows once the run starts,
// stop cleanly (exit 1, summary.json "incomplete" with the reason, trajectory.incomplete.csv, no
// trajectory.csv). Never a signal, never a hang, never output that looks complete.
//
// A corpus file starts with "# expect: <substring of the error message>", optionally followed by
// "# exit: 1" for a run that starts and must stop cleanly (default: exit 2, rejected on loading).
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "cli_run.hpp"

#ifdef UKDYN_CLI

namespace {

namespace fs = std::filesystem;
using ukdyn_test::sh;
using ukdyn_test::slurp;
const fs::path kSource = UKDYN_SOURCE_DIR;
constexpr int kTimeoutSeconds = 20;

const fs::path& scratch() { return ukdyn_test::process_scratch("ukdyn_hostile_test"); }

struct Outcome {
  int exit_code = -1;  // 124: timed out (hang); > 128: killed by a signal (crash)
  std::string err;
};

// `ukdyn simulate FILE`, with `optimize` set `ukdyn optimize FILE` (a problem file), or with
// `linearize` set `ukdyn linearize FILE ARGS...` (its JSON to /dev/null).
Outcome simulate(const fs::path& scenario, const fs::path& out_dir, bool optimize = false,
                 bool linearize = false, const std::vector<std::string>& args = {}) {
  const fs::path err = scratch() / "stderr.txt";
  std::string cmd = "timeout -k 5 " + std::to_string(kTimeoutSeconds) + " " + sh(UKDYN_CLI);
  if (linearize) {
    cmd += " linearize " + sh(scenario.string());
    for (const auto& a : args) cmd += " " + sh(a);
  } else {
    cmd += (optimize ? " optimize " : " simulate ") + sh(scenario.string()) + " --out " +
           sh(out_dir.string()) + (optimize ? " --quiet" : " --no-figures --quiet");
  }
  cmd += " < /dev/null > /dev/null 2> " + sh(err.string());
  const int rc = std::system(cmd.c_str());
  Outcome o;
  o.exit_code = WIFEXITED(rc) ? WEXITSTATUS(rc) : 128 + (WIFSIGNALED(rc) ? WTERMSIG(rc) : 0);
  o.err = slurp(err);
  return o;
}

struct Case {
  std::string name;
  fs::path file;       // a corpus file, or empty for a generated one
  std::string expect;  // substring of the message
  int exit_code = 2;   // 2: rejected on loading; 1: the run starts and stops cleanly
  std::string (*generate)() = nullptr;  // writes the scenario text at test time
  bool optimize = false;  // a problem file for `ukdyn optimize` (`# command: optimize`)
  // `# command: linearize` and `# args: A B ...`: `ukdyn linearize FILE A B ...`, an argument
  // starting with @ a path relative to tests/hostile/ (a state file, a run's CSV).
  bool linearize = false;
  std::vector<std::string> args = {};
};

void PrintTo(const Case& c, std::ostream* os) { *os << c.name; }

// ---- generated cases: too big (or too odd) to commit

// A valid one-arm scenario, with `extra` spliced in before `initial:`.
std::string arm_scenario(const std::string& coordinates = "[x, y, d, a1, a2, a3]",
                         const std::string& q = "[0, 0, 0, 0.5, -0.5, 0]",
                         const std::string& extra = "") {
  return "ukdyn: 1\nname: generated\nsubsystems:\n  - {name: arm, type: mobile_manipulator, "
         "coordinates: " +
         coordinates + "}\n" + extra + "initial:\n  q: " + q +
         "\nsimulation:\n  t_end: 1\n  sample_dt: 0.1\n";
}

std::string list_of(std::size_t n, const std::string& prefix) {
  std::string s = "[";
  for (std::size_t i = 0; i < n; ++i) s += (i ? ", " : "") + prefix + std::to_string(i);
  return s + "]";
}

std::string gen_zero_bytes() { return ""; }
std::string gen_huge_q() { return arm_scenario("[x, y, d, a1, a2, a3]", list_of(100000, "")); }
std::string gen_huge_coordinates() { return arm_scenario(list_of(100000, "c")); }
std::string gen_long_coordinate_name() {
  return arm_scenario("[" + std::string(1 << 20, 'x') + ", y, d, a1, a2, a3]");
}
std::string gen_long_constraint_name() {
  return arm_scenario("[x, y, d, a1, a2, a3]", "[0, 0, 0, 0.5, -0.5, 0]",
                      "constraints:\n  - {type: coordinate, name: " + std::string(5000, 'c') +
                          ", coordinate: x}\n");
}
std::string gen_over_4mib() {
  std::string s = arm_scenario();
  const std::string pad = "# " + std::string(1000, '#') + "\n";
  while (s.size() <= (4u << 20)) s += pad;
  return s;
}
std::string gen_deep_sequence() {
  return arm_scenario() + "description: " + std::string(10000, '[') + std::string(10000, ']') +
         "\n";
}
std::string gen_deep_mapping() {
  std::string s = arm_scenario() + "description: ";
  for (int i = 0; i < 10000; ++i) s += "{a: ";
  s += "1";
  for (int i = 0; i < 10000; ++i) s += "}";
  return s + "\n";
}
std::string gen_deep_block_sequence() {  // "- - - - ... x" on one line: 10000 nested block lists
  std::string s = arm_scenario() + "description:\n  ";
  for (int i = 0; i < 10000; ++i) s += "- ";
  return s + "x\n";
}
std::string gen_random_bytes() {
  std::mt19937 rng(20240601);
  std::string s(1 << 16, '\0');
  for (char& c : s) c = static_cast<char>(rng() & 0xff);
  return s;
}

std::vector<Case> generated_cases() {
  return {
      {"gen_zero_bytes", {}, "must be a YAML mapping", 2, gen_zero_bytes},
      {"gen_huge_q", {}, "key 'initial.q': expected 6 numbers, got 100000", 2, gen_huge_q},
      {"gen_huge_coordinates",
       {},
       "key 'subsystems[0].coordinates': too many coordinates",
       2,
       gen_huge_coordinates},
      {"gen_long_coordinate_name",
       {},
       "key 'subsystems[0].coordinates[0]': a name must be",
       2,
       gen_long_coordinate_name},
      {"gen_long_constraint_name",
       {},
       "key 'constraints[0].name': a name must be",
       2,
       gen_long_constraint_name},
      {"gen_over_4mib", {}, "larger than 4 MiB", 2, gen_over_4mib},
      {"gen_deep_sequence", {}, "YAML syntax error: nested too deeply", 2, gen_deep_sequence},
      {"gen_deep_mapping", {}, "YAML syntax error: nested too deeply", 2, gen_deep_mapping},
      {"gen_deep_block_sequence",
       {},
       "YAML syntax error: nested too deeply",
       2,
       gen_deep_block_sequence},
      {"gen_random_bytes", {}, "YAML syntax error", 2, gen_random_bytes},
  };
}

// ---- the committed corpus

fs::path dir_of_corpus() { return kSource / "tests" / "hostile"; }

std::vector<Case> corpus_cases() {
  std::vector<Case> cases;
  const fs::path dir = dir_of_corpus();
  std::vector<fs::path> files;
  for (const auto& e : fs::directory_iterator(dir)) {
    if (e.path().extension() == ".yaml") files.push_back(e.path());
  }
  std::sort(files.begin(), files.end());
  for (const auto& f : files) {
    Case c;
    c.name = f.stem().string();
    std::replace_if(
        c.name.begin(), c.name.end(),
        [](char ch) { return !std::isalnum(static_cast<unsigned char>(ch)); }, '_');
    c.file = f;
    std::istringstream in(slurp(f));
    std::string line;
    std::getline(in, line);
    const std::string tag = "# expect: ";
    c.expect = line.rfind(tag, 0) == 0 ? line.substr(tag.size()) : "";
    while (std::getline(in, line) && line.rfind("# ", 0) == 0) {  // options after the first line
      if (line == "# exit: 1") c.exit_code = 1;
      if (line == "# command: optimize") c.optimize = true;
      if (line == "# command: linearize") c.linearize = true;
      if (line.rfind("# args: ", 0) == 0) {
        std::istringstream words(line.substr(8));
        for (std::string w; words >> w;)
          c.args.push_back(w[0] == '@' ? (dir / w.substr(1)).string() : w);
      }
    }
    cases.push_back(c);
  }
  return cases;
}

class Hostile : public ::testing::TestWithParam<Case> {};

TEST_P(Hostile, ClearErrorNoCrashNoHang) {
  const Case& c = GetParam();
  ASSERT_FALSE(c.expect.empty()) << c.file << ": the first line must be '# expect: <substring>'";
  fs::path file = c.file;
  if (c.generate) {
    file = scratch() / (c.name + ".yaml");
    std::ofstream(file, std::ios::binary) << c.generate();
  }
  const fs::path out = scratch() / ("out_" + c.name);
  fs::remove_all(out);

  const Outcome r = simulate(file, out, c.optimize, c.linearize, c.args);
  if (c.generate) fs::remove(file);
  ASSERT_NE(r.exit_code, 124) << "hang: no answer within " << kTimeoutSeconds << " s";
  ASSERT_LT(r.exit_code, 128) << "crash: killed by signal " << r.exit_code - 128 << "\n" << r.err;
  EXPECT_EQ(r.exit_code, c.exit_code) << r.err;
  EXPECT_NE(r.err.find(c.expect), std::string::npos) << "expected '" << c.expect << "' in:\n"
                                                     << r.err;
  EXPECT_FALSE(fs::exists(out / "trajectory.csv")) << "output that looks complete";

  if (c.exit_code == 2) {
    // The scenario is named, or the file of an argument whose content is at fault (a state).
    bool named = r.err.find(file.string()) != std::string::npos;
    for (const auto& a : c.args) {
      // an option whose own value is at fault (--dt nan) is named by the option
      if (a.rfind("--", 0) == 0) named = named || r.err.find(a) != std::string::npos;
      if (a.rfind(dir_of_corpus().string(), 0) != 0) continue;
      const auto colon = a.find(':', dir_of_corpus().string().size());  // RUN.csv:N
      named = named || r.err.find(a.substr(0, colon)) != std::string::npos;
    }
    EXPECT_TRUE(named) << "the file is not named:\n" << r.err;
    EXPECT_FALSE(fs::exists(out / "summary.json"));
  } else {
    EXPECT_NE(r.err.find("run incomplete"), std::string::npos) << r.err;
    ASSERT_TRUE(fs::exists(out / "summary.json"));
    EXPECT_TRUE(fs::exists(out / "trajectory.incomplete.csv"));
    const auto summary = nlohmann::json::parse(slurp(out / "summary.json"));
    EXPECT_EQ(summary["status"], "incomplete");
    ASSERT_TRUE(summary.contains("stop_reason"));
    EXPECT_NE(summary["stop_reason"].get<std::string>().find(c.expect), std::string::npos)
        << summary["stop_reason"];
    EXPECT_EQ(summary["scenario"]["path"], file.string());
  }
  fs::remove_all(out);
}

INSTANTIATE_TEST_SUITE_P(Corpus, Hostile, ::testing::ValuesIn(corpus_cases()),
                         [](const ::testing::TestParamInfo<Case>& i) { return i.param.name; });
INSTANTIATE_TEST_SUITE_P(Generated, Hostile, ::testing::ValuesIn(generated_cases()),
                         [](const ::testing::TestParamInfo<Case>& i) { return i.param.name; });

TEST(HostileCorpus, HasAtLeast25FilesEachWithItsOwnExpectation) {
  const auto cases = corpus_cases();
  EXPECT_GE(cases.size(), 25u);
  for (const auto& c : cases) EXPECT_FALSE(c.expect.empty()) << c.file;
}

// Names become CSV columns and figure file names: a name that tries to leave the output folder must
// be refused before anything is written (nothing may appear next to the output folder).
TEST(HostileCorpus, PathLikeNamesWriteNothingOutsideTheOutputFolder) {
  const fs::path root = scratch() / "escape";
  fs::remove_all(root);
  const fs::path out = root / "a" / "b" / "out";
  const fs::path file = root / "escape.yaml";
  fs::create_directories(root);
  std::ofstream(file) << arm_scenario("[x, y, d, a1, a2, a3]", "[0, 0, 0, 0.5, -0.5, 0]",
                                      "constraints:\n  - {type: coordinate, name: "
                                      "'../../../escaped', coordinate: x}\n");
  const Outcome r = simulate(file, out);
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_NE(r.err.find("key 'constraints[0].name': a name must be"), std::string::npos) << r.err;
  std::vector<std::string> found;
  for (const auto& e : fs::recursive_directory_iterator(root)) {
    if (e.path() != file) found.push_back(e.path().string());
  }
  EXPECT_TRUE(found.empty()) << found.front();
  fs::remove_all(root);
}

// Injection payloads (issue 15, class 1): corpus files that try to run `touch canary` through a
// name (gnuplot system(), a CR ending a C comment, ...) are refused by every command that writes a
// generated file, and no canary appears in the working directory or the output folder.
TEST(HostileCorpus, InjectionPayloadsRunNothing) {
  const fs::path work = scratch() / "injection";
  fs::remove_all(work);
  fs::create_directories(work);
  int payloads = 0;
  for (const auto& c : corpus_cases()) {
    const std::string text = slurp(c.file);
    if (text.find("canary") == std::string::npos && text.find("system(") == std::string::npos)
      continue;
    ++payloads;
    const std::string cd = "cd " + sh(work.string()) + " && ";
    for (const std::string& cmd :
         std::vector<std::string>{"simulate " + sh(c.file.string()) + " --out out",
                                  "derive " + sh(c.file.string()) + " --format c",
                                  "derive " + sh(c.file.string()) + " --format latex",
                                  "derive " + sh(c.file.string()) + " --format matlab"}) {
      const int rc = std::system((cd + "timeout -k 5 " + std::to_string(kTimeoutSeconds) + " " +
                                  sh(UKDYN_CLI) + " " + cmd + " > /dev/null 2>&1")
                                     .c_str());
      EXPECT_TRUE(WIFEXITED(rc) && WEXITSTATUS(rc) == 2) << c.name << ": " << cmd;
    }
    for (const auto& e : fs::recursive_directory_iterator(work))
      EXPECT_EQ(e.path().filename().string().find("canary"), std::string::npos) << e.path();
    EXPECT_FALSE(fs::exists(fs::current_path() / "canary"));
  }
  EXPECT_GE(payloads, 5);
  fs::remove_all(work);
}

// A FIFO (or a directory) given as the scenario is named as what it is, never opened (a FIFO
// would block), never reported as missing.
TEST(HostileCorpus, FifoScenarioIsNamedNotOpened) {
  const fs::path fifo = scratch() / "scenario_fifo.yaml";
  fs::remove(fifo);
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  const Outcome r = simulate(fifo, scratch() / "out_fifo");
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_NE(r.err.find("is a FIFO (named pipe), not a scenario file"), std::string::npos) << r.err;
  fs::remove(fifo);
  const Outcome d = simulate(scratch(), scratch() / "out_dir");
  EXPECT_EQ(d.exit_code, 2) << d.err;
  EXPECT_NE(d.err.find("is a folder, not a scenario file"), std::string::npos) << d.err;
}

// An MJCF model that is a FIFO, or that includes one or names one as a mesh, is named as what it
// is before MuJoCo opens anything (MuJoCo's reader would block on the FIFO forever); an include
// cycle is refused.
TEST(HostileCorpus, MjcfFifoAndIncludeCycleAreRefusedBeforeMuJoCoReads) {
  const fs::path dir = scratch() / "mjcf_fifo";
  fs::remove_all(dir);
  fs::create_directories(dir);
  ASSERT_EQ(::mkfifo((dir / "pipe.xml").c_str(), 0600), 0);
  std::ofstream(dir / "top.xml") << "<mujoco><include file=\"pipe.xml\"/><worldbody/></mujoco>\n";
  std::ofstream(dir / "a.xml") << "<mujoco><include file='b.xml'/></mujoco>\n";
  std::ofstream(dir / "b.xml") << "<mujoco><include file='a.xml'/></mujoco>\n";
  ASSERT_EQ(::mkfifo((dir / "pipe.obj").c_str(), 0600), 0);
  std::ofstream(dir / "mesh.xml")
      << "<mujoco><asset><mesh name='m' file='pipe.obj'/></asset><worldbody/></mujoco>\n";
  auto scenario = [&](const std::string& model) {
    const fs::path p = dir / ("s_" + model + ".yaml");
    std::ofstream(p) << "ukdyn: 1\nname: m\ngravity: 9.81\nsubsystems:\n  - name: arm\n"
                        "    type: serial_chain\n    coordinates: [a]\n    mjcf: "
                     << model << "\ninitial:\n  q: [0]\n  qd: [0]\nsimulation:\n  t_end: 1\n"
                     << "  sample_dt: 0.01\n";
    return p;
  };
  const struct {
    const char* model;
    const char* expect;
  } cases[] = {
      {"pipe.xml", "pipe.xml: is a FIFO (named pipe), not a MJCF file"},
      {"top.xml", "pipe.xml (included from top.xml): is a FIFO (named pipe)"},
      {"a.xml", "more than 32 levels of <include> (a cycle?)"},
      {"mesh.xml",
       "pipe.obj (<mesh file=\"pipe.obj\"> in mesh.xml): is a FIFO (named pipe), not a "
       "mesh file"},
  };
  for (const auto& c : cases) {
    const Outcome r = simulate(scenario(c.model), dir / "out");
    EXPECT_EQ(r.exit_code, 2) << c.model << ": " << r.err;
    EXPECT_NE(r.err.find(c.expect), std::string::npos) << r.err;
  }
  fs::remove_all(dir);
}

}  // namespace

#endif  // UKDYN_CLI
