#include "ukdyn/core/constraint_forces.hpp"

#include <Eigen/Cholesky>
#include <Eigen/QR>
#include <Eigen/SVD>

#include "core/cod_solve.hpp"

namespace ukdyn {

namespace {

// Moore–Penrose inverse by SVD with a relative cut-off.
Mat pinv(const Mat& X, double rel_tol = 1e-12) {
  if (X.size() == 0) return Mat::Zero(X.cols(), X.rows());
  Eigen::JacobiSVD<Mat> svd(X, Eigen::ComputeThinU | Eigen::ComputeThinV);
  const Vec& s = svd.singularValues();
  const double cut = s.size() > 0 ? rel_tol * s(0) : 0.0;
  Vec inv = Vec::Zero(s.size());
  for (Index i = 0; i < s.size(); ++i) inv(i) = s(i) > cut ? 1.0 / s(i) : 0.0;
  return svd.matrixV() * inv.asDiagonal() * svd.matrixU().transpose();
}

}  // namespace

ConstraintForceWorkspace::ConstraintForceWorkspace(Index m, Index n, std::vector<Index> offsets)
    : row_offsets(std::move(offsets)),
      At(n, m),
      cod(n, m),
      r(n),
      c(n),
      y(m),
      z_temp(std::max<Index>(n, 1)),
      hh(1) {
  result.lambda = Vec::Zero(m);
  if (m == 0) return;  // no rows: no blocks
  for (std::size_t k = 0; k < row_offsets.size(); ++k) {
    const Index r0 = row_offsets[k];
    const Index r1 = k + 1 < row_offsets.size() ? row_offsets[k + 1] : m;
    result.block_lambda.push_back(Vec::Zero(r1 - r0));
    result.block_force.push_back(Vec::Zero(n));
  }
}

void split_constraint_force(const Mat& A, const Vec& Qc, ConstraintForceWorkspace& ws,
                            double rel_tol) {
  ConstraintForceSplit& s = ws.result;
  const Index m = A.rows();
  if (m == 0) return;
  ws.At = A.transpose();
  // The threshold is set before compute(): the decomposition's Z (the complete orthogonal step) is
  // built for the rank at compute(); a threshold changed afterwards would solve with another rank
  // against that Z (not the least-norm solution, and reading past the factor).
  ws.cod.setThreshold(rel_tol);  // relative to the largest pivot
  ws.cod.compute(ws.At);
  s.rank = static_cast<int>(ws.cod.rank());
  s.unique = s.rank == m;
  // The least-norm least-squares solution, cod.solve(Qc) without its temporaries.
  core_detail::cod_solve_into(ws.cod, Qc, s.lambda, ws.c, ws.y, ws.z_temp, ws.hh);
  ws.r.noalias() = A.transpose() * s.lambda;  // (a buffer: Aᵀλ − Qc in one expression allocates)
  ws.r -= Qc;
  s.residual = ws.r.norm();
  for (std::size_t k = 0; k < ws.row_offsets.size(); ++k) {
    const Index r0 = ws.row_offsets[k];
    const Index r1 = k + 1 < ws.row_offsets.size() ? ws.row_offsets[k + 1] : m;
    Vec& lk = s.block_lambda[k];
    lk = s.lambda.segment(r0, r1 - r0);
    if (r1 > r0) {
      s.block_force[k].noalias() = A.middleRows(r0, r1 - r0).transpose() * lk;
    } else {
      s.block_force[k].setZero();
    }
  }
}

ConstraintForceSplit split_constraint_force(const Mat& A, const Vec& Qc,
                                            const std::vector<Index>& row_offsets, double rel_tol) {
  ConstraintForceWorkspace ws(A.rows(), A.cols(), row_offsets);
  split_constraint_force(A, Qc, ws, rel_tol);
  return std::move(ws.result);
}

Mat grasp_matrix(const std::vector<Vec3>& points, const Vec3& reference) {
  const Index N = static_cast<Index>(points.size());
  Mat G = Mat::Zero(6, 6 * N);
  for (Index k = 0; k < N; ++k) {
    const Vec3 d = points[static_cast<std::size_t>(k)] - reference;
    G.block<3, 3>(0, 6 * k).setIdentity();
    G.block<3, 3>(3, 6 * k + 3).setIdentity();
    Eigen::Matrix3d D;
    D << 0, -d(2), d(1), d(2), 0, -d(0), -d(1), d(0), 0;
    G.block<3, 3>(3, 6 * k) = D;  // (p_k − r) × f_k
  }
  return G;
}

Vec internal_wrench_walker(const Mat& G, const Vec& w) { return w - pinv(G) * (G * w); }

Vec internal_wrench_weighted(const Mat& G, const Mat& Lambda, const Vec& w) {
  const Mat LGt = Lambda * G.transpose();
  const Mat Gstar = LGt * pinv(G * LGt);
  return w - Gstar * (G * w);
}

Mat task_space_inertia(const Mat& M, const Mat& J) {
  const Eigen::LLT<Mat> llt(M);
  const Mat MinvJt = llt.solve(J.transpose());
  return pinv(J * MinvJt);
}

}  // namespace ukdyn
