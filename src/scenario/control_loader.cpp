#include "scenario/control_loader.hpp"

#include <fmt/format.h>

#include <cmath>
#include <limits>
#include <set>

#include "scenario/yaml_paths.hpp"
#include "ukdyn/scenario/scenario_file.hpp"

namespace ukdyn::io_detail {

RoleChoice take_role(const Loader& L, const Node& c, const std::string& type) {
  RoleChoice r;
  if (type == "cut_point_trajectory" || type == "coordinate" || type == "point_trajectory") {
    r.role = ConstraintRole::servo;
  } else if (type == "expression") {
    r.by_time = true;
  }
  if (!c.node.IsMap()) return r;
  const Node rn = L.child(c, "role", false);
  if (!rn.node.IsDefined()) return r;
  const std::string v = L.string(rn);
  if (v == "physical") {
    r.role = ConstraintRole::physical;
  } else if (v == "servo") {
    r.role = ConstraintRole::servo;
  } else {
    L.fail(rn, "unknown role '" + v + "' (expected physical or servo)");
  }
  r.by_time = false;
  r.given = v;
  YAML::Node mut = c.node;  // a handle on the same map
  mut.remove("role");
  return r;
}

void restore_role(const Node& c, const RoleChoice& choice) {
  if (choice.given.empty()) return;
  YAML::Node mut = c.node;
  mut["role"] = choice.given;
}

ConstraintRole resolve_role(const RoleChoice& choice, const Constraint& c, const Vec& q0) {
  if (!choice.by_time) return choice.role;
  const Index m = c.rows();
  Vec p0(m), p(m), v(m);
  const Vec qd = Vec::Zero(q0.size());
  c.position_residual({}, q0, p0);
  for (double t : {0.0, 0.37, 1.3, 2.9}) {  // a few unrelated times: Φ(q0, t) − Φ(q0, 0), Φ_t
    c.position_residual({t}, q0, p);
    c.velocity_residual({t}, q0, qd, v);
    if ((p - p0).cwiseAbs().maxCoeff() > 1e-12 || v.cwiseAbs().maxCoeff() > 1e-12)
      return ConstraintRole::servo;
  }
  return ConstraintRole::physical;
}

double motor_key(const Loader& L, const Node& m, const char* key, double fallback,
                 bool (*ok)(double), const char* rule) {
  const Node n = L.child(m, key, false);
  if (!n.node.IsDefined()) return fallback;
  const double v = L.number(n);
  if (!ok(v)) L.fail(n, fmt::format("{} {} (got {})", key, rule, v));
  return v;
}

namespace {

double number_at_least(const Loader& L, const Node& parent, const char* key, double fallback,
                       double lo) {
  const Node n = L.child(parent, key, false);
  if (!n.node.IsDefined()) return fallback;
  const double v = L.number(n);
  if (!(v >= lo)) L.fail(n, "must be >= " + std::to_string(lo));
  return v;
}

// An actuator's `motor:` block (docs/motors.md, "Keys"): the motor and gearbox behind it. Its
// reflected rotor inertia n² J_m b bᵀ goes into M, its friction −b n τ_f(n bᵀq̇) into the applied
// forces of `system` (ukdyn/model/motor.hpp).
MotorSpec load_motor(const Loader& L, const Node& m, const std::string& actuator, CVecRef b,
                     System& system) {
  if (!m.node.IsMap()) L.fail(m, "expected a map of motor keys (docs/motors.md)");
  L.only_keys(m, {"ratio", "efficiency", "rotor_inertia", "viscous", "coulomb", "coulomb_speed",
                  "torque_constant", "resistance", "stall_torque", "no_load_speed",
                  "continuous_torque", "peak_torque"});
  const auto pos = [](double v) { return v > 0.0 && std::isfinite(v); };
  const auto nonneg = [](double v) { return v >= 0.0 && std::isfinite(v); };
  const auto limit = [](double v) { return v > 0.0; };  // .inf allowed: no limit
  const auto eff = [](double v) { return v > 0.0 && v <= 1.0; };
  const char* kPos = "must be > 0 and finite";
  const char* kNonneg = "must be >= 0 and finite";
  MotorSpec s;
  L.child(m, "ratio", true);
  L.child(m, "torque_constant", true);
  s.ratio = motor_key(L, m, "ratio", 1.0, pos, kPos);
  s.efficiency = motor_key(L, m, "efficiency", 1.0, eff, "must be in (0, 1]");
  s.rotor_inertia = motor_key(L, m, "rotor_inertia", 0.0, nonneg, kNonneg);
  s.viscous = motor_key(L, m, "viscous", 0.0, nonneg, kNonneg);
  s.coulomb = motor_key(L, m, "coulomb", 0.0, nonneg, kNonneg);
  s.coulomb_speed = motor_key(L, m, "coulomb_speed", s.coulomb_speed, pos, kPos);
  s.torque_constant = motor_key(L, m, "torque_constant", 1.0, pos, kPos);
  s.resistance = motor_key(L, m, "resistance", 0.0, nonneg, kNonneg);
  const double inf = std::numeric_limits<double>::infinity();
  s.stall_torque = motor_key(L, m, "stall_torque", inf, limit, "must be > 0");
  s.no_load_speed = motor_key(L, m, "no_load_speed", inf, limit, "must be > 0");
  s.continuous_torque = motor_key(L, m, "continuous_torque", inf, limit, "must be > 0");
  s.peak_torque = motor_key(L, m, "peak_torque", inf, limit, "must be > 0");
  try {
    if (s.rotor_inertia > 0.0) system.add_reflected_inertia(b, s.ratio * s.ratio * s.rotor_inertia);
    if (s.viscous > 0.0 || s.coulomb > 0.0)
      system.add_applied_force(std::make_shared<MotorFriction>("motor_" + actuator, s, Vec(b)));
  } catch (const std::invalid_argument& e) {
    L.fail(m, e.what());
  }
  return s;
}

void load_actuators(const Loader& L, const Node& a, Scenario& sc, System& system,
                    const std::map<std::string, Index>& coord_index) {
  const Index n = sc.system->dof();
  if (!a.node.IsSequence() || a.node.size() == 0)
    L.fail(a, "expected a non-empty list of actuators {name, coordinate | gains, limit}");
  Actuators& act = sc.actuators;
  const auto k = static_cast<Index>(a.node.size());
  act.B = Mat::Zero(n, k);
  act.limit = Vec::Constant(k, std::numeric_limits<double>::infinity());
  act.motors.assign(static_cast<std::size_t>(k), std::nullopt);
  std::set<std::string> names;
  for (std::size_t j = 0; j < a.node.size(); ++j) {
    const Node e{a.node[j], a.key + "[" + std::to_string(j) + "]"};
    L.only_keys(e, {"name", "coordinate", "gains", "limit", "motor"});
    const std::string nm = L.name(L.child(e, "name", true));
    if (!names.insert(nm).second) L.fail(e, "duplicate actuator name '" + nm + "'");
    act.names.push_back(nm);
    const auto col = static_cast<Index>(j);
    const Node cn = L.child(e, "coordinate", false), gn = L.child(e, "gains", false);
    if (cn.node.IsDefined() == gn.node.IsDefined())
      L.fail(e, "give exactly one of 'coordinate' and 'gains'");
    if (cn.node.IsDefined()) {
      const std::string c = L.string(cn);
      auto it = coord_index.find(c);
      if (it == coord_index.end()) L.fail(cn, "no coordinate named '" + c + "'");
      act.B(it->second, col) = 1.0;
    } else if (gn.node.IsMap()) {  // {coordinate: gain, ...}
      for (const auto& kv : gn.node) {
        const std::string c = kv.first.as<std::string>();
        const Node g{kv.second, gn.key + "." + c};
        auto it = coord_index.find(c);
        if (it == coord_index.end()) L.fail(g, "no coordinate named '" + c + "'");
        act.B(it->second, col) = L.number(g);
      }
    } else {
      act.B.col(col) = L.vector(gn, n);
    }
    if (act.B.col(col).norm() == 0.0) L.fail(e, "the actuator's gains are all zero");
    if (Node ln = L.child(e, "limit", false); ln.node.IsDefined()) act.limit(col) = L.positive(ln);
    if (Node mn = L.child(e, "motor", false); mn.node.IsDefined())
      act.motors[j] = load_motor(L, mn, nm, act.B.col(col), system);
  }
}

// The document of the plant file `pn` names (its text in `text`), checked before it is loaded or
// copied: the limits of every YAML file (parse_scenario_yaml), and no control section of its own,
// so that a plant naming its own file, or two plants naming each other, is refused at once
// instead of loading plants without end.
YAML::Node plant_document(const Loader& L, const Node& pn, const std::filesystem::path& where,
                          std::string& text) {
  YAML::Node doc;
  try {
    text = read_scenario_text(where);
    doc = parse_scenario_yaml(text, where);
  } catch (const ScenarioError& e) {
    L.fail(pn, std::string("the plant scenario: ") + e.what());
  }
  if (doc.IsMap() && doc["control"].IsDefined())
    L.fail(pn, "the plant scenario must not have a control section itself");
  return doc;
}

// control.plant_set: the plant is the plant file (or, without one, this scenario's own tree less
// its control and actuators sections) with the listed values changed, each {path, value} or
// {path, scale} (the number there times scale) or {path, expression} (the text of an expression
// put there, e.g. a load mass of t: docs/control.md "A time-varying load mass"). Paths as in
// sweeps (src/scenario/yaml_paths.hpp).
std::shared_ptr<Scenario> perturbed_plant(const Loader& L, const Node& root, const Node& set,
                                          const Node* plant_file, const Scenario& sc) {
  if (!set.node.IsSequence() || set.node.size() == 0)
    L.fail(set, "expected a list of {path, value}, {path, scale} or {path, expression}");
  std::filesystem::path where = sc.path;
  YAML::Node doc;
  std::string hash_input;
  if (plant_file != nullptr) {
    where = sc.path.parent_path() / L.string(*plant_file);
    doc = clone_yaml(plant_document(L, *plant_file, where, hash_input));
  } else {
    doc = clone_yaml(root.node);
    doc.remove("control");
    // The actuators stay when a motor is behind one: its rotor and friction belong to the plant.
    bool motors = false;
    if (const YAML::Node acts = doc["actuators"]; acts.IsSequence())
      for (const auto& a : acts) motors = motors || (a.IsMap() && a["motor"].IsDefined());
    if (!motors) doc.remove("actuators");
    hash_input = sc.hash;
  }
  for (std::size_t i = 0; i < set.node.size(); ++i) {
    const Node e{set.node[i], set.key + "[" + std::to_string(i) + "]"};
    L.only_keys(e, {"path", "value", "scale", "expression"});
    const Node pn = L.child(e, "path", true);
    const std::string path = L.string(pn);
    const Node vn = L.child(e, "value", false), sn = L.child(e, "scale", false),
               xn = L.child(e, "expression", false);
    const int given = (vn.node.IsDefined() ? 1 : 0) + (sn.node.IsDefined() ? 1 : 0) +
                      (xn.node.IsDefined() ? 1 : 0);
    if (given != 1) {
      L.fail(e, xn.node.IsDefined() ? "give exactly one of 'value', 'scale' and 'expression'"
                                    : "give exactly one of 'value' and 'scale'");
    }
    std::string why;
    // A value goes only where a number is (never over an expression); a scale needs a number there
    // (said below); an expression may go anywhere a scalar is.
    auto at = vn.node.IsDefined() ? find_number(doc, path, why) : find_scalar(doc, path, why);
    if (!at) L.fail(pn, "'" + path + "': " + why);
    if (xn.node.IsDefined()) {
      // The text goes in as written; the plant's loader parses it (and names this key's path in
      // its own errors, through "the perturbed plant: ...").
      const std::string text = L.string(xn);
      *at = text;
      hash_input += "\n" + path + "=" + text;
      continue;
    }
    double v = 0.0;
    if (vn.node.IsDefined()) {
      v = L.number(vn);
    } else {
      double old = 0.0;
      if (!Loader::parse_number(at->Scalar(), old) || !std::isfinite(old))
        L.fail(
            pn,
            "'" + path + "' holds '" + escape_controls(at->Scalar()) +
                "', not a number: 'scale' needs one (give the path of a number it uses, such as a "
                "parameter, or an 'expression')");
      v = old * L.number(sn);
    }
    *at = fmt::format("{}", v);  // the shortest text that reads back as v
    hash_input += "\n" + path + "=" + fmt::format("{}", v);
  }
  try {
    return std::make_shared<Scenario>(
        load_scenario_yaml(doc, scenario_text_hash(hash_input), where, LoadOptions{}));
  } catch (const ScenarioError& e) {
    L.fail(set, std::string("the perturbed plant: ") + e.what());
  }
}

void load_control(const Loader& L, const Node& root, const Node& c, Scenario& sc,
                  const std::map<std::string, Index>& coord_index) {
  L.only_keys(c, {"law", "omega", "lambda", "kappa", "rho", "epsilon", "plant", "plant_set",
                  "disturbance", "initial_offset"});
  if (sc.actuators.count() == 0) L.fail(c, "a control section needs an 'actuators:' list");
  const System& sys = *sc.system;
  auto spec = std::make_shared<ControlSpec>();
  ServoLawSettings& law = spec->law;
  const Node ln = L.child(c, "law", true);
  const std::string kind = L.string(ln);
  if (kind == "feedforward") {
    law.kind = ControlLawKind::feedforward;
  } else if (kind == "stabilized") {
    law.kind = ControlLawKind::stabilized;
  } else if (kind == "robust") {
    law.kind = ControlLawKind::robust;
  } else {
    L.fail(ln, "unknown law '" + kind + "' (expected feedforward, stabilized or robust)");
  }
  law.omega = number_at_least(L, c, "omega", law.omega, 0.0);
  law.lambda = number_at_least(L, c, "lambda", law.lambda, 0.0);
  law.kappa = number_at_least(L, c, "kappa", law.kappa, 0.0);
  law.rho = number_at_least(L, c, "rho", law.rho, 0.0);
  if (Node en = L.child(c, "epsilon", false); en.node.IsDefined()) law.epsilon = L.positive(en);
  spec->disturbance = Vec::Zero(sys.dof());
  if (Node dn = L.child(c, "disturbance", false); dn.node.IsDefined()) {
    if (!dn.node.IsMap()) L.fail(dn, "expected a mapping {coordinate: constant generalized force}");
    for (const auto& kv : dn.node) {
      const std::string cn = kv.first.as<std::string>();
      const Node g{kv.second, dn.key + "." + cn};
      auto it = coord_index.find(cn);
      if (it == coord_index.end()) L.fail(g, "no coordinate named '" + cn + "'");
      spec->disturbance(it->second) = L.number(g);
    }
  }
  spec->initial_offset = Vec::Zero(sys.rows());
  const std::vector<bool> servo = servo_row_flags(sys, sc.constraint_roles);
  if (Node on = L.child(c, "initial_offset", false); on.node.IsDefined()) {
    if (!on.node.IsMap()) L.fail(on, "expected a mapping {servo row: offset}");
    for (const auto& kv : on.node) {
      const std::string rn = kv.first.as<std::string>();
      const Node g{kv.second, on.key + "." + rn};
      const auto& rows = sys.constraint_row_names();
      const auto it = std::find(rows.begin(), rows.end(), rn);
      if (it == rows.end()) L.fail(g, "no constraint row named '" + rn + "'");
      const auto r = static_cast<std::size_t>(it - rows.begin());
      if (!servo[r]) L.fail(g, "row '" + rn + "' is not a servo row (only servo rows start off)");
      spec->initial_offset(static_cast<Index>(r)) = L.number(g);
    }
  }
  const Node pn = L.child(c, "plant", false);
  if (Node sn = L.child(c, "plant_set", false); sn.node.IsDefined()) {
    spec->plant = perturbed_plant(L, root, sn, pn.node.IsDefined() ? &pn : nullptr, sc);
    if (spec->plant->control)
      L.fail(pn, "the plant scenario must not have a control section itself");
    if (spec->plant->system->coordinate_names() != sys.coordinate_names())
      L.fail(sn, "the plant's coordinates differ from the model's (same names, same order)");
  } else if (pn.node.IsDefined()) {
    const std::filesystem::path p = sc.path.parent_path() / L.string(pn);
    std::string text;
    const YAML::Node doc = plant_document(L, pn, p, text);
    Scenario plant;
    try {
      plant = load_scenario_yaml(doc, scenario_text_hash(text), p, LoadOptions{});
    } catch (const ScenarioError& e) {
      L.fail(pn, std::string("the plant scenario: ") + e.what());
    }
    if (plant.control) L.fail(pn, "the plant scenario must not have a control section itself");
    if (plant.system->coordinate_names() != sys.coordinate_names())
      L.fail(pn, "the plant's coordinates differ from the model's (same names, same order)");
    spec->plant = std::make_shared<Scenario>(std::move(plant));
  }
  sc.control = std::move(spec);
}

}  // namespace

void load_control_sections(const Loader& L, const Node& root, Scenario& sc, System& system,
                           const std::map<std::string, Index>& coord_index) {
  if (Node a = L.child(root, "actuators", false); a.node.IsDefined())
    load_actuators(L, a, sc, system, coord_index);
  if (Node c = L.child(root, "control", false); c.node.IsDefined())
    load_control(L, root, c, sc, coord_index);
}

}  // namespace ukdyn::io_detail
