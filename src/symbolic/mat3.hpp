// The 3 × 3 and 3-vector algebra of GiNaC expressions shared by the chain builder (chain.cpp) and
// the frame constraints (frame_constraints.cpp): one product, exact. Internal to ukdyn::symbolic
// (not installed). Mat3Ex is row-major (ukdyn/symbolic/chain.hpp).
//
// The products are exact: every entry is the sum Σ_k a_ik b_kj of GiNaC expressions, its numbers
// exact rationals. A caller that composes many rotations by constant angles bounds the numbers
// itself (chain.cpp, compose(): round_long_rationals of canonical.hpp, for the documented reason
// given there); nothing here rounds.
#pragma once

#include <ginac/ginac.h>

#include <cstddef>

#include "ukdyn/symbolic/chain.hpp"

namespace ukdyn::symbolic {

/// aᵀ
inline Mat3Ex transposed(const Mat3Ex& a) {
  return {a[0], a[3], a[6], a[1], a[4], a[7], a[2], a[5], a[8]};
}

/// a b: r_ij = Σ_k a_ik b_kj (k = 0, 1, 2 in order)
inline Mat3Ex mul(const Mat3Ex& a, const Mat3Ex& b) {
  Mat3Ex r;
  for (std::size_t i = 0; i < 3; ++i) {
    for (std::size_t j = 0; j < 3; ++j) {
      GiNaC::ex s = 0;
      for (std::size_t k = 0; k < 3; ++k) s += a[3 * i + k] * b[3 * k + j];
      r[3 * i + j] = s;
    }
  }
  return r;
}

/// a v: r_i = a_i0 v_0 + a_i1 v_1 + a_i2 v_2
inline Vec3Ex mul(const Mat3Ex& a, const Vec3Ex& v) {
  Vec3Ex r;
  for (std::size_t i = 0; i < 3; ++i)
    r[i] = a[3 * i] * v[0] + a[3 * i + 1] * v[1] + a[3 * i + 2] * v[2];
  return r;
}

/// aᵀ b (the same sums as mul of aᵀ)
inline Mat3Ex mul_tn(const Mat3Ex& a, const Mat3Ex& b) { return mul(transposed(a), b); }

/// aᵀ v (the same sums as mul of aᵀ)
inline Vec3Ex mul_transposed(const Mat3Ex& a, const Vec3Ex& v) { return mul(transposed(a), v); }

}  // namespace ukdyn::symbolic
