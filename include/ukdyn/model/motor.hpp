// Motors and gearboxes behind actuators (docs/motors.md). An actuator j of τ = B u (column b of B,
// ukdyn/simulate/control.hpp) driven by a DC motor through a gear of ratio n:
//
//   joint-side speed   ω_j = bᵀq̇,        motor speed ω_m = n ω_j;
//   rotor inertia      ½ J_m ω_m² = ½ q̇ᵀ (n² J_m b bᵀ) q̇: the reflected inertia n² J_m b bᵀ is
//                      added to M exactly (System::add_reflected_inertia; MuJoCo's `armature`,
//                      Drake's rotor_inertia · gear_ratio², both for b = e_i);
//   motor friction     τ_f(ω_m) = b_m ω_m + c_m tanh(ω_m / ω_s) at the motor shaft, seen through
//                      the ideal ratio at the joint: Q_f = −b n τ_f (MotorFriction below; the
//                      viscous part is n² b_m on the joint, the Coulomb part n c_m);
//   gear efficiency    u, the actuator's input (τ = B u), drives the joint's equation, which takes
//                      the rotor's inertia and friction above; u / n is the motor's torque through
//                      an ideal gear. The gear's losses go on top: the motor's electromagnetic
//                      torque is τ_m = u / (n η) when the motor drives
//                      the load (u ω_j ≥ 0, "motoring") and τ_m = u η / n when the load drives the
//                      motor (u ω_j < 0, "braking": the gear loses on the way back too);
//   electrical         i = τ_m / k_t, back-EMF k_e ω_m with k_e = k_t (SI), V = R i + k_t ω_m,
//                      P_el = V i = τ_m ω_m + R i² (copper loss R i², gear loss τ_m ω_m − u ω_j).
//
// So P_el = u ω_j + P_gear + P_cu, and the mechanical side u ω_j = dE/dt + P_f (+ the work of the
// other forces): ∫P_el = ΔE + E_f + E_gear + E_cu (tests/test_motors.cpp, MotorEnergy.*).
#pragma once

#include <limits>
#include <memory>
#include <string>

#include "ukdyn/model/applied_force.hpp"

namespace ukdyn {

/// One motor + gearbox (docs/motors.md, "Keys"). Units SI: N·m, rad/s, kg·m², A, Ω.
struct MotorSpec {
  double ratio = 1.0;           ///< n = ω_m / ω_j (> 0)
  double efficiency = 1.0;      ///< η in (0, 1]
  double rotor_inertia = 0.0;   ///< J_m ≥ 0 (motor side)
  double viscous = 0.0;         ///< b_m ≥ 0 (motor side, N·m·s/rad)
  double coulomb = 0.0;         ///< c_m ≥ 0 (motor side, N·m)
  double coulomb_speed = 1e-2;  ///< ω_s > 0: tanh smoothing of the Coulomb friction (rad/s, motor)
  double torque_constant = 1.0;                                    ///< k_t > 0 (N·m/A = V·s/rad)
  double resistance = 0.0;                                         ///< R ≥ 0 (Ω)
  double stall_torque = std::numeric_limits<double>::infinity();   ///< T_s (motor side)
  double no_load_speed = std::numeric_limits<double>::infinity();  ///< ω_0 (motor side, rad/s)
  double continuous_torque = std::numeric_limits<double>::infinity();  ///< T_c: RMS limit
  double peak_torque = std::numeric_limits<double>::infinity();        ///< T_p: |τ_m| limit
};

/// The motor's operating point for an actuator input u at the joint-side speed ω_j.
struct MotorPoint {
  double omega_m = 0.0;     ///< n ω_j
  double torque = 0.0;      ///< τ_m (electromagnetic, motor side)
  double current = 0.0;     ///< τ_m / k_t
  double voltage = 0.0;     ///< R i + k_t ω_m
  double p_elec = 0.0;      ///< V i
  double p_copper = 0.0;    ///< R i²
  double p_gear = 0.0;      ///< τ_m ω_m − u ω_j (≥ 0)
  double p_friction = 0.0;  ///< τ_f(ω_m) ω_m (≥ 0)
  double available = 0.0;   ///< T_avail(ω_m) = min(T_p, T_s (1 − |ω_m| / ω_0)) (may be < 0)
  double margin = 0.0;      ///< (T_avail − |τ_m|) / T_ref, T_ref = min(T_p, T_s) (< 0: outside)
};

/// τ_f(ω_m) = b_m ω_m + c_m tanh(ω_m / ω_s), the friction torque at the motor shaft.
double motor_friction_torque(const MotorSpec& m, double omega_m);
/// The operating point (docs/motors.md, "The model"). Allocation-free.
MotorPoint motor_point(const MotorSpec& m, double u, double omega_j);
/// Throws std::invalid_argument naming the field of the first bad value (n ≤ 0, η ∉ (0, 1],
/// J_m < 0, b_m < 0, c_m < 0, ω_s ≤ 0, k_t ≤ 0, R < 0, a limit ≤ 0, any NaN).
void check_motor(const MotorSpec& m);

/// The motor's friction on the joint coordinates: Q_f = −b n τ_f(n bᵀq̇) (b: the actuator's column
/// of B over all n system coordinates). Non-conservative; exact derivatives.
class MotorFriction : public AppliedForce {
 public:
  MotorFriction(std::string name, const MotorSpec& motor, Vec b);
  [[nodiscard]] const std::string& name() const override { return name_; }
  double add_to(double t, CVecRef q, CVecRef qd, VecRef Q) const override;
  [[nodiscard]] double potential(CVecRef q) const override;
  [[nodiscard]] bool has_derivatives() const override { return true; }
  bool add_tangent(double t, CVecRef q, CVecRef qd, CVecRef dq, CVecRef dqd,
                   VecRef dQ) const override;
  /// Q_f does not depend on t: ∂Q_f/∂t = 0 (exact).
  bool add_time_tangent(double, CVecRef, CVecRef, VecRef) const override { return true; }

 private:
  std::string name_;
  MotorSpec m_;
  Vec b_;
};

}  // namespace ukdyn
