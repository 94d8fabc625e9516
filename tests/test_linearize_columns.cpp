// The every-direction derivatives of the derived components (DerivedConstraint::tangent_columns,
// DerivedSubsystem::inverse_dynamics_jacobian: one pass of the tape for several directions) against
// their one-direction tangents, and the KKT solve by the Schur complement (LinearizeData::
// allow_schur) against the LU of the whole KKT matrix it replaces, and the path without constraint
// rows (M⁻¹ times the inverse dynamics' derivatives) against the same LU and against differences
// (docs/derivatives.md, "Cost").
#include <gtest/gtest.h>

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <random>
#include <utility>
#include <vector>

#include "moving_state.hpp"
#include "ukdyn/model/column_derivatives.hpp"
#include "ukdyn/model/linearize.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/symbolic/definitions.hpp"
#include "ukdyn/symbolic/frame_constraints.hpp"

namespace {

using namespace ukdyn;
const std::filesystem::path kSource = UKDYN_SOURCE_DIR;

double rel(const Mat& a, const Mat& b) {
  return (a - b).cwiseAbs().maxCoeff() / (1.0 + b.cwiseAbs().maxCoeff());
}

using test::moving_state;
using test::State;

bool is_derived(const Constraint& c) {
  if (dynamic_cast<const symbolic::DerivedConstraint*>(&c) != nullptr) return true;
  const auto* f = dynamic_cast<const symbolic::FrameConstraint*>(&c);
  return f != nullptr && f->derived() != nullptr;
}

// Every constraint's tangent_columns() against tangent() along each e_j of q and of q̇ (a derived
// one bit for bit: the same tape operations on the same values; the numeric frame rows, whose
// tree ends take the analytic passes, to 1e-12), and every derived subsystem's
// inverse_dynamics_jacobian() against inverse_dynamics_tangent(); returns how many of them have
// tangents that are not all zero.
int expect_columns_match_tangents(const Scenario& sc) {
  const System& sys = *sc.system;
  const Index n = sys.dof();
  const State s = moving_state(sc);
  ForwardData fd(sys);
  forward(sys, fd, sc.sim.t0, s.q, s.qd, s.tau);
  int compared = 0;
  for (std::size_t c = 0; c < sys.constraints().size(); ++c) {
    const Constraint& con = *sys.constraints()[c];
    const auto* all = dynamic_cast<const ConstraintColumns*>(&con);
    if (all == nullptr) continue;
    const Index m = con.rows();
    Vec lambda(m);
    for (Index i = 0; i < m; ++i) lambda(i) = std::cos(0.7 * static_cast<double>(i) + 0.2);
    const ConstraintContext ctx{sc.sim.t0, fd.constraint_slots(c)};
    Mat res_all(m, 2 * n), force_all = Mat::Constant(n, 2 * n, 0.25);
    EXPECT_TRUE(all->tangent_columns(ctx, s.q, s.qd, fd.qdd, lambda, res_all, force_all));
    Mat res_one(m, 2 * n), force_one = Mat::Constant(n, 2 * n, 0.25);
    Vec dq = Vec::Zero(n), dqd = Vec::Zero(n), res(m), force(n);
    for (Index col = 0; col < 2 * n; ++col) {
      Vec& dir = col < n ? dq : dqd;
      dir(col % n) = 1.0;
      force.setZero();
      EXPECT_TRUE(con.tangent(ctx, s.q, s.qd, fd.qdd, lambda, dq, dqd, res, force));
      res_one.col(col) = res;
      force_one.col(col) += force;
      dir(col % n) = 0.0;
    }
    if (is_derived(con)) {
      EXPECT_EQ(res_all, res_one) << "constraint " << c << ": " << rel(res_all, res_one);
      EXPECT_EQ(force_all, force_one) << "constraint " << c << ": " << rel(force_all, force_one);
    } else {
      EXPECT_LE(rel(res_all, res_one), 1e-12) << "constraint " << c;
      EXPECT_LE(rel(force_all, force_one), 1e-12) << "constraint " << c;
    }
    if (res_one.cwiseAbs().maxCoeff() > 0.0) ++compared;  // (a row linear in q has none)
  }
  const auto& L = sys.layout();
  for (std::size_t k = 0; k < sys.subsystems().size(); ++k) {
    const auto* sub = dynamic_cast<const symbolic::DerivedSubsystem*>(sys.subsystems()[k].get());
    if (sub == nullptr) continue;
    const Index s0 = L.start[k], nk = L.size[k];
    const EvalContext ctx{sc.sim.t0, fd.subsystem_slot(k)};
    const Vec q = s.q.segment(s0, nk), qd = s.qd.segment(s0, nk), qdd = fd.qdd.segment(s0, nk);
    Mat dq_all(nk, nk), dqd_all(nk, nk);
    EXPECT_TRUE(sub->inverse_dynamics_jacobian(ctx, q, qd, qdd, dq_all, dqd_all));
    Mat dq_one(nk, nk), dqd_one(nk, nk);
    Vec dq = Vec::Zero(nk), dqd = Vec::Zero(nk), dID(nk);
    for (Index col = 0; col < 2 * nk; ++col) {
      Vec& dir = col < nk ? dq : dqd;
      dir(col % nk) = 1.0;
      EXPECT_TRUE(sub->inverse_dynamics_tangent(ctx, q, qd, qdd, dq, dqd, dID));
      (col < nk ? dq_one : dqd_one).col(col % nk) = dID;
      dir(col % nk) = 0.0;
    }
    EXPECT_EQ(dq_all, dq_one) << "subsystem " << k << ": " << rel(dq_all, dq_one);
    EXPECT_EQ(dqd_all, dqd_one) << "subsystem " << k << ": " << rel(dqd_all, dqd_one);
    if (dq_one.cwiseAbs().maxCoeff() > 0.0) ++compared;
  }
  return compared;
}

}  // namespace

// The paper's chains (points_coincide and point_trajectory rows derived from the chains' points: 24
// directions, three passes of eight lanes), its definitions twin (derived subsystems too), the
// free-body load of two UR5e (its dynamics tape, its unit-quaternion row, and the welds' numeric
// rows with the load's frame as an expressions end: its tape on lanes) and the two Pandas.
TEST(DerivedColumns, EveryDirectionAtOnceMatchesOneDirectionAtATime) {
  int total = 0;
  for (const char* name :
       {"paper_chain.yaml", "paper_generic.yaml", "two_ur5e_load.yaml", "two_pandas_weld.yaml"}) {
    SCOPED_TRACE(name);
    const int compared = expect_columns_match_tangents(load_scenario(kSource / "scenarios" / name));
    EXPECT_GE(compared, 2);
    total += compared;
  }
  EXPECT_GE(total, 10);
}

// ConstraintContext::structural_only (what the arrow path asks for): the numeric frame rows'
// evaluate() and tangent_columns() then write only the entries of their row_columns() (A's
// columns, d(A q̈ − b)'s directions of q and q̇ of those coordinates) and leave the others as they
// are. Those hold NaN here and must still hold NaN; the written entries must equal the full call's,
// whose other entries must be zero. On the N-robot welds (a free-body load as an expressions end)
// and two UR5e on a load.
TEST(DerivedColumns, StructuralOnlyWritesTheRowColumnsAlone) {
  for (const char* name : {"n_robots_4_weld.yaml", "two_ur5e_load.yaml"}) {
    SCOPED_TRACE(name);
    const Scenario sc = load_scenario(kSource / "scenarios" / name);
    const System& sys = *sc.system;
    const Index n = sys.dof();
    const State s = moving_state(sc);
    ForwardData fd(sys);
    forward(sys, fd, sc.sim.t0, s.q, s.qd, s.tau);
    int numeric = 0;
    for (std::size_t c = 0; c < sys.constraints().size(); ++c) {
      const Constraint& con = *sys.constraints()[c];
      const auto* all = dynamic_cast<const ConstraintColumns*>(&con);
      if (dynamic_cast<const symbolic::FrameConstraint*>(&con) == nullptr || is_derived(con) ||
          all == nullptr)
        continue;
      const Index m = con.rows();
      std::vector<char> own(static_cast<std::size_t>(n), 0);
      const auto row_columns = con.row_columns();
      for (const Index j : row_columns.at(0)) own[static_cast<std::size_t>(j)] = 1;
      const ConstraintContext full{sc.sim.t0, fd.constraint_slots(c)};
      const ConstraintContext structural{sc.sim.t0, fd.constraint_slots(c), true};
      Mat A_full(m, n), A_st = Mat::Constant(m, n, std::nan(""));
      Vec b_full(m), b_st(m);
      con.evaluate(full, s.q, s.qd, A_full, b_full);
      con.evaluate(structural, s.q, s.qd, A_st, b_st);
      const Vec lambda = Vec::LinSpaced(m, -1.0, 1.0);
      Mat r_full(m, 2 * n), r_st = Mat::Constant(m, 2 * n, std::nan(""));
      Mat f_full = Mat::Zero(n, 2 * n), f_st = Mat::Zero(n, 2 * n);
      ASSERT_TRUE(all->tangent_columns(full, s.q, s.qd, fd.qdd, lambda, r_full, f_full));
      ASSERT_TRUE(all->tangent_columns(structural, s.q, s.qd, fd.qdd, lambda, r_st, f_st));
      EXPECT_EQ(b_st, b_full);
      EXPECT_EQ(f_st, f_full);
      for (Index j = 0; j < n; ++j) {
        const bool mine = own[static_cast<std::size_t>(j)] != 0;
        for (Index i = 0; i < m; ++i) {
          for (const auto& [got, want] :
               {std::pair{A_st(i, j), A_full(i, j)}, std::pair{r_st(i, j), r_full(i, j)},
                std::pair{r_st(i, n + j), r_full(i, n + j)}}) {
            if (mine) {
              EXPECT_EQ(got, want) << "constraint " << c << " row " << i << " column " << j;
            } else {
              EXPECT_TRUE(std::isnan(got)) << "constraint " << c << " wrote column " << j;
              EXPECT_EQ(want, 0.0) << "constraint " << c << " column " << j;
            }
          }
        }
      }
      ++numeric;
    }
    EXPECT_GE(numeric, 2);  // the welds' numeric rows
  }
}

// The numeric frame rows keep their ends' J in the scratch every constraint of a ForwardData shares
// (ConstraintSlots::shared(), after the slots): the data holds the largest shared_slot_size() once,
// and a call must write every entry it reads there. The area is filled with NaN before each call
// (what another constraint could leave) and the tangents must equal, bit for bit, those of the
// same call on a zeroed area; the call must have written the area (it is in use). Then linearize()
// with the area NaN-filled between calls against a fresh LinearizeData, every part.
TEST(DerivedColumns, SharedScratchCarriesNothingBetweenCalls) {
  for (const char* name : {"n_robots_4_weld.yaml", "two_ur5e_load.yaml", "four_panda_plate.yaml"}) {
    SCOPED_TRACE(name);
    const Scenario sc = load_scenario(kSource / "scenarios" / name);
    const System& sys = *sc.system;
    const Index n = sys.dof();
    const State s = moving_state(sc);
    ForwardData fd(sys);
    Index largest = 0;
    for (const auto& con : sys.constraints()) largest = std::max(largest, con->shared_slot_size());
    ASSERT_GT(largest, 0);
    ASSERT_EQ(fd.slots.size(), fd.slot_start.back() + largest);
    auto shared = fd.slots.tail(largest);
    forward(sys, fd, sc.sim.t0, s.q, s.qd, s.tau);
    int numeric = 0;
    for (std::size_t c = 0; c < sys.constraints().size(); ++c) {
      const Constraint& con = *sys.constraints()[c];
      const auto* all = dynamic_cast<const ConstraintColumns*>(&con);
      if (all == nullptr || con.shared_slot_size() == 0) continue;
      const Index m = con.rows();
      const ConstraintContext ctx{sc.sim.t0, fd.constraint_slots(c), true};
      ASSERT_EQ(ctx.slots.shared().size(), static_cast<std::size_t>(largest));
      const Vec lambda = Vec::LinSpaced(m, -1.0, 1.0);
      Mat r_zero = Mat::Zero(m, 2 * n), r_nan = Mat::Zero(m, 2 * n);
      Mat f_zero = Mat::Zero(n, 2 * n), f_nan = Mat::Zero(n, 2 * n);
      shared.setZero();
      ASSERT_TRUE(all->tangent_columns(ctx, s.q, s.qd, fd.qdd, lambda, r_zero, f_zero));
      shared.setConstant(std::nan(""));
      ASSERT_TRUE(all->tangent_columns(ctx, s.q, s.qd, fd.qdd, lambda, r_nan, f_nan));
      EXPECT_TRUE(r_nan.array().isFinite().all() && f_nan.array().isFinite().all());
      EXPECT_EQ(r_nan, r_zero) << "constraint " << c;
      EXPECT_EQ(f_nan, f_zero) << "constraint " << c;
      EXPECT_GT(shared.array().isFinite().count(), 0) << "constraint " << c << " left it unused";
      ++numeric;
    }
    EXPECT_GE(numeric, 2);  // the welds' numeric rows
    LinearizeData fresh(sys), reused(sys);
    linearize(sys, fresh, sc.sim.t0, s.q, s.qd, s.tau);
    for (int k = 0; k < 2; ++k) {
      reused.fwd.slots.tail(largest).setConstant(std::nan(""));
      linearize(sys, reused, sc.sim.t0, s.q, s.qd, s.tau);
    }
    EXPECT_EQ(reused.lin.dqdd_dq, fresh.lin.dqdd_dq);
    EXPECT_EQ(reused.lin.dqdd_dqd, fresh.lin.dqdd_dqd);
    EXPECT_EQ(reused.lin.dQc_dq, fresh.lin.dQc_dq);
    EXPECT_EQ(reused.lin.dQc_dqd, fresh.lin.dQc_dqd);
  }
}

// linearize() with the KKT system solved by the Schur complement (the row choice's Cholesky and QR
// factors) against the LU of the whole KKT matrix (allow_schur = false), every part: the same rows
// and trust, every matrix within 1e-12 relative.
TEST(LinearizeSchur, MatchesTheLuOfTheKktMatrix) {
  for (const char* name :
       {"paper_chain.yaml", "paper_generic.yaml", "two_ur5e_load.yaml", "two_pandas_weld.yaml"}) {
    SCOPED_TRACE(name);
    const Scenario sc = load_scenario(kSource / "scenarios" / name);
    const System& sys = *sc.system;
    const State s = moving_state(sc);
    LinearizeData schur(sys), lu(sys);
    lu.allow_schur = false;
    linearize(sys, schur, sc.sim.t0, s.q, s.qd, s.tau, sc.sim.uk);
    linearize(sys, lu, sc.sim.t0, s.q, s.qd, s.tau, sc.sim.uk);
    EXPECT_TRUE(schur.used_schur);
    EXPECT_FALSE(lu.used_schur);
    test::expect_same_linearization(schur.lin, lu.lin, 1e-12);
  }
}

// A system without constraint rows (a lone arm; a floating-base chain with its unit-norm row left
// out; the flyball governor's definitions subsystem and spring-dampers without its drive row, for
// the applied forces' columns) takes no KKT system: ∂q̈/∂x = M⁻¹ (−∂ID/∂x) with forward()'s Cholesky factors of M. Against
// the general path forced to the LU of its KKT matrix K = M (allow_schur = false), every part, at
// random states: the same trust and sizes, every matrix within 1e-12 relative; the fast path forms
// no K (data.K stays empty). ∂q̈/∂τ times M is the identity (1e-12), ∂q̈/∂(q, q̇) alone is bitwise
// the same as with every part, and every fifth column agrees with central differences of
// forward() (expect_columns_match_differences).
TEST(LinearizeWithoutRows, MatchesTheKktPathAndDifferences) {
  const Scenario floating = load_scenario(kSource / "bench" / "floating_chain7.yaml");
  auto no_rows = std::make_shared<System>();
  for (const auto& sub : floating.system->subsystems()) no_rows->add_subsystem(sub);
  Scenario floating_free = floating;
  floating_free.system = no_rows;
  Scenario governor = load_scenario(kSource / "scenarios" / "benchmarks" / "flyball_governor.yaml");
  auto forces_only = std::make_shared<System>();
  for (const auto& sub : governor.system->subsystems()) forces_only->add_subsystem(sub);
  for (const auto& f : governor.system->applied_forces()) forces_only->add_applied_force(f);
  ASSERT_FALSE(forces_only->applied_forces().empty());
  governor.system = forces_only;
  const Scenario cases[] = {load_scenario(kSource / "bench" / "panda_arm.yaml"),
                            load_scenario(kSource / "bench" / "iiwa_arm.yaml"), floating_free,
                            governor};
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (const Scenario& sc : cases) {
    const System& sys = *sc.system;
    const Index n = sys.dof();
    SCOPED_TRACE(sc.name + ", " + std::to_string(n) + " coordinates");
    ASSERT_EQ(sys.rows(), 0);
    double worst = 0.0;
    for (int k = 0; k < 3; ++k) {
      State s{sc.q0, Vec(n), Vec(n)};
      for (Index i = 0; i < n; ++i) {
        s.q(i) += 0.5 * u(rng);
        s.qd(i) = u(rng);
        s.tau(i) = 5.0 * u(rng);
      }
      LinearizeData fast(sys), lu(sys), alone(sys);
      lu.allow_schur = false;
      linearize(sys, fast, sc.sim.t0, s.q, s.qd, s.tau, sc.sim.uk);
      linearize(sys, lu, sc.sim.t0, s.q, s.qd, s.tau, sc.sim.uk);
      EXPECT_EQ(fast.K.size(), 0);
      EXPECT_EQ(lu.K.rows(), n);
      EXPECT_EQ(fast.lin.rank, 0);
      EXPECT_EQ(fast.lin.Qc, Vec::Zero(n));
      test::expect_same_linearization(fast.lin, lu.lin, 1e-12);
      for (const auto& [a, b] : {std::pair{&fast.lin.dqdd_dq, &lu.lin.dqdd_dq},
                                 {&fast.lin.dqdd_dqd, &lu.lin.dqdd_dqd},
                                 {&fast.lin.dqdd_dtau, &lu.lin.dqdd_dtau}})
        worst = std::max(worst, rel(*a, *b));
      ForwardData fd(sys);
      forward(sys, fd, sc.sim.t0, s.q, s.qd, s.tau, sc.sim.uk);
      EXPECT_LE(rel(fast.lin.dqdd_dtau * fd.M, Mat::Identity(n, n)), 1e-12);
      linearize(sys, alone, sc.sim.t0, s.q, s.qd, s.tau, sc.sim.uk, LinearizeParts{false, false});
      EXPECT_EQ(alone.lin.dqdd_dq, fast.lin.dqdd_dq);
      EXPECT_EQ(alone.lin.dqdd_dqd, fast.lin.dqdd_dqd);
      EXPECT_EQ(alone.lin.dqdd_dtau.size(), 0);
      EXPECT_EQ(alone.lin.dQc_dq.size(), 0);
      test::expect_columns_match_differences(sc, s, fast.lin.dqdd_dq, fast.lin.dqdd_dqd);
    }
    std::printf("%s (%td coordinates): without rows vs the LU of K = M: %.2g\n", sc.name.c_str(), n,
                worst);
  }
}
