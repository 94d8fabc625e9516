// sin θ and cos θ of one joint angle together, without a call into the C library: the placement
// of a rigid tree (tree.cpp) needs both for every revolute joint, and glibc's sincos cost about a
// sixth of the arms' placement. The argument is reduced by the nearest multiple n of π/2 with π/2
// split into three parts (Cody and Waite's reduction as in fdlibm's e_rem_pio2.c, Sun
// Microsystems 1993, in the form of musl's __rem_pio2.c: a second and third part only when the
// first leaves too few bits), and sin, cos on [−π/4, π/4] are fdlibm's polynomial kernels
// (k_sin.c, k_cos.c: error below 1 ulp there). Arguments of magnitude 1e5 or more, ∞ and NaN go
// to std::sin and std::cos. tests/test_tree_sin_cos.cpp checks the result against the C
// library's to 1 ulp.
//
// The kernels and the reduction's constants follow fdlibm, whose notice is kept as it asks:
//   Copyright (C) 1993 by Sun Microsystems, Inc. All rights reserved.
//   Developed at SunPro, a Sun Microsystems, Inc. business.
//   Permission to use, copy, modify, and distribute this software is freely granted, provided
//   that this notice is preserved.
#pragma once

#include <bit>
#include <cmath>
#include <cstdint>

namespace ukdyn::tree::trig {

// fdlibm's __kernel_sin(x, y, iy) for |x + y| ≤ π/4 (y: the tail of a reduced argument, tail:
// whether there is one).
inline double kernel_sin(double x, double y, bool tail) {
  constexpr double S1 = -1.66666666666666324348e-01;  // 0xBFC55555 55555549
  constexpr double S2 = 8.33333333332248946124e-03;   // 0x3F811111 1110F8A6
  constexpr double S3 = -1.98412698298579493134e-04;  // 0xBF2A01A0 19C161D5
  constexpr double S4 = 2.75573137070700676789e-06;   // 0x3EC71DE3 57B1FE7D
  constexpr double S5 = -2.50507602534068634195e-08;  // 0xBE5AE5E6 8A2B9CEB
  constexpr double S6 = 1.58969099521155010221e-10;   // 0x3DE5D93A 5ACFD57C
  const double z = x * x, w = z * z;
  const double r = S2 + z * (S3 + z * S4) + z * w * (S5 + z * S6);
  const double v = z * x;
  if (!tail) return x + v * (S1 + z * r);
  return x - ((z * (0.5 * y - v * r) - y) - v * S1);
}

// fdlibm's __kernel_cos(x, y) for |x + y| ≤ π/4.
inline double kernel_cos(double x, double y) {
  constexpr double C1 = 4.16666666666666019037e-02;   // 0x3FA55555 5555554C
  constexpr double C2 = -1.38888888888741095749e-03;  // 0xBF56C16C 16C15177
  constexpr double C3 = 2.48015872894767294178e-05;   // 0x3EFA01A0 19CB1590
  constexpr double C4 = -2.75573143513906633035e-07;  // 0xBE927E4F 809C52AD
  constexpr double C5 = 2.08757232129817482790e-09;   // 0x3E21EE9E BDB4B1C4
  constexpr double C6 = -1.13596475577881948265e-11;  // 0xBDA8FAE9 BE8838D4
  const double z = x * x, w = z * z;
  const double r = z * (C1 + z * (C2 + z * C3)) + w * w * (C4 + z * (C5 + z * C6));
  const double hz = 0.5 * z, u = 1.0 - hz;
  return u + (((1.0 - u) - hz) + (z * r - x * y));
}

// The biased exponent of x.
inline int exponent_bits(double x) {
  return static_cast<int>((std::bit_cast<std::uint64_t>(x) >> 52) & 0x7ff);
}

// n and x − n π/2 = y0 + y1 (|y0 + y1| ≤ π/4 up to round-off) for |x| < 1e5.
inline int reduce_half_pi(double x, double& y0, double& y1) {
  constexpr double toint = 6755399441055744.0;            // 1.5 / DBL_EPSILON: rounds to an integer
  constexpr double invpio2 = 6.36619772367581382433e-01;  // 0x3FE45F30 6DC9C883
  constexpr double pio2_1 = 1.57079632673412561417e+00;   // 0x3FF921FB 54400000: 33 bits of π/2
  constexpr double pio2_1t = 6.07710050650619224932e-11;  // 0x3DD0B461 1A626331: π/2 − pio2_1
  constexpr double pio2_2 = 6.07710050630396597660e-11;   // 0x3DD0B461 1A600000: 33 more bits
  constexpr double pio2_2t = 2.02226624879595063154e-21;  // 0x3BA3198A 2E037073
  constexpr double pio2_3 = 2.02226624871116645580e-21;   // 0x3BA3198A 2E000000: 33 more bits
  constexpr double pio2_3t = 8.47842766036889956997e-32;  // 0x397B839A 252049C1
  const double fn = x * invpio2 + toint - toint;
  const int n = static_cast<int>(fn);
  double r = x - fn * pio2_1;
  double w = fn * pio2_1t;  // good to 85 bits
  y0 = r - w;
  const int ex = exponent_bits(x);
  if (ex - exponent_bits(y0) > 16) {  // cancellation: a second part, good to 118 bits
    double t = r;
    w = fn * pio2_2;
    r = t - w;
    w = fn * pio2_2t - ((t - r) - w);
    y0 = r - w;
    if (ex - exponent_bits(y0) > 33) {  // a third, good to 151 bits: every double below 1e5
      t = r;
      w = fn * pio2_3;
      r = t - w;
      w = fn * pio2_3t - ((t - r) - w);
      y0 = r - w;
    }
  }
  y1 = (r - y0) - w;
  return n;
}

// s = sin x, c = cos x.
inline void sin_cos(double x, double& s, double& c) {
  constexpr double pio4 = 7.85398163397448278999e-01;  // 0x3FE921FB 54442D18
  const double ax = std::abs(x);
  if (ax <= pio4) {
    s = ax < 0x1p-26 ? x : kernel_sin(x, 0.0, false);  // x itself: sin(−0) = −0
    c = kernel_cos(x, 0.0);
    return;
  }
  if (!(ax < 1e5)) {  // far arguments, ∞, NaN
    s = std::sin(x);
    c = std::cos(x);
    return;
  }
  double y0 = 0.0, y1 = 0.0;
  const int n = reduce_half_pi(x, y0, y1);
  const double sn = kernel_sin(y0, y1, true), cs = kernel_cos(y0, y1);
  switch (n & 3) {
    case 0:
      s = sn;
      c = cs;
      break;
    case 1:
      s = cs;
      c = -sn;
      break;
    case 2:
      s = -sn;
      c = -cs;
      break;
    default:
      s = -cs;
      c = sn;
      break;
  }
}

}  // namespace ukdyn::tree::trig
