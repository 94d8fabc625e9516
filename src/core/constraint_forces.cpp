#include "ukdyn/core/constraint_forces.hpp"

#include <Eigen/Cholesky>
#include <Eigen/QR>
#include <Eigen/SVD>
#include <cmath>
#include <limits>

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

// X⁺ into out with the buffers of svd (preallocated for X's size), inv and tmp: pinv()'s result
// (the same cut-off), no allocation.
void pinv_into(const Mat& X, Eigen::JacobiSVD<Mat>& svd, Vec& inv, Mat& tmp, Mat& out,
               double rel_tol = 1e-12) {
  svd.compute(X, Eigen::ComputeThinU | Eigen::ComputeThinV);
  const auto& s = svd.singularValues();
  const double cut = s.size() > 0 ? rel_tol * s(0) : 0.0;
  for (Index i = 0; i < s.size(); ++i) inv(i) = s(i) > cut ? 1.0 / s(i) : 0.0;
  tmp.noalias() = svd.matrixV() * inv.asDiagonal();
  out.noalias() = tmp * svd.matrixU().transpose();
}

// X⁺ of a symmetric positive semidefinite X (n × n) into out. When the Cholesky factor's diagonal
// shows X well conditioned (λ_min / λ_max above 1e-8 by the diagonal's ratio squared), X⁺ = X⁻¹ by
// that factor: several times faster than the SVD at 24 × 24. Otherwise pinv_into(). No allocation.
void pinv_psd_into(const Mat& X, Eigen::LLT<Mat>& llt, Eigen::JacobiSVD<Mat>& svd, Vec& inv,
                   Mat& tmp, Mat& out) {
  llt.compute(X);
  if (llt.info() == Eigen::Success) {
    const auto d = llt.matrixLLT().diagonal();
    const double lo = d.minCoeff(), hi = d.maxCoeff();
    if (lo > 0.0 && lo * lo > 1e-8 * hi * hi) {
      out.setIdentity();
      llt.solveInPlace(out);
      return;
    }
  }
  pinv_into(X, svd, inv, tmp, out);
}

// The same for a fixed 6 × 6 X (no allocation by construction).
using Mat6 = Eigen::Matrix<double, 6, 6>;
Mat6 pinv6(const Mat6& X, double rel_tol = 1e-12) {
  const Eigen::JacobiSVD<Mat6> svd(X, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const auto& s = svd.singularValues();
  const double cut = rel_tol * s(0);
  Eigen::Matrix<double, 6, 1> inv;
  for (Index i = 0; i < 6; ++i) inv(i) = s(i) > cut ? 1.0 / s(i) : 0.0;
  return svd.matrixV() * inv.asDiagonal() * svd.matrixU().transpose();
}

// pinv6() of a symmetric positive semidefinite X: X⁻¹ by Cholesky when well conditioned (as
// pinv_psd_into), else the SVD.
Mat6 pinv6_psd(const Mat6& X) {
  const Eigen::LLT<Mat6> llt(X);
  if (llt.info() == Eigen::Success) {
    const auto d = llt.matrixLLT().diagonal();
    const double lo = d.minCoeff(), hi = d.maxCoeff();
    if (lo > 0.0 && lo * lo > 1e-8 * hi * hi) return llt.solve(Mat6::Identity());
  }
  return pinv6(X);
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
  Mat G(6, 6 * static_cast<Index>(points.size()));
  grasp_matrix(points, reference, G);
  return G;
}

void grasp_matrix(const std::vector<Vec3>& points, const Vec3& reference, Mat& G) {
  const Index N = static_cast<Index>(points.size());
  G.setZero();
  for (Index k = 0; k < N; ++k) {
    const Vec3 d = points[static_cast<std::size_t>(k)] - reference;
    G.block<3, 3>(0, 6 * k).setIdentity();
    G.block<3, 3>(3, 6 * k + 3).setIdentity();
    Eigen::Matrix3d D;
    D << 0, -d(2), d(1), d(2), 0, -d(0), -d(1), d(0), 0;
    G.block<3, 3>(3, 6 * k) = D;  // (p_k − r) × f_k
  }
}

Vec internal_wrench_walker(const Mat& G, const Vec& w) { return w - pinv(G) * (G * w); }

// With S = G Gᵀ, y = S⁻¹ G w and w_int = w − Gᵀ y [Walker1991], along s ([GolubPereyra1973]
// for the full-row-rank G⁺ = Gᵀ S⁻¹):
//   dy = S⁻¹ (dG w + G dw − (dG Gᵀ + G dGᵀ) y),  dw_int = dw − dGᵀ y − Gᵀ dy,
// dG: the blocks [d(p_k − p_0)]× at rows 3..5, columns 6k..6k+2 (grasp_matrix()), zero elsewhere.
Mat internal_wrench_walker_derivative(const std::vector<Vec3>& points, const Vec& w,
                                      const Mat& dpoints, const Mat& dw) {
  const Mat G = grasp_matrix(points, points.front());
  const Eigen::LLT<Mat> S(G * G.transpose());
  const Vec y = S.solve(G * w);
  const Index N = static_cast<Index>(points.size()), n = dw.cols();
  Mat out(6 * N, n), dG(6, 6 * N);
  std::vector<Vec3> dd(points.size());
  for (Index j = 0; j < n; ++j) {
    for (Index k = 0; k < N; ++k)
      dd[static_cast<std::size_t>(k)] = dpoints.block<3, 1>(3 * k, j) - dpoints.block<3, 1>(0, j);
    grasp_matrix(dd, Vec3::Zero(), dG);
    for (Index k = 0; k < N; ++k) {  // keep only the (p_k − p_0)× blocks
      dG.block<3, 3>(0, 6 * k).setZero();
      dG.block<3, 3>(3, 6 * k + 3).setZero();
    }
    const Vec dy =
        S.solve(dG * w + G * dw.col(j) - dG * (G.transpose() * y) - G * (dG.transpose() * y));
    out.col(j) = dw.col(j) - dG.transpose() * y - G.transpose() * dy;
  }
  return out;
}

Vec internal_wrench_weighted(const Mat& G, const Mat& Lambda, const Vec& w) {
  const Mat LGt = Lambda * G.transpose();
  const Mat Gstar = LGt * pinv(G * LGt);
  return w - Gstar * (G * w);
}

InternalWrenchWorkspace::InternalWrenchWorkspace(Index grasps, Index agent_dof)
    : points(static_cast<std::size_t>(grasps), Vec3::Zero()),
      w(Vec::Zero(6 * grasps)),
      J(Mat::Zero(6 * grasps, agent_dof)),
      M(Mat::Zero(agent_dof, agent_dof)),
      walker(Vec::Zero(6 * grasps)),
      weighted(Vec::Zero(6 * grasps)),
      G(6, 6 * grasps),
      MinvJt(agent_dof, 6 * grasps),
      K(6 * grasps, 6 * grasps),
      Lambda(6 * grasps, 6 * grasps),
      LGt(6 * grasps, 6),
      tmpN(6 * grasps, 6 * grasps),
      S(6, 6),
      S6(6, 6),
      llt(agent_dof),
      llt_big(6 * grasps),
      svd_big(6 * grasps, 6 * grasps, Eigen::ComputeThinU | Eigen::ComputeThinV),
      inv_big(6 * grasps),
      Gw(6),
      y6(6) {}

void internal_wrenches(InternalWrenchWorkspace& ws) {
  grasp_matrix(ws.points, ws.points.empty() ? Vec3::Zero() : ws.points.front(), ws.G);
  const Mat& G = ws.G;
  ws.Gw.noalias() = G * ws.w;
  // [Walker1991]: G⁺ = Gᵀ (G Gᵀ)⁺, so (I − G⁺G) w = w − Gᵀ (G Gᵀ)⁺ G w.
  ws.S.noalias() = G * G.transpose();
  ws.S6 = pinv6_psd(ws.S);
  ws.y6.noalias() = ws.S6 * ws.Gw;
  ws.walker = ws.w;
  ws.walker.noalias() -= G.transpose() * ws.y6;
  // [Verginis2019]: Λ = (J M⁻¹ Jᵀ)⁺, G* = Λ Gᵀ (G Λ Gᵀ)⁺, (I − G*G) w.
  ws.llt.compute(ws.M);
  ws.weighted_ok = ws.llt.info() == Eigen::Success;
  if (!ws.weighted_ok) {
    ws.weighted.setConstant(std::numeric_limits<double>::quiet_NaN());
    return;
  }
  ws.MinvJt = ws.J.transpose();
  ws.llt.solveInPlace(ws.MinvJt);
  ws.K.noalias() = ws.J * ws.MinvJt;
  pinv_psd_into(ws.K, ws.llt_big, ws.svd_big, ws.inv_big, ws.tmpN, ws.Lambda);
  ws.LGt.noalias() = ws.Lambda * G.transpose();
  ws.S.noalias() = G * ws.LGt;
  ws.S6 = pinv6_psd(ws.S);
  ws.y6.noalias() = ws.S6 * ws.Gw;
  ws.weighted = ws.w;
  ws.weighted.noalias() -= ws.LGt * ws.y6;
}

Mat task_space_inertia(const Mat& M, const Mat& J) {
  const Eigen::LLT<Mat> llt(M);
  const Mat MinvJt = llt.solve(J.transpose());
  return pinv(J * MinvJt);
}

}  // namespace ukdyn
