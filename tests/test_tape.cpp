// Compiled tapes (src/symbolic/tape.cpp) against GiNaC: values, shared subexpressions, fused
// products, sin/cos pairs.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

#include "helpers.hpp"
#include "ukdyn/symbolic/definitions.hpp"
#include "ukdyn/symbolic/tape_inputs.hpp"

namespace {

namespace sym = ukdyn::symbolic;
using GiNaC::ex;
using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;

double num(const ex& e) { return GiNaC::ex_to<GiNaC::numeric>(e.evalf()).to_double(); }

// ------------------------------------------------------------------------------------ tape

TEST(SymbolicTape, EvaluatesLikeGiNaCAndSharesSubexpressions) {
  sym::SymbolTable symbols;
  const GiNaC::symbol a = sym::coordinate_symbol(symbols, "tape_a"),
                      b = sym::coordinate_symbol(symbols, "tape_b");
  const GiNaC::symbol v = sym::velocity_symbol(symbols, "tape_a"), t = sym::time_symbol(symbols);
  sym::InputMap in;
  in[a] = {sym::TapeInput::Source::q, 0};
  in[b] = {sym::TapeInput::Source::q, 1};
  in[v] = {sym::TapeInput::Source::qd, 0};
  in[t] = {sym::TapeInput::Source::time, 0};
  const std::vector<ex> outs = {
      GiNaC::sin(a) * GiNaC::cos(b) -
          GiNaC::numeric(3, 7) * GiNaC::pow(v, 3) / (2 + GiNaC::pow(a, 2)),
      GiNaC::sqrt(1 + GiNaC::pow(b, 2)) + GiNaC::exp(-t) * GiNaC::atan2(a, b) +
          GiNaC::pow(GiNaC::abs(a) + 1, GiNaC::numeric(1, 3)),
      GiNaC::sin(a) * GiNaC::cos(b) + GiNaC::Pi * GiNaC::tan(a / 3) - GiNaC::log(2 + GiNaC::cos(t)),
      ex(5) / 4};
  const sym::Tape tape(outs, in);
  std::mt19937_64 rng(3);
  for (int k = 0; k < 50; ++k) {
    const double q[2] = {uktest::uniform(rng, -2, 2), uktest::uniform(rng, -2, 2)};
    const double qd[1] = {uktest::uniform(rng, -2, 2)};
    const double tt = uktest::uniform(rng, 0, 3);
    double out[4];
    tape.eval(tt, q, qd, out);
    const GiNaC::exmap at = {{a, q[0]}, {b, q[1]}, {v, qd[0]}, {t, tt}};
    for (std::size_t i = 0; i < outs.size(); ++i) {
      EXPECT_NEAR(out[i], num(outs[i].subs(at)), 1e-13 * (1 + std::abs(out[i])));
    }
  }
  // sin(a) cos(b) appears twice: with value numbering, one sin, one cos, one product.
  std::size_t sins = 0;
  const sym::Tape twice({GiNaC::sin(a) * GiNaC::cos(b), 2 * GiNaC::sin(a) * GiNaC::cos(b) + 1}, in);
  EXPECT_LE(twice.operations(), 5u);  // sin, cos, mul, mul_c, add_c
  (void)sins;
  EXPECT_THROW(sym::Tape({GiNaC::symbol("stranger")}, in), ukdyn::Error);
}

// coordinate_inputs: coordinate i reads q[i], its velocity q̇[i], the time symbol t; q binds the
// coordinates alone; q_interned skips (and does not intern) a coordinate the table does not have.
TEST(SymbolicTape, CoordinateInputsBindQQdotAndTime) {
  sym::SymbolTable symbols;
  const GiNaC::symbol a = sym::coordinate_symbol(symbols, "ci_a");
  const GiNaC::symbol b = sym::coordinate_symbol(symbols, "ci_b");
  const GiNaC::symbol ad = sym::velocity_symbol(symbols, "ci_a");
  const GiNaC::symbol t = sym::time_symbol(symbols);
  const sym::InputMap all = sym::coordinate_inputs(symbols, {"ci_a", "ci_b"});
  const sym::Tape tape({a + 10 * b + 100 * ad + 1000 * t}, all);
  const double q[2] = {1.0, 2.0}, qd[2] = {3.0, 4.0};
  double out = 0.0;
  tape.eval(5.0, q, qd, &out);
  EXPECT_EQ(out, 1.0 + 20.0 + 300.0 + 5000.0);
  EXPECT_EQ(all.size(), 5u);  // 2 coordinates, 2 velocities, t
  const sym::InputMap pos = sym::coordinate_inputs(symbols, {"ci_a", "ci_b"}, sym::InputSet::q);
  EXPECT_EQ(pos.size(), 2u);
  EXPECT_THROW(sym::Tape({ad}, pos), ukdyn::Error);  // velocities are not bound
  const std::size_t interned = symbols.size();
  const sym::InputMap known =
      sym::coordinate_inputs(symbols, {"ci_new", "ci_b"}, sym::InputSet::q_interned);
  EXPECT_EQ(symbols.size(), interned);  // ci_new was not added
  ASSERT_EQ(known.size(), 1u);
  const sym::Tape tb({b}, known);
  tb.eval(0.0, q, nullptr, &out);
  EXPECT_EQ(out, 2.0);  // ci_b is q[1]
}

// Products used once are folded into their user (add, sub, mul): fewer instructions executed, the
// same values (same operations in the same order; only FMA contraction, with -march=native, can
// differ by an ulp). A product used twice, or a tape output, is kept.
TEST(SymbolicTape, ProductsFoldIntoTheirOnlyUser) {
  sym::SymbolTable symbols;
  const GiNaC::symbol a = sym::coordinate_symbol(symbols, "pf_a"),
                      b = sym::coordinate_symbol(symbols, "pf_b"),
                      c = sym::coordinate_symbol(symbols, "pf_c");
  sym::InputMap in;
  in[a] = {sym::TapeInput::Source::q, 0};
  in[b] = {sym::TapeInput::Source::q, 1};
  in[c] = {sym::TapeInput::Source::q, 2};
  const ex ab = a * b;
  const std::vector<ex> outs = {c + 3 * ab * c - GiNaC::sin(a) * b, 2 * a - c * b * 5,
                                ab,  // an output: not folded away
                                GiNaC::pow(c, 2) + ab};
  const sym::Tape tape(outs, in);
  EXPECT_LT(tape.executed_instructions(), tape.instructions());
  std::mt19937_64 rng(6);
  for (int k = 0; k < 1000; ++k) {
    const double q[3] = {uktest::uniform(rng, -5, 5), uktest::uniform(rng, -5, 5),
                         uktest::uniform(rng, -5, 5)};
    double out[4];
    tape.eval(0.0, q, nullptr, out);
    const double x = q[0], y = q[1], z = q[2];
    const double ref[4] = {z + 3 * x * y * z - std::sin(x) * y, 2 * x - z * y * 5, x * y,
                           z * z + x * y};
    for (int i = 0; i < 4; ++i) EXPECT_NEAR(out[i], ref[i], 1e-14 * (1 + std::abs(ref[i])));
    EXPECT_EQ(out[2], x * y);
  }
}

// sin and cos of one argument are computed by one sincos (the first of the two in the tape writes
// both); either order, a pair sharing nothing, and a lone sin or cos must all give exactly
// std::sin / std::cos.
TEST(SymbolicTape, SinCosPairsGiveTheSeparateCallsValues) {
  sym::SymbolTable symbols;
  const GiNaC::symbol a = sym::coordinate_symbol(symbols, "sc_a"),
                      b = sym::coordinate_symbol(symbols, "sc_b");
  sym::InputMap in;
  in[a] = {sym::TapeInput::Source::q, 0};
  in[b] = {sym::TapeInput::Source::q, 1};
  const std::vector<ex> outs = {GiNaC::cos(a + b), GiNaC::sin(a) * 2, GiNaC::sin(a + b),
                                GiNaC::cos(a) + GiNaC::sin(b), GiNaC::cos(a)};
  const sym::Tape tape(outs, in);
  // a + b; sin, cos of a + b; sin, cos of a; sin b; ·2; +  — counted as before fusing.
  EXPECT_EQ(tape.operations(), 8u);
  EXPECT_EQ(tape.sincos_pairs(), 2u);  // (a + b) and a; sin b stays alone
  std::mt19937_64 rng(4);
  for (int k = 0; k < 1000; ++k) {
    const double q[2] = {uktest::uniform(rng, -50, 50), uktest::uniform(rng, -50, 50)};
    double out[5];
    tape.eval(0.0, q, nullptr, out);
    const double ab = q[0] + q[1];
    EXPECT_EQ(out[0], std::cos(ab));
    EXPECT_EQ(out[1], std::sin(q[0]) * 2);
    EXPECT_EQ(out[2], std::sin(ab));
    EXPECT_EQ(out[3], std::cos(q[0]) + std::sin(q[1]));
    EXPECT_EQ(out[4], std::cos(q[0]));
  }
}

}  // namespace
