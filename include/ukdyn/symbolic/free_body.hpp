// A rigid body free in space in position + unit quaternion coordinates (docs/free-bodies.md):
//   q = (x, y, z, qw, qx, qy, qz),  p = (x, y, z) the centre of mass in the world frame,
//   R(q) = the rotation body → world of the quaternion (homogeneous form, orthonormal for |q| = 1),
//   ω_body = 2 E(q) q̇_quat = vee(Rᵀ Ṙ) on |q| = 1,
//   E = [−qx qw qz −qy; −qy −qz qw qx; −qz qy −qx qw]
// ([Udwadia2010b]). M, C, G follow from T = ½ m ṗ·ṗ + ½ ωᵀ J ω and
// V = −m g·p by the same derivation as every definition (definitions.hpp). M = diag(m I, 4 Eᵀ J E)
// is singular (E q = 0): the unit-norm row qw² + qx² + qy² + qz² − 1 = 0
// (free_body_norm_constraint) gives [M; A] full column rank, and the U-K solve for singular M
// (core/uk_singular.hpp) the motion.
//
// The body is one BodyDef named like the subsystem, with `com` and `rotation` set: frame
// constraints read its pose from there.
#pragma once

#include <array>
#include <string>
#include <vector>

#include "ukdyn/symbolic/definitions.hpp"

namespace ukdyn::symbolic {

/// The coordinates of a free body: NAME_x, NAME_y, NAME_z, NAME_qw, NAME_qx, NAME_qy, NAME_qz.
std::vector<std::string> free_body_coordinates(const std::string& name);

/// R(w, x, y, z) (row-major, body → world): [w²+x²−y²−z², 2(xy−wz), 2(xz+wy); 2(xy+wz),
/// w²−x²+y²−z², 2(yz−wx); 2(xz−wy), 2(yz+wx), w²−x²−y²+z²].
std::array<GiNaC::ex, 9> quaternion_rotation(const GiNaC::ex& w, const GiNaC::ex& x,
                                             const GiNaC::ex& y, const GiNaC::ex& z);

/// ω_body = 2 E(q) q̇ (the formula of the header), the body-frame angular velocity of the rotation
/// quaternion_rotation(w, x, y, z) with rates (wd, xd, yd, zd); shared by free bodies and the
/// floating joints of chains (chain.hpp).
std::array<GiNaC::ex, 3> quaternion_body_rate(const GiNaC::ex& w, const GiNaC::ex& x,
                                              const GiNaC::ex& y, const GiNaC::ex& z,
                                              const GiNaC::ex& wd, const GiNaC::ex& xd,
                                              const GiNaC::ex& yd, const GiNaC::ex& zd);

/// Adds the free body (named like def) to `def`, whose first 7 coordinates are (x, y, z, qw, qx,
/// qy, qz): mass and the inertia tensor about the CoM in the body frame (row-major, symmetric).
BodyDef& add_free_body(SubsystemDef& def, const GiNaC::ex& mass,
                       const std::array<GiNaC::ex, 9>& inertia);

/// A complete free-body definition with numeric mass, inertia (body frame) and gravity; coordinates
/// default to free_body_coordinates(name).
SubsystemDef free_body_definition(const std::string& name, double mass,
                                  const std::array<double, 9>& inertia,
                                  const std::array<double, 3>& gravity,
                                  std::vector<std::string> coordinates = {},
                                  std::shared_ptr<SymbolTable> symbols = nullptr);

/// The unit-norm row NAME_unit: qw² + qx² + qy² + qz² − 1 = 0 over the system's coordinates;
/// `quaternion` names the 4 quaternion coordinates (qw, qx, qy, qz).
ConstraintDef free_body_norm_constraint(const std::string& name,
                                        const std::vector<std::string>& quaternion,
                                        const std::vector<std::string>& system_coordinates,
                                        std::shared_ptr<SymbolTable> symbols = nullptr);

}  // namespace ukdyn::symbolic
