// The Python module ukdyn (docs/python.md): types shared by the binding files.
#pragma once

#include <pybind11/pybind11.h>

#include <memory>

#include "ukdyn/model/system.hpp"

namespace ukdyn_python {

namespace py = pybind11;

/// A subsystem / constraint block / applied force made in Python (constant, shared with Systems).
struct PySubsystem {
  std::shared_ptr<const ukdyn::Subsystem> ptr;
};
struct PyConstraint {
  std::shared_ptr<const ukdyn::Constraint> ptr;
};
struct PyAppliedForce {
  std::shared_ptr<const ukdyn::AppliedForce> ptr;
};

/// A System under construction in Python. A Scenario made from it takes a copy, so adding to it
/// later never changes a scenario that exists.
struct PySystem {
  std::shared_ptr<ukdyn::System> ptr = std::make_shared<ukdyn::System>();
};

/// Binds SubsystemDef, ConstraintDef, ForceDef, make_subsystem, make_constraint,
/// make_applied_force and System (definitions.cpp).
void bind_definitions(py::module_& m);

/// Binds optimize, ipopt_available and Optimized (optimize.cpp; docs/optimization.md).
void bind_optimize(py::module_& m);
void bind_size(py::module_& m);

}  // namespace ukdyn_python
