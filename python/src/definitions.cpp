// The Python module ukdyn: systems built from definitions in code (ukdyn/symbolic/definitions.hpp,
// forces.hpp). Expressions are given as text (the syntax of docs/definitions.md) or as numbers.
// The derivations run with the GIL held: GiNaC is not thread-safe, so two Python threads never
// derive at once.
#include "ukdyn/symbolic/definitions.hpp"

#include <pybind11/stl.h>

#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "bindings.hpp"
#include "ukdyn/symbolic/forces.hpp"

namespace ukdyn_python {

namespace {

using ukdyn::Error;
using ukdyn::symbolic::ConstraintDef;
using ukdyn::symbolic::DefinitionScope;
using ukdyn::symbolic::ExpressionError;
using ukdyn::symbolic::ForceDef;
using ukdyn::symbolic::SubsystemDef;

// An expression from Python: a str in the syntax of docs/definitions.md, or a number (its repr,
// read exactly as a decimal). `what` names the argument in error messages.
GiNaC::ex to_ex(const DefinitionScope& scope, const py::handle& v, const std::string& what) {
  std::string text;
  if (py::isinstance<py::str>(v)) {
    text = v.cast<std::string>();
  } else if (!py::isinstance<py::bool_>(v) &&
             (py::isinstance<py::int_>(v) || py::isinstance<py::float_>(v))) {
    text = py::repr(v).cast<std::string>();
  } else {
    throw py::type_error(what + ": expected an expression (str) or a number, got " +
                         py::repr(v).cast<std::string>());
  }
  try {
    return scope.parse(text);
  } catch (const ExpressionError& e) {
    throw Error(what + ": '" + text + "': column " + std::to_string(e.offset + 1) + ": " +
                e.what());
  }
}

template <std::size_t N>
std::array<GiNaC::ex, N> to_ex_array(const DefinitionScope& scope, const py::handle& v,
                                     const std::string& what) {
  if (py::isinstance<py::str>(v) || !py::isinstance<py::sequence>(v) ||
      py::len(v) != static_cast<std::size_t>(N)) {
    throw py::type_error(what + ": expected a sequence of " + std::to_string(N) +
                         " expressions (str or numbers)");
  }
  const auto seq = py::reinterpret_borrow<py::sequence>(v);
  std::array<GiNaC::ex, N> out;
  for (std::size_t i = 0; i < N; ++i) {
    out[i] = to_ex(scope, seq[i], what + "[" + std::to_string(i) + "]");
  }
  return out;
}

template <class Def>
void bind_scope(py::class_<Def>& c) {
  c.def(
       "parameter",
       [](Def& d, const std::string& name, const py::object& value) {
         d.parameter(name, to_ex(d, value, "parameter '" + name + "'"));
       },
       py::arg("name"), py::arg("value"),
       "Declares a parameter: a named number (an expression of earlier parameters allowed); it "
       "stays a symbol in the printed derivation.")
      .def(
          "let",
          [](Def& d, const std::string& name, const py::object& value) {
            d.let(name, to_ex(d, value, "let '" + name + "'"));
          },
          py::arg("name"), py::arg("value"),
          "A named intermediate expression, usable by later expressions.")
      .def_property_readonly(
          "parameters",
          [](const Def& d) {
            std::vector<std::string> names;
            for (const auto& p : d.parameters()) names.push_back(p.name);
            return names;
          },
          "Names of the parameters declared so far.");
}

}  // namespace

// long function bind_definitions: the binding table of the definitions API (one .def per method),
// declarative; the logic is in the functions above.
void bind_definitions(py::module_& m) {
  py::class_<PySubsystem>(m, "Subsystem",
                          "A subsystem (its M, C, G): made by make_subsystem(); constant.")
      .def_property_readonly("name", [](const PySubsystem& s) { return s.ptr->name(); })
      .def_property_readonly("dof", [](const PySubsystem& s) { return s.ptr->dof(); })
      .def_property_readonly("coordinate_names",
                             [](const PySubsystem& s) { return s.ptr->coordinate_names(); })
      .def("__repr__", [](const PySubsystem& s) {
        return "<ukdyn.Subsystem '" + s.ptr->name() + "', " + std::to_string(s.ptr->dof()) +
               " coordinates>";
      });
  py::class_<PyConstraint>(
      m, "Constraint", "A block of constraint rows (A, b): made by make_constraint(); constant.")
      .def_property_readonly("rows", [](const PyConstraint& c) { return c.ptr->rows(); })
      .def_property_readonly("row_names", [](const PyConstraint& c) { return c.ptr->row_names(); })
      .def("__repr__", [](const PyConstraint& c) {
        return "<ukdyn.Constraint, " + std::to_string(c.ptr->rows()) + " rows>";
      });
  py::class_<PyAppliedForce>(m, "AppliedForce",
                             "An applied force Q_a(t, q, qd) derived from a ForceDef; constant.")
      .def_property_readonly("name", [](const PyAppliedForce& f) { return f.ptr->name(); });

  py::class_<SubsystemDef> sd(m, "SubsystemDef", R"doc(A subsystem written as definitions: bodies
with masses, centre-of-mass positions p(q) and inertias; M, C, G are derived exactly (GiNaC).

    d = ukdyn.SubsystemDef("pendulum", ["phi"])
    d.parameter("l", 1.0)
    d.parameter("m", 2.0)
    d.add_body("bob", mass="m", com=["l*sin(phi)", 0, "-l*cos(phi)"])
    d.gravity = [0, 0, -9.81]
    sub = ukdyn.make_subsystem(d)

Expressions are str in the syntax of docs/definitions.md (velocities are <name>_dot) or numbers.)doc");
  sd.def(py::init<std::string, std::vector<std::string>>(), py::arg("name"), py::arg("coordinates"),
         "Declares the subsystem's coordinates (unique identifiers).");
  bind_scope(sd);
  sd.def_property_readonly("name", &SubsystemDef::name)
      .def_property_readonly("coordinates", &SubsystemDef::coordinates)
      .def(
          "add_body",
          [](SubsystemDef& d, const std::string& name, const py::object& mass,
             const py::object& com, const py::object& angular_velocity, const py::object& rotation,
             const py::object& inertia, const std::string& inertia_frame) {
            const std::string where = "body '" + name + "'";
            ukdyn::symbolic::BodyDef b;
            b.name = name;
            b.mass = to_ex(d, mass, where + " mass");
            b.com = to_ex_array<3>(d, com, where + " com");
            if (!angular_velocity.is_none()) {
              b.angular_velocity = to_ex_array<3>(d, angular_velocity, where + " angular_velocity");
            }
            if (!rotation.is_none()) b.rotation = to_ex_array<9>(d, rotation, where + " rotation");
            if (!inertia.is_none()) {
              if (py::isinstance<py::str>(inertia) || !py::isinstance<py::sequence>(inertia)) {
                b.inertia_kind = ukdyn::symbolic::BodyDef::InertiaKind::scalar;
                b.inertia_scalar = to_ex(d, inertia, where + " inertia");
              } else if (py::len(inertia) == 3) {  // the principal moments: a diagonal tensor
                b.inertia_kind = ukdyn::symbolic::BodyDef::InertiaKind::tensor;
                const auto diag = to_ex_array<3>(d, inertia, where + " inertia");
                b.inertia_tensor = {diag[0], 0, 0, 0, diag[1], 0, 0, 0, diag[2]};
              } else {
                b.inertia_kind = ukdyn::symbolic::BodyDef::InertiaKind::tensor;
                b.inertia_tensor = to_ex_array<9>(d, inertia, where + " inertia");
              }
            }
            if (inertia_frame == "body") {
              b.inertia_frame = ukdyn::symbolic::Frame::body;
            } else if (inertia_frame == "world") {
              b.inertia_frame = ukdyn::symbolic::Frame::world;
            } else {
              throw Error(where + " inertia_frame: '" + inertia_frame +
                          "' (expected 'body' or 'world')");
            }
            d.add_body(name) = std::move(b);
          },
          py::arg("name"), py::arg("mass"), py::arg("com"),
          py::arg("angular_velocity") = py::none(), py::arg("rotation") = py::none(),
          py::arg("inertia") = py::none(), py::arg("inertia_frame") = "body",
          R"doc(Adds a body: mass, centre of mass com = p(q) (3 expressions, world frame), optionally
the angular velocity (3) or the rotation body -> world (9, row-major), and the inertia about the
CoM: one expression (T_rot = 1/2 I w.w), 3 (principal moments) or 9 (a tensor, row-major) in
inertia_frame 'body' or 'world'.)doc")
      .def_property(
          "gravity",
          [](const SubsystemDef& d) {
            std::vector<std::string> g;
            for (const auto& e : d.gravity) {
              std::ostringstream os;
              os << e;
              g.push_back(os.str());
            }
            return g;
          },
          [](SubsystemDef& d, const py::object& g) { d.gravity = to_ex_array<3>(d, g, "gravity"); },
          "Gravitational acceleration (3 expressions, e.g. [0, 0, -9.81]).")
      .def_property(
          "extra_potential",
          [](const SubsystemDef& d) {
            std::ostringstream os;
            os << d.extra_potential;
            return os.str();
          },
          [](SubsystemDef& d, const py::object& v) {
            d.extra_potential = to_ex(d, v, "extra_potential");
          },
          "An extra potential added to V (springs, ...).");

  py::class_<ConstraintDef> cd(m, "ConstraintDef", R"doc(A block of constraint rows written as
expressions: holonomic rows Phi(q, t) = 0 or nonholonomic rows B(q, t) qd + c(q, t) = 0; A and b
are derived exactly. system_coordinates are all coordinates of the system, in order.)doc");
  cd.def(py::init([](const std::string& name, const std::string& kind,
                     const std::vector<std::string>& coords) {
           if (kind != "holonomic" && kind != "nonholonomic") {
             throw Error("ConstraintDef '" + name + "': kind '" + kind +
                         "' (expected 'holonomic' or 'nonholonomic')");
           }
           return ConstraintDef(name,
                                kind == "holonomic" ? ConstraintDef::Kind::holonomic
                                                    : ConstraintDef::Kind::nonholonomic,
                                coords);
         }),
         py::arg("name"), py::arg("kind"), py::arg("system_coordinates"));
  bind_scope(cd);
  cd.def_property_readonly("name", &ConstraintDef::name)
      .def(
          "add_row",
          [](ConstraintDef& d, const std::string& row, const py::object& e) {
            d.add_row(row, to_ex(d, e, "row '" + row + "'"));
          },
          py::arg("name"), py::arg("expression"), "Adds a row (= 0 is implied).");

  py::class_<ForceDef> fd(m, "ForceDef", R"doc(Applied forces written as definitions (the YAML
forces: section, docs/scenario-format.md): generalized forces, spring-dampers, joint friction,
torques; derived exactly and compiled. system_coordinates are all coordinates, in order.)doc");
  fd.def(py::init<std::vector<std::string>, std::string>(), py::arg("system_coordinates"),
         py::arg("name") = "forces");
  bind_scope(fd);
  fd.def(
        "add_generalized",
        [](ForceDef& d, const std::string& coord, const py::object& v) {
          d.add_generalized(coord, to_ex(d, v, "generalized '" + coord + "'"));
        },
        py::arg("coordinate"), py::arg("value"), "Q_i += value(t, q, qd) on `coordinate`.")
      .def(
          "add_spring_damper",
          [](ForceDef& d, const std::string& element, const py::object& a, const py::object& b,
             const py::object& k, const py::object& c, const py::object& l0) {
            const std::string w = "spring_damper '" + element + "'";
            d.add_spring_damper(element, to_ex_array<3>(d, a, w + " a"),
                                to_ex_array<3>(d, b, w + " b"), to_ex(d, k, w + " stiffness"),
                                to_ex(d, c, w + " damping"), to_ex(d, l0, w + " rest_length"));
          },
          py::arg("element"), py::arg("a"), py::arg("b"), py::arg("stiffness") = 0,
          py::arg("damping") = 0, py::arg("rest_length") = 0,
          "A spring-damper between the points a and b (3 expressions of q, t each).")
      .def(
          "add_joint_friction",
          [](ForceDef& d, const std::string& element, const std::string& coord,
             const py::object& viscous, const py::object& coulomb, const py::object& scale) {
            const std::string w = "joint_friction '" + element + "'";
            d.add_joint_friction(element, coord, to_ex(d, viscous, w + " viscous"),
                                 to_ex(d, coulomb, w + " coulomb"),
                                 to_ex(d, scale, w + " velocity_scale"));
          },
          py::arg("element"), py::arg("coordinate"), py::arg("viscous"), py::arg("coulomb") = 0,
          py::arg("velocity_scale") = 1e-3,
          "Q_i += -viscous qd_i - coulomb tanh(qd_i / velocity_scale).")
      .def(
          "add_torque",
          [](ForceDef& d, const std::string& element, const std::string& coord,
             const py::object& v) {
            d.add_torque(element, coord, to_ex(d, v, "torque '" + element + "'"));
          },
          py::arg("element"), py::arg("coordinate"), py::arg("value"), "Q_i += value(t, q, qd).");

  m.def(
      "make_subsystem",
      [](const SubsystemDef& d) { return PySubsystem{ukdyn::symbolic::make_subsystem(d)}; },
      py::arg("definition"),
      "Derives M, C, G of a SubsystemDef exactly and compiles them (raises ukdyn.Error).");
  m.def(
      "make_constraint",
      [](const ConstraintDef& d) { return PyConstraint{ukdyn::symbolic::make_constraint(d)}; },
      py::arg("definition"), "Derives A, b of a ConstraintDef exactly and compiles them.");
  m.def(
      "make_applied_force",
      [](const ForceDef& d) { return PyAppliedForce{ukdyn::symbolic::make_applied_force(d)}; },
      py::arg("definition"), "Derives the forces of a ForceDef exactly and compiles them.");

  py::class_<PySystem>(m, "System", R"doc(A constrained system under construction: subsystems (their
coordinates follow each other), constraint blocks (rows stacked) and applied forces. Turn it into
a runnable Scenario with Scenario.from_system().)doc")
      .def(py::init<>())
      .def(
          "add_subsystem",
          [](PySystem& s, const PySubsystem& sub) { return s.ptr->add_subsystem(sub.ptr); },
          py::arg("subsystem"), "Appends a subsystem; returns its offset in q.")
      .def(
          "add_constraint",
          [](PySystem& s, const PyConstraint& c) { return s.ptr->add_constraint(c.ptr); },
          py::arg("constraint"), "Appends a block of constraint rows; returns its first row.")
      .def(
          "add_applied_force",
          [](PySystem& s, const PyAppliedForce& f) { s.ptr->add_applied_force(f.ptr); },
          py::arg("force"), "Adds an applied force made by make_applied_force().")
      .def_property_readonly("dof", [](const PySystem& s) { return s.ptr->dof(); })
      .def_property_readonly("rows", [](const PySystem& s) { return s.ptr->rows(); })
      .def_property_readonly("coordinate_names",
                             [](const PySystem& s) { return s.ptr->coordinate_names(); })
      .def_property_readonly("constraint_row_names",
                             [](const PySystem& s) { return s.ptr->constraint_row_names(); });
}

}  // namespace ukdyn_python
