// ukdyn.optimize (docs/optimization.md, docs/python.md "Optimal trajectories"): a problem file
// solved by collocation on IPOPT, the result as numpy arrays.
#include <pybind11/eigen.h>
#include <pybind11/stl.h>

#include <optional>
#include <string>

#include "bindings.hpp"
#include "ukdyn/run/optimize_run.hpp"
#include "ukdyn/scenario/optimization_file.hpp"

namespace ukdyn_python {

namespace {

struct PyOptimized {
  ukdyn::TrajectorySolution s;
  std::vector<std::string> coordinates, actuators, rows;
  ukdyn::ReplayCheck replay;
};

// Solves on a worker thread with the GIL released (IPOPT runs in C++ only); with `out`, also the
// run folder. Ctrl-C stops IPOPT after its current iteration (IpoptSettings::cancel) and raises
// KeyboardInterrupt; the folder, if asked for, holds that last iterate, untrusted.
PyOptimized optimize(const std::string& path, const std::optional<std::string>& out) {
  ukdyn::OptimizationFile f = ukdyn::load_optimization_file(path);
  bool interrupted = false;
  PyOptimized r = interruptible<PyOptimized>(
      [&f, &out](const std::atomic<bool>& cancel) {
        PyOptimized o;
        f.ipopt.cancel = &cancel;
        if (out) {
          ukdyn::OptimizeReport rep = ukdyn::run_optimization(f, *out);
          o.s = std::move(rep.solution);
          o.replay = rep.replay;
        } else {
          o.s = ukdyn::optimize_trajectory(f.problem, f.ipopt);
        }
        return o;
      },
      interrupted);
  if (interrupted) throw py::error_already_set();  // KeyboardInterrupt
  r.coordinates = f.problem.system->coordinate_names();
  r.actuators = f.problem.actuator_names;
  for (const auto k : r.s.kept_rows)
    r.rows.push_back(f.problem.system->constraint_row_names()[static_cast<std::size_t>(k)]);
  return r;
}

}  // namespace

void bind_optimize(py::module_& m) {
  py::class_<PyOptimized>(m, "Optimized", "An optimal trajectory (docs/optimization.md)")
      .def_property_readonly(
          "t", [](const PyOptimized& r) { return r.s.t; }, "times of the points")
      .def_property_readonly(
          "knot", [](const PyOptimized& r) { return r.s.knot; },
          "per point: a knot (False: a Hermite-Simpson midpoint)")
      .def_property_readonly(
          "q", [](const PyOptimized& r) { return r.s.q; }, "points x n")
      .def_property_readonly(
          "qd", [](const PyOptimized& r) { return r.s.qd; }, "points x n")
      .def_property_readonly(
          "qdd", [](const PyOptimized& r) { return r.s.qdd; }, "points x n")
      .def_property_readonly(
          "u", [](const PyOptimized& r) { return r.s.u; }, "points x k")
      .def_property_readonly(
          "Qc", [](const PyOptimized& r) { return r.s.Qc; }, "points x n")
      .def_property_readonly(
          "mu", [](const PyOptimized& r) { return r.s.mu; },
          "points x rank: the force of each independent row (rows)")
      .def_readonly("coordinates", &PyOptimized::coordinates)
      .def_readonly("actuators", &PyOptimized::actuators)
      .def_readonly("rows", &PyOptimized::rows, "the independent constraint rows (columns of mu)")
      .def_property_readonly("cost", [](const PyOptimized& r) { return r.s.cost; })
      .def_property_readonly("duration", [](const PyOptimized& r) { return r.s.duration; })
      .def_property_readonly(
          "status", [](const PyOptimized& r) { return r.s.status; }, "IPOPT's return status")
      .def_property_readonly("converged", [](const PyOptimized& r) { return r.s.converged; })
      .def_property_readonly(
          "trusted", [](const PyOptimized& r) { return r.s.trusted; },
          "False when ukdyn cannot vouch for the result (message says why)")
      .def_property_readonly("message", [](const PyOptimized& r) { return r.s.message; })
      .def_property_readonly("iterations", [](const PyOptimized& r) { return r.s.iterations; })
      .def_property_readonly("dual_infeasibility",
                             [](const PyOptimized& r) { return r.s.dual_infeasibility; })
      .def_property_readonly("max_defect", [](const PyOptimized& r) { return r.s.max_defect; })
      .def_property_readonly("max_position_residual",
                             [](const PyOptimized& r) { return r.s.max_position_residual; })
      .def_property_readonly("max_velocity_residual",
                             [](const PyOptimized& r) { return r.s.max_velocity_residual; })
      .def_property_readonly("max_correction_ratio",
                             [](const PyOptimized& r) { return r.s.max_correction_ratio; })
      .def_property_readonly(
          "max_waypoint_residual", [](const PyOptimized& r) { return r.s.max_waypoint_residual; },
          "max |Phi_w| over the waypoints at their times (0 without waypoints)")
      .def_property_readonly(
          "internal_wrench", [](const PyOptimized& r) { return r.s.internal_wrench; },
          "points x 6 per grasp of each bounded load: Walker's internal wrench [f; m]")
      .def_property_readonly(
          "replay_max_q_deviation",
          [](const PyOptimized& r) -> std::optional<double> {
            if (!r.replay.done) return std::nullopt;
            return r.replay.max_q_deviation;
          },
          "the open-loop replay check (with out= only; None otherwise)");
  m.def("ipopt_available", &ukdyn::ipopt_available, "Whether this build has IPOPT");
  m.def("optimize", &optimize, py::arg("path"), py::arg("out") = std::nullopt,
        "Solves a trajectory-optimisation problem file (docs/optimization.md); with out, also "
        "writes the run folder (trajectory.csv, summary.json, replay.yaml, replay_open_loop.yaml) "
        "and "
        "runs the open-loop replay check");
}

}  // namespace ukdyn_python
