// Private to ukdyn: the solver plumbing behind forward() (include/ukdyn/model/system.hpp), shared
// with simulate/ (drift control, the control law's actuation solve). Not installed.
#pragma once

#include "ukdyn/model/system.hpp"

namespace ukdyn {

/// The U-K solve of forward() on data.M (factored here) and data.A for the given b and Q: the
/// positive-definite block solve, or uk_solve_singular() (core/uk_singular.hpp) when a block of M
/// is not positive definite (or a pivot is under kSingularPivot). Allocation-free.
UkResult uk_solve_dispatch(ForwardData& data, const Vec& b, const Vec& Q, Vec& qdd, Vec& Qc,
                           const UkSettings& settings = {});

/// Last stage of forward(): q̈, Qc and data.result from data.M, Q, A, b (the U-K solve, uk_solve.hpp). forward()
/// ends with it; drift control (Baumgarte) calls the stages itself with b adjusted before this one.
/// The block-arrow path is used when the system has the structure, data was built with its
/// buffers, and the method is exact or adaptive.
void solve_stage(const System& system, ForwardData& data, const UkSettings& settings);
/// Whether solve_stage tries the block-arrow solve (ukdyn/core/uk_arrow.hpp) first.
bool arrow_applies(const System& system, const ForwardData& data, const UkSettings& settings);

}  // namespace ukdyn
