// Exact motion of the N-four-bar benchmark (MBS benchmark library problem A02, González, Dopico,
// Lugrís, Cuadrado, Multibody Syst. Dyn. 16 (2006) 179–190) on its parallelogram branch, where all
// N+1 cranks turn together (φ_i = φ) and the couplers translate (ψ_i = 0): a one-degree-of-freedom
// pendulum. With rods of mass m and length l (uniform, I_pivot = m l²/3, I_centre = m l²/12):
//   T = ½ J φ̇²,  J = m l² ((N+1)/3 + N)      (N+1 cranks about their pivots, N translating
//   couplers) V = m g l K sin φ,  K = (N+1)/2 + N       (crank CoM at l/2 sin φ, coupler CoM at l
//   sin φ)
// Measured from the bottom, θ = φ + π/2: ½ θ̇² − ω0² cos θ = const with ω0² = g K /(l J/(m l²)).
// The benchmark starts at the top (θ = π) with θ̇ = −v0/l (x velocity of B0 = v0 > 0), which is
// above the separatrix, so the cranks rotate for ever. The rotating pendulum's solution in Jacobi
// elliptic functions (Byrd & Friedman, Handbook of Elliptic Integrals, 1971; derived again here:
// with it, ½ θ̃̇² = ½ θ̇_b² dn² = ½ θ̇_b² − 2 ω0² sin²(θ̃/2), which is the energy integral)
//   θ̃(t) = 2 am(ω t + u0, k),  ω = θ̇_b / 2,  k = 2 ω0 / θ̇_b,  θ̇_b² = θ̇(0)² + 4 ω0²  (θ̇ at the
//   bottom)
// for the increasing angle θ̃ = −θ, with am(u0) = −π/2, i.e. u0 = −K(k). Hence
//   φ(t) = −2 am(ω t − K(k), k) − π/2,   φ̇(t) = −2 ω dn(ω t − K(k), k).
// am is evaluated as n π + atan2(sn, cn) after reducing the argument by its period 2K (Boost.Math's
// jacobi_elliptic and ellint_1). tests/test_n_four_bar.cpp checks the result against the ODE and
// the energy integral by finite differences, independently of this derivation.
#pragma once

#include <boost/math/special_functions/ellint_1.hpp>
#include <boost/math/special_functions/jacobi_elliptic.hpp>
#include <cmath>

namespace ukdyn::benchmarks {

struct NFourBarExact {
  int n = 2;        ///< number of windows N
  double g = 9.81;  ///< gravity [m/s²]
  double l = 1.0;   ///< link length [m]
  double v0 = 1.0;  ///< x velocity of B0 at t = 0 [m/s] (cranks vertical)
  double omega = 0, k = 0, K = 0;

  NFourBarExact(int windows, double gravity, double length, double b0_speed)
      : n(windows), g(gravity), l(length), v0(b0_speed) {
    const double J = (n + 1) / 3.0 + n;    // per m l²
    const double Kv = (n + 1) / 2.0 + n;   // per m l
    const double w0sq = g * Kv / (l * J);  // ω0²
    const double thd0 = v0 / l;
    const double thdb = std::sqrt(thd0 * thd0 + 4.0 * w0sq);
    omega = thdb / 2.0;
    k = 2.0 * std::sqrt(w0sq) / thdb;
    K = boost::math::ellint_1(k);
  }

  /// Crank angle φ(t) and its rate φ̇(t).
  void phi(double t, double& phi_out, double& phid_out) const {
    const double u = omega * t - K;
    const double periods = std::round(u / (2.0 * K));
    const double ur = u - 2.0 * K * periods;  // in [−K, K]: cn ≥ 0
    double cn = 0, dn = 0;
    const double sn = boost::math::jacobi_elliptic(k, ur, &cn, &dn);
    const double am = periods * M_PI + std::atan2(sn, cn);
    phi_out = -2.0 * am - M_PI / 2.0;
    // φ̇ = −2 ω dn(u), evaluated from the energy integral ½ J φ̇² + g K l sin φ = ½ J v0² + g K l
    // instead: dn near u = ±K (the top) came out of Boost 7e-4 off for k near 1 (v0 = 0.5).
    const double J = (n + 1) / 3.0 + n, Kv = (n + 1) / 2.0 + n;
    phid_out = -std::sqrt(v0 * v0 / (l * l) + 2.0 * g * Kv * (1.0 - std::sin(phi_out)) / (l * J));
  }

  /// Point B0 (tip of the first crank, first point of the first coupler): (l cos φ, l sin φ).
  void b0(double t, double& x, double& y) const {
    double p = 0, pd = 0;
    phi(t, p, pd);
    x = l * std::cos(p);
    y = l * std::sin(p);
  }
};

}  // namespace ukdyn::benchmarks
