// A free body's M, C q̇ and G in closed form (docs/free-bodies.md, "The closed form of M, C q̇ and
// G"), evaluated by DerivedSubsystem instead of its dynamics tape. In q = (p, u), u = (w, x, y, z):
//   E(u) = [−x w z −y; −y −z w x; −z y −x w],  ω = 2 E(u) u̇  (free_body.hpp, [Udwadia2010b]),
// T = ½ m ṗ·ṗ + ½ ωᵀ J ω and V = G_p · p + const give, as polynomial identities in (u, u̇) valid off
// |u| = 1 too (E is linear, E(a) b = −E(b) a, E(u̇) u̇ = 0):
//   M = diag(m I₃, 4 E(u)ᵀ J E(u)),
//   C q̇ = Ṁ q̇ − ∂T/∂q = (0, 2 E(u̇)ᵀ J ω + 2 E(u̇)ᵀ J ω) = (0, 4 E(u̇)ᵀ J ω)
//   (Ṁ u̇ = 4 E(u̇)ᵀ J E u̇ + 4 Eᵀ J E(u̇) u̇, the second 0; ∂T/∂u = −2 E(u̇)ᵀ J ω),
//   G = ∂V/∂q = (G_p, 0)   (G_p = −m g for gravity g).
// Internal to ukdyn::symbolic (not installed).
#pragma once

#include <array>
#include <memory>

#include "ukdyn/symbolic/definitions.hpp"

namespace ukdyn::symbolic {

struct FreeBodyDynamics {
  double mass = 0.0;
  /// 4 J (body frame, row-major, symmetric): M's quaternion block is E(u)ᵀ (4 J) E(u), C q̇'s is
  /// E(u̇)ᵀ (4 J) (2 E(u) u̇) (scaled by powers of 2: the same bits as scaling later).
  std::array<double, 9> inertia4{};
  bool diagonal = false;                  ///< J's off-diagonal entries are 0 (principal axes)
  std::array<double, 3> gravity_force{};  ///< G_p = ∂V/∂p, constant
};

/// The closed form of a derivation when it is a free body's: 7 coordinates (p, u), not of t, its
/// kinetic energy equal (exactly, parameters substituted) to ½ m ṗ·ṗ + ½ ωᵀ J ω for numbers m and
/// J read from it, and its potential of p alone with a constant gradient. Null otherwise (the tapes
/// then evaluate it).
std::shared_ptr<const FreeBodyDynamics> free_body_closed_form(const SubsystemDerivation& d);

/// M (7 × 7, every entry written) at q.
void free_body_mass(const FreeBodyDynamics& f, CVecRef q, MatRef M);
/// C q̇ at (q, q̇).
void free_body_velocity_products(const FreeBodyDynamics& f, CVecRef q, CVecRef qd, VecRef Cqd);
/// G (constant).
void free_body_gravity(const FreeBodyDynamics& f, VecRef G);

}  // namespace ukdyn::symbolic
