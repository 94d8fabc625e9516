// One sample in memory (docs/sweeps.md): its scenario (shared between samples that differ only in
// the initial state), its run, and its row of results.csv (sweep_header() names the columns).
#include "sweep/sample.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "run/run_observer.hpp"
#include "scenario/yaml_loader.hpp"
#include "sweep/scenario_tree.hpp"
#include "ukdyn/run/run.hpp"
#include "ukdyn/scenario/scenario_file.hpp"
#include "ukdyn/text/safe_text.hpp"

namespace ukdyn {

std::vector<std::string> sweep_header(const Sweep& sw, const Scenario& base) {
  std::vector<std::string> h{"sample"};
  for (const auto& p : sw.parameters) h.push_back(p.name);
  h.insert(h.end(), {"status", "reason", "t_reached", "steps"});
  const auto& names = base.system->coordinate_names();
  const auto& m = sw.metrics;
  if (m.max_residual) h.push_back("max_residual");
  if (m.energy_drift) h.push_back("energy_drift");
  if (m.energy_balance_drift) h.push_back("energy_balance_drift");
  if (m.control)
    h.insert(h.end(), {"max_abs_e", "max_abs_e_second_half", "max_abs_u", "max_abs_udot",
                       "saturation_time", "saturation_max_over_limit"});
  if (m.squeeze) h.insert(h.end(), {"max_closure_force", "max_squeeze_force"});
  if (m.max_abs_qc)
    for (const auto& n : names) h.push_back("max_abs_Qc_" + n);
  if (m.final_state) {
    for (const auto& n : names) h.push_back("final_" + n);
    for (const auto& n : names) h.push_back("final_" + n + "_dot");
  }
  for (const auto& c : m.columns)
    for (const auto& s : c.stats) h.push_back(s + "_" + c.column);
  return h;
}

namespace sweep_detail {

using io_detail::nanmax;

// Metrics over the samples of one run: the trajectory.csv quantities and the report's extrema come
// from the SampleRecorder that run_scenario() uses (run/run_observer.hpp); kept here: max |Qc|, the
// final state and the statistics of chosen columns.
struct SampleObserver {
  SampleObserver(const System& s, bool balance, std::size_t row_size,
                 std::vector<std::vector<std::size_t>> cols, bool need_sigma)
      : recorder(s, rep, balance, row_size, {!cols.empty(), false, need_sigma}),
        col_index(std::move(cols)),
        max_qc(Vec::Zero(s.dof())),
        cmin(col_index.size(), NAN),
        cmax(col_index.size(), NAN),
        csq(col_index.size(), 0.0),
        clast(col_index.size(), NAN),
        cabs(col_index.size(), 0.0) {}
  RunReport rep;  // (before the recorder, which writes into it)
  io_detail::SampleRecorder recorder;
  // into the trajectory row, per ColumnMetric: its column, or the columns of its norm
  std::vector<std::vector<std::size_t>> col_index;
  Vec max_qc, q_last, qd_last;
  std::vector<double> cmin, cmax, csq, clast, cabs;
  long count = 0;
  // A control run: its columns after the trajectory's (as run_scenario's Observer fills them),
  // and their extrema once the run is over.
  ControlColumns* control = nullptr;
  std::size_t control_at = 0;
  // The frame constraints' columns (only when a metric names one), before the control columns.
  ConstraintForceColumns* forces = nullptr;
  std::size_t forces_at = 0;
  ControlColumns::Peaks peaks;

  [[nodiscard]] double max_residual() const {
    double r = 0.0;
    for (double v : rep.max_abs_residual) r = nanmax(r, v);
    return r;
  }

  bool operator()(double t, CVecRef q, CVecRef qd, const ForwardData& d) {
    recorder.record(t, q, qd, d);
    if (forces != nullptr) forces->fill(q, d, recorder.row().data() + forces_at);
    if (control != nullptr) control->fill(t, q, qd, d, recorder.row().data() + control_at);
    for (Index i = 0; i < max_qc.size(); ++i) max_qc(i) = nanmax(max_qc(i), std::abs(d.Qc(i)));
    q_last = q;
    qd_last = qd;
    const std::vector<double>& row = recorder.row();
    for (std::size_t c = 0; c < col_index.size(); ++c) {
      const std::vector<std::size_t>& ix = col_index[c];
      double v = row[ix.front()];
      if (ix.size() > 1) {  // a norm (docs/sweeps.md)
        double sq = 0.0;
        for (std::size_t i : ix) sq += row[i] * row[i];
        v = std::sqrt(sq);
      }
      if (count == 0) {
        cmin[c] = cmax[c] = v;
      } else {
        cmin[c] = std::isnan(v) || std::isnan(cmin[c]) ? NAN : std::min(cmin[c], v);
        cmax[c] = nanmax(cmax[c], v);
      }
      cabs[c] = nanmax(cabs[c], std::abs(v));
      csq[c] += v * v;
      clast[c] = v;
    }
    ++count;
    return true;
  }
};

namespace {

std::string clean_reason(std::string s) {
  for (char& c : s)
    if (c == '\n' || c == '\r') c = ' ';
  if (s.size() > 400) s = s.substr(0, 400) + "...";
  return csv_field(printable(s));
}

}  // namespace

// What the run of one sample leaves for its row.
struct SampleRunner::SampleOutcome {
  std::string status = "completed", reason;
  SimulationStats stats;
  std::optional<SampleObserver> obs;  // empty if the sample did not run (or failed)
};

SampleRunner::SampleRunner(const Sweep& sw, const Scenario& base) : sw_(sw), base_(base) {
  // A control scenario loads each sample whole (its plant and offset start follow q0).
  share_state_ = !base.control && system_independent_of_state(base_yaml(sw));
  for (const auto& p : sw.parameters) {
    for (const auto& t : p.targets) {
      bool vel = false;
      const long i = state_index(t.path, vel);
      // A state path beyond the coordinates cannot be shared (the loader will refuse it).
      if (i >= base.system->dof()) share_state_ = false;
    }
  }
  header_ = sweep_header(sw, base);
}

std::string SampleRunner::row(long k, const std::atomic<bool>* cancel) {
  const auto vals = sample_values(sw_, k);
  std::string r = fmt::format("{}", k);
  for (double v : vals) r += "," + num(v);
  SampleOutcome out;
  // Building (and dropping) a model from definitions runs GiNaC, which is not thread-safe
  // (docs/architecture.md, "Thread safety"): the sample's scenario and control run are built and
  // released under build_mu_; only the integration runs in parallel.
  std::optional<Scenario> held;
  std::unique_ptr<ControlRun> ctl;
  try {
    {
      std::lock_guard<std::mutex> lock(build_mu_);
      held.emplace(scenario_for(k, vals, out.status, out.reason));
    }
    Scenario& sc = *held;
    if (out.status == "completed" && prepare_initial_state(sc, out)) {
      simulate_sample(sc, ctl, cancel, out);
    }
  } catch (const std::exception& e) {
    out.status = "error";
    out.reason = e.what();
    out.obs.reset();
  }
  {
    std::lock_guard<std::mutex> lock(build_mu_);
    ctl.reset();
    held.reset();
  }
  if (cancel && cancel->load()) return {};  // not recorded: recomputed on resume
  r += "," + out.status + "," + clean_reason(out.reason);
  r += "," + num(out.stats.t_reached) + "," + std::to_string(out.stats.steps);
  const std::size_t fixed = 1 + vals.size() + 4;
  std::vector<std::string> cells;
  if (out.obs) cells = metric_cells(*out.obs);
  // A failed load leaves the metric cells empty (same count as the header).
  cells.resize(header_.size() - fixed);
  for (const auto& c : cells) r += "," + c;
  return r;
}

// Moves (q0, q̇0) onto the constraints (`assemble: true`), or checks that they meet them.
// Returns false (with out.status and out.reason saying why) if the sample cannot run.
bool SampleRunner::prepare_initial_state(Scenario& sc, SampleOutcome& out) const {
  const System& sys = *sc.system;
  const Index m = sys.rows();
  if (sw_.assemble) {
    const auto a = assemble(sys, sc.sim.t0, sc.q0, sc.qd0, sc.held);
    if (!a.success) {
      out.status = "assembly_failed";
      out.reason = a.message;
      return false;
    }
    sc.q0 = a.q;
    sc.qd0 = a.qd;
  } else if (m > 0) {
    Vec phi(m), phid(m);
    position_residuals(sys, sc.sim.t0, sc.q0, phi);
    velocity_residuals(sys, sc.sim.t0, sc.q0, sc.qd0, phid);
    const double p = phi.cwiseAbs().maxCoeff(), v = phid.cwiseAbs().maxCoeff();
    if (!(p <= sc.initial_tolerance) || !(v <= sc.initial_tolerance)) {
      out.status = "inconsistent_initial";
      out.reason = fmt::format(
          "initial state violates the constraints: max |Phi| = {:.3e}, "
          "max |Phi_dot| = {:.3e} > initial_tolerance {:g}",
          p, v, sc.initial_tolerance);
      return false;
    }
  }
  return true;
}

// The trajectory row's index of each column metric; need_sigma: one of them is sigma_min (an SVD
// per sample only with simulation.sigma_min: svd).
std::vector<std::vector<std::size_t>> SampleRunner::metric_column_indices(
    const std::vector<std::string>& th, bool& need_sigma) const {
  std::vector<std::vector<std::size_t>> cols;
  need_sigma = false;
  for (const auto& c : sw_.metrics.columns) {
    std::vector<std::size_t> ix;
    for (const auto& name : c.norm.empty() ? std::vector<std::string>{c.column} : c.norm) {
      const auto it = std::find(th.begin(), th.end(), name);
      if (it == th.end()) throw Error("no trajectory column named '" + name + "'");
      ix.push_back(static_cast<std::size_t>(it - th.begin()));
      need_sigma = need_sigma || name == "sigma_min";
    }
    cols.push_back(std::move(ix));
  }
  return cols;
}

// Whether a column metric names a column that only the frame constraints' columns have.
bool SampleRunner::needs_force_columns(const std::vector<std::string>& th) const {
  const auto missing = [&th](const std::string& n) {
    return std::find(th.begin(), th.end(), n) == th.end();
  };
  for (const auto& c : sw_.metrics.columns) {
    if (c.norm.empty() ? missing(c.column) : std::any_of(c.norm.begin(), c.norm.end(), missing))
      return true;
  }
  return false;
}

// Integrates the sample, its metrics into out.obs. ctl: its control run, built here and released
// by row() (both under build_mu_).
void SampleRunner::simulate_sample(const Scenario& sc, std::unique_ptr<ControlRun>& ctl,
                                   const std::atomic<bool>* cancel, SampleOutcome& out) {
  const System& sys = *sc.system;
  const bool balance = sc.sim.energy_balance;
  // docs/control.md: with `control:` the plant (physical rows only, τ = B u from the
  // law) is integrated, exactly as run_scenario() does it (io/run.cpp).
  {
    std::lock_guard<std::mutex> lock(build_mu_);
    ctl = make_control_run(sc);
  }
  const System& psys = ctl ? *ctl->plant : sys;
  // The columns of the run's trajectory.csv (io_detail::run_csv_header, as `ukdyn simulate`); the
  // frame constraints' columns are computed only when a metric names one of them.
  std::optional<ControlColumns> cc;
  cc.emplace(sc, ctl ? ctl->loop.get() : nullptr);
  if (ctl) cc->set_plant(*ctl->plant);
  std::optional<ConstraintForceColumns> fc;
  if (!ctl && needs_force_columns(io_detail::run_csv_header(psys, balance, nullptr, *cc)))
    fc.emplace(sc);
  const auto th = io_detail::run_csv_header(psys, balance, fc ? &*fc : nullptr, *cc);
  const std::size_t forces_at = trajectory_header(psys, balance).size();
  const std::size_t control_at = forces_at + (fc ? fc->header().size() : 0);
  bool need_sigma = false;
  std::vector<std::vector<std::size_t>> cols = metric_column_indices(th, need_sigma);
  const Vec& q0 = ctl ? ctl->q0 : sc.q0;
  const Vec& qd0 = ctl ? ctl->qd0 : sc.qd0;
  out.obs.emplace(psys, balance, th.size(), std::move(cols), need_sigma && sc.sim.sigma_min_svd);
  out.obs->q_last = q0;
  out.obs->qd_last = qd0;
  const bool row = !out.obs->col_index.empty();
  out.obs->control = ctl || (row && !cc->empty()) ? &*cc : nullptr;
  out.obs->control_at = control_at;
  out.obs->forces = row && fc && !fc->empty() ? &*fc : nullptr;
  out.obs->forces_at = forces_at;
  if (sc.error_estimate)  // set: by the sweep (the base is refused at load): not run per sample
    throw Error(
        "simulation.error_estimate: shadow is not run per sample by a sweep (docs/accuracy.md)");
  SimulationSettings settings = sc.sim;
  settings.cancel = cancel;
  const ForceFunction f = io_detail::run_forces(sc, ctl.get(), settings);
  SampleObserver& o = *out.obs;
  out.stats = simulate(
      psys, q0, qd0, f, settings,
      [&o](double t, CVecRef q, CVecRef qd, const ForwardData& d) { return o(t, q, qd, d); });
  if (ctl) out.obs->peaks = cc->peaks();
  out.obs->control = nullptr;
  out.obs->forces = nullptr;
  cc.reset();
  out.status = to_string(out.stats.status);
  out.reason = out.stats.message;
  if (out.stats.status == RunStatus::completed) out.reason.clear();
}

// The metric cells of a sample that ran, in the order of sweep_header().
std::vector<std::string> SampleRunner::metric_cells(const SampleObserver& o) const {
  std::vector<std::string> cells;
  const auto& mx = sw_.metrics;
  if (mx.max_residual) cells.push_back(num(o.max_residual()));
  if (mx.energy_drift) cells.push_back(num(o.rep.max_energy_drift));
  if (mx.energy_balance_drift)
    cells.push_back(o.rep.energy_balance ? num(o.rep.energy_balance_drift) : "nan");
  const auto& pk = o.peaks;
  if (mx.control) {
    for (double v : {pk.max_abs_e, pk.max_abs_e_second_half, pk.max_abs_u, pk.max_abs_udot,
                     pk.saturation_time, pk.saturation_max_over_limit})
      cells.push_back(num(v));
  }
  if (mx.squeeze) {
    cells.push_back(o.count > 0 ? num(pk.max_closure_force) : "nan");
    cells.push_back(o.count > 0 ? num(pk.max_squeeze_force) : "nan");
  }
  if (mx.max_abs_qc)
    for (Index i = 0; i < o.max_qc.size(); ++i) cells.push_back(num(o.max_qc(i)));
  if (mx.final_state) {
    for (Index i = 0; i < o.q_last.size(); ++i) cells.push_back(num(o.q_last(i)));
    for (Index i = 0; i < o.qd_last.size(); ++i) cells.push_back(num(o.qd_last(i)));
  }
  std::size_t ci = 0;
  for (const auto& c : mx.columns) {
    for (const auto& s : c.stats) {
      const double cnt = static_cast<double>(std::max(o.count, 1L));
      const double v = s == "min"       ? o.cmin[ci]
                       : s == "max"     ? o.cmax[ci]
                       : s == "rms"     ? std::sqrt(o.csq[ci] / cnt)
                       : s == "max_abs" ? o.cabs[ci]
                                        : o.clast[ci];
      cells.push_back(num(v));
    }
    ++ci;
  }
  return cells;
}

Scenario SampleRunner::scenario_for(long k, const std::vector<double>& vals, std::string& status,
                                    std::string& reason) {
  // The values that shape the model: every target but the state ones when they can be shared.
  std::string key;
  for (std::size_t j = 0; j < vals.size(); ++j) {
    for (const auto& t : sw_.parameters[j].targets) {
      bool vel = false;
      if (share_state_ && state_index(t.path, vel) >= 0) continue;
      key += num(target_value(t, vals[j])) + ";";
    }
  }
  ModelCache::Entry e;
  {
    std::lock_guard<std::mutex> lock(cache_.mu);
    if (auto it = cache_.entries.find(key); it != cache_.entries.end()) e = it->second;
  }
  if (!e.sc && e.error.empty()) {
    // The values are written into a copy of the base scenario's tree, parsed once (load_sweep):
    // no text is emitted and parsed again per sample.
    try {
      e.sc = std::make_shared<const Scenario>(io_detail::load_scenario_yaml(
          sample_doc(sw_, vals, !share_state_), base_hash_, sw_.base_path, LoadOptions{false}));
    } catch (const ScenarioError& err) {
      e.error = err.what();
    }
    std::lock_guard<std::mutex> lock(cache_.mu);
    if (cache_.entries.size() >= 256) cache_.entries.clear();  // bounded; never changes results
    cache_.entries.emplace(key, e);
  }
  if (!e.sc) {
    status = "invalid_scenario";
    reason = fmt::format("sample {}: {}", k, e.error);
    return base_;
  }
  Scenario sc = *e.sc;
  if (share_state_) {
    for (std::size_t j = 0; j < vals.size(); ++j) {
      for (const auto& t : sw_.parameters[j].targets) {
        bool vel = false;
        const long i = state_index(t.path, vel);
        if (i < 0) continue;
        (vel ? sc.qd0 : sc.q0)(static_cast<Index>(i)) = target_value(t, vals[j]);
      }
    }
  }
  return sc;
}

}  // namespace sweep_detail

std::string run_sample(const Sweep& sw, const Scenario& base, long k,
                       const std::atomic<bool>* cancel) {
  sweep_detail::SampleRunner r(sw, base);
  return r.row(k, cancel);
}

}  // namespace ukdyn
