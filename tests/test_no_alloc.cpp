// forward() and the integrator's right-hand side (the real one, ukdyn::IntegratorRhs) allocate
// nothing once their workspace exists, for the paper's closed-form system and a definitions system.
//
// This file replaces the global operator new/delete and, on glibc, malloc/calloc/realloc/free with
// versions that count calls while a flag is set (Eigen allocates with std::malloc, not operator
// new, so both are needed). Every test in the binary links against these; with the flag off they
// only forward to the C library.
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <new>
#include <string>
#include <vector>

#include "helpers.hpp"
#include "n_robots_model.hpp"
#include "symbolic_systems.hpp"
#include "ukdyn/core/force_split.hpp"
#include "ukdyn/model/linearize.hpp"
#include "ukdyn/model/system.hpp"
#include "ukdyn/simulate/drift.hpp"
#include "ukdyn/simulate/simulate.hpp"
#include "ukdyn/symbolic/chain_tree.hpp"
#include "ukdyn/symbolic/free_body.hpp"
#ifdef UKDYN_HAVE_IO
#include "control_systems.hpp"
#include "ukdyn/output/constraint_force_output.hpp"
#include "ukdyn/output/control_output.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/symbolic/forces.hpp"
#include "ukdyn/tree/tree.hpp"
#endif

namespace {
std::atomic<bool> g_counting{false};
std::atomic<long> g_new_calls{0};
std::atomic<long> g_malloc_calls{0};

void count_new() {
  if (g_counting.load(std::memory_order_relaxed))
    g_new_calls.fetch_add(1, std::memory_order_relaxed);
}
}  // namespace

// Not under a sanitizer, whose runtime replaces malloc itself (UKDYN_TEST_SANITIZED,
// test_paths.hpp; with the replacements below, clang's ASan runtime was handed glibc's pointers and
// munmap_chunk() aborted).
#if defined(__GLIBC__) && !defined(UKDYN_TEST_SANITIZED)
#define UKDYN_TEST_COUNTS_MALLOC 1
// glibc's own entry points, so that these replacements can forward without recursion.
extern "C" {
void* __libc_malloc(std::size_t);
void* __libc_calloc(std::size_t, std::size_t);
void* __libc_realloc(void*, std::size_t);
void __libc_free(void*);

void* malloc(std::size_t n) {
  if (g_counting.load(std::memory_order_relaxed))
    g_malloc_calls.fetch_add(1, std::memory_order_relaxed);
  return __libc_malloc(n);
}
void* calloc(std::size_t k, std::size_t n) {
  if (g_counting.load(std::memory_order_relaxed))
    g_malloc_calls.fetch_add(1, std::memory_order_relaxed);
  return __libc_calloc(k, n);
}
void* realloc(void* p, std::size_t n) {
  if (g_counting.load(std::memory_order_relaxed))
    g_malloc_calls.fetch_add(1, std::memory_order_relaxed);
  return __libc_realloc(p, n);
}
void free(void* p) { __libc_free(p); }
}
#endif

// Counting global operator new/delete (all replaceable forms that allocate).
void* operator new(std::size_t n) {
  count_new();
  if (void* p = std::malloc(n == 0 ? 1 : n)) return p;
  throw std::bad_alloc();
}
void* operator new[](std::size_t n) {
  count_new();
  if (void* p = std::malloc(n == 0 ? 1 : n)) return p;
  throw std::bad_alloc();
}
void* operator new(std::size_t n, const std::nothrow_t&) noexcept {
  count_new();
  return std::malloc(n == 0 ? 1 : n);
}
void* operator new[](std::size_t n, const std::nothrow_t&) noexcept {
  count_new();
  return std::malloc(n == 0 ? 1 : n);
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }
void operator delete(void* p, const std::nothrow_t&) noexcept { std::free(p); }
void operator delete[](void* p, const std::nothrow_t&) noexcept { std::free(p); }

namespace {

using ukdyn::Mat;
using ukdyn::Vec;

/// Counts the allocations made by f() (operator new and, on glibc, malloc & co.).
template <typename F>
long allocations_in(F&& f) {
  g_new_calls = 0;
  g_malloc_calls = 0;
  g_counting = true;
  f();
  g_counting = false;
  return g_new_calls.load() + g_malloc_calls.load();
}

// The detector works: a deliberately allocating line is seen, by both counters. (If this test
// fails, the zero counts below prove nothing.)
TEST(NoAlloc, CounterSeesAllocations) {
  int* volatile p = nullptr;
  const long with_new = allocations_in([&] { p = new int(42); });
  delete p;
  EXPECT_GE(with_new, 1);
  EXPECT_GE(g_new_calls.load(), 1);
#ifdef UKDYN_TEST_COUNTS_MALLOC
  // An Eigen temporary (Eigen allocates with std::malloc).
  Vec v = Vec::LinSpaced(64, 0.0, 1.0);
  double s = 0.0;
  const long with_eigen = allocations_in([&] {
    const Vec w = v * 2.0;  // deliberately allocating
    s = w.sum();
  });
  EXPECT_GE(with_eigen, 1);
  EXPECT_GE(g_malloc_calls.load(), 1);
  EXPECT_DOUBLE_EQ(s, 64.0);
#endif
  EXPECT_EQ(allocations_in([] {}), 0);
}

struct PaperSystem {
  uktest::TwoArms two;
  Vec q0 = uktest::paper_q0();
  explicit PaperSystem(bool trajectory) {
    two.add_closure();
    if (trajectory) two.add_paper_trajectory(q0);
  }
};

void expect_forward_allocation_free(bool trajectory) {
  PaperSystem ps(trajectory);
  const ukdyn::System& sys = *ps.two.system;
  ukdyn::ForwardData data(sys);
  const Vec qd = Vec::LinSpaced(12, -0.3, 0.4);
  const Vec tau = Vec::LinSpaced(12, -2.0, 2.0);
  ukdyn::forward(sys, data, 0.0, ps.q0, qd, tau);  // first call (nothing to set up, but allowed)
  ASSERT_TRUE(data.result.finite);
  const long n = allocations_in([&] {
    for (int k = 0; k < 20; ++k) ukdyn::forward(sys, data, 0.01 * k, ps.q0, qd, tau);
  });
  EXPECT_EQ(n, 0) << "forward() allocated " << n << " times in 20 calls"
                  << (trajectory ? " (closure + trajectory)" : " (closure)");
  EXPECT_EQ(data.result.rank, trajectory ? 12 : 6);
}

TEST(NoAlloc, ForwardClosureAllocatesNothing) { expect_forward_allocation_free(false); }
TEST(NoAlloc, ForwardClosureAndTrajectoryAllocatesNothing) { expect_forward_allocation_free(true); }

// The exact tangents of the paper's closed-form robot and its constraints (linearize()'s per-column
// calls) run on fixed-size dual numbers on the stack: no allocation once the outputs exist.
TEST(NoAlloc, PaperTangentsAllocateNothing) {
  PaperSystem ps(true);
  const ukdyn::System& sys = *ps.two.system;
  const Vec qd = Vec::LinSpaced(12, -0.3, 0.4), qdd = Vec::LinSpaced(12, 1.0, 2.0);
  const Vec dq = Vec::LinSpaced(12, 0.2, -0.1), dqd = Vec::LinSpaced(12, -0.5, 0.5);
  Vec dID(6), d_res(6), d_force = Vec::Zero(12);
  const Vec lambda = Vec::LinSpaced(6, 1.0, 3.0);
  bool ok = true;
  const long n = allocations_in([&] {
    for (int k = 0; k < 5; ++k) {
      ok = ok &&
           ps.two.left->inverse_dynamics_tangent({}, ps.q0.head<6>(), qd.head<6>(), qdd.head<6>(),
                                                 dq.head<6>(), dqd.head<6>(), dID);
      for (const auto& c : sys.constraints()) {
        const Eigen::Index m = c->rows();
        ok = ok &&
             c->tangent({0.1 * k}, ps.q0, qd, qdd, lambda.head(m), dq, dqd, d_res.head(m), d_force);
      }
    }
  });
  EXPECT_TRUE(ok);
  EXPECT_EQ(n, 0) << "the paper's tangents allocated " << n << " times";
}

// The integrator's right-hand side itself (ukdyn::IntegratorRhs: the object simulate() hands to
// Boost.Odeint), called on a moving state: x = [q; q̇] in a std::vector<double> as odeint keeps it.
long rhs_allocations(const ukdyn::System& sys, const Vec& q0, const ukdyn::SimulationSettings& s,
                     const ukdyn::ForceFunction& tau, int calls, ukdyn::UkResult* last) {
  const Eigen::Index n = sys.dof();
  ukdyn::IntegratorRhs rhs(sys, tau, s);
  std::vector<double> x(static_cast<std::size_t>(2 * n), 0.0), dxdt(x.size(), 0.0);
  for (Eigen::Index i = 0; i < n; ++i) x[static_cast<std::size_t>(i)] = q0(i);
  rhs(x, dxdt, 0.0);  // first call
  const long count = allocations_in([&] {
    // Explicit Euler steps through the right-hand side (the state moves every call).
    for (int k = 0; k < calls; ++k) {
      rhs(x, dxdt, 1e-3 * k);
      for (std::size_t i = 0; i < x.size(); ++i) x[i] += 1e-3 * dxdt[i];
    }
  });
  if (last) *last = rhs.data().result;
  return count;
}

TEST(NoAlloc, IntegratorRightHandSideAllocatesNothing) {
  PaperSystem ps(true);
  ukdyn::SimulationSettings s;  // projection: the right-hand side is forward()
  ukdyn::UkResult r;
  const long count = rhs_allocations(*ps.two.system, ps.q0, s, {}, 50, &r);
  EXPECT_EQ(count, 0) << "the right-hand side allocated " << count << " times in 50 calls";
  EXPECT_TRUE(r.finite);
  EXPECT_EQ(r.rank, 12);
}

// Baumgarte's right-hand side also evaluates Φ and Φ̇ (with the ForwardData's slots), and applied
// forces go through the ForceFunction.
TEST(NoAlloc, IntegratorRightHandSideWithBaumgarteAndForcesAllocatesNothing) {
  PaperSystem ps(false);
  ukdyn::SimulationSettings s;
  s.drift.kind = ukdyn::DriftControl::baumgarte;
  const ukdyn::ForceFunction tau = [](double t, ukdyn::CVecRef, ukdyn::CVecRef, ukdyn::VecRef f) {
    f.setZero();
    f(3) = 0.5 * t;
  };
  ukdyn::UkResult r;
  const long count = rhs_allocations(*ps.two.system, ps.q0, s, tau, 50, &r);
  EXPECT_EQ(count, 0) << "the Baumgarte right-hand side allocated " << count << " times";
  EXPECT_TRUE(r.finite);
  EXPECT_EQ(r.rank, 6);
}

// A system built from definitions: tapes run in the ForwardData's slots (no thread-local or
// per-call buffers), the constraint evaluates a spline.
TEST(NoAlloc, DefinitionsSystemRightHandSideAllocatesNothing) {
  const auto sys = uktest::spline_cart_system("na_");
  Vec q0 = Vec::Zero(2);
  q0(1) = 0.3;
  for (const auto kind : {ukdyn::DriftControl::projection, ukdyn::DriftControl::baumgarte}) {
    ukdyn::SimulationSettings s;
    s.drift.kind = kind;
    ukdyn::UkResult r;
    const long count = rhs_allocations(*sys, q0, s, {}, 50, &r);
    EXPECT_EQ(count, 0) << "allocated " << count << " times (" << ukdyn::to_string(kind) << ")";
    EXPECT_TRUE(r.finite);
    EXPECT_EQ(r.rank, 1);
  }
  // forward() alone, too.
  ukdyn::ForwardData data(*sys);
  const Vec qd = Vec::Constant(2, 0.2), tau = Vec::Zero(2);
  ukdyn::forward(*sys, data, 0.1, q0, qd, tau);
  const long n = allocations_in([&] {
    for (int k = 0; k < 20; ++k) ukdyn::forward(*sys, data, 0.05 * k, q0, qd, tau);
  });
  EXPECT_EQ(n, 0) << "forward() on the definitions system allocated " << n << " times";
}

// A floating body carrying a revolute and a ball joint on the tree algorithms (quaternion joints,
// docs/tree-algorithms.md) with the unit-norm rows: forward(), the exact derivatives, a frame's
// state and the Christoffel matrix C in the subsystem's slot allocate nothing.
TEST(NoAlloc, QuaternionTreeForwardAllocatesNothing) {
  namespace sym = ukdyn::symbolic;
  sym::ChainDef c("qt", {"x", "y", "z", "qw", "qx", "qy", "qz", "t1", "bw", "bx", "by", "bz"});
  c.gravity = {0, 0, -9.81};
  auto& f = c.add_joint("float", sym::JointDef::Type::floating, "body");
  f.coordinates = {"x", "y", "z", "qw", "qx", "qy", "qz"};
  f.inertial.mass = 2;
  f.inertial.com = {0.1, 0, 0};
  f.inertial.inertia = {0.1, 0, 0, 0, 0.2, 0, 0, 0, 0.3};
  auto& j = c.add_joint("j1", sym::JointDef::Type::revolute, "arm");
  j.coordinate = "t1";
  j.origin.xyz = {0.2, 0, 0};
  j.inertial.mass = 1;
  j.inertial.com = {0.1, 0, 0};
  j.inertial.inertia = {0.01, 0, 0, 0, 0.02, 0, 0, 0, 0.02};
  auto& b = c.add_joint("wrist", sym::JointDef::Type::ball, "hand");
  b.coordinates = {"bw", "bx", "by", "bz"};
  b.origin.xyz = {0.3, 0, 0};
  b.inertial.mass = 0.5;
  b.inertial.com = {0.05, 0.01, 0};
  b.inertial.inertia = {0.002, 0, 0, 0, 0.003, 0, 0, 0, 0.004};
  sym::ChainTree t = sym::chain_tree(c);
  ASSERT_TRUE(t.model) << t.reason;
  const auto tree = ukdyn::tree::make_subsystem(std::move(*t.model));
  auto sys = std::make_shared<ukdyn::System>();
  sys->add_subsystem(tree);
  const std::vector<std::vector<std::string>> quats = {{"qw", "qx", "qy", "qz"},
                                                       {"bw", "bx", "by", "bz"}};
  for (const auto& qn : quats)
    sys->add_constraint(sym::make_constraint(
        sym::free_body_norm_constraint("qt_" + qn[0], qn, sys->coordinate_names())));
  const Eigen::Index n = sys->dof();
  Vec q = Vec::LinSpaced(n, -0.8, 0.9), qd = Vec::LinSpaced(n, 0.4, -0.3);
  q.segment(3, 4).normalize();
  q.segment(8, 4).normalize();
  const Vec tau = Vec::Zero(n), dq = Vec::Ones(n);
  ukdyn::ForwardData data(*sys);
  ukdyn::forward(*sys, data, 0.0, q, qd, tau);
  ASSERT_TRUE(data.result.finite);
  std::vector<double> slot(static_cast<std::size_t>(tree->slot_size()));
  std::vector<double> buf(static_cast<std::size_t>(12 * n));
  ukdyn::tree::FrameState fs(buf.data(), buf.data() + 3 * n, n);
  Vec dID(n);
  ukdyn::Mat C(n, n), C_own(n, n), C_data(n, n);
  tree->coriolis({}, q, qd, C_own);  // without a slot: a buffer of its own
  const int hand = tree->link_index("hand");
  const long count = allocations_in([&] {
    for (int k = 0; k < 20; ++k) {
      ukdyn::forward(*sys, data, 0.01 * k, q, qd, tau);
      tree->inverse_dynamics_tangent({0.0, ukdyn::Slot(slot)}, q, qd, data.qdd, dq, dq, dID);
      tree->frame_state(q, qd, hand, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero(),
                        ukdyn::Slot(slot), fs);
      // The Christoffel matrix (12 joint variables: two passes of the lanes, and the ball
      // joints' radial term), in the slot and in the ForwardData's.
      tree->coriolis({0.0, ukdyn::Slot(slot)}, q, qd, C);
      ukdyn::coriolis_matrix(*sys, data, 0.0, q, qd, C_data);
    }
  });
  EXPECT_EQ(count, 0) << "the quaternion tree allocated " << count << " times";
  EXPECT_EQ((C - C_own).lpNorm<Eigen::Infinity>(), 0.0);
  EXPECT_EQ((C_data - C_own).lpNorm<Eigen::Infinity>(), 0.0);
  EXPECT_GT(C.lpNorm<Eigen::Infinity>(), 0.0);
}

// linearize() asks a tree for ∂ID (inverse_dynamics_jacobian, in the subsystem's slot) and then,
// per frame on it, for the frame's columns (frame_state_jacobian); the frame pass reads the links
// the first left in the slot at the same (q, q̇, q̈) and needs no workspace then: without a scratch
// it allocates nothing (the reuse taken), and at another state it runs its own pass (a buffer of
// its own: allocations) with the same values as without the slot.
TEST(NoAlloc, TreeFramePassOnTheInverseDynamicsLinksAllocatesNothing) {
  namespace sym = ukdyn::symbolic;
  sym::ChainDef c("arm", {"t1", "t2", "t3", "t4"});
  c.gravity = {0.3, -0.2, -9.81};
  for (int i = 0; i < 4; ++i) {
    auto& j = c.add_joint("j" + std::to_string(i + 1), sym::JointDef::Type::revolute,
                          "l" + std::to_string(i + 1));
    j.coordinate = "t" + std::to_string(i + 1);
    j.origin.xyz = {i == 0 ? 0.0 : 0.3, 0.02 * i, 0.1};
    j.axis = i % 2 == 0 ? sym::Vec3Ex{0, 0, 1} : sym::Vec3Ex{0, 1, 0};
    j.inertial.mass = 1.0 + 0.1 * i;
    j.inertial.com = {0.1, 0.01, 0};
    j.inertial.inertia = {0.01, 0, 0, 0, 0.02, 0, 0, 0, 0.02};
  }
  sym::ChainTree t = sym::chain_tree(c);
  ASSERT_TRUE(t.model) << t.reason;
  const auto tree = ukdyn::tree::make_subsystem(std::move(*t.model));
  const Eigen::Index n = tree->dof(), rows = tree->frame_jacobian_rows();
  const Vec q = Vec::LinSpaced(n, -0.8, 0.9), qd = Vec::LinSpaced(n, 0.4, -0.3),
            qdd = Vec::LinSpaced(n, 1.0, -2.0);
  std::vector<double> slot(static_cast<std::size_t>(tree->slot_size()));
  std::vector<double> b0(static_cast<std::size_t>(12 * n)), b1(b0);
  ukdyn::tree::FrameState value(b0.data(), b0.data() + 3 * n, n),
      alone(b1.data(), b1.data() + 3 * n, n);
  ukdyn::Mat Jq(n, n), Jqd(n, n), J(rows, 2 * n), J_alone(rows, 2 * n);
  const ukdyn::Slot s(slot);
  const int tip = static_cast<int>(n) - 1;
  const Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  const Eigen::Vector3d x(0.2, 0, 0);
  tree->inverse_dynamics_jacobian({0.0, s}, q, qd, qdd, Jq, Jqd);
  const long reused = allocations_in([&] {
    for (int k = 0; k < 5; ++k) {
      tree->inverse_dynamics_jacobian({0.0, s}, q, qd, qdd, Jq, Jqd);
      tree->frame_state_jacobian(q, qd, qdd, tip, R, x, s, {}, value, J);
    }
  });
  EXPECT_EQ(reused, 0) << "the frame pass did not take the links at their state";
  tree->frame_state_jacobian(q, qd, qdd, tip, R, x, {}, {}, alone, J_alone);
  EXPECT_LE((J - J_alone).lpNorm<Eigen::Infinity>(), 1e-13 * J_alone.lpNorm<Eigen::Infinity>());
  Vec q1 = q;
  q1(1) += 1e-3;
  const long stale = allocations_in([&] {
    tree->inverse_dynamics_jacobian({0.0, s}, q, qd, qdd, Jq, Jqd);
    tree->frame_state_jacobian(q1, qd, qdd, tip, R, x, s, {}, value, J);
  });
  EXPECT_GT(stale, 0) << "the frame pass took links of another state";
  tree->frame_state_jacobian(q1, qd, qdd, tip, R, x, {}, {}, alone, J_alone);
  EXPECT_EQ(J, J_alone);
}

// The block-arrow solve (ukdyn/core/uk_arrow.hpp) at several N, with every rank decision taken
// (a duplicated grasp, a row on the load alone, a free robot): nothing allocated either.
TEST(NoAlloc, ArrowForwardAllocatesNothing) {
  for (const int robots : {2, 4, 9}) {
    uktest::NRobotsOptions o;
    o.robots = robots;
    o.duplicate_grasp = true;
    o.load_row = true;
    o.free_robot = true;
    const auto sys = uktest::n_robots_system(o);
    ukdyn::ForwardData data(*sys);
    const Eigen::Index n = sys->dof();
    const Vec q = Vec::LinSpaced(n, -0.8, 0.9), qd = Vec::LinSpaced(n, 0.4, -0.3);
    const Vec tau = Vec::Zero(n);
    ukdyn::forward(*sys, data, 0.0, q, qd, tau);
    ASSERT_TRUE(data.used_arrow);
    const long count = allocations_in([&] {
      for (int k = 0; k < 20; ++k) ukdyn::forward(*sys, data, 0.01 * k, q, qd, tau);
    });
    EXPECT_EQ(count, 0) << "the arrow forward() allocated " << count << " times (N = " << robots
                        << ")";
    EXPECT_TRUE(data.used_arrow);
    EXPECT_EQ(data.result.rank, 2 * robots + 1);
    // The drift projection's solves take the same path (src/simulate/drift.cpp).
    const ukdyn::DriftSettings ds;
    const ukdyn::UkSettings uk;
    ukdyn::detail::Projector projector(*sys, ds, uk);
    std::vector<double> x(q.data(), q.data() + n);
    x.insert(x.end(), qd.data(), qd.data() + n);
    long iterations = 0;
    const long in_projection =
        allocations_in([&] { projector.project(0.0, x.data(), iterations); });
    EXPECT_EQ(in_projection, 0) << "the arrow projection allocated (N = " << robots << ")";
    EXPECT_GT(iterations, 0);
    EXPECT_TRUE(projector.data.used_arrow);
  }
}

// C(q, q̇) of every subsystem into its block of the system's C, with the subsystem's slot of a
// ForwardData as scratch: the derived arms (tapes; their C a block of a larger matrix) and the
// paper's closed-form arms.
TEST(NoAlloc, CoriolisInTheDataSlotAllocatesNothing) {
  uktest::NRobotsOptions o;
  o.robots = 4;
  const auto arms = uktest::n_robots_system(o);
  PaperSystem paper(false);
  for (const ukdyn::System* sys :
       std::initializer_list<const ukdyn::System*>{arms.get(), paper.two.system.get()}) {
    ukdyn::ForwardData data(*sys);
    const Eigen::Index n = sys->dof();
    const Vec q = Vec::LinSpaced(n, -0.8, 0.9), qd = Vec::LinSpaced(n, 0.4, -0.3);
    ukdyn::Mat C = ukdyn::Mat::Zero(n, n), C0(n, n);
    // Without the data (no slot): on the stack at these sizes.
    const long without = allocations_in([&] { ukdyn::coriolis_matrix(*sys, q, qd, C0); });
    EXPECT_EQ(without, 0) << "coriolis_matrix allocated " << without << " times (n = " << n << ")";
    const auto& L = sys->layout();
    const auto& subs = sys->subsystems();
    const long count = allocations_in([&] {
      for (std::size_t k = 0; k < subs.size(); ++k) {
        const Eigen::Index s = L.start[k], m = L.size[k];
        subs[k]->coriolis({0.0, data.subsystem_slot(k)}, q.segment(s, m), qd.segment(s, m),
                          C.block(s, s, m, m));
      }
    });
    EXPECT_EQ(count, 0) << "coriolis() allocated " << count << " times (n = " << n << ")";
    EXPECT_EQ((C - C0).lpNorm<Eigen::Infinity>(), 0.0);
    EXPECT_GT(C.lpNorm<Eigen::Infinity>(), 0.0);
  }
}

#ifdef UKDYN_HAVE_IO
// forward() with state-dependent applied forces (a spring-damper, joint friction, a torque of t):
// the compiled force tapes allocate nothing either.
TEST(NoAlloc, ForwardWithAppliedForcesAllocatesNothing) {
  PaperSystem ps(false);
  auto& sys = *ps.two.system;
  const auto& c = sys.coordinate_names();
  namespace sym = ukdyn::symbolic;
  sym::ForceDef f(c);
  f.add_spring_damper("s", {f.parse(c[0]), f.parse(c[1]), 0}, {0, 0, f.parse("0.5")},
                      f.parameter("k", 100), f.parameter("c", 2), 0.3);
  f.add_joint_friction("f", c[3], 0.1, 0.2, 1e-3);
  f.add_torque("drive", c[4], f.parse("0.5*sin(2*t)"));
  sys.add_applied_force(sym::make_applied_force(f));
  ukdyn::ForwardData data(sys);
  const Vec qd = Vec::LinSpaced(12, -0.3, 0.4);
  const Vec tau = Vec::Zero(12);
  ukdyn::forward(sys, data, 0.0, ps.q0, qd, tau);  // first call
  ASSERT_TRUE(data.result.finite);
  const long n = allocations_in([&] {
    for (int k = 0; k < 20; ++k) ukdyn::forward(sys, data, 0.01 * k, ps.q0, qd, tau);
  });
  EXPECT_EQ(n, 0) << "forward() with applied forces allocated " << n << " times in 20 calls";
  EXPECT_NE(data.applied_power, 0.0);
}

// The actuation solve in its workspace (the control law's last step, ukdyn/core/force_split.hpp)
// for every shape the law meets: fully, under- and redundantly actuated, physical rows of full
// rank and rank-deficient (a row the sum of two others: the COD's Z step runs), redundant
// actuators (two equal columns of B), no physical rows. Deterministic matrices (no RNG here).
TEST(NoAlloc, ActuationSolveInItsWorkspaceAllocatesNothing) {
  struct Case {
    Eigen::Index n, k, mp;
    bool deficient_rows, equal_actuators;
  };
  for (const Case c :
       {Case{6, 6, 2, false, false}, Case{6, 3, 2, false, false}, Case{6, 9, 3, false, false},
        Case{5, 5, 3, true, false}, Case{6, 6, 3, true, true}, Case{4, 2, 0, false, false}}) {
    ukdyn::Mat B(c.n, c.k), Ap(c.mp, c.n);
    for (Eigen::Index i = 0; i < c.n; ++i)
      for (Eigen::Index j = 0; j < c.k; ++j)
        B(i, j) = std::sin(1.0 + 3.0 * double(i) + 7.0 * double(j));
    for (Eigen::Index i = 0; i < c.mp; ++i)
      for (Eigen::Index j = 0; j < c.n; ++j)
        Ap(i, j) = std::cos(2.0 + 5.0 * double(i) + 1.3 * double(j));
    if (c.deficient_rows) Ap.row(2) = Ap.row(0) + 0.5 * Ap.row(1);
    if (c.equal_actuators) B.col(1) = B.col(0);
    const Vec Qc = Vec::LinSpaced(c.n, -1.0, 2.0);
    ukdyn::ActuationWorkspace ws(c.n, c.k, c.mp);
    ws.Ap = Ap;
    ukdyn::solve_actuation(B, Qc, ws);  // first call
    const ukdyn::Actuation ref = ukdyn::solve_actuation(B, Ap, Qc);
    const long count = allocations_in([&] {
      for (int k = 0; k < 10; ++k) {
        ws.Ap = Ap;
        ukdyn::solve_actuation(B, Qc, ws);
      }
    });
    EXPECT_EQ(count, 0) << "n " << c.n << " k " << c.k << " mp " << c.mp << ": " << count
                        << " allocations in 10 solves";
    EXPECT_EQ(ws.result.u, ref.u);  // and the numbers are the allocating solve's
    // The Z steps ran: Apᵀ (n × mp) rank-deficient with the dependent row, P B (n × k) whenever
    // its rank is under k (rank P B ≤ n − rank Ap).
    if (c.deficient_rows) {
      EXPECT_LT(ws.codp.rank(), c.mp);
    }
    if (c.mp > 0) {
      EXPECT_LT(ws.cod.rank(), c.k);
    }
  }
}

// A closed-loop control run (docs/control.md): the plant's right-hand side calls the controller
// (forward() of the model, the law's U-K solve, the actuation solve in its workspace, τ = B u) at
// every evaluation. Each built-in law, a heavier plant (plant_set), a constant disturbance.
// docs/control.md "No allocation": not reached yet.
TEST(NoAlloc, ControlRightHandSideAllocatesNothing) {
  for (const char* law : {"feedforward", "stabilized", "robust"}) {
    const auto sc = ukdyn::load_scenario_text(
        uktest::pendulum_servo_yaml(
            1.0, std::string("control:\n  law: ") + law +
                     "\n  rho: 2\n  disturbance: {x: 0.1}\n  plant_set:\n    - {path: "
                     "\"subsystems[bob].parameters.m\", scale: 1.2}\n"),
        "na_control.yaml");
    const auto run = ukdyn::make_control_run(sc);
    ASSERT_TRUE(run);
    Vec q0 = run->q0;
    q0 << std::sin(0.1), -std::cos(0.1);  // off the trajectory at t = 0
    ukdyn::SimulationSettings s = sc.sim;
    ukdyn::UkResult r;
    const long count = rhs_allocations(*run->plant, q0, s, run->loop->force_function(), 50, &r);
    std::printf("control right-hand side (%s): %ld allocations in 50 calls\n", law, count);
    EXPECT_EQ(count, 0) << "the control right-hand side (" << law << ") allocated " << count
                        << " times in 50 calls";
    EXPECT_TRUE(r.finite);
    EXPECT_EQ(r.rank, 1);
    EXPECT_GT(run->loop->u.norm(), 0.0);
  }
}
// The control columns of trajectory.csv (ukdyn/output/control_output.hpp) over ControlForces
// (ukdyn/simulate/control_forces.hpp): the split by role, u (inverse dynamics of the model, or the
// law's), the servo errors and ‖δ‖, and on the paper's plant the closure and squeeze force. The
// first sample is left out (a split found not unique there keeps its redundant rows once).
TEST(NoAlloc, ControlColumnsAllocateNothingPerSample) {
  struct Case {
    std::string name, yaml_or_file;
    bool file;
  };
  const std::vector<Case> cases{
      {"inverse dynamics", uktest::pendulum_servo_yaml(), false},
      {"stabilized law", uktest::pendulum_servo_yaml(1.0, "control:\n  law: stabilized\n"), false},
      {"robust law", uktest::pendulum_servo_yaml(1.0, "control:\n  law: robust\n  rho: 2\n"),
       false},
      {"the paper's control run (closure, squeeze)",
       std::string(UKDYN_SOURCE_DIR) + "/scenarios/paper_control.yaml", true}};
  for (const Case& c : cases) {
    const auto sc = c.file ? ukdyn::load_scenario(c.yaml_or_file)
                           : ukdyn::load_scenario_text(c.yaml_or_file, "na_columns.yaml");
    const auto run = ukdyn::make_control_run(sc);
    const ukdyn::System& sys = run ? *run->plant : *sc.system;
    ukdyn::ControlColumns cols(sc, run ? run->loop.get() : nullptr);
    if (run) cols.set_plant(*run->plant);
    ASSERT_FALSE(cols.empty()) << c.name;
    const Vec q = run ? run->q0 : sc.q0;
    const Vec qd = run ? run->qd0 : sc.qd0;
    ukdyn::ForwardData d(sys);
    ukdyn::forward(sys, d, sc.sim.t0, q, qd, Vec::Zero(sys.dof()));
    std::vector<double> out(cols.header().size());
    cols.fill(sc.sim.t0, q, qd, d, out.data());
    const long count = allocations_in([&] {
      for (int k = 1; k <= 10; ++k) cols.fill(sc.sim.t0 + 0.01 * k, q, qd, d, out.data());
    });
    EXPECT_EQ(count, 0) << c.name << ": " << count << " allocations in 10 samples";
    if (c.file) {
      EXPECT_TRUE(cols.peaks().closure);
    }
  }
}

// The frame constraints' columns (ukdyn/output/constraint_force_output.hpp): the split of Qc by
// block (split_constraint_force() in its workspace) and the wrenches (FrameWrenchMap::evaluate() in
// its workspace), the same numbers as the allocating functions.
TEST(NoAlloc, ConstraintForceColumnsAllocateNothing) {
  const auto sc =
      ukdyn::load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/n_robots_3_weld.yaml");
  const ukdyn::System& sys = *sc.system;
  ukdyn::ConstraintForceColumns cols(sc);
  ASSERT_FALSE(cols.empty());
  ukdyn::ForwardData d(sys);
  ukdyn::forward(sys, d, sc.sim.t0, sc.q0, sc.qd0, sc.tau);
  std::vector<double> out(cols.header().size());
  cols.fill(sc.q0, d, out.data());
  const long count = allocations_in([&] {
    for (int k = 0; k < 10; ++k) cols.fill(sc.q0, d, out.data());
  });
  EXPECT_EQ(count, 0) << count << " allocations in 10 samples";
  // λ bit for bit Eigen's own least-norm solve (what split_constraint_force() did before its
  // workspace).
  ukdyn::ConstraintForceWorkspace ws(sys.rows(), sys.dof(), sys.constraint_row_offsets());
  ukdyn::split_constraint_force(d.A, d.Qc, ws);
  Eigen::CompleteOrthogonalDecomposition<ukdyn::Mat> cod(d.A.transpose());
  cod.setThreshold(cod.maxPivot() > 0 ? 1e-10 : 1.0);
  const Vec lambda = cod.solve(d.Qc);
  EXPECT_EQ(ws.result.lambda, lambda);
}

// linearize() into its LinearizeData (ukdyn/model/linearize.hpp), arms on trees welded to a load
// by numeric frame constraints, at states moving along the constraints (the rank of A stays): all
// parts and ∂q̈/∂(q, q̇) alone allocate nothing after the first call, and give the same numbers as
// the allocating linearize(). The two weld systems have the block-arrow structure; the three arms
// on a free-body load run with the arrow KKT solve (ukdyn/core/uk_arrow_kkt.hpp; two robots keep
// the dense one, by the Schur complement) and with the dense LU (allow_arrow = false). The paper's
// chains add derived constraints (their tape tangents, every direction in one call; their time
// tangents, the trajectory's, for ∂q̈/∂t) and no arrow. A lone Panda (bench/panda_arm.yaml) has no
// constraint rows: M⁻¹ times the inverse dynamics' derivatives, no KKT system (with allow_arrow =
// false the LU of K = M, the reference).
TEST(NoAlloc, LinearizeInItsWorkspaceAllocatesNothing) {
  for (const char* name : {"two_ur5e_load.yaml", "n_robots_3_weld.yaml", "paper_chain.yaml",
                           "../bench/panda_arm.yaml"}) {
    SCOPED_TRACE(name);
    const auto sc = ukdyn::load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/" + name);
    const ukdyn::System& sys = *sc.system;
    const Eigen::Index n = sys.dof();
    ASSERT_TRUE(ukdyn::components_without_derivatives(sys).empty());
    const Vec tau = Vec::LinSpaced(n, -0.5, 0.5);
    for (const bool arrow : {true, false}) {
      ukdyn::LinearizeData data(sys);
      data.allow_arrow = arrow;
      for (const bool all : {true, false}) {
        const ukdyn::LinearizeParts parts{all, all};
        ukdyn::linearize(sys, data, sc.sim.t0, sc.q0, sc.qd0, tau, sc.sim.uk, parts);  // sizes
        ASSERT_TRUE(data.lin.trusted) << data.lin.message;
        EXPECT_EQ(data.used_arrow, arrow && std::string(name) == "n_robots_3_weld.yaml");
        const long count = allocations_in([&] {
          for (int k = 0; k < 5; ++k)
            ukdyn::linearize(sys, data, sc.sim.t0 + 0.01 * k, sc.q0, sc.qd0, tau, sc.sim.uk, parts);
        });
        EXPECT_EQ(count, 0) << count << " allocations in 5 calls (all parts: " << all
                            << ", arrow: " << arrow << ")";
        ukdyn::LinearizeData fresh(sys);
        fresh.allow_arrow = arrow;
        ukdyn::linearize(sys, fresh, sc.sim.t0 + 0.04, sc.q0, sc.qd0, tau, sc.sim.uk);
        const ukdyn::Linearization& ref = fresh.lin;
        EXPECT_EQ(data.lin.dqdd_dq, ref.dqdd_dq);
        EXPECT_EQ(data.lin.dqdd_dqd, ref.dqdd_dqd);
        // The time column (LinearizeParts::time, on in both) too: the same numbers.
        ASSERT_EQ(data.lin.dqdd_dt.size(), n) << data.lin.time_message;
        EXPECT_EQ(data.lin.dqdd_dt, ref.dqdd_dt);
        if (all) {
          EXPECT_EQ(data.lin.dqdd_dtau, ref.dqdd_dtau);
          EXPECT_EQ(data.lin.dQc_dq, ref.dQc_dq);
        } else {
          EXPECT_EQ(data.lin.dqdd_dtau.size(), 0);
          EXPECT_EQ(data.lin.dQc_dq.size(), 0);
        }
      }
      // ∂q̈/∂(q, q̇) structured (own blocks and the coupling through the load) where the arrow
      // solve runs, dense otherwise: no allocation either, and the same matrix expanded.
      const ukdyn::LinearizeParts structured{false, false, true};
      ukdyn::linearize(sys, data, sc.sim.t0, sc.q0, sc.qd0, tau, sc.sim.uk, structured);
      EXPECT_EQ(data.structured, data.used_arrow);
      const long count = allocations_in([&] {
        for (int k = 0; k < 5; ++k)
          ukdyn::linearize(sys, data, sc.sim.t0 + 0.01 * k, sc.q0, sc.qd0, tau, sc.sim.uk,
                           structured);
      });
      EXPECT_EQ(count, 0) << count << " allocations in 5 structured calls (arrow: " << arrow << ")";
      ukdyn::LinearizeData fresh(sys);
      fresh.allow_arrow = arrow;
      ukdyn::linearize(sys, fresh, sc.sim.t0 + 0.04, sc.q0, sc.qd0, tau, sc.sim.uk);
      Mat dq, dqd;
      ukdyn::dqdd_dx_dense(data, dq, dqd);
      EXPECT_LE((dq - fresh.lin.dqdd_dq).cwiseAbs().maxCoeff(),
                1e-12 * (1.0 + fresh.lin.dqdd_dq.cwiseAbs().maxCoeff()));
      EXPECT_LE((dqd - fresh.lin.dqdd_dqd).cwiseAbs().maxCoeff(),
                1e-12 * (1.0 + fresh.lin.dqdd_dqd.cwiseAbs().maxCoeff()));
    }
  }
}
// A tree's potential from the placement forward() left in its slot (TreeSubsystem::potential with
// `placed`, the per-sample recorder's path) is taken from that slot: no pass, so with no scratch
// slot nothing is allocated. At another state the slot is not used: the fresh pass then needs a
// buffer of its own, which the counter sees (both paths give the value of a fresh potential()).
TEST(NoAlloc, PotentialFromThePlacementOfForwardAllocatesNothing) {
  const auto sc =
      ukdyn::load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/two_pandas_weld.yaml");
  const ukdyn::System& sys = *sc.system;
  const auto& L = sys.layout();
  ukdyn::ForwardData data(sys);
  const Vec qd = Vec::LinSpaced(sys.dof(), -0.3, 0.4);
  ukdyn::forward(sys, data, 0.0, sc.q0, qd, Vec::Zero(sys.dof()));
  Vec q2 = sc.q0;
  q2.array() += 0.01;
  int trees = 0;
  for (std::size_t k = 0; k < sys.subsystems().size(); ++k) {
    const auto* tree = dynamic_cast<const ukdyn::tree::TreeSubsystem*>(sys.subsystems()[k].get());
    if (tree == nullptr) continue;
    ++trees;
    const ukdyn::ConstSlot placed(
        data.slots.data() + data.slot_start[k],
        static_cast<std::size_t>(data.slot_start[k + 1] - data.slot_start[k]));
    const auto qk = sc.q0.segment(L.start[k], L.size[k]);
    const auto q2k = q2.segment(L.start[k], L.size[k]);
    double V = 0.0, V2 = 0.0;
    EXPECT_EQ(allocations_in([&] { V = tree->potential(qk, placed, {}); }), 0);
    EXPECT_GT(allocations_in([&] { V2 = tree->potential(q2k, placed, {}); }), 0);
    EXPECT_EQ(V, tree->potential({}, qk));
    EXPECT_EQ(V2, tree->potential({}, q2k));
  }
  EXPECT_EQ(trees, 2);
}
#endif

}  // namespace
