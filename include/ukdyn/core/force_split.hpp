// Constraint roles and the split of the Udwadia–Kalaba force by role (docs/control.md).
//
// A constraint is `physical` (closure, grasps, frame constraints: the plant's structure enforces
// it) or `servo` (trajectory / task rows: actuators must realise it). The U-K force is
// Qc = Aᵀλ (paper Eq. (4): Qc = M^{1/2}(A M^{-1/2})⁺(b − A M⁻¹Q) lies in the range of Aᵀ), so with
// the rows sorted by role
//   Qc = A_pᵀλ_p + A_sᵀλ_s = Q_p + Q_s.
// λ is the least-norm least-squares solution of Aᵀλ = Qc. When the stacked rows are redundant
// (rank A < m) only Qc is determined: the split is not unique, and `unique` is false with the rows
// that take part in a dependency in `redundant_rows`.
//
// Actuation (inverse dynamics of the constrained system): a plant that enforces only its physical
// constraints follows the servo rows iff B u = Qc − A_pᵀμ for some μ (the physical constraints
// react to whatever the actuators do; with that τ the U-K solve of the physical rows alone returns
// the same q̈, the KKT system being uniquely solvable for q̈). solve_actuation() solves
//   [B, A_pᵀ][u; μ] = Qc
// in least squares with the least-norm u: with P the orthogonal projector onto
// null(A_p) (= range(A_pᵀ)^⊥),
//   u = (P B)⁺ P Qc,   μ = (A_pᵀ)⁺ (Qc − B u),
// and the residual ‖B u + A_pᵀμ − Qc‖ = ‖P(B u − Qc)‖. A residual that is not round-off means the
// actuators cannot realise the servo constraints (underactuation): never hidden, the caller warns.
#pragma once

#include <Eigen/QR>
#include <Eigen/SVD>
#include <string>
#include <vector>

#include "ukdyn/core/types.hpp"

namespace ukdyn {

enum class ConstraintRole { physical, servo };
inline const char* to_string(ConstraintRole r) {
  return r == ConstraintRole::physical ? "physical" : "servo";
}

struct RoleForceSplit {
  Vec lambda;  ///< least-norm λ with Aᵀλ = Qc (m)
  Vec Qp;      ///< A_pᵀλ_p (n)
  Vec Qs;      ///< A_sᵀλ_s (n)
  int rank = 0;
  bool unique = true;                 ///< rank A == m
  double residual = 0.0;              ///< ‖Aᵀλ − Qc‖
  std::vector<Index> redundant_rows;  ///< rows with a share in null(Aᵀ) (empty when unique)
};

/// row_servo[i]: row i of A is a servo row. rel_tol: singular values under rel_tol · σ_max count
/// as zero. Allocates.
RoleForceSplit split_by_role(const Mat& A, const Vec& Qc, const std::vector<bool>& row_servo,
                             double rel_tol = 1e-10);

/// The buffers of split_by_role() for A: m × n, allocated once.
struct RoleSplitWorkspace {
  RoleSplitWorkspace(Index m, Index n);
  Mat At;                                           ///< n × m: Aᵀ
  Eigen::CompleteOrthogonalDecomposition<Mat> cod;  ///< of Aᵀ: λ when the rows are independent
  Eigen::JacobiSVD<Mat> svd;                        ///< of Aᵀ: the rank and λ otherwise
  Vec r;                                            ///< n: Aᵀλ − Qc
  Vec c, y, z_temp;                                 ///< the COD solve's buffers (n, m, n)
  Eigen::Matrix<double, 1, Eigen::Dynamic, Eigen::RowMajor> hh;  ///< its Householder workspace
  RoleForceSplit result;  ///< λ (m), Qp, Qs (n); room for m redundant rows
};

/// split_by_role() into ws.result: the same numbers, and no heap allocation once ws exists
/// (tests/test_no_alloc.cpp).
void split_by_role(const Mat& A, const Vec& Qc, const std::vector<bool>& row_servo,
                   RoleSplitWorkspace& ws, double rel_tol = 1e-10);

/// The rows of A whose flag is `servo` (or not).
Mat select_rows(const Mat& A, const std::vector<bool>& row_servo, bool servo);

struct Actuation {
  Vec u;                       ///< least-norm actuator inputs (columns of B)
  Vec mu;                      ///< the physical constraints' multipliers for that u
  double residual = 0.0;       ///< ‖B u + A_pᵀμ − Qc‖
  double scale = 0.0;          ///< ‖Qc‖ + ‖B‖ ‖u‖ (what the residual is relative to)
  bool underactuated = false;  ///< residual > rel_tol_residual · (scale + 1)
};

/// B: n × k actuator gains (τ = B u); Ap: physical rows (m_p × n); Qc: the force to realise.
Actuation solve_actuation(const Mat& B, const Mat& Ap, const Vec& Qc, double rel_tol = 1e-10,
                          double rel_tol_residual = 1e-8);

/// The buffers of solve_actuation() for B: n × k and A_p: m_p × n, allocated once (the control
/// law's right-hand side, docs/control.md "No allocation").
struct ActuationWorkspace {
  ActuationWorkspace(Index n, Index k, Index mp);
  Mat Ap;  ///< m_p × n: the caller writes the physical rows here
  Mat P, X, ApTX, PB, I, c_mat, y_mat;
  Vec PQc, rest, Bu, ApTmu, r, c_vec, y_k, y_mp, z_temp;
  Eigen::Matrix<double, 1, Eigen::Dynamic, Eigen::RowMajor> hh_mat, hh_vec;
  Eigen::CompleteOrthogonalDecomposition<Mat> codp, cod;
  Actuation result;  ///< u (k), mu (m_p) sized once
};

/// solve_actuation(B, ws.Ap, Qc) into ws.result without heap allocation once ws exists, the Z step
/// of a rank-deficient decomposition included (tests/test_no_alloc.cpp). Bit for bit the same
/// numbers as solve_actuation() (Actuation.WorkspaceSolveIsBitIdentical) below rank 48, where
/// Eigen's own solve switches to its blocked Householder path and the two agree to round-off.
void solve_actuation(const Mat& B, const Vec& Qc, ActuationWorkspace& ws, double rel_tol = 1e-10,
                     double rel_tol_residual = 1e-8);

}  // namespace ukdyn
