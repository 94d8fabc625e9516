// Free rigid bodies in quaternion coordinates (ukdyn/symbolic/free_body.hpp) and the U-K solve for
// singular mass matrices (ukdyn/core/uk_singular.hpp), against closed forms: the torque-free body's
// invariants and the Dzhanibekov period (Landau & Lifshitz, Mechanics, Sec. 37), the heavy
// symmetric top's steady precession (Goldstein, Classical Mechanics, Sec. 5.7), the pendulum with a
// massless rod (θ̈ = −(g/l) sin θ; period 4 K(sin(θ0/2)) sqrt(l/g)), and both solve paths agreeing.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <numbers>
#include <random>

#include "ukdyn/core/uk_singular.hpp"
#include "ukdyn/model/system.hpp"
#include "ukdyn/simulate/simulate.hpp"
#include "ukdyn/symbolic/canonical.hpp"
#include "ukdyn/symbolic/definitions.hpp"
#include "ukdyn/symbolic/free_body.hpp"
#ifdef UKDYN_HAVE_IO
#include "ukdyn/scenario/scenario.hpp"
#endif

namespace {

using ukdyn::CVecRef;
using ukdyn::ForwardData;
using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::System;
using ukdyn::Vec;
namespace sym = ukdyn::symbolic;

// Independent numeric forms (not from the library): R of a unit quaternion (w, x, y, z) and
// ω_body = 2 (w ẋ − x ẇ + ...) by the quaternion product 2 q* ⊗ q̇.
Eigen::Matrix3d rot(const Vec& q4) {
  return Eigen::Quaterniond(q4(0), q4(1), q4(2), q4(3)).toRotationMatrix();
}
Eigen::Vector3d omega_body(const Vec& q4, const Vec& qd4) {
  const Eigen::Quaterniond q(q4(0), q4(1), q4(2), q4(3)), qd(qd4(0), qd4(1), qd4(2), qd4(3));
  const Eigen::Quaterniond w = q.conjugate() * qd;
  return 2.0 * Eigen::Vector3d(w.x(), w.y(), w.z());
}

struct Body {
  std::shared_ptr<System> system = std::make_shared<System>();
  std::shared_ptr<sym::DerivedSubsystem> sub;
};

// A free body with principal inertias J and gravity g (z), optionally with its point c (body frame)
// held at the world origin (a ball joint, the heavy top), by expression rows.
Body free_body(const std::array<double, 3>& J, double m, double g,
               const std::optional<Eigen::Vector3d>& pivot = std::nullopt) {
  Body b;
  const auto def =
      sym::free_body_definition("b", m, {J[0], 0, 0, 0, J[1], 0, 0, 0, J[2]}, {0, 0, -g});
  b.sub = sym::make_subsystem(def);
  b.system->add_subsystem(b.sub);
  const auto names = sym::free_body_coordinates("b");
  b.system->add_constraint(sym::make_constraint(
      sym::free_body_norm_constraint("b", {names[3], names[4], names[5], names[6]}, names)));
  if (pivot) {
    sym::ConstraintDef c("ball", sym::ConstraintDef::Kind::holonomic, names);
    const auto R = sym::quaternion_rotation(c.parse("b_qw"), c.parse("b_qx"), c.parse("b_qy"),
                                            c.parse("b_qz"));
    const char* pos[3] = {"b_x", "b_y", "b_z"};
    const char* rn[3] = {"x", "y", "z"};
    for (int i = 0; i < 3; ++i) {
      GiNaC::ex row = c.parse(pos[i]);
      for (int j = 0; j < 3; ++j) row += R[static_cast<std::size_t>(3 * i + j)] * (*pivot)(j);
      c.add_row(rn[i], row);
    }
    b.system->add_constraint(sym::make_constraint(c));
  }
  return b;
}

// q̇ of the quaternion for a body angular velocity: ½ q ⊗ (0, ω).
Vec quat_rate(const Vec& q4, const Eigen::Vector3d& w) {
  const Eigen::Quaterniond q(q4(0), q4(1), q4(2), q4(3)), o(0, w(0), w(1), w(2));
  const Eigen::Quaterniond r = q * o;
  Vec v(4);
  v << 0.5 * r.w(), 0.5 * r.x(), 0.5 * r.y(), 0.5 * r.z();
  return v;
}

ukdyn::SimulationSettings tight(double t_end, double dt) {
  ukdyn::SimulationSettings s;
  s.t_end = t_end;
  s.sample_dt = dt;
  s.integrator = ukdyn::IntegratorKind::rkf78;
  s.abs_tol = 1e-14;
  s.rel_tol = 1e-14;
  return s;
}

}  // namespace

TEST(FreeBody, KineticEnergyIsThatOfOmegaFromR) {
  // T from the derived tape equals ½ ωᵀ J ω with ω = vee(Rᵀ Ṙ) by finite differences of R(q(t)).
  const Body b = free_body({1.0, 2.5, 3.5}, 2.0, 0.0);
  std::mt19937_64 rng(7);
  std::normal_distribution<double> nd;
  for (int trial = 0; trial < 20; ++trial) {
    Vec q(7), qd(7);
    for (int i = 0; i < 7; ++i) {
      q(i) = nd(rng);
      qd(i) = nd(rng);
    }
    q.tail(4).normalize();
    qd.tail(4) -= q.tail(4).dot(qd.tail(4)) * q.tail(4);  // tangent to |q| = 1
    const double h = 1e-6;
    auto R_at = [&](double s) {
      Vec qq = q.tail(4) + s * qd.tail(4);
      return rot(qq / qq.norm());
    };
    const Eigen::Matrix3d S = R_at(0).transpose() * (R_at(h) - R_at(-h)) / (2 * h);
    const Eigen::Vector3d w(S(2, 1), S(0, 2), S(1, 0));
    const double T = 0.5 * 2.0 * qd.head(3).squaredNorm() +
                     0.5 * (1.0 * w(0) * w(0) + 2.5 * w(1) * w(1) + 3.5 * w(2) * w(2));
    EXPECT_NEAR(b.sub->kinetic({}, q, qd), T, 1e-8 * T);
    EXPECT_LT((omega_body(q.tail(4), qd.tail(4)) - w).norm(), 1e-7);
  }
}

TEST(FreeBody, MassMatrixIsSingularAndTheAugmentedSolveIsUsed) {
  const Body b = free_body({1.0, 2.0, 3.0}, 1.0, 9.81);
  ForwardData d(*b.system);
  EXPECT_TRUE(d.singular.any_structural);
  Vec q(7), qd(7);
  q << 0.1, 0.2, 0.3, 0.5, 0.5, 0.5, 0.5;
  qd << 1, 0, 0, 0, 0.1, -0.2, 0.1;
  ukdyn::forward(*b.system, d, 0.0, q, qd, Vec::Zero(7));
  EXPECT_TRUE(d.result.finite);
  EXPECT_TRUE(d.singular.active);
  EXPECT_FALSE(d.singular.dense_used);  // the norm row lies in the body's own block
  // Translation: free fall.
  EXPECT_NEAR(d.qdd(0), 0.0, 1e-14);
  EXPECT_NEAR(d.qdd(2), -9.81, 1e-13);
  // Rotation: Euler's equations J ω̇ = (J ω) × ω against q̈ = ½ (q̇ ⊗ ω + q ⊗ ω̇).
  const Eigen::Vector3d J(1, 2, 3);
  const Eigen::Vector3d w = omega_body(q.tail(4), qd.tail(4));
  const Eigen::Vector3d wd = (J.cwiseProduct(w)).cross(w).cwiseQuotient(J);
  const Eigen::Quaterniond qq(q(3), q(4), q(5), q(6)), qqd(qd(3), qd(4), qd(5), qd(6));
  const Eigen::Quaterniond a = qqd * Eigen::Quaterniond(0, w(0), w(1), w(2));
  const Eigen::Quaterniond c = qq * Eigen::Quaterniond(0, wd(0), wd(1), wd(2));
  Vec expect(4);
  expect << 0.5 * (a.w() + c.w()), 0.5 * (a.x() + c.x()), 0.5 * (a.y() + c.y()),
      0.5 * (a.z() + c.z());
  EXPECT_LT((d.qdd.tail(4) - expect).norm(), 1e-13) << d.qdd.transpose();
}

namespace {
// Energy and world angular momentum R J ω of a torque-free body over a run.
struct Invariants {
  double E0 = 0, dE = 0, L0 = 0, dL = 0;
  Eigen::Vector3d Lw0;
};
bool track(Invariants& inv, bool first, CVecRef q, CVecRef qd) {
  const Eigen::Vector3d J(1, 2, 3);
  const Vec q4 = q.tail(4), qd4 = qd.tail(4);
  const Eigen::Vector3d w = omega_body(q4 / q4.norm(), qd4 / q4.norm());
  const double E = 0.5 * w.dot(J.cwiseProduct(w));
  const Eigen::Vector3d L = rot(q4 / q4.norm()) * J.cwiseProduct(w);
  if (first) {
    inv.E0 = E;
    inv.Lw0 = L;
    inv.L0 = L.norm();
  }
  inv.dE = std::max(inv.dE, std::abs(E - inv.E0) / inv.E0);
  inv.dL = std::max(inv.dL, (L - inv.Lw0).norm() / inv.L0);
  return true;
}
}  // namespace

TEST(FreeBody, TorqueFreeConservesEnergyAndWorldAngularMomentum) {
  const Body b = free_body({1.0, 2.0, 3.0}, 1.0, 0.0);
  Vec q0(7), qd0 = Vec::Zero(7);
  q0 << 0, 0, 0, std::cos(0.3), std::sin(0.3) / std::sqrt(2.0), 0, std::sin(0.3) / std::sqrt(2.0);
  qd0.tail(4) = quat_rate(q0.tail(4), Eigen::Vector3d(0.3, 2.0, -0.4));
  Invariants inv;
  bool first = true;
  const double t_end = 100.0;
  const auto st = ukdyn::simulate(*b.system, q0, qd0, nullptr, tight(t_end, 0.5),
                                  [&](double, CVecRef q, CVecRef qd, const ForwardData&) {
                                    track(inv, first, q, qd);
                                    first = false;
                                    return true;
                                  });
  ASSERT_EQ(st.status, ukdyn::RunStatus::completed) << st.message;
  EXPECT_LE(inv.dE, 1e-12);
  EXPECT_LE(inv.dL, 1e-12);
  std::printf("torque-free body, %g s, rkf78 1e-14: max |dE|/E = %.3g, max |dL|/|L| = %.3g\n",
              t_end, inv.dE, inv.dL);
}

TEST(FreeBody, DzhanibekovPeriodMatchesTheEllipticIntegral) {
  // Landau & Lifshitz Sec. 37 (I1 < I2 < I3, L² > 2 E I2): ω is periodic with
  // T = 4 K(k) / sqrt((I3 − I2)(L² − 2 E I1) / (I1 I2 I3)), k² = (I2 − I1)(2 E I3 − L²) /
  // ((I3 − I2)(L² − 2 E I1)); ω2 ∝ sn changes sign twice per period (the flips).
  const double I1 = 1, I2 = 2, I3 = 3;
  const Eigen::Vector3d w0(0.0, 2.0, 0.02);
  const double twoE = I1 * w0(0) * w0(0) + I2 * w0(1) * w0(1) + I3 * w0(2) * w0(2);
  const double L2 = I1 * I1 * w0(0) * w0(0) + I2 * I2 * w0(1) * w0(1) + I3 * I3 * w0(2) * w0(2);
  ASSERT_GT(L2, twoE * I2);
  const double k2 = (I2 - I1) * (twoE * I3 - L2) / ((I3 - I2) * (L2 - twoE * I1));
  const double rate = std::sqrt((I3 - I2) * (L2 - twoE * I1) / (I1 * I2 * I3));
  const double T = 4.0 * std::comp_ellint_1(std::sqrt(k2)) / rate;
  const Body b = free_body({I1, I2, I3}, 1.0, 0.0);
  Vec q0(7), qd0 = Vec::Zero(7);
  q0 << 0, 0, 0, 1, 0, 0, 0;
  qd0.tail(4) = quat_rate(q0.tail(4), w0);
  int flips = 0;
  double last = w0(1);
  Eigen::Vector3d wT;
  const auto st = ukdyn::simulate(*b.system, q0, qd0, nullptr, tight(T, T / 400),
                                  [&](double, CVecRef q, CVecRef qd, const ForwardData&) {
                                    const Eigen::Vector3d w = omega_body(q.tail(4), qd.tail(4));
                                    if (w(1) * last < 0) ++flips;
                                    last = w(1);
                                    wT = w;
                                    return true;
                                  });
  ASSERT_EQ(st.status, ukdyn::RunStatus::completed) << st.message;
  EXPECT_EQ(flips, 2);
  // ω(T) = ω(0); a period error δ shows as ω(T) − ω(0) ≈ ω̇ δ, ω̇(0) from Euler's equations.
  const Eigen::Vector3d J(I1, I2, I3);
  const Eigen::Vector3d wd0 = (J.cwiseProduct(w0)).cross(w0).cwiseQuotient(J);
  const double delta = (wT - w0).dot(wd0) / wd0.squaredNorm();
  const double off = (wT - w0 - wd0 * delta).norm();
  EXPECT_LE(std::abs(delta) / T, 1e-8) << "T = " << T;
  EXPECT_LE(off, 1e-8);
  std::printf("Dzhanibekov: T = %.12f s (K(k), k^2 = %.6g), period error %.3g relative\n", T, k2,
              std::abs(delta) / T);
}

TEST(FreeBody, HeavySymmetricTopPrecessesSteadily) {
  // Goldstein Sec. 5.7: a symmetric top (I1 = I2 about the CoM, I3), its tip held at the origin,
  // CoM at distance l on the axis; steady precession at tilt θ: m g l = φ̇ (I3 ω3 − I1' φ̇ cos θ),
  // I1' = I1 + m l². The axis keeps θ and turns about z at φ̇.
  const double m = 1.5, l = 0.4, g = 9.81, I1 = 0.02, I3 = 0.03, th = 0.6, w3 = 100.0;
  const double I1p = I1 + m * l * l;
  const double c = std::cos(th), s = std::sin(th);
  const double disc = I3 * I3 * w3 * w3 - 4.0 * I1p * m * g * l * c;
  const double phid = (I3 * w3 - std::sqrt(disc)) / (2.0 * I1p * c);  // the slow precession
  const Body b = free_body({I1, I1, I3}, m, g, Eigen::Vector3d(0, 0, -l));
  Vec q0(7), qd0(7);
  q0.tail(4) << std::cos(th / 2), std::sin(th / 2), 0, 0;  // the axis tilted about x
  const Eigen::Matrix3d R = rot(q0.tail(4));
  const Eigen::Vector3d e3 = R.col(2);  // (0, −sin θ, cos θ)
  q0.head(3) = l * e3;
  const double psid = w3 - phid * c;
  const Eigen::Vector3d w_world = phid * Eigen::Vector3d::UnitZ() + psid * e3;
  qd0.head(3) = w_world.cross(Eigen::Vector3d(q0.head(3)));
  qd0.tail(4) = quat_rate(q0.tail(4), R.transpose() * w_world);
  double err = 0.0;
  const auto st = ukdyn::simulate(*b.system, q0, qd0, nullptr, tight(5.0, 0.05),
                                  [&](double t, CVecRef q, CVecRef, const ForwardData&) {
                                    const Eigen::Vector3d axis = rot(q.tail(4)).col(2);
                                    const Eigen::Vector3d expect(s * std::sin(phid * t),
                                                                 -s * std::cos(phid * t), c);
                                    err = std::max(err, (axis - expect).norm());
                                    return true;
                                  });
  ASSERT_EQ(st.status, ukdyn::RunStatus::completed) << st.message;
  EXPECT_LE(err, 1e-9);
  std::printf("heavy top: precession %.9f rad/s, max axis error over 5 s %.3g\n", phid, err);
}

TEST(FreeBody, HeavyTopNutatesBetweenTheRootsOfTheEnergyCubic) {
  // Goldstein Sec. 5.7: with u = cos θ, the energy and the two momenta p_φ, p_ψ = I3 ω3 give
  // u̇² = f(u) = (1 − u²)(α − β u) − (b − a u)², a = I3 ω3 / I1', b = p_φ / I1', α = 2 E' / I1',
  // β = 2 m g l / I1', I1' = I1 + m l² (about the tip). Released at θ0 with θ̇ = φ̇ = 0:
  // b = a u0, α = β u0, so f(u) = (u0 − u)[β(1 − u²) − a²(u0 − u)] and θ nutates between θ0 and
  // the root u2 = (a² − sqrt(a⁴ − 4β(a² u0 − β))) / (2β) of the bracket.
  const double m = 1.5, l = 0.4, g = 9.81, I1 = 0.02, I3 = 0.03, th0 = 0.6, w3 = 100.0;
  const double I1p = I1 + m * l * l, u0 = std::cos(th0);
  const double a = I3 * w3 / I1p, beta = 2.0 * m * g * l / I1p;
  const double u2 = (a * a - std::sqrt(a * a * a * a - 4.0 * beta * (a * a * u0 - beta))) /
                    (2.0 * beta);
  ASSERT_GT(u2, -1.0);
  ASSERT_LT(u2, u0);
  const Body b = free_body({I1, I1, I3}, m, g, Eigen::Vector3d(0, 0, -l));
  Vec q0(7), qd0(7);
  q0.tail(4) << std::cos(th0 / 2), std::sin(th0 / 2), 0, 0;
  const Eigen::Matrix3d R = rot(q0.tail(4));
  q0.head(3) = l * R.col(2);
  const Eigen::Vector3d w_world = w3 * R.col(2);  // spin only: θ̇ = φ̇ = 0
  qd0.head(3) = w_world.cross(Eigen::Vector3d(q0.head(3)));
  qd0.tail(4) = quat_rate(q0.tail(4), R.transpose() * w_world);
  std::vector<double> u;
  double dpphi = 0, dppsi = 0;
  const double pphi0 = I3 * w3 * u0;
  const auto st = ukdyn::simulate(
      *b.system, q0, qd0, nullptr, tight(2.0, 0.001),
      [&](double, CVecRef q, CVecRef qd, const ForwardData&) {
        const Eigen::Matrix3d Rq = rot(q.tail(4));
        const Eigen::Vector3d w = omega_body(q.tail(4), qd.tail(4));
        u.push_back(Rq(2, 2));
        // p_ψ = I3 ω3 (body z); p_φ = L_z about the tip: (R J ω)_z + m (p × ṗ)_z.
        const Eigen::Vector3d J(I1, I1, I3);
        const Eigen::Vector3d p = q.head(3), pd = qd.head(3);
        const double pphi = (Rq * J.cwiseProduct(w))(2) + m * p.cross(pd)(2);
        dppsi = std::max(dppsi, std::abs(I3 * w(2) - I3 * w3) / (I3 * w3));
        dpphi = std::max(dpphi, std::abs(pphi - pphi0) / (I3 * w3));
        return true;
      });
  ASSERT_EQ(st.status, ukdyn::RunStatus::completed) << st.message;
  // Extremes of u between samples: a parabola through the three samples around each one.
  double umin = 1.0, umax = -1.0, below = 0.0, above = 0.0;
  for (std::size_t i = 1; i + 1 < u.size(); ++i) {
    below = std::max(below, u2 - u[i]);
    above = std::max(above, u[i] - u0);
    const bool lo = u[i] <= u[i - 1] && u[i] <= u[i + 1];
    const bool hi = u[i] >= u[i - 1] && u[i] >= u[i + 1];
    if (!lo && !hi) continue;
    const double c2 = 0.5 * (u[i + 1] - 2 * u[i] + u[i - 1]), c1 = 0.5 * (u[i + 1] - u[i - 1]);
    const double ext = std::abs(c2) > 0 ? u[i] - c1 * c1 / (4 * c2) : u[i];
    if (lo) umin = std::min(umin, ext);
    if (hi && i > 5) umax = std::max(umax, ext);
  }
  std::printf(
      "heavy top nutation: theta in [%.10f, %.10f] rad, closed form [%.10f, %.10f]; "
      "|p_phi|, |p_psi| drift %.3g, %.3g\n",
      std::acos(umax), std::acos(umin), th0, std::acos(u2), dpphi, dppsi);
  EXPECT_NEAR(umin, u2, 1e-8);
  EXPECT_NEAR(umax, u0, 1e-8);
  EXPECT_LE(below, 1e-10);  // never outside the bounds
  EXPECT_LE(above, 1e-10);
  EXPECT_LE(dpphi, 1e-11);
  EXPECT_LE(dppsi, 1e-11);
}

namespace {
// An Euler-angle body (Z-Y-X: R = Rz(yaw) Ry(pitch) Rx(roll)), ω_body from the angle rates; M is
// singular at pitch = ±π/2 (gimbal lock): its rotational block has det ∝ cos² pitch.
std::shared_ptr<System> euler_body() {
  sym::SubsystemDef d("euler", {"yaw", "pitch", "roll"});
  auto& b = d.add_body("body");
  b.mass = 1;
  b.com = {0, 0, 0};
  b.rotation = std::array<GiNaC::ex, 9>{
      d.parse("cos(yaw)*cos(pitch)"),
      d.parse("cos(yaw)*sin(pitch)*sin(roll) - sin(yaw)*cos(roll)"),
      d.parse("cos(yaw)*sin(pitch)*cos(roll) + sin(yaw)*sin(roll)"),
      d.parse("sin(yaw)*cos(pitch)"),
      d.parse("sin(yaw)*sin(pitch)*sin(roll) + cos(yaw)*cos(roll)"),
      d.parse("sin(yaw)*sin(pitch)*cos(roll) - cos(yaw)*sin(roll)"),
      d.parse("-sin(pitch)"),
      d.parse("cos(pitch)*sin(roll)"),
      d.parse("cos(pitch)*cos(roll)")};
  // ω_body of Z-Y-X angles: [ṙ − ẏ sin p, ṗ cos r + ẏ cos p sin r, −ṗ sin r + ẏ cos p cos r].
  b.angular_velocity = std::array<GiNaC::ex, 3>{
      d.parse("roll_dot - yaw_dot*sin(pitch)"),
      d.parse("pitch_dot*cos(roll) + yaw_dot*cos(pitch)*sin(roll)"),
      d.parse("-pitch_dot*sin(roll) + yaw_dot*cos(pitch)*cos(roll)")};
  b.inertia_kind = sym::BodyDef::InertiaKind::tensor;
  b.inertia_tensor = {1, 0, 0, 0, 2, 0, 0, 0, 3};
  b.inertia_frame = sym::Frame::body;
  auto sys = std::make_shared<System>();
  sys->add_subsystem(sym::make_subsystem(d));
  return sys;
}
}  // namespace

TEST(SingularMass, GimbalLockIsWarnedBeforeTheSolveBreaks) {
  // Along pitch → π/2 the condition estimate passes kMassConditionWarning (1e8) at a distance
  // from the lock where q̈ is still finite and accurate; the solve gives up only much closer.
  const auto sys = euler_body();
  ForwardData d(*sys);
  double warn_at = -1, break_at = -1;
  for (int k = 1; k <= 14; ++k) {
    const double eps = std::pow(10.0, -0.5 * k);  // π/2 − pitch
    Vec q(3), qd(3);
    q << 0.3, std::numbers::pi / 2 - eps, 0.2;
    qd << 0.0, 0.5, 0.0;  // a pure pitch rate: the exact motion stays regular
    ukdyn::forward(*sys, d, 0.0, q, qd, Vec::Zero(3));
    const double cond = ukdyn::mass_condition(d);
    if (warn_at < 0 && cond > ukdyn::kMassConditionWarning) warn_at = eps;
    const bool ok = d.result.finite && !d.singular.active;
    if (break_at < 0 && !ok) break_at = eps;
  }
  std::printf("Euler angles: warned at pi/2 - pitch = %.3g, solve leaves the fast path at %.3g\n",
              warn_at, break_at);
  ASSERT_GT(warn_at, 0);
  EXPECT_TRUE(break_at < 0 || warn_at > 10 * break_at);
  // A run heading into the lock (pitch rate π/2 rad/s, lock at t = 1 s) ending 3e-5 s before it:
  // the warning names the subsystem.
  ukdyn::SimulationSettings s = tight(1.0 - 3e-5, (1.0 - 3e-5) / 100);
  Vec q0(3), qd0(3);
  q0 << 0.0, 0.0, 0.0;
  qd0 << 0.0, std::numbers::pi / 2, 0.0;
  const auto st = ukdyn::simulate(*sys, q0, qd0, nullptr, s,
                                  [&](double, CVecRef, CVecRef, const ForwardData&) { return true; });
  bool warned = false;
  for (const auto& w : st.warnings) {
    if (w.kind == "ill_conditioned_mass") {
      warned = true;
      EXPECT_NE(w.message.find("'euler'"), std::string::npos) << w.message;
    }
  }
  EXPECT_TRUE(warned) << "no ill_conditioned_mass warning; status " << st.message;
}

namespace {
// A pendulum: a massless rod (angle th) and a point mass m at (x, z), held together by
// x − l sin th = 0, z + l cos th = 0. M = diag(0, m, m) is singular; [M; A] has full rank.
// split: the rod and the mass as two subsystems (the rows couple blocks: the dense fallback).
std::shared_ptr<System> massless_rod_pendulum(bool split, double l, double m, double g) {
  auto sys = std::make_shared<System>();
  const std::vector<std::string> all{"th", "x", "z"};
  if (split) {
    sym::SubsystemDef rod("rod", {"th"});
    rod.add_body("rod").com = {rod.parse("sin(th)"), 0, rod.parse("-cos(th)")};  // mass 0
    sys->add_subsystem(sym::make_subsystem(rod));
    sym::SubsystemDef bob("bob", {"x", "z"});
    auto& p = bob.add_body("bob");
    p.mass = bob.parameter("m", m);
    p.com = {bob.parse("x"), 0, bob.parse("z")};
    bob.gravity = {0, 0, sym::exact_rational(-g)};
    sys->add_subsystem(sym::make_subsystem(bob));
  } else {
    sym::SubsystemDef d("pendulum", all);
    d.add_body("rod").com = {d.parse("sin(th)"), 0, d.parse("-cos(th)")};  // mass 0
    auto& p = d.add_body("bob");
    p.mass = d.parameter("m", m);
    p.com = {d.parse("x"), 0, d.parse("z")};
    d.gravity = {0, 0, sym::exact_rational(-g)};
    sys->add_subsystem(sym::make_subsystem(d));
  }
  sym::ConstraintDef c("rod", sym::ConstraintDef::Kind::holonomic, all);
  const GiNaC::ex L = c.parameter("l", l);
  c.add_row("x", c.parse("x") - L * GiNaC::sin(c.parse("th")));
  c.add_row("z", c.parse("z") + L * GiNaC::cos(c.parse("th")));
  sys->add_constraint(sym::make_constraint(c));
  return sys;
}
}  // namespace

TEST(SingularMass, MasslessRodPendulumMatchesTheAnalyticSolution) {
  const double l = 0.8, m = 1.3, g = 9.81;
  for (bool split : {false, true}) {
    const auto sys = massless_rod_pendulum(split, l, m, g);
    ForwardData d(*sys);
    std::mt19937_64 rng(3);
    std::uniform_real_distribution<double> u(-2.5, 2.5);
    for (int trial = 0; trial < 50; ++trial) {
      const double th = u(rng), thd = u(rng);
      Vec q(3), qd(3);
      q << th, l * std::sin(th), -l * std::cos(th);
      qd << thd, l * std::cos(th) * thd, l * std::sin(th) * thd;
      ukdyn::forward(*sys, d, 0.0, q, qd, Vec::Zero(3));
      ASSERT_TRUE(d.result.finite);
      EXPECT_EQ(d.singular.dense_used, split);
      const double thdd = -g / l * std::sin(th);
      EXPECT_NEAR(d.qdd(0), thdd, 1e-12 * (1 + std::abs(thdd)));
      EXPECT_NEAR(d.qdd(1), l * (std::cos(th) * thdd - std::sin(th) * thd * thd), 1e-11);
      EXPECT_NEAR(d.qdd(2), l * (std::sin(th) * thdd + std::cos(th) * thd * thd), 1e-11);
      // The rod's tension on the mass: Qc = M q̈ − Q (Q = −G = (0, 0, −m g)).
      EXPECT_NEAR(d.Qc(2), m * d.qdd(2) + m * g, 1e-10);
    }
    // Released at 1 rad from rest: back at rest at the other side after half the period
    // T = 4 K(sin(θ0/2)) sqrt(l/g).
    const double th0 = 1.0;
    const double T = 4.0 * std::comp_ellint_1(std::sin(th0 / 2)) * std::sqrt(l / g);
    Vec q0(3);
    q0 << th0, l * std::sin(th0), -l * std::cos(th0);
    Vec q_end;
    const auto st = ukdyn::simulate(*sys, q0, Vec::Zero(3), nullptr, tight(T / 2, T / 2),
                                    [&](double, CVecRef q, CVecRef, const ForwardData&) {
                                      q_end = q;
                                      return true;
                                    });
    ASSERT_EQ(st.status, ukdyn::RunStatus::completed) << st.message;
    EXPECT_NEAR(q_end(0), -th0, 1e-10) << (split ? "split" : "one subsystem");
  }
}

TEST(SingularMass, UndeterminedDirectionIsNamed) {
  // Without the z row the rod angle is still fixed by x (except where cos th = 0); without both
  // rows nothing fixes th.
  sym::SubsystemDef d("p", {"th", "x"});
  d.add_body("rod").com = {d.parse("sin(th)"), 0, 0};  // massless
  auto& p = d.add_body("bob");
  p.mass = 1;
  p.com = {d.parse("x"), 0, 0};
  System sys;
  sys.add_subsystem(sym::make_subsystem(d));
  ForwardData data(sys);
  Vec q(2), qd = Vec::Zero(2);
  q << 0.3, 0.1;
  ukdyn::forward(sys, data, 0.0, q, qd, Vec::Zero(2));
  EXPECT_FALSE(data.result.finite);
  EXPECT_TRUE(data.singular.rank_deficient);
  const std::string why = ukdyn::undetermined_direction(data.M, data.A, sys.coordinate_names());
  EXPECT_NE(why.find("[th]"), std::string::npos) << why;
}

#ifdef UKDYN_HAVE_IO
TEST(SingularMass, BothPathsAgreeOnPositiveDefiniteSystems) {
  // Every block forced through the augmented solve (rows inside a block: the block path; rows
  // across blocks: the dense fallback) against the positive-definite fast path.
  for (const char* file :
       {"paper.yaml", "rolling_disk.yaml", "five_bar_redundant.yaml", "paper_generic.yaml"}) {
    const auto sc = ukdyn::load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/" + file);
    const System& sys = *sc.system;
    const Index n = sys.dof();
    ForwardData fast(sys), forced(sys);
    ASSERT_FALSE(fast.singular.any_structural) << file;
    std::fill(forced.singular.structural.begin(), forced.singular.structural.end(), 1);
    forced.singular.any_structural = true;
    std::mt19937_64 rng(11);
    std::uniform_real_distribution<double> u(-0.3, 0.3);
    double worst = 0.0;
    for (int trial = 0; trial < 20; ++trial) {
      Vec q = sc.q0, qd = sc.qd0;
      for (Index i = 0; i < n; ++i) {
        q(i) += u(rng);
        qd(i) += u(rng);
      }
      ukdyn::forward(sys, fast, 0.0, q, qd, Vec::Zero(n));
      ukdyn::forward(sys, forced, 0.0, q, qd, Vec::Zero(n));
      ASSERT_TRUE(forced.singular.active);
      ASSERT_FALSE(fast.singular.active);
      // (A consistent row set: the identity M_a q̈ = Q_a + Qc holds; a redundant inconsistent set
      // would differ, so only consistent states count.)
      if (!fast.result.consistent) continue;
      const double sq = (fast.qdd - forced.qdd).norm() / (1.0 + fast.qdd.norm());
      const double sc_ = (fast.Qc - forced.Qc).norm() / (1.0 + fast.Qc.norm());
      worst = std::max({worst, sq, sc_});
    }
    EXPECT_LE(worst, 1e-12) << file;
    std::printf("%s: fast vs augmented path, max relative difference %.3g\n", file, worst);
  }
}

TEST(FreeBody, ScenarioLoadsWithItsNormRow) {
  const auto sc =
      ukdyn::load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/free_body_dzhanibekov.yaml");
  EXPECT_EQ(sc.system->dof(), 7);
  EXPECT_EQ(sc.system->rows(), 1);
  EXPECT_EQ(sc.system->constraint_row_names()[0], "body_unit");
  EXPECT_EQ(sc.system->coordinate_names()[3], "body_qw");
}

TEST(SingularMass, ScenarioWithAnUnfixedMasslessCoordinateIsRefused) {
  const std::string text = R"(ukdyn: 1
name: s
subsystems:
  - name: p
    type: definitions
    coordinates: [th, x]
    bodies:
      - {name: rod, mass: 0, com: [sin(th), 0, 0]}
      - {name: bob, mass: 1, com: [x, 0, 0]}
initial:
  q: [0.3, 0.1]
simulation: {t_end: 1, sample_dt: 0.1}
)";
  try {
    (void)ukdyn::load_scenario_text(text, "s.yaml");
    FAIL() << "accepted";
  } catch (const std::exception& e) {
    const std::string w = e.what();
    EXPECT_NE(w.find("not positive definite"), std::string::npos) << w;
    EXPECT_NE(w.find("[th]"), std::string::npos) << w;
  }
}
#endif
