// Printing derivations (src/symbolic/format.cpp): LaTeX, C and MATLAB.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

#include "helpers.hpp"
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
