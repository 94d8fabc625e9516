#include "ukdyn/simulate/drift.hpp"

#include <algorithm>
#include <cmath>

#include "model/solve_stages.hpp"

namespace ukdyn::detail {

void baumgarte_adjust_b(const System& system, ForwardData& data, const DriftSettings& ds, double t,
                        CVecRef q, CVecRef qd, Vec& phi, Vec& phid) {
  position_residuals(system, data, t, q, phi);
  velocity_residuals(system, data, t, q, qd, phid);
  data.b -= 2.0 * ds.alpha * phid + ds.beta * ds.beta * phi;
}

Projector::Projector(const System& sys, const DriftSettings& d, const UkSettings& u)
    : system(sys),
      ds(d),
      uk(u),
      data(sys),
      phi(sys.rows()),
      zero_Q(Vec::Zero(sys.dof())),
      delta(sys.dof()),
      Qc_scratch(sys.dof()),
      n(sys.dof()) {}

double Projector::project(double t, double* x, long& iterations, ForwardData* at_x) {
  Eigen::Map<Vec> q(x, n);
  Eigen::Map<Vec> qd(x + n, n);
  position_residuals(system, data, t, q, phi);
  double r = phi.cwiseAbs().maxCoeff();
  last_dq = 0.0;
  for (int it = 0; it < ds.max_iterations && r > ds.position_tol; ++it) {
    // At the unmoved q, M and A of the caller's evaluation there (the same bytes) if it has one.
    ForwardData& d = it == 0 && at_x ? *at_x : data;
    if (&d == &data) {
      evaluate_dynamics(system, data, t, q, qd);
      constraint_stage(system, data, t, q, qd, uk);
    }
    phi = -phi;
    solve_for(system, d, phi, zero_Q, delta, Qc_scratch, uk);
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
  evaluate_dynamics(system, data, t, q, qd);
  constraint_stage(system, data, t, q, qd, uk);
  velocity_residuals(system, data, t, q, qd, phi);
  phi = -phi;
  solve_for(system, data, phi, zero_Q, delta, Qc_scratch, uk);
  qd += delta;
  last_dqd = delta.cwiseAbs().maxCoeff();
  return r;
}

// A damped solve (regularized, adaptive in its band) leaves a constraint acceleration error of up
// to a = UkResult::damped_acceleration, which the projection then removes: over a step h that is
// ½ a h² in q and a h in q̇, added to the allowance (× branch_factor), so that a correct damped run
// is not reported; a jump to another branch is O(1), far beyond either.
BranchCheck check_branch(const SimulationSettings& s, bool fixed, double xmax, double h,
                         double damped, double dq, double dqd) {
  BranchCheck c;
  const double bound =
      s.drift.branch_factor * (fixed ? 1e-9 * (1.0 + xmax) : s.abs_tol + s.rel_tol * xmax);
  c.bound_q = bound + s.drift.branch_factor * 0.5 * damped * h * h;
  c.bound_qd = bound + s.drift.branch_factor * damped * h;
  c.ratio = damped > 0.0 ? std::max(dq / c.bound_q, dqd / c.bound_qd) : std::max(dq, dqd) / bound;
  return c;
}

}  // namespace ukdyn::detail
