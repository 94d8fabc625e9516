// The U-K solve (paper Eq. 4) against the textbook pseudo-inverse form, the KKT system, Gauss's
// principle of least constraint and d'Alembert's principle (ideal constraints do no virtual work).
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <Eigen/SVD>
#include <cmath>
#include <limits>

#include "helpers.hpp"
#include "ukdyn/core/uk_solve.hpp"

namespace {

using ukdyn::BlockLayout;
using ukdyn::Mat;
using ukdyn::UkResult;
using ukdyn::UkWorkspace;
using ukdyn::Vec;
using uktest::rel_err;

constexpr int kTrials = 30;
constexpr double kTol = 1e-10;  // relative, between solve forms

BlockLayout layout66() { return BlockLayout{{0, 6}, {6, 6}}; }

Mat random_matrix(std::mt19937_64& rng, Eigen::Index r, Eigen::Index c) {
  std::normal_distribution<double> nd(0.0, 1.0);
  Mat X(r, c);
  for (Eigen::Index i = 0; i < r; ++i)
    for (Eigen::Index j = 0; j < c; ++j) X(i, j) = nd(rng);
  return X;
}
Vec random_vector(std::mt19937_64& rng, Eigen::Index n) { return random_matrix(rng, n, 1); }

/// Random SPD block-diagonal M with blocks 6 + 6 and a condition number of a few hundred at most.
Mat random_spd_mass(std::mt19937_64& rng) {
  Mat M = Mat::Zero(12, 12);
  for (int k = 0; k < 2; ++k) {
    const Mat R = random_matrix(rng, 6, 6);
    M.block(6 * k, 6 * k, 6, 6) =
        R * R.transpose() + uktest::uniform(rng, 0.5, 5.0) * Mat::Identity(6, 6);
  }
  return M;
}

struct Solution {
  Vec qdd, Qc;
  UkResult res;
};

Solution solve_uk(const Mat& M, const Mat& A, const Vec& b, const Vec& Q) {
  UkWorkspace ws(layout66(), A.rows());
  Solution s;
  s.qdd.resize(12);
  s.Qc.resize(12);
  s.res = ukdyn::uk_solve(M, A, b, Q, ws, s.qdd, s.Qc);
  return s;
}
Solution solve_textbook(const Mat& M, const Mat& A, const Vec& b, const Vec& Q) {
  Solution s;
  s.qdd.resize(12);
  s.Qc.resize(12);
  s.res = ukdyn::uk_solve_textbook(M, A, b, Q, s.qdd, s.Qc);
  return s;
}
Solution solve_kkt(const Mat& M, const Mat& A, const Vec& b, const Vec& Q) {
  Solution s;
  s.qdd.resize(12);
  s.Qc.resize(12);
  ukdyn::kkt_solve(M, A, b, Q, s.qdd, s.Qc);
  return s;
}

/// Gauss's function (x − a)ᵀ M (x − a), a = M⁻¹Q.
double gauss(const Mat& M, const Vec& Q, const Vec& x) {
  const Vec a = M.llt().solve(Q);
  return (x - a).dot(M * (x - a));
}

TEST(UkSolve, FullRankAgreesWithKktAndTextbook) {
  std::mt19937_64 rng(101);
  for (int trial = 0; trial < kTrials; ++trial) {
    const Eigen::Index m = 1 + trial % 11;  // 1..11 rows
    const Mat M = random_spd_mass(rng);
    const Mat A = random_matrix(rng, m, 12);
    const Vec b = random_vector(rng, m), Q = random_vector(rng, 12);
    const auto uk = solve_uk(M, A, b, Q);
    const auto tb = solve_textbook(M, A, b, Q);
    const auto kk = solve_kkt(M, A, b, Q);
    EXPECT_TRUE(uk.res.finite);
    EXPECT_TRUE(uk.res.consistent);
    EXPECT_EQ(uk.res.rank, m);
    EXPECT_EQ(tb.res.rank, m);
    EXPECT_LE(rel_err(uk.qdd, kk.qdd), kTol) << "trial " << trial;
    EXPECT_LE(rel_err(uk.Qc, kk.Qc), kTol) << "trial " << trial;
    EXPECT_LE(rel_err(uk.qdd, tb.qdd), kTol) << "trial " << trial;
    EXPECT_LE(rel_err(uk.Qc, tb.Qc), kTol) << "trial " << trial;
    EXPECT_LE(rel_err(Vec(A * uk.qdd), b), kTol) << "trial " << trial;
    EXPECT_NEAR(uk.res.residual, (A * uk.qdd - b).norm(), 1e-12 * (b.norm() + 1.0));
    // q̈ = M⁻¹(Q + Qc).
    EXPECT_LE(rel_err(Vec(M * uk.qdd), Vec(Q + uk.Qc)), kTol);
    // The reported extreme singular values match an SVD of A M^{-1/2}.
    const Vec sv = ukdyn::singular_values_A_Minvhalf(M, A);
    EXPECT_NEAR(tb.res.sigma_max, sv(0), 1e-10 * sv(0));
    EXPECT_NEAR(tb.res.sigma_min_kept, sv(m - 1), 1e-10 * sv(0));
    // The production form reports sqrt of LDLᵀ pivots of W = A M⁻¹ Aᵀ: every pivot lies in
    // [λ_min(W), λ_max(W)] and the largest (first, diagonal pivoting) is ≥ λ_max / m.
    const double m_d = static_cast<double>(m);
    EXPECT_LE(uk.res.sigma_max, sv(0) * (1 + 1e-10));
    EXPECT_GE(uk.res.sigma_max, sv(0) / std::sqrt(m_d) * (1 - 1e-10));
    EXPECT_GE(uk.res.sigma_min_kept, sv(m - 1) * (1 - 1e-10));
    EXPECT_LE(uk.res.sigma_min_kept, uk.res.sigma_max);
  }
}

// A with 12 rows of rank 10 (two rows are combinations of the others), b consistent.
struct Redundant {
  Mat A;
  Vec b;
  Mat A_indep;
  Vec b_indep;
};
Redundant redundant_set(std::mt19937_64& rng) {
  Redundant r;
  r.A_indep = random_matrix(rng, 10, 12);
  r.b_indep = random_vector(rng, 10);
  const Mat W = random_matrix(rng, 2, 10);  // the two redundant rows
  r.A.resize(12, 12);
  r.b.resize(12);
  r.A << r.A_indep.topRows(5), W * r.A_indep, r.A_indep.bottomRows(5);
  r.b << r.b_indep.head(5), W * r.b_indep, r.b_indep.tail(5);
  return r;
}

TEST(UkSolve, RankDeficientConsistentAgreesWithPseudoInverse) {
  std::mt19937_64 rng(102);
  for (int trial = 0; trial < kTrials; ++trial) {
    const Mat M = random_spd_mass(rng);
    const auto r = redundant_set(rng);
    const Vec Q = random_vector(rng, 12);
    const auto uk = solve_uk(M, r.A, r.b, Q);
    const auto tb = solve_textbook(M, r.A, r.b, Q);
    // The same motion as the independent rows alone (KKT on a full-rank set).
    const auto kk = solve_kkt(M, r.A_indep, r.b_indep, Q);
    EXPECT_EQ(uk.res.rank, 10) << "trial " << trial;
    EXPECT_EQ(tb.res.rank, 10) << "trial " << trial;
    EXPECT_TRUE(uk.res.consistent) << "trial " << trial << " residual " << uk.res.residual;
    EXPECT_TRUE(uk.res.finite);
    EXPECT_LE(rel_err(uk.qdd, tb.qdd), kTol) << "trial " << trial;
    EXPECT_LE(rel_err(uk.Qc, tb.Qc), kTol) << "trial " << trial;
    EXPECT_LE(rel_err(uk.qdd, kk.qdd), kTol) << "trial " << trial;
    EXPECT_LE(rel_err(uk.Qc, kk.Qc), kTol) << "trial " << trial;
    EXPECT_LE(rel_err(Vec(r.A * uk.qdd), r.b), kTol) << "trial " << trial;
  }
}

TEST(UkSolve, InconsistentRightHandSideIsReported) {
  std::mt19937_64 rng(103);
  for (int trial = 0; trial < kTrials; ++trial) {
    const Mat M = random_spd_mass(rng);
    auto r = redundant_set(rng);
    r.b(6) += 0.5;  // a redundant row that now contradicts the others
    const Vec Q = random_vector(rng, 12);
    const auto uk = solve_uk(M, r.A, r.b, Q);
    EXPECT_FALSE(uk.res.consistent) << "trial " << trial << " residual " << uk.res.residual;
    EXPECT_GT(uk.res.residual, 1e-3);
    EXPECT_TRUE(uk.res.finite);
    const auto tb = solve_textbook(M, r.A, r.b, Q);
    EXPECT_FALSE(tb.res.consistent);
    EXPECT_TRUE(std::isfinite(uk.qdd.norm()));
    // Note: for an inconsistent set the production form (a basic solution of the pivoted LDLᵀ) is
    // NOT the pseudo-inverse's least-squares answer of the textbook form; only the flag is
    // promised.
  }
}

TEST(UkSolve, GaussPrincipleOfLeastConstraint) {
  std::mt19937_64 rng(104);
  for (int trial = 0; trial < kTrials; ++trial) {
    const Eigen::Index m = 1 + trial % 11;
    const Mat M = random_spd_mass(rng);
    const Mat A = random_matrix(rng, m, 12);
    const Vec b = random_vector(rng, m), Q = random_vector(rng, 12);
    const auto uk = solve_uk(M, A, b, Q);
    const Mat N = uktest::null_space(A);
    ASSERT_EQ(N.cols(), 12 - m);
    const double g0 = gauss(M, Q, uk.qdd);
    for (int k = 0; k < 10; ++k) {
      const Vec dx = N * random_vector(rng, N.cols()) * uktest::uniform(rng, 1e-3, 1.0);
      const Vec x = uk.qdd + dx;  // admissible: A x = b
      const double g = gauss(M, Q, x);
      EXPECT_GE(g, g0) << "trial " << trial;
      // Exactly: G(q̈ + dx) − G(q̈) = dxᵀ M dx (q̈ − M⁻¹Q is M-orthogonal to null(A)).
      EXPECT_NEAR(g - g0, dx.dot(M * dx), 1e-9 * (g0 + 1.0)) << "trial " << trial;
    }
  }
}

TEST(UkSolve, IdealConstraintForceDoesNoVirtualWork) {
  std::mt19937_64 rng(105);
  for (int trial = 0; trial < kTrials; ++trial) {
    const Eigen::Index m = 1 + trial % 11;
    const Mat M = random_spd_mass(rng);
    Mat A = random_matrix(rng, m, 12);
    const Vec b = random_vector(rng, m), Q = random_vector(rng, 12);
    const auto uk = solve_uk(M, A, b, Q);
    const Mat N = uktest::null_space(A);
    EXPECT_LE((N.transpose() * uk.Qc).norm(), 1e-12 * (uk.Qc.norm() + Q.norm()))
        << "trial " << trial;
  }
  // Also for the redundant set.
  const Mat M = random_spd_mass(rng);
  const auto r = redundant_set(rng);
  const auto uk = solve_uk(M, r.A, r.b, random_vector(rng, 12));
  const Mat N = uktest::null_space(r.A);
  ASSERT_EQ(N.cols(), 2);
  EXPECT_LE((N.transpose() * uk.Qc).norm(), 1e-11 * (uk.Qc.norm() + 1.0));
}

TEST(UkSolve, NoConstraintRowsGivesUnconstrainedAcceleration) {
  std::mt19937_64 rng(106);
  const Mat M = random_spd_mass(rng);
  const Vec Q = random_vector(rng, 12);
  const Mat A(0, 12);
  const Vec b(0);
  const auto uk = solve_uk(M, A, b, Q);
  EXPECT_TRUE(uk.res.finite);
  EXPECT_EQ(uk.res.rank, 0);
  EXPECT_LE(rel_err(uk.qdd, Vec(M.llt().solve(Q))), 1e-13);
  EXPECT_LE(uk.Qc.norm(), 0.0);
  const auto tb = solve_textbook(M, A, b, Q);
  EXPECT_LE(rel_err(tb.qdd, Vec(M.llt().solve(Q))), 1e-12);
  EXPECT_LE(tb.Qc.norm(), 1e-14);
}

TEST(UkSolve, NonPositiveDefiniteMassIsReportedWithoutCrash) {
  std::mt19937_64 rng(107);
  Mat M = random_spd_mass(rng);
  M(8, 8) = -50.0;  // the second block is indefinite
  const Mat A = random_matrix(rng, 4, 12);
  const Vec b = random_vector(rng, 4), Q = random_vector(rng, 12);
  const auto uk = solve_uk(M, A, b, Q);
  EXPECT_FALSE(uk.res.finite);
  // A NaN entry as well.
  Mat Mn = random_spd_mass(rng);
  Mn(2, 2) = std::numeric_limits<double>::quiet_NaN();
  const auto un = solve_uk(Mn, A, b, Q);
  EXPECT_FALSE(un.res.finite);
  // A singular (zero) block.
  Mat Mz = random_spd_mass(rng);
  Mz.block(0, 0, 6, 6).setZero();
  const auto uz = solve_uk(Mz, A, b, Q);
  EXPECT_FALSE(uz.res.finite);
}

TEST(UkSolve, WorkspaceIsReusableAndFactoredPathAgrees) {
  std::mt19937_64 rng(108);
  UkWorkspace ws(layout66(), 7);
  Vec qdd(12), Qc(12), qdd2(12), Qc2(12);
  for (int trial = 0; trial < 5; ++trial) {
    const Mat M = random_spd_mass(rng);
    const Mat A = random_matrix(rng, 7, 12);
    const Vec b = random_vector(rng, 7), Q = random_vector(rng, 12);
    ukdyn::uk_solve(M, A, b, Q, ws, qdd, Qc);
    const auto fresh = solve_uk(M, A, b, Q);
    EXPECT_EQ((qdd - fresh.qdd).norm(), 0.0);
    EXPECT_EQ((Qc - fresh.Qc).norm(), 0.0);
    ASSERT_TRUE(ukdyn::factor_mass(M, ws));
    ukdyn::uk_solve_factored(A, b, Q, ws, qdd2, Qc2);
    EXPECT_EQ((qdd2 - qdd).norm(), 0.0);
  }
}

// The paper's shapes (two blocks of 6, m = 6 or 12) run a compile-time-sized path of the solve;
// a single 12 × 12 block runs the generic one on the same numbers (L has exact zeros off the
// blocks). Both must give the same rank and agree to rounding: full rank, redundant rows, and
// sparse rows (rows that touch one arm only, as trajectory rows do).
TEST(UkSolve, FixedSizePathAgreesWithGenericPath) {
  std::mt19937_64 rng(109);
  for (int trial = 0; trial < 200; ++trial) {
    const Mat M = random_spd_mass(rng);
    const Eigen::Index m = trial % 2 == 0 ? 6 : 12;
    Mat A = random_matrix(rng, m, 12);
    if (trial % 3 == 1) {  // redundant: the last two rows are combinations of the others
      A.row(m - 1) = 0.5 * A.row(0) - 1.5 * A.row(1);
      A.row(m - 2) = 2.0 * A.row(2) + 0.25 * A.row(3);
    } else if (trial % 3 == 2) {  // sparse: half of the rows touch one arm only
      for (Eigen::Index i = 0; i < m / 2; ++i) A.block(i, i % 2 == 0 ? 6 : 0, 1, 6).setZero();
    }
    const Vec x = random_vector(rng, 12), Q = random_vector(rng, 12);
    const Vec b = A * x;
    UkWorkspace fixed(layout66(), m), generic(BlockLayout::single(12), m);
    Vec qf(12), Qcf(12), qg(12), Qcg(12);
    const UkResult rf = ukdyn::uk_solve(M, A, b, Q, fixed, qf, Qcf);
    const UkResult rg = ukdyn::uk_solve(M, A, b, Q, generic, qg, Qcg);
    const int expected_rank = trial % 3 == 1 ? static_cast<int>(m) - 2 : static_cast<int>(m);
    EXPECT_EQ(rf.rank, expected_rank) << "trial " << trial;
    EXPECT_EQ(rg.rank, expected_rank) << "trial " << trial;
    EXPECT_TRUE(rf.consistent && rg.consistent) << "trial " << trial;
    // Rounding differs between the two paths (FMA contraction with -march=native), and W = A M⁻¹Aᵀ
    // amplifies it by κ(W) = κ(A M^{-1/2})²: the bound is a few ulps of that.
    const Vec sv = ukdyn::singular_values_A_Minvhalf(M, A);
    const double kappa = sv(0) / sv(expected_rank - 1);
    const double tol = 1e-15 * std::max(1.0, kappa * kappa);
    EXPECT_LE(rel_err(qf, qg), tol) << "trial " << trial << " kappa " << kappa;
    EXPECT_LE(rel_err(Qcf, Qcg), tol) << "trial " << trial << " kappa " << kappa;
    EXPECT_NEAR(rf.sigma_max, rg.sigma_max, 1e-12 * rg.sigma_max) << "trial " << trial;
  }
}

// The paper's system: at q0 the closure + trajectory constraints have full rank 12, and forward()
// gives a q̈ that satisfies A q̈ = b and agrees with the KKT solve.
TEST(UkSolve, PaperSystemHasFullRankAtInitialState) {
  uktest::TwoArms two;
  two.add_closure();
  const Vec q0 = uktest::paper_q0();
  two.add_paper_trajectory(q0);
  ASSERT_EQ(two.system->rows(), 12);
  ukdyn::ForwardData data(*two.system);
  const Vec qd = Vec::Zero(12), tau = Vec::Zero(12);
  ukdyn::forward(*two.system, data, 0.0, q0, qd, tau);
  EXPECT_EQ(data.result.rank, 12);
  EXPECT_TRUE(data.result.finite);
  EXPECT_TRUE(data.result.consistent);
  EXPECT_LE((data.A * data.qdd - data.b).norm(), 1e-12 * (data.b.norm() + 1.0));
  Vec qdd(12), Qc(12);
  ukdyn::kkt_solve(data.M, data.A, data.b, data.Q, qdd, Qc);
  EXPECT_LE(rel_err(data.qdd, qdd), 1e-10);
  EXPECT_LE(rel_err(data.Qc, Qc), 1e-10);
  // Fully prescribed: q̈ follows from A q̈ = b alone (A square, invertible).
  const Vec qdd_kin = data.A.fullPivLu().solve(data.b);
  EXPECT_LE(rel_err(data.qdd, qdd_kin), 1e-10);
  // b at t = 0, q̇ = 0: only the trajectory's f̈ = 0.5 π² (y and z rows).
  EXPECT_NEAR(data.b(7), 0.5 * uktest::kPi * uktest::kPi, 1e-12);
  EXPECT_NEAR(data.b(8), 0.5 * uktest::kPi * uktest::kPi, 1e-12);
}

// The closure alone leaves 6 degrees of freedom (rank 6) and τ changes the motion.
TEST(UkSolve, PaperClosureOnlyHasRankSix) {
  uktest::TwoArms two;
  two.add_closure();
  ukdyn::ForwardData data(*two.system);
  const Vec q0 = uktest::paper_q0();
  Vec tau = Vec::Zero(12);
  ukdyn::forward(*two.system, data, 0.0, q0, Vec::Zero(12), tau);
  EXPECT_EQ(data.result.rank, 6);
  const Vec qdd0 = data.qdd;
  tau(3) = 5.0;
  ukdyn::forward(*two.system, data, 0.0, q0, Vec::Zero(12), tau);
  EXPECT_GT((data.qdd - qdd0).norm(), 1e-3);
  EXPECT_LE((data.A * data.qdd - data.b).norm(), 1e-12);
}

}  // namespace
