// Internal to ukdyn::io: constraint roles (`role:` of a constraint), `actuators:` and `control:`
// (docs/control.md, docs/scenario-format.md "Roles, actuators and control").
#pragma once

#include <map>
#include <string>

#include "scenario/yaml_loader.hpp"

namespace ukdyn::io_detail {

/// A constraint's role as written (`role: physical | servo`) or, if absent, by its type:
/// closure, frame constraints, points_coincide, angle_relation, nonholonomic → physical;
/// cut_point_trajectory, coordinate, point_trajectory → servo; expression → decided by
/// resolve_role (servo iff Φ depends on t explicitly).
struct RoleChoice {
  ConstraintRole role = ConstraintRole::physical;
  bool by_time = false;  ///< expression without `role:`: servo iff rheonomic
  std::string given;     ///< the `role:` text as written ("" if none), for restore_role
};

/// Reads and removes `role:` from the constraint node c (so that the type's own key check does not
/// see it). Bad values: file:line:column and the key. Put it back with restore_role once the
/// constraint is built: the document is read again for a plant (control.plant_set without a plant
/// file), and a row marked servo there must stay servo.
RoleChoice take_role(const Loader& L, const Node& c, const std::string& type);

/// The role of the built constraint (by_time: Φ(q0, t) or Φ̇(q0, 0, t) varies with t).
ConstraintRole resolve_role(const RoleChoice& choice, const Constraint& c, const Vec& q0);

/// Puts back the `role:` that take_role removed from c (nothing if none was given).
void restore_role(const Node& c, const RoleChoice& choice);

/// One numeric key of a `motor:` block (or of a catalogue's motor or gearbox,
/// src/sweep/sizing_file.cpp): absent → fallback; present → a number for which ok() is true, else
/// an error at the key (file:line:column, the key path, "KEY RULE (got V)").
double motor_key(const Loader& L, const Node& m, const char* key, double fallback,
                 bool (*ok)(double), const char* rule);

/// `actuators:` and `control:` (after the constraints and the initial state are loaded). An
/// actuator's `motor:` block (docs/motors.md) adds its reflected rotor inertia and its friction to
/// `system` (the scenario's own, sc.system).
void load_control_sections(const Loader& L, const Node& root, Scenario& sc, System& system,
                           const std::map<std::string, Index>& coord_index);

}  // namespace ukdyn::io_detail
