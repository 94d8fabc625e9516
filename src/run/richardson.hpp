// Richardson's extrapolation of two central differences [Richardson1911], shared by the
// parameter sensitivities (sensitivity.cpp) and the control law's derivatives
// (closed_loop_derivatives.cpp).
#pragma once

namespace ukdyn {

/// (4 D(h/2) − D(h)) / 3 with D(h) = (f(p + h) − f(p − h)) / 2h, from f(p + h), f(p − h),
/// f(p + h/2), f(p − h/2): error O(h⁴) for f smooth in p.
template <typename T>
auto richardson(const T& fph, const T& fmh, const T& fph2, const T& fmh2, double h) {
  return ((4.0 / h) * (fph2 - fmh2) - (0.5 / h) * (fph - fmh)) / 3.0;
}

}  // namespace ukdyn
