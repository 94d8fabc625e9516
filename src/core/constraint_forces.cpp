#include "ukdyn/core/constraint_forces.hpp"

#include <Eigen/Cholesky>
#include <Eigen/QR>
#include <Eigen/SVD>

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

ConstraintForceSplit split_constraint_force(const Mat& A, const Vec& Qc,
                                            const std::vector<Index>& row_offsets, double rel_tol) {
  ConstraintForceSplit s;
  const Index m = A.rows(), n = A.cols();
  if (m == 0) {
    s.lambda = Vec::Zero(0);
    return s;
  }
  Eigen::CompleteOrthogonalDecomposition<Mat> cod(A.transpose());
  const double top = cod.maxPivot();
  cod.setThreshold(top > 0 ? rel_tol : 1.0);
  s.rank = static_cast<int>(cod.rank());
  s.unique = s.rank == m;
  s.lambda = cod.solve(Qc);  // least-norm least-squares solution
  s.residual = (A.transpose() * s.lambda - Qc).norm();
  for (std::size_t k = 0; k < row_offsets.size(); ++k) {
    const Index r0 = row_offsets[k];
    const Index r1 = k + 1 < row_offsets.size() ? row_offsets[k + 1] : m;
    const Vec lk = s.lambda.segment(r0, r1 - r0);
    s.block_lambda.push_back(lk);
    s.block_force.push_back(r1 > r0 ? Vec(A.middleRows(r0, r1 - r0).transpose() * lk)
                                    : Vec(Vec::Zero(n)));
  }
  return s;
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
