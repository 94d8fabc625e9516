// An INDEPENDENT reference formulation of one mobile manipulator, for the tests.
//
// Nothing here uses the library's closed-form M, C, G. Everything is derived from the kinematics
// alone (positions of the centres of mass as functions of q) by automatic differentiation (Eigen's
// unsupported AutoDiffScalar, nested for second derivatives):
//   Jv_i = ∂p_i/∂q                                (AD)
//   M    = Σ m_i Jv_iᵀ Jv_i + Σ Jω_kᵀ I_k Jω_k      (paper Eq. 5; the paper's scalar rotational model)
//   G    = ∂V/∂q,  V = g Σ m_i z_i                  (AD; gravity along −Z)
//   ∂M/∂q_k                                         (nested AD of M)
//   C q̇  = Ṁ q̇ − ∂T/∂q,  Ṁ = Σ_k ∂M/∂q_k q̇_k,  ∂T/∂q_k = ½ q̇ᵀ ∂M/∂q_k q̇   (Euler–Lagrange)
//   C    = Christoffel symbols of M (paper Eq. 9)
// The only inputs are the geometric description of the paper (see docs/paper-notes.md):
// platform and joint r at the platform's (x, y); link k's CoM at horizontal radius
// r_k = Σ_{j<k} l_j cos θ_j + ½ l_k cos θ_k along the yaw δ and at height
// l_r + Σ_{j<k} l_j sin θ_j + ½ l_k sin θ_k; rotational energy ½ I_r δ̇² + Σ ½ I_k (δ̇² + θ̇_k²).
#pragma once

#include <Eigen/Core>
#include <array>
#include <cmath>
#include <unsupported/Eigen/AutoDiff>

#include "ukdyn/paper_robot/mobile_manipulator.hpp"

namespace ukref {

using Params = ukdyn::MobileManipulatorParams;
template <class S>
using V3 = Eigen::Matrix<S, 3, 1>;
template <class S>
using V6 = Eigen::Matrix<S, 6, 1>;
template <class S>
using M6 = Eigen::Matrix<S, 6, 6>;
using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;

/// First-order AD scalar with 6 derivative directions (one per coordinate).
using AD6 = Eigen::AutoDiffScalar<Vector6d>;

/// Number of point masses: platform, joint r, link 1, link 2, link 3.
inline constexpr int kBodies = 5;

/// Mass of body i (platform, joint r, links 1..3).
inline double body_mass(const Params& p, int i) {
  switch (i) {
    case 0:
      return p.platform_mass;
    case 1:
      return p.base_mass;
    default:
      return p.link_mass[static_cast<std::size_t>(i - 2)];
  }
}

/// Centres of mass of the five bodies as functions of q = [Δx, Δy, δ, θ1, θ2, θ3] (world frame,
/// platform at height 0, Z up). Joint r's CoM is put at half its height (a constant: irrelevant).
template <class S>
std::array<V3<S>, kBodies> com_positions(const Params& p, const V6<S>& q) {
  using std::cos;
  using std::sin;
  const S x = q(0), y = q(1), delta = q(2);
  const S cd = cos(delta), sd = sin(delta);
  std::array<V3<S>, kBodies> out;
  out[0] = V3<S>(x, y, S(0.0));
  out[1] = V3<S>(x, y, S(0.5 * p.base_length));
  S reach = S(0.0);           // Σ_{j<k} l_j cos θ_j
  S rise = S(p.base_length);  // l_r + Σ_{j<k} l_j sin θ_j
  for (int k = 0; k < 3; ++k) {
    const S th = q(3 + k);
    const S l = S(p.link_length[static_cast<std::size_t>(k)]);
    const S ck = cos(th), sk = sin(th);
    const S r = reach + S(0.5) * l * ck;
    const S z = rise + S(0.5) * l * sk;
    out[static_cast<std::size_t>(2 + k)] = V3<S>(x + r * cd, y + r * sd, z);
    reach = reach + l * ck;
    rise = rise + l * sk;
  }
  return out;
}

/// The cut point: the end of link 3.
template <class S>
V3<S> cut_point(const Params& p, const V6<S>& q) {
  using std::cos;
  using std::sin;
  S reach = S(0.0);
  S rise = S(p.base_length);
  for (int k = 0; k < 3; ++k) {
    const S l = S(p.link_length[static_cast<std::size_t>(k)]);
    reach = reach + l * cos(q(3 + k));
    rise = rise + l * sin(q(3 + k));
  }
  return V3<S>(q(0) + reach * cos(q(2)), q(1) + reach * sin(q(2)), rise);
}

/// Linear-velocity Jacobians (3 × 6) of the five CoMs by AD, for any scalar S.
template <class S>
std::array<Eigen::Matrix<S, 3, 6>, kBodies> com_jacobians(const Params& p, const V6<S>& q) {
  using AD = Eigen::AutoDiffScalar<V6<S>>;
  V6<AD> qa;
  for (int i = 0; i < 6; ++i) {
    V6<S> seed = V6<S>::Constant(S(0.0));
    seed(i) = S(1.0);
    qa(i) = AD(q(i), seed);
  }
  const auto pos = com_positions<AD>(p, qa);
  std::array<Eigen::Matrix<S, 3, 6>, kBodies> J;
  for (std::size_t b = 0; b < static_cast<std::size_t>(kBodies); ++b)
    for (int r = 0; r < 3; ++r) J[b].row(r) = pos[b](r).derivatives().transpose();
  return J;
}

/// Mass matrix, paper Eq. (5): Σ m Jvᵀ Jv + Σ Jωᵀ I Jω with the paper's rotational model.
template <class S>
M6<S> mass_matrix(const Params& p, const V6<S>& q) {
  const auto J = com_jacobians<S>(p, q);
  M6<S> M = M6<S>::Constant(S(0.0));
  for (int b = 0; b < kBodies; ++b) {
    const auto& Jb = J[static_cast<std::size_t>(b)];
    M += S(body_mass(p, b)) * (Jb.transpose() * Jb);
  }
  // Rotational part: ω_r = δ̇ (I_r); link k: ω = [δ̇, θ̇_k] with one scalar inertia I_k.
  Eigen::Matrix<double, 2, 6> Jw;
  Matrix6d Mrot = Matrix6d::Zero();
  Mrot(2, 2) += p.base_inertia;
  for (int k = 0; k < 3; ++k) {
    Jw.setZero();
    Jw(0, 2) = 1.0;
    Jw(1, 3 + k) = 1.0;
    Mrot += p.link_inertia[static_cast<std::size_t>(k)] * (Jw.transpose() * Jw);
  }
  for (int i = 0; i < 6; ++i)
    for (int j = 0; j < 6; ++j) M(i, j) += S(Mrot(i, j));
  return M;
}

/// Potential energy V = g Σ m z (gravity along −Z).
template <class S>
S potential(const Params& p, const V6<S>& q) {
  const auto pos = com_positions<S>(p, q);
  S V = S(0.0);
  for (int b = 0; b < kBodies; ++b)
    V += S(body_mass(p, b) * p.gravity) * pos[static_cast<std::size_t>(b)](2);
  return V;
}

/// G = ∂V/∂q by AD.
inline Vector6d gravity(const Params& p, const Vector6d& q) {
  V6<AD6> qa;
  for (int i = 0; i < 6; ++i) qa(i) = AD6(q(i), Vector6d::Unit(i));
  return potential<AD6>(p, qa).derivatives();
}

/// ∂M/∂q_k, k = 0..5, by nested AD of M.
inline std::array<Matrix6d, 6> mass_derivatives(const Params& p, const Vector6d& q) {
  V6<AD6> qa;
  for (int i = 0; i < 6; ++i) qa(i) = AD6(q(i), Vector6d::Unit(i));
  const M6<AD6> Ma = mass_matrix<AD6>(p, qa);
  std::array<Matrix6d, 6> dM;
  for (int k = 0; k < 6; ++k)
    for (int i = 0; i < 6; ++i)
      for (int j = 0; j < 6; ++j) dM[static_cast<std::size_t>(k)](i, j) = Ma(i, j).derivatives()(k);
  return dM;
}

/// Ṁ = Σ_k ∂M/∂q_k q̇_k, computed directly by a directional AD seed q̇ (independent of
/// mass_derivatives: one derivative direction instead of six).
inline Matrix6d mass_dot(const Params& p, const Vector6d& q, const Vector6d& qd) {
  using AD1 = Eigen::AutoDiffScalar<Eigen::Matrix<double, 1, 1>>;
  V6<AD1> qa;
  for (int i = 0; i < 6; ++i) qa(i) = AD1(q(i), Eigen::Matrix<double, 1, 1>(qd(i)));
  const M6<AD1> Ma = mass_matrix<AD1>(p, qa);
  Matrix6d Md;
  for (int i = 0; i < 6; ++i)
    for (int j = 0; j < 6; ++j) Md(i, j) = Ma(i, j).derivatives()(0);
  return Md;
}

/// Kinetic energy T(q, q̇) = ½ q̇ᵀ M(q) q̇.
template <class S>
S kinetic_energy(const Params& p, const V6<S>& q, const V6<S>& qd) {
  return S(0.5) * qd.dot(mass_matrix<S>(p, q) * qd);
}

/// ∂T/∂q by nested AD of T (q̇ held constant).
inline Vector6d kinetic_energy_gradient(const Params& p, const Vector6d& q, const Vector6d& qd) {
  V6<AD6> qa, qda;
  for (int i = 0; i < 6; ++i) {
    qa(i) = AD6(q(i), Vector6d::Unit(i));
    qda(i) = AD6(qd(i), Vector6d::Zero());
  }
  return kinetic_energy<AD6>(p, qa, qda).derivatives();
}

/// C(q, q̇) q̇ by the Euler–Lagrange form: Ṁ q̇ − ∂T/∂q.
inline Vector6d coriolis_times_qd(const Params& p, const Vector6d& q, const Vector6d& qd) {
  return mass_dot(p, q, qd) * qd - kinetic_energy_gradient(p, q, qd);
}

/// The Christoffel C of paper Eq. (9): C_ij = ½ Σ_k (∂M_ij/∂q_k + ∂M_ik/∂q_j − ∂M_jk/∂q_i) q̇_k.
inline Matrix6d christoffel_coriolis(const Params& p, const Vector6d& q, const Vector6d& qd) {
  const auto dM = mass_derivatives(p, q);
  Matrix6d C = Matrix6d::Zero();
  for (int i = 0; i < 6; ++i)
    for (int j = 0; j < 6; ++j)
      for (int k = 0; k < 6; ++k)
        C(i, j) += 0.5 *
                   (dM[static_cast<std::size_t>(k)](i, j) + dM[static_cast<std::size_t>(j)](i, k) -
                    dM[static_cast<std::size_t>(i)](j, k)) *
                   qd(k);
  return C;
}

/// Cut point Jacobian (3 × 6) by AD.
inline Eigen::Matrix<double, 3, 6> cut_point_jacobian(const Params& p, const Vector6d& q) {
  V6<AD6> qa;
  for (int i = 0; i < 6; ++i) qa(i) = AD6(q(i), Vector6d::Unit(i));
  const V3<AD6> c = cut_point<AD6>(p, qa);
  Eigen::Matrix<double, 3, 6> J;
  for (int r = 0; r < 3; ++r) J.row(r) = c(r).derivatives().transpose();
  return J;
}

/// Nested AD scalars seeded along q(s) = q + s q̇: the second derivative of any function of them
/// is d²/ds² at s = 0, i.e. J̇ q̇ for a position.
using AD1 = Eigen::AutoDiffScalar<Eigen::Matrix<double, 1, 1>>;
using AD2 = Eigen::AutoDiffScalar<Eigen::Matrix<AD1, 1, 1>>;
inline V6<AD2> seed_along_qd(const Vector6d& q, const Vector6d& qd) {
  V6<AD2> qa;
  for (int i = 0; i < 6; ++i) {
    const AD1 val(q(i), Eigen::Matrix<double, 1, 1>(qd(i)));
    Eigen::Matrix<AD1, 1, 1> der;
    der(0) = AD1(qd(i), Eigen::Matrix<double, 1, 1>(0.0));
    qa(i) = AD2(val, der);
  }
  return qa;
}

/// J̇ q̇ of every CoM: the second derivative d²/ds² p_i(q + s q̇) at s = 0, by nested AD.
inline std::array<Eigen::Vector3d, kBodies> com_jdot_qd(const Params& p, const Vector6d& q,
                                                        const Vector6d& qd) {
  const V6<AD2> qa = seed_along_qd(q, qd);
  const auto pos = com_positions<AD2>(p, qa);
  std::array<Eigen::Vector3d, kBodies> out;
  for (std::size_t b = 0; b < static_cast<std::size_t>(kBodies); ++b)
    for (int r = 0; r < 3; ++r) out[b](r) = pos[b](r).derivatives()(0).derivatives()(0);
  return out;
}

}  // namespace ukref

namespace ukref {

/// d²/ds² of the cut point along q(s) = q + s q̇ (= J̇ q̇ of the cut point), by nested AD.
inline Eigen::Vector3d cut_point_jdot_qd(const Params& p, const Vector6d& q, const Vector6d& qd) {
  const V6<AD2> qa = seed_along_qd(q, qd);
  const V3<AD2> c = cut_point<AD2>(p, qa);
  Eigen::Vector3d out;
  for (int r = 0; r < 3; ++r) out(r) = c(r).derivatives()(0).derivatives()(0);
  return out;
}

}  // namespace ukref
