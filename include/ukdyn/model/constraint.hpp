// Constraints in second-order form, paper Eq. (2): A(q, q̇, t) q̈ = b(q, q̇, t) ([Udwadia1996];
// references: docs/references.md).
#pragma once

#include <algorithm>
#include <string>
#include <vector>

#include "ukdyn/model/subsystem.hpp"

namespace ukdyn {

/// What a constraint sees of one ForwardData's data slots (ForwardData::slots): its own slot
/// (scratch, slot_size() doubles), the scratch every constraint of the data shares (at least
/// shared_slot_size() doubles) and, read-only, the slots its subsystems filled in dynamics()
/// earlier in the same forward(). A default-constructed view has no slots (every lookup is empty).
class ConstraintSlots {
 public:
  ConstraintSlots() = default;
  /// own: this constraint's slot; starts: the subsystems' first coordinates in q (ascending);
  /// subsystem k's slot is base[slot_start[k], slot_start[k + 1]) (slot_start has one more entry);
  /// shared: the scratch shared by every constraint.
  ConstraintSlots(Slot own, const double* base, std::span<const Index> starts,
                  std::span<const Index> slot_start, Slot shared = {})
      : own_(own), shared_(shared), base_(base), starts_(starts), slot_start_(slot_start) {}
  /// This constraint's slot (empty if it declared none).
  [[nodiscard]] Slot own() const { return own_; }
  /// The scratch every constraint of the data shares (the largest shared_slot_size(); empty
  /// without slots): its content is dead outside one call of one constraint, which may leave
  /// anything there.
  [[nodiscard]] Slot shared() const { return shared_; }
  /// The slot of the subsystem whose first coordinate is `first_coordinate` in q (empty if no
  /// subsystem starts there). Its content is whatever that subsystem wrote in dynamics(): a
  /// reader must check that it belongs to the state it evaluates (MobileManipulator keeps the
  /// angles it was computed for next to the values).
  [[nodiscard]] ConstSlot subsystem(Index first_coordinate) const {
    std::size_t lo = 0, hi = starts_.size();
    while (lo < hi) {  // binary search over the ascending starts
      const std::size_t mid = (lo + hi) / 2;
      if (starts_[mid] < first_coordinate)
        lo = mid + 1;
      else
        hi = mid;
    }
    if (lo >= starts_.size() || starts_[lo] != first_coordinate) return {};
    const Index b = slot_start_[lo], e = slot_start_[lo + 1];
    return {base_ + b, static_cast<std::size_t>(e - b)};
  }

 private:
  Slot own_;
  Slot shared_;
  const double* base_ = nullptr;
  std::span<const Index> starts_;
  std::span<const Index> slot_start_;
};

/// What an evaluation of a constraint is given besides the state (q, q̇), and what is wanted:
/// the time, the caller's data slots (its own and, read-only, its subsystems'), and whether only
/// the structural entries of A are wanted. forward() and the drift control pass their ForwardData's
/// slots; a default ConstraintContext (t = 0, no slots, every entry) asks for the values alone.
struct ConstraintContext {
  double t = 0.0;
  ConstraintSlots slots{};
  /// evaluate() (tangent_columns(): d_residual's columns): write only A's entries of row_columns()
  /// (and b); the other entries of its rows may be left untouched (0 when only it writes them):
  /// O(non-zeros), not O(rows × n). A constraint may ignore it and write every entry.
  bool structural_only = false;
};

/// A block of constraint rows acting on the whole system's coordinates q (size n).
/// Holonomic rows also give their position residual Φ(q, t) and their velocity residual
/// Φ̇ = A q̇ + ∂Φ/∂t, so that drift can be measured (CSV columns res_<name>) and corrected.
/// One method per quantity, each given a ConstraintContext. With no slots in the context, the
/// constraint computes what it would have read from a slot (the values are the same).
class Constraint {
 public:
  virtual ~Constraint() = default;
  [[nodiscard]] virtual Index rows() const = 0;
  /// One name per row, used for CSV columns and error messages.
  [[nodiscard]] virtual const std::vector<std::string>& row_names() const = 0;
  /// Doubles of data slot this constraint uses (0: none); ForwardData holds one per constraint.
  [[nodiscard]] virtual Index slot_size() const { return 0; }
  /// Doubles of scratch it needs within one call and never after (0: none): ForwardData holds one
  /// area of the largest of these, shared by every constraint (ConstraintSlots::shared()), so a
  /// pass over many constraints reuses the same memory instead of one copy per constraint.
  [[nodiscard]] virtual Index shared_slot_size() const { return 0; }
  /// Structural sparsity of A: for each row, the columns (coordinates of q, ascending) whose
  /// entries may be non-zero. Empty (the default): not known, every column may be. System uses it
  /// once, when the constraint is added, to find a block-arrow structure (ukdyn/core/uk_arrow.hpp).
  [[nodiscard]] virtual std::vector<std::vector<Index>> row_columns() const { return {}; }

  /// Its rows() rows of A (rows() × n; every entry, or the structural ones when
  /// c.structural_only) and of b, paper Eq. (2).
  virtual void evaluate(const ConstraintContext& c, CVecRef q, CVecRef qd, MatRef A,
                        VecRef b) const = 0;
  /// Position-level residual Φ(q, t) (rows()).
  virtual void position_residual(const ConstraintContext& c, CVecRef q, VecRef phi) const = 0;
  /// Velocity-level residual Φ̇(q, q̇, t) = A q̇ + ∂Φ/∂t (rows()).
  virtual void velocity_residual(const ConstraintContext& c, CVecRef q, CVecRef qd,
                                 VecRef phid) const = 0;
  /// Φ and Φ̇ in one call (what a run records at each sample). The default calls
  /// position_residual() and velocity_residual(); a constraint whose two share work (the numeric
  /// frame rows: one pass over the trees for both) overrides it. Same values as the two calls.
  virtual void residuals(const ConstraintContext& c, CVecRef q, CVecRef qd, VecRef phi,
                         VecRef phid) const {
    position_residual(c, q, phi);
    velocity_residual(c, q, qd, phid);
  }

  /// Exact derivatives (docs/derivatives.md): whether tangent() is implemented.
  [[nodiscard]] virtual bool has_derivatives() const { return false; }
  /// Directional derivatives along (dq, dqd) (n each) at fixed q̈ (n) and multipliers λ (rows()):
  /// d_residual = d(A q̈ − b) (rows()) and d_force = d(Aᵀ λ) (n), exact. Returns false when this
  /// constraint has no exact derivatives (the default).
  virtual bool tangent(const ConstraintContext& c, CVecRef q, CVecRef qd, CVecRef qdd,
                       CVecRef lambda, CVecRef dq, CVecRef dqd, VecRef d_residual,
                       VecRef d_force) const {
    (void)c, (void)q, (void)qd, (void)qdd, (void)lambda, (void)dq, (void)dqd, (void)d_residual,
        (void)d_force;
    return false;
  }
  /// The time tangents at fixed (q, q̇), q̈ and λ: d_residual = ∂(A q̈ − b)/∂t (rows()), written,
  /// and ∂(Aᵀλ)/∂t (n) added to d_force, exact: what linearize() needs for ∂q̈/∂t
  /// (docs/derivatives.md, "Time"). A constraint whose A and b do not depend on t writes 0 and
  /// adds nothing. Returns false when this constraint has no exact ∂/∂t (the default: a
  /// constraint may read t through its context, so no default can vouch for 0).
  virtual bool time_tangent(const ConstraintContext& c, CVecRef q, CVecRef qd, CVecRef qdd,
                            CVecRef lambda, VecRef d_residual, VecRef d_force) const {
    (void)c, (void)q, (void)qd, (void)qdd, (void)lambda, (void)d_residual, (void)d_force;
    return false;
  }
};

/// Sets every entry of a block of constraint rows to 0 (for evaluate(), before writing the
/// nonzeros). When the rows are all of A (one constraint) the block is contiguous: one fill.
/// Otherwise a plain column loop: Eigen's setZero() on a strided block of a few rows runs its
/// vectorisation prologue once per column, which cost more than the zeros themselves here (and
/// the compiler turns each column into a memset call: one call in place of `cols` saves ≈ 110
/// instructions per forward/closure call, docs/performance.md).
inline void zero_rows(MatRef A) {
  const Index rows = A.rows(), cols = A.cols(), ld = A.outerStride();
  double* d = A.data();
  if (rows == ld) {
    std::fill_n(d, rows * cols, 0.0);
    return;
  }
  for (Index j = 0; j < cols; ++j)
    for (Index i = 0; i < rows; ++i) d[i + j * ld] = 0.0;
}

}  // namespace ukdyn
