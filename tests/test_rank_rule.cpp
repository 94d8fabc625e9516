// The one pivoted LDLᵀ and rank rule of the U-K solves (src/core/dense_kernels.hpp, pivoted_ldlt):
// the stopping criterion D_k ≤ max(μ/2, τ² s), s = max(D_0 − μ, s_ref), and the rank count
// D_k − μ > τ² s, on small matrices whose pivots are known.
#include <gtest/gtest.h>

#include <vector>

#include "core/dense_kernels.hpp"

namespace {

using ukdyn::Index;
using ukdyn::detail::LdltPivots;
using ukdyn::detail::pivoted_ldlt;
using ukdyn::detail::RankRule;

// diag(d) in lower column-major storage; its pivots are d sorted descending.
std::vector<double> diagonal(const std::vector<double>& d) {
  const std::size_t m = d.size();
  std::vector<double> W(m * m, 0.0);
  for (std::size_t i = 0; i < m; ++i) W[i + i * m] = d[i];
  return W;
}

LdltPivots factor(std::vector<double> W, Index m, const RankRule& rule,
                  std::vector<Index>* piv_out = nullptr) {
  std::vector<Index> piv(static_cast<std::size_t>(m), 0);
  std::vector<double> t(static_cast<std::size_t>(m), 0.0);
  const LdltPivots pv = pivoted_ldlt(W.data(), m, m, piv.data(), t.data(), rule);
  if (piv_out) *piv_out = piv;
  return pv;
}

TEST(RankRule, DropsPivotsUnderTauSquaredOfTheLargest) {
  // Pivots 4, 1, 1e-15, 0: with τ = 1e-7 (τ² = 1e-14) the cut-off is 4e-14.
  const auto pv = factor(diagonal({1e-15, 4.0, 0.0, 1.0}), 4, RankRule{1e-14});
  EXPECT_EQ(pv.kept, 2);
  EXPECT_EQ(pv.rank, 2);
  EXPECT_EQ(pv.d_max, 4.0);
  EXPECT_EQ(pv.d_min_kept, 1.0);
}

TEST(RankRule, PivotsAreTakenLargestFirst) {
  std::vector<Index> piv;
  factor(diagonal({1.0, 3.0, 2.0}), 3, RankRule{1e-14}, &piv);
  EXPECT_EQ(piv[0], 1);  // 3 first
  EXPECT_EQ(piv[1], 2);  // then 2 (row 2 after the swap of rows 0 and 1)
}

TEST(RankRule, AReferenceScaleCarriesTheWholeProblemsScaleIntoAPiece) {
  // A Schur-complement piece with pivots 1e-3, 1e-12 of a problem whose max diag W is 1e3: the
  // whole problem's cut-off τ² · 1e3 = 1e-11 drops 1e-12, which the piece's own scale would keep.
  const auto own = factor(diagonal({1e-3, 1e-12}), 2, RankRule{1e-14});
  EXPECT_EQ(own.kept, 2);
  const auto whole = factor(diagonal({1e-3, 1e-12}), 2, RankRule{1e-14, 0.0, 1e3});
  EXPECT_EQ(whole.kept, 1);
  EXPECT_EQ(whole.rank, 1);
  // A reference under the piece's own largest pivot changes nothing.
  const auto small_ref = factor(diagonal({1e-3, 1e-12}), 2, RankRule{1e-14, 0.0, 1e-6});
  EXPECT_EQ(small_ref.kept, 2);
}

TEST(RankRule, AShiftedMatrixKeepsPivotsAboveHalfTheShiftAndCountsTheUnshifted) {
  // W + μ I with W = diag(1, 1e-20) and μ = 1e-10: pivots 1 + μ, 1e-20 + μ.
  const double mu = 1e-10;
  // Regularized: only μ/2 is a cut-off; the second pivot is kept but not counted in the rank
  // (1e-20 ≤ τ² s).
  const auto reg = factor(diagonal({1.0 + mu, 1e-20 + mu}), 2, RankRule{1e-14, mu, 0.0, false});
  EXPECT_EQ(reg.kept, 2);
  EXPECT_EQ(reg.rank, 1);
  // With τ above μ/2's level (τ² s = 1e-8 > μ/2) the damped adaptive rule drops it, the
  // regularized one still keeps it.
  const auto damped = factor(diagonal({1.0 + mu, 1e-20 + mu}), 2, RankRule{1e-8, mu});
  EXPECT_EQ(damped.kept, 1);
  const auto reg_big_tau =
      factor(diagonal({1.0 + mu, 1e-20 + mu}), 2, RankRule{1e-8, mu, 0.0, false});
  EXPECT_EQ(reg_big_tau.kept, 2);
}

TEST(RankRule, AZeroMatrixKeepsNothing) {
  const auto pv = factor(diagonal({0.0, 0.0}), 2, RankRule{1e-14});
  EXPECT_EQ(pv.kept, 0);
  EXPECT_EQ(pv.rank, 0);
  EXPECT_EQ(pv.d_max, 0.0);
}

TEST(RankRule, BasicSolutionGivesZeroToDroppedRows) {
  // W = [[2, 2], [2, 2]] (rank 1), r = (2, 2): the kept pivot is row 0, λ = (1, 0).
  std::vector<double> W = {2.0, 2.0, 0.0, 2.0};
  std::vector<Index> piv(2, 0);
  std::vector<double> t(2, 0.0);
  const auto pv = pivoted_ldlt(W.data(), 2, 2, piv.data(), t.data(), RankRule{1e-14});
  ASSERT_EQ(pv.kept, 1);
  std::vector<double> lam = {2.0, 2.0};
  ukdyn::detail::ldlt_basic_solve(W.data(), 2, 2, pv.kept, piv.data(), lam.data());
  EXPECT_DOUBLE_EQ(lam[0], 1.0);
  EXPECT_EQ(lam[1], 0.0);
}

}  // namespace
