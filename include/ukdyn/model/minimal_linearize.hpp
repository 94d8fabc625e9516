// The linearisation of the U-K equation in minimal coordinates on the constraint manifold, and
// the zero-order-hold discretisation of a linear model (docs/derivatives.md, "Minimal
// coordinates" and "Discrete time").
//
// At a state (q, q̇) on the manifold Φ(q, t) = 0, A(q) q̇ + Φ_t = 0 of the holonomic rows, with A_R
// the independent rows the linearisation kept (Linearization::kept_rows) and N an orthonormal
// basis of null(A_R) (n × k, k = n − r), a first-order perturbation that stays on the manifold is
//   δq = N z₁                      (A_R δq = 0),
//   δq̇ = N z₂ − A_R⁺ D N z₁         (A_R δq̇ + D δq = 0, D = ∂(A_R q̇ + Φ_t)/∂q at fixed q̇),
// with z₁ = Nᵀδq, z₂ = Nᵀδq̇ and A_R⁺ = A_Rᵀ(A_R A_Rᵀ)⁻¹ (NᵀA_R⁺ = 0). In x = (δq, δq̇) that is
// x = T z, T = [[N, 0], [−A_R⁺ D N, N]]; with P = diag(Nᵀ, Nᵀ) (P T = I) the reduced model is
//   ż = F_min z + G_min δτ,   F_min = P F T,   G_min = P G,
// i.e. F_min = [[0, I], [Nᵀ(∂q̈/∂q − ∂q̈/∂q̇ A_R⁺ D)N, Nᵀ ∂q̈/∂q̇ N]], G_min = [[0], [Nᵀ ∂q̈/∂τ]].
// At rest (q̇ = 0) D = ∂Φ_t/∂q (0 for scleronomic rows). At an equilibrium (q̇ = 0, q̈ = 0) of
// scleronomic rows the manifold's tangent space range(T) is invariant under F (F T = T F_min) and
// the spectrum of F is that of F_min plus 2r zeros (the constraint directions, along which the
// linearised Φ̈ = 0 leaves a double zero). Elsewhere the
// tangent space moves with the state and N is frozen at it: F_min is the instantaneous projection
// of the linear time-varying model along the trajectory, like F itself away from an equilibrium.
//
// N is defined up to an orthogonal change of basis z → R z (F_min → R F_min Rᵀ: the eigenvalues
// do not depend on it). ukdyn takes the last k right singular vectors of A_R (Eigen::JacobiSVD,
// deterministic for a given A_R) and flips the sign of each column so that its entry of largest
// magnitude (the first such) is positive.
#pragma once

#include <string>
#include <vector>

#include "ukdyn/model/linearize.hpp"

namespace ukdyn {

/// The reduced model of one state (minimal_model()).
struct MinimalModel {
  Mat N;   ///< n × k orthonormal basis of null(A_R), k = n − rank
  Mat AR;  ///< r × n: the kept rows of A at the state
  /// r × n: ∂(A_R q̇ + Φ_t)/∂q at fixed q̇, exact: ½ ∂(A_R q̈ − b_R)/∂q̇ from the constraints'
  /// tangents (b is quadratic in q̇ for a holonomic row, docs/derivatives.md)
  Mat D;
  Mat T;                        ///< 2n × 2k: x = T z, the tangent of the manifold in (δq, δq̇)
  Mat F, G;                     ///< the full model (state_space())
  Mat F_min, G_min;             ///< 2k × 2k and 2k × n
  double null_residual = 0.0;   ///< max |A_R N|
  double ortho_residual = 0.0;  ///< max |NᵀN − I|
  /// max |Φ_R| and max |A_R q̇ + Φ_t| at the state: how far it is from the manifold the model
  /// describes (the note says so above 1e-8)
  double position_residual = 0.0, velocity_residual = 0.0;
  bool at_rest = true;  ///< q̇ = 0 (then D = ∂Φ_t/∂q, 0 unless a row is rheonomic)
  /// A kept row's velocity constraint depends on t at the state: Φ_t ≠ 0 or ∂Φ_t/∂q ≠ 0 (the
  /// manifold moves with t; D holds ∂Φ_t/∂q exactly either way).
  bool rheonomic = false;
  std::string note;  ///< what the model means away from rest, how D was had ("" otherwise)
};

/// The orthonormal basis of null(A_R) described above (n × (n − rows)); A_R must have independent
/// rows (Linearization::kept_rows). Throws std::invalid_argument when A_R has more rows than
/// columns.
Mat null_space_basis(const Mat& AR);

/// The reduced model at (t, q, q̇, τ) from its linearisation `lin` (linearize() at the same state).
/// Throws ukdyn::Error when a kept row is velocity-level (nonholonomic: its position residual does
/// not vary along its row of A, so the manifold has no position part for it; ukdyn does not build
/// the mixed reduction, see docs/derivatives.md) or when a constraint has no exact tangent.
MinimalModel minimal_model(const System& system, double t, CVecRef q, CVecRef qd, CVecRef tau,
                           const Linearization& lin);

/// The matrix exponential e^X by scaling and squaring with the [13/13] Padé approximant
/// (Higham, "The scaling and squaring method for the matrix exponential revisited", SIAM J.
/// Matrix Anal. Appl. 26(4), 2005, Algorithm 2.3 with the θ_m of its Table 2.3).
Mat expm(const Mat& X);

/// Zero-order hold with step h > 0: x_{k+1} = Fd x_k + Gd u_k for ẋ = F x + G u with u constant on
/// each step, from exp([[F, G], [0, 0]] h) = [[Fd, Gd], [0, I]] (Van Loan 1978). Throws
/// std::invalid_argument for h ≤ 0 or not finite, or for mismatched sizes.
void discretize_zoh(const Mat& F, const Mat& G, double h, Mat& Fd, Mat& Gd);

}  // namespace ukdyn
