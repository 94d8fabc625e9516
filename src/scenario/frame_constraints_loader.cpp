#include "scenario/frame_constraints_loader.hpp"

#include <Eigen/Geometry>
#include <cmath>
#include <optional>

#include "ukdyn/symbolic/canonical.hpp"
#include "ukdyn/symbolic/expression.hpp"
#include "ukdyn/symbolic/tape_inputs.hpp"

namespace ukdyn::io_detail {

namespace {

using GiNaC::ex;
namespace sym = ukdyn::symbolic;

sym::Vec3Ex vec3(const Loader& L, const Node& n, const sym::DefinitionScope& scope) {
  if (!n.node.IsSequence() || n.node.size() != 3) L.fail(n, "expected a list of 3 expressions");
  sym::Vec3Ex v;
  for (std::size_t i = 0; i < 3; ++i)
    v[i] = parse_expression(L, scope, Node{n.node[i], n.key + "[" + std::to_string(i) + "]"});
  return v;
}

// A frame: "SUBSYSTEM.FRAME" or {frame: SUBSYSTEM.FRAME, xyz: [...], rpy: [...]}. A frame of a
// chain on the tree algorithms (with a numeric offset) comes back as `tree_end`, its pose left
// empty: the constraint is then numeric (symbolic/numeric_frame_constraint.hpp), and the chain's
// link poses are never written out as expressions.
sym::FramePose load_frame(const Loader& L, const Node& n, const sym::DefinitionScope& scope,
                          DefinitionContext& context, std::string& name,
                          const std::vector<std::string>& coordinates,
                          std::optional<sym::NumericFrameEnd>& tree_end) {
  // (Bound once: assigning a YAML::Node would overwrite the node it refers to.)
  const bool mapping = n.node.IsMap();
  if (mapping) L.only_keys(n, {"frame", "xyz", "rpy"});
  const Node ref = mapping ? L.child(n, "frame", true) : n;
  sym::OriginDef offset;
  if (mapping) {
    if (Node x = L.child(n, "xyz", false); x.node.IsDefined()) offset.xyz = vec3(L, x, scope);
    if (Node r = L.child(n, "rpy", false); r.node.IsDefined()) offset.rpy = vec3(L, r, scope);
  } else if (!n.node.IsScalar()) {
    L.fail(n, "expected a frame SUBSYSTEM.FRAME or {frame: SUBSYSTEM.FRAME, xyz: [..], rpy: [..]}");
  }
  name = L.string(ref);
  if (name != "world" && name.find('.') == std::string::npos)
    L.fail(ref,
           "expected SUBSYSTEM.FRAME (a link, body or point, e.g. left.link3) or world, got '" +
               name + "'");
  try {
    const GiNaC::exmap pv = scope.parameter_values();
    tree_end = tree_frame_end(context, name, offset, pv, coordinates);
    if (tree_end) return {};
    const sym::FramePose& f = find_frame(context, name);
    sym::OriginDef values = offset;
    for (auto& e : values.xyz) e = e.subs(pv);
    for (auto& e : values.rpy) e = e.subs(pv);
    return sym::offset_frame(f, values);
  } catch (const Error& e) {  // no such frame; a chain's kinematics that cannot be built
    L.fail(ref, std::string(e.what()) + " (frame '" + name + "')");
  } catch (const std::exception& e) {  // GiNaC: a division by zero, log(0)
    L.fail(ref, std::string("cannot evaluate: ") + e.what() + " (frame '" + name + "')");
  }
}

}  // namespace

bool is_frame_constraint(const std::string& type) {
  return type == "weld" || type == "ball" || type == "hinge" || type == "level" ||
         type == "distance";
}

namespace {

// A number of an expression of the constraint's parameters, or a failure at `at`.
double number_at(const Loader& L, const Node& at, const ex& e, const GiNaC::exmap& values,
                 const char* what) {
  const ex v = e.subs(values).evalf();
  if (!GiNaC::is_a<GiNaC::numeric>(v) || !GiNaC::ex_to<GiNaC::numeric>(v).is_real())
    L.fail(at, std::string(what) + " must be a constant");
  return GiNaC::ex_to<GiNaC::numeric>(v).to_double();
}

Eigen::Vector3d unit_at(const Loader& L, const Node& at, const sym::Vec3Ex& v,
                        const GiNaC::exmap& values, const char* what) {
  const Eigen::Vector3d u(number_at(L, at, v[0], values, what),
                          number_at(L, at, v[1], values, what),
                          number_at(L, at, v[2], values, what));
  if (!(u.norm() > 0.0) || !u.allFinite())
    L.fail(at, std::string(what) + " must be a nonzero vector");
  return u / u.norm();
}

// An axis or up direction must be constant (numbers and parameters: the rows take it as one) and
// not zero: checked, and named, at the key where it is written.
void check_nonzero(const Loader& L, const Node& at, const sym::Vec3Ex& v,
                   const GiNaC::exmap& values, const char* what) {
  Eigen::Vector3d u;
  for (int k = 0; k < 3; ++k) {
    const ex e = v[static_cast<std::size_t>(k)].subs(values).evalf();
    if (!GiNaC::is_a<GiNaC::numeric>(e) || !GiNaC::ex_to<GiNaC::numeric>(e).is_real())
      L.fail(at, std::string(what) + " must be a constant vector (numbers and parameters), got " +
                     "a function of the coordinates or t in element " + std::to_string(k));
    u(k) = GiNaC::ex_to<GiNaC::numeric>(e).to_double();
  }
  if (!(u.norm() > 0.0) || !u.allFinite())
    L.fail(at, std::string(what) + " must be a nonzero vector");
}

// A frame constraint with a frame of a chain on the tree algorithms: numeric rows
// (symbolic/numeric_frame_constraint.hpp); the other frame by its expressions (a body, the world)
// or on its tree.
std::shared_ptr<const Constraint> numeric_frame_constraint(
    const Loader& L, const Node& c, const sym::FrameConstraintDef& f, const sym::ConstraintDef& def,
    std::optional<sym::NumericFrameEnd> ta, std::optional<sym::NumericFrameEnd> tb,
    const std::vector<std::string>& system_coordinates, const Vec& q0, const Node& axis_node,
    const Node& up_node) {
  using K = sym::FrameConstraintDef::Kind;
  const GiNaC::exmap values = def.parameter_values();
  sym::NumericFrameSpec spec;
  spec.kind = f.kind;
  spec.name = f.name;
  spec.frame_a = f.frame_a;
  spec.frame_b = f.frame_b;
  if (f.kind == K::hinge) spec.axis = unit_at(L, axis_node, f.axis, values, "the hinge axis");
  if (f.kind == K::level) {
    spec.axis = unit_at(L, axis_node, f.axis, values, "the level axis");
    spec.up = unit_at(L, up_node, f.up, values, "the level up direction");
    spec.vertical = f.vertical;
  }
  auto end_of = [](std::optional<sym::NumericFrameEnd>& t, const sym::FramePose& pose) {
    if (t) return std::move(*t);
    sym::NumericFrameEnd e;
    e.kind = sym::NumericFrameEnd::Kind::expressions;
    e.pose = pose;
    return e;
  };
  sym::NumericFrameEnd a = end_of(ta, f.a);
  sym::NumericFrameEnd b = f.kind == K::level ? sym::NumericFrameEnd{} : end_of(tb, f.b);
  bool initial_length = false;
  Node ln = c;
  if (f.kind == K::distance) {
    ln = L.child(c, "length", true);
    initial_length = ln.node.IsScalar() && ln.node.Scalar() == "initial";
    spec.length = initial_length ? 1.0
                                 : number_at(L, ln, parse_expression(L, def, ln), values,
                                             "the distance length");
    if (!initial_length && !(spec.length > 0.0)) L.fail(ln, "the distance length must be positive");
  }
  try {
    auto con = sym::make_numeric_frame_constraint(spec, a, b, system_coordinates, L.symbol_table());
    if (initial_length) {  // |p_a − p_b| at initial.q: Φ = ½(d² − 1) with length 1
      Vec phi(1);
      con->position_residual({}, q0, phi);
      const double d2 = 2.0 * phi(0) + 1.0;
      if (!std::isfinite(d2) || !(d2 > 0.0))
        L.fail(ln, "the frames coincide (or are not finite) at initial.q: no positive length");
      spec.length = std::sqrt(d2);
      con = sym::make_numeric_frame_constraint(spec, std::move(a), std::move(b), system_coordinates,
                                               L.symbol_table());
    }
    return con;
  } catch (const Error& e) {
    L.fail(c, e.what());
  } catch (const std::exception& e) {  // GiNaC: a division by zero, log(0)
    L.fail(c, std::string("cannot evaluate: ") + e.what());
  }
}

}  // namespace

std::shared_ptr<const Constraint> load_frame_constraint(
    const Loader& L, const Node& c, const std::string& name, const std::string& type,
    const std::vector<std::string>& system_coordinates, DefinitionContext& context, const Vec& q0) {
  using K = sym::FrameConstraintDef::Kind;
  sym::FrameConstraintDef f;
  f.name = name;
  if (type == "weld" || type == "ball") {
    L.only_keys(c, {"type", "name", "parameters", "let", "a", "b"});
    f.kind = type == "weld" ? K::weld : K::ball;
  } else if (type == "hinge") {
    L.only_keys(c, {"type", "name", "parameters", "let", "a", "b", "axis"});
    f.kind = K::hinge;
  } else if (type == "level") {
    L.only_keys(c, {"type", "name", "parameters", "let", "a", "axis", "orientation", "up"});
    f.kind = K::level;
  } else {
    L.only_keys(c, {"type", "name", "parameters", "let", "a", "b", "length"});
    f.kind = K::distance;
  }
  sym::ConstraintDef def(name, sym::ConstraintDef::Kind::holonomic, system_coordinates,
                         L.symbol_table());
  load_parameters(L, c, def);
  const Node an = L.child(c, "a", true);
  std::optional<sym::NumericFrameEnd> ta, tb;
  f.a = load_frame(L, an, def, context, f.frame_a, system_coordinates, ta);
  const Node bn = f.kind != K::level ? L.child(c, "b", true) : an;  // (bound once, see above)
  if (f.kind != K::level) {
    f.b = load_frame(L, bn, def, context, f.frame_b, system_coordinates, tb);
    if (f.frame_a == f.frame_b && !an.node.IsMap() && !bn.node.IsMap())
      L.fail(bn, "a and b are the same frame '" + f.frame_a + "'");
  }
  const bool has_axis = f.kind == K::hinge || f.kind == K::level;
  const Node axis_node = has_axis ? L.child(c, "axis", true) : c;
  Node up_node = c;
  if (has_axis) {
    f.axis = vec3(L, axis_node, def);
    check_nonzero(L, axis_node, f.axis, def.parameter_values(),
                  f.kind == K::hinge ? "the hinge axis" : "the level axis");
  }
  if (f.kind == K::level) {
    if (Node o = L.child(c, "orientation", false); o.node.IsDefined()) {
      const std::string s = L.string(o);
      if (s == "vertical") {
        f.vertical = true;
      } else if (s != "horizontal") {
        L.fail(o, "expected horizontal or vertical, got '" + s + "'");
      }
    }
    if (Node u = L.child(c, "up", false); u.node.IsDefined()) {
      f.up = vec3(L, u, def);
      up_node = u;
      check_nonzero(L, u, f.up, def.parameter_values(), "the level up direction");
    }
  }
  if (ta || tb)
    return numeric_frame_constraint(L, c, f, def, std::move(ta), std::move(tb), system_coordinates,
                                    q0, axis_node, up_node);
  if (f.kind == K::distance) {
    const Node ln = L.child(c, "length", true);
    if (ln.node.IsScalar() && ln.node.Scalar() == "initial") {
      // |p_a − p_b| at initial.q by compiled tapes, kept as the exact value of that double.
      const sym::InputMap in =
          sym::coordinate_inputs(L.symbols(), system_coordinates, sym::InputSet::q);
      double d2 = 0.0;
      for (std::size_t k = 0; k < 3; ++k) {
        double v = 0.0;
        try {
          const sym::Tape tape({(f.a.position[k] - f.b.position[k]).expand()}, in);
          tape.eval(0.0, q0.data(), nullptr, &v);
        } catch (const Error&) {
          L.fail(ln, "the frames are not functions of q only");
        }
        d2 += v * v;
      }
      if (!std::isfinite(d2) || !(d2 > 0.0))
        L.fail(ln, "the frames coincide (or are not finite) at initial.q: no positive length");
      f.length = sym::exact_rational(std::sqrt(d2));
    } else {
      f.length = parse_expression(L, def, ln);
    }
  }
  try {
    sym::add_frame_constraint(def, f);
  } catch (const sym::DefinitionError& e) {
    L.fail(axis_node, e.what());
  }
  try {
    return sym::make_frame_constraint(def, f);
  } catch (const Error& e) {
    L.fail(c, e.what());
  } catch (const std::exception& e) {  // GiNaC: a division by zero, log(0)
    L.fail(c, std::string("cannot evaluate: ") + e.what());
  }
}

std::shared_ptr<const Constraint> make_link_constraint(
    const std::string& subsystem, const sym::LinkConstraintDef& lc,
    const std::vector<std::string>& system_coordinates, DefinitionContext& context,
    std::shared_ptr<sym::SymbolTable> symbols) {
  using K = sym::FrameConstraintDef::Kind;
  sym::FrameConstraintDef f;
  f.name = subsystem + "_" + lc.name;
  f.kind = lc.kind == sym::LinkConstraintDef::Kind::weld ? K::weld : K::ball;
  f.frame_a = subsystem + "." + lc.link_a;
  f.frame_b = subsystem + "." + lc.link_b;
  const std::string what = std::string(sym::to_string(f.kind)) + " '" + lc.name + "'";
  try {
    auto ta = tree_frame_end(context, f.frame_a, lc.offset_a, {}, system_coordinates);
    auto tb = tree_frame_end(context, f.frame_b, lc.offset_b, {}, system_coordinates);
    if (ta && tb) {  // a chain on the tree algorithms: numeric rows
      sym::NumericFrameSpec spec;
      spec.kind = f.kind;
      spec.name = f.name;
      spec.frame_a = f.frame_a;
      spec.frame_b = f.frame_b;
      return sym::make_numeric_frame_constraint(spec, std::move(*ta), std::move(*tb),
                                                system_coordinates, std::move(symbols));
    }
    f.a = sym::offset_frame(find_frame(context, f.frame_a), lc.offset_a);
    f.b = sym::offset_frame(find_frame(context, f.frame_b), lc.offset_b);
    sym::ConstraintDef def(f.name, sym::ConstraintDef::Kind::holonomic, system_coordinates,
                           std::move(symbols));
    sym::add_frame_constraint(def, f);
    return sym::make_frame_constraint(def, f);
  } catch (const Error& e) {
    throw sym::DefinitionError(what + " of subsystem '" + subsystem + "': " + e.what());
  }
}

}  // namespace ukdyn::io_detail
