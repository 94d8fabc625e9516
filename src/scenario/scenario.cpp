#include "ukdyn/scenario/scenario.hpp"

#include <yaml-cpp/depthguard.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <numbers>
#include <set>
#include <sstream>

#include "core/fnv1a.hpp"
#include "scenario/control_loader.hpp"
#include "scenario/definitions_loader.hpp"
#include "scenario/forces_loader.hpp"
#include "scenario/frame_constraints_loader.hpp"
#include "scenario/wheeled_platform_loader.hpp"
#include "scenario/yaml_loader.hpp"
#include "scenario/yaml_paths.hpp"
#include "ukdyn/paper_robot/cooperative_constraints.hpp"
#include "ukdyn/paper_robot/mobile_manipulator.hpp"
#include "ukdyn/scenario/scenario_file.hpp"
#include "ukdyn/symbolic/frame_constraints.hpp"
#include "ukdyn/symbolic/free_body.hpp"
#include "ukdyn/symbolic/wheeled_platform.hpp"

namespace ukdyn {

namespace {

using io_detail::Loader;
using io_detail::Node;

constexpr Index kMaxDof = 10'000;

MobileManipulatorParams load_mm_params(const Loader& L, const Node& n, double gravity) {
  MobileManipulatorParams p;
  p.gravity = gravity;
  if (!n.node.IsDefined()) return p;
  L.only_keys(n, {"platform_mass", "base_mass", "base_inertia", "base_length", "link_mass",
                  "link_inertia", "link_length"});
  auto nonneg = [&](const std::string& key, double fallback) {
    Node c = L.child(n, key, false);
    if (!c.node.IsDefined()) return fallback;
    const double v = L.number(c);
    if (v < 0.0) L.fail(c, "must be >= 0 (a mass, inertia or length), got " + c.node.Scalar());
    return v;
  };
  p.platform_mass = nonneg("platform_mass", p.platform_mass);
  p.base_mass = nonneg("base_mass", p.base_mass);
  p.base_inertia = nonneg("base_inertia", p.base_inertia);
  p.base_length = nonneg("base_length", p.base_length);
  for (const char* key : {"link_mass", "link_inertia", "link_length"}) {
    Node c = L.child(n, key, false);
    if (!c.node.IsDefined()) continue;
    const Vec v = L.vector(c, 3);
    for (Index i = 0; i < 3; ++i) {
      const Node e{c.node[static_cast<std::size_t>(i)], c.key + "[" + std::to_string(i) + "]"};
      if (v(i) < 0.0) L.fail(e, "must be >= 0, got " + e.node.Scalar());
      if (std::string(key) == "link_length" && v(i) == 0.0) L.fail(e, "a link length must be > 0");
    }
    std::array<double, 3>& dst = std::string(key) == "link_mass"      ? p.link_mass
                                 : std::string(key) == "link_inertia" ? p.link_inertia
                                                                      : p.link_length;
    dst = {v(0), v(1), v(2)};
  }
  if (p.platform_mass + p.base_mass + p.link_mass[0] + p.link_mass[1] + p.link_mass[2] <= 0.0) {
    L.fail(n, "the total mass is zero: the mass matrix would be singular");
  }
  return p;
}

TimeFunction load_time_function(const Loader& L, const Node& n) {
  // A bare number is a constant.
  if (n.node.IsScalar()) return TimeFunction::make_constant(L.number(n));
  if (!n.node.IsMap()) {
    L.fail(n, "expected a number or a time function {type: constant|cosine|polynomial, ...}");
  }
  const std::string type = L.string(L.child(n, "type", true));
  if (type == "constant") {
    L.only_keys(n, {"type", "value"});
    return TimeFunction::make_constant(L.number(L.child(n, "value", true)));
  }
  if (type == "cosine") {
    L.only_keys(n, {"type", "mean", "amplitude", "omega", "phase"});
    return TimeFunction::make_cosine(
        L.number_or(n, "mean", 0.0), L.number(L.child(n, "amplitude", true)),
        L.number(L.child(n, "omega", true)), L.number_or(n, "phase", 0.0));
  }
  if (type == "polynomial") {
    L.only_keys(n, {"type", "coefficients"});
    Node c = L.child(n, "coefficients", true);
    if (!c.node.IsSequence() || c.node.size() == 0 || c.node.size() > 8) {
      L.fail(c, "expected a list of 1 to 8 coefficients (c0 + c1 t + c2 t^2 + ...)");
    }
    TimeFunction f;
    f.kind = TimeFunction::Kind::polynomial;
    f.ncoeff = static_cast<int>(c.node.size());
    for (std::size_t i = 0; i < c.node.size(); ++i) {
      f.coeff[i] = L.number(Node{c.node[i], c.key + "[" + std::to_string(i) + "]"});
    }
    return f;
  }
  L.fail(L.child(n, "type", true),
         "unknown time function type '" + type + "' (expected constant, cosine or polynomial)");
}

// YAML syntax: the document, or a ScenarioError at the line and column of the problem.
// Then the size of the document with its aliases expanded, before anything walks or copies it.
YAML::Node parse_yaml(const std::string& text, const std::filesystem::path& path) {
  try {
    YAML::Node doc = YAML::Load(text);
    YAML::Mark at;
    if (const std::string why = io_detail::yaml_expansion_problem(doc, at); !why.empty()) {
      throw ScenarioError(escape_controls(path.string()) + ":" + std::to_string(at.line + 1) + ":" +
                          std::to_string(at.column + 1) + ": " + why);
    }
    return doc;
  } catch (const YAML::Exception& e) {
    std::ostringstream os;
    os << path.string() << ":" << (e.mark.line + 1) << ":" << (e.mark.column + 1)
       << ": YAML syntax error: ";
    if (dynamic_cast<const YAML::DeepRecursion*>(&e)) {
      os << "nested too deeply (more than " << static_cast<const YAML::DeepRecursion&>(e).depth()
         << " levels)";
    } else {
      for (unsigned char ch : e.msg) {  // the message may quote a byte of binary garbage
        if (ch >= 0x20 && ch < 0x7f) {
          os << ch;
        } else {
          os << "\\x"
             << "0123456789abcdef"[ch >> 4] << "0123456789abcdef"[ch & 15];
        }
      }
    }
    throw ScenarioError(os.str());
  }
}

// The format version, name and description; returns the scenario's gravity g.
double load_header(const Loader& L, const Node& root, Scenario& sc) {
  L.only_keys(root,
              {"ukdyn", "name", "description", "gravity", "subsystems", "constraints", "initial",
               "forces", "simulation", "solver", "actuators", "control", "outputs"});
  {
    Node v = L.child(root, "ukdyn", true);
    if (L.number(v) != 1.0) L.fail(v, "unsupported format version (this ukdyn reads version 1)");
  }
  {
    // Free text, but printed to terminals and written to JSON: no control characters.
    const Node nn = L.child(root, "name", true);
    sc.name = L.string(nn);
    if (sc.name.empty() || sc.name.size() > 200)
      L.fail(nn, "the name must have 1 to 200 characters");
    for (unsigned char ch : sc.name) {
      if (ch < 0x20 || ch == 0x7f) L.fail(nn, "the name must not contain control characters");
    }
  }
  if (Node d = L.child(root, "description", false); d.node.IsDefined())
    sc.description = L.string(d);
  return L.number_or(root, "gravity", 9.8);
}

// What the loading steps share: the system as it is built and the names it holds so far.
struct Loading {
  std::shared_ptr<System> system = std::make_shared<System>();
  std::map<std::string, std::pair<std::shared_ptr<const MobileManipulator>, Index>> arms;
  std::map<std::string, Index> coord_index;
  std::shared_ptr<io_detail::DefinitionContext> definition_context =
      io_detail::make_definition_context();  // serial_chain points
  Node subs;                                 // the subsystems list
  std::vector<Node> sub_nodes;  // the node of each subsystem (an instance: its template)
  // free_body subsystems: name and quaternion coordinates (their unit-norm rows come first).
  std::vector<std::pair<std::string, std::vector<std::string>>> free_bodies;
  // Wheeled platforms (docs/wheeled-platforms.md): their rolling rows come after the unit norms.
  std::vector<io_detail::LoadedPlatform> platforms;
  // Subsystems whose M(q0) is not positive definite: checked with the constraints ([M; A]).
  std::vector<std::size_t> singular_mass;
  Node init;  // the initial block
};

// A subsystem entry's `instances:` (docs/scenario-format.md, "One robot, many copies"): for each,
// its name, its coordinate prefix (default NAME_), its parameter overrides and mount. No
// `instances:`: one entry, the subsystem itself.
struct InstanceEntry {
  std::string name;
  std::string prefix;
  bool is_instance = false;
  io_detail::InstanceSpec spec;
  Node at;  // the instance's node (or the subsystem's)
};

std::vector<InstanceEntry> instance_entries(const Loader& L, const Node& s, const std::string& name,
                                            const std::string& type) {
  const Node in = L.child(s, "instances", false);
  if (!in.node.IsDefined()) return {InstanceEntry{name, "", false, {}, s}};
  if (type != "definitions" && type != "serial_chain" && !io_detail::is_wheeled_platform(type))
    L.fail(in,
           "instances are available for definitions, serial_chain, mecanum, omni and "
           "differential_drive subsystems");
  if (!in.node.IsSequence() || in.node.size() == 0)
    L.fail(in, "expected a non-empty list of {name, prefix, parameters, mount}");
  if (in.node.size() > 4096) L.fail(in, "too many instances (at most 4096)");
  std::vector<InstanceEntry> out;
  for (std::size_t j = 0; j < in.node.size(); ++j) {
    const Node e{in.node[j], in.key + "[" + std::to_string(j) + "]"};
    L.only_keys(e, {"name", "prefix", "parameters", "mount"});
    InstanceEntry ie;
    ie.is_instance = true;
    ie.at = e;
    ie.name = L.name(L.child(e, "name", true));
    ie.prefix = ie.name + "_";
    if (Node p = L.child(e, "prefix", false); p.node.IsDefined()) ie.prefix = L.string(p);
    if (Node p = L.child(e, "parameters", false); p.node.IsDefined()) {
      if (!p.node.IsMap()) L.fail(p, "expected a mapping name: value");
      for (const auto& kv : p.node) {
        const std::string k = L.key(p, kv.first);
        ie.spec.parameters[k] = Node{kv.second, p.key + "." + k};
      }
    }
    if (Node mt = L.child(e, "mount", false); mt.node.IsDefined()) {
      if (type != "serial_chain")
        L.fail(mt,
               "mount is a serial_chain key (a definitions subsystem takes its pose from "
               "parameters)");
      ie.spec.mount = mt;
    }
    out.push_back(std::move(ie));
  }
  return out;
}

// subsystems: each one built and added to the system; coordinate names unique.
void load_subsystems(const Loader& L, const Node& root, double gravity, Scenario& sc, Loading& st) {
  const std::shared_ptr<System>& system = st.system;
  auto& arms = st.arms;
  auto& coord_index = st.coord_index;
  std::set<std::string> subsystem_names;
  const auto& definition_context = st.definition_context;
  st.subs = L.child(root, "subsystems", true);
  const Node& subs = st.subs;
  if (!subs.node.IsSequence() || subs.node.size() == 0) L.fail(subs, "expected a non-empty list");
  // Each entry, or each of its instances (instance_entries).
  std::vector<std::pair<Node, InstanceEntry>> entries;
  for (std::size_t i = 0; i < subs.node.size(); ++i) {
    const Node s{subs.node[i], subs.key + "[" + std::to_string(i) + "]"};
    const std::string tname = L.name(L.child(s, "name", true));
    for (auto& e : instance_entries(L, s, tname, L.string(L.child(s, "type", true))))
      entries.emplace_back(s, std::move(e));
  }
  for (std::size_t i = 0; i < entries.size(); ++i) {
    const Node& s = entries[i].first;
    const InstanceEntry& inst = entries[i].second;
    const Node name_node = L.child(inst.at, "name", true);
    const std::string name = inst.name;
    if (subsystem_names.count(name)) L.fail(name_node, "duplicate subsystem name '" + name + "'");
    subsystem_names.insert(name);
    const Node type_node = L.child(s, "type", true);
    const std::string type = L.string(type_node);
    // Coordinate names: unique across the system, usable as CSV column names.
    std::vector<std::string> names, local;
    const bool default_names = !L.child(s, "coordinates", false).node.IsDefined();
    if (default_names && (type == "free_body" || io_detail::is_wheeled_platform(type))) {
      names = type == "free_body"  // NAME_x, ..., NAME_qz; NAME_x, NAME_y, NAME_yaw, NAME_phi1, ...
                  ? symbolic::free_body_coordinates(name)
                  : io_detail::wheeled_platform_default_coordinates(
                        L, s, type, inst.is_instance ? inst.prefix : name + "_");
      for (std::size_t j = 0; j < names.size(); ++j) {
        if (coord_index.count(names[j]))
          L.fail(name_node, "duplicate coordinate name '" + names[j] + "'");
        coord_index[names[j]] = system->dof() + static_cast<Index>(j);
      }
      local = names;
    } else {
      const Node cn = L.child(s, "coordinates", true);
      if (!cn.node.IsSequence() || cn.node.size() == 0)
        L.fail(cn, "expected a list of coordinate names");
      if (cn.node.size() > static_cast<std::size_t>(kMaxDof)) L.fail(cn, "too many coordinates");
      for (std::size_t j = 0; j < cn.node.size(); ++j) {
        const Node e{cn.node[j], cn.key + "[" + std::to_string(j) + "]"};
        local.push_back(L.name(e));
        std::string c = inst.prefix + local.back();  // an instance: its prefix (else none)
        if (inst.is_instance) (void)L.name(Node{YAML::Node(c), inst.at.key + ".prefix"});
        if (coord_index.count(c))
          L.fail(inst.is_instance ? inst.at : e, "duplicate coordinate name '" + c + "'");
        coord_index[c] = system->dof() + static_cast<Index>(j);
        names.push_back(std::move(c));
      }
    }
    const Node cn = L.child(s, "coordinates", false);
    io_detail::InstanceSpec spec = inst.spec;
    spec.local = local;
    const io_detail::InstanceSpec* ispec = inst.is_instance ? &spec : nullptr;
    std::shared_ptr<const Subsystem> sub;
    try {
      if (type == "mobile_manipulator") {
        L.only_keys(s, {"name", "type", "coordinates", "params"});
        if (names.size() != 6) {
          L.fail(cn,
                 "a mobile_manipulator has 6 coordinates [dx, dy, delta, theta1, theta2, theta3]");
        }
        auto arm = std::make_shared<MobileManipulator>(
            name, load_mm_params(L, L.child(s, "params", false), gravity), std::move(names));
        arms[name] = {arm, system->dof()};
        sub = arm;
      } else if (type == "definitions") {  // docs/definitions.md
        sub = io_detail::load_definitions_subsystem(L, s, name, names, gravity, ispec,
                                                    definition_context.get());
      } else if (type == "serial_chain") {  // docs/definitions.md
        sub =
            io_detail::load_chain_subsystem(L, s, name, names, gravity, *definition_context, ispec);
      } else if (type == "free_body") {  // docs/free-bodies.md
        st.free_bodies.push_back({name, {names[3], names[4], names[5], names[6]}});
        sub = io_detail::load_free_body_subsystem(L, s, name, names, gravity,
                                                  definition_context.get());
      } else if (io_detail::is_wheeled_platform(type)) {  // docs/wheeled-platforms.md
        st.platforms.emplace_back();
        sub = io_detail::load_wheeled_platform(L, s, type, name, names, definition_context.get(),
                                               st.platforms.back(), ispec);
      } else {
        L.fail(type_node, "unknown subsystem type '" + type +
                              "' (expected mobile_manipulator, definitions, serial_chain, "
                              "free_body, mecanum, omni or differential_drive)");
      }
    } catch (const ScenarioError&) {
      throw;
    } catch (const std::exception& e) {  // GiNaC's evaluation errors, a bound exceeded, ...
      L.fail(s, e.what());
    }
    const Index off = system->add_subsystem(sub);
    sc.subsystems.push_back({name, type, off, sub->dof()});
    st.sub_nodes.push_back(s);
  }
  if (system->dof() > kMaxDof) L.fail(subs, "too many coordinates");
}

// A list of n numbers, each a plain number (as everywhere) or an expression of numbers, pi, the
// functions of docs/definitions.md and the names of initial.parameters / let: "sqrt(0.09)".
Vec initial_vector(const Loader& L, const Node& n, Index expected,
                   const symbolic::DefinitionScope& scope) {
  if (!n.node.IsSequence())
    L.fail(n, "expected a list of " + std::to_string(expected) + " numbers");
  if (static_cast<Index>(n.node.size()) != expected) {
    L.fail(n, "expected " + std::to_string(expected) + " numbers, got " +
                  std::to_string(n.node.size()));
  }
  Vec v(expected);
  for (Index i = 0; i < expected; ++i) {
    const Node e{n.node[static_cast<std::size_t>(i)], n.key + "[" + std::to_string(i) + "]"};
    double x = 0.0;
    if (e.node.IsScalar() && Loader::parse_number(e.node.Scalar(), x)) {
      v(i) = L.number(e);  // (the finite check and its message)
      continue;
    }
    if (!e.node.IsScalar()) L.fail(e, "expected a number or an expression");
    GiNaC::ex val;
    try {
      val = io_detail::parse_expression(L, scope, e).subs(scope.parameter_values()).evalf();
    } catch (const ScenarioError&) {
      throw;
    } catch (const std::exception& ex) {  // GiNaC: 1/0, log(0)
      L.fail(e, std::string("cannot evaluate: ") + ex.what());
    }
    if (!GiNaC::is_a<GiNaC::numeric>(val) || !GiNaC::ex_to<GiNaC::numeric>(val).is_real())
      L.fail(e,
             "expected a number: the expression must evaluate to a real number (it may use "
             "numbers, pi, functions and the names of initial.parameters)");
    v(i) = GiNaC::ex_to<GiNaC::numeric>(val).to_double();
    if (!std::isfinite(v(i))) L.fail(e, "must be finite, got '" + e.node.Scalar() + "'");
  }
  return v;
}

// initial: q, qd, hold; then M(q0) positive definite for the definition-based subsystems.
// A free body's orientation is a unit quaternion (docs/free-bodies.md), and so is that of a
// chain's floating or ball joint: a zero (or non-finite) one at initial.q is named as such, before
// M(q0), singular there, would be blamed.
void check_initial_quaternions(const Loader& L, const Scenario& sc, const Loading& st) {
  std::vector<std::pair<std::string, std::vector<std::string>>> all;
  for (const auto& [fb, quat] : st.free_bodies) all.push_back({"free body '" + fb + "'", quat});
  for (const auto& info : sc.subsystems) {
    for (const auto& [joint, quat] :
         io_detail::chain_quaternions(st.definition_context.get(), info.name))
      all.push_back({"joint '" + joint + "' of chain '" + info.name + "'", quat});
  }
  for (const auto& [what, quat] : all) {
    double norm2 = 0.0;
    std::ostringstream values;
    values.precision(6);
    for (const std::string& c : quat) {
      const auto it = st.coord_index.find(c);
      if (it == st.coord_index.end()) break;  // not coordinates of the system: not checked here
      const double v = sc.q0(it->second);
      norm2 += v * v;
      values << (&c == quat.data() ? "" : ", ") << v;
    }
    if (quat.size() != 4 || (std::isfinite(norm2) && norm2 > 1e-12)) continue;
    L.fail(L.child(st.init, "q", true),
           "the orientation quaternion of " + what + " (" + quat[0] + ", " + quat[1] + ", " +
               quat[2] + ", " + quat[3] + ") is [" + values.str() +
               "] at initial.q: it must be a unit quaternion (1, 0, 0, 0 is the identity)");
  }
}

void load_initial(const Loader& L, const Node& root, Scenario& sc, Loading& st) {
  const std::shared_ptr<System>& system = st.system;
  const auto& coord_index = st.coord_index;
  const Index n = system->dof();
  st.init = L.child(root, "initial", true);
  const Node& init = st.init;
  L.only_keys(init, {"q", "qd", "hold", "parameters", "let"});
  // initial.parameters / let: names for the expressions of q and qd (docs/scenario-format.md).
  symbolic::DefinitionScope scope(L.symbol_table());
  io_detail::load_parameters(L, init, scope);
  sc.q0 = initial_vector(L, L.child(init, "q", true), n, scope);
  if (Node qd = L.child(init, "qd", false); qd.node.IsDefined()) {
    if (qd.node.IsScalar() && qd.node.Scalar() == "zeros") {
      sc.qd0 = Vec::Zero(n);
    } else {
      sc.qd0 = initial_vector(L, qd, n, scope);
    }
  } else {
    sc.qd0 = Vec::Zero(n);
  }
  sc.held.assign(static_cast<std::size_t>(n), false);
  if (Node h = L.child(init, "hold", false); h.node.IsDefined()) {
    if (!h.node.IsSequence())
      L.fail(h, "expected a list of coordinate names to hold during assembly");
    for (std::size_t i = 0; i < h.node.size(); ++i) {
      const Node e{h.node[i], h.key + "[" + std::to_string(i) + "]"};
      const std::string c = L.string(e);
      auto it = coord_index.find(c);
      if (it == coord_index.end()) L.fail(e, "no coordinate named '" + c + "'");
      sc.held[static_cast<std::size_t>(it->second)] = true;
    }
  }
  check_initial_quaternions(L, sc, st);
  for (std::size_t k = 0; k < sc.subsystems.size(); ++k) {  // M(q0) positive definite (definitions)
    const auto& info = sc.subsystems[k];
    // Singular M is allowed when the constraints fix its null directions ([M; A] of full column
    // rank, core/uk_singular.hpp): checked once the constraints are loaded (check_singular_mass).
    if (!symbolic::mass_matrix_problem(*system->subsystems()[k],
                                       sc.q0.segment(info.offset, info.dof))
             .empty())
      st.singular_mass.push_back(k);
  }
}

// A subsystem with M(q0) singular: fine if [M; A] has full column rank at q0, else the error names
// the coordinates of the undetermined direction.
void check_singular_mass(const Loader& L, Scenario& sc, Loading& st) {
  if (st.singular_mass.empty()) return;
  const System& system = *st.system;
  ForwardData d(system);
  const Vec qd = Vec::Zero(system.dof());
  evaluate_dynamics(system, d, sc.sim.t0, sc.q0, qd);
  evaluate_constraints(system, d, sc.sim.t0, sc.q0, qd);
  const std::string why = undetermined_direction(d.M, d.A, system.coordinate_names());
  if (why.empty()) return;
  const std::size_t k = st.singular_mass.front();
  const auto& info = sc.subsystems[k];
  const std::string problem =
      symbolic::mass_matrix_problem(*system.subsystems()[k], sc.q0.segment(info.offset, info.dof));
  L.fail(st.sub_nodes[k], "at initial.q, " + problem + "; " + why);
}

// A mass of t must stay >= 0 over the run (derive() checks t = 0 only).
void check_masses_of_t(const Loader& L, const Scenario& sc, const Loading& st) {
  const auto problem =
      symbolic::negative_mass_over_run(*st.system, sc.sim.t0, sc.sim.t_end, sc.sim.sample_dt);
  if (problem.message.empty()) return;
  L.fail(st.sub_nodes[problem.subsystem],
         problem.message + " (a mass of t must stay >= 0 from simulation.t0 to t_end)");
}

// Adds constraints to the system: their row names unique, each with the control role of the block
// being added.
struct ConstraintSink {
  const Loader& L;
  Scenario& sc;
  System& system;
  std::set<std::string> row_names;
  io_detail::RoleChoice role;  // of the block being added (docs/control.md)

  void add(const Node& at, std::shared_ptr<const Constraint> c) {
    for (const auto& r : c->row_names()) {
      if (!row_names.insert(r).second) L.fail(at, "duplicate constraint row name '" + r + "'");
    }
    sc.constraint_roles.push_back(io_detail::resolve_role(role, *c, sc.q0));
    system.add_constraint(std::move(c));
  }
};

// The unit-norm rows |q|² = 1 of the free bodies (docs/free-bodies.md) and of the chains' floating
// and ball joints (NAME_JOINT_unit).
void add_quaternion_norms(const Loader& L, const Scenario& sc, const Loading& st,
                          ConstraintSink& sink) {
  const System& system = *st.system;
  for (const auto& [fb, quat] : st.free_bodies) {  // free bodies: |q|² = 1 (docs/free-bodies.md)
    try {
      sink.add(st.subs, symbolic::make_constraint(symbolic::free_body_norm_constraint(
                            fb, quat, system.coordinate_names(), L.symbol_table())));
    } catch (const Error& e) {
      L.fail(st.subs, e.what());
    }
  }
  for (const auto& info : sc.subsystems) {  // floating joints of chains: NAME_JOINT_unit
    for (const auto& [joint, quat] :
         io_detail::chain_quaternions(st.definition_context.get(), info.name)) {
      try {
        sink.add(st.subs,
                 symbolic::make_constraint(symbolic::free_body_norm_constraint(
                     info.name + "_" + joint, quat, system.coordinate_names(), L.symbol_table())));
      } catch (const Error& e) {
        L.fail(st.subs, e.what());
      }
    }
  }
}

// The rolling rows of the wheeled platforms (docs/wheeled-platforms.md), nonholonomic.
void add_platform_rolling(const Loader& L, const Loading& st, ConstraintSink& sink) {
  for (const auto& p : st.platforms) {
    try {
      sink.add(p.at,
               symbolic::make_constraint(symbolic::wheeled_platform_rolling_constraint(
                   p.name, p.def, p.coordinates, st.system->coordinate_names(), L.symbol_table())));
    } catch (const ScenarioError&) {
      throw;
    } catch (const Error& e) {
      L.fail(p.at, e.what());
    }
  }
}

// The weld / connect equalities of the chains read from MJCF files.
void add_link_constraints(const Loader& L, const Scenario& sc, const Loading& st,
                          ConstraintSink& sink) {
  for (std::size_t k = 0; k < sc.subsystems.size(); ++k) {  // an MJCF file's weld / connect
    const auto& info = sc.subsystems[k];
    std::vector<std::string> coords;
    for (const auto& lc :
         io_detail::chain_link_constraints(st.definition_context.get(), info.name)) {
      if (coords.empty()) coords = st.system->coordinate_names();
      try {
        sink.add(st.sub_nodes[k],
                 io_detail::make_link_constraint(info.name, lc, coords, *st.definition_context,
                                                 L.symbol_table()));
      } catch (const Error& e) {
        L.fail(st.sub_nodes[k], e.what());
      }
    }
  }
}

// The mobile manipulator subsystem named by parent.key, and its coordinate offset.
std::pair<std::shared_ptr<const MobileManipulator>, Index> arm_ref(const Loader& L,
                                                                   const Loading& st,
                                                                   const Node& parent,
                                                                   const std::string& key) {
  const Node a = L.child(parent, key, true);
  const std::string nm = L.string(a);
  auto it = st.arms.find(nm);
  if (it == st.arms.end()) L.fail(a, "no subsystem named '" + nm + "'");
  return it->second;
}

// The system's coordinate names, in order.
std::vector<std::string> system_coordinates(const Loading& st) {
  std::vector<std::string> coords(static_cast<std::size_t>(st.system->dof()));
  for (const auto& [cn, ci] : st.coord_index) coords[static_cast<std::size_t>(ci)] = cn;
  return coords;
}

std::shared_ptr<const Constraint> closure_constraint(const Loader& L, const Node& c,
                                                     const std::string& cname, const Loading& st) {
  L.only_keys(c, {"type", "name", "left", "right", "dz", "yaw_offset", "load_pitch"});
  auto [left, lo] = arm_ref(L, st, c, "left");
  auto [right, ro] = arm_ref(L, st, c, "right");
  if (left == right) L.fail(L.child(c, "right", true), "left and right must differ");
  ClosureConstraint::Options o;
  o.prefix = cname;
  o.dz = L.number_or(c, "dz", 0.0);
  o.yaw_offset = L.number_or(c, "yaw_offset", std::numbers::pi);
  if (Node lp = L.child(c, "load_pitch", false); lp.node.IsDefined()) {
    const Vec v = L.vector(lp, 2);
    o.load_pitch1 = v(0);
    o.load_pitch2 = v(1);
  }
  return std::make_shared<ClosureConstraint>(left, lo, right, ro, o);
}

std::shared_ptr<const Constraint> cut_point_trajectory(const Loader& L, const Node& c,
                                                       const std::string& cname, const Scenario& sc,
                                                       const Loading& st) {
  L.only_keys(c, {"type", "name", "arm", "origin", "x", "y", "z"});
  auto [arm, off] = arm_ref(L, st, c, "arm");
  Vec3 origin = Vec3::Zero();
  const Node on = L.child(c, "origin", false);
  if (!on.node.IsDefined() || (on.node.IsScalar() && on.node.Scalar() == "initial")) {
    origin = arm->cut_point(sc.q0.segment(off, 6));
  } else {
    origin = L.vector(on, 3);
  }
  std::array<std::optional<TimeFunction>, 3> axes;
  const char* keys[3] = {"x", "y", "z"};
  for (std::size_t a = 0; a < 3; ++a) {
    if (Node f = L.child(c, keys[a], false); f.node.IsDefined()) axes[a] = load_time_function(L, f);
  }
  if (!axes[0] && !axes[1] && !axes[2]) L.fail(c, "give at least one of x, y, z");
  return std::make_shared<CutPointTrajectory>(arm, off, axes, origin, cname);
}

std::shared_ptr<const Constraint> coordinate_constraint(const Loader& L, const Node& c,
                                                        const std::string& cname,
                                                        const Scenario& sc, const Loading& st) {
  L.only_keys(c, {"type", "name", "coordinate", "value"});
  const Node cn = L.child(c, "coordinate", true);
  const std::string coord = L.string(cn);
  auto it = st.coord_index.find(coord);
  if (it == st.coord_index.end()) L.fail(cn, "no coordinate named '" + coord + "'");
  const Node vn = L.child(c, "value", false);
  TimeFunction f = TimeFunction::make_constant(sc.q0(it->second));
  if (vn.node.IsDefined() && !(vn.node.IsScalar() && vn.node.Scalar() == "initial")) {
    f = load_time_function(L, vn);
  }
  return std::make_shared<CoordinateConstraint>(it->second, f, cname);
}

// The constraint of an entry of constraints, by its type.
std::shared_ptr<const Constraint> listed_constraint(const Loader& L, const Node& c,
                                                    const Node& type_node, const std::string& type,
                                                    const std::string& cname, const Scenario& sc,
                                                    const Loading& st) {
  if (type == "closure") return closure_constraint(L, c, cname, st);
  if (type == "cut_point_trajectory") return cut_point_trajectory(L, c, cname, sc, st);
  if (type == "coordinate") return coordinate_constraint(L, c, cname, sc, st);
  if (type == "expression" || type == "nonholonomic") {  // docs/definitions.md
    return io_detail::load_definitions_constraint(
        L, c, cname, type == "expression", system_coordinates(st),
        io_detail::tape_pool(st.definition_context.get()));
  }
  if (io_detail::is_frame_constraint(type)) {  // docs/frame-constraints.md
    return io_detail::load_frame_constraint(L, c, cname, type, system_coordinates(st),
                                            *st.definition_context, sc.q0);
  }
  if (type == "rolling_wheels") {  // docs/wheeled-platforms.md
    return io_detail::load_rolling_wheels(L, c, cname, system_coordinates(st));
  }
  if (io_detail::is_constraint_kind(type)) {  // docs/definitions.md
    return io_detail::load_constraint_kind(L, c, cname, type, system_coordinates(st),
                                           *st.definition_context, sc.q0);
  }
  L.fail(type_node, "unknown constraint type '" + type +
                        "' (expected closure, cut_point_trajectory, coordinate, expression, "
                        "nonholonomic, points_coincide, point_trajectory, angle_relation, weld, "
                        "ball, hinge, level, distance or rolling_wheels)");
}

// constraints: each entry built, with its role, and added.
void add_listed_constraints(const Loader& L, const Node& root, const Scenario& sc,
                            const Loading& st, ConstraintSink& sink) {
  const Node cons = L.child(root, "constraints", false);
  if (!cons.node.IsDefined()) return;
  if (!cons.node.IsSequence()) L.fail(cons, "expected a list of constraints");
  for (std::size_t i = 0; i < cons.node.size(); ++i) {
    const Node c{cons.node[i], cons.key + "[" + std::to_string(i) + "]"};
    const Node type_node = L.child(c, "type", true);
    const std::string type = L.string(type_node);
    const std::string cname = L.name(L.child(c, "name", true));
    sink.role = io_detail::take_role(L, c, type);  // `role:` (removed from c) or the type's default
    try {
      sink.add(c, listed_constraint(L, c, type_node, type, cname, sc, st));
      io_detail::restore_role(c, sink.role);  // the document as written, for a plant_set plant
    } catch (const ScenarioError&) {
      throw;
    } catch (const Error& e) {
      L.fail(c, e.what());
    } catch (const std::exception& e) {  // GiNaC's evaluation errors
      L.fail(c, std::string("cannot evaluate: ") + e.what());
    }
  }
}

// constraints: each one built and added to the system; row names unique.
void load_constraints(const Loader& L, const Node& root, Scenario& sc, Loading& st) {
  ConstraintSink sink{L, sc, *st.system, {}, {}};
  add_quaternion_norms(L, sc, st, sink);
  add_platform_rolling(L, st, sink);
  add_link_constraints(L, sc, st, sink);
  add_listed_constraints(L, root, sc, st, sink);
}

// forces: tau (constant), and the state-dependent parameters / generalized / elements
// (forces_loader.cpp), added to the system as one applied force. True if there is one.
bool load_forces(const Loader& L, const Node& root, Scenario& sc, Loading& st) {
  System& system = *st.system;
  sc.tau = Vec::Zero(system.dof());
  const Node f = L.child(root, "forces", false);
  if (!f.node.IsDefined()) return false;
  L.only_keys(f, {"tau", "parameters", "generalized", "elements"});
  if (Node t = L.child(f, "tau", false); t.node.IsDefined()) sc.tau = L.vector(t, system.dof());
  std::vector<std::string> coords(static_cast<std::size_t>(system.dof()));
  for (const auto& [cn, ci] : st.coord_index) coords[static_cast<std::size_t>(ci)] = cn;
  auto force = io_detail::load_applied_forces(L, f, coords, *st.definition_context);
  if (!force) return false;
  system.add_applied_force(std::move(force));
  return true;
}

// simulation.jacobian: the Jacobian of bdf / esdirk's Newton iterations (simulate.hpp,
// JacobianKind); after the integrator.
void load_jacobian(const Loader& L, const Node& s, SimulationSettings& sim) {
  const Node jn = L.child(s, "jacobian", false);
  if (!jn.node.IsDefined()) return;
  const std::string v = L.string(jn);
  if (v == "auto") {
    sim.jacobian = JacobianKind::automatic;
  } else if (v == "exact") {
    sim.jacobian = JacobianKind::exact;
  } else if (v == "difference") {
    sim.jacobian = JacobianKind::difference;
  } else {
    L.fail(jn, "unknown jacobian '" + v + "' (expected auto, exact or difference)");
  }
  if (sim.integrator != IntegratorKind::bdf && sim.integrator != IntegratorKind::esdirk)
    L.fail(jn, "only used with integrator bdf or esdirk (the implicit integrators)");
}

// simulation: what each sample carries besides the state — the energy balance, the sigma_min
// column, the shadow run's error estimate. applied: as load_simulation().
void load_sample_options(const Loader& L, const Node& s, Scenario& sc, bool applied) {
  auto& sim = sc.sim;
  // Energy balance E − W (simulate.hpp): on by default with state-dependent forces.
  sim.energy_balance = applied;
  if (Node eb = L.child(s, "energy_balance", false); eb.node.IsDefined()) {
    const std::string v = L.string(eb);
    if (v != "true" && v != "false") L.fail(eb, "expected true or false");
    sim.energy_balance = v == "true";
  }
  // The run's global error by a shadow run at tighter settings (docs/accuracy.md).
  if (Node ee = L.child(s, "error_estimate", false); ee.node.IsDefined()) {
    const std::string v = L.string(ee);
    if (v != "shadow" && v != "none") L.fail(ee, "expected shadow or none");
    sc.error_estimate = v == "shadow";
  }
  // The sigma_min column: the solve's pivot estimate, or an SVD per sample (simulate.hpp).
  if (Node sm = L.child(s, "sigma_min", false); sm.node.IsDefined()) {
    const std::string v = L.string(sm);
    if (v != "estimate" && v != "svd") L.fail(sm, "expected estimate or svd");
    sim.sigma_min_svd = v == "svd";
  }
}

// simulation: the time span, sampling, integrator, tolerances and drift control.
// applied: the system has state-dependent applied forces (energy balance on by default).
void load_simulation(const Loader& L, const Node& root, Scenario& sc, bool applied) {
  const Node s = L.child(root, "simulation", true);
  L.only_keys(s, {"t0", "t_end", "sample_dt", "integrator", "adaptive", "abs_tol", "rel_tol",
                  "step", "initial_tolerance", "drift", "energy_balance", "sigma_min", "jacobian",
                  "error_estimate"});
  auto& sim = sc.sim;
  sim.t0 = L.number_or(s, "t0", 0.0);
  const Node te = L.child(s, "t_end", true);
  sim.t_end = L.number(te);
  if (!(sim.t_end > sim.t0)) L.fail(te, "t_end must be greater than t0");
  if (sim.t_end - sim.t0 > 1e7) L.fail(te, "duration over 1e7 s: refusing an absurd horizon");
  const Node sd = L.child(s, "sample_dt", true);
  sim.sample_dt = L.positive(sd);
  if (sim.sample_dt > sim.t_end - sim.t0) L.fail(sd, "must not exceed the duration t_end - t0");
  if ((sim.t_end - sim.t0) / sim.sample_dt > 1e7) {
    L.fail(sd, "more than 1e7 output samples: increase sample_dt");
  }
  const double t_scale = std::max(std::abs(sim.t0), std::abs(sim.t_end));  // t + dt == t below
  if (sim.sample_dt < 1e-10 * t_scale) {
    L.fail(sd, "below the time resolution at t0 (1e-10 |t0|): move t0 nearer 0");
  }
  if (Node in = L.child(s, "integrator", false); in.node.IsDefined()) {
    const std::string kind = L.string(in);
    if (kind == "dopri5") {
      sim.integrator = IntegratorKind::dopri5;
    } else if (kind == "rk4") {
      sim.integrator = IntegratorKind::rk4;
    } else if (kind == "rkf78") {
      sim.integrator = IntegratorKind::rkf78;
    } else if (kind == "bdf") {
      if (!bdf_available()) L.fail(in, "this ukdyn was built without SUNDIALS CVODE (bdf)");
      sim.integrator = IntegratorKind::bdf;
    } else if (kind == "esdirk") {
      if (!esdirk_available()) L.fail(in, "this ukdyn was built without SUNDIALS ARKODE (esdirk)");
      sim.integrator = IntegratorKind::esdirk;
    } else {
      L.fail(in, "unknown integrator '" + kind + "' (expected dopri5, rkf78, rk4, bdf or esdirk)");
    }
  }
  if (Node ad = L.child(s, "adaptive", false); ad.node.IsDefined()) {
    const std::string v = L.string(ad);
    if (v != "true" && v != "false") L.fail(ad, "expected true or false");
    sim.adaptive = v == "true";
    if (!sim.adaptive && sim.integrator == IntegratorKind::bdf)
      L.fail(ad, "the bdf integrator is always adaptive");
    if (!sim.adaptive && sim.integrator == IntegratorKind::esdirk)
      L.fail(ad, "the esdirk integrator is always adaptive");
  }
  load_jacobian(L, s, sim);
  load_sample_options(L, s, sc, applied);
  if (Node dr = L.child(s, "drift", false); dr.node.IsDefined()) {
    L.only_keys(dr, {"method", "alpha", "beta", "branch_factor", "on_branch_switch"});
    // The branch check of the projection (docs/singular-positions.md).
    if (Node bf = L.child(dr, "branch_factor", false); bf.node.IsDefined()) {
      sim.drift.branch_factor = L.number(bf);
      if (!(sim.drift.branch_factor >= 1.0 && sim.drift.branch_factor <= 1e12))
        L.fail(bf, "must lie in [1, 1e12]");
    }
    if (Node ob = L.child(dr, "on_branch_switch", false); ob.node.IsDefined()) {
      const std::string v = L.string(ob);
      if (v != "warn" && v != "stop") L.fail(ob, "expected warn or stop");
      sim.drift.stop_on_branch_switch = v == "stop";
    }
    const Node mn = L.child(dr, "method", true);
    const std::string method = L.string(mn);
    if (method == "none") {
      sim.drift.kind = DriftControl::none;
    } else if (method == "baumgarte") {
      sim.drift.kind = DriftControl::baumgarte;
    } else if (method == "projection") {
      sim.drift.kind = DriftControl::projection;
    } else {
      L.fail(mn, "unknown drift control '" + method + "' (expected none, baumgarte or projection)");
    }
    for (const char* key : {"alpha", "beta"}) {
      const Node g = L.child(dr, key, false);
      if (!g.node.IsDefined()) continue;
      if (sim.drift.kind != DriftControl::baumgarte) L.fail(g, "only used with method: baumgarte");
      const double v = L.number(g);
      if (!(v >= 0.0 && v <= 1e6)) L.fail(g, "a Baumgarte gain must lie in [0, 1e6] 1/s");
      (std::string(key) == "alpha" ? sim.drift.alpha : sim.drift.beta) = v;
    }
  }
  auto tol = [&](const char* key, double fallback) {
    const Node t = L.child(s, key, false);
    if (!t.node.IsDefined()) return fallback;
    const double v = L.number(t);
    if (!(v >= 1e-16 && v <= 1.0)) L.fail(t, "a tolerance must lie in [1e-16, 1]");
    return v;
  };
  sim.abs_tol = tol("abs_tol", sim.abs_tol);
  sim.rel_tol = tol("rel_tol", sim.rel_tol);
  if (Node st = L.child(s, "step", false); st.node.IsDefined()) {
    sim.step = L.positive(st);
    if (sim.integrator == IntegratorKind::rk4 || !sim.adaptive) {
      if ((sim.t_end - sim.t0) / sim.step > 1e9) L.fail(st, "more than 1e9 steps: increase step");
      const double ratio = sim.sample_dt / sim.step;
      if (std::abs(ratio - std::round(ratio)) > 1e-9 * ratio || std::round(ratio) < 1) {
        L.fail(st, "the fixed step must divide simulation.sample_dt");
      }
    }
    if (sim.step < 1e-10 * t_scale) {
      L.fail(st, "below the time resolution at t0 (1e-10 |t0|): move t0 nearer 0");
    }
  }
  sc.initial_tolerance = tol("initial_tolerance", sc.initial_tolerance);
}

// solver: the rank and consistency tolerances of the Udwadia-Kalaba solve.
void load_solver(const Loader& L, const Node& root, Scenario& sc) {
  // A scenario's default solve is the adaptive one (exact away from singular positions, damped
  // only near them: docs/singular-positions.md); the C++ default UkSettings{} stays exact.
  sc.sim.uk.method = UkMethod::adaptive;
  // Its damping scale: 1e-5, as UkSettings' (the band starts at σ_min/σ_max = 1e-3). Measured
  // against 1e-6 (docs/accuracy.md, "The default damping scale"): the N-four-bar N = 40 over 20 s
  // ends 1.5e-8 m from the exact motion instead of 6.7e-6 m (and the projection's largest q̇
  // correction is 6.5e-6 instead of 2.7e-4), N = 2 at half speed 3.2e-8 m instead of 3.3e-6 m;
  // Bricard, paper.yaml and n_robots_4_weld are not damped at either scale (the same results).
  constexpr double kAdaptiveRegularization = 1e-5;
  sc.sim.uk.regularization = kAdaptiveRegularization;
  if (Node s = L.child(root, "solver", false); s.node.IsDefined()) {
    L.only_keys(s, {"rank_tol", "consistency_tol", "method", "regularization"});
    // solver.method / solver.regularization: docs/singular-positions.md (added by H4).
    if (Node mt = L.child(s, "method", false); mt.node.IsDefined()) {
      const std::string method = L.string(mt);
      if (method == "regularized") {
        sc.sim.uk.method = UkMethod::regularized;
      } else if (method == "exact") {
        sc.sim.uk.method = UkMethod::exact;
      } else if (method == "adaptive") {
        sc.sim.uk.method = UkMethod::adaptive;
      } else {
        L.fail(mt,
               "unknown solver method '" + method + "' (expected adaptive, exact or regularized)");
      }
    }
    if (sc.sim.uk.method != UkMethod::adaptive)
      sc.sim.uk.regularization = UkSettings{}.regularization;
    if (Node rg = L.child(s, "regularization", false); rg.node.IsDefined()) {
      sc.sim.uk.regularization = L.number(rg);
      if (!(sc.sim.uk.regularization >= 1e-14 && sc.sim.uk.regularization <= 1e-2))
        L.fail(rg, "must lie in [1e-14, 1e-2]");
      if (sc.sim.uk.method != UkMethod::regularized && sc.sim.uk.method != UkMethod::adaptive)
        L.fail(rg, "only used with method: regularized or adaptive");
    }
    if (Node r = L.child(s, "rank_tol", false); r.node.IsDefined()) {
      sc.sim.uk.rank_rel_tol = L.number(r);
      if (!(sc.sim.uk.rank_rel_tol > 0 && sc.sim.uk.rank_rel_tol < 1))
        L.fail(r, "must lie in (0, 1)");
    }
    if (Node r = L.child(s, "consistency_tol", false); r.node.IsDefined()) {
      sc.sim.uk.consistency_rel_tol = L.number(r);
      if (!(sc.sim.uk.consistency_rel_tol > 0 && sc.sim.uk.consistency_rel_tol < 1))
        L.fail(r, "must lie in (0, 1)");
    }
  }
}

// A weld's orientation rows ½ vee(R_rel − R_relᵀ) = sin θ · u vanish at the welded pose θ = 0 and
// again at θ = 180° (a spurious root where they lose two ranks and hold no rotation across u:
// docs/frame-constraints.md, "Where the weld's orientation rows are regular"). A start with zero
// residual can sit on that root (an offset turning a frame 180° the bodies were not turned by):
// refused, the rows being regular only for θ < 90°.
void check_weld_rotations(const Loader& L, const System& system, const Vec& q0, const Node& init) {
  for (const auto& c : system.constraints()) {
    const auto* f = dynamic_cast<const symbolic::FrameConstraint*>(c.get());
    if (f == nullptr || f->wrench().kind() != symbolic::FrameConstraintDef::Kind::weld) continue;
    const symbolic::FrameWrench w = f->wrench().evaluate(q0, Vec::Zero(f->rows()));
    const double cos_theta = 0.5 * ((w.rotation_a.transpose() * w.rotation_b).trace() - 1.0);
    if (cos_theta > 0.0) continue;
    std::ostringstream os;
    os.precision(4);
    os << "weld '" << f->wrench().name() << "': at initial.q its frames '" << f->wrench().frame_a()
       << "' and '" << f->wrench().frame_b() << "' are "
       << std::acos(std::clamp(cos_theta, -1.0, 1.0)) * 180.0 / std::numbers::pi
       << " degrees apart, not welded: the weld's orientation rows are regular only below 90 "
          "degrees and vanish again at 180 (where they would hold no rotation); turn the bodies "
          "as the frames' rpy offsets say, or put the relative orientation in the offsets";
    L.fail(init, os.str());
  }
}

// The initial state must satisfy the constraints (paper, assumption 3).// The initial state must satisfy the constraints (paper, assumption 3).
void check_initial_state(const Loader& L, const Loading& st, Scenario& sc) {
  const std::shared_ptr<System>& system = st.system;
  const Node& init = st.init;
  if (system->rows() > 0) {
    Vec phi(system->rows()), phid(system->rows());
    position_residuals(*system, sc.sim.t0, sc.q0, phi);
    velocity_residuals(*system, sc.sim.t0, sc.q0, sc.qd0, phid);
    Index worst = 0;
    const double pmax = phi.cwiseAbs().maxCoeff(&worst);
    if (!(pmax <= sc.initial_tolerance)) {
      std::ostringstream os;
      os.precision(3);
      os << "initial.q violates constraint '"
         << system->constraint_row_names()[static_cast<std::size_t>(worst)] << "': residual "
         << std::scientific << phi(worst) << " > initial_tolerance " << sc.initial_tolerance;
      L.fail(init, os.str());
    }
    const double vmax = phid.cwiseAbs().maxCoeff(&worst);
    if (!(vmax <= sc.initial_tolerance)) {
      std::ostringstream os;
      os.precision(3);
      os << "initial.qd violates the velocity form of constraint '"
         << system->constraint_row_names()[static_cast<std::size_t>(worst)] << "': residual "
         << std::scientific << phid(worst) << " > initial_tolerance " << sc.initial_tolerance;
      L.fail(init, os.str());
    }
    check_weld_rotations(L, *system, sc.q0, init);
  }
}

}  // namespace

namespace {

// Scenario::coordinate_limits() (the chains' robot file limits at their subsystems' offsets, in
// sim.limits) and Scenario::notes.
void collect_limits_and_notes(Scenario& sc) {
  sc.sim.limits.assign(static_cast<std::size_t>(sc.system->dof()), CoordinateLimits{});
  for (const SubsystemInfo& info : sc.subsystems) {
    const auto lim = io_detail::chain_coordinate_limits(sc.definitions.get(), info.name);
    for (std::size_t k = 0; k < lim.size() && static_cast<Index>(k) < info.dof; ++k)
      sc.sim.limits[static_cast<std::size_t>(info.offset) + k] = lim[k];
  }
  sc.notes = io_detail::robot_file_notes(sc.definitions.get());
}

// outputs: {sensitivities: [NAME, ...]}: the numbers of the file whose sensitivities `ukdyn simulate`
// writes to sensitivities.csv (docs/derivatives.md, "Sensitivities to parameters"). Checked here for
// their form; ukdyn/run/sensitivity.hpp resolves them (requested_parameters).
void load_outputs(const Loader& L, const Node& root) {
  const Node o = L.child(root, "outputs", false);
  if (!o.node.IsDefined()) return;
  L.only_keys(o, {"sensitivities"});
  const Node s = L.child(o, "sensitivities", true);
  if (!s.node.IsSequence() || s.node.size() == 0)
    L.fail(s, "expected a non-empty list of parameters (keys of a parameters: map, or paths)");
  std::set<std::string> seen;
  for (std::size_t i = 0; i < s.node.size(); ++i) {
    const Node e{s.node[i], s.key + "[" + std::to_string(i) + "]"};
    const std::string name = L.string(e);
    if (!io_detail::parameter_name_ok(name)) L.fail(e, io_detail::kParameterNameRule);
    if (!seen.insert(name).second) L.fail(e, "parameter '" + name + "' named twice");
  }
}

Scenario load_scenario_unguarded(const YAML::Node& root_node, const std::string& hash,
                                 const std::filesystem::path& path, const LoadOptions& options) {
  // The symbols of this system's derivation: shared by every definition loaded below, held by the
  // derived blocks, freed with the system (docs/architecture.md, "Symbols").
  Loader L(path, std::make_shared<symbolic::SymbolTable>());
  Scenario sc;
  sc.path = path;
  sc.hash = hash;
  const Node root{root_node, ""};
  if (!root_node.IsMap()) {
    throw ScenarioError(escape_controls(path.string()) +
                        ": the scenario must be a YAML mapping (see docs/scenario-format.md)");
  }
  const double gravity = load_header(L, root, sc);
  Loading st;
  io_detail::set_symbolic_chains(*st.definition_context, options.symbolic_chains);
  load_subsystems(L, root, gravity, sc, st);
  sc.definitions = st.definition_context;
  load_initial(L, root, sc, st);
  load_constraints(L, root, sc, st);
  const bool applied = load_forces(L, root, sc, st);
  load_simulation(L, root, sc, applied);
  check_masses_of_t(L, sc, st);
  load_solver(L, root, sc);
  load_outputs(L, root);
  sc.system = st.system;
  io_detail::load_control_sections(L, root, sc, *st.system, st.coord_index);  // docs/control.md
  check_singular_mass(L, sc, st);
  if (options.check_initial) check_initial_state(L, st, sc);
  sc.system = st.system;
  collect_limits_and_notes(sc);
  return sc;
}

}  // namespace

Scenario load_scenario_text(const std::string& text, const std::filesystem::path& path,
                            const LoadOptions& options) {
  try {
    return load_scenario_unguarded(parse_yaml(text, path), io_detail::scenario_text_hash(text),
                                   path, options);
  } catch (const ScenarioError&) {
    throw;
  } catch (const std::exception& e) {  // a last resort: yaml-cpp or GiNaC errors not caught where
                                       // they arose still name the file and exit as bad input
    throw ScenarioError(escape_controls(path.string() + ": " + e.what()));
  }
}

YAML::Node io_detail::parse_scenario_yaml(const std::string& text,
                                          const std::filesystem::path& path) {
  return parse_yaml(text, path);
}

std::string io_detail::scenario_text_hash(const std::string& text) {
  return detail::Fnv1a64(detail::kUkdynHashBasis).add(text).hex();
}

Scenario io_detail::load_scenario_yaml(const YAML::Node& root, const std::string& hash,
                                       const std::filesystem::path& path,
                                       const LoadOptions& options) {
  try {
    return load_scenario_unguarded(root, hash, path, options);
  } catch (const ScenarioError&) {
    throw;
  } catch (const std::exception& e) {  // as load_scenario_text
    throw ScenarioError(escape_controls(path.string() + ": " + e.what()));
  }
}

Scenario load_scenario(const std::filesystem::path& path, const LoadOptions& options) {
  return load_scenario_file(path, options);  // the checks of every file ukdyn reads
}

}  // namespace ukdyn
