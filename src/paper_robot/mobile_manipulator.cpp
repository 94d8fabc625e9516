#include "ukdyn/paper_robot/mobile_manipulator.hpp"

#include <bit>
#include <cmath>
#include <cstdint>
#include <sstream>
#include <unsupported/Eigen/AutoDiff>

namespace ukdyn {

namespace {

// ---- sin/cos of the four angles (δ, θ1, θ2, θ3), shared between dynamics() and the cut-point
// kinematics of the constraints through this arm's data slot in ForwardData.
//
// forward() evaluates every arm's M, C q̇, G (dynamics()) and then the constraints, whose
// cut-point Jacobians need the sin/cos of the same four angles of the same arms. dynamics()
// computes them and records them in the arm's slot, next to the exact bit patterns of the angles;
// kinematics() and cut_point() given that slot use it when the angles match and call sin/cos
// otherwise. A hit returns bit-identical results to a recomputation: the slot changes the cost,
// never a value, and a slot left from another state (or none) is only slower. The slot is
// caller-owned (one per ForwardData): no sharing between threads, no hidden order of calls.
template <class T>
struct AngleSinCosT {
  std::array<T, 4> cos{}, sin{};  // [δ, θ1, θ2, θ3]
};
using AngleSinCos = AngleSinCosT<double>;

// Slot layout (MobileManipulator::kSlotSize = 13): [0] 1 when filled, [1..4] the angles,
// [5..8] their cos, [9..12] their sin.
constexpr std::size_t kFilled = 0, kAngles = 1, kCos = 5, kSin = 9;

// V: CVecRef (doubles) or a fixed-size vector of dual numbers; cos/sin found by ADL for the duals.
template <class T, class V>
AngleSinCosT<T> compute_angles(const V& q) {
  using std::cos;
  using std::sin;
  AngleSinCosT<T> a;
  for (int j = 0; j < 4; ++j) {
    const auto u = static_cast<std::size_t>(j);
    a.cos[u] = cos(q(2 + j));
    a.sin[u] = sin(q(2 + j));
  }
  return a;
}

void record_angles(Slot slot, CVecRef q, const AngleSinCos& a) {
  if (slot.size() != static_cast<std::size_t>(MobileManipulator::kSlotSize)) return;
  for (std::size_t j = 0; j < 4; ++j) {
    slot[kAngles + j] = q(2 + static_cast<Index>(j));
    slot[kCos + j] = a.cos[j];
    slot[kSin + j] = a.sin[j];
  }
  slot[kFilled] = 1.0;
}

// The recorded values when the slot holds these exact angles (bit for bit), else computes them.
AngleSinCos lookup_angles(CVecRef q, ConstSlot slot) {
  if (slot.size() == static_cast<std::size_t>(MobileManipulator::kSlotSize) &&
      slot[kFilled] == 1.0) {
    bool same = true;
    for (std::size_t j = 0; j < 4; ++j) {
      same = same && std::bit_cast<std::uint64_t>(slot[kAngles + j]) ==
                         std::bit_cast<std::uint64_t>(q(2 + static_cast<Index>(j)));
    }
    if (same) {
      AngleSinCos a;
      for (std::size_t j = 0; j < 4; ++j) {
        a.cos[j] = slot[kCos + j];
        a.sin[j] = slot[kSin + j];
      }
      return a;
    }
  }
  return compute_angles<double>(q);
}

void require(bool ok, const std::string& where, const std::string& key, const std::string& what) {
  if (!ok) throw Error(where + ": " + key + " " + what);
}
}  // namespace

void MobileManipulatorParams::validate(const std::string& where) const {
  auto finite_nonneg = [&](double v, const std::string& key) {
    require(std::isfinite(v), where, key, "must be a finite number");
    require(v >= 0.0, where, key, "must be >= 0 (got " + std::to_string(v) + ")");
  };
  finite_nonneg(platform_mass, "platform_mass");
  finite_nonneg(base_mass, "base_mass");
  finite_nonneg(base_inertia, "base_inertia");
  finite_nonneg(base_length, "base_length");
  double total = platform_mass + base_mass;
  for (std::size_t k = 0; k < 3; ++k) {
    const std::string idx = "[" + std::to_string(k) + "]";
    finite_nonneg(link_mass[k], "link_mass" + idx);
    finite_nonneg(link_inertia[k], "link_inertia" + idx);
    finite_nonneg(link_length[k], "link_length" + idx);
    require(link_length[k] > 0.0, where, "link_length" + idx, "must be > 0");
    total += link_mass[k];
  }
  require(total > 0.0, where, "masses", "must not all be zero (M would be singular)");
  require(std::isfinite(gravity), where, "gravity", "must be a finite number");
}

MobileManipulator::MobileManipulator(std::string name, MobileManipulatorParams params,
                                     std::vector<std::string> coordinate_names)
    : name_(std::move(name)), p_(params), names_(std::move(coordinate_names)) {
  p_.validate(name_);
  if (names_.size() != 6) {
    throw Error(name_ + ": a mobile manipulator has 6 coordinates, got " +
                std::to_string(names_.size()) + " names");
  }
  const auto& m = p_.link_mass;
  a_ = {m[0] / 2 + m[1] + m[2], m[1] / 2 + m[2], m[2] / 2};
}

namespace {

// ---- The closed forms, templated on the scalar T: double for the evaluation, Dual for the exact
// tangents. A Dual carries a value and one directional derivative; every arithmetic operation and
// sin/cos applies its derivative rule, so evaluating an expression on Duals seeded with (x, dx)
// gives its value and its exact directional derivative along dx (forward-mode automatic
// differentiation, Griewank & Walther, Evaluating Derivatives, SIAM 2008, ch. 3). The derivative
// part is a fixed-size 1-vector: no heap allocation.
using Dual = Eigen::AutoDiffScalar<Eigen::Matrix<double, 1, 1>>;
using DualVec6 = Eigen::Matrix<Dual, 6, 1>;

Dual seed(double value, double direction) {
  return Dual(value, Eigen::Matrix<double, 1, 1>(direction));
}

double tangent_of(const Dual& x) { return x.derivatives()(0); }

DualVec6 seed6(CVecRef x, CVecRef dx) {
  DualVec6 out;
  for (Index i = 0; i < 6; ++i) out(i) = seed(x(i), dx(i));
  return out;
}

// The sin/cos every closed-form expression below uses, evaluated once per state: δ and θ1..θ3
// directly, θi − θj by
//   cos(a − b) = cos a cos b + sin a sin b,  sin(a − b) = sin a cos b − cos a sin b.
template <class T>
struct Trig {
  T cd = T(1), sd = T(0);   // cos δ, sin δ
  std::array<T, 3> ct, st;  // cos θk, sin θk
  std::array<T, 3> c, s;    // ĉk = lk cos θk, ŝk = lk sin θk
  T c12, c13, c23;          // cos(θ1 − θ2), cos(θ1 − θ3), cos(θ2 − θ3)
  T s12, s13, s23;          // sin(θ1 − θ2), sin(θ1 − θ3), sin(θ2 − θ3)
};

template <class T>
Trig<T> trig_from(const MobileManipulatorParams& p, const AngleSinCosT<T>& a) {
  Trig<T> t;
  t.cd = a.cos[0];
  t.sd = a.sin[0];
  for (std::size_t u = 0; u < 3; ++u) {
    t.ct[u] = a.cos[u + 1];
    t.st[u] = a.sin[u + 1];
    // ĉ_j = l_j cos θ_j (the paper prints cos δ_j: erratum 1), ŝ_j = l_j sin θ_j.
    t.c[u] = p.link_length[u] * t.ct[u];
    t.s[u] = p.link_length[u] * t.st[u];
  }
  // cos/sin(θi − θj) by the angle-difference identities (no further trig calls).
  t.c12 = t.ct[0] * t.ct[1] + t.st[0] * t.st[1];
  t.c13 = t.ct[0] * t.ct[2] + t.st[0] * t.st[2];
  t.c23 = t.ct[1] * t.ct[2] + t.st[1] * t.st[2];
  t.s12 = t.st[0] * t.ct[1] - t.ct[0] * t.st[1];
  t.s13 = t.st[0] * t.ct[2] - t.ct[0] * t.st[2];
  t.s23 = t.st[1] * t.ct[2] - t.ct[1] * t.st[2];
  return t;
}

// ĉ, ŝ, κ̂, ρ̂, ζ̂, ψ̂, γ̂ (paper notation below Eq. (13)) from the angles' sin/cos and q̇.
template <class T, class V>
ArmKinematicsT<T> kinematics_from(const MobileManipulatorParams& p, const AngleSinCosT<T>& a,
                                  const V& qd) {
  ArmKinematicsT<T> k;
  k.cos_delta = a.cos[0];
  k.sin_delta = a.sin[0];
  T sum_s_thd(0.0);
  for (int j = 0; j < 3; ++j) {
    const auto u = static_cast<std::size_t>(j);
    // ĉ_j = l_j cos θ_j (the paper prints cos δ_j: erratum 1), ŝ_j = l_j sin θ_j.
    k.c[u] = p.link_length[u] * a.cos[u + 1];
    k.s[u] = p.link_length[u] * a.sin[u + 1];
    const T thd = qd(3 + j);
    k.kappa += k.c[u];
    k.rho += k.s[u];
    sum_s_thd += k.s[u] * thd;
    k.psi += k.c[u] * thd * thd;
    k.gamma += k.s[u] * thd * thd;
  }
  k.zeta = sum_s_thd * qd(2);
  return k;
}

// J and c of MobileManipulator::cut_point_jacobian from the kinematics and δ̇.
template <class T, class MJ, class VC>
void cut_point_jacobian_from(const ArmKinematicsT<T>& k, const T& dd, MJ& J, VC& c) {
  // Rows of paper Eq. (15) for one arm: ∂(Δx + κ̂ cos δ, Δy + κ̂ sin δ, l_r + ρ̂)/∂q. Every entry
  // is written (no setZero pass).
  J(0, 0) = 1.0;
  J(1, 0) = 0.0;
  J(2, 0) = 0.0;
  J(0, 1) = 0.0;
  J(1, 1) = 1.0;
  J(2, 1) = 0.0;
  J(0, 2) = -k.kappa * k.sin_delta;
  J(1, 2) = k.kappa * k.cos_delta;
  J(2, 2) = 0.0;
  for (int j = 0; j < 3; ++j) {
    const auto u = static_cast<std::size_t>(j);
    J(0, 3 + j) = -k.s[u] * k.cos_delta;
    J(1, 3 + j) = -k.s[u] * k.sin_delta;
    J(2, 3 + j) = k.c[u];
  }
  // Velocity-product terms of Eq. (13) (moved to b in Eq. (16)).
  const T radial = k.psi + k.kappa * dd * dd;
  c(0) = -radial * k.cos_delta + 2.0 * k.zeta * k.sin_delta;
  c(1) = -radial * k.sin_delta - 2.0 * k.zeta * k.cos_delta;
  c(2) = -k.gamma;
}

// Mass matrix, paper appendix (Eq. (5) evaluated), with the printed typos corrected. a: the mass
// sums a_1 = m1/2 + m2 + m3, a_2 = m2/2 + m3, a_3 = m3/2.
template <class T, class MM>
void mass_from(const MobileManipulatorParams& p, const std::array<double, 3>& a, const Trig<T>& t,
               MM& M) {
  const auto& m = p.link_mass;
  const auto& I = p.link_inertia;
  const auto& l = p.link_length;
  const T &cd = t.cd, &sd = t.sd;
  const T &c1 = t.c[0], &c2 = t.c[1], &c3 = t.c[2];
  const T &s1 = t.s[0], &s2 = t.s[1], &s3 = t.s[2];
  // K = a1 ĉ1 + a2 ĉ2 + a3 ĉ3: first moment of the arm's mass about the yaw axis.
  const T K = a[0] * c1 + a[1] * c2 + a[2] * c3;
  const T r1 = c1 / 2.0, r2 = c1 + c2 / 2.0, r3 = c1 + c2 + c3 / 2.0;  // CoM radii

  M(0, 0) = M(1, 1) = p.platform_mass + p.base_mass + m[0] + m[1] + m[2];
  M(0, 1) = M(1, 0) = 0.0;
  // M33: the paper prints m1 ĉ1/4; the square is missing (erratum 3).
  M(2, 2) = m[0] * r1 * r1 + m[1] * r2 * r2 + m[2] * r3 * r3 + I[0] + I[1] + I[2] + p.base_inertia;
  M(3, 3) = (m[0] / 4 + m[1] + m[2]) * l[0] * l[0] + I[0];
  M(4, 4) = (m[1] / 4 + m[2]) * l[1] * l[1] + I[1];
  M(5, 5) = m[2] * l[2] * l[2] / 4 + I[2];
  M(0, 2) = M(2, 0) = -K * sd;
  M(1, 2) = M(2, 1) = K * cd;
  M(0, 3) = M(3, 0) = -a[0] * s1 * cd;
  M(1, 3) = M(3, 1) = -a[0] * s1 * sd;
  M(0, 4) = M(4, 0) = -a[1] * s2 * cd;
  M(1, 4) = M(4, 1) = -a[1] * s2 * sd;
  M(0, 5) = M(5, 0) = -a[2] * s3 * cd;
  M(1, 5) = M(5, 1) = -a[2] * s3 * sd;
  // The yaw row has no coupling to the pitches: M34 = M35 = M36 = 0.
  M(2, 3) = M(3, 2) = 0.0;
  M(2, 4) = M(4, 2) = 0.0;
  M(2, 5) = M(5, 2) = 0.0;
  // M45: the paper prints (m2 + m3)/2 · l1 l2 cos(θ1 − θ2); correct is (m2/2 + m3) (erratum 4).
  M(3, 4) = M(4, 3) = a[1] * l[0] * l[1] * t.c12;
  M(3, 5) = M(5, 3) = a[2] * l[0] * l[2] * t.c13;
  M(4, 5) = M(5, 4) = a[2] * l[1] * l[2] * t.c23;
}

// Coriolis matrix from the Christoffel symbols, paper Eq. (9) / appendix, corrected (double only:
// the tangent differentiates C q̇, below).
void coriolis_from(const MobileManipulatorParams& p, const std::array<double, 3>& a,
                   const Trig<double>& t, CVecRef qd, MatRef C) {
  const auto& m = p.link_mass;
  const auto& l = p.link_length;
  const double cd = t.cd, sd = t.sd;
  const double c1 = t.c[0], c2 = t.c[1], c3 = t.c[2];
  const double s1 = t.s[0], s2 = t.s[1], s3 = t.s[2];
  const double dd = qd(2), t1 = qd(3), t2 = qd(4), t3 = qd(5);
  const double K = a[0] * c1 + a[1] * c2 + a[2] * c3;
  const double S = a[0] * s1 * t1 + a[1] * s2 * t2 + a[2] * s3 * t3;
  const double r2 = c1 + c2 / 2, r3 = c1 + c2 + c3 / 2;

  C.setZero();
  // C13: the operator between the two brackets is lost in print; it is "−" (erratum 6).
  C(0, 2) = S * sd - K * cd * dd;
  C(0, 3) = a[0] * (s1 * sd * dd - c1 * cd * t1);
  C(0, 4) = a[1] * (s2 * sd * dd - c2 * cd * t2);
  C(0, 5) = a[2] * (s3 * sd * dd - c3 * cd * t3);
  C(1, 2) = -S * cd - K * sd * dd;
  C(1, 3) = -a[0] * (s1 * cd * dd + c1 * sd * t1);
  C(1, 4) = -a[1] * (s2 * cd * dd + c2 * sd * t2);
  C(1, 5) = -a[2] * (s3 * cd * dd + c3 * sd * t3);
  C(2, 2) = -m[0] / 4 * c1 * s1 * t1 - m[1] / 2 * r2 * (2 * s1 * t1 + s2 * t2) -
            m[2] / 2 * r3 * (2 * s1 * t1 + 2 * s2 * t2 + s3 * t3);
  // C34, C43: the paper prints m1 ĉ1/2; the Christoffel symbol gives m1 ĉ1/4 (erratum 5, a real
  // error that changes C q̇ although Ṁ − 2C stays skew-symmetric with it).
  const double k1 = (m[0] * c1 / 4 + m[1] * r2 + m[2] * r3) * s1 * dd;
  const double k2 = (m[1] / 2 * r2 + m[2] * r3) * s2 * dd;
  const double k3 = m[2] / 2 * r3 * s3 * dd;
  C(2, 3) = -k1;
  C(2, 4) = -k2;
  C(2, 5) = -k3;
  C(3, 2) = k1;
  C(4, 2) = k2;
  C(5, 2) = k3;
  // sin(θi − θj) = −sin(θj − θi).
  C(3, 4) = a[1] * l[0] * l[1] * t.s12 * t2;
  C(3, 5) = a[2] * l[0] * l[2] * t.s13 * t3;
  C(4, 3) = -a[1] * l[0] * l[1] * t.s12 * t1;
  C(4, 5) = a[2] * l[1] * l[2] * t.s23 * t3;
  C(5, 3) = -a[2] * l[0] * l[2] * t.s13 * t1;
  C(5, 4) = -a[2] * l[1] * l[2] * t.s23 * t2;
}

// C(q, q̇) q̇ expanded from the entries of coriolis_from (same corrected appendix, errata 5 and 6),
// without forming C:
//   rows 1, 2: the yaw-row products collapse to ±2 S δ̇ (sin δ, cos δ) − (K δ̇² + Σ a_k ĉ_k θ̇_k²)(cos δ,
//              sin δ) with S = Σ a_k ŝ_k θ̇_k (C13 with the "−" of erratum 6);
//   row 3:     C33 δ̇ − Σ k_j θ̇_j = 2 C33 δ̇, because Σ k_j θ̇_j = −C33 δ̇ (C34..C36 = −k_j);
//   rows 4–6:  k_j δ̇ + Σ_{i≠j} a_{max(i,j)} l_i l_j sin(θ_j − θ_i) θ̇_i² (k1 with m1 ĉ1/4, erratum 5).
template <class T, class V, class VC>
void coriolis_times_qd_from(const MobileManipulatorParams& p, const std::array<double, 3>& a,
                            const Trig<T>& t, const V& qd, VC& Cqd) {
  const auto& m = p.link_mass;
  const auto& l = p.link_length;
  const T &cd = t.cd, &sd = t.sd;
  const T &c1 = t.c[0], &c2 = t.c[1], &c3 = t.c[2];
  const T &s1 = t.s[0], &s2 = t.s[1], &s3 = t.s[2];
  const T dd = qd(2), t1 = qd(3), t2 = qd(4), t3 = qd(5);
  const T K = a[0] * c1 + a[1] * c2 + a[2] * c3;
  const T S = a[0] * s1 * t1 + a[1] * s2 * t2 + a[2] * s3 * t3;
  const T P = a[0] * c1 * t1 * t1 + a[1] * c2 * t2 * t2 + a[2] * c3 * t3 * t3;
  const T r2 = c1 + c2 / 2.0, r3 = c1 + c2 + c3 / 2.0;

  const T radial = K * dd * dd + P;
  Cqd(0) = 2.0 * S * sd * dd - radial * cd;
  Cqd(1) = -2.0 * S * cd * dd - radial * sd;
  const T C33 = -m[0] / 4 * c1 * s1 * t1 - m[1] / 2 * r2 * (2.0 * s1 * t1 + s2 * t2) -
                m[2] / 2 * r3 * (2.0 * s1 * t1 + 2.0 * s2 * t2 + s3 * t3);
  Cqd(2) = 2.0 * C33 * dd;
  // k_j as in coriolis_from (C43 with m1 ĉ1/4: erratum 5).
  const T k1 = (m[0] * c1 / 4.0 + m[1] * r2 + m[2] * r3) * s1 * dd;
  const T k2 = (m[1] / 2 * r2 + m[2] * r3) * s2 * dd;
  const T k3 = m[2] / 2 * r3 * s3 * dd;
  const T e12 = a[1] * l[0] * l[1] * t.s12;  // C45 / θ̇2 = −C54 / θ̇1
  const T e13 = a[2] * l[0] * l[2] * t.s13;  // C46 / θ̇3 = −C64 / θ̇1
  const T e23 = a[2] * l[1] * l[2] * t.s23;  // C56 / θ̇3 = −C65 / θ̇2
  const T t1s = t1 * t1, t2s = t2 * t2, t3s = t3 * t3;
  Cqd(3) = k1 * dd + e12 * t2s + e13 * t3s;
  Cqd(4) = k2 * dd - e12 * t1s + e23 * t3s;
  Cqd(5) = k3 * dd - e13 * t1s - e23 * t2s;
}

// G = ∂V/∂q, paper appendix (Eq. (8) with gravity along −Z, erratum 7), from ĉ1..ĉ3 (the only
// trig G needs).
template <class T, class VG>
void gravity_from(const MobileManipulatorParams& p, const std::array<double, 3>& a,
                  const std::array<T, 3>& c, VG& G) {
  const double g = p.gravity;
  G(0) = G(1) = G(2) = 0.0;
  G(3) = a[0] * g * c[0];
  G(4) = a[1] * g * c[1];
  G(5) = a[2] * g * c[2];
}

}  // namespace

ArmKinematics MobileManipulator::kinematics(CVecRef q, CVecRef qd, ConstSlot slot) const {
  return kinematics_from(p_, lookup_angles(q, slot), qd);
}

Vec3 MobileManipulator::cut_point(CVecRef q, ConstSlot slot) const {
  const AngleSinCos a = lookup_angles(q, slot);
  double kappa = 0.0, rho = 0.0;
  for (int j = 0; j < 3; ++j) {
    const auto u = static_cast<std::size_t>(j);
    kappa += p_.link_length[u] * a.cos[u + 1];
    rho += p_.link_length[u] * a.sin[u + 1];
  }
  return {q(0) + kappa * a.cos[0], q(1) + kappa * a.sin[0], p_.base_length + rho};
}

void MobileManipulator::cut_point_jacobian(CVecRef q, CVecRef qd, Eigen::Matrix<double, 3, 6>& J,
                                           Vec3& c, ConstSlot slot) const {
  cut_point_jacobian_from(kinematics(q, qd, slot), qd(2), J, c);
}

// dJ, dc: J and c evaluated once on Duals seeded with (q, dq), (q̇, dq̇) (forward mode, Griewank
// & Walther 2008, ch. 3); the derivative parts are the exact directional derivatives.
void MobileManipulator::cut_point_jacobian_tangent(CVecRef q, CVecRef qd, CVecRef dq, CVecRef dqd,
                                                   Eigen::Matrix<double, 3, 6>& dJ,
                                                   Vec3& dc) const {
  const DualVec6 qx = seed6(q, dq), qdx = seed6(qd, dqd);
  const ArmKinematicsT<Dual> k = kinematics_from(p_, compute_angles<Dual>(qx), qdx);
  Eigen::Matrix<Dual, 3, 6> J;
  Eigen::Matrix<Dual, 3, 1> c;
  cut_point_jacobian_from(k, qdx(2), J, c);
  for (Index j = 0; j < 6; ++j)
    for (Index i = 0; i < 3; ++i) dJ(i, j) = tangent_of(J(i, j));
  for (Index i = 0; i < 3; ++i) dc(i) = tangent_of(c(i));
}

void MobileManipulator::mass(const EvalContext& /*c*/, CVecRef q, MatRef M) const {
  mass_from(p_, a_, trig_from(p_, compute_angles<double>(q)), M);
}

void MobileManipulator::coriolis(const EvalContext& /*c*/, CVecRef q, CVecRef qd, MatRef C) const {
  coriolis_from(p_, a_, trig_from(p_, compute_angles<double>(q)), qd, C);
}

void MobileManipulator::coriolis_times_qd(const EvalContext& /*c*/, CVecRef q, CVecRef qd,
                                          VecRef Cqd) const {
  coriolis_times_qd_from(p_, a_, trig_from(p_, compute_angles<double>(q)), qd, Cqd);
}

void MobileManipulator::gravity(const EvalContext& /*c*/, CVecRef q, VecRef G) const {
  const auto& l = p_.link_length;
  const std::array<double, 3> c{l[0] * std::cos(q(3)), l[1] * std::cos(q(4)),
                                l[2] * std::cos(q(5))};
  gravity_from(p_, a_, c, G);
}

double MobileManipulator::dynamics(const EvalContext& c, CVecRef q, CVecRef qd, MatRef M,
                                   VecRef Cqd, VecRef G) const {
  const AngleSinCos a = compute_angles<double>(q);
  record_angles(c.slot, q, a);
  const Trig<double> t = trig_from(p_, a);
  mass_from(p_, a_, t, M);
  coriolis_times_qd_from(p_, a_, t, qd, Cqd);
  gravity_from(p_, a_, t.c, G);
  return 0.0;
}

// dID = d(M q̈ + C q̇ + G) at fixed q̈: the closed forms of dynamics() evaluated once on Duals
// seeded with (q, dq), (q̇, dq̇) (forward mode, Griewank & Walther 2008, ch. 3). Stack only.
bool MobileManipulator::inverse_dynamics_tangent(const EvalContext& /*c*/, CVecRef q, CVecRef qd,
                                                 CVecRef qdd, CVecRef dq, CVecRef dqd,
                                                 VecRef dID) const {
  const DualVec6 qx = seed6(q, dq), qdx = seed6(qd, dqd);
  const Trig<Dual> t = trig_from(p_, compute_angles<Dual>(qx));
  Eigen::Matrix<Dual, 6, 6> M;
  DualVec6 Cqd, G;
  mass_from(p_, a_, t, M);
  coriolis_times_qd_from(p_, a_, t, qdx, Cqd);
  gravity_from(p_, a_, t.c, G);
  for (Index i = 0; i < 6; ++i) {
    double d = tangent_of(Cqd(i)) + tangent_of(G(i));
    for (Index j = 0; j < 6; ++j) d += tangent_of(M(i, j)) * qdd(j);
    dID(i) = d;
  }
  return true;
}

double MobileManipulator::potential(const EvalContext& /*c*/, CVecRef q) const {
  const auto& m = p_.link_mass;
  const auto& l = p_.link_length;
  const double s1 = l[0] * std::sin(q(3)), s2 = l[1] * std::sin(q(4)), s3 = l[2] * std::sin(q(5));
  const double lr = p_.base_length;
  // CoM heights above the platform: joint r at l_r/2, link k at l_r + Σ_{j<k} ŝ_j + ŝ_k/2.
  const double h = p_.base_mass * lr / 2 + m[0] * (lr + s1 / 2) + m[1] * (lr + s1 + s2 / 2) +
                   m[2] * (lr + s1 + s2 + s3 / 2);
  return p_.gravity * h;
}

}  // namespace ukdyn
