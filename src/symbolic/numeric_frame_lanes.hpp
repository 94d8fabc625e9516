// The numeric frame constraints' all-directions tangents on lanes (the rows lifted to dual numbers
// of eight directions per pass), kept as the reference that the tests compare the doubles pass of
// ConstraintColumns::tangent_columns with (docs/derivatives.md, "Cost"). Internal to
// ukdyn::symbolic (not installed).
#pragma once

#include "ukdyn/symbolic/frame_constraints.hpp"

namespace ukdyn::symbolic {

/// tangent_columns() of c's numeric rows computed on lanes: the same outputs (d_residual written,
/// d_force added to). False when c's rows are not numeric (derived ones).
bool numeric_frame_columns_on_lanes(const FrameConstraint& c, const ConstraintContext& ctx,
                                    CVecRef q, CVecRef qd, CVecRef qdd, CVecRef lambda,
                                    MatRef d_residual, MatRef d_force);

}  // namespace ukdyn::symbolic
