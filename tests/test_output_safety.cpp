// ukdyn on hostile output folders, names, signals, disks and eval lines (issue 15): it touches only
// what it creates, never follows a planted link, never runs a command through a generated script,
// never leaves a file that lies about the run, stops promptly on SIGTERM, and says what went wrong.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/mount.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <nlohmann/json.hpp>
#include <random>
#include <thread>

#include "cli_run.hpp"

#ifdef UKDYN_HAVE_IO
#include "run/run_faults.hpp"
#include "ukdyn/output/plots.hpp"
#include "ukdyn/run/eval_protocol.hpp"
#include "ukdyn/run/run.hpp"
#include "ukdyn/text/safe_text.hpp"

extern char** environ;

namespace {

using namespace ukdyn_test;
const fs::path kSource = UKDYN_SOURCE_DIR;

fs::path scratch() {
  static const ScratchDir d("ukdyn_safety_test");
  return d.path;
}

// The paper's free-base scenario with textual substitutions (each must apply), written to scratch.
fs::path scenario(const std::string& name,
                  const std::vector<std::pair<std::string, std::string>>& subs) {
  std::string text = slurp(kSource / "scenarios" / "paper_free.yaml");
  for (const auto& [from, to] : subs) {
    const auto pos = text.find(from);
    EXPECT_NE(pos, std::string::npos) << "substitution not found: " << from;
    if (pos != std::string::npos) text.replace(pos, from.size(), to);
  }
  const fs::path p = scratch() / (name + ".yaml");
  std::ofstream(p) << text;
  return p;
}

fs::path short_scenario() { return scenario("short", {{"t_end: 5", "t_end: 0.2"}}); }

nlohmann::json summary_of(const fs::path& out) {
  return nlohmann::json::parse(slurp(out / "summary.json"));
}

// Every data line of a CSV has the header's number of fields and ends with a newline.
void expect_whole_rows(const fs::path& csv, long expected_rows) {
  const std::string text = slurp(csv);
  ASSERT_FALSE(text.empty());
  EXPECT_EQ(text.back(), '\n') << "last row cut: " << csv;
  std::istringstream in(text);
  std::string header;
  std::getline(in, header);
  const auto fields = std::count(header.begin(), header.end(), ',');
  long rows = 0;
  for (std::string l; std::getline(in, l);) {
    ++rows;
    EXPECT_EQ(std::count(l.begin(), l.end(), ','), fields) << "row " << rows;
  }
  EXPECT_EQ(rows, expected_rows);
}

#ifdef UKDYN_CLI
const fs::path kCli = UKDYN_CLI;

// A run that takes minutes unless stopped: rk4 at 1e-4 s, one sample step over the whole span.
fs::path endless_scenario(const std::string& name, const std::string& sample_dt) {
  return scenario(name, {{"t_end: 5", "t_end: 1000"},
                         {"sample_dt: 0.01", "sample_dt: " + sample_dt},
                         {"integrator: dopri5", "integrator: rk4\n  step: 1e-4"}});
}

CliResult run(const std::string& args, const std::string& in = "", const std::string& prefix = "") {
  return run_cli(kCli, scratch(), args, in, prefix);
}

std::string simulate_args(const fs::path& sc, const fs::path& out, bool figures = false) {
  return "simulate " + sh(sc.string()) + " --out " + sh(out.string()) +
         (figures ? "" : " --no-figures");
}

// Starts ukdyn in the background (stdout/stderr to files); returns its pid.
pid_t spawn_cli(const std::vector<std::string>& args, const fs::path& log) {
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  posix_spawn_file_actions_addopen(&fa, 0, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&fa, 1, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_adddup2(&fa, 1, 2);
  std::vector<std::string> all{kCli.string()};
  all.insert(all.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& a : all) argv.push_back(a.data());
  argv.push_back(nullptr);
  pid_t pid = -1;
  const int rc = posix_spawn(&pid, kCli.c_str(), &fa, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&fa);
  return rc == 0 ? pid : -1;
}

// Waits for pid at most `limit`; kills it (and returns -1) if it is still running then.
int wait_for(pid_t pid, std::chrono::milliseconds limit) {
  const auto end = std::chrono::steady_clock::now() + limit;
  int status = 0;
  while (std::chrono::steady_clock::now() < end) {
    if (::waitpid(pid, &status, WNOHANG) == pid)
      return WIFEXITED(status) ? WEXITSTATUS(status) : -2;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  ::kill(pid, SIGKILL);
  ::waitpid(pid, &status, 0);
  return -1;
}

bool wait_until(const std::function<bool()>& cond, std::chrono::milliseconds limit) {
  const auto end = std::chrono::steady_clock::now() + limit;
  while (std::chrono::steady_clock::now() < end) {
    if (cond()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return false;
}

bool running(const fs::path& out) {
  try {
    return fs::exists(out / ".ukdyn.lock") && summary_of(out)["status"] == "running";
  } catch (...) {
    return false;
  }
}

// ---- class 2: files outside the run

TEST(OutputSafety, RootsAreRefusedAlsoThroughLinks) {
  const fs::path sc = short_scenario();
  fs::create_symlink("/", scratch() / "link_to_root");
  fs::create_symlink("/usr", scratch() / "link_to_usr");
  const bool had_summary = fs::exists("/summary.json"), had_csv = fs::exists("/trajectory.csv");
  const bool had_figs = fs::exists("/figures");
  for (const fs::path& out :
       {fs::path("/"), fs::path("/usr"), fs::path("/usr/.."), scratch() / "link_to_root",
        scratch() / "link_to_usr", scratch() / "link_to_root" / "etc"}) {
    const CliResult r = run(simulate_args(sc, out, true));
    EXPECT_EQ(r.exit_code, 2) << out << ": " << r.err;
    EXPECT_NE(r.err.find("refusing to write into"), std::string::npos) << r.err;
  }
  EXPECT_EQ(fs::exists("/summary.json"), had_summary);
  EXPECT_EQ(fs::exists("/trajectory.csv"), had_csv);
  EXPECT_EQ(fs::exists("/figures"), had_figs);
  EXPECT_FALSE(fs::exists("/usr/summary.json"));
}

TEST(OutputSafety, MountPointIsRefused) {
  const fs::path mnt = scratch() / "mnt";
  fs::create_directories(mnt);
  if (::mount("tmpfs", mnt.c_str(), "tmpfs", 0, "size=1m") != 0) {
    GTEST_SKIP() << "cannot mount a tmpfs here (not root?)";
  }
  const CliResult r = run(simulate_args(short_scenario(), mnt));
  const CliResult sub = run(simulate_args(short_scenario(), mnt / "run"));
  ::umount(mnt.c_str());
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_NE(r.err.find("mount point"), std::string::npos) << r.err;
  EXPECT_EQ(sub.exit_code, 0) << sub.err;  // a folder inside it is fine
}

TEST(OutputSafety, PlantedLinksAreNeverFollowed) {
  const fs::path sc = short_scenario();
  const fs::path victims = scratch() / "victims";
  fs::create_directories(victims / "folder");
  std::ofstream(victims / "precious.txt") << "the user's data\n";
  std::ofstream(victims / "folder" / "energy.png") << "not a figure\n";
  const auto before = snapshot(victims);
  for (const std::string planted :
       {"trajectory.csv.part", "summary.json.part", "trajectory.csv", "summary.json",
        "trajectory.incomplete.csv", ".ukdyn.lock", "figures"}) {
    const fs::path out = scratch() / ("planted_" + planted);
    fs::create_directories(out);
    fs::create_symlink(planted == "figures" ? victims / "folder" : victims / "precious.txt",
                       out / planted);
    const CliResult r = run(simulate_args(sc, out, true));
    EXPECT_EQ(r.exit_code, 2) << planted << ": " << r.err;
    EXPECT_NE(r.err.find(planted), std::string::npos) << r.err;
    EXPECT_TRUE(fs::is_symlink(out / planted)) << planted;  // not removed either
    EXPECT_EQ(snapshot(victims), before) << planted;
    if (planted != "trajectory.csv") {
      EXPECT_FALSE(fs::exists(out / "trajectory.csv")) << planted;
    }
  }
}

TEST(OutputSafety, UserFilesInTheOutputFolderAreUntouched) {
  const fs::path sc = short_scenario();
  const fs::path out = scratch() / "user_files";
  fs::create_directories(out / "figures" / "keep");
  std::ofstream(out / "mine.csv") << "a,b\n1,2\n";
  std::ofstream(out / "figures" / "notes.txt") << "my notes\n";
  std::ofstream(out / "figures" / "keep" / "data.bin") << std::string("\0\1\2", 3);
  // A forged list of "ukdyn's figures" must not make ukdyn remove anything but its own names.
  std::ofstream(out / "figures" / ".ukdyn-figures")
      << "notes.txt\n../mine.csv\nkeep\nkeep/data.bin\n";
  const auto mine = [&] {
    auto s = snapshot(out);
    std::map<std::string, std::string> user;
    for (const char* k :
         {"mine.csv", "figures/notes.txt", "figures/keep", "figures/keep/data.bin"}) {
      user[k] = s[k];
    }
    return user;
  };
  const auto before = mine();
  const CliResult a = run(simulate_args(sc, out, true));
  ASSERT_EQ(a.exit_code, 0) << a.err;
  EXPECT_EQ(mine(), before);
  EXPECT_TRUE(fs::exists(out / "figures" / "energy.png"));
  EXPECT_TRUE(fs::exists(out / "figures" / "figures.gp"));
  // --no-figures: the figures of the run before are ukdyn's, and stale: they go; the user's stay.
  const CliResult b = run(simulate_args(sc, out, false));
  ASSERT_EQ(b.exit_code, 0) << b.err;
  EXPECT_EQ(mine(), before);
  EXPECT_FALSE(fs::exists(out / "figures" / "energy.png"));
  EXPECT_TRUE(fs::is_directory(out / "figures"));
  EXPECT_EQ(summary_of(out)["figures"].size(), 0u);
  EXPECT_FALSE(fs::exists(out / ".ukdyn.lock"));
}

TEST(OutputSafety, ConcurrentRunsIntoOneFolder) {
  const fs::path out = scratch() / "busy";
  fs::create_directories(out);
  std::ofstream(out / "mine.txt") << "untouched\n";
  const fs::path a_sc = endless_scenario("endless_a", "0.01");
  const pid_t a = spawn_cli({"simulate", a_sc.string(), "--out", out.string(), "--no-figures"},
                            scratch() / "a.log");
  ASSERT_GT(a, 0);
  ASSERT_TRUE(wait_until([&] { return running(out); }, std::chrono::seconds(30)));
  const auto mine = slurp(out / "mine.txt");
  const CliResult b = run(simulate_args(short_scenario(), out));
  EXPECT_EQ(b.exit_code, 2) << b.err;
  EXPECT_NE(b.err.find("another ukdyn run (pid " + std::to_string(a) + ")"), std::string::npos)
      << b.err;
  EXPECT_TRUE(running(out));  // B changed nothing: A's summary is still there, still running
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  ::kill(a, SIGTERM);
  EXPECT_EQ(wait_for(a, std::chrono::seconds(20)), 1) << slurp(scratch() / "a.log");
  EXPECT_EQ(slurp(out / "mine.txt"), mine);
  // A's summary describes A's trajectory.
  const auto s = summary_of(out);
  EXPECT_EQ(s["status"], "incomplete");
  EXPECT_EQ(s["scenario"]["path"], a_sc.string());
  expect_whole_rows(out / "trajectory.incomplete.csv", s["samples"].get<long>());
  EXPECT_FALSE(fs::exists(out / ".ukdyn.lock"));
  // Free again: a new run goes through.
  EXPECT_EQ(run(simulate_args(short_scenario(), out)).exit_code, 0);
}

// ---- class 3: results on disk that do not lie

TEST(OutputSafety, FileSizeLimitMidRunLeavesAnIncompleteSummaryAndWholeRows) {
  const fs::path out = scratch() / "fsize";
  // A complete run first: its summary must not survive a failed re-run.
  ASSERT_EQ(run(simulate_args(short_scenario(), out)).exit_code, 0);
  ASSERT_EQ(summary_of(out)["status"], "complete");
  // The full paper_free run writes ~1 MB of CSV; the limit is 256 blocks (128–256 KiB).
  const fs::path sc = kSource / "scenarios" / "paper_free.yaml";
  const CliResult r = run(simulate_args(sc, out), "", "ulimit -f 256; ");
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_NE(r.err.find("write failed"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(out / "trajectory.csv"));
  EXPECT_FALSE(fs::exists(out / "trajectory.csv.part"));
  const auto s = summary_of(out);
  EXPECT_EQ(s["status"], "incomplete");
  EXPECT_NE(s["stop_reason"].get<std::string>().find("write failed"), std::string::npos);
  ASSERT_TRUE(fs::exists(out / "trajectory.incomplete.csv"));
  expect_whole_rows(out / "trajectory.incomplete.csv", s["trajectory_rows"].get<long>());
}

TEST(OutputSafety, FullDiskOnASmallTmpfs) {
  const fs::path mnt = scratch() / "small_disk";
  fs::create_directories(mnt);
  if (::mount("tmpfs", mnt.c_str(), "tmpfs", 0, "size=96k") != 0) {
    GTEST_SKIP() << "cannot mount a tmpfs here (not root?)";
  }
  const fs::path out = mnt / "out";
  const CliResult r = run(simulate_args(kSource / "scenarios" / "paper_free.yaml", out, true));
  const bool has_summary = fs::exists(out / "summary.json");
  const std::string summary = has_summary ? slurp(out / "summary.json") : "";
  const bool has_csv = fs::exists(out / "trajectory.csv");
  const bool has_partial = fs::exists(out / "trajectory.incomplete.csv");
  long rows = -1;
  if (has_summary) rows = nlohmann::json::parse(summary).value("trajectory_rows", -1L);
  if (has_partial) expect_whole_rows(out / "trajectory.incomplete.csv", rows);
  ::umount(mnt.c_str());
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_FALSE(has_csv);
  // Either the summary says incomplete, or (no room even for that) there is none.
  if (has_summary) {
    EXPECT_EQ(nlohmann::json::parse(summary)["status"], "incomplete") << summary;
  }
}

// ---- class 6: signals and exit codes

TEST(Signals, SigtermStopsWithinAStepNotASample) {
  // One output sample over 1000 s at 1e-4 s steps: honoured only at samples, SIGTERM would wait
  // for ten million steps.
  const fs::path out = scratch() / "sigterm";
  const fs::path sc = endless_scenario("one_sample", "1000");
  const pid_t pid = spawn_cli({"simulate", sc.string(), "--out", out.string(), "--no-figures"},
                              scratch() / "sigterm.log");
  ASSERT_GT(pid, 0);
  ASSERT_TRUE(wait_until([&] { return running(out); }, std::chrono::seconds(30)));
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  const auto sent = std::chrono::steady_clock::now();
  ::kill(pid, SIGTERM);
  const int rc = wait_for(pid, std::chrono::seconds(10));
  const double waited =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - sent).count();
  EXPECT_EQ(rc, 1) << "still running 10 s after SIGTERM (killed): "
                   << slurp(scratch() / "sigterm.log");
  EXPECT_LT(waited, 10.0);
  const auto s = summary_of(out);
  EXPECT_EQ(s["status"], "incomplete");
  EXPECT_NE(s["stop_reason"].get<std::string>().find("interrupted"), std::string::npos);
  EXPECT_GT(s["steps"].get<long>(), 0);
}

TEST(ExitCodes, UsageErrorsExit2) {
  const std::string sc = sh(short_scenario().string());
  for (const std::string& args : {std::string(""), std::string("bogus"), std::string("simulate"),
                                  "simulate " + sc + " --nonsense", "simulate " + sc + " --out",
                                  "derive " + sc + " --format pdf", "check " + sc + " extra"}) {
    const CliResult r = run(args);
    EXPECT_EQ(r.exit_code, 2) << "'" << args << "': " << r.err;
  }
  EXPECT_EQ(run("--help").exit_code, 0);
  const CliResult v = run("--version");
  EXPECT_EQ(v.exit_code, 0);
  EXPECT_NE(v.out.find("0."), std::string::npos);
}

// ---- class 5 / 7: eval answers a bad line with an error on that line

TEST(Eval, BadLinesAreAnsweredWithTheirLineAndTheProcessFails) {
  const std::string q =
      "[0,0,0,1.5707963267948966,-1.0471975511965976,0,1.6,0,-3.141592653589793,"
      "1.5707963267948966,-1.0471975511965976,0]";
  const std::string z = "[0,0,0,0,0,0,0,0,0,0,0,0]";
  const std::string big =
      "[1e300,1e300,1e300,1e300,1e300,1e300,1e300,1e300,1e300,1e300,1e300,1e300]";
  const std::string input = "{\"q\": " + q + ", \"qd\": " + z + "}\n" +  // 1 good
                            "{\"q\": " + q + ", \"qd\": " + z + ", \"Tau\": " + z + "}\n" +  // 2
                            "{\"time\": 1, \"q\": " + q + ", \"qd\": " + z + "}\n" +         // 3
                            "\n" +                                                     // 4 blank
                            "{\"q\": [1, 2], \"qd\": " + z + "}\n" +                   // 5
                            "{\"t\": 1e999, \"q\": " + q + ", \"qd\": " + z + "}\n" +  // 6
                            "{\"q\": " + q + ", \"qd\": " + big + "}\n";               // 7 overflow
  const CliResult r =
      run("eval " + sh((kSource / "scenarios" / "paper_free.yaml").string()), input);
  EXPECT_EQ(r.exit_code, 1);
  std::istringstream lines(r.out);
  std::vector<nlohmann::json> answers;
  for (std::string l; std::getline(lines, l);) answers.push_back(nlohmann::json::parse(l));
  ASSERT_EQ(answers.size(), 6u) << r.out;
  EXPECT_TRUE(answers[0].contains("qdd"));
  EXPECT_TRUE(answers[0]["consistent"].get<bool>());
  const std::vector<std::pair<long, std::string>> expected{{2, "unknown key 'Tau'"},
                                                           {3, "unknown key 'time'"},
                                                           {5, "key 'q'"},
                                                           {6, "number overflow"},
                                                           {7, "non-finite"}};
  for (std::size_t k = 0; k < expected.size(); ++k) {
    const auto& a = answers[k + 1];
    ASSERT_TRUE(a.contains("error")) << a.dump();
    EXPECT_FALSE(a.contains("consistent")) << a.dump();
    EXPECT_EQ(a["line"], expected[k].first) << a.dump();
    const auto msg = a["error"].get<std::string>();
    EXPECT_NE(msg.find("stdin:" + std::to_string(expected[k].first) + ":"), std::string::npos)
        << msg;
    EXPECT_NE(msg.find(expected[k].second), std::string::npos) << msg;
  }
  EXPECT_EQ(r.out.find("null"), std::string::npos) << r.out;
}

// ---- class 1: no code execution through generated scripts

TEST(Injection, PayloadsInOutAndNamesRunNothing) {
  const fs::path canary = scratch() / "CANARY";
  const std::string touch = "system(\"touch " + canary.string() + "\")";
  // In --out (a path may hold a newline: it must never reach the gnuplot script as code).
  const fs::path out = scratch() / ("inj\n" + touch + "\n'\n" + touch + "\n");
  const CliResult r = run(simulate_args(short_scenario(), out, true));
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_FALSE(fs::exists(canary));
  EXPECT_TRUE(fs::exists(out / "figures" / "energy.png")) << r.err;
  // In a coordinate name (refused at load, or quoted in the script: either way nothing runs).
  const fs::path named = scenario(
      "inj_name", {{"dx1,", "'a'' . " + touch + " . ''',"}, {"name: paper_free", "name: \"x'\""}});
  const fs::path out2 = scratch() / "inj_name_out";
  const CliResult r2 = run(simulate_args(named, out2, true));
  EXPECT_TRUE(r2.exit_code == 0 || r2.exit_code == 2) << r2.err;
  EXPECT_FALSE(fs::exists(canary));
  if (r2.exit_code == 0) {
    std::istringstream gp(slurp(out2 / "figures" / "figures.gp"));
    for (std::string l; std::getline(gp, l);) EXPECT_NE(l.rfind("system", 0), 0u) << l;
  }
}

// ---- class 7: messages

TEST(Messages, ControlBytesNeverReachTheTerminalRaw) {
  // A scenario file whose name holds ESC [ 31 m and the C1 control CSI (U+009B).
  const fs::path sc = scratch() / "sc\x1b[31m\xc2\x9bred.yaml";
  fs::copy_file(short_scenario(), sc, fs::copy_options::overwrite_existing);
  const CliResult ok = run("check " + sh(sc.string()));
  EXPECT_EQ(ok.exit_code, 0) << ok.err;
  const CliResult missing = run("check " + sh(sc.string() + "\x07missing"));
  EXPECT_EQ(missing.exit_code, 2);
  for (const std::string& s : {ok.out, ok.err, missing.out, missing.err}) {
    EXPECT_EQ(s.find('\x1b'), std::string::npos) << s;
    EXPECT_EQ(s.find('\x07'), std::string::npos) << s;
    EXPECT_EQ(s.find("\xc2\x9b"), std::string::npos) << s;
  }
  EXPECT_NE(ok.out.find("\\x1b[31m"), std::string::npos) << ok.out;
}

TEST(Messages, FifoFolderAndDeviceAreNamedAndNeverBlock) {
  const fs::path fifo = scratch() / "scenario.fifo";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  const std::vector<std::pair<fs::path, std::string>> cases{
      {fifo, "is a FIFO"},
      {scratch(), "is a folder"},
      {"/dev/zero", "is a device"},
      {scratch() / "nothing.yaml", "no such scenario file"}};
  for (const auto& [path, what] : cases) {
    const CliResult r = run("check " + sh(path.string()), "", "timeout 20 ");
    EXPECT_EQ(r.exit_code, 2) << path << ": " << r.err;  // 124 would be a hang
    EXPECT_NE(r.err.find(what), std::string::npos) << r.err;
  }
}
#endif  // UKDYN_CLI

// In-process: injected write failures at chosen moments.
class InjectedFailure : public ::testing::Test {
 protected:
  ukdyn::RunReport run_with(const fs::path& out,
                            const std::function<bool(std::string_view, std::size_t)>& hook) {
    const ukdyn::Scenario sc = ukdyn::load_scenario(short_scenario());
    ukdyn::RunOptions opt;
    opt.figures = false;
    return ukdyn::io_detail::run_scenario_with_write_failures(sc, out, opt, hook);
  }
};

TEST_F(InjectedFailure, AtTheFinalFlushOfTheTrajectory) {
  const fs::path out = scratch() / "inj_csv";
  ASSERT_TRUE(run_with(out, {}).complete());
  // Fail the last write of trajectory.csv (the commit's flush): all rows computed, not all written.
  long writes = 0;
  const auto count = [&](std::string_view name, std::size_t) {
    writes += name == "trajectory.csv";
    return false;
  };
  run_with(scratch() / "inj_csv_count", count);
  long k = 0;
  const auto rep = run_with(out, [&](std::string_view name, std::size_t) {
    return name == "trajectory.csv" && ++k >= writes;  // and the disk stays full
  });
  EXPECT_FALSE(rep.complete());
  EXPECT_NE(rep.write_error.find("injected"), std::string::npos) << rep.write_error;
  EXPECT_FALSE(fs::exists(out / "trajectory.csv"));
  const auto s = summary_of(out);
  EXPECT_EQ(s["status"], "incomplete");
  expect_whole_rows(out / "trajectory.incomplete.csv", s["trajectory_rows"].get<long>());
  EXPECT_LT(s["trajectory_rows"].get<long>(), s["samples"].get<long>());
}

TEST_F(InjectedFailure, AtTheFinalSummaryNoSummarySaysComplete) {
  const fs::path out = scratch() / "inj_summary";
  ASSERT_TRUE(run_with(out, {}).complete());
  long k = 0;
  // The first summary ("running") goes through; every later one fails, the fallback too.
  const auto rep = run_with(
      out, [&](std::string_view name, std::size_t) { return name == "summary.json" && ++k > 1; });
  EXPECT_FALSE(rep.complete());
  EXPECT_FALSE(fs::exists(out / "summary.json"));  // neither "running" nor the old "complete"
  // Only the final fails: the fallback says incomplete.
  long j = 0;
  const auto rep2 = run_with(out, [&](std::string_view name, std::size_t bytes) {
    return name == "summary.json" && ++j == 2 && bytes > 0;
  });
  EXPECT_FALSE(rep2.complete());
  EXPECT_EQ(summary_of(out)["status"], "incomplete");
}

TEST_F(InjectedFailure, AtTheFirstSummaryNothingIsLeft) {
  const fs::path out = scratch() / "inj_first";
  ASSERT_TRUE(run_with(out, {}).complete());
  EXPECT_THROW(
      run_with(out, [](std::string_view name, std::size_t) { return name == "summary.json"; }),
      ukdyn::WriteFailed);
  EXPECT_FALSE(fs::exists(out / "summary.json"));
  EXPECT_FALSE(fs::exists(out / "trajectory.csv"));
  EXPECT_FALSE(fs::exists(out / ".ukdyn.lock"));
}

TEST(SafeText, GnuplotStringsCannotEndTheCommand) {
  for (const std::string& payload :
       {std::string("a\nsystem('touch X')"), std::string("a'\nsystem(\"touch X\")\n'"),
        std::string("a\\\nb"), std::string("a\r\nb"), std::string("it's")}) {
    const std::string lit = ukdyn::gnuplot_string(payload);
    EXPECT_EQ(lit.find_first_of("\n\r`@'"), std::string::npos) << lit;
    ASSERT_GE(lit.size(), 2u);
    EXPECT_EQ(lit.front(), '"');
    EXPECT_EQ(lit.back(), '"');
    // Inside, every '"' and '\' is escaped: the literal is never closed early.
    const std::string inner = lit.substr(1, lit.size() - 2);
    for (std::size_t i = 0; i < inner.size(); ++i) {
      EXPECT_NE(inner[i], '"') << lit;
      if (inner[i] == '\\') {
        ASSERT_LT(i + 1, inner.size()) << lit;
        ++i;
      }
    }
  }
}

TEST(SafeText, GnuplotItselfRunsNothingFromQuotedPayloads) {
  if (std::system("command -v gnuplot > /dev/null 2>&1") != 0) GTEST_SKIP() << "no gnuplot";
  const fs::path dir = scratch() / "gp";
  fs::create_directories(dir);
  const fs::path canary = dir / "CANARY";
  std::string script;
  for (const std::string& payload :
       {"\nsystem(\"touch " + canary.string() + "\")\n",
        "'\nsystem(\"touch " + canary.string() + "\")", "`touch " + canary.string() + "`",
        "\\\nsystem(\"touch " + canary.string() + "\")",
        "'; system(\"touch " + canary.string() + "\"); '",
        "\"; system(\"touch " + canary.string() + "\"); \"",
        "''' ; system(\"touch " + canary.string() + "\") ; '",
        "@x `touch " + canary.string() + "`"}) {
    script += "set title " + ukdyn::gnuplot_string(payload) + " noenhanced\n";
    script += "print " + ukdyn::gnuplot_string(payload) + "\n";
  }
  // A macro that would run the command if "@x" were expanded.
  std::ofstream(dir / "t.gp") << "x = 'system(\"touch " + canary.string() + "\")'\n" << script;
  const int rc =
      std::system(("gnuplot " + sh((dir / "t.gp").string()) + " > /dev/null 2>&1").c_str());
  EXPECT_EQ(rc, 0);
  EXPECT_FALSE(fs::exists(canary));
}

TEST(SafeText, PrintableEscapesControlsAndKeepsUtf8) {
  EXPECT_EQ(ukdyn::printable("a\x1b[31mb"), "a\\x1b[31mb");
  EXPECT_EQ(ukdyn::printable("\xc2\x9b"), "\\xc2\\x9b");  // C1 CSI
  EXPECT_EQ(ukdyn::printable("Φ̈ ok"), "Φ̈ ok");
  EXPECT_EQ(ukdyn::printable("\xff\xfe"), "\\xff\\xfe");
  EXPECT_EQ(ukdyn::printable("l1\nl2", true), "l1\nl2");
  EXPECT_EQ(ukdyn::printable("l1\nl2"), "l1\\x0al2");
  EXPECT_EQ(ukdyn::file_stem("../a b/\n"), "_.._a_b__");
  EXPECT_EQ(ukdyn::csv_field("a,\"b\""), "\"a,\"\"b\"\"\"");
}

// The scenario loader's narrower escape: C0 controls and DEL only, every other byte kept; what
// reaches a terminal then goes through printable() as well, and reads exactly as printable() alone.
TEST(SafeText, EscapeControlsEscapesOnlyC0AndDelAndPrintableStillCatchesTheRest) {
  EXPECT_EQ(ukdyn::escape_controls("a\x1b[31m\tb\x7f"), "a\\x1b[31m\\x09b\\x7f");
  EXPECT_EQ(ukdyn::escape_controls("l1\nl2"), "l1\\x0al2");
  EXPECT_EQ(ukdyn::escape_controls("\xc2\x9b \xff Φ\\x"), "\xc2\x9b \xff Φ\\x");  // not checked
  // ASCII, controls, C1, valid UTF-8 of 2 to 4 bytes, and bytes that are not UTF-8 (a lone lead or
  // continuation byte, a truncated sequence, a surrogate).
  const std::vector<std::string> pieces{"a",
                                        "\\",
                                        "\n",
                                        "\t",
                                        "\x1b",
                                        "\x7f",
                                        "\xc2\x9b",
                                        "\xc2\xa0",
                                        "Φ",
                                        "\xe2\x82\xac",
                                        "\xf0\x9f\x98\x80",
                                        "\xff",
                                        "\xc2",
                                        "\xe2\x82",
                                        "\x80",
                                        "\xed\xa0\x80"};
  std::mt19937 rng(15);
  std::uniform_int_distribution<std::size_t> pick(0, pieces.size() - 1), count(0, 12);
  for (int k = 0; k < 20000; ++k) {
    std::string s;
    for (std::size_t n = count(rng); n > 0; --n) s += pieces[pick(rng)];
    ASSERT_EQ(ukdyn::printable(ukdyn::escape_controls(s), true), ukdyn::printable(s))
        << ukdyn::printable(s);
  }
}

TEST(Figures, ThousandsOfRowsDrawABoundedNumberOfFigures) {
  std::vector<ukdyn::Figure> figs;
  for (int k = 0; k < 3000; ++k) {
    ukdyn::Figure f{"residuals_" + std::to_string(k) + ".png", "t", "y", {}};
    for (int c = 0; c < 200; ++c) f.columns.push_back("c" + std::to_string(c));
    figs.push_back(f);
  }
  std::vector<std::string> notes;
  ukdyn::cap_figures(figs, notes);
  EXPECT_EQ(figs.size(), ukdyn::kMaxFigures);
  for (const auto& f : figs) EXPECT_EQ(f.columns.size(), ukdyn::kMaxSeriesPerFigure);
  ASSERT_FALSE(notes.empty());
  EXPECT_NE(notes.back().find("of 3000 figures"), std::string::npos) << notes.back();
}

TEST(Eval, HostileLinesEachGetTheirOwnError) {
  const ukdyn::Scenario sc = ukdyn::load_scenario(kSource / "scenarios" / "paper_free.yaml");
  std::istringstream cases(slurp(kSource / "tests" / "hostile_eval" / "cases.txt"));
  int n = 0;
  for (std::string head; std::getline(cases, head);) {
    if (head.empty() || head[0] == '#') continue;
    ASSERT_EQ(head.rfind("expect: ", 0), 0u) << head;
    std::string line;
    ASSERT_TRUE(std::getline(cases, line));
    ++n;
    std::istringstream in("\n" + line + "\n");  // on line 2
    std::ostringstream out;
    const auto counts = ukdyn::run_eval_protocol(sc, in, out, nullptr);
    EXPECT_EQ(counts.failures, 1) << head;
    const auto j = nlohmann::json::parse(out.str());
    ASSERT_TRUE(j.contains("error")) << head << ": " << out.str().substr(0, 200);
    EXPECT_EQ(j["line"], 2);
    const std::string msg = j["error"].get<std::string>();
    EXPECT_EQ(msg.rfind("stdin:2: ", 0), 0u) << msg;
    EXPECT_NE(msg.find(head.substr(8)), std::string::npos) << head << "\n  got: " << msg;
  }
  EXPECT_GE(n, 30);
}

TEST(Eval, SingularMassMatrixIsAnErrorOnItsLine) {
  // Any M has a reciprocal condition <= 1: a threshold above that makes every M "singular", which
  // shows the path a singular M takes (an error object, never a result).
  const ukdyn::Scenario sc = ukdyn::load_scenario(kSource / "scenarios" / "paper_free.yaml");
  ukdyn::EvalOptions opt;
  opt.min_rcond = 2.0;
  std::istringstream in(
      "{\"q\": [0,0,0,1.57,-1.04,0,1.6,0,-3.14,1.57,-1.04,0], \"qd\": "
      "[0,0,0,0,0,0,0,0,0,0,0,0]}\n");
  std::ostringstream out;
  const auto counts = ukdyn::run_eval_protocol(sc, in, out, nullptr, opt);
  EXPECT_EQ(counts.failures, 1);
  const auto j = nlohmann::json::parse(out.str());
  EXPECT_EQ(j["line"], 1);
  EXPECT_NE(j["error"].get<std::string>().find("singular"), std::string::npos);
  EXPECT_FALSE(j.contains("qdd"));
}

}  // namespace

#endif  // UKDYN_HAVE_IO
