#include "ukdyn/core/uk_solve.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <Eigen/SVD>
#include <cmath>
#include <limits>

namespace ukdyn {

UkWorkspace::UkWorkspace(const BlockLayout& block_layout, Index m)
    : layout(block_layout),
      M_inv_Q(block_layout.dof()),
      Linv_At(block_layout.dof(), m),
      A_Minv_At(m, m),
      ldlt(m),
      r(m),
      lambda(m),
      tmp_m(m),
      tmp_n(block_layout.dof()) {
  llt.reserve(layout.blocks());
  for (std::size_t k = 0; k < layout.blocks(); ++k) llt.emplace_back(layout.size[k]);
}

bool factor_mass(const Mat& M, UkWorkspace& ws) {
  const auto& L = ws.layout;
  for (std::size_t k = 0; k < L.blocks(); ++k) {
    ws.llt[k].compute(M.block(L.start[k], L.start[k], L.size[k], L.size[k]));
    if (ws.llt[k].info() != Eigen::Success) return false;
  }
  return true;
}

namespace {

// x ← M^{-1} x, block by block.
template <typename Derived>
void apply_M_inv(UkWorkspace& ws, Eigen::MatrixBase<Derived>& x) {
  const auto& L = ws.layout;
  for (std::size_t k = 0; k < L.blocks(); ++k) {
    auto seg = x.middleRows(L.start[k], L.size[k]);
    ws.llt[k].solveInPlace(seg);
  }
}

// X ← L^{-1} X, block by block (L the lower Cholesky factor of each block).
void apply_L_inv(UkWorkspace& ws, Mat& X) {
  const auto& L = ws.layout;
  for (std::size_t k = 0; k < L.blocks(); ++k) {
    auto rows = X.middleRows(L.start[k], L.size[k]);
    ws.llt[k].matrixL().solveInPlace(rows);
  }
}

bool all_finite(const Vec& v) { return v.allFinite(); }

void finish(const Mat& A, const Vec& b, const Vec& qdd, const Vec& Qc, const UkSettings& s,
            Vec& scratch_m, UkResult& res) {
  if (A.rows() > 0) {
    scratch_m.noalias() = A * qdd;
    scratch_m -= b;
    res.residual = scratch_m.norm();
    const double scale = b.norm() + A.cwiseAbs().rowwise().sum().maxCoeff() * qdd.norm() + 1.0;
    res.consistent = res.residual <= s.consistency_rel_tol * scale;
  }
  res.finite = all_finite(qdd) && all_finite(Qc) && std::isfinite(res.residual);
}

}  // namespace

UkResult uk_solve_factored(const Mat& A, const Vec& b, const Vec& Q, UkWorkspace& ws, Vec& qdd,
                           Vec& Qc, const UkSettings& settings) {
  UkResult res;
  const Index m = A.rows();
  // a = M^{-1} Q: the unconstrained acceleration, paper Eq. (1).
  ws.M_inv_Q = Q;
  apply_M_inv(ws, ws.M_inv_Q);
  if (m == 0) {
    qdd = ws.M_inv_Q;
    Qc.setZero();
    res.finite = qdd.allFinite();
    return res;
  }
  // X = L^{-1} Aᵀ, W = Xᵀ X = A M^{-1} Aᵀ.
  ws.Linv_At = A.transpose();
  apply_L_inv(ws, ws.Linv_At);
  ws.A_Minv_At.noalias() = ws.Linv_At.transpose() * ws.Linv_At;
  // r = b − A M^{-1} Q, the bracket of paper Eq. (4).
  ws.r = b;
  ws.r.noalias() -= A * ws.M_inv_Q;

  // Pivoted LDLᵀ of W: P W Pᵀ = L D Lᵀ with |D| non-increasing in practice (diagonal pivoting).
  ws.ldlt.compute(ws.A_Minv_At);
  const auto& D = ws.ldlt.vectorD();
  const double d_max = D.cwiseAbs().maxCoeff();
  const double cutoff = settings.rank_rel_tol * settings.rank_rel_tol * d_max;
  double d_min_kept = std::numeric_limits<double>::infinity();
  int rank = 0;

  // Basic solution of W λ = r: λ = Pᵀ L^{-ᵀ} D⁺ L^{-1} P r, dropping pivots under the cutoff.
  ws.lambda = ws.ldlt.transpositionsP() * ws.r;
  ws.ldlt.matrixL().solveInPlace(ws.lambda);
  for (Index i = 0; i < m; ++i) {
    if (d_max > 0.0 && D(i) > cutoff) {
      ws.lambda(i) /= D(i);
      d_min_kept = std::min(d_min_kept, D(i));
      ++rank;
    } else {
      ws.lambda(i) = 0.0;
    }
  }
  ws.ldlt.matrixU().solveInPlace(ws.lambda);
  ws.lambda = ws.ldlt.transpositionsP().transpose() * ws.lambda;

  // Qc = Aᵀ λ  (= M^{1/2}(A M^{-1/2})^+ r, paper Eq. (4));  q̈ = a + M^{-1} Qc, paper Eq. (18).
  Qc.noalias() = A.transpose() * ws.lambda;
  ws.tmp_n = Qc;
  apply_M_inv(ws, ws.tmp_n);
  qdd = ws.M_inv_Q + ws.tmp_n;

  res.rank = rank;
  res.sigma_max = std::sqrt(std::max(d_max, 0.0));
  res.sigma_min_kept = rank > 0 ? std::sqrt(d_min_kept) : 0.0;
  finish(A, b, qdd, Qc, settings, ws.tmp_m, res);
  return res;
}

UkResult uk_solve(const Mat& M, const Mat& A, const Vec& b, const Vec& Q, UkWorkspace& ws, Vec& qdd,
                  Vec& Qc, const UkSettings& settings) {
  if (!factor_mass(M, ws)) {
    UkResult res;
    res.finite = false;
    qdd.setConstant(std::numeric_limits<double>::quiet_NaN());
    Qc.setConstant(std::numeric_limits<double>::quiet_NaN());
    return res;
  }
  return uk_solve_factored(A, b, Q, ws, qdd, Qc, settings);
}

namespace {
// Symmetric root and inverse root of an SPD matrix by eigen-decomposition.
void sym_roots(const Mat& M, Mat& M_half, Mat& M_inv_half) {
  Eigen::SelfAdjointEigenSolver<Mat> es(M);
  const Vec ev = es.eigenvalues();
  if (ev.minCoeff() <= 0.0) {
    throw Error("uk_solve_textbook: M is not positive definite");
  }
  M_half = es.eigenvectors() * ev.cwiseSqrt().asDiagonal() * es.eigenvectors().transpose();
  M_inv_half = es.eigenvectors() * ev.cwiseSqrt().cwiseInverse().asDiagonal() *
               es.eigenvectors().transpose();
}
}  // namespace

UkResult uk_solve_textbook(const Mat& M, const Mat& A, const Vec& b, const Vec& Q, Vec& qdd,
                           Vec& Qc, const UkSettings& settings) {
  UkResult res;
  Mat M_half, M_inv_half;
  sym_roots(M, M_half, M_inv_half);
  const Vec M_inv_Q = M.llt().solve(Q);
  if (A.rows() == 0) {
    qdd = M_inv_Q;
    Qc = Vec::Zero(Q.size());
    res.finite = qdd.allFinite();
    return res;
  }
  const Mat B = A * M_inv_half;  // A M^{-1/2}
  Eigen::JacobiSVD<Mat> svd(B, Eigen::ComputeThinU | Eigen::ComputeThinV);
  const Vec& s = svd.singularValues();
  const double cutoff = settings.rank_rel_tol * (s.size() > 0 ? s(0) : 0.0);
  Vec s_inv = Vec::Zero(s.size());
  int rank = 0;
  for (Index i = 0; i < s.size(); ++i) {
    if (s(i) > cutoff && s(i) > 0.0) {
      s_inv(i) = 1.0 / s(i);
      ++rank;
    }
  }
  const Mat B_pinv = svd.matrixV() * s_inv.asDiagonal() * svd.matrixU().transpose();
  // Qc = M^{1/2} (A M^{-1/2})^+ (b − A M^{-1} Q), paper Eq. (4), literally.
  Qc = M_half * (B_pinv * (b - A * M_inv_Q));
  qdd = M.llt().solve(Q + Qc);
  res.rank = rank;
  res.sigma_max = s.size() > 0 ? s(0) : 0.0;
  res.sigma_min_kept = rank > 0 ? s(rank - 1) : 0.0;
  Vec scratch(A.rows());
  finish(A, b, qdd, Qc, settings, scratch, res);
  return res;
}

Vec singular_values_A_Minvhalf(const Mat& M, const Mat& A) {
  Mat M_half, M_inv_half;
  sym_roots(M, M_half, M_inv_half);
  return Eigen::JacobiSVD<Mat>(A * M_inv_half).singularValues();
}

void kkt_solve(const Mat& M, const Mat& A, const Vec& b, const Vec& Q, Vec& qdd, Vec& Qc) {
  const Index n = M.rows();
  const Index m = A.rows();
  Mat K = Mat::Zero(n + m, n + m);
  K.topLeftCorner(n, n) = M;
  K.topRightCorner(n, m) = A.transpose();
  K.bottomLeftCorner(m, n) = A;
  Vec rhs(n + m);
  rhs << Q, b;
  const Vec x = K.fullPivLu().solve(rhs);
  qdd = x.head(n);
  // M q̈ + Aᵀ μ = Q  ⇒  Qc = −Aᵀ μ.
  Qc = -(A.transpose() * x.tail(m));
}

}  // namespace ukdyn
