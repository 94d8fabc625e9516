// The small dense kernels of the U-K solves (src/core/dense_kernels.hpp) on the block sizes they
// unroll for (6, 7, 10) against the same kernel at run-time size, which has no fixed-size code
// path: the fixed sizes promise the same operations in the same order, so the factors must be
// equal bit for bit; and against the matrix itself (L Lᵀ = M), which does not trust either.
#include <gtest/gtest.h>

#include <random>

#include "core/dense_kernels.hpp"

namespace {

using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;

template <int N>
void expect_fixed_cholesky_is_the_runtime_one(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  // The block at (3, 3) of a larger matrix, as in a system's M: leading dimensions 27, not N.
  const Index n = N, ld = 27, s = 3;
  for (int trial = 0; trial < 50; ++trial) {
    const Mat F = Mat::NullaryExpr(n, n, [&] { return u(rng); });
    Mat M = Mat::Zero(ld, ld);
    M.block(s, s, n, n) = F * F.transpose() + 0.01 * Mat::Identity(n, n);
    Mat L_fixed = Mat::Zero(ld, ld), L_rt = Mat::Zero(ld, ld);
    Vec id_fixed = Vec::Zero(ld), id_rt = Vec::Zero(ld);
    double ratio_fixed = 0.0, ratio_rt = 0.0;
    const double* Mk = M.data() + s + s * ld;
    ASSERT_TRUE(ukdyn::detail::chol_block<N>(Mk, ld, L_fixed.data() + s + s * ld, ld,
                                             id_fixed.data() + s, n, &ratio_fixed));
    ASSERT_TRUE(ukdyn::detail::chol_block<0>(Mk, ld, L_rt.data() + s + s * ld, ld, id_rt.data() + s,
                                             n, &ratio_rt));
    for (Index j = 0; j < ld; ++j)
      for (Index i = 0; i < ld; ++i) EXPECT_EQ(L_fixed(i, j), L_rt(i, j)) << i << ", " << j;
    for (Index i = 0; i < ld; ++i) EXPECT_EQ(id_fixed[i], id_rt[i]);
    EXPECT_EQ(ratio_fixed, ratio_rt);
    // Only the block's lower triangle is written, and it factors M's block.
    const Mat Lk = L_fixed.block(s, s, n, n).triangularView<Eigen::Lower>();
    Mat outside = L_fixed;
    outside.block(s, s, n, n) -= Lk;
    EXPECT_EQ(outside.cwiseAbs().maxCoeff(), 0.0);
    EXPECT_LE((Lk * Lk.transpose() - M.block(s, s, n, n)).lpNorm<Eigen::Infinity>(),
              1e-13 * M.block(s, s, n, n).lpNorm<Eigen::Infinity>());
  }
}

TEST(DenseKernels, FixedSizeCholeskyIsTheRuntimeSizeOneBitForBit) {
  std::mt19937 rng(20261205u);
  expect_fixed_cholesky_is_the_runtime_one<6>(rng);
  expect_fixed_cholesky_is_the_runtime_one<7>(rng);
  expect_fixed_cholesky_is_the_runtime_one<10>(rng);
}

}  // namespace
