// The base scenario's tree and the samples written into copies of it (scenario_tree.hpp), and a
// sample as standalone scenario text (`ukdyn sweep --extract K`).
#include "sweep/scenario_tree.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cstring>
#include <sstream>

#include "scenario/yaml_loader.hpp"
#include "scenario/yaml_paths.hpp"
#include "ukdyn/run/run.hpp"
#include "ukdyn/scenario/scenario_file.hpp"
#include "ukdyn/text/safe_text.hpp"

namespace ukdyn {

namespace sweep_detail {

std::string num(double v) { return fmt::format("{}", v); }

std::string read_text(const std::filesystem::path& p, const std::string& what,
                      std::size_t max_bytes) {
  return read_input_text(p, what, max_bytes);
}

YAML::Node clone(const YAML::Node& n) { return io_detail::clone_yaml(n); }

const YAML::Node& base_yaml(const Sweep& sw) {
  return *static_cast<const YAML::Node*>(sw.base_doc.get());
}

bool plant_path(const std::string& path) { return path.rfind(kPlantPrefix, 0) == 0; }

YAML::Node plant_tree(const YAML::Node& doc, const std::filesystem::path& base_path) {
  const YAML::Node pf = doc["control"]["plant"];
  if (pf && pf.IsScalar()) {
    const auto where = base_path.parent_path() / pf.Scalar();
    return clone(io_detail::parse_scenario_yaml(read_text(where, "plant scenario"), where));
  }
  YAML::Node t = clone(doc);
  t.remove("control");
  t.remove("actuators");
  return t;
}

long state_index(const std::string& path, bool& velocity) {
  for (const char* pre : {"initial.q[", "initial.qd["}) {
    const std::string p = pre;
    if (path.rfind(p, 0) == 0 && path.back() == ']') {
      const std::string inner = path.substr(p.size(), path.size() - p.size() - 1);
      if (inner.empty() || inner.size() > 6 ||
          !std::all_of(inner.begin(), inner.end(), [](char c) { return c >= '0' && c <= '9'; }))
        return -1;
      velocity = p == "initial.qd[";
      return std::stol(inner);
    }
  }
  return -1;
}

bool system_independent_of_state(const YAML::Node& doc) {
  const YAML::Node cons = doc["constraints"];
  if (!cons || cons.IsNull()) return true;
  if (!cons.IsSequence()) return false;
  for (const auto& c : cons) {
    if (!c.IsMap() || !c["type"] || !c["type"].IsScalar()) return false;
    const std::string type = c["type"].Scalar();
    if (type == "closure" || type == "expression" || type == "nonholonomic") continue;
    const char* key = type == "coordinate"             ? "value"
                      : type == "cut_point_trajectory" ? "origin"
                                                       : nullptr;
    if (!key) return false;  // the other kinds may take a point's initial position
    const YAML::Node v = c[key];
    if (!v || v.IsNull() || (v.IsScalar() && v.Scalar() == "initial")) return false;
  }
  return true;
}

double target_value(const SweepTarget& t, double v) { return t.scale * v + t.offset; }

namespace {

using io_detail::find_scalar;

void write_at(YAML::Node& doc, const std::string& path, double value) {
  std::string why;
  auto n = find_scalar(doc, path, why);
  if (n) *n = num(value);  // assigns the node's content in the tree
}

// A `plant.P` target: {path: P, value: v} appended to control.plant_set (applied after the
// entries of the base scenario, so it replaces what they wrote at P).
void write_target(YAML::Node& doc, const std::string& path, double value) {
  if (!plant_path(path)) {
    write_at(doc, path, value);
    return;
  }
  YAML::Node e(YAML::NodeType::Map);
  e["path"] = path.substr(std::strlen(kPlantPrefix));
  e["value"] = num(value);
  if (!doc["control"]["plant_set"].IsSequence())
    doc["control"]["plant_set"] = YAML::Node(YAML::NodeType::Sequence);
  doc["control"]["plant_set"].push_back(e);
}

std::string emit(const YAML::Node& doc) {
  YAML::Emitter e;
  e << doc;
  return std::string(e.c_str()) + "\n";
}

}  // namespace

YAML::Node sample_doc(const Sweep& sw, const std::vector<double>& vals, bool with_state) {
  YAML::Node doc = clone(base_yaml(sw));
  for (std::size_t i = 0; i < sw.fixed.size(); ++i)
    write_target(doc, sw.fixed[i].path, sw.fixed_values[i]);
  for (std::size_t j = 0; j < sw.parameters.size(); ++j) {
    for (const auto& t : sw.parameters[j].targets) {
      bool vel = false;
      if (!with_state && state_index(t.path, vel) >= 0) continue;
      write_target(doc, t.path, target_value(t, vals[j]));
    }
  }
  return doc;
}

namespace {

std::string scenario_text(const Sweep& sw, const std::vector<double>& vals, bool with_state) {
  return emit(sample_doc(sw, vals, with_state));
}

}  // namespace

}  // namespace sweep_detail

std::string sample_scenario_text(const Sweep& sw, long k) {
  const auto vals = sample_values(sw, k);
  std::string head = fmt::format(
      "# Sample {} of sweep '{}' ({}), base scenario {}; written by ukdyn {} sweep --extract.\n", k,
      sw.name, printable(sw.path.string()), printable(sw.base_path.string()), version());
  for (std::size_t j = 0; j < vals.size(); ++j)
    head += fmt::format("#   {} = {}\n", sw.parameters[j].name, sweep_detail::num(vals[j]));
  return head + sweep_detail::scenario_text(sw, vals, true);
}

}  // namespace ukdyn
