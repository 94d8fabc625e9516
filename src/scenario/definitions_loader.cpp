#include "scenario/definitions_loader.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <optional>
#include <sstream>

#include "ukdyn/robot_files/mjcf.hpp"
#include "ukdyn/robot_files/urdf.hpp"
#include "ukdyn/symbolic/canonical.hpp"
#include "ukdyn/symbolic/chain_tree.hpp"
#include "ukdyn/symbolic/constraint_kinds.hpp"
#include "ukdyn/symbolic/definitions.hpp"
#include "ukdyn/symbolic/free_body.hpp"
#include "ukdyn/symbolic/spline.hpp"
#include "ukdyn/symbolic/tape_inputs.hpp"

namespace ukdyn::io_detail {

namespace {

using GiNaC::ex;
namespace sym = ukdyn::symbolic;

// FILE:LINE:COL: key 'K': message, with the column moved to `offset` inside a one-line scalar.
[[noreturn]] void fail_at(const Loader& L, const Node& n, std::size_t offset,
                          const std::string& message) {
  const YAML::Mark mark = n.node.IsDefined() ? n.node.Mark() : YAML::Mark::null_mark();
  if (mark.line < 0) L.fail(n, message);
  std::ostringstream os;
  // Quoted scalars carry the tag "!"; their first character sits one column after the mark.
  const bool quoted = n.node.IsScalar() && n.node.Tag() == "!";
  const std::string text = n.node.IsScalar() ? n.node.Scalar() : std::string();
  const bool one_line = text.find('\n') == std::string::npos;
  const std::size_t col =
      static_cast<std::size_t>(mark.column) + 1 + (one_line ? offset + (quoted ? 1 : 0) : 0);
  os << L.path().string() << ":" << (mark.line + 1) << ":" << col << ": key '" << n.key
     << "': " << message;
  throw ScenarioError(escape_controls(os.str()));
}

// The text of an expression node: a string or a plain number.
std::string expr_text(const Loader& L, const Node& n) {
  if (!n.node.IsScalar())
    L.fail(n, "expected an expression (a string such as \"l1*cos(theta1)\" or a number)");
  return n.node.Scalar();
}

ex parse(const Loader& L, const sym::DefinitionScope& scope, const Node& n) {
  const std::string text = expr_text(L, n);
  try {
    return scope.parse(text);
  } catch (const sym::ExpressionError& e) {
    fail_at(L, n, e.offset, e.what());
  } catch (const std::exception& e) {
    L.fail(n, std::string("cannot evaluate: ") + e.what());
  }
}

template <std::size_t N>
std::array<ex, N> parse_list(const Loader& L, const sym::DefinitionScope& scope, const Node& n) {
  if (!n.node.IsSequence() || n.node.size() != N) {
    L.fail(n, "expected a list of " + std::to_string(N) + " expressions");
  }
  std::array<ex, N> out;
  for (std::size_t i = 0; i < N; ++i)
    out[i] = parse(L, scope, Node{n.node[i], n.key + "[" + std::to_string(i) + "]"});
  return out;
}

// A 3×3 matrix: a list of 3 rows of 3 expressions. A list of 3 expressions is a diagonal.
std::array<ex, 9> parse_matrix(const Loader& L, const sym::DefinitionScope& scope, const Node& n,
                               bool allow_diagonal) {
  std::array<ex, 9> m{0, 0, 0, 0, 0, 0, 0, 0, 0};
  if (!n.node.IsSequence() || n.node.size() != 3) {
    L.fail(n, allow_diagonal ? "expected a 3x3 matrix (3 rows of 3) or a diagonal (3 expressions)"
                             : "expected a 3x3 matrix (a list of 3 rows of 3 expressions)");
  }
  if (allow_diagonal && n.node[0].IsScalar()) {
    const auto d = parse_list<3>(L, scope, n);
    for (std::size_t i = 0; i < 3; ++i) m[4 * i] = d[i];
    return m;
  }
  for (std::size_t i = 0; i < 3; ++i) {
    const auto row =
        parse_list<3>(L, scope, Node{n.node[i], n.key + "[" + std::to_string(i) + "]"});
    for (std::size_t j = 0; j < 3; ++j) m[3 * i + j] = row[j];
  }
  return m;
}

// parameters: {name: value}, then let: {name: expression} (in order).
// `overrides` (an instance's parameters) replace the values of the parameters of the same name.
void load_scope(const Loader& L, const Node& parent, sym::DefinitionScope& scope,
                const std::map<std::string, Node>* overrides = nullptr) {
  if (Node p = L.child(parent, "parameters", false); p.node.IsDefined()) {
    if (!p.node.IsMap()) L.fail(p, "expected a mapping name: value");
    for (const auto& kv : p.node) {
      const std::string k = L.key(p, kv.first);
      const Node key_node{kv.first, p.key + "." + k};
      Node v{kv.second, p.key + "." + k};
      if (overrides) {
        if (auto it = overrides->find(k); it != overrides->end()) v = it->second;
      }
      const ex value = parse(L, scope, v);  // may use earlier parameters
      try {
        scope.parameter(k, value.subs(scope.parameter_values()));
      } catch (const sym::ExpressionError& e) {
        L.fail(key_node, e.what());
      } catch (const std::exception& e) {  // GiNaC: 1/p with p: 0, log(p) with p: 0
        L.fail(v, std::string("cannot evaluate: ") + e.what());
      }
    }
  }
  if (Node l = L.child(parent, "let", false); l.node.IsDefined()) {
    if (!l.node.IsMap()) L.fail(l, "expected a mapping name: expression (evaluated in order)");
    for (const auto& kv : l.node) {
      const std::string k = L.key(l, kv.first);
      const Node v{kv.second, l.key + "." + k};
      const ex value = parse(L, scope, v);
      try {
        scope.let(k, value);
      } catch (const sym::ExpressionError& e) {
        L.fail(Node{kv.first, l.key + "." + k}, e.what());
      }
    }
  }
}

// gravity: [gx, gy, gz] expressions, or [0, 0, -g] with the scenario's g (short decimals exact).
void load_gravity(const Loader& L, const Node& s, sym::SubsystemDef& def, double gravity) {
  if (Node g = L.child(s, "gravity", false); g.node.IsDefined()) {
    def.gravity = parse_list<3>(L, def, g);
  } else {
    def.gravity = {0, 0, sym::exact_rational(-gravity)};  // exact (canonical.hpp)
    // Keep a short decimal such as 9.8 exact.
    std::ostringstream os;
    os.precision(15);
    os << gravity;
    try {
      const ex e = def.parse(os.str());
      if (std::abs(GiNaC::ex_to<GiNaC::numeric>(e.evalf()).to_double() - gravity) <=
          1e-15 * std::abs(gravity)) {
        def.gravity[2] = -e;
      }
    } catch (const sym::ExpressionError&) {
    }
  }
}

// Constructs a subsystem definition (SubsystemDef or ChainDef), naming the coordinate at fault if
// the names are refused, then reads what every definition-based subsystem shares: parameters and
// `let` (load_scope), gravity and an extra potential.
template <typename Def>
std::unique_ptr<Def> start_definition(const Loader& L, const Node& s, const std::string& name,
                                      const std::vector<std::string>& coordinates, double gravity,
                                      const InstanceSpec* instance) {
  const Node cn = L.child(s, "coordinates", true);
  std::unique_ptr<Def> def;
  try {
    def = std::make_unique<Def>(name, coordinates, L.symbol_table());
  } catch (const sym::DefinitionError& e) {
    if (e.coordinate >= 0) {
      L.fail(Node{cn.node[static_cast<std::size_t>(e.coordinate)],
                  cn.key + "[" + std::to_string(e.coordinate) + "]"},
             e.what());
    }
    L.fail(cn, e.what());
  }
  if (instance) {
    // An instance: the template's coordinate names stand for the prefixed ones in its expressions.
    for (std::size_t i = 0; i < coordinates.size() && i < instance->local.size(); ++i) {
      try {
        def->let(instance->local[i], def->q(coordinates[i]));
        def->let(instance->local[i] + "_dot", def->qd(coordinates[i]));
      } catch (const std::exception& e) {
        L.fail(Node{cn.node[i], cn.key + "[" + std::to_string(i) + "]"}, e.what());
      }
    }
    // Every override names a parameter of the template.
    const Node p = L.child(s, "parameters", false);
    for (const auto& [k, v] : instance->parameters) {
      if (!p.node.IsDefined() || !p.node.IsMap() || !p.node[k].IsDefined())
        L.fail(v, "'" + k + "' is not a parameter of the subsystem it is an instance of");
    }
  }
  load_scope(L, s, *def, instance ? &instance->parameters : nullptr);
  load_gravity(L, s, *def, gravity);
  if (Node p = L.child(s, "potential", false); p.node.IsDefined()) {
    def->extra_potential = parse(L, *def, p);
  }
  return def;
}

}  // namespace

}  // namespace ukdyn::io_detail

// What later constraints and the replay page (geometry.cpp) need of the subsystems loaded; opaque
// outside ukdyn::io (Scenario::definitions).
struct ukdyn::LoadedDefinitions {
  std::map<std::string, symbolic::ChainModel> chains;
  symbolic::FrameTable frames;  // docs/frame-constraints.md
  /// Per chain: (parent link, child link) of every joint and (link, point) of every named point,
  /// for drawing (geometry.cpp).
  std::map<std::string, std::vector<std::pair<std::string, std::string>>> edges;
  /// Per chain: the coordinates that are lengths (the base's x, y; prismatic joints'), in order.
  std::map<std::string, std::vector<std::string>> base_coordinates, prismatic_coordinates;
  /// Per definitions subsystem: its bodies' CoMs (parameters substituted).
  std::map<std::string, std::vector<std::pair<std::string, symbolic::Vec3Ex>>> bodies;
  /// Per definitions subsystem: its bodies (parameters substituted), for their boxes on the page.
  std::map<std::string, std::vector<symbolic::BodyDef>> body_defs;
  /// Per wheeled platform: its wheels' radius and headings, for drawing them.
  std::map<std::string, io_detail::PlatformWheels> platform_wheels;
  /// Per free_body subsystem: its mass and inertia (body frame, row-major), as numbers.
  std::map<std::string, io_detail::FreeBodyInertia> free_bodies;
  /// Per free_body subsystem with a `shape:`: that shape (the replay page).
  std::map<std::string, io_detail::FreeBodyShape> free_body_shapes;
  /// Per serial chain read from a robot file: ("urdf" or "mjcf", the file), for its shapes on the
  /// replay page (read only when drawn: robot_files/visuals.hpp).
  std::map<std::string, std::pair<std::string, std::string>> robot_files;
  /// Per chain: the constraints between its links (an MJCF file's weld / connect equalities).
  std::map<std::string, std::vector<symbolic::LinkConstraintDef>> link_constraints;
  /// LoadOptions::symbolic_chains: `dynamics: auto` chains derived symbolically.
  bool symbolic_chains = false;
  /// Chains on the tree algorithms whose symbolic kinematics (a ChainModel in `chains`, their
  /// frames in `frames`) nothing has needed yet (require_chain).
  std::map<std::string, std::shared_ptr<const symbolic::ChainDef>> pending;
  /// The chains on the tree algorithms, by name (their frames' numeric constraints).
  std::map<std::string, std::shared_ptr<const tree::TreeSubsystem>> trees;
  /// Per chain with a limit: the limits of its coordinates (ChainDef::coordinate_limits).
  std::map<std::string, std::vector<CoordinateLimits>> limits;
  /// Per chain: its floating and ball joints' quaternion coordinates (ChainModel::quaternions),
  /// whether it runs on the tree algorithms or not (their unit-norm rows).
  std::map<std::string, std::vector<std::pair<std::string, std::vector<std::string>>>> quaternions;
  /// What the robot file readers noted (ChainDef::notes), each line once.
  std::vector<std::string> notes;
  /// The derived subsystems' tapes, each distinct one once: the instances of one robot share
  /// theirs (symbolic::TapePool).
  symbolic::TapePool tapes;
};

namespace ukdyn::io_detail {

symbolic::TapePool* tape_pool(DefinitionContext* context) {
  return context ? &context->tapes : nullptr;
}

}  // namespace ukdyn::io_detail

namespace ukdyn::io_detail {

void record_definition_bodies(DefinitionContext* context, const std::string& name,
                              const sym::SubsystemDef& def, const std::vector<std::string>& base) {
  if (!context) return;
  if (!base.empty()) context->base_coordinates[name] = base;
  context->frames.add_bodies(def);     // frame constraints
  auto& list = context->bodies[name];  // the bodies' CoMs, for drawing (geometry.cpp)
  const GiNaC::exmap values = def.parameter_values();
  auto& defs = context->body_defs[name];
  for (const auto& b : def.bodies) {
    list.push_back({b.name,
                    {b.com[0].subs(values).expand(), b.com[1].subs(values).expand(),
                     b.com[2].subs(values).expand()}});
    sym::BodyDef d = b;
    d.mass = b.mass.subs(values);
    for (auto& e : d.com) e = e.subs(values).expand();
    d.inertia_scalar = b.inertia_scalar.subs(values);
    for (auto& e : d.inertia_tensor) e = e.subs(values);
    if (d.rotation)
      for (auto& e : *d.rotation) e = e.subs(values).expand();
    defs.push_back(std::move(d));
  }
}

std::shared_ptr<const Subsystem> load_definitions_subsystem(
    const Loader& L, const Node& s, const std::string& name,
    const std::vector<std::string>& coordinates, double gravity, const InstanceSpec* instance,
    DefinitionContext* context) {
  L.only_keys(s, {"name", "type", "coordinates", "parameters", "let", "bodies", "gravity",
                  "potential", "instances"});
  auto def = start_definition<sym::SubsystemDef>(L, s, name, coordinates, gravity, instance);
  const Node cn = L.child(s, "coordinates", true);
  const Node bodies = L.child(s, "bodies", true);
  if (!bodies.node.IsSequence() || bodies.node.size() == 0)
    L.fail(bodies, "expected a non-empty list of bodies");
  for (std::size_t i = 0; i < bodies.node.size(); ++i) {
    const Node b{bodies.node[i], bodies.key + "[" + std::to_string(i) + "]"};
    L.only_keys(
        b, {"name", "mass", "com", "inertia", "inertia_frame", "angular_velocity", "rotation"});
    sym::BodyDef& body = def->add_body(L.label(L.child(b, "name", true)));
    body.mass = parse(L, *def, L.child(b, "mass", true));
    body.com = parse_list<3>(L, *def, L.child(b, "com", true));
    if (Node in = L.child(b, "inertia", false); in.node.IsDefined()) {
      if (in.node.IsScalar()) {
        body.inertia_kind = sym::BodyDef::InertiaKind::scalar;
        body.inertia_scalar = parse(L, *def, in);
      } else {
        body.inertia_kind = sym::BodyDef::InertiaKind::tensor;
        body.inertia_tensor = parse_matrix(L, *def, in, true);
      }
    }
    if (Node f = L.child(b, "inertia_frame", false); f.node.IsDefined()) {
      const std::string fr = L.string(f);
      if (fr == "body") {
        body.inertia_frame = sym::Frame::body;
      } else if (fr == "world") {
        body.inertia_frame = sym::Frame::world;
      } else {
        L.fail(f, "expected body or world, got '" + fr + "'");
      }
    }
    if (Node w = L.child(b, "angular_velocity", false); w.node.IsDefined()) {
      body.angular_velocity = parse_list<3>(L, *def, w);
    }
    if (Node r = L.child(b, "rotation", false); r.node.IsDefined())
      body.rotation = parse_matrix(L, *def, r, false);
  }
  try {
    auto sub = sym::make_subsystem(*def, sym::Deadline(), tape_pool(context));
    record_definition_bodies(context, name, *def);
    return sub;
  } catch (const sym::DefinitionError& e) {
    if (e.body >= 0)
      L.fail(Node{bodies.node[static_cast<std::size_t>(e.body)],
                  bodies.key + "[" + std::to_string(e.body) + "]"},
             e.what());
    if (e.coordinate >= 0) {
      L.fail(Node{cn.node[static_cast<std::size_t>(e.coordinate)],
                  cn.key + "[" + std::to_string(e.coordinate) + "]"},
             e.what());
    }
    L.fail(s, e.what());
  } catch (const Error& e) {
    L.fail(s, e.what());
  } catch (const std::exception& e) {  // GiNaC: a division by zero, log(0)
    L.fail(s, std::string("cannot evaluate: ") + e.what());
  }
}

namespace {

// The free body's mass and inertia as numbers, for drawing (geometry.cpp); not recorded if they are
// not numbers once the parameters are substituted.
void record_free_body(DefinitionContext& context, const std::string& name,
                      const sym::SubsystemDef& def, const sym::BodyDef& body) {
  const GiNaC::exmap values = def.parameter_values();
  const auto value = [&](const ex& e, double& out) {
    const ex v = e.subs(values).evalf();
    if (!GiNaC::is_a<GiNaC::numeric>(v) || !GiNaC::ex_to<GiNaC::numeric>(v).is_real()) return false;
    out = GiNaC::ex_to<GiNaC::numeric>(v).to_double();
    return true;
  };
  FreeBodyInertia fb;
  bool ok = value(body.mass, fb.mass);
  for (std::size_t k = 0; k < 9; ++k) ok = ok && value(body.inertia_tensor[k], fb.inertia[k]);
  if (ok) context.free_bodies[name] = fb;
}

// shape: {box: [lx, ly, lz]} | {sphere: r} | {cylinder: [r, h]} (docs/free-bodies.md), lengths in m.
FreeBodyShape load_free_body_shape(const Loader& L, const Node& n) {
  const char* expected = "expected one of {box: [lx, ly, lz]}, {sphere: r}, {cylinder: [r, h]}";
  if (!n.node.IsMap() || n.node.size() != 1) L.fail(n, expected);
  L.only_keys(n, {"box", "sphere", "cylinder"});
  const std::string kind = n.node.begin()->first.Scalar();
  const Node v = L.child(n, kind, true);
  const std::size_t count = kind == "box" ? 3 : kind == "cylinder" ? 2 : 1;
  std::array<double, 3> x{0, 0, 0};
  if (count == 1) {
    x[0] = L.positive(v);
  } else {
    if (!v.node.IsSequence() || v.node.size() != count)
      L.fail(v, kind == "box" ? "expected [lx, ly, lz]: the box's 3 edge lengths (m)"
                              : "expected [r, h]: the cylinder's radius and length (m)");
    for (std::size_t i = 0; i < count; ++i)
      x[i] = L.positive(Node{v.node[i], v.key + "[" + std::to_string(i) + "]"});
  }
  if (kind == "box") return {kind, x};
  if (kind == "sphere") return {kind, {2 * x[0], 2 * x[0], 2 * x[0]}};
  return {kind, {2 * x[0], 2 * x[0], x[1]}};
}

}  // namespace

std::shared_ptr<const Subsystem> load_free_body_subsystem(
    const Loader& L, const Node& s, const std::string& name,
    const std::vector<std::string>& coordinates, double gravity, DefinitionContext* context) {
  L.only_keys(s, {"name", "type", "coordinates", "parameters", "let", "mass", "inertia", "gravity",
                  "potential", "shape"});
  if (Node sh = L.child(s, "shape", false); sh.node.IsDefined()) {
    const FreeBodyShape shape = load_free_body_shape(L, sh);
    if (context != nullptr) context->free_body_shapes[name] = shape;
  }
  if (coordinates.size() != 7) {
    L.fail(
        L.child(s, "coordinates", true),
        "a free_body has 7 coordinates [x, y, z, qw, qx, qy, qz] (default NAME_x, ..., NAME_qz)");
  }
  std::unique_ptr<sym::SubsystemDef> def;
  try {
    def = std::make_unique<sym::SubsystemDef>(name, coordinates, L.symbol_table());
  } catch (const sym::DefinitionError& e) {
    L.fail(L.child(s, "coordinates", false).node.IsDefined() ? L.child(s, "coordinates", true) : s,
           e.what());
  }
  load_scope(L, s, *def);
  load_gravity(L, s, *def, gravity);
  if (Node p = L.child(s, "potential", false); p.node.IsDefined()) {
    def->extra_potential = parse(L, *def, p);
  }
  const ex mass = parse(L, *def, L.child(s, "mass", true));
  const Node in = L.child(s, "inertia", true);
  std::array<ex, 9> J{0, 0, 0, 0, 0, 0, 0, 0, 0};
  if (in.node.IsScalar()) {
    const ex j = parse(L, *def, in);
    J = {j, 0, 0, 0, j, 0, 0, 0, j};
  } else {
    J = parse_matrix(L, *def, in, true);
  }
  try {
    const sym::BodyDef& body = sym::add_free_body(*def, mass, J);
    if (context != nullptr) {
      context->frames.add_bodies(*def);  // frame constraints
      record_free_body(*context, name, *def, body);
    }
    return sym::make_subsystem(*def, sym::Deadline(), tape_pool(context));
  } catch (const sym::DefinitionError& e) {
    L.fail(e.body >= 0 ? in : s, e.what());
  } catch (const Error& e) {
    L.fail(s, e.what());
  } catch (const std::exception& e) {  // GiNaC: a division by zero, log(0)
    L.fail(s, std::string("cannot evaluate: ") + e.what());
  }
}

std::shared_ptr<const Constraint> load_definitions_constraint(
    const Loader& L, const Node& c, const std::string& name, bool holonomic,
    const std::vector<std::string>& system_coordinates, symbolic::TapePool* pool) {
  L.only_keys(c, {"type", "name", "parameters", "let", "rows"});
  sym::ConstraintDef def(
      name,
      holonomic ? sym::ConstraintDef::Kind::holonomic : sym::ConstraintDef::Kind::nonholonomic,
      system_coordinates, L.symbol_table());
  load_scope(L, c, def);
  const Node rows = L.child(c, "rows", true);
  std::vector<Node> row_nodes;
  if (rows.node.IsMap()) {
    // rows: {x: "expr", y: "expr"} → row names <name>_x, <name>_y
    for (const auto& kv : rows.node) {
      const std::string k = L.key(rows, kv.first);
      const Node v{kv.second, rows.key + "." + k};
      (void)L.name(Node{kv.first, rows.key + "." + k});  // <name>_<k> is a CSV column
      if ((name + "_" + k).size() > 64)
        L.fail(v, "the row name '" + name + "_" + k + "' is longer than 64 characters");
      def.add_row(name + "_" + k, parse(L, def, v));
      row_nodes.push_back(v);
    }
  } else if (rows.node.IsSequence()) {
    for (std::size_t i = 0; i < rows.node.size(); ++i) {
      const Node v{rows.node[i], rows.key + "[" + std::to_string(i) + "]"};
      def.add_row(rows.node.size() == 1 ? name : name + "_" + std::to_string(i + 1),
                  parse(L, def, v));
      row_nodes.push_back(v);
    }
  } else {
    L.fail(
        rows,
        holonomic
            ? "expected rows of Phi(q, t) = 0: a list of expressions or a mapping name: expression"
            : "expected rows of B(q,t) qd + c(q,t) = 0: a list of expressions or a mapping name: "
              "expression");
  }
  if (row_nodes.empty()) L.fail(rows, "a constraint needs at least one row");
  if (row_nodes.size() > system_coordinates.size() * 4 + 16)
    L.fail(rows, "too many rows for the number of coordinates");
  try {
    return sym::make_constraint(def, pool);
  } catch (const sym::DefinitionError& e) {
    if (e.row >= 0) L.fail(row_nodes[static_cast<std::size_t>(e.row)], e.what());
    L.fail(c, e.what());
  } catch (const Error& e) {
    L.fail(c, e.what());
  } catch (const std::exception& e) {  // GiNaC: a division by zero, log(0)
    L.fail(c, std::string("cannot evaluate: ") + e.what());
  }
}

// ------------------------------------------------------------------------------ serial chains

std::vector<CoordinateLimits> chain_coordinate_limits(const DefinitionContext* context,
                                                      const std::string& name) {
  if (!context) return {};
  auto it = context->limits.find(name);
  return it == context->limits.end() ? std::vector<CoordinateLimits>{} : it->second;
}

std::vector<std::string> robot_file_notes(const DefinitionContext* context) {
  return context ? context->notes : std::vector<std::string>{};
}

std::vector<std::pair<std::string, symbolic::Vec3Ex>> definitions_bodies(
    const DefinitionContext* context, const std::string& name) {
  if (!context) return {};
  auto it = context->bodies.find(name);
  return it == context->bodies.end() ? std::vector<std::pair<std::string, symbolic::Vec3Ex>>{}
                                     : it->second;
}

std::vector<symbolic::BodyDef> definitions_body_defs(const DefinitionContext* context,
                                                     const std::string& name) {
  if (!context) return {};
  auto it = context->body_defs.find(name);
  return it == context->body_defs.end() ? std::vector<symbolic::BodyDef>{} : it->second;
}

void record_platform_wheels(DefinitionContext* context, const std::string& name,
                            PlatformWheels wheels) {
  if (context) context->platform_wheels[name] = std::move(wheels);
}

std::optional<PlatformWheels> platform_wheels(const DefinitionContext* context,
                                              const std::string& name) {
  if (!context) return std::nullopt;
  auto it = context->platform_wheels.find(name);
  if (it == context->platform_wheels.end()) return std::nullopt;
  return it->second;
}

std::optional<FreeBodyInertia> free_body_inertia(const DefinitionContext* context,
                                                 const std::string& name) {
  if (!context) return std::nullopt;
  auto it = context->free_bodies.find(name);
  if (it == context->free_bodies.end()) return std::nullopt;
  return it->second;
}

std::optional<FreeBodyShape> free_body_shape(const DefinitionContext* context,
                                             const std::string& name) {
  if (!context) return std::nullopt;
  auto it = context->free_body_shapes.find(name);
  if (it == context->free_body_shapes.end()) return std::nullopt;
  return it->second;
}

std::optional<std::pair<std::string, std::string>> chain_robot_file(
    const DefinitionContext* context, const std::string& name) {
  if (!context) return std::nullopt;
  auto it = context->robot_files.find(name);
  if (it == context->robot_files.end()) return std::nullopt;
  return it->second;
}

std::vector<std::string> chain_base_coordinates(const DefinitionContext* context,
                                                const std::string& name) {
  if (!context) return {};
  auto it = context->base_coordinates.find(name);
  return it == context->base_coordinates.end() ? std::vector<std::string>{} : it->second;
}

std::vector<std::string> chain_prismatic_coordinates(const DefinitionContext* context,
                                                     const std::string& name) {
  if (!context) return {};
  auto it = context->prismatic_coordinates.find(name);
  return it == context->prismatic_coordinates.end() ? std::vector<std::string>{} : it->second;
}

const sym::ChainModel* chain_model(const DefinitionContext* context, const std::string& name) {
  if (!context) return nullptr;
  auto it = context->chains.find(name);
  return it == context->chains.end() ? nullptr : &it->second;
}

std::vector<std::pair<std::string, std::vector<std::string>>> chain_quaternions(
    const DefinitionContext* context, const std::string& name) {
  if (!context) return {};
  auto it = context->quaternions.find(name);
  return it == context->quaternions.end()
             ? std::vector<std::pair<std::string, std::vector<std::string>>>{}
             : it->second;
}

std::vector<std::pair<std::string, std::string>> chain_edges(const DefinitionContext* context,
                                                             const std::string& name) {
  if (!context) return {};
  auto it = context->edges.find(name);
  return it == context->edges.end() ? std::vector<std::pair<std::string, std::string>>{}
                                    : it->second;
}

std::shared_ptr<DefinitionContext> make_definition_context() {
  return std::make_shared<DefinitionContext>();
}

void require_chain(DefinitionContext& context, const std::string& name) {
  auto it = context.pending.find(name);
  if (it == context.pending.end()) return;
  sym::ChainModel model = sym::build_chain(*it->second);
  context.frames.add_chain(name, model, it->second.get());
  context.chains.emplace(name, std::move(model));
  context.pending.erase(it);
}

namespace {

// A number from an offset expression, or nullopt.
std::optional<double> offset_number(const ex& e, const GiNaC::exmap& values) {
  const ex v = e.subs(values).evalf();
  if (!GiNaC::is_a<GiNaC::numeric>(v) || !GiNaC::ex_to<GiNaC::numeric>(v).is_real())
    return std::nullopt;
  const double d = GiNaC::ex_to<GiNaC::numeric>(v).to_double();
  if (!std::isfinite(d)) return std::nullopt;
  return d;
}

}  // namespace

std::optional<sym::NumericFrameEnd> tree_frame_end(const DefinitionContext& context,
                                                   const std::string& name,
                                                   const sym::OriginDef& offset,
                                                   const GiNaC::exmap& values,
                                                   const std::vector<std::string>& coordinates) {
  const auto dot = name.find('.');
  if (dot == std::string::npos) return std::nullopt;
  auto it = context.trees.find(name.substr(0, dot));
  if (it == context.trees.end()) return std::nullopt;
  double o[6];
  for (int k = 0; k < 6; ++k) {
    const auto v = offset_number(k < 3 ? offset.xyz[static_cast<std::size_t>(k)]
                                       : offset.rpy[static_cast<std::size_t>(k - 3)],
                                 values);
    if (!v) return std::nullopt;
    o[k] = *v;
  }
  const tree::TreeSubsystem& t = *it->second;
  const std::string frame = name.substr(dot + 1);
  sym::NumericFrameEnd e;
  e.kind = sym::NumericFrameEnd::Kind::tree;
  e.tree = it->second;
  e.link = t.link_index(frame);
  Eigen::Vector3d base = Eigen::Vector3d::Zero();
  if (e.link == -2) {  // a named point, in its link's axes
    const auto& pts = t.model().points;
    const auto pt =
        std::find_if(pts.begin(), pts.end(), [&](const tree::Point& p) { return p.name == frame; });
    if (pt == pts.end()) {
      std::string known = t.model().root_name;
      for (const auto& l : t.model().links) {
        if (l.name.find('/') == std::string::npos) known += (known.empty() ? "" : ", ") + l.name;
      }
      for (const auto& p : pts) known += ", " + p.name;
      throw sym::DefinitionError("no frame '" + name + "' (known: " + known + ")");
    }
    e.link = pt->link;
    base = pt->xyz;
  }
  e.offset_p = base + Eigen::Vector3d(o[0], o[1], o[2]);
  e.offset_R = (Eigen::AngleAxisd(o[5], Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(o[4], Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(o[3], Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  const auto first = std::find(coordinates.begin(), coordinates.end(), t.coordinate_names()[0]);
  e.first_coordinate = static_cast<Index>(first - coordinates.begin());
  return e;
}

const sym::FramePose& find_frame(DefinitionContext& context, const std::string& name) {
  if (const auto dot = name.find('.'); dot != std::string::npos)
    require_chain(context, name.substr(0, dot));
  return context.frames.find(name);
}

void set_symbolic_chains(DefinitionContext& context, bool symbolic) {
  context.symbolic_chains = symbolic;
}

std::vector<sym::LinkConstraintDef> chain_link_constraints(const DefinitionContext* context,
                                                           const std::string& name) {
  if (!context) return {};
  auto it = context->link_constraints.find(name);
  return it == context->link_constraints.end() ? std::vector<sym::LinkConstraintDef>{} : it->second;
}

namespace {

sym::Vec3Ex parse_vec3_or(const Loader& L, const sym::DefinitionScope& scope, const Node& parent,
                          const std::string& key) {
  if (Node n = L.child(parent, key, false); n.node.IsDefined()) return parse_list<3>(L, scope, n);
  return {0, 0, 0};
}

// mass, com, inertia (3 diagonal entries or 3x3, about the CoM), inertia_rpy of a link or base.
void load_inertial(const Loader& L, const sym::DefinitionScope& scope, const Node& n,
                   sym::InertialDef& in) {
  if (Node m = L.child(n, "mass", false); m.node.IsDefined()) in.mass = parse(L, scope, m);
  in.com = parse_vec3_or(L, scope, n, "com");
  if (Node i = L.child(n, "inertia", false); i.node.IsDefined())
    in.inertia = parse_matrix(L, scope, i, true);
  in.rpy = parse_vec3_or(L, scope, n, "inertia_rpy");
}

// A coordinate named in a chain: one of its coordinates, or in an instance the template's name of
// one (→ the instance's, prefixed, coordinate).
struct ChainCoordinateNames {
  const Loader& L;
  const std::vector<std::string>& coordinates;
  const InstanceSpec* instance;

  std::string operator()(const Node& n) const {
    const std::string c = L.string(n);
    if (instance) {  // the template's name → the instance's (prefixed) coordinate
      const auto& loc = instance->local;
      const auto it = std::find(loc.begin(), loc.end(), c);
      if (it != loc.end() && static_cast<std::size_t>(it - loc.begin()) < coordinates.size())
        return coordinates[static_cast<std::size_t>(it - loc.begin())];
    }
    if (std::find(coordinates.begin(), coordinates.end(), c) == coordinates.end())
      L.fail(n, "'" + c + "' is not a coordinate of this subsystem");
    return c;
  }
};

// mount: {xyz, rpy}; an instance's mount replaces the template's.
void load_mount(const Loader& L, const Node& s, const InstanceSpec* instance, sym::ChainDef& def) {
  Node m = L.child(s, "mount", false);
  if (instance && instance->mount.node.IsDefined()) m = instance->mount;
  if (m.node.IsDefined()) {
    L.only_keys(m, {"xyz", "rpy"});
    def.mount = {parse_vec3_or(L, def, m, "xyz"), parse_vec3_or(L, def, m, "rpy")};
  }
}

// base: the omnidirectional mobile base (x, y, optional yaw) and its inertia.
void load_base(const Loader& L, const Node& s, const ChainCoordinateNames& coordinate_name,
               sym::ChainDef& def) {
  const Node b = L.child(s, "base", false);
  if (!b.node.IsDefined()) return;
  L.only_keys(b, {"type", "link", "x", "y", "yaw", "mass", "com", "inertia", "inertia_rpy"});
  if (Node t = L.child(b, "type", false); t.node.IsDefined() && L.string(t) != "omnidirectional")
    L.fail(t, "unknown base type '" + L.string(t) + "' (expected omnidirectional)");
  def.base.enabled = true;
  if (Node k = L.child(b, "link", false); k.node.IsDefined()) def.base.link = L.string(k);
  def.base.x = coordinate_name(L.child(b, "x", true));
  def.base.y = coordinate_name(L.child(b, "y", true));
  if (Node y = L.child(b, "yaw", false); y.node.IsDefined()) def.base.yaw = coordinate_name(y);
  load_inertial(L, def, b, def.base.inertial);
}

sym::JointDef::Type load_joint_type(const Loader& L, const Node& tn) {
  const std::string type = L.string(tn);
  if (type == "revolute" || type == "continuous") return sym::JointDef::Type::revolute;
  if (type == "prismatic") return sym::JointDef::Type::prismatic;
  if (type == "fixed") return sym::JointDef::Type::fixed;
  if (type == "floating")  // docs/free-bodies.md, "Floating joints"
    return sym::JointDef::Type::floating;
  if (type == "ball") return sym::JointDef::Type::ball;
  L.fail(tn, "unknown joint type '" + type +
                 "' (expected revolute, prismatic, fixed, floating or ball)");
}

// A joint's variable: coordinates (floating, ball), none (fixed), a coordinate or a value.
void load_joint_variable(const Loader& L, const Node& j,
                         const ChainCoordinateNames& coordinate_name, sym::ChainDef& def,
                         sym::JointDef& jd) {
  const Node cnode = L.child(j, "coordinate", false);
  const Node vnode = L.child(j, "value", false);
  const Node csnode = L.child(j, "coordinates", false);
  const sym::JointDef::Type jt = jd.type;
  if (jt == sym::JointDef::Type::floating || jt == sym::JointDef::Type::ball) {
    const bool fl = jt == sym::JointDef::Type::floating;
    const std::size_t nc = fl ? 7 : 4;
    const std::string what = fl ? "a floating joint takes coordinates (7: x, y, z, qw, qx, qy, qz)"
                                : "a ball joint takes coordinates (4: qw, qx, qy, qz)";
    if (cnode.node.IsDefined() || vnode.node.IsDefined())
      L.fail(j, what + ", not a coordinate or value");
    if (!csnode.node.IsDefined() || !csnode.node.IsSequence() || csnode.node.size() != nc)
      L.fail(csnode.node.IsDefined() ? csnode : j, what);
    for (std::size_t k = 0; k < nc; ++k)
      jd.coordinates.push_back(
          coordinate_name(Node{csnode.node[k], csnode.key + "[" + std::to_string(k) + "]"}));
  } else if (csnode.node.IsDefined()) {
    L.fail(csnode, "only floating and ball joints take coordinates (give coordinate)");
  } else if (jt == sym::JointDef::Type::fixed) {
    if (cnode.node.IsDefined() || vnode.node.IsDefined())
      L.fail(j, "a fixed joint has no coordinate or value");
  } else if (cnode.node.IsDefined() && vnode.node.IsDefined()) {
    L.fail(j, "give coordinate or value, not both");
  } else if (vnode.node.IsDefined()) {
    jd.value = parse(L, def, vnode);
  } else if (cnode.node.IsDefined()) {
    jd.coordinate = coordinate_name(cnode);
  } else {
    L.fail(j,
           "a movable joint needs a coordinate (or a value: an expression of the "
           "coordinates)");
  }
}

// One entry of joints: name, type, parent, link, origin, axis, its variable and its link's inertia.
void load_joint(const Loader& L, const Node& j, const ChainCoordinateNames& coordinate_name,
                sym::ChainDef& def) {
  L.only_keys(j, {"name", "type", "parent", "link", "origin", "axis", "coordinate", "value", "mass",
                  "com", "inertia", "inertia_rpy", "coordinates"});
  const std::string jname = L.label(L.child(j, "name", true));
  const sym::JointDef::Type jt = load_joint_type(L, L.child(j, "type", true));
  std::string link = jname;
  if (Node k = L.child(j, "link", false); k.node.IsDefined()) link = L.label(k);
  sym::JointDef& jd = def.add_joint(jname, jt, link);
  if (Node p = L.child(j, "parent", false); p.node.IsDefined()) jd.parent = L.string(p);
  if (Node o = L.child(j, "origin", false); o.node.IsDefined()) {
    L.only_keys(o, {"xyz", "rpy"});
    jd.origin = {parse_vec3_or(L, def, o, "xyz"), parse_vec3_or(L, def, o, "rpy")};
  }
  if (Node a = L.child(j, "axis", false); a.node.IsDefined()) jd.axis = parse_list<3>(L, def, a);
  load_joint_variable(L, j, coordinate_name, def, jd);
  load_inertial(L, def, j, jd.inertial);
}

void load_joints(const Loader& L, const Node& joints, const ChainCoordinateNames& coordinate_name,
                 sym::ChainDef& def) {
  if (!joints.node.IsSequence() || joints.node.size() == 0)
    L.fail(joints, "expected a non-empty list of joints");
  for (std::size_t i = 0; i < joints.node.size(); ++i)
    load_joint(L, Node{joints.node[i], joints.key + "[" + std::to_string(i) + "]"}, coordinate_name,
               def);
}

// The file a urdf: or mjcf: key names, relative to the scenario's folder.
std::filesystem::path model_file(const Loader& L, const Node& key) {
  std::filesystem::path file = L.string(key);
  if (file.is_relative()) file = L.path().parent_path() / file;
  return file;
}

// mjcf: a file read with MuJoCo's parser (ukdyn/robot_files/mjcf.hpp).
void load_mjcf(const Loader& L, const Node& mjcf, sym::ChainDef& def) {
  const std::filesystem::path file = model_file(L, mjcf);
  try {
    sym::append_mjcf(def, file.string());
  } catch (const sym::DefinitionError& e) {
    L.fail(mjcf, e.what());
  }
}

// urdf: a file, with floating_root and joint_values.
void load_urdf(const Loader& L, const Node& s, const Node& urdf,
               const ChainCoordinateNames& coordinate_name, sym::ChainDef& def) {
  if (Node fr = L.child(s, "floating_root", false); fr.node.IsDefined()) {
    // The URDF's root link on a floating joint (docs/free-bodies.md, "Floating joints").
    if (!fr.node.IsSequence() || fr.node.size() != 7)
      L.fail(fr, "expected a list of 7 coordinates (x, y, z, qw, qx, qy, qz)");
    if (def.base.enabled) L.fail(fr, "a floating root and a mobile base exclude each other");
    for (std::size_t k = 0; k < 7; ++k)
      def.floating_root.push_back(
          coordinate_name(Node{fr.node[k], fr.key + "[" + std::to_string(k) + "]"}));
  }
  const std::filesystem::path file = model_file(L, urdf);
  std::map<std::string, ex> values;
  if (Node jv = L.child(s, "joint_values", false); jv.node.IsDefined()) {
    if (!jv.node.IsMap()) L.fail(jv, "expected a mapping joint: coordinate or expression");
    for (const auto& kv : jv.node) {
      const std::string k = L.key(jv, kv.first);
      values[k] = parse(L, def, Node{kv.second, jv.key + "." + k});
    }
  }
  try {
    sym::append_urdf(def, file.string(), values);
  } catch (const sym::DefinitionError& e) {
    L.fail(urdf, e.what());
  }
}

// The links: joints (a list), urdf (a file) or mjcf (a file), exactly one of them.
void load_links(const Loader& L, const Node& s, const ChainCoordinateNames& coordinate_name,
                sym::ChainDef& def) {
  const Node joints = L.child(s, "joints", false);
  const Node urdf = L.child(s, "urdf", false);
  const Node mjcf = L.child(s, "mjcf", false);
  if (int(joints.node.IsDefined()) + int(urdf.node.IsDefined()) + int(mjcf.node.IsDefined()) != 1)
    L.fail(s, "give one of joints (a list), urdf (a file) or mjcf (a file)");
  if (Node fr = L.child(s, "floating_root", false); fr.node.IsDefined() && !urdf.node.IsDefined())
    L.fail(fr, "floating_root is for urdf: (in joints, give the first joint type: floating)");
  if (joints.node.IsDefined()) {
    load_joints(L, joints, coordinate_name, def);
  } else if (mjcf.node.IsDefined()) {
    load_mjcf(L, mjcf, def);
  } else {
    load_urdf(L, s, urdf, coordinate_name, def);
  }
}

// points: {name: {link, xyz}}.
void load_points(const Loader& L, const Node& s, sym::ChainDef& def) {
  const Node p = L.child(s, "points", false);
  if (!p.node.IsDefined()) return;
  if (!p.node.IsMap()) L.fail(p, "expected a mapping name: {link: LINK, xyz: [x, y, z]}");
  for (const auto& kv : p.node) {
    const std::string k = L.key(p, kv.first);
    const Node v{kv.second, p.key + "." + k};
    (void)L.name(Node{kv.first, p.key + "." + k});
    if (k.find('.') != std::string::npos)
      L.fail(Node{kv.first, p.key + "." + k}, "a point name may not hold '.' (SUBSYSTEM.POINT)");
    L.only_keys(v, {"link", "xyz"});
    def.add_point(k, L.string(L.child(v, "link", true)), parse_vec3_or(L, def, v, "xyz"));
  }
}

// What later constraints and the replay page need of a chain (DefinitionContext): its link tree,
// coordinates and link constraints; its symbolic kinematics (`model`) now, or on first use when
// it runs on the tree algorithms (pending, require_chain).
void record_chain(DefinitionContext& context, const std::string& name,
                  std::shared_ptr<const sym::ChainDef> def, std::optional<sym::ChainModel> model) {
  if (!def->link_constraints.empty()) context.link_constraints[name] = def->link_constraints;
  if (auto lim = def->coordinate_limits();
      std::any_of(lim.begin(), lim.end(), [](const CoordinateLimits& l) { return l.any(); }))
    context.limits[name] = std::move(lim);
  for (const auto& note : def->notes) {
    if (std::find(context.notes.begin(), context.notes.end(), note) == context.notes.end())
      context.notes.push_back(note);
  }
  // The link tree as build_chain resolves it (an empty parent: the previous joint's child).
  auto& edges = context.edges[name];
  std::string last = def->base.enabled ? def->base.link : def->root_link;
  for (const auto& j : def->joints) {
    edges.emplace_back(j.parent.empty() ? last : j.parent, j.link);
    last = j.link;
  }
  for (const auto& pt : def->points) edges.emplace_back(pt.link, pt.name);
  if (def->base.enabled) context.base_coordinates[name] = {def->base.x, def->base.y};
  for (const auto& j : def->joints) {  // as build_chain lists them (ChainModel::quaternions)
    if (j.type == sym::JointDef::Type::floating || j.type == sym::JointDef::Type::ball) {
      const long o = j.type == sym::JointDef::Type::floating ? 3 : 0;
      context.quaternions[name].emplace_back(
          j.name, std::vector<std::string>(j.coordinates.begin() + o, j.coordinates.end()));
    }
  }
  for (const auto& j : def->joints) {
    if (j.type == sym::JointDef::Type::prismatic && !j.coordinate.empty())
      context.prismatic_coordinates[name].push_back(j.coordinate);
  }
  if (model) {
    context.frames.add_chain(name, *model, def.get());  // frame constraints
    context.chains.emplace(name, std::move(*model));
  } else {
    context.pending.emplace(name, std::move(def));
  }
}

}  // namespace

std::shared_ptr<const Subsystem> load_chain_subsystem(const Loader& L, const Node& s,
                                                      const std::string& name,
                                                      const std::vector<std::string>& coordinates,
                                                      double gravity, DefinitionContext& context,
                                                      const InstanceSpec* instance) {
  L.only_keys(s, {"name", "type", "coordinates", "parameters", "let", "gravity", "potential",
                  "mount", "base", "joints", "urdf", "mjcf", "joint_values", "points", "instances",
                  "floating_root", "dynamics"});
  const Node dyn = L.child(s, "dynamics", false);
  const std::string dynamics = dyn.node.IsDefined() ? L.string(dyn) : "auto";
  if (dynamics != "auto" && dynamics != "tree" && dynamics != "symbolic")
    L.fail(dyn, "unknown dynamics '" + dynamics + "' (expected auto, tree or symbolic)");
  auto def = start_definition<sym::ChainDef>(L, s, name, coordinates, gravity, instance);
  load_mount(L, s, instance, *def);
  const ChainCoordinateNames coordinate_name{L, coordinates, instance};
  load_base(L, s, coordinate_name, *def);
  load_links(L, s, coordinate_name, *def);
  for (const char* format : {"urdf", "mjcf"}) {  // its shapes for the replay page
    if (Node f = L.child(s, format, false); f.node.IsDefined())
      context.robot_files[name] = {format, model_file(L, f).string()};
  }
  load_points(L, s, *def);
  try {
    // The recursive algorithms when every number is known (docs/tree-algorithms.md); the
    // symbolic kinematics (points, frames) then only when something needs them (require_chain).
    if (dynamics == "tree" || (dynamics == "auto" && !context.symbolic_chains)) {
      sym::ChainTree t = sym::chain_tree(*def);
      if (t.model) {
        auto sub = tree::make_subsystem(std::move(*t.model));
        context.trees[name] = sub;
        record_chain(context, name, std::move(def), std::nullopt);
        return sub;
      }
      if (dynamics == "tree") {
        L.fail(dyn, "the tree algorithms cannot take this chain: " + t.reason +
                        " (use dynamics: auto or symbolic)");
      }
    }
    const sym::Deadline deadline;  // one budget for the chain and its dynamics
    sym::ChainModel model = sym::build_chain(*def, deadline);
    auto sub = sym::make_subsystem(model.def, deadline, &context.tapes);
    record_chain(context, name, std::move(def), std::move(model));
    return sub;
  } catch (const sym::DerivationTimeout& e) {
    // The recursive algorithms need no derivation: say so when they can take this chain.
    const bool tree = [&] {
      try {
        return def && dynamics == "symbolic" && static_cast<bool>(sym::chain_tree(*def).model);
      } catch (const std::exception&) {
        return false;
      }
    }();
    L.fail(s, "subsystem '" + name + "': " + e.what() +
                  (tree ? "; the tree algorithms can take this chain without deriving it: "
                          "use dynamics: tree (or auto, the default)"
                        : ""));
  } catch (const Error& e) {
    L.fail(s, e.what());
  } catch (const std::exception& e) {  // GiNaC: a division by zero, log(0)
    L.fail(s, std::string("cannot evaluate: ") + e.what());
  }
}

// ------------------------------------------------------------------------------ constraint kinds

bool is_constraint_kind(const std::string& type) {
  return type == "points_coincide" || type == "point_trajectory" || type == "angle_relation";
}

namespace {

// A point: "subsystem.point" (a serial chain's named point) or [x, y, z] expressions.
sym::Vec3Ex load_point(const Loader& L, const Node& n, const sym::DefinitionScope& scope,
                       DefinitionContext& context) {
  if (n.node.IsSequence()) return parse_list<3>(L, scope, n);
  const std::string ref = L.string(n);
  const auto dot = ref.find('.');
  if (dot == std::string::npos)
    L.fail(n, "expected SUBSYSTEM.POINT (e.g. left.end) or a list of 3 expressions");
  const std::string sub = ref.substr(0, dot), point = ref.substr(dot + 1);
  try {
    require_chain(context, sub);  // a chain on the tree algorithms: its symbolic kinematics now
  } catch (const Error& e) {
    L.fail(n, "the kinematics of chain '" + sub + "' for this point: " + e.what());
  } catch (const std::exception& e) {  // GiNaC: a division by zero, log(0)
    L.fail(n, std::string("cannot evaluate: ") + e.what());
  }
  auto it = context.chains.find(sub);
  if (it == context.chains.end())
    L.fail(n, "no serial_chain subsystem named '" + sub + "' (defined before this constraint)");
  try {
    return it->second.world_point(point);
  } catch (const Error& e) {
    L.fail(n, e.what());
  } catch (const std::exception& e) {  // GiNaC: a division by zero, log(0)
    L.fail(n, std::string("cannot evaluate: ") + e.what());
  }
}

// A time function: an expression of t (or a number), or {type: constant|cosine|polynomial, ...}
// whose fields are expressions (omega: pi is exact).
ex load_time_expression(const Loader& L, const Node& n, const sym::DefinitionScope& scope) {
  if (n.node.IsScalar()) return parse(L, scope, n);
  if (!n.node.IsMap()) {
    L.fail(n,
           "expected an expression of t or a time function {type: constant|cosine|polynomial|"
           "spline, ...}");
  }
  const Node tn = L.child(n, "type", true);
  const std::string type = L.string(tn);
  auto field = [&](const char* key, bool required) -> ex {
    const Node f = L.child(n, key, required);
    return f.node.IsDefined() ? parse(L, scope, f) : ex(0);
  };
  if (type == "constant") {
    L.only_keys(n, {"type", "value"});
    return field("value", true);
  }
  if (type == "cosine") {
    L.only_keys(n, {"type", "mean", "amplitude", "omega", "phase"});
    return sym::cosine_expression(field("mean", false), field("amplitude", true),
                                  field("omega", true), field("phase", false),
                                  sym::time_symbol(scope.symbols()));
  }
  if (type == "polynomial") {
    L.only_keys(n, {"type", "coefficients"});
    const Node c = L.child(n, "coefficients", true);
    if (!c.node.IsSequence() || c.node.size() == 0 || c.node.size() > 16)
      L.fail(c, "expected a list of 1 to 16 coefficients (c0 + c1 t + c2 t^2 + ...)");
    std::vector<ex> cs;
    for (std::size_t i = 0; i < c.node.size(); ++i)
      cs.push_back(parse(L, scope, Node{c.node[i], c.key + "[" + std::to_string(i) + "]"}));
    return sym::polynomial_expression(cs, sym::time_symbol(scope.symbols()));
  }
  if (type == "spline") {
    L.only_keys(n, {"type", "times", "values", "end", "slopes"});
    auto numbers = [&](const Node& list, std::size_t expected) {
      if (!list.node.IsSequence() || list.node.size() < 2 ||
          (expected > 0 && list.node.size() != expected)) {
        L.fail(list, expected > 0 ? "expected a list of " + std::to_string(expected) + " numbers"
                                  : "expected a list of at least 2 numbers");
      }
      std::vector<double> v;
      for (std::size_t i = 0; i < list.node.size(); ++i) {
        const Node e{list.node[i], list.key + "[" + std::to_string(i) + "]"};
        const ex x = parse(L, scope, e).subs(scope.parameter_values()).evalf();
        if (!GiNaC::is_a<GiNaC::numeric>(x) || !GiNaC::ex_to<GiNaC::numeric>(x).is_real())
          L.fail(e, "expected a number");
        v.push_back(GiNaC::ex_to<GiNaC::numeric>(x).to_double());
      }
      return v;
    };
    const Node tn2 = L.child(n, "times", true);
    const std::vector<double> times = numbers(tn2, 0);
    const std::vector<double> values = numbers(L.child(n, "values", true), times.size());
    sym::CubicSpline::End end = sym::CubicSpline::End::natural;
    if (Node e = L.child(n, "end", false); e.node.IsDefined()) {
      const std::string es = L.string(e);
      if (es == "clamped") {
        end = sym::CubicSpline::End::clamped;
      } else if (es != "natural") {
        L.fail(e, "expected natural or clamped, got '" + es + "'");
      }
    }
    std::vector<double> slopes{0.0, 0.0};
    if (Node sl = L.child(n, "slopes", false); sl.node.IsDefined()) {
      if (end != sym::CubicSpline::End::clamped) L.fail(sl, "slopes are for end: clamped");
      slopes = numbers(sl, 2);
    }
    try {
      return sym::spline_expression(sym::CubicSpline(times, values, end, slopes[0], slopes[1]),
                                    sym::time_symbol(scope.symbols()));
    } catch (const Error& e) {
      L.fail(tn2, e.what());
    } catch (const std::exception& e) {  // GiNaC: a division by zero, log(0)
      L.fail(tn2, std::string("cannot evaluate: ") + e.what());
    }
  }
  L.fail(tn, "unknown time function type '" + type +
                 "' (expected constant, cosine, polynomial or spline)");
}

}  // namespace

std::shared_ptr<const Constraint> load_constraint_kind(
    const Loader& L, const Node& c, const std::string& name, const std::string& type,
    const std::vector<std::string>& system_coordinates, DefinitionContext& context, const Vec& q0) {
  sym::ConstraintDef def(name, sym::ConstraintDef::Kind::holonomic, system_coordinates,
                         L.symbol_table());
  static const char* const kAxis[3] = {"x", "y", "z"};
  if (type == "points_coincide") {
    L.only_keys(c, {"type", "name", "parameters", "let", "a", "b", "axes"});
    load_scope(L, c, def);
    const sym::Vec3Ex a = load_point(L, L.child(c, "a", true), def, context);
    const sym::Vec3Ex b = load_point(L, L.child(c, "b", true), def, context);
    std::array<bool, 3> axes{true, true, true};
    if (Node an = L.child(c, "axes", false); an.node.IsDefined()) {
      if (!an.node.IsSequence() || an.node.size() == 0)
        L.fail(an, "expected a list of axes (x, y, z)");
      axes = {false, false, false};
      for (std::size_t i = 0; i < an.node.size(); ++i) {
        const Node e{an.node[i], an.key + "[" + std::to_string(i) + "]"};
        const std::string ax = L.string(e);
        const auto k = ax == "x" ? 0 : ax == "y" ? 1 : ax == "z" ? 2 : 3;
        if (k == 3) L.fail(e, "expected x, y or z, got '" + ax + "'");
        if (axes[static_cast<std::size_t>(k)]) L.fail(e, "axis '" + ax + "' given twice");
        axes[static_cast<std::size_t>(k)] = true;
      }
    }
    sym::add_points_coincide(def, name, a, b, axes);
  } else if (type == "point_trajectory") {
    L.only_keys(c, {"type", "name", "parameters", "let", "point", "origin", "x", "y", "z"});
    load_scope(L, c, def);
    const sym::Vec3Ex p = load_point(L, L.child(c, "point", true), def, context);
    sym::Vec3Ex origin{0, 0, 0};
    if (Node o = L.child(c, "origin", false); o.node.IsDefined()) {
      if (o.node.IsScalar() && o.node.Scalar() == "initial") {
        // p(q0) by a compiled tape (GiNaC's float evaluation would sum in its process-dependent
        // term order), kept as the exact value of that double.
        const sym::InputMap in =
            sym::coordinate_inputs(def.symbols(), system_coordinates, sym::InputSet::q);
        for (std::size_t k = 0; k < 3; ++k) {
          double v = 0.0;
          try {
            const sym::Tape tape({p[k].subs(def.parameter_values()).expand()}, in);
            tape.eval(0.0, q0.data(), nullptr, &v);
          } catch (const Error&) {
            L.fail(o, "the point is not a function of q only");
          }
          if (!std::isfinite(v)) L.fail(o, "the point is not finite at initial.q");
          origin[k] = sym::exact_rational(v);
        }
      } else {
        origin = parse_list<3>(L, def, o);
      }
    }
    std::array<std::optional<ex>, 3> f;
    for (std::size_t k = 0; k < 3; ++k) {
      if (Node fn = L.child(c, kAxis[k], false); fn.node.IsDefined())
        f[k] = load_time_expression(L, fn, def);
    }
    if (!f[0] && !f[1] && !f[2]) L.fail(c, "give at least one of x, y, z");
    sym::add_point_trajectory(def, name, p, f, origin);
  } else {  // angle_relation
    L.only_keys(c, {"type", "name", "parameters", "let", "terms", "value"});
    load_scope(L, c, def);
    const Node tn = L.child(c, "terms", true);
    if (!tn.node.IsMap() || tn.node.size() == 0)
      L.fail(tn, "expected a mapping coordinate: coefficient (e.g. {delta1: 1, delta2: -1})");
    std::vector<std::pair<std::string, ex>> terms;
    for (const auto& kv : tn.node) {
      const std::string k = L.key(tn, kv.first);
      const Node v{kv.second, tn.key + "." + k};
      if (std::find(system_coordinates.begin(), system_coordinates.end(), k) ==
          system_coordinates.end())
        L.fail(v, "no coordinate named '" + k + "'");
      terms.emplace_back(k, parse(L, def, v));
    }
    ex value = 0;
    if (Node v = L.child(c, "value", false); v.node.IsDefined())
      value = load_time_expression(L, v, def);
    try {
      sym::add_angle_relation(def, name, terms, value);
    } catch (const sym::DefinitionError& e) {
      L.fail(tn, e.what());
    }
  }
  try {
    return sym::make_constraint(def);
  } catch (const Error& e) {
    L.fail(c, e.what());
  } catch (const std::exception& e) {  // GiNaC: a division by zero, log(0)
    L.fail(c, std::string("cannot evaluate: ") + e.what());
  }
}

void check_mass_matrix(const Loader& L, const Node& s, const Subsystem& sub, const Vec& q) {
  const std::string problem = sym::mass_matrix_problem(sub, q);
  if (!problem.empty()) L.fail(s, "at initial.q, " + problem);
}

ex parse_expression(const Loader& L, const sym::DefinitionScope& scope, const Node& n) {
  return parse(L, scope, n);
}

void load_parameters(const Loader& L, const Node& parent, sym::DefinitionScope& scope) {
  load_scope(L, parent, scope);
}

sym::Vec3Ex load_point_expression(const Loader& L, const Node& n, const sym::DefinitionScope& scope,
                                  DefinitionContext& context) {
  return load_point(L, n, scope, context);
}

ex load_time_function_expression(const Loader& L, const Node& n,
                                 const sym::DefinitionScope& scope) {
  return load_time_expression(L, n, scope);
}

}  // namespace ukdyn::io_detail
