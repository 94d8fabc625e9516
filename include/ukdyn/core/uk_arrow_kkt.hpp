// The KKT system of a block-arrow constraint structure (ukdyn/core/uk_arrow.hpp) for many
// right-hand sides at once, in O(N) block operations per column: what the exact derivatives
// (ukdyn/model/linearize.hpp) solve for their 2n columns when every row of A is independent.
//
//   [ M   −Aᵀ ] [ X ]   [ F ]         M block-diagonal, positive definite per block;
//   [ A    0  ] [ Y ] = [ G ],        A with full row rank, grouped as in ArrowStructure.
//
// With robot k's rows [B_k | C_k] (its columns, the load's) and the load's own rows D0, eliminating
// each robot's X_k = M_k⁻¹(F_k + B_kᵀ Y_k) and Y_k = S_k⁻¹(R_k − C_k X_L), S_k = B_k M_k⁻¹ B_kᵀ,
// R_k = G_k − B_k M_k⁻¹ F_k, leaves the load's KKT system
//   H X_L − D0ᵀ Y_0 = F_L + Σ C_kᵀ S_k⁻¹ R_k,   D0 X_L = G_0,   H = M_L + Σ C_kᵀ S_k⁻¹ C_k,
// solved with V = D0 H⁻¹ D0ᵀ: the Schur complement elimination of uk_solve_arrow ([Baraff1996];
// Featherstone, Rigid Body Dynamics Algorithms, 2008, ch. 7; references: docs/references.md)
// with every right-hand side a column of one matrix (Eigen's blocked triangular solves and
// products on the robots' small blocks).
//
// arrow_kkt_factor() also gives tr W and tr W⁻¹ of W = A M⁻¹ Aᵀ from the same pieces (robot row j
// of group k: (W⁻¹)_jj = (S_k⁻¹)_jj − v_jᵀ P v_j with v_j = C_kᵀ S_k⁻¹ e_j and
// P = H⁻¹ − H⁻¹ D0ᵀ V⁻¹ D0 H⁻¹; a load row: (V⁻¹)_jj): the bound σ_min/σ_max(A M^{-1/2}) ≥
// 1/√(tr W · tr W⁻¹) (Golub & Van Loan, Matrix Computations, 4th ed., §2.3.2) that the dense row
// choice of linearize() computes from its QR factor as 1/(‖R⁻¹‖_F ‖R‖_F) — the same number.
#pragma once

#include <Eigen/Cholesky>
#include <vector>

#include "ukdyn/core/types.hpp"
#include "ukdyn/core/uk_arrow.hpp"
#include "ukdyn/core/uk_solve.hpp"

namespace ukdyn {

/// Every buffer of the arrow KKT solve for one structure, for up to `columns` right-hand sides
/// (more columns resize them once).
class ArrowKktWorkspace {
 public:
  ArrowKktWorkspace() = default;
  ArrowKktWorkspace(const ArrowStructure& structure, const BlockLayout& layout, Index columns);

  struct GroupBuffers {
    Mat B, C;                 ///< m_k × n_k, m_k × n_L: the group's rows of A
    Mat Xt;                   ///< m_k × n_k: B_k L_k^{-ᵀ}
    Mat Sm;                   ///< m_k × m_k: S_k = Xt Xtᵀ
    Eigen::LLT<Mat> S;        ///< S_k = L_S L_Sᵀ
    Mat T;                    ///< m_k × n_L: L_S⁻¹ C_k
    Mat P;                    ///< m_k × n_L: L_S^{-ᵀ} T_k (Y_k's response to X_L)
    Mat Q;                    ///< n_k × n_L: L_k^{-ᵀ} Xtᵀ P (X_k's response to X_L)
    Mat Z, Rc, R;             ///< n_k, m_k, m_k × columns: the group's columns in the solve
    Mat U;                    ///< n_L × m_k: L_H⁻¹ C_kᵀ S_k⁻¹ (for tr W⁻¹)
    std::vector<Index> cols;  ///< the columns where F_k or G_k is not zero (capacity: columns)
  };
  std::vector<GroupBuffers> g;
  Mat D0;                   ///< m0 × n_L: the load's own rows
  Mat LL;                   ///< n_L × n_L: the load's factor L_L (M_L = L_L L_Lᵀ)
  Mat H;                    ///< n_L × n_L: M_L + Σ C_kᵀ S_k⁻¹ C_k
  Eigen::LLT<Mat> LH;       ///< H = L_H L_Hᵀ
  Mat E;                    ///< n_L × m0: L_H⁻¹ D0ᵀ
  Mat Vm;                   ///< m0 × m0: V = Eᵀ E = D0 H⁻¹ D0ᵀ
  Eigen::LLT<Mat> V;        ///< V = L_V L_Vᵀ
  Mat VE, Vinv;             ///< m0 × m_k scratch, m0 × m0
  Mat gL, Y0;               ///< n_L × columns, m0 × columns
  std::vector<char> other;  ///< per layout block: 1 when neither a robot of a group nor the load
  double trace_w = 0.0, trace_w_inv = 0.0;  ///< tr W and tr W⁻¹, W = A M⁻¹ Aᵀ
  [[nodiscard]] bool built() const { return built_; }

 private:
  bool built_ = false;
};

/// Factors the arrow KKT matrix of (M, A): M's blocks already factored into `mass` (factor_mass:
/// their Cholesky factors are reused, not recomputed), A's group, load and coupling blocks into
/// `ws`, with tr W and tr W⁻¹. Returns false when a piece is not positive definite enough to
/// eliminate: an S_k or V pivot at or under rank_rel_tol² · max diag W (the rank rule of the
/// forward solves: the row would have been dropped), or H not positive definite. Allocation-free.
bool arrow_kkt_factor(const ArrowStructure& structure, const Mat& A, const UkWorkspace& mass,
                      double rank_rel_tol, ArrowKktWorkspace& ws);

/// Which columns robot k's own eliminations run on.
enum class ArrowColumns {
  scan,        ///< those where its rows of F or G are not zero (read from F and G)
  structural,  ///< F's columns are directions of the n coordinates, in sets of n (q, then q̇):
               ///< in each set the robot's own and the load's — the only ones where the
               ///< derivatives' F_k, G_k can be non-zero (its rows touch no other coordinates),
               ///< known without reading F and G. The caller vouches that F_k, G_k are zero
               ///< elsewhere, and that a block without rows has F_b zero outside its own columns.
};

/// X (n × p) and Y (m × p, rows in A's order) of the KKT system above for the p columns of F
/// (n × p) and G (m × p), with the factors of arrow_kkt_factor(). Robot k's own eliminations run
/// on its columns (`columns`); every column gets X_k = (own part) − Q_k X_L and Y_k = (own part) −
/// P_k X_L, one product each. Y with no rows: the robots' multipliers are not formed (X alone).
/// Allocation-free while p is within the workspace's columns.
void arrow_kkt_solve(const ArrowStructure& structure, const UkWorkspace& mass,
                     ArrowKktWorkspace& ws, const Eigen::Ref<const Mat>& F,
                     const Eigen::Ref<const Mat>& G, Eigen::Ref<Mat> X, Eigen::Ref<Mat> Y,
                     ArrowColumns columns = ArrowColumns::scan);

/// The X of arrow_kkt_solve() in O(N) storage, for columns that are directions of the coordinates
/// (ArrowColumns::structural): X = (own parts) + (coupling through the load), row block by row
/// block —
///   the load's rows:      X_L (n_L × p, every column);
///   robot k's rows:       X_k = Own_k E_kᵀ − Q_k X_L, Own_k on its columns cols_k (its own and
///                         the load's directions), E_k the selection of those columns;
///   a block without rows: Own_b E_bᵀ (its own directions; Q_b empty).
/// Dense, X is n × p with N² blocks; here it is the n_L × p X_L plus N small blocks.
struct ArrowResponse {
  struct Block {
    Index start = 0, size = 0;
    std::vector<Index> cols;  ///< the columns of Own, ascending
    Mat own;                  ///< size × cols.size()
    Mat Q;                    ///< size × n_L: the response to the load's X_L (no rows: none)
  };
  Index rows = 0, cols = 0;  ///< n, p
  Index load_start = 0, load_size = 0;
  Mat XL;  ///< n_L × p
  std::vector<Block> blocks;
};

/// arrow_kkt_solve(..., ArrowColumns::structural) into `out` without forming the dense X: the
/// robots' own eliminations and the load's solve, O(N) for the derivatives' 2n columns.
/// Allocation-free after the first call for a structure.
void arrow_kkt_solve_response(const ArrowStructure& structure, const UkWorkspace& mass,
                              ArrowKktWorkspace& ws, const Eigen::Ref<const Mat>& F,
                              const Eigen::Ref<const Mat>& G, ArrowResponse& out);

/// The dense X (rows × cols) of a response.
void arrow_response_expand(const ArrowResponse& r, Eigen::Ref<Mat> X);

/// out = X V for V (cols × k) without the dense X: X_L V once, then per block Own (rows of V at its
/// columns) − Q (X_L V). `scratch` takes X_L V (resized to n_L × k).
void arrow_response_multiply(const ArrowResponse& r, const Eigen::Ref<const Mat>& V,
                             Eigen::Ref<Mat> out, Mat& scratch);

/// out += Aᵀ Y for the arrow-structured A (its group and load blocks in ws; Y m × p, out n × p):
/// the constraint force's columns without a dense product.
void arrow_add_at_times(const ArrowStructure& structure, const ArrowKktWorkspace& ws,
                        const Eigen::Ref<const Mat>& Y, Eigen::Ref<Mat> out);

}  // namespace ukdyn
