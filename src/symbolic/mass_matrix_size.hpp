// The size of a derived mass matrix counted before it is derived (definitions.cpp): the early
// check that refuses an entry too large to keep before the derivatives are taken. Internal to
// ukdyn::symbolic (not installed).
#pragma once

#include <ginac/ginac.h>

#include <vector>

namespace ukdyn::symbolic {

/// nodes[i * n + j] (i ≤ j, n = qd.size()): the nodes written out (as check_expression_size()
/// counts them) of (∂²T/∂q̇_i∂q̇_j).expand(), counted from the terms of the expanded T alone,
/// linear in its size: a term c f(q) q̇_i q̇_j (c f(q) q̇_i²) gives the term c f(q) (2 c f(q)).
/// Terms of T with a velocity inside a function or of a degree other than 2 in the velocities
/// are not counted (the derivation refuses such a T: M depends on q̇). Exact for an expanded T
/// quadratic in qd (Limits.MassMatrixSizeBeforeTheDerivatives).
std::vector<double> mass_matrix_nodes(const GiNaC::ex& T, const std::vector<GiNaC::symbol>& qd);

}  // namespace ukdyn::symbolic
