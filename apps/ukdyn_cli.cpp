// ukdyn: command-line front end. Holds no physics: it parses arguments and calls ukdyn::io.
//   ukdyn simulate SCENARIO [--out DIR] [--no-figures] [--quiet]
//   ukdyn eval SCENARIO            (JSON lines on stdin → JSON lines on stdout)
//   ukdyn check SCENARIO           (load and validate only)
//   ukdyn derive SCENARIO [--format latex|c|matlab|text]  (derived M, C, G, A, b;
//   docs/definitions.md)
// Exit codes: 0 success, 1 run incomplete or some eval lines failed, 2 bad input.
#include <fmt/format.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <atomic>
#include <cmath>
#include <csignal>
#include <iostream>
#include <nlohmann/json.hpp>
#include <string>

#include "ukdyn/io/run.hpp"
#include "ukdyn/io/scenario.hpp"
#include "ukdyn/symbolic/definitions.hpp"

#ifndef UKDYN_VERSION
#define UKDYN_VERSION "unknown"
#endif

namespace {

using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;
using json = nlohmann::json;

json rows_of(const Mat& M) {
  json out = json::array();
  for (Index i = 0; i < M.rows(); ++i) {
    json r = json::array();
    for (Index j = 0; j < M.cols(); ++j) r.push_back(M(i, j));
    out.push_back(r);
  }
  return out;
}

json vec_of(const Vec& v) {
  json out = json::array();
  for (Index i = 0; i < v.size(); ++i) out.push_back(v(i));
  return out;
}

Vec read_vec(const json& j, const char* key, Index n, bool required) {
  if (!j.contains(key)) {
    if (required) throw ukdyn::Error(fmt::format("missing key '{}'", key));
    return Vec::Zero(n);
  }
  const json& a = j.at(key);
  if (!a.is_array() || static_cast<Index>(a.size()) != n) {
    throw ukdyn::Error(fmt::format("key '{}': expected a list of {} numbers", key, n));
  }
  Vec v(n);
  for (Index i = 0; i < n; ++i) {
    const json& e = a[static_cast<std::size_t>(i)];
    if (!e.is_number()) throw ukdyn::Error(fmt::format("key '{}[{}]': expected a number", key, i));
    v(i) = e.get<double>();
    if (!std::isfinite(v(i))) throw ukdyn::Error(fmt::format("key '{}[{}]': not finite", key, i));
  }
  return v;
}

int cmd_eval(const ukdyn::Scenario& sc) {
  const ukdyn::System& sys = *sc.system;
  const Index n = sys.dof();
  ukdyn::ForwardData data(sys);
  Mat C(n, n);
  std::string line;
  long lineno = 0;
  int failures = 0;
  while (std::getline(std::cin, line)) {
    ++lineno;
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    try {
      json in;
      try {
        in = json::parse(line);
      } catch (const json::parse_error& e) {
        throw ukdyn::Error(std::string("invalid JSON: ") + e.what());
      }
      if (!in.is_object())
        throw ukdyn::Error("expected a JSON object {\"t\", \"q\", \"qd\", \"tau\"}");
      double t = 0.0;
      if (in.contains("t")) {
        if (!in["t"].is_number()) throw ukdyn::Error("key 't': expected a number");
        t = in["t"].get<double>();
      }
      const Vec q = read_vec(in, "q", n, true);
      const Vec qd = read_vec(in, "qd", n, true);
      const Vec tau = read_vec(in, "tau", n, false);
      ukdyn::forward(sys, data, t, q, qd, tau, sc.sim.uk);
      ukdyn::coriolis_matrix(sys, q, qd, C);
      json out;
      out["t"] = t;
      out["M"] = rows_of(data.M);
      out["C"] = rows_of(C);
      out["Cqd"] = vec_of(data.Cqd);
      out["G"] = vec_of(data.G);
      out["Q"] = vec_of(data.Q);
      out["A"] = rows_of(data.A);
      out["b"] = vec_of(data.b);
      out["Qc"] = vec_of(data.Qc);
      out["qdd"] = vec_of(data.qdd);
      out["rank"] = data.result.rank;
      out["residual"] = data.result.residual;
      out["consistent"] = data.result.consistent;
      if (sys.rows() > 0) {
        out["singular_values"] = vec_of(ukdyn::singular_values_A_Minvhalf(data.M, data.A));
      }
      std::cout << out.dump() << "\n";
    } catch (const std::exception& e) {
      ++failures;
      const std::string msg = fmt::format("stdin:{}: {}", lineno, e.what());
      std::cerr << "ukdyn eval: " << msg << "\n";
      std::cout << json{{"error", msg}}.dump() << "\n";
    }
  }
  std::cout.flush();
  return failures == 0 ? 0 : 1;
}

// Prints what assembly changed; returns false (and names the constraints) if it failed.
bool report_assembly(const ukdyn::Scenario& sc, const ukdyn::AssemblyResult& a, std::ostream& os) {
  const auto& names = sc.system->coordinate_names();
  os << fmt::format(
      "assembly: {} Gauss-Newton iterations, max |Phi| = {:.3e}, max |Phi_dot| = {:.3e}\n",
      a.iterations, a.max_position_residual, a.max_velocity_residual);
  os << fmt::format("  {:<14} {:>24} {:>24} {:>11} {:>11}\n", "coordinate", "q guess",
                    "q assembled", "change", "qd change");
  for (std::size_t j = 0; j < names.size(); ++j) {
    const auto i = static_cast<Index>(j);
    const double dq = a.q(i) - sc.q0(i), dv = a.qd(i) - sc.qd0(i);
    if (dq == 0.0 && dv == 0.0) continue;
    os << fmt::format("  {:<14} {:>24.17g} {:>24.17g} {:>11.3e} {:>11.3e}{}\n", names[j], sc.q0(i),
                      a.q(i), dq, dv, sc.held[j] ? "  (held)" : "");
  }
  if (!a.success) {
    std::string rows;
    for (Index r : a.unmet_rows) {
      rows += (rows.empty() ? "" : ", ") +
              sc.system->constraint_row_names()[static_cast<std::size_t>(r)];
    }
    std::cerr << fmt::format("ukdyn: error: {}: {}; constraints not met: {}\n", sc.path.string(),
                             a.message, rows.empty() ? "-" : rows);
    return false;
  }
  return true;
}

std::atomic<bool> g_interrupted{false};
extern "C" void on_interrupt(int /*signal*/) { g_interrupted.store(true); }

int cmd_simulate(const ukdyn::Scenario& sc, const std::string& out, bool figures, bool quiet) {
  ukdyn::RunOptions opt;
  opt.figures = figures;
  if (!quiet && isatty(STDERR_FILENO)) opt.progress = &std::cerr;
  // Ctrl-C (or SIGTERM) ends the run at the next sample; what was computed is kept.
  std::signal(SIGINT, on_interrupt);
  std::signal(SIGTERM, on_interrupt);
  opt.cancel = &g_interrupted;
  const auto rep = ukdyn::run_scenario(sc, out, opt);
  const auto& names = sc.system->constraint_row_names();
  double worst = 0.0;
  std::string worst_name = "-";
  for (std::size_t i = 0; i < rep.max_abs_residual.size(); ++i) {
    if (rep.max_abs_residual[i] >= worst) {
      worst = rep.max_abs_residual[i];
      worst_name = names[i];
    }
  }
  if (!quiet) {
    std::cout << fmt::format("ukdyn {}: scenario '{}' ({}), t = {} .. {} s\n", UKDYN_VERSION,
                             sc.name, sc.path.string(), sc.sim.t0, rep.stats.t_reached);
    std::cout << fmt::format("  status              {}{}\n", ukdyn::to_string(rep.stats.status),
                             rep.stats.message.empty() ? "" : " (" + rep.stats.message + ")");
    std::cout << fmt::format(
        "  steps               {} accepted, {} rejected, {} force evaluations, {} samples\n",
        rep.stats.steps, rep.stats.rejected_steps, rep.stats.rhs_evaluations, rep.stats.samples);
    const bool adaptive = sc.sim.integrator != ukdyn::IntegratorKind::rk4 && sc.sim.adaptive;
    std::cout << fmt::format(
        "  integrator          {} ({}), drift control {}\n", ukdyn::to_string(sc.sim.integrator),
        adaptive ? fmt::format("abs/rel tol {:g}/{:g}", sc.sim.abs_tol, sc.sim.rel_tol)
                 : fmt::format("fixed step {:g} s", sc.sim.step),
        ukdyn::to_string(sc.sim.drift.kind));
    std::cout << fmt::format("  wall time           {:.3f} s\n", rep.wall_seconds);
    std::cout << fmt::format("  rank of A           {}..{} of {} rows ({} free DOF)\n",
                             rep.rank_min, rep.rank_max, sc.system->rows(),
                             sc.system->dof() - rep.rank_max);
    std::cout << fmt::format("  max |residual|      {:.3e} ({})\n", worst, worst_name);
    std::cout << fmt::format("  max |A qdd - b|     {:.3e}\n", rep.max_acc_residual);
    std::cout << fmt::format(
        "  energy              E0 = {:.9g} J, max |E - E0| = {:.3e} J, max T = {:.6g} J\n", rep.E0,
        rep.max_energy_drift, rep.max_T);
    std::cout << fmt::format("  outputs             {}\n", rep.csv.string());
    std::cout << fmt::format("                      {}\n", rep.summary.string());
    if (!rep.figures.empty()) {
      std::cout << fmt::format("                      {} figures in {}\n", rep.figures.size(),
                               (std::filesystem::path(out) / "figures").string());
    }
  }
  for (const auto& w : rep.stats.warnings) {
    std::cerr << fmt::format("ukdyn: warning at t = {:.6g} s: {}\n", w.t, w.message);
  }
  if (!rep.figure_error.empty()) std::cerr << "ukdyn: warning: " << rep.figure_error << "\n";
  if (rep.stats.status != ukdyn::RunStatus::completed) {
    std::cerr << "ukdyn: run incomplete: " << sc.path.string() << ": " << rep.stats.message
              << "; partial results in " << rep.csv.string() << "\n";
    return 1;
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"ukdyn: Udwadia–Kalaba dynamics of constrained multibody systems"};
  app.set_version_flag("--version", std::string(UKDYN_VERSION));
  app.require_subcommand(1);

  std::string scenario, out = "out";
  bool no_figures = false, quiet = false, do_assemble = false;
  auto* sim = app.add_subcommand(
      "simulate", "Simulate a scenario; write trajectory.csv, summary.json, figures/");
  sim->add_option("scenario", scenario, "scenario file (YAML)")->required();
  sim->add_option("--out,-o", out, "output folder")->capture_default_str();
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

  CLI11_PARSE(app, argc, argv);

  try {
    const bool assembling = *asmb || (*sim && do_assemble);
    ukdyn::LoadOptions lopt;
    lopt.check_initial = !assembling;
    ukdyn::Scenario sc = ukdyn::load_scenario(scenario, lopt);
    if (assembling) {
      const auto a = ukdyn::assemble(*sc.system, sc.sim.t0, sc.q0, sc.qd0, sc.held);
      if (!report_assembly(sc, a, *asmb ? std::cout : std::cerr)) return 2;
      if (*asmb) return 0;
      sc.q0 = a.q;
      sc.qd0 = a.qd;
    }
    if (*sim) return cmd_simulate(sc, out, !no_figures, quiet);
    if (*ev) return cmd_eval(sc);
    if (*drv) {
      std::cout << ukdyn::symbolic::format_system(*sc.system,
                                                  ukdyn::symbolic::parse_format(derive_format));
      return 0;
    }
    if (*chk) {
      std::cout << fmt::format("{}: ok: '{}', {} coordinates, {} constraint rows\n", scenario,
                               sc.name, sc.system->dof(), sc.system->rows());
      return 0;
    }
  } catch (const ukdyn::ScenarioError& e) {
    std::cerr << "ukdyn: error: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "ukdyn: error: " << e.what() << "\n";
    return 2;
  }
  return 0;
}
