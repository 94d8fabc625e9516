// The rigid tree's sin and cos of a joint angle (src/tree/sin_cos.hpp: a Cody–Waite reduction by
// π/2 and fdlibm's polynomial kernels) against the C library's std::sin and std::cos: within
// 1 ulp everywhere, on random angles of every range a joint meets, on the doubles next to the
// multiples of π/2 (where the reduction cancels most), and the special values.
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>

#include "tree/sin_cos.hpp"

namespace {

// The distance of a and b in units in the last place (both finite, of one sign, or both zero).
std::int64_t ulps(double a, double b) {
  if (a == b) return 0;
  if (std::signbit(a) != std::signbit(b)) return std::numeric_limits<std::int64_t>::max();
  const auto ia = std::bit_cast<std::int64_t>(a), ib = std::bit_cast<std::int64_t>(b);
  return ia > ib ? ia - ib : ib - ia;
}

void expect_close(double x) {
  double s = 0.0, c = 0.0;
  ukdyn::tree::trig::sin_cos(x, s, c);
  EXPECT_LE(ulps(s, std::sin(x)), 1) << "sin " << x;
  EXPECT_LE(ulps(c, std::cos(x)), 1) << "cos " << x;
}

TEST(TreeSinCos, WithinOneUlpOfTheCLibraryOnRandomAngles) {
  std::mt19937_64 rng(20261205);
  for (const double range : {0.5, 1.0, 3.5, 7.0, 40.0, 1e3, 99999.0}) {
    std::uniform_real_distribution<double> u(-range, range);
    for (int i = 0; i < 20000; ++i) expect_close(u(rng));
  }
}

TEST(TreeSinCos, WithinOneUlpNextToTheMultiplesOfHalfPi) {
  // x − n π/2 cancels to a few bits of x here: the reduction's second and third parts.
  for (int k = -40000; k <= 40000; k += 7) {
    double x = k * 1.5707963267948966;
    for (int d = 0; d < 3; ++d) {
      expect_close(x);
      expect_close(-x);
      x = std::nextafter(x, 1e9);
    }
  }
}

TEST(TreeSinCos, SpecialValues) {
  double s = 1.0, c = 0.0;
  ukdyn::tree::trig::sin_cos(-0.0, s, c);
  EXPECT_TRUE(s == 0.0 && std::signbit(s));  // sin(−0) = −0
  EXPECT_EQ(c, 1.0);
  ukdyn::tree::trig::sin_cos(0.0, s, c);
  EXPECT_TRUE(s == 0.0 && !std::signbit(s));
  EXPECT_EQ(c, 1.0);
  for (const double x : {1e-300, -4e-320, 0.7853981633974483, 0.7853981633974484, 2.356194490192345,
                         3.141592653589793, -3.141592653589793, 1e5, -1e5, 1e300}) {
    expect_close(x);
  }
  ukdyn::tree::trig::sin_cos(std::numeric_limits<double>::infinity(), s, c);
  EXPECT_TRUE(std::isnan(s) && std::isnan(c));
  ukdyn::tree::trig::sin_cos(std::numeric_limits<double>::quiet_NaN(), s, c);
  EXPECT_TRUE(std::isnan(s) && std::isnan(c));
}

}  // namespace
