#include "ukdyn/io/run.hpp"

#include <fmt/format.h>

#include <chrono>
#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>
#include <ostream>

#include "ukdyn/io/csv_writer.hpp"
#include "ukdyn/io/plots.hpp"

#ifndef UKDYN_VERSION
#define UKDYN_VERSION "unknown"
#endif

namespace ukdyn {

std::vector<std::string> trajectory_header(const System& system) {
  std::vector<std::string> h{"t"};
  const auto& names = system.coordinate_names();
  for (const auto& n : names) h.push_back(n);
  for (const auto& n : names) h.push_back(n + "_dot");
  for (const auto& n : names) h.push_back(n + "_ddot");
  for (const auto& n : names) h.push_back("Qc_" + n);
  for (const auto& r : system.constraint_row_names()) h.push_back("res_" + r);
  h.insert(h.end(), {"T", "V", "E", "rank", "free_dof", "sigma_min", "acc_residual"});
  return h;
}

namespace {

std::vector<Figure> default_figures(const Scenario& sc) {
  const System& sys = *sc.system;
  std::vector<Figure> figs;
  // One figure per constraint block: its position-level residuals (paper Figs. 3–4 for the
  // closure).
  const auto& rows = sys.constraint_row_names();
  const auto& cons = sys.constraints();
  const auto& offs = sys.constraint_row_offsets();
  for (std::size_t c = 0; c < cons.size(); ++c) {
    Figure f;
    const std::string& first = rows[static_cast<std::size_t>(offs[c])];
    // A block of several rows is named <prefix>_<row>; a single row carries the block's name.
    const auto cut = first.rfind('_');
    const std::string block =
        cons[c]->rows() == 1 || cut == std::string::npos ? first : first.substr(0, cut);
    f.file = "residuals_" + block + ".png";
    f.title = "Constraint residuals Φ of '" + block + "' (position level)";
    f.ylabel = "Φ [m or rad]";
    for (Index r = 0; r < cons[c]->rows(); ++r) {
      f.columns.push_back("res_" + rows[static_cast<std::size_t>(offs[c] + r)]);
    }
    figs.push_back(f);
  }
  // Platform displacements of the mobile manipulators (paper Fig. 5).
  Figure plat{"platforms.png", "Platform displacements", "[m]", {}};
  for (const auto& s : sc.subsystems) {
    if (s.type == "mobile_manipulator") {
      plat.columns.push_back(sys.coordinate_names()[static_cast<std::size_t>(s.offset)]);
      plat.columns.push_back(sys.coordinate_names()[static_cast<std::size_t>(s.offset + 1)]);
    }
  }
  if (!plat.columns.empty()) figs.push_back(plat);
  // Joint angles per subsystem (paper Fig. 6), constraint forces, accelerations.
  for (const auto& s : sc.subsystems) {
    Figure ang{"angles_" + s.name + ".png", "Joint angles of '" + s.name + "'", "[rad]", {}};
    Figure qc{"constraint_force_" + s.name + ".png",
              "Constraint force Qc on '" + s.name + "'",
              "Qc [N or N·m]",
              {}};
    for (Index j = 0; j < s.dof; ++j) {
      const auto& nm = sys.coordinate_names()[static_cast<std::size_t>(s.offset + j)];
      if (s.type != "mobile_manipulator" || j >= 2) ang.columns.push_back(nm);
      qc.columns.push_back("Qc_" + nm);
    }
    figs.push_back(ang);
    figs.push_back(qc);
  }
  figs.push_back(
      {"energy.png", "Energy (T kinetic, V potential, E = T + V)", "[J]", {"T", "V", "E"}});
  return figs;
}

class Progress {
 public:
  Progress(std::ostream* os, double t0, double t1) : os_(os), t0_(t0), t1_(t1) {}
  void update(double t) {
    if (!os_) return;
    const auto now = std::chrono::steady_clock::now();
    if (now - last_ < std::chrono::milliseconds(100) && t < t1_) return;
    last_ = now;
    const double frac = std::clamp((t - t0_) / (t1_ - t0_), 0.0, 1.0);
    const int width = 40;
    const int filled = static_cast<int>(frac * width);
    *os_ << "\r[" << std::string(static_cast<std::size_t>(filled), '#')
         << std::string(static_cast<std::size_t>(width - filled), ' ') << "] "
         << fmt::format("{:5.1f}%  t = {:.3f} s", 100.0 * frac, t) << std::flush;
  }
  void done() {
    if (os_) *os_ << "\n" << std::flush;
  }

 private:
  std::ostream* os_;
  double t0_, t1_;
  std::chrono::steady_clock::time_point last_{};
};

void write_json_atomically(const std::filesystem::path& path, const nlohmann::json& j) {
  auto tmp = path;
  tmp += ".part";
  {
    std::ofstream out(tmp);
    if (!out) throw Error(tmp.string() + ": cannot open for writing");
    out << j.dump(2) << "\n";
    if (!out) throw Error(tmp.string() + ": write failed");
  }
  std::filesystem::rename(tmp, path);
}

double finite_or_null(double v) { return std::isfinite(v) ? v : std::nan(""); }

}  // namespace

RunReport run_scenario(const Scenario& sc, const std::filesystem::path& out_dir,
                       const RunOptions& options) {
  const System& sys = *sc.system;
  const Index n = sys.dof();
  const Index m = sys.rows();
  std::filesystem::create_directories(out_dir);
  // Remove what an earlier run left, so that nothing stale looks like this run's output.
  for (const char* f :
       {"trajectory.csv", "trajectory.incomplete.csv", "trajectory.csv.part", "summary.json"}) {
    std::filesystem::remove(out_dir / f);
  }
  std::filesystem::remove_all(out_dir / "figures");

  RunReport rep;
  rep.summary = out_dir / "summary.json";
  rep.max_abs_residual.assign(static_cast<std::size_t>(m), 0.0);
  rep.max_abs_velocity_residual.assign(static_cast<std::size_t>(m), 0.0);
  rep.rank_min = static_cast<int>(m);
  rep.sigma_min = std::numeric_limits<double>::infinity();

  nlohmann::json summary;
  summary["ukdyn_version"] = UKDYN_VERSION;
  summary["scenario"] = {{"name", sc.name}, {"path", sc.path.string()}, {"hash_fnv1a64", sc.hash}};
  summary["integrator"] = {
      {"method", to_string(sc.sim.integrator)},
      {"adaptive", sc.sim.integrator != IntegratorKind::rk4 && sc.sim.adaptive},
      {"drift_control", to_string(sc.sim.drift.kind)},
      {"abs_tol", sc.sim.abs_tol},
      {"rel_tol", sc.sim.rel_tol},
      {"step", sc.sim.step},
      {"sample_dt", sc.sim.sample_dt},
      {"t0", sc.sim.t0},
      {"t_end", sc.sim.t_end}};
  summary["status"] = "running";
  write_json_atomically(rep.summary, summary);

  const auto header = trajectory_header(sys);
  CsvWriter csv(out_dir / "trajectory.csv", header);
  std::vector<double> row(header.size());
  Vec phi(m), phid(m);
  Progress progress(options.progress, sc.sim.t0, sc.sim.t_end);
  bool first = true;

  auto observer = [&](double t, CVecRef q, CVecRef qd, const ForwardData& d) -> bool {
    position_residuals(sys, t, q, phi);
    velocity_residuals(sys, t, q, qd, phid);
    const double T = kinetic_energy(d, qd);
    const double V = potential_energy(sys, q);
    const double E = T + V;
    if (first) {
      rep.E0 = E;
      first = false;
    }
    rep.max_energy_drift = std::max(rep.max_energy_drift, std::abs(E - rep.E0));
    rep.max_T = std::max(rep.max_T, T);
    for (Index i = 0; i < m; ++i) {
      auto& r = rep.max_abs_residual[static_cast<std::size_t>(i)];
      r = std::max(r, std::abs(phi(i)));
      auto& v = rep.max_abs_velocity_residual[static_cast<std::size_t>(i)];
      v = std::max(v, std::abs(phid(i)));
    }
    rep.max_acc_residual = std::max(rep.max_acc_residual, d.result.residual);
    rep.rank_min = std::min(rep.rank_min, d.result.rank);
    rep.rank_max = std::max(rep.rank_max, d.result.rank);
    if (d.result.rank > 0) rep.sigma_min = std::min(rep.sigma_min, d.result.sigma_min_kept);
    std::size_t k = 0;
    row[k++] = t;
    for (Index i = 0; i < n; ++i) row[k++] = q(i);
    for (Index i = 0; i < n; ++i) row[k++] = qd(i);
    for (Index i = 0; i < n; ++i) row[k++] = d.qdd(i);
    for (Index i = 0; i < n; ++i) row[k++] = d.Qc(i);
    for (Index i = 0; i < m; ++i) row[k++] = phi(i);
    row[k++] = T;
    row[k++] = V;
    row[k++] = E;
    // Diagnostics: rank of A, free DOF n − rank, smallest kept singular value of A M^{-1/2}
    // (exact, by SVD at the sample), ‖A q̈ − b‖.
    row[k++] = d.result.rank;
    row[k++] = static_cast<double>(n - d.result.rank);
    if (m > 0) {
      const Vec sv = singular_values_A_Minvhalf(d.M, d.A);
      row[k++] = d.result.rank > 0 ? sv(d.result.rank - 1) : 0.0;
    } else {
      row[k++] = 0.0;
    }
    row[k++] = d.result.residual;
    csv.row(row);
    progress.update(t);
    return !(options.cancel && options.cancel->load());
  };

  const ForceFunction tau = [&sc](double, CVecRef, CVecRef, VecRef out) { out = sc.tau; };
  const auto start = std::chrono::steady_clock::now();
  rep.stats = simulate(sys, sc.q0, sc.qd0, tau, sc.sim, observer);
  rep.wall_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  progress.done();
  if (rep.stats.status == RunStatus::stopped && options.cancel && options.cancel->load()) {
    rep.stats.message =
        fmt::format("interrupted (SIGINT/SIGTERM) after t = {}", rep.stats.t_reached);
  }

  const bool complete = rep.stats.status == RunStatus::completed;
  rep.csv = complete ? csv.commit() : csv.abandon();
  if (complete && options.figures) {
    rep.figures =
        render_figures(rep.csv, header, default_figures(sc), out_dir / "figures", rep.figure_error);
  }

  summary["status"] = complete ? "complete" : "incomplete";
  summary["stop_reason"] = complete ? "" : to_string(rep.stats.status) + ": " + rep.stats.message;
  summary["t_reached"] = rep.stats.t_reached;
  summary["steps"] = rep.stats.steps;
  summary["rejected_steps"] = rep.stats.rejected_steps;
  summary["projection_iterations"] = rep.stats.projections;
  // Branch check (docs/singular-positions.md): the drift projection's largest corrections, and
  // the largest ratio of a position correction to what the integration error explains.
  summary["max_projection_correction"] = {{"position", rep.stats.max_position_correction},
                                          {"velocity", rep.stats.max_velocity_correction},
                                          {"ratio_to_bound", rep.stats.max_correction_ratio}};
  nlohmann::json warnings = nlohmann::json::array();
  for (const auto& w : rep.stats.warnings) {
    warnings.push_back({{"t", w.t}, {"kind", w.kind}, {"message", w.message}});
  }
  summary["warnings"] = warnings;
  summary["rhs_evaluations"] = rep.stats.rhs_evaluations;
  summary["samples"] = rep.stats.samples;
  summary["wall_seconds"] = rep.wall_seconds;
  summary["trajectory_csv"] = rep.csv.filename().string();
  nlohmann::json res = nlohmann::json::object();
  nlohmann::json vres = nlohmann::json::object();
  double worst = 0.0;
  for (Index i = 0; i < m; ++i) {
    const auto u = static_cast<std::size_t>(i);
    res[sys.constraint_row_names()[u]] = finite_or_null(rep.max_abs_residual[u]);
    vres[sys.constraint_row_names()[u]] = finite_or_null(rep.max_abs_velocity_residual[u]);
    worst = std::max(worst, rep.max_abs_residual[u]);
  }
  summary["max_abs_position_residual"] = res;
  summary["max_abs_velocity_residual"] = vres;
  summary["max_abs_position_residual_all"] = finite_or_null(worst);
  summary["max_acceleration_residual"] = finite_or_null(rep.max_acc_residual);
  summary["energy"] = {{"E0", finite_or_null(rep.E0)},
                       {"max_abs_drift", finite_or_null(rep.max_energy_drift)},
                       {"max_T", finite_or_null(rep.max_T)}};
  summary["rank"] = {{"min", rep.rank_min},
                     {"max", rep.rank_max},
                     {"rows", m},
                     {"free_dof_min", n - rep.rank_max},
                     {"smallest_kept_sigma_estimate", finite_or_null(rep.sigma_min)}};
  nlohmann::json figs = nlohmann::json::array();
  for (const auto& f : rep.figures) figs.push_back(f.lexically_relative(out_dir).string());
  summary["figures"] = figs;
  if (!rep.figure_error.empty()) summary["figure_error"] = rep.figure_error;
  write_json_atomically(rep.summary, summary);
  return rep;
}

}  // namespace ukdyn
