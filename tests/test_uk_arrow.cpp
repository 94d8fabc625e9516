// The block-arrow U-K solve (ukdyn/core/uk_arrow.hpp) against the dense one (uk_solve.hpp) on the
// same states: N arms carrying a load (tests/n_robots_model.hpp), with redundant grasps, a
// rank-deficient robot block, duplicated rows, rows on the load alone and on a robot alone.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <cmath>
#include <random>

#include "helpers.hpp"
#include "n_robots_model.hpp"
#include "ukdyn/core/uk_arrow.hpp"
#include "ukdyn/model/system.hpp"
#include "ukdyn/symbolic/definitions.hpp"
#ifdef UKDYN_HAVE_IO
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/simulate/simulate.hpp"
#endif

namespace {

using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;

TEST(UkArrow, DetectsTheArrowStructure) {
  const ukdyn::BlockLayout lay{{0, 3, 6, 9}, {3, 3, 3, 3}};
  // Rows on (0, 3), (1, 3), (2, 3), (3), (1): an arrow with load 3.
  const auto s = ukdyn::detect_arrow(lay, {{0, 3}, {1, 3}, {1, 3}, {2, 3}, {3}, {1}});
  ASSERT_TRUE(s.has_value());
  EXPECT_EQ(s->load_block, 3);
  ASSERT_EQ(s->groups.size(), 3u);
  EXPECT_EQ(s->groups[1].block, 1);
  EXPECT_EQ(s->groups[1].rows, (std::vector<Index>{1, 2, 5}));
  EXPECT_EQ(s->load_rows, (std::vector<Index>{4}));
  // A row coupling two robots breaks it, so does a row on three blocks.
  EXPECT_FALSE(ukdyn::detect_arrow(lay, {{0, 3}, {1, 3}, {0, 1}}).has_value());
  EXPECT_FALSE(ukdyn::detect_arrow(lay, {{0, 3}, {1, 2, 3}}).has_value());
  // A single coupled pair: the dense solve is kept (min_groups = 2).
  EXPECT_FALSE(ukdyn::detect_arrow(lay, {{0, 3}, {3}}).has_value());
}

TEST(UkArrow, SystemsWithoutDeclaredSparsityStayDense) {
  uktest::TwoArms two;  // the paper's closed-form arms and closure constraint
  two.add_closure();
  EXPECT_EQ(two.system->arrow(), nullptr);
}

struct Case {
  const char* name;
  uktest::NRobotsOptions o;
  int expected_rank;  // at a generic state
  /// Relative agreement in q̈ and Qc. Full-rank rows: 1e-12. With redundant rows (rank decisions)
  /// both solves are accurate to cond · ε only, and their different elimination orders were
  /// measured to differ by up to 1.7e-11 (q̈) and 4.5e-11 (Qc) over these 300 states: 1e-10.
  double tol = 1e-12;
};

void expect_arrow_agrees_with_dense(const Case& c, int states) {
  SCOPED_TRACE(c.name);
  const auto sys = uktest::n_robots_system(c.o);
  ASSERT_NE(sys->arrow(), nullptr);
  const Index n = sys->dof(), m = sys->rows();
  ukdyn::ForwardData data(*sys);
  ukdyn::UkWorkspace dense_ws(sys->layout(), m);
  Vec qdd_d(n), Qc_d(n);
  std::mt19937 rng(20261201u);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  double worst_q = 0.0, worst_c = 0.0;
  for (int k = 0; k < states; ++k) {
    Vec q(n), qd(n), tau(n);
    for (Index i = 0; i < n; ++i) {
      q[i] = 1.5 * u(rng);
      qd[i] = u(rng);
      tau[i] = 2.0 * u(rng);
    }
    const double t = u(rng);
    ukdyn::forward(*sys, data, t, q, qd, tau);
    ASSERT_TRUE(data.used_arrow);
    ASSERT_TRUE(data.result.finite);
    EXPECT_TRUE(data.result.consistent);
    const ukdyn::UkResult rd =
        ukdyn::uk_solve(data.M, data.A, data.b, data.Q, dense_ws, qdd_d, Qc_d);
    ASSERT_TRUE(rd.finite);
    EXPECT_EQ(data.result.rank, rd.rank) << "state " << k;
    EXPECT_EQ(data.result.rank, c.expected_rank) << "state " << k;
    // Relative agreement (infinity norm).
    const double dq = (data.qdd - qdd_d).lpNorm<Eigen::Infinity>() /
                      std::max(1.0, qdd_d.lpNorm<Eigen::Infinity>());
    const double dc =
        (data.Qc - Qc_d).lpNorm<Eigen::Infinity>() / std::max(1.0, Qc_d.lpNorm<Eigen::Infinity>());
    worst_q = std::max(worst_q, dq);
    worst_c = std::max(worst_c, dc);
    // The multipliers reproduce Qc: Aᵀλ = Qc, and M q̈ = Q + Qc.
    const Vec Atl = data.A.transpose() * data.arrow.lambda;
    EXPECT_LE((Atl - data.Qc).lpNorm<Eigen::Infinity>(),
              1e-12 * std::max(1.0, data.Qc.lpNorm<Eigen::Infinity>()));
  }
  EXPECT_LE(worst_q, c.tol);
  EXPECT_LE(worst_c, c.tol);
  ::testing::Test::RecordProperty("worst_qdd_rel", ::testing::PrintToString(worst_q));
}

TEST(UkArrow, AgreesWithDenseSolveRedundantGrasps) {
  for (int robots : {2, 3, 5, 8}) {
    uktest::NRobotsOptions o;
    o.robots = robots;
    expect_arrow_agrees_with_dense({"grasps", o, 2 * robots}, 100);
  }
}

TEST(UkArrow, AgreesWithDenseSolveRankDecisions) {
  uktest::NRobotsOptions o;
  o.robots = 4;
  o.duplicate_grasp = true;  // 2 exactly redundant rows in robot 0's block
  o.load_row = true;
  o.free_robot = true;
  expect_arrow_agrees_with_dense({"duplicate + load row + free robot", o, 9, 1e-10}, 100);
  uktest::NRobotsOptions p;
  p.robots = 3;
  p.one_link_robot = true;  // robot 0: 1 joint, 2 grasp rows: one row moves to the load
  p.load_row = true;
  expect_arrow_agrees_with_dense({"one-link robot + load row", p, 7, 1e-10}, 100);
  uktest::NRobotsOptions r;
  r.robots = 3;
  r.robot_row = true;
  r.duplicate_grasp = true;
  expect_arrow_agrees_with_dense({"robot row + duplicate", r, 7, 1e-10}, 100);
}

// The shape with compile-time sizes (two arms of 10 coordinates with 6 rows each on a load of 7
// with one row of its own: two Pandas welded to a plate) against the dense solve, on random
// problems: full rank, and with one arm's row repeated (a rank decision in its block); each with
// every arm's rows consecutive in A and with the two arms' rows interleaved.
void expect_fixed_shape_agrees_with_dense(bool redundant, double tol, bool interleaved = false) {
  const ukdyn::BlockLayout lay{{0, 10, 20}, {10, 10, 7}};
  std::vector<std::vector<Index>> row_blocks(6, {0, 2});
  row_blocks.insert(row_blocks.end(), 6, {1, 2});
  // Interleaved: the two robots' rows alternate in A, so neither group's rows are consecutive
  // (the solve gathers them instead of reading A's columns in place).
  if (interleaved)
    for (std::size_t i = 0; i < 12; ++i) row_blocks[i] = {static_cast<Index>(i % 2), 2};
  row_blocks.push_back({2});
  const auto st = ukdyn::detect_arrow(lay, row_blocks);
  ASSERT_TRUE(st.has_value());
  const Index n = 27, m = 13;
  ukdyn::UkWorkspace arrow_dws(lay, m), dense_ws(lay, m);
  ukdyn::ArrowWorkspace aws(*st, m);
  std::mt19937 rng(redundant ? 20261205u : 20261204u);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  double worst_q = 0.0, worst_c = 0.0;
  for (int k = 0; k < 200; ++k) {
    Mat M = Mat::Zero(n, n), A = Mat::Zero(m, n);
    for (std::size_t blk = 0; blk < 3; ++blk) {
      const Index s = lay.start[blk], nk = lay.size[blk];
      const Mat F = Mat::NullaryExpr(nk, nk, [&] { return u(rng); });
      M.block(s, s, nk, nk) = F * F.transpose() + 0.1 * Mat::Identity(nk, nk);
    }
    for (Index i = 0; i < m; ++i)
      for (const Index blk : row_blocks[static_cast<std::size_t>(i)])
        for (Index j = 0; j < lay.size[static_cast<std::size_t>(blk)]; ++j)
          A(i, lay.start[static_cast<std::size_t>(blk)] + j) = u(rng);
    Vec Q = Vec::NullaryExpr(n, [&] { return u(rng); });
    Vec b = Vec::NullaryExpr(m, [&] { return u(rng); });
    if (redundant) {  // a row repeated in its group (its right-hand side too): rank 12
      const Index from = 2, to = interleaved ? 6 : 5;
      A.row(to) = A.row(from);
      b[to] = b[from];
    }
    Vec qdd(n), Qc(n), qdd_d(n), Qc_d(n);
    ukdyn::UkResult ra;
    ASSERT_TRUE(ukdyn::factor_mass(M, arrow_dws));
    ASSERT_TRUE(ukdyn::uk_solve_arrow(*st, M, A, b, Q, arrow_dws, aws, qdd, Qc, {}, ra));
    const ukdyn::UkResult rd = ukdyn::uk_solve(M, A, b, Q, dense_ws, qdd_d, Qc_d);
    EXPECT_EQ(ra.rank, rd.rank) << "problem " << k;
    EXPECT_EQ(ra.rank, redundant ? 12 : 13) << "problem " << k;
    EXPECT_TRUE(ra.consistent);
    worst_q = std::max(worst_q, (qdd - qdd_d).lpNorm<Eigen::Infinity>() /
                                    std::max(1.0, qdd_d.lpNorm<Eigen::Infinity>()));
    worst_c = std::max(worst_c, (Qc - Qc_d).lpNorm<Eigen::Infinity>() /
                                    std::max(1.0, Qc_d.lpNorm<Eigen::Infinity>()));
    // The multipliers reproduce Qc.
    EXPECT_LE((A.transpose() * aws.lambda - Qc).lpNorm<Eigen::Infinity>(),
              1e-12 * std::max(1.0, Qc.lpNorm<Eigen::Infinity>()));
    if (redundant) {
      // The repeated row asking for another value: inconsistent for both solves, with the same
      // residual (the basic solution keeps one of the two rows, 1 apart: ‖A q̈ − b‖ = 1).
      Vec b_bad = b;
      b_bad[interleaved ? 6 : 5] += 1.0;
      ukdyn::UkResult rb;
      ASSERT_TRUE(ukdyn::uk_solve_arrow(*st, M, A, b_bad, Q, arrow_dws, aws, qdd, Qc, {}, rb));
      const ukdyn::UkResult rdb = ukdyn::uk_solve(M, A, b_bad, Q, dense_ws, qdd_d, Qc_d);
      EXPECT_FALSE(rb.consistent) << "problem " << k;
      EXPECT_FALSE(rdb.consistent) << "problem " << k;
      EXPECT_NEAR(rb.residual, 1.0, 1e-9) << "problem " << k;
      EXPECT_NEAR(rdb.residual, 1.0, 1e-9) << "problem " << k;
      // A tolerance under which only the ‖A‖_∞ ‖q̈‖ term of the scale makes it consistent: half
      // the residual over ‖b‖ + 1 (the scale's other terms), with ‖A‖_∞ ‖q̈‖ ≥ 2 (‖b‖ + 1).
      const double a_inf = A.cwiseAbs().rowwise().sum().maxCoeff();
      ASSERT_GE(a_inf * qdd_d.norm(), 2.0 * (b_bad.norm() + 1.0)) << "problem " << k;
      ukdyn::UkSettings loose;
      loose.consistency_rel_tol = 0.5 * rdb.residual / (b_bad.norm() + 1.0);
      ASSERT_TRUE(ukdyn::uk_solve_arrow(*st, M, A, b_bad, Q, arrow_dws, aws, qdd, Qc, loose, rb));
      EXPECT_TRUE(rb.consistent) << "problem " << k;
      EXPECT_TRUE(ukdyn::uk_solve(M, A, b_bad, Q, dense_ws, qdd_d, Qc_d, loose).consistent);
    }
  }
  EXPECT_LE(worst_q, tol);
  EXPECT_LE(worst_c, tol);
}

TEST(UkArrow, FixedSizeShapeAgreesWithDenseSolve) {
  expect_fixed_shape_agrees_with_dense(false, 1e-12);
  expect_fixed_shape_agrees_with_dense(true, 1e-10);
  expect_fixed_shape_agrees_with_dense(false, 1e-12, true);
  expect_fixed_shape_agrees_with_dense(true, 1e-10, true);
}

// The rank scale max diag W, W_ii = S_ii + C_i M_L⁻¹ C_iᵀ, is formed only when a decision depends
// on it (uk_arrow.cpp, RankScale): here one row's load part makes max diag W 1e8 times any S_ii, and
// a near-repeated row (rows 2 and 5 differ by 1e-5 on the robot's columns alone) gives S_0 a pivot
// dp that the rank rule drops on max diag W (τ² max diag W = 100 dp) but would keep on max S_ii. The
// arrow solve must drop it as the dense solve does: the same rank, and q̈ and Qc to 1e-4 (the two
// eliminations settle the dropped row's 1e-5 differently; kept, q̈ moves by O(1)). Robots of 10
// (the compile-time shape) and of 9 coordinates (runtime sizes).
void expect_scale_dependent_decision_as_dense(Index nk) {
  const ukdyn::BlockLayout lay{{0, nk, 2 * nk}, {nk, nk, 7}};
  std::vector<std::vector<Index>> row_blocks(6, {0, 2});
  row_blocks.insert(row_blocks.end(), 6, {1, 2});
  row_blocks.push_back({2});
  const auto st = ukdyn::detect_arrow(lay, row_blocks);
  ASSERT_TRUE(st.has_value());
  const Index n = 2 * nk + 7, m = 13;
  ukdyn::UkWorkspace arrow_dws(lay, m), dense_ws(lay, m);
  ukdyn::ArrowWorkspace aws(*st, m);
  std::mt19937 rng(20261206u);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int k = 0; k < 20; ++k) {
    Mat M = Mat::Zero(n, n), A = Mat::Zero(m, n);
    for (std::size_t blk = 0; blk < 3; ++blk) {
      const Index s = lay.start[blk], nb = lay.size[blk];
      const Mat F = Mat::NullaryExpr(nb, nb, [&] { return u(rng); });
      M.block(s, s, nb, nb) = F * F.transpose() + 0.1 * Mat::Identity(nb, nb);
    }
    for (Index i = 0; i < m; ++i)
      for (const Index blk : row_blocks[static_cast<std::size_t>(i)])
        for (Index j = 0; j < lay.size[static_cast<std::size_t>(blk)]; ++j)
          A(i, lay.start[static_cast<std::size_t>(blk)] + j) = u(rng);
    A.block(0, 2 * nk, 1, 7) *= 1e4;  // row 0's load part: W_00 ≫ every S_ii
    A.row(5) = A.row(2);
    for (Index j = 0; j < nk; ++j) A(5, j) += 1e-5 * u(rng);
    const Vec Q = Vec::NullaryExpr(n, [&] { return u(rng); });
    Vec b = Vec::NullaryExpr(m, [&] { return u(rng); });
    b[5] = b[2];
    // The scales and the pivot, formed here from M and A directly.
    const Mat Minv = M.inverse();
    const Mat W = A * Minv * A.transpose();
    const Mat B0 = A.block(0, 0, 6, nk);
    const Mat S0 = B0 * Minv.block(0, 0, nk, nk) * B0.transpose();
    const double w_ref = W.diagonal().maxCoeff();
    double s_max = 0.0;
    for (std::size_t g = 0; g < 2; ++g) {
      const Mat Bg = A.block(6 * static_cast<Index>(g), nk * static_cast<Index>(g), 6, nk);
      const Mat Sg = Bg *
                     Minv.block(nk * static_cast<Index>(g), nk * static_cast<Index>(g), nk, nk) *
                     Bg.transpose();
      s_max = std::max(s_max, Sg.diagonal().maxCoeff());
    }
    const Eigen::SelfAdjointEigenSolver<Mat> es(S0);
    const double dp =
        es.eigenvalues()(0);  // ≈ the last pivot of S_0 (a 1-dimensional near-null space)
    ukdyn::UkSettings settings;
    settings.rank_rel_tol = std::sqrt(100.0 * dp / w_ref);
    const double tol2 = settings.rank_rel_tol * settings.rank_rel_tol;
    ASSERT_LT(tol2 * s_max, 1e-3 * dp) << "problem " << k;  // kept on max S_ii alone
    Vec qdd(n), Qc(n), qdd_d(n), Qc_d(n);
    ukdyn::UkResult ra;
    ASSERT_TRUE(ukdyn::factor_mass(M, arrow_dws));
    ASSERT_TRUE(ukdyn::uk_solve_arrow(*st, M, A, b, Q, arrow_dws, aws, qdd, Qc, settings, ra));
    const ukdyn::UkResult rd = ukdyn::uk_solve(M, A, b, Q, dense_ws, qdd_d, Qc_d, settings);
    EXPECT_EQ(rd.rank, 12) << "problem " << k;
    EXPECT_EQ(ra.rank, rd.rank) << "problem " << k;
    EXPECT_LE((qdd - qdd_d).lpNorm<Eigen::Infinity>(),
              1e-4 * std::max(1.0, qdd_d.lpNorm<Eigen::Infinity>()))
        << "problem " << k;
    EXPECT_LE((Qc - Qc_d).lpNorm<Eigen::Infinity>(),
              1e-4 * std::max(1.0, Qc_d.lpNorm<Eigen::Infinity>()))
        << "problem " << k;
  }
}

TEST(UkArrow, ARankDecisionThatDependsOnTheScaleIsTheDenseSolves) {
  expect_scale_dependent_decision_as_dense(10);
  expect_scale_dependent_decision_as_dense(9);
}

TEST(UkArrow, OtherMethodsUseTheDenseSolve) {
  uktest::NRobotsOptions o;
  const auto sys = uktest::n_robots_system(o);
  ukdyn::ForwardData data(*sys);
  const Vec q = Vec::Constant(sys->dof(), 0.3), qd = Vec::Constant(sys->dof(), 0.1);
  const Vec tau = Vec::Zero(sys->dof());
  ukdyn::UkSettings s;
  s.method = ukdyn::UkMethod::regularized;
  ukdyn::forward(*sys, data, 0.0, q, qd, tau, s);
  EXPECT_FALSE(data.used_arrow);
  ukdyn::forward(*sys, data, 0.0, q, qd, tau);
  EXPECT_TRUE(data.used_arrow);
}

// The grasps compiled with their numbers as tape inputs and positional coordinates, one program
// shared by robots 1..N−1 (TapePool; DerivedConstraint), against the same grasps compiled each with
// its numbers in its own tape (no pool): the two compilations differ in the order and form of the
// arithmetic, so they agree to round-off only. A, b, Φ, Φ̇ with and without slots, q̈ and Qc of
// forward(), and the tangents of A q̈ − b and Aᵀλ, at random states; N = 3 and 8, with redundant
// rows (a duplicated grasp), a row on the load and one on robot 0 alone.
TEST(SharedGraspTapes, SameRowsAndAccelerationsAsSeparateTapes) {
  struct SharedCase {
    const char* name;
    uktest::NRobotsOptions o;
    double tol;
  };
  std::vector<SharedCase> cases;
  for (int robots : {3, 8}) {
    uktest::NRobotsOptions o;
    o.robots = robots;
    cases.push_back({"grasps", o, 1e-12});
    o.duplicate_grasp = o.load_row = o.robot_row = true;
    cases.push_back({"redundant grasps, a load row and a robot row", o, 1e-10});
  }
  namespace sym = ukdyn::symbolic;
  const auto derived = [](const ukdyn::System& s, std::size_t c) {
    return dynamic_cast<const sym::DerivedConstraint*>(s.constraints()[c].get());
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(std::string(c.name) + ", N = " + std::to_string(c.o.robots));
    const auto shared = uktest::n_robots_system(c.o);
    uktest::NRobotsOptions own = c.o;
    own.share_tapes = false;
    const auto separate = uktest::n_robots_system(own);
    // Grasps 1..N−1 run one A, b tape; grasp 0 (grasp angle 0: a term fewer) its own; without the
    // pool every grasp has its own.
    for (int k = 2; k < c.o.robots; ++k) {
      EXPECT_EQ(&derived(*shared, static_cast<std::size_t>(k))->ab_tape(),
                &derived(*shared, 1)->ab_tape());
      EXPECT_NE(&derived(*separate, static_cast<std::size_t>(k))->ab_tape(),
                &derived(*separate, 1)->ab_tape());
    }
    EXPECT_NE(&derived(*shared, 0)->ab_tape(), &derived(*shared, 1)->ab_tape());
    const Index n = shared->dof(), m = shared->rows();
    ASSERT_EQ(separate->rows(), m);
    ukdyn::ForwardData a(*shared), b(*separate);
    std::mt19937 rng(20261205u);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    double worst = 0.0, worst_rows = 0.0;
    const auto rel = [](const auto& x, const auto& y) {
      return (x - y).template lpNorm<Eigen::Infinity>() /
             std::max(1.0, y.template lpNorm<Eigen::Infinity>());
    };
    for (int s = 0; s < 30; ++s) {
      Vec q(n), qd(n), tau(n), dq(n), dqd(n);
      for (Index i = 0; i < n; ++i) {
        q[i] = 1.5 * u(rng);
        qd[i] = u(rng);
        tau[i] = 2.0 * u(rng);
        dq[i] = u(rng);
        dqd[i] = u(rng);
      }
      const double t = u(rng);
      ukdyn::forward(*shared, a, t, q, qd, tau);
      ukdyn::forward(*separate, b, t, q, qd, tau);
      ASSERT_TRUE(a.result.finite && b.result.finite);
      EXPECT_EQ(a.result.rank, b.result.rank);
      worst_rows = std::max({worst_rows, rel(a.A, b.A), rel(a.b, b.b)});
      worst = std::max({worst, rel(a.qdd, b.qdd), rel(a.Qc, b.Qc)});
      Vec phi_a(m), phi_b(m), phid_a(m), phid_b(m), phi_s(m), phid_s(m);
      ukdyn::residuals(*shared, a, t, q, qd, phi_a, phid_a);  // in the slots
      ukdyn::position_residuals(*shared, t, q, phi_s);        // without slots
      ukdyn::velocity_residuals(*shared, t, q, qd, phid_s);
      ukdyn::residuals(*separate, b, t, q, qd, phi_b, phid_b);
      worst_rows = std::max({worst_rows, rel(phi_a, phi_b), rel(phid_a, phid_b)});
      EXPECT_EQ(phi_s, phi_a);
      EXPECT_EQ(phid_s, phid_a);
      // Tangents of A q̈ − b and Aᵀλ along (dq, dq̇), in the slots and without.
      for (std::size_t k = 0; k < shared->constraints().size(); ++k) {
        const Index r = shared->constraints()[k]->rows();
        const Vec lambda = Vec::LinSpaced(r, -1.0, 2.0);
        Vec dr_a(r), dr_b(r), dr_s(r);
        Vec df_a = Vec::Zero(n), df_b = Vec::Zero(n), df_s = Vec::Zero(n);
        derived(*shared, k)
            ->tangent({t, a.constraint_slots(k)}, q, qd, a.qdd, lambda, dq, dqd, dr_a, df_a);
        derived(*shared, k)->tangent({t}, q, qd, a.qdd, lambda, dq, dqd, dr_s, df_s);
        derived(*separate, k)
            ->tangent({t, b.constraint_slots(k)}, q, qd, a.qdd, lambda, dq, dqd, dr_b, df_b);
        worst_rows = std::max({worst_rows, rel(dr_a, dr_b), rel(df_a, df_b)});
        EXPECT_EQ(dr_a, dr_s);
        EXPECT_EQ(df_a, df_s);
      }
    }
    EXPECT_LE(worst_rows, 1e-13);
    EXPECT_LE(worst, c.tol);
    ::testing::Test::RecordProperty("worst_rel", ::testing::PrintToString(worst));
  }
}

#ifdef UKDYN_HAVE_IO
// The arm written once and instantiated N times (`instances:`, tools/n_robots.py) is the same
// system as the one built directly in C++ (tests/n_robots_model.hpp): names, M, A, b and q̈ at
// random states.
TEST(Instances, GeneratedScenarioMatchesTheDirectModel) {
  const auto sc =
      ukdyn::load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/n_robots_3.yaml");
  uktest::NRobotsOptions o;
  o.robots = 3;
  const auto direct = uktest::n_robots_system(o);
  ASSERT_EQ(sc.system->coordinate_names(), direct->coordinate_names());
  EXPECT_EQ(sc.system->coordinate_names()[3], "r1_t1");
  EXPECT_EQ(sc.system->constraint_row_names(), direct->constraint_row_names());
  ASSERT_NE(sc.system->arrow(), nullptr);
  EXPECT_EQ(sc.system->arrow()->groups.size(), 3u);
  EXPECT_EQ(sc.subsystems[1].name, "robot1");
  // The three instances evaluate one compiled dynamics tape (symbolic::TapePool; their M, C q̇ and
  // G do not depend on the mount, the one parameter they differ in); the load has its own.
  auto tape_of = [](const ukdyn::System& s, std::size_t k) {
    const auto* d = dynamic_cast<const ukdyn::symbolic::DerivedSubsystem*>(s.subsystems()[k].get());
    return d ? &d->dynamics_tape() : nullptr;
  };
  for (const ukdyn::System* s :
       std::initializer_list<const ukdyn::System*>{sc.system.get(), direct.get()}) {
    ASSERT_NE(tape_of(*s, 0), nullptr);
    EXPECT_EQ(tape_of(*s, 1), tape_of(*s, 0));
    EXPECT_EQ(tape_of(*s, 2), tape_of(*s, 0));
    EXPECT_NE(tape_of(*s, 3), tape_of(*s, 0));
    // The grasps of robots 1 and 2 one A, b tape too (their numbers are inputs); robot 0's grasp
    // angle 0 leaves a term out of its rows.
    auto grasp_tape = [&](std::size_t c) {
      return &dynamic_cast<const ukdyn::symbolic::DerivedConstraint&>(*s->constraints()[c])
                  .ab_tape();
    };
    EXPECT_EQ(grasp_tape(2), grasp_tape(1));
    EXPECT_NE(grasp_tape(0), grasp_tape(1));
  }
  const Index n = direct->dof();
  ukdyn::ForwardData a(*sc.system), b(*direct);
  std::mt19937 rng(7u);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int k = 0; k < 20; ++k) {
    Vec q(n), qd(n);
    for (Index i = 0; i < n; ++i) {
      q[i] = 1.5 * u(rng);
      qd[i] = u(rng);
    }
    const Vec tau = Vec::Zero(n);
    ukdyn::forward(*sc.system, a, 0.0, q, qd, tau);
    ukdyn::forward(*direct, b, 0.0, q, qd, tau);
    EXPECT_LE((a.M - b.M).lpNorm<Eigen::Infinity>(), 1e-12);
    EXPECT_LE((a.A - b.A).lpNorm<Eigen::Infinity>(), 1e-12);
    EXPECT_LE((a.b - b.b).lpNorm<Eigen::Infinity>(), 1e-12 * (1 + b.b.lpNorm<Eigen::Infinity>()));
    EXPECT_LE((a.qdd - b.qdd).lpNorm<Eigen::Infinity>(),
              1e-10 * (1 + b.qdd.lpNorm<Eigen::Infinity>()));
  }
  // The initial state satisfies the grasps (load_scenario checked it) and a short run completes
  // with the arrow solve, holding the grasps.
  ukdyn::SimulationSettings s = sc.sim;
  s.t_end = 0.2;
  double worst = 0.0;
  const auto stats =
      ukdyn::simulate(*sc.system, sc.q0, sc.qd0, {}, s,
                      [&](double t, ukdyn::CVecRef q, ukdyn::CVecRef, const ukdyn::ForwardData& d) {
                        EXPECT_TRUE(d.used_arrow);
                        Vec phi(sc.system->rows());
                        ukdyn::position_residuals(*sc.system, t, q, phi);
                        worst = std::max(worst, phi.lpNorm<Eigen::Infinity>());
                        return true;
                      });
  EXPECT_EQ(stats.status, ukdyn::RunStatus::completed) << stats.message;
  EXPECT_LE(worst, 1e-9);
}

TEST(Instances, BadInstancesAreReportedWithTheirPosition) {
  const std::string head = R"(ukdyn: 1
name: bad
subsystems:
  - name: arm
    type: definitions
    coordinates: [t1]
    parameters: {bx: 0}
    bodies:
      - {name: b, mass: 1, com: [bx + cos(t1), 0, sin(t1)]}
)";
  const std::string tail = R"(initial:
  q: [0, 0]
simulation:
  t_end: 1
  sample_dt: 0.1
)";
  auto error_of = [&](const std::string& instances) {
    try {
      (void)ukdyn::load_scenario_text(head + instances + tail, "bad.yaml");
    } catch (const ukdyn::ScenarioError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  const std::string unknown = error_of(
      "    instances:\n      - {name: a0, parameters: {bx: 1}}\n      - {name: a1, "
      "parameters: {by: 2}}\n");
  EXPECT_NE(unknown.find("bad.yaml:12:"), std::string::npos) << unknown;
  EXPECT_NE(unknown.find("'by' is not a parameter"), std::string::npos) << unknown;
  const std::string dup =
      error_of("    instances:\n      - {name: a0, prefix: p_}\n      - {name: a1, prefix: p_}\n");
  EXPECT_NE(dup.find("duplicate coordinate name 'p_t1'"), std::string::npos) << dup;
  const std::string key =
      error_of("    instances:\n      - {name: a0, pose: 1}\n      - {name: a1}\n");
  EXPECT_NE(key.find("pose"), std::string::npos) << key;
}
#endif

}  // namespace
