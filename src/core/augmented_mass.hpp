// Private to ukdyn: the block-arrow solve's augmented mass factor (core/uk_singular.hpp's augmented
// form, [Udwadia2010]) formed beside M instead of in it. Used by the forward glue
// (src/model/system.cpp, solve_for). Not installed.
#pragma once

#include <cstddef>

#include "ukdyn/core/uk_singular.hpp"

namespace ukdyn::detail {

/// The worst block of mass_condition_estimate(), max_i M_ii / min_j L_jj², and which block it is.
struct MassCondition {
  double estimate = 0.0;
  std::size_t block = 0;
};

/// factor_mass() of M_a: every structural block k (sw.structural) of M + A_kᵀ α A_k over its own
/// rows sw.own_rows[k], the blocks of augmented_blocks(), and Q_a = Q + A_kᵀ α b. M and Q are not
/// changed: the structural blocks' lower triangles go to sw.scratch (same place; the rest of
/// sw.scratch is not written) and the whole of Q_a to sw.Qa. Each block is factored into ws as
/// factor_mass() does (ws.pivot_ratio for mass_factor_regular()), and `cond` gets
/// mass_condition_estimate() of M_a from the same pass. Returns false (ws partly written) when a
/// structural block has no row of its own or a block's Cholesky fails. Allocation-free.
bool factor_augmented_mass(const BlockLayout& layout, const Mat& M, const Mat& A, const Vec& b,
                           const Vec& Q, UkSingularWorkspace& sw, UkWorkspace& ws,
                           MassCondition& cond);

}  // namespace ukdyn::detail
