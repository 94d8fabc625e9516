#include "scenario/forces_loader.hpp"

#include <algorithm>

#include "ukdyn/symbolic/forces.hpp"

namespace ukdyn::io_detail {

namespace sym = ukdyn::symbolic;

std::shared_ptr<const AppliedForce> load_applied_forces(
    const Loader& L, const Node& forces, const std::vector<std::string>& system_coordinates,
    DefinitionContext& context) {
  const Node gen = L.child(forces, "generalized", false);
  const Node els = L.child(forces, "elements", false);
  if (!gen.node.IsDefined() && !els.node.IsDefined()) {
    if (Node p = L.child(forces, "parameters", false); p.node.IsDefined())
      L.fail(p, "parameters are only used by forces.generalized and forces.elements");
    return nullptr;
  }
  sym::ForceDef def(system_coordinates, "forces", L.symbol_table());
  load_parameters(L, forces, def);
  auto coordinate = [&](const Node& parent, const std::string& key) {
    const Node c = L.child(parent, key, true);
    const std::string name = L.string(c);
    if (std::find(system_coordinates.begin(), system_coordinates.end(), name) ==
        system_coordinates.end())
      L.fail(c, "no coordinate named '" + name + "'");
    return name;
  };
  if (gen.node.IsDefined()) {
    if (!gen.node.IsMap() || gen.node.size() == 0)
      L.fail(gen, "expected a mapping coordinate: expression of t, q and q_dot");
    for (const auto& kv : gen.node) {
      const std::string c = kv.first.as<std::string>();
      const Node key{kv.first, gen.key + "." + c};
      const Node v{kv.second, gen.key + "." + c};
      if (std::find(system_coordinates.begin(), system_coordinates.end(), c) ==
          system_coordinates.end())
        L.fail(key, "no coordinate named '" + c + "'");
      try {
        def.add_generalized(c, parse_expression(L, def, v));
      } catch (const ScenarioError&) {
        throw;
      } catch (const Error& e) {
        L.fail(v, e.what());
      }
    }
  }
  if (els.node.IsDefined()) {
    if (!els.node.IsSequence()) L.fail(els, "expected a list of force elements");
    std::vector<std::string> names;
    for (std::size_t i = 0; i < els.node.size(); ++i) {
      const Node e{els.node[i], els.key + "[" + std::to_string(i) + "]"};
      if (!e.node.IsMap()) L.fail(e, "expected a force element {type: ..., name: ...}");
      const Node tn = L.child(e, "type", true);
      const std::string type = L.string(tn);
      const Node nn = L.child(e, "name", true);
      const std::string name = L.name(nn);
      if (std::find(names.begin(), names.end(), name) != names.end())
        L.fail(nn, "duplicate force element name '" + name + "'");
      names.push_back(name);
      auto expr = [&](const char* key, const char* fallback) -> GiNaC::ex {
        const Node f = L.child(e, key, fallback == nullptr);
        if (!f.node.IsDefined()) return def.parse(fallback);
        return parse_expression(L, def, f);
      };
      try {
        if (type == "spring_damper") {
          L.only_keys(e, {"type", "name", "a", "b", "stiffness", "damping", "rest_length"});
          const sym::Vec3Ex a = load_point_expression(L, L.child(e, "a", true), def, context);
          const sym::Vec3Ex b = load_point_expression(L, L.child(e, "b", true), def, context);
          def.add_spring_damper(name, a, b, expr("stiffness", "0"), expr("damping", "0"),
                                expr("rest_length", "0"));
        } else if (type == "joint_friction") {
          L.only_keys(e, {"type", "name", "coordinate", "viscous", "coulomb", "velocity_scale"});
          const std::string c = coordinate(e, "coordinate");
          def.add_joint_friction(name, c, expr("viscous", "0"), expr("coulomb", "0"),
                                 expr("velocity_scale", "1e-3"));
        } else if (type == "torque") {
          L.only_keys(e, {"type", "name", "coordinate", "value"});
          const std::string c = coordinate(e, "coordinate");
          def.add_torque(name, c, load_time_function_expression(L, L.child(e, "value", true), def));
        } else {
          L.fail(tn, "unknown force element type '" + type +
                         "' (expected spring_damper, joint_friction or torque)");
        }
      } catch (const ScenarioError&) {
        throw;
      } catch (const Error& ex) {
        L.fail(e, ex.what());
      }
    }
  }
  try {
    return sym::make_applied_force(def);
  } catch (const ScenarioError&) {
    throw;
  } catch (const Error& ex) {
    L.fail(forces, ex.what());
  }
}

}  // namespace ukdyn::io_detail
