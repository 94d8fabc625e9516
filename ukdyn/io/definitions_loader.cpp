#include "ukdyn/io/definitions_loader.hpp"

#include <sstream>

#include "ukdyn/symbolic/definitions.hpp"

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
  throw ScenarioError(os.str());
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
void load_scope(const Loader& L, const Node& parent, sym::DefinitionScope& scope) {
  if (Node p = L.child(parent, "parameters", false); p.node.IsDefined()) {
    if (!p.node.IsMap()) L.fail(p, "expected a mapping name: value");
    for (const auto& kv : p.node) {
      const std::string k = kv.first.as<std::string>();
      const Node key_node{kv.first, p.key + "." + k};
      const Node v{kv.second, p.key + "." + k};
      const ex value = parse(L, scope, v);  // may use earlier parameters
      try {
        scope.parameter(k, value.subs(scope.parameter_values()));
      } catch (const sym::ExpressionError& e) {
        L.fail(key_node, e.what());
      }
    }
  }
  if (Node l = L.child(parent, "let", false); l.node.IsDefined()) {
    if (!l.node.IsMap()) L.fail(l, "expected a mapping name: expression (evaluated in order)");
    for (const auto& kv : l.node) {
      const std::string k = kv.first.as<std::string>();
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

}  // namespace

std::shared_ptr<const Subsystem> load_definitions_subsystem(
    const Loader& L, const Node& s, const std::string& name,
    const std::vector<std::string>& coordinates, double gravity) {
  L.only_keys(
      s, {"name", "type", "coordinates", "parameters", "let", "bodies", "gravity", "potential"});
  const Node cn = L.child(s, "coordinates", true);
  std::unique_ptr<sym::SubsystemDef> def;
  try {
    def = std::make_unique<sym::SubsystemDef>(name, coordinates);
  } catch (const sym::DefinitionError& e) {
    if (e.coordinate >= 0) {
      L.fail(Node{cn.node[static_cast<std::size_t>(e.coordinate)],
                  cn.key + "[" + std::to_string(e.coordinate) + "]"},
             e.what());
    }
    L.fail(cn, e.what());
  }
  load_scope(L, s, *def);
  if (Node g = L.child(s, "gravity", false); g.node.IsDefined()) {
    def->gravity = parse_list<3>(L, *def, g);
  } else {
    def->gravity = {0, 0, GiNaC::numeric(-gravity)};
    // Keep a short decimal such as 9.8 exact.
    std::ostringstream os;
    os.precision(15);
    os << gravity;
    try {
      const ex e = def->parse(os.str());
      if (std::abs(GiNaC::ex_to<GiNaC::numeric>(e.evalf()).to_double() - gravity) <=
          1e-15 * std::abs(gravity)) {
        def->gravity[2] = -e;
      }
    } catch (const sym::ExpressionError&) {
    }
  }
  if (Node p = L.child(s, "potential", false); p.node.IsDefined())
    def->extra_potential = parse(L, *def, p);
  const Node bodies = L.child(s, "bodies", true);
  if (!bodies.node.IsSequence() || bodies.node.size() == 0)
    L.fail(bodies, "expected a non-empty list of bodies");
  for (std::size_t i = 0; i < bodies.node.size(); ++i) {
    const Node b{bodies.node[i], bodies.key + "[" + std::to_string(i) + "]"};
    L.only_keys(
        b, {"name", "mass", "com", "inertia", "inertia_frame", "angular_velocity", "rotation"});
    sym::BodyDef& body = def->add_body(L.string(L.child(b, "name", true)));
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
    return sym::make_subsystem(*def);
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
  }
}

std::shared_ptr<const Constraint> load_definitions_constraint(
    const Loader& L, const Node& c, const std::string& name, bool holonomic,
    const std::vector<std::string>& system_coordinates) {
  L.only_keys(c, {"type", "name", "parameters", "let", "rows"});
  sym::ConstraintDef def(
      name,
      holonomic ? sym::ConstraintDef::Kind::holonomic : sym::ConstraintDef::Kind::nonholonomic,
      system_coordinates);
  load_scope(L, c, def);
  const Node rows = L.child(c, "rows", true);
  std::vector<Node> row_nodes;
  if (rows.node.IsMap()) {
    // rows: {x: "expr", y: "expr"} → row names <name>_x, <name>_y
    for (const auto& kv : rows.node) {
      const std::string k = kv.first.as<std::string>();
      const Node v{kv.second, rows.key + "." + k};
      if (k.empty() || k.find_first_of(", \"\n'") != std::string::npos)
        L.fail(v, "invalid row name '" + k + "'");
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
    return sym::make_constraint(def);
  } catch (const sym::DefinitionError& e) {
    if (e.row >= 0) L.fail(row_nodes[static_cast<std::size_t>(e.row)], e.what());
    L.fail(c, e.what());
  } catch (const Error& e) {
    L.fail(c, e.what());
  }
}

void check_mass_matrix(const Loader& L, const Node& s, const Subsystem& sub, const Vec& q) {
  const std::string problem = sym::mass_matrix_problem(sub, q);
  if (!problem.empty()) L.fail(s, "at initial.q, " + problem);
}

}  // namespace ukdyn::io_detail
