// Bounded work and the identifier rule (issue 15, classes 1 and 4; docs/definitions.md, "Names and
// limits"): each limit refuses the input just past it and accepts the input at it, so that every
// test can fail both ways; the tape evaluates huge integer exponents as powers, not wrapped around.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <string>

#include "symbolic/mass_matrix_size.hpp"
#include "symbolic/tape_work.hpp"
#include "ukdyn/symbolic/chain.hpp"
#include "ukdyn/symbolic/constraint_kinds.hpp"
#include "ukdyn/symbolic/definitions.hpp"
#include "ukdyn/symbolic/tape.hpp"

namespace {

namespace sym = ukdyn::symbolic;
namespace lim = sym::limits;

sym::Scope xy() {
  sym::Scope s;
  sym::SymbolTable symbols;  // the symbols live on in the expressions that use them
  s.add("x", sym::coordinate_symbol(symbols, "x"));
  s.add("y", sym::coordinate_symbol(symbols, "y"));
  return s;
}

std::string error_of(const std::string& text) {
  try {
    (void)xy().parse(text);
  } catch (const sym::ExpressionError& e) {
    return e.what();
  }
  return "";
}

TEST(Limits, NestingIsCappedNotAStackOverflow) {
  const std::size_t n = lim::kNesting;
  // n - 1 parentheses: the nesting of unary() is the parentheses plus the outermost level.
  EXPECT_EQ(error_of(std::string(n - 1, '(') + "x" + std::string(n - 1, ')')), "");
  EXPECT_NE(error_of(std::string(n, '(') + "x" + std::string(n, ')')).find("nested more than"),
            std::string::npos);
  EXPECT_NE(error_of(std::string(3000, '-') + "x").find("nested more than"), std::string::npos);
  std::string tower;
  for (int i = 0; i < 1000; ++i) tower += "x^";
  EXPECT_NE(error_of(tower + "x").find("nested more than"), std::string::npos);
}

TEST(Limits, LengthDigitsAndExponents) {
  EXPECT_NE(error_of("x" + std::string(lim::kExpressionChars, ' ')).find("longer than"),
            std::string::npos);
  EXPECT_EQ(error_of(std::string(lim::kNumberDigits, '9') + "*x"), "");
  EXPECT_NE(error_of(std::string(lim::kNumberDigits + 1, '9') + "*x").find("digits"),
            std::string::npos);
  EXPECT_EQ(error_of("x^" + std::to_string(lim::kExponent)), "");
  EXPECT_NE(error_of("x^" + std::to_string(lim::kExponent + 1)).find("exponent out of range"),
            std::string::npos);
  EXPECT_NE(error_of("x^(2^65+1)").find("exponent out of range"), std::string::npos);
  EXPECT_NE(error_of("x^(-(2^65))").find("exponent out of range"), std::string::npos);
}

TEST(Limits, ExactNumbersAreBoundedInBits) {
  // 2^4000 has 4001 bits (< 4096); 2^5000 and the tower 2^2^2^2^2^2 do not fit.
  EXPECT_EQ(error_of("2^4000*x"), "");
  EXPECT_NE(error_of("2^5000*x").find("too large"), std::string::npos);
  EXPECT_NE(error_of("2^2^2^2^2^2").find("too large"), std::string::npos);
  EXPECT_NE(error_of("10^100000").find("too large"), std::string::npos);
  EXPECT_EQ(error_of("1^100000000 + (-1)^100000001 + 0^100000000"), "");  // small bases stay small
  // Products of numbers below the cap are caught when the expression is checked.
  EXPECT_NE(error_of("2^4000*2^4000*x").find("bits"), std::string::npos);
}

TEST(Limits, ExpOfAHugeNumberIsRefusedNotWrong) {
  // CLN evaluated exp(exp(exp(exp(10)))) to 2.718...: a wrong finite number.
  EXPECT_EQ(error_of("exp(709)"), "");
  EXPECT_NE(error_of("exp(710)").find("overflows a double"), std::string::npos);
  EXPECT_NE(error_of("exp(exp(exp(exp(10))))").find("overflows a double"), std::string::npos);
  EXPECT_NE(error_of("cosh(-800)").find("overflows a double"), std::string::npos);
  EXPECT_EQ(error_of("exp(exp(x))"), "");  // symbolic arguments are evaluated later, in doubles
}

TEST(Limits, EvaluationErrorsAreExpressionErrorsWithAColumn) {
  EXPECT_NE(error_of("x + log(0)").find("cannot evaluate: log_eval(): log(0)"), std::string::npos);
  EXPECT_NE(error_of("x + 0^(-1)").find("division by zero"), std::string::npos);
  EXPECT_NE(error_of("x/(y - y)").find("division by zero"), std::string::npos);
  try {
    (void)xy().parse("x + log(0)");
    FAIL();
  } catch (const sym::ExpressionError& e) {
    EXPECT_EQ(e.offset, 4u);  // the column of log
  }
}

TEST(Limits, ExpandedSizeIsBoundedBeforeExpanding) {
  sym::SymbolTable symbols;
  const GiNaC::ex x = sym::coordinate_symbol(symbols, "x"),
                  y = sym::coordinate_symbol(symbols, "y");
  EXPECT_NO_THROW(sym::check_expression_size(GiNaC::pow(x + y + 1, 10), "e"));
  // (x + y + 1)^500 has an expansion bound of 3^500 terms.
  EXPECT_THROW(sym::check_expression_size(GiNaC::pow(x + y + 1, 500), "e"), sym::ExpressionError);
  // A DAG that doubles: a_{k+1} = sin(a_k) + cos(a_k), 2^30 nodes written out, checked in linear
  // time thanks to the memo (this test would not end otherwise).
  GiNaC::ex a = x + y;
  for (int k = 0; k < 30; ++k) a = GiNaC::sin(a) + GiNaC::cos(a);
  try {
    sym::check_expression_size(a, "the tower");
    FAIL();
  } catch (const sym::ExpressionError& e) {
    EXPECT_NE(std::string(e.what()).find("the tower is too large"), std::string::npos);
  }
}

// A random small expression in x, y, sin(x), cos(y) and small integers: sums, products and integer
// powers (negative too) of depth up to `depth`.
GiNaC::ex random_expression(std::mt19937& rng, const GiNaC::ex& x, const GiNaC::ex& y, int depth) {
  auto pick = [&](int n) { return static_cast<int>(rng() % static_cast<unsigned>(n)); };
  const GiNaC::ex leaves[] = {x, y, GiNaC::sin(x), GiNaC::cos(y), 2, -1, 3};
  if (depth == 0 || pick(4) == 0) return leaves[pick(7)];
  const int kind = pick(3), arity = 2 + pick(2);
  if (kind == 2) return GiNaC::pow(random_expression(rng, x, y, depth - 1), pick(5) - 1);
  GiNaC::ex r = kind == 0 ? 0 : 1;
  for (int k = 0; k < arity; ++k) {
    const GiNaC::ex c = random_expression(rng, x, y, depth - 1);
    r = kind == 0 ? r + c : r * c;
  }
  return r;
}

// The bound on the terms of an expansion that check_expression_size() refuses on is an upper
// bound: never below the terms of GiNaC's expand(), on random small expressions. The bound B(e) is
// seen through the limit: e · P with P = A B + C (A, B, C sums of fresh symbols, P expanding to
// exactly K = |A| |B| + |C| terms, the least K with N K past the limit, N the terms of e's
// expansion) expands to exactly N K terms, so it must be refused; kept, B(e) K ≤ the limit < N K.
TEST(Limits, ExpansionBoundIsNeverBelowTheExpansion) {
  sym::SymbolTable symbols;
  const GiNaC::ex x = sym::coordinate_symbol(symbols, "x"),
                  y = sym::coordinate_symbol(symbols, "y");
  auto fresh_sum = [](long n, const std::string& name) {
    GiNaC::ex s = 0;
    for (long k = 0; k < n; ++k) s += GiNaC::symbol(name + std::to_string(k));
    return s;
  };
  std::mt19937 rng(20261205);
  int checked = 0;
  for (int trial = 0; trial < 200; ++trial) {
    const GiNaC::ex e = random_expression(rng, x, y, 3);
    const GiNaC::ex expanded = e.expand();
    const long n = expanded.is_zero()                  ? 0
                   : GiNaC::is_a<GiNaC::add>(expanded) ? static_cast<long>(expanded.nops())
                                                       : 1;
    if (n == 0 || n > 400) continue;
    const auto limit = static_cast<long>(lim::kExpandedTerms);
    const long K = limit / n + 1, a = static_cast<long>(std::sqrt(static_cast<double>(K)));
    const GiNaC::ex P = fresh_sum(a, "a") * fresh_sum(a, "b") + fresh_sum(K - a * a, "c");
    ASSERT_GT(n * K, limit);
    EXPECT_THROW(sym::check_expression_size(e * P, "e"), sym::ExpressionError)
        << e << " expands to " << n << " terms: its bound is below that";
    ++checked;
  }
  EXPECT_GT(checked, 100);
}

// The nodes of an expression written out (the count check_expression_size() limits).
double nodes_of(const GiNaC::ex& e) {
  double n = 1;
  for (std::size_t k = 0; k < e.nops(); ++k) n += nodes_of(e.op(k));
  return n;
}

// mass_matrix_nodes counts the size of each M(i, j) = ∂²T/∂q̇_i∂q̇_j from T's terms before any
// derivative is taken (so that an entry too large is refused before the derivatives): on random
// kinetic energies (sums of random coefficients times random functions of q times q̇_i q̇_j, and
// squares of such velocities) it must be exactly the size of the entry as differentiated.
TEST(Limits, MassMatrixSizeBeforeTheDerivatives) {
  sym::SymbolTable symbols;
  const GiNaC::ex x = sym::coordinate_symbol(symbols, "x"),
                  y = sym::coordinate_symbol(symbols, "y");
  const std::vector<GiNaC::symbol> qd = {sym::velocity_symbol(symbols, "x"),
                                         sym::velocity_symbol(symbols, "y"),
                                         sym::velocity_symbol(symbols, "z")};
  const GiNaC::ex coefficients[] = {1, GiNaC::numeric(1, 2), 2, -3, GiNaC::numeric(3, 7)};
  std::mt19937 rng(7);
  auto pick = [&](int n) { return static_cast<int>(rng() % static_cast<unsigned>(n)); };
  for (int trial = 0; trial < 300; ++trial) {
    GiNaC::ex T = 0;
    const int terms = 1 + pick(6);
    for (int k = 0; k < terms; ++k) {
      const GiNaC::ex f = pick(3) == 0 ? GiNaC::ex(1) : random_expression(rng, x, y, 2);
      if (pick(3) == 0) {  // ½ m v², v a sum of functions times velocities
        const GiNaC::ex v = f * qd[pick(3)] + random_expression(rng, x, y, 1) * qd[pick(3)];
        T += coefficients[pick(5)] * v * v;
      } else {
        T += coefficients[pick(5)] * f * qd[pick(3)] * qd[pick(3)];
      }
    }
    T = T.expand();
    const std::vector<double> nodes = sym::mass_matrix_nodes(T, qd);
    for (std::size_t i = 0; i < 3; ++i) {
      for (std::size_t j = i; j < 3; ++j) {
        const GiNaC::ex m = T.diff(qd[i]).diff(qd[j]).expand();
        EXPECT_EQ(nodes[i * 3 + j], nodes_of(m)) << "M(" << i << ", " << j << ") of T = " << T;
      }
    }
  }
}

// A position of 200 sines of one coordinate: an M(x, x) of 20100 terms, about 2.2 · 10^5 nodes, is
// refused before it is derived, naming the entry and the limit; 60 sines derive.
TEST(Limits, MassMatrixEntryTooLargeIsRefusedBeforeItIsDerived) {
  auto sines = [](int n) {
    sym::SubsystemDef d("s", {"x", "phi"});
    std::string p;
    for (int k = 1; k <= n; ++k) p += (k > 1 ? "+" : "") + ("sin(" + std::to_string(k) + "*x)");
    auto& b = d.add_body("b");
    b.mass = 1;
    b.com = {d.parse(p), d.parse("phi"), 0};
    return d;
  };
  try {
    (void)sym::derive(sines(200));
    FAIL();
  } catch (const sym::ExpressionError& e) {
    EXPECT_NE(std::string(e.what()).find("M(x, x) would be too large (more than 200000 nodes"),
              std::string::npos)
        << e.what();
  }
  EXPECT_NO_THROW((void)sym::derive(sines(60)));
}

TEST(Limits, DeadlineNamesThePlace) {
  EXPECT_NO_THROW(sym::Deadline(60.0).check("M(x, x)"));
  try {
    sym::Deadline(-1.0).check("M(x, y)");
    FAIL();
  } catch (const ukdyn::Error& e) {
    EXPECT_NE(std::string(e.what()).find("stopped at M(x, y)"), std::string::npos) << e.what();
  }
}

// expand_checked builds the expansion term by term so that a deadline can stop it: it must give
// GiNaC's own expand() (two formulations of one expansion), for sums, products of sums, integer
// powers of sums, negative powers and functions of sums.
TEST(Limits, CheckedExpansionIsGiNaCsExpansion) {
  sym::SymbolTable symbols;
  const GiNaC::ex x = sym::coordinate_symbol(symbols, "x"),
                  y = sym::coordinate_symbol(symbols, "y"),
                  z = sym::coordinate_symbol(symbols, "z");
  const GiNaC::ex s = GiNaC::sin(x), c = GiNaC::cos(y);
  const GiNaC::ex cases[] = {
      (x + y) * (x - y + 3) * (s + c),
      GiNaC::pow(x + 2 * y + s, 3) * (z - 1) + GiNaC::pow(x * y, 2),
      (x + y) / (z + 1) + GiNaC::sin(x * (y + z)) * (x + 1),
      GiNaC::numeric(3, 7) * (x + y) * (x + y) - 2 * (s * c + x) * (s * c - x),
      (GiNaC::pow(s, 2) + GiNaC::pow(c, 2)) * ((x + 1) * (y + 2) + z),
      GiNaC::ex(5),
  };
  const sym::Deadline deadline(60.0);
  for (const GiNaC::ex& e : cases) {
    const GiNaC::ex a = sym::expand_checked(e, deadline, "e"), b = e.expand();
    EXPECT_TRUE((a - b).expand().is_zero()) << e << ": " << a << " vs " << b;
    EXPECT_TRUE(a.is_equal(b)) << e << ": " << a << " vs " << b;
  }
  // A sum of ~2.3 · 10^4 distinct terms, more than one combination of the partial sums holds (the
  // derivative of an expanded square of 150 sines: not marked expanded, so taken term by term).
  GiNaC::ex sines = 0;
  for (int k = 1; k <= 150; ++k) sines += GiNaC::sin(k * x);
  const GiNaC::ex big = (sines * sines).expand().diff(GiNaC::ex_to<GiNaC::symbol>(x));
  const GiNaC::ex a = sym::expand_checked(big, deadline, "big"), b = big.expand();
  EXPECT_GT(b.nops(), 20000u);
  EXPECT_TRUE(a.is_equal(b));
}

// An 8-link chain with skewed hinge axes (each not along a frame axis, so every rotation entry
// mixes all angles): deriving it symbolically takes minutes, most of it inside single GiNaC
// expansions of one link's angular velocity. With a 2 s budget the derivation stops at the
// budget, not after the expansion in hand: this test would take minutes (and time out) if the
// deadline were only checked between joints. The refusal names where it stopped.
TEST(Limits, DeadlineStopsALongChainDerivationInsideAnExpansion) {
  // The axes as MuJoCo compiles them (unit vectors in doubles; exact_number as the MJCF reader).
  const double axes[8][3] = {{0.3, 0.7, 0.2}, {0.9, 0.1, 0.4}, {0.2, 0.5, 0.8}, {0.6, 0.3, 0.7},
                             {0.1, 0.8, 0.5}, {0.7, 0.6, 0.1}, {0.4, 0.2, 0.9}, {0.8, 0.4, 0.3}};
  std::vector<std::string> q;
  for (int k = 0; k < 8; ++k) q.push_back("q" + std::to_string(k));
  sym::ChainDef c("skewed", q);
  c.gravity = {0, 0, GiNaC::numeric(-981, 100)};
  for (int k = 0; k < 8; ++k) {
    auto& j = c.add_joint("j" + std::to_string(k), sym::JointDef::Type::revolute,
                          "l" + std::to_string(k));
    const double* a = axes[k];
    const double n = std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
    j.axis = {sym::exact_number(a[0] / n), sym::exact_number(a[1] / n),
              sym::exact_number(a[2] / n)};
    if (k > 0) j.origin.xyz = {GiNaC::numeric(3, 10), 0, 0};
    j.coordinate = q[static_cast<std::size_t>(k)];
    j.inertial.mass = 1;
    j.inertial.com = {GiNaC::numeric(3, 20), 0, 0};
    j.inertial.inertia = {GiNaC::numeric(1, 100), 0, 0, 0, GiNaC::numeric(1, 50), 0, 0, 0,
                          GiNaC::numeric(3, 100)};
  }
  try {
    const sym::Deadline deadline(2.0);
    const sym::ChainModel model = sym::build_chain(c, deadline);
    (void)sym::make_subsystem(model.def, deadline);
    FAIL() << "derived within 2 s";
  } catch (const sym::DerivationTimeout& e) {
    EXPECT_NE(std::string(e.what()).find("took longer than 2 s (stopped at "), std::string::npos)
        << e.what();
  }
}

// The tapes are compiled within the derivation's budget: a derivation finished inside it, then
// handed a budget already spent (the limit -1 s), is refused at the compilation, naming the tape.
// Without the clock read during compilation every case below would construct and not throw.
TEST(Limits, DeadlineCoversTheTapeCompilation) {
  const sym::Deadline spent(-1.0);
  auto stopped_at = [](const auto& make) {
    try {
      make();
    } catch (const sym::DerivationTimeout& e) {
      return std::string(e.what());
    }
    return std::string("not stopped");
  };
  // A subsystem: a two-link chain derived within 60 s, compiled within the spent budget.
  sym::ChainDef c("two", {"a", "b"});
  for (int k = 0; k < 2; ++k) {
    auto& j = c.add_joint("j" + std::to_string(k), sym::JointDef::Type::revolute,
                          "l" + std::to_string(k));
    j.axis = {0, 0, 1};
    if (k > 0) j.origin.xyz = {1, 0, 0};
    j.coordinate = k == 0 ? "a" : "b";
    j.inertial.mass = 1;
    j.inertial.com = {GiNaC::numeric(1, 2), 0, 0};
    j.inertial.inertia = {GiNaC::numeric(1, 12), 0, 0, 0, GiNaC::numeric(1, 12), 0, 0, 0,
                          GiNaC::numeric(1, 12)};
  }
  const sym::Deadline budget(60.0);
  const sym::ChainModel model = sym::build_chain(c, budget);
  sym::SubsystemDerivation derived = sym::derive(model.def, budget);
  EXPECT_NO_THROW((void)sym::DerivedSubsystem(derived, "two", budget));
  const std::string sub = stopped_at([&] { (void)sym::DerivedSubsystem(derived, "two", spent); });
  EXPECT_NE(sub.find("took longer than -1 s (stopped at compiling row a of M"), std::string::npos)
      << sub;
  // A constraint: the same.
  sym::ConstraintDef d("circle", sym::ConstraintDef::Kind::holonomic, {"lim_x", "lim_y"});
  d.add_row("circle", d.parse("lim_x^2 + lim_y^2 - 1"));
  const sym::ConstraintDerivation cd = sym::derive(d, budget);
  EXPECT_NO_THROW((void)sym::DerivedConstraint(cd, budget));
  const std::string con = stopped_at([&] { (void)sym::DerivedConstraint(cd, spent); });
  EXPECT_NE(con.find("(stopped at compiling row 'circle'"), std::string::npos) << con;
  // A tape alone names the place it was given.
  sym::SymbolTable symbols;
  const GiNaC::ex x = sym::coordinate_symbol(symbols, "x");
  const sym::InputMap in{{x, {sym::TapeInput::Source::q, 0}}};
  EXPECT_NO_THROW((void)sym::Tape({GiNaC::sin(x)}, in, budget, "compiling the sum"));
  const std::string tape =
      stopped_at([&] { (void)sym::Tape({GiNaC::sin(x)}, in, spent, "compiling the sum"); });
  EXPECT_NE(tape.find("(stopped at compiling the sum)"), std::string::npos) << tape;
}

// The work of a compilation is the operand count of the outputs as a DAG (tape_work.hpp), against
// its closed form: Σ_{i<j} x_i x_j over m symbols is one sum of C(m, 2) products of two symbols,
// 1 + 3 C(m, 2) visits; a shared subexpression is visited once more per use but expanded once, so
// {e², e} gives 1 (the power) + 2 (e and 2) + 3 C(m, 2) + 1 (the second output, seen); the count
// goes on from `done` and is refused just past the limit, accepted at it.
TEST(Limits, TapeWorkIsTheOperandCountOfTheDag) {
  const std::size_t m = 30, pairs = m * (m - 1) / 2;
  std::vector<GiNaC::symbol> x;
  for (std::size_t i = 0; i < m; ++i) x.emplace_back("x" + std::to_string(i));
  GiNaC::ex e = 0;
  for (std::size_t i = 0; i < m; ++i) {
    for (std::size_t j = i + 1; j < m; ++j) e += x[i] * x[j];
  }
  ASSERT_EQ(e.nops(), pairs);
  const std::size_t one = 1 + 3 * pairs;
  EXPECT_EQ(sym::tape_work({e}, lim::kTapeWork, "e"), one);
  EXPECT_EQ(sym::tape_work({GiNaC::sin(e)}, lim::kTapeWork, "sin e"), one + 1);
  EXPECT_EQ(sym::tape_work({GiNaC::pow(e, 2), e}, lim::kTapeWork, "e^2, e"), one + 3);
  EXPECT_EQ(sym::tape_work({e, e}, lim::kTapeWork, "e, e"), one + 1);
  EXPECT_EQ(sym::tape_work({e}, lim::kTapeWork, "e", 1000), one + 1000);
  EXPECT_EQ(sym::tape_work({e}, one, "e"), one);
  try {
    (void)sym::tape_work({e}, one - 1, "compiling e");
    FAIL();
  } catch (const sym::DerivationTimeout& err) {
    const std::string what = err.what();
    EXPECT_NE(what.find("would take more than " + std::to_string(one - 1) +
                        " operand visits (stopped at compiling e"),
              std::string::npos)
        << what;
  }
  EXPECT_THROW((void)sym::tape_work({e}, lim::kTapeWork, "e", lim::kTapeWork - one + 1),
               sym::DerivationTimeout);
}

// A generated subsystem past the work limit (100 sines sin(a q_i + q_j) of pairs of 4 coordinates
// in one position, as tests/limits/tape_work_sines_of_pairs.yaml; every entry of M and C under
// the node limit) is refused by the count, naming the limit and the tape, before any tape is
// compiled; 40 such sines compile.
TEST(Limits, TapeWorkRefusesADerivedSubsystemPastTheLimit) {
  auto sines = [](int n) {
    const std::vector<std::string> q{"q0", "q1", "q2", "q3"};
    sym::SubsystemDef d("s", q);
    std::string p;
    for (int s = 0; s < n; ++s) {
      const int pair = s % 12, i = pair / 3, k = pair % 3, j = k < i ? k : k + 1;
      p += (s > 0 ? "+" : "") +
           ("sin(" + std::to_string(1 + s / 12) + "*" + q[i] + "+" + q[j] + ")");
    }
    auto& b = d.add_body("p");
    b.mass = 1;
    b.com = {d.parse(p), 0, 0};
    for (const std::string& c : q) {
      auto& o = d.add_body("b" + c);
      o.mass = 1;
      o.com = {0, d.parse(c), 0};
    }
    return d;
  };
  EXPECT_NO_THROW((void)sym::make_subsystem(sines(40)));
  try {
    (void)sym::make_subsystem(sines(100));
    FAIL();
  } catch (const sym::DerivationTimeout& e) {
    EXPECT_NE(std::string(e.what()).find("compiling the tapes would take more than 1000000 "
                                         "operand visits (stopped at compiling C;"),
              std::string::npos)
        << e.what();
  }
}

TEST(Limits, DerivedSubsystemCoordinatesAreCapped) {
  auto make = [](std::size_t n) {
    std::vector<std::string> names;
    for (std::size_t i = 0; i < n; ++i) names.push_back("c" + std::to_string(i));
    sym::SubsystemDef d("big", names);
    for (const auto& c : names) {
      auto& b = d.add_body("b" + c);
      b.mass = 1;
      b.com = {sym::coordinate_symbol(d.symbols(), c), 0, 0};
    }
    return sym::derive(d);
  };
  EXPECT_NO_THROW(make(3));
  try {
    make(lim::kDerivedCoordinates + 1);
    FAIL();
  } catch (const sym::DefinitionError& e) {
    EXPECT_NE(std::string(e.what()).find("at most " + std::to_string(lim::kDerivedCoordinates)),
              std::string::npos);
  }
}

TEST(Names, IdentifierRuleRefusesWhatPrintsAsSomethingElse) {
  for (const char* ok : {"x", "theta1", "l_r", "M", "b", "q", "I", "_x", "Pi2", "Ee"}) {
    std::string why;
    EXPECT_TRUE(sym::valid_name(ok, &why)) << ok << ": " << why;
  }
  for (const char* bad :
       {"Pi",       "E", "Euler", "Catalan", "M_PI", "int", "double", "return", "end",
        "function", "i", "j",     "eps",     "Inf",  "NaN", "pow",    "__x",    "_X",
        "ukdyn_m",  "t", "pi",    "sin",     "a.b",  "a-b", "1x",     "",       "x\ry"}) {
    EXPECT_FALSE(sym::valid_name(bad)) << bad;
  }
  EXPECT_TRUE(sym::valid_name(std::string(64, 'a')));
  EXPECT_FALSE(sym::valid_name(std::string(65, 'a')));
  std::string why;
  EXPECT_FALSE(sym::valid_name("x\x1b[2J", &why));
  EXPECT_EQ(why.find('\x1b'), std::string::npos) << "a control byte in the message";
}

// x^(2^65 + 1): to_long() wrapped the exponent to 1 and the tape evaluated x. It is a power now:
// 0.5^(2^65+1) underflows to 0, 1.25^(2^65+1) overflows to inf.
TEST(Limits, TapeDoesNotWrapHugeIntegerExponents) {
  sym::SymbolTable symbols;
  const GiNaC::symbol x = sym::coordinate_symbol(symbols, "x");
  const GiNaC::ex big = GiNaC::pow(GiNaC::numeric(2), 65) + 1;
  sym::InputMap in;
  in[x] = {sym::TapeInput::Source::q, 0};
  const sym::Tape tape({GiNaC::pow(x, big), GiNaC::pow(x, 64), GiNaC::pow(x, 65)}, in);
  for (double v : {0.5, 1.25}) {
    double out[3];
    tape.eval(0.0, &v, nullptr, out);
    EXPECT_EQ(out[0], v < 1 ? 0.0 : HUGE_VAL) << v;
    EXPECT_DOUBLE_EQ(out[1], std::pow(v, 64));
    EXPECT_DOUBLE_EQ(out[2], std::pow(v, 65));
  }
}

}  // namespace
