// Assembly: a consistent initial state near a guess (Gauss–Newton with minimum-norm steps over the
// free coordinates, [Nikravesh1988]). Declared in simulate.hpp.
#include <Eigen/QR>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "ukdyn/simulate/simulate.hpp"

namespace ukdyn {

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
