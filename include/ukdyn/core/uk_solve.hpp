// The Udwadia–Kalaba solve, paper Eq. (4) [Dong2022], the fundamental equation of [Udwadia1992]
// (references: docs/references.md):
//   Qc = M^{1/2} (A M^{-1/2})^+ (b − A M^{-1} Q),   q̈ = M^{-1}(Q + Qc).
//
// Production form (Cholesky, block-diagonal M = diag(L_k L_kᵀ)):
//   y = L^{-1} Q,  X = L^{-1} Aᵀ,  W = Xᵀ X = A M^{-1} Aᵀ,  r = b − A M^{-1} Q = b − Xᵀ y,
//   λ solves W λ = r (rank-revealing, see below),  Qc = Aᵀ λ,  q̈ = M^{-1}(Q + Qc) = L^{-ᵀ}(y + X λ).
// This is the same force as Eq. (4): with M = L Lᵀ, M^{1/2}(A M^{-1/2})^+ = Aᵀ (A M^{-1} Aᵀ)^+ on
// the range of A M^{-1/2}, and any λ with W λ = r gives the same Aᵀλ (null(W) = null(Aᵀ)).
//
// Rank: W is factored by an LDLᵀ with symmetric (diagonal) pivoting, i.e. a pivoted Cholesky
// ([Higham2002] §10.3, [Golub2013]); the one rank rule of the library (the arrow solve's too) is
// documented with that kernel (src/core/dense_kernels.hpp, pivoted_ldlt). For the exact method a
// pivot D_k is kept when D_k > rel_tol² · max_j D_j (max_j D_j = D_0 = max diag W); the pivots
// approximate σ_k² of A M^{-1/2}, so rel_tol is a relative tolerance on its singular values
// (default 1e-7: pivots under 1e-14 of the largest are round-off of a redundant row). Redundant but
// consistent rows are normal; an inconsistent set shows as a residual ‖A q̈ − b‖ that is not
// round-off, reported in UkResult::consistent.
#pragma once

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <vector>

#include "ukdyn/core/types.hpp"

namespace ukdyn {

/// How λ is found from W λ = r (W = A M^{-1}Aᵀ, docs/singular-positions.md):
///  equilibrated: the pseudo-inverse of Eq. (4) for the rows scaled to unit length in
///    the metric of M^{-1} (Ŵ = D W D, D = diag(W_ii^{-1/2}), λ = D Ŵ⁺ D r). Scaling rows does not
///    change the constraint set, so for a consistent set Qc is the same as exact's; but a row whose
///    gradient shrinks towards a singular position (the N-four-bar's x rows at the flat positions)
///    keeps its full weight in the rank decision instead of being cut off once its norm falls under
///    rank_tol of the others, so q̈ stays continuous through the rank change. Rows shorter than
///    row_floor of the longest (round-off of a vanishing gradient) are dropped.
///  exact (default): the pseudo-inverse with the rank cut-off rank_rel_tol on W itself.
///  regularized: (W + μ I) λ = r, μ = regularization² · max diag W (damped, Tikhonov; continuous,
///    but the force of a direction with σ < √μ is lost). The drift projection uses it.
///  adaptive: exact, unless the smallest kept singular value σ_min of A M^{-1/2} is under
///    adaptive_band · regularization · σ_max; then regularized with μ scaled by a smooth weight of
///    σ_min/σ_max (0 at the band's edge, 1 at σ_min ≤ regularization · σ_max), so q̈ is continuous
///    through a rank change and exact to round-off on well-conditioned constraints.
enum class UkMethod { equilibrated, exact, regularized, adaptive };
inline const char* to_string(UkMethod m) {
  return m == UkMethod::equilibrated ? "equilibrated"
         : m == UkMethod::exact      ? "exact"
         : m == UkMethod::adaptive   ? "adaptive"
                                     : "regularized";
}

struct UkSettings {
  UkMethod method = UkMethod::exact;
  /// regularized: √μ relative to the largest singular value of A M^{-1/2}.
  double regularization = 1e-5;  // measured best on the N-four-bar (docs/singular-positions.md)
  /// adaptive: damping starts when σ_min < adaptive_band · regularization · σ_max.
  double adaptive_band = 100.0;
  /// equilibrated: rows with ‖A_i M^{-1/2}‖ under row_floor · max_j ‖A_j M^{-1/2}‖ are dropped.
  double row_floor = 1e-13;
  /// Relative tolerance on the singular values of A M^{-1/2} below which a direction is dropped
  /// (exact), or not counted in the reported rank (regularized).
  double rank_rel_tol = 1e-7;
  /// ‖A q̈ − b‖ above consistency_rel_tol · (‖b‖ + ‖A‖_∞ ‖q̈‖ + 1) flags the set as inconsistent.
  double consistency_rel_tol = 1e-8;
  /// adaptive: how many rows are redundant around the whole motion (constant redundancy, e.g.
  /// Bricard's mechanism: rank 4 of 5 rows everywhere), as simulate() finds at the start
  /// (detail::structural_redundancy). Up to this many directions dropped by the exact cut-off are a
  /// redundancy, not a singular position: an inconsistency they leave (the drift of an integrator
  /// stage off the manifold) keeps the exact least-squares answer instead of the damped solve.
  int structural_redundancy = 0;
};

struct UkResult {
  int rank = 0;  ///< numerical rank of A M^{-1/2}
  double sigma_min_kept =
      0.0;                 ///< sqrt of the smallest kept pivot (≈ smallest kept singular value)
  double sigma_max = 0.0;  ///< sqrt of the largest pivot (≈ largest singular value)
  double residual = 0.0;   ///< ‖A q̈ − b‖_2
  bool consistent = true;  ///< residual is at round-off level
  bool finite = true;      ///< every output is finite
  /// adaptive: the damping applied (weight · regularization; 0 = the exact solve was used).
  double damping = 0.0;
  /// regularized / adaptive with damping: an estimate of max|q̈ − q̈_exact|, the acceleration the
  /// damping did not apply (its constraint error, which the drift projection removes); 0 otherwise.
  double damped_acceleration = 0.0;
};

/// Block layout of a block-diagonal mass matrix: block k covers rows/cols
/// [start[k], start[k]+size[k]).
struct BlockLayout {
  std::vector<Index> start;
  std::vector<Index> size;
  [[nodiscard]] Index dof() const { return start.empty() ? 0 : start.back() + size.back(); }
  [[nodiscard]] std::size_t blocks() const { return start.size(); }
  /// A single block covering n coordinates.
  static BlockLayout single(Index n) { return BlockLayout{{0}, {n}}; }
};

/// Every buffer the U-K solve writes, allocated once for (layout, m constraint rows). The solve
/// itself is hand-written loops over these buffers (no Eigen GEMM dispatch, no temporaries): for
/// the small dense systems it is built for (blocks of 6, a dozen rows) dispatch and blocking cost
/// more than the arithmetic. Blocks of size 6 use code specialised for that size.
struct UkWorkspace {
  UkWorkspace() = default;
  UkWorkspace(const BlockLayout& layout, Index m);

  BlockLayout layout;
  Mat L;                   ///< n × n: block k's lower Cholesky factor in its diagonal block
  Vec inv_diag;            ///< 1 / L_ii (n)
  Vec Linv_Q;              ///< y = L^{-1} Q (M^{-1} Q when there are no rows)
  Mat A_Linvt;             ///< Xᵀ = A L^{-ᵀ} (m × n), X = L^{-1} Aᵀ
  Mat A_Minv_At;           ///< W = A M^{-1} Aᵀ (m × m, lower), factored in place
  std::vector<Index> piv;  ///< pivot transpositions of the LDLᵀ (m)
  Vec r;                   ///< b − A a
  Vec lambda;              ///< W λ = r (basic solution)
  Vec tmp_m;               ///< scratch (m)
  Vec row_scale;           ///< equilibrated: D_ii = W_ii^{-1/2} (0 for a dropped row)
  /// Set by factor_mass(): the smallest over the blocks of (smallest pivot L_jj²) / (largest
  /// diagonal entry M_ii) of the block (mass_factor_regular() compares it with kSingularPivot).
  double pivot_ratio = 0.0;
};

/// Factors M per block (Cholesky, L_k L_kᵀ) into ws.L. Returns false if a block is not positive
/// definite.
bool factor_mass(const Mat& M, UkWorkspace& ws);

/// U-K solve with M already factored by factor_mass. Writes q̈ and Qc; allocation-free.
/// A (m × n), b (m), Q (n). m may be 0 (unconstrained).
UkResult uk_solve_factored(const Mat& A, const Vec& b, const Vec& Q, UkWorkspace& ws, Vec& qdd,
                           Vec& Qc, const UkSettings& settings = {});

/// factor_mass + uk_solve_factored. If M is not positive definite, result.finite is false.
UkResult uk_solve(const Mat& M, const Mat& A, const Vec& b, const Vec& Q, UkWorkspace& ws, Vec& qdd,
                  Vec& Qc, const UkSettings& settings = {});

/// The textbook form of Eq. (4), literally: M^{1/2} by a symmetric eigen-decomposition, the
/// Moore–Penrose inverse of A M^{-1/2} by a JacobiSVD with the same relative tolerance. Allocates;
/// for tests and benchmarks. sigma_min_kept / sigma_max are exact singular values here.
UkResult uk_solve_textbook(const Mat& M, const Mat& A, const Vec& b, const Vec& Q, Vec& qdd,
                           Vec& Qc, const UkSettings& settings = {});

/// Exact singular values of A M^{-1/2} (descending), for diagnostics. Allocates.
Vec singular_values_A_Minvhalf(const Mat& M, const Mat& A);

/// KKT (Lagrange multiplier) solve:  [M Aᵀ; A 0] [q̈; −λ] = [Q; b], by a full-pivot LU. Requires A
/// of full row rank. Qc = Aᵀλ. Allocates; an independent check of the U-K solve.
void kkt_solve(const Mat& M, const Mat& A, const Vec& b, const Vec& Q, Vec& qdd, Vec& Qc);

}  // namespace ukdyn
