// Derivatives of a control scenario's closed loop (ukdyn/run/closed_loop_derivatives.hpp,
// docs/derivatives.md, "Controlled runs").
#include "ukdyn/run/closed_loop_derivatives.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <memory>
#include <optional>

#include "run/law_jacobian.hpp"
#include "run/richardson.hpp"

namespace ukdyn {

namespace {

constexpr std::array<double, 4> kProbeOffsets = {1.0, -1.0, 0.5, -0.5};  // × h

// One evaluation of the loop: τ, and what tells on which side of a kink the law is.
struct Probe {
  Vec tau, u_raw;
  double mu_norm = 0.0;  // the robust law's ‖μ‖ = ρ ‖β‖ (0 for the other laws)
};

void probe(ControlRun& run, double t, CVecRef q, CVecRef qd, Probe& p) {
  run.loop->evaluate(t, q, qd);
  p.tau.resize(run.plant->dof());
  run.loop->plant_tau(p.tau);
  p.u_raw = run.loop->u_raw;
  const ServoLawSettings& s = run.law->settings();
  p.mu_norm = 0.0;
  if (s.kind == ControlLawKind::robust && s.rho > 0.0) {
    Vec e, ed;
    servo_errors(run.model, t, q, qd, e, ed);
    p.mu_norm = s.rho * (ed + s.lambda * e).norm();
  }
}

// The causes of a kink between the probes: a side of ‖μ‖ = ε or of an actuator's limit that
// changes among them.
void find_kinks(const ControlRun& run, const std::array<Probe, 5>& ps,
                std::vector<std::string>& kinks) {
  const ServoLawSettings& s = run.law->settings();
  const Actuators& act = run.model.actuators;
  auto changes = [&](auto side) {
    return std::any_of(ps.begin(), ps.end(),
                       [&](const Probe& p) { return side(p) != side(ps[0]); });
  };
  if (s.kind == ControlLawKind::robust && s.rho > 0.0 &&
      changes([&](const Probe& p) { return p.mu_norm > s.epsilon; })) {
    add_kink(kinks, boundary_layer_kink(s.epsilon));
  }
  for (Index j = 0; j < act.count(); ++j) {
    const double lim = act.limit(j);
    if (!std::isfinite(lim)) continue;
    if (changes([&](const Probe& p) { return std::abs(p.u_raw(j)) > lim; }))
      add_kink(kinks, actuator_kink(act.names[static_cast<std::size_t>(j)], lim));
  }
}

// ∂τ/∂y along the direction (dq, dq̇) with step h: probes at h, −h, h/2, −h/2 and the centre
// (ps[0], already evaluated), Richardson's extrapolation of the two central differences.
Vec directional(ControlRun& run, double t, CVecRef q, CVecRef qd, CVecRef dq, CVecRef dqd, double h,
                std::array<Probe, 5>& ps, std::vector<std::string>& kinks) {
  for (std::size_t k = 0; k < 4; ++k) {
    const Vec qk = q + kProbeOffsets[k] * h * dq, qdk = qd + kProbeOffsets[k] * h * dqd;
    probe(run, t, qk, qdk, ps[k + 1]);
  }
  find_kinks(run, ps, kinks);
  return richardson(ps[1].tau, ps[2].tau, ps[3].tau, ps[4].tau, h);
}

// ∂τ/∂(q, q̇) by differences (ps[0]: the centre, evaluated).
void jacobian_by_differences(ControlRun& run, double t, CVecRef q, CVecRef qd,
                             std::array<Probe, 5>& ps, LawDerivatives& out) {
  const Index n = run.plant->dof();
  out.dtau_dq.resize(n, n);
  out.dtau_dqd.resize(n, n);
  const Vec zero = Vec::Zero(n);
  for (Index j = 0; j < n; ++j) {
    const Vec e = Vec::Unit(n, j);
    out.dtau_dq.col(j) = directional(run, t, q, qd, e, zero, law_step(q(j)), ps, out.kinks);
    out.dtau_dqd.col(j) = directional(run, t, q, qd, zero, e, law_step(qd(j)), ps, out.kinks);
  }
}

// ∂τ/∂t at fixed (q, q̇) by Richardson differences of the loop in t (ps[0]: the centre).
Vec dtau_dt_by_differences(ControlRun& run, double t, CVecRef q, CVecRef qd,
                           std::array<Probe, 5>& ps, std::vector<std::string>& kinks) {
  const double ht = law_step(t);
  for (std::size_t k = 0; k < 4; ++k) probe(run, t + kProbeOffsets[k] * ht, q, qd, ps[k + 1]);
  find_kinks(run, ps, kinks);
  return richardson(ps[1].tau, ps[2].tau, ps[3].tau, ps[4].tau, ht);
}

// τ, u, ∂τ/∂(q, q̇) and ∂τ/∂t (exact unless `differences` or the exact path declines).
LawDerivatives derivatives(ControlRun& run, double t, CVecRef q, CVecRef qd, bool differences) {
  LawDerivatives out;
  std::array<Probe, 5> ps;
  probe(run, t, q, qd, ps[0]);
  out.tau = ps[0].tau;
  out.u = run.loop->u;
  std::string why_not = "asked for";
  std::optional<LinearizeData> ld;
  if (!differences) ld.emplace(*run.model.system);
  LawTimeDerivative dt;
  dt.why_not = why_not;
  if (ld && exact_law_jacobian(run, *ld, t, q, qd, ps[0].u_raw, out.dtau_dq, out.dtau_dqd,
                               out.kinks, why_not, &dt)) {
    out.method = "exact";
  } else {
    jacobian_by_differences(run, t, q, qd, ps, out);
    out.method = "differences: " + why_not;
    if (dt.why_not.empty()) dt.why_not = why_not;
  }
  if (dt.exact) {
    out.dtau_dt = dt.dtau_dt;
    out.dtau_dt_method = "exact";
  } else {
    out.dtau_dt = dtau_dt_by_differences(run, t, q, qd, ps, out.kinks);
    out.dtau_dt_method = "differences: " + dt.why_not;
  }
  run.loop->evaluate(t, q, qd);  // the loop left at the state itself
  return out;
}

}  // namespace

double law_step(double x) { return 1e-6 * std::max(1.0, std::abs(x)); }

LawDerivatives law_derivatives(ControlRun& run, double t, CVecRef q, CVecRef qd) {
  return derivatives(run, t, q, qd, false);
}

LawDerivatives law_derivatives_by_differences(ControlRun& run, double t, CVecRef q, CVecRef qd) {
  return derivatives(run, t, q, qd, true);
}

Vec law_direction(ControlRun& run, double t, CVecRef q, CVecRef qd, CVecRef dq, CVecRef dqd,
                  std::vector<std::string>& kinks) {
  const double size = std::max(dq.cwiseAbs().maxCoeff(), dqd.cwiseAbs().maxCoeff());
  if (!(size > 0.0)) return Vec::Zero(run.plant->dof());
  const double scale = std::max(q.cwiseAbs().maxCoeff(), qd.cwiseAbs().maxCoeff());
  std::array<Probe, 5> ps;
  probe(run, t, q, qd, ps[0]);
  // A step of 1e-6 max(1, |x|∞) in x along the direction, whatever the direction's size.
  const double h = law_step(scale) / size;
  return directional(run, t, q, qd, dq, dqd, h, ps, kinks);
}

bool law_jacobian(const ControlRun& run, LawJacobianWorkspace& ws, double t, CVecRef q, CVecRef qd,
                  Mat& dtau_dq, Mat& dtau_dqd) {
  run.loop->evaluate(t, q, qd);
  ws.kinks.clear();
  ws.why_not.clear();
  if (!exact_law_jacobian(run, ws.ld, t, q, qd, run.loop->u_raw, dtau_dq, dtau_dqd, ws.kinks,
                          ws.why_not))
    return false;
  if (ws.kinks.empty()) return true;
  ws.why_not = "a kink of the law: " + ws.kinks.front();
  return false;
}

ForceJacobian law_force_jacobian(const ControlRun& run) {
  auto ws = std::make_shared<LawJacobianWorkspace>(run);
  return [&run, ws](double t, CVecRef q, CVecRef qd, Mat& dtau_dq, Mat& dtau_dqd) {
    if (!law_jacobian(run, *ws, t, q, qd, dtau_dq, dtau_dqd))
      throw Error(fmt::format("the law's d tau/d(q, qd) at t = {:g}: {}", t, ws->why_not));
  };
}

ClosedLoopLinearization closed_loop_linearization(const Scenario& sc, double t, CVecRef q,
                                                  CVecRef qd) {
  const std::unique_ptr<ControlRun> run = make_control_run(sc);
  if (!run)
    throw Error(
        "a closed-loop linearisation needs a scenario with a control: section "
        "(docs/control.md)");
  ClosedLoopLinearization out;
  out.law = law_derivatives(*run, t, q, qd);
  out.lin = linearize(*run->plant, t, q, qd, out.law.tau, sc.sim.uk);
  Linearization& lin = out.lin;
  lin.dqdd_dq += lin.dqdd_dtau * out.law.dtau_dq;
  lin.dqdd_dqd += lin.dqdd_dtau * out.law.dtau_dqd;
  lin.dQc_dq += lin.dQc_dtau * out.law.dtau_dq;
  lin.dQc_dqd += lin.dQc_dtau * out.law.dtau_dqd;
  // d/dt of q̈(t, q, q̇, τ(t, q, q̇)) = ∂q̈/∂t + ∂q̈/∂τ ∂τ/∂t (the law's ∂τ/∂t: dtau_dt_method).
  if (lin.dqdd_dt.size() > 0 && out.law.dtau_dt.size() == lin.dqdd_dt.size()) {
    lin.dqdd_dt += lin.dqdd_dtau * out.law.dtau_dt;
    lin.dQc_dt += lin.dQc_dtau * out.law.dtau_dt;
    lin.dmu_dt += lin.dmu_dtau * out.law.dtau_dt;
  }
  return out;
}

}  // namespace ukdyn
