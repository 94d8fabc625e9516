#include "ukdyn/simulate/control.hpp"

#include <Eigen/QR>
#include <algorithm>
#include <cmath>
#include <utility>

#include "model/solve_stages.hpp"
#include "ukdyn/core/types.hpp"

namespace ukdyn {

std::string to_string(ControlLawKind kind) {
  switch (kind) {
    case ControlLawKind::feedforward:
      return "feedforward";
    case ControlLawKind::stabilized:
      return "stabilized";
    case ControlLawKind::robust:
      return "robust";
  }
  return "?";
}

std::vector<bool> servo_row_flags(const System& system, const std::vector<ConstraintRole>& roles) {
  std::vector<bool> flags(static_cast<std::size_t>(system.rows()), false);
  const auto& offs = system.constraint_row_offsets();
  for (std::size_t c = 0; c < system.constraints().size(); ++c) {
    const bool servo = c < roles.size() && roles[c] == ConstraintRole::servo;
    for (Index r = 0; r < system.constraints()[c]->rows(); ++r)
      flags[static_cast<std::size_t>(offs[c] + r)] = servo;
  }
  return flags;
}

std::shared_ptr<System> physical_system(const System& system,
                                        const std::vector<ConstraintRole>& roles) {
  auto out = std::make_shared<System>();
  for (const auto& s : system.subsystems()) out->add_subsystem(s);
  for (std::size_t k = 0; k < system.subsystems().size(); ++k)  // reflected rotor inertias
    if (system.added_mass(k).size() != 0) out->add_block_inertia(k, system.added_mass(k));
  for (std::size_t c = 0; c < system.constraints().size(); ++c) {
    if (c < roles.size() && roles[c] == ConstraintRole::servo) continue;
    out->add_constraint(system.constraints()[c]);
  }
  for (const auto& f : system.applied_forces()) out->add_applied_force(f);
  return out;
}

Actuation actuation_for(const ControlModel& model, const ForwardData& d) {
  const Mat Ap = select_rows(d.A, model.row_servo, false);
  return solve_actuation(model.actuators.B, Ap, d.Qc);
}

ActuationWorkspace actuation_workspace(const ControlModel& model) {
  Index mp = 0;
  for (bool s : model.row_servo) mp += s ? 0 : 1;
  return ActuationWorkspace(model.system->dof(), model.actuators.count(), mp);
}

void actuation_for(const ControlModel& model, const ForwardData& d, ActuationWorkspace& ws) {
  // The physical rows into the workspace (select_rows() without its allocation).
  Index r = 0;
  for (Index i = 0; i < d.A.rows(); ++i)
    if (!model.row_servo[static_cast<std::size_t>(i)]) ws.Ap.row(r++) = d.A.row(i);
  solve_actuation(model.actuators.B, d.Qc, ws);
}

void servo_errors(const ControlModel& model, double t, CVecRef q, CVecRef qd, Vec& e, Vec& ed) {
  const System& sys = *model.system;
  Vec phi(sys.rows()), phid(sys.rows());
  position_residuals(sys, t, q, phi);
  velocity_residuals(sys, t, q, qd, phid);
  Index k = 0;
  for (bool s : model.row_servo) k += s ? 1 : 0;
  e.resize(k);
  ed.resize(k);
  k = 0;
  for (Index i = 0; i < sys.rows(); ++i) {
    if (!model.row_servo[static_cast<std::size_t>(i)]) continue;
    e(k) = phi(i);
    ed(k++) = phid(i);
  }
}

ServoLaw::ServoLaw(const ControlModel& model, ServoLawSettings settings)
    : s_(settings),
      work_(*model.system),
      phi_(model.system->rows()),
      phid_(model.system->rows()),
      b_(model.system->rows()),
      act_(actuation_workspace(model)) {}

double ServoLaw::servo_uncertainty(const ControlModel& model, CVecRef qdd) const {
  // ë = A_s q̈ − b_s on any trajectory (b_s: the servo rows' U-K right-hand side at the state), and
  // the law asked for ë = v (b_ = b + v), so δ = A_s q̈ − b_ (docs/control.md).
  double s2 = 0.0;
  for (Index i = 0; i < work_.A.rows(); ++i) {
    if (!model.row_servo[static_cast<std::size_t>(i)]) continue;
    const double delta = work_.A.row(i).dot(qdd) - b_(i);
    s2 += delta * delta;
  }
  return std::sqrt(s2);
}

void ServoLaw::control(const ControlModel& model, double t, CVecRef q, CVecRef qd,
                       const ForwardData& md, VecRef u) {
  const System& sys = *model.system;
  const Index m = sys.rows();
  b_ = md.b;
  if (s_.kind != ControlLawKind::feedforward) {
    position_residuals(sys, work_, t, q, phi_);
    velocity_residuals(sys, work_, t, q, qd, phid_);
    double mu_norm2 = 0.0;
    if (s_.kind == ControlLawKind::robust) {
      for (Index i = 0; i < m; ++i) {
        if (!model.row_servo[static_cast<std::size_t>(i)]) continue;
        const double beta = phid_(i) + s_.lambda * phi_(i);
        mu_norm2 += s_.rho * s_.rho * beta * beta;
      }
    }
    // γ of [Chen1998]'s smoothed robust term: 1/‖μ‖ outside the boundary layer ε, 1/ε inside.
    const double mu_norm = std::sqrt(mu_norm2);
    const double gamma = mu_norm > s_.epsilon ? 1.0 / mu_norm : 1.0 / s_.epsilon;
    for (Index i = 0; i < m; ++i) {
      if (!model.row_servo[static_cast<std::size_t>(i)]) continue;
      const double e = phi_(i), ed = phid_(i);
      double v = 0.0;
      if (s_.kind == ControlLawKind::stabilized) {
        v = -2.0 * s_.omega * ed - s_.omega * s_.omega * e;  // ë + 2ωė + ω²e = 0 [Udwadia2003]
      } else {
        const double beta = ed + s_.lambda * e;  // β = ė + λe: the first-order servo constraint
        const double mu = s_.rho * beta;         // μ = ρ β
        v = -s_.lambda * ed - s_.kappa * beta - s_.rho * gamma * mu;
      }
      b_(i) += v;
    }
  }
  // The model's U-K solve with the corrected servo rows (Qc is linear in b: the nominal force plus
  // the corrections), then the actuators' share of it.
  work_.M = md.M;
  work_.A = md.A;
  work_.Q = md.Q;
  uk_solve_dispatch(work_, b_, work_.Q, work_.qdd, work_.Qc, model.uk);
  actuation_for(model, work_, act_);
  u = act_.result.u;
}

ClosedLoop::ClosedLoop(const ControlModel& m, ControlLaw& l, Vec plant_tau_,
                       std::function<void(double, VecRef)> dist)
    : model(m),
      law(l),
      tau_plant(std::move(plant_tau_)),
      disturbance(std::move(dist)),
      model_data(*m.system),
      u_raw(Vec::Zero(m.actuators.count())),
      u(Vec::Zero(m.actuators.count())),
      d(Vec::Zero(m.system->dof())),
      Bu_(Vec::Zero(m.system->dof())) {}

void ClosedLoop::evaluate(double t, CVecRef q, CVecRef qd) {
  forward(*model.system, model_data, t, q, qd, model.tau, model.uk);
  law.control(model, t, q, qd, model_data, u_raw);
  saturated = false;
  for (Index j = 0; j < u.size(); ++j) {
    const double lim = model.actuators.limit(j);
    u(j) = std::clamp(u_raw(j), -lim, lim);
    // (a u of no number is not "clipped": the run stops on it, simulate.cpp names the cause)
    saturated = saturated || (std::isfinite(u_raw(j)) && u(j) != u_raw(j));
  }
  d.setZero();
  if (disturbance) disturbance(t, d);
}

void ClosedLoop::plant_tau(VecRef tau) {
  Bu_.noalias() = model.actuators.B * u;  // the temporary of tau_plant + B u + d, in a buffer
  tau = tau_plant + Bu_ + d;
}

ForceFunction ClosedLoop::force_function() {
  return [this](double t, CVecRef q, CVecRef qd, VecRef tau) {
    evaluate(t, q, qd);
    plant_tau(tau);
  };
}

void offset_start(const ControlModel& model, double t, const Vec& offset, Vec& q, Vec& qd) {
  const System& sys = *model.system;
  ForwardData d(sys);
  Vec phi(sys.rows()), phid(sys.rows());
  double worst = 0.0;
  for (int it = 0; it < 50; ++it) {
    position_residuals(sys, d, t, q, phi);
    phi -= offset;
    worst = phi.size() ? phi.cwiseAbs().maxCoeff() : 0.0;
    if (worst < 1e-14) break;
    evaluate_dynamics(sys, d, t, q, qd);
    evaluate_constraints(sys, d, t, q, qd);
    Eigen::CompleteOrthogonalDecomposition<Mat> cod(d.A);
    q -= cod.solve(phi);
  }
  position_residuals(sys, d, t, q, phi);
  phi -= offset;
  worst = phi.size() ? phi.cwiseAbs().maxCoeff() : 0.0;
  if (!(worst < 1e-13)) throw Error("offset start: the constraints with the offsets cannot be met");
  evaluate_dynamics(sys, d, t, q, qd);
  evaluate_constraints(sys, d, t, q, qd);
  velocity_residuals(sys, d, t, q, qd, phid);
  Eigen::CompleteOrthogonalDecomposition<Mat> cod(d.A);
  qd -= cod.solve(phid);
}

}  // namespace ukdyn
