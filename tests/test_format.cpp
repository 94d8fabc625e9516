// Printing derivations (src/symbolic/format.cpp, canonical_print.cpp): LaTeX, C and MATLAB.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <iostream>
#include <map>
#include <numbers>
#include <random>
#include <regex>
#include <sstream>

#include "helpers.hpp"
#include "symbolic/canonical_print.hpp"
#include "ukdyn/symbolic/definitions.hpp"

namespace {

namespace sym = ukdyn::symbolic;
using GiNaC::ex;
using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;

TEST(SymbolicFormat, PrintsLatexCAndMatlab) {
  sym::SubsystemDef d("pend", {"fm_phi"});
  d.parameter("m", 2);
  d.parameter("l", 0.5);
  auto& b = d.add_body("bob");
  b.mass = d.parse("m");
  b.com = {d.parse("l*sin(fm_phi)"), 0, d.parse("-l*cos(fm_phi)")};
  d.gravity = {0, 0, -9.8};
  const auto der = sym::derive(d);
  const std::string latex = sym::format_derivation(der, "pend", sym::Format::latex);
  EXPECT_NE(latex.find("\\begin{align*}"), std::string::npos);
  EXPECT_NE(latex.find("\\sin(\\mathrm{fm}_{phi})"), std::string::npos) << latex;
  const std::string c = sym::format_derivation(der, "pend", sym::Format::c);
  EXPECT_NE(c.find("M[0][0] = "), std::string::npos) << c;
  EXPECT_NE(c.find("const double m = "), std::string::npos) << c;
  const std::string mat = sym::format_derivation(der, "pend", sym::Format::matlab);
  EXPECT_NE(mat.find("M(1,1) = "), std::string::npos) << mat;
  EXPECT_NE(mat.find("G(1) = "), std::string::npos) << mat;
  // M = m l², G = m g l sin φ, exactly.
  EXPECT_TRUE((der.M(0, 0) - GiNaC::pow(d.parse("l"), 2) * d.parse("m")).is_zero());
}

}  // namespace

namespace {

// A row with acos(t): its b holds (1 − t²)^(−3/2), which GiNaC cannot collect as a polynomial in
// t (it throws "undefined degree because of non-integer exponent"); every format still prints it
// (the fuzzer's finding, fuzz/expression_seeds/noninteger_exponent_of_t.txt).
TEST(SymbolicFormat, PrintsNonIntegerPowersOfTime) {
  sym::ConstraintDef d("c", sym::ConstraintDef::Kind::holonomic, {"fx", "fy"});
  d.add_row("r", d.parse("log(2 + acos(t)) - fx"));
  const auto der = sym::derive(d);
  for (auto f : {sym::Format::latex, sym::Format::c, sym::Format::matlab, sym::Format::text}) {
    std::string out;
    EXPECT_NO_THROW(out = sym::format_derivation(der, "c", f));
    EXPECT_NE(out.find(f == sym::Format::latex ? "arccos" : "acos"), std::string::npos) << out;
  }
}

}  // namespace

// canonical_print (src/symbolic/canonical_print.cpp): every format prints the expression itself,
// checked by reading the text back (GiNaC's parser; the C and LaTeX texts first rewritten into its
// syntax) and evaluating both at random points; and the text depends on the expression only, not
// on GiNaC's operand order.
namespace {

using GiNaC::numeric;

// A random expression of depth ≤ `depth` in the symbols s: sums, products, integer and rational
// powers, sin, cos, exp, atan2 and pi, with rational coefficients of either sign.
ex random_ex(std::mt19937_64& rng, int depth, const std::vector<GiNaC::symbol>& s) {
  std::uniform_int_distribution<int> pick(0, 9), small(-4, 4),
      idx(0, static_cast<int>(s.size()) - 1);
  const auto rational = [&] {
    return numeric(small(rng) == 0 ? 1 : small(rng), 1 + (pick(rng) % 3));
  };
  if (depth == 0) return pick(rng) < 8 ? ex(s[static_cast<std::size_t>(idx(rng))]) : ex(rational());
  const auto sub = [&] { return random_ex(rng, depth - 1, s); };
  switch (pick(rng)) {
    case 0:
    case 1:
    case 2:
      return rational() * sub() + sub() - rational() * sub() + rational();
    case 3:
    case 4:
      return rational() * sub() * sub() * sub();
    case 5:
      return GiNaC::pow(sub(), small(rng) == 0 ? 2 : small(rng)) * sub();
    case 6:
      return GiNaC::sin(sub()) * GiNaC::cos(sub()) + GiNaC::Pi * sub();
    case 7:
      return GiNaC::sqrt(GiNaC::pow(sub(), 2) + 1) +
             GiNaC::pow(GiNaC::pow(sub(), 2) + 2, numeric(-3, 2));
    case 8:
      return GiNaC::exp(-sub() / 3) * GiNaC::atan2(sub(), GiNaC::pow(sub(), 2) + 1);
    default:
      return sub() / (GiNaC::pow(sub(), 2) + 1) - sub() / (sub() * sub());
  }
}

// LaTeX as GiNaC's parser reads it: \frac{a}{b} → ((a)/(b)), \sqrt{a} → sqrt(a), groups {..} →
// (..), a space between factors → *, \sin → sin, \ln → log, \arctan → atan, \pi → pi,
// \mbox{atan2} → atan2.
void from_latex(const std::string& s, std::size_t& i, std::string& out, char stop) {
  while (i < s.size() && s[i] != stop) {
    const auto group = [&](const std::string& before, const std::string& after) {
      out += before;
      from_latex(s, i, out, '}');
      ++i;
      out += after;
    };
    if (s.compare(i, 6, "\\frac{") == 0) {
      i += 6;
      group("((", ")/(");
      ++i;  // '{'
      group("", "))");
    } else if (s.compare(i, 6, "\\sqrt{") == 0) {
      i += 6;
      group("sqrt(", ")");
    } else if (s.compare(i, 12, "\\mbox{atan2}") == 0) {
      i += 12;
      out += "atan2";
    } else if (s[i] == '\\') {
      std::string name;
      for (++i; i < s.size() && std::isalpha(static_cast<unsigned char>(s[i])); ++i) name += s[i];
      out += name == "ln" ? "log" : name == "arctan" ? "atan" : name;
    } else if (s[i] == '{') {
      ++i;
      group("(", ")");
    } else {
      out += s[i] == ' ' ? '*' : s[i];
      ++i;
    }
  }
}

std::string parseable(const std::string& text, sym::Format f) {
  if (f == sym::Format::latex) {
    std::string out;
    std::size_t i = 0;
    from_latex(text, i, out, '\0');
    return out;
  }
  if (f == sym::Format::c) return std::regex_replace(text, std::regex("M_PI"), "pi");
  return text;
}

// e at the point (a complex number: roots of negative numbers are allowed, the same on both sides).
numeric value(const ex& e, const GiNaC::exmap& point) {
  const ex v = GiNaC::evalf(e.subs(point));
  EXPECT_TRUE(GiNaC::is_a<numeric>(v)) << v;
  return GiNaC::is_a<numeric>(v) ? GiNaC::ex_to<numeric>(v) : numeric(0);
}

TEST(CanonicalPrint, EveryFormatPrintsTheExpression) {
  const std::vector<GiNaC::symbol> s = {GiNaC::symbol("x"), GiNaC::symbol("y"), GiNaC::symbol("z"),
                                        GiNaC::symbol("w")};
  GiNaC::symtab table;
  for (const auto& x : s) table[x.get_name()] = x;
  table["pi"] = GiNaC::Pi;
  std::mt19937_64 rng(2024);
  std::uniform_real_distribution<double> u(0.2, 1.7);
  int checked = 0;
  for (int n = 0; n < 300; ++n) {
    ex e;
    try {
      e = random_ex(rng, 1 + n % 3, s);
    } catch (const std::exception&) {  // a division by a sum that cancelled to 0
      continue;
    }
    GiNaC::exmap point;
    for (const auto& x : s) point[x] = u(rng);
    const numeric want = value(e, point);
    for (auto f : {sym::Format::latex, sym::Format::c, sym::Format::matlab, sym::Format::text}) {
      const std::string text = sym::canonical_print(e, f);
      ex back;
      try {
        GiNaC::parser read(table, true);
        back = read(parseable(text, f));
      } catch (const std::exception& err) {
        ADD_FAILURE() << "format " << static_cast<int>(f) << ": " << err.what() << "\n" << text;
        continue;
      }
      const numeric got = value(back, point);
      EXPECT_LE(GiNaC::abs(got - want).to_double(), 1e-9 * (1 + GiNaC::abs(want).to_double()))
          << "format " << static_cast<int>(f) << "\n"
          << text << "\nexpression " << e;
      ++checked;
    }
  }
  EXPECT_GE(checked, 1000);
}

// The same expression built over symbols made in another order (GiNaC orders the operands of
// sums and products by hashes of the symbols' serial numbers, so its own printing of the two
// differs): the same text in every format.
TEST(CanonicalPrint, TextDependsOnTheExpressionOnly) {
  const std::vector<std::string> names = {"a", "b", "c", "d", "e1", "f"};
  std::vector<GiNaC::symbol> first, second;
  for (const auto& n : names) first.emplace_back(n);
  for (auto it = names.rbegin(); it != names.rend(); ++it) second.emplace_back(*it);
  std::reverse(second.begin(), second.end());
  int ginac_differs = 0;
  for (int n = 0; n < 200; ++n) {
    std::mt19937_64 r1(static_cast<unsigned>(n)), r2(static_cast<unsigned>(n));
    ex e1, e2;
    try {
      e1 = random_ex(r1, 1 + n % 3, first);
      e2 = random_ex(r2, 1 + n % 3, second);
    } catch (const std::exception&) {  // a division by a sum that cancelled to 0
      continue;
    }
    std::ostringstream g1, g2;
    g1 << e1;
    g2 << e2;
    ginac_differs += g1.str() != g2.str();
    for (auto f : {sym::Format::latex, sym::Format::c, sym::Format::matlab, sym::Format::text})
      EXPECT_EQ(sym::canonical_print(e1, f), sym::canonical_print(e2, f)) << g1.str();
  }
  // The test has teeth: GiNaC's own order differs for some of these (printed, not asserted: it
  // depends on GiNaC's hash).
  std::cout << "GiNaC's own text differs for " << ginac_differs << " of 200 expressions\n";
}

}  // namespace

namespace {

// A derivation printed by format_derivation reads back as itself: every entry of M, C, G of a
// planar double pendulum (text, MATLAB and C lines re-read by GiNaC's parser, the C numbers as
// floats) against the derived entry at random points, symbols matched by name.
TEST(CanonicalPrint, ADerivationReadsBackAsItself) {
  sym::SubsystemDef d("dp", {"a1", "a2"});
  d.parameter("m1", 2);
  d.parameter("m2", 0.75);
  d.parameter("l1", 0.5);
  d.parameter("l2", 0.3);
  auto& b1 = d.add_body("b1");
  b1.mass = d.parse("m1");
  b1.com = {d.parse("l1*sin(a1)"), 0, d.parse("-l1*cos(a1)")};
  auto& b2 = d.add_body("b2");
  b2.mass = d.parse("m2");
  b2.com = {d.parse("l1*sin(a1) + l2*sin(a1 + a2)"), 0, d.parse("-l1*cos(a1) - l2*cos(a1 + a2)")};
  d.gravity = {0, 0, -9.8};
  const auto der = sym::derive(d);
  std::map<std::string, ex> by_name;  // the derivation's symbols by name
  for (const GiNaC::matrix* m : {&der.M, &der.C, &der.G}) {
    for (unsigned i = 0; i < m->nops(); ++i) {
      for (auto it = m->op(i).preorder_begin(); it != m->op(i).preorder_end(); ++it)
        if (GiNaC::is_a<GiNaC::symbol>(*it))
          by_name.emplace(GiNaC::ex_to<GiNaC::symbol>(*it).get_name(), *it);
    }
  }
  GiNaC::symtab table(by_name.begin(), by_name.end());
  table["pi"] = table["M_PI"] = GiNaC::Pi;
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-1.5, 1.5);
  int entries = 0;
  for (auto f : {sym::Format::text, sym::Format::matlab, sym::Format::c}) {
    std::istringstream lines(sym::format_derivation(der, "dp", f));
    const std::regex entry(f == sym::Format::c ? R"(\s*([MCG])\[(\d)\](?:\[(\d)\])? = (.*);)"
                                               : R"(([MCG])\((\d)(?:,(\d))?\) = (.*);)");
    for (std::string line; std::getline(lines, line);) {
      std::smatch m;
      if (!std::regex_match(line, m, entry)) continue;
      if (std::regex_search(m[4].str(), std::regex("^[MCG][[(]"))) continue;  // a symmetric copy
      const unsigned base = f == sym::Format::c ? 0 : 1;
      const unsigned i = static_cast<unsigned>(std::stoi(m[2])) - base;
      const unsigned j = m[3].matched ? static_cast<unsigned>(std::stoi(m[3])) - base : 0;
      const GiNaC::matrix& mat = m[1] == "M" ? der.M : m[1] == "C" ? der.C : der.G;
      GiNaC::parser read(table, true);
      const ex back = read(m[4].str());
      GiNaC::exmap point;
      for (const auto& [n, s] : by_name) point[s] = u(rng);
      const numeric want = value(mat(i, j), point), got = value(back, point);
      EXPECT_LE(GiNaC::abs(got - want).to_double(), 1e-12 * (1 + GiNaC::abs(want).to_double()))
          << line;
      ++entries;
    }
  }
  EXPECT_GE(entries, 3 * 6);  // M's upper triangle (3), C (≥ 1), G (2) in each format
}

}  // namespace
