// The adaptive U-K solve (UkMethod::adaptive, docs/singular-positions.md): exact where the
// constraints are well conditioned, damped only inside a band about a singular position, and
// continuous in between; and the branch check's allowance for the damping (simulate/drift.hpp).
#include <gtest/gtest.h>

#include <cmath>

#include "ukdyn/core/uk_solve.hpp"
#include "ukdyn/simulate/drift.hpp"

namespace {

using namespace ukdyn;

// A 4-coordinate system with two rows; row 1 is s times a fixed gradient (with b scaled alike), so
// its singular value goes to 0 with s while the force it asks for stays finite (the N-four-bar's x
// rows at a flat position: a 0/0 limit).
struct Shrinking {
  Mat M = Mat::Identity(4, 4);
  Mat A = Mat::Zero(2, 4);
  Vec b = Vec::Zero(2), Q = Vec::Zero(4);
  explicit Shrinking(double s) {
    M(0, 0) = 2.0;
    M(1, 1) = 1.5;
    M(0, 1) = M(1, 0) = 0.3;
    A.row(0) << 1.0, 0.5, 0.0, 0.2;
    A.row(1) << 0.0, s, s, 0.0;
    b << 0.7, s * 1.3;
    Q << 0.1, -0.4, 0.25, 1.0;
  }
};

UkResult solve(const Shrinking& p, UkMethod method, Vec& qdd) {
  UkWorkspace ws(BlockLayout::single(4), 2);
  Vec Qc(4);
  UkSettings st;
  st.method = method;
  return uk_solve(p.M, p.A, p.b, p.Q, ws, qdd, Qc, st);
}

TEST(AdaptiveSolve, IsTheExactSolveBitForBitAwayFromTheBand) {
  for (double s : {1.0, 0.1, 2e-3}) {  // σ ratio well above adaptive_band · ε = 1e-3
    const Shrinking p(s);
    Vec q_exact(4), q_adaptive(4);
    const UkResult re = solve(p, UkMethod::exact, q_exact);
    const UkResult ra = solve(p, UkMethod::adaptive, q_adaptive);
    EXPECT_EQ(ra.damping, 0.0) << s;
    EXPECT_EQ(ra.damped_acceleration, 0.0) << s;
    EXPECT_EQ(ra.rank, re.rank);
    for (Index j = 0; j < 4; ++j) EXPECT_EQ(q_adaptive(j), q_exact(j)) << s;  // same bytes
  }
}

// Independent reference: the KKT solve of the same (full-rank) system.
TEST(AdaptiveSolve, DampsOnlyInsideTheBandAndStaysContinuous) {
  const UkSettings defaults;  // regularization 1e-5, adaptive_band 100
  Vec prev(4);
  double prev_s = 0.0;
  for (double s = 1e-2; s > 1e-12; s *= 0.8) {
    const Shrinking p(s);
    Vec qa(4), qk(4), Qc(4);
    const UkResult ra = solve(p, UkMethod::adaptive, qa);
    ASSERT_TRUE(ra.finite);
    ASSERT_TRUE(ra.consistent) << s;
    kkt_solve(p.M, p.A, p.b, p.Q, qk, Qc);
    // ρ = σ_min/σ_max ≈ c s: damping 0 above the band, ≤ ε inside.
    EXPECT_LE(ra.damping, defaults.regularization);
    if (s > 5e-3) {
      EXPECT_EQ(ra.damping, 0.0) << s;
    }
    if (s < 1e-6 && s > 1e-7) {
      EXPECT_NEAR(ra.damping, defaults.regularization, 1e-20) << s;
    }
    // Past the exact cut-off (σ ratio < 1e-7) the row is dropped; it is damped (fully) only while
    // dropping it leaves a residual above round-off, i.e. while it still asks for a force.
    if (s <= 1e-7) {
      EXPECT_TRUE(ra.damping == 0.0 || ra.damping == defaults.regularization) << s;
    }
    // Exact where the damping is off; within the damping's filter error otherwise.
    if (ra.damping == 0.0) {
      EXPECT_LT((qa - qk).cwiseAbs().maxCoeff(), 1e-12) << s;
    }
    // Continuous: between neighbouring s (a factor 0.8 apart) q̈ changes by little, also across
    // the band's edge and through the rank change (there the exact solve jumps).
    if (prev_s > 0.0) {
      EXPECT_LT((qa - prev).cwiseAbs().maxCoeff(), 0.1) << s;
    }
    prev = qa;
    prev_s = s;
  }
}

TEST(AdaptiveSolve, ExactSolveJumpsWhereTheAdaptiveOneDoesNot) {
  // Just above and below the exact method's cut-off (σ ratio 1e-7): the exact solve drops the
  // row's finite force, the adaptive one has already faded it out smoothly.
  Vec e_hi(4), e_lo(4), a_hi(4), a_lo(4);
  const Shrinking hi(3e-7), lo(3e-8);
  solve(hi, UkMethod::exact, e_hi);
  solve(lo, UkMethod::exact, e_lo);
  solve(hi, UkMethod::adaptive, a_hi);
  solve(lo, UkMethod::adaptive, a_lo);
  EXPECT_GT((e_hi - e_lo).cwiseAbs().maxCoeff(), 0.1);
  EXPECT_LT((a_hi - a_lo).cwiseAbs().maxCoeff(), 1e-2);
}

TEST(BranchCheck, AllowsTheDampedSolvesConstraintErrorButNotAJump) {
  SimulationSettings s;
  s.abs_tol = s.rel_tol = 1e-12;
  const double xmax = 3.0, h = 1e-3;
  // Undamped: the old allowance branch_factor (abs_tol + rel_tol max|x|).
  const double bound = s.drift.branch_factor * (1e-12 + 1e-12 * xmax);
  auto c = detail::check_branch(s, false, xmax, h, 0.0, 0.5 * bound, 0.0);
  EXPECT_DOUBLE_EQ(c.ratio, 0.5);
  c = detail::check_branch(s, false, xmax, h, 0.0, 2.0 * bound, 0.0);
  EXPECT_GT(c.ratio, 1.0);
  // Damped with a = 1e-2: ½ a h² = 5e-9 in q and a h = 1e-5 in q̇ are explained.
  c = detail::check_branch(s, false, xmax, h, 1e-2, 5e-9, 1e-5);
  EXPECT_LT(c.ratio, 1.0);
  // A jump of 1e-3 in q (another branch) is not, whatever the damping admitted.
  c = detail::check_branch(s, false, xmax, h, 1e-2, 1e-3, 1e-5);
  EXPECT_GT(c.ratio, 1.0);
}

}  // namespace
