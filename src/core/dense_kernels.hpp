// Small dense kernels on raw column-major storage, shared by the U-K solve (uk_solve.cpp) and the
// block-arrow solve (uk_arrow.cpp). Internal to ukdyn::core (not installed).
// N > 0: the size is known at compile time (the loops unroll); N == 0: the runtime size n is used.
// Every routine works for any size; it is tuned for the small blocks of multibody models.
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>

#include "ukdyn/core/types.hpp"

namespace ukdyn::detail {

// Cholesky M = L Lᵀ of one n × n block (lower triangle of M read). Writes L's lower triangle and
// 1/L_ii. Returns false when a pivot is not > 0 (not positive definite, or NaN). pivot_ratio (if
// given) gets min_j L_jj² / max_i M_ii, the singular-mass test's measure (uk_singular.hpp).
template <int N>
bool chol_block(const double* M, Index ldm, double* L, Index ldl, double* inv_diag, Index n_rt,
                double* pivot_ratio = nullptr) {
  const Index n = N > 0 ? Index{N} : n_rt;
  double d_min = std::numeric_limits<double>::infinity(), m_max = 0.0;
  for (Index j = 0; j < n; ++j) {
    double d = M[j + j * ldm];
    m_max = std::max(m_max, d);
    for (Index k = 0; k < j; ++k) d -= L[j + k * ldl] * L[j + k * ldl];
    if (!(d > 0.0)) return false;
    d_min = std::min(d_min, d);
    const double ljj = std::sqrt(d);
    const double inv = 1.0 / ljj;
    L[j + j * ldl] = ljj;
    inv_diag[j] = inv;
    for (Index i = j + 1; i < n; ++i) {
      double s = M[i + j * ldm];
      for (Index k = 0; k < j; ++k) s -= L[i + k * ldl] * L[j + k * ldl];
      L[i + j * ldl] = s * inv;
    }
  }
  if (pivot_ratio != nullptr) *pivot_ratio = d_min / m_max;
  return true;
}

// x ← L^{-1} x (forward substitution), x contiguous, 1/L_ii in inv_diag.
template <int N>
void l_solve(const double* L, Index ldl, const double* inv_diag, double* x, Index n_rt) {
  const Index n = N > 0 ? Index{N} : n_rt;
  for (Index i = 0; i < n; ++i) {
    double s = x[i];
    for (Index k = 0; k < i; ++k) s -= L[i + k * ldl] * x[k];
    x[i] = s * inv_diag[i];
  }
}

// x ← L^{-T} x (back substitution with the columns of L), x contiguous.
template <int N>
void lt_solve(const double* L, Index ldl, const double* inv_diag, double* x, Index n_rt) {
  const Index n = N > 0 ? Index{N} : n_rt;
  for (Index i = n - 1; i >= 0; --i) {
    double s = x[i];
    for (Index k = i + 1; k < n; ++k) s -= L[k + i * ldl] * x[k];
    x[i] = s * inv_diag[i];
  }
}

}  // namespace ukdyn::detail
