// Three and four robots welded to a free-body load (scenarios/n_robots_{3,4}_weld.yaml, generated
// by tools/n_robots.py N --weld). Independent evidence: (1) Newton–Euler of the load: the sum of
// the grasp wrenches reported for the welds equals [m (a − g); dH/dt] of the load computed here
// from its q̈ (quaternion kinematics by Eigen, Euler's equations), at rest and at random consistent
// velocities; (2) released from rest with the robots gravity-compensated, every robot's own
// (unconstrained) grasp acceleration is zero, a motion every grasp agrees with, so the
// inertia-weighted decomposition [Verginis2019] reports no squeeze, while the Moore–Penrose one
// [Walker1991] does on the asymmetric grasps; both internal parts lie in null(G).
#include <gtest/gtest.h>

#ifdef UKDYN_HAVE_IO
#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <fstream>
#include <random>
#include <sstream>

#include "core/augmented_mass.hpp"
#include "ukdyn/core/constraint_forces.hpp"
#include "ukdyn/core/uk_singular.hpp"
#include "ukdyn/model/system.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/simulate/simulate.hpp"
#include "ukdyn/symbolic/frame_constraints.hpp"
#ifdef UKDYN_CLI
#include "cli_run.hpp"
#endif

namespace {

using ukdyn::ForwardData;
using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;
using ukdyn::Vec3;

constexpr double kMass = 3.0, kG = 9.81;
const Eigen::Vector3d kJ(0.05, 0.06, 0.08);

struct Grasps {
  Vec w;                     // 6N: force, moment about the grasp point (world), on the load
  std::vector<Vec3> points;  // grasp points (world)
  Mat J;                     // 6N × n_robots: twist Jacobians of the robots' tool frames
};

Grasps grasp_wrenches(const ukdyn::Scenario& sc, const ForwardData& d, const Vec& q,
                      Index robot_dof) {
  const auto& sys = *sc.system;
  const auto split = ukdyn::split_constraint_force(d.A, d.Qc, sys.constraint_row_offsets());
  EXPECT_TRUE(split.unique);
  std::vector<const ukdyn::symbolic::FrameWrenches*> maps;
  std::vector<std::size_t> blocks;
  for (std::size_t c = 0; c < sys.constraints().size(); ++c) {
    if (const auto* fc =
            dynamic_cast<const ukdyn::symbolic::FrameConstraint*>(sys.constraints()[c].get())) {
      maps.push_back(&fc->wrench());
      blocks.push_back(c);
    }
  }
  const auto n = static_cast<Index>(maps.size());
  Grasps g{Vec(6 * n), {}, Mat(6 * n, robot_dof)};
  for (Index k = 0; k < n; ++k) {
    const auto kk = static_cast<std::size_t>(k);
    const auto wr = maps[kk]->evaluate(q, split.block_lambda[blocks[kk]]);
    g.w.segment<3>(6 * k) = wr.force_b;
    g.w.segment<3>(6 * k + 3) = wr.moment_b;
    g.points.push_back(wr.position_b);
    Mat Ja, Jb;
    maps[kk]->jacobians(q, Ja, Jb);
    g.J.middleRows(6 * k, 6) = Ja.leftCols(robot_dof);
  }
  return g;
}

// Newton–Euler of the load from its own q̈: [m (p̈ − g); R (J ω̇ + ω × J ω)], ω = 2 (q* ⊗ q̇),
// ω̇ = 2 (q* ⊗ q̈) (vector parts; q̇* ⊗ q̇ is a scalar).
Vec load_newton_euler(const Vec& q7, const Vec& qd7, const Vec& qdd7) {
  const Eigen::Quaterniond q(q7(3), q7(4), q7(5), q7(6)), qd(qd7(3), qd7(4), qd7(5), qd7(6)),
      qdd(qdd7(3), qdd7(4), qdd7(5), qdd7(6));
  const Eigen::Quaterniond a = q.conjugate() * qd, b = q.conjugate() * qdd;
  const Eigen::Vector3d w = 2.0 * a.vec(), wd = 2.0 * b.vec();
  const Eigen::Matrix3d R = q.toRotationMatrix();
  Vec f(6);
  f.head<3>() = kMass * (qdd7.head<3>() - Eigen::Vector3d(0, 0, -kG));
  f.tail<3>() = R * (kJ.cwiseProduct(wd) + w.cross(kJ.cwiseProduct(w)));
  return f;
}

struct Check {
  double newton_euler = 0, weighted = 0, walker = 0, null_walker = 0, null_weighted = 0, wnorm = 0;
};

Check check_scenario(const std::string& file, int random_states) {
  const auto sc = ukdyn::load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/" + file);
  const auto& sys = *sc.system;
  const Index n = sys.dof(), nr = n - 7;
  Check c;
  ForwardData d(sys);
  // At rest: the released state.
  ukdyn::forward(sys, d, 0.0, sc.q0, sc.qd0, Vec::Zero(n));
  EXPECT_TRUE(d.result.finite);
  {
    const Grasps g = grasp_wrenches(sc, d, sc.q0, nr);
    const Mat G = ukdyn::grasp_matrix(g.points, sc.q0.segment<3>(nr));
    const Vec ne = load_newton_euler(sc.q0.tail(7), sc.qd0.tail(7), d.qdd.tail(7));
    c.newton_euler = (G * g.w - ne).norm() / ne.norm();
    const Mat Lambda = ukdyn::task_space_inertia(d.M.topLeftCorner(nr, nr), g.J);
    const Vec walker = ukdyn::internal_wrench_walker(G, g.w);
    const Vec weighted = ukdyn::internal_wrench_weighted(G, Lambda, g.w);
    c.walker = walker.norm();
    c.weighted = weighted.norm();
    c.wnorm = g.w.norm();
    c.null_walker = (G * walker).norm() / g.w.norm();
    c.null_weighted = (G * weighted).norm() / g.w.norm();
  }
  // Random consistent velocities (the null space of A at q0): Newton–Euler still holds.
  std::mt19937_64 rng(3);
  std::normal_distribution<double> nd;
  const Mat N = Eigen::FullPivLU<Mat>(d.A).kernel();
  for (int s = 0; s < random_states; ++s) {
    Vec z(N.cols());
    for (Index i = 0; i < z.size(); ++i) z(i) = nd(rng);
    const Vec qd = N * z;
    ukdyn::forward(sys, d, 0.0, sc.q0, qd, Vec::Zero(n));
    EXPECT_TRUE(d.result.finite);
    const Grasps g = grasp_wrenches(sc, d, sc.q0, nr);
    const Mat G = ukdyn::grasp_matrix(g.points, sc.q0.segment<3>(nr));
    const Vec ne = load_newton_euler(sc.q0.tail(7), qd.tail(7), d.qdd.tail(7));
    c.newton_euler = std::max(c.newton_euler, (G * g.w - ne).norm() / ne.norm());
  }
  return c;
}

}  // namespace

TEST(NRobotsWeld, GraspWrenchesObeyNewtonEulerAndDoNotSqueeze) {
  for (const char* file : {"n_robots_3_weld.yaml", "n_robots_4_weld.yaml"}) {
    const Check c = check_scenario(file, 10);
    std::printf(
        "%s: |G w - NE| / |NE| = %.3g (rest + 10 random velocities); at rest |w| = %.4g N, "
        "weighted internal %.3g, Walker internal %.4g (m g = %.4g N); |G w_int|/|w| %.3g, %.3g\n",
        file, c.newton_euler, c.wnorm, c.weighted, c.walker, kMass * kG, c.null_walker,
        c.null_weighted);
    EXPECT_LE(c.newton_euler, 1e-10) << file;
    EXPECT_LE(c.weighted, 1e-9 * kMass * kG) << file;
    EXPECT_LE(c.null_walker, 1e-10) << file;
    EXPECT_LE(c.null_weighted, 1e-10) << file;
  }
}

// The free-body load's quaternion block of M is singular at every state; forward() takes the O(N)
// block-arrow solve in the augmented form (core/uk_singular.hpp), M_a's block and Q_a formed beside
// M and Q (core/augmented_mass.hpp), which stay as evaluated. Against the dense singular solve of
// the same (M, A, b, Q): the same q̈ and Qc; and the condition estimate, formed in the factor's
// pass, is mass_condition_estimate() of the M_a that solved_mass() forms.
TEST(NRobotsWeld, ArrowSolveOfTheSingularLoadMatchesTheDenseSolve) {
  for (const char* file : {"n_robots_3_weld.yaml", "n_robots_4_weld.yaml"}) {
    const auto sc = ukdyn::load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/" + file);
    const auto& sys = *sc.system;
    ASSERT_NE(sys.arrow(), nullptr) << file;
    ForwardData d(sys);
    ASSERT_TRUE(d.singular.any_structural) << file;
    std::mt19937_64 rng(5);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    for (int k = 0; k < 5; ++k) {
      Vec qd(sys.dof()), tau(sys.dof());
      for (Index i = 0; i < sys.dof(); ++i) {
        qd(i) = u(rng);
        tau(i) = 5.0 * u(rng);
      }
      ukdyn::forward(sys, d, 0.0, sc.q0, qd, tau, sc.sim.uk);
      EXPECT_TRUE(d.used_arrow) << file;
      EXPECT_TRUE(d.singular.active) << file;
      // The dense singular solve on what forward() left in d (M and Q as evaluated: put back).
      ukdyn::UkWorkspace ws(sys.layout(), sys.rows());
      ukdyn::UkSingularWorkspace sw(sys.layout(), sys.rows());
      sw.structural = d.singular.structural;
      sw.any_structural = true;
      Vec qdd(sys.dof()), Qc(sys.dof());
      const auto r = ukdyn::uk_solve_singular(d.M, d.A, d.b, d.Q, ws, sw, qdd, Qc, sc.sim.uk);
      ASSERT_TRUE(r.finite) << file;
      EXPECT_LE((qdd - d.qdd).norm(), 1e-10 * std::max(1.0, qdd.norm())) << file;
      EXPECT_LE((Qc - d.Qc).norm(), 1e-10 * std::max(1.0, Qc.norm())) << file;
      // M is the subsystems' (block-diagonal, the load's block singular), not the augmented one.
      Mat Mk = d.M.bottomRightCorner(7, 7);
      EXPECT_LT(Eigen::SelfAdjointEigenSolver<Mat>(Mk).eigenvalues()(0), 1e-10);
      std::size_t block = 99, block_ref = 98;
      const double cond = ukdyn::mass_condition(d, &block);
      EXPECT_EQ(cond, ukdyn::mass_condition_estimate(ukdyn::solved_mass(sys, d), d.uk, &block_ref))
          << file;
      EXPECT_EQ(block, block_ref) << file;
    }
  }
}

// factor_augmented_mass (the arrow path's factor of M_a, formed beside M) against the two steps it
// replaces, on n_robots_3_weld's M, A, b, Q at a state: M_a and Q_a by augmented_blocks() on
// copies, then factor_mass() and mass_condition_estimate(). The robots' blocks are set to the
// identity (condition 1), so that the load's augmented block is the worst one the estimate reports.
// The same factor and Q_a bit for bit, the same estimate and block, and M and Q unchanged.
TEST(NRobotsWeld, TheAugmentedFactorIsTheFactorOfTheAugmentedMass) {
  const auto sc =
      ukdyn::load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/n_robots_3_weld.yaml");
  const auto& sys = *sc.system;
  const auto& lay = sys.layout();
  ForwardData d(sys);
  ukdyn::forward(sys, d, 0.0, sc.q0, sc.qd0, Vec::Zero(sys.dof()), sc.sim.uk);
  ASSERT_TRUE(d.used_arrow);
  Mat M = d.M;
  const std::size_t load = static_cast<std::size_t>(sys.arrow()->load_block);
  for (std::size_t k = 0; k < lay.blocks(); ++k)
    if (k != load) M.block(lay.start[k], lay.start[k], lay.size[k], lay.size[k]).setIdentity();
  const Mat M_before = M;
  const Vec Q_before = d.Q;
  ukdyn::UkSingularWorkspace& sw = d.singular;
  ukdyn::UkWorkspace ws(lay, sys.rows()), ws_ref(lay, sys.rows());
  ukdyn::detail::MassCondition cond;
  ASSERT_TRUE(ukdyn::detail::factor_augmented_mass(lay, M, d.A, d.b, d.Q, sw, ws, cond));
  Mat Ma = M;
  Vec Qa = d.Q;
  ukdyn::augmented_blocks(lay, d.A, d.b, sw, Ma, Qa);
  ASSERT_TRUE(ukdyn::factor_mass(Ma, ws_ref));
  std::size_t block_ref = 99;
  const double cond_ref = ukdyn::mass_condition_estimate(Ma, ws_ref, &block_ref);
  EXPECT_EQ(block_ref, load);
  EXPECT_EQ(cond.block, block_ref);
  EXPECT_EQ(cond.estimate, cond_ref);
  EXPECT_EQ(ws.pivot_ratio, ws_ref.pivot_ratio);
  for (std::size_t k = 0; k < lay.blocks(); ++k) {
    const Index s = lay.start[k], n = lay.size[k];
    for (Index j = 0; j < n; ++j) {
      EXPECT_EQ(ws.inv_diag[s + j], ws_ref.inv_diag[s + j]);
      for (Index i = j; i < n; ++i) EXPECT_EQ(ws.L(s + i, s + j), ws_ref.L(s + i, s + j));
    }
  }
  for (Index i = 0; i < sys.dof(); ++i) EXPECT_EQ(sw.Qa[i], Qa[i]) << i;
  EXPECT_EQ((M - M_before).cwiseAbs().maxCoeff(), 0.0);
  EXPECT_EQ((d.Q - Q_before).cwiseAbs().maxCoeff(), 0.0);
}

// A point-mass load (no rotational inertia): its block augmented by its own unit-norm row is still
// singular (three rotational directions are held by the welds only), so the arrow path's check of
// the factor (factor_mass, mass_factor_regular) must send forward() to the dense singular solve,
// with the load's M and Q put back first: M as evaluate_dynamics() gives it, q̈ and Qc the dense
// singular solve's.
TEST(NRobotsWeld, ALoadBlockThatStaysSingularTakesTheDenseSolve) {
  const std::string file = std::string(UKDYN_SOURCE_DIR) + "/scenarios/n_robots_3_weld.yaml";
  std::ifstream in(file);
  std::stringstream ss;
  ss << in.rdbuf();
  std::string text = ss.str();
  const std::string inertia = "inertia: [0.05, 0.06, 0.08]";
  const auto pos = text.find(inertia);
  ASSERT_NE(pos, std::string::npos);
  text.replace(pos, inertia.size(), "inertia: [0, 0, 0]");
  const auto sc = ukdyn::load_scenario_text(text, file);
  const auto& sys = *sc.system;
  ASSERT_NE(sys.arrow(), nullptr);
  ForwardData d(sys), e(sys);
  ASSERT_TRUE(d.singular.any_structural);
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int k = 0; k < 3; ++k) {
    Vec qd(sys.dof()), tau(sys.dof());
    for (Index i = 0; i < sys.dof(); ++i) {
      qd(i) = u(rng);
      tau(i) = 5.0 * u(rng);
    }
    ukdyn::forward(sys, d, 0.0, sc.q0, qd, tau, sc.sim.uk);
    EXPECT_FALSE(d.used_arrow);
    ASSERT_TRUE(d.qdd.allFinite());
    ukdyn::evaluate_dynamics(sys, e, 0.0, sc.q0, qd);
    EXPECT_EQ(d.M, e.M);  // put back: not the augmented block
    ukdyn::UkWorkspace ws(sys.layout(), sys.rows());
    ukdyn::UkSingularWorkspace sw(sys.layout(), sys.rows());
    sw.structural = d.singular.structural;
    sw.any_structural = true;
    Vec qdd(sys.dof()), Qc(sys.dof());
    const auto r = ukdyn::uk_solve_singular(e.M, d.A, d.b, d.Q, ws, sw, qdd, Qc, sc.sim.uk);
    ASSERT_TRUE(r.finite);
    EXPECT_LE((qdd - d.qdd).norm(), 1e-10 * std::max(1.0, qdd.norm()));
    EXPECT_LE((Qc - d.Qc).norm(), 1e-10 * std::max(1.0, Qc.norm()));
  }
}

// Φ and Φ̇ in one call (what a run records at each sample: one pass over the trees for the
// numeric frame rows) are bitwise those of the two calls, and Φ̇ = A q̇ (the rows do not depend on
// t), A from forward()'s constraint stage.
TEST(NRobotsWeld, ResidualsInOneCallAreThoseOfTheTwoCalls) {
  for (const char* file : {"n_robots_3_weld.yaml", "n_robots_4_weld.yaml", "two_pandas_weld.yaml",
                           "four_panda_plate.yaml"}) {
    const auto sc = ukdyn::load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/" + file);
    const auto& sys = *sc.system;
    const Index n = sys.dof(), m = sys.rows();
    ForwardData one(sys), two(sys);
    std::mt19937_64 rng(17);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    for (int k = 0; k < 5; ++k) {
      Vec q = sc.q0, qd(n);
      for (Index i = 0; i < n; ++i) {
        q(i) += 0.1 * u(rng);
        qd(i) = u(rng);
      }
      Vec phi(m), phid(m), phi2(m), phid2(m);
      ukdyn::residuals(sys, one, 0.3, q, qd, phi, phid);
      ukdyn::position_residuals(sys, two, 0.3, q, phi2);
      ukdyn::velocity_residuals(sys, two, 0.3, q, qd, phid2);
      EXPECT_EQ(phi, phi2) << file;
      EXPECT_EQ(phid, phid2) << file;
      EXPECT_GT(phi.norm(), 0.0) << file;  // off the manifold: a non-trivial comparison
      ukdyn::evaluate_constraints(sys, two, 0.3, q, qd);
      EXPECT_LE((two.A * qd - phid).norm(), 1e-12 * std::max(1.0, phid.norm())) << file;
    }
  }
}

TEST(NRobotsWeld, AsymmetricGraspsShowAWalkerSqueeze) {
  // The unweighted split sees a squeeze where none is (robots of unequal inertia at the grasps).
  const Check c = check_scenario("n_robots_4_weld.yaml", 0);
  EXPECT_GT(c.walker, 1e-3 * kMass * kG);
}

TEST(NRobotsWeld, RunsAndKeepsTheWelds) {
  for (const char* file : {"n_robots_3_weld.yaml", "n_robots_4_weld.yaml"}) {
    auto sc = ukdyn::load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/" + file);
    sc.sim.t_end = 0.5;
    double drift = 0, fall = 0;
    const auto& sys = *sc.system;
    Vec phi(sys.rows());
    ForwardData scratch(sys);
    const auto st =
        ukdyn::simulate(sys, sc.q0, sc.qd0, nullptr, sc.sim,
                        [&](double t, ukdyn::CVecRef q, ukdyn::CVecRef, const ForwardData&) {
                          ukdyn::position_residuals(sys, scratch, t, q, phi);
                          drift = std::max(drift, phi.cwiseAbs().maxCoeff());
                          fall = q(sys.dof() - 5);  // load z
                          return true;
                        });
    ASSERT_EQ(st.status, ukdyn::RunStatus::completed) << file << ": " << st.message;
    EXPECT_LE(drift, 1e-8) << file;
    EXPECT_LT(fall, -0.1) << file;  // it falls (less than g t²/2: it drags the robots)
    EXPECT_GT(fall, -0.5 * kG * 0.25) << file;
    std::printf("%s: 0.5 s, max |Phi| = %.3g, load z = %.4f m\n", file, drift, fall);
  }
}
#ifdef UKDYN_CLI
TEST(NRobotsWeld, CliRunWithFiguresCompletes) {
  // The figures of a scenario with frame constraints (force_*, wrench_*): ukdyn simulate crashed
  // here (a dangling reference to a copy of ConstraintForceColumns' figure lists).
  ukdyn_test::ScratchDir dir("ukdyn_weld_cli");
  const std::string file = std::string(UKDYN_SOURCE_DIR) + "/scenarios/n_robots_3_weld.yaml";
  const auto r = ukdyn_test::run_cli(
      UKDYN_CLI, dir.path,
      "simulate " + ukdyn_test::sh(file) + " --out " + ukdyn_test::sh((dir.path / "out").string()));
  EXPECT_EQ(r.exit_code, 0) << r.err;
  const std::string summary = ukdyn_test::slurp(dir.path / "out" / "summary.json");
  EXPECT_NE(summary.find("\"complete\""), std::string::npos) << summary.substr(0, 400);
}
#endif
#endif
