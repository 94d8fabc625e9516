#include "ukdyn/model/motor.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace ukdyn {

double motor_friction_torque(const MotorSpec& m, double omega_m) {
  return m.viscous * omega_m + m.coulomb * std::tanh(omega_m / m.coulomb_speed);
}

MotorPoint motor_point(const MotorSpec& m, double u, double omega_j) {
  MotorPoint p;
  p.omega_m = m.ratio * omega_j;
  // Gear efficiency on the power through the gear (docs/motors.md): motoring when u ω_j ≥ 0.
  const bool motoring = u * omega_j >= 0.0;
  p.torque = motoring ? u / (m.ratio * m.efficiency) : u * m.efficiency / m.ratio;
  p.current = p.torque / m.torque_constant;
  p.voltage = m.resistance * p.current + m.torque_constant * p.omega_m;
  p.p_elec = p.voltage * p.current;
  p.p_copper = m.resistance * p.current * p.current;
  p.p_gear = p.torque * p.omega_m - u * omega_j;
  p.p_friction = motor_friction_torque(m, p.omega_m) * p.omega_m;
  // The DC motor's speed–torque line at nominal voltage, cut at the peak torque.
  const double line = std::isfinite(m.no_load_speed)
                          ? m.stall_torque * (1.0 - std::abs(p.omega_m) / m.no_load_speed)
                          : m.stall_torque;
  p.available = std::min(m.peak_torque, line);
  const double ref = std::min(m.peak_torque, m.stall_torque);
  p.margin = std::isfinite(ref) ? (p.available - std::abs(p.torque)) / ref
                                : std::numeric_limits<double>::infinity();
  return p;
}

void check_motor(const MotorSpec& m) {
  auto bad = [](const char* key, const char* rule, double v) {
    throw std::invalid_argument(std::string(key) + " " + rule + " (got " + std::to_string(v) + ")");
  };
  if (!(m.ratio > 0.0) || !std::isfinite(m.ratio)) bad("ratio", "must be > 0 and finite", m.ratio);
  if (!(m.efficiency > 0.0 && m.efficiency <= 1.0))
    bad("efficiency", "must be in (0, 1]", m.efficiency);
  if (!(m.rotor_inertia >= 0.0) || !std::isfinite(m.rotor_inertia))
    bad("rotor_inertia", "must be >= 0 and finite", m.rotor_inertia);
  if (!(m.viscous >= 0.0) || !std::isfinite(m.viscous))
    bad("viscous", "must be >= 0 and finite", m.viscous);
  if (!(m.coulomb >= 0.0) || !std::isfinite(m.coulomb))
    bad("coulomb", "must be >= 0 and finite", m.coulomb);
  if (!(m.coulomb_speed > 0.0) || !std::isfinite(m.coulomb_speed))
    bad("coulomb_speed", "must be > 0 and finite", m.coulomb_speed);
  if (!(m.torque_constant > 0.0) || !std::isfinite(m.torque_constant))
    bad("torque_constant", "must be > 0 and finite", m.torque_constant);
  if (!(m.resistance >= 0.0) || !std::isfinite(m.resistance))
    bad("resistance", "must be >= 0 and finite", m.resistance);
  if (!(m.stall_torque > 0.0)) bad("stall_torque", "must be > 0", m.stall_torque);
  if (!(m.no_load_speed > 0.0)) bad("no_load_speed", "must be > 0", m.no_load_speed);
  if (!(m.continuous_torque > 0.0)) bad("continuous_torque", "must be > 0", m.continuous_torque);
  if (!(m.peak_torque > 0.0)) bad("peak_torque", "must be > 0", m.peak_torque);
}

MotorFriction::MotorFriction(std::string name, const MotorSpec& motor, Vec b)
    : name_(std::move(name)), m_(motor), b_(std::move(b)) {
  check_motor(m_);
}

double MotorFriction::add_to(double t, CVecRef q, CVecRef qd, VecRef Q) const {
  (void)t, (void)q;
  const double omega_j = b_.dot(qd);
  const double tau_joint = m_.ratio * motor_friction_torque(m_, m_.ratio * omega_j);
  Q.noalias() -= tau_joint * b_;
  return -tau_joint * omega_j;  // the power of Q_f: −τ_f ω_m ≤ 0
}

double MotorFriction::potential(CVecRef q) const {
  (void)q;
  return 0.0;
}

bool MotorFriction::add_tangent(double t, CVecRef q, CVecRef qd, CVecRef dq, CVecRef dqd,
                                VecRef dQ) const {
  (void)t, (void)q, (void)dq;
  // d/dω_m [b_m ω_m + c_m tanh(ω_m/ω_s)] = b_m + c_m (1 − tanh²) / ω_s; dω_m = n bᵀdq̇.
  const double omega_m = m_.ratio * b_.dot(qd);
  const double th = std::tanh(omega_m / m_.coulomb_speed);
  const double slope = m_.viscous + m_.coulomb * (1.0 - th * th) / m_.coulomb_speed;
  dQ.noalias() -= (m_.ratio * slope * m_.ratio * b_.dot(dqd)) * b_;
  return true;
}

}  // namespace ukdyn
