// Diagnostics of a failed run (internal to simulate()).
#pragma once

#include <string>
#include <vector>

#include "ukdyn/model/system.hpp"

namespace ukdyn::detail {

/// v with 3 significant digits ("%.3g").
std::string sci(double v);

/// Why a step failed (issue 15 class 5): evaluated at the state x = [q; q̇] where the step control
/// gave up, on the failure path only (allocates). Names the cause and the coordinates / constraint
/// rows involved, or returns "" when neither M nor A is singular there.
std::string diagnose_singularity(const System& system, double t, const std::vector<double>& x,
                                 const UkSettings& uk);

}  // namespace ukdyn::detail
