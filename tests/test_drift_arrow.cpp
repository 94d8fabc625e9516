// Drift control on the block-arrow path (ukdyn/core/uk_arrow.hpp): the projection onto the
// constraint manifold and the Baumgarte right-hand side of N arms carrying a load
// (tests/n_robots_model.hpp) against the same model whose constraints hide their sparsity, so
// that every solve is the dense one (uk_solve.hpp). Two solves of the same equations: they must
// agree to round-off.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <numbers>
#include <random>

#include "n_robots_model.hpp"
#include "ukdyn/model/system.hpp"
#include "ukdyn/simulate/drift.hpp"
#include "ukdyn/simulate/simulate.hpp"

namespace {

using ukdyn::Index;
using ukdyn::Vec;

// A constraint that forwards everything to `inner` but declares no sparsity (row_columns() empty):
// a System built from these has no arrow structure and takes the dense solve.
class HiddenSparsity final : public ukdyn::Constraint {
 public:
  explicit HiddenSparsity(std::shared_ptr<const ukdyn::Constraint> inner)
      : inner_(std::move(inner)) {}
  [[nodiscard]] Index rows() const override { return inner_->rows(); }
  [[nodiscard]] const std::vector<std::string>& row_names() const override {
    return inner_->row_names();
  }
  [[nodiscard]] Index slot_size() const override { return inner_->slot_size(); }
  [[nodiscard]] Index shared_slot_size() const override { return inner_->shared_slot_size(); }
  void evaluate(const ukdyn::ConstraintContext& c, ukdyn::CVecRef q, ukdyn::CVecRef qd,
                ukdyn::MatRef A, ukdyn::VecRef b) const override {
    inner_->evaluate(c, q, qd, A, b);
  }
  void position_residual(const ukdyn::ConstraintContext& c, ukdyn::CVecRef q,
                         ukdyn::VecRef phi) const override {
    inner_->position_residual(c, q, phi);
  }
  void velocity_residual(const ukdyn::ConstraintContext& c, ukdyn::CVecRef q, ukdyn::CVecRef qd,
                         ukdyn::VecRef phid) const override {
    inner_->velocity_residual(c, q, qd, phid);
  }

 private:
  std::shared_ptr<const ukdyn::Constraint> inner_;
};

std::shared_ptr<ukdyn::System> dense_twin(const ukdyn::System& sys) {
  auto twin = std::make_shared<ukdyn::System>();
  for (const auto& s : sys.subsystems()) twin->add_subsystem(s);
  for (const auto& c : sys.constraints()) twin->add_constraint(std::make_shared<HiddenSparsity>(c));
  return twin;
}

double rel_diff(const Vec& a, const Vec& b) {
  return (a - b).lpNorm<Eigen::Infinity>() / std::max(1.0, b.lpNorm<Eigen::Infinity>());
}

// [q; q̇ = 0] of tests/n_robots_model.hpp with the load at (x, z, φ) and each arm's tip on its
// grasp point, the last link pointing at the load's centre, elbow up (as tools/n_robots.py).
std::vector<double> ik_state(int robots, double x, double z, double phi) {
  const double l1 = 0.5, l2 = 0.4, l3 = 0.3;
  std::vector<double> q;
  for (int k = 0; k < robots; ++k) {
    const double a = 2.0 * std::numbers::pi * k / robots;
    const double bx = 1.2 * std::cos(a), bz = 1.2 * std::sin(a);
    const double px = x + 0.3 * std::cos(phi + a), pz = z + 0.3 * std::sin(phi + a);
    const double end = a + phi + std::numbers::pi;
    const double wx = px - l3 * std::cos(end) - bx, wz = pz - l3 * std::sin(end) - bz;
    const double c2 = (wx * wx + wz * wz - l1 * l1 - l2 * l2) / (2.0 * l1 * l2);
    const double t2 = -std::acos(c2);
    const double t1 = std::atan2(wz, wx) - std::atan2(l2 * std::sin(t2), l1 + l2 * std::cos(t2));
    q.insert(q.end(), {t1, t2, end - t1 - t2});
  }
  q.insert(q.end(), {x, z, phi});
  q.resize(2 * q.size(), 0.0);
  return q;
}

TEST(DriftArrow, ProjectionAgreesWithTheDenseProjection) {
  for (int robots : {2, 3, 5, 8}) {
    SCOPED_TRACE(robots);
    uktest::NRobotsOptions o;
    o.robots = robots;
    const auto sys = uktest::n_robots_system(o);
    ASSERT_NE(sys->arrow(), nullptr);
    const auto twin = dense_twin(*sys);
    ASSERT_EQ(twin->arrow(), nullptr);
    const Index n = sys->dof();
    ukdyn::DriftSettings ds;
    ds.position_tol = 1e-13;  // quadratic convergence from 1e-4: the same steps in both
    const ukdyn::UkSettings uk;
    ukdyn::detail::Projector arrow(*sys, ds, uk), dense(*twin, ds, uk);
    std::mt19937 rng(20261205u);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    double worst = 0.0;
    for (int k = 0; k < 20; ++k) {
      // A state on the manifold (ik_state), moved off by up to 1e-4 in q and 1e-2 in q̇.
      std::vector<double> x0 = ik_state(robots, 0.05 * u(rng), 0.05 * u(rng), 0.2 * u(rng));
      for (Index i = n; i < 2 * n; ++i) x0[static_cast<std::size_t>(i)] = u(rng);
      std::vector<double> xa = x0, xd = x0;
      for (Index i = 0; i < 2 * n; ++i) {
        const double d = (i < n ? 1e-4 : 1e-2) * u(rng);
        xa[static_cast<std::size_t>(i)] += d;
        xd[static_cast<std::size_t>(i)] += d;
      }
      long ia = 0, id = 0;
      const double ra = arrow.project(0.1, xa.data(), ia);
      const double rd = dense.project(0.1, xd.data(), id);
      EXPECT_TRUE(arrow.data.used_arrow);
      EXPECT_FALSE(dense.data.used_arrow);
      EXPECT_GT(ia, 0);
      EXPECT_EQ(ia, id);
      EXPECT_LE(ra, 1e-12);
      EXPECT_LE(rd, 1e-12);
      const Eigen::Map<const Vec> va(xa.data(), 2 * n), vd(xd.data(), 2 * n);
      worst = std::max(worst, rel_diff(va, vd));
    }
    EXPECT_LE(worst, 1e-12);
    ::testing::Test::RecordProperty("worst_rel_" + std::to_string(robots),
                                    ::testing::PrintToString(worst));
  }
}

// Projector::project(..., at_x): M and A of a forward() at exactly the state to be projected (what
// dopri5's last stage leaves in simulate()'s right-hand side) serve the first Gauss–Newton
// iteration. Functions of (t, q) alone, they are the bytes the projector would evaluate itself, so
// the projected state is bitwise the same, on the arrow and on the dense solve. The control: a
// forward() at another q (1e-6 away) changes the result, so the data given is really used.
TEST(DriftArrow, ProjectionWithTheCallersEvaluationIsTheSameBytes) {
  uktest::NRobotsOptions o;
  o.robots = 3;
  const auto sys = uktest::n_robots_system(o);
  const auto twin = dense_twin(*sys);
  for (const auto* s : {sys.get(), twin.get()}) {
    SCOPED_TRACE(s == sys.get() ? "arrow" : "dense");
    const Index n = s->dof();
    const ukdyn::DriftSettings ds;
    const ukdyn::UkSettings uk;
    ukdyn::detail::Projector own(*s, ds, uk), shared(*s, ds, uk);
    ukdyn::ForwardData at(*s);
    std::mt19937 rng(20261205u);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    for (int k = 0; k < 10; ++k) {
      std::vector<double> x0 = ik_state(3, 0.05 * u(rng), 0.05 * u(rng), 0.2 * u(rng));
      for (Index i = n; i < 2 * n; ++i) x0[static_cast<std::size_t>(i)] = u(rng);
      for (Index i = 0; i < 2 * n; ++i) x0[static_cast<std::size_t>(i)] += 1e-8 * u(rng);
      const Eigen::Map<const Vec> q(x0.data(), n), qd(x0.data() + n, n);
      const Vec tau = Vec::Zero(n);
      ukdyn::forward(*s, at, 0.1, q, qd, tau, uk);
      std::vector<double> xa = x0, xb = x0;
      long ia = 0, ib = 0;
      const double ra = own.project(0.1, xa.data(), ia);
      const double rb = shared.project(0.1, xb.data(), ib, &at);
      EXPECT_GT(ia, 0);
      EXPECT_EQ(ia, ib);
      EXPECT_EQ(std::memcmp(&ra, &rb, sizeof ra), 0);
      EXPECT_EQ(std::memcmp(xa.data(), xb.data(), xa.size() * sizeof(double)), 0);
      // The control: M and A of another q give another correction.
      Vec q_other = q;
      q_other(0) += 1e-6;
      ukdyn::forward(*s, at, 0.1, q_other, qd, tau, uk);
      std::vector<double> xc = x0;
      long ic = 0;
      shared.project(0.1, xc.data(), ic, &at);
      EXPECT_NE(std::memcmp(xa.data(), xc.data(), xa.size() * sizeof(double)), 0);
    }
  }
}

TEST(DriftArrow, BaumgarteRightHandSideAgreesWithTheDenseOne) {
  for (int robots : {2, 3, 5, 8}) {
    SCOPED_TRACE(robots);
    uktest::NRobotsOptions o;
    o.robots = robots;
    const auto sys = uktest::n_robots_system(o);
    const auto twin = dense_twin(*sys);
    ukdyn::SimulationSettings s;
    s.drift.kind = ukdyn::DriftControl::baumgarte;
    const ukdyn::ForceFunction none;
    ukdyn::IntegratorRhs fa(*sys, none, s), fd(*twin, none, s);
    const Index n = sys->dof();
    std::mt19937 rng(20261206u);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    double worst = 0.0;
    for (int k = 0; k < 50; ++k) {
      std::vector<double> x(static_cast<std::size_t>(2 * n)), da(x.size()), dd(x.size());
      for (double& v : x) v = 1.5 * u(rng);  // off the manifold: the Baumgarte terms are O(1)
      const double t = u(rng);
      fa(x, da, t);
      fd(x, dd, t);
      ASSERT_TRUE(fa.data().used_arrow);
      ASSERT_FALSE(fd.data().used_arrow);
      const Eigen::Map<const Vec> va(da.data(), 2 * n), vd(dd.data(), 2 * n);
      worst = std::max(worst, rel_diff(va, vd));
    }
    EXPECT_LE(worst, 1e-12);
    ::testing::Test::RecordProperty("worst_rel_" + std::to_string(robots),
                                    ::testing::PrintToString(worst));
  }
}

}  // namespace
