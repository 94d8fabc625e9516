// An unconstrained subsystem in Lagrange form, paper Eq. (10): M(q) q̈ + C(q, q̇) q̇ + G(q) = τ.
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
};

}  // namespace ukdyn
