// Exact reference solutions of the IFToMM benchmark problems that are exactly solvable (the simple
// pendulum, benchmark A01, and the parallelogram branch of the N-four-bar mechanism, A02), written
// independently of ukdyn from the classical closed form of the plane pendulum. Used by
// tools/benchmarks.cpp (`make benchmarks`) and tests/test_benchmarks.cpp. Header-only.
//
// The plane pendulum θ̈ = −ω² sin θ (θ from the downward vertical), from any state (θ0, θ̇0), with
// the energy constant  e = (θ̇0 / 2ω)² + sin²(θ0/2)  (so θ̇² = 4ω² (e − sin²(θ/2))):
//  - libration, e < 1:   sin(θ/2) = k sn(ω t + u0, k),   k = √e                 (DLMF 22.19.2)
//  - circulation, e > 1: θ/2 = am(±(ω/k) t + u0, k),       k = 1/√e              (DLMF 22.19.3)
// with u0 from the incomplete elliptic integral of the first kind F(φ, k) (DLMF 19.2.4) so that
// θ(0) = θ0 and θ̇(0) has the sign of θ̇0; the libration period is 4K(k)/ω (DLMF 22.19.2 with
// K = F(π/2, k), 19.2.8). Jacobi's sn, cn and F, K are Boost.Math's (DLMF 22.2, 22.20 AGM); dn =
// √(1 − k² sn²). DLMF: NIST Digital Library of Mathematical Functions, https://dlmf.nist.gov (F. W.
// J. Olver et al., eds.); also Abramowitz & Stegun, Handbook of Mathematical Functions (1964), 16.1
// and 17.2.
#pragma once

#include <algorithm>
#include <boost/math/special_functions/ellint_1.hpp>
#include <boost/math/special_functions/jacobi_elliptic.hpp>
#include <cmath>
#include <numbers>
#include <stdexcept>

namespace ukdyn_bench {

class ExactPendulum {
 public:
  /// θ̈ = −ω² sin θ with θ(0) = theta0, θ̇(0) = thetad0. Throws on the separatrix (e = 1 within
  /// 1e-12), where the motion takes infinite time to reach the top and the forms above degenerate.
  ExactPendulum(double omega, double theta0, double thetad0) : omega_(omega) {
    if (!(omega > 0)) throw std::invalid_argument("ExactPendulum: omega must be positive");
    const double s0 = std::sin(theta0 / 2);
    e_ = std::pow(thetad0 / (2 * omega), 2) + s0 * s0;
    if (std::abs(e_ - 1.0) < 1e-12) throw std::invalid_argument("ExactPendulum: separatrix motion");
    circulating_ = e_ > 1.0;
    if (!circulating_) {
      k_ = std::sqrt(e_);
      K_ = boost::math::ellint_1(k_);
      if (k_ == 0.0) {  // at rest at the bottom
        u0_ = 0.0;
        return;
      }
      const double ratio = std::clamp(s0 / k_, -1.0, 1.0);
      const double F0 = boost::math::ellint_1(k_, std::asin(ratio));  // in [−K, K]
      // sn(2K − u) = sn(u), cn(2K − u) = −cn(u): the branch with d/dt sin(θ/2) = kω cn dn of the
      // sign of θ̇0.
      u0_ = thetad0 >= 0 ? F0 : 2 * K_ - F0;
    } else {
      k_ = 1.0 / std::sqrt(e_);
      K_ = boost::math::ellint_1(k_);
      sign_ = thetad0 >= 0 ? 1.0 : -1.0;
      u0_ = boost::math::ellint_1(k_, theta0 / 2);  // am(u0) = θ0/2 (F is odd and quasi-periodic)
    }
  }

  /// θ(t).
  [[nodiscard]] double theta(double t) const {
    if (!circulating_) {
      if (k_ == 0.0) return 0.0;
      const double sn = boost::math::jacobi_sn(k_, omega_ * t + u0_);
      return 2 * std::asin(std::clamp(k_ * sn, -1.0, 1.0));
    }
    return 2 * am(sign_ * omega_ / k_ * t + u0_);
  }

  /// θ̇(t): libration θ̇ = 2kω cn (as cos(θ/2) = dn), circulation θ̇ = ±(2ω/k) dn. dn is taken as
  /// √(1 − k² sn²) (dn > 0 for real u, k < 1), not from Boost 1.74's jacobi_elliptic, whose dn is
  /// off by up to 1e-2 near u = K (dn(K, 0.5) = 0.86399 instead of k' = 0.86603; sn, cn are right).
  [[nodiscard]] double theta_dot(double t) const {
    double cn = 0, dn = 0;
    if (!circulating_) {
      if (k_ == 0.0) return 0.0;
      boost::math::jacobi_elliptic(k_, omega_ * t + u0_, &cn, &dn);
      return 2 * k_ * omega_ * cn;
    }
    const double sn = boost::math::jacobi_elliptic(k_, sign_ * omega_ / k_ * t + u0_, &cn, &dn);
    return 2 * sign_ * omega_ / k_ * std::sqrt(std::max(0.0, 1.0 - k_ * k_ * sn * sn));
  }

  [[nodiscard]] bool circulating() const { return circulating_; }
  [[nodiscard]] double modulus() const { return k_; }
  /// Libration: the period 4K/ω. Circulation: the time of one full turn, 2K k/ω.
  [[nodiscard]] double period() const {
    return circulating_ ? 2 * K_ * k_ / omega_ : 4 * K_ / omega_;
  }

 private:
  /// Jacobi's amplitude am(u, k) = ∫ dn: u = 2K j + r with r in [−K, K] (where cn ≥ 0), am(u) =
  /// jπ + atan2(sn r, cn r)  (am(u + 2K) = am(u) + π, DLMF 22.16.2).
  [[nodiscard]] double am(double u) const {
    const double j = std::round(u / (2 * K_));
    const double r = u - 2 * K_ * j;
    double cn = 0, dn = 0;
    const double sn = boost::math::jacobi_elliptic(k_, r, &cn, &dn);
    return j * std::numbers::pi + std::atan2(sn, cn);
  }

  double omega_ = 1, e_ = 0, k_ = 0, K_ = 0, u0_ = 0, sign_ = 1;
  bool circulating_ = false;
};

/// IFToMM A01: a point mass on a massless rod of length L pivoted at the origin, gravity g along
/// −y, released at rest from the horizontal with P1 = (+L, 0) (θ0 = π/2).
///   P1(t) = L (sin θ, −cos θ).
struct SimplePendulumReference {
  double L = 1.0, g = 9.81;
  ExactPendulum pendulum{std::sqrt(g / L), std::numbers::pi / 2, 0.0};
  void point(double t, double& x, double& y) const {
    const double th = pendulum.theta(t);
    x = L * std::sin(th);
    y = -L * std::cos(th);
  }
};

/// IFToMM A02, the N-four-bar mechanism on its parallelogram branch: N + 1 cranks of length L
/// pivoted at (i L, 0), i = 0..N, and N couplers of length L joining their tips, every link a
/// uniform rod of mass m. While every window stays a parallelogram, all cranks have the same angle
/// φ from the +x axis and the couplers translate, so the mechanism is one pendulum:
///   T = ½ J φ̇²,  J = ((N+1)/3 + N) m L²;   V = G sin φ,  G = ((N+1)/2 + N) m g L;
/// i.e. θ = φ + π/2 obeys θ̈ = −(G/J) sin θ. The specification starts with the cranks vertical
/// (φ0 = π/2) and ẋ of B0 (the tip of crank 0) equal to 1 m/s: φ̇0 = −ẋ_B0 / (L sin φ0).
/// B0(t) = L (cos φ, sin φ).
struct NFourBarReference {
  NFourBarReference(int N_, double xdot_B0 = 1.0, double phi0 = std::numbers::pi / 2,
                    double L_ = 1.0, double m_ = 1.0, double g_ = 9.81)
      : N(N_),
        L(L_),
        m(m_),
        g(g_),
        J(((N_ + 1) / 3.0 + N_) * m_ * L_ * L_),
        G(((N_ + 1) / 2.0 + N_) * m_ * g_ * L_),
        pendulum(std::sqrt(G / J), phi0 + std::numbers::pi / 2, -xdot_B0 / (L_ * std::sin(phi0))) {}
  int N;
  double L, m, g, J, G;
  ExactPendulum pendulum;
  [[nodiscard]] double phi(double t) const { return pendulum.theta(t) - std::numbers::pi / 2; }
  void point_B0(double t, double& x, double& y) const {
    const double p = phi(t);
    x = L * std::cos(p);
    y = L * std::sin(p);
  }
  /// Total energy T + V on the branch (V with the pivots at height 0).
  [[nodiscard]] double energy() const {
    const double pd = pendulum.theta_dot(0.0);
    return 0.5 * J * pd * pd + G * std::sin(phi(0.0));
  }
};

}  // namespace ukdyn_bench
