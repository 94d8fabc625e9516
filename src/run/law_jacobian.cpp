// The exact derivatives of the built-in servo laws (run/law_jacobian.hpp, docs/derivatives.md,
// "Controlled runs").
//
// ServoLaw::control() (ukdyn/simulate/control.hpp) computes u = G⁺ P Qc' with
//   Qc' the model's U-K constraint force for the right-hand side b + v(Φ, Φ̇),
//   P = I − A_p⁺ A_p the projector onto null(A_p) (A_p: the model's physical rows), G = P B
// (solve_actuation(), core/force_split.hpp), and the loop applies B sat(u). Along a direction:
//   dQc' from the KKT system with b + v (linearize_corrected()),
//   dP z = −A_p⁺ dA_p (P z) − P dA_pᵀ (A_p⁺ᵀ z) ([GolubPereyra1973], the derivative of the
//     orthogonal projector A_p⁺A_p of constant rank), dA_p w and dA_pᵀ y from the constraints'
//     tangents (d(A q̈ − b) is affine in q̈: dA w = d(A w − b) − d(A·0 − b)),
//   dG⁺ y = −G⁺ dG G⁺ y + G⁺G⁺ᵀ dGᵀ (I − G G⁺) y + (I − G⁺G) dGᵀ G⁺ᵀ G⁺ y ([GolubPereyra1973],
//     Theorem 4.3), dG = dP B, so that with u = G⁺ P Qc':
//   du = G⁺ dP (Qc' − B u) + G⁺G⁺ᵀ Bᵀ dP P (Qc' − B u) + (I − G⁺G) Bᵀ dP G⁺ᵀ u + G⁺ P dQc'.
#include "run/law_jacobian.hpp"

#include <fmt/format.h>

#include <Eigen/QR>
#include <algorithm>
#include <cmath>

#include "model/linearize_corrected.hpp"
#include "ukdyn/run/closed_loop_derivatives.hpp"
#include "ukdyn/run/run.hpp"

namespace ukdyn {

namespace {

constexpr double kRankTol = 1e-10;   // solve_actuation()'s rank threshold
constexpr double kAgreement = 1e-8;  // KKT against the law's U-K solve (as linearize())
constexpr double kKinkTol = 1e-6;    // a state this close (relative) to a kink is "at" it

// v(Φ, Φ̇) of ServoLaw::control() over every row (0 on the physical rows) and its Jacobians.
//   stabilized: v = −2ω Φ̇ − ω² Φ;
//   robust: v = −λ Φ̇ − κ β − ρ² γ β, β = Φ̇ + λ Φ, ∂(−ρ²γβ)/∂β = −(ρ²/ε) I inside the
//   boundary layer (ρ‖β‖ ≤ ε), −(ρ/‖β‖)(I − β̂β̂ᵀ) outside (−ρ β/‖β‖).
RhsCorrection law_correction(const ControlModel& md, const ServoLawSettings& s, const Vec& phi,
                             const Vec& phid, std::vector<std::string>& kinks) {
  const Index m = phi.size();
  RhsCorrection c{Vec::Zero(m), Mat::Zero(m, m), Mat::Zero(m, m)};
  if (s.kind == ControlLawKind::feedforward) return c;
  std::vector<Index> rows;
  for (Index i = 0; i < m; ++i)
    if (md.row_servo[static_cast<std::size_t>(i)]) rows.push_back(i);
  const auto k = static_cast<Index>(rows.size());
  Vec e(k), ed(k);
  for (Index a = 0; a < k; ++a) {
    e(a) = phi(rows[static_cast<std::size_t>(a)]);
    ed(a) = phid(rows[static_cast<std::size_t>(a)]);
  }
  Vec v(k);
  Mat dv_de(k, k), dv_ded(k, k);
  if (s.kind == ControlLawKind::stabilized) {
    v = -2.0 * s.omega * ed - s.omega * s.omega * e;
    dv_ded = -2.0 * s.omega * Mat::Identity(k, k);
    dv_de = -s.omega * s.omega * Mat::Identity(k, k);
  } else {
    const Vec beta = ed + s.lambda * e;
    const double mu_norm = std::sqrt(s.rho * s.rho * beta.squaredNorm());
    const double gamma = mu_norm > s.epsilon ? 1.0 / mu_norm : 1.0 / s.epsilon;
    Mat dv_dbeta = -s.kappa * Mat::Identity(k, k);
    if (mu_norm > s.epsilon) {
      const Vec bh = beta / beta.norm();
      dv_dbeta -= (std::abs(s.rho) / beta.norm()) * (Mat::Identity(k, k) - bh * bh.transpose());
    } else {
      dv_dbeta -= (s.rho * s.rho / s.epsilon) * Mat::Identity(k, k);
    }
    if (s.rho != 0.0 && std::abs(mu_norm - s.epsilon) <= kKinkTol * s.epsilon)
      add_kink(kinks, boundary_layer_kink(s.epsilon));
    v = -s.lambda * ed - s.kappa * beta - s.rho * s.rho * gamma * beta;
    dv_ded = -s.lambda * Mat::Identity(k, k) + dv_dbeta;
    dv_de = s.lambda * dv_dbeta;
  }
  for (Index a = 0; a < k; ++a) {
    const Index i = rows[static_cast<std::size_t>(a)];
    c.v(i) = v(a);
    for (Index b = 0; b < k; ++b) {
      c.dv_dphi(i, rows[static_cast<std::size_t>(b)]) = dv_de(a, b);
      c.dv_dphid(i, rows[static_cast<std::size_t>(b)]) = dv_ded(a, b);
    }
  }
  return c;
}

// What dP z needs: the state, the physical rows, A_p⁺ and P, the constraints' d(A·0 − b).
struct ProjectorTangent {
  const System& sys;
  LinearizeData& ld;
  double t;
  CVecRef q, qd;
  std::vector<Index> phys;  // the physical rows of A
  Mat Ap_pinv, P;           // n × m_p, n × n
  const Mat& dres0;         // d(A·0 − b) along every direction of (q, q̇)
  bool time = false;        // a column 2n along t too
  Vec dres0_t;              // ∂(A·0 − b)/∂t (time)
  Mat dforce;

  // dP z along every direction (n × 2n; n × (2n + 1) with `time`).
  Mat operator()(const Vec& z) {
    const Index n = sys.dof(), mp = static_cast<Index>(phys.size());
    Vec lambda = Vec::Zero(sys.rows());
    const Vec y = Ap_pinv.transpose() * z;
    for (Index a = 0; a < mp; ++a) lambda(phys[static_cast<std::size_t>(a)]) = y(a);
    const Vec w = P * z;
    Mat dres;
    constraint_tangent_columns(sys, ld, t, q, qd, w, lambda, dres, dforce);
    Vec dres_t, dforce_t;
    if (time && !constraint_time_tangent(sys, ld, t, q, qd, w, lambda, dres_t, dforce_t))
      throw Error("a constraint of the law's model has no exact d/dt");
    const Index cols = 2 * n + (time ? 1 : 0);
    Mat dAw(mp, cols);  // dA_p w = d(A_p w − b_p) − d(A_p·0 − b_p)
    for (Index a = 0; a < mp; ++a) {
      const Index i = phys[static_cast<std::size_t>(a)];
      dAw.row(a).head(2 * n) = dres.row(i) - dres0.row(i);
      if (time) dAw(a, 2 * n) = dres_t(i) - dres0_t(i);
    }
    Mat dF(n, cols);
    dF.leftCols(2 * n) = dforce;
    if (time) dF.col(2 * n) = dforce_t;
    return -(Ap_pinv * dAw) - P * dF;
  }
};

// ∂Qc'/∂t at fixed (q, q̇) into ld.lin.dQc_dt: the corrected KKT system's time column with
// ∂v/∂t = ∂v/∂Φ Φ_t + ∂v/∂Φ̇ Φ̇_t, Φ_t = Φ̇ − A q̇ and, for the (holonomic) servo rows,
// Φ̇_t = −b + ½ (∂b/∂q̇) q̇ (b = −(∂Φ̇/∂q) q̇ − ∂Φ̇/∂t with ∂Φ̇/∂q = −½ ∂b/∂q̇, as
// linearize_corrected()); dres0: d(A·0 − b) along (q, q̇), its q̇ half −∂b/∂q̇. False with
// why_not when a component of the model has no exact ∂/∂t.
bool corrected_time_column(const System& sys, LinearizeData& ld, double t, CVecRef q, CVecRef qd,
                           const Vec& phid, const RhsCorrection& corr, const Mat& dres0,
                           std::string& why_not) {
  const Index n = sys.dof();
  const Vec phi_t = phid - ld.fwd.A * qd;
  const Vec phid_t = -ld.fwd.b - 0.5 * (dres0.rightCols(n) * qd);
  const Vec dv_dt = corr.dv_dphi * phi_t + corr.dv_dphid * phid_t;
  linearize_corrected_time(sys, ld, t, q, qd, dv_dt);
  if (ld.lin.dQc_dt.size() == n) return true;
  why_not = "the law's model: " + ld.lin.time_message;
  return false;
}

// du (k × 2n; with `time` k × (2n + 1), ∂u/∂t last, ld.lin.dQc_dt computed) of u = G⁺ P Qc' (the
// header's formula, t one more direction), or false with why_not. dres0: d(A·0 − b) along (q, q̇).
bool actuation_jacobian(const ControlModel& md, LinearizeData& ld, double t, CVecRef q, CVecRef qd,
                        CVecRef u_raw, const Mat& dres0, bool time, Mat& du, std::string& why_not) {
  const System& sys = *md.system;
  const Index n = sys.dof(), k = md.actuators.count(), cols = 2 * n + (time ? 1 : 0);
  const Mat& B = md.actuators.B;
  ProjectorTangent dP{sys,   ld,   t,  q, qd, {}, Mat::Zero(n, 0), Mat::Identity(n, n),
                      dres0, time, {}, {}};
  for (Index i = 0; i < sys.rows(); ++i)
    if (!md.row_servo[static_cast<std::size_t>(i)]) dP.phys.push_back(i);
  const Mat Ap = select_rows(ld.fwd.A, md.row_servo, false);
  if (Ap.rows() > 0) {
    Eigen::CompleteOrthogonalDecomposition<Mat> codp;
    codp.setThreshold(kRankTol);
    codp.compute(Ap.transpose());
    const Mat ApT_pinv = codp.pseudoInverse();  // (A_pᵀ)⁺ = (A_p⁺)ᵀ
    dP.Ap_pinv = ApT_pinv.transpose();
    dP.P -= Ap.transpose() * ApT_pinv;
  }
  const Mat G = dP.P * B;
  du.setZero(k, cols);
  if (k == 0 || G.norm() <= kRankTol * B.norm()) return true;  // u = 0 (solve_actuation())
  Eigen::CompleteOrthogonalDecomposition<Mat> cod;
  cod.setThreshold(kRankTol);
  cod.compute(G);
  const Mat Gp = cod.pseudoInverse();
  const Vec& Qc = ld.lin.Qc;
  const Vec u = Gp * (dP.P * Qc);
  const double agree = (u - u_raw).cwiseAbs().maxCoeff() / (1.0 + u_raw.cwiseAbs().maxCoeff());
  if (!(agree <= kAgreement)) {
    why_not = fmt::format("the KKT solve and the law's U-K solve give u {:.3g} apart", agree);
    return false;
  }
  Vec dforce0_t;
  if (time && !constraint_time_tangent(sys, ld, t, q, qd, Vec::Zero(n), Vec::Zero(sys.rows()),
                                       dP.dres0_t, dforce0_t))
    throw Error("a constraint of the law's model has no exact d/dt");
  const Vec za = Qc - B * u;
  const Vec zc = Gp.transpose() * u;
  Mat dQc(n, cols);
  dQc.leftCols(2 * n) << ld.lin.dQc_dq, ld.lin.dQc_dqd;
  if (time) dQc.col(2 * n) = ld.lin.dQc_dt;
  du = Gp * (dP(za) + dP.P * dQc) + Gp * (Gp.transpose() * (B.transpose() * dP(dP.P * za))) +
       (Mat::Identity(k, k) - Gp * G) * (B.transpose() * dP(zc));
  return true;
}

// True when the loop's disturbance is unset or gives bitwise the same τ_d at t − h, t and t + h
// (h = 1e-3 max(1, |t|)): a constant τ_d, as make_control_run() builds it.
bool disturbance_constant_near(const ClosedLoop& loop, double t) {
  if (!loop.disturbance) return true;
  const Index n = loop.tau_plant.size();
  const double h = 1e-3 * std::max(1.0, std::abs(t));
  Vec d0 = Vec::Zero(n), d = Vec::Zero(n);
  loop.disturbance(t, d0);
  for (const double s : {-h, h}) {
    loop.disturbance(t + s, d);
    if (d != d0) return false;
  }
  return true;
}

}  // namespace

void add_kink(std::vector<std::string>& kinks, const std::string& kink) {
  if (std::find(kinks.begin(), kinks.end(), kink) == kinks.end()) kinks.push_back(kink);
}

std::string boundary_layer_kink(double epsilon) {
  return fmt::format("robust law: the boundary layer |mu| = epsilon = {:g}", epsilon);
}

std::string actuator_kink(const std::string& name, double limit) {
  return fmt::format("actuator '{}' at its limit {:g}", name, limit);
}

std::string law_jacobian_gap(const ControlRun& run) {
  // A user's law in the loop (run_scenario_in_memory()'s MemoryRunOptions::law): not run.law.
  if (run.law == nullptr || &run.loop->law != static_cast<const ControlLaw*>(run.law.get()))
    return "the loop's law is a user's (its d tau/d(q, qd) is not known)";
  const System& sys = *run.model.system;
  if (const auto missing = components_without_derivatives(sys); !missing.empty())
    return "the law's model has no exact derivatives for " + missing.front();
  // dv's ∂Φ̇/∂q = −½ ∂b/∂q̇ (linearize_corrected) holds for position-level rows only: a servo row
  // that is velocity-level (nonholonomic) takes the differences.
  const std::vector<bool> vel = velocity_level_rows(sys);
  for (std::size_t i = 0; i < vel.size(); ++i) {
    if (vel[i] && run.model.row_servo[i]) {
      return "servo row '" + sys.constraint_row_names()[i] +
             "' is velocity-level (nonholonomic): its exact correction term is not derived";
    }
  }
  return {};
}

bool exact_law_jacobian(const ControlRun& run, LinearizeData& ld, double t, CVecRef q, CVecRef qd,
                        CVecRef u_raw, Mat& dtau_dq, Mat& dtau_dqd, std::vector<std::string>& kinks,
                        std::string& why_not, LawTimeDerivative* dt) {
  const ControlModel& md = run.model;
  const System& sys = *md.system;
  why_not = law_jacobian_gap(run);
  if (!why_not.empty()) return false;
  const Index n = sys.dof(), m = sys.rows();
  Vec phi(m), phid(m);
  position_residuals(sys, t, q, phi);
  velocity_residuals(sys, t, q, qd, phid);
  std::vector<std::string> found;
  const RhsCorrection corr = law_correction(md, run.law->settings(), phi, phid, found);
  Mat du, dres0, dforce0;
  bool time = false;
  try {
    linearize_corrected(sys, ld, t, q, qd, md.tau, corr, md.uk);
    if (!ld.lin.trusted) {
      why_not = "the law's model: " + ld.lin.message;
      return false;
    }
    constraint_tangent_columns(sys, ld, t, q, qd, Vec::Zero(n), Vec::Zero(m), dres0, dforce0);
    if (dt != nullptr)
      time = corrected_time_column(sys, ld, t, q, qd, phid, corr, dres0, dt->why_not);
    if (!actuation_jacobian(md, ld, t, q, qd, u_raw, dres0, time, du, why_not)) return false;
  } catch (const Error& e) {
    why_not = e.what();
    return false;
  }
  // sat(u): slope 1 inside the limit, 0 beyond it.
  const Actuators& act = md.actuators;
  for (Index j = 0; j < act.count(); ++j) {
    const double lim = act.limit(j);
    if (!std::isfinite(lim)) continue;
    if (std::abs(u_raw(j)) > lim) du.row(j).setZero();
    if (std::abs(std::abs(u_raw(j)) - lim) <= kKinkTol * std::max(1.0, lim))
      add_kink(found, actuator_kink(act.names[static_cast<std::size_t>(j)], lim));
  }
  const Mat dtau = act.B * du;
  dtau_dq = dtau.leftCols(n);
  dtau_dqd = dtau.middleCols(n, n);
  // τ_plant and the disturbance τ_d of make_control_run() are constant: ∂τ/∂t = B ∂sat(u)/∂t.
  // A loop built by hand may carry a τ_d(t): probed at t ± h, a τ_d that moves there has no
  // exact ∂/∂t here, and the time column falls back to differences, saying why.
  if (time && !disturbance_constant_near(*run.loop, t)) {
    time = false;
    if (dt != nullptr) dt->why_not = "the loop's disturbance tau_d(t) depends on t";
  }
  if (dt != nullptr) dt->exact = time;
  if (time) dt->dtau_dt = dtau.col(2 * n);
  for (const auto& f : found) add_kink(kinks, f);
  return true;
}

}  // namespace ukdyn
