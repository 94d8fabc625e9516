// Compiled tapes (src/symbolic/tape.cpp) against GiNaC: values, shared subexpressions, fused
// products, sin/cos pairs; forward-mode tangents against GiNaC's derivatives, and the tangents of a
// derived model's M, C q̇, G against a closed form and Richardson-extrapolated differences.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <iostream>
#include <numbers>
#include <random>

#include "helpers.hpp"
#include "ukdyn/symbolic/definitions.hpp"
#include "ukdyn/symbolic/spline.hpp"
#include "ukdyn/symbolic/tape_inputs.hpp"
#ifdef UKDYN_HAVE_IO
#include "ukdyn/scenario/scenario.hpp"
#endif

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

// ------------------------------------------------------------------------------- forward mode

// Inputs of the tangent tests: real symbols (GiNaC differentiates abs(x) of a real x to x'·x/|x|,
// which a tape compiles), a = q[0], b = q[1], v = q̇[0], t.
struct TangentInputs {
  GiNaC::realsymbol a{"tg_a"}, b{"tg_b"}, v{"tg_v"}, t{"tg_t"};
  sym::InputMap in;
  TangentInputs() {
    in[a] = {sym::TapeInput::Source::q, 0};
    in[b] = {sym::TapeInput::Source::q, 1};
    in[v] = {sym::TapeInput::Source::qd, 0};
    in[t] = {sym::TapeInput::Source::time, 0};
  }
  [[nodiscard]] std::vector<GiNaC::symbol> symbols() const { return {a, b, v, t}; }
};

// The tangent of `outs` along (dt, dq, dqd) from a tape of GiNaC's symbolic gradient, combined
// numerically along the direction.
struct GradientReference {
  sym::Tape grad;
  std::size_t n;
  GradientReference(const std::vector<ex>& outs, const TangentInputs& x) : n(outs.size()) {
    std::vector<ex> g;
    for (const ex& e : outs) {
      for (const GiNaC::symbol& s : x.symbols()) g.push_back(e.diff(s));
    }
    grad = sym::Tape(g, x.in);
  }
  // dir = (da, db, dv, dt); returns the directional derivatives and, in scale, Σ |term|.
  std::vector<double> along(double t, const double* q, const double* qd, const double dir[4],
                            std::vector<double>& scale) const {
    std::vector<double> g(grad.outputs()), d(n, 0.0);
    grad.eval(t, q, qd, g.data());
    scale.assign(n, 0.0);
    for (std::size_t i = 0; i < n; ++i) {
      for (std::size_t j = 0; j < 4; ++j) {
        const double term = g[4 * i + j] * dir[j];
        if (dir[j] != 0.0) d[i] += term;  // a zero direction drops the term (0 · ∞)
        if (dir[j] != 0.0) scale[i] += std::abs(term);
      }
    }
    return d;
  }
};

// eval_tangent against GiNaC's derivative at random points: every op, sin/cos pairs in both
// orders, the superinstructions, splines of q and of t and their derivatives.
TEST(SymbolicTape, TangentMatchesGiNaCDerivativeForEveryOp) {
  const TangentInputs x;
  const ex a = x.a, b = x.b, v = x.v, t = x.t;
  const sym::CubicSpline spline({0.0, 0.7, 1.5, 2.2, 3.0}, {0.3, -1.0, 0.4, 2.0, 1.1});
  const ex sa = sym::spline_expression(spline, a * b);
  const ex st = sym::spline_expression(spline, t);
  using GiNaC::numeric;
  // Each case is compiled alone (fusion decided by what the case holds) and all together.
  const std::vector<std::vector<ex>> cases = {
      {a + b, a - b, a * b, a / (1 + b * b), -GiNaC::sin(a * b), 3 * a + 2, GiNaC::pow(a, 2)},
      {GiNaC::pow(a * a + 1, b), GiNaC::pow(2 + GiNaC::sin(a), numeric(1, 3)), GiNaC::pow(a, 65),
       GiNaC::pow(1 + b * b, numeric(-7, 5)) * v},
      {GiNaC::sqrt(1 + a * a), 1 / GiNaC::sqrt(2 + GiNaC::cos(b))},
      {GiNaC::sin(a)},                             // a lone sin: Op::sin
      {GiNaC::cos(b)},                             // a lone cos: Op::cos
      {GiNaC::sin(a + b), GiNaC::cos(a + b)},      // sin first: sin_cos
      {GiNaC::cos(a * v), GiNaC::sin(a * v) * 2},  // cos first: cos_sin
      {GiNaC::tan(a / 2), GiNaC::asin(a / 3), GiNaC::acos(b / 3), GiNaC::atan(a * v)},
      {GiNaC::atan2(a, b), GiNaC::atan2(v * b, a + 2)},
      {GiNaC::exp(-t * a), GiNaC::log(a * a + 1), GiNaC::log(2 + GiNaC::cos(t))},
      {GiNaC::sinh(a), GiNaC::cosh(b * v), GiNaC::tanh(a - b)},
      {GiNaC::abs(a - b), GiNaC::abs(v) * a},
      {sa, sa.diff(x.a), sa.diff(x.a, 2), sa.diff(x.a, 3), st, st.diff(x.t), st.diff(x.t, 2),
       st.diff(x.t, 3)},
      // Products folded into their users (add_mul, sub_mul, add_mul_c, sub_mul_c, mul_c_mul,
      // mul_mul_c), as in ProductsFoldIntoTheirOnlyUser.
      {v + 3 * a * b * v - GiNaC::sin(a) * b, 2 * a - v * b * 5, a * b, GiNaC::pow(v, 2) + a * b,
       t - a * v, 7 * (a * b) + 1, (3 * a) * (b * t)},
  };
  std::vector<ex> all;
  for (const auto& c : cases) all.insert(all.end(), c.begin(), c.end());
  std::vector<std::vector<ex>> tapes = cases;
  tapes.push_back(all);
  std::mt19937_64 rng(11);
  double worst = 0.0;
  std::size_t fused_pairs = 0, folded = 0;
  for (const auto& outs : tapes) {
    const sym::Tape tape(outs, x.in);
    const GradientReference ref(outs, x);
    fused_pairs += tape.sincos_pairs();
    folded += tape.instructions() - tape.executed_instructions();
    const std::size_t m = tape.outputs();
    std::vector<double> out(m), dout(m), val(m), work(tape.work_size()), dwork(tape.work_size());
    for (int k = 0; k < 200; ++k) {
      const double q[2] = {uktest::uniform(rng, -1.2, 1.2), uktest::uniform(rng, -1.2, 1.2)};
      const double qd[1] = {uktest::uniform(rng, -2, 2)};
      const double tt = uktest::uniform(rng, -0.5, 3.5);  // beyond both ends of the spline too
      const double dir[4] = {uktest::uniform(rng, -1, 1), uktest::uniform(rng, -1, 1),
                             uktest::uniform(rng, -1, 1), uktest::uniform(rng, -1, 1)};
      const double dq[2] = {dir[0], dir[1]}, dqd[1] = {dir[2]};
      tape.eval_tangent(tt, q, qd, dir[3], dq, dqd, out.data(), dout.data(), work.data(),
                        dwork.data());
      tape.eval(tt, q, qd, val.data());
      std::vector<double> scale;
      const std::vector<double> d = ref.along(tt, q, qd, dir, scale);
      for (std::size_t i = 0; i < m; ++i) {
        EXPECT_EQ(out[i], val[i]);  // the values are eval()'s, bit for bit
        const double err = std::abs(dout[i] - d[i]) / (1.0 + scale[i]);
        worst = std::max(worst, err);
        EXPECT_LE(err, 1e-12) << outs[i] << " at a=" << q[0] << " b=" << q[1] << " v=" << qd[0]
                              << " t=" << tt;
      }
    }
  }
  EXPECT_GE(fused_pairs, 3u);  // the pair cases, alone and in the tape of all
  EXPECT_GE(folded, 7u);
  std::cout << "tangent vs GiNaC derivative: worst " << worst << " (relative to 1 + Σ|terms|)\n";
}

// At the edges: a zero tangent stays zero where the derivative is infinite or the log undefined,
// abs has derivative 0 at 0, and pow(x, y) with x < 0 and y a variable whose tangent is 0 uses
// y x^(y−1) dx alone.
TEST(SymbolicTape, TangentAtTheEdgesOfTheDomains) {
  const TangentInputs x;
  const ex a = x.a, b = x.b, v = x.v;
  const sym::Tape tape(
      {GiNaC::sqrt(a), GiNaC::abs(a), GiNaC::pow(b, v), GiNaC::log(a), GiNaC::asin(b / 2 + a)},
      x.in);
  std::vector<double> out(5), dout(5), work(tape.work_size()), dwork(tape.work_size());
  const double q[2] = {0.0, -1.5}, qd[1] = {3.0};
  const double dq[2] = {0.0, 0.25}, dqd[1] = {0.0};
  tape.eval_tangent(0.0, q, qd, 0.0, dq, dqd, out.data(), dout.data(), work.data(), dwork.data());
  EXPECT_EQ(dout[0], 0.0);  // sqrt at 0, da = 0
  EXPECT_EQ(dout[1], 0.0);  // abs at 0
  EXPECT_EQ(out[2], -3.375);
  EXPECT_DOUBLE_EQ(dout[2], 3.0 * 2.25 * 0.25);  // 3 b² db, b < 0, dv = 0
  const double dq2[2] = {1.0, 0.0};
  tape.eval_tangent(0.0, q, qd, 0.0, dq2, dqd, out.data(), dout.data(), work.data(), dwork.data());
  EXPECT_EQ(dout[1], 0.0);           // abs at 0 along a nonzero direction: 0 by convention
  EXPECT_TRUE(std::isinf(dout[0]));  // sqrt at 0 along a: infinite, as the derivative is
  EXPECT_EQ(dout[2], 0.0);
}

// K directions at once: each column bitwise the single-direction call (dt null: 0; dq, dqd null:
// 0), the values bitwise eval()'s.
TEST(SymbolicTape, MultiDirectionTangentsEqualSingleDirectionCalls) {
  const TangentInputs x;
  const ex a = x.a, b = x.b, v = x.v, t = x.t;
  const sym::CubicSpline spline({0.0, 1.0, 2.0, 3.0}, {0.0, 1.0, -1.0, 0.5});
  const std::vector<ex> outs = {
      v + 3 * a * b * v - GiNaC::sin(a) * b,
      GiNaC::cos(a) * GiNaC::sin(a) / (2 + GiNaC::cos(b)) + GiNaC::atan2(a, b + 3),
      GiNaC::pow(a * a + 1, b) - GiNaC::sqrt(1 + v * v) * GiNaC::exp(-t),
      GiNaC::tanh(a) * GiNaC::log(2 + b) + GiNaC::abs(a - v) + GiNaC::asin(b / 3),
      sym::spline_expression(spline, t).diff(x.t) * a + 7 * (a * b) + (3 * a) * (b * t)};
  const sym::Tape tape(outs, x.in);
  const std::size_t m = tape.outputs(), W = tape.work_size();
  std::mt19937_64 rng(12);
  for (const std::size_t K : {1u, 2u, 3u, 4u, 7u, 9u}) {
    std::vector<double> dq(2 * K), dqd(K), dt(K), dout(m * K), out(m), work(W), dwork(W * K);
    std::vector<double> o1(m), d1(m), w1(W), dw1(W), val(m);
    for (int rep = 0; rep < 20; ++rep) {
      const double q[2] = {uktest::uniform(rng, -1.2, 1.2), uktest::uniform(rng, -1.2, 1.2)};
      const double qd[1] = {uktest::uniform(rng, -2, 2)};
      const double tt = uktest::uniform(rng, 0, 3);
      for (double& d : dq) d = uktest::uniform(rng, -1, 1);
      for (double& d : dqd) d = uktest::uniform(rng, -1, 1);
      for (double& d : dt) d = uktest::uniform(rng, -1, 1);
      tape.eval(tt, q, qd, val.data());
      tape.eval_tangents(K, tt, q, qd, dt.data(), dq.data(), 2, dqd.data(), 1, out.data(),
                         dout.data(), work.data(), dwork.data());
      for (std::size_t i = 0; i < m; ++i) EXPECT_EQ(out[i], val[i]);
      for (std::size_t k = 0; k < K; ++k) {
        tape.eval_tangent(tt, q, qd, dt[k], &dq[2 * k], &dqd[k], o1.data(), d1.data(), w1.data(),
                          dw1.data());
        for (std::size_t i = 0; i < m; ++i) EXPECT_EQ(dout[i + m * k], d1[i]) << i << ", " << k;
      }
      // Null directions: dt null is dt = 0; dqd null is dq̇ = 0.
      tape.eval_tangents(K, tt, q, qd, nullptr, dq.data(), 2, nullptr, 1, out.data(), dout.data(),
                         work.data(), dwork.data());
      for (std::size_t k = 0; k < K; ++k) {
        const double zero[1] = {0.0};
        tape.eval_tangent(tt, q, qd, 0.0, &dq[2 * k], zero, o1.data(), d1.data(), w1.data(),
                          dw1.data());
        for (std::size_t i = 0; i < m; ++i) EXPECT_EQ(dout[i + m * k], d1[i]) << i << ", " << k;
      }
    }
  }
}

// ------------------------------------------------------------------- tangents of a model

sym::SubsystemDef double_pendulum_def() {
  sym::SubsystemDef d("tangent_pendulum", {"tp_a", "tp_b"});
  d.parameter("m1", 1.3);
  d.parameter("m2", 0.7);
  d.parameter("l1", 0.9);
  d.parameter("l2", 1.1);
  auto& b1 = d.add_body("bob1");
  b1.mass = d.parse("m1");
  b1.com = {d.parse("l1*sin(tp_a)"), 0, d.parse("-l1*cos(tp_a)")};
  auto& b2 = d.add_body("bob2");
  b2.mass = d.parse("m2");
  b2.com = {d.parse("l1*sin(tp_a) + l2*sin(tp_b)"), 0, d.parse("-l1*cos(tp_a) - l2*cos(tp_b)")};
  d.gravity = {0, 0, d.parse("-9.81")};
  return d;
}

// Double pendulum (point masses, absolute angles), δ = θ1 − θ2, k = m2 l1 l2:
//   M12 = k cos δ, C q̇ = k sin δ (θ̇2², −θ̇1²), G = g ((m1 + m2) l1 sin θ1, m2 l2 sin θ2), so
//   dM12 = −k sin δ dδ, dCqd1 = k (cos δ dδ θ̇2² + 2 sin δ θ̇2 dθ̇2),
//   dCqd2 = −k (cos δ dδ θ̇1² + 2 sin δ θ̇1 dθ̇1), dG = g ((m1 + m2) l1 cos θ1 dθ1, m2 l2 cos θ2 dθ2).
TEST(SymbolicTape, DynamicsTangentOfADoublePendulumMatchesTheClosedForm) {
  const auto sub = sym::make_subsystem(double_pendulum_def());
  const double m1 = 1.3, m2 = 0.7, l1 = 0.9, l2 = 1.1, g = 9.81, k = m2 * l1 * l2;
  std::mt19937_64 rng(13);
  double worst = 0.0;
  for (int rep = 0; rep < 200; ++rep) {
    Vec q(2), qd(2), dq(2), dqd(2);
    for (Vec* x : {&q, &qd, &dq, &dqd})
      *x << uktest::uniform(rng, -3, 3), uktest::uniform(rng, -3, 3);
    Mat M(2, 2), dM(2, 2), M0(2, 2);
    Vec c(2), G(2), dc(2), dG(2), c0(2), G0(2);
    sub->dynamics_tangent({}, q, qd, dq, dqd, M, c, G, dM, dc, dG);
    sub->dynamics({}, q, qd, M0, c0, G0);
    EXPECT_EQ(M, M0);
    EXPECT_EQ(c, c0);
    EXPECT_EQ(G, G0);
    const double s = std::sin(q(0) - q(1)), co = std::cos(q(0) - q(1)), dd = dq(0) - dq(1);
    Mat dMref(2, 2);
    dMref << 0.0, -k * s * dd, -k * s * dd, 0.0;
    Vec dcref(2), dGref(2);
    dcref << k * (co * dd * qd(1) * qd(1) + 2 * s * qd(1) * dqd(1)),
        -k * (co * dd * qd(0) * qd(0) + 2 * s * qd(0) * dqd(0));
    dGref << g * (m1 + m2) * l1 * std::cos(q(0)) * dq(0), g * m2 * l2 * std::cos(q(1)) * dq(1);
    worst = std::max({worst, (dM - dMref).norm() / (1 + dMref.norm()),
                      (dc - dcref).norm() / (1 + dcref.norm()),
                      (dG - dGref).norm() / (1 + dGref.norm())});
  }
  EXPECT_LE(worst, 1e-12);
  std::cout << "double pendulum dM, d(C qd), dG vs closed form: worst " << worst << "\n";
}

#ifdef UKDYN_HAVE_IO
// The paper's system from definitions (scenarios/paper_generic.yaml): the tangents of M, C q̇ and G
// of every subsystem along random (dq, dq̇) against central differences of dynamics() with one
// Richardson step, (4 D(h/2) − D(h)) / 3, error O(h⁴).
TEST(SymbolicTape, DynamicsTangentOfThePaperTwinMatchesRichardsonDifferences) {
  const ukdyn::Scenario sc =
      ukdyn::load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/paper_generic.yaml");
  std::mt19937_64 rng(14);
  double worst = 0.0;
  int subsystems = 0;
  for (const auto& base : sc.system->subsystems()) {
    const auto* sub = dynamic_cast<const sym::DerivedSubsystem*>(base.get());
    ASSERT_NE(sub, nullptr);
    ++subsystems;
    const Index n = sub->dof();
    // All of M, C q̇, G stacked in one vector.
    auto stacked = [&](const Vec& q, const Vec& qd) {
      Mat M(n, n);
      Vec c(n), G(n), all(n * n + 2 * n);
      sub->dynamics({}, q, qd, M, c, G);
      all << M.reshaped(), c, G;
      return all;
    };
    for (int rep = 0; rep < 20; ++rep) {
      const Vec q = uktest::random_vec(rng, n, -1.2, 1.2), qd = uktest::random_vec(rng, n, -2, 2);
      const Vec dq = uktest::random_vec(rng, n, -1, 1), dqd = uktest::random_vec(rng, n, -1, 1);
      Mat M(n, n), dM(n, n);
      Vec c(n), G(n), dc(n), dG(n), tangent(n * n + 2 * n);
      sub->dynamics_tangent({}, q, qd, dq, dqd, M, c, G, dM, dc, dG);
      tangent << dM.reshaped(), dc, dG;
      auto central = [&](double h) {
        return Vec((stacked(q + h * dq, qd + h * dqd) - stacked(q - h * dq, qd - h * dqd)) /
                   (2 * h));
      };
      const double h = 1e-3;
      const Vec rich = (4 * central(h / 2) - central(h)) / 3;
      const double err = (tangent - rich).norm() / (1 + tangent.norm());
      worst = std::max(worst, err);
      EXPECT_LE(err, 1e-8) << sub->name() << " rep " << rep;
    }
  }
  EXPECT_GE(subsystems, 2);
  std::cout << "paper twin tangents vs Richardson differences: worst " << worst << "\n";
}
#endif

}  // namespace
