// Scalar functions of time for trajectory (servo) constraints, with exact first, second and third
// derivatives.
#pragma once

#include <array>
#include <cmath>

namespace ukdyn {

/// f(t) as one of:
///   constant:   f = c0
///   cosine:     f = mean + amplitude · cos(omega · t + phase)     (paper Eq. (19): 0.5 − 0.5 cos(πt))
///   polynomial: f = Σ_k coeff[k] t^k, k < 8
struct TimeFunction {
  enum class Kind { constant, cosine, polynomial };
  Kind kind = Kind::constant;
  double mean = 0.0, amplitude = 0.0, omega = 0.0, phase = 0.0;
  std::array<double, 8> coeff{};
  int ncoeff = 0;

  static TimeFunction make_constant(double c) {
    TimeFunction f;
    f.coeff[0] = c;
    f.ncoeff = 1;
    return f;
  }
  static TimeFunction make_cosine(double mean, double amplitude, double omega, double phase = 0.0) {
    TimeFunction f;
    f.kind = Kind::cosine;
    f.mean = mean;
    f.amplitude = amplitude;
    f.omega = omega;
    f.phase = phase;
    return f;
  }

  /// d-th derivative (d = 0, 1, 2, 3) at t (the third: ∂b/∂t of a trajectory row, b = f̈).
  [[nodiscard]] double eval(double t, int d = 0) const {
    switch (kind) {
      case Kind::constant:
        return d == 0 ? coeff[0] : 0.0;
      case Kind::cosine: {
        const double arg = omega * t + phase;
        if (d == 0) return mean + amplitude * std::cos(arg);
        if (d == 1) return -amplitude * omega * std::sin(arg);
        if (d == 2) return -amplitude * omega * omega * std::cos(arg);
        return amplitude * omega * omega * omega * std::sin(arg);
      }
      case Kind::polynomial: {
        double value = 0.0;
        for (int k = ncoeff - 1; k >= d; --k) {
          double c = coeff[static_cast<std::size_t>(k)];
          for (int j = 0; j < d; ++j) c *= static_cast<double>(k - j);
          value = value * t + c;
        }
        return value;
      }
    }
    return 0.0;
  }
};

}  // namespace ukdyn
