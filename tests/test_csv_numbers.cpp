// The numbers of trajectory.csv (src/output/shortest_double.hpp): io_detail::write_shortest, the
// writer's own formatting (Dragonbox digits laid out by libstdc++'s rule), writes exactly the text
// of std::to_chars(first, last, value) (Ryū's digits, the library's layout: a second, independent
// implementation of the same C++17 rule), and every text reads back (std::from_chars) to the same
// bits. Values: random bit patterns (every exponent, subnormals), numbers of the size a run writes,
// short decimals, powers of two and ten with their neighbours (where the digits round and the
// layout switches between fixed and scientific), zero, infinities, NaN.
#include <gtest/gtest.h>

#include <bit>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "output/shortest_double.hpp"

namespace {

using ukdyn::io_detail::kShortestDoubleChars;
using ukdyn::io_detail::write_shortest;

std::vector<double> values_to_check() {
  std::vector<double> v{0.0,
                        -0.0,
                        std::numeric_limits<double>::infinity(),
                        -std::numeric_limits<double>::infinity(),
                        std::numeric_limits<double>::quiet_NaN(),
                        std::numeric_limits<double>::max(),
                        std::numeric_limits<double>::min(),
                        std::numeric_limits<double>::denorm_min(),
                        -std::numeric_limits<double>::denorm_min(),
                        1e23,                     // 9.999999999999999e22 as a double
                        9007199254740993.0,       // 2^53 + 1 rounded
                        123456789012345680000.0,  // whole, digits beyond the significand
                        1e21,
                        -2.2250738585072014e-308};
  std::mt19937_64 g(2024);
  for (int i = 0; i < 100000; ++i) {
    v.push_back(std::bit_cast<double>(g()));
    const double x = std::ldexp(static_cast<double>(g() >> 11), -53) *
                     std::pow(10.0, static_cast<int>(g() % 40) - 20);
    v.push_back(x);
    v.push_back(-x);
    v.push_back(static_cast<double>(static_cast<std::int64_t>(g() % 2000001) - 1000000) /
                std::pow(10.0, static_cast<int>(g() % 12)));
    v.push_back(static_cast<double>(g() % 100000000000000000ULL) *
                std::pow(10.0, static_cast<int>(g() % 30) - 5));
  }
  for (int k = -325; k <= 308; ++k)
    for (const int m : {1, 2, 5, 9, 10, 12, 99, 123, 4567, 99999}) {
      const double x = m * std::pow(10.0, k);
      v.insert(v.end(), {x, std::nextafter(x, 0.0), std::nextafter(x, 2 * x), -x});
    }
  for (int k = -1074; k <= 1023; ++k) {
    const double p = std::ldexp(1.0, k);
    v.insert(v.end(), {p, std::nextafter(p, 0.0), std::nextafter(p, 2 * p)});
  }
  return v;
}

TEST(CsvNumbers, ShortestTextIsStdToCharsText) {
  long differ = 0;
  for (const double x : values_to_check()) {
    char a[64], b[kShortestDoubleChars];
    const auto ra = std::to_chars(a, a + sizeof a, x);
    ASSERT_EQ(ra.ec, std::errc{});
    char* const eb = write_shortest(b, x);
    ASSERT_LE(eb - b, kShortestDoubleChars);
    const std::string ta(a, ra.ptr), tb(b, eb);
    if (ta != tb && ++differ <= 10) ADD_FAILURE() << "to_chars " << ta << ", written " << tb;
  }
  EXPECT_EQ(differ, 0);
}

TEST(CsvNumbers, EveryTextReadsBackBitForBit) {
  for (const double x : values_to_check()) {
    if (std::isnan(x)) continue;
    char b[kShortestDoubleChars];
    char* const eb = write_shortest(b, x);
    double y = 0.0;
    const auto r = std::from_chars(b, eb, y);
    ASSERT_EQ(r.ec, std::errc{}) << std::string(b, eb);
    ASSERT_EQ(r.ptr, eb) << std::string(b, eb);
    ASSERT_EQ(std::bit_cast<std::uint64_t>(y), std::bit_cast<std::uint64_t>(x))
        << std::string(b, eb);
  }
}

}  // namespace
