#include "ukdyn/output/csv_writer.hpp"

#include <fmt/format.h>

#include <array>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <system_error>

#include "output/shortest_double.hpp"
#include "ukdyn/text/safe_text.hpp"

namespace ukdyn {

namespace io_detail {

namespace {

// "00", "01", …, "99": two digits a step.
constexpr std::array<char, 200> kDigitPairs = [] {
  std::array<char, 200> t{};
  for (int i = 0; i < 100; ++i) {
    t[static_cast<std::size_t>(2 * i)] = static_cast<char>('0' + i / 10);
    t[static_cast<std::size_t>(2 * i + 1)] = static_cast<char>('0' + i % 10);
  }
  return t;
}();

constexpr std::array<std::uint64_t, 18> kPow10 = [] {
  std::array<std::uint64_t, 18> t{};
  t[0] = 1;
  for (std::size_t i = 1; i < t.size(); ++i) t[i] = 10 * t[i - 1];
  return t;
}();

// The number of decimal digits of m (0 < m < 10^17): ⌊log10 m⌋ + 1 from the bit width (log10 2 ≈
// 1233 / 4096), one comparison to correct it.
int digit_count(std::uint64_t m) {
  const int guess = (static_cast<int>(std::bit_width(m)) * 1233) >> 12;
  return guess + (m >= kPow10[static_cast<std::size_t>(guess)] ? 1 : 0);
}

// Writes the len digits of m ending at end (backwards, two at a time; 32-bit arithmetic below
// 10^8).
void write_digits(std::uint64_t m, char* end) {
  while (m >= 100000000) {
    auto lo = static_cast<std::uint32_t>(m % 100000000);
    m /= 100000000;
    for (int k = 0; k < 4; ++k, lo /= 100) {
      end -= 2;
      std::memcpy(end, &kDigitPairs[2 * (lo % 100)], 2);
    }
  }
  auto x = static_cast<std::uint32_t>(m);
  for (; x >= 100; x /= 100) {
    end -= 2;
    std::memcpy(end, &kDigitPairs[2 * (x % 100)], 2);
  }
  if (x >= 10) {
    std::memcpy(end - 2, &kDigitPairs[2 * x], 2);
  } else {
    end[-1] = static_cast<char>('0' + x);
  }
}

// The exponent of the scientific form: "e", its sign, at least two digits.
char* write_exponent(char* p, int exp10) {
  *p++ = 'e';
  *p++ = exp10 < 0 ? '-' : '+';
  auto a = static_cast<unsigned>(exp10 < 0 ? -exp10 : exp10);
  if (a >= 100) {
    *p++ = static_cast<char>('0' + a / 100);
    a %= 100;
  }
  std::memcpy(p, &kDigitPairs[2 * a], 2);
  return p + 2;
}

}  // namespace

// libstdc++'s choice (src/c++17/floating_to_chars.cc, __floating_to_chars_shortest) on the same
// shortest digits m · 10^e (len of them): fixed iff −(len + 3) ≤ e ≤ 5 (one digit: −(len + 2) ≤
// e ≤ 4, the point of the scientific form being left out), the two lengths compared. A whole
// number whose digits do not fit the 53-bit significand is written exactly in fixed notation
// there, not as m followed by zeros: that case, infinities and NaN go to std::to_chars.
char* write_shortest(char* out, double v) {
  if (v == 0.0) {  // "0", "-0"
    if (std::signbit(v)) *out++ = '-';
    *out = '0';
    return out + 1;
  }
  if (!std::isfinite(v)) return std::to_chars(out, out + kShortestDoubleChars, v).ptr;
  const auto dec = fmt::detail::dragonbox::to_decimal(v);
  std::uint64_t m = dec.significand;
  int e = dec.exponent;
  while (m % 10 == 0) {  // the shortest digits carry no trailing zero
    m /= 10;
    ++e;
  }
  const int len = digit_count(m);
  const bool fixed = len == 1 ? e >= -(len + 2) && e <= 4 : e >= -(len + 3) && e <= 5;
  if (fixed && e >= 0 && static_cast<int>(std::bit_width(m)) - 1 + (e * 10 + 2) / 3 >= 50)
    return std::to_chars(out, out + kShortestDoubleChars, v).ptr;
  char* p = out;
  if (v < 0) *p++ = '-';
  if (!fixed) {  // d.ddd: the digits one place on, the first moved in front of the point
    write_digits(m, p + 1 + len);
    p[0] = p[1];
    if (len == 1) return write_exponent(p + 1, e);
    p[1] = '.';
    return write_exponent(p + 1 + len, e + len - 1);
  }
  if (e >= 0) {  // a whole number: its digits, then e zeros
    write_digits(m, p + len);
    std::memset(p + len, '0', static_cast<std::size_t>(e));
    return p + len + e;
  }
  const int whole = len + e;  // digits before the point
  if (whole <= 0) {           // 0.000ddd
    *p++ = '0';
    *p++ = '.';
    std::memset(p, '0', static_cast<std::size_t>(-whole));
    write_digits(m, p - whole + len);
    return p - whole + len;
  }
  write_digits(m, p + 1 + len);  // ddd.ddd: the whole digits moved one place back
  std::memmove(p, p + 1, static_cast<std::size_t>(whole));
  p[whole] = '.';
  return p + 1 + len;
}

}  // namespace io_detail

CsvWriter::CsvWriter(const OutputDir& dir, std::string name, const std::vector<std::string>& header)
    : file_(dir, dir.fd(), "", std::move(name)), columns_(header.size()) {
  std::string line;
  for (std::size_t i = 0; i < header.size(); ++i) {
    if (i) line += ',';
    line += csv_field(header[i]);
  }
  line += '\n';
  file_.write(line);
  file_.flush();
}

void CsvWriter::row(const std::vector<double>& values) {
  if (values.size() != columns_) throw Error("CsvWriter: row has the wrong number of columns");
  // Each number in its shortest form that reads back to the same double (the text of
  // std::to_chars without a precision, io_detail::write_shortest: exact, the CSV holds the run's
  // doubles bit for bit), written straight into the row's buffer.
  buffer_.resize(values.size() * (io_detail::kShortestDoubleChars + 1) + 1);
  char* p = buffer_.data();
  for (std::size_t i = 0; i < values.size(); ++i) {
    if (i) *p++ = ',';
    p = io_detail::write_shortest(p, values[i]);
  }
  *p++ = '\n';
  buffer_.resize(static_cast<std::size_t>(p - buffer_.data()));
  file_.write(buffer_);
  ++rows_;
  if (rows_ % 64 == 0 || file_.buffered() > (std::size_t{1} << 20)) {
    file_.flush();
    rows_flushed_ = rows_;
  }
}

void CsvWriter::commit() {
  file_.commit();
  rows_flushed_ = rows_;
}

std::string CsvWriter::incomplete_name(const std::string& name) {
  const auto dot = name.rfind('.');
  return (dot == std::string::npos ? name : name.substr(0, dot)) + ".incomplete.csv";
}

std::string CsvWriter::abandon() noexcept {
  try {
    file_.flush();
    rows_flushed_ = rows_;
  } catch (...) {  // the disk is full: keep the rows handed over before
  }
  std::string as;
  try {
    as = incomplete_name(file_.name());
  } catch (...) {
    return {};
  }
  return file_.commit_truncated(as) ? as : std::string{};
}

}  // namespace ukdyn
