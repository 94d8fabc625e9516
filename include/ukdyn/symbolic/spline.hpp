// Cubic splines through points as time functions of definition-based constraints.
//
// spline_expression(s, t) is a GiNaC function ukdyn_spline(S, k, t) (the k-th derivative of spline
// S): GiNaC differentiates it exactly (d/dt raises k; k ≥ 4 is 0), and the compiled tapes evaluate
// it with a binary search over the knots (allocation-free). Outside [t_0, t_n] the first or last
// cubic piece continues. S is a GiNaC object that holds the spline by shared_ptr: the spline lives
// as long as an expression or a tape that uses it, and no more (there is no registry). Two splines
// with the same knots and coefficients are the same S. In printed derivations S appears as
// S_<hex digits of a hash of its content> (the same in every process).
#pragma once

#include <ginac/ginac.h>

#include <array>
#include <cstddef>
#include <cstdint>
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
  /// Total order by content (knots, then coefficients, bit patterns): < 0, 0, > 0.
  [[nodiscard]] int compare(const CubicSpline& other) const;
  /// FNV-1a hash of the content (for printing; equal splines have equal fingerprints).
  [[nodiscard]] std::uint64_t fingerprint() const;

 private:
  std::vector<double> t_;
  std::vector<std::array<double, 4>> c_;  // per piece: a + b s + c s^2 + d s^3, s = t - t_i
};

/// f(arg) as an expression holding a copy of the spline (freed with the last expression or tape
/// that uses it).
GiNaC::ex spline_expression(const CubicSpline& spline, const GiNaC::ex& arg);
/// The spline held by S, the first argument of ukdyn_spline(S, k, t) (for the tape compiler);
/// throws ukdyn::Error if `handle` is not such an argument.
std::shared_ptr<const CubicSpline> spline_of(const GiNaC::ex& handle);

}  // namespace ukdyn::symbolic
