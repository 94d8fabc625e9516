#include "ukdyn/simulate/simulate.hpp"

#include <boost/numeric/odeint.hpp>
#include <cmath>
#include <vector>

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
  const UkSettings& uk;
  ForwardData data;
  Vec tau;
  Index n;
  long evaluations = 0;
  bool inconsistent = false;
  double inconsistent_time = 0.0;

  Rhs(const System& s, const ForceFunction& f, const UkSettings& u)
      : system(s), tau_fn(f), uk(u), data(s), tau(Vec::Zero(s.dof())), n(s.dof()) {}

  void eval(const double* x, double t) {
    const Eigen::Map<const Vec> q(x, n);
    const Eigen::Map<const Vec> qd(x + n, n);
    if (tau_fn) tau_fn(t, q, qd, tau);
    forward(system, data, t, q, qd, tau, uk);
    ++evaluations;
    if (!data.result.consistent && !inconsistent) {
      inconsistent = true;
      inconsistent_time = t;
    }
  }

  void operator()(const State& x, State& dxdt, double t) {
    eval(x.data(), t);
    Eigen::Map<Vec> dq(dxdt.data(), n);
    Eigen::Map<Vec> dqd(dxdt.data() + n, n);
    dq = Eigen::Map<const Vec>(x.data() + n, n);
    dqd = data.qdd;
  }
};

bool finite_state(const State& x) {
  for (double v : x) {
    if (!std::isfinite(v)) return false;
  }
  return true;
}

}  // namespace

SimulationStats simulate(const System& system, const Vec& q0, const Vec& qd0,
                         const ForceFunction& tau, const SimulationSettings& s,
                         const SampleObserver& observer) {
  const Index n = system.dof();
  if (q0.size() != n || qd0.size() != n) {
    throw Error("simulate: q0 and qd0 must have " + std::to_string(n) + " entries");
  }
  if (!(s.t_end > s.t0) || !std::isfinite(s.t_end) || !std::isfinite(s.t0)) {
    throw Error("simulate: t_end must be finite and greater than t0");
  }
  if (!(s.sample_dt > 0.0) || !std::isfinite(s.sample_dt)) {
    throw Error("simulate: sample_dt must be a positive number");
  }
  if (!(s.step > 0.0) || !std::isfinite(s.step)) throw Error("simulate: step must be positive");
  const double span = s.t_end - s.t0;
  const auto n_samples = static_cast<long>(std::floor(span / s.sample_dt + 1e-9)) + 1;
  if (n_samples > 100'000'000) throw Error("simulate: more than 1e8 output samples requested");
  long substeps = 1;
  if (s.integrator == IntegratorKind::rk4) {
    const double ratio = s.sample_dt / s.step;
    substeps = std::lround(ratio);
    if (substeps < 1 || std::abs(ratio - static_cast<double>(substeps)) > 1e-9 * ratio) {
      throw Error("simulate: the rk4 step must divide sample_dt (sample_dt/step = " +
                  std::to_string(ratio) + ")");
    }
  } else {
    if (!(s.abs_tol > 0.0) || !(s.rel_tol >= 0.0)) {
      throw Error("simulate: abs_tol must be > 0 and rel_tol >= 0");
    }
  }

  SimulationStats stats;
  Rhs rhs(system, tau, s.uk);
  State x(static_cast<std::size_t>(2 * n));
  Eigen::Map<Vec>(x.data(), n) = q0;
  Eigen::Map<Vec>(x.data() + n, n) = qd0;
  State x_out(x.size());

  // Observer: evaluates forward() at the sample (its own ForwardData) and hands it over.
  ForwardData sample_data(system);
  Vec tau_buf = Vec::Zero(n);
  auto observe = [&](double t, const State& xs) -> bool {
    const Eigen::Map<const Vec> q(xs.data(), n);
    const Eigen::Map<const Vec> qd(xs.data() + n, n);
    if (tau) tau(t, q, qd, tau_buf);
    forward(system, sample_data, t, q, qd, tau_buf, s.uk);
    ++stats.samples;
    stats.t_reached = t;
    const bool keep_going = observer ? observer(t, q, qd, sample_data) : true;
    if (!sample_data.result.finite || !finite_state(xs)) {
      stats.status = RunStatus::non_finite;
      stats.message = "non-finite state or acceleration at t = " + std::to_string(t);
      return false;
    }
    if (!sample_data.result.consistent) {
      stats.status = RunStatus::inconsistent_constraints;
      stats.message = "inconsistent constraints at t = " + std::to_string(t) +
                      " (|A qdd - b| = " + std::to_string(sample_data.result.residual) + ")";
      return false;
    }
    if (!keep_going) {
      stats.status = RunStatus::stopped;
      stats.message = "stopped by the observer at t = " + std::to_string(t);
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
  auto finish = [&]() {
    stats.rhs_evaluations = rhs.evaluations;
    return stats;
  };
  if (!observe(s.t0, x)) return finish();

  constexpr long max_steps = 100'000'000;
  try {
    if (s.integrator == IntegratorKind::dopri5) {
      // Controlled Dormand–Prince 5(4) with dense output (Boost.Odeint): steps are chosen by the
      // error control, samples are interpolated at the requested times.
      auto stepper =
          odeint::make_dense_output(s.abs_tol, s.rel_tol, odeint::runge_kutta_dopri5<State>());
      stepper.initialize(x, s.t0, std::min(s.step, s.sample_dt));
      for (long i = 1; i < total_samples; ++i) {
        const double ts = sample_time(i);
        while (stepper.current_time() < ts) {
          stepper.do_step(std::ref(rhs));
          ++stats.steps;
          if (!finite_state(stepper.current_state())) {
            stats.status = RunStatus::non_finite;
            stats.message = "non-finite state at t = " + std::to_string(stepper.current_time());
            return finish();
          }
          if (stats.steps > max_steps) {
            stats.status = RunStatus::step_failure;
            stats.message = "more than 1e8 steps before t = " + std::to_string(ts);
            return finish();
          }
        }
        stepper.calc_state(ts, x_out);
        if (!observe(ts, x_out)) return finish();
      }
    } else {
      // Classical fixed-step Runge–Kutta 4 (Boost.Odeint).
      odeint::runge_kutta4<State> stepper;
      long k = 0;
      for (long i = 1; i < total_samples; ++i) {
        const double ts = sample_time(i);
        while (true) {
          const double t = s.t0 + static_cast<double>(k) * s.step;
          if (t >= ts - 1e-9 * s.step) break;
          const double h = std::min(s.step, ts - t);
          stepper.do_step(std::ref(rhs), x, t, h);
          ++k;
          ++stats.steps;
          if (!finite_state(x)) {
            stats.status = RunStatus::non_finite;
            stats.message = "non-finite state at t = " + std::to_string(t + h);
            return finish();
          }
        }
        if (!observe(ts, x)) return finish();
      }
    }
  } catch (const odeint::step_adjustment_error& e) {
    stats.status = RunStatus::step_failure;
    stats.message = std::string("step size control failed: ") + e.what();
  } catch (const odeint::no_progress_error& e) {
    stats.status = RunStatus::step_failure;
    stats.message = std::string("integrator made no progress: ") + e.what();
  }
  return finish();
}

}  // namespace ukdyn
