// Constraints in second-order form, paper Eq. (2): A(q, q̇, t) q̈ = b(q, q̇, t).
#pragma once

#include <string>
#include <vector>

#include "ukdyn/model/subsystem.hpp"

namespace ukdyn {

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
};

/// Sets every entry of a block of constraint rows to 0 (for evaluate(), before writing the
/// nonzeros). A plain column loop: Eigen's setZero() on a strided block of a few rows runs its
/// vectorisation prologue once per column, which cost more than the zeros themselves here.
inline void zero_rows(MatRef A) {
  const Index rows = A.rows(), cols = A.cols(), ld = A.outerStride();
  double* d = A.data();
  for (Index j = 0; j < cols; ++j)
    for (Index i = 0; i < rows; ++i) d[i + j * ld] = 0.0;
}

}  // namespace ukdyn
