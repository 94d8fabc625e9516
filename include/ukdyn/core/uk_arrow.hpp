// The U-K solve in O(N) for a block-arrow constraint structure: N "robot" subsystems, each coupled
// by its own constraint rows to one shared "load" subsystem (cooperative transport, [Walker1991],
// [Erhart2015]; references: docs/references.md).
//
// With the rows grouped per robot k, A = [blockdiag(B_k) | C; 0 | D0] (B_k: robot k's columns,
// C_k: the load's, D0: rows on the load alone), the KKT system [M Aᵀ; A 0] ordered robot blocks
// first is block-arrow. Eliminating each robot's coordinates and multipliers first (the Schur
// complement onto the load, as in the linear-time constrained dynamics of [Baraff1996] and the
// articulated-body inertia of [Featherstone2008] ch. 7):
//   a_k = M_k⁻¹ Q_k,  S_k = B_k M_k⁻¹ B_kᵀ,  r_k = b_k − B_k a_k,
//   λ_k = S_k⁻¹ (r_k − C_k q̈_L),                                   (robot k's rows)
//   H = M_L + Σ C_kᵀ S_k⁻¹ C_k,   g = Q_L + Σ C_kᵀ S_k⁻¹ r_k,       (the load's Schur complement)
//   q̈_L = H⁻¹ (g + Dᵀ μ),  D H⁻¹ Dᵀ μ = d − D H⁻¹ g                 (a small U-K on the load)
// and then Qc = Aᵀλ, q̈ = M⁻¹(Q + Qc) per block. The cost is O(N) small dense pieces (one per robot)
// plus one problem of the load's size: O(N) per evaluation.
//
// Rank decisions (redundant rows), both by the dense solve's pivoted LDLᵀ and rank rule (one
// kernel, src/core/dense_kernels.hpp) with the relative tolerance settings.rank_rel_tol on singular
// values: pivots ≤ tol² · max diag W are dropped, W = A M⁻¹Aᵀ, whose diagonal S_ii + C_i M_L⁻¹ C_iᵀ
// is the dense solve's scale, passed to the kernel as its reference scale (formed only when a
// decision depends on it: between bounds otherwise, uk_arrow.cpp's RankScale):
//  - per robot on S_k: a kept set of r_k rows; every dropped row i gives the combination
//    e_i = row_i − L21 L11⁻¹ (kept rows), which has no robot part (e_i B_k = 0 up to round-off) and
//    is therefore a constraint on the load alone: e_i C_k q̈_L = e_i b_k. It joins D (so a robot at
//    a singular configuration, or a robot with fewer joints than grasp rows, is handled exactly);
//  - on the load's D H⁻¹ Dᵀ (rows D0 and every e_i): dropped directions get μ = 0 (basic solution),
//    exactly as the dense solve does for W.
// Redundancy *between* robots (more grasp rows than the load has coordinates, the usual case of a
// load held by N grasps) needs no rank decision at all: H is positive definite whenever M_L is, and
// the internal forces are the particular split λ_k above (Qc and q̈ are unique; λ is not).
// The rank reported is Σ r_k + rank(D H⁻¹ Dᵀ) = rank(A) (the kept rows of the B_k sit in disjoint
// columns); sigma_max / sigma_min_kept are the square roots of the largest and smallest kept pivots
// over those pieces (pivots of Schur complements, not singular values of A M^{-1/2}).
//
// The cost is O(N) while the number of rows on the load alone (D0 plus the dropped robot rows)
// stays bounded; their own U-K is dense in that number.
#pragma once

#include <optional>
#include <vector>

#include "ukdyn/core/types.hpp"
#include "ukdyn/core/uk_solve.hpp"

namespace ukdyn {

/// The arrow structure of a constraint matrix over a block layout, found once from its structural
/// sparsity (detect_arrow).
struct ArrowStructure {
  struct Group {
    Index block = 0;  ///< the robot's block in the layout
    Index start = 0, size = 0;
    std::vector<Index> rows;  ///< the rows of A that touch this robot (and possibly the load)
  };
  Index load_block = -1;  ///< the load's block (-1: no load, the groups are independent)
  Index load_start = 0, load_size = 0;
  std::vector<Group> groups;
  std::vector<Index> load_rows;  ///< rows that touch only the load
};

/// From the blocks each row of A touches (row_blocks[i], ascending, non-empty), the arrow
/// structure, or nothing when the rows do not have one: some row touches three blocks or more, or
/// two rows couple pairs of blocks with no block in common. Blocks coupled to the load by rows form
/// the groups; a row touching one robot alone belongs to that robot's group. With a single coupled
/// pair, the later block is the load. Returns nothing also when fewer than `min_groups` robots are
/// coupled to the load (then the dense solve is as fast).
std::optional<ArrowStructure> detect_arrow(const BlockLayout& layout,
                                           const std::vector<std::vector<Index>>& row_blocks,
                                           std::size_t min_groups = 2);

/// Every buffer of the arrow solve, allocated once for a structure.
class ArrowWorkspace {
 public:
  ArrowWorkspace() = default;
  ArrowWorkspace(const ArrowStructure& structure, Index m);

  struct GroupBuffers {
    Mat B, C;  ///< m_k × n_k, m_k × n_L: the group's rows of A (pivoted in place)
    Mat Xt;    ///< m_k × n_k: B_k L_k^{-ᵀ}
    Mat S;     ///< m_k × m_k: S_k, factored in place (pivoted LDLᵀ, lower)
    Mat T;     ///< m_k × n_L: D^{-1/2} L11⁻¹ C1 (kept rows), then e_i C_k (dropped rows)
    Vec r, bb, z, w, lam;  ///< m_k each
    std::vector<Index> piv;
    Index kept = 0;
  };
  std::vector<GroupBuffers> g;
  Mat H;     ///< n_L × n_L: the load's Schur complement, factored in place (Cholesky)
  Vec gL;    ///< n_L
  Vec qddL;  ///< n_L
  Mat Dt;    ///< (m0 + Σ m_k) × n_L: the load's own rows, then L_H⁻¹-solved
  Vec d;     ///< their right-hand sides
  Mat WD;    ///< their D H⁻¹ Dᵀ, factored in place
  Vec rD, lamD, tmp;
  std::vector<Index> pivD;
  /// Where row i of Dt comes from: (group, pivoted row) or (−1, index into load_rows).
  std::vector<std::pair<Index, Index>> d_from;
  Vec lambda;  ///< m: the multipliers of every row of A (one particular split, see the header)
  [[nodiscard]] bool built() const { return built_; }

 private:
  bool built_ = false;
};

/// The U-K solve by the arrow elimination above, for UkMethod::exact. M must already be factored
/// into dense_ws by factor_mass (its block factors are read; M itself for the load's block). Writes
/// q̈, Qc, ws.lambda and the diagnostics into res, allocation-free. Returns false (nothing written)
/// when it cannot vouch for the result: the load's Schur complement H is not positive definite —
/// the caller then uses the dense solve.
bool uk_solve_arrow(const ArrowStructure& structure, const Mat& M, const Mat& A, const Vec& b,
                    const Vec& Q, const UkWorkspace& dense_ws, ArrowWorkspace& ws, Vec& qdd,
                    Vec& Qc, const UkSettings& settings, UkResult& res);

}  // namespace ukdyn
