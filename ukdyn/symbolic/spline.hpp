// Cubic splines through points as time functions of definition-based constraints.
//
// spline_expression(s) is a GiNaC function ukdyn_spline(id, k, t) (the k-th derivative of spline
// `id`): GiNaC differentiates it exactly (d/dt raises k; k ≥ 4 is 0), and the compiled tapes
// evaluate it with a binary search over the knots (allocation-free). Outside [t_0, t_n] the first
// or last cubic piece continues. In printed derivations it appears as ukdyn_spline(id, k, t).
#pragma once

#include <ginac/ginac.h>

#include <array>
#include <cstddef>
#include <memory>
#include <vector>

namespace ukdyn::symbolic {

class CubicSpline {
 public:
  enum class End { natural, clamped };
  /// Through (t_i, y_i), t strictly increasing, at least 2 points. natural: S'' = 0 at both ends;
  /// clamped: S'(t_0) = slope0, S'(t_n) = slope1. Throws ukdyn::Error on bad input.
  CubicSpline(std::vector<double> t, std::vector<double> y, End end = End::natural,
              double slope0 = 0.0, double slope1 = 0.0);
  /// d-th derivative (0..3; higher is 0) at t.
  [[nodiscard]] double eval(double t, int d = 0) const;
  [[nodiscard]] const std::vector<double>& knots() const { return t_; }

 private:
  std::vector<double> t_;
  std::vector<std::array<double, 4>> c_;  // per piece: a + b s + c s^2 + d s^3, s = t - t_i
};

/// Registers the spline (for the lifetime of the program) and returns f(arg) as an expression.
GiNaC::ex spline_expression(const CubicSpline& spline, const GiNaC::ex& arg);
/// spline_expression(spline, t) with the global time symbol.
GiNaC::ex spline_expression(const CubicSpline& spline);
/// The registered spline `id` (for the tape compiler); throws ukdyn::Error if unknown.
std::shared_ptr<const CubicSpline> registered_spline(std::size_t id);

}  // namespace ukdyn::symbolic
