// Constraints in second-order form, paper Eq. (2): A(q, q̇, t) q̈ = b(q, q̇, t) ([Udwadia1996];
// references: docs/references.md).
#pragma once

#include <algorithm>
#include <string>
#include <vector>

#include "ukdyn/model/subsystem.hpp"

namespace ukdyn {

/// What a constraint sees of one ForwardData's data slots (ForwardData::slots): its own slot
/// (scratch, slot_size() doubles) and, read-only, the slots its subsystems filled in
/// dynamics_with() earlier in the same forward(). A default-constructed view has no slots (every
/// lookup is empty).
class ConstraintSlots {
 public:
  ConstraintSlots() = default;
  /// own: this constraint's slot; starts: the subsystems' first coordinates in q (ascending);
  /// subsystem k's slot is base[slot_start[k], slot_start[k + 1]) (slot_start has one more entry).
  ConstraintSlots(Slot own, const double* base, std::span<const Index> starts,
                  std::span<const Index> slot_start)
      : own_(own), base_(base), starts_(starts), slot_start_(slot_start) {}
  /// This constraint's slot (empty if it declared none).
  [[nodiscard]] Slot own() const { return own_; }
  /// The slot of the subsystem whose first coordinate is `first_coordinate` in q (empty if no
  /// subsystem starts there). Its content is whatever that subsystem wrote in dynamics_with(): a
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
  const double* base_ = nullptr;
  std::span<const Index> starts_;
  std::span<const Index> slot_start_;
};

/// A block of constraint rows acting on the whole system's coordinates q (size n).
/// Holonomic rows also give their position residual Φ(q, t) and their velocity residual
/// Φ̇ = A q̇ + ∂Φ/∂t, so that drift can be measured (CSV columns res_<name>) and corrected.
class Constraint {
 public:
  virtual ~Constraint() = default;
  [[nodiscard]] virtual Index rows() const = 0;
  /// One name per row, used for CSV columns and error messages.
  [[nodiscard]] virtual const std::vector<std::string>& row_names() const = 0;
  /// Overwrites its rows() rows of A (rows() × n, every entry) and of b.
  virtual void evaluate(double t, CVecRef q, CVecRef qd, MatRef A, VecRef b) const = 0;
  /// Position-level residual Φ(q, t) (rows()).
  virtual void position_residual(double t, CVecRef q, VecRef phi) const = 0;
  /// Velocity-level residual Φ̇(q, q̇, t) = A q̇ + ∂Φ/∂t (rows()).
  virtual void velocity_residual(double t, CVecRef q, CVecRef qd, VecRef phid) const = 0;

  /// Doubles of data slot this constraint uses (0: none); ForwardData holds one per constraint.
  [[nodiscard]] virtual Index slot_size() const { return 0; }
  /// The three evaluations as forward() and the drift control call them, with the data slots of the
  /// caller's ForwardData. Same values as the versions without; defaults call those.
  virtual void evaluate_with(const ConstraintSlots& slots, double t, CVecRef q, CVecRef qd,
                             MatRef A, VecRef b) const {
    (void)slots;
    evaluate(t, q, qd, A, b);
  }
  virtual void position_residual_with(const ConstraintSlots& slots, double t, CVecRef q,
                                      VecRef phi) const {
    (void)slots;
    position_residual(t, q, phi);
  }
  virtual void velocity_residual_with(const ConstraintSlots& slots, double t, CVecRef q, CVecRef qd,
                                      VecRef phid) const {
    (void)slots;
    velocity_residual(t, q, qd, phid);
  }

  /// Structural sparsity of A: for each row, the columns (coordinates of q, ascending) whose
  /// entries may be non-zero. Empty (the default): not known, every column may be. System uses it
  /// once, when the constraint is added, to find a block-arrow structure (ukdyn/core/uk_arrow.hpp).
  [[nodiscard]] virtual std::vector<std::vector<Index>> row_columns() const { return {}; }
  /// As evaluate_with(), but writes only the entries of A listed by row_columns() (and b); the
  /// other entries of its rows are left untouched (they are 0 when only this constraint writes
  /// them). O(non-zeros) instead of O(rows × n). Default: evaluate_with().
  virtual void evaluate_structural_with(const ConstraintSlots& slots, double t, CVecRef q,
                                        CVecRef qd, MatRef A, VecRef b) const {
    evaluate_with(slots, t, q, qd, A, b);
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
