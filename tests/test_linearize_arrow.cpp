// The derivatives' block-arrow KKT solve (ukdyn/core/uk_arrow_kkt.hpp, docs/derivatives.md) against
// the dense KKT factorisation it replaces (LinearizeData::allow_arrow = false: the reference), on
// robots welded to a free-body load; its trace identities against the dense W; and the fallback to
// the dense row choice when a row is redundant, checked against central differences of forward().
#include <gtest/gtest.h>

#include <Eigen/SVD>
#include <cmath>
#include <filesystem>
#include <numbers>
#include <sstream>
#include <string>

#include "moving_state.hpp"
#include "ukdyn/model/linearize.hpp"
#include "ukdyn/scenario/scenario.hpp"

namespace {

using namespace ukdyn;
const std::filesystem::path kSource = UKDYN_SOURCE_DIR;

double rel(const Mat& a, const Mat& b) {
  return (a - b).cwiseAbs().maxCoeff() / (1.0 + b.cwiseAbs().maxCoeff());
}

// N 6-DoF arms (the arm of tools/n_robots.py --weld) around a free-body load, each welded to it at
// a grasp frame 0.3 m from its centre (symmetric grasps: the arms' coordinates 0.6 0 0 0 0 0 hold
// the load at rest at the origin); `duplicate`: robot 0's weld written twice (6 redundant rows).
std::string n_robots_weld(int n, bool duplicate) {
  std::ostringstream y;
  y.precision(17);
  y << "ukdyn: 1\nname: n_robots_weld_test\ngravity: 9.81\nsubsystems:\n"
       "  - name: arm\n    type: serial_chain\n    coordinates: [px, py, pz, r1, r2, r3]\n"
       "    gravity: [0, 0, 0]\n    joints:\n"
       "      - {name: jx, type: prismatic, link: cx, axis: [1, 0, 0], coordinate: px, mass: 4}\n"
       "      - {name: jy, type: prismatic, link: cy, axis: [0, 1, 0], coordinate: py, mass: 3}\n"
       "      - {name: jz, type: prismatic, link: cz, axis: [0, 0, 1], coordinate: pz, mass: 2}\n"
       "      - {name: w1, type: revolute, link: wl1, axis: [0, 0, 1], coordinate: r1, mass: 0.3,"
       " inertia: [0.002, 0.002, 0.003]}\n"
       "      - {name: w2, type: revolute, link: wl2, axis: [0, 1, 0], coordinate: r2, mass: 0.3,"
       " inertia: [0.002, 0.003, 0.002]}\n"
       "      - {name: w3, type: revolute, link: hand, axis: [1, 0, 0], coordinate: r3, mass: 0.5,"
       " com: [0.05, 0, 0], inertia: [0.003, 0.002, 0.002]}\n"
       "    points:\n      tool: {link: hand, xyz: [0.1, 0, 0]}\n    instances:\n";
  for (int k = 0; k < n; ++k) {
    const double a = 2.0 * std::numbers::pi * k / n;
    y << "      - {name: robot" << k << ", prefix: r" << k << "_, mount: {xyz: [" << std::cos(a)
      << ", " << std::sin(a) << ", 0], rpy: [0, 0, " << a + std::numbers::pi << "]}}\n";
  }
  y << "  - name: load\n    type: free_body\n    mass: 3\n    inertia: [0.05, 0.06, 0.08]\n"
       "constraints:\n";
  for (int k = 0; k < n + (duplicate ? 1 : 0); ++k) {
    const int r = k % n;
    const double a = 2.0 * std::numbers::pi * r / n;
    y << "  - {type: weld, name: grasp" << k << ", a: robot" << r
      << ".tool, b: {frame: load.load, xyz: [" << 0.3 * std::cos(a) << ", " << 0.3 * std::sin(a)
      << ", 0], rpy: [0, 0, " << a + std::numbers::pi << "]}}\n";
  }
  y << "initial:\n  q: [";
  for (int k = 0; k < n; ++k) y << "0.6, 0, 0, 0, 0, 0, ";
  y << "0, 0, 0, 1, 0, 0, 0]\n  qd: zeros\nsimulation:\n  t_end: 1\n  sample_dt: 0.01\n";
  return y.str();
}

using test::moving_state;
using test::State;

// linearize() with the arrow KKT and with the dense one, every part: the same rows and trust, and
// every matrix within 1e-10 relative.
void expect_arrow_matches_dense(const Scenario& sc) {
  const System& sys = *sc.system;
  ASSERT_NE(sys.arrow(), nullptr);
  const State s = moving_state(sc);
  LinearizeData arrow(sys), dense(sys);
  dense.allow_arrow = false;
  linearize(sys, arrow, sc.sim.t0, s.q, s.qd, s.tau, sc.sim.uk);
  linearize(sys, dense, sc.sim.t0, s.q, s.qd, s.tau, sc.sim.uk);
  ASSERT_TRUE(arrow.fwd.used_arrow);
  EXPECT_TRUE(arrow.used_arrow);
  EXPECT_FALSE(dense.used_arrow);
  EXPECT_EQ(arrow.lin.rank, sys.rows());
  test::expect_same_linearization(arrow.lin, dense.lin, 1e-10);
  // tr W and tr W⁻¹ of the blocks against the dense W = A M_s⁻¹ Aᵀ (M_s: the mass the solve used).
  const Mat Ms = solved_mass(sys, arrow.fwd);
  const Mat W = arrow.fwd.A * Ms.llt().solve(arrow.fwd.A.transpose());
  EXPECT_NEAR(arrow.arrow.trace_w, W.trace(), 1e-10 * W.trace());
  const double tr_inv = W.inverse().trace();
  EXPECT_NEAR(arrow.arrow.trace_w_inv, tr_inv, 1e-9 * tr_inv);
}

}  // namespace

TEST(LinearizeArrow, ShippedWeldSystemsMatchTheDenseKkt) {
  for (const char* name :
       {"n_robots_4_weld.yaml", "four_panda_plate.yaml", "n_robots_3_weld.yaml"}) {
    SCOPED_TRACE(name);
    expect_arrow_matches_dense(load_scenario(kSource / "scenarios" / name));
  }
}

TEST(LinearizeArrow, EightRobotsMatchTheDenseKkt) {
  expect_arrow_matches_dense(load_scenario_text(n_robots_weld(8, false), "n8.yaml"));
}

// A redundant weld: robot 0's rows twice. The arrow KKT cannot eliminate S_0 (singular), so the
// dense row choice keeps 6 fewer rows, exactly as without the arrow path; the derivatives match
// central differences of forward() (the rank stays constant along the differences).
TEST(LinearizeArrow, RedundantRowsTakeTheDenseRowChoice) {
  const Scenario sc = load_scenario_text(n_robots_weld(8, true), "n8_redundant.yaml");
  const System& sys = *sc.system;
  const State s = moving_state(sc);
  LinearizeData arrow(sys), dense(sys);
  dense.allow_arrow = false;
  linearize(sys, arrow, sc.sim.t0, s.q, s.qd, s.tau, sc.sim.uk);
  linearize(sys, dense, sc.sim.t0, s.q, s.qd, s.tau, sc.sim.uk);
  ASSERT_TRUE(arrow.fwd.used_arrow);
  EXPECT_FALSE(arrow.used_arrow);
  EXPECT_EQ(arrow.lin.rank, sys.rows() - 6);
  EXPECT_EQ(arrow.lin.kept_rows, dense.lin.kept_rows);
  EXPECT_EQ(arrow.lin.dqdd_dq, dense.lin.dqdd_dq);
  EXPECT_EQ(arrow.lin.dmu_dq, dense.lin.dmu_dq);
  test::expect_columns_match_differences(sc, s, arrow.lin.dqdd_dq, arrow.lin.dqdd_dqd);
}

namespace {

// ∂q̈/∂(q, q̇) alone (LinearizeParts{false, false}: the structural right-hand sides, the products
// written straight into the result) and the structured result (LinearizeParts::structured), both
// against the dense KKT path; the structured one expanded and multiplied by a matrix.
void expect_dqdd_dx_matches_dense(const Scenario& sc) {
  const System& sys = *sc.system;
  const Index n = sys.dof();
  const State s = moving_state(sc);
  LinearizeData alone(sys), structured(sys), dense(sys);
  dense.allow_arrow = false;
  linearize(sys, dense, sc.sim.t0, s.q, s.qd, s.tau, sc.sim.uk);
  linearize(sys, alone, sc.sim.t0, s.q, s.qd, s.tau, sc.sim.uk, LinearizeParts{false, false});
  linearize(sys, structured, sc.sim.t0, s.q, s.qd, s.tau, sc.sim.uk,
            LinearizeParts{false, false, true});
  ASSERT_TRUE(alone.used_arrow);
  ASSERT_TRUE(structured.used_arrow);
  EXPECT_FALSE(alone.structured);
  ASSERT_TRUE(structured.structured);
  EXPECT_EQ(structured.lin.dqdd_dq.size(), 0);
  EXPECT_EQ(alone.lin.dmu_dq.size(), 0);
  EXPECT_LE(rel(alone.lin.dqdd_dq, dense.lin.dqdd_dq), 1e-12);
  EXPECT_LE(rel(alone.lin.dqdd_dqd, dense.lin.dqdd_dqd), 1e-12);
  Mat sq, sqd;
  dqdd_dx_dense(structured, sq, sqd);
  EXPECT_LE(rel(sq, dense.lin.dqdd_dq), 1e-12);
  EXPECT_LE(rel(sqd, dense.lin.dqdd_dqd), 1e-12);
  // O(N) storage: X_L and N small blocks, fewer entries than the dense n × 2n.
  const ArrowResponse& r = structured.dqdd_dx;
  Index stored = r.XL.size();
  for (const auto& b : r.blocks) stored += b.own.size() + b.Q.size();
  EXPECT_LT(stored, 2 * n * n);
  // [∂q̈/∂q ∂q̈/∂q̇] V without the dense matrix, against the dense product.
  Mat V(2 * n, 3);
  for (Index i = 0; i < V.size(); ++i) V(i) = std::sin(0.37 * static_cast<double>(i) + 0.1);
  Mat out(n, 3), scratch;
  dqdd_dx_times(structured, V, out, scratch);
  const Mat ref = dense.lin.dqdd_dq * V.topRows(n) + dense.lin.dqdd_dqd * V.bottomRows(n);
  EXPECT_LE(rel(out, ref), 1e-12);
  dqdd_dx_times(alone, V, out, scratch);
  EXPECT_LE(rel(out, ref), 1e-12);
}

}  // namespace

TEST(LinearizeArrow, DqddAloneAndStructuredMatchTheDenseKkt) {
  for (const char* name : {"n_robots_4_weld.yaml", "four_panda_plate.yaml"}) {
    SCOPED_TRACE(name);
    expect_dqdd_dx_matches_dense(load_scenario(kSource / "scenarios" / name));
  }
  SCOPED_TRACE("8 robots");
  expect_dqdd_dx_matches_dense(load_scenario_text(n_robots_weld(8, false), "n8.yaml"));
}

// The structured ∂q̈/∂(q, q̇) against central differences of forward() (Richardson-extrapolated),
// every fifth column, on the shipped four-robot system and eight generated ones.
TEST(LinearizeArrow, StructuredMatchesCentralDifferences) {
  const Scenario scs[] = {load_scenario(kSource / "scenarios" / "n_robots_4_weld.yaml"),
                          load_scenario_text(n_robots_weld(8, false), "n8.yaml")};
  for (const Scenario& sc : scs) {
    const System& sys = *sc.system;
    const State s = moving_state(sc);
    LinearizeData d(sys);
    linearize(sys, d, sc.sim.t0, s.q, s.qd, s.tau, sc.sim.uk, LinearizeParts{false, false, true});
    ASSERT_TRUE(d.structured);
    Mat dq, dqd;
    dqdd_dx_dense(d, dq, dqd);
    test::expect_columns_match_differences(sc, s, dq, dqd);
  }
}
