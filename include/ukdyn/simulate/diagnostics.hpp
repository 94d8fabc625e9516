// Diagnostics of a run (internal to simulate()): why a step failed, and the rank at the start.
#pragma once

#include <string>
#include <vector>

#include "ukdyn/model/system.hpp"
#include "ukdyn/simulate/simulate.hpp"

namespace ukdyn::detail {

/// v with 3 significant digits ("%.3g").
std::string sci(double v);

/// Why a step failed (issue 15 class 5): evaluated at the state x = [q; q̇] where the step control
/// gave up, on the failure path only (allocates). Names the cause and the coordinates / constraint
/// rows involved, or returns "" when neither M nor A is singular there.
std::string diagnose_singularity(const System& system, double t, const std::vector<double>& x,
                                 const UkSettings& uk);

/// The rows redundant around the start of a run (constant redundancy, as Bricard's mechanism),
/// told from a start at a singular position: the smallest rank deficiency of the exact solve at
/// (t0, q0) and at two configurations nearby on the manifold (q0 moved along A's null space and
/// assembled back onto Φ = 0). A singular position's missing rank comes back nearby; a structural
/// redundancy's does not. At setup only (allocates).
int structural_redundancy(const System& system, double t0, const Vec& q0, const Vec& qd0,
                          const UkSettings& uk);

}  // namespace ukdyn::detail
