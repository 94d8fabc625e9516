// Scenario.parameter_derivatives, Scenario.sensitivities, Scenario.closed_loop_linearize and
// Scenario.linearize_structured (docs/python.md, docs/derivatives.md "Sensitivities to
// parameters", "Controlled runs", "Cost"): ukdyn/run/sensitivity.hpp, closed_loop_derivatives.hpp
// and the structured ∂q̈/∂(q, q̇) of ukdyn/model/linearize.hpp with numpy arrays, the C++ work with
// the GIL released.
#include "ukdyn/run/sensitivity.hpp"

#include <pybind11/stl.h>

#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "scenario_bindings.hpp"
#include "ukdyn/model/linearize.hpp"
#include "ukdyn/model/minimal_linearize.hpp"
#include "ukdyn/run/closed_loop_derivatives.hpp"
#include "ukdyn/run/eval_protocol.hpp"

namespace ukdyn_python {

namespace {

using ukdyn::Index;

py::list paths_of(const std::vector<ukdyn::ScenarioParameter>& ps) {
  py::list out;
  for (const auto& p : ps) out.append(py::cast(p.paths));
  return out;
}

py::dict parameter_derivatives(const PyScenario& s, const std::vector<std::string>& params,
                               double t, const py::object& q_in, const py::object& qd_in,
                               const py::object& tau_in) {
  const ukdyn::Scenario& sc = s.sc;
  const Index n = sc.system->dof();
  require_finite(t, "t");
  const ukdyn::Vec q = vector_arg(q_in, n, "q");
  const ukdyn::Vec qd = vector_arg(qd_in, n, "qd");
  const ukdyn::Vec tau = tau_in.is_none() ? sc.tau : vector_arg(tau_in, n, "tau");
  std::vector<ukdyn::ScenarioParameter> ps;
  ukdyn::ParameterLinearization pl;
  ukdyn::Mat dq0, dqd0;
  {
    py::gil_scoped_release release;
    ps = ukdyn::scenario_parameters(sc, params);
    pl = ukdyn::state_sensitivities(sc, ps, t, q, qd, tau);
    ukdyn::initial_state_derivatives(sc, ps, dq0, dqd0);
  }
  py::dict d;
  d["parameters"] = params;
  d["paths"] = paths_of(ps);
  d["qdd"] = numpy_of(pl.lin.qdd);
  d["Qc"] = numpy_of(pl.lin.Qc);
  d["dqdd_dp"] = numpy_of(pl.dqdd_dp);
  d["dQc_dp"] = numpy_of(pl.dQc_dp);
  d["dq0_dp"] = numpy_of(dq0);
  d["dqd0_dp"] = numpy_of(dqd0);
  d["trusted"] = pl.lin.trusted;
  d["message"] = pl.lin.message;
  return d;
}

// (P, T, n) from one T × n matrix per parameter.
py::array_t<double> stacked(const std::vector<ukdyn::Mat>& ms, Index rows, Index cols) {
  py::array_t<double> a({static_cast<Index>(ms.size()), rows, cols});
  auto w = a.mutable_unchecked<3>();
  for (std::size_t j = 0; j < ms.size(); ++j)
    for (Index k = 0; k < rows; ++k)
      for (Index i = 0; i < cols; ++i) w(static_cast<Index>(j), k, i) = ms[j](k, i);
  return a;
}

py::dict sensitivities(const PyScenario& s, const std::vector<std::string>& params) {
  const ukdyn::Scenario& sc = s.sc;
  const auto ps = ukdyn::scenario_parameters(sc, params);
  // Ctrl-C stops the run (interruptible(), bindings.hpp) and raises KeyboardInterrupt.
  bool interrupted = false;
  ukdyn::RunSensitivities rs = interruptible<ukdyn::RunSensitivities>(
      [&](const std::atomic<bool>& cancel) { return ukdyn::run_sensitivities(sc, ps, &cancel); },
      interrupted);
  if (interrupted) throw py::error_already_set();
  const auto T = static_cast<Index>(rs.t.size());
  py::dict d;
  d["parameters"] = rs.parameters;
  d["t"] = numpy_of(ukdyn::Vec(Eigen::Map<const ukdyn::Vec>(rs.t.data(), T)));
  d["q"] = numpy_of(rs.q);
  d["qd"] = numpy_of(rs.qd);
  d["dq_dp"] = stacked(rs.dq_dp, T, sc.system->dof());
  d["dqd_dp"] = stacked(rs.dqd_dp, T, sc.system->dof());
  d["steps"] = rs.steps;
  d["rhs_evaluations"] = rs.rhs_evaluations;
  d["trusted"] = rs.trusted;
  d["message"] = rs.message;
  d["warnings"] = rs.warnings;
  if (!rs.law_derivative.empty()) d["law_derivative"] = rs.law_derivative;
  return d;
}

// The closed loop of a control scenario at (t, q, qd), default its start
// (ukdyn/run/closed_loop_derivatives.hpp).
py::dict closed_loop_linearize(const PyScenario& s, const py::object& t_in, const py::object& q_in,
                               const py::object& qd_in) {
  const ukdyn::Scenario& sc = s.sc;
  const Index n = sc.system->dof();
  const auto run = ukdyn::make_control_run(sc);
  if (!run)
    throw std::invalid_argument(
        "closed_loop_linearize: the scenario has no control: section (docs/control.md)");
  const double t = t_in.is_none() ? sc.sim.t0 : t_in.cast<double>();
  require_finite(t, "t");
  const ukdyn::Vec q = q_in.is_none() ? run->q0 : vector_arg(q_in, n, "q");
  const ukdyn::Vec qd = qd_in.is_none() ? run->qd0 : vector_arg(qd_in, n, "qd");
  ukdyn::ClosedLoopLinearization cl;
  ukdyn::MinimalModel mm;
  ukdyn::Mat F, G;
  {
    py::gil_scoped_release release;
    cl = ukdyn::closed_loop_linearization(sc, t, q, qd);
    ukdyn::state_space(cl.lin, F, G);
    mm = ukdyn::minimal_model(*run->plant, t, q, qd, cl.law.tau, cl.lin);
  }
  py::dict d;
  d["t"] = t;
  d["q"] = numpy_of(q);
  d["qd"] = numpy_of(qd);
  d["tau"] = numpy_of(cl.law.tau);
  d["u"] = numpy_of(cl.law.u);
  d["dtau_dq"] = numpy_of(cl.law.dtau_dq);
  d["dtau_dqd"] = numpy_of(cl.law.dtau_dqd);
  d["dtau_dt"] = numpy_of(cl.law.dtau_dt);
  d["dtau_method"] = cl.law.method;
  d["dtau_dt_method"] = cl.law.dtau_dt_method;
  d["F"] = numpy_of(F);
  d["N"] = numpy_of(mm.N);
  d["F_min"] = numpy_of(mm.F_min);
  d["kinks"] = cl.law.kinks;
  d["trusted"] = cl.lin.trusted && cl.law.kinks.empty();
  d["message"] = cl.lin.message;
  return d;
}

// ∂q̈/∂(q, q̇) as LinearizeParts::structured gives it (ukdyn/model/linearize.hpp): the load's
// response XL and, per block, its own part on its columns and its response Q to the load, kept
// in the C++ LinearizeData for dqdd_dx_times() and dense(); the dense matrices where the
// block-arrow KKT solve did not run (structured False).
struct StructuredDerivatives {
  std::shared_ptr<PyScenario> scenario;  // the System the data was built for
  std::shared_ptr<ukdyn::LinearizeData> data;
  py::object qdd, XL, blocks;
};

StructuredDerivatives linearize_structured(const std::shared_ptr<PyScenario>& s, double t,
                                           const py::object& q_in, const py::object& qd_in,
                                           const py::object& tau_in) {
  const ukdyn::Scenario& sc = s->sc;
  const ukdyn::System& sys = *sc.system;
  const Index n = sys.dof();
  require_finite(t, "t");
  const ukdyn::Vec q = vector_arg(q_in, n, "q");
  const ukdyn::Vec qd = vector_arg(qd_in, n, "qd");
  const ukdyn::Vec tau =
      tau_in.is_none() ? ukdyn::Vec(ukdyn::Vec::Zero(n)) : vector_arg(tau_in, n, "tau");
  StructuredDerivatives r{s, std::make_shared<ukdyn::LinearizeData>(sys), py::none(), py::none(),
                          py::list()};
  {
    py::gil_scoped_release release;
    ukdyn::linearize(sys, *r.data, t, q, qd, tau, sc.sim.uk,
                     ukdyn::LinearizeParts{false, false, true});
  }
  r.qdd = numpy_of(r.data->lin.qdd);
  if (r.data->structured) {
    const ukdyn::ArrowResponse& x = r.data->dqdd_dx;
    r.XL = numpy_of(x.XL);
    py::list blocks;
    for (const auto& b : x.blocks) {
      py::dict d;
      d["start"] = b.start;
      d["size"] = b.size;
      d["cols"] = b.cols;
      d["own"] = numpy_of(b.own);
      d["Q"] = numpy_of(b.Q);
      blocks.append(d);
    }
    r.blocks = blocks;
  }
  const auto off = ukdyn::constraint_offset(sys, t, q, qd, sc.initial_tolerance);
  if (!off.warning.empty() && PyErr_WarnEx(PyExc_UserWarning, off.warning.c_str(), 1) != 0)
    throw py::error_already_set();  // warnings turned into errors
  return r;
}

// [∂q̈/∂q ∂q̈/∂q̇] V for V of shape (2n,) or (2n, k), without the dense matrices where the
// result is structured (ukdyn::dqdd_dx_times).
py::array_t<double> structured_times(const StructuredDerivatives& r, const py::object& v) {
  using Rows = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  const Index n = r.data->lin.qdd.size();
  const auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(v);
  if (!a || a.ndim() < 1 || a.ndim() > 2 || a.shape(0) != 2 * n)
    throw py::value_error("dqdd_dx_times: V must have shape (" + std::to_string(2 * n) + ",) or (" +
                          std::to_string(2 * n) + ", k)");
  const Index k = a.ndim() == 2 ? a.shape(1) : 1;
  const ukdyn::Mat V = Eigen::Map<const Rows>(a.data(), 2 * n, k);
  if (!V.allFinite()) throw py::value_error("dqdd_dx_times: V has an entry that is not finite");
  ukdyn::Mat out(n, k), scratch;
  ukdyn::dqdd_dx_times(*r.data, V, out, scratch);
  if (a.ndim() == 1) return numpy_of(ukdyn::Vec(out.col(0)));
  return numpy_of(out);
}

py::tuple structured_dense(const StructuredDerivatives& r) {
  ukdyn::Mat dq, dqd;
  ukdyn::dqdd_dx_dense(*r.data, dq, dqd);
  return py::make_tuple(numpy_of(dq), numpy_of(dqd));
}

void bind_structured(py::module_& m, PyScenarioClass& cls) {
  py::class_<StructuredDerivatives>(
      m, "StructuredDerivatives",
      "dqdd/d(q, qd) of N robots on one load in O(N) storage (docs/derivatives.md, \"Cost\")")
      .def_property_readonly(
          "structured", [](const StructuredDerivatives& r) { return r.data->structured; },
          "True when the block-arrow KKT solve gave the blocks; False: the "
          "dense matrices (two robots, redundant rows, applied forces)")
      .def_readonly("qdd", &StructuredDerivatives::qdd, "qdd of the KKT system, n")
      .def_readonly("XL", &StructuredDerivatives::XL,
                    "the load's rows of [dqdd/dq dqdd/dqd], n_L x 2n (None unless structured)")
      .def_readonly("blocks", &StructuredDerivatives::blocks,
                    "per block a dict start, size, cols, own (size x len(cols)), Q (size x n_L): "
                    "its rows are own on cols minus Q XL ([] unless structured)")
      .def_property_readonly(
          "load_start", [](const StructuredDerivatives& r) { return r.data->dqdd_dx.load_start; },
          "the load's first coordinate")
      .def_property_readonly(
          "load_size", [](const StructuredDerivatives& r) { return r.data->dqdd_dx.load_size; },
          "the load's coordinates n_L")
      .def_property_readonly(
          "trusted", [](const StructuredDerivatives& r) { return r.data->lin.trusted; },
          "False where ukdyn cannot vouch for the derivatives (see message)")
      .def_property_readonly(
          "message", [](const StructuredDerivatives& r) { return r.data->lin.message; },
          "why not trusted ('' if trusted)")
      .def("dqdd_dx_times", &structured_times, py::arg("V"),
           "[dqdd/dq dqdd/dqd] V for V of shape (2n,) or (2n, k), in O(N k) when structured")
      .def("dense", &structured_dense, "(dqdd_dq, dqdd_dqd), n x n each, expanded");
  cls.def("linearize_structured", &linearize_structured, py::arg("t"), py::arg("q"), py::arg("qd"),
          py::arg("tau") = py::none(),
          "dqdd/d(q, qd) at (t, q, qd, tau) (default 0) as the load's response and per-robot "
          "blocks (O(N) storage for N robots on one load) where the block-arrow KKT solve runs, "
          "else the dense matrices: a StructuredDerivatives (docs/derivatives.md, \"Cost\").");
}

}  // namespace

void bind_sensitivity(py::module_& m, PyScenarioClass& cls) {
  bind_structured(m, cls);
  cls.def("parameter_derivatives", &parameter_derivatives, py::arg("parameters"), py::arg("t"),
          py::arg("q"), py::arg("qd"), py::arg("tau") = py::none(),
          "Derivatives of qdd and Qc at (t, q, qd, tau) with respect to numbers of the scenario "
          "file (a parameters: key such as 'm1', or a path such as 'forces.tau[2]'): a dict with "
          "dqdd_dp, dQc_dp (n x P), dq0_dp, dqd0_dp, paths, trusted, message "
          "(docs/derivatives.md, \"Sensitivities to parameters\"). tau: the scenario's if None.")
      .def("sensitivities", &sensitivities, py::arg("parameters"),
           "dq/dp and dqd/dp of the scenario's run from its initial state (variational "
           "equations, no drift control): a dict with t (T), q, qd (T x n), dq_dp, dqd_dp "
           "(P x T x n), steps, rhs_evaluations, trusted, message, warnings. A control "
           "scenario: the plant's closed loop from its start; a gain is a parameter "
           "('control.kappa').")
      .def("closed_loop_linearize", &closed_loop_linearize, py::arg("t") = py::none(),
           py::arg("q") = py::none(), py::arg("qd") = py::none(),
           "A control scenario's closed loop at (t, q, qd) (default: its start): a dict with tau, "
           "u, dtau_dq, dtau_dqd, dtau_dt (the law's, by Richardson differences), F (2n x 2n), N, "
           "F_min "
           "(minimal coordinates of the plant), kinks, trusted, message "
           "(docs/derivatives.md, \"Controlled runs\").");
}

}  // namespace ukdyn_python
