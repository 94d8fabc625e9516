#include "ukdyn/core/force_split.hpp"

#include <Eigen/QR>
#include <Eigen/SVD>
#include <algorithm>

#include "core/cod_solve.hpp"

namespace ukdyn {

using core_detail::cod_solve_into;

Mat select_rows(const Mat& A, const std::vector<bool>& row_servo, bool servo) {
  Index k = 0;
  for (bool s : row_servo) k += s == servo ? 1 : 0;
  Mat out(k, A.cols());
  Index r = 0;
  for (Index i = 0; i < A.rows(); ++i)
    if (row_servo[static_cast<std::size_t>(i)] == servo) out.row(r++) = A.row(i);
  return out;
}

RoleSplitWorkspace::RoleSplitWorkspace(Index m, Index n)
    : At(n, m),
      cod(n, m),
      svd(n, m, Eigen::ComputeThinU | Eigen::ComputeFullV),
      r(n),
      c(n),
      y(m),
      z_temp(std::max<Index>(n, 1)),
      hh(1) {
  result.lambda = Vec::Zero(m);
  result.Qp = Vec::Zero(n);
  result.Qs = Vec::Zero(n);
  result.redundant_rows.reserve(static_cast<std::size_t>(m));
}

namespace {

// λ = (Aᵀ)⁺ Qc by an SVD of Aᵀ (n × m): V's columns past the rank span null(Aᵀ) ⊂ R^m, whose
// rows name the redundant constraint rows.
void split_by_svd(const Vec& Qc, RoleSplitWorkspace& ws, double rel_tol) {
  RoleForceSplit& s = ws.result;
  const Index m = ws.At.cols();
  ws.svd.compute(ws.At, Eigen::ComputeThinU | Eigen::ComputeFullV);  // U: its first rank columns
  const Vec& sv = ws.svd.singularValues();
  const double top = sv.size() > 0 ? sv(0) : 0.0;
  int rank = 0;
  for (Index i = 0; i < sv.size(); ++i)
    if (sv(i) > rel_tol * top && top > 0) ++rank;
  s.rank = rank;
  s.unique = rank == m;
  const Mat& U = ws.svd.matrixU();
  const Mat& V = ws.svd.matrixV();
  s.lambda.setZero();
  for (int i = 0; i < rank; ++i) s.lambda += V.col(i) * (U.col(i).dot(Qc) / sv(i));
  if (!s.unique) {
    for (Index i = 0; i < m; ++i) {
      double share = 0.0;
      for (Index k = rank; k < m; ++k) share = std::max(share, std::abs(V(i, k)));
      if (share > 1e-8) s.redundant_rows.push_back(i);
    }
  }
}

}  // namespace

void split_by_role(const Mat& A, const Vec& Qc, const std::vector<bool>& row_servo,
                   RoleSplitWorkspace& ws, double rel_tol) {
  RoleForceSplit& s = ws.result;
  const Index m = A.rows();
  s.Qp.setZero();
  s.Qs.setZero();
  s.rank = 0;
  s.unique = true;
  s.redundant_rows.clear();
  if (m == 0) {
    s.residual = Qc.norm();
    return;
  }
  ws.At = A.transpose();
  // Rows independent with a margin (the column-pivoted QR's smallest pivot 1e3 times above the
  // cut-off): λ is unique, the least-squares solution of the complete orthogonal decomposition
  // (a QR: several times cheaper than the SVD, which this once took at every output sample).
  // Otherwise, or near the cut-off, the SVD decides the rank and names the redundant rows.
  ws.cod.setThreshold(Eigen::Default);
  ws.cod.compute(ws.At);
  const double top = ws.cod.maxPivot();
  const auto& T = ws.cod.matrixQTZ();
  double smallest = top;
  for (Index i = 0; i < std::min(T.rows(), T.cols()); ++i)
    smallest = std::min(smallest, std::abs(T(i, i)));
  if (top > 0.0 && m <= A.cols() && smallest > 1e3 * rel_tol * top) {
    ws.cod.setThreshold(rel_tol);
    s.rank = static_cast<int>(m);
    core_detail::cod_solve_into(ws.cod, Qc, s.lambda, ws.c, ws.y, ws.z_temp, ws.hh);
  } else {
    split_by_svd(Qc, ws, rel_tol);
  }
  ws.r.noalias() = A.transpose() * s.lambda;  // (a buffer: Aᵀλ − Qc in one expression allocates)
  ws.r -= Qc;
  s.residual = ws.r.norm();
  for (Index i = 0; i < m; ++i) {
    (row_servo[static_cast<std::size_t>(i)] ? s.Qs : s.Qp) += A.row(i).transpose() * s.lambda(i);
  }
}

RoleForceSplit split_by_role(const Mat& A, const Vec& Qc, const std::vector<bool>& row_servo,
                             double rel_tol) {
  RoleSplitWorkspace ws(A.rows(), A.cols());
  split_by_role(A, Qc, row_servo, ws, rel_tol);
  return std::move(ws.result);
}

Actuation solve_actuation(const Mat& B, const Mat& Ap, const Vec& Qc, double rel_tol,
                          double rel_tol_residual) {
  Actuation a;
  const Index n = B.rows();
  // P = I − A_pᵀ(A_pᵀ)⁺, the projector onto range(A_pᵀ)^⊥ = null(A_p).
  Mat P = Mat::Identity(n, n);
  Eigen::CompleteOrthogonalDecomposition<Mat> codp;
  // Thresholds before compute(): Z is built for the rank at compute() (see split_constraint_force).
  if (Ap.rows() > 0) {
    codp.setThreshold(rel_tol);
    codp.compute(Ap.transpose());
    P -= Ap.transpose() * codp.solve(Mat::Identity(n, n));
  }
  const Mat PB = P * B;
  Eigen::CompleteOrthogonalDecomposition<Mat> cod;
  cod.setThreshold(rel_tol);
  cod.compute(PB);
  // P B of round-off size (the physical rows span every actuated direction): nothing is left for
  // the actuators; the relative threshold alone would keep the round-off at full rank.
  const bool none = PB.norm() <= rel_tol * B.norm();
  a.u = B.cols() > 0 && !none ? Vec(cod.solve(P * Qc)) : Vec::Zero(B.cols());
  const Vec rest = Qc - B * a.u;
  a.mu = Ap.rows() > 0 ? Vec(codp.solve(rest)) : Vec::Zero(0);
  const Vec r = B * a.u + Ap.transpose() * a.mu - Qc;
  a.residual = r.norm();
  a.scale = Qc.norm() + (B.size() > 0 ? B.norm() * a.u.norm() : 0.0);
  a.underactuated = a.residual > rel_tol_residual * (a.scale + 1.0);
  return a;
}

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
    w.codp.setThreshold(rel_tol);  // before compute(): Z is built for the rank at compute()
    w.codp.compute(w.Ap.transpose());
    // codp is n × mp: its solve of I (n × n) is mp × n.
    cod_solve_into(w.codp, w.I, w.X, w.c_mat, w.y_mat, w.z_temp, w.hh_mat);
    w.ApTX.noalias() = w.Ap.transpose() * w.X;
    w.P -= w.ApTX;
  }
  w.PB.noalias() = w.P * B;
  w.cod.setThreshold(rel_tol);
  w.cod.compute(w.PB);
  if (B.cols() > 0 && w.PB.norm() > rel_tol * B.norm()) {  // else P B is round-off (above)
    w.PQc.noalias() = w.P * Qc;
    cod_solve_into(w.cod, w.PQc, a.u, w.c_vec, w.y_k, w.z_temp, w.hh_vec);
  } else {
    a.u.setZero();
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
