// The text of a double in trajectory.csv (src/output/csv_writer.cpp): byte for byte what
// std::to_chars(first, last, value) writes (C++17 [charconv.to.chars]: the shortest digits that
// read back to the same double, in fixed or scientific notation, whichever is shorter, fixed on a
// tie), found by Dragonbox (fmt's, Jeon 2020) instead of libstdc++'s Ryū, about twice as fast.
// Internal to ukdyn::io; tests/test_outputs.cpp checks it against std::to_chars.
#pragma once

namespace ukdyn::io_detail {

/// The longest text write_shortest() writes: "-2.2250738585072014e-308" is 24 characters.
inline constexpr int kShortestDoubleChars = 24;

/// Writes v at out (room for kShortestDoubleChars characters) as std::to_chars(out, end, v) does;
/// returns the end of what it wrote.
char* write_shortest(char* out, double v);

}  // namespace ukdyn::io_detail
