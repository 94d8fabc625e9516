// The expression parser (src/symbolic/expression.cpp). (Split from the former test_symbolic.cpp.)
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

double num(const ex& e) { return GiNaC::ex_to<GiNaC::numeric>(e.evalf()).to_double(); }

// ------------------------------------------------------------------------------------ parser

TEST(SymbolicParser, ReadsDecimalsExactlyAndRespectsPrecedence) {
  sym::Scope s;
  const GiNaC::symbol x("x");
  s.add("x", x);
  EXPECT_TRUE(s.parse("0.855").is_equal(GiNaC::numeric(171, 200)));
  EXPECT_TRUE(s.parse("1.5e-3").is_equal(GiNaC::numeric(3, 2000)));
  EXPECT_TRUE(s.parse("2e2").is_equal(GiNaC::numeric(200)));
  EXPECT_TRUE((s.parse("-x^2") + GiNaC::pow(x, 2)).is_zero());  // −(x²), not (−x)²
  EXPECT_TRUE((s.parse("2^3^2") - 512).is_zero());              // right-associative
  EXPECT_TRUE((s.parse("x**2 - x*x")).is_zero());
  EXPECT_TRUE((s.parse("1/2/x") - 1 / (2 * x)).is_zero());
  EXPECT_NEAR(num(s.parse("cos(pi/3) + sqrt(4) + atan2(1, 1)")), 0.5 + 2 + std::numbers::pi / 4,
              1e-15);
}

TEST(SymbolicParser, ErrorsNameTheColumn) {
  sym::Scope s;
  s.add("theta1", GiNaC::symbol("theta1"));
  auto offset_of = [&](const std::string& text) -> long {
    try {
      (void)s.parse(text);
    } catch (const sym::ExpressionError& e) {
      return static_cast<long>(e.offset);
    }
    return -1;
  };
  EXPECT_EQ(offset_of("l1*cos(theta1)"), 0);  // unknown symbol l1
  EXPECT_EQ(offset_of("2*cos(theta1"), 12);   // missing ')'
  EXPECT_EQ(offset_of("theta1 + * 2"), 9);    // '*' where an operand belongs
  EXPECT_EQ(offset_of("2theta1"), 1);         // implicit product
  EXPECT_EQ(offset_of("foo(theta1)"), 0);     // unknown function
  EXPECT_EQ(offset_of("sin(theta1, 2)"), 0);  // arity
  EXPECT_EQ(offset_of("theta1 )"), 7);        // trailing garbage
  EXPECT_EQ(offset_of(""), 0);
  try {
    (void)s.parse("theta1 + thet");
  } catch (const sym::ExpressionError& e) {
    EXPECT_NE(std::string(e.what()).find("unknown symbol 'thet'"), std::string::npos) << e.what();
  }
  EXPECT_THROW(s.add("t", GiNaC::symbol("t")), sym::ExpressionError);    // reserved
  EXPECT_THROW(s.add("sin", GiNaC::symbol("s")), sym::ExpressionError);  // a function
  EXPECT_THROW(s.add("theta1", GiNaC::symbol("u")), sym::ExpressionError);
}

}  // namespace
