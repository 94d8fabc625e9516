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
/// The solve of solve_stage() for another b and Q (the drift projection's b = −Φ or −Φ̇ with
/// Q = 0): the block-arrow solve when it applies (then data.used_arrow), else uk_solve_dispatch().
/// Structurally singular blocks are augmented beside M and Q (data.singular's buffers): M and Q
/// stay as they are. Allocation-free.
UkResult solve_for(const System& system, ForwardData& data, const Vec& b, const Vec& Q, Vec& qdd,
                   Vec& Qc, const UkSettings& settings);
/// The constraint stage of forward(): A and b at (t, q, q̇); when the block-arrow solve applies,
/// only A's structural non-zeros are written (O(N) for N robots; the rest of data.A stays 0),
/// else evaluate_constraints().
void constraint_stage(const System& system, ForwardData& data, double t, CVecRef q, CVecRef qd,
                      const UkSettings& settings);
/// Whether solve_stage tries the block-arrow solve (ukdyn/core/uk_arrow.hpp) first.
bool arrow_applies(const System& system, const ForwardData& data, const UkSettings& settings);

}  // namespace ukdyn
