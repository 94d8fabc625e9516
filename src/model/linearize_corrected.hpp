// The pieces of linearize() the exact derivatives of the servo laws are composed of
// (run/law_jacobian.cpp, docs/derivatives.md "Controlled runs"): the KKT system's derivatives with
// a corrected right-hand side b + v(Φ, Φ̇), and the constraints' tangents at a chosen q̈ and λ.
#pragma once

#include "ukdyn/model/linearize.hpp"

namespace ukdyn {

/// A right-hand side b + v of the KKT system, v a function of the rows' residuals Φ and Φ̇ (the
/// servo laws' corrections, ukdyn/simulate/control.hpp): v (m) at the state and its Jacobians
/// ∂v/∂Φ, ∂v/∂Φ̇ (m × m each). The rows whose residuals v uses must be holonomic: then ∂Φ/∂q = A,
/// ∂Φ̇/∂q̇ = A and ∂Φ̇/∂q = −½ ∂b/∂q̇ (b = −(∂Φ̇/∂q) q̇ − ∂Φ̇/∂t, ∂Φ̇/∂q linear in q̇ with the
/// symmetric second derivatives of Φ), all from the constraints' exact tangents.
struct RhsCorrection {
  Vec v;
  Mat dv_dphi, dv_dphid;
};

/// linearize() of the KKT system with the right-hand side b + v: q̈, Qc, μ and their derivatives
/// along (q, q̇) are those of the corrected solve, v's own derivatives included (∂/∂τ as
/// linearize()). Always the dense KKT factorisation. lin.kkt_agreement is 0: forward()'s q̈ is
/// that of b, the caller compares with its own corrected solve.
void linearize_corrected(const System& system, LinearizeData& data, double t, CVecRef q, CVecRef qd,
                         CVecRef tau, const RhsCorrection& correction,
                         const UkSettings& settings = {});

/// After linearize_corrected() at (t, q, q̇): its time column with ∂v/∂t at fixed (q, q̇) (m), into
/// data.lin.dqdd_dt, dQc_dt, dmu_dt (one more right-hand side of its factorisation); those are
/// left empty, with data.lin.time_message, when a component has no exact ∂/∂t.
void linearize_corrected_time(const System& system, LinearizeData& data, double t, CVecRef q,
                              CVecRef qd, const Vec& dv_dt);

/// Every constraint's exact time tangents at (q̈, λ): ∂(A q̈ − b)/∂t into dres (m) and ∂(Aᵀλ)/∂t
/// into dforce (n), at fixed (q, q̇); data.fwd as for constraint_tangent_columns(). False when a
/// constraint has no exact ∂/∂t.
bool constraint_time_tangent(const System& system, LinearizeData& data, double t, CVecRef q,
                             CVecRef qd, CVecRef qdd, CVecRef lambda, Vec& dres, Vec& dforce);

/// Every constraint's exact tangents at (q̈, λ) (λ: m, every row) along e_j of q (column j) and
/// of q̇ (column n + j): d(A q̈ − b) into dres (m × 2n), d(Aᵀλ) into dforce (n × 2n). data.fwd
/// must hold forward() at (t, q, q̇) (the constraints' slots), as after linearize().
void constraint_tangent_columns(const System& system, LinearizeData& data, double t, CVecRef q,
                                CVecRef qd, CVecRef qdd, CVecRef lambda, Mat& dres, Mat& dforce);

}  // namespace ukdyn
