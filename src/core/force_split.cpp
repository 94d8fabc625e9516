#include "ukdyn/core/force_split.hpp"

#include <Eigen/QR>
#include <Eigen/SVD>
#include <algorithm>

namespace ukdyn {

Mat select_rows(const Mat& A, const std::vector<bool>& row_servo, bool servo) {
  Index k = 0;
  for (bool s : row_servo) k += s == servo ? 1 : 0;
  Mat out(k, A.cols());
  Index r = 0;
  for (Index i = 0; i < A.rows(); ++i)
    if (row_servo[static_cast<std::size_t>(i)] == servo) out.row(r++) = A.row(i);
  return out;
}

RoleForceSplit split_by_role(const Mat& A, const Vec& Qc, const std::vector<bool>& row_servo,
                             double rel_tol) {
  RoleForceSplit s;
  const Index m = A.rows(), n = A.cols();
  s.Qp = Vec::Zero(n);
  s.Qs = Vec::Zero(n);
  if (m == 0) {
    s.lambda = Vec::Zero(0);
    s.residual = Qc.norm();
    return s;
  }
  // λ = (Aᵀ)⁺ Qc by an SVD of Aᵀ (n × m): V's columns past the rank span null(Aᵀ) ⊂ R^m.
  Eigen::JacobiSVD<Mat> svd(A.transpose(), Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Vec& sv = svd.singularValues();
  const double top = sv.size() > 0 ? sv(0) : 0.0;
  int rank = 0;
  for (Index i = 0; i < sv.size(); ++i)
    if (sv(i) > rel_tol * top && top > 0) ++rank;
  s.rank = rank;
  s.unique = rank == m;
  const Mat& U = svd.matrixU();
  const Mat& V = svd.matrixV();
  s.lambda = Vec::Zero(m);
  for (int i = 0; i < rank; ++i) s.lambda += V.col(i) * (U.col(i).dot(Qc) / sv(i));
  s.residual = (A.transpose() * s.lambda - Qc).norm();
  if (!s.unique) {
    for (Index i = 0; i < m; ++i) {
      double share = 0.0;
      for (Index k = rank; k < m; ++k) share = std::max(share, std::abs(V(i, k)));
      if (share > 1e-8) s.redundant_rows.push_back(i);
    }
  }
  for (Index i = 0; i < m; ++i) {
    (row_servo[static_cast<std::size_t>(i)] ? s.Qs : s.Qp) += A.row(i).transpose() * s.lambda(i);
  }
  return s;
}

Actuation solve_actuation(const Mat& B, const Mat& Ap, const Vec& Qc, double rel_tol,
                          double rel_tol_residual) {
  Actuation a;
  const Index n = B.rows();
  // P = I − A_pᵀ(A_pᵀ)⁺, the projector onto range(A_pᵀ)^⊥ = null(A_p).
  Mat P = Mat::Identity(n, n);
  Eigen::CompleteOrthogonalDecomposition<Mat> codp;
  if (Ap.rows() > 0) {
    codp.compute(Ap.transpose());
    codp.setThreshold(rel_tol);
    P -= Ap.transpose() * codp.solve(Mat::Identity(n, n));
  }
  const Mat PB = P * B;
  Eigen::CompleteOrthogonalDecomposition<Mat> cod(PB);
  cod.setThreshold(rel_tol);
  a.u = B.cols() > 0 ? Vec(cod.solve(P * Qc)) : Vec::Zero(0);
  const Vec rest = Qc - B * a.u;
  a.mu = Ap.rows() > 0 ? Vec(codp.solve(rest)) : Vec::Zero(0);
  const Vec r = B * a.u + Ap.transpose() * a.mu - Qc;
  a.residual = r.norm();
  a.scale = Qc.norm() + (B.size() > 0 ? B.norm() * a.u.norm() : 0.0);
  a.underactuated = a.residual > rel_tol_residual * (a.scale + 1.0);
  return a;
}

namespace {

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

}  // namespace

ActuationWorkspace::ActuationWorkspace(Index n, Index k, Index mp)
    : Ap(Mat::Zero(mp, n)),
      P(n, n),
      X(mp, n),
      ApTX(n, n),
      PB(n, k),
      I(Mat::Identity(n, n)),
      c_mat(n, n),
      y_mat(mp, n),
      PQc(n),
      rest(n),
      Bu(n),
      ApTmu(n),
      r(n),
      c_vec(n),
      y_k(k),
      y_mp(mp),
      z_temp(std::max<Index>(n, 1)),
      hh_mat(n),
      hh_vec(1),
      codp(n, mp),
      cod(n, k) {
  result.u = Vec::Zero(k);
  result.mu = Vec::Zero(mp);
}

void solve_actuation(const Mat& B, const Vec& Qc, ActuationWorkspace& w, double rel_tol,
                     double rel_tol_residual) {
  // The same steps as solve_actuation(B, Ap, Qc) above, each into a buffer of w.
  Actuation& a = w.result;
  const Index mp = w.Ap.rows();
  w.P.setIdentity();
  if (mp > 0) {
    w.codp.setThreshold(Eigen::Default);  // a fresh decomposition's rank at compute()
    w.codp.compute(w.Ap.transpose());
    w.codp.setThreshold(rel_tol);
    // codp is n × mp: its solve of I (n × n) is mp × n.
    cod_solve_into(w.codp, w.I, w.X, w.c_mat, w.y_mat, w.z_temp, w.hh_mat);
    w.ApTX.noalias() = w.Ap.transpose() * w.X;
    w.P -= w.ApTX;
  }
  w.PB.noalias() = w.P * B;
  w.cod.setThreshold(Eigen::Default);
  w.cod.compute(w.PB);
  w.cod.setThreshold(rel_tol);
  if (B.cols() > 0) {
    w.PQc.noalias() = w.P * Qc;
    cod_solve_into(w.cod, w.PQc, a.u, w.c_vec, w.y_k, w.z_temp, w.hh_vec);
  }
  w.Bu.noalias() =
      B * a.u;  // before `rest`: Qc − B u written at once evaluates B u into a heap temporary
  w.rest = Qc - w.Bu;
  if (mp > 0) cod_solve_into(w.codp, w.rest, a.mu, w.c_vec, w.y_mp, w.z_temp, w.hh_vec);
  w.ApTmu.noalias() = w.Ap.transpose() * a.mu;
  w.r = w.Bu + w.ApTmu - Qc;
  a.residual = w.r.norm();
  a.scale = Qc.norm() + (B.size() > 0 ? B.norm() * a.u.norm() : 0.0);
  a.underactuated = a.residual > rel_tol_residual * (a.scale + 1.0);
}

}  // namespace ukdyn
