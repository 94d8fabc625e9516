// Derivatives of the constrained dynamics q̈ and Qc with respect to parameters of the model
// (masses, lengths, inertias, spring constants, ...) at a state (docs/derivatives.md,
// "Sensitivities to parameters").
//
// At fixed (t, q, q̇) a parameter p enters the KKT form of Gauss's principle (linearize.hpp)
//   M q̈ − A_Rᵀ μ = Q,   A_R q̈ = b_R,   Qc = A_Rᵀ μ,   Q = τ + Q_a − C q̇ − G,
// only through M, Q, A and b, so (implicit differentiation, the same KKT matrix and factorisation as
// the state columns of linearize())
//   M ∂q̈ − A_Rᵀ ∂μ = ∂Q − ∂M q̈ + (∂A_R)ᵀ μ,   A_R ∂q̈ = ∂b_R − ∂A_R q̈,
//   ∂Qc = (∂A_R)ᵀ μ + A_Rᵀ ∂μ.
// The caller gives ∂M, ∂Q, ∂A, ∂b at the state (the scenario layer computes them from the model
// re-loaded at p ± h: ukdyn/run/sensitivity.hpp).
#pragma once

#include <vector>

#include "ukdyn/model/linearize.hpp"

namespace ukdyn {

/// The derivatives of the model's pieces at one state with respect to one parameter: ∂M (n × n),
/// ∂Q (n, Q = τ + Q_a − C q̇ − G as ForwardData::Q), ∂A (m × n), ∂b (m).
struct ModelParameterDerivative {
  Mat dM;
  Vec dQ;
  Mat dA;
  Vec db;
};

/// The linearisation of a state and its derivatives with respect to P parameters (one column per
/// parameter, in the order given).
struct ParameterLinearization {
  /// q̈, Qc, rank, trusted, message; with_state: the state columns as linearize() gives them;
  /// with_time: the time column too (dqdd_dt, dQc_dt, dmu_dt, or empty with time_message naming
  /// the component without an exact ∂/∂t), else empty with time_message saying it was not asked
  Linearization lin;
  Mat dqdd_dp;  ///< n × P
  Mat dQc_dp;   ///< n × P
  Mat dmu_dp;   ///< r × P (the kept rows' multipliers, lin.kept_rows)
};

/// The derivatives at (t, q, q̇, τ) of q̈ and Qc along the model derivatives `dp`. with_state: also
/// the state columns of linearize() (then every component must have exact tangents, as for
/// linearize()); without, only the KKT solve is needed and any system will do. with_time (with
/// with_state): also linearize()'s time column, one more right-hand side of the same
/// factorisation; off by default: the variational equations of a run (ukdyn/run/sensitivity.hpp),
/// which call this at every right-hand-side evaluation, do not use it (about 10 % of their time on
/// the five-bar, docs/derivatives.md). `lin.trusted` and `lin.message` say, as for linearize(), when
/// the derivatives cannot be vouched for.
ParameterLinearization linearize_parameters(const System& system, double t, CVecRef q, CVecRef qd,
                                            CVecRef tau,
                                            const std::vector<ModelParameterDerivative>& dp,
                                            const UkSettings& settings = {}, bool with_state = true,
                                            bool with_time = false);

}  // namespace ukdyn
