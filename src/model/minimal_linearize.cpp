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

#include "model/linearize_corrected.hpp"
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

// D = ∂(A_R q̇ + Φ_t)/∂q at fixed q̇ (r × n) at (t, q, v), exact; ld.fwd must hold forward() at
// (t, q, v) (the constraints' slots). For a holonomic row Φ(q, t) = 0 the velocity constraint is
// Φ̇ = Φ_q q̇ + Φ_t = 0 and the acceleration row A q̈ = b has A = Φ_q and
//   b = −(∂(Φ_q q̇)/∂q) q̇ − 2 Φ_tq q̇ − Φ_tt
// (Φ̈ = 0: the right-hand side γ of the acceleration equations, [Nikravesh1988]), quadratic in q̇.
// With the symmetric second derivatives of Φ, ∂b/∂q̇ = −2 (∂(Φ_q q̇)/∂q + Φ_tq) = −2 ∂Φ̇/∂q, so
//   D = ∂Φ̇/∂q = −½ ∂b/∂q̇ = ½ ∂(A q̈ − b)/∂q̇   (A = Φ_q does not depend on q̇):
// column j is half the constraints' exact tangent along e_j of q̇ (constraint_tangent_columns(),
// its columns n .. 2n − 1, at q̈ = 0 and λ = 0), the rheonomic part ∂Φ_t/∂q included. The same
// identity gives linearize_corrected() its ∂Φ̇/∂q. The rows must be position-level
// (require_position_rows()); a velocity-level row has no Φ.
Mat velocity_constraint_jacobian(const System& system, LinearizeData& ld, double t, CVecRef q,
                                 CVecRef v, const std::vector<Index>& kept) {
  const Index n = system.dof(), r = static_cast<Index>(kept.size());
  Mat dres, dforce;
  constraint_tangent_columns(system, ld, t, q, v, Vec::Zero(n), Vec::Zero(system.rows()), dres,
                             dforce);
  Mat D(r, n);
  for (Index k = 0; k < r; ++k)
    D.row(k) = 0.5 * dres.row(kept[static_cast<std::size_t>(k)]).tail(n);
  return D;
}

// Whether a kept row's velocity constraint depends on t at q: Φ_t ≠ 0 (the velocity residual at
// q̇ = 0; exactly 0 for a scleronomic row) or ∂Φ_t/∂q ≠ 0 (D at q̇ = 0). Leaves ld.fwd at
// (t, q, 0). D0: D at q̇ = 0, i.e. ∂Φ_t/∂q.
bool rheonomic_rows(const System& system, LinearizeData& ld, double t, CVecRef q, CVecRef tau,
                    const std::vector<Index>& kept, Mat& D0) {
  const Vec zero = Vec::Zero(system.dof());
  forward(system, ld.fwd, t, q, zero, tau);
  D0 = velocity_constraint_jacobian(system, ld, t, q, zero, kept);
  Vec phit(system.rows());
  velocity_residuals(system, ld.fwd, t, q, zero, phit);
  bool moving = !D0.isZero(0.0);
  for (Index row : kept) moving = moving || phit(row) != 0.0;
  return moving;
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
  LinearizeData ld(system);
  ForwardData& d = ld.fwd;
  forward(system, d, t, q, qd, tau);
  const Index r = static_cast<Index>(lin.kept_rows.size());
  mm.AR.resize(r, n);
  for (Index k = 0; k < r; ++k) mm.AR.row(k) = d.A.row(lin.kept_rows[static_cast<std::size_t>(k)]);
  require_position_rows(system, d, t, q, mm.AR, lin.kept_rows);
  mm.N = null_space_basis(mm.AR);
  const Index k = mm.N.cols();
  mm.null_residual = r > 0 && k > 0 ? (mm.AR * mm.N).cwiseAbs().maxCoeff() : 0.0;
  mm.ortho_residual =
      k > 0 ? (mm.N.transpose() * mm.N - Mat::Identity(k, k)).cwiseAbs().maxCoeff() : 0.0;
  mm.at_rest = qd.isZero(0.0);
  mm.D = Mat::Zero(r, n);
  if (r > 0) mm.rheonomic = rheonomic_rows(system, ld, t, q, tau, lin.kept_rows, mm.D);
  if (r > 0 && !mm.at_rest) {
    forward(system, d, t, q, qd, tau);  // the slots at the state, for the tangents
    mm.D = velocity_constraint_jacobian(system, ld, t, q, qd, lin.kept_rows);
  }
  forward(system, d, t, q, qd, tau);  // leave the slots at the state
  state_space(lin, mm.F, mm.G);
  // T = [[N, 0], [−A_R⁺ D N, N]], A_R⁺ = A_Rᵀ (A_R A_Rᵀ)⁻¹ by the normal equations (the kept rows
  // are independent; their Gram matrix squares cond(A_R), which the rank rule keeps moderate).
  mm.T = Mat::Zero(2 * n, 2 * k);
  // k = 0 (the rows fix every coordinate): T and P are empty, and a block at row n of an empty
  // matrix would offset its null data pointer (undefined behaviour the sanitizer reports).
  if (k > 0) {
    mm.T.topLeftCorner(n, k) = mm.N;
    mm.T.bottomRightCorner(n, k) = mm.N;
  }
  if (k > 0 && r > 0 && !mm.D.isZero(0.0)) {
    const Mat ARt = mm.AR.transpose();
    const Mat gram = mm.AR * ARt;
    mm.T.bottomLeftCorner(n, k) = -ARt * gram.partialPivLu().solve(mm.D * mm.N);
  }
  Mat P = Mat::Zero(2 * k, 2 * n);
  if (k > 0) {
    P.topLeftCorner(k, n) = mm.N.transpose();
    P.bottomRightCorner(k, n) = mm.N.transpose();
  }
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
    mm.note += std::string(mm.note.empty() ? "" : "; ") +
               "rheonomic rows: the manifold moves with t and N is frozen at this t (D holds the "
               "exact d(Phi_t)/dq)";
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
