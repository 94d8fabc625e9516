// Internal to ukdyn::core: x = cod⁺ rhs of a complete orthogonal decomposition into the caller's
// buffers (no heap allocation), shared by the actuation solve (force_split.cpp) and the split of
// the constraint force by block (constraint_forces.cpp).
#pragma once

#include <Eigen/QR>

#include "ukdyn/core/types.hpp"

namespace ukdyn::core_detail {

// x = cod⁺ rhs as CompleteOrthogonalDecomposition::_solve_impl (Eigen 3.4) computes it, with the
// caller's buffers: c = Qᵀ rhs, T z = c(0:r), y = Zᵀ [z; 0], x = P y. The same operations in the
// same order as cod.solve(rhs), so the same bits; the copies replace Eigen's per-call temporaries
// (c, the Householder workspace, Z's temp and the in-place permutation's mask).
template <typename Rhs, typename Dst, typename Work>
void cod_solve_into(const Eigen::CompleteOrthogonalDecomposition<Mat>& cod, const Rhs& rhs,
                    Dst& dst, Dst& c, Dst& y, Vec& z_temp, Work& hh_work) {
  // c: as rhs (cod.rows() rows); y, dst: cod.cols() rows.
  const Index rank = cod.rank();
  if (rank == 0) {
    dst.setZero();
    return;
  }
  c = rhs;
  // c = Qᵀ c: HouseholderSequence::applyThisOnTheLeft (Eigen 3.4, unblocked path) for the adjoint
  // of Q = H_0 ⋯ H_{r−1} (H_0 first), written out with the same types and operations so that the
  // bits are Eigen's; the one change is τ v, which Eigen's outer product evaluates into a heap
  // temporary, is evaluated into z_temp (free until the Z step below).
  const auto hq = cod.householderQ();
  hh_work.resize(c.cols());  // no-op once sized (as Eigen's workspace.resize)
  for (Index k = 0; k < rank; ++k) {
    const Index rows_k = hq.rows() - k;
    Eigen::Block<Dst, Eigen::Dynamic, Eigen::Dynamic> sub(c, k, 0, rows_k, c.cols());
    const double tau = cod.hCoeffs().coeff(k);  // Q's coefficients (real: not conjugated)
    if (rows_k == 1) {                          // MatrixBase::applyHouseholderOnTheLeft
      sub *= 1.0 - tau;
    } else if (tau != 0.0) {
      const auto essential = hq.essentialVector(k);
      Eigen::Map<Eigen::Matrix<double, 1, Eigen::Dynamic>> tmp(hh_work.data(), sub.cols());
      Eigen::Block<decltype(sub), Eigen::Dynamic, Eigen::Dynamic> bottom(sub, 1, 0, rows_k - 1,
                                                                         sub.cols());
      tmp.noalias() = essential.adjoint() * bottom;
      tmp += sub.row(0);
      sub.row(0) -= tau * tmp;
      auto tau_v = z_temp.head(rows_k - 1);
      tau_v = tau * essential;
      for (Index j = 0; j < sub.cols(); ++j) bottom.col(j) -= tmp(j) * tau_v;
    }
  }
  y.topRows(rank) = cod.matrixT()
                        .topLeftCorner(rank, rank)
                        .template triangularView<Eigen::Upper>()
                        .solve(c.topRows(rank));
  const Index cols = cod.cols();
  if (rank < cols) {
    y.bottomRows(cols - rank).setZero();
    // applyZAdjointOnTheLeftInPlace (a protected member of Eigen's COD), with z_temp.
    const Mat& qtz = cod.matrixQTZ();
    for (Index k = 0; k < rank; ++k) {
      if (k != rank - 1) y.row(k).swap(y.row(rank - 1));
      y.middleRows(rank - 1, cols - rank + 1)
          .applyHouseholderOnTheLeft(qtz.row(k).tail(cols - rank).adjoint(), cod.zCoeffs()(k),
                                     &z_temp(0));
      if (k != rank - 1) y.row(k).swap(y.row(rank - 1));
    }
  }
  // x = P y out of place (Eigen's in-place permutation would allocate its mask).
  const auto& perm = cod.colsPermutation().indices();
  for (Index i = 0; i < perm.size(); ++i) dst.row(perm(i)) = y.row(i);
}

}  // namespace ukdyn::core_detail
