// The catalogue and sizing files of `ukdyn size` (ukdyn/sweep/sizing.hpp, docs/sizing.md).
#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <set>

#include "scenario/control_loader.hpp"
#include "scenario/yaml_loader.hpp"
#include "sweep/scenario_tree.hpp"
#include "ukdyn/scenario/scenario_file.hpp"
#include "ukdyn/sweep/sizing.hpp"
#include "ukdyn/text/safe_text.hpp"

namespace ukdyn {

namespace {

using io_detail::Loader;
using io_detail::motor_key;
using io_detail::Node;

constexpr double kInf = std::numeric_limits<double>::infinity();

bool positive_finite(double v) { return v > 0.0 && std::isfinite(v); }
bool nonnegative_finite(double v) { return v >= 0.0 && std::isfinite(v); }
bool limit_value(double v) { return v > 0.0; }  // .inf: no limit
bool efficiency_value(double v) { return v > 0.0 && v <= 1.0; }

constexpr const char* kPos = "must be > 0 and finite";
constexpr const char* kNonneg = "must be >= 0 and finite";
constexpr const char* kLimit = "must be > 0 (.inf: no limit)";

// The text of a small file and its YAML tree (errors at the file's line and column).
YAML::Node read_yaml(const std::filesystem::path& path, const std::string& what) {
  return io_detail::parse_scenario_yaml(sweep_detail::read_text(path, what), path);
}

CatalogueMotor load_catalogue_motor(const Loader& L, const Node& m) {
  L.only_keys(m, {"name", "mass", "note", "rotor_inertia", "viscous", "coulomb", "coulomb_speed",
                  "torque_constant", "resistance", "stall_torque", "no_load_speed",
                  "continuous_torque", "peak_torque"});
  CatalogueMotor c;
  c.name = L.name(L.child(m, "name", true));
  c.mass = motor_key(L, m, "mass", c.mass, positive_finite, kPos);
  if (Node n = L.child(m, "note", false); n.node.IsDefined()) L.string(n);
  MotorSpec& s = c.spec;
  L.child(m, "torque_constant", true);
  s.rotor_inertia = motor_key(L, m, "rotor_inertia", 0.0, nonnegative_finite, kNonneg);
  s.viscous = motor_key(L, m, "viscous", 0.0, nonnegative_finite, kNonneg);
  s.coulomb = motor_key(L, m, "coulomb", 0.0, nonnegative_finite, kNonneg);
  s.coulomb_speed = motor_key(L, m, "coulomb_speed", s.coulomb_speed, positive_finite, kPos);
  s.torque_constant = motor_key(L, m, "torque_constant", 1.0, positive_finite, kPos);
  s.resistance = motor_key(L, m, "resistance", 0.0, nonnegative_finite, kNonneg);
  s.stall_torque = motor_key(L, m, "stall_torque", kInf, limit_value, kLimit);
  s.no_load_speed = motor_key(L, m, "no_load_speed", kInf, limit_value, kLimit);
  s.continuous_torque = motor_key(L, m, "continuous_torque", kInf, limit_value, kLimit);
  s.peak_torque = motor_key(L, m, "peak_torque", kInf, limit_value, kLimit);
  if (std::isinf(s.stall_torque) && std::isinf(s.peak_torque))
    L.fail(m,
           "motor '" + c.name + "': give stall_torque or peak_torque (a torque limit to size by)");
  return c;
}

CatalogueGearbox load_catalogue_gearbox(const Loader& L, const Node& g) {
  L.only_keys(g, {"name", "mass", "note", "ratio", "efficiency", "inertia", "continuous_torque",
                  "peak_torque", "max_input_speed"});
  CatalogueGearbox c;
  c.name = L.name(L.child(g, "name", true));
  L.child(g, "ratio", true);
  c.ratio = motor_key(L, g, "ratio", 1.0, positive_finite, kPos);
  c.efficiency = motor_key(L, g, "efficiency", 1.0, efficiency_value, "must be in (0, 1]");
  c.inertia = motor_key(L, g, "inertia", 0.0, nonnegative_finite, kNonneg);
  c.mass = motor_key(L, g, "mass", c.mass, positive_finite, kPos);
  c.continuous_torque = motor_key(L, g, "continuous_torque", kInf, limit_value, kLimit);
  c.peak_torque = motor_key(L, g, "peak_torque", kInf, limit_value, kLimit);
  c.max_input_speed = motor_key(L, g, "max_input_speed", kInf, limit_value, kLimit);
  if (Node n = L.child(g, "note", false); n.node.IsDefined()) L.string(n);
  return c;
}

// A non-empty list of entries with unique names.
template <class Entry, class Read>
std::vector<Entry> load_entries(const Loader& L, const Node& list, Read read) {
  if (!list.node.IsSequence() || list.node.size() == 0 || list.node.size() > 10000)
    L.fail(list, "expected a non-empty list (at most 10000 entries)");
  std::vector<Entry> out;
  std::set<std::string> names;
  for (std::size_t i = 0; i < list.node.size(); ++i) {
    const Node e{list.node[i], list.key + "[" + std::to_string(i) + "]"};
    if (!e.node.IsMap()) L.fail(e, "expected a mapping with a name");
    out.push_back(read(L, e));
    if (!names.insert(out.back().name).second)
      L.fail(L.child(e, "name", true), "duplicate name '" + out.back().name + "'");
  }
  return out;
}

void check_version(const Loader& L, const Node& root, const char* key, const char* what) {
  const Node v = L.child(root, key, true);
  if (L.number(v) != 1.0)
    L.fail(v, fmt::format("unsupported {} format version (this ukdyn reads 1)", what));
}

}  // namespace

Catalogue load_catalogue(const std::filesystem::path& path) {
  const YAML::Node doc = read_yaml(path, "catalogue");
  Loader L(path);
  const Node root{doc, ""};
  if (!doc.IsMap()) throw ScenarioError(printable(path.string()) + ": expected a mapping");
  L.only_keys(root, {"ukdyn_catalogue", "name", "note", "motors", "gearboxes"});
  check_version(L, root, "ukdyn_catalogue", "catalogue");
  Catalogue c;
  c.path = path;
  c.name = L.name(L.child(root, "name", true));
  c.motors = load_entries<CatalogueMotor>(L, L.child(root, "motors", true), load_catalogue_motor);
  c.gearboxes =
      load_entries<CatalogueGearbox>(L, L.child(root, "gearboxes", true), load_catalogue_gearbox);
  return c;
}

MotorSpec candidate_spec(const Catalogue& c, const SizingCandidate& k) {
  const CatalogueGearbox& g = c.gearboxes[k.gearbox];
  MotorSpec s = c.motors[k.motor].spec;
  s.ratio = g.ratio;
  s.efficiency = g.efficiency;
  s.rotor_inertia += g.inertia;
  return s;
}

std::string candidate_name(const Catalogue& c, const SizingCandidate& k) {
  return c.motors[k.motor].name + " + " + c.gearboxes[k.gearbox].name;
}

namespace {

// The ordering (docs/sizing.md, "Smallest"): `order_by` as given, else mass when every motor and
// gearbox of the catalogue has one, else the motor's continuous torque.
void choose_order(const Loader& L, const Node& root, SizingFile& f) {
  const Catalogue& c = f.catalogue;
  bool masses = true;
  for (const auto& m : c.motors) masses = masses && std::isfinite(m.mass);
  for (const auto& g : c.gearboxes) masses = masses && std::isfinite(g.mass);
  const Node ob = L.child(root, "order_by", false);
  if (!ob.node.IsDefined()) {
    f.order_by = masses ? "mass" : "continuous_torque";
    f.order_reason = masses ? "default: every motor and gearbox of the catalogue has a mass"
                            : "default: some catalogue entry has no mass";
    return;
  }
  f.order_by = L.string(ob);
  if (f.order_by != "mass" && f.order_by != "continuous_torque" && f.order_by != "peak_torque")
    L.fail(ob, "expected mass, continuous_torque or peak_torque");
  if (f.order_by == "mass" && !masses)
    L.fail(ob, "order_by: mass needs a mass on every motor and gearbox of the catalogue");
  f.order_reason = "order_by in the sizing file";
}

// The candidates of one actuator in ascending order: by mass (motor + gearbox), or by the motor's
// continuous / peak torque, then the gearbox (its mass if every gearbox has one, else its rated
// output torque, then its ratio), then catalogue order.
std::vector<SizingCandidate> order_candidates(const SizingFile& f, const std::set<std::size_t>& ms,
                                              const std::set<std::size_t>& gs) {
  const Catalogue& c = f.catalogue;
  bool gear_masses = true;
  for (const auto& g : c.gearboxes) gear_masses = gear_masses && std::isfinite(g.mass);
  std::vector<SizingCandidate> out;
  for (std::size_t m : ms) {
    for (std::size_t g : gs) {
      const MotorSpec& s = c.motors[m].spec;
      const double motor_key = f.order_by == "mass" ? c.motors[m].mass
                               : f.order_by == "continuous_torque"
                                   ? s.continuous_torque
                                   : std::min(s.peak_torque, s.stall_torque);
      const double size = f.order_by == "mass" ? c.motors[m].mass + c.gearboxes[g].mass : motor_key;
      out.push_back({m, g, size});
    }
  }
  const auto gear_key = [&](std::size_t g) {
    const CatalogueGearbox& b = c.gearboxes[g];
    return std::make_tuple(gear_masses ? b.mass : 0.0, b.continuous_torque, b.peak_torque, b.ratio);
  };
  std::stable_sort(out.begin(), out.end(), [&](const SizingCandidate& a, const SizingCandidate& b) {
    if (a.size != b.size) return a.size < b.size;
    if (f.order_by != "mass" && a.motor != b.motor) return a.motor < b.motor;
    return gear_key(a.gearbox) < gear_key(b.gearbox);
  });
  return out;
}

// A list of catalogue names (`motors:` / `gearboxes:` of an actuator), as indices.
template <class Entry>
std::set<std::size_t> pick(const Loader& L, const Node& parent, const char* key,
                           const std::vector<Entry>& all) {
  std::set<std::size_t> out;
  const Node n = L.child(parent, key, false);
  if (!n.node.IsDefined()) {
    for (std::size_t i = 0; i < all.size(); ++i) out.insert(i);
    return out;
  }
  if (!n.node.IsSequence() || n.node.size() == 0) L.fail(n, "expected a non-empty list of names");
  for (std::size_t i = 0; i < n.node.size(); ++i) {
    const Node e{n.node[i], n.key + "[" + std::to_string(i) + "]"};
    const std::string name = L.string(e);
    std::size_t j = 0;
    while (j < all.size() && all[j].name != name) ++j;
    if (j == all.size()) L.fail(e, "the catalogue has no entry named '" + name + "'");
    out.insert(j);
  }
  return out;
}

// The sweep of a sizing file: a sweep file (`sweep:`), or a scenario (`scenario:`) as one sample.
void load_samples(const Loader& L, const Node& root, SizingFile& f) {
  const Node sn = L.child(root, "scenario", false), wn = L.child(root, "sweep", false);
  if (sn.node.IsDefined() == wn.node.IsDefined())
    L.fail(root, "give either scenario: (one run) or sweep: (a sweep file's samples)");
  const std::filesystem::path dir = f.path.parent_path();
  f.from_sweep = wn.node.IsDefined();
  try {
    if (f.from_sweep) {
      f.sweep = load_sweep(dir / L.string(wn));
      return;
    }
    Sweep& sw = f.sweep;
    sw.path = sw.base_path = dir / L.string(sn);
    sw.name = f.name;
    sw.base_text = sweep_detail::read_text(sw.base_path, "scenario");
    sw.base_doc = std::make_shared<YAML::Node>(
        sweep_detail::clone(io_detail::parse_scenario_yaml(sw.base_text, sw.base_path)));
    sw.mode = Sweep::Mode::list;
    sw.samples = 1;
    sw.hash = io_detail::scenario_text_hash(sw.base_text);
  } catch (const ScenarioError& e) {
    L.fail(f.from_sweep ? wn : sn, e.what());
  }
}

// `actuators:` names (or {name, motors, gearboxes}) of the scenario's actuators.
void load_sized_actuators(const Loader& L, const Node& root, const Scenario& base, SizingFile& f) {
  const Node an = L.child(root, "actuators", true);
  if (!an.node.IsSequence() || an.node.size() == 0)
    L.fail(an, "expected a non-empty list of actuator names (or {name, motors, gearboxes})");
  const std::vector<std::string>& names = base.actuators.names;
  std::set<std::string> seen;
  for (std::size_t i = 0; i < an.node.size(); ++i) {
    const Node e{an.node[i], an.key + "[" + std::to_string(i) + "]"};
    const bool is_map = e.node.IsMap();
    if (is_map) L.only_keys(e, {"name", "motors", "gearboxes"});
    // (never assign a YAML::Node to another: yaml-cpp would rewrite the node it refers to)
    const Node name_node = is_map ? L.child(e, "name", true) : e;
    const std::string name = L.string(name_node);
    const Node lists = is_map ? e : Node{YAML::Node(YAML::NodeType::Map), e.key};
    const std::set<std::size_t> ms = pick(L, lists, "motors", f.catalogue.motors);
    const std::set<std::size_t> gs = pick(L, lists, "gearboxes", f.catalogue.gearboxes);
    if (std::find(names.begin(), names.end(), name) == names.end())
      L.fail(name_node, "the scenario has no actuator named '" + name + "'");
    if (!seen.insert(name).second) L.fail(name_node, "actuator '" + name + "' is listed twice");
    f.actuators.push_back({name, order_candidates(f, ms, gs)});
  }
}

}  // namespace

SizingFile load_sizing_file(const std::filesystem::path& path) {
  const YAML::Node doc = read_yaml(path, "sizing file");
  Loader L(path);
  const Node root{doc, ""};
  if (!doc.IsMap()) throw ScenarioError(printable(path.string()) + ": expected a mapping");
  L.only_keys(root, {"ukdyn_sizing", "name", "catalogue", "scenario", "sweep", "actuators",
                     "margin", "order_by", "continuous", "max_rounds"});
  check_version(L, root, "ukdyn_sizing", "sizing");
  SizingFile f;
  f.path = path;
  f.name = L.name(L.child(root, "name", true));
  const Node cn = L.child(root, "catalogue", true);
  try {
    f.catalogue = load_catalogue(path.parent_path() / L.string(cn));
  } catch (const ScenarioError& e) {
    L.fail(cn, e.what());
  }
  load_samples(L, root, f);
  const Node mn = L.child(root, "margin", false);
  if (mn.node.IsDefined()) {
    f.margin = L.number(mn);
    if (!(f.margin >= 0.0 && f.margin < 1.0)) L.fail(mn, "margin must be in [0, 1)");
  }
  if (Node c = L.child(root, "continuous", false); c.node.IsDefined()) {
    const std::string v = L.string(c);
    if (v != "true" && v != "false") L.fail(c, "expected true or false");
    f.continuous = v == "true";
  }
  if (Node r = L.child(root, "max_rounds", false); r.node.IsDefined()) {
    const double v = L.number(r);
    if (!(v >= 1 && v <= 10000 && v == std::floor(v)))
      L.fail(r, "expected an integer in [1, 10000]");
    f.max_rounds = static_cast<int>(v);
  }
  choose_order(L, root, f);
  Scenario base;
  try {
    base = load_scenario_text(f.sweep.base_text, f.sweep.base_path, {false});
  } catch (const ScenarioError& e) {
    L.fail(L.child(root, f.from_sweep ? "sweep" : "scenario", true), e.what());
  }
  const bool servo = std::any_of(base.constraint_roles.begin(), base.constraint_roles.end(),
                                 [](ConstraintRole r) { return r == ConstraintRole::servo; });
  if (!servo && !base.control)
    L.fail(L.child(root, f.from_sweep ? "sweep" : "scenario", true),
           "the scenario has no servo constraint rows and no control: section, so the actuators' "
           "inputs u are 0 at every sample (docs/control.md): there is nothing to size by");
  const YAML::Node control = sweep_detail::base_yaml(f.sweep)["control"];
  if (control.IsDefined() && control.IsMap() && control["plant"].IsDefined())
    L.fail(L.child(root, f.from_sweep ? "sweep" : "scenario", true),
           "the scenario's control.plant is a separate file, whose motors the sizing cannot "
           "replace: size on a scenario whose plant is the scenario itself (docs/sizing.md)");
  load_sized_actuators(L, root, base, f);
  return f;
}

}  // namespace ukdyn
