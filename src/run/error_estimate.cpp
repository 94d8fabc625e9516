#include "run/error_estimate.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>

#include "run/run_observer.hpp"
#include "ukdyn/output/control_output.hpp"
#include "ukdyn/simulate/control.hpp"

namespace ukdyn::io_detail {

SimulationSettings shadow_settings(const SimulationSettings& s) {
  SimulationSettings t = s;
  if (adaptive_steps(s)) {
    // dopri5's global error scales about as the tolerance (its error per unit step is
    // controlled, [Hairer1993] II.4): 100× tighter leaves the shadow's own error ~1 % of the run's.
    t.abs_tol = std::max(s.abs_tol / 100.0, 1e-16);
    t.rel_tol = s.rel_tol > 0.0 ? std::max(s.rel_tol / 100.0, 1e-16) : 0.0;
  } else {
    t.step = s.step / 4.0;  // rk4: error / 256; still divides sample_dt
  }
  // The damping of the adaptive / regularized solve is kept: a smaller one meets the exact
  // cut-off (rank_rel_tol 1e-7 against the scenario default 1e-6) and the shadow stops at the
  // singular position the run passed (measured: the N-four-bar, N = 2, at t = 0.714 s). So the
  // estimate covers the integration error, not the damping's (docs/accuracy.md).
  t.limits.clear();
  t.sigma_min_svd = false;
  return t;
}

ShadowEstimate::ShadowEstimate(const Scenario& sc, const std::atomic<bool>* cancel)
    : settings_(shadow_settings(sc.sim)) {
  settings_.cancel = cancel;
  const std::unique_ptr<ControlRun> ctl = make_control_run(sc);
  const System& sys = ctl ? *ctl->plant : *sc.system;
  n_ = sys.dof();
  const double span = settings_.t_end - settings_.t0;
  const long samples = static_cast<long>(std::floor(span / settings_.sample_dt + 1e-9)) + 2;
  const long budget = 2'000'000;  // numbers kept: 16 MB
  stride_ = std::max<long>(1, (samples * std::max<Index>(n_, 1) + budget - 1) / budget);
  q_.reserve(static_cast<std::size_t>((samples / stride_ + 1) * n_));
  t_.reserve(static_cast<std::size_t>(samples / stride_ + 1));
  const ForceFunction tau = run_forces(sc, ctl.get(), settings_);
  long k = 0;
  const auto start = std::chrono::steady_clock::now();
  shadow_stats_ = simulate(sys, ctl ? ctl->q0 : sc.q0, ctl ? ctl->qd0 : sc.qd0, tau, settings_,
                           [&](double t, CVecRef q, CVecRef, const ForwardData&) {
                             if (k++ % stride_ == 0) {
                               t_.push_back(t);
                               q_.insert(q_.end(), q.data(), q.data() + q.size());
                             }
                             return true;
                           });
  shadow_seconds_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  settings_.tau_jacobian = {};  // a law's references ctl, which ends here
}

void ShadowEstimate::compare(double t, CVecRef q) {
  const long k = sample_++;
  if (k % stride_ != 0) return;
  const auto i = static_cast<std::size_t>(k / stride_);
  // The same sample times in both runs (t0 + i Δ, then t_end): a different time is not compared.
  if (i >= t_.size() || std::abs(t_[i] - t) > 1e-9 * std::max(1.0, std::abs(t))) return;
  const double* qs = q_.data() + i * static_cast<std::size_t>(n_);
  for (Index j = 0; j < n_ && j < q.size(); ++j) {
    const double e = std::abs(q(j) - qs[j]);
    if (e > max_ || std::isnan(e)) {
      max_ = std::isnan(e) ? std::numeric_limits<double>::infinity() : e;
      max_t_ = t;
      max_coordinate_ = j;
    }
  }
  ++compared_;
}

namespace {

// Where the constraint force was damped (a damped_solve warning of the run or of its shadow, or the
// regularized solve everywhere): the time, or a negative number if nowhere.
double damped_at(const SimulationStats& run, const SimulationStats& shadow,
                 const SimulationSettings& s) {
  if (s.uk.method == UkMethod::regularized) return s.t0;
  for (const SimulationStats* st : {&run, &shadow})
    for (const RunWarning& w : st->warnings)
      if (w.kind == "damped_solve") return w.t;
  return -1.0;
}

}  // namespace

ErrorEstimate ShadowEstimate::result(const System& system, const SimulationStats& run) const {
  ErrorEstimate e;
  e.requested = true;
  e.max_abs_q = max_;
  e.t = max_t_;
  if (max_coordinate_ >= 0 &&
      static_cast<std::size_t>(max_coordinate_) < system.coordinate_names().size()) {
    e.coordinate = system.coordinate_names()[static_cast<std::size_t>(max_coordinate_)];
  }
  e.samples_compared = compared_;
  e.stride = stride_;
  e.shadow_status = to_string(shadow_stats_.status);
  e.shadow_t_reached = shadow_stats_.t_reached;
  e.shadow_abs_tol = settings_.abs_tol;
  e.shadow_rel_tol = settings_.rel_tol;
  e.shadow_step = adaptive_steps(settings_) ? 0.0 : settings_.step;
  e.shadow_regularization = settings_.uk.regularization;
  e.shadow_seconds = shadow_seconds_;
  if (shadow_stats_.status != RunStatus::completed) {
    e.note = "the shadow run stopped at t = " + std::to_string(shadow_stats_.t_reached) + " (" +
             shadow_stats_.message + "): the estimate covers the samples before it only";
  }
  // Through a singular position both runs keep the damping (shadow_settings): the difference then
  // measured 0.1x to 4x the true error (docs/accuracy.md), so it is not vouched for.
  if (const double td = damped_at(run, shadow_stats_, settings_); td >= 0.0) {
    e.reliable = false;
    const std::string why =
        settings_.uk.method == UkMethod::regularized
            ? std::string("the regularized solve damps the constraint force everywhere")
            : "the constraint force was damped near a singular position (from t = " +
                  std::to_string(td) + ", damped_solve)";
    e.note = (e.note.empty() ? "" : e.note + "; ") + "not reliable: " + why +
             ", and both runs carry the damping's error, so the difference is not the run's "
             "error in either direction (docs/accuracy.md)";
  }
  return e;
}

}  // namespace ukdyn::io_detail
