// The Python module ukdyn (docs/python.md): the Scenario wrapper and the argument checks shared by
// module.cpp (loading, forward, simulate) and state.cpp (the fast path and the quantities of a
// state).
#pragma once

#include <pybind11/numpy.h>

#include <memory>

#include "bindings.hpp"
#include "ukdyn/scenario/scenario.hpp"

namespace ukdyn_python {

struct PyScenario {
  ukdyn::Scenario sc;
};
using PyScenarioClass = py::class_<PyScenario, std::shared_ptr<PyScenario>>;

/// A float64 C-contiguous view of v (no copy when v already is one), checked: 1-D with n entries,
/// every entry finite. TypeError for a non-numeric v, ValueError naming `what` and the index of a
/// wrong size or a NaN / Inf (as `ukdyn eval` refuses them).
py::array_t<double, py::array::c_style | py::array::forcecast> checked_vector(const py::object& v,
                                                                              ukdyn::Index n,
                                                                              const char* what);
/// checked_vector() copied into a Vec.
ukdyn::Vec vector_arg(const py::object& v, ukdyn::Index n, const char* what);
/// ValueError unless t is finite.
void require_finite(double t, const char* what);

/// Copies into new numpy arrays (module.cpp).
py::array_t<double> numpy_of(const ukdyn::Vec& v);
py::array_t<double> numpy_of(const ukdyn::Mat& M);

/// Binds Scenario.parameter_derivatives, Scenario.sensitivities, Scenario.closed_loop_linearize
/// and Scenario.linearize_structured with its StructuredDerivatives (sensitivity.cpp).
void bind_sensitivity(py::module_& m, PyScenarioClass& cls);

/// Binds Data, Scenario.forward(q, qd, t=, tau=, out=), forward_qdd, forward_batch, energies,
/// constraints and inverse_dynamics (state.cpp).
void bind_state(py::module_& m, PyScenarioClass& cls);

}  // namespace ukdyn_python
