// An unconstrained subsystem in Lagrange form, paper Eq. (10): M(q) q̈ + C(q, q̇) q̇ + G(q) = τ
// (with a mass of t: M(q, t), G(q, t) and the extra (∂M/∂t) q̇ term, see Subsystem::dynamics()).
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

/// What an evaluation of a subsystem is given besides the state (q, q̇): the time and the caller's
/// data slot. forward() passes its time and the subsystem's slot of its ForwardData; a default
/// EvalContext (t = 0, no slot) asks for the values alone (the subsystem then computes what it
/// would have kept in its slot). Every quantity is the same function of (t, q, q̇) whatever the
/// slot: the slot changes the cost, never a value.
struct EvalContext {
  double t = 0.0;  ///< time; matters only for a time_varying() subsystem
  Slot slot{};     ///< this subsystem's data slot (slot_size() doubles), or empty
};

/// A subsystem owns `dof()` consecutive generalized coordinates of the system. Implementations are
/// constant after construction; every method writes into caller-owned storage and allocates
/// nothing. One method per quantity, each given an EvalContext.
///
/// Time-varying subsystems (docs/definitions.md, "Time-varying masses"): a Lagrangian
/// L(q, q̇, t) = T(q, q̇, t) − V(q, t) with T = ½ q̇ᵀ M(q, t) q̇ (a mass or inertia of t). Lagrange's
/// equations d/dt ∂T/∂q̇ − ∂T/∂q + ∂V/∂q = Q give M q̈ + C q̇ + (∂M/∂t) q̇ + G(q, t) = Q: the "C q̇"
/// of coriolis_times_qd() and dynamics() then includes (∂M/∂t) q̇ = ∂²T/∂q̇∂t.
class Subsystem {
 public:
  virtual ~Subsystem() = default;
  [[nodiscard]] virtual Index dof() const = 0;
  [[nodiscard]] virtual const std::string& name() const = 0;
  [[nodiscard]] virtual const std::vector<std::string>& coordinate_names() const = 0;
  /// Doubles of data slot this subsystem uses in forward() (0: none). ForwardData holds one slot of
  /// this size per subsystem, zero-filled when it is built; the model itself stays constant. A
  /// subsystem keeps there its scratch (a tape's work buffer) and what constraints on its
  /// coordinates read back later in the same forward() (ConstraintSlots::subsystem(): the mobile
  /// manipulator's sin/cos).
  [[nodiscard]] virtual Index slot_size() const { return 0; }
  /// True if M, G or V depend on t explicitly (default false: every subsystem but a derived one
  /// with a mass or inertia of t).
  [[nodiscard]] virtual bool time_varying() const { return false; }

  /// Mass matrix M(q, t), paper Eq. (5). Writes a dof × dof block.
  virtual void mass(const EvalContext& c, CVecRef q, MatRef M) const = 0;
  /// Coriolis/centrifugal matrix C(q, q̇, t) with Ṁ − 2C skew-symmetric, paper Eq. (9).
  virtual void coriolis(const EvalContext& c, CVecRef q, CVecRef qd, MatRef C) const = 0;
  /// The vector C(q, q̇) q̇ (cheaper than forming C); with (∂M/∂t) q̇ added when time_varying().
  virtual void coriolis_times_qd(const EvalContext& c, CVecRef q, CVecRef qd, VecRef Cqd) const = 0;
  /// Generalized gravity G(q, t) = ∂V/∂q, paper Eq. (8).
  virtual void gravity(const EvalContext& c, CVecRef q, VecRef G) const = 0;
  /// Potential energy V(q, t) (gravity), up to a constant.
  [[nodiscard]] virtual double potential(const EvalContext& c, CVecRef q) const = 0;
  /// M, C q̇ and G in one call (what forward() needs, paper Eq. (10)), using the slot in `c`; returns
  /// Lt = ∂L/∂t = ∂T/∂t − ∂V/∂t at (q, q̇, t), the power that enters the energy balance
  /// dE/dt = Q_ncᵀq̇ + Q_cᵀq̇ − ∂L/∂t (0 when not time_varying()). The default calls mass(),
  /// coriolis_times_qd() and gravity() and returns 0; a subsystem whose three share work (the same
  /// sin/cos, say) or that is time-varying overrides it. Same values as the three calls.
  virtual double dynamics(const EvalContext& c, CVecRef q, CVecRef qd, MatRef M, VecRef Cqd,
                          VecRef G) const {
    mass(c, q, M);
    coriolis_times_qd(c, q, qd, Cqd);
    gravity(c, q, G);
    return 0.0;
  }

  /// Exact derivatives (docs/derivatives.md): whether inverse_dynamics_tangent() is implemented.
  [[nodiscard]] virtual bool has_derivatives() const { return false; }
  /// The directional derivative of the inverse dynamics ID(q, q̇, q̈) = M(q) q̈ + C(q, q̇) q̇ + G(q)
  /// at fixed q̈ (and t) along (dq, dqd): dID = (∂ID/∂q) dq + (∂ID/∂q̇) dqd, exact (no finite
  /// differences). The slot in `c`, if given, is this subsystem's data slot (scratch). Returns
  /// false when this subsystem has no exact derivatives (the default).
  virtual bool inverse_dynamics_tangent(const EvalContext& c, CVecRef q, CVecRef qd, CVecRef qdd,
                                        CVecRef dq, CVecRef dqd, VecRef dID) const {
    (void)c, (void)q, (void)qd, (void)qdd, (void)dq, (void)dqd, (void)dID;
    return false;
  }
  /// The time tangent of the inverse dynamics at fixed (q, q̇, q̈): dID = ∂ID/∂t = (∂M/∂t) q̈ +
  /// ∂(C q̇)/∂t + ∂G/∂t (C q̇ with its (∂M/∂t) q̇ term), exact; what linearize() needs for ∂q̈/∂t
  /// (docs/derivatives.md, "Time"). The default: 0 for a subsystem that is not time_varying()
  /// (nothing of it depends on t), and false (no exact ∂/∂t) for one that is.
  virtual bool inverse_dynamics_time_tangent(const EvalContext& c, CVecRef q, CVecRef qd,
                                             CVecRef qdd, VecRef dID) const {
    (void)c, (void)q, (void)qd, (void)qdd;
    if (time_varying()) return false;
    dID.setZero();
    return true;
  }
};

}  // namespace ukdyn
