#include "simulate/exact_jacobian.hpp"

#include <exception>

namespace ukdyn::detail {

std::string exact_jacobian_gap(const System& system, const ForceFunction& tau,
                               const SimulationSettings& s) {
  std::string gap;
  const auto add = [&gap](const std::string& why) { gap += (gap.empty() ? "" : "; ") + why; };
  const auto missing = components_without_derivatives(system);
  if (!missing.empty()) {
    std::string names;
    for (const auto& m : missing) names += (names.empty() ? "" : ", ") + m;
    add("no exact derivatives for " + names);
  }
  if (tau && !s.tau_jacobian) {
    add("the applied torques tau(t, q, qd) (a control law whose model has no exact derivatives, "
        "or a force function without SimulationSettings::tau_jacobian) have no exact "
        "d tau/d(q, qd)");
  }
  if (s.drift.kind == DriftControl::baumgarte && system.rows() > 0) {
    add("the Baumgarte terms in b (-2 alpha Phi_dot - beta^2 Phi) are not differentiated");
  }
  if (s.uk.method == UkMethod::regularized) {
    add("the regularized solve's damped acceleration is not the one linearize() differentiates");
  }
  return gap;
}

ExactJacobian::ExactJacobian(const System& system, const ForceFunction& tau,
                             const SimulationSettings& settings)
    : system_(system),
      tau_fn_(tau),
      s_(settings),
      n_(system.dof()),
      size_(2 * system.dof() + (settings.energy_balance ? 1 : 0)),
      tau_(Vec::Zero(system.dof())),
      dtau_dq_(Mat::Zero(n_, n_)),
      dtau_dqd_(Mat::Zero(n_, n_)),
      lin_(system) {}

bool ExactJacobian::operator()(double t, const double* x, double* J) {
  const Eigen::Map<const Vec> q(x, n_);
  const Eigen::Map<const Vec> qd(x + n_, n_);
  Eigen::Map<Mat> Jm(J, size_, size_);  // column-major, as SUNDIALS' dense matrix
  // With the energy balance, row and column 2n (W) stay zero: W is a quadrature (see the header).
  // Called from SUNDIALS (C): nothing may propagate out of it.
  try {
    if (tau_fn_) tau_fn_(t, q, qd, tau_);
    // ∂q̈/∂τ only for the chain rule through τ(t, q, q̇); ∂Qc and ∂/∂t are not terms of ∂f/∂x.
    linearize(system_, lin_, t, q, qd, tau_, s_.uk,
              LinearizeParts{/*tau=*/static_cast<bool>(tau_fn_), /*constraint_force=*/false,
                             /*structured=*/false, /*time=*/false});
    const Linearization& lin = lin_.lin;
    if (!lin.trusted) return false;
    for (Index i = 0; i < n_; ++i) Jm(i, n_ + i) = 1.0;  // ∂q̇/∂q̇ = I
    Jm.block(n_, 0, n_, n_) = lin.dqdd_dq;
    Jm.block(n_, n_, n_, n_) = lin.dqdd_dqd;
    if (tau_fn_) {  // the chain rule through τ(t, q, q̇)
      s_.tau_jacobian(t, q, qd, dtau_dq_, dtau_dqd_);
      Jm.block(n_, 0, n_, n_).noalias() += lin.dqdd_dtau * dtau_dq_;
      Jm.block(n_, n_, n_, n_).noalias() += lin.dqdd_dtau * dtau_dqd_;
    }
  } catch (const std::exception&) {
    return false;
  }
  return true;
}

}  // namespace ukdyn::detail
