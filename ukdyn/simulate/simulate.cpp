#include "ukdyn/simulate/simulate.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/QR>
#include <Eigen/SVD>
#include <boost/numeric/odeint.hpp>
#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>
#include <vector>

#include "ukdyn/simulate/implicit.hpp"

namespace ukdyn {

std::string to_string(RunStatus status) {
  switch (status) {
    case RunStatus::completed:
      return "completed";
    case RunStatus::non_finite:
      return "non_finite";
    case RunStatus::inconsistent_constraints:
      return "inconsistent_constraints";
    case RunStatus::step_failure:
      return "step_failure";
    case RunStatus::stopped:
      return "stopped";
    case RunStatus::branch_switch:
      return "branch_switch";
  }
  return "unknown";
}

std::string to_string(IntegratorKind kind) {
  switch (kind) {
    case IntegratorKind::rk4:
      return "rk4";
    case IntegratorKind::dopri5:
      return "dopri5";
    case IntegratorKind::rkf78:
      return "rkf78";
    case IntegratorKind::bdf:
      return "bdf";
  }
  return "unknown";
}

bool bdf_available() { return detail::cvode_available(); }

std::string to_string(DriftControl kind) {
  switch (kind) {
    case DriftControl::none:
      return "none";
    case DriftControl::baumgarte:
      return "baumgarte";
    case DriftControl::projection:
      return "projection";
  }
  return "unknown";
}

namespace {

namespace odeint = boost::numeric::odeint;
using State = std::vector<double>;

// The first-order system x = [q; q̇], ẋ = [q̇; q̈] with q̈ from the U-K equation (paper Eq. (18)).
// Every buffer lives here, allocated once; operator() allocates nothing.
struct Rhs {
  const System& system;
  const ForceFunction& tau_fn;
  const SimulationSettings& s;
  ForwardData data;
  Vec tau, phi, phid;
  Index n;
  long evaluations = 0;

  Rhs(const System& sys, const ForceFunction& f, const SimulationSettings& settings)
      : system(sys),
        tau_fn(f),
        s(settings),
        data(sys),
        tau(Vec::Zero(sys.dof())),
        phi(sys.rows()),
        phid(sys.rows()),
        n(sys.dof()) {}

  // forward(), with the Baumgarte terms added to b when asked for.
  void eval(CVecRef q, CVecRef qd, double t, ForwardData& d) {
    if (tau_fn) tau_fn(t, q, qd, tau);
    if (s.drift.kind != DriftControl::baumgarte || system.rows() == 0) {
      forward(system, d, t, q, qd, tau, s.uk);
      return;
    }
    evaluate_dynamics(system, d, q, qd);
    generalized_forces(system, d, t, q, qd, tau);  // paper Eq. (11), with the applied forces
    evaluate_constraints(system, d, t, q, qd);
    position_residuals(system, d, t, q, phi);
    velocity_residuals(system, d, t, q, qd, phid);
    // Baumgarte: Φ̈ + 2α Φ̇ + β² Φ = 0  ⇒  A q̈ = b − 2α Φ̇ − β² Φ.
    d.b -= 2.0 * s.drift.alpha * phid + s.drift.beta * s.drift.beta * phi;
    d.result = uk_solve_dispatch(d, d.b, d.Q, d.qdd, d.Qc, s.uk);
  }

  void operator()(const State& x, State& dxdt, double t) { eval_raw(x.data(), dxdt.data(), t); }

  void eval_raw(const double* x, double* dxdt, double t) {
    const Eigen::Map<const Vec> q(x, n);
    const Eigen::Map<const Vec> qd(x + n, n);
    eval(q, qd, t, data);
    ++evaluations;
    Eigen::Map<Vec>(dxdt, n) = qd;
    Eigen::Map<Vec>(dxdt + n, n) = data.qdd;
    // Energy balance: Ẇ = (τ + Q_nc + Qc)ᵀ q̇ as state 2n.
    if (s.energy_balance) dxdt[2 * n] = data.applied_power + data.Qc.dot(qd);
  }
};

}  // namespace

struct IntegratorRhs::Impl {
  Rhs rhs;
};

IntegratorRhs::IntegratorRhs(const System& system, const ForceFunction& tau,
                             const SimulationSettings& settings)
    : impl_(std::make_unique<Impl>(Impl{Rhs(system, tau, settings)})) {}
IntegratorRhs::~IntegratorRhs() = default;
void IntegratorRhs::operator()(const std::vector<double>& x, std::vector<double>& dxdt, double t) {
  impl_->rhs(x, dxdt, t);
}
const ForwardData& IntegratorRhs::data() const { return impl_->rhs.data; }

namespace {

// Projection onto the constraint manifold in the metric of M: each correction is the U-K solve with
// Q = 0 and b = −Φ (positions) or b = −Φ̇ (velocities): Δ = M^{-1}Aᵀ(A M^{-1}Aᵀ)^+ (−r), the
// smallest change in the kinetic-energy norm that removes the residual r to first order.
struct Projector {
  const System& system;
  const DriftSettings& ds;
  const UkSettings& uk;
  ForwardData data;
  Vec phi, zero_Q, delta, Qc_scratch;
  Index n;
  double last_dq = 0.0, last_dqd = 0.0;  ///< Σ max|Δq| and max|Δq̇| of the last project()

  Projector(const System& sys, const DriftSettings& d, const UkSettings& u)
      : system(sys),
        ds(d),
        uk(u),
        data(sys),
        phi(sys.rows()),
        zero_Q(Vec::Zero(sys.dof())),
        delta(sys.dof()),
        Qc_scratch(sys.dof()),
        n(sys.dof()) {}

  // Returns max|Φ| after projecting; counts Gauss–Newton iterations.
  double project(double t, double* x, long& iterations) {
    Eigen::Map<Vec> q(x, n);
    Eigen::Map<Vec> qd(x + n, n);
    position_residuals(system, data, t, q, phi);
    double r = phi.cwiseAbs().maxCoeff();
    last_dq = 0.0;
    for (int it = 0; it < ds.max_iterations && r > ds.position_tol; ++it) {
      evaluate_dynamics(system, data, q, qd);
      evaluate_constraints(system, data, t, q, qd);
      phi = -phi;
      uk_solve_dispatch(data, phi, zero_Q, delta, Qc_scratch, uk);
      q += delta;
      last_dq += delta.cwiseAbs().maxCoeff();
      ++iterations;
      position_residuals(system, data, t, q, phi);
      const double r_new = phi.cwiseAbs().maxCoeff();
      if (!(r_new < 0.5 * r)) {
        r = r_new;
        break;  // round-off floor reached (or no progress)
      }
      r = r_new;
    }
    // Velocities onto A q̇ + Φ_t = 0 at the projected q.
    evaluate_dynamics(system, data, q, qd);
    evaluate_constraints(system, data, t, q, qd);
    velocity_residuals(system, data, t, q, qd, phi);
    phi = -phi;
    uk_solve_dispatch(data, phi, zero_Q, delta, Qc_scratch, uk);
    qd += delta;
    last_dqd = delta.cwiseAbs().maxCoeff();
    return r;
  }
};

bool finite_state(const State& x) {
  for (double v : x) {
    if (!std::isfinite(v)) return false;
  }
  return true;
}

std::string sci(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3g", v);
  return buf;
}

// Why a step failed (issue 15 class 5): evaluated at the state where the step control gave up, on
// the failure path only (allocates). Names the cause and the coordinates / constraint rows
// involved, or returns "" when neither M nor A is singular there.
std::string diagnose_singularity(const System& system, double t, const State& x,
                                 const UkSettings& uk) {
  const Index n = system.dof();
  const Eigen::Map<const Vec> q(x.data(), n);
  const Eigen::Map<const Vec> qd(x.data() + n, n);
  ForwardData d(system);
  evaluate_dynamics(system, d, q, qd);
  const auto& cn = system.coordinate_names();
  const auto& rn = system.constraint_row_names();
  auto names = [](const std::vector<std::string>& all, const Vec& v) {
    std::string out;
    const double vmax = v.cwiseAbs().maxCoeff();
    for (Index i = 0; i < v.size(); ++i) {
      if (std::abs(v(i)) >= 0.3 * vmax && static_cast<std::size_t>(i) < all.size()) {
        out += (out.empty() ? "" : ", ") + all[static_cast<std::size_t>(i)];
      }
    }
    return out;
  };
  Eigen::SelfAdjointEigenSolver<Mat> es(0.5 * (d.M + d.M.transpose()));
  if (es.info() != Eigen::Success || !d.M.allFinite()) {
    return "the mass matrix is not finite at t = " + std::to_string(t);
  }
  const double ev_min = es.eigenvalues()(0), ev_max = es.eigenvalues()(n - 1);
  if (!(ev_min > 1e-8 * std::max(ev_max, 0.0))) {
    // A singular M is fine when [M; A] has full column rank (core/uk_singular.hpp).
    evaluate_constraints(system, d, t, q, qd);
    const std::string why = undetermined_direction(d.M, d.A, cn);
    if (!why.empty()) return "at t = " + std::to_string(t) + ": " + why;
    if (system.rows() > 0) return "";
    return "the mass matrix is (nearly) singular at t = " + std::to_string(t) +
           ": smallest eigenvalue " + sci(ev_min) + " of largest " + sci(ev_max) +
           ", in coordinates [" + names(cn, es.eigenvectors().col(0)) + "]";
  }
  if (system.rows() == 0) return "";
  evaluate_constraints(system, d, t, q, qd);
  const Mat Mih = es.eigenvectors() * es.eigenvalues().cwiseSqrt().cwiseInverse().asDiagonal() *
                  es.eigenvectors().transpose();
  Eigen::JacobiSVD<Mat> svd(d.A * Mih, Eigen::ComputeFullU);
  const Vec& sv = svd.singularValues();
  if (sv.size() == 0 || !(sv(0) > 0.0)) return "";
  // The smallest singular value above round-off of redundant rows, and the rows of its direction.
  Index k = sv.size() - 1;
  while (k > 0 && sv(k) <= 1e-14 * sv(0)) --k;
  const double ratio = sv(k) / sv(0);
  if (ratio > 1e3 * uk.rank_rel_tol) return "";
  return "the constraints are near a singular position at t = " + std::to_string(t) +
         ": a singular value of A M^-1/2 is " + sci(ratio) + " of the largest (rank_tol " +
         sci(uk.rank_rel_tol) + "), in rows [" + names(rn, svd.matrixU().col(k)) + "]";
}

}  // namespace

SimulationStats simulate(const System& system, const Vec& q0, const Vec& qd0,
                         const ForceFunction& tau, const SimulationSettings& s,
                         const SampleObserver& observer) {
  const Index n = system.dof();
  if (q0.size() != n || qd0.size() != n) {  // the public edge: sizes, expected and actual
    throw std::invalid_argument("simulate: q0 has " + std::to_string(q0.size()) + " and qd0 " +
                                std::to_string(qd0.size()) + " entries, expected " +
                                std::to_string(n) + " (system.dof())");
  }
  if (!(s.t_end > s.t0) || !std::isfinite(s.t_end) || !std::isfinite(s.t0)) {
    throw Error("simulate: t_end must be finite and greater than t0");
  }
  if (!(s.sample_dt > 0.0) || !std::isfinite(s.sample_dt)) {
    throw Error("simulate: sample_dt must be a positive number");
  }
  if (!(s.step > 0.0) || !std::isfinite(s.step)) throw Error("simulate: step must be positive");
  const double span = s.t_end - s.t0;
  if (span / s.sample_dt > 1e8) throw Error("simulate: more than 1e8 output samples requested");
  const auto n_samples = static_cast<long>(std::floor(span / s.sample_dt + 1e-9)) + 1;
  const bool fixed = !adaptive_steps(s);
  if (fixed) {
    const double ratio = s.sample_dt / s.step;
    const long substeps = std::lround(ratio);
    if (substeps < 1 || std::abs(ratio - static_cast<double>(substeps)) > 1e-9 * ratio) {
      throw Error("simulate: the fixed step must divide sample_dt (sample_dt/step = " +
                  std::to_string(ratio) + ")");
    }
    if (span / s.step > 1e10) throw Error("simulate: more than 1e10 fixed steps requested");
  } else if (!(s.abs_tol > 0.0) || !(s.rel_tol >= 0.0)) {
    throw Error("simulate: abs_tol must be > 0 and rel_tol >= 0");
  }

  SimulationStats stats;
  Rhs rhs(system, tau, s);
  Projector projector(system, s.drift, s.uk);
  const bool project = s.drift.kind == DriftControl::projection && system.rows() > 0;
  State x(static_cast<std::size_t>(2 * n + (s.energy_balance ? 1 : 0)), 0.0);  // [q; q̇; W]
  Eigen::Map<Vec>(x.data(), n) = q0;
  Eigen::Map<Vec>(x.data() + n, n) = qd0;
  State x_out(x.size());

  // ---- observer: evaluates forward() at the sample (its own ForwardData), diagnoses, hands over.
  ForwardData sample_data(system);
  int last_rank = -1;
  auto warn = [&](double t, const std::string& kind, const std::string& message) {
    for (const auto& w : stats.warnings) {
      if (w.kind == kind) return;
    }
    stats.warnings.push_back({t, kind, message});
  };
  auto observe = [&](double t, const State& xs) -> bool {
    const Eigen::Map<const Vec> q(xs.data(), n);
    const Eigen::Map<const Vec> qd(xs.data() + n, n);
    rhs.eval(q, qd, t, sample_data);
    sample_data.work = s.energy_balance ? xs[static_cast<std::size_t>(2 * n)] : 0.0;
    ++stats.samples;
    stats.t_reached = t;
    const UkResult& r = sample_data.result;
    if (r.finite) {  // M near singular (gimbal lock): warned before the solve gives up
      std::size_t blk = 0;
      const double cond = mass_condition(sample_data, &blk);
      if (cond > kMassConditionWarning) {
        const bool dense = sample_data.singular.active && sample_data.singular.dense_used;
        warn(t, "ill_conditioned_mass",
             "the mass matrix" +
                 (dense ? std::string(" (augmented with the constraints)")
                        : " of subsystem '" + system.subsystems()[blk]->name() + "'") +
                 " is ill-conditioned (cond >= " + sci(cond) +
                 ", Cholesky pivot estimate): a singular configuration of its coordinates is near "
                 "(the gimbal lock of Euler angles?); digits are lost, and the run stops at cond " +
                 sci(1.0 / kSingularPivot) + " (use type: free_body for a rigid body in space)");
      }
    }
    const bool keep_going = observer ? observer(t, q, qd, sample_data) : true;
    if (!r.finite || !finite_state(xs)) {
      stats.status = RunStatus::non_finite;
      stats.message = "non-finite state or acceleration at t = " + std::to_string(t);
      if (finite_state(xs)) {
        const std::string cause = diagnose_singularity(system, t, xs, s.uk);
        if (!cause.empty()) stats.message += ": " + cause;
      }
      return false;
    }
    if (system.rows() > 0) {
      if (r.rank == n) {
        warn(t, "fully_prescribed",
             "the constraints have full rank " + std::to_string(n) +
                 ": the motion is fully prescribed by kinematics; only Qc depends on the dynamics");
      }
      if (r.rank > 0 && r.sigma_min_kept < s.near_singular_ratio * r.sigma_max) {
        warn(t, "near_singular",
             "near-singular configuration: smallest kept singular value of A M^-1/2 is " +
                 std::to_string(r.sigma_min_kept / r.sigma_max) + " of the largest");
      }
      if (last_rank >= 0 && r.rank != last_rank) {
        warn(t, "rank_change",
             "rank of A changed from " + std::to_string(last_rank) + " to " +
                 std::to_string(r.rank));
      }
      last_rank = r.rank;
      if (!r.consistent) {
        warn(t, "inconsistent_constraints",
             "inconsistent constraints: |A qdd - b| = " + std::to_string(r.residual));
        stats.status = RunStatus::inconsistent_constraints;
        stats.message = "inconsistent constraints at t = " + std::to_string(t) +
                        " (|A qdd - b| = " + std::to_string(r.residual) + ")";
        return false;
      }
    }
    if (!keep_going) {
      stats.status = RunStatus::stopped;
      stats.message = "stopped by the observer at t = " + std::to_string(t);
      return false;
    }
    return true;
  };
  auto finish = [&]() {
    stats.rhs_evaluations = rhs.evaluations;
    return stats;
  };
  // Branch check (issue 9 item 2): the projection only removes integration error, so its position
  // correction must stay within what the error control allows per step (× branch_factor); a larger
  // one means the state was carried somewhere else, e.g. onto another assembly branch near a
  // singular position. Warned (branch_switch, with its time) or, by setting, the run stops.
  auto check_branch = [&](double t, const State& xs) -> bool {
    double xmax = 0.0;
    for (double v : xs) xmax = std::max(xmax, std::abs(v));
    const double bound =
        s.drift.branch_factor * (fixed ? 1e-9 * (1.0 + xmax) : s.abs_tol + s.rel_tol * xmax);
    const double dq = projector.last_dq, dqd = projector.last_dqd;
    stats.max_position_correction = std::max(stats.max_position_correction, dq);
    stats.max_velocity_correction = std::max(stats.max_velocity_correction, dqd);
    const double ratio = std::max(dq, dqd) / bound;
    stats.max_correction_ratio = std::max(stats.max_correction_ratio, ratio);
    if (ratio > 1.0) {
      const std::string what =
          "the drift projection moved q by " + std::to_string(dq) + " and qd by " +
          std::to_string(dqd) + " at t = " + std::to_string(t) +
          ", more than the integration error explains (" + std::to_string(bound) + ")";
      warn(t, "branch_switch", what + ": the state may have left its assembly branch");
      if (s.drift.stop_on_branch_switch) {
        stats.status = RunStatus::branch_switch;
        stats.message = "branch switch: " + what;
        return false;
      }
    }
    return true;
  };
  // After every accepted step: projection (if chosen) and the NaN check. False ends the run.
  auto after_step = [&](double t, State& xs) -> bool {
    ++stats.steps;
    if (s.cancel && s.cancel->load(std::memory_order_relaxed)) {
      stats.status = RunStatus::stopped;
      stats.message = "cancelled at t = " + std::to_string(t);
      return false;
    }
    if (!finite_state(xs)) {
      stats.status = RunStatus::non_finite;
      stats.message = "non-finite state at t = " + std::to_string(t);
      return false;
    }
    if (project) {
      const double r = projector.project(t, xs.data(), stats.projections);
      if (!(r <= s.drift.failure_threshold)) {
        stats.status = RunStatus::step_failure;
        stats.message = "projection onto the constraints failed at t = " + std::to_string(t) +
                        " (max |Phi| = " + std::to_string(r) + ")";
        return false;
      }
      if (!check_branch(t, xs)) return false;
    }
    if (stats.steps > 1'000'000'000L) {
      stats.status = RunStatus::step_failure;
      stats.message = "more than 1e9 steps at t = " + std::to_string(t);
      return false;
    }
    return true;
  };

  // Sample times t0 + i·Δ, plus t_end itself when Δ does not divide the span.
  long total_samples = n_samples;
  const double last_grid = s.t0 + static_cast<double>(n_samples - 1) * s.sample_dt;
  const bool extra_end = s.t_end - last_grid > 1e-9 * s.sample_dt;
  if (extra_end) ++total_samples;
  auto sample_time = [&](long i) {
    return (extra_end && i == total_samples - 1) ? s.t_end
                                                 : s.t0 + static_cast<double>(i) * s.sample_dt;
  };

  if (project) {
    // The initial state is checked by the loader; polish it onto the manifold to round-off.
    projector.project(s.t0, x.data(), stats.projections);
  }
  if (!observe(s.t0, x)) return finish();

  try {
    if (s.integrator == IntegratorKind::bdf) {
      // Implicit BDF (SUNDIALS CVODE, implicit.hpp): same right-hand side, projection and samples.
      detail::ImplicitProblem p;
      p.size = x.size();
      p.rhs = [&](double t, const double* xs, double* dx) { rhs.eval_raw(xs, dx, t); };
      if (project) {
        p.project = [&](double t, double* xs) { projector.project(t, xs, stats.projections); };
      }
      p.observe = [&](double t, State& xs) { return observe(t, xs); };
      p.sample_time = sample_time;
      p.total_samples = total_samples;
      const auto r = detail::integrate_bdf(p, x, s.t0, s);
      stats.steps = r.steps;
      stats.rejected_steps = r.error_test_failures + r.nonlinear_failures;
      if (r.failed && stats.status == RunStatus::completed) {
        stats.status = RunStatus::step_failure;
        stats.message = r.message;
      }
      return finish();
    }
    if (fixed) {
      // Fixed step: rk4, or the dopri5 / rkf78 schemes with a constant step (for order studies).
      odeint::runge_kutta4<State> rk4;
      odeint::runge_kutta_dopri5<State> dp5;
      odeint::runge_kutta_fehlberg78<State> f78;
      long k = 0;
      for (long i = 1; i < total_samples; ++i) {
        const double ts = sample_time(i);
        while (true) {
          const double t = s.t0 + static_cast<double>(k) * s.step;
          if (t >= ts - 1e-9 * s.step) break;
          const double h = std::min(s.step, ts - t);
          switch (s.integrator) {
            case IntegratorKind::rk4:
              rk4.do_step(std::ref(rhs), x, t, h);
              break;
            case IntegratorKind::dopri5:
              dp5.reset();  // the FSAL derivative is stale after a projection
              dp5.do_step(std::ref(rhs), x, t, h);
              break;
            case IntegratorKind::rkf78:
              f78.do_step(std::ref(rhs), x, t, h);
              break;
            case IntegratorKind::bdf:  // handled above (always adaptive)
              break;
          }
          ++k;
          if (!after_step(t + h, x)) return finish();
        }
        if (!observe(ts, x)) return finish();
      }
    } else if (s.integrator == IntegratorKind::dopri5) {
      // Controlled Dormand–Prince 5(4) (FSAL) with dense output at the sample times.
      auto ctrl =
          odeint::make_controlled(s.abs_tol, s.rel_tol, odeint::runge_kutta_dopri5<State>());
      State x_new(x.size()), dxdt(x.size()), dxdt_new(x.size());
      double t = s.t0;
      double dt = std::min(s.step, s.sample_dt);
      rhs(x, dxdt, t);
      long i = 1;
      int failures_in_row = 0;
      while (i < total_samples) {
        const double t_old = t;
        const auto res = ctrl.try_step(std::ref(rhs), x, dxdt, t, x_new, dxdt_new, dt);
        if (res == odeint::fail) {
          ++stats.rejected_steps;
          if (++failures_in_row > 500 || !(dt > 1e-14 * std::max(1.0, std::abs(t)))) {
            stats.status = RunStatus::step_failure;
            stats.message = "step size control failed at t = " + std::to_string(t) + " (step " +
                            std::to_string(dt) + ")";
            const std::string cause = diagnose_singularity(system, t, x, s.uk);
            if (!cause.empty()) stats.message += ": " + cause;
            return finish();
          }
          continue;
        }
        failures_in_row = 0;
        if (stats.min_step == 0.0 || t - t_old < stats.min_step) {
          stats.min_step = t - t_old;
          stats.min_step_t = t;
        }
        // An accepted step this short means the error control resolved a violent change of the
        // motion; at a singular position that is how a run turns onto another assembly branch
        // while every residual stays at round-off (docs/singular-positions.md).
        if (t - t_old < 1e-10 * std::max(1.0, std::abs(t))) {
          warn(t, "step_collapse",
               "an accepted step of " + sci(t - t_old) + " s at t = " + std::to_string(t) +
                   ": the motion changed violently there (near a singular position this is how "
                   "a run switches assembly branch); check the result");
        }
        // Samples inside (t_old, t]: interpolate with the step's dense output.
        while (i < total_samples && sample_time(i) <= t) {
          ctrl.stepper().calc_state(sample_time(i), x_out, x, dxdt, t_old, x_new, dxdt_new, t);
          if (project) projector.project(sample_time(i), x_out.data(), stats.projections);
          if (!observe(sample_time(i), x_out)) return finish();
          ++i;
        }
        if (!after_step(t, x_new)) return finish();
        x.swap(x_new);
        if (project) {
          rhs(x, dxdt, t);  // the FSAL derivative is stale after a projection
        } else {
          dxdt.swap(dxdt_new);
        }
      }
    } else {
      // Controlled Runge–Kutta–Fehlberg 7(8), stepping exactly onto each sample time.
      auto ctrl =
          odeint::make_controlled(s.abs_tol, s.rel_tol, odeint::runge_kutta_fehlberg78<State>());
      double t = s.t0;
      double dt = std::min(s.step, s.sample_dt);
      int failures_in_row = 0;
      for (long i = 1; i < total_samples; ++i) {
        const double ts = sample_time(i);
        while (t < ts - 1e-12 * std::max(1.0, std::abs(ts))) {
          double h = std::min(dt, ts - t);
          const bool clipped = h < dt;
          const auto res = ctrl.try_step(std::ref(rhs), x, t, h);
          if (res == odeint::fail) {
            ++stats.rejected_steps;
            dt = h;
            if (++failures_in_row > 500 || !(dt > 1e-14 * std::max(1.0, std::abs(t)))) {
              stats.status = RunStatus::step_failure;
              stats.message = "step size control failed at t = " + std::to_string(t);
              const std::string cause = diagnose_singularity(system, t, x, s.uk);
              if (!cause.empty()) stats.message += ": " + cause;
              return finish();
            }
            continue;
          }
          failures_in_row = 0;
          if (!clipped || h > dt) dt = h;  // keep the controller's proposal unless clipped
          if (!after_step(t, x)) return finish();
        }
        t = ts;
        if (!observe(ts, x)) return finish();
      }
    }
  } catch (const odeint::step_adjustment_error& e) {
    stats.status = RunStatus::step_failure;
    stats.message = std::string("step size control failed: ") + e.what();
  }
  return finish();
}

// ------------------------------------------------------------------------------------ assembly

AssemblyResult assemble(const System& system, double t, const Vec& q_guess, const Vec& qd_guess,
                        const std::vector<bool>& held, double tol, int max_iterations) {
  const Index n = system.dof();
  const Index m = system.rows();
  if (q_guess.size() != n || qd_guess.size() != n || static_cast<Index>(held.size()) != n) {
    throw Error("assemble: q, qd and held must have " + std::to_string(n) + " entries");
  }
  AssemblyResult res;
  res.q = q_guess;
  res.qd = qd_guess;
  if (m == 0) {
    res.success = true;
    return res;
  }
  std::vector<Index> free;
  for (Index j = 0; j < n; ++j) {
    if (!held[static_cast<std::size_t>(j)]) free.push_back(j);
  }
  const auto nf = static_cast<Index>(free.size());
  ForwardData d(system);
  Vec phi(m);
  Mat Af(m, nf);
  auto gather = [&]() {
    for (Index k = 0; k < nf; ++k) Af.col(k) = d.A.col(free[static_cast<std::size_t>(k)]);
  };
  position_residuals(system, t, res.q, phi);
  double r = phi.cwiseAbs().maxCoeff();
  // Gauss–Newton with minimum-norm steps over the free coordinates: Δq_f = −A_f^+ Φ. Rows that the
  // free coordinates cannot reach (an unsatisfiable set) get the least-squares compromise; the
  // iteration ends when the residual is met or the steps have shrunk to round-off.
  while (r > tol && res.iterations < max_iterations && nf > 0) {
    evaluate_constraints(system, d, t, res.q, res.qd);
    gather();
    const Vec step = Af.completeOrthogonalDecomposition().solve(-phi);
    for (Index k = 0; k < nf; ++k) res.q(free[static_cast<std::size_t>(k)]) += step(k);
    ++res.iterations;
    position_residuals(system, t, res.q, phi);
    r = phi.cwiseAbs().maxCoeff();
    if (!std::isfinite(r)) break;
    if (step.norm() <= 1e-15 * (1.0 + res.q.norm())) break;
  }
  res.max_position_residual = r;
  // Velocities: the nearest q̇ (free coordinates) with A q̇ + Φ_t = 0.
  evaluate_constraints(system, d, t, res.q, res.qd);
  gather();
  Vec phid(m);
  velocity_residuals(system, t, res.q, res.qd, phid);
  if (nf > 0) {
    const Vec dv = Af.completeOrthogonalDecomposition().solve(-phid);
    for (Index k = 0; k < nf; ++k) res.qd(free[static_cast<std::size_t>(k)]) += dv(k);
  }
  velocity_residuals(system, t, res.q, res.qd, phid);
  res.max_velocity_residual = phid.cwiseAbs().maxCoeff();
  // Accept the round-off floor: a satisfiable set lands within a few ulps of the coordinates.
  const double floor_tol = std::max(
      tol, 64 * std::numeric_limits<double>::epsilon() * (1.0 + res.q.cwiseAbs().maxCoeff()));
  res.success = std::isfinite(r) && r <= floor_tol && res.max_velocity_residual <= 1e3 * floor_tol;
  // A bounded move (issue 15 class 5): Gauss–Newton may "converge" by sending a coordinate to
  // 1e14, where the constraints hold to their (absolute) round-off. A move beyond
  // 1e6 (1 + max|q_guess|) is no assembly near the guess: reported as a failure, naming it.
  const double move_bound = 1e6 * (1.0 + q_guess.cwiseAbs().maxCoeff());
  Index far = 0;
  const double move = (res.q - q_guess).cwiseAbs().maxCoeff(&far);
  if (!(move <= move_bound)) {
    res.success = false;
    res.message = "assembly moved coordinate '" +
                  system.coordinate_names()[static_cast<std::size_t>(far)] + "' by " +
                  std::to_string(move) + ", beyond the bound " + std::to_string(move_bound) +
                  " for a move near the guess: no consistent state found near initial.q";
    for (Index i = 0; i < m; ++i) res.unmet_rows.push_back(i);
    return res;
  }
  if (!res.success) {
    for (Index i = 0; i < m; ++i) {
      if (!(std::abs(phi(i)) <= floor_tol)) res.unmet_rows.push_back(i);
    }
    if (res.unmet_rows.empty() && !(res.max_velocity_residual <= 1e3 * floor_tol)) {
      for (Index i = 0; i < m; ++i) {
        if (!(std::abs(phid(i)) <= 1e3 * floor_tol)) res.unmet_rows.push_back(i);
      }
    }
    res.message = "the constraints cannot be met from this guess with the held coordinates fixed";
  }
  return res;
}

}  // namespace ukdyn
