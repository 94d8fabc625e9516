// What `ukdyn size` writes and prints (ukdyn/sweep/sizing.hpp, docs/sizing.md): sizing.json,
// candidates.csv and the console table.
#include <fmt/format.h>

#include <cmath>
#include <nlohmann/json.hpp>
#include <ostream>

#include "sweep/scenario_tree.hpp"
#include "ukdyn/output/output_dir.hpp"
#include "ukdyn/sweep/sizing.hpp"
#include "ukdyn/text/safe_text.hpp"

namespace ukdyn {

namespace {

using sweep_detail::num;

nlohmann::json number_or_null(double v) {
  return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr);
}

nlohmann::json point_json(const SizingFile& f, const SizingPoint& p) {
  nlohmann::json j;
  j["sample"] = p.sample;
  nlohmann::json params = nlohmann::json::object();
  for (std::size_t i = 0; i < p.values.size() && i < f.sweep.parameters.size(); ++i)
    params[f.sweep.parameters[i].name] = p.values[i];
  j["parameters"] = params;
  j["t"] = number_or_null(p.t);  // null: a limit over the whole run (RMS)
  j["margin"] = number_or_null(p.margin);
  j["limit"] = p.limit;
  j["u"] = p.u;
  j["omega_joint"] = p.omega_j;
  j["motor_torque"] = p.torque;
  j["motor_speed"] = p.omega_m;
  if (!p.failure.empty()) j["failure"] = p.failure;
  return j;
}

nlohmann::json candidate_json(const SizingFile& f, const SizingCandidate& c) {
  const Catalogue& cat = f.catalogue;
  return {{"motor", cat.motors[c.motor].name},
          {"gearbox", cat.gearboxes[c.gearbox].name},
          {"ratio", cat.gearboxes[c.gearbox].ratio},
          {"size", number_or_null(c.size)}};
}

// "sample 3 (load_mass = 2, omega = 4.712)".
std::string sample_text(const SizingFile& f, const SizingPoint& p) {
  std::string s = fmt::format("sample {}", p.sample);
  if (p.values.empty()) return s;
  s += " (";
  for (std::size_t i = 0; i < p.values.size() && i < f.sweep.parameters.size(); ++i)
    s += fmt::format("{}{} = {:.6g}", i ? ", " : "", f.sweep.parameters[i].name, p.values[i]);
  return s + ")";
}

// Where and how a point meets its limit, in words.
std::string point_text(const SizingFile& f, const SizingPoint& p) {
  if (!p.failure.empty()) return p.failure;
  const std::string where = sample_text(f, p);
  if (std::isnan(p.t)) {
    const bool gear = p.limit.starts_with("gearbox");
    return fmt::format("{}, over the whole run: RMS {} = {:.4g} N m", where,
                       gear ? "output torque |u|" : "motor torque", gear ? p.u : p.torque);
  }
  return fmt::format(
      "{}, t = {:.4g} s: u = {:.4g} N m at {:.4g} rad/s (motor {:.4g} N m at {:.4g} rad/s)", where,
      p.t, p.u, p.omega_j, p.torque, p.omega_m);
}

// Text for the terminal: control bytes escaped, the line breaks kept.
std::string line(const std::string& s) { return printable(s, true); }

std::string percent(double m) {
  return std::isfinite(m) ? fmt::format("{:.1f} %", 100.0 * m)
                          : std::string(std::isnan(m) ? "nan" : "-inf");
}

}  // namespace

std::string sizing_json(const SizingFile& f, const SizingResult& r) {
  nlohmann::json j;
  j["sizing"] = f.name;
  j["file"] = f.path.string();
  j["catalogue"] = {{"name", f.catalogue.name}, {"path", f.catalogue.path.string()}};
  nlohmann::json params = nlohmann::json::array();
  for (const auto& p : f.sweep.parameters) params.push_back(p.name);
  j["samples"] = {{"source", f.from_sweep ? "sweep" : "scenario"},
                  {"path", (f.from_sweep ? f.sweep.path : f.sweep.base_path).string()},
                  {"scenario", f.sweep.base_path.string()},
                  {"count", f.sweep.samples},
                  {"parameters", params}};
  j["margin"] = f.margin;
  j["continuous"] = f.continuous;
  j["order_by"] = f.order_by;
  j["order_reason"] = f.order_reason;
  j["converged"] = r.converged;
  j["configurations"] = r.configurations;
  j["runs"] = r.runs;
  j["all_found"] = r.all_found();
  nlohmann::json acts = nlohmann::json::array();
  for (std::size_t a = 0; a < f.actuators.size(); ++a) {
    const SizingActuator& act = f.actuators[a];
    const SizingChoice& c = r.choices[a];
    nlohmann::json e;
    e["name"] = act.name;
    e["found"] = c.found;
    e["candidates"] = act.candidates.size();
    e[c.found ? "choice" : "last_tried"] = candidate_json(f, act.candidates[c.candidate]);
    e["choice_rank"] = c.candidate;
    e["binding"] = point_json(f, c.binding);
    if (c.has_smaller) {
      e["next_smaller"] = candidate_json(f, act.candidates[c.smaller]);
      e["next_smaller"]["fails_at"] = point_json(f, c.smaller_fails);
    } else {
      e["next_smaller"] = nullptr;
    }
    if (!c.found) {
      e["best"] = candidate_json(f, act.candidates[c.best_candidate]);
      e["best_margin"] = number_or_null(c.best_margin);
      e["shortfall"] = number_or_null(f.margin - c.best_margin);
    }
    acts.push_back(e);
  }
  j["actuators"] = acts;
  return j.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n";
}

std::string sizing_csv(const SizingFile& f, const SizingResult& r) {
  std::string s =
      "actuator,candidate,motor,gearbox,size,holds,worst_margin,limit,sample,t,configuration\n";
  for (const auto& e : r.evaluations) {
    const SizingActuator& act = f.actuators[e.actuator];
    const SizingCandidate& c = act.candidates[e.candidate];
    s += fmt::format("{},{},{},{},{},{},{},{},{},{},{}\n", csv_field(act.name), e.candidate,
                     csv_field(f.catalogue.motors[c.motor].name),
                     csv_field(f.catalogue.gearboxes[c.gearbox].name), num(c.size),
                     e.holds ? "true" : "false", num(e.worst.margin), csv_field(e.worst.limit),
                     e.worst.sample, std::isnan(e.worst.t) ? "" : num(e.worst.t), e.configuration);
  }
  return s;
}

void write_sizing(const SizingFile& f, const SizingResult& r, const std::filesystem::path& out) {
  OutputDir dir(out);
  for (const auto& [name, text] : {std::pair{"sizing.json", sizing_json(f, r)},
                                   std::pair{"candidates.csv", sizing_csv(f, r)}}) {
    AtomicFile file(dir, dir.fd(), "", name);
    file.write(text);
    file.commit();
  }
  dir.sync();
}

void print_sizing_report(std::ostream& os, const SizingFile& f, const SizingResult& r) {
  std::string params;
  for (const auto& p : f.sweep.parameters) params += (params.empty() ? "" : ", ") + p.name;
  os << line(
      fmt::format("ukdyn size {}: {} sample(s) of {} {}{}; catalogue {}\n"
                  "  margin {:.3g} % of every limit; smallest = by {} ({})\n",
                  f.name, f.sweep.samples, f.from_sweep ? "sweep" : "scenario",
                  (f.from_sweep ? f.sweep.path : f.sweep.base_path).string(),
                  params.empty() ? "" : " over " + params, f.catalogue.name, 100.0 * f.margin,
                  f.order_by, f.order_reason));
  os << fmt::format("  {:<12} {:<32} {:>10} {:>9}  {}\n", "actuator", "choice",
                    f.order_by == "mass" ? "mass (kg)" : "T (N m)", "margin", "limit");
  for (std::size_t a = 0; a < f.actuators.size(); ++a) {
    const SizingActuator& act = f.actuators[a];
    const SizingChoice& c = r.choices[a];
    const SizingCandidate& k = act.candidates[c.candidate];
    os << line(fmt::format("  {:<12} {:<32} {:>10.4g} {:>9}  {}{}\n", act.name,
                           c.found ? candidate_name(f.catalogue, k) : "NONE HOLDS", k.size,
                           percent(c.binding.margin), c.binding.limit,
                           c.found ? "" : " (largest tried)"));
    os << line("      binding: " + point_text(f, c.binding)) << "\n";
    if (!c.found) {
      os << line(fmt::format(
          "      no candidate keeps {}: the best, {}, keeps {} (short by {:.3g} points)\n",
          percent(f.margin), candidate_name(f.catalogue, act.candidates[c.best_candidate]),
          percent(c.best_margin), 100.0 * (f.margin - c.best_margin)));
    } else if (c.has_smaller) {
      os << line(fmt::format("      next smaller {} fails: margin {} ({}) at {}\n",
                             candidate_name(f.catalogue, act.candidates[c.smaller]),
                             percent(c.smaller_fails.margin), c.smaller_fails.limit,
                             point_text(f, c.smaller_fails)));
    } else {
      os << "      (the smallest candidate it may use)\n";
    }
  }
  os << fmt::format("  {} configurations, {} runs, {:.1f} s{}\n", r.configurations, r.runs,
                    r.wall_seconds,
                    r.converged ? "" : fmt::format("; NOT converged in {} rounds", f.max_rounds));
}

}  // namespace ukdyn
