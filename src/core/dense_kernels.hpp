// Small dense kernels on raw column-major storage, shared by the U-K solve (uk_solve.cpp) and the
// block-arrow solve (uk_arrow.cpp). Internal to ukdyn::core (not installed).
// N > 0: the size is known at compile time (the loops unroll); N == 0: the runtime size n is used.
// The triangular loops (bounds that depend on an outer index: k < j, i > j) carry UKDYN_UNROLL:
// with N known g++ unrolls them completely only when told (factor_mass on this shape: 4 143 →
// 2 813 instructions, docs/performance.md, "Unrolled triangular loops"); the operations and their
// order are unchanged.
// Every routine works for any size; it is tuned for the small blocks of multibody models. Every
// routine writes only the caller's storage (no allocation).
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>
#include <type_traits>
#include <utility>

#include "ukdyn/core/types.hpp"

// `UKDYN_UNROLL` for g++ (complete unrolling of the loops above up to 16 iterations);
// nothing for clang, which accepts the pragma but warns (-Wpass-failed) wherever it cannot honour it
// (loops with a runtime length or an early exit).
#if defined(__clang__)
#define UKDYN_UNROLL
#else
#define UKDYN_UNROLL _Pragma("GCC unroll 16")
#endif

namespace ukdyn::detail {

// Calls f(std::integral_constant<int, N>) with N = n for the block sizes of the shipped models
// (6: the paper's arms; 7: a free body in quaternions; 10: a 7-joint arm on an x, y, yaw
// platform), so that the kernels below unroll for them, and N = 0 (runtime size) for any other.
template <typename F>
[[gnu::always_inline]] inline void with_block_size(Index n, F&& f) {
  switch (n) {
    case 6:
      f(std::integral_constant<int, 6>{});
      break;
    case 7:
      f(std::integral_constant<int, 7>{});
      break;
    case 10:
      f(std::integral_constant<int, 10>{});
      break;
    default:
      f(std::integral_constant<int, 0>{});
      break;
  }
}

// Cholesky M = L Lᵀ of one n × n block (lower triangle of M read). Writes L's lower triangle and
// 1/L_ii. Returns false when a pivot is not > 0 (not positive definite, or NaN). pivot_ratio (if
// given) gets min_j L_jj² / max_i M_ii, the singular-mass test's measure (uk_singular.hpp).
template <int N>
bool chol_block(const double* M, Index ldm, double* L, Index ldl, double* inv_diag, Index n_rt,
                double* pivot_ratio = nullptr) {
  const Index n = N > 0 ? Index{N} : n_rt;
  double d_min = std::numeric_limits<double>::infinity(), m_max = 0.0;
  UKDYN_UNROLL
  for (Index j = 0; j < n; ++j) {
    double d = M[j + j * ldm];
    m_max = std::max(m_max, d);
    UKDYN_UNROLL
    for (Index k = 0; k < j; ++k) d -= L[j + k * ldl] * L[j + k * ldl];
    if (!(d > 0.0)) return false;
    d_min = std::min(d_min, d);
    const double ljj = std::sqrt(d);
    const double inv = 1.0 / ljj;
    L[j + j * ldl] = ljj;
    inv_diag[j] = inv;
    Index i = j + 1;
    if constexpr (N > 0) {
      // N fixed: rows i and i + 1 as one 2-vector (adjacent in M's and L's columns), the column's
      // pairs side by side with k outer (L_jk loaded once), each entry the same sum in the same
      // order as one row at a time; an odd last row beside them.
      using Pair = Eigen::Matrix<double, 2, 1>;
      const Index np = (n - j - 1) / 2, it = j + 1 + 2 * np;
      const bool tail = it < n;
      Pair acc[N / 2 > 0 ? N / 2 : 1];
      double st = tail ? M[it + j * ldm] : 0.0;
      UKDYN_UNROLL
      for (Index t = 0; t < np; ++t) acc[t] = Eigen::Map<const Pair>(M + i + 2 * t + j * ldm);
      UKDYN_UNROLL
      for (Index k = 0; k < j; ++k) {
        const double ljk = L[j + k * ldl];
        UKDYN_UNROLL
        for (Index t = 0; t < np; ++t)
          acc[t] -= Eigen::Map<const Pair>(L + i + 2 * t + k * ldl) * ljk;
        if (tail) st -= L[it + k * ldl] * ljk;
      }
      UKDYN_UNROLL
      for (Index t = 0; t < np; ++t) Eigen::Map<Pair>(L + i + 2 * t + j * ldl) = acc[t] * inv;
      if (tail) L[it + j * ldl] = st * inv;
      i = n;
    }
    UKDYN_UNROLL
    for (; i < n; ++i) {
      double s = M[i + j * ldm];
      UKDYN_UNROLL
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
  if constexpr (N > 0) {
    // N fixed: by columns (x_k final, then x_i −= L_ik x_k below it), in a local copy of x; each
    // x_i gets the same subtractions in the same order (k ascending) as the row loop below.
    double v[N];
    UKDYN_UNROLL
    for (Index i = 0; i < N; ++i) v[i] = x[i];
    UKDYN_UNROLL
    for (Index k = 0; k < N; ++k) {
      v[k] = v[k] * inv_diag[k];
      UKDYN_UNROLL
      for (Index i = k + 1; i < N; ++i) v[i] -= L[i + k * ldl] * v[k];
    }
    UKDYN_UNROLL
    for (Index i = 0; i < N; ++i) x[i] = v[i];
    return;
  }
  UKDYN_UNROLL
  for (Index i = 0; i < n; ++i) {
    double s = x[i];
    UKDYN_UNROLL
    for (Index k = 0; k < i; ++k) s -= L[i + k * ldl] * x[k];
    x[i] = s * inv_diag[i];
  }
}

// x ← L^{-T} x (back substitution with the columns of L), x contiguous.
template <int N>
void lt_solve(const double* L, Index ldl, const double* inv_diag, double* x, Index n_rt) {
  const Index n = N > 0 ? Index{N} : n_rt;
  if constexpr (N > 0) {
    // N fixed: the same loop on a local copy of x (held in registers).
    double v[N];
    UKDYN_UNROLL
    for (Index i = 0; i < N; ++i) v[i] = x[i];
    UKDYN_UNROLL
    for (Index i = N - 1; i >= 0; --i) {
      double s = v[i];
      UKDYN_UNROLL
      for (Index k = i + 1; k < N; ++k) s -= L[k + i * ldl] * v[k];
      v[i] = s * inv_diag[i];
    }
    UKDYN_UNROLL
    for (Index i = 0; i < N; ++i) x[i] = v[i];
    return;
  }
  UKDYN_UNROLL
  for (Index i = n - 1; i >= 0; --i) {
    double s = x[i];
    UKDYN_UNROLL
    for (Index k = i + 1; k < n; ++k) s -= L[k + i * ldl] * x[k];
    x[i] = s * inv_diag[i];
  }
}

// ---- The pivoted LDLᵀ and the library's rank rule: every rank decision of the U-K solves (the
// dense W = A M⁻¹Aᵀ of uk_solve.cpp; each robot's S_k and the load's W_D of uk_arrow.cpp) is this
// one kernel with this one rule.
//
// Factorisation: P W Pᵀ = L D Lᵀ of the symmetric positive semidefinite m × m matrix W (lower
// triangle, leading dimension ldw), in place, by symmetric (diagonal) pivoting: step k takes as
// pivot the largest diagonal entry of the remaining Schur complement S_k, D_k = max_i (S_k)_ii, so
// D is non-increasing up to round-off and D_0 = max diag W. This is the outer-product pivoted
// Cholesky of [Higham2002] §10.3 (LINPACK xCHDC; LAPACK xPSTRF, [Lucas2004]) without its square
// roots; the pivots D_k approximate σ_k² of A M^{-1/2} (W = Xᵀ X).
//
// Rank rule. With τ the relative tolerance on singular values (UkSettings::rank_rel_tol), μ ≥ 0 a
// shift already added to W's diagonal (regularized and damped solves, W + μ I) and s the scale of
// the whole problem,
//     s = max(D_0 − μ, s_ref)      (max diag of the unshifted W; s_ref: see RankRule::scale)
//   - the factorisation stops at the first pivot D_k ≤ δ,  δ = max(μ/2, τ² s)  (τ² s dropped for
//     RankRule::drop_by_tolerance = false): Higham's stopping criterion "stop when the largest
//     remaining diagonal max_i (S_k)_ii falls to a tolerance relative to the largest diagonal of
//     the matrix" (xPSTRF: stop when the pivot ≤ TOL), with the relative tolerance τ² on pivots,
//     i.e. τ on singular values. What remains is round-off of redundant rows; they get λ = 0 in the
//     basic solution (ldlt_basic_solve). μ/2 guards a shifted W against round-off: in exact
//     arithmetic every pivot of W + μ I is ≥ μ.
//   - a kept pivot counts in the rank when D_k − μ > τ² s (the unshifted pivot above the same
//     threshold): for μ = 0 the rank is the number kept.
// In the arrow solve the pieces S_k and W_D are Schur complements of the whole W = A M⁻¹Aᵀ (their
// diagonals are ≤ W's), so s_ref = max diag W carries the dense solve's scale s = D_0 = max diag W
// into them: each piece drops what the dense factorisation of W would.
struct RankRule {
  double tol2 = 0.0;   ///< τ²
  double shift = 0.0;  ///< μ, already on W's diagonal
  double scale = 0.0;  ///< s_ref: the whole problem's max diag W (0: W is the whole problem)
  /// false: stop at μ/2 only (the regularized solve drops no direction by τ: all its pivots are
  /// ≥ μ; τ then only sets the reported rank).
  bool drop_by_tolerance = true;
  /// The factorisation keeps at most this many pivots: m − the structural redundancy of the
  /// adaptive solve (UkSettings::structural_redundancy). The pivots of a positive semidefinite W
  /// under diagonal pivoting do not increase, so the ones left are the smallest: the directions of
  /// the rows that are dependent at every configuration, whatever drift has lifted them to.
  Index keep_at_most = std::numeric_limits<Index>::max();
};

struct LdltPivots {
  Index kept = 0;      ///< pivots factored (the leading kept × kept of L and D are valid)
  Index rank = 0;      ///< of those, the ones with D_k − μ > τ² s
  double d_max = 0.0;  ///< max(D_0, 0)
  double d_min_kept = std::numeric_limits<double>::infinity();  ///< smallest D_k − μ counted
};

// P W Pᵀ = L D Lᵀ with the rank rule above. piv (m) gets the transpositions (row k swapped with
// piv[k], k < kept), W the unit lower L below its diagonal and D on it; t is scratch of m.
// Always inlined: the dense solve's compile-time m must reach its loops (docs/performance.md).
[[gnu::always_inline]] inline LdltPivots pivoted_ldlt(double* W, Index ldw, Index m, Index* piv,
                                                      double* t, const RankRule& rule) {
  LdltPivots pv;
  double cutoff = 0.0, count_floor = 0.0;
  UKDYN_UNROLL
  for (Index k = 0; k < m; ++k) {
    Index p = k;
    double dp = W[k + k * ldw];
    UKDYN_UNROLL
    for (Index i = k + 1; i < m; ++i) {
      if (W[i + i * ldw] > dp) {
        dp = W[i + i * ldw];
        p = i;
      }
    }
    if (k == 0) {
      pv.d_max = std::max(dp, 0.0);
      count_floor = rule.tol2 * std::max(pv.d_max - rule.shift, rule.scale);  // τ² s
      cutoff = std::max(0.5 * rule.shift, rule.drop_by_tolerance ? count_floor : 0.0);
    }
    if (!(pv.d_max > 0.0 && dp > cutoff) || k >= rule.keep_at_most) break;
    piv[k] = p;
    if (p != k) {
      // Symmetric swap of rows/columns k and p in lower storage.
      UKDYN_UNROLL
      for (Index j = 0; j < k; ++j) std::swap(W[k + j * ldw], W[p + j * ldw]);
      std::swap(W[k + k * ldw], W[p + p * ldw]);
      UKDYN_UNROLL
      for (Index j = k + 1; j < p; ++j) std::swap(W[j + k * ldw], W[p + j * ldw]);
      UKDYN_UNROLL
      for (Index i = p + 1; i < m; ++i) std::swap(W[i + k * ldw], W[i + p * ldw]);
    }
    const double inv_d = 1.0 / dp;
    double* colk = W + k * ldw;
    {
      // L_ik = W_ik / D_k (the old W_ik kept in t), rows i and i + 1 as one 2-vector.
      using Pair = Eigen::Matrix<double, 2, 1>;
      Index i = k + 1;
      UKDYN_UNROLL
      for (; i + 1 < m; i += 2) {
        const Pair c = Eigen::Map<const Pair>(colk + i);
        Eigen::Map<Pair>(t + i) = c;
        Eigen::Map<Pair>(colk + i) = c * inv_d;
      }
      if (i < m) {
        t[i] = colk[i];
        colk[i] *= inv_d;
      }
    }
    // Schur complement, lower triangle: W_ij −= L_ik D_k L_jk, rows i and i + 1 of a column as one
    // 2-vector (adjacent in W's columns; each entry the same operation).
    UKDYN_UNROLL
    for (Index j = k + 1; j < m; ++j) {
      using Pair = Eigen::Matrix<double, 2, 1>;
      const double tj = t[j];
      double* colj = W + j * ldw;
      Index i = j;
      UKDYN_UNROLL
      for (; i + 1 < m; i += 2) Eigen::Map<Pair>(colj + i) -= Eigen::Map<const Pair>(colk + i) * tj;
      if (i < m) colj[i] -= colk[i] * tj;
    }
    if (dp - rule.shift > count_floor) {
      pv.d_min_kept = std::min(pv.d_min_kept, dp - rule.shift);
      ++pv.rank;
    }
    ++pv.kept;
  }
  return pv;
}

// The basic solution of W λ = r from pivoted_ldlt's factors, in place (lam holds r on entry):
// λ = Pᵀ L^{-ᵀ} D⁺ L^{-1} P r, where only the leading kept × kept part of L and D enters and the
// components past it are 0 (the basic solution of a rank-deficient system, [Golub2013] §5.5).
// Stopping the factorisation early therefore changes nothing in it.
[[gnu::always_inline]] inline void ldlt_basic_solve(const double* W, Index ldw, Index m, Index kept,
                                                    const Index* piv, double* lam) {
  for (Index k = 0; k < kept; ++k) std::swap(lam[k], lam[piv[k]]);
  for (Index i = 0; i < kept; ++i) {
    double s = lam[i];
    for (Index k = 0; k < i; ++k) s -= W[i + k * ldw] * lam[k];
    lam[i] = s;
  }
  for (Index i = 0; i < kept; ++i) lam[i] /= W[i + i * ldw];
  for (Index i = kept; i < m; ++i) lam[i] = 0.0;
  for (Index i = kept - 1; i >= 0; --i) {
    double s = lam[i];
    const double* coli = W + i * ldw;
    for (Index k = i + 1; k < kept; ++k) s -= coli[k] * lam[k];
    lam[i] = s;
  }
  for (Index k = kept - 1; k >= 0; --k) std::swap(lam[k], lam[piv[k]]);
}

}  // namespace ukdyn::detail
