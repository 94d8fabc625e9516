// The Python module ukdyn (docs/python.md): scenarios, forward dynamics and simulation with numpy
// arrays. The C++ work runs with the GIL released; Python callables (controllers, applied forces)
// take it back while they run. A run's columns are views of one C++ buffer (no copy). ukdyn::Error
// and its subclasses become ukdyn.Error (ScenarioError, DefinitionError), with ukdyn's message.
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/stl.h>

#include <Eigen/Cholesky>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <exception>
#include <future>
#include <limits>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "scenario_bindings.hpp"
#include "ukdyn/model/linearize.hpp"
#include "ukdyn/model/minimal_linearize.hpp"
#include "ukdyn/run/eval_protocol.hpp"
#include "ukdyn/run/run.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/scenario/scenario_file.hpp"
#include "ukdyn/simulate/control.hpp"
#include "ukdyn/symbolic/definitions.hpp"
#include "ukdyn/version.hpp"

namespace ukdyn_python {

py::array_t<double, py::array::c_style | py::array::forcecast> checked_vector(const py::object& v,
                                                                              ukdyn::Index n,
                                                                              const char* what) {
  const auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(v);
  if (!a) {
    PyErr_Clear();
    throw py::type_error(std::string(what) + ": expected a sequence of " + std::to_string(n) +
                         " numbers");
  }
  if (a.ndim() != 1 || a.size() != n) {
    throw py::value_error(std::string(what) + ": expected " + std::to_string(n) +
                          " numbers, got an array of " + std::to_string(a.size()) + " in " +
                          std::to_string(a.ndim()) + " dimensions");
  }
  const double* p = a.data();
  for (ukdyn::Index i = 0; i < n; ++i) {
    if (!std::isfinite(p[i])) {
      throw py::value_error(std::string(what) + "[" + std::to_string(i) + "]: not finite (" +
                            std::to_string(p[i]) + ")");
    }
  }
  return a;
}

ukdyn::Vec vector_arg(const py::object& v, ukdyn::Index n, const char* what) {
  const auto a = checked_vector(v, n, what);
  ukdyn::Vec out(n);
  std::copy(a.data(), a.data() + n, out.data());
  return out;
}

void require_finite(double t, const char* what) {
  if (!std::isfinite(t)) throw py::value_error(std::string(what) + ": not finite");
}

namespace {
// A tolerance as the scenario loader takes it (src/scenario/scenario.cpp): in [1e-16, 1].
double checked_tolerance(double v, const char* what) {
  if (!(v >= 1e-16 && v <= 1.0))
    throw py::value_error(std::string(what) + ": a tolerance must lie in [1e-16, 1], got " +
                          std::to_string(v));
  return v;
}
}  // namespace

namespace {

using ukdyn::CVecRef;
using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;
using ukdyn::VecRef;

// ---------------------------------------------------------------------------- Python callbacks

// The first exception raised by a Python callable during one forward() / simulate() call. A
// callback never lets an exception through the C++ integrators (CVODE is C): it records it, returns
// NaN (which ends the run as non_finite), and later callbacks return NaN without calling Python;
// the call then re-raises the recorded exception.
struct CallbackErrors {
  std::exception_ptr first;
};

py::array_t<double> copy_of(CVecRef v) {
  py::array_t<double> a(v.size());
  std::copy(v.data(), v.data() + v.size(), a.mutable_data());
  return a;
}

// Calls f(t, q, qd) (the GIL taken) and hands its numbers (C order) to take(p); the result must be
// `rows` numbers (cols = 0) or a rows × cols array. An exception or another shape is recorded in
// `errors` and take(nullptr) is called (the caller writes NaN).
template <class Take>
void call_python_array(const py::object& f, const char* what, CallbackErrors& errors, double t,
                       CVecRef q, CVecRef qd, Index rows, Index cols, Take take) {
  py::gil_scoped_acquire gil;
  if (!errors.first) {
    try {
      const py::object r = f(t, copy_of(q), copy_of(qd));
      const auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(r);
      const std::string expected = cols == 0 ? std::to_string(rows) + " numbers"
                                             : "an array of shape (" + std::to_string(rows) + ", " +
                                                   std::to_string(cols) + ")";
      if (!a) {
        PyErr_Clear();
        throw ukdyn::Error(std::string(what) + " at t = " + std::to_string(t) + ": returned " +
                           py::repr(r).cast<std::string>() + ", expected " +
                           (cols == 0 ? "a sequence of " : "") + expected);
      }
      const bool fits = cols == 0 ? a.ndim() == 1 && a.size() == rows
                                  : a.ndim() == 2 && a.shape(0) == rows && a.shape(1) == cols;
      if (!fits) {
        throw ukdyn::Error(
            std::string(what) + " at t = " + std::to_string(t) + ": returned an array of shape " +
            py::repr(a.attr("shape")).cast<std::string>() + ", expected " + expected);
      }
      take(a.data());
      return;
    } catch (...) {
      errors.first = std::current_exception();
    }
  }
  take(nullptr);
}

// Calls f(t, q, qd) (the GIL taken) and adds (add = true) or writes its n numbers into out.
void call_python(const py::object& f, const char* what, CallbackErrors& errors, double t, CVecRef q,
                 CVecRef qd, VecRef out, bool add) {
  call_python_array(f, what, errors, t, q, qd, out.size(), 0, [&](const double* p) {
    if (p == nullptr) {
      out.setConstant(std::numeric_limits<double>::quiet_NaN());
      return;
    }
    for (Index i = 0; i < out.size(); ++i) out(i) = add ? out(i) + p[i] : p[i];
  });
}

// The method `name` of a Python force object, or None when it has none (or it is not callable).
py::object force_method(const py::object& f, const char* name) {
  py::gil_scoped_acquire gil;
  if (py::hasattr(f, name) && PyCallable_Check(f.attr(name).ptr())) return f.attr(name);
  return py::none();
}

// A Python callable f(t, q, qd) -> Q_a (n numbers) as an applied force: all of it
// non-conservative (no potential), its power Q_aᵀ q̇ counted in the energy balance. Its exact
// derivatives (docs/python.md, docs/derivatives.md) are its optional methods f.dQ_dq(t, q, qd) and
// f.dQ_dqd(t, q, qd) (n × n each, both or neither: add_tangent) and f.dQ_dt(t, q, qd) (n:
// add_time_tangent); without them the force has no exact derivatives, as a C++ AppliedForce
// without the overrides.
class PythonForce final : public ukdyn::AppliedForce {
 public:
  PythonForce(py::object f, std::string name, Index n, CallbackErrors& errors)
      : f_(new py::object(std::move(f)), release_with_gil),
        dq_(new py::object(force_method(*f_, "dQ_dq")), release_with_gil),
        dqd_(new py::object(force_method(*f_, "dQ_dqd")), release_with_gil),
        dt_(new py::object(force_method(*f_, "dQ_dt")), release_with_gil),
        name_(std::move(name)),
        errors_(errors),
        buffer_(n) {}
  [[nodiscard]] const std::string& name() const override { return name_; }
  double add_to(double t, CVecRef q, CVecRef qd, VecRef Q) const override {
    // buffer_ is scratch of this force object, which exists for one call only (make_run_system).
    call_python(*f_, "applied force", errors_, t, q, qd, buffer_, false);
    Q += buffer_;
    return buffer_.dot(qd);
  }
  [[nodiscard]] double potential(CVecRef) const override { return 0.0; }
  [[nodiscard]] bool has_derivatives() const override {
    return !dq_->is_none() && !dqd_->is_none();
  }
  // dQ += ∂Q_a/∂q dq + ∂Q_a/∂q̇ dqd, each matrix asked for only where its direction is not 0.
  bool add_tangent(double t, CVecRef q, CVecRef qd, CVecRef dq, CVecRef dqd,
                   VecRef dQ) const override {
    if (!has_derivatives()) return false;
    const Index n = dQ.size();
    for (const bool rate : {false, true}) {
      const CVecRef dir = rate ? dqd : dq;
      if (dir.isZero(0.0)) continue;
      call_python_array(
          *(rate ? dqd_ : dq_), rate ? "applied force's dQ_dqd" : "applied force's dQ_dq", errors_,
          t, q, qd, n, n, [&](const double* p) {
            if (p == nullptr) {
              dQ.setConstant(std::numeric_limits<double>::quiet_NaN());
              return;
            }
            using RowMajor = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
            dQ += Eigen::Map<const RowMajor>(p, n, n) * dir;
          });
    }
    return true;
  }
  bool add_time_tangent(double t, CVecRef q, CVecRef qd, VecRef dQ) const override {
    if (dt_->is_none()) return false;
    call_python(*dt_, "applied force's dQ_dt", errors_, t, q, qd, dQ, true);
    return true;
  }

 private:
  static void release_with_gil(py::object* p) {
    py::gil_scoped_acquire gil;
    delete p;
  }
  std::shared_ptr<py::object> f_, dq_, dqd_, dt_;
  std::string name_;
  CallbackErrors& errors_;
  mutable Vec buffer_;
};

// The system of one call: the scenario's, plus the Python forces (a copy; the scenario's own
// system is never changed).
std::shared_ptr<const ukdyn::System> make_run_system(const ukdyn::Scenario& sc,
                                                     const std::vector<py::object>& forces,
                                                     CallbackErrors& errors) {
  if (forces.empty()) return sc.system;
  auto sys = std::make_shared<ukdyn::System>(*sc.system);
  for (std::size_t k = 0; k < forces.size(); ++k) {
    if (!PyCallable_Check(forces[k].ptr())) {
      throw py::type_error("forces[" + std::to_string(k) + "]: expected a callable f(t, q, qd)");
    }
    sys->add_applied_force(std::make_shared<PythonForce>(
        forces[k], "python_force_" + std::to_string(k), sys->dof(), errors));
  }
  return sys;
}

void rethrow_recorded(const CallbackErrors& errors) {
  if (errors.first) std::rethrow_exception(errors.first);
}

// ---------------------------------------------------------------------------- control laws

// What a Python control law sees besides (t, q, q̇): the controller's model at the measured state
// (ForwardData of forward() with the model's tau, all rows), its residuals Φ, Φ̇, which rows are
// servo rows, and the actuators (docs/python.md "Control laws in Python"). Copies: the law may
// keep them.
struct ControlData {
  double t = 0.0;
  py::array_t<double> M, Q, A, b, Qc, qdd, phi, phid, B, limit, tau;
  py::array_t<bool> servo;
  int rank = 0;
};

// A Python callable law(t, q, qd, data) -> u (k numbers) as a ukdyn::ControlLaw: the closed loop
// calls it at every right-hand-side evaluation and at every sample, with the GIL taken only for
// the call (the run itself holds no GIL). An exception is recorded in `errors`, u is set to NaN
// (the run ends as non_finite) and simulate() re-raises it.
class PythonControlLaw final : public ukdyn::ControlLaw {
 public:
  PythonControlLaw(py::object f, CallbackErrors& errors)
      : f_(new py::object(std::move(f)), release_with_gil), errors_(errors) {}
  void control(const ukdyn::ControlModel& model, double t, CVecRef q, CVecRef qd,
               const ukdyn::ForwardData& md, VecRef u) override {
    const ukdyn::System& sys = *model.system;
    phi_.resize(sys.rows());
    phid_.resize(sys.rows());
    ukdyn::position_residuals(sys, t, q, phi_);
    ukdyn::velocity_residuals(sys, t, q, qd, phid_);
    py::gil_scoped_acquire gil;
    if (!errors_.first) {
      try {
        ControlData d;
        d.t = t;
        d.M = numpy_of(md.M);
        d.Q = copy_of(md.Q);
        d.A = numpy_of(md.A);
        d.b = copy_of(md.b);
        d.Qc = copy_of(md.Qc);
        d.qdd = copy_of(md.qdd);
        d.phi = copy_of(phi_);
        d.phid = copy_of(phid_);
        d.B = numpy_of(model.actuators.B);
        d.limit = copy_of(model.actuators.limit);
        d.tau = copy_of(model.tau);
        d.servo = py::array_t<bool>(static_cast<py::ssize_t>(model.row_servo.size()));
        for (std::size_t i = 0; i < model.row_servo.size(); ++i)
          d.servo.mutable_data()[i] = model.row_servo[i];
        d.rank = md.result.rank;
        const py::object r = (*f_)(t, copy_of(q), copy_of(qd), py::cast(std::move(d)));
        const auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(r);
        if (!a) {
          PyErr_Clear();
          throw ukdyn::Error("control law at t = " + std::to_string(t) + ": returned " +
                             py::repr(r).cast<std::string>() + ", expected a sequence of " +
                             std::to_string(u.size()) + " numbers (one per actuator)");
        }
        if (a.ndim() != 1 || a.size() != u.size()) {
          throw ukdyn::Error("control law at t = " + std::to_string(t) +
                             ": returned an array of shape " +
                             py::repr(a.attr("shape")).cast<std::string>() + ", expected " +
                             std::to_string(u.size()) + " numbers (one per actuator)");
        }
        std::copy(a.data(), a.data() + u.size(), u.data());
        return;
      } catch (...) {
        errors_.first = std::current_exception();
      }
    }
    u.setConstant(std::numeric_limits<double>::quiet_NaN());
  }

 private:
  static void release_with_gil(py::object* p) {
    py::gil_scoped_acquire gil;
    delete p;
  }
  std::shared_ptr<py::object> f_;
  CallbackErrors& errors_;
  Vec phi_, phid_;
};

// law(t, q, qd, data), or an object with a method control(t, q, qd, data).
py::object control_law_callable(const py::object& law) {
  if (py::hasattr(law, "control") && PyCallable_Check(law.attr("control").ptr()))
    return law.attr("control");
  if (PyCallable_Check(law.ptr())) return law;
  throw py::type_error(
      "control_law: expected a callable law(t, q, qd, data) -> u or an object with a method "
      "control(t, q, qd, data)");
}

// ---------------------------------------------------------------------------- scenario

}  // namespace

// Shared with sensitivity.cpp (scenario_bindings.hpp).
py::array_t<double> numpy_of(const Vec& v) { return copy_of(v); }
py::array_t<double> numpy_of(const Mat& M) {
  py::array_t<double> a({M.rows(), M.cols()});
  auto w = a.mutable_unchecked<2>();
  for (Index i = 0; i < M.rows(); ++i) {
    for (Index j = 0; j < M.cols(); ++j) w(i, j) = M(i, j);
  }
  return a;
}

namespace {

template <class Enum>
Enum enum_of(const std::string& name, std::initializer_list<Enum> values, const char* what) {
  std::string known;
  for (Enum e : values) {
    if (to_string(e) == name) return e;
    // (two appends: GCC 12's LTO reports a false -Wstringop-overflow for the concatenation)
    if (!known.empty()) known += ", ";
    known += to_string(e);
  }
  throw ukdyn::Error(std::string(what) + ": '" + name + "' (expected one of " + known + ")");
}

// ---------------------------------------------------------------------------- forward

struct ForwardResult {
  py::array_t<double> M, C, Cqd, G, Q, A, b, Qc, qdd;
  int rank = 0;
  double residual = 0.0, sigma_min = 0.0, sigma_max = 0.0;
  bool consistent = true, finite = true;
};

// What `ukdyn eval` refuses to answer (src/run/eval_protocol.cpp), refused here too: a singular M
// (also to round-off: LLT reciprocal condition under 1e-13, eval's min_rcond) that the constraints
// do not make up for, and any non-finite result. Raises ukdyn.Error.
void check_forward_result(const ukdyn::System& sys, const ukdyn::ForwardData& data, const Mat& C) {
  if (!data.M.allFinite())
    throw ukdyn::Error("forward: the mass matrix M is not finite at this state");
  if (data.singular.rank_deficient) {
    throw ukdyn::Error(
        "forward: the mass matrix M is singular and the constraints do not fix the undetermined "
        "directions ([M; A] is rank deficient) at this state");
  }
  const Eigen::LLT<Mat> llt(ukdyn::solved_mass(sys, data));
  if (llt.info() != Eigen::Success)
    throw ukdyn::Error(
        "forward: the mass matrix M is singular (not positive definite) at this state");
  if (const double rc = llt.rcond(); !(rc >= 1e-13)) {
    std::ostringstream os;
    os << "forward: the mass matrix M is singular to round-off at this state (reciprocal "
          "condition "
       << rc << ")";
    throw ukdyn::Error(os.str());
  }
  if (!data.result.finite || !data.qdd.allFinite() || !data.Qc.allFinite() || !data.A.allFinite() ||
      !data.b.allFinite() || !data.G.allFinite() || !data.Q.allFinite() || !data.Cqd.allFinite() ||
      !C.allFinite()) {
    throw ukdyn::Error(
        "forward: non-finite result at this state (M, A, b, forces or accelerations)");
  }
}

ForwardResult forward(const PyScenario& s, double t, const py::object& q_in,
                      const py::object& qd_in, const py::object& tau_in,
                      const std::vector<py::object>& forces) {
  const ukdyn::Scenario& sc = s.sc;
  const Index n = sc.system->dof();
  require_finite(t, "t");
  const Vec q = vector_arg(q_in, n, "q");
  const Vec qd = vector_arg(qd_in, n, "qd");
  const Vec tau = tau_in.is_none() ? Vec(Vec::Zero(n)) : vector_arg(tau_in, n, "tau");
  CallbackErrors errors;
  const auto sys = make_run_system(sc, forces, errors);
  ukdyn::ForwardData data(*sys);
  Mat C(n, n);
  {
    py::gil_scoped_release release;
    ukdyn::forward(*sys, data, t, q, qd, tau, sc.sim.uk);
    ukdyn::coriolis_matrix(*sys, data, t, q, qd, C);
  }
  rethrow_recorded(errors);
  check_forward_result(*sys, data, C);
  ForwardResult r;
  r.M = numpy_of(data.M);
  r.C = numpy_of(C);
  r.Cqd = numpy_of(data.Cqd);
  r.G = numpy_of(data.G);
  r.Q = numpy_of(data.Q);
  r.A = numpy_of(data.A);
  r.b = numpy_of(data.b);
  r.Qc = numpy_of(data.Qc);
  r.qdd = numpy_of(data.qdd);
  r.rank = data.result.rank;
  r.residual = data.result.residual;
  r.sigma_min = data.result.sigma_min_kept;
  r.sigma_max = data.result.sigma_max;
  r.consistent = data.result.consistent;
  r.finite = data.result.finite;
  return r;
}

// ---------------------------------------------------------------------------- linearize

struct PyLinearization {
  py::array_t<double> qdd, Qc, dqdd_dq, dqdd_dqd, dqdd_dtau, dQc_dq, dQc_dqd, dQc_dtau, F, G;
  int rank = 0;
  std::vector<std::string> kept_rows;
  double kkt_agreement = 0.0;
  bool trusted = true;
  std::string message;
  // dt: the discrete model (None without dt); minimal: ukdyn/model/minimal_linearize.hpp.
  py::object dt = py::none(), Fd = py::none(), Gd = py::none();
  py::object N = py::none(), T = py::none(), D = py::none(), F_min = py::none(), G_min = py::none(),
             Fd_min = py::none(), Gd_min = py::none();
  py::object at_rest = py::none(), rheonomic = py::none();
  std::string minimal_note;
  // d/dt at fixed (q, qd, tau): None where a component has no exact d/dt (time_message says which).
  py::object dqdd_dt = py::none(), dQc_dt = py::none(), dmu_dt = py::none();
  std::string time_message;
};

// The discrete and minimal parts of a linearisation (with the GIL held: numpy arrays).
void add_minimal_and_discrete(PyLinearization& r, const ukdyn::MinimalModel* mm, const Mat& F,
                              const Mat& G, double dt) {
  if (dt > 0.0) {
    Mat Fd, Gd;
    ukdyn::discretize_zoh(F, G, dt, Fd, Gd);
    r.dt = py::float_(dt);
    r.Fd = numpy_of(Fd);
    r.Gd = numpy_of(Gd);
  }
  if (!mm) return;
  r.N = numpy_of(mm->N);
  r.T = numpy_of(mm->T);
  r.D = numpy_of(mm->D);
  r.F_min = numpy_of(mm->F_min);
  r.G_min = numpy_of(mm->G_min);
  r.at_rest = py::bool_(mm->at_rest);
  r.rheonomic = py::bool_(mm->rheonomic);
  r.minimal_note = mm->note;
  if (dt > 0.0) {
    Mat Fd, Gd;
    ukdyn::discretize_zoh(mm->F_min, mm->G_min, dt, Fd, Gd);
    r.Fd_min = numpy_of(Fd);
    r.Gd_min = numpy_of(Gd);
  }
}

// The exact derivatives at (t, q, qd, tau) (ukdyn/model/linearize.hpp, docs/derivatives.md).
PyLinearization linearize(const PyScenario& s, double t, const py::object& q_in,
                          const py::object& qd_in, const py::object& tau_in, bool minimal,
                          const py::object& dt_in, const std::vector<py::object>& forces) {
  double dt = 0.0;
  if (!dt_in.is_none()) {
    dt = dt_in.cast<double>();
    if (!(std::isfinite(dt) && dt > 0.0))
      throw std::invalid_argument("linearize: dt must be a positive finite step (or None)");
  }
  const ukdyn::Scenario& sc = s.sc;
  CallbackErrors errors;
  const auto with_forces = make_run_system(sc, forces, errors);
  const ukdyn::System& sys = *with_forces;
  const Index n = sys.dof();
  require_finite(t, "t");
  const Vec q = vector_arg(q_in, n, "q");
  const Vec qd = vector_arg(qd_in, n, "qd");
  const Vec tau = tau_in.is_none() ? Vec(Vec::Zero(n)) : vector_arg(tau_in, n, "tau");
  ukdyn::Linearization lin;
  ukdyn::MinimalModel mm;
  Mat F, G;
  std::exception_ptr failed;
  {
    py::gil_scoped_release release;
    try {
      lin = ukdyn::linearize(sys, t, q, qd, tau, sc.sim.uk);
      ukdyn::state_space(lin, F, G);
      if (minimal) mm = ukdyn::minimal_model(sys, t, q, qd, tau, lin);
    } catch (...) {
      failed = std::current_exception();
    }
  }
  rethrow_recorded(errors);  // a Python force's own exception first
  if (failed) std::rethrow_exception(failed);
  PyLinearization r;
  add_minimal_and_discrete(r, minimal ? &mm : nullptr, F, G, dt);
  r.qdd = numpy_of(lin.qdd);
  r.Qc = numpy_of(lin.Qc);
  r.dqdd_dq = numpy_of(lin.dqdd_dq);
  r.dqdd_dqd = numpy_of(lin.dqdd_dqd);
  r.dqdd_dtau = numpy_of(lin.dqdd_dtau);
  r.dQc_dq = numpy_of(lin.dQc_dq);
  r.dQc_dqd = numpy_of(lin.dQc_dqd);
  r.dQc_dtau = numpy_of(lin.dQc_dtau);
  if (lin.dqdd_dt.size() == n) {
    r.dqdd_dt = numpy_of(lin.dqdd_dt);
    r.dQc_dt = numpy_of(lin.dQc_dt);
    r.dmu_dt = numpy_of(lin.dmu_dt);
  }
  r.time_message = lin.time_message;
  r.F = numpy_of(F);
  r.G = numpy_of(G);
  r.rank = lin.rank;
  for (Index k : lin.kept_rows)
    r.kept_rows.push_back(sys.constraint_row_names()[static_cast<std::size_t>(k)]);
  r.kkt_agreement = lin.kkt_agreement;
  r.trusted = lin.trusted;
  r.message = lin.message;
  // A state off the constraints is linearised all the same, with a UserWarning naming the row (as
  // `ukdyn linearize` warns on stderr).
  const auto off = ukdyn::constraint_offset(sys, t, q, qd, sc.initial_tolerance);
  if (!off.warning.empty() && PyErr_WarnEx(PyExc_UserWarning, off.warning.c_str(), 1) != 0)
    throw py::error_already_set();  // warnings turned into errors
  return r;
}

// ---------------------------------------------------------------------------- simulate

// A run: the trajectory in one C++ buffer, column-major (each column contiguous), owned by a
// capsule; every array handed out is a view of it with the capsule as its base.
struct Run {
  std::vector<std::string> columns;
  Index rows = 0;
  py::capsule owner;
  double* values = nullptr;
  py::object summary;
  py::list warnings;
  std::string status, message;
  bool complete = false;
  ukdyn::SimulationStats stats;
  py::object assembly = py::none();  // simulate(assemble=True): what assemble() returned

  [[nodiscard]] Index column_index(const std::string& name) const {
    for (std::size_t j = 0; j < columns.size(); ++j) {
      if (columns[j] == name) return static_cast<Index>(j);
    }
    std::string known;
    for (const auto& c : columns) known += (known.empty() ? "" : ", ") + c;
    throw py::key_error("no column '" + name + "' (the columns are " + known + ")");
  }
  [[nodiscard]] py::array column(const std::string& name) const {
    const Index j = column_index(name);
    return py::array_t<double>({rows}, {static_cast<py::ssize_t>(sizeof(double))},
                               values + j * rows, owner);
  }
  /// The columns prefix + suffixes[0..], adjacent in trajectory.csv, as one rows × k view (the
  /// buffer is column-major: adjacent columns are one strided block, no copy).
  [[nodiscard]] py::array block(const std::string& prefix,
                                const std::vector<std::string>& suffixes) const {
    const Index j = column_index(prefix + suffixes.front());
    for (std::size_t i = 1; i < suffixes.size(); ++i) {
      const auto c = static_cast<std::size_t>(j) + i;
      if (c >= columns.size() || columns[c] != prefix + suffixes[i])
        throw py::key_error("no column '" + prefix + suffixes[i] + "' after '" + prefix +
                            suffixes.front() + "'");
    }
    const auto s = static_cast<py::ssize_t>(sizeof(double));
    return py::array_t<double>({rows, static_cast<Index>(suffixes.size())}, {s, s * rows},
                               values + j * rows, owner);
  }
  [[nodiscard]] py::array data() const {
    const auto s = static_cast<py::ssize_t>(sizeof(double));
    return py::array_t<double>({rows, static_cast<Index>(columns.size())}, {s, s * rows}, values,
                               owner);
  }
};

py::dict assembly_dict(const ukdyn::AssemblyResult& a) {
  py::dict d;
  d["q"] = numpy_of(a.q);
  d["qd"] = numpy_of(a.qd);
  d["success"] = a.success;
  d["iterations"] = a.iterations;
  d["max_position_residual"] = a.max_position_residual;
  d["max_velocity_residual"] = a.max_velocity_residual;
  d["message"] = a.message;
  return d;
}

// The rows of `r` over tol, worst first: "'name' = residual, ..." (at most 8 named).
std::string violated_rows(const ukdyn::System& sys, const Vec& r, double tol) {
  std::vector<Index> rows;
  for (Index i = 0; i < r.size(); ++i) {
    if (!(std::abs(r(i)) <= tol)) rows.push_back(i);
  }
  std::sort(rows.begin(), rows.end(),
            [&r](Index a, Index b) { return std::abs(r(a)) > std::abs(r(b)); });
  std::ostringstream os;
  os.precision(3);
  for (std::size_t k = 0; k < rows.size() && k < 8; ++k) {
    os << (k ? ", " : "") << "'" << sys.constraint_row_names()[static_cast<std::size_t>(rows[k])]
       << "' = " << std::scientific << r(rows[k]);
  }
  if (rows.size() > 8) os << " and " << rows.size() - 8 << " more";
  return os.str();
}

// The start of a run, as the scenario loader checks `initial:` (paper, assumption 3): q0, qd0, t0,
// t_end overridden where given, then |Φ(q0, t0)| and |Φ̇| ≤ initial_tolerance on every row, or a
// ValueError naming the rows and their residuals. With `assemble`, the state is assemble()'s
// (`ukdyn assemble`), returned as a dict (None otherwise).
py::object prepare_start(ukdyn::Scenario& sc, const py::object& q0, const py::object& qd0,
                         const py::object& t0, const py::object& t_end, bool assemble) {
  const Index n = sc.system->dof();
  if (!q0.is_none()) sc.q0 = vector_arg(q0, n, "q0");
  if (!qd0.is_none()) sc.qd0 = vector_arg(qd0, n, "qd0");
  if (!t0.is_none()) sc.sim.t0 = t0.cast<double>();
  if (!t_end.is_none()) sc.sim.t_end = t_end.cast<double>();
  require_finite(sc.sim.t0, "t0");
  require_finite(sc.sim.t_end, "t_end");
  if (!(sc.sim.t_end > sc.sim.t0)) throw py::value_error("t_end must be greater than t0");
  if (assemble) {
    const ukdyn::AssemblyResult a = ukdyn::assemble(*sc.system, sc.sim.t0, sc.q0, sc.qd0, sc.held);
    if (!a.success) throw ukdyn::Error("simulate(assemble=True): assembly failed: " + a.message);
    sc.q0 = a.q;
    sc.qd0 = a.qd;
    return assembly_dict(a);
  }
  const ukdyn::System& sys = *sc.system;
  if (sys.rows() == 0) return py::none();
  Vec phi(sys.rows()), phid(sys.rows());
  ukdyn::position_residuals(sys, sc.sim.t0, sc.q0, phi);
  ukdyn::velocity_residuals(sys, sc.sim.t0, sc.q0, sc.qd0, phid);
  const double tol = sc.initial_tolerance;
  std::ostringstream os;
  os.precision(3);
  if (!(phi.cwiseAbs().maxCoeff() <= tol)) {
    os << "simulate: q0 violates the constraints at t0 beyond initial_tolerance " << tol
       << " (residual Phi of the rows " << violated_rows(sys, phi, tol) << ")";
  } else if (!(phid.cwiseAbs().maxCoeff() <= tol)) {
    os << "simulate: qd0 violates the velocity constraints at t0 beyond initial_tolerance " << tol
       << " (residual Phi_dot of the rows " << violated_rows(sys, phid, tol) << ")";
  }
  if (!os.str().empty()) {
    throw py::value_error(os.str() +
                          "; pass assemble=True to start from the consistent state assemble() "
                          "finds, or give a consistent q0, qd0");
  }
  return py::none();
}

// run_scenario_in_memory() interruptible by Ctrl-C (interruptible(), bindings.hpp): a signal
// cancels the run (options.cancel: it stops after the current step, status `stopped`, as the CLI's
// run on SIGINT); `interrupted` is then true and the run so far is returned.
ukdyn::MemoryRun run_interruptible(const ukdyn::Scenario& sc, ukdyn::MemoryRunOptions opt,
                                   bool& interrupted) {
  return interruptible<ukdyn::MemoryRun>(
      [&sc, &opt](const std::atomic<bool>& cancel) {
        opt.cancel = &cancel;
        return ukdyn::run_scenario_in_memory(sc, opt);
      },
      interrupted);
}

// The Run of a MemoryRun: its columns moved into one column-major buffer owned by a capsule.
std::shared_ptr<Run> make_run(const ukdyn::MemoryRun& mem, const py::object& assembly) {
  auto run = std::make_shared<Run>();
  run->columns = mem.header;
  const std::size_t cols = mem.header.size();
  run->rows = mem.report.csv_rows;
  // Row-major (as sampled) → column-major, once, in C++.
  // (never empty: a run with no sample still hands out views of a valid pointer)
  auto* buffer = new std::vector<double>(std::max<std::size_t>(1, mem.values.size()));
  const auto rows = static_cast<std::size_t>(run->rows);
  for (std::size_t i = 0; i < rows; ++i) {
    for (std::size_t j = 0; j < cols; ++j) (*buffer)[j * rows + i] = mem.values[i * cols + j];
  }
  run->values = buffer->data();
  run->owner = py::capsule(buffer, [](void* p) { delete static_cast<std::vector<double>*>(p); });
  run->summary = mem.summary_json.empty()
                     ? py::object(py::none())
                     : py::module_::import("json").attr("loads")(mem.summary_json);
  for (const auto& w : mem.report.stats.warnings) {
    py::dict d;
    d["t"] = w.t;
    d["kind"] = w.kind;
    d["message"] = w.message;
    run->warnings.append(d);
  }
  run->stats = mem.report.stats;
  run->status = ukdyn::to_string(mem.report.stats.status);
  run->message = mem.report.stats.message;
  run->complete = mem.report.complete();
  run->assembly = assembly;
  return run;
}

std::shared_ptr<Run> simulate(const PyScenario& s, const py::object& controller,
                              const std::vector<py::object>& forces, const py::object& control_law,
                              const py::object& q0, const py::object& qd0, const py::object& t0,
                              const py::object& t_end, bool assemble) {
  ukdyn::Scenario sc = s.sc;
  CallbackErrors errors;
  py::object assembly = prepare_start(sc, q0, qd0, t0, t_end, assemble);
  if (sc.control && !forces.empty()) {
    throw ukdyn::Error(
        "forces: Python applied forces are not supported with a control: section (they would act "
        "on the controller's model and the plant alike); use the plant's forces: or control.");
  }
  if (sc.control && !controller.is_none()) {
    throw ukdyn::Error(
        "controller: a scenario with a control: section takes control_law=law(t, q, qd, data) -> u "
        "(per actuator), not controller= (docs/python.md)");
  }
  if (!sc.control && !control_law.is_none()) {
    throw ukdyn::Error("control_law: scenario '" + sc.name +
                       "' has no control: section (actuators, plant and model; docs/control.md); "
                       "use controller=u(t, q, qd) for generalized forces");
  }
  sc.system = make_run_system(s.sc, forces, errors);
  ukdyn::MemoryRunOptions opt;
  std::unique_ptr<PythonControlLaw> law;
  if (!control_law.is_none()) {
    law = std::make_unique<PythonControlLaw>(control_law_callable(control_law), errors);
    opt.law = law.get();
  }
  std::shared_ptr<py::object> ctrl;
  if (!controller.is_none()) {
    if (!PyCallable_Check(controller.ptr())) {
      throw py::type_error("controller: expected a callable u(t, q, qd) returning tau");
    }
    ctrl = std::shared_ptr<py::object>(new py::object(controller), [](py::object* p) {
      py::gil_scoped_acquire gil;
      delete p;
    });
    // τ = forces.tau + u(t, q, q̇): the controller's output adds to the scenario's constant τ.
    opt.tau = [&sc, &errors, ctrl](double t, CVecRef q, CVecRef qd, VecRef tau) {
      tau = sc.tau;
      call_python(*ctrl, "controller", errors, t, q, qd, tau, true);
    };
  }
  ukdyn::MemoryRun result;
  bool interrupted = false;
  try {
    result = run_interruptible(sc, opt, interrupted);
  } catch (...) {
    law.reset();  // with the GIL (it holds a Python object)
    throw;
  }
  law.reset();
  if (interrupted) {
    // KeyboardInterrupt (or what the signal's handler raised), with the run so far as its .run
    // (status `stopped`, incomplete, as the CLI's run on Ctrl-C).
    py::error_already_set e;  // takes the pending exception
    e.value().attr("run") = py::cast(make_run(result, assembly));
    throw e;
  }
  rethrow_recorded(errors);
  return make_run(result, assembly);
}

std::shared_ptr<PyScenario> from_system(const PySystem& system, const py::object& q0,
                                        const py::object& qd0, const py::object& tau, double t0,
                                        double t_end, double sample_dt,
                                        const std::string& integrator, bool adaptive,
                                        double abs_tol, double rel_tol, double step,
                                        const std::string& drift, bool energy_balance,
                                        const std::string& name) {
  auto s = std::make_shared<PyScenario>();
  ukdyn::Scenario& sc = s->sc;
  sc.system = std::make_shared<const ukdyn::System>(*system.ptr);
  const Index n = sc.system->dof();
  if (n == 0) throw ukdyn::Error("Scenario.from_system: the system has no coordinates");
  sc.path = "<python>";
  sc.name = name;
  sc.q0 = vector_arg(q0, n, "q0");
  sc.qd0 = qd0.is_none() ? Vec(Vec::Zero(n)) : vector_arg(qd0, n, "qd0");
  sc.tau = tau.is_none() ? Vec(Vec::Zero(n)) : vector_arg(tau, n, "tau");
  sc.held.assign(static_cast<std::size_t>(n), false);
  sc.sim.t0 = t0;
  sc.sim.t_end = t_end;
  sc.sim.sample_dt = sample_dt;
  sc.sim.integrator = enum_of(
      integrator,
      {ukdyn::IntegratorKind::rk4, ukdyn::IntegratorKind::dopri5, ukdyn::IntegratorKind::rkf78,
       ukdyn::IntegratorKind::bdf, ukdyn::IntegratorKind::esdirk},
      "integrator");
  sc.sim.adaptive = adaptive;
  sc.sim.abs_tol = abs_tol;
  sc.sim.rel_tol = rel_tol;
  sc.sim.step = step;
  sc.sim.drift.kind = enum_of(
      drift,
      {ukdyn::DriftControl::none, ukdyn::DriftControl::baumgarte, ukdyn::DriftControl::projection},
      "drift");
  sc.sim.energy_balance = energy_balance;
  require_finite(t0, "t0");
  require_finite(t_end, "t_end");
  checked_tolerance(abs_tol, "abs_tol");
  checked_tolerance(rel_tol, "rel_tol");
  if (!(t_end > t0) || !(sample_dt > 0.0) || !(step > 0.0) || !std::isfinite(sample_dt) ||
      !std::isfinite(step)) {
    throw ukdyn::Error("Scenario.from_system: need t_end > t0, sample_dt > 0 and step > 0");
  }
  return s;
}

}  // namespace

}  // namespace ukdyn_python

// long function PYBIND11_MODULE: the module's binding table (one .def per function and class),
// declarative; the logic is in the functions above.
PYBIND11_MODULE(_ukdyn, m) {
  using namespace ukdyn_python;
  m.doc() = "ukdyn: Udwadia-Kalaba dynamics of constrained multibody systems (C++ core).";
  m.attr("__version__") = ukdyn::version();

  // Errors: ukdyn::Error → ukdyn.Error (the most derived type registered last is tried first).
  static py::exception<ukdyn::Error> error(m, "Error");
  static py::exception<ukdyn::ScenarioError> scenario_error(m, "ScenarioError", error.ptr());
  static py::exception<ukdyn::symbolic::DefinitionError> definition_error(m, "DefinitionError",
                                                                          error.ptr());
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const ukdyn::ScenarioError& e) {
      PyErr_SetString(scenario_error.ptr(), e.what());
    } catch (const ukdyn::symbolic::DefinitionError& e) {
      PyErr_SetString(definition_error.ptr(), e.what());
    } catch (const ukdyn::Error& e) {
      PyErr_SetString(error.ptr(), e.what());
    }
  });

  bind_definitions(m);
  bind_optimize(m);
  bind_size(m);

  py::class_<PyLinearization>(m, "Linearization",
                              "Exact derivatives of qdd and Qc at a state (docs/derivatives.md)")
      .def_readonly("qdd", &PyLinearization::qdd, "qdd of the KKT system, n")
      .def_readonly("Qc", &PyLinearization::Qc, "constraint force, n")
      .def_readonly("dqdd_dq", &PyLinearization::dqdd_dq, "d qdd / d q, n x n")
      .def_readonly("dqdd_dqd", &PyLinearization::dqdd_dqd, "d qdd / d qd, n x n")
      .def_readonly("dqdd_dtau", &PyLinearization::dqdd_dtau, "d qdd / d tau, n x n")
      .def_readonly("dQc_dq", &PyLinearization::dQc_dq, "d Qc / d q, n x n")
      .def_readonly("dQc_dqd", &PyLinearization::dQc_dqd, "d Qc / d qd, n x n")
      .def_readonly("dQc_dtau", &PyLinearization::dQc_dtau, "d Qc / d tau, n x n")
      .def_readonly("dqdd_dt", &PyLinearization::dqdd_dt,
                    "d qdd / d t at fixed (q, qd, tau), n, or None (see time_message)")
      .def_readonly("dQc_dt", &PyLinearization::dQc_dt, "d Qc / d t, n, or None")
      .def_readonly("dmu_dt", &PyLinearization::dmu_dt,
                    "d mu / d t of the kept rows' multipliers, r, or None")
      .def_readonly("time_message", &PyLinearization::time_message,
                    "why d/dt is None ('' when given)")
      .def_readonly("F", &PyLinearization::F, "state matrix of x = (q, qd), 2n x 2n")
      .def_readonly("G", &PyLinearization::G, "input matrix of tau, 2n x n")
      .def_readonly("rank", &PyLinearization::rank, "rank of A")
      .def_readonly("kept_rows", &PyLinearization::kept_rows, "the independent rows used, by name")
      .def_readonly("kkt_agreement", &PyLinearization::kkt_agreement,
                    "max |qdd_KKT - qdd_forward| / (1 + max |qdd_forward|)")
      .def_readonly("trusted", &PyLinearization::trusted,
                    "False where ukdyn cannot vouch for the derivatives (see message)")
      .def_readonly("message", &PyLinearization::message, "why not trusted ('' if trusted)")
      .def_readonly("dt", &PyLinearization::dt, "the step of the discrete model, or None")
      .def_readonly("Fd", &PyLinearization::Fd, "zero-order-hold exp(F dt), 2n x 2n, or None")
      .def_readonly("Gd", &PyLinearization::Gd, "zero-order-hold input matrix, 2n x n, or None")
      .def_readonly("N", &PyLinearization::N,
                    "orthonormal basis of null(A_R), n x k (minimal=True), or None")
      .def_readonly("T", &PyLinearization::T, "x = T z on the manifold, 2n x 2k, or None")
      .def_readonly("D", &PyLinearization::D, "d(A_R qd)/dq, r x n, or None")
      .def_readonly("F_min", &PyLinearization::F_min,
                    "state matrix of z = (N^T dq, N^T dqd), 2k x 2k, or None")
      .def_readonly("G_min", &PyLinearization::G_min, "input matrix of z, 2k x n, or None")
      .def_readonly("Fd_min", &PyLinearization::Fd_min, "discrete F_min (dt), or None")
      .def_readonly("Gd_min", &PyLinearization::Gd_min, "discrete G_min (dt), or None")
      .def_readonly("at_rest", &PyLinearization::at_rest,
                    "qd == 0: the minimal model is time-invariant on the manifold (minimal=True)")
      .def_readonly("rheonomic", &PyLinearization::rheonomic,
                    "a kept row has Phi_t != 0: D's d(Phi_t)/dq by differences (minimal=True)")
      .def_readonly("minimal_note", &PyLinearization::minimal_note,
                    "what the minimal model means away from rest ('' at rest)");

  py::class_<ForwardResult>(m, "ForwardResult",
                            "Forward dynamics at one state (paper Eqs. (4), (11), (18)).")
      .def_readonly("M", &ForwardResult::M, "mass matrix, n x n")
      .def_readonly("C", &ForwardResult::C, "Coriolis matrix C(q, qd), n x n")
      .def_readonly("Cqd", &ForwardResult::Cqd, "C(q, qd) qd, n")
      .def_readonly("G", &ForwardResult::G, "gravity G(q), n")
      .def_readonly("Q", &ForwardResult::Q, "tau + Q_a - C qd - G, n")
      .def_readonly("A", &ForwardResult::A, "constraint matrix, m x n")
      .def_readonly("b", &ForwardResult::b, "constraint right-hand side, m")
      .def_readonly("Qc", &ForwardResult::Qc, "constraint force, n (Eq. (4))")
      .def_readonly("qdd", &ForwardResult::qdd, "accelerations M^-1 (Q + Qc), n (Eq. (18))")
      .def_readonly("rank", &ForwardResult::rank, "numerical rank of A M^-1/2")
      .def_readonly("residual", &ForwardResult::residual, "||A qdd - b||_2")
      .def_readonly("sigma_min", &ForwardResult::sigma_min,
                    "smallest kept singular value (pivot estimate)")
      .def_readonly("sigma_max", &ForwardResult::sigma_max, "largest singular value (estimate)")
      .def_readonly("consistent", &ForwardResult::consistent,
                    "the residual is at round-off level (consistent constraints)")
      .def_readonly("finite", &ForwardResult::finite, "every output is finite")
      .def("__repr__", [](const ForwardResult& r) {
        return "<ukdyn.ForwardResult rank=" + std::to_string(r.rank) +
               " residual=" + std::to_string(r.residual) + ">";
      });

  py::class_<Run, std::shared_ptr<Run>>(m, "Run", R"doc(A simulation run. run["theta1"] is the
column of trajectory.csv of that name as a numpy array; every column is a view of one C++ buffer
(run.data, rows x columns, column-major), nothing is copied.)doc")
      .def_readonly("columns", &Run::columns, "the column names, as in trajectory.csv")
      .def("__getitem__", &Run::column, py::arg("name"), "the column `name` (a view, no copy)")
      .def("__contains__",
           [](const Run& r, const std::string& name) {
             for (const auto& c : r.columns) {
               if (c == name) return true;
             }
             return false;
           })
      .def("__len__", [](const Run& r) { return r.rows; })
      .def("keys", [](const Run& r) { return r.columns; })
      .def_property_readonly("data", &Run::data,
                             "all columns: rows x columns (Fortran order), a view of the buffer")
      .def_property_readonly("rows", [](const Run& r) { return r.rows; })
      .def(
          "wrench",
          [](const Run& r, const std::string& constraint, const std::string& form) {
            const std::string prefix = form == "world"               ? "W_"
                                       : form == "grasp"             ? "Wg_"
                                       : form == "internal_walker"   ? "Wint_walker_"
                                       : form == "internal_weighted" ? "Wint_weighted_"
                                                                     : "";
            if (prefix.empty())
              throw py::value_error(
                  "form must be world, grasp, internal_walker or "
                  "internal_weighted, not '" +
                  form + "'");
            return r.block(prefix + constraint + "_", {"fx", "fy", "fz", "mx", "my", "mz"});
          },
          py::arg("constraint"), py::arg("form") = "world",
          R"doc(The wrench of frame constraint `constraint` on its frame b, rows x 6 (fx, fy, fz,
mx, my, mz; a view of the W_ columns): form "world" (world axes, moment about the frame origin),
"grasp" (the frame's own axes, Wg_), "internal_walker" / "internal_weighted" (the internal part
of a grasp on a load held by two or more welds, Wint_; docs/frame-constraints.md).)doc")
      .def(
          "pose",
          [](const Run& r, const std::string& constraint) {
            return r.block("pose_" + constraint + "_", {"x", "y", "z", "qw", "qx", "qy", "qz"});
          },
          py::arg("constraint"),
          "frame b of frame constraint `constraint`: rows x 7 (x, y, z, qw, qx, qy, qz; the "
          "pose_ columns, a unit quaternion frame -> world with qw >= 0)")
      .def_property_readonly(
          "velocity_level_rows",
          [](const Run& r) {
            std::vector<std::string> rows;
            for (const auto& c : r.columns)
              if (c.rfind("vres_", 0) == 0) rows.push_back(c.substr(5));
            return rows;
          },
          "the nonholonomic constraint rows: their columns are vres_<row> (B qd + c), not res_")
      .def_readonly("summary", &Run::summary,
                    "summary.json of the run as a dict (as `ukdyn simulate` writes it)")
      .def_readonly("warnings", &Run::warnings, "the run's warnings: dicts t, kind, message")
      .def_readonly("status", &Run::status,
                    "completed, non_finite, inconsistent_constraints, step_failure, stopped, "
                    "branch_switch")
      .def_readonly("message", &Run::message, "why the run stopped early (empty if completed)")
      .def_readonly("assembly", &Run::assembly,
                    "simulate(assemble=True): assemble()'s dict (q, qd, residuals), else None")
      .def_readonly("complete", &Run::complete, "the integration reached t_end")
      .def_property_readonly("steps", [](const Run& r) { return r.stats.steps; })
      .def_property_readonly("rhs_evaluations",
                             [](const Run& r) { return r.stats.rhs_evaluations; })
      .def("__repr__", [](const Run& r) {
        return "<ukdyn.Run " + r.status + ", " + std::to_string(r.rows) + " rows x " +
               std::to_string(r.columns.size()) + " columns>";
      });

  py::class_<ControlData>(m, "ControlData", R"doc(What a Python control law sees (besides t, q, qd):
the controller's model at the measured state, as ukdyn's built-in laws see it (docs/control.md).
Every array is a copy (keep it if you like). m = constraint rows of the model (physical and servo),
n = coordinates, k = actuators.)doc")
      .def_readonly("t", &ControlData::t, "time [s]")
      .def_readonly("M", &ControlData::M, "the model's mass matrix, n x n")
      .def_readonly("Q", &ControlData::Q, "tau + Q_a - C qd - G of the model (its own tau), n")
      .def_readonly("A", &ControlData::A, "constraint matrix of all the model's rows, m x n")
      .def_readonly("b", &ControlData::b, "constraint right-hand side, m (A qdd = b)")
      .def_readonly("Qc", &ControlData::Qc,
                    "the model's U-K constraint force for all rows, n (paper Eq. (4))")
      .def_readonly("qdd", &ControlData::qdd, "the model's accelerations M^-1 (Q + Qc), n")
      .def_readonly("phi", &ControlData::phi, "position residuals Phi(q, t) of every row, m")
      .def_readonly("phid", &ControlData::phid, "velocity residuals dPhi/dt of every row, m")
      .def_readonly("servo", &ControlData::servo, "m booleans: the servo rows (role: servo)")
      .def_readonly("B", &ControlData::B, "the actuators' input map tau = B u, n x k")
      .def_readonly("limit", &ControlData::limit, "|u_j| allowed, k (inf: none); u is clipped")
      .def_readonly("tau", &ControlData::tau, "the model's constant forces.tau, n")
      .def_readonly("rank", &ControlData::rank, "numerical rank of the model's A M^-1/2");

  PyScenarioClass scenario_class(m, "Scenario", R"doc(A system with its initial
state, constant forces and run settings: loaded from a YAML scenario (docs/scenario-format.md) or
made from a System built in code (Scenario.from_system).)doc");
  scenario_class
      .def_static(
          "load",
          [](const std::string& path, bool check_initial) {
            ukdyn::LoadOptions o;
            o.check_initial = check_initial;
            return std::make_shared<PyScenario>(PyScenario{ukdyn::load_scenario_file(path, o)});
          },
          py::arg("path"), py::arg("check_initial") = true,
          "Loads and validates a scenario file; raises ukdyn.ScenarioError with "
          "FILE:LINE:COLUMN: key '...': message.")
      .def_static(
          "from_text",
          [](const std::string& text, const std::string& path, bool check_initial) {
            ukdyn::LoadOptions o;
            o.check_initial = check_initial;
            return std::make_shared<PyScenario>(
                PyScenario{ukdyn::load_scenario_text(text, path, o)});
          },
          py::arg("text"), py::arg("path") = "<string>", py::arg("check_initial") = true,
          "Same, from YAML text (`path` is used in messages only).")
      .def_static("from_system", &from_system, py::arg("system"), py::arg("q0"),
                  py::arg("qd0") = py::none(), py::arg("tau") = py::none(), py::arg("t0") = 0.0,
                  py::arg("t_end") = 1.0, py::arg("sample_dt") = 0.01,
                  py::arg("integrator") = "dopri5", py::arg("adaptive") = true,
                  py::arg("abs_tol") = 1e-12, py::arg("rel_tol") = 1e-12, py::arg("step") = 1e-3,
                  py::arg("drift") = "projection", py::arg("energy_balance") = false,
                  py::arg("name") = "python",
                  "A scenario from a System built in code (the system is copied).")
      .def_property_readonly("name", [](const PyScenario& s) { return s.sc.name; })
      .def_property_readonly("path", [](const PyScenario& s) { return s.sc.path.string(); })
      .def_property_readonly("description", [](const PyScenario& s) { return s.sc.description; })
      .def_property_readonly("dof", [](const PyScenario& s) { return s.sc.system->dof(); })
      .def_property_readonly("rows", [](const PyScenario& s) { return s.sc.system->rows(); })
      .def_property_readonly("coordinate_names",
                             [](const PyScenario& s) { return s.sc.system->coordinate_names(); })
      .def_property_readonly(
          "constraint_row_names",
          [](const PyScenario& s) { return s.sc.system->constraint_row_names(); })
      .def_property(
          "q0", [](const PyScenario& s) { return numpy_of(s.sc.q0); },
          [](PyScenario& s, const py::object& v) {
            s.sc.q0 = vector_arg(v, s.sc.system->dof(), "q0");
          },
          "initial coordinates (a copy; assign to change)")
      .def_property(
          "qd0", [](const PyScenario& s) { return numpy_of(s.sc.qd0); },
          [](PyScenario& s, const py::object& v) {
            s.sc.qd0 = vector_arg(v, s.sc.system->dof(), "qd0");
          },
          "initial velocities")
      .def_property(
          "tau", [](const PyScenario& s) { return numpy_of(s.sc.tau); },
          [](PyScenario& s, const py::object& v) {
            s.sc.tau = vector_arg(v, s.sc.system->dof(), "tau");
          },
          "constant generalized forces (forces.tau)")
      .def_property(
          "t0", [](const PyScenario& s) { return s.sc.sim.t0; },
          [](PyScenario& s, double v) {
            require_finite(v, "t0");
            if (!(v < s.sc.sim.t_end))
              throw py::value_error("t0: must be less than t_end (" +
                                    std::to_string(s.sc.sim.t_end) + "); set t_end first");
            s.sc.sim.t0 = v;
          },
          "start time [s] (finite, < t_end)")
      .def_property(
          "t_end", [](const PyScenario& s) { return s.sc.sim.t_end; },
          [](PyScenario& s, double v) {
            require_finite(v, "t_end");
            if (!(v > s.sc.sim.t0))
              throw py::value_error("t_end: must be greater than t0 (" +
                                    std::to_string(s.sc.sim.t0) + ")");
            s.sc.sim.t_end = v;
          },
          "end time [s] (finite, > t0)")
      .def_property(
          "sample_dt", [](const PyScenario& s) { return s.sc.sim.sample_dt; },
          [](PyScenario& s, double v) {
            if (!(std::isfinite(v) && v > 0.0))
              throw py::value_error("sample_dt: must be a finite number > 0");
            s.sc.sim.sample_dt = v;
          },
          "output sample step [s] (> 0)")
      .def_property(
          "abs_tol", [](const PyScenario& s) { return s.sc.sim.abs_tol; },
          [](PyScenario& s, double v) { s.sc.sim.abs_tol = checked_tolerance(v, "abs_tol"); },
          "the integrator's absolute tolerance, in [1e-16, 1] (simulation.abs_tol)")
      .def_property(
          "rel_tol", [](const PyScenario& s) { return s.sc.sim.rel_tol; },
          [](PyScenario& s, double v) { s.sc.sim.rel_tol = checked_tolerance(v, "rel_tol"); },
          "the integrator's relative tolerance, in [1e-16, 1] (simulation.rel_tol)")
      .def_property(
          "initial_tolerance", [](const PyScenario& s) { return s.sc.initial_tolerance; },
          [](PyScenario& s, double v) {
            s.sc.initial_tolerance = checked_tolerance(v, "initial_tolerance");
          },
          "max |Phi|, |Phi_dot| allowed at the start of simulate(), in [1e-16, 1]")
      .def_property(
          "energy_balance", [](const PyScenario& s) { return s.sc.sim.energy_balance; },
          [](PyScenario& s, bool v) { s.sc.sim.energy_balance = v; },
          "integrate W and write the W, E_balance columns")
      .def_property_readonly(
          "actuator_names", [](const PyScenario& s) { return s.sc.actuators.names; },
          "the actuators (`actuators:`), in the order of u")
      .def_property_readonly(
          "control_law",
          [](const PyScenario& s) -> py::object {
            if (!s.sc.control) return py::none();
            return py::str(ukdyn::to_string(s.sc.control->law.kind));
          },
          "the built-in law of the control: section (feedforward, stabilized, robust), or None")
      .def_property_readonly("integrator",
                             [](const PyScenario& s) { return to_string(s.sc.sim.integrator); })
      .def(
          "forward", &forward, py::arg("t"), py::arg("q"), py::arg("qd"),
          py::arg("tau") = py::none(), py::arg("forces") = std::vector<py::object>{},
          R"doc(Forward dynamics at (t, q, qd) with generalized forces tau (default 0): M, C, Cqd, G,
Q, A, b, Qc, qdd, rank, residual as `ukdyn eval` answers them. forces: Python callables
f(t, q, qd) -> Q_a (n numbers) added as applied forces.)doc")
      .def("linearize", &linearize, py::arg("t"), py::arg("q"), py::arg("qd"),
           py::arg("tau") = py::none(), py::kw_only(), py::arg("minimal") = false,
           py::arg("dt") = py::none(), py::arg("forces") = std::vector<py::object>{},
           R"doc(Exact derivatives of qdd and Qc at (t, q, qd) with generalized forces tau (default
0): implicit differentiation of the KKT form of the U-K equation over the model's exact tangents
(no finite differences). Check .trusted: False at or near a singular position, after a damped
solve, or with inconsistent constraints (.message says which). Raises ukdyn.Error naming a
component without exact derivatives. minimal=True: also N, T, D, F_min, G_min, the model in
z = (N^T dq, N^T dqd) on the constraint manifold (raises ukdyn.Error for velocity-level rows).
dt: also the zero-order-hold Fd, Gd (and Fd_min, Gd_min). forces: Python applied forces
f(t, q, qd) -> Q_a as in forward(), with their exact derivatives as methods f.dQ_dq(t, q, qd) and
f.dQ_dqd(t, q, qd) (n x n each; without them: ukdyn.Error) and, for dqdd_dt, f.dQ_dt(t, q, qd)
(n; without it dqdd_dt is None, time_message naming the force). docs/derivatives.md.)doc")
      .def("simulate", &simulate, py::arg("controller") = py::none(),
           py::arg("forces") = std::vector<py::object>{}, py::kw_only(),
           py::arg("control_law") = py::none(), py::arg("q0") = py::none(),
           py::arg("qd0") = py::none(), py::arg("t0") = py::none(), py::arg("t_end") = py::none(),
           py::arg("assemble") = false,
           R"doc(Runs the scenario as `ukdyn simulate` does (same samples, columns and summary), in
memory. controller: u(t, q, qd) -> n numbers, added to the constant tau. forces: callables
f(t, q, qd) -> Q_a (n numbers), applied forces (non-conservative). A scenario with a control:
section runs its closed loop (the plant integrated, the controller on the model; the columns
u_*, e_*, ed_*, Qp_*, Qs_* and summary["control"] as `ukdyn simulate` writes them);
control_law: law(t, q, qd, data) -> u (one number per actuator), or an object with a method
control(t, q, qd, data), replaces its built-in law; data is a ControlData (the model's M, Q, A,
b, Qc, qdd, phi, phid at the measured state, the servo-row mask, B, limits). The GIL is released
while C++ runs and taken back for each call of a callable; an exception raised there ends the run
and is re-raised here with its type. q0, qd0, t0, t_end: the start and the end of this run (else the
scenario's). The start must satisfy the constraints (|Phi|, |Phi_dot| <= initial_tolerance), else
ValueError naming the rows and their residuals; assemble=True starts from assemble()'s state
instead (run.assembly says what it did). Ctrl-C stops the run and raises KeyboardInterrupt.)doc")
      .def(
          "assemble",
          [](const PyScenario& s) {
            ukdyn::AssemblyResult a;
            {
              py::gil_scoped_release release;
              a = ukdyn::assemble(*s.sc.system, s.sc.sim.t0, s.sc.q0, s.sc.qd0, s.sc.held);
            }
            return assembly_dict(a);
          },
          "The consistent (q, qd) nearest to (q0, qd0), holding initial.hold, as `ukdyn "
          "assemble` finds it: a dict q, qd, success, iterations, residuals, message.")
      .def("__repr__", [](const PyScenario& s) {
        return "<ukdyn.Scenario '" + s.sc.name + "', " + std::to_string(s.sc.system->dof()) +
               " coordinates, " + std::to_string(s.sc.system->rows()) + " constraint rows>";
      });
  bind_state(m, scenario_class);
  bind_sensitivity(m, scenario_class);
}
