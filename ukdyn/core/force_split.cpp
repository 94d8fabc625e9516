#include "ukdyn/core/force_split.hpp"

#include <Eigen/QR>
#include <Eigen/SVD>

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

}  // namespace ukdyn
