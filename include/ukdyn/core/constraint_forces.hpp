// The force of each constraint block, and the internal (squeeze) wrench on a grasped load
// (docs/frame-constraints.md).
//
// Split: Qc = Aᵀλ = Σ_k A_kᵀλ_k. When A has full row rank λ is unique and so is every block's force
// A_kᵀλ_k. When rows are redundant (rank A < m) only the total Qc is determined; the split reported
// is the documented choice λ = (Aᵀ)⁺ Qc, the multipliers of least Euclidean norm (a complete
// orthogonal decomposition of Aᵀ), and `unique` is false.
//
// Internal wrench: w (6N) stacks the wrenches [f_k; m_k] that N grasps apply to a load at the
// grasp points p_k (world axes, moments about p_k). The grasp matrix G (6 × 6N) gives the net
// wrench about the reference point r: [Σ f_k; Σ m_k + (p_k − r) × f_k]. Any right inverse G# of G
// splits w = G# G w + (I − G# G) w into a manipulating and an internal part:
//   walker:   G# = G⁺ = Gᵀ(G Gᵀ)⁻¹, the null-space decomposition of [Walker1991];
//   weighted: G* = Λ Gᵀ (G Λ Gᵀ)⁻¹ with Λ the agents' inertia at the grasps, [Verginis2019]
//             (their Theorem on internal-force-free distributions): zero for motion that does not
//             squeeze, e.g. agents driven by forces proportional to their inertia.
// Both internal parts lie in null(G): G w_int = 0.
#pragma once

#include <Eigen/Cholesky>
#include <Eigen/QR>
#include <Eigen/SVD>
#include <vector>

#include "ukdyn/core/types.hpp"

namespace ukdyn {

struct ConstraintForceSplit {
  Vec lambda;                     ///< λ with Aᵀλ = Qc (least norm when not unique)
  std::vector<Vec> block_force;   ///< A_kᵀλ_k per block (n each)
  std::vector<Vec> block_lambda;  ///< λ_k per block
  int rank = 0;                   ///< numerical rank of A
  bool unique = true;             ///< rank == rows: the split is the only one
  double residual = 0.0;          ///< ‖Aᵀλ − Qc‖
};

/// `row_offsets[k]`: first row of block k (ascending; block k ends where k+1 starts, the last at
/// A.rows()). `rel_tol`: singular values of A under rel_tol · σ_max count as zero. Allocates.
ConstraintForceSplit split_constraint_force(const Mat& A, const Vec& Qc,
                                            const std::vector<Index>& row_offsets,
                                            double rel_tol = 1e-10);

/// The buffers of split_constraint_force() for A: m × n with blocks starting at `row_offsets`,
/// allocated once.
struct ConstraintForceWorkspace {
  ConstraintForceWorkspace(Index m, Index n, std::vector<Index> row_offsets);
  std::vector<Index> row_offsets;
  Mat At;  ///< n × m: Aᵀ
  Eigen::CompleteOrthogonalDecomposition<Mat> cod;
  Vec r, c, y, z_temp;  ///< Aᵀλ − Qc; the solve's buffers
  Eigen::Matrix<double, 1, Eigen::Dynamic, Eigen::RowMajor> hh;
  ConstraintForceSplit result;  ///< λ, λ_k and A_kᵀλ_k sized once
};

/// split_constraint_force() into ws.result: the same numbers, and no heap allocation once ws
/// exists (tests/test_no_alloc.cpp).
void split_constraint_force(const Mat& A, const Vec& Qc, ConstraintForceWorkspace& ws,
                            double rel_tol = 1e-10);

/// G (6 × 6N) for grasp points p_k and reference point r.
Mat grasp_matrix(const std::vector<Vec3>& points, const Vec3& reference);

/// (I − G⁺G) w, [Walker1991].
Vec internal_wrench_walker(const Mat& G, const Vec& w);

/// The derivative of internal_wrench_walker(grasp_matrix(points, points.front()), w) along n
/// directions s: dpoints (3N × n) holds dp_k/ds in rows 3k..3k+2, dw (6N × n) dw/ds; returns
/// d(I − G⁺G)w/ds (6N × n). G has full row rank (its first block is the identity), so G⁺ =
/// Gᵀ(G Gᵀ)⁻¹ has the derivative of a pseudo-inverse of constant rank [GolubPereyra1973].
Mat internal_wrench_walker_derivative(const std::vector<Vec3>& points, const Vec& w,
                                      const Mat& dpoints, const Mat& dw);

/// (I − G*G) w, G* = Λ Gᵀ (G Λ Gᵀ)⁺, [Verginis2019]. Λ: 6N × 6N, symmetric positive semidefinite
/// with G Λ Gᵀ invertible.
Vec internal_wrench_weighted(const Mat& G, const Mat& Lambda, const Vec& w);

/// G for grasp points p_k and reference r into G (6 × 6N, sized by the caller): no allocation.
void grasp_matrix(const std::vector<Vec3>& points, const Vec3& reference, Mat& G);

/// The buffers of internal_wrenches() for N grasps and agents of n_a coordinates, allocated once.
/// The caller fills points, w, J and M; internal_wrenches() fills walker and weighted.
struct InternalWrenchWorkspace {
  InternalWrenchWorkspace(Index grasps, Index agent_dof);
  std::vector<Vec3> points;  ///< N grasp points (world)
  Vec w;                     ///< 6N: [f_k; m_k] on the load, moments about p_k (world axes)
  Mat J;                     ///< 6N × n_a: the agents' twist Jacobians at the grasps
  Mat M;                     ///< n_a × n_a: the agents' mass matrix
  Vec walker, weighted;      ///< 6N: (I − G⁺G) w and (I − G*G) w
  bool weighted_ok = false;  ///< M was positive definite (else `weighted` is NaN)
  // the buffers
  Mat G, MinvJt, K, Lambda, LGt, tmpN, S, S6;
  Eigen::LLT<Mat> llt;
  Eigen::LLT<Mat> llt_big;
  Eigen::JacobiSVD<Mat> svd_big;
  Vec inv_big, Gw, y6;
};

/// internal_wrench_walker() and internal_wrench_weighted() with Λ = task_space_inertia(M, J), the
/// same formulas (G⁺ = Gᵀ(G Gᵀ)⁺; the pseudo-inverses of the symmetric positive semidefinite
/// G Gᵀ, J M⁻¹ Jᵀ and G Λ Gᵀ by Cholesky when well conditioned, where they equal the inverse,
/// else by SVD with the same cut-off), into ws's
/// buffers: no heap allocation once ws exists (tests/test_no_alloc.cpp). The reference point is
/// the first grasp point (both internal parts do not depend on it: null(G) does not, nor G*G).
void internal_wrenches(InternalWrenchWorkspace& ws);

/// Λ = (J M⁻¹ Jᵀ)⁺: the inertia seen at the grasp frames of twist Jacobian J (6N × n), M the mass
/// matrix (positive definite). For a free rigid body J is square and Λ its spatial inertia at the
/// grasp.
Mat task_space_inertia(const Mat& M, const Mat& J);

}  // namespace ukdyn
