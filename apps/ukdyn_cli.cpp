// ukdyn: command-line front end. Holds no physics and no report formatting: it parses arguments
// and calls ukdyn::io.
//   ukdyn simulate SCENARIO [--out DIR] [--no-figures] [--quiet] [--assemble] [--html]
//   ukdyn replay OUT_DIR [--scenario FILE]   (OUT_DIR/replay.html, the run in 3D: docs/replay.md)
//   ukdyn assemble SCENARIO
//   ukdyn eval SCENARIO            (JSON lines on stdin → JSON lines on stdout)
//   ukdyn check SCENARIO           (load and validate only)
//   ukdyn linearize SCENARIO [--minimal] [--dt H] [--state FILE.json | --row RUN.csv:N]
//                  [--out FILE.json|FILE.npz] [--closed-loop]   (exact derivatives of q̈ and Qc at
//                  the initial state or the given one, JSON; in minimal coordinates; discrete; a
//                  control scenario's closed loop; docs/derivatives.md)
//   ukdyn sensitivities SCENARIO --param P [--param P2 ...] [--out DIR]   (dq/dp, dqd/dp of the
//                  run by the variational equations, DIR/sensitivities.csv; docs/derivatives.md)
//   ukdyn derive SCENARIO [--format latex|c|matlab|text]  (derived M, C, G, A, b;
//   docs/definitions.md)
//   ukdyn sweep SWEEP [--out DIR] [--threads N] [--shard i/N] [--extract K]   (docs/sweeps.md;
//   also under mpirun)
//   ukdyn sweep merge SWEEP --out DIR SHARD_DIR...
//   ukdyn optimize PROBLEM [--out DIR] [--quiet]   (optimal trajectory by collocation on IPOPT;
//                  docs/optimization.md)
//   ukdyn size SIZING [--out DIR] [--threads N] [--quiet]   (the smallest motor + gearbox of a
//                  catalogue for each actuator; docs/sizing.md)
// Exit codes: 0 success; 1 run incomplete (stopped, interrupted, a write failed), some eval lines
// failed, linearize could not vouch for its derivatives, or size found no catalogue entry that
// holds for some actuator; 2 bad input: a usage error, a bad
// scenario, an output folder ukdyn refuses or one in use.
#include <fcntl.h>
#include <fmt/format.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <atomic>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "apps/sweep_mpi.hpp"
#include "core/input_file.hpp"
#include "ukdyn/output/replay.hpp"
#include "ukdyn/run/closed_loop_derivatives.hpp"
#include "ukdyn/run/eval_protocol.hpp"
#include "ukdyn/run/optimize_run.hpp"
#include "ukdyn/run/run.hpp"
#include "ukdyn/run/sensitivity.hpp"
#include "ukdyn/scenario/scenario_file.hpp"
#include "ukdyn/sweep/sizing.hpp"
#include "ukdyn/sweep/sweep.hpp"
#include "ukdyn/symbolic/definitions.hpp"
#include "ukdyn/text/safe_text.hpp"

namespace {

std::atomic<bool> g_interrupted{false};
extern "C" void on_interrupt(int /*signal*/) { g_interrupted.store(true); }

int cmd_simulate(const ukdyn::Scenario& sc, const std::string& out, bool figures, bool quiet,
                 double progress_every) {
  ukdyn::RunOptions opt;
  opt.figures = figures;
  if (!quiet) {  // a bar on a terminal, else a line every few seconds (a log, a batch job)
    opt.progress = &std::cerr;
    opt.progress_lines = isatty(STDERR_FILENO) == 0;
    opt.progress_every = progress_every;
  }
  // Ctrl-C (or SIGTERM) ends the run after the current step; what was computed is kept.
  std::signal(SIGINT, on_interrupt);
  std::signal(SIGTERM, on_interrupt);
  opt.cancel = &g_interrupted;
  const auto rep = ukdyn::run_scenario(sc, out, opt);
  if (!quiet) ukdyn::print_run_report(std::cout, sc, rep);
  std::cout.flush();
  ukdyn::print_run_warnings(std::cerr, sc, rep);
  return rep.complete() ? 0 : 1;
}

struct SweepArgs {
  std::string file, out, shard = "0/1";
  int threads = 0;
  long extract = -1;
  double progress_every = 5.0;
  bool no_figures = false, quiet = false, fresh = false;
  std::vector<std::string> shard_dirs;
};

int cmd_sweep(const SweepArgs& a, bool merge, int* argc, char*** argv) {
  auto comm = merge ? nullptr : ukdyn_app::make_mpi_comm(argc, argv);
  const bool root = !comm || comm->rank() == 0;
  ukdyn::Sweep sw = ukdyn::load_sweep(a.file);
  if (a.no_figures) sw.figures = false;
  const std::string out = a.out.empty() ? "out/sweep-" + sw.name : a.out;
  if (a.extract >= 0) {
    if (a.extract >= sw.samples)
      throw ukdyn::ScenarioError(
          fmt::format("--extract: the sweep has samples 0..{}", sw.samples - 1));
    if (root) std::cout << ukdyn::sample_scenario_text(sw, a.extract);
    return 0;
  }
  ukdyn::SweepReport rep;
  if (merge) {
    std::vector<std::filesystem::path> dirs(a.shard_dirs.begin(), a.shard_dirs.end());
    rep = ukdyn::merge_sweep(sw, dirs, out);
  } else {
    ukdyn::SweepOptions opt;
    if (!ukdyn::parse_shard(a.shard, opt.shard, opt.shards))
      throw ukdyn::ScenarioError("--shard: expected i/N with 0 <= i < N (decimal digits), got '" +
                                 ukdyn::printable(a.shard) + "'");
    opt.threads = a.threads;
    if (!a.quiet) {
      opt.progress = &std::cerr;
      opt.progress_tty = isatty(STDERR_FILENO) != 0;
      opt.progress_every = a.progress_every;
    }
    std::signal(SIGINT, on_interrupt);
    std::signal(SIGTERM, on_interrupt);
    opt.cancel = &g_interrupted;
    opt.comm = comm.get();
    opt.resume = !a.fresh;
    rep = ukdyn::run_sweep(sw, out, opt);
    if (!root) return 0;
  }
  if (!a.quiet) ukdyn::print_sweep_report(std::cout, sw, rep);
  if (!rep.complete) {
    std::cerr << fmt::format(
        "ukdyn: sweep incomplete: {} of {} samples in {}; run it again to "
        "resume\n",
        rep.computed + rep.resumed, rep.samples, ukdyn::printable(out));
    return 1;
  }
  return 0;
}

// OUT/replay.html of a run: the page's size on stdout (unless quiet).
int write_replay_page(const ukdyn::Scenario& sc, const std::string& out, bool quiet,
                      const std::string& status) {
  ukdyn::ReplayOptions ro;
  ro.status = status;
  const auto r = ukdyn::write_replay(sc, out, ro);
  if (!quiet) {
    std::cout << fmt::format(
        "replay page:          {} ({:.2f} MB, {} frames{})\n", ukdyn::printable(r.file.string()),
        static_cast<double>(r.bytes) / 1e6, r.frames,
        r.stride > 1 ? fmt::format(", 1 in {} of {} samples", r.stride, r.source_rows)
                     : std::string());
  }
  for (const auto& s : r.left_out) {
    if (s.find("drawn as its bounding box") != std::string::npos) {  // an MJCF mesh
      std::cerr << "ukdyn: note: replay: " << ukdyn::printable(s) << "\n";
    } else if (s.find(" (") != std::string::npos) {  // a shape of a link: "NAME.LINK (why)"
      std::cerr << "ukdyn: note: replay: not drawn: " << ukdyn::printable(s) << "\n";
    } else {
      std::cerr << "ukdyn: note: replay: subsystem '" << ukdyn::printable(s)
                << "' is not drawn (no geometry)\n";
    }
  }
  return 0;
}

// OUT/summary.json of a run, read with the checks of every input file (at most 1 MiB); null if
// there is none.
nlohmann::json run_summary(const std::string& out_dir) {
  const std::string summary = out_dir + "/summary.json";
  try {
    const std::string text = ukdyn::detail::read_input_file(
        summary, {"run summary", ukdyn::detail::kMiB, ukdyn::printable(summary)});
    return nlohmann::json::parse(text, nullptr, false);
  } catch (const ukdyn::detail::InputFileError& e) {
    if (e.missing()) return nullptr;
    throw ukdyn::ScenarioError(e.what());
  }
}

// The scenario of an output folder when --scenario is not given: the file its summary.json names,
// read only if its text is the run's (the hash summary.json records). A summary.json is data
// like any other: a path in it that leads elsewhere is never parsed (nor quoted in a message).
ukdyn::Scenario scenario_of(const std::string& out_dir, const nlohmann::json& j) {
  const std::string summary = ukdyn::printable(out_dir + "/summary.json");
  const auto path = nlohmann::json::json_pointer("/scenario/path");
  const auto hash = nlohmann::json::json_pointer("/scenario/hash_fnv1a64");
  if (j.is_null()) {
    throw ukdyn::ScenarioError(summary +
                               ": no such file: not the output folder of a run (give a folder "
                               "`ukdyn simulate` wrote, or the scenario with --scenario)");
  }
  if (j.is_discarded())
    throw ukdyn::ScenarioError(summary + ": not JSON (give the scenario with --scenario)");
  if (!j.is_object() || !j.contains(path) || !j[path].is_string() || !j.contains(hash) ||
      !j[hash].is_string())
    throw ukdyn::ScenarioError(summary +
                               ": no scenario.path and hash_fnv1a64 (give the scenario with "
                               "--scenario)");
  const std::string file = j[path].get<std::string>();
  const std::string text = ukdyn::read_scenario_text(file);
  if (ukdyn::scenario_text_hash(text) != j[hash].get<std::string>())
    throw ukdyn::ScenarioError(
        summary + ": the scenario it names, " + ukdyn::printable(file) +
        ", is not the run's (its hash differs from summary.json's): give the scenario with "
        "--scenario");
  return ukdyn::load_scenario_text(text, file);
}

// f(), with an error of the model at the scenario's state (the linearisation's "the forward
// dynamics is not finite at this state": a mass of 1e308 times gravity) said with the scenario
// file, as bad input; the errors that already name a file or an output are passed on.
template <typename F>
int naming_the_scenario(const std::string& scenario, F f) {
  try {
    return f();
  } catch (const ukdyn::ScenarioError&) {
    throw;
  } catch (const ukdyn::OutputRefused&) {
    throw;
  } catch (const ukdyn::WriteFailed&) {
    throw;
  } catch (const ukdyn::Error& e) {
    throw ukdyn::ScenarioError(ukdyn::printable(scenario) + ": " + e.what());
  }
}

struct LinearizeArgs {
  bool minimal = false;
  std::string dt;  ///< --dt as given (parse_step())
  std::string state, row, out;
  std::vector<std::string> parameters;
  bool closed_loop = false;
};

// `ukdyn optimize`: solve, write the run folder, print what was found. Exit 0 when IPOPT
// converged and ukdyn vouches for the result, 1 otherwise (the folder is written either way).
int cmd_optimize(const std::string& problem, const std::string& out, bool quiet) {
  ukdyn::OptimizationFile f = ukdyn::load_optimization_file(problem);
  if (!ukdyn::ipopt_available()) ukdyn::optimize_trajectory(f.problem);  // throws the message
  // Ctrl-C (or SIGTERM) stops IPOPT after its current iteration; the folder is written with the
  // last iterate, untrusted (summary.json says interrupted), and the exit code is 1.
  std::signal(SIGINT, on_interrupt);
  std::signal(SIGTERM, on_interrupt);
  f.ipopt.cancel = &g_interrupted;
  const ukdyn::OptimizeReport rep = ukdyn::run_optimization(f, out);
  const auto& s = rep.solution;
  if (!quiet) {
    std::cout << fmt::format(
        "{}: {} ({} iterations, {:.2f} s), cost {:.9g}, duration {:.6g} s\n"
        "  {} with {} intervals; max defect {:.2e}, |Phi| {:.2e}, |Phi'| {:.2e}, correction "
        "{:.2e}\n",
        ukdyn::printable(f.name), s.status, s.iterations, rep.wall_seconds, s.cost, s.duration,
        ukdyn::to_string(f.problem.method), f.problem.intervals, s.max_defect,
        s.max_position_residual, s.max_velocity_residual, s.max_correction);
    if (!f.problem.waypoints.empty())
      std::cout << fmt::format("  {} waypoint(s): max |Phi_w| {:.2e}\n", f.problem.waypoints.size(),
                               s.max_waypoint_residual);
    if (rep.replay.done)
      std::cout << fmt::format(
          "  open-loop replay of u(t): {}, max |q - q_opt| {:.2e}, |Phi| {:.2e}\n",
          rep.replay.status, rep.replay.max_q_deviation, rep.replay.max_position_residual);
    std::cout << fmt::format(
        "  wrote {}/trajectory.csv, summary.json, replay.yaml, replay_open_loop.yaml\n",
        ukdyn::printable(out));
  }
  if (rep.replay.done && !(rep.replay.max_q_deviation <= 1e-3))
    std::cerr << fmt::format(
        "ukdyn: warning: the optimal u(t) integrated open loop leaves the optimal motion by {:.2e} "
        "(an open-loop unstable system, or a mesh that does not resolve the motion)\n",
        rep.replay.max_q_deviation);
  if (!rep.replay_scenario_note.empty())
    std::cerr << "ukdyn: warning: replay.yaml: " << ukdyn::printable(rep.replay_scenario_note, true)
              << "\n";
  if (!s.trusted) {
    std::cerr << "ukdyn: warning: " << ukdyn::printable(s.message, true) << "\n";
    return 1;
  }
  return 0;
}

// `ukdyn size`: the smallest catalogue motor + gearbox per actuator (docs/sizing.md). Exit 0 when
// every actuator has one, 1 when some has none that holds (or the iteration did not settle, or it
// was interrupted), 2 for bad input.
int cmd_size(const std::string& file, const std::string& out_arg, int threads, bool quiet) {
  const ukdyn::SizingFile f = ukdyn::load_sizing_file(file);
  const std::string out = out_arg.empty() ? "out/size-" + f.name : out_arg;
  ukdyn::check_output_folder(out);  // refused before the runs, not after them
  std::signal(SIGINT, on_interrupt);
  std::signal(SIGTERM, on_interrupt);
  ukdyn::SizingOptions opt;
  opt.threads = threads;
  opt.progress = quiet ? nullptr : &std::cerr;
  opt.cancel = &g_interrupted;
  const ukdyn::SizingResult r = ukdyn::run_sizing(f, opt);
  if (g_interrupted.load()) {
    std::cerr << "ukdyn: size interrupted: nothing written\n";
    return 1;
  }
  ukdyn::write_sizing(f, r, out);
  if (!quiet) {
    ukdyn::print_sizing_report(std::cout, f, r);
    std::cout << "  wrote " << ukdyn::printable(out) << "/sizing.json, candidates.csv\n";
  }
  std::cout.flush();
  int rc = 0;
  for (std::size_t a = 0; a < f.actuators.size(); ++a) {
    const ukdyn::SizingChoice& c = r.choices[a];
    if (c.found) continue;
    std::cerr << ukdyn::printable(
        fmt::format("ukdyn: actuator '{}': no catalogue entry keeps the margin {:.3g} %: the best, "
                    "{}, keeps "
                    "{:.3g} % (short by {:.3g} points)\n",
                    f.actuators[a].name, 100.0 * f.margin,
                    ukdyn::candidate_name(f.catalogue, f.actuators[a].candidates[c.best_candidate]),
                    100.0 * c.best_margin, 100.0 * (f.margin - c.best_margin)),
        true);
    rc = 1;
  }
  if (!r.converged) {
    std::cerr << fmt::format(
        "ukdyn: the sizing did not settle in {} rounds (max_rounds): the choices are those of the "
        "last round and not vouched for\n",
        f.max_rounds);
    rc = 1;
  }
  return rc;
}

// --dt: a finite step > 0 in plain decimal (not NaN, which would silently leave the discrete model
// out, nor inf, hex or a number that overflows).
double parse_step(const std::string& text) {
  double v = 0.0;
  const char* end = text.data() + text.size();
  const auto r = std::from_chars(text.data(), end, v, std::chars_format::general);
  if (text.empty() || r.ec != std::errc() || r.ptr != end || !std::isfinite(v) || !(v > 0.0))
    throw ukdyn::Error("--dt '" + ukdyn::printable(text) +
                       "': expected a finite step > 0 in seconds, e.g. --dt 0.01");
  return v;
}

// --out FILE of `ukdyn linearize`: written whole to FILE.part beside it, then renamed, so FILE is
// either the complete object or absent/unchanged (a full disk, Ctrl-C). Refused (exit 2) before
// anything is written: a folder that does not exist or cannot be written, and a FILE that is not a
// regular file (a folder, a FIFO, whose open would block, a device, a symbolic link).
void write_whole_file_check(const std::string& path) {
  namespace fs = std::filesystem;
  const fs::path file(path);
  const fs::path dir = file.parent_path().empty() ? fs::path(".") : file.parent_path();
  const std::string shown = ukdyn::printable(path);
  std::error_code ec;
  const auto dir_status = fs::status(dir, ec);
  if (!fs::is_directory(dir_status))
    throw ukdyn::OutputRefused("--out " + shown + ": the folder " + ukdyn::printable(dir.string()) +
                               (fs::exists(dir_status) ? " is not a folder" : " does not exist"));
  const auto st = fs::symlink_status(file, ec);
  if (fs::exists(st) && !fs::is_regular_file(st))
    throw ukdyn::OutputRefused("--out " + shown + ": exists and is not a regular file (" +
                               (fs::is_directory(st) ? "a folder"
                                : fs::is_symlink(st) ? "a symbolic link"
                                : fs::is_fifo(st)    ? "a FIFO"
                                                     : "a device or socket") +
                               "): refusing to replace it");
  if (::access(dir.c_str(), W_OK) != 0)
    throw ukdyn::OutputRefused("--out " + shown + ": cannot write into " +
                               ukdyn::printable(dir.string()) + ": " + std::strerror(errno));
}

void write_whole_file(const std::string& path, const std::string& bytes) {
  namespace fs = std::filesystem;
  write_whole_file_check(path);  // again: the folder may have changed during the work
  const fs::path file(path);
  const std::string shown = ukdyn::printable(path);
  std::error_code ec;
  // FILE.part: a stale one of ours (a regular file) is replaced; anything else there (a FIFO,
  // whose open would block, a link) is refused; created anew, never through a link.
  const std::string part = path + ".part";
  const auto part_status = fs::symlink_status(part, ec);
  if (fs::exists(part_status) && !fs::is_regular_file(part_status))
    throw ukdyn::OutputRefused(ukdyn::printable(part) +
                               ": exists and is not a regular file: refusing to replace it");
  fs::remove(part, ec);
  const int fd = ::open(part.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0644);
  if (fd < 0)
    throw ukdyn::WriteFailed("cannot create " + ukdyn::printable(part) + ": " +
                             std::strerror(errno));
  std::size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t w = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (w < 0 && errno == EINTR) continue;
    if (w < 0) {
      const int e = errno;
      ::close(fd);
      fs::remove(part, ec);
      throw ukdyn::WriteFailed("writing " + ukdyn::printable(part) +
                               " failed: " + std::strerror(e));
    }
    done += static_cast<std::size_t>(w);
  }
  if (::close(fd) != 0) {
    fs::remove(part, ec);
    throw ukdyn::WriteFailed("writing " + ukdyn::printable(part) + " failed");
  }
  fs::rename(part, file, ec);
  if (ec) {
    fs::remove(part, ec);
    throw ukdyn::WriteFailed("cannot rename " + ukdyn::printable(part) + " to " + shown);
  }
}

// `ukdyn linearize`: the state (the scenario's initial one, --state or --row), then the JSON on
// stdout or in --out. Exit 0, or 1 when ukdyn cannot vouch for the derivatives.
int cmd_linearize(const ukdyn::Scenario& sc, const LinearizeArgs& a) {
  ukdyn::LinearizeState st{sc.sim.t0, sc.q0, sc.qd0, sc.tau};
  const double dt = a.dt.empty() ? 0.0 : parse_step(a.dt);
  if (!a.state.empty()) st = ukdyn::read_state_json(sc, a.state);
  if (!a.row.empty()) {  // RUN.csv:N, split at the last ':'; N decimal digits only
    const auto colon = a.row.rfind(':');
    const std::string digits = colon == std::string::npos ? "" : a.row.substr(colon + 1);
    long n = -1;
    const auto r = std::from_chars(digits.data(), digits.data() + digits.size(), n);
    if (digits.empty() || r.ec != std::errc() || r.ptr != digits.data() + digits.size() || n < 0)
      throw ukdyn::Error("--row " + ukdyn::printable(a.row) +
                         ": expected RUN.csv:N (N >= 0 in decimal digits, the data row)");
    st = ukdyn::read_state_csv_row(sc, a.row.substr(0, colon), n);
  }
  if (a.closed_loop && a.state.empty() && a.row.empty()) {  // the closed loop's start
    const auto run = ukdyn::make_control_run(sc);
    if (!run)
      throw ukdyn::Error("--closed-loop: the scenario has no control: section (docs/control.md)");
    st.q = run->q0;
    st.qd = run->qd0;
  }
  const ukdyn::LinearizeOptions opt{a.minimal, dt, a.parameters, a.closed_loop, &std::cerr};
  if (a.out.empty()) {
    return naming_the_scenario(sc.path.string(), [&] {
      return ukdyn::write_linearization(sc, st.t, st.q, st.qd, st.tau, std::cout, opt) ? 0 : 1;
    });
  }
  const bool npz = a.out.ends_with(".npz");
  if (!npz && !a.out.ends_with(".json"))
    throw ukdyn::Error("--out " + ukdyn::printable(a.out) +
                       ": name it FILE.json (JSON) or FILE.npz (numpy)");
  write_whole_file_check(a.out);  // refused before the work, not after it
  // Computed whole before the file is opened: an error leaves no empty or partial FILE behind.
  std::ostringstream bytes(std::ios::binary);
  const bool trusted = naming_the_scenario(sc.path.string(), [&] {
    return npz ? ukdyn::write_linearization_npz(sc, st.t, st.q, st.qd, st.tau, bytes, opt)
               : ukdyn::write_linearization(sc, st.t, st.q, st.qd, st.tau, bytes, opt);
  });
  write_whole_file(a.out, bytes.str());
  return trusted ? 0 : 1;
}

}  // namespace

// long function main: the command line as one CLI11 table (every subcommand, its options and its
// help text), read top to bottom; the work is in ukdyn::io.
int main(int argc, char** argv) {
  // A file-size limit (ulimit -f) makes a write fail (EFBIG), reported like a full disk, instead
  // of killing the process before it can say so.
  std::signal(SIGXFSZ, SIG_IGN);
  CLI::App app{"ukdyn: Udwadia–Kalaba dynamics of constrained multibody systems"};
  app.set_version_flag("--version", std::string(ukdyn::version()));
  app.require_subcommand(1);

  std::string scenario, out = "out";
  bool no_figures = false, quiet = false, do_assemble = false;
  auto* sim = app.add_subcommand(
      "simulate", "Simulate a scenario; write trajectory.csv, summary.json, figures/");
  sim->add_option("scenario", scenario, "scenario file (YAML)")->required();
  sim->add_option("--out,-o", out,
                  "output folder (not a filesystem root; ukdyn touches only its own files there)")
      ->capture_default_str();
  sim->add_flag("--no-figures", no_figures, "skip the figures");
  sim->add_flag("--quiet,-q", quiet, "print nothing but errors");
  double progress_every = 5.0;
  sim->add_option("--progress-every", progress_every,
                  "seconds between progress lines when stderr is not a terminal")
      ->check(CLI::Range(0.01, 86400.0))
      ->capture_default_str();
  sim->add_flag(
      "--assemble", do_assemble,
      "first move q0, qd0 onto the constraints (holding initial.hold), as `assemble` does");
  bool html = false;
  sim->add_flag("--html", html, "also write OUT/replay.html, the run in 3D (docs/replay.md)");

  std::string replay_dir, replay_scenario;
  auto* rpl = app.add_subcommand(
      "replay", "Write OUT_DIR/replay.html: the run of OUT_DIR in 3D, one self-contained page");
  rpl->add_option("out_dir", replay_dir, "output folder of a run (trajectory.csv)")->required();
  rpl->add_option("--scenario,-s", replay_scenario,
                  "its scenario (default: the path in OUT_DIR/summary.json)");
  rpl->add_flag("--quiet,-q", quiet, "print nothing but errors");

  auto* asmb = app.add_subcommand(
      "assemble", "Find the consistent (q0, qd0) nearest to the scenario's guess and report it");
  asmb->add_option("scenario", scenario, "scenario file (YAML)")->required();

  auto* ev = app.add_subcommand(
      "eval",
      "Read JSON lines {t, q, qd, tau} on stdin; write M, C, G, A, b, Qc, qdd as JSON lines");
  ev->add_option("scenario", scenario, "scenario file (YAML)")->required();

  auto* lin = app.add_subcommand(
      "linearize",
      "Print the exact derivatives of q'' and Qc at the scenario's initial state as JSON");
  lin->add_option("scenario", scenario, "scenario file (YAML)")->required();
  LinearizeArgs la;
  lin->add_flag("--minimal", la.minimal,
                "also the model in minimal coordinates on the constraint manifold");
  lin->add_option("--dt", la.dt, "also the zero-order-hold discrete model with this step (s)");
  auto* lin_state =
      lin->add_option("--state", la.state, "linearise at {t, q, qd, tau} of this JSON file");
  lin->add_option("--row", la.row,
                  "linearise at data row N (from 0) of a run's trajectory.csv: RUN.csv:N")
      ->excludes(lin_state);
  lin->add_option("--out,-o", la.out,
                  "write FILE.json (the JSON) or FILE.npz (numpy arrays) instead of stdout");
  lin->add_flag("--closed-loop", la.closed_loop,
                "a control scenario's plant under its law: F and the minimal model with the law's "
                "d tau/d(q, qd), at the closed loop's start unless --state or --row");
  lin->add_option("--param,-p", la.parameters,
                  "also the derivatives with respect to this number of the scenario file (a "
                  "parameters: key or a path; repeatable; docs/derivatives.md)");

  std::vector<std::string> sens_params;
  std::string sens_out = "out";
  auto* sens = app.add_subcommand(
      "sensitivities",
      "Write OUT/sensitivities.csv: dq/dp and dqd/dp of the scenario's run for named parameters");
  sens->add_option("scenario", scenario, "scenario file (YAML)")->required();
  sens->add_option("--param,-p", sens_params,
                   "a number of the scenario file (a parameters: key or a path; repeatable)")
      ->required();
  sens->add_option("--out,-o", sens_out, "output folder")->capture_default_str();

  auto* chk =
      app.add_subcommand("check", "Load and validate a scenario (the initial state included)");
  chk->add_option("scenario", scenario, "scenario file (YAML)")->required();

  std::string derive_format = "latex";
  auto* drv = app.add_subcommand(
      "derive",
      "Print the derived, simplified M, C, G and A, b of a scenario written by definitions");
  drv->add_option("scenario", scenario, "scenario file (YAML)")->required();
  drv->add_option("--format,-f", derive_format, "latex, c, matlab or text")
      ->check(CLI::IsMember({"latex", "c", "matlab", "text"}))
      ->capture_default_str();

  SweepArgs sa;
  auto* swp = app.add_subcommand(
      "sweep", "Run a scenario over a grid, a list or random draws of its parameters");
  swp->add_option("sweep", sa.file, "sweep file (YAML, docs/sweeps.md)");
  swp->add_option("--out,-o", sa.out, "output folder (default out/sweep-NAME)");
  swp->add_option("--threads,-j", sa.threads, "worker threads (default: every core)")
      ->check(CLI::Range(1, ukdyn::max_sweep_threads()));
  swp->add_option("--shard", sa.shard, "compute shard i of N (samples k with k % N == i)");
  swp->add_option("--extract", sa.extract, "print sample K as a standalone scenario")
      ->check(CLI::Range(0L, 100000000L));
  swp->add_flag("--no-figures", sa.no_figures, "skip the figures");
  swp->add_flag("--quiet,-q", sa.quiet, "print nothing but errors");
  swp->add_option("--progress-every", sa.progress_every,
                  "seconds between progress lines when stderr is not a terminal")
      ->check(CLI::Range(0.01, 86400.0))
      ->capture_default_str();
  swp->add_flag("--fresh", sa.fresh, "ignore the journal of an earlier, interrupted run");
  auto* mrg = swp->add_subcommand("merge", "Merge the output folders of shards into one table");
  mrg->add_option("sweep", sa.file, "sweep file (YAML)")->required();
  mrg->add_option("--out,-o", sa.out, "output folder")->required();
  mrg->add_option("shards", sa.shard_dirs, "the shards' output folders")->required();
  mrg->add_flag("--quiet,-q", sa.quiet, "print nothing but errors");

  std::string problem;
  auto* opt = app.add_subcommand(
      "optimize",
      "Optimal trajectory of a problem file by collocation on IPOPT (docs/optimization.md)");
  opt->add_option("problem", problem, "problem file (YAML)")->required();
  opt->add_option("--out,-o", out, "output folder")->capture_default_str();
  opt->add_flag("--quiet,-q", quiet, "print nothing but errors and warnings");

  std::string size_file, size_out;
  int size_threads = 0;
  auto* sz = app.add_subcommand(
      "size", "Choose the smallest catalogue motor + gearbox for each actuator (docs/sizing.md)");
  sz->add_option("sizing", size_file, "sizing file (YAML)")->required();
  sz->add_option("--out,-o", size_out, "output folder (default out/size-NAME)");
  sz->add_option("--threads,-j", size_threads, "worker threads (default: every core)")
      ->check(CLI::Range(1, 4096));
  sz->add_flag("--quiet,-q", quiet, "print nothing but errors and warnings");

  try {
    app.parse(argc, argv);
    if (*swp && !*mrg && sa.file.empty()) throw CLI::RequiredError("sweep");
  } catch (const CLI::ParseError& e) {
    // --help and --version exit 0; every usage error exits 2 (CLI11's own codes are 105–114).
    return app.exit(e) == 0 ? 0 : 2;
  }

  try {
    if (*swp) return cmd_sweep(sa, mrg->parsed(), &argc, &argv);
    if (*opt) return cmd_optimize(problem, out, quiet);
    if (*sz) return cmd_size(size_file, size_out, size_threads, quiet);
    if (*rpl) {
      // The run folder and its scenario are checked first (bad input is named as such whatever
      // this build can draw).
      const nlohmann::json j = run_summary(replay_dir);
      const ukdyn::Scenario sc = replay_scenario.empty()
                                     ? scenario_of(replay_dir, j)
                                     : ukdyn::load_scenario_file(replay_scenario);
      if (!ukdyn::replay_available()) {
        throw ukdyn::Error(
            "ukdyn replay: this ukdyn was built without three.js (web/node_modules/three was "
            "missing when it was configured): run `npm ci` in web/ (scripts/install-deps.sh does) "
            "and rebuild");
      }
      std::string status = "unknown";
      if (j.is_object() && j.contains("status") && j["status"].is_string()) status = j["status"];
      if (j.is_object() && j.contains("scenario") && j["scenario"].is_object() &&
          j["scenario"].value("hash_fnv1a64", sc.hash) != sc.hash) {
        std::cerr << "ukdyn: warning: " << ukdyn::printable(replay_scenario)
                  << " changed since the run (its hash differs from summary.json's)\n";
      }
      return write_replay_page(sc, replay_dir, quiet, status);
    }
    const bool assembling = *asmb || (*sim && do_assemble);
    ukdyn::LoadOptions lopt;
    lopt.check_initial = !assembling;
    lopt.symbolic_chains = static_cast<bool>(*drv);  // derive prints the chains' M, C, G
    ukdyn::Scenario sc = ukdyn::load_scenario_file(scenario, lopt);
    if (assembling) {
      const auto a = ukdyn::assemble(*sc.system, sc.sim.t0, sc.q0, sc.qd0, sc.held);
      if (!ukdyn::print_assembly_report(*asmb ? std::cout : std::cerr, std::cerr, sc, a)) return 2;
      if (*asmb) {
        ukdyn::print_assembled_initial(std::cout, sc, a);
        return 0;
      }
      sc.q0 = a.q;
      sc.qd0 = a.qd;
    }
    if (*sim || *chk) {  // what the robot file readers left out (meshes, limits taken as absent)
      if (*chk || !quiet) {
        for (const auto& note : sc.notes)
          std::cerr << "ukdyn: note: " << ukdyn::printable(note) << "\n";
      }
    }
    if (*sim) {
      if (html && !ukdyn::replay_available()) {  // said before the run, not after it
        ukdyn::write_replay(sc, out);            // throws the message: how to get three.js
      }
      // outputs.sensitivities: resolved before the run (bad input exits 2 with nothing written),
      // integrated after it into OUT/sensitivities.csv (docs/derivatives.md).
      const auto sens_ps = ukdyn::requested_parameters(sc);
      int rc = cmd_simulate(sc, out, !no_figures, quiet, progress_every);
      std::ostringstream unshown;  // --quiet: the report line is not printed
      if (!sens_ps.empty() &&
          !ukdyn::write_run_sensitivities(sc, sens_ps, out, quiet ? unshown : std::cout))
        rc = rc == 0 ? 1 : rc;
      if (!html) return rc;
      try {
        write_replay_page(sc, out, quiet, rc == 0 ? "complete" : "incomplete");
      } catch (const ukdyn::OutputRefused&) {
        throw;
      } catch (const std::exception& e) {
        std::cerr << "ukdyn: error: replay page: " << ukdyn::printable(e.what(), true) << "\n";
        return rc == 0 ? 1 : rc;
      }
      return rc;
    }
    if (*ev) {
      const auto counts = ukdyn::run_eval_protocol(sc, std::cin, std::cout, &std::cerr);
      return counts.failures == 0 ? 0 : 1;
    }
    if (*lin) {  // exit 1: computed, but ukdyn cannot vouch for them ("trusted": false)
      return cmd_linearize(sc, la);
    }
    if (*sens) {  // exit 1: computed, but ukdyn cannot vouch for them ("trusted": false)
      return naming_the_scenario(scenario, [&] {
        const auto ps = ukdyn::scenario_parameters(sc, sens_params);
        return ukdyn::write_run_sensitivities(sc, ps, sens_out, std::cout) ? 0 : 1;
      });
    }
    if (*drv) {
      std::cout << ukdyn::symbolic::format_system(*sc.system,
                                                  ukdyn::symbolic::parse_format(derive_format));
      return 0;
    }
    if (*chk) {
      ukdyn::requested_parameters(sc);  // outputs.sensitivities names numbers the run uses
      std::cout << fmt::format("{}: ok: '{}', {} coordinates, {} constraint rows\n",
                               ukdyn::printable(scenario), ukdyn::printable(sc.name),
                               sc.system->dof(), sc.system->rows());
      return 0;
    }
  } catch (const ukdyn::WriteFailed& e) {
    std::cerr << "ukdyn: error: " << ukdyn::printable(e.what(), true) << "\n";
    return 1;
  } catch (const std::exception& e) {
    // ScenarioError, OutputRefused (a root, a folder in use, a planted link), other bad input.
    std::cerr << "ukdyn: error: " << ukdyn::printable(e.what(), true) << "\n";
    return 2;
  }
  return 0;
}
