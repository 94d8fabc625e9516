// Ready-made constraint kinds for definition-based systems. Each adds rows Φ(q, t) = 0 to a
// ConstraintDef; the existing derivation (definitions.hpp) then gives A = ∂Φ/∂q and b exactly.
//
//   points_coincide   a − b = 0 (3 rows, or the chosen axes): the cut of a load, a closed loop
//   point_trajectory  p_k − f_k(t) = 0 for the given axes: a point follows time functions
//   angle_relation    Σ c_i q_i − f(t) = 0: a linear relation between coordinates (δ1 − δ2 = π)
//   coordinate        q_i − f(t) = 0 (as ukdyn::CoordinateConstraint, but derived)
//
// Points come from ChainModel::world_point (chain.hpp) or any expressions of the coordinates.
#pragma once

#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "ukdyn/model/time_function.hpp"
#include "ukdyn/symbolic/chain.hpp"
#include "ukdyn/symbolic/definitions.hpp"

namespace ukdyn::symbolic {

/// A double as an exact number when it is a short decimal (0.7 → 7/10), else as a float.
GiNaC::ex exact_number(double v);

/// f(t) of a TimeFunction (constant, cosine, polynomial) as an expression of the time symbol t.
GiNaC::ex time_expression(const TimeFunction& f, const GiNaC::symbol& t);

/// The same kinds with exact (symbolic) coefficients: mean + amplitude cos(omega t + phase), and
/// Σ c_k t^k.
GiNaC::ex cosine_expression(const GiNaC::ex& mean, const GiNaC::ex& amplitude,
                            const GiNaC::ex& omega, const GiNaC::ex& phase, const GiNaC::symbol& t);
GiNaC::ex polynomial_expression(const std::vector<GiNaC::ex>& coefficients, const GiNaC::symbol& t);

/// Rows <prefix>_x, _y, _z: a_k − b_k for the axes selected (all by default).
void add_points_coincide(ConstraintDef& def, const std::string& prefix, const Vec3Ex& a,
                         const Vec3Ex& b, std::array<bool, 3> axes = {true, true, true});

/// Rows <prefix>_x, _y, _z for each axis with a function: p_k − (origin_k + f_k(t)).
void add_point_trajectory(ConstraintDef& def, const std::string& prefix, const Vec3Ex& p,
                          const std::array<std::optional<GiNaC::ex>, 3>& f,
                          const Vec3Ex& origin = {0, 0, 0});

/// Row `row`: Σ c_i q_i − value(t). Throws DefinitionError for an unknown coordinate, a
/// coefficient that is not a constant, or no nonzero term.
void add_angle_relation(ConstraintDef& def, const std::string& row,
                        const std::vector<std::pair<std::string, GiNaC::ex>>& terms,
                        const GiNaC::ex& value);

/// Row `row`: q − value(t).
void add_coordinate(ConstraintDef& def, const std::string& row, const std::string& coordinate,
                    const GiNaC::ex& value);

}  // namespace ukdyn::symbolic
