// Diagnostics of a run: why the step control gave up, and the redundancy at the start
// (docs/singular-positions.md).
#include "ukdyn/simulate/diagnostics.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <cstdio>

namespace ukdyn::detail {

std::string sci(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3g", v);
  return buf;
}

// Why a step failed (issue 15 class 5): evaluated at the state where the step control gave up, on
// the failure path only (allocates). Names the cause and the coordinates / constraint rows
// involved, or returns "" when neither M nor A is singular there.
std::string diagnose_singularity(const System& system, double t, const std::vector<double>& x,
                                 const UkSettings& uk) {
  const Index n = system.dof();
  const Eigen::Map<const Vec> q(x.data(), n);
  const Eigen::Map<const Vec> qd(x.data() + n, n);
  ForwardData d(system);
  evaluate_dynamics(system, d, t, q, qd);
  const auto& cn = system.coordinate_names();
  const auto& rn = system.constraint_row_names();
  auto names = [](const std::vector<std::string>& all, const Vec& v) {
    std::string out;
    const double vmax = v.cwiseAbs().maxCoeff();
    for (Index i = 0; i < v.size(); ++i) {
      if (std::abs(v(i)) >= 0.3 * vmax && static_cast<std::size_t>(i) < all.size()) {
        out += (out.empty() ? "" : ", ") + all[static_cast<std::size_t>(i)];
      }
    }
    return out;
  };
  Eigen::SelfAdjointEigenSolver<Mat> es(0.5 * (d.M + d.M.transpose()));
  if (es.info() != Eigen::Success || !d.M.allFinite()) {
    return "the mass matrix is not finite at t = " + std::to_string(t);
  }
  const double ev_min = es.eigenvalues()(0), ev_max = es.eigenvalues()(n - 1);
  if (!(ev_min > 1e-8 * std::max(ev_max, 0.0))) {
    // A singular M is fine when [M; A] has full column rank (core/uk_singular.hpp).
    evaluate_constraints(system, d, t, q, qd);
    const std::string why = undetermined_direction(d.M, d.A, cn);
    if (!why.empty()) return "at t = " + std::to_string(t) + ": " + why;
    if (system.rows() > 0) return "";
    return "the mass matrix is (nearly) singular at t = " + std::to_string(t) +
           ": smallest eigenvalue " + sci(ev_min) + " of largest " + sci(ev_max) +
           ", in coordinates [" + names(cn, es.eigenvectors().col(0)) + "]";
  }
  if (system.rows() == 0) return "";
  evaluate_constraints(system, d, t, q, qd);
  const Mat Mih = es.eigenvectors() * es.eigenvalues().cwiseSqrt().cwiseInverse().asDiagonal() *
                  es.eigenvectors().transpose();
  Eigen::JacobiSVD<Mat> svd(d.A * Mih, Eigen::ComputeFullU);
  const Vec& sv = svd.singularValues();
  if (sv.size() == 0 || !(sv(0) > 0.0)) return "";
  // The smallest singular value above round-off of redundant rows, and the rows of its direction.
  Index k = sv.size() - 1;
  while (k > 0 && sv(k) <= 1e-14 * sv(0)) --k;
  const double ratio = sv(k) / sv(0);
  if (ratio > 1e3 * uk.rank_rel_tol) return "";
  return "the constraints are near a singular position at t = " + std::to_string(t) +
         ": a singular value of A M^-1/2 is " + sci(ratio) + " of the largest (rank_tol " +
         sci(uk.rank_rel_tol) + "), in rows [" + names(rn, svd.matrixU().col(k)) + "]";
}

// Constant redundancy against a singular start (diagnostics.hpp). The singular values of a
// singular position grow like the distance from it (h here), far above the rank cut-off
// (rank_rel_tol = 1e-7 of the largest) for h = 1e-3; a redundancy holds at every configuration.
int structural_redundancy(const System& system, double t0, const Vec& q0, const Vec& qd0,
                          const UkSettings& uk) {
  const Index n = system.dof(), m = system.rows();
  if (m == 0 || n == 0) return 0;
  UkSettings exact = uk;
  exact.method = UkMethod::exact;
  exact.structural_redundancy = 0;
  ForwardData d(system);
  const Vec zero = Vec::Zero(n);
  auto deficiency = [&](const Vec& q, const Vec& qd) {
    forward(system, d, t0, q, qd, zero, exact);
    return d.result.finite ? static_cast<int>(m) - d.result.rank : 0;
  };
  int r = deficiency(q0, qd0);
  if (r <= 0) return 0;
  evaluate_constraints(system, d, t0, q0, qd0);
  const Eigen::BDCSVD<Mat> svd(d.A, Eigen::ComputeFullV);
  const Index rank_a = svd.rank();
  if (rank_a >= n) return r;  // nothing can move: no configuration nearby to compare with
  const Mat null = svd.matrixV().rightCols(n - rank_a);
  const double h = 1e-3 * (1.0 + q0.cwiseAbs().maxCoeff());
  const std::vector<bool> held(static_cast<std::size_t>(n), false);
  for (int k = 0; k < 2 && r > 0; ++k) {
    Vec c = Vec::Ones(null.cols());
    for (Index i = 1; k == 1 && i < c.size(); i += 2) c(i) = -1.0;
    const Vec dir = (null * c).normalized();
    const AssemblyResult a = assemble(system, t0, q0 + h * dir, qd0, held, 1e-12);
    if (!a.success) continue;  // not back on the manifold: no evidence either way
    r = std::min(r, deficiency(a.q, a.qd));
  }
  return r;
}

}  // namespace ukdyn::detail
