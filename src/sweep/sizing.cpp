// `ukdyn size` (ukdyn/sweep/sizing.hpp, docs/sizing.md): candidates evaluated exactly, by running
// every sample with the candidate's motor written into the scenario (its reflected rotor inertia
// and friction in the model), and the fixed-point iteration over several actuators.
//
// A sample is the sweep's (sample_values, sample_doc: the same tree as `ukdyn sweep`'s row k), run
// by run_scenario_in_memory (the run of `ukdyn simulate`, its motor columns from MotorColumns,
// ukdyn/output/motor_output.hpp); nothing here recomputes the motor model.
#include "ukdyn/sweep/sizing.hpp"

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <ostream>
#include <thread>

#include "scenario/yaml_loader.hpp"
#include "sweep/scenario_tree.hpp"
#include "ukdyn/output/motor_output.hpp"
#include "ukdyn/run/run.hpp"

namespace ukdyn {

bool SizingResult::all_found() const {
  return std::all_of(choices.begin(), choices.end(), [](const SizingChoice& c) { return c.found; });
}

namespace {

using sweep_detail::num;

// The actuator's `motor:` block for spec (the keys of docs/motors.md; an infinite limit left out).
YAML::Node motor_node(const MotorSpec& s) {
  YAML::Node m(YAML::NodeType::Map);
  const auto put = [&m](const char* key, double v) {
    if (std::isfinite(v)) m[key] = num(v);
  };
  put("ratio", s.ratio);
  put("efficiency", s.efficiency);
  put("rotor_inertia", s.rotor_inertia);
  put("viscous", s.viscous);
  put("coulomb", s.coulomb);
  put("coulomb_speed", s.coulomb_speed);
  put("torque_constant", s.torque_constant);
  put("resistance", s.resistance);
  put("stall_torque", s.stall_torque);
  put("no_load_speed", s.no_load_speed);
  put("continuous_torque", s.continuous_torque);
  put("peak_torque", s.peak_torque);
  return m;
}

// a is worse than b: a smaller margin; a NaN margin (a point that cannot be vouched for) is worse
// than any number.
bool worse(const SizingPoint& a, const SizingPoint& b) {
  if (std::isnan(a.margin)) return !std::isnan(b.margin);
  if (std::isnan(b.margin)) return false;
  return a.margin < b.margin;
}

bool holds(const SizingPoint& p, double margin) { return p.failure.empty() && p.margin >= margin; }

// Every sized actuator's point for a sample that did not run (or ran short): not vouched for.
std::vector<SizingPoint> failed_sample(std::size_t count, long k, const std::vector<double>& vals,
                                       const std::string& why) {
  SizingPoint p;
  p.sample = k;
  p.values = vals;
  p.margin = -std::numeric_limits<double>::infinity();
  p.limit = "sample failed";
  p.failure = fmt::format("sample {}: {}", k, why);
  return std::vector<SizingPoint>(count, p);
}

// A run without the columns to size by: bad input for the whole sizing, not a failed sample.
class MissingColumns : public ScenarioError {
 public:
  using ScenarioError::ScenarioError;
};

struct Columns {
  std::size_t u = 0, speed = 0, torque = 0, margin = 0;
};

Columns find_columns(const SizingFile& f, const std::vector<std::string>& header,
                     const std::string& a) {
  const auto at = [&](const std::string& c) {
    const auto it = std::find(header.begin(), header.end(), c);
    if (it == header.end())
      throw MissingColumns(fmt::format(
          "{}: the run has no column '{}': the inputs u of actuator '{}' are computed only with "
          "servo constraint rows (inverse dynamics) or a control: section (docs/motors.md, "
          "\"Outputs\"), so there is nothing to size it by",
          f.sweep.base_path.string(), c, a));
    return static_cast<std::size_t>(it - header.begin());
  };
  return {at("u_" + a), at("motor_speed_" + a), at("motor_torque_" + a), at("motor_margin_" + a)};
}

// The worst point of one actuator over one run: the motor's envelope (the motor_margin_ column),
// the gearbox's peak output torque and input speed at every output sample; with `continuous`, the
// RMS limits of the motor (summary.json → motors → rms_margin) and of the gearbox (RMS |u|, by the
// same quadrature as the summary's, SampleIntegral).
SizingPoint worst_point(const SizingFile& f, const MotorSpec& m, const CatalogueGearbox& g,
                        const MemoryRun& run, const nlohmann::json& motor_summary,
                        const Columns& c) {
  SizingPoint w;
  w.margin = std::numeric_limits<double>::infinity();
  const std::size_t width = run.header.size();
  SampleIntegral u2;
  double t_first = 0.0, t_last = 0.0;
  for (long r = 0; r < run.report.csv_rows; ++r) {
    const double* row = run.values.data() + static_cast<std::size_t>(r) * width;
    const double t = row[0], u = row[c.u], wm = row[c.speed], tm = row[c.torque];
    if (r == 0) t_first = t;
    t_last = t;
    u2.add(t, u * u);
    const bool on_line = m.stall_torque * (1.0 - std::abs(wm) / m.no_load_speed) < m.peak_torque;
    const std::pair<double, const char*> limits[] = {
        {row[c.margin], on_line ? "torque-speed line" : "peak torque"},
        {1.0 - std::abs(u) / g.peak_torque, "gearbox peak torque"},
        {1.0 - std::abs(wm) / g.max_input_speed, "gearbox input speed"}};
    for (const auto& [margin, label] : limits) {
      SizingPoint p{-1, {}, t, margin, label, u, wm / m.ratio, tm, wm, {}};
      if (worse(p, w)) w = p;
    }
  }
  if (!f.continuous) return w;
  const double T = t_last - t_first;
  if (std::isfinite(m.continuous_torque) && motor_summary.contains("rms_margin")) {
    const double rms = motor_summary.value("rms_torque", 0.0);
    SizingPoint p{-1,
                  {},
                  NAN,
                  motor_summary["rms_margin"].get<double>(),
                  "motor continuous torque",
                  0.0,
                  0.0,
                  rms,
                  0.0,
                  {}};
    if (worse(p, w)) w = p;
  }
  if (std::isfinite(g.continuous_torque) && T > 0.0) {
    const double rms = std::sqrt(u2.value() / T);
    SizingPoint p{
        -1,  {},  NAN, 1.0 - rms / g.continuous_torque, "gearbox continuous torque", rms, 0.0,
        0.0, 0.0, {}};
    if (worse(p, w)) w = p;
  }
  return w;
}

class Sizer {
 public:
  Sizer(const SizingFile& f, const SizingOptions& o) : f_(f), opt_(o) {
    hash_ = io_detail::scenario_text_hash(f.sweep.base_text);
    res_.choices.resize(f.actuators.size());
  }
  SizingResult run();

 private:
  const std::vector<SizingPoint>& evaluate(const std::vector<std::size_t>& cfg);
  std::vector<SizingPoint> run_sample(const std::vector<std::size_t>& cfg, long k);
  std::vector<SizingPoint> run_loaded(const std::vector<std::size_t>& cfg, Scenario& sc, long k,
                                      const std::vector<double>& vals);
  bool verify(std::vector<std::size_t>& cur, const std::vector<SizingPoint>& r);
  void finish(const std::vector<std::size_t>& cur);
  [[nodiscard]] bool ok(const SizingPoint& p) const { return holds(p, f_.margin); }

  const SizingFile& f_;
  const SizingOptions& opt_;
  std::string hash_;
  std::mutex build_mu_;  // model building and release (GiNaC is not thread-safe; sample.cpp)
  std::map<std::vector<std::size_t>, std::vector<SizingPoint>> cache_;
  SizingResult res_;
};

// Sample k under configuration cfg: per sized actuator, its worst point over the run.
std::vector<SizingPoint> Sizer::run_sample(const std::vector<std::size_t>& cfg, long k) {
  const Sweep& sw = f_.sweep;
  const std::vector<double> vals = sample_values(sw, k);
  std::optional<Scenario> sc;
  std::vector<SizingPoint> out;
  try {
    {
      // The sample's tree (copied from the base tree, as the sweep does under its lock) and its
      // model are built under build_mu_: yaml-cpp and GiNaC are not thread-safe.
      std::lock_guard<std::mutex> lock(build_mu_);
      YAML::Node doc = sweep_detail::sample_doc(sw, vals, true);
      for (std::size_t a = 0; a < cfg.size(); ++a) {
        const SizingActuator& act = f_.actuators[a];
        const MotorSpec spec = candidate_spec(f_.catalogue, act.candidates[cfg[a]]);
        for (YAML::Node e : doc["actuators"])
          if (e.IsMap() && e["name"].IsScalar() && e["name"].Scalar() == act.name)
            e["motor"] = motor_node(spec);
      }
      sc.emplace(
          io_detail::load_scenario_yaml(doc, hash_, sw.base_path, LoadOptions{!sw.assemble}));
    }
    out = run_loaded(cfg, *sc, k, vals);
  } catch (const MissingColumns&) {
    std::lock_guard<std::mutex> lock(build_mu_);
    sc.reset();
    throw;
  } catch (const ScenarioError& e) {
    out = failed_sample(cfg.size(), k, vals, std::string("invalid scenario: ") + e.what());
  } catch (const std::exception& e) {
    out = failed_sample(cfg.size(), k, vals, e.what());
  }
  std::lock_guard<std::mutex> lock(build_mu_);
  sc.reset();
  return out;
}

std::vector<SizingPoint> Sizer::run_loaded(const std::vector<std::size_t>& cfg, Scenario& sc,
                                           long k, const std::vector<double>& vals) {
  if (f_.sweep.assemble) {
    const auto a = assemble(*sc.system, sc.sim.t0, sc.q0, sc.qd0, sc.held);
    if (!a.success) return failed_sample(cfg.size(), k, vals, "assembly failed: " + a.message);
    sc.q0 = a.q;
    sc.qd0 = a.qd;
  }
  MemoryRunOptions mo;
  mo.cancel = opt_.cancel;
  std::optional<MemoryRun> run;
  if (sc.control) {  // the control run is built from the scenario (GiNaC for definitions)
    std::lock_guard<std::mutex> lock(build_mu_);
    run.emplace(run_scenario_in_memory(sc, mo));
  } else {
    run.emplace(run_scenario_in_memory(sc, mo));
  }
  const SimulationStats& st = run->report.stats;
  if (st.status != RunStatus::completed)
    return failed_sample(
        cfg.size(), k, vals,
        fmt::format("{} at t = {:.6g} s: {}", to_string(st.status), st.t_reached, st.message));
  if (run->report.csv_rows == 0)  // no operating point: nothing to vouch for
    return failed_sample(cfg.size(), k, vals, "the run has no output samples");
  const auto summary = nlohmann::json::parse(run->summary_json, nullptr, false);
  std::vector<SizingPoint> out;
  for (std::size_t a = 0; a < cfg.size(); ++a) {
    const SizingActuator& act = f_.actuators[a];
    const SizingCandidate& cand = act.candidates[cfg[a]];
    const Columns c = find_columns(f_, run->header, act.name);
    nlohmann::json ms = nlohmann::json::object();
    if (summary.is_object() && summary.contains("motors") && summary["motors"].contains(act.name))
      ms = summary["motors"][act.name];
    SizingPoint p = worst_point(f_, candidate_spec(f_.catalogue, cand),
                                f_.catalogue.gearboxes[cand.gearbox], *run, ms, c);
    p.sample = k;
    p.values = vals;
    out.push_back(std::move(p));
  }
  return out;
}

// Every sample under cfg (a pool of threads over the samples), reduced to each actuator's worst
// point (the first sample in sample order on a tie); cached by configuration.
const std::vector<SizingPoint>& Sizer::evaluate(const std::vector<std::size_t>& cfg) {
  if (auto it = cache_.find(cfg); it != cache_.end()) return it->second;
  const long n = f_.sweep.samples;
  std::vector<std::vector<SizingPoint>> per(static_cast<std::size_t>(n));
  int threads = opt_.threads > 0
                    ? opt_.threads
                    : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  threads = static_cast<int>(std::min<long>(threads, n));
  std::atomic<long> next{0};
  std::exception_ptr error;
  std::mutex error_mu;
  {
    std::vector<std::jthread> pool;
    for (int i = 0; i < threads; ++i) {
      pool.emplace_back([&] {
        for (long k = next.fetch_add(1); k < n; k = next.fetch_add(1)) {
          try {
            per[static_cast<std::size_t>(k)] = run_sample(cfg, k);
          } catch (...) {
            std::lock_guard<std::mutex> lock(error_mu);
            if (!error) error = std::current_exception();
          }
        }
      });
    }
  }
  if (error) std::rethrow_exception(error);
  res_.runs += n;
  std::vector<SizingPoint> worst(cfg.size());
  for (std::size_t a = 0; a < cfg.size(); ++a) {
    worst[a].margin = std::numeric_limits<double>::infinity();
    for (const auto& s : per)
      if (worse(s[a], worst[a])) worst[a] = s[a];
  }
  const int index = res_.configurations++;
  for (std::size_t a = 0; a < cfg.size(); ++a)
    res_.evaluations.push_back({a, cfg[a], ok(worst[a]), worst[a], index, cfg});
  if (opt_.progress) {
    int held = 0;
    for (const auto& w : worst) held += ok(w) ? 1 : 0;
    *opt_.progress << fmt::format(
        "ukdyn size: configuration {}: {} runs, {} of {} actuators hold\n", index, n, held,
        cfg.size());
  }
  return cache_.emplace(cfg, std::move(worst)).first->second;
}

// Every actuator holds in cur: re-run, for each actuator in turn, its next smaller candidate with
// the others at their choice. The first that holds is taken (returns true: iterate on); else each
// one's failure is kept for the report.
bool Sizer::verify(std::vector<std::size_t>& cur, const std::vector<SizingPoint>& r) {
  for (std::size_t a = 0; a < cur.size(); ++a) {
    res_.choices[a].has_smaller = false;
    if (!ok(r[a]) || cur[a] == 0) continue;
    std::vector<std::size_t> lower = cur;
    --lower[a];
    const SizingPoint p = evaluate(lower)[a];
    if (ok(p)) {
      cur = lower;
      return true;
    }
    res_.choices[a].has_smaller = true;
    res_.choices[a].smaller = lower[a];
    res_.choices[a].smaller_fails = p;
  }
  return false;
}

void Sizer::finish(const std::vector<std::size_t>& cur) {
  const std::vector<SizingPoint>& r = evaluate(cur);
  for (std::size_t a = 0; a < cur.size(); ++a) {
    SizingChoice& c = res_.choices[a];
    c.found = ok(r[a]);
    c.candidate = cur[a];
    c.binding = r[a];
    for (const auto& e : res_.evaluations) {
      if (e.actuator == a && (c.best_margin == -std::numeric_limits<double>::infinity() ||
                              e.worst.margin > c.best_margin)) {
        c.best_margin = e.worst.margin;
        c.best_candidate = e.candidate;
      }
    }
  }
}

// The fixed-point iteration (docs/sizing.md, "Several actuators"): every actuator starts at its
// smallest candidate; a round runs the configuration and moves every failing actuator to its next
// candidate (an actuator at its last candidate stays there: none holds). When every actuator that
// can hold does, verify() re-runs each one's next smaller candidate with the others at their
// choices, and takes it if it holds. Converged when nothing moves.
SizingResult Sizer::run() {
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<std::size_t> cur(f_.actuators.size(), 0);
  for (int round = 0; round < f_.max_rounds; ++round) {
    const std::vector<SizingPoint> r = evaluate(cur);
    bool moved = false;
    for (std::size_t a = 0; a < cur.size(); ++a) {
      if (!ok(r[a]) && cur[a] + 1 < f_.actuators[a].candidates.size()) {
        ++cur[a];
        moved = true;
      }
    }
    if (moved) continue;
    if (!verify(cur, r)) {
      res_.converged = true;
      break;
    }
  }
  finish(cur);
  res_.wall_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return res_;
}

}  // namespace

SizingResult run_sizing(const SizingFile& file, const SizingOptions& options) {
  Sizer s(file, options);
  return s.run();
}

}  // namespace ukdyn
