// Wheeled platforms on the floor (docs/wheeled-platforms.md): a rigid platform moving in the plane,
// q = (x, y, ψ, φ_1, …, φ_N) — the platform's reference point, its yaw, and each wheel's spin
// angle — with one exact nonholonomic row per wheel.
//
// Wheel i sits at p_i = (a_i, b_i) in the platform frame, rolls along d_i = (cos β_i, sin β_i)
// (its heading β_i; axle direction s_i = (−sin β_i, cos β_i)), with radius r; its rollers' axes,
// projected on the floor, make the roller angle γ_i with the axle: e_i = cos γ_i s_i + sin γ_i d_i.
// A roller turns freely about its own axis, so the only no-slip condition is that the contact
// point does not slide along e_i ([Muir1987]; [Zeidis2019]):
//
//   e_i · (v_i − r φ̇_i d_i) = 0,   v_i = R(ψ)ᵀ (ẋ, ẏ) + ψ̇ (−b_i, a_i)   (platform frame),
//
// i.e.  e_x (cψ ẋ + sψ ẏ) + e_y (−sψ ẋ + cψ ẏ) + ψ̇ (e_y a_i − e_x b_i) − r sin γ_i φ̇_i = 0.
// Its value is the slip velocity along the roller axis (m/s). Mecanum: γ_i = ±π/4 typically;
// omni: γ_i = π/2 (the rollers' axes along d_i: the wheel rolls without slip along d_i and slides
// freely along its axle). γ = 0 would make the row free of φ̇_i (refused). A differential drive is
// two wheels of γ = π/2 at (0, ±W/2) with heading 0 plus the row "no lateral slip of the axle",
// −sψ ẋ + cψ ẏ = 0 (the unicycle).
//
// The kinetic energy: T = ½ m |ṗ_c|² + ½ I_c ψ̇² + ½ J Σ φ̇_i², p_c the centre of mass (the reference
// point moved by `com` in the platform frame), I_c the platform's yaw inertia about it (wheels
// included, their diametral inertia too), J the spin inertia of one wheel about its axle; the
// rollers are massless. The wheels' angular velocity ψ̇ e_z + φ̇_i s_i has no cross term in
// T (s_i ⊥ e_z, wheel axisymmetric), so this split is exact.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "ukdyn/core/types.hpp"
#include "ukdyn/symbolic/definitions.hpp"

namespace ukdyn::symbolic {

enum class WheeledPlatformKind { mecanum, omni, differential_drive };

struct PlatformWheel {
  double x = 0.0, y = 0.0;    ///< position in the platform frame (m)
  double heading = 0.0;       ///< β: rolling direction in the platform frame (rad)
  double roller_angle = 0.0;  ///< γ: roller axis from the axle toward d (rad); omni: π/2
};

struct WheeledPlatformDef {
  WheeledPlatformKind kind = WheeledPlatformKind::mecanum;
  std::vector<PlatformWheel> wheels;  ///< differential_drive: differential_drive_wheels()
  double wheel_radius = 0.0;          ///< r > 0
  double mass = 0.0;                  ///< m > 0 (platform with wheels)
  double yaw_inertia = 0.0;           ///< I_c > 0, about the centre of mass
  double wheel_inertia = 0.0;         ///< J > 0, spin inertia of one wheel about its axle
  double com_x = 0.0, com_y = 0.0;    ///< centre of mass in the platform frame
};

/// NAME_x, NAME_y, NAME_yaw, NAME_phi1, …, NAME_phiN.
std::vector<std::string> wheeled_platform_coordinates(const std::string& name, std::size_t wheels);

/// The left (0, W/2) and right (0, −W/2) wheels of a differential drive of track width W.
std::vector<PlatformWheel> differential_drive_wheels(double track_width);

/// H (N×3): φ̇ = H (u, w, ω) for the platform twist in its own frame at the reference point
/// (u forward, w left, ω = ψ̇): row i = (e_x, e_y, e_y a_i − e_x b_i) / (r sin γ_i).
Mat wheel_rate_matrix(const WheeledPlatformDef& def);

/// The first thing wrong with `def` (empty if none): a radius, mass or inertia not > 0, fewer than
/// 3 wheels (mecanum, omni), a roller angle with |sin γ| < 1e-3 (the row loses φ̇_i), wheels that
/// cannot turn the platform every way (rank H < 3).
std::string wheeled_platform_problem(const WheeledPlatformDef& def);

/// The platform's definition: bodies `platform` (mass m at the centre of mass, rotation Rz(ψ),
/// scalar yaw inertia) and `wheelK` (spin inertia J about the axle), parameters m, I, J kept as
/// symbols, the floor horizontal (gravity does no work). `coordinates`: x, y, ψ, φ_1..φ_N.
SubsystemDef wheeled_platform_definition(const std::string& name, const WheeledPlatformDef& def,
                                         const std::vector<std::string>& coordinates,
                                         std::shared_ptr<SymbolTable> symbols = nullptr);

/// The rolling rows NAME_wheelK (mecanum, omni; one per wheel) or NAME_lateral, NAME_roll_left,
/// NAME_roll_right (differential_drive), nonholonomic, over the system's coordinates; the
/// constraint is named NAME_rolling, or `constraint_name` if given (the listed constraint
/// `type: rolling_wheels` on another subsystem's coordinates). Only the wheels, the radius and the
/// kind of `def` are used. `coordinates`: x, y, ψ, φ_1..φ_N (any coordinates of the system).
ConstraintDef wheeled_platform_rolling_constraint(
    const std::string& name, const WheeledPlatformDef& def,
    const std::vector<std::string>& coordinates, const std::vector<std::string>& system_coordinates,
    std::shared_ptr<SymbolTable> symbols = nullptr, const std::string& constraint_name = {});

}  // namespace ukdyn::symbolic
