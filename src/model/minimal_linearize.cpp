// Minimal coordinates on the constraint manifold and the zero-order-hold discretisation
// (ukdyn/model/minimal_linearize.hpp, docs/derivatives.md).
#include "ukdyn/model/minimal_linearize.hpp"

#include <Eigen/LU>
#include <Eigen/SVD>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <sstream>
#include <stdexcept>

#include "ukdyn/model/constraint_jacobians.hpp"

namespace ukdyn {

namespace {

std::string sci(double v) {
  std::ostringstream os;
  os.precision(3);
  os << v;
  return os.str();
}

// Refuses a kept row that is velocity-level (first_velocity_level_row, constraint_jacobians.hpp).
void require_position_rows(const System& system, ForwardData& d, double t, CVecRef q, const Mat& AR,
                           const std::vector<Index>& kept) {
  const Index k = first_velocity_level_row(system, d, t, q, AR, kept);
  if (k < 0) return;
  throw Error(
      "minimal coordinates: constraint row '" +
      system.constraint_row_names()[static_cast<std::size_t>(kept[static_cast<std::size_t>(k)])] +
      "' is velocity-level (nonholonomic: its position residual does not vary along its row "
      "of A); ukdyn builds minimal coordinates for holonomic rows only");
}

// D = ∂(A_R q̇)/∂q at fixed q̇ from the constraints' exact tangents (constraint_jacobians.hpp).
Mat velocity_jacobian(const System& system, ForwardData& d, double t, CVecRef q, CVecRef qd,
                      const std::vector<Index>& kept) {
  Mat D;
  std::vector<Mat> unused;
  constraint_state_jacobians(system, d, t, q, qd, kept, {}, D, unused);
  return D;
}

// Rheonomic rows (Φ(q, t)): the velocity constraint is A q̇ + Φ_t = 0, so its linearisation has
// the extra term ∂Φ_t/∂q δq. Φ_t(q) is the velocity residual at q̇ = 0 (exactly 0 for a
// scleronomic row, velocity_residual() = A q̇); where it is not 0 at the state or a probe around
// it, ∂Φ_t/∂q comes from Richardson-extrapolated central differences of it (error O(h⁴); the
// constraints have no tangent of Φ_t) and `rheonomic` is set. Returns the r × n term.
Mat phi_t_jacobian(const System& system, ForwardData& d, double t, CVecRef q,
                   const std::vector<Index>& kept, bool& rheonomic) {
  const Index n = system.dof(), m = system.rows(), r = static_cast<Index>(kept.size());
  const Vec zero = Vec::Zero(n);
  Vec phit(m);
  auto phi_t = [&](const Vec& x) {
    velocity_residuals(system, d, t, x, zero, phit);
    Vec out(r);
    for (Index k = 0; k < r; ++k) out(k) = phit(kept[static_cast<std::size_t>(k)]);
    return out;
  };
  const double h = 1e-3 * (1.0 + q.cwiseAbs().maxCoeff());
  Mat E(r, n);
  double seen = phi_t(q).cwiseAbs().maxCoeff();
  for (Index j = 0; j < n; ++j) {
    auto central = [&](double step) {
      Vec xp = q, xm = q;
      xp(j) += step;
      xm(j) -= step;
      const Vec fp = phi_t(xp), fm = phi_t(xm);
      seen = std::max({seen, fp.cwiseAbs().maxCoeff(), fm.cwiseAbs().maxCoeff()});
      return Vec((fp - fm) / (2.0 * step));
    };
    E.col(j) = (4.0 * central(h / 2) - central(h)) / 3.0;
  }
  rheonomic = r > 0 && seen > 0.0;
  return rheonomic ? E : Mat::Zero(r, n);
}

}  // namespace

Mat null_space_basis(const Mat& AR) {
  const Index r = AR.rows(), n = AR.cols();
  if (r > n) {
    throw std::invalid_argument("null_space_basis: " + std::to_string(r) + " rows for " +
                                std::to_string(n) + " columns");
  }
  Mat N;
  if (r == 0) {
    N = Mat::Identity(n, n);
  } else {
    Eigen::JacobiSVD<Mat> svd(AR, Eigen::ComputeFullV);
    N = svd.matrixV().rightCols(n - r);
  }
  // The sign rule: the (first) entry of largest magnitude of each column is positive.
  for (Index j = 0; j < N.cols(); ++j) {
    Index imax = 0;
    N.col(j).cwiseAbs().maxCoeff(&imax);
    if (N(imax, j) < 0.0) N.col(j) *= -1.0;
  }
  return N;
}

MinimalModel minimal_model(const System& system, double t, CVecRef q, CVecRef qd, CVecRef tau,
                           const Linearization& lin) {
  const Index n = system.dof();
  if (lin.dqdd_dq.rows() != n || q.size() != n || qd.size() != n || tau.size() != n)
    throw std::invalid_argument("minimal_model: the linearisation or the state has the wrong size");
  MinimalModel mm;
  ForwardData d(system);
  forward(system, d, t, q, qd, tau);
  const Index r = static_cast<Index>(lin.kept_rows.size());
  mm.AR.resize(r, n);
  for (Index k = 0; k < r; ++k) mm.AR.row(k) = d.A.row(lin.kept_rows[static_cast<std::size_t>(k)]);
  require_position_rows(system, d, t, q, mm.AR, lin.kept_rows);
  forward(system, d, t, q, qd, tau);  // the slots again at the state, for the tangents
  mm.N = null_space_basis(mm.AR);
  const Index k = mm.N.cols();
  mm.null_residual = r > 0 && k > 0 ? (mm.AR * mm.N).cwiseAbs().maxCoeff() : 0.0;
  mm.ortho_residual =
      k > 0 ? (mm.N.transpose() * mm.N - Mat::Identity(k, k)).cwiseAbs().maxCoeff() : 0.0;
  mm.at_rest = qd.isZero(0.0);
  mm.D = mm.at_rest ? Mat::Zero(r, n) : velocity_jacobian(system, d, t, q, qd, lin.kept_rows);
  if (r > 0) mm.D += phi_t_jacobian(system, d, t, q, lin.kept_rows, mm.rheonomic);
  forward(system, d, t, q, qd, tau);  // leave the slots at the state
  state_space(lin, mm.F, mm.G);
  // T = [[N, 0], [−A_R⁺ D N, N]], A_R⁺ = A_Rᵀ (A_R A_Rᵀ)⁻¹ by the normal equations (the kept rows
  // are independent; their Gram matrix squares cond(A_R), which the rank rule keeps moderate).
  mm.T = Mat::Zero(2 * n, 2 * k);
  mm.T.topLeftCorner(n, k) = mm.N;
  mm.T.bottomRightCorner(n, k) = mm.N;
  if (r > 0 && !mm.D.isZero(0.0)) {
    const Mat ARt = mm.AR.transpose();
    const Mat gram = mm.AR * ARt;
    mm.T.bottomLeftCorner(n, k) = -ARt * gram.partialPivLu().solve(mm.D * mm.N);
  }
  Mat P = Mat::Zero(2 * k, 2 * n);
  P.topLeftCorner(k, n) = mm.N.transpose();
  P.bottomRightCorner(k, n) = mm.N.transpose();
  mm.F_min = P * mm.F * mm.T;
  mm.G_min = P * mm.G;
  Vec phi(system.rows()), phid(system.rows());
  position_residuals(system, d, t, q, phi);
  velocity_residuals(system, d, t, q, qd, phid);
  for (Index row : lin.kept_rows) {
    mm.position_residual = std::max(mm.position_residual, std::abs(phi(row)));
    mm.velocity_residual = std::max(mm.velocity_residual, std::abs(phid(row)));
  }
  forward(system, d, t, q, qd, tau);
  if (mm.position_residual > 1e-8 || mm.velocity_residual > 1e-8) {
    mm.note = "the state is off the constraint manifold (|Phi| " + sci(mm.position_residual) +
              ", |Phi'| " + sci(mm.velocity_residual) + ")";
  }
  if (mm.rheonomic) {
    mm.note +=
        std::string(mm.note.empty() ? "" : "; ") +
        "rheonomic rows: the d(Phi_t)/dq part of D is by Richardson central differences (the "
        "constraints give no tangent of Phi_t)";
  }
  if (!mm.at_rest) {
    mm.note +=
        std::string(mm.note.empty() ? "" : "; ") +
        "q' != 0: N is frozen at this state, the model is the instantaneous projection of the "
        "time-varying linearisation along the trajectory (docs/derivatives.md)";
  }
  return mm;
}

Mat expm(const Mat& X) {
  if (X.rows() != X.cols()) throw std::invalid_argument("expm: the matrix is not square");
  if (!X.allFinite()) throw std::invalid_argument("expm: the matrix is not finite");
  const Index n = X.rows();
  if (n == 0) return X;
  // Higham (2005), Algorithm 2.3 with m = 13 throughout: b_j of the [13/13] Padé approximant and
  // θ_13 = 5.371920351148152 (Table 2.3); scaling by 2^-s so that ‖X/2^s‖₁ ≤ θ_13.
  constexpr std::array<double, 14> b = {64764752532480000.0,
                                        32382376266240000.0,
                                        7771770303897600.0,
                                        1187353796428800.0,
                                        129060195264000.0,
                                        10559470521600.0,
                                        670442572800.0,
                                        33522128640.0,
                                        1323241920.0,
                                        40840800.0,
                                        960960.0,
                                        16380.0,
                                        182.0,
                                        1.0};
  constexpr double theta13 = 5.371920351148152;
  const double norm1 = X.cwiseAbs().colwise().sum().maxCoeff();
  // A norm that overflows would make s (log2 of it) undefined and the result garbage (zeros).
  if (!std::isfinite(norm1)) throw std::invalid_argument("expm: the matrix's norm overflows");
  int s = 0;
  if (norm1 > theta13) s = static_cast<int>(std::ceil(std::log2(norm1 / theta13)));
  // The squaring phase multiplies the approximant's rounding by up to 2^s (Higham 2005, §2;
  // [AlMohyHigham2009]): past 32 squarings (‖X‖₁ > 2.3e10)
  // that is 1e-6 and more of the result (a nilpotent X h with h = 1e308 gave zeros for I + X h).
  if (s > 32) {
    char norm[32];
    std::snprintf(norm, sizeof norm, "%.3g", norm1);
    throw std::invalid_argument(std::string("expm: the matrix's norm ") + norm +
                                " needs more than 32 squarings, whose rounding cannot be vouched "
                                "for (a smaller step)");
  }
  const Mat A = X / std::ldexp(1.0, s);
  const Mat I = Mat::Identity(n, n);
  const Mat A2 = A * A, A4 = A2 * A2, A6 = A4 * A2;
  const Mat U = A * (A6 * (b[13] * A6 + b[11] * A4 + b[9] * A2) + b[7] * A6 + b[5] * A4 +
                     b[3] * A2 + b[1] * I);
  const Mat V =
      A6 * (b[12] * A6 + b[10] * A4 + b[8] * A2) + b[6] * A6 + b[4] * A4 + b[2] * A2 + b[0] * I;
  Mat R = (V - U).partialPivLu().solve(V + U);
  for (int i = 0; i < s; ++i) R = R * R;
  if (!R.allFinite()) throw std::invalid_argument("expm: the exponential overflows");
  return R;
}

void discretize_zoh(const Mat& F, const Mat& G, double h, Mat& Fd, Mat& Gd) {
  if (!(std::isfinite(h) && h > 0.0))
    throw std::invalid_argument("discretize_zoh: the step h must be positive and finite");
  const Index n = F.rows(), m = G.cols();
  if (F.cols() != n || G.rows() != n)
    throw std::invalid_argument("discretize_zoh: F must be square and G have F's rows");
  Mat aug = Mat::Zero(n + m, n + m);
  aug.topLeftCorner(n, n) = F * h;
  aug.topRightCorner(n, m) = G * h;
  const Mat E = expm(aug);
  Fd = E.topLeftCorner(n, n);
  Gd = E.topRightCorner(n, m);
}

}  // namespace ukdyn
