// Problem checks and the IPOPT driver of the collocation NLP (ukdyn/optimize/trajectory.hpp).
// IPOPT (Wächter & Biegler, Math. Program. 106, 2006) through its TNLP interface, version 3.11
// from Debian (coinor-libipopt-dev, MUMPS as the linear solver); optional at build time.
#include "ukdyn/optimize/trajectory.hpp"

#include <cmath>
#include <tuple>

#include "optimize/transcription.hpp"
#include "ukdyn/model/constraint_jacobians.hpp"
#include "ukdyn/model/linearize.hpp"
#include "ukdyn/simulate/diagnostics.hpp"

#if UKDYN_HAVE_IPOPT
#include <IpIpoptApplication.hpp>
#include <IpRegOptions.hpp>
#include <IpSolveStatistics.hpp>
#include <IpTNLP.hpp>
#endif

namespace ukdyn {

std::string to_string(CollocationMethod method) {
  return method == CollocationMethod::trapezoidal ? "trapezoidal" : "hermite_simpson";
}

namespace {

using detail::sci;  // "%.3g", ukdyn/simulate/diagnostics.hpp

void check_size(const char* what, Index expected, Index got, bool may_be_empty) {
  if (got == expected || (may_be_empty && got == 0)) return;
  throw Error(std::string("optimize: ") + what + " has " + std::to_string(got) + " entries, " +
              std::to_string(expected) + " expected");
}

void check_bounds(const char* what, const Vec& lo, const Vec& hi) {
  for (Index i = 0; i < lo.size() && i < hi.size(); ++i)
    if (!(lo(i) <= hi(i)))
      throw Error(std::string("optimize: ") + what + " bounds of entry " + std::to_string(i) +
                  " are empty (lower " + sci(lo(i)) + " > upper " + sci(hi(i)) + ")");
}

// The boundary state must lie on the manifold: |Φ(q)| and |A q̇| at most `tol`.
void check_on_manifold(const System& sys, double t, const Vec& q, const Vec& qd, const char* which,
                       bool velocity) {
  const Index m = sys.rows();
  if (m == 0) return;
  Vec phi(m), phid(m);
  position_residuals(sys, t, q, phi);
  Index worst = 0;
  const double p = phi.cwiseAbs().maxCoeff(&worst);
  constexpr double tol = 1e-8;
  if (!(p <= tol))
    throw Error(std::string("optimize: the ") + which + " q violates constraint row '" +
                sys.constraint_row_names()[static_cast<std::size_t>(worst)] + "' by " + sci(p) +
                " (assemble it first: `ukdyn assemble`)");
  if (!velocity) return;
  velocity_residuals(sys, t, q, qd, phid);
  const double v = phid.cwiseAbs().maxCoeff(&worst);
  if (!(v <= tol))
    throw Error(std::string("optimize: the ") + which + " qd violates constraint row '" +
                sys.constraint_row_names()[static_cast<std::size_t>(worst)] +
                "' at velocity level by " + sci(v));
}

void check_start_in_bounds(const TrajectoryProblem& pr) {
  auto inside = [](const char* what, const Vec& x, const Vec& lo, const Vec& hi) {
    for (Index i = 0; i < x.size(); ++i) {
      if (!std::isfinite(x(i))) continue;
      if ((lo.size() && x(i) < lo(i)) || (hi.size() && x(i) > hi(i)))
        throw Error(std::string("optimize: ") + what + " entry " + std::to_string(i) + " = " +
                    sci(x(i)) + " lies outside its bounds");
    }
  };
  inside("the start q", pr.q_start, pr.q_lower, pr.q_upper);
  inside("the start qd", pr.qd_start, pr.qd_lower, pr.qd_upper);
  inside("the end q", pr.q_end, pr.q_lower, pr.q_upper);
  inside("the end qd", pr.qd_end, pr.qd_lower, pr.qd_upper);
}

void check_costs_and_time(const TrajectoryProblem& pr, Index k) {
  if (pr.intervals < 1) throw Error("optimize: intervals must be at least 1");
  if (!(std::isfinite(pr.duration) && pr.duration > 0.0))
    throw Error("optimize: the duration must be finite and positive, got " + sci(pr.duration));
  if (pr.free_duration &&
      !(pr.min_duration > 0.0 && pr.min_duration <= pr.duration && pr.duration <= pr.max_duration))
    throw Error("optimize: a free duration needs 0 < min_duration <= duration <= max_duration");
  check_size("costs.effort", k, pr.costs.effort.size(), true);
  const auto& c = pr.costs;
  for (const double w : {c.power, c.constraint_force, c.smoothness, c.duration})
    if (!(std::isfinite(w) && w >= 0.0))
      throw Error("optimize: a cost weight is negative or not finite");
  if (c.effort.size() && !(c.effort.allFinite() && c.effort.minCoeff() >= 0.0))
    throw Error("optimize: an effort weight is negative or not finite");
  for (const auto& e : pr.envelopes) {
    if (e.actuator < 0 || e.actuator >= k)
      throw Error("optimize: an envelope names actuator " + std::to_string(e.actuator) + " of " +
                  std::to_string(k));
    if (!(e.u_max > 0.0 && e.speed_max > 0.0 && std::isfinite(e.u_max) &&
          std::isfinite(e.speed_max)))
      throw Error("optimize: an envelope needs a finite positive u_max and speed_max");
  }
}

// A waypoint's rows are holonomic and exact, at a time in (t0, t0 + T]: t with a fixed duration,
// or a fraction of the duration (fixed or free).
void check_waypoints(const TrajectoryProblem& pr) {
  for (const auto& w : pr.waypoints) {
    const std::string what = "optimize: waypoint '" + w.name + "'";
    if (!w.rows || w.rows->rows() == 0) throw Error(what + " has no rows");
    if (!std::isnan(w.fraction)) {
      if (!(w.fraction > 0.0 && w.fraction <= 1.0))
        throw Error(what + ": fraction = " + sci(w.fraction) + " is not in (0, 1]");
      continue;
    }
    if (pr.free_duration)
      throw Error(what +
                  ": with a free duration give its time as a fraction of the duration "
                  "(`fraction`), not t");
    if (!(std::isfinite(w.t) && w.t > 0.0 && w.t <= pr.duration * (1.0 + 1e-12)))
      throw Error(what + ": t = " + sci(w.t) + " is not in (0, duration]");
  }
}

// Whether the system depends on t (a rheonomic row, a force or a mass of t): q̈ (forward()), Φ or
// Φ_t at the start state differ between times across the longest duration. (Each point's own t
// is used in the NLP; the probe decides only whether a free duration, which moves the points'
// times, is refused.)
bool depends_on_time(const System& sys, const TrajectoryProblem& pr) {
  if (time_varying(sys)) return true;
  const Index n = sys.dof(), m = sys.rows();
  const double span = std::isfinite(pr.max_duration) ? pr.max_duration : 10.0 * pr.duration;
  ForwardData d(sys);
  Vec ref, phi(m), phit(m), phi_ref(m), phit_ref(m);
  const Vec zero = Vec::Zero(n);
  for (const double s : {0.0, 0.3183098861837907, 0.7071067811865476, 1.0}) {
    const double t = pr.t0 + s * span;
    forward(sys, d, t, pr.q_start, pr.qd_start, pr.tau, pr.uk);
    position_residuals(sys, t, pr.q_start, phi);
    velocity_residuals(sys, t, pr.q_start, zero, phit);
    if (s == 0.0) {
      ref = d.qdd, phi_ref = phi, phit_ref = phit;
      if (m > 0 && phit.cwiseAbs().maxCoeff() > 0.0) return true;
      continue;
    }
    auto differ = [](const Vec& a, const Vec& b) {
      return a.size() > 0 &&
             (a - b).cwiseAbs().maxCoeff() > 1e-12 * (1.0 + b.cwiseAbs().maxCoeff());
    };
    if (differ(d.qdd, ref) || differ(phi, phi_ref) || differ(phit, phit_ref)) return true;
  }
  return false;
}

// Rheonomic rows Φ(q, t): the knots keep A v + Φ_t = 0, and its Jacobian in q is taken as D =
// ∂(A v)/∂q alone, exact when Φ_t does not depend on q (a prescribed path of a point or a
// coordinate, Φ = g(q) − r(t)); the constraints give no tangent of Φ_t. So Φ_t (the velocity
// residual at q̇ = 0) must be the same at the boundary states and probes 1e-3 around the start
// along every coordinate, at the start, the middle and the end time; else the row is refused.
void check_rheonomic_rates(const System& sys, const TrajectoryProblem& pr) {
  const Index n = sys.dof(), m = sys.rows();
  if (m == 0) return;
  const Vec zero = Vec::Zero(n);
  Vec ref(m), at(m);
  std::vector<Vec> states{pr.q_start};
  if (pr.q_end.allFinite()) states.push_back(pr.q_end);
  for (Index j = 0; j < n; ++j)
    for (const double step : {1e-3, -1e-3}) {
      states.push_back(pr.q_start);
      states.back()(j) += step * (1.0 + std::abs(pr.q_start(j)));
    }
  for (const double s : {0.0, 0.5, 1.0}) {
    const double t = pr.t0 + s * pr.duration;
    velocity_residuals(sys, t, pr.q_start, zero, ref);
    for (const Vec& q : states) {
      velocity_residuals(sys, t, q, zero, at);
      Index row = 0;
      const double d = (at - ref).cwiseAbs().maxCoeff(&row);
      if (d > 1e-12 * (1.0 + ref.cwiseAbs().maxCoeff()))
        throw Error(
            "optimize: constraint row '" +
            sys.constraint_row_names()[static_cast<std::size_t>(row)] +
            "' has a time rate (Phi_t) that depends on q (it changes by " + sci(d) +
            " over a step of 1e-3 from the start): trajectory optimisation takes rheonomic rows "
            "Phi = g(q) - r(t) only (a prescribed path of a point or a coordinate)");
    }
  }
}

void check_internal_wrench_bounds(const TrajectoryProblem& pr) {
  for (const auto& b : pr.internal_wrench_bounds) {
    const std::string what = "optimize: the internal wrench bound of load '" + b.load + "'";
    if (!b.walker || !b.walker_dq || b.grasps < 2)
      throw Error(what + " needs a load held by two or more welds");
    if (!(b.max_force > 0.0) || !(b.max_torque > 0.0))
      throw Error(what + ": the bounds must be positive");
    if (!std::isfinite(b.max_force) && !std::isfinite(b.max_torque))
      throw Error(what + " bounds neither the force nor the torque");
  }
}

}  // namespace

void validate(const TrajectoryProblem& pr) {
  if (!pr.system) throw Error("optimize: no system");
  const System& sys = *pr.system;
  const Index n = sys.dof(), k = pr.B.cols();
  if (pr.B.rows() != n) throw Error("optimize: B must have one row per coordinate");
  check_size("actuator_names", k, static_cast<Index>(pr.actuator_names.size()), false);
  check_size("tau", n, pr.tau.size(), false);
  check_size("q_start", n, pr.q_start.size(), false);
  check_size("qd_start", n, pr.qd_start.size(), false);
  check_size("q_end", n, pr.q_end.size(), false);
  check_size("qd_end", n, pr.qd_end.size(), false);
  check_size("q_lower", n, pr.q_lower.size(), true);
  check_size("q_upper", n, pr.q_upper.size(), true);
  check_size("qd_lower", n, pr.qd_lower.size(), true);
  check_size("qd_upper", n, pr.qd_upper.size(), true);
  check_size("u_lower", k, pr.u_lower.size(), true);
  check_size("u_upper", k, pr.u_upper.size(), true);
  check_bounds("q", pr.q_lower, pr.q_upper);
  check_bounds("qd", pr.qd_lower, pr.qd_upper);
  check_bounds("u", pr.u_lower, pr.u_upper);
  check_size("multiplier_lower", sys.rows(), pr.multiplier_lower.size(), true);
  check_size("multiplier_upper", sys.rows(), pr.multiplier_upper.size(), true);
  if (pr.multiplier_lower.size() != pr.multiplier_upper.size())
    throw Error("optimize: multiplier_lower and multiplier_upper must both be given or both empty");
  check_bounds("multiplier", pr.multiplier_lower, pr.multiplier_upper);
  check_size("costs.multiplier", sys.rows(), pr.costs.multiplier.size(), true);
  if (pr.costs.multiplier.size() &&
      !(pr.costs.multiplier.allFinite() && pr.costs.multiplier.minCoeff() >= 0.0))
    throw Error("optimize: a multiplier weight is negative or not finite");
  if (!(pr.q_start.allFinite() && pr.qd_start.allFinite() && pr.tau.allFinite() &&
        pr.B.allFinite()))
    throw Error("optimize: the start state, tau and B must be finite");
  check_costs_and_time(pr, k);
  check_waypoints(pr);
  check_internal_wrench_bounds(pr);
  const Index P =
      pr.method == CollocationMethod::hermite_simpson ? 2 * pr.intervals + 1 : pr.intervals + 1;
  for (const auto& [what, G, cols] :
       {std::tuple{"q_guess", &pr.q_guess, n}, std::tuple{"qd_guess", &pr.qd_guess, n},
        std::tuple{"u_guess", &pr.u_guess, k}})
    if (G->size() && (G->rows() != P || G->cols() != cols || !G->allFinite()))
      throw Error(std::string("optimize: ") + what + " must be finite with one row per point (" +
                  std::to_string(P) + ") and " + std::to_string(cols) + " columns");
  if (pr.free_duration && depends_on_time(sys, pr))
    throw Error(
        "optimize: the system depends on time (a rheonomic constraint or a time-dependent "
        "force) and the duration is free: the points' times would move with T; fix the "
        "duration");
  if (const auto missing = components_without_derivatives(sys); !missing.empty())
    throw Error("optimize: no exact derivatives for " + missing.front() +
                " (docs/derivatives.md lists the kinds that have them)");
  check_rheonomic_rates(sys, pr);
  check_on_manifold(sys, pr.t0, pr.q_start, pr.qd_start, "start", true);
  if (pr.q_end.allFinite())
    check_on_manifold(sys, pr.t0 + pr.duration, pr.q_end, pr.qd_end, "end", pr.qd_end.allFinite());
  check_start_in_bounds(pr);
  // Holonomic rows only: a velocity-level row has no position residual to keep at the knots.
  if (sys.rows() > 0) {
    const Linearization lin = linearize(sys, pr.t0, pr.q_start, pr.qd_start, pr.tau, pr.uk);
    ForwardData d(sys);
    forward(sys, d, pr.t0, pr.q_start, pr.qd_start, pr.tau, pr.uk);
    Mat AR(static_cast<Index>(lin.kept_rows.size()), n);
    for (Index i = 0; i < AR.rows(); ++i)
      AR.row(i) = d.A.row(lin.kept_rows[static_cast<std::size_t>(i)]);
    if (const Index bad = first_velocity_level_row(sys, d, pr.t0, pr.q_start, AR, lin.kept_rows);
        bad >= 0)
      throw Error(
          "optimize: constraint row '" +
          sys.constraint_row_names()[static_cast<std::size_t>(
              lin.kept_rows[static_cast<std::size_t>(bad)])] +
          "' is velocity-level (nonholonomic); trajectory optimisation takes holonomic rows only");
  }
}

#if UKDYN_HAVE_IPOPT

bool ipopt_available() { return true; }

namespace {

using IIndex = Ipopt::Index;  // IPOPT's int index type
using Ipopt::Number;

constexpr double kIpoptInf = 1e20;  // IPOPT's nlp_{lower,upper}_bound_inf default is ±1e19

class StructureSink final : public optimize::JacobianSink {
 public:
  StructureSink(IIndex* rows, IIndex* cols) : rows_(rows), cols_(cols) {}
  void dense(ukdyn::Index r, ukdyn::Index c, const Mat& b) override {
    for (ukdyn::Index j = 0; j < b.cols(); ++j)
      for (ukdyn::Index i = 0; i < b.rows(); ++i) put(r + i, c + j);
  }
  void identity(ukdyn::Index r, ukdyn::Index c, ukdyn::Index size, double) override {
    for (ukdyn::Index i = 0; i < size; ++i) put(r + i, c + i);
  }
  void column(ukdyn::Index r, ukdyn::Index c, const Vec& v) override {
    for (ukdyn::Index i = 0; i < v.size(); ++i) put(r + i, c);
  }

 private:
  void put(ukdyn::Index r, ukdyn::Index c) {
    rows_[at_] = static_cast<IIndex>(r);
    cols_[at_++] = static_cast<IIndex>(c);
  }
  IIndex* rows_;
  IIndex* cols_;
  std::size_t at_ = 0;
};

class ValueSink final : public optimize::JacobianSink {
 public:
  explicit ValueSink(Number* values) : values_(values) {}
  void dense(ukdyn::Index, ukdyn::Index, const Mat& b) override {
    for (ukdyn::Index j = 0; j < b.cols(); ++j)
      for (ukdyn::Index i = 0; i < b.rows(); ++i) values_[at_++] = b(i, j);
  }
  void identity(ukdyn::Index, ukdyn::Index, ukdyn::Index size, double s) override {
    for (ukdyn::Index i = 0; i < size; ++i) values_[at_++] = s;
  }
  void column(ukdyn::Index, ukdyn::Index, const Vec& v) override {
    for (ukdyn::Index i = 0; i < v.size(); ++i) values_[at_++] = v(i);
  }

 private:
  Number* values_;
  std::size_t at_ = 0;
};

Vec view(const Number* x, IIndex n) { return Eigen::Map<const Vec>(x, n); }

// Bounds for IPOPT: ±inf as ±kIpoptInf (beyond nlp_{lower,upper}_bound_inf: no bound).
void copy(const Vec& v, Number* out, IIndex n) {
  for (IIndex i = 0; i < n; ++i)
    out[i] = std::isfinite(v(i)) ? v(i) : (v(i) > 0 ? kIpoptInf : -kIpoptInf);
}

// The TNLP: every callback maps x onto the transcription; an evaluation that throws (a state where
// the dynamics is not finite, say) returns false, and IPOPT shortens its step.
class CollocationTnlp final : public Ipopt::TNLP {
 public:
  CollocationTnlp(optimize::Transcription& tr, const std::atomic<bool>* cancel)
      : tr_(tr), cancel_(cancel) {}
  Vec x_final;
  Ipopt::SolverReturn status = Ipopt::UNASSIGNED;
  std::string error;

  bool get_nlp_info(IIndex& n, IIndex& m, IIndex& nnz_jac, IIndex& nnz_h,
                    IndexStyleEnum& style) override {
    n = static_cast<IIndex>(tr_.variables());
    m = static_cast<IIndex>(tr_.constraints());
    nnz_jac = static_cast<IIndex>(tr_.jacobian_nonzeros());
    nnz_h = 0;
    style = C_STYLE;
    return true;
  }
  bool get_bounds_info(IIndex n, Number* xl, Number* xu, IIndex m, Number* gl,
                       Number* gu) override {
    Vec a, b, c, d;
    tr_.bounds(a, b, c, d);
    copy(a, xl, n), copy(b, xu, n), copy(c, gl, m), copy(d, gu, m);
    return true;
  }
  bool get_starting_point(IIndex n, bool init_x, Number* x, bool, Number*, Number*, IIndex, bool,
                          Number*) override {
    if (init_x) {
      const Vec x0 = tr_.initial_guess();
      for (IIndex i = 0; i < n; ++i) x[i] = x0(i);
    }
    return true;
  }
  bool eval_f(IIndex n, const Number* x, bool, Number& f) override {
    return guard([&] { f = tr_.cost(view(x, n)); });
  }
  bool eval_grad_f(IIndex n, const Number* x, bool, Number* g) override {
    return guard([&] {
      Vec grad;
      tr_.cost_gradient(view(x, n), grad);
      for (IIndex i = 0; i < n; ++i) g[i] = grad(i);
    });
  }
  bool eval_g(IIndex n, const Number* x, bool, IIndex m, Number* g) override {
    return guard([&] {
      Vec v;
      tr_.constraint_values(view(x, n), v);
      for (IIndex i = 0; i < m; ++i) g[i] = v(i);
    });
  }
  bool eval_jac_g(IIndex n, const Number* x, bool, IIndex, IIndex, IIndex* rows, IIndex* cols,
                  Number* values) override {
    return guard([&] {
      if (values == nullptr) {
        StructureSink sink(rows, cols);
        tr_.jacobian(tr_.initial_guess(), sink);
      } else {
        ValueSink sink(values);
        tr_.jacobian(view(x, n), sink);
      }
    });
  }
  void finalize_solution(Ipopt::SolverReturn s, IIndex n, const Number* x, const Number*,
                         const Number*, IIndex, const Number*, const Number*, Number,
                         const Ipopt::IpoptData*, Ipopt::IpoptCalculatedQuantities*) override {
    status = s;
    x_final = view(x, n);
  }
  // Called by IPOPT after every iteration: false stops the solve (User_Requested_Stop).
  bool intermediate_callback(Ipopt::AlgorithmMode, IIndex, Number, Number, Number, Number, Number,
                             Number, Number, Number, IIndex, const Ipopt::IpoptData*,
                             Ipopt::IpoptCalculatedQuantities*) override {
    return !(cancel_ && cancel_->load());
  }

 private:
  template <class F>
  bool guard(F&& f) {
    try {
      f();
      return true;
    } catch (const std::exception& e) {
      error = e.what();
      return false;
    }
  }
  optimize::Transcription& tr_;
  const std::atomic<bool>* cancel_;
};

std::string status_name(Ipopt::ApplicationReturnStatus s) {
  switch (s) {
    case Ipopt::Solve_Succeeded:
      return "Solve_Succeeded";
    case Ipopt::Solved_To_Acceptable_Level:
      return "Solved_To_Acceptable_Level";
    case Ipopt::Infeasible_Problem_Detected:
      return "Infeasible_Problem_Detected";
    case Ipopt::Search_Direction_Becomes_Too_Small:
      return "Search_Direction_Becomes_Too_Small";
    case Ipopt::Diverging_Iterates:
      return "Diverging_Iterates";
    case Ipopt::User_Requested_Stop:
      return "User_Requested_Stop";
    case Ipopt::Feasible_Point_Found:
      return "Feasible_Point_Found";
    case Ipopt::Maximum_Iterations_Exceeded:
      return "Maximum_Iterations_Exceeded";
    case Ipopt::Restoration_Failed:
      return "Restoration_Failed";
    case Ipopt::Error_In_Step_Computation:
      return "Error_In_Step_Computation";
    case Ipopt::Maximum_CpuTime_Exceeded:
      return "Maximum_CpuTime_Exceeded";
    case Ipopt::Not_Enough_Degrees_Of_Freedom:
      return "Not_Enough_Degrees_Of_Freedom";
    case Ipopt::Invalid_Problem_Definition:
      return "Invalid_Problem_Definition";
    case Ipopt::Invalid_Option:
      return "Invalid_Option";
    case Ipopt::Invalid_Number_Detected:
      return "Invalid_Number_Detected";
    default:
      return "Internal_Error (" + std::to_string(static_cast<int>(s)) + ")";
  }
}

}  // namespace

TrajectorySolution optimize_trajectory(const TrajectoryProblem& problem,
                                       const IpoptSettings& settings) {
  optimize::Transcription tr(problem);  // validates
  Ipopt::SmartPtr<CollocationTnlp> nlp = new CollocationTnlp(tr, settings.cancel);
  Ipopt::SmartPtr<Ipopt::IpoptApplication> app = IpoptApplicationFactory();
  auto& o = *app->Options();
  o.SetStringValue("sb", "yes");  // no banner
  o.SetIntegerValue("print_level", settings.print_level);
  o.SetStringValue("hessian_approximation", "limited-memory");
  o.SetIntegerValue("limited_memory_max_history", settings.lbfgs_memory);
  o.SetNumericValue("tol", settings.tol);
  o.SetNumericValue("dual_inf_tol", settings.dual_inf_tol);
  o.SetNumericValue("constr_viol_tol", settings.constr_viol_tol);
  o.SetIntegerValue("max_iter", settings.max_iter);
  // MUMPS's working space: IPOPT's default adds 1000 % to MUMPS's estimate and the factorisation
  // zeroes all of it every iteration (a third of the solve time measured on the paper's problem);
  // IPOPT raises it by itself when MUMPS reports too little.
  o.SetIntegerValue("mumps_mem_percent", 50);
  // MUMPS's ordering and scaling, chosen by measurement on the paper's lift (Hermite–Simpson, 50
  // intervals; docs/optimization.md): IPOPT's defaults (automatic ordering, permuting scaling)
  // 3.6–4.5 s in 23 iterations; AMD ordering 1.8 s; AMD without the permuting scaling 0.84 s in 18.
  o.SetIntegerValue("mumps_pivot_order", 0);
  o.SetIntegerValue("mumps_permuting_scaling", 0);
  o.SetNumericValue("nlp_lower_bound_inf", -kIpoptInf / 10);
  o.SetNumericValue("nlp_upper_bound_inf", kIpoptInf / 10);
  for (const auto& [k, v] : settings.string_options)
    if (!o.SetStringValue(k, v)) throw Error("optimize: IPOPT refuses option " + k + " = " + v);
  for (const auto& [k, v] : settings.integer_options)
    if (!o.SetIntegerValue(k, v))
      throw Error("optimize: IPOPT refuses option " + k + " = " + std::to_string(v));
  for (const auto& [k, v] : settings.numeric_options)
    if (!o.SetNumericValue(k, v))
      throw Error("optimize: IPOPT refuses option " + k + " = " + sci(v));
  // No options file: IPOPT's Initialize() would read ./ipopt.opt, an input that no problem file
  // names (a stray one in the working directory would change the solve unseen).
  if (app->Initialize(std::string()) != Ipopt::Solve_Succeeded)
    throw Error("optimize: IPOPT could not be initialised");
  const Ipopt::ApplicationReturnStatus rs = app->OptimizeTNLP(nlp);
  if (nlp->x_final.size() != tr.variables()) {
    throw Error("optimize: IPOPT stopped before a first iterate (" + status_name(rs) + ")" +
                (nlp->error.empty() ? "" : ": " + nlp->error));
  }
  TrajectorySolution s = tr.solution(nlp->x_final);
  s.status = status_name(rs);
  s.converged = rs == Ipopt::Solve_Succeeded;
  if (auto stats = app->Statistics(); Ipopt::IsValid(stats)) {
    s.iterations = stats->IterationCount();
    Number dual = 0, viol = 0, compl_ = 0, kkt = 0, v1 = 0, v2 = 0, v3 = 0, v4 = 0;
    stats->ScaledInfeasibilities(v1, v2, v3, v4);
    stats->Infeasibilities(dual, viol, compl_, kkt);
    s.dual_infeasibility = dual;
    s.constraint_violation = viol;
    s.complementarity = compl_;
    s.kkt_error = kkt;
  }
  if (rs == Ipopt::User_Requested_Stop && settings.cancel && settings.cancel->load()) {
    s.trusted = false;
    s.message = "interrupted: IPOPT stopped after " + std::to_string(s.iterations) +
                " iterations; the trajectory is its last iterate, not an optimum";
  } else if (!s.converged) {
    s.trusted = false;
    s.message = "IPOPT did not converge: " + s.status +
                (nlp->error.empty() ? "" : " (last evaluation error: " + nlp->error + ")");
  }
  return s;
}

namespace {

// Options that make IPOPT read or write a file, or load a library, by a name in the problem file.
bool names_a_file(const std::string& name) {
  for (const char* f : {"output_file", "option_file_name", "hsllib", "pardisolib", "file_append",
                        "file_print_level"})
    if (name == f) return true;
  return false;
}

}  // namespace

std::string add_ipopt_option(IpoptSettings& settings, const std::string& name,
                             const std::string& text, const double* number) {
  if (names_a_file(name))
    return "IPOPT option '" + name +
           "' makes IPOPT read or write a file or load a library: not taken from a problem file";
  Ipopt::SmartPtr<Ipopt::IpoptApplication> app = new Ipopt::IpoptApplication(false);
  const Ipopt::SmartPtr<const Ipopt::RegisteredOption> opt = app->RegOptions()->GetOption(name);
  if (Ipopt::IsNull(opt)) return "no IPOPT option named '" + name + "'";
  switch (opt->Type()) {
    case Ipopt::OT_Integer:
      if (!number || *number != std::floor(*number) || std::abs(*number) > 2e9 ||
          !opt->IsValidIntegerSetting(static_cast<IIndex>(*number)))
        return "IPOPT option '" + name + "' takes a whole number in its range, got '" + text + "'";
      settings.integer_options.emplace_back(name, static_cast<int>(*number));
      return {};
    case Ipopt::OT_Number:
      if (!number || !opt->IsValidNumberSetting(*number))
        return "IPOPT option '" + name + "' takes a number in its range, got '" + text + "'";
      settings.numeric_options.emplace_back(name, *number);
      return {};
    default:
      if (!opt->IsValidStringSetting(text))
        return "IPOPT option '" + name + "' does not take '" + text + "'";
      settings.string_options.emplace_back(name, text);
      return {};
  }
}

#else

bool ipopt_available() { return false; }

std::string add_ipopt_option(IpoptSettings& settings, const std::string& name,
                             const std::string& text, const double* number) {
  if (number && *number == std::floor(*number) && std::abs(*number) < 1e9 &&
      text.find_first_of(".eE") == std::string::npos)
    settings.integer_options.emplace_back(name, static_cast<int>(*number));
  else if (number)
    settings.numeric_options.emplace_back(name, *number);
  else
    settings.string_options.emplace_back(name, text);
  return {};
}

TrajectorySolution optimize_trajectory(const TrajectoryProblem& problem, const IpoptSettings&) {
  validate(problem);
  throw Error(
      "optimize: this ukdyn was built without IPOPT: install coinor-libipopt-dev "
      "(scripts/install-deps.sh does) and rebuild");
}

#endif

}  // namespace ukdyn
