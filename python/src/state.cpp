// The Python module ukdyn (docs/python.md): the fast path of forward dynamics (a reusable Data whose
// numpy arrays are views of a ukdyn::ForwardData, a q̈-only call, a batch over (k, n) arrays) and
// the quantities of one state: T, V, E; Φ, Φ̇, A, b and the ranks; the constrained inverse
// dynamics. Every input is checked (sizes, NaN / Inf) and every result too: nothing non-finite
// is handed back silently.
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/stl.h>

#include <Eigen/SVD>
#include <cmath>
#include <limits>
#include <memory>
#include <string>

#include "scenario_bindings.hpp"
#include "ukdyn/core/force_split.hpp"
#include "ukdyn/model/system.hpp"
#include "ukdyn/output/geometry.hpp"
#include "ukdyn/simulate/control.hpp"
#include "ukdyn/tree/tree.hpp"

namespace ukdyn_python {

namespace {

using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;
using CMap = Eigen::Map<const Vec>;
using DoubleArray = py::array_t<double, py::array::c_style | py::array::forcecast>;

// ---------------------------------------------------------------------------- Data

// numpy views of a ForwardData's Eigen buffers (column-major), kept alive by `owner`.
py::array vector_view(Vec& v, const py::capsule& owner) {
  if (v.size() == 0) return py::array_t<double>(0);
  return py::array_t<double>({v.size()}, {static_cast<py::ssize_t>(sizeof(double))}, v.data(),
                             owner);
}
py::array matrix_view(Mat& m, const py::capsule& owner) {
  if (m.size() == 0) return py::array_t<double>({m.rows(), m.cols()});
  const auto s = static_cast<py::ssize_t>(sizeof(double));
  return py::array_t<double>({m.rows(), m.cols()}, {s, s * m.rows()}, m.data(), owner);
}

// A ForwardData for one scenario's system, reused from call to call. Its arrays (M, Cqd, G, Q, A,
// b, Qc, qdd) are numpy views of the ForwardData's own buffers (Eigen, column-major: M and A are
// Fortran-ordered), made once: forward(..., out=data) writes into them and allocates nothing.
struct PyData {
  std::shared_ptr<const ukdyn::System> system;
  std::shared_ptr<ukdyn::ForwardData> data;
  Vec zero_tau;
  py::array M, Cqd, G, Q, A, b, Qc, qdd;
  double t = std::numeric_limits<double>::quiet_NaN();

  explicit PyData(std::shared_ptr<const ukdyn::System> sys)
      : system(std::move(sys)),
        data(std::make_shared<ukdyn::ForwardData>(*system)),
        zero_tau(Vec::Zero(system->dof())) {
    // The capsule keeps the ForwardData alive as long as any view of it.
    auto* keep = new std::shared_ptr<ukdyn::ForwardData>(data);
    const py::capsule owner(
        keep, [](void* p) { delete static_cast<std::shared_ptr<ukdyn::ForwardData>*>(p); });
    ukdyn::ForwardData& d = *data;
    M = matrix_view(d.M, owner);
    A = matrix_view(d.A, owner);
    Cqd = vector_view(d.Cqd, owner);
    G = vector_view(d.G, owner);
    Q = vector_view(d.Q, owner);
    b = vector_view(d.b, owner);
    Qc = vector_view(d.Qc, owner);
    qdd = vector_view(d.qdd, owner);
  }
};

PyData& data_for(const PyScenario& s, const py::object& out, const char* what) {
  PyData* d = nullptr;
  try {
    d = &out.cast<PyData&>();
  } catch (const py::cast_error&) {
    throw py::type_error(std::string(what) + ": expected a ukdyn.Data (Scenario.make_data())");
  }
  if (d->system.get() != s.sc.system.get()) {
    throw py::value_error(std::string(what) + ": this Data was made for another scenario ('" +
                          std::string("make it with this scenario's make_data()") + "')");
  }
  return *d;
}

// The checks `ukdyn eval` makes of a result (src/run/eval_protocol.cpp), those that cost nothing:
// a singular M that the constraints do not make up for, a non-finite q̈ or Qc. nullptr if none.
const char* result_problem(const ukdyn::ForwardData& d) {
  if (d.singular.rank_deficient) {
    return "the mass matrix M is singular and the constraints do not fix the undetermined "
           "directions ([M; A] is rank deficient) at this state";
  }
  if (!d.result.finite || !d.qdd.allFinite() || !d.Qc.allFinite()) {
    return "non-finite result at this state (M not positive definite, or non-finite M, A, b, "
           "forces or accelerations)";
  }
  return nullptr;
}

void check_result(const ukdyn::ForwardData& d, const std::string& where) {
  if (const char* p = result_problem(d)) throw ukdyn::Error(where + ": " + p);
}

// forward(q, qd, t=..., tau=..., out=data): into data's buffers; returns data.
py::object forward_into(const PyScenario& s, const py::object& q_in, const py::object& qd_in,
                        const py::object& out, double t, const py::object& tau_in) {
  PyData& d = data_for(s, out, "out");
  const Index n = s.sc.system->dof();
  require_finite(t, "t");
  const DoubleArray q = checked_vector(q_in, n, "q");
  const DoubleArray qd = checked_vector(qd_in, n, "qd");
  py::object keep_tau;  // no array made when tau is None
  const double* tau = d.zero_tau.data();
  if (!tau_in.is_none()) {
    const DoubleArray a = checked_vector(tau_in, n, "tau");
    tau = a.data();
    keep_tau = a;
  }
  {
    py::gil_scoped_release release;
    ukdyn::forward(*s.sc.system, *d.data, t, CMap(q.data(), n), CMap(qd.data(), n), CMap(tau, n),
                   s.sc.sim.uk);
  }
  d.t = t;
  check_result(*d.data, "forward");
  return out;
}

// ---------------------------------------------------------------------------- q̈ only, batches

// A (k, n) or (n,) float64 C-contiguous array of finite numbers; k = 0 for (n,).
DoubleArray checked_rows(const py::object& v, Index n, const char* what, Index& k) {
  const auto a = DoubleArray::ensure(v);
  if (!a) {
    PyErr_Clear();
    throw py::type_error(std::string(what) + ": expected an array of shape (n,) or (k, n)");
  }
  if (a.ndim() == 1 && a.shape(0) == n) {
    k = 0;
  } else if (a.ndim() == 2 && a.shape(1) == n) {
    k = a.shape(0);
  } else {
    throw py::value_error(std::string(what) + ": expected shape (" + std::to_string(n) +
                          ",) or (k, " + std::to_string(n) + "), got " +
                          py::repr(a.attr("shape")).cast<std::string>());
  }
  const double* p = a.data();
  for (py::ssize_t i = 0; i < a.size(); ++i) {
    if (!std::isfinite(p[i])) {
      const std::string at =
          a.ndim() == 1 ? std::to_string(i) : std::to_string(i / n) + ", " + std::to_string(i % n);
      throw py::value_error(std::string(what) + "[" + at + "]: not finite (" +
                            std::to_string(p[i]) + ")");
    }
  }
  return a;
}

// Rows of a batch: q, qd (k, n), tau None / (n,) / (k, n), t a number or k numbers. The arrays
// are held (keep_*), read through pointers; k = 0 for one state of shape (n,).
struct Batch {
  Index n = 0, k = 0;
  py::object keep_q, keep_qd, keep_tau, keep_t;
  const double *q = nullptr, *qd = nullptr, *tau = nullptr, *t = nullptr;
  bool tau_rows = false, t_rows = false;
  double t_scalar = 0.0;
  [[nodiscard]] CMap q_row(Index i) const { return {q + i * n, n}; }
  [[nodiscard]] CMap qd_row(Index i) const { return {qd + i * n, n}; }
  [[nodiscard]] CMap tau_row(Index i, const Vec& zero) const {
    return tau ? CMap(tau + (tau_rows ? i * n : 0), n) : CMap(zero.data(), n);
  }
  [[nodiscard]] double t_at(Index i) const { return t ? t[t_rows ? i : 0] : t_scalar; }
};

Batch batch_of(const PyScenario& s, const py::object& q_in, const py::object& qd_in,
               const py::object& t_in, const py::object& tau_in) {
  Batch b;
  b.n = s.sc.system->dof();
  Index kq = 0, kqd = 0;
  const DoubleArray q = checked_rows(q_in, b.n, "q", kq);
  const DoubleArray qd = checked_rows(qd_in, b.n, "qd", kqd);
  if (kq != kqd || q.ndim() != qd.ndim()) throw py::value_error("q and qd: not the same shape");
  b.k = kq;
  b.q = q.data();
  b.qd = qd.data();
  b.keep_q = q;
  b.keep_qd = qd;
  if (py::isinstance<py::float_>(t_in) || py::isinstance<py::int_>(t_in)) {
    b.t_scalar = t_in.cast<double>();  // a number: no array made
    require_finite(b.t_scalar, "t");
  } else {
    const DoubleArray t = DoubleArray::ensure(t_in);  // k numbers (or a 0-d array)
    if (!t || t.ndim() > 1 || (t.ndim() == 1 && t.size() != std::max<Index>(b.k, 1))) {
      PyErr_Clear();
      throw py::value_error("t: expected a number or one number per row of q");
    }
    b.t_rows = t.ndim() == 1;
    for (py::ssize_t i = 0; i < t.size(); ++i) {
      if (!std::isfinite(t.data()[i])) throw py::value_error("t: not finite");
    }
    b.t = t.data();
    b.keep_t = t;
  }
  if (!tau_in.is_none()) {
    Index ktau = 0;
    const DoubleArray tau = checked_rows(tau_in, b.n, "tau", ktau);
    b.tau_rows = tau.ndim() == 2;
    if (b.tau_rows && ktau != b.k) throw py::value_error("tau: not one row per row of q");
    b.tau = tau.data();
    b.keep_tau = tau;
  }
  return b;
}

// forward_qdd: q̈ of each row of (q, qd) into out (allocated if None), with data's buffers
// (a Data made here if None). Each row is one forward() call: bit for bit the single call.
py::object forward_qdd(const PyScenario& s, const py::object& q_in, const py::object& qd_in,
                       const py::object& t_in, const py::object& tau_in, const py::object& out,
                       const py::object& data_in) {
  const Batch b = batch_of(s, q_in, qd_in, t_in, tau_in);
  const Index rows = std::max<Index>(b.k, 1);
  py::object result = out;
  double* o = nullptr;
  if (out.is_none()) {
    py::array_t<double> r = b.k == 0 ? py::array_t<double>(b.n) : py::array_t<double>({b.k, b.n});
    o = r.mutable_data();
    result = r;
  } else {
    // out must be the array itself (no converted copy): a float64, C-contiguous, writeable array.
    const bool ok = py::isinstance<py::array_t<double>>(out) &&
                    (py::array(out).flags() & py::array::c_style) && py::array(out).writeable() &&
                    py::array(out).size() == rows * b.n;
    if (!ok) {
      throw py::value_error("out: expected a writeable C-contiguous float64 array of " +
                            std::to_string(rows * b.n) + " numbers (the shape of q)");
    }
    o = static_cast<double*>(py::array(out).mutable_data());
  }
  std::unique_ptr<PyData> own;
  PyData* d = nullptr;
  if (data_in.is_none()) {
    own = std::make_unique<PyData>(s.sc.system);
    d = own.get();
  } else {
    d = &data_for(s, data_in, "data");
  }
  {
    py::gil_scoped_release release;
    for (Index i = 0; i < rows; ++i) {
      ukdyn::forward(*s.sc.system, *d->data, b.t_at(i), b.q_row(i), b.qd_row(i),
                     b.tau_row(i, d->zero_tau), s.sc.sim.uk);
      if (result_problem(*d->data)) {
        check_result(*d->data, b.k > 0 ? "forward_qdd: row " + std::to_string(i) : "forward_qdd");
      }
      std::copy(d->data->qdd.data(), d->data->qdd.data() + b.n, o + i * b.n);
    }
  }
  return result;
}

// forward_batch: qdd, Qc (k, n), rank, residual, consistent (k) of each row.
py::dict forward_batch(const PyScenario& s, const py::object& q_in, const py::object& qd_in,
                       const py::object& t_in, const py::object& tau_in) {
  const Batch b = batch_of(s, q_in, qd_in, t_in, tau_in);
  if (b.k == 0 && py::array(b.keep_q).ndim() != 2)
    throw py::value_error("forward_batch: q and qd must be (k, n) arrays");
  py::array_t<double> qdd({b.k, b.n}), Qc({b.k, b.n}), residual(b.k);
  py::array_t<int> rank(b.k);
  py::array_t<bool> consistent(b.k);
  PyData d(s.sc.system);
  double* pq = qdd.mutable_data();
  double* pc = Qc.mutable_data();
  {
    py::gil_scoped_release release;
    for (Index i = 0; i < b.k; ++i) {
      ukdyn::forward(*s.sc.system, *d.data, b.t_at(i), b.q_row(i), b.qd_row(i),
                     b.tau_row(i, d.zero_tau), s.sc.sim.uk);
      if (result_problem(*d.data)) check_result(*d.data, "forward_batch: row " + std::to_string(i));
      std::copy(d.data->qdd.data(), d.data->qdd.data() + b.n, pq + i * b.n);
      std::copy(d.data->Qc.data(), d.data->Qc.data() + b.n, pc + i * b.n);
      residual.mutable_data()[i] = d.data->result.residual;
      rank.mutable_data()[i] = d.data->result.rank;
      consistent.mutable_data()[i] = d.data->result.consistent;
    }
  }
  py::dict r;
  r["qdd"] = qdd;
  r["Qc"] = Qc;
  r["rank"] = rank;
  r["residual"] = residual;
  r["consistent"] = consistent;
  return r;
}

// ---------------------------------------------------------------------------- quantities

py::array_t<double> array_of(const Vec& v) {
  py::array_t<double> a(v.size());
  std::copy(v.data(), v.data() + v.size(), a.mutable_data());
  return a;
}

// T = ½ q̇ᵀ M q̇, V = Σ V_k(q, t) + the applied forces' potentials, E = T + V: the T, V, E columns
// of trajectory.csv (src/run/run_observer.cpp).
py::dict energies(const PyScenario& s, const py::object& q_in, const py::object& qd_in, double t) {
  require_finite(t, "t");
  const ukdyn::System& sys = *s.sc.system;
  const Vec q = vector_arg(q_in, sys.dof(), "q");
  const Vec qd = vector_arg(qd_in, sys.dof(), "qd");
  ukdyn::ForwardData d(sys);
  ukdyn::evaluate_dynamics(sys, d, t, q, qd);
  const double T = ukdyn::kinetic_energy(d, qd);
  const double V = ukdyn::potential_energy(sys, t, q);
  if (!std::isfinite(T) || !std::isfinite(V))
    throw ukdyn::Error("energies: non-finite T or V at this state");
  py::dict r;
  r["T"] = T;
  r["V"] = V;
  r["E"] = T + V;
  return r;
}

// World positions of the system's named points at q (ukdyn/output/geometry.hpp: what the replay
// page draws: platforms, joints, cut points and grasps of the paper's arms, link frame origins and
// named points of chains and URDF / MJCF arms, centres of mass of definitions bodies).
py::dict points(const PyScenario& s, const py::object& q_in) {
  const Vec q = vector_arg(q_in, s.sc.system->dof(), "q");
  const ukdyn::Geometry g = ukdyn::build_geometry(s.sc);
  std::vector<ukdyn::Vec3> pos;
  g.evaluate(q, pos);
  py::dict r;
  for (std::size_t i = 0; i < pos.size(); ++i) {
    if (!pos[i].allFinite())
      throw ukdyn::Error("points: non-finite position of '" + g.points()[i].name + "'");
    r[py::str(g.points()[i].name)] = array_of(pos[i]);
  }
  return r;
}

// ---------------------------------------------------------------------------- frames

// A link frame of a tree subsystem (URDF / MJCF arms, serial chains on the recursive algorithms,
// ukdyn/tree/tree.hpp), named "<subsystem>.<link>".
struct FrameRef {
  const ukdyn::tree::TreeSubsystem* tree = nullptr;
  Index offset = 0;  // the subsystem's first coordinate in q
  int link = -2;
};

std::vector<std::string> frame_names(const PyScenario& s) {
  std::vector<std::string> names;
  for (const auto& sub : s.sc.system->subsystems()) {
    if (const auto* t = dynamic_cast<const ukdyn::tree::TreeSubsystem*>(sub.get())) {
      for (const auto& l : t->model().links) names.push_back(t->name() + "." + l.name);
    }
  }
  return names;
}

FrameRef find_frame(const PyScenario& s, const std::string& name) {
  const ukdyn::System& sys = *s.sc.system;
  for (std::size_t k = 0; k < sys.subsystems().size(); ++k) {
    const auto* t = dynamic_cast<const ukdyn::tree::TreeSubsystem*>(sys.subsystems()[k].get());
    const std::string prefix = t ? t->name() + "." : std::string();
    if (!t || name.rfind(prefix, 0) != 0) continue;
    const int link = t->link_index(name.substr(prefix.size()));
    if (link >= -1) return {t, sys.layout().start[k], link};
  }
  std::string known;
  for (const auto& n : frame_names(s)) {
    if (!known.empty()) known += ", ";
    known += n;
  }
  throw py::key_error("frame '" + name + "': no such frame (the frames of tree subsystems are " +
                      (known.empty() ? std::string("none") : known) + ")");
}

// vee(S) of a skew-symmetric S: S x = vee(S) × x.
Eigen::Vector3d vee(const Eigen::Matrix3d& S) { return {S(2, 1), S(0, 2), S(1, 0)}; }

// The pose, velocity and Jacobians of a link frame at (q, q̇), in the world frame, from the tree's
// frame_state (its recursive pass): p, R (x_world = R x_link + p), v = ṗ, ω = vee(Ṙ Rᵀ), and over
// all n coordinates of the system J_p = ∂p/∂q (3 × n) and J_ω (3 × n, column j = vee(∂R/∂q_j Rᵀ)),
// so that v = J_p q̇ and ω = J_ω q̇.
py::dict frame(const PyScenario& s, const std::string& name, const py::object& q_in,
               const py::object& qd_in) {
  const Index n = s.sc.system->dof();
  const Vec q = vector_arg(q_in, n, "q");
  const Vec qd = qd_in.is_none() ? Vec(Vec::Zero(n)) : vector_arg(qd_in, n, "qd");
  const FrameRef f = find_frame(s, name);
  const Index k = f.tree->dof();
  std::vector<double> dp(static_cast<std::size_t>(3 * k)), dR(static_cast<std::size_t>(9 * k));
  ukdyn::tree::FrameState st(dp.data(), dR.data(), k);
  f.tree->frame_state(q.segment(f.offset, k), qd.segment(f.offset, k), f.link,
                      Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero(), {}, st);
  Mat Jp = Mat::Zero(3, n), Jw = Mat::Zero(3, n);
  Jp.middleCols(f.offset, k) = st.dp;
  for (Index j = 0; j < k; ++j) {
    Eigen::Matrix3d dRj;  // column j of dR: ∂R/∂q_j, row-major
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) dRj(a, b) = st.dR(3 * a + b, j);
    }
    Jw.col(f.offset + j) = vee(dRj * st.R.transpose());
  }
  const Eigen::Vector3d omega = vee(st.Rd * st.R.transpose());
  if (!st.p.allFinite() || !st.R.allFinite() || !Jp.allFinite() || !Jw.allFinite())
    throw ukdyn::Error("frame '" + name + "': non-finite pose or Jacobian at this state");
  py::dict r;
  r["p"] = array_of(st.p);
  r["R"] = py::cast(Mat(st.R));
  r["v"] = array_of(st.pd);
  r["omega"] = array_of(omega);
  r["Jp"] = py::cast(Jp);
  r["Jw"] = py::cast(Jw);
  return r;
}

// Φ(q, t), Φ̇ = A q̇ + Φ_t, A and b (A q̈ = b, paper Eq. (2)) with the rank of A (SVD, singular
// values over 1e-10 σ_max) and of A M^{-1/2} (the U-K solve's, the `rank` column).
py::dict constraints(const PyScenario& s, const py::object& q_in, const py::object& qd_in,
                     double t) {
  require_finite(t, "t");
  const ukdyn::System& sys = *s.sc.system;
  const Index n = sys.dof(), m = sys.rows();
  const Vec q = vector_arg(q_in, n, "q");
  const Vec qd = vector_arg(qd_in, n, "qd");
  ukdyn::ForwardData d(sys);
  Vec phi(m), phid(m);
  ukdyn::position_residuals(sys, d, t, q, phi);
  ukdyn::velocity_residuals(sys, d, t, q, qd, phid);
  ukdyn::forward(sys, d, t, q, qd, Vec::Zero(n), s.sc.sim.uk);
  check_result(d, "constraints");
  int rank_A = 0;
  if (m > 0) {
    const Eigen::JacobiSVD<Mat> svd(d.A);
    const Vec& sv = svd.singularValues();
    for (Index i = 0; i < sv.size(); ++i) rank_A += sv(i) > 1e-10 * sv(0) ? 1 : 0;
  }
  if (!phi.allFinite() || !phid.allFinite() || !d.A.allFinite() || !d.b.allFinite())
    throw ukdyn::Error("constraints: non-finite Phi, Phi_dot, A or b at this state");
  py::dict r;
  r["phi"] = array_of(phi);
  r["phid"] = array_of(phid);
  r["A"] = py::cast(d.A);
  r["b"] = array_of(d.b);
  r["rank"] = rank_A;
  r["rank_uk"] = d.result.rank;
  r["free_dof"] = n - rank_A;
  r["rows"] = sys.constraint_row_names();
  return r;
}

// The constrained inverse dynamics at (t, q, q̇, q̈) with A q̈ = b: the generalized force τ of least
// norm and the constraint force Qc with M q̈ = τ + Q(0) + Qc, Qc = Aᵀλ (Q(0) = Q_a − C q̇ − G).
// With r = M q̈ − Q(0) this is the actuation problem of the control code (core/force_split.hpp,
// solve_actuation) with B = I (every coordinate actuated) and A_p = A (every row enforced by the
// structure): τ = P r, P the projector onto null(A), and λ = (Aᵀ)⁺ (r − τ). P and (Aᵀ)⁺ come from
// one SVD of A with the rank cut at 1e-10 σ_max (solve_actuation's rel_tol). (solve_actuation
// itself is not used: with B = I and A of full column rank, P B is round-off, and its relative
// rank threshold keeps that round-off as rank n.) Forward dynamics with that τ gives back q̈: the
// U-K q̈ is the unique solution of the KKT system [Udwadia1992].
struct InverseDynamics {
  Vec tau, Qc, lambda;
  double residual = 0.0;
};

InverseDynamics least_norm_tau(const Mat& A, const Vec& r) {
  const Index n = r.size(), m = A.rows();
  InverseDynamics out;
  out.tau = r;
  out.lambda = Vec::Zero(m);
  if (m > 0) {
    const Eigen::JacobiSVD<Mat> svd(A, Eigen::ComputeFullU | Eigen::ComputeFullV);
    const Vec& sv = svd.singularValues();
    Index rank = 0;
    while (rank < sv.size() && sv(rank) > 1e-10 * sv(0)) ++rank;
    const Mat& V = svd.matrixV();
    const Mat N = V.rightCols(n - rank);  // null(A)
    out.tau = N * (N.transpose() * r);
    // λ = U_r Σ_r⁻¹ V_rᵀ (r − τ): the least-norm λ with Aᵀλ = r − τ.
    const Vec y = V.leftCols(rank).transpose() * (r - out.tau);
    out.lambda = svd.matrixU().leftCols(rank) * y.cwiseQuotient(sv.head(rank));
  }
  out.Qc = r - out.tau;
  out.residual = (out.tau + A.transpose() * out.lambda - r).norm();
  return out;
}

// With the scenario's actuators (`actuators:`, τ = B u, docs/control.md): the least-norm u that
// realises q̈ on a plant enforcing only the physical rows, B u + A_pᵀμ = r, by the control code's
// solve_actuation() (core/force_split.hpp); `underactuated` when its residual is not round-off.
void add_actuation(const ukdyn::Scenario& sc, const Mat& A, const Vec& r, py::dict& out) {
  if (sc.actuators.count() == 0) return;
  const std::vector<bool> servo = ukdyn::servo_row_flags(*sc.system, sc.constraint_roles);
  const ukdyn::Actuation act =
      ukdyn::solve_actuation(sc.actuators.B, ukdyn::select_rows(A, servo, false), r);
  out["u"] = array_of(act.u);
  out["mu"] = array_of(act.mu);
  out["actuation_residual"] = act.residual;
  out["underactuated"] = act.underactuated;
}

py::dict inverse_dynamics(const PyScenario& s, const py::object& q_in, const py::object& qd_in,
                          const py::object& qdd_in, double t, double tol) {
  require_finite(t, "t");
  if (!(tol >= 0.0 && std::isfinite(tol))) throw py::value_error("tol: expected a finite tol >= 0");
  const ukdyn::System& sys = *s.sc.system;
  const Index n = sys.dof(), m = sys.rows();
  const Vec q = vector_arg(q_in, n, "q");
  const Vec qd = vector_arg(qd_in, n, "qd");
  const Vec qdd = vector_arg(qdd_in, n, "qdd");
  ukdyn::ForwardData d(sys);
  ukdyn::forward(sys, d, t, q, qd, Vec::Zero(n), s.sc.sim.uk);
  check_result(d, "inverse_dynamics");
  const Vec acc = d.A * qdd - d.b;  // on the manifold: A q̈ = b
  Index worst = 0;
  const double acc_res = m > 0 ? acc.cwiseAbs().maxCoeff(&worst) : 0.0;
  if (m > 0 && !(acc_res <= tol * (1.0 + d.b.cwiseAbs().maxCoeff()))) {
    throw py::value_error(
        "inverse_dynamics: qdd is not on the constraint manifold: |A qdd - b| = " +
        std::to_string(acc_res) + " at row '" +
        sys.constraint_row_names()[static_cast<std::size_t>(worst)] + "' (tol " +
        std::to_string(tol) + " x (1 + max|b|))");
  }
  const Vec r = d.M * qdd - d.Q;
  const InverseDynamics inv = least_norm_tau(d.A, r);
  py::dict out;
  out["tau"] = array_of(inv.tau);
  out["Qc"] = array_of(inv.Qc);
  out["lambda"] = array_of(inv.lambda);
  out["acc_residual"] = acc_res;
  out["residual"] = inv.residual;
  add_actuation(s.sc, d.A, r, out);
  return out;
}

}  // namespace

// long function bind_state: the binding table of this file (one .def per function), declarative.
void bind_state(py::module_& m, PyScenarioClass& cls) {
  py::class_<PyData, std::shared_ptr<PyData>>(m, "Data", R"doc(Reusable buffers of forward dynamics
for one scenario (Scenario.make_data()): forward(q, qd, t=..., out=data) writes into them and
allocates nothing. The arrays are views of the C++ buffers, refreshed in place by every call:
copy them to keep a value.)doc")
      .def_readonly("M", &PyData::M, "mass matrix, n x n (Fortran order)")
      .def_readonly("Cqd", &PyData::Cqd, "C(q, qd) qd, n")
      .def_readonly("G", &PyData::G, "gravity G(q), n")
      .def_readonly("Q", &PyData::Q, "tau + Q_a - C qd - G, n")
      .def_readonly("A", &PyData::A, "constraint matrix, m x n (Fortran order)")
      .def_readonly("b", &PyData::b, "constraint right-hand side, m")
      .def_readonly("Qc", &PyData::Qc, "constraint force, n (Eq. (4))")
      .def_readonly("qdd", &PyData::qdd, "accelerations, n (Eq. (18))")
      .def_readonly("t", &PyData::t, "the time of the last call (nan before the first)")
      .def_property_readonly("rank", [](const PyData& d) { return d.data->result.rank; })
      .def_property_readonly("residual", [](const PyData& d) { return d.data->result.residual; })
      .def_property_readonly("consistent",
                             [](const PyData& d) { return d.data->result.consistent; })
      .def_property_readonly("sigma_min",
                             [](const PyData& d) { return d.data->result.sigma_min_kept; });

  cls.def(
         "make_data", [](const PyScenario& s) { return std::make_shared<PyData>(s.sc.system); },
         "A reusable Data for forward(q, qd, t=..., out=data) and forward_qdd(..., data=data).")
      .def("forward", &forward_into, py::arg("q"), py::arg("qd"), py::arg("out"),
           py::arg("t") = 0.0, py::arg("tau") = py::none(),
           "Forward dynamics into out (a Data): no allocation; returns out. Called with keywords "
           "(out=, t=, tau=) Python makes a transient dict for them; positionally, nothing at "
           "all. Raises ValueError for "
           "non-finite inputs, ukdyn.Error for a singular M or a non-finite result.")
      .def(
          "forward_qdd", &forward_qdd, py::arg("q"), py::arg("qd"), py::arg("t") = 0.0,
          py::arg("tau") = py::none(), py::arg("out") = py::none(), py::arg("data") = py::none(),
          "qdd only: q, qd of shape (n,) or (k, n) (a batch, row by row); t a number or k numbers; "
          "tau None, (n,) or (k, n). out: a C-contiguous float64 array of q's shape to write into "
          "(returned). data: a Data to reuse (else one is made per call).")
      .def("forward_batch", &forward_batch, py::arg("q"), py::arg("qd"), py::kw_only(),
           py::arg("t") = 0.0, py::arg("tau") = py::none(),
           "Forward dynamics of each row of (k, n) arrays: a dict qdd, Qc (k x n), rank, residual, "
           "consistent (k); row i is bit for bit forward() of row i.")
      .def("points", &points, py::arg("q"),
           "World positions (3 numbers each) of the system's named points at q, as the replay "
           "page draws them: a dict name -> array.")
      .def_property_readonly("frame_names", &frame_names,
                             "the link frames of tree subsystems (URDF / MJCF arms, chains), "
                             "'<subsystem>.<link>'")
      .def("frame", &frame, py::arg("name"), py::arg("q"), py::arg("qd") = py::none(),
           "Pose, velocity and Jacobians of a link frame in the world frame: a dict p (3), R "
           "(3 x 3, x_world = R x_link + p), v, omega (3), Jp, Jw (3 x n: v = Jp qd, omega = Jw "
           "qd). KeyError naming the frames for an unknown name.")
      .def("energies", &energies, py::arg("q"), py::arg("qd"), py::kw_only(), py::arg("t") = 0.0,
           "T, V, E at (t, q, qd), as the T, V, E columns of trajectory.csv: a dict.")
      .def("constraints", &constraints, py::arg("q"), py::arg("qd"), py::kw_only(),
           py::arg("t") = 0.0,
           "phi, phid, A, b (A qdd = b), rank (of A), rank_uk (of A M^-1/2, the rank column), "
           "free_dof, rows (names) at (t, q, qd): a dict.")
      .def(
          "inverse_dynamics", &inverse_dynamics, py::arg("q"), py::arg("qd"), py::arg("qdd"),
          py::kw_only(), py::arg("t") = 0.0, py::arg("tol") = 1e-9,
          "Constrained inverse dynamics: for qdd on the manifold (|A qdd - b| <= tol (1 + max|b|), "
          "else ValueError), the least-norm tau and the constraint force Qc = A^T lambda with "
          "M qdd = tau + Q_a - C qd - G + Qc: a dict tau, Qc, lambda, acc_residual, residual; with "
          "actuators (tau = B u), also u, mu (the physical rows' multipliers), "
          "actuation_residual, underactuated (docs/control.md).");
}

}  // namespace ukdyn_python
