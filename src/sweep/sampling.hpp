// Internal to the sweep (src/sweep/): the normal distribution function, for the sweep file's check
// of a truncated normal (sweep_file.cpp) and its draws (sampling.cpp).
#pragma once

namespace ukdyn::sweep_detail {

/// Φ, the standard normal distribution function.
double normal_cdf(double x);

}  // namespace ukdyn::sweep_detail
