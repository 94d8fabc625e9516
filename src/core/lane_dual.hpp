// A forward-mode dual number of several lanes: a value and L directional derivatives, one lane per
// direction (vector-mode forward differentiation, Griewank & Walther, Evaluating Derivatives, 2nd
// ed., 2008, §3.1). Every operation is inline on plain arrays, which the compiler vectorises over
// the lanes; Eigen's AutoDiffScalar of a fixed-size vector builds and assigns an expression per
// operation, which measured slower than one-lane passes (docs/derivatives.md, "Cost"). The scalar
// of the tree's and the numeric frame constraints' all-directions passes (Eigen matrices of it:
// NumTraits below). Default-constructed lanes are uninitialised, as Eigen's scalars are; a constant
// (from a double) has zero lanes.
#pragma once

#include <Eigen/Core>
#include <cmath>

namespace ukdyn {

template <int L>
struct LaneDual {
  double v;
  double d[L];
  LaneDual() = default;
  LaneDual(double value) : v(value) {  // NOLINT(google-explicit-constructor): constants
    for (int l = 0; l < L; ++l) d[l] = 0.0;
  }
  [[nodiscard]] double value() const { return v; }
  LaneDual& operator+=(const LaneDual& b) {
    v += b.v;
    for (int l = 0; l < L; ++l) d[l] += b.d[l];
    return *this;
  }
  LaneDual& operator-=(const LaneDual& b) {
    v -= b.v;
    for (int l = 0; l < L; ++l) d[l] -= b.d[l];
    return *this;
  }
  LaneDual& operator*=(const LaneDual& b) {
    for (int l = 0; l < L; ++l) d[l] = d[l] * b.v + v * b.d[l];
    v *= b.v;
    return *this;
  }
  LaneDual& operator/=(const LaneDual& b) {
    const double inv = 1.0 / b.v, q = v * inv;
    for (int l = 0; l < L; ++l) d[l] = (d[l] - q * b.d[l]) * inv;
    v = q;
    return *this;
  }
};

template <int L>
LaneDual<L> operator+(LaneDual<L> a, const LaneDual<L>& b) {
  return a += b;
}
template <int L>
LaneDual<L> operator-(LaneDual<L> a, const LaneDual<L>& b) {
  return a -= b;
}
template <int L>
LaneDual<L> operator*(LaneDual<L> a, const LaneDual<L>& b) {
  return a *= b;
}
template <int L>
LaneDual<L> operator/(LaneDual<L> a, const LaneDual<L>& b) {
  return a /= b;
}
template <int L>
LaneDual<L> operator-(LaneDual<L> a) {
  a.v = -a.v;
  for (int l = 0; l < L; ++l) a.d[l] = -a.d[l];
  return a;
}
template <int L>
LaneDual<L> operator+(const LaneDual<L>& a) {
  return a;
}
// With a constant: no product of lanes.
template <int L>
LaneDual<L> operator*(LaneDual<L> a, double b) {
  a.v *= b;
  for (int l = 0; l < L; ++l) a.d[l] *= b;
  return a;
}
template <int L>
LaneDual<L> operator*(double b, LaneDual<L> a) {
  return a * b;
}
template <int L>
LaneDual<L> operator/(LaneDual<L> a, double b) {
  return a * (1.0 / b);
}
template <int L>
LaneDual<L> operator/(double a, const LaneDual<L>& b) {
  return LaneDual<L>(a) / b;
}
template <int L>
LaneDual<L> operator+(LaneDual<L> a, double b) {
  a.v += b;
  return a;
}
template <int L>
LaneDual<L> operator+(double b, LaneDual<L> a) {
  a.v += b;
  return a;
}
template <int L>
LaneDual<L> operator-(LaneDual<L> a, double b) {
  a.v -= b;
  return a;
}
template <int L>
LaneDual<L> operator-(double b, const LaneDual<L>& a) {
  return -a + b;
}
template <int L>
LaneDual<L> sin(const LaneDual<L>& a) {
  LaneDual<L> r;
  r.v = std::sin(a.v);
  const double c = std::cos(a.v);
  for (int l = 0; l < L; ++l) r.d[l] = c * a.d[l];
  return r;
}
template <int L>
LaneDual<L> cos(const LaneDual<L>& a) {
  LaneDual<L> r;
  r.v = std::cos(a.v);
  const double s = -std::sin(a.v);
  for (int l = 0; l < L; ++l) r.d[l] = s * a.d[l];
  return r;
}

}  // namespace ukdyn

namespace Eigen {

template <int L>
struct NumTraits<ukdyn::LaneDual<L>> : NumTraits<double> {
  using Real = ukdyn::LaneDual<L>;
  using NonInteger = Real;
  using Literal = Real;
  using Nested = Real;
  enum {
    IsComplex = 0,
    IsInteger = 0,
    IsSigned = 1,
    RequireInitialization = 1,
    ReadCost = L + 1,
    AddCost = L + 1,
    MulCost = 2 * L + 1
  };
};

template <int L, typename Op>
struct ScalarBinaryOpTraits<ukdyn::LaneDual<L>, double, Op> {
  using ReturnType = ukdyn::LaneDual<L>;
};
template <int L, typename Op>
struct ScalarBinaryOpTraits<double, ukdyn::LaneDual<L>, Op> {
  using ReturnType = ukdyn::LaneDual<L>;
};

}  // namespace Eigen
