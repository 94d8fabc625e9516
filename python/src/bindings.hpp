// The Python module ukdyn (docs/python.md): types shared by the binding files.
#pragma once

#include <pybind11/pybind11.h>

#include <atomic>
#include <chrono>
#include <future>
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

/// f(cancel) on a worker thread while this (Python's) thread waits with the GIL released and, every
/// 20 ms, takes it back to check for signals (PyErr_CheckSignals: Ctrl-C). A signal whose handler
/// raises (KeyboardInterrupt) sets `cancel`, which f heeds by stopping soon with what it has;
/// `interrupted` is then true, the Python error stays set, and f's result is returned once f has
/// returned (R{} if f threw: the signal's exception is the one raised). Python callables run by f
/// take the GIL on the worker thread.
template <class R, class F>
R interruptible(F f, bool& interrupted) {
  std::atomic<bool> cancel{false};
  auto done = std::async(std::launch::async, [&f, &cancel] { return f(cancel); });
  interrupted = false;
  for (;;) {
    {
      py::gil_scoped_release release;
      if (done.wait_for(std::chrono::milliseconds(20)) == std::future_status::ready) break;
    }
    if (!interrupted && PyErr_CheckSignals() != 0) {
      interrupted = true;
      cancel.store(true);
    }
  }
  if (interrupted) {
    try {
      return done.get();
    } catch (...) {
      return R{};
    }
  }
  return done.get();
}

/// Binds SubsystemDef, ConstraintDef, ForceDef, make_subsystem, make_constraint,
/// make_applied_force and System (definitions.cpp).
void bind_definitions(py::module_& m);

/// Binds optimize, ipopt_available and Optimized (optimize.cpp; docs/optimization.md).
void bind_optimize(py::module_& m);
void bind_size(py::module_& m);

}  // namespace ukdyn_python
