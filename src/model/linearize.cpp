// Exact derivatives of the constrained forward dynamics by implicit differentiation of the KKT
// form of Gauss's principle (ukdyn/model/linearize.hpp, docs/derivatives.md).
#include "ukdyn/model/linearize.hpp"

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <Eigen/QR>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "ukdyn/model/parameter_sensitivity.hpp"

namespace ukdyn {

namespace {

std::string sci(double v) {
  std::ostringstream os;
  os.precision(3);
  os << v;
  return os.str();
}

void check_size(const char* what, Index expected, Index got) {
  if (expected != got) {
    throw std::invalid_argument(std::string("linearize: ") + what + " has " + std::to_string(got) +
                                " entries, the system has " + std::to_string(expected));
  }
}

// The independent rows of A under the solve's rank rule (σ_k(A M^{-1/2}) > rank_rel_tol σ_1),
// chosen by a column-pivoted QR of (A L^{-T})ᵀ, M = L Lᵀ (the singular values of A L^{-T} are
// those of A M^{-1/2}); and how far the state is from a change of rank.
struct RowChoice {
  std::vector<Index> kept;
  double sigma_ratio_kept = 1.0;     // σ_r / σ_1
  double sigma_ratio_dropped = 0.0;  // σ_{r+1} / σ_1
};

RowChoice independent_rows(const Mat& Ms, const Mat& A, double rel_tol) {
  RowChoice rc;
  const Index m = A.rows();
  if (m == 0) return rc;
  Eigen::LLT<Mat> llt(Ms);
  if (llt.info() != Eigen::Success)
    throw Error("linearize: the mass matrix is not positive definite");
  // X = A L^{-T}: Xᵀ = L^{-1} Aᵀ.
  const Mat Xt = llt.matrixL().solve(A.transpose());
  Eigen::JacobiSVD<Mat> svd(Xt);
  const Vec& s = svd.singularValues();
  const double top = s.size() > 0 ? s(0) : 0.0;
  Index r = 0;
  while (r < s.size() && top > 0.0 && s(r) > rel_tol * top) ++r;
  if (r > 0) rc.sigma_ratio_kept = s(r - 1) / top;
  if (r < s.size() && top > 0.0) rc.sigma_ratio_dropped = s(r) / top;
  Eigen::ColPivHouseholderQR<Mat> qr(Xt);
  for (Index k = 0; k < r; ++k) rc.kept.push_back(qr.colsPermutation().indices()(k));
  std::sort(rc.kept.begin(), rc.kept.end());
  return rc;
}

void mark(Linearization& lin, const std::string& why) {
  lin.trusted = false;
  lin.message += (lin.message.empty() ? "" : "; ") + why;
}

// Where the derivatives may not be those of the motion: lin.trusted and lin.message
// (docs/derivatives.md, "When ukdyn cannot vouch for them").
void vouch(Linearization& lin, const RowChoice& rc, const UkResult& result,
           const UkSettings& settings, Index m) {
  const Index r = static_cast<Index>(rc.kept.size());
  if (r > 0 && rc.sigma_ratio_kept < 1e2 * settings.rank_rel_tol) {
    mark(lin, "near a singular position: the smallest kept singular value of A M^-1/2 is " +
                  sci(rc.sigma_ratio_kept) + " of the largest, the rank of A may change");
  }
  // Rows dropped as redundant must be so to round-off: a dropped singular value above ~1e4 ε
  // means the rows are nearly, not exactly, dependent (a singular position a step away).
  if (r < m && rc.sigma_ratio_dropped > 1e-12) {
    mark(lin,
         "near a singular position: a dropped row is not redundant to round-off (singular "
         "value " +
             sci(rc.sigma_ratio_dropped) + " of the largest), the rank of A may change");
  }
  if (r != result.rank) {
    mark(lin, "the forward solve kept " + std::to_string(result.rank) + " rows, the derivatives " +
                  std::to_string(r));
  }
  if (result.damping > 0.0 || settings.method == UkMethod::regularized)
    mark(lin,
         "the forward solve was damped (regularized or near a singular position): the "
         "derivatives are those of the exact solution");
  if (!result.consistent) mark(lin, "the constraints are inconsistent at this state");
}

}  // namespace

std::vector<std::string> components_without_derivatives(const System& system) {
  std::vector<std::string> out;
  for (const auto& s : system.subsystems()) {
    if (!s->has_derivatives()) out.push_back("subsystem '" + s->name() + "'");
  }
  const auto& names = system.constraint_row_names();
  const auto& offs = system.constraint_row_offsets();
  for (std::size_t c = 0; c < system.constraints().size(); ++c) {
    if (system.constraints()[c]->has_derivatives()) continue;
    const auto row = static_cast<std::size_t>(offs[c]);
    out.push_back("constraint of row '" + (row < names.size() ? names[row] : std::string("?")) +
                  "'");
  }
  for (const auto& f : system.applied_forces()) {
    if (!f->has_derivatives()) out.push_back("applied force '" + f->name() + "'");
  }
  return out;
}

void state_space(const Linearization& lin, Mat& F, Mat& G) {
  const Index n = lin.dqdd_dq.rows();
  F = Mat::Zero(2 * n, 2 * n);
  F.topRightCorner(n, n).setIdentity();
  F.bottomLeftCorner(n, n) = lin.dqdd_dq;
  F.bottomRightCorner(n, n) = lin.dqdd_dqd;
  G = Mat::Zero(2 * n, n);
  G.bottomRows(n) = lin.dqdd_dtau;
}

namespace {

// The derivatives from the solved columns X = K⁻¹ [rhs along e_j of q | of q̇] (n + r rows: dq̈
// over dμ) and the τ columns, solved here with the same factorisation.
void store_solutions(Linearization& lin, const Eigen::PartialPivLU<Mat>& lu, const Mat& X,
                     const Mat& dforce_all, const Mat& AR, const Vec& mu) {
  const Index n = AR.cols(), r = AR.rows();
  lin.dqdd_dq = X.topLeftCorner(n, n);
  lin.dqdd_dqd = X.topRightCorner(n, n);
  const Mat dQc = dforce_all + AR.transpose() * X.bottomRows(r);  // (dA_R)ᵀ μ + A_Rᵀ dμ
  lin.dQc_dq = dQc.leftCols(n);
  lin.dQc_dqd = dQc.rightCols(n);
  lin.mu = mu;
  lin.dmu_dq = X.bottomLeftCorner(r, n);
  lin.dmu_dqd = X.bottomRightCorner(r, n);
  // τ enters Q alone: M dq̈ − A_Rᵀ dμ = e_j, A_R dq̈ = 0.
  Mat rhs_tau = Mat::Zero(n + r, n);
  rhs_tau.topRows(n).setIdentity();
  const Mat Xt = lu.solve(rhs_tau);
  lin.dqdd_dtau = Xt.topRows(n);
  lin.dQc_dtau = AR.transpose() * Xt.bottomRows(r);
  lin.dmu_dtau = Xt.bottomRows(r);
}

}  // namespace

namespace {

// The KKT system of the kept rows at a state, [M −A_Rᵀ; A_R 0] factorised once, and [q̈; μ]: what
// every column of the derivatives (state directions, parameters) is solved with.
struct Kkt {
  explicit Kkt(const System& system) : d(system) {}
  ForwardData d;
  RowChoice rc;
  Mat AR;
  Eigen::PartialPivLU<Mat> lu;
  Vec mu, lambda;  // μ over the kept rows; λ over all rows (0 on the dropped ones)
};

void build_kkt(const System& system, Kkt& k, Linearization& lin, double t, CVecRef q, CVecRef qd,
               CVecRef tau, const UkSettings& settings) {
  const Index n = system.dof(), m = system.rows();
  if (!(std::isfinite(t) && q.allFinite() && qd.allFinite() && tau.allFinite()))
    throw std::invalid_argument("linearize: t, q, qd and tau must be finite");
  ForwardData& d = k.d;
  forward(system, d, t, q, qd, tau, settings);
  if (!d.result.finite) throw Error("linearize: the forward dynamics is not finite at this state");
  const Mat Ms = solved_mass(system, d);
  k.rc = independent_rows(Ms, d.A, settings.rank_rel_tol);
  const Index r = static_cast<Index>(k.rc.kept.size());
  lin.rank = static_cast<int>(r);
  lin.kept_rows = k.rc.kept;
  vouch(lin, k.rc, d.result, settings, m);

  // The KKT matrix of the kept rows, [M −A_Rᵀ; A_R 0], and [q̈; μ] at the state.
  k.AR.resize(r, n);
  Vec bR(r);
  for (Index i = 0; i < r; ++i) {
    k.AR.row(i) = d.A.row(k.rc.kept[static_cast<std::size_t>(i)]);
    bR(i) = d.b(k.rc.kept[static_cast<std::size_t>(i)]);
  }
  Mat K = Mat::Zero(n + r, n + r);
  K.topLeftCorner(n, n) = d.M;
  K.topRightCorner(n, r) = -k.AR.transpose();
  K.bottomLeftCorner(r, n) = k.AR;
  k.lu.compute(K);
  Vec rhs(n + r);
  rhs.head(n) = d.Q;
  rhs.tail(r) = bR;
  const Vec sol = k.lu.solve(rhs);
  if (!sol.allFinite()) throw Error("linearize: the KKT matrix of the constraints is singular");
  lin.qdd = sol.head(n);
  k.mu = sol.tail(r);
  lin.Qc = k.AR.transpose() * k.mu;
  lin.kkt_agreement = (lin.qdd - d.qdd).cwiseAbs().maxCoeff() / (1.0 + d.qdd.cwiseAbs().maxCoeff());
  if (!(lin.kkt_agreement <= 1e-8)) {
    mark(lin, "the U-K and KKT accelerations differ by " + sci(lin.kkt_agreement));
  }
  k.lambda = Vec::Zero(m);
  for (Index i = 0; i < r; ++i) k.lambda(k.rc.kept[static_cast<std::size_t>(i)]) = k.mu(i);
}

// The state columns (∂/∂q, ∂/∂q̇, ∂/∂τ) of lin from the components' exact tangents.
void state_columns(const System& system, Kkt& k, Linearization& lin, double t, CVecRef q,
                   CVecRef qd) {
  const Index n = system.dof(), m = system.rows(), r = k.AR.rows();
  ForwardData& d = k.d;
  // The directions e_j of q and of q̇: the right-hand sides of the differentiated KKT system, one
  // column each, solved together with the one factorisation. A subsystem's inverse dynamics
  // depends on its own coordinates only (M, C, G are block-diagonal, paper Eq. (10)-(11)): along
  // e_j only the subsystem holding j has a tangent, the others' is zero and is not computed.
  const auto& L = system.layout();
  const auto& subs = system.subsystems();
  const auto& cons = system.constraints();
  const auto& offs = system.constraint_row_offsets();
  Mat rhs_all = Mat::Zero(n + r, 2 * n), dforce_all(n, 2 * n);
  Vec dID(n), dQa(n), dres(m), dforce_c(n);
  std::vector<std::size_t> owner(static_cast<std::size_t>(n), 0);
  for (std::size_t s = 0; s < subs.size(); ++s)
    for (Index i = 0; i < L.size[s]; ++i) owner[static_cast<std::size_t>(L.start[s] + i)] = s;
  Vec dq = Vec::Zero(n), dqd = Vec::Zero(n);
  auto direction = [&](Index col) {
    dID.setZero();
    const Index j = col % n;
    const std::size_t sk = owner[static_cast<std::size_t>(j)];
    const Index s = L.start[sk], nk = L.size[sk];
    if (!subs[sk]->inverse_dynamics_tangent(
            {t, d.subsystem_slot(sk)}, q.segment(s, nk), qd.segment(s, nk), lin.qdd.segment(s, nk),
            dq.segment(s, nk), dqd.segment(s, nk), dID.segment(s, nk)))
      throw Error("linearize: subsystem '" + subs[sk]->name() + "' has no exact derivatives");
    dQa.setZero();
    for (const auto& f : system.applied_forces()) {
      if (!f->add_tangent(t, q, qd, dq, dqd, dQa))
        throw Error("linearize: applied force '" + f->name() + "' has no exact derivatives");
    }
    auto dforce = dforce_all.col(col);
    dforce.setZero();
    dres.setZero();
    for (std::size_t c = 0; c < cons.size(); ++c) {
      const Index rows = cons[c]->rows();
      dforce_c.setZero();
      if (!cons[c]->tangent({t, d.constraint_slots(c)}, q, qd, lin.qdd,
                            k.lambda.segment(offs[c], rows), dq, dqd, dres.segment(offs[c], rows),
                            dforce_c))
        throw Error("linearize: a constraint has no exact derivatives");
      dforce += dforce_c;
    }
    rhs_all.col(col).head(n) = -dID + dQa + dforce;
    for (Index i = 0; i < r; ++i)
      rhs_all(n + i, col) = -dres(k.rc.kept[static_cast<std::size_t>(i)]);
  };
  for (Index j = 0; j < n; ++j) {
    dq(j) = 1.0;
    direction(j);
    dq(j) = 0.0;
    dqd(j) = 1.0;
    direction(n + j);
    dqd(j) = 0.0;
  }
  store_solutions(lin, k.lu, k.lu.solve(rhs_all), dforce_all, k.AR, k.mu);
}

void check_sizes(const System& system, CVecRef q, CVecRef qd, CVecRef tau) {
  const Index n = system.dof();
  check_size("q", n, q.size());
  check_size("qd", n, qd.size());
  check_size("tau", n, tau.size());
}

void require_derivatives(const System& system) {
  if (const auto missing = components_without_derivatives(system); !missing.empty()) {
    std::string list;
    for (const auto& s : missing) list += (list.empty() ? "" : ", ") + s;
    throw Error("linearize: no exact derivatives for " + list +
                " (docs/derivatives.md lists the kinds that have them)");
  }
}

}  // namespace

Linearization linearize(const System& system, double t, CVecRef q, CVecRef qd, CVecRef tau,
                        const UkSettings& settings) {
  check_sizes(system, q, qd, tau);
  require_derivatives(system);
  Linearization lin;
  Kkt k(system);
  build_kkt(system, k, lin, t, q, qd, tau, settings);
  state_columns(system, k, lin, t, q, qd);
  return lin;
}

ParameterLinearization linearize_parameters(const System& system, double t, CVecRef q, CVecRef qd,
                                            CVecRef tau,
                                            const std::vector<ModelParameterDerivative>& dp,
                                            const UkSettings& settings, bool with_state) {
  check_sizes(system, q, qd, tau);
  if (with_state) require_derivatives(system);
  const Index n = system.dof(), m = system.rows();
  for (const auto& p : dp) {
    if (p.dM.rows() != n || p.dM.cols() != n || p.dQ.size() != n || p.dA.rows() != m ||
        p.dA.cols() != n || p.db.size() != m)
      throw std::invalid_argument(
          "linearize_parameters: a parameter's dM, dQ, dA, db do not match the system's sizes");
  }
  ParameterLinearization out;
  Kkt k(system);
  build_kkt(system, k, out.lin, t, q, qd, tau, settings);
  if (with_state) state_columns(system, k, out.lin, t, q, qd);
  // Implicit differentiation of the KKT system in p at fixed (t, q, q̇):
  //   M ∂q̈ − A_Rᵀ ∂μ = ∂Q − ∂M q̈ + (∂A_R)ᵀ μ,   A_R ∂q̈ = ∂b_R − ∂A_R q̈,
  //   ∂Qc = (∂A_R)ᵀ μ + A_Rᵀ ∂μ   (the same factorisation as the state columns).
  const Index r = k.AR.rows(), P = static_cast<Index>(dp.size());
  const Vec& qdd = out.lin.qdd;
  Mat rhs(n + r, P), dforce(n, P);
  for (Index j = 0; j < P; ++j) {
    const auto& p = dp[static_cast<std::size_t>(j)];
    dforce.col(j) = p.dA.transpose() * k.lambda;
    rhs.col(j).head(n) = p.dQ - p.dM * qdd + dforce.col(j);
    const Vec dres = p.dA * qdd - p.db;
    for (Index i = 0; i < r; ++i) rhs(n + i, j) = -dres(k.rc.kept[static_cast<std::size_t>(i)]);
  }
  const Mat X = k.lu.solve(rhs);
  out.dqdd_dp = X.topRows(n);
  out.dmu_dp = X.bottomRows(r);
  out.dQc_dp = dforce + k.AR.transpose() * out.dmu_dp;
  return out;
}

}  // namespace ukdyn
