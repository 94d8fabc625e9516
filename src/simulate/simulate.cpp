#include "ukdyn/simulate/simulate.hpp"

#include <algorithm>
#include <boost/numeric/odeint.hpp>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "model/solve_stages.hpp"
#include "simulate/exact_jacobian.hpp"
#include "ukdyn/simulate/diagnostics.hpp"
#include "ukdyn/simulate/drift.hpp"
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
    case IntegratorKind::esdirk:
      return "esdirk";
  }
  return "unknown";
}

bool bdf_available() { return detail::cvode_available(); }
bool esdirk_available() { return detail::arkode_available(); }

std::string to_string(JacobianKind kind) {
  switch (kind) {
    case JacobianKind::automatic:
      return "auto";
    case JacobianKind::exact:
      return "exact";
    case JacobianKind::difference:
      return "difference";
  }
  return "unknown";
}

void zero_force_jacobian(double, CVecRef, CVecRef, Mat& dtau_dq, Mat& dtau_dqd) {
  dtau_dq.setZero();
  dtau_dqd.setZero();
}

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
using detail::sci;

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
  /// Where data was last evaluated by eval_raw(): t and the bytes of q (evaluated_at()).
  double last_t = std::numeric_limits<double>::quiet_NaN();
  Vec last_q;
  /// Largest UkResult::damped_acceleration since reset (the branch check's allowance for it).
  double max_damped = 0.0;
  /// Time of the first evaluation that used the adaptive solve's damping (−1: none yet).
  double damped_t = -1.0;

  Rhs(const System& sys, const ForceFunction& f, const SimulationSettings& settings)
      : system(sys),
        tau_fn(f),
        s(settings),
        data(sys),
        tau(Vec::Zero(sys.dof())),
        phi(sys.rows()),
        phid(sys.rows()),
        n(sys.dof()),
        last_q(Vec::Zero(sys.dof())) {}

  // Whether data's M and A are those at (t, q of x): its last evaluation was at exactly these
  // bytes (so that the drift projection may use them, Projector::project).
  [[nodiscard]] bool evaluated_at(double t, const double* x) const {
    return std::memcmp(&t, &last_t, sizeof t) == 0 &&
           std::memcmp(x, last_q.data(), static_cast<std::size_t>(n) * sizeof(double)) == 0;
  }

  // forward(); with Baumgarte, its stages with b adjusted between the constraints and the solve.
  void eval(CVecRef q, CVecRef qd, double t, ForwardData& d) {
    if (tau_fn) tau_fn(t, q, qd, tau);
    if (s.drift.kind != DriftControl::baumgarte || system.rows() == 0) {
      forward(system, d, t, q, qd, tau, s.uk);
      return;
    }
    evaluate_dynamics(system, d, t, q, qd);
    generalized_forces(system, d, t, q, qd, tau);  // paper Eq. (11), with the applied forces
    constraint_stage(system, d, t, q, qd, s.uk);   // O(N) when the arrow solve applies
    detail::baumgarte_adjust_b(system, d, s.drift, t, q, qd, phi, phid);
    solve_stage(system, d, s.uk);
  }

  void operator()(const State& x, State& dxdt, double t) { eval_raw(x.data(), dxdt.data(), t); }

  void eval_raw(const double* x, double* dxdt, double t) {
    const Eigen::Map<const Vec> q(x, n);
    const Eigen::Map<const Vec> qd(x + n, n);
    last_t = std::numeric_limits<double>::quiet_NaN();  // data is in between until eval returns
    eval(q, qd, t, data);
    last_q = q;
    last_t = t;
    ++evaluations;
    max_damped = std::max(max_damped, data.result.damped_acceleration);
    if (damped_t < 0.0 && data.result.damping > 0.0) damped_t = t;
    Eigen::Map<Vec>(dxdt, n) = qd;
    Eigen::Map<Vec>(dxdt + n, n) = data.qdd;
    // Energy balance: Ẇ = (τ + Q_nc + Qc)ᵀ q̇ − ∂L/∂t as state 2n (the last term is 0 unless a mass
    // depends on t: dE/dt = (τ + Q_nc + Qc)ᵀ q̇ − ∂L/∂t, docs/definitions.md "Time-varying masses").
    if (s.energy_balance) dxdt[2 * n] = data.applied_power + data.Qc.dot(qd) - data.lagrangian_dt;
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

bool finite_state(const State& x) {
  for (double v : x) {
    if (!std::isfinite(v)) return false;
  }
  return true;
}

// A number for a message, to 6 significant digits.
std::string g6(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.6g", v);
  return buf;
}

// Checks the arguments of simulate() (the public edge); returns the number of grid samples.
long check_arguments(const System& system, const Vec& q0, const Vec& qd0,
                     const SimulationSettings& s) {
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
  if (!adaptive_steps(s)) {
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
  if (!s.limits.empty() && static_cast<Index>(s.limits.size()) != n) {
    throw std::invalid_argument("simulate: settings.limits has " + std::to_string(s.limits.size()) +
                                " entries, expected 0 or " + std::to_string(n) + " (system.dof())");
  }
  return n_samples;
}

// One simulation run: the state, the right-hand side, the projection, the statistics, and one
// member per job: observe() a sample, after_step() an accepted step, and one integration loop per
// integrator. simulate() builds it and calls run().
class Run {
 public:
  Run(const System& system, const Vec& q0, const Vec& qd0, const ForceFunction& tau,
      const SimulationSettings& s, const SampleObserver& observer, long n_samples)
      : system_(system),
        s_(s),
        observer_(observer),
        n_(system.dof()),
        fixed_(!adaptive_steps(s)),
        project_(s.drift.kind == DriftControl::projection && system.rows() > 0),
        rhs_(system, tau, s),
        projector_(system, s.drift, s.uk),
        x_(static_cast<std::size_t>(2 * n_ + (s.energy_balance ? 1 : 0)), 0.0),  // [q; q̇; W]
        x_out_(x_.size()),
        last_good_(x_.size()),
        sample_data_(system),
        limit_warned_(s.limits.size(), 0) {
    Eigen::Map<Vec>(x_.data(), n_) = q0;
    Eigen::Map<Vec>(x_.data() + n_, n_) = qd0;
    // Sample times t0 + i·Δ, plus t_end itself when Δ does not divide the span.
    total_samples_ = n_samples;
    const double last_grid = s.t0 + static_cast<double>(n_samples - 1) * s.sample_dt;
    extra_end_ = s.t_end - last_grid > 1e-9 * s.sample_dt;
    if (extra_end_) ++total_samples_;
  }

  SimulationStats run() {
    if (project_) {
      // The initial state is checked by the loader; polish it onto the manifold to round-off.
      projector_.project(s_.t0, x_.data(), stats_.projections);
    }
    if (!observe(s_.t0, x_)) return finish();
    try {
      if (s_.integrator == IntegratorKind::bdf || s_.integrator == IntegratorKind::esdirk) {
        run_bdf();
      } else if (fixed_) {
        run_fixed();
      } else if (s_.integrator == IntegratorKind::dopri5) {
        run_dopri5();
      } else {
        run_rkf78();
      }
    } catch (const odeint::step_adjustment_error& e) {
      stats_.status = RunStatus::step_failure;
      stats_.message = std::string("step size control failed: ") + e.what();
    }
    return finish();
  }

 private:
  double sample_time(long i) const {
    return (extra_end_ && i == total_samples_ - 1) ? s_.t_end
                                                   : s_.t0 + static_cast<double>(i) * s_.sample_dt;
  }

  SimulationStats finish() {
    stats_.rhs_evaluations = rhs_.evaluations;
    return stats_;
  }

  void warn(double t, const std::string& kind, const std::string& message) {
    for (const auto& w : stats_.warnings) {
      if (w.kind == kind) return;
    }
    stats_.warnings.push_back({t, kind, message});
  }

  // The input forces τ of the last evaluation, if they are not numbers: then they, not the model,
  // made the state or acceleration non-finite (a control law, a controller, a force function).
  [[nodiscard]] std::string force_cause() const {
    const Vec& tau = rhs_.tau;
    for (Index i = 0; i < tau.size(); ++i) {
      if (std::isfinite(tau(i))) continue;
      return "the input force tau of coordinate '" +
             system_.coordinate_names()[static_cast<std::size_t>(i)] + "' is " +
             (std::isnan(tau(i)) ? std::string("NaN") : std::to_string(tau(i))) +
             " (the forces given to the model: a control law's u, a controller or a force function "
             "gave no number there)";
    }
    return {};
  }

  // The observer: evaluates forward() at the sample (its own ForwardData), diagnoses, hands over.
  bool observe(double t, const State& xs) {
    const Eigen::Map<const Vec> q(xs.data(), n_);
    const Eigen::Map<const Vec> qd(xs.data() + n_, n_);
    rhs_.eval(q, qd, t, sample_data_);
    sample_data_.work = s_.energy_balance ? xs[static_cast<std::size_t>(2 * n_)] : 0.0;
    ++stats_.samples;
    stats_.t_reached = t;
    const UkResult& r = sample_data_.result;
    if (r.finite) warn_mass_condition(t);
    if (!limit_warned_.empty()) check_limits(t, q, qd);
    const bool keep_going = observer_ ? observer_(t, q, qd, sample_data_) : true;
    if (!r.finite || !finite_state(xs)) {
      stats_.status = RunStatus::non_finite;
      stats_.message = "non-finite state or acceleration at t = " + std::to_string(t);
      if (const std::string forces = force_cause(); !forces.empty()) {
        stats_.message += ": " + forces;
      } else if (finite_state(xs)) {
        const std::string cause = detail::diagnose_singularity(system_, t, xs, s_.uk);
        if (!cause.empty()) stats_.message += ": " + cause;
      }
      return false;
    }
    if (system_.rows() > 0 && !check_solve(t, r)) return false;
    if (!keep_going) {
      stats_.status = RunStatus::stopped;
      stats_.message = "stopped by the observer at t = " + std::to_string(t);
      return false;
    }
    return true;
  }

  // SimulationSettings::limits: a sample outside a coordinate's position range or over its
  // velocity limit is warned (kind joint_limit) once per coordinate, with the first time and the
  // value; the run goes on. Allocates only when it warns (at most once per coordinate).
  void check_limits(double t, const Eigen::Map<const Vec>& q, const Eigen::Map<const Vec>& qd) {
    for (Index i = 0; i < n_; ++i) {
      const auto k = static_cast<std::size_t>(i);
      if (limit_warned_[k]) continue;
      const CoordinateLimits& L = s_.limits[k];
      const bool below = q(i)<L.lower, above = q(i)> L.upper;
      const bool fast = std::abs(qd(i)) > L.velocity;
      if (!below && !above && !fast) continue;
      limit_warned_[k] = 1;
      const std::string& name = system_.coordinate_names()[k];
      const std::string what =
          below || above
              ? "left its range [" + g6(L.lower) + ", " + g6(L.upper) + "]: q = " + g6(q(i))
              : "exceeded its velocity limit " + g6(L.velocity) + ": |qd| = " + g6(std::abs(qd(i)));
      stats_.warnings.push_back({t, "joint_limit",
                                 "coordinate '" + name + "' " + what +
                                     " (the robot file's limit; nothing enforces it, the run "
                                     "goes on)"});
    }
  }

  // The solve's indicators at a sample: warnings, and the end of the run on inconsistency.
  bool check_solve(double t, const UkResult& r) {
    if (r.rank == n_) {
      warn(t, "fully_prescribed",
           "the constraints have full rank " + std::to_string(n_) +
               ": the motion is fully prescribed by kinematics; only Qc depends on the dynamics");
    }
    if (r.rank > 0 && r.sigma_min_kept < s_.near_singular_ratio * r.sigma_max) {
      warn(t, "near_singular",
           "near-singular configuration: smallest kept singular value of A M^-1/2 is " +
               std::to_string(r.sigma_min_kept / r.sigma_max) + " of the largest");
    }
    if (r.damping > 0.0) warn_damped(t);
    if (last_rank_ >= 0 && r.rank != last_rank_) {
      warn(
          t, "rank_change",
          "rank of A changed from " + std::to_string(last_rank_) + " to " + std::to_string(r.rank));
    }
    last_rank_ = r.rank;
    if (!r.consistent) {
      warn(t, "inconsistent_constraints",
           "inconsistent constraints: |A qdd - b| = " + std::to_string(r.residual));
      stats_.status = RunStatus::inconsistent_constraints;
      stats_.message = "inconsistent constraints at t = " + std::to_string(t) +
                       " (|A qdd - b| = " + std::to_string(r.residual) + ")";
      return false;
    }
    return true;
  }

  // M near singular (gimbal lock of Euler angles): warned before the solve gives up.
  void warn_mass_condition(double t) {
    std::size_t blk = 0;
    const double cond = mass_condition(sample_data_, &blk);
    if (!(cond > kMassConditionWarning)) return;
    const bool dense = sample_data_.singular.active && sample_data_.singular.dense_used;
    warn(t, "ill_conditioned_mass",
         "the mass matrix" +
             (dense ? std::string(" (augmented with the constraints)")
                    : " of subsystem '" + system_.subsystems()[blk]->name() + "'") +
             " is ill-conditioned (cond >= " + detail::sci(cond) +
             ", Cholesky pivot estimate): a singular configuration of its coordinates is near "
             "(the gimbal lock of Euler angles?); digits are lost, and the run stops at cond " +
             detail::sci(1.0 / kSingularPivot) +
             " (use type: free_body for a rigid body in space)");
  }

  // The adaptive solve damped the constraint force somewhere in the run: said once, with the time.
  void warn_damped(double t) {
    if (s_.uk.method != UkMethod::adaptive) return;  // regularized: damped everywhere, by choice
    warn(t, "damped_solve",
         "a singular value of A M^-1/2 came within " + sci(s_.uk.adaptive_band) + " x " +
             sci(s_.uk.regularization) +
             " of the largest (a singular position): the constraint force was damped there "
             "(solver.method adaptive), so the accuracy near it is that of the damping, not "
             "of the tolerance; the drift projection removes the constraint error");
  }

  // Branch check (issue 9 item 2, drift.hpp): warned (branch_switch, with its time) or, by
  // setting, the run stops.
  bool check_branch(double t, double h, const State& xs) {
    double xmax = 0.0;
    for (double v : xs) xmax = std::max(xmax, std::abs(v));
    const double dq = projector_.last_dq, dqd = projector_.last_dqd;
    const detail::BranchCheck c =
        detail::check_branch(s_, fixed_, xmax, h, rhs_.max_damped, dq, dqd);
    rhs_.max_damped = 0.0;
    stats_.max_position_correction = std::max(stats_.max_position_correction, dq);
    stats_.max_velocity_correction = std::max(stats_.max_velocity_correction, dqd);
    stats_.max_correction_ratio = std::max(stats_.max_correction_ratio, c.ratio);
    if (c.ratio > 1.0) {
      const std::string what = "the drift projection moved q by " + std::to_string(dq) +
                               " and qd by " + std::to_string(dqd) +
                               " at t = " + std::to_string(t) +
                               ", more than the integration error explains (" +
                               std::to_string(c.bound_q) + ", " + std::to_string(c.bound_qd) + ")";
      warn(t, "branch_switch", what + ": the state may have left its assembly branch");
      if (s_.drift.stop_on_branch_switch) {
        stats_.status = RunStatus::branch_switch;
        stats_.message = "branch switch: " + what;
        return false;
      }
    }
    return true;
  }

  // After every accepted step (of length h, ending at t): projection (if chosen) and the NaN
  // check. False ends the run.
  bool after_step(double t, double h, State& xs) {
    ++stats_.steps;
    if (rhs_.damped_t >= 0.0) warn_damped(rhs_.damped_t);
    if (s_.cancel && s_.cancel->load(std::memory_order_relaxed)) {
      stats_.status = RunStatus::stopped;
      stats_.message = "cancelled at t = " + std::to_string(t);
      return false;
    }
    if (!finite_state(xs)) {
      stats_.status = RunStatus::non_finite;
      stats_.message = "non-finite state at t = " + std::to_string(t);
      if (const std::string forces = force_cause(); !forces.empty()) {
        stats_.message += ": " + forces;
      } else if (std::isfinite(last_good_t_)) {  // why: at the last finite state (singular M, A)
        const std::string cause =
            detail::diagnose_singularity(system_, last_good_t_, last_good_, s_.uk);
        if (!cause.empty()) stats_.message += ": " + cause;
      }
      // The evaluation that gave the NaN: a singular M whose null direction no constraint fixes.
      const ForwardData& d = rhs_.data;
      if (stats_.message.find(':') == std::string::npos && d.singular.active) {
        const std::string why = undetermined_direction(d.M, d.A, system_.coordinate_names());
        if (!why.empty()) stats_.message += ": " + why;
      }
      return false;
    }
    if (project_) {
      // dopri5's last stage was at this state (FSAL): its M and A serve the first iteration.
      ForwardData* at_x = rhs_.evaluated_at(t, xs.data()) ? &rhs_.data : nullptr;
      const double r = projector_.project(t, xs.data(), stats_.projections, at_x);
      if (!(r <= s_.drift.failure_threshold)) {
        stats_.status = RunStatus::step_failure;
        stats_.message = "projection onto the constraints failed at t = " + std::to_string(t) +
                         " (max |Phi| = " + std::to_string(r) + ")";
        return false;
      }
      if (!check_branch(t, h, xs)) return false;
    }
    if (stats_.steps > 1'000'000'000L) {
      stats_.status = RunStatus::step_failure;
      stats_.message = "more than 1e9 steps at t = " + std::to_string(t);
      return false;
    }
    std::copy(xs.begin(), xs.end(), last_good_.begin());  // no allocation: same size
    last_good_t_ = t;
    return true;
  }

  // A rejected adaptive step: false (and the status) when the step control has given up.
  bool step_rejected(double t, double dt, int& failures_in_row, bool with_step) {
    ++stats_.rejected_steps;
    if (++failures_in_row > 500 || !(dt > 1e-14 * std::max(1.0, std::abs(t)))) {
      stats_.status = RunStatus::step_failure;
      stats_.message = "step size control failed at t = " + std::to_string(t);
      if (with_step) stats_.message += " (step " + std::to_string(dt) + ")";
      const std::string cause = detail::diagnose_singularity(system_, t, x_, s_.uk);
      if (!cause.empty()) stats_.message += ": " + cause;
      return false;
    }
    return true;
  }

  // The Jacobian of bdf / esdirk (SimulationSettings::jacobian): the exact one when asked for or
  // when, under automatic, it covers every term of f; else SUNDIALS's difference quotients, and
  // under automatic the reason in stats_.jacobian_note (said once, in the summary).
  void choose_jacobian(detail::ImplicitProblem& p) {
    stats_.jacobian = "difference";
    if (s_.jacobian == JacobianKind::difference) return;
    const std::string gap = detail::exact_jacobian_gap(system_, rhs_.tau_fn, s_);
    if (!gap.empty()) {  // jacobian: exact was refused by simulate() already
      stats_.jacobian_note = "difference-quotient Jacobian: " + gap;
      return;
    }
    exact_.emplace(system_, rhs_.tau_fn, s_);
    p.jacobian = [this](double t, const double* xs, double* J) { return (*exact_)(t, xs, J); };
    stats_.jacobian = "exact";
    if (s_.energy_balance) {  // exact_jacobian.hpp: W is a quadrature
      stats_.jacobian_note =
          "exact Jacobian of (q, qd); the energy-balance state W is a quadrature (f does not "
          "depend on it), its row is left zero";
    }
  }

  // Implicit BDF (SUNDIALS CVODE, implicit.hpp): same right-hand side, projection and samples.
  void run_bdf() {
    detail::ImplicitProblem p;
    choose_jacobian(p);
    p.size = x_.size();
    p.rhs = [&](double t, const double* xs, double* dx) { rhs_.eval_raw(xs, dx, t); };
    if (project_) {
      p.project = [&](double t, double* xs) { projector_.project(t, xs, stats_.projections); };
    }
    p.observe = [&](double t, State& xs) { return observe(t, xs); };
    p.sample_time = [&](long i) { return sample_time(i); };
    p.total_samples = total_samples_;
    const auto r = s_.integrator == IntegratorKind::esdirk
                       ? detail::integrate_esdirk(p, x_, s_.t0, s_)
                       : detail::integrate_bdf(p, x_, s_.t0, s_);
    stats_.steps = r.steps;
    stats_.rejected_steps = r.error_test_failures + r.nonlinear_failures;
    stats_.jacobian_evaluations = r.jacobians;
    stats_.jacobian_fallbacks = r.jacobian_fallbacks;
    if (r.failed && stats_.status == RunStatus::completed) {
      stats_.status = RunStatus::step_failure;
      stats_.message = r.message;
      // Why, as for the explicit steppers' failed step control: at the state the solver reached
      // (a singular M or A there, named with its coordinates or rows).
      const std::string cause = detail::diagnose_singularity(system_, stats_.t_reached, x_, s_.uk);
      if (!cause.empty()) stats_.message += ": " + cause;
    }
  }

  // Fixed step: rk4, or the dopri5 / rkf78 schemes with a constant step (for order studies).
  void run_fixed() {
    odeint::runge_kutta4<State> rk4;
    odeint::runge_kutta_dopri5<State> dp5;
    odeint::runge_kutta_fehlberg78<State> f78;
    long k = 0;
    for (long i = 1; i < total_samples_; ++i) {
      const double ts = sample_time(i);
      while (true) {
        const double t = s_.t0 + static_cast<double>(k) * s_.step;
        if (t >= ts - 1e-9 * s_.step) break;
        const double h = std::min(s_.step, ts - t);
        switch (s_.integrator) {
          case IntegratorKind::rk4:
            rk4.do_step(std::ref(rhs_), x_, t, h);
            break;
          case IntegratorKind::dopri5:
            dp5.reset();  // the FSAL derivative is stale after a projection
            dp5.do_step(std::ref(rhs_), x_, t, h);
            break;
          case IntegratorKind::rkf78:
            f78.do_step(std::ref(rhs_), x_, t, h);
            break;
          case IntegratorKind::bdf:  // handled by run_bdf (always adaptive)
          case IntegratorKind::esdirk:
            break;
        }
        ++k;
        if (!after_step(t + h, h, x_)) return;
      }
      if (!observe(ts, x_)) return;
    }
  }

  // Controlled Dormand–Prince 5(4) (FSAL) with dense output at the sample times.
  void run_dopri5() {
    auto ctrl =
        odeint::make_controlled(s_.abs_tol, s_.rel_tol, odeint::runge_kutta_dopri5<State>());
    State x_new(x_.size()), dxdt(x_.size()), dxdt_new(x_.size());
    double t = s_.t0;
    double dt = std::min(s_.step, s_.sample_dt);
    rhs_(x_, dxdt, t);
    long i = 1;
    int failures_in_row = 0;
    while (i < total_samples_) {
      const double t_old = t;
      const auto res = ctrl.try_step(std::ref(rhs_), x_, dxdt, t, x_new, dxdt_new, dt);
      if (res == odeint::fail) {
        if (!step_rejected(t, dt, failures_in_row, true)) return;
        continue;
      }
      failures_in_row = 0;
      note_accepted_step(t_old, t);
      // Samples inside (t_old, t]: interpolate with the step's dense output.
      while (i < total_samples_ && sample_time(i) <= t) {
        ctrl.stepper().calc_state(sample_time(i), x_out_, x_, dxdt, t_old, x_new, dxdt_new, t);
        if (project_) projector_.project(sample_time(i), x_out_.data(), stats_.projections);
        if (!observe(sample_time(i), x_out_)) return;
        ++i;
      }
      if (!after_step(t, t - t_old, x_new)) return;
      x_.swap(x_new);
      if (project_) {
        rhs_(x_, dxdt, t);  // the FSAL derivative is stale after a projection
      } else {
        dxdt.swap(dxdt_new);
      }
    }
  }

  // The smallest accepted step, and the step_collapse warning.
  void note_accepted_step(double t_old, double t) {
    if (stats_.min_step == 0.0 || t - t_old < stats_.min_step) {
      stats_.min_step = t - t_old;
      stats_.min_step_t = t;
    }
    // An accepted step this short means the error control resolved a violent change of the
    // motion; at a singular position that is how a run turns onto another assembly branch while
    // every residual stays at round-off (docs/singular-positions.md).
    if (t - t_old < 1e-10 * std::max(1.0, std::abs(t))) {
      warn(t, "step_collapse",
           "an accepted step of " + sci(t - t_old) + " s at t = " + std::to_string(t) +
               ": the motion changed violently there (near a singular position this is how "
               "a run switches assembly branch); check the result");
    }
  }

  // Controlled Runge–Kutta–Fehlberg 7(8), stepping exactly onto each sample time.
  void run_rkf78() {
    auto ctrl =
        odeint::make_controlled(s_.abs_tol, s_.rel_tol, odeint::runge_kutta_fehlberg78<State>());
    double t = s_.t0;
    double dt = std::min(s_.step, s_.sample_dt);
    int failures_in_row = 0;
    for (long i = 1; i < total_samples_; ++i) {
      const double ts = sample_time(i);
      while (t < ts - 1e-12 * std::max(1.0, std::abs(ts))) {
        double h = std::min(dt, ts - t);
        const bool clipped = h < dt;
        const double t_before = t;
        const auto res = ctrl.try_step(std::ref(rhs_), x_, t, h);
        if (res == odeint::fail) {
          dt = h;
          if (!step_rejected(t, dt, failures_in_row, false)) return;
          continue;
        }
        failures_in_row = 0;
        if (!clipped || h > dt) dt = h;  // keep the controller's proposal unless clipped
        if (!after_step(t, t - t_before, x_)) return;
      }
      t = ts;
      if (!observe(ts, x_)) return;
    }
  }

  const System& system_;
  const SimulationSettings& s_;
  const SampleObserver& observer_;
  const Index n_;
  const bool fixed_, project_;
  Rhs rhs_;
  detail::Projector projector_;
  State x_, x_out_;
  State last_good_;  ///< the state after the last accepted finite step (for the diagnosis)
  double last_good_t_ = std::numeric_limits<double>::quiet_NaN();
  ForwardData sample_data_;
  SimulationStats stats_;
  int last_rank_ = -1;
  std::vector<char> limit_warned_;  ///< per coordinate: joint_limit said (sized once)
  long total_samples_ = 0;
  bool extra_end_ = false;
  std::optional<detail::ExactJacobian> exact_;  ///< bdf / esdirk with the exact Jacobian
};

}  // namespace

SimulationStats simulate(const System& system, const Vec& q0, const Vec& qd0,
                         const ForceFunction& tau, const SimulationSettings& s,
                         const SampleObserver& observer) {
  const long n_samples = check_arguments(system, q0, qd0, s);
  if (s.jacobian == JacobianKind::exact &&
      (s.integrator == IntegratorKind::bdf || s.integrator == IntegratorKind::esdirk)) {
    const std::string gap = detail::exact_jacobian_gap(system, tau, s);
    if (!gap.empty()) {
      throw Error("simulate: jacobian exact: the exact Jacobian does not cover f: " + gap +
                  " (use jacobian auto or difference)");
    }
  }
  // The rows redundant around the whole motion (Bricard's mechanism), told from a start at a
  // singular position: the adaptive solve damps only the latter (UkSettings::structural_redundancy).
  const int redundancy = s.uk.structural_redundancy > 0
                             ? s.uk.structural_redundancy
                             : detail::structural_redundancy(system, s.t0, q0, qd0, s.uk);
  SimulationSettings with_redundancy;
  const bool copy = redundancy != s.uk.structural_redundancy;
  if (copy) {
    with_redundancy = s;
    with_redundancy.uk.structural_redundancy = redundancy;
  }
  Run run(system, q0, qd0, tau, copy ? with_redundancy : s, observer, n_samples);
  SimulationStats stats = run.run();
  stats.structural_redundancy = redundancy;
  return stats;
}

}  // namespace ukdyn
