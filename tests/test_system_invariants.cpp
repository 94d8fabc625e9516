// Invariants of the closure-only free motion (τ = 0, gravity on) of the paper's two-arm system,
// with q̈ from forward() and every other quantity from the independent AD reference
// (reference_model.hpp):
//   * ideal constraints: Qcᵀ q̇ = 0 for A q̇ = 0;
//   * energy: d/dt (T + V) = q̇ᵀ M q̈ + ½ q̇ᵀ Ṁ q̇ + Gᵀ q̇ = τᵀ q̇ = 0;
//   * horizontal linear momentum and vertical angular momentum (about the world Z axis, including
//   the
//     paper's rotational terms I_r δ̇ + Σ I_k δ̇) have zero rate: dP/dt = Σ m (J q̈ + J̇ q̇), …;
//   * the same quantities stay constant along a short RK4 integration of forward().
#include <gtest/gtest.h>

#include <Eigen/QR>

#include "helpers.hpp"
#include "reference_model.hpp"

namespace {

using ukdyn::Mat;
using ukdyn::Vec;
using uktest::Vector6d;

struct Invariants {
  double energy = 0;
  Eigen::Vector2d P = Eigen::Vector2d::Zero();
  double Lz = 0;
};

/// Total energy, horizontal momentum and vertical angular momentum from the reference kinematics.
Invariants invariants(const std::array<ukdyn::MobileManipulatorParams, 2>& p, const Vec& q,
                      const Vec& qd) {
  Invariants inv;
  for (int k = 0; k < 2; ++k) {
    const auto& pk = p[static_cast<std::size_t>(k)];
    const Vector6d qk = q.segment<6>(6 * k), vk = qd.segment<6>(6 * k);
    inv.energy += ukref::kinetic_energy<double>(pk, qk, vk) + ukref::potential<double>(pk, qk);
    const auto pos = ukref::com_positions<double>(pk, qk);
    const auto J = ukref::com_jacobians<double>(pk, qk);
    for (std::size_t b = 0; b < 5; ++b) {
      const double m = ukref::body_mass(pk, static_cast<int>(b));
      const Eigen::Vector3d v = J[b] * vk;
      inv.P += m * v.head<2>();
      inv.Lz += m * (pos[b](0) * v(1) - pos[b](1) * v(0));
    }
    inv.Lz +=
        (pk.base_inertia + pk.link_inertia[0] + pk.link_inertia[1] + pk.link_inertia[2]) * vk(2);
  }
  return inv;
}

/// Rates of the invariants at (q, q̇, q̈): chain rule with the reference's Ṁ, G, J, J̇q̇.
Invariants invariant_rates(const std::array<ukdyn::MobileManipulatorParams, 2>& p, const Vec& q,
                           const Vec& qd, const Vec& qdd) {
  Invariants r;
  for (int k = 0; k < 2; ++k) {
    const auto& pk = p[static_cast<std::size_t>(k)];
    const Vector6d qk = q.segment<6>(6 * k), vk = qd.segment<6>(6 * k), ak = qdd.segment<6>(6 * k);
    const auto M = ukref::mass_matrix<double>(pk, qk);
    const auto Md = ukref::mass_dot(pk, qk, vk);
    r.energy += vk.dot(M * ak) + 0.5 * vk.dot(Md * vk) + ukref::gravity(pk, qk).dot(vk);
    const auto pos = ukref::com_positions<double>(pk, qk);
    const auto J = ukref::com_jacobians<double>(pk, qk);
    const auto Jdqd = ukref::com_jdot_qd(pk, qk, vk);
    for (std::size_t b = 0; b < 5; ++b) {
      const double m = ukref::body_mass(pk, static_cast<int>(b));
      const Eigen::Vector3d a = J[b] * ak + Jdqd[b];
      r.P += m * a.head<2>();
      r.Lz += m * (pos[b](0) * a(1) - pos[b](1) * a(0));  // ṙ × v = v × v = 0
    }
    r.Lz +=
        (pk.base_inertia + pk.link_inertia[0] + pk.link_inertia[1] + pk.link_inertia[2]) * ak(2);
  }
  return r;
}

struct Fixture {
  std::array<ukdyn::MobileManipulatorParams, 2> params;
  uktest::TwoArms two;
  std::shared_ptr<ukdyn::ClosureConstraint> closure;
  explicit Fixture(const std::array<ukdyn::MobileManipulatorParams, 2>& p)
      : params(p), two(p[0], p[1]), closure(two.add_closure()) {}

  Mat A(const Vec& q) const {
    Mat a = Mat::Zero(6, 12);
    Vec b(6);
    closure->evaluate({}, q, Vec::Zero(12), a, b);
    return a;
  }
  /// Gauss–Newton projection of q onto the closure manifold Φ(q) = 0.
  Vec project(Vec q) const {
    Vec phi(6);
    for (int it = 0; it < 50; ++it) {
      closure->position_residual({}, q, phi);
      if (phi.norm() < 1e-14) break;
      q -= A(q).completeOrthogonalDecomposition().solve(phi);
    }
    return q;
  }
  /// A random configuration near the paper's q0 on the closure manifold, with a random velocity in
  /// null(A) (velocity-consistent).
  std::pair<Vec, Vec> random_state(std::mt19937_64& rng) const {
    Vec q = uktest::paper_q0();
    for (Eigen::Index i = 0; i < 12; ++i) q(i) += uktest::uniform(rng, -0.3, 0.3);
    q = project(q);
    const Mat N = uktest::null_space(A(q));
    Vec z(N.cols());
    for (Eigen::Index i = 0; i < z.size(); ++i) z(i) = uktest::uniform(rng, -1.0, 1.0);
    return {q, N * z};
  }
};

std::array<ukdyn::MobileManipulatorParams, 2> table1() { return {}; }
std::array<ukdyn::MobileManipulatorParams, 2> random_pair() {
  std::mt19937_64 rng(777);
  auto a = uktest::random_params(rng);
  auto b = uktest::random_params(rng);
  // The closure's z row assumes equal base heights unless dz is set; keep l_r equal.
  b.base_length = a.base_length;
  return {a, b};
}

TEST(SystemInvariants, ConstraintForceHasZeroPowerOnConsistentVelocities) {
  for (const auto& p : {table1(), random_pair()}) {
    Fixture f(p);
    ukdyn::ForwardData data(*f.two.system);
    std::mt19937_64 rng(201);
    for (int s = 0; s < 50; ++s) {
      const auto [q, qd] = f.random_state(rng);
      Vec phi(6), phid(6);
      f.closure->position_residual({}, q, phi);
      ASSERT_LE(phi.norm(), 1e-13);
      f.closure->velocity_residual({}, q, qd, phid);
      ASSERT_LE(phid.norm(), 1e-13);
      ukdyn::forward(*f.two.system, data, 0.0, q, qd, Vec::Zero(12));
      ASSERT_TRUE(data.result.finite);
      EXPECT_EQ(data.result.rank, 6);
      const double scale = data.Qc.norm() * qd.norm() + 1e-300;
      EXPECT_LE(std::abs(data.Qc.dot(qd)), 1e-12 * scale) << "state " << s;
      // And for every direction of null(A), not only the actual velocity.
      const Mat N = uktest::null_space(data.A);
      EXPECT_LE((N.transpose() * data.Qc).norm(), 1e-12 * (data.Qc.norm() + 1.0)) << "state " << s;
    }
  }
}

TEST(SystemInvariants, EnergyAndMomentaHaveZeroRate) {
  for (const auto& p : {table1(), random_pair()}) {
    Fixture f(p);
    ukdyn::ForwardData data(*f.two.system);
    std::mt19937_64 rng(202);
    for (int s = 0; s < 50; ++s) {
      const auto [q, qd] = f.random_state(rng);
      ukdyn::forward(*f.two.system, data, 0.0, q, qd, Vec::Zero(12));
      ASSERT_TRUE(data.result.finite);
      const Invariants r = invariant_rates(p, q, qd, data.qdd);
      // Scales: the size of the individual terms (gravity power, momentum rates of single bodies).
      double e_scale = 0.0, p_scale = 0.0;
      for (int k = 0; k < 2; ++k) {
        const auto& pk = p[static_cast<std::size_t>(k)];
        const Vector6d qk = q.segment<6>(6 * k), vk = qd.segment<6>(6 * k);
        e_scale +=
            std::abs(ukref::gravity(pk, qk).dot(vk)) +
            std::abs(vk.dot(ukref::mass_matrix<double>(pk, qk) * data.qdd.segment<6>(6 * k)));
        p_scale += (ukref::mass_matrix<double>(pk, qk) * data.qdd.segment<6>(6 * k)).norm();
      }
      EXPECT_LE(std::abs(r.energy), 1e-11 * (e_scale + 1.0)) << "state " << s;
      EXPECT_LE(r.P.norm(), 1e-11 * (p_scale + 1.0))
          << "state " << s << " dP/dt " << r.P.transpose();
      EXPECT_LE(std::abs(r.Lz), 1e-11 * (p_scale + 1.0) * 5.0) << "state " << s;
    }
  }
}

// With τ ≠ 0 the energy rate equals the applied power τᵀ q̇ (the constraint force does no work).
TEST(SystemInvariants, EnergyRateEqualsAppliedPower) {
  Fixture f(table1());
  ukdyn::ForwardData data(*f.two.system);
  std::mt19937_64 rng(203);
  for (int s = 0; s < 20; ++s) {
    const auto [q, qd] = f.random_state(rng);
    Vec tau(12);
    for (Eigen::Index i = 0; i < 12; ++i) tau(i) = uktest::uniform(rng, -10, 10);
    ukdyn::forward(*f.two.system, data, 0.0, q, qd, tau);
    const Invariants r = invariant_rates(f.params, q, qd, data.qdd);
    const double power = tau.dot(qd);
    EXPECT_NEAR(r.energy, power, 1e-11 * (std::abs(power) + tau.norm() * qd.norm() + 100.0));
  }
}

// A short RK4 integration of forward() from the paper's spatial start (paper-notes): energy, P and
// Lz stay constant to the integrator's accuracy; the yaw terms are exercised (δ̇ ≠ 0).
TEST(SystemInvariants, ConservedAlongRk4Integration) {
  Fixture f(table1());
  ukdyn::ForwardData data(*f.two.system);
  Vec q = uktest::paper_q0();
  Vec qd(12);
  qd << 0.19943338785662684, -0.3090685792886618, 0.3238357241108272, 0.6732214266883658,
      -0.10243493969032202, 0, 0.09956390871238911, 0.20906857928866182, 0.3238357241108272,
      -0.7333193364981856, -0.10243493969031958, 0;
  const Vec tau = Vec::Zero(12);
  auto rhs = [&](double t, const Vec& x) {
    ukdyn::forward(*f.two.system, data, t, x.head(12), x.tail(12), tau);
    Vec dx(24);
    dx << x.tail(12), data.qdd;
    return dx;
  };
  Vec x(24);
  x << q, qd;
  const Invariants i0 = invariants(f.params, q, qd);
  const double h = 1e-3;
  double t = 0.0;
  double max_dE = 0.0, max_dP = 0.0, max_dL = 0.0, max_phi = 0.0;
  for (int step = 0; step < 500; ++step) {
    const Vec k1 = rhs(t, x);
    const Vec k2 = rhs(t + h / 2, x + h / 2 * k1);
    const Vec k3 = rhs(t + h / 2, x + h / 2 * k2);
    const Vec k4 = rhs(t + h, x + h * k3);
    x += h / 6 * (k1 + 2 * k2 + 2 * k3 + k4);
    t += h;
    const Invariants it = invariants(f.params, x.head(12), x.tail(12));
    max_dE = std::max(max_dE, std::abs(it.energy - i0.energy));
    max_dP = std::max(max_dP, (it.P - i0.P).norm());
    max_dL = std::max(max_dL, std::abs(it.Lz - i0.Lz));
    Vec phi(6);
    f.closure->position_residual({t}, x.head(12), phi);
    max_phi = std::max(max_phi, phi.norm());
  }
  EXPECT_LE(max_dE, 1e-9 * std::abs(i0.energy)) << "energy drift";
  EXPECT_LE(max_dP, 1e-10) << "horizontal momentum drift";
  EXPECT_LE(max_dL, 1e-10) << "vertical angular momentum drift";
  EXPECT_LE(max_phi, 1e-8) << "closure drift";
  // The motion is spatial: the yaw moved.
  EXPECT_GT(std::abs(x(2)), 0.05);
}

// Why the momentum checks matter: with the paper's printed C34/C43 (m1 ĉ1/2 instead of m1 ĉ1/4) the
// energy rate is still zero (Ṁ − 2C stays skew-symmetric, so q̇ᵀ(½Ṁ − C)q̇ = 0), but the vertical
// angular momentum is no longer conserved. Our C gives zero for both.
TEST(SystemInvariants, PrintedC34ErratumConservesEnergyButBreaksAngularMomentum) {
  Fixture f(table1());
  ukdyn::ForwardData data(*f.two.system);
  std::mt19937_64 rng(204);
  int caught = 0;
  for (int s = 0; s < 20; ++s) {
    const auto [q, qd] = f.random_state(rng);
    ukdyn::forward(*f.two.system, data, 0.0, q, qd, Vec::Zero(12));
    // Printed C34/C43 differ from the correct ones by ∓ m1 ĉ1 ŝ1 δ̇ / 4 in each arm.
    Vec Cqd_printed = data.Cqd;
    for (int k = 0; k < 2; ++k) {
      const auto& pk = f.params[static_cast<std::size_t>(k)];
      const Eigen::Index o = 6 * k;
      const double c1 = pk.link_length[0] * std::cos(q(o + 3));
      const double s1 = pk.link_length[0] * std::sin(q(o + 3));
      const double d = pk.link_mass[0] * c1 * s1 * qd(o + 2) / 4.0;
      Cqd_printed(o + 2) += -d * qd(o + 3);  // ΔC34 θ̇1
      Cqd_printed(o + 3) += d * qd(o + 2);   // ΔC43 δ̇
    }
    const Vec Q = -Cqd_printed - data.G;
    ukdyn::UkWorkspace ws(f.two.system->layout(), 6);
    Vec qdd(12), Qc(12);
    ukdyn::uk_solve(data.M, data.A, data.b, Q, ws, qdd, Qc);
    const Invariants good = invariant_rates(f.params, q, qd, data.qdd);
    const Invariants bad = invariant_rates(f.params, q, qd, qdd);
    EXPECT_LE(std::abs(good.Lz), 1e-10);
    EXPECT_LE(std::abs(bad.energy), 1e-10) << "state " << s;
    if (std::abs(bad.Lz) > 1e-6) ++caught;  // ours: < 1e-10
  }
  EXPECT_GE(caught, 18);
}

}  // namespace
