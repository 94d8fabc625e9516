// The actuation inverse dynamics and the split of the constraint force by block
// (ukdyn/core/force_split.hpp, ukdyn/core/constraint_forces.hpp) where the rank is decided at the
// tolerance and the matrix has round-off entries: the least-norm solutions, in closed form.
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <Eigen/LU>

#include "ukdyn/core/constraint_forces.hpp"
#include "ukdyn/core/force_split.hpp"

namespace ukdyn {
namespace {

// B = I (every coordinate actuated) and physical rows A_p of full rank: P = I − A_p⁺A_p is a
// projector whose round-off entries keep P B of full numerical rank at Eigen's default threshold
// but not at the solve's. The least-norm u with B u + A_pᵀμ = Qc is u = P Qc (B = I, P an
// orthogonal projector), μ = (A_p A_pᵀ)⁻¹ A_p Qc.
TEST(ActuationSolve, LeastNormWhenTheProjectorHasRoundOffRank) {
  Mat Ap(2, 3);
  Ap << 1.0, 0.3, -0.7, 0.2, 1.1, 0.4;
  Vec Qc(3);
  Qc << 0.5, -1.25, 2.0;
  const Mat B = Mat::Identity(3, 3);
  const Mat P = Mat::Identity(3, 3) - Ap.transpose() * (Ap * Ap.transpose()).inverse() * Ap;
  const Vec u_exact = P * Qc;
  const Vec mu_exact = (Ap * Ap.transpose()).ldlt().solve(Ap * Qc);
  const Actuation a = solve_actuation(B, Ap, Qc);
  EXPECT_LT((a.u - u_exact).cwiseAbs().maxCoeff(), 1e-12) << a.u.transpose();
  EXPECT_LT((a.mu - mu_exact).cwiseAbs().maxCoeff(), 1e-12) << a.mu.transpose();
  ActuationWorkspace ws(3, 3, 2);
  ws.Ap = Ap;
  solve_actuation(B, Qc, ws);
  EXPECT_LT((ws.result.u - u_exact).cwiseAbs().maxCoeff(), 1e-12) << ws.result.u.transpose();
  // Four wheels for three platform directions (redundant actuation, no physical rows): the
  // least-norm u = Bᵀ(B Bᵀ)⁻¹ Qc, here equal shares.
  Mat W(3, 4);
  W << 1, 1, 1, 1, -1, 1, 1, -1, -1, 1, -1, 1;
  Vec f(3);
  f << 2.65, 0, 0;
  const Actuation w = solve_actuation(W, Mat(0, 3), f);
  EXPECT_LT((w.u - Vec::Constant(4, 0.6625)).cwiseAbs().maxCoeff(), 1e-12) << w.u.transpose();
  // Two actuators that differ by 1e-12 (rank 1 at the solve's tolerance 1e-10, rank 2 at Eigen's
  // default): the least-norm u shares the force, u = (1, 1), not the basic solution (2, 0).
  Mat B2(2, 2);
  B2 << 1.0, 1.0, 1.0, 1.0 + 1e-12;
  const Vec f2 = Vec::Constant(2, 2.0);
  const Actuation b = solve_actuation(B2, Mat(0, 2), f2);
  EXPECT_LT((b.u - Vec::Ones(2)).cwiseAbs().maxCoeff(), 1e-9) << b.u.transpose();
  ActuationWorkspace ws2(2, 2, 0);
  solve_actuation(B2, f2, ws2);
  EXPECT_LT((ws2.result.u - Vec::Ones(2)).cwiseAbs().maxCoeff(), 1e-9) << ws2.result.u.transpose();
}

// Physical rows that span every coordinate (A_p of full column rank): P = 0 up to round-off, so
// nothing is left for the actuators, u = 0 (the relative rank threshold alone kept the round-off
// at full rank and amplified it: τ of 296 on the paper's fully prescribed system).
TEST(ActuationSolve, NothingLeftForTheActuatorsGivesZero) {
  Mat Ap(3, 3);
  Ap << 1.0, 0.3, -0.7, 0.2, 1.1, 0.4, 0.5, -0.2, 0.9;
  Vec Qc(3);
  Qc << 0.5, -1.25, 2.0;
  const Actuation a = solve_actuation(Mat::Identity(3, 3), Ap, Qc);
  EXPECT_EQ(a.u.cwiseAbs().maxCoeff(), 0.0) << a.u.transpose();
  EXPECT_LT((Ap.transpose() * a.mu - Qc).cwiseAbs().maxCoeff(), 1e-12);
  ActuationWorkspace ws(3, 3, 3);
  ws.Ap = Ap;
  solve_actuation(Mat::Identity(3, 3), Qc, ws);
  EXPECT_EQ(ws.result.u.cwiseAbs().maxCoeff(), 0.0) << ws.result.u.transpose();
}

// Two identical rows (rank 1 of 2): the least-norm λ splits the force equally.
TEST(ConstraintForceSplit, RedundantRowsShareTheForceEqually) {
  Mat A(2, 2);
  A << 1.0, 2.0, 1.0, 2.0 + 1e-12;  // rank 1 at 1e-10, 2 at Eigen's default threshold
  Vec Qc(2);
  Qc << 3.0, 6.0;
  const ConstraintForceSplit s = split_constraint_force(A, Qc, {0, 1});
  EXPECT_EQ(s.rank, 1);
  EXPECT_NEAR(s.lambda(0), 1.5, 1e-9);
  EXPECT_NEAR(s.lambda(1), 1.5, 1e-9);
}

}  // namespace
}  // namespace ukdyn
