// The weld rows of arms on trees as forward() evaluates them (TreeSubsystem::frame_twists: the
// frame's columns as twists, the link placements reused from the arm's dynamics() in its data
// slot) against independent evaluations: A from the velocity residual Φ̇ = A q̇ (the frames' rates
// from the link velocities, no columns), b from a fresh pass without slots, q̈ and Qc from a dense
// KKT solve with those A and b. And the reuse must never serve placements of another state.
#include <gtest/gtest.h>

#include <Eigen/LU>
#include <filesystem>

#include "ukdyn/model/system.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/tree/tree.hpp"

namespace {

using namespace ukdyn;
const std::filesystem::path kSource = UKDYN_SOURCE_DIR;

double rel(const Mat& a, const Mat& b) {
  return (a - b).cwiseAbs().maxCoeff() / (1e-300 + b.cwiseAbs().maxCoeff());
}

// A state near q0 (every component moved by up to 0.05, quaternions too: the rows are defined off
// the constraint manifold) with a velocity of every component.
void some_state(const Scenario& s, unsigned seed, Vec& q, Vec& qd) {
  const Index n = s.system->dof();
  q = s.q0;
  qd.resize(n);
  std::uint64_t x = 0x2545f4914f6cdd1dULL + seed;
  auto next = [&x] {
    x = x * 6364136223846793005ULL + 1442695040888963407ULL;  // LCG, Knuth MMIX
    return static_cast<double>(x >> 11) * 0x1.0p-52 - 1.0;
  };
  for (Index i = 0; i < n; ++i) {
    q(i) += 0.05 * next();
    qd(i) = 0.7 * next();
  }
}

// Constraint c's A and b with the context given (slots of `d`, or none).
void rows_of(const System& sys, std::size_t c, const ConstraintContext& ctx, const Vec& q,
             const Vec& qd, Mat& A, Vec& b) {
  const Index r = sys.constraints()[c]->rows();
  A = Mat::Zero(r, sys.dof());
  b = Vec::Zero(r);
  sys.constraints()[c]->evaluate(ctx, q, qd, A, b);
}

// A of every constraint from its velocity residual: column j is Φ̇(q, e_j) (the rows do not
// depend on t).
Mat velocity_columns(const System& sys, const Vec& q) {
  const Index n = sys.dof();
  Mat A(sys.rows(), n);
  const auto& offs = sys.constraint_row_offsets();
  for (Index j = 0; j < n; ++j) {
    const Vec e = Vec::Unit(n, j);
    for (std::size_t c = 0; c < sys.constraints().size(); ++c) {
      const Index r = sys.constraints()[c]->rows();
      Vec phid(r);
      sys.constraints()[c]->velocity_residual({}, q, e, phid);
      A.block(offs[c], j, r, 1) = phid;
    }
  }
  return A;
}

void check_scenario(const char* file) {
  SCOPED_TRACE(file);
  const Scenario s = load_scenario(kSource / "scenarios" / file);
  const System& sys = *s.system;
  const Index n = sys.dof(), m = sys.rows();
  ForwardData d(sys);
  for (unsigned seed = 0; seed < 4; ++seed) {
    Vec q, qd;
    some_state(s, seed, q, qd);
    const Vec tau = Vec::LinSpaced(n, -0.5, 0.5);
    forward(sys, d, 0.0, q, qd, tau);
    ASSERT_TRUE(d.qdd.allFinite());
    // A against the velocity residual's columns; b against a pass without slots.
    const Mat A = velocity_columns(sys, q);
    Vec b(m);
    const auto& offs = sys.constraint_row_offsets();
    for (std::size_t c = 0; c < sys.constraints().size(); ++c) {
      Mat Ac;
      Vec bc;
      rows_of(sys, c, {}, q, qd, Ac, bc);
      b.segment(offs[c], bc.size()) = bc;
    }
    EXPECT_LT(rel(d.A, A), 1e-13);
    EXPECT_LT(rel(d.b, b), 1e-13);
    // q̈ and Qc against the KKT system [M Aᵀ; A 0] [q̈; −λ] = [Q; b] (full rank here: the free
    // body's M is singular only along its quaternion, which its unit-norm row fixes).
    Mat K = Mat::Zero(n + m, n + m);
    K.topLeftCorner(n, n) = d.M;
    K.topRightCorner(n, m) = A.transpose();
    K.bottomLeftCorner(m, n) = A;
    Vec rhs(n + m);
    rhs << d.Q, b;
    const Vec x = K.fullPivLu().solve(rhs);
    const Vec Qc = -A.transpose() * x.tail(m);
    EXPECT_LT(rel(d.qdd, x.head(n)), 1e-10);
    EXPECT_LT(rel(d.Qc, Qc), 1e-10);
  }
}

}  // namespace

TEST(WeldFastPath, TwoPandasRowsAndAccelerationsAgreeWithIndependentEvaluations) {
  check_scenario("two_pandas_weld.yaml");
}

TEST(WeldFastPath, FourPandasRowsAndAccelerationsAgreeWithIndependentEvaluations) {
  check_scenario("four_panda_plate.yaml");
}

// The placements an arm's dynamics() left in its slot belong to one state: a constraint evaluated
// at another state with those slots (no dynamics() in between), or after another call on the
// arm's slot (mass() at a new q, which re-places the links without moving them), must get the
// rows of a fresh pass.
TEST(WeldFastPath, PlacementsOfAnotherStateAreNeverReused) {
  const Scenario s = load_scenario(kSource / "scenarios" / "two_pandas_weld.yaml");
  const System& sys = *s.system;
  ForwardData d(sys);
  Vec q1, qd1, q2, qd2;
  some_state(s, 11, q1, qd1);
  some_state(s, 12, q2, qd2);
  const Vec tau = Vec::Zero(sys.dof());
  const auto& subs = sys.subsystems();
  const auto& L = sys.layout();
  for (std::size_t c = 0; c < sys.constraints().size(); ++c) {
    Mat A_fresh, A_slot;
    Vec b_fresh, b_slot;
    auto expect_fresh = [&](const Vec& q, const Vec& qd, const char* what) {
      SCOPED_TRACE(what);
      rows_of(sys, c, {}, q, qd, A_fresh, b_fresh);
      rows_of(sys, c, {0.0, d.constraint_slots(c)}, q, qd, A_slot, b_slot);
      EXPECT_LT(rel(A_slot, A_fresh), 1e-13);
      EXPECT_LT(rel(b_slot, b_fresh), 1e-13);
    };
    forward(sys, d, 0.0, q1, qd1, tau);
    expect_fresh(q1, qd1, "the state of the slots");
    expect_fresh(q2, qd2, "another state");
    expect_fresh(q1, qd2, "another velocity");
    Vec q3 = q1;
    q3(4) = std::nextafter(q3(4), 1.0);  // one arm joint moved by one ulp
    expect_fresh(q3, qd1, "one ulp away");
    forward(sys, d, 0.0, q1, qd1, tau);
    for (std::size_t k = 0; k < subs.size(); ++k) {
      Mat M(L.size[k], L.size[k]);
      subs[k]->mass({0.0, d.subsystem_slot(k)}, q2.segment(L.start[k], L.size[k]), M);
    }
    expect_fresh(q2, qd1, "after mass() at another q");
  }
}

// A tree's potential read from the placement an earlier forward() left in its slot
// (TreeSubsystem::potential with `placed`: the per-sample recorder's V) is bitwise that of a fresh
// pass without slots; a placement of another state (another q, one ulp away, or re-placed by
// mass() without being moved) is never used, and V then is the fresh V of the state asked for,
// which differs from the slot's.
TEST(WeldFastPath, PotentialFromAPlacementIsTheFreshOneAndNeverStale) {
  for (const char* file : {"two_pandas_weld.yaml", "four_panda_plate.yaml"}) {
    SCOPED_TRACE(file);
    const Scenario s = load_scenario(kSource / "scenarios" / file);
    const System& sys = *s.system;
    const auto& subs = sys.subsystems();
    const auto& L = sys.layout();
    ForwardData d(sys), scratch(sys);
    Vec q1, qd1, q2, qd2;
    some_state(s, 21, q1, qd1);
    some_state(s, 22, q2, qd2);
    const Vec tau = Vec::Zero(sys.dof());
    int trees = 0;
    for (std::size_t k = 0; k < subs.size(); ++k) {
      const auto* arm = dynamic_cast<const tree::TreeSubsystem*>(subs[k].get());
      if (arm == nullptr) continue;
      ++trees;
      const ConstSlot placed(d.slots.data() + d.slot_start[k],
                             static_cast<std::size_t>(d.slot_start[k + 1] - d.slot_start[k]));
      const auto at = [&](const Vec& q) { return q.segment(L.start[k], L.size[k]); };
      auto V = [&](const Vec& q) {
        return arm->potential(at(q), placed, scratch.subsystem_slot(k));
      };
      auto fresh = [&](const Vec& q) { return arm->potential({}, at(q)); };
      forward(sys, d, 0.0, q1, qd1, tau);
      EXPECT_EQ(V(q1), fresh(q1));
      const double V2 = V(q2);
      EXPECT_EQ(V2, fresh(q2));
      EXPECT_NE(V2, fresh(q1));  // the states differ enough for V to tell them apart
      Vec q3 = q1;
      q3(L.start[k]) = std::nextafter(q3(L.start[k]), 10.0);  // the arm's first joint by one ulp
      EXPECT_EQ(V(q3), fresh(q3));
      Mat M(L.size[k], L.size[k]);
      subs[k]->mass({0.0, d.subsystem_slot(k)}, at(q2), M);  // placed at q2, not moved
      EXPECT_EQ(V(q1), fresh(q1));
      EXPECT_EQ(V(q2), fresh(q2));
      // The one-slot form reuses the slot it is given when that slot holds this q.
      forward(sys, d, 0.0, q1, qd1, tau);
      EXPECT_EQ(arm->potential({0.0, d.subsystem_slot(k)}, at(q1)), fresh(q1));
    }
    EXPECT_GE(trees, 2);
  }
}
