// Applied generalized forces Q_a(t, q, q̇) that depend on the state: dampers, springs between
// points, joint friction, drive torques, feedback laws. The System adds them in forward():
//   Q = τ + Σ Q_a(t, q, q̇) − C q̇ − G   (paper Eq. (11) with the applied forces).
// A force may have a conservative part Q = −∂V_a/∂q with a potential V_a(q) (a spring between
// points fixed in time); V_a is then counted in the potential energy, and only the rest does work
// in the energy balance E − W_nc (simulate.hpp, SimulationSettings::energy_balance).
#pragma once

#include <string>

#include "ukdyn/model/subsystem.hpp"

namespace ukdyn {

class AppliedForce {
 public:
  virtual ~AppliedForce() = default;
  [[nodiscard]] virtual const std::string& name() const = 0;
  /// Adds Q_a(t, q, q̇) (all n system coordinates) to Q. Returns the power of its
  /// non-conservative part, Q_ncᵀ q̇ (everything but −∂V_a/∂q). Allocation-free.
  virtual double add_to(double t, CVecRef q, CVecRef qd, VecRef Q) const = 0;
  /// The potential V_a(q) of the conservative part (0 if it has none).
  [[nodiscard]] virtual double potential(CVecRef q) const = 0;
  /// Exact derivatives (docs/derivatives.md): whether add_tangent() is implemented.
  [[nodiscard]] virtual bool has_derivatives() const { return false; }
  /// Adds the directional derivative of Q_a along (dq, dqd) at fixed t to dQ, exact. Returns false
  /// when this force has no exact derivatives (the default).
  virtual bool add_tangent(double t, CVecRef q, CVecRef qd, CVecRef dq, CVecRef dqd,
                           VecRef dQ) const {
    (void)t, (void)q, (void)qd, (void)dq, (void)dqd, (void)dQ;
    return false;
  }
  /// Adds ∂Q_a/∂t at fixed (q, q̇) to dQ, exact (docs/derivatives.md, "Time"); a force that does
  /// not depend on t adds nothing. Returns false when this force has no exact ∂/∂t (the default:
  /// add_to() is given t, so no default can vouch for 0).
  virtual bool add_time_tangent(double t, CVecRef q, CVecRef qd, VecRef dQ) const {
    (void)t, (void)q, (void)qd, (void)dQ;
    return false;
  }
};

}  // namespace ukdyn
