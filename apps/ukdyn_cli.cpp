// ukdyn: command-line front end. Holds no physics and no report formatting: it parses arguments
// and calls ukdyn::io.
//   ukdyn simulate SCENARIO [--out DIR] [--no-figures] [--quiet] [--assemble]
//   ukdyn assemble SCENARIO
//   ukdyn eval SCENARIO            (JSON lines on stdin → JSON lines on stdout)
//   ukdyn check SCENARIO           (load and validate only)
//   ukdyn derive SCENARIO [--format latex|c|matlab|text]  (derived M, C, G, A, b;
//   docs/definitions.md)
// Exit codes: 0 success; 1 run incomplete (stopped, interrupted, a write failed) or some eval lines
// failed; 2 bad input: a usage error, a bad scenario, an output folder ukdyn refuses or one in use.
#include <fmt/format.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <atomic>
#include <csignal>
#include <iostream>
#include <string>

#include "ukdyn/io/eval_protocol.hpp"
#include "ukdyn/io/run.hpp"
#include "ukdyn/io/safe_text.hpp"
#include "ukdyn/io/scenario_file.hpp"
#include "ukdyn/symbolic/definitions.hpp"

namespace {

std::atomic<bool> g_interrupted{false};
extern "C" void on_interrupt(int /*signal*/) { g_interrupted.store(true); }

int cmd_simulate(const ukdyn::Scenario& sc, const std::string& out, bool figures, bool quiet) {
  ukdyn::RunOptions opt;
  opt.figures = figures;
  if (!quiet && isatty(STDERR_FILENO)) opt.progress = &std::cerr;
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

}  // namespace

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
  sim->add_flag(
      "--assemble", do_assemble,
      "first move q0, qd0 onto the constraints (holding initial.hold), as `assemble` does");

  auto* asmb = app.add_subcommand(
      "assemble", "Find the consistent (q0, qd0) nearest to the scenario's guess and report it");
  asmb->add_option("scenario", scenario, "scenario file (YAML)")->required();

  auto* ev = app.add_subcommand(
      "eval",
      "Read JSON lines {t, q, qd, tau} on stdin; write M, C, G, A, b, Qc, qdd as JSON lines");
  ev->add_option("scenario", scenario, "scenario file (YAML)")->required();

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

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help and --version exit 0; every usage error exits 2 (CLI11's own codes are 105–114).
    return app.exit(e) == 0 ? 0 : 2;
  }

  try {
    const bool assembling = *asmb || (*sim && do_assemble);
    ukdyn::LoadOptions lopt;
    lopt.check_initial = !assembling;
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
    if (*sim) return cmd_simulate(sc, out, !no_figures, quiet);
    if (*ev) {
      const auto counts = ukdyn::run_eval_protocol(sc, std::cin, std::cout, &std::cerr);
      return counts.failures == 0 ? 0 : 1;
    }
    if (*drv) {
      std::cout << ukdyn::symbolic::format_system(*sc.system,
                                                  ukdyn::symbolic::parse_format(derive_format));
      return 0;
    }
    if (*chk) {
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
