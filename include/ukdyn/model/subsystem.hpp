// An unconstrained subsystem in Lagrange form, paper Eq. (10): M(q) q̈ + C(q, q̇) q̇ + G(q) = τ
// (with a mass of t: M(q, t), G(q, t) and the extra (∂M/∂t) q̇ term, see dynamics_at()).
#pragma once

#include <span>
#include <string>
#include <vector>

#include "ukdyn/core/types.hpp"

namespace ukdyn {

using VecRef = Eigen::Ref<Vec>;
using CVecRef = const Eigen::Ref<const Vec>&;
using MatRef = Eigen::Ref<Mat>;
/// A block's data slot: caller-owned doubles in ForwardData (see ForwardData::slots) that the
/// block's evaluation may use as scratch and to hand values to a later stage of the same forward().
using Slot = std::span<double>;
using ConstSlot = std::span<const double>;

/// A subsystem owns `dof()` consecutive generalized coordinates of the system. Implementations are
/// constant after construction; every method writes into caller-owned storage and allocates
/// nothing.
class Subsystem {
 public:
  virtual ~Subsystem() = default;
  [[nodiscard]] virtual Index dof() const = 0;
  [[nodiscard]] virtual const std::string& name() const = 0;
  [[nodiscard]] virtual const std::vector<std::string>& coordinate_names() const = 0;

  /// Mass matrix M(q), paper Eq. (5). Writes a dof × dof block.
  virtual void mass(CVecRef q, MatRef M) const = 0;
  /// Coriolis/centrifugal matrix C(q, q̇) with Ṁ − 2C skew-symmetric, paper Eq. (9).
  virtual void coriolis(CVecRef q, CVecRef qd, MatRef C) const = 0;
  /// The vector C(q, q̇) q̇ (cheaper than forming C).
  virtual void coriolis_times_qd(CVecRef q, CVecRef qd, VecRef Cqd) const = 0;
  /// Generalized gravity G(q) = ∂V/∂q, paper Eq. (8).
  virtual void gravity(CVecRef q, VecRef G) const = 0;
  /// M(q), C(q, q̇) q̇ and G(q) in one call (what the forward evaluation needs, paper Eq. (10)).
  /// The default calls mass(), coriolis_times_qd() and gravity(); a subsystem whose three share
  /// work (the same sin/cos, say) overrides it. Must give the same values as the three calls.
  virtual void dynamics(CVecRef q, CVecRef qd, MatRef M, VecRef Cqd, VecRef G) const {
    mass(q, M);
    coriolis_times_qd(q, qd, Cqd);
    gravity(q, G);
  }
  /// Doubles of data slot this subsystem uses in forward() (0: none). ForwardData holds one slot of
  /// this size per subsystem, zero-filled when it is built; the model itself stays constant.
  [[nodiscard]] virtual Index slot_size() const { return 0; }
  /// dynamics() as forward() calls it, with this subsystem's data slot (slot_size() doubles, or
  /// empty). A subsystem keeps there its scratch (a tape's work buffer) and what constraints on its
  /// coordinates read back later in the same forward() (ConstraintSlots::subsystem(): the mobile
  /// manipulator's sin/cos). Same values as dynamics(). Default: dynamics(), slot unused.
  virtual void dynamics_with(Slot slot, CVecRef q, CVecRef qd, MatRef M, VecRef Cqd,
                             VecRef G) const {
    (void)slot;
    dynamics(q, qd, M, Cqd, G);
  }
  /// Potential energy V(q) (gravity), up to a constant.
  [[nodiscard]] virtual double potential(CVecRef q) const = 0;

  // Time-varying subsystems (docs/definitions.md, "Time-varying masses"): a Lagrangian
  // L(q, q̇, t) = T(q, q̇, t) − V(q, t) with T = ½ q̇ᵀ M(q, t) q̇ (a mass or inertia of t). Lagrange's
  // equations d/dt ∂T/∂q̇ − ∂T/∂q + ∂V/∂q = Q give M q̈ + C q̇ + (∂M/∂t) q̇ + G(q, t) = Q: the
  // "C q̇" of dynamics_at() then includes (∂M/∂t) q̇ = ∂²T/∂q̇∂t. The t-less methods above are the
  // values at t = 0 for such a subsystem; forward() uses dynamics_at() and potential_at().
  /// True if M, G or V depend on t explicitly (default false: every subsystem but a derived one
  /// with a mass or inertia of t).
  [[nodiscard]] virtual bool time_varying() const { return false; }
  /// dynamics_with() at time t, also giving Lt = ∂L/∂t = ∂T/∂t − ∂V/∂t at (q, q̇, t) (the power
  /// that enters the energy balance, dE/dt = Q_ncᵀq̇ + Q_cᵀq̇ − ∂L/∂t). Default: dynamics_with()
  /// and Lt = 0 (a time-invariant subsystem). Same values as dynamics_with() when not
  /// time_varying().
  virtual void dynamics_at(Slot slot, double t, CVecRef q, CVecRef qd, MatRef M, VecRef Cqd,
                           VecRef G, double& Lt) const {
    (void)t;
    dynamics_with(slot, q, qd, M, Cqd, G);
    Lt = 0.0;
  }
  /// V(q, t). Default: potential(q).
  [[nodiscard]] virtual double potential_at(double t, CVecRef q) const {
    (void)t;
    return potential(q);
  }
};

}  // namespace ukdyn
