// Exact state derivatives of the velocity-level constraint and of a constraint force, from the
// constraints' tangents (Constraint::tangent, docs/derivatives.md): what minimal coordinates and
// trajectory optimisation on the constraint manifold need besides ∂q̈/∂x.
#pragma once

#include <vector>

#include "ukdyn/model/system.hpp"

namespace ukdyn {

/// The r × n matrix D = ∂(A_R v)/∂q at fixed v, and the n × n matrices ∂(A_Rᵀ λ_k)/∂q for each
/// multiplier vector λ_k (r entries each, on the kept rows R) at (t, q). Column j from two tangents
/// along e_j: tangent() gives d(A x − b) along dq at fixed x, so d(A) v = d(A v − b) − d(A·0 − b),
/// and d(Aᵀλ) directly. 2n tangent calls per constraint. Throws ukdyn::Error when a constraint has
/// no exact derivatives. `d` is a scratch ForwardData of `system` (its slots are read).
void constraint_state_jacobians(const System& system, ForwardData& d, double t, CVecRef q,
                                CVecRef v, const std::vector<Index>& kept,
                                const std::vector<Vec>& lambdas, Mat& D,
                                std::vector<Mat>& dforce_dq);

/// The first kept row (index into `kept`) that is velocity-level (nonholonomic), or −1. A holonomic
/// row has a_i = ∂Φ_i/∂q, so the central difference of Φ_i along a_iᵀ/|a_i| is |a_i|; a
/// velocity-level row has no Φ_i (its position residual is 0). The difference only classifies the
/// row (a factor 1e3 apart); no derivative of the model comes from it. AR: the kept rows of A at q.
Index first_velocity_level_row(const System& system, ForwardData& d, double t, CVecRef q,
                               const Mat& AR, const std::vector<Index>& kept);

}  // namespace ukdyn
