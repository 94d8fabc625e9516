#include "ukdyn/run/run.hpp"

#include <fmt/format.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <nlohmann/json.hpp>
#include <optional>
#include <ostream>

#include "run/error_estimate.hpp"
#include "run/run_faults.hpp"
#include "run/run_observer.hpp"
#include "scenario/definitions_loader.hpp"
#include "ukdyn/output/constraint_force_output.hpp"
#include "ukdyn/output/control_output.hpp"
#include "ukdyn/output/csv_writer.hpp"
#include "ukdyn/output/plots.hpp"
#include "ukdyn/output/replay.hpp"
#include "ukdyn/text/safe_text.hpp"

namespace ukdyn {

std::vector<std::string> trajectory_header(const System& system, bool energy_balance) {
  std::vector<std::string> h{"t"};
  const auto& names = system.coordinate_names();
  for (const auto& n : names) h.push_back(n);
  for (const auto& n : names) h.push_back(n + "_dot");
  for (const auto& n : names) h.push_back(n + "_ddot");
  for (const auto& n : names) h.push_back("Qc_" + n);
  const std::vector<bool> vel = velocity_level_rows(system);
  const auto& rows = system.constraint_row_names();
  for (std::size_t i = 0; i < rows.size(); ++i) h.push_back((vel[i] ? "vres_" : "res_") + rows[i]);
  h.insert(h.end(), {"T", "V", "E", "rank", "free_dof", "sigma_min", "acc_residual"});
  if (energy_balance) h.insert(h.end(), {"W", "E_balance"});  // W = ∫ (τ + Q_nc + Qc)ᵀ q̇ dt
  return h;
}

std::vector<bool> velocity_level_rows(const System& system) {
  std::vector<bool> vel;
  for (const auto& c : system.constraints()) {
    const auto* d = dynamic_cast<const symbolic::DerivedConstraint*>(c.get());
    const bool v = d != nullptr && !d->derivation().holonomic;
    vel.insert(vel.end(), static_cast<std::size_t>(c->rows()), v);
  }
  return vel;
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
  const std::vector<bool> vel = velocity_level_rows(sys);
  for (std::size_t c = 0; c < cons.size(); ++c) {
    Figure f;
    const std::string& first = rows[static_cast<std::size_t>(offs[c])];
    // A block of several rows is named <prefix>_<row>; a single row carries the block's name.
    const auto cut = first.rfind('_');
    const std::string block =
        cons[c]->rows() == 1 || cut == std::string::npos ? first : first.substr(0, cut);
    const bool v = cons[c]->rows() > 0 && vel[static_cast<std::size_t>(offs[c])];
    f.file = "residuals_" + block + ".png";
    f.title = v ? "Velocity residuals B qdot + c of '" + block + "' (nonholonomic rows)"
                : "Constraint residuals Φ of '" + block + "' (position level)";
    f.ylabel = v ? "B qdot + c [m/s or rad/s]" : "Φ [m or rad]";
    for (Index r = 0; r < cons[c]->rows(); ++r) {
      f.columns.push_back((v ? "vres_" : "res_") + rows[static_cast<std::size_t>(offs[c] + r)]);
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
    // A serial chain's mobile base: its x, y translation (metres) here, not among the angles.
    for (const auto& c : io_detail::chain_base_coordinates(sc.definitions.get(), s.name)) {
      plat.columns.push_back(c);
    }
  }
  if (!plat.columns.empty()) figs.push_back(plat);
  // Joint angles per subsystem (paper Fig. 6), constraint forces, accelerations.
  for (const auto& s : sc.subsystems) {
    // Units: a mobile_manipulator's angles and a chain's revolute joints are rad; a chain's
    // prismatic joints are m; a definitions subsystem's coordinates may be either.
    const auto base = io_detail::chain_base_coordinates(sc.definitions.get(), s.name);
    const auto prismatic = io_detail::chain_prismatic_coordinates(sc.definitions.get(), s.name);
    const bool chain = s.type == "serial_chain";
    Figure ang{
        "angles_" + s.name + ".png",
        (chain || s.type == "mobile_manipulator" ? "Joint angles of '" : "Coordinates of '") +
            s.name + "'" + (prismatic.empty() ? "" : " (prismatic joints in m)"),
        chain || s.type == "mobile_manipulator" ? (prismatic.empty() ? "[rad]" : "[rad or m]")
                                                : "[m or rad]",
        {}};
    Figure qc{"constraint_force_" + s.name + ".png",
              "Constraint force Qc on '" + s.name + "'",
              "Qc [N or N·m]",
              {}};
    for (Index j = 0; j < s.dof; ++j) {
      const auto& nm = sys.coordinate_names()[static_cast<std::size_t>(s.offset + j)];
      const bool platform = (s.type == "mobile_manipulator" && j < 2) ||
                            std::find(base.begin(), base.end(), nm) != base.end();
      if (!platform) ang.columns.push_back(nm);
      qc.columns.push_back("Qc_" + nm);
    }
    if (!ang.columns.empty()) figs.push_back(ang);
    figs.push_back(qc);
  }
  figs.push_back(
      {"energy.png", "Energy (T kinetic, V potential, E = T + V)", "[J]", {"T", "V", "E"}});
  return figs;
}

class Progress {
 public:
  Progress(std::ostream* os, double t0, double t1, bool lines = false, double every = 5.0)
      : os_(os), t0_(t0), t1_(t1), lines_(lines), every_(every) {}
  void update(double t) {
    if (!os_) return;
    const auto now = std::chrono::steady_clock::now();
    if (lines_) {  // not a terminal: a whole line every `every_` seconds, none for a short run
      if (start_ == std::chrono::steady_clock::time_point{}) start_ = last_ = now;
      if (std::chrono::duration<double>(now - last_).count() < every_) return;
      last_ = now;
      const double frac = std::clamp((t - t0_) / (t1_ - t0_), 0.0, 1.0);
      const double el = std::chrono::duration<double>(now - start_).count();
      const double eta = frac > 0.0 ? el * (1.0 - frac) / frac : 0.0;
      *os_ << fmt::format(
                  "ukdyn: t = {:.6g} s of {:.6g} s ({:.1f}%), {:.0f} s elapsed, ETA {:.0f} s\n", t,
                  t1_, 100.0 * frac, el, eta)
           << std::flush;
      return;
    }
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
    if (os_ && !lines_) *os_ << "\n" << std::flush;
  }

 private:
  std::ostream* os_;
  double t0_, t1_;
  bool lines_ = false;
  double every_ = 5.0;
  std::chrono::steady_clock::time_point last_{}, start_{};
};

constexpr const char* kSummary = "summary.json";
constexpr const char* kCsv = "trajectory.csv";

// JSON text; invalid UTF-8 (in a path, say) is replaced, never a reason to throw.
std::string json_text(const nlohmann::json& j) {
  return j.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n";
}

void write_json(const OutputDir& out, const std::string& name, const nlohmann::json& j) {
  AtomicFile f(out, out.fd(), "", name);
  f.write(json_text(j));
  f.commit();
}

double finite_or_null(double v) { return std::isfinite(v) ? v : std::nan(""); }

// The final summary; if it cannot be written, a minimal one saying so; if not even that, no
// summary at all (never the "running" one of a run that ended).
void write_final_summary(const OutputDir& out, const nlohmann::json& summary, RunReport& rep) {
  try {
    write_json(out, kSummary, summary);
    return;
  } catch (const Error& e) {
    if (rep.write_error.empty()) rep.write_error = e.what();
  }
  try {
    write_json(out, kSummary,
               {{"ukdyn_version", version()},
                {"status", "incomplete"},
                {"stop_reason", "write failed: " + rep.write_error}});
    return;
  } catch (const Error&) {
  }
  try {
    out.remove_file(out.fd(), kSummary);
  } catch (const Error&) {
  }
  rep.summary.clear();
}

// The rows and extrema come from the SampleRecorder shared with the sweep (src/run/run_observer.hpp).
struct Observer {
  io_detail::SampleRecorder recorder;
  RunReport& rep;
  CsvWriter* csv;  ///< the rows go here, or (if null) into `memory`
  Progress& progress;
  const std::atomic<bool>* cancel;
  ConstraintForceColumns* forces = nullptr;  // the last columns of the row, if any
  ControlColumns* control = nullptr;         // after those (docs/control.md), if any
  bool split_unique = true;                  // the force split was unique at every sample
  double split_t = 0.0;                      // the first sample where it was not
  std::vector<double>* memory = nullptr;     ///< run_scenario_in_memory(): the rows, back to back
  io_detail::ShadowEstimate* shadow = nullptr;  ///< simulation.error_estimate: shadow

  bool operator()(double t, CVecRef q, CVecRef qd, const ForwardData& d) {
    if (shadow != nullptr) shadow->compare(t, q);
    std::size_t k = recorder.record(t, q, qd, d);
    std::vector<double>& row = recorder.row();
    if (forces != nullptr && !forces->empty()) {  // docs/frame-constraints.md
      if (!forces->fill(q, d, row.data() + k) && split_unique) {
        split_unique = false;
        split_t = t;
      }
      k += forces->header().size();
    }
    if (control != nullptr && !control->empty()) control->fill(t, q, qd, d, row.data() + k);
    if (!csv) {
      memory->insert(memory->end(), row.begin(), row.end());
    } else {
      try {
        csv->row(row);
      } catch (const Error& e) {
        rep.write_error = e.what();
        return false;
      }
    }
    progress.update(t);
    return !(cancel && cancel->load());
  }
};

// Every name used must be free or a regular file. The previous run's outputs go first, the
// summary before anything else, so that nothing on disk describes a run that is not this one;
// only regular files under ukdyn's own names are removed.
// The summary goes even when the run is refused below (a FIFO or a folder at another name): a
// refused run must not leave the previous run's "complete" summary in the folder.
void clear_previous_outputs(const OutputDir& out) {
  const std::string incomplete = CsvWriter::incomplete_name(kCsv);
  out.require_file_or_absent(out.fd(), "", kSummary);
  out.remove_file(out.fd(), kSummary);
  for (const std::string& f : {std::string(kSummary) + ".part", std::string(kCsv),
                               std::string(kCsv) + ".part", incomplete, std::string(kReplayFile)}) {
    out.require_file_or_absent(out.fd(), "", f);
  }
  if (const int figures = out.open_subdir("figures", false); figures >= 0) {
    ::close(figures);  // (a real folder: a link or a file there is refused by open_subdir)
  }
  // (replay.html too: a page of the previous run; simulate --html writes this run's afterwards)
  for (const std::string& f : {std::string(kCsv), incomplete, std::string(kReplayFile)}) {
    out.remove_file(out.fd(), f);
  }
  remove_previous_figures(out);
}

nlohmann::json summary_start(const Scenario& sc) {
  nlohmann::json summary;
  summary["ukdyn_version"] = version();
  summary["scenario"] = {{"name", sc.name}, {"path", sc.path.string()}, {"hash_fnv1a64", sc.hash}};
  summary["integrator"] = {{"method", to_string(sc.sim.integrator)},
                           {"adaptive", adaptive_steps(sc.sim)},
                           {"drift_control", to_string(sc.sim.drift.kind)},
                           {"abs_tol", sc.sim.abs_tol},
                           {"rel_tol", sc.sim.rel_tol},
                           {"step", sc.sim.step},
                           {"sample_dt", sc.sim.sample_dt},
                           {"t0", sc.sim.t0},
                           {"t_end", sc.sim.t_end}};
  return summary;
}

// The results of a run, into its summary.
// simulation.error_estimate: shadow (docs/accuracy.md).
nlohmann::json error_estimate_json(const ErrorEstimate& e) {
  nlohmann::json j = {{"method", "shadow"}, {"note", e.note}, {"reliable", e.reliable}};
  if (e.shadow_status.empty()) return j;  // not computed (the note says why)
  j["max_abs_q_difference"] = finite_or_null(e.max_abs_q);
  j["t"] = e.t;
  j["coordinate"] = e.coordinate;
  j["samples_compared"] = e.samples_compared;
  j["sample_stride"] = e.stride;
  j["shadow"] = {{"status", e.shadow_status},       {"t_reached", e.shadow_t_reached},
                 {"abs_tol", e.shadow_abs_tol},     {"rel_tol", e.shadow_rel_tol},
                 {"step", e.shadow_step},           {"regularization", e.shadow_regularization},
                 {"wall_seconds", e.shadow_seconds}};
  return j;
}

void summary_results(nlohmann::json& summary, const System& sys, const RunReport& rep) {
  const Index n = sys.dof();
  const Index m = sys.rows();
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
  if (!rep.stats.jacobian.empty()) {  // bdf, esdirk (docs/derivatives.md)
    summary["jacobian"] = {{"kind", rep.stats.jacobian},
                           {"evaluations", rep.stats.jacobian_evaluations},
                           {"fallbacks", rep.stats.jacobian_fallbacks},
                           {"note", rep.stats.jacobian_note}};
  }
  summary["samples"] = rep.stats.samples;
  summary["wall_seconds"] = rep.wall_seconds;
  summary["trajectory_csv"] =
      rep.csv.empty() ? nlohmann::json(nullptr) : nlohmann::json(rep.csv.filename().string());
  summary["trajectory_rows"] = rep.csv_rows;
  nlohmann::json res = nlohmann::json::object();
  nlohmann::json vres = nlohmann::json::object();
  for (Index i = 0; i < m; ++i) {
    const auto u = static_cast<std::size_t>(i);
    res[sys.constraint_row_names()[u]] = finite_or_null(rep.max_abs_residual[u]);
    vres[sys.constraint_row_names()[u]] = finite_or_null(rep.max_abs_velocity_residual[u]);
  }
  summary["max_abs_position_residual"] = res;
  summary["max_abs_velocity_residual"] = vres;
  summary["max_abs_position_residual_all"] =
      finite_or_null(worst_position_residual(sys, rep).value);
  if (const WorstResidual v = worst_velocity_residual(sys, rep); v.row != "-") {
    // nonholonomic rows (the vres_ columns): no position residual, B q̇ + c is theirs
    nlohmann::json rows = nlohmann::json::array();
    const std::vector<bool> vel = velocity_level_rows(sys);
    for (std::size_t i = 0; i < vel.size(); ++i)
      if (vel[i]) rows.push_back(sys.constraint_row_names()[i]);
    summary["velocity_level_rows"] = rows;
    summary["max_abs_velocity_residual_nonholonomic"] = finite_or_null(v.value);
  }
  summary["max_acceleration_residual"] = finite_or_null(rep.max_acc_residual);
  summary["energy"] = {{"E0", finite_or_null(rep.E0)},
                       {"max_abs_drift", finite_or_null(rep.max_energy_drift)},
                       {"max_T", finite_or_null(rep.max_T)}};
  if (rep.energy_balance) {
    summary["energy_balance_drift"] = finite_or_null(rep.energy_balance_drift);
    summary["energy"]["work_nonconservative_final"] = finite_or_null(rep.work_final);
  }
  summary["rank"] = {{"min", rep.rank_min},
                     {"max", rep.rank_max},
                     {"rows", m},
                     {"free_dof_min", n - rep.rank_max},
                     {"redundant_rows", rep.stats.structural_redundancy},
                     {"smallest_kept_sigma_estimate", finite_or_null(rep.sigma_min)}};
  if (rep.error_estimate.requested)
    summary["error_estimate"] = error_estimate_json(rep.error_estimate);
  nlohmann::json figs = nlohmann::json::array();
  for (const auto& f : rep.figures) figs.push_back(f.lexically_relative(rep.out_dir).string());
  summary["figures"] = figs;
  if (!rep.figure_notes.empty()) summary["figures_left_out"] = rep.figure_notes;
  if (!rep.figure_error.empty()) summary["figure_error"] = rep.figure_error;
}

// What the stages of run_scenario() share, all owned by run_scenario(): the scenario, the system
// integrated and the columns of trajectory.csv.
struct RunSetup {
  const Scenario& sc;
  const RunOptions& options;
  const ControlRun* ctl;  // docs/control.md: the plant and its loop, or null
  const System& sys;      // the plant with `control:`, else the scenario's system
  ConstraintForceColumns& force_columns;
  ControlColumns& control_columns;
  const std::vector<std::string>& header;
};

// A report with nothing seen yet: its extrema start from m rows of zero residual.
RunReport start_report(const System& sys, const ControlRun* ctl,
                       const std::filesystem::path& out_dir) {
  const Index m = sys.rows();
  RunReport rep;
  if (ctl) rep.plant = ctl->plant;
  rep.out_dir = out_dir;
  rep.summary = out_dir / kSummary;
  rep.max_abs_residual.assign(static_cast<std::size_t>(m), 0.0);
  rep.max_abs_velocity_residual.assign(static_cast<std::size_t>(m), 0.0);
  rep.rank_min = static_cast<int>(m);
  rep.sigma_min = std::numeric_limits<double>::infinity();
  return rep;
}

}  // namespace

std::vector<std::string> io_detail::run_csv_header(const System& sys, bool balance,
                                                   const ConstraintForceColumns* forces,
                                                   const ControlColumns& control_columns) {
  auto header = trajectory_header(sys, balance);
  if (forces) header.insert(header.end(), forces->header().begin(), forces->header().end());
  header.insert(header.end(), control_columns.header().begin(), control_columns.header().end());
  return header;
}

namespace {

// Integrates the scenario, every sample a row of `csv`; rep.stats and its warnings are the run's.
// Returns whether the constraint force split was unique at every sample.
bool simulate_to_csv(const RunSetup& s, CsvWriter& csv, Progress& progress, RunReport& rep,
                     const OutputDir& out, nlohmann::json& summary) {
  const Scenario& sc = s.sc;
  const ControlRun* ctl = s.ctl;
  Observer observer{
      {s.sys, rep, sc.sim.energy_balance, s.header.size(), {true, true, sc.sim.sigma_min_svd}},
      rep,
      &csv,
      progress,
      s.options.cancel};
  observer.forces = ctl ? nullptr : &s.force_columns;
  observer.control = &s.control_columns;
  SimulationSettings settings = sc.sim;
  settings.cancel = s.options.cancel;
  const ForceFunction tau = io_detail::run_forces(sc, ctl, settings);
  try {
    // The shadow run first (a closed loop of its own), so that the run's samples are compared as
    // they come (docs/accuracy.md).
    std::optional<io_detail::ShadowEstimate> shadow;
    if (sc.error_estimate) observer.shadow = &shadow.emplace(sc, s.options.cancel);
    rep.stats = simulate(s.sys, ctl ? ctl->q0 : sc.q0, ctl ? ctl->qd0 : sc.qd0, tau, settings,
                         [&observer](double t, CVecRef q, CVecRef qd, const ForwardData& d) {
                           return observer(t, q, qd, d);
                         });
    if (!observer.split_unique) {  // docs/frame-constraints.md
      rep.stats.warnings.push_back(
          {observer.split_t, "constraint_force_split",
           "redundant constraint rows: the force of each constraint block is not unique; the "
           "Fc_ and W_ columns report the least-norm multipliers (docs/frame-constraints.md)"});
    }
    for (auto& w : s.control_columns.warnings()) rep.stats.warnings.push_back(std::move(w));
    rep.motors_line = s.control_columns.motors().console_line();
    if (shadow) rep.error_estimate = shadow->result(s.sys, rep.stats);
  } catch (const std::exception& e) {
    // Invalid settings: the summary must not be left saying "running".
    progress.done();
    csv.abandon();
    summary["status"] = "incomplete";
    summary["stop_reason"] = std::string("error: ") + e.what();
    write_final_summary(out, summary, rep);
    throw;
  }
  return observer.split_unique;
}

// A run stopped by options.cancel: its message says it was interrupted, and when.
void describe_interruption(RunReport& rep, const RunOptions& options) {
  if (rep.stats.status == RunStatus::stopped && options.cancel && options.cancel->load()) {
    // simulate() says "cancelled at t = <time of the step>" when it stopped between samples.
    const std::string tag = "cancelled at t = ";
    const auto at = rep.stats.message.rfind(tag, 0) == 0
                        ? " at t = " + rep.stats.message.substr(tag.size())
                        : std::string();
    rep.stats.message = fmt::format("interrupted (SIGINT/SIGTERM){}; last sample at t = {}", at,
                                    rep.stats.t_reached);
  }
}

// trajectory.csv of a complete run; that of any other (or one whose commit failed) is kept under
// its incomplete name.
void finish_csv(std::optional<CsvWriter>& csv, RunReport& rep,
                const std::filesystem::path& out_dir) {
  bool committed = false;
  if (csv && rep.complete()) {
    try {
      csv->commit();
      committed = true;
      rep.csv = out_dir / kCsv;
    } catch (const Error& e) {
      rep.write_error = e.what();
    }
  }
  if (csv && !committed) {
    const std::string name = csv->abandon();
    if (!name.empty()) rep.csv = out_dir / name;
  }
  if (csv) rep.csv_rows = csv->rows_written();
}

// The figures of a run: the defaults, the frame constraints' forces, the control figures (within
// the caps; what is left out goes to rep.figure_notes).
std::vector<Figure> run_figures(const RunSetup& s, RunReport& rep) {
  std::vector<Figure> figs = default_figures(s.sc);
  const ConstraintForceColumns& force_columns = s.force_columns;
  for (std::size_t f = 0; f < force_columns.figure_names().size(); ++f) {
    const auto& cols = force_columns.figure_columns()[f];
    if (cols.empty()) continue;
    const std::string& nm = force_columns.figure_names()[f];
    const bool wrench = nm.rfind("wrench_", 0) == 0;
    figs.push_back({nm + ".png",
                    wrench ? "Wrench of '" + nm.substr(7) + "' on its frame (world axes)"
                           : "Force A_k^T lambda_k of '" + nm.substr(6) + "'",
                    wrench ? "[N or N·m]" : "[N or N·m]", cols});
  }
  for (const auto& [nm, cols] : s.control_columns.figures())  // docs/control.md
    figs.push_back({nm + ".png", nm, "[N, N·m or m]", cols});
  for (auto& f : s.control_columns.motors().envelope_figures())  // docs/motors.md
    figs.push_back(std::move(f));
  if (s.ctl) {  // the plant has no servo rows: drop the curves of columns it does not write
    const std::vector<std::string>& header = s.header;
    for (auto& f : figs)
      std::erase_if(f.columns, [&header](const std::string& c) {
        return std::find(header.begin(), header.end(), c) == header.end();
      });
    std::erase_if(figs, [](const Figure& f) { return f.columns.empty(); });
  }
  cap_figures(figs, rep.figure_notes);
  return figs;
}

// Draws the run's figures (gnuplot) into OUT/figures; a failure goes to rep.figure_error.
void draw_run_figures(const RunSetup& s, const OutputDir& out, RunReport& rep) {
  const std::vector<Figure> figs = run_figures(s, rep);
  const RunOptions& options = s.options;
  // Said before and after: drawing a long run's figures takes seconds (no silent wait).
  const auto drawing = std::chrono::steady_clock::now();
  if (options.progress) {
    *options.progress << fmt::format("drawing {} figures (gnuplot) ...\n", figs.size())
                      << std::flush;
  }
  try {
    const FigureResult fr = render_figures(out, kCsv, s.header, figs, options.cancel);
    for (const auto& f : fr.written) rep.figures.push_back(rep.out_dir / f);
    rep.figure_error = fr.error;
    if (!fr.note.empty()) rep.figure_notes.push_back(fr.note);
    if (options.progress) {
      *options.progress
          << fmt::format(
                 "drew {} figures in {:.1f} s\n", fr.written.size(),
                 std::chrono::duration<double>(std::chrono::steady_clock::now() - drawing).count())
          << std::flush;
    }
  } catch (const Error& e) {
    rep.figure_error = e.what();
  }
}

// The final summary's status, stop reason, control and constraint force sections, and results.
void summary_final(nlohmann::json& summary, const RunSetup& s, bool split_unique,
                   const RunReport& rep) {
  const bool complete = rep.complete();
  std::string reason;
  if (!rep.write_error.empty()) {
    reason = "write failed: " + rep.write_error;
  } else if (!complete) {
    reason = to_string(rep.stats.status) + ": " + rep.stats.message;
  }
  if (!s.control_columns.empty()) summary["control"] = s.control_columns.summary();
  if (!s.control_columns.motors().empty())  // docs/motors.md
    summary["motors"] = s.control_columns.motors().summary();
  if (!s.force_columns.empty() && !s.ctl) {
    summary["constraint_forces"] = {
        {"split_unique", split_unique},
        {"choice", split_unique ? "unique" : "least-norm multipliers (not unique)"}};
  }
  summary["status"] = complete ? "complete" : "incomplete";
  summary["stop_reason"] = reason;
  summary_results(summary, s.sys, rep);
}

}  // namespace

namespace {

// The largest of `values` over the rows of one level (velocity-level or not).
WorstResidual worst_residual(const System& system, const std::vector<double>& values,
                             bool velocity_level) {
  WorstResidual w;
  const auto& names = system.constraint_row_names();
  const std::vector<bool> vel = velocity_level_rows(system);
  for (std::size_t i = 0; i < values.size() && i < names.size(); ++i) {
    if (vel[i] != velocity_level) continue;
    // NaN counts as the worst (it is the least trustworthy).
    const double v = values[i];
    if (w.row == "-" || v > w.value || (std::isnan(v) && !std::isnan(w.value))) {
      w.value = v;
      w.row = names[i];
    }
  }
  return w;
}

}  // namespace

WorstResidual worst_position_residual(const System& system, const RunReport& rep) {
  return worst_residual(system, rep.max_abs_residual, false);
}

WorstResidual worst_velocity_residual(const System& system, const RunReport& rep) {
  return worst_residual(system, rep.max_abs_velocity_residual, true);
}

RunReport run_scenario(const Scenario& sc, const std::filesystem::path& out_dir,
                       const RunOptions& options) {
  return io_detail::run_scenario_with_write_failures(sc, out_dir, options, {});
}

RunReport io_detail::run_scenario_with_write_failures(const Scenario& sc,
                                                      const std::filesystem::path& out_dir,
                                                      const RunOptions& options,
                                                      WriteFailureHook write_failure) {
  // docs/control.md: with `control:` the plant (physical rows only, τ = B u) is integrated.
  const std::unique_ptr<ControlRun> ctl = make_control_run(sc);
  const System& sys = ctl ? *ctl->plant : *sc.system;
  OutputDir out(out_dir);
  WriteFaults::set_hook(out, std::move(write_failure));
  clear_previous_outputs(out);

  RunReport rep = start_report(sys, ctl.get(), out_dir);

  nlohmann::json summary = summary_start(sc);
  summary["status"] = "running";
  write_json(out, kSummary, summary);  // throws: then there is no summary at all

  const bool balance = sc.sim.energy_balance;
  rep.energy_balance = balance;
  ConstraintForceColumns force_columns(sc);                             // frame constraints only
  ControlColumns control_columns(sc, ctl ? ctl->loop.get() : nullptr);  // docs/control.md
  if (ctl) control_columns.set_plant(*ctl->plant);  // the closure / squeeze force
  const std::vector<std::string> header =
      io_detail::run_csv_header(sys, balance, ctl ? nullptr : &force_columns, control_columns);
  const RunSetup setup{sc, options, ctl.get(), sys, force_columns, control_columns, header};
  bool split_unique = true;
  std::optional<CsvWriter> csv;
  try {
    csv.emplace(out, kCsv, header);
  } catch (const WriteFailed& e) {
    rep.write_error = e.what();
  }
  Progress progress(options.progress, sc.sim.t0, sc.sim.t_end, options.progress_lines,
                    options.progress_every);
  const auto start = std::chrono::steady_clock::now();
  if (csv) split_unique = simulate_to_csv(setup, *csv, progress, rep, out, summary);
  rep.wall_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  progress.done();
  describe_interruption(rep, options);
  finish_csv(csv, rep, out_dir);
  out.sync();

  if (rep.complete() && options.figures) draw_run_figures(setup, out, rep);

  summary_final(summary, setup, split_unique, rep);
  write_final_summary(out, summary, rep);
  out.sync();
  return rep;
}

MemoryRun run_scenario_in_memory(const Scenario& sc, const MemoryRunOptions& options) {
  // docs/control.md: with `control:` the plant (physical rows only, τ = B u) is integrated, as in
  // run_scenario().
  const std::unique_ptr<ControlRun> ctl = make_control_run(sc);
  if (ctl && options.tau)
    throw Error(
        "a scenario with control: takes a control law, not applied generalized forces tau "
        "(the plant's tau is the closed loop's, docs/control.md)");
  if (!ctl && options.law != nullptr)
    throw Error("a control law needs a scenario with a control: section (docs/control.md)");
  if (ctl && options.law != nullptr) {  // the user's law in place of the built-in one
    ctl->loop = std::make_unique<ClosedLoop>(ctl->model, *options.law, ctl->loop->tau_plant,
                                             ctl->loop->disturbance);
  }
  const System& sys = ctl ? *ctl->plant : *sc.system;
  // The loader checked the masses of t over its own t0..t_end; a system built in Python, or a
  // span changed since, is checked here (docs/definitions.md, "Time-varying masses").
  if (const auto problem =
          symbolic::negative_mass_over_run(sys, sc.sim.t0, sc.sim.t_end, sc.sim.sample_dt);
      !problem.message.empty()) {
    throw Error(problem.message + " (a mass of t must stay >= 0 from t0 to t_end)");
  }
  const Index m = sys.rows();
  MemoryRun run;
  RunReport& rep = run.report;
  if (ctl) rep.plant = ctl->plant;
  rep.max_abs_residual.assign(static_cast<std::size_t>(m), 0.0);
  rep.max_abs_velocity_residual.assign(static_cast<std::size_t>(m), 0.0);
  rep.rank_min = static_cast<int>(m);
  rep.sigma_min = std::numeric_limits<double>::infinity();
  const bool balance = sc.sim.energy_balance;
  rep.energy_balance = balance;
  run.header = trajectory_header(sys, balance);
  ConstraintForceColumns force_columns(sc);  // frame constraints only, as run_scenario's
  if (!ctl) {
    run.header.insert(run.header.end(), force_columns.header().begin(),
                      force_columns.header().end());
  }
  ControlColumns control_columns(sc, ctl ? ctl->loop.get() : nullptr);  // as run_scenario's CSV
  if (ctl) control_columns.set_plant(*ctl->plant);  // the closure / squeeze force, as there
  run.header.insert(run.header.end(), control_columns.header().begin(),
                    control_columns.header().end());
  const std::size_t cols = run.header.size();
  // The rows are known in advance (one per sample): reserve them, up to 128 MiB.
  const double samples = std::floor((sc.sim.t_end - sc.sim.t0) / sc.sim.sample_dt) + 2.0;
  if (samples > 0.0 && samples * static_cast<double>(cols) < double(std::size_t{1} << 24)) {
    run.values.reserve(static_cast<std::size_t>(samples) * cols);
  }
  Progress progress(nullptr, sc.sim.t0, sc.sim.t_end);
  Observer observer{{sys, rep, balance, cols, {true, true, sc.sim.sigma_min_svd}},
                    rep,
                    nullptr,
                    progress,
                    options.cancel};
  observer.memory = &run.values;
  observer.forces = ctl ? nullptr : &force_columns;
  observer.control = &control_columns;
  SimulationSettings settings = sc.sim;
  settings.cancel = options.cancel;
  // A Python controller has no ∂τ (difference quotients, said in the stats' jacobian_note).
  const ForceFunction tau =
      !ctl && options.tau ? options.tau : io_detail::run_forces(sc, ctl.get(), settings);
  // The shadow run re-runs the scenario's own forces or law; a Python force function or law is not
  // re-run (it may keep state), so the estimate is missing then, and says why.
  std::optional<io_detail::ShadowEstimate> shadow;
  if (sc.error_estimate && !options.tau && options.law == nullptr) {
    observer.shadow = &shadow.emplace(sc, options.cancel);
  } else if (sc.error_estimate) {
    rep.error_estimate.requested = true;
    rep.error_estimate.note =
        "not computed: the run's forces or control law come from the caller, and a second run "
        "of them could differ (they may keep state)";
  }
  const auto start = std::chrono::steady_clock::now();
  rep.stats = simulate(sys, ctl ? ctl->q0 : sc.q0, ctl ? ctl->qd0 : sc.qd0, tau, settings,
                       [&observer](double t, CVecRef q, CVecRef qd, const ForwardData& d) {
                         return observer(t, q, qd, d);
                       });
  if (shadow) rep.error_estimate = shadow->result(sys, rep.stats);
  rep.wall_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  rep.csv_rows = static_cast<long>(run.values.size() / cols);
  if (!observer.split_unique) {  // docs/frame-constraints.md, as run_scenario()
    rep.stats.warnings.push_back(
        {observer.split_t, "constraint_force_split",
         "redundant constraint rows: the force of each constraint block is not unique; the "
         "Fc_ and W_ columns report the least-norm multipliers (docs/frame-constraints.md)"});
  }
  for (auto& w : control_columns.warnings()) rep.stats.warnings.push_back(std::move(w));
  nlohmann::json summary = summary_start(sc);
  if (!control_columns.empty()) summary["control"] = control_columns.summary();
  if (!control_columns.motors().empty())  // docs/motors.md
    summary["motors"] = control_columns.motors().summary();
  if (!force_columns.empty() && !ctl) {
    summary["constraint_forces"] = {
        {"split_unique", observer.split_unique},
        {"choice", observer.split_unique ? "unique" : "least-norm multipliers (not unique)"}};
  }
  summary["status"] = rep.complete() ? "complete" : "incomplete";
  summary["stop_reason"] =
      rep.complete() ? std::string() : to_string(rep.stats.status) + ": " + rep.stats.message;
  summary_results(summary, sys, rep);
  run.summary_json = json_text(summary);
  return run;
}

bool print_assembly_report(std::ostream& os, std::ostream& err, const Scenario& sc,
                           const AssemblyResult& a) {
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
    os << fmt::format("  {:<14} {:>24.17g} {:>24.17g} {:>11.3e} {:>11.3e}{}\n", printable(names[j]),
                      sc.q0(i), a.q(i), dq, dv, sc.held[j] ? "  (held)" : "");
  }
  if (!a.success) {
    std::string rows;
    for (Index r : a.unmet_rows) {
      rows += (rows.empty() ? "" : ", ") +
              printable(sc.system->constraint_row_names()[static_cast<std::size_t>(r)]);
    }
    err << fmt::format("ukdyn: error: {}: {}; constraints not met: {}\n",
                       printable(sc.path.string()), printable(a.message),
                       rows.empty() ? "-" : rows);
    return false;
  }
  return true;
}

void print_assembled_initial(std::ostream& os, const Scenario& sc, const AssemblyResult& a) {
  // Shortest round-trip decimal of each number ("{}"): the pasted file loads the same doubles.
  const auto list = [](const Vec& v) {
    std::string s = "[";
    for (Index i = 0; i < v.size(); ++i) s += fmt::format("{}{}", i ? ", " : "", v(i));
    return s + "]";
  };
  os << "# assembled initial state, ready to paste over the scenario's initial: section\n";
  os << "initial:\n";
  os << "  q: " << list(a.q) << "\n";
  os << "  qd: " << list(a.qd) << "\n";
  std::string hold;
  const auto& names = sc.system->coordinate_names();
  for (std::size_t j = 0; j < names.size() && j < sc.held.size(); ++j) {
    if (sc.held[j]) hold += (hold.empty() ? "" : ", ") + printable(names[j]);
  }
  if (!hold.empty()) os << "  hold: [" << hold << "]\n";
}

void print_run_report(std::ostream& os, const Scenario& sc, const RunReport& rep) {
  const auto p = [](const std::string& s) { return printable(s); };
  const WorstResidual worst = worst_position_residual(rep.plant ? *rep.plant : *sc.system, rep);
  os << fmt::format("ukdyn {}: scenario '{}' ({}), t = {} .. {} s\n", version(), p(sc.name),
                    p(sc.path.string()), sc.sim.t0, rep.stats.t_reached);
  os << fmt::format("  status              {}{}\n",
                    rep.write_error.empty() ? to_string(rep.stats.status) : "write_failed",
                    !rep.write_error.empty()    ? " (" + p(rep.write_error) + ")"
                    : rep.stats.message.empty() ? ""
                                                : " (" + p(rep.stats.message) + ")");
  os << fmt::format(
      "  steps               {} accepted, {} rejected, {} force evaluations, {} samples\n",
      rep.stats.steps, rep.stats.rejected_steps, rep.stats.rhs_evaluations, rep.stats.samples);
  os << fmt::format(
      "  integrator          {} ({}), drift control {}\n", to_string(sc.sim.integrator),
      adaptive_steps(sc.sim) ? fmt::format("abs/rel tol {:g}/{:g}", sc.sim.abs_tol, sc.sim.rel_tol)
                             : fmt::format("fixed step {:g} s", sc.sim.step),
      to_string(sc.sim.drift.kind));
  if (!rep.stats.jacobian.empty()) {  // bdf, esdirk
    os << fmt::format(
        "  jacobian            {} ({} evaluations{}){}\n", rep.stats.jacobian,
        rep.stats.jacobian_evaluations,
        rep.stats.jacobian_fallbacks > 0
            ? fmt::format(", {} by differences at untrusted states or kinks of the law",
                          rep.stats.jacobian_fallbacks)
            : "",
        rep.stats.jacobian_note.empty() ? "" : ": " + p(rep.stats.jacobian_note));
  }
  os << fmt::format("  wall time           {:.3f} s\n", rep.wall_seconds);
  os << fmt::format(
      "  rank of A           {}..{} of {} rows ({} free DOF{})\n", rep.rank_min, rep.rank_max,
      sc.system->rows(), sc.system->dof() - rep.rank_max,
      rep.stats.structural_redundancy > 0
          ? fmt::format(", {} redundant around the motion", rep.stats.structural_redundancy)
          : "");
  const System& sys = rep.plant ? *rep.plant : *sc.system;
  const WorstResidual vworst = worst_velocity_residual(sys, rep);
  if (worst.row != "-" || vworst.row == "-")
    os << fmt::format("  max |residual|      {:.3e} ({})\n", worst.value, p(worst.row));
  if (vworst.row != "-")  // nonholonomic rows: no position residual, B qdot + c instead
    os << fmt::format("  max |vel. residual| {:.3e} ({}, velocity level: B qdot + c)\n",
                      vworst.value, p(vworst.row));
  os << fmt::format("  max |A qdd - b|     {:.3e}\n", rep.max_acc_residual);
  if (const ErrorEstimate& e = rep.error_estimate; e.requested) {  // docs/accuracy.md
    os << (e.shadow_status.empty()
               ? fmt::format("  error estimate      {}\n", e.note)
               : fmt::format(
                     "  error estimate      max |q - q_shadow| = {:.3e} ({} at t = {:.6g} s; "
                     "shadow run at {}){}\n",
                     e.max_abs_q, p(e.coordinate), e.t,
                     e.shadow_step > 0.0 ? fmt::format("step {:.3g}", e.shadow_step)
                                         : fmt::format("tolerances {:.3g} / {:.3g}",
                                                       e.shadow_abs_tol, e.shadow_rel_tol),
                     e.note.empty() ? "" : "; " + e.note));
  }
  os << fmt::format(
      "  energy              E0 = {:.9g} J, max |E - E0| = {:.3e} J, max T = {:.6g} J\n", rep.E0,
      rep.max_energy_drift, rep.max_T);
  if (!rep.motors_line.empty())  // docs/motors.md
    os << fmt::format("  motors              {}\n", p(rep.motors_line));
  os << fmt::format("  outputs             {}\n",
                    rep.csv.empty() ? std::string("(no trajectory written)") : p(rep.csv.string()));
  if (!rep.summary.empty())
    os << fmt::format("                      {}\n", p(rep.summary.string()));
  if (!rep.figures.empty()) {
    os << fmt::format("                      {} figures in {}\n", rep.figures.size(),
                      p((rep.out_dir / "figures").string()));
  }
}

void print_run_warnings(std::ostream& os, const Scenario& sc, const RunReport& rep) {
  for (const auto& w : rep.stats.warnings) {
    os << fmt::format("ukdyn: warning at t = {:.6g} s: {}\n", w.t, printable(w.message));
  }
  for (const auto& note : rep.figure_notes) {
    os << "ukdyn: note: figures: " << printable(note) << "\n";
  }
  if (!rep.figure_error.empty()) os << "ukdyn: warning: " << printable(rep.figure_error) << "\n";
  if (!rep.complete()) {
    const std::string why =
        rep.write_error.empty() ? rep.stats.message : "write failed: " + rep.write_error;
    os << "ukdyn: run incomplete: " << printable(sc.path.string()) << ": " << printable(why)
       << "; partial results in "
       << (rep.csv.empty() ? std::string("(none)") : printable(rep.csv.string())) << "\n";
  }
}

}  // namespace ukdyn
