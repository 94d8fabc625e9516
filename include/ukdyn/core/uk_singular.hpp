// The Udwadia–Kalaba solve for a positive semi-definite mass matrix M ([Udwadia2006],
// [Udwadia2010]; docs/free-bodies.md): quaternion coordinates, massless links, bodies without axial
// inertia. The motion is unique when [M; A] has full column rank; then, for any α > 0,
//   M_a = M + Aᵀ α A  is positive definite,  Q_a = Q + Aᵀ α b,
// and q̈ solves the U-K equation with (M_a, Q_a) in place of (M, Q) ([Udwadia2010], the augmented
// form): from M q̈ = Q + Qc and A q̈ = b, M_a q̈ = Q_a + Qc with the same Qc = Aᵀλ. So the
// positive-definite solve (uk_solve_factored) gives q̈ and Qc unchanged.
//
// α is diagonal, α_i = s / ‖A_i‖² with s the largest diagonal entry of the block (or of M), so that
// Aᵀ α A is of the size of M. Rows whose entries all lie in one block (a free body's unit-norm row)
// augment that block only: M_a stays block-diagonal and the block solve is used. When a block is
// still singular after that, every row augments the whole of M (one dense block). When even that
// is singular, [M; A] is rank deficient and the motion is undetermined (result.finite = false;
// undetermined_direction() names the coordinates).
//
// Dispatch (src/model/system.cpp): only when factor_mass() fails or mass_factor_regular() finds
// a pivot under kSingularPivot of its block's largest diagonal entry. Allocation-free.
#pragma once

#include <string>
#include <vector>

#include "ukdyn/core/types.hpp"
#include "ukdyn/core/uk_solve.hpp"

namespace ukdyn {

/// A Cholesky pivot L_jj² under kSingularPivot · max_i M_ii (of its block) counts as singular: the
/// estimate max M_ii / min L_jj² is a lower bound on cond(M_k), so a block above 1e11 goes to the
/// singular solve. docs/free-bodies.md.
inline constexpr double kSingularPivot = 1e-11;
/// simulate() warns (ill_conditioned_mass, once) at a sample where the estimate of cond(M_k) of a
/// block passes this: a configuration approaching a singularity of its coordinates (the gimbal lock
/// of Euler angles), well before the solve gives up at 1 / kSingularPivot.
inline constexpr double kMassConditionWarning = 1e8;

/// The singular solve's buffers, allocated once for (layout, m).
struct UkSingularWorkspace {
  UkSingularWorkspace() = default;
  UkSingularWorkspace(const BlockLayout& layout, Index m);

  Mat Ma;                        ///< n × n: M + Aᵀ α A
  Vec Qa;                        ///< n: Q + Aᵀ α b
  Mat scratch;                   ///< n × n: trial factors
  std::vector<Index> row_block;  ///< m: the block holding all of row i's entries, or −1
  /// Per block: the rows whose structural entries lie in that block alone (a free body's
  /// unit-norm row), known when the system declared its sparsity: augment_singular_blocks().
  std::vector<std::vector<Index>> own_rows;
  /// Per block: M_k is singular at every state (a free body's quaternion block, a massless link),
  /// found by ForwardData at three fixed pseudo-random states; such a block always takes the
  /// singular solve (a round-off pivot of an exactly singular M can pass any pivot threshold).
  std::vector<char> structural;
  bool any_structural = false;
  UkWorkspace dense;            ///< one block of n: the dense fallback
  bool active = false;          ///< the last solve was a singular one
  bool dense_used = false;      ///< ... and needed the dense fallback
  bool rank_deficient = false;  ///< ... and [M; A] was rank deficient
  double cond_estimate = 1.0;   ///< max M_a,ii / min pivot of the last singular solve
  std::size_t cond_block = 0;   ///< ... in this block (0 after the dense fallback)
};

/// True if every block's factor in ws (factor_mass succeeded) has all pivots L_jj² ≥
/// kSingularPivot · max_i M_ii of that block: ws.pivot_ratio, which factor_mass() records, against
/// kSingularPivot (one compare). M is the matrix factor_mass() factored (kept for the interface).
bool mass_factor_regular(const Mat& M, const UkWorkspace& ws);

/// Largest over blocks of max_i M_ii / min_j L_jj² (a lower bound on cond(M_k)) for a factor in ws;
/// `block` gets the worst block.
double mass_condition_estimate(const Mat& M, const UkWorkspace& ws, std::size_t* block = nullptr);

/// The U-K solve for M positive semi-definite (see above). ws: the block workspace (its factor is
/// overwritten with M_a's). Writes q̈ and Qc; allocation-free.
UkResult uk_solve_singular(const Mat& M, const Mat& A, const Vec& b, const Vec& Q, UkWorkspace& ws,
                           UkSingularWorkspace& sw, Vec& qdd, Vec& Qc,
                           const UkSettings& settings = {});

/// The block-arrow solve with structurally singular blocks (a free-body load on N robots,
/// uk_arrow.hpp): each structural block k augmented in place with the rows that lie in it alone
/// (sw.own_rows[k]), M_kk += A_kᵀ α A_k and Q_k += A_kᵀ α b — the augmented form above, which
/// keeps M block-diagonal, so the arrow solve of (M_a, Q_a) gives the q̈ and Qc of (M, Q). The
/// blocks' originals are kept in sw (sw.scratch, sw.Qa) for restore_singular_blocks(). Returns
/// false, M and Q unchanged, if a block has no such row; one that stays singular fails the
/// caller's check of the factor (factor_mass, mass_factor_regular). O(Σ n_k²); allocation-free.
bool augment_singular_blocks(const BlockLayout& layout, const Mat& A, const Vec& b, Mat& M, Vec& Q,
                             UkSingularWorkspace& sw);
/// M_kk + A_kᵀ α A_k and Q_k + A_kᵀ α b on the structural blocks with their own rows, as
/// augment_singular_blocks() forms them (no checks, nothing saved).
void augmented_blocks(const BlockLayout& layout, const Mat& A, const Vec& b,
                      const UkSingularWorkspace& sw, Mat& M, Vec& Q);
/// Puts back the blocks of M and Q that augment_singular_blocks() changed.
void restore_singular_blocks(const BlockLayout& layout, Mat& M, Vec& Q,
                             const UkSingularWorkspace& sw);

/// Empty if [M; A] has full column rank (smallest eigenvalue of M + Aᵀ α A above kSingularPivot of
/// its largest); otherwise a message naming the coordinates of the undetermined direction.
/// Allocates (error path, load-time checks).
std::string undetermined_direction(const Mat& M, const Mat& A,
                                   const std::vector<std::string>& coordinate_names);

}  // namespace ukdyn
