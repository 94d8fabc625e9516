// Exact first derivatives of the constrained forward dynamics q̈(q, q̇, τ) and of the constraint
// force Qc(q, q̇, τ) (docs/derivatives.md): the linearisation of the U-K equation at a state.
//
// The U-K acceleration is the one of Gauss's principle, q̈ = argmin (q̈ − a)ᵀ M (q̈ − a) subject to
// A q̈ = b with a = M⁻¹Q ([Udwadia1996]; paper Eq. (4)); with consistent rows and M positive
// definite on null(A) it is the q̈ of the KKT system of the independent rows R of A,
//   [ M    −A_Rᵀ ] [ q̈ ]   [ Q   ]          Qc = A_Rᵀ μ,
//   [ A_R    0   ] [ μ  ] = [ b_R ],
// and, while rank A stays constant near the state, q̈ and Qc are differentiable functions of the
// state whose derivatives solve the same KKT matrix (implicit differentiation) with the directional
// derivatives of the model on the right:
//   M dq̈ − A_Rᵀ dμ = dτ − d(M q̈ + C q̇ + G)|_q̈ + dQ_a + (dA_R)ᵀ μ,
//   A_R dq̈ = −d(A_R q̈ − b_R)|_q̈,            dQc = (dA_R)ᵀ μ + A_Rᵀ dμ.
// Every directional derivative of the model comes from the components' exact tangents
// (Subsystem::inverse_dynamics_tangent, Constraint::tangent, AppliedForce::add_tangent): no finite
// differences. One factorisation of the KKT matrix serves every column. The time t is one more
// direction (dt = 1, dq = dq̇ = dτ = 0), its column from the components' time tangents
// (Subsystem::inverse_dynamics_time_tangent, Constraint::time_tangent,
// AppliedForce::add_time_tangent): ∂q̈/∂t of trajectory rows, forces and masses of t.
#pragma once

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <Eigen/QR>
#include <Eigen/SVD>
#include <string>
#include <vector>

#include "ukdyn/core/uk_arrow_kkt.hpp"
#include "ukdyn/model/system.hpp"

namespace ukdyn {

/// The derivatives of one state (t, q, q̇, τ). Matrices are n × n (n = system.dof()).
struct Linearization {
  Vec qdd;  ///< q̈ of the KKT system (equal to forward()'s to round-off, see kkt_agreement)
  Vec Qc;   ///< the constraint force A_Rᵀ μ
  Mat dqdd_dq, dqdd_dqd, dqdd_dtau;
  Mat dQc_dq, dQc_dqd, dQc_dtau;
  /// The multipliers of the kept rows (Qc = A_Rᵀ μ; one entry per kept_rows entry) and their
  /// derivatives (r × n each): the force each independent row carries.
  Vec mu;
  Mat dmu_dq, dmu_dqd, dmu_dtau;
  /// ∂q̈/∂t, ∂Qc/∂t (n) and ∂μ/∂t (r) at fixed (q, q̇, τ): what time-varying constraints, forces
  /// and masses add (0 for a system in which nothing depends on t). Empty when not asked for
  /// (LinearizeParts::time) or when a component has no exact ∂/∂t (time_message says which): the
  /// other derivatives are given all the same.
  Vec dqdd_dt, dQc_dt, dmu_dt;
  /// Empty when ∂/∂t was given or not asked for; else why not ("no exact d/dt for constraint of
  /// row 'x'").
  std::string time_message;
  int rank = 0;                  ///< rank of A (rows kept: kept_rows)
  std::vector<Index> kept_rows;  ///< the independent rows R of A the derivatives use
  /// max |q̈_KKT − q̈_forward| / (1 + max |q̈_forward|): the two formulations at the state.
  double kkt_agreement = 0.0;
  /// False when ukdyn cannot vouch for the derivatives at this state; `message` says why (the
  /// rank of A is about to change, the forward solve was damped, the constraints are
  /// inconsistent, the two formulations disagree).
  bool trusted = true;
  std::string message;
};

/// State-space form of a linearisation for x = (q, q̇), u = τ: ẋ ≈ F δx + G δu with
/// F = [[0, I], [∂q̈/∂q, ∂q̈/∂q̇]], G = [[0], [∂q̈/∂τ]] (2n × 2n and 2n × n).
void state_space(const Linearization& lin, Mat& F, Mat& G);

/// Which parts of a Linearization to compute. ∂q̈/∂q and ∂q̈/∂q̇ always; the rest on request:
/// the implicit integrators' Jacobian needs ∂q̈/∂(q, q̇) alone (∂q̈/∂τ only for a force function
/// with a Jacobian of its own). The members not asked for are left empty (size 0).
struct LinearizeParts {
  bool tau = true;  ///< ∂q̈/∂τ (and, with constraint_force, ∂Qc/∂τ and ∂μ/∂τ)
  bool constraint_force = true;  ///< ∂Qc/∂(q, q̇) and ∂μ/∂(q, q̇) (Qc and μ are always given)
  /// ∂q̈/∂(q, q̇) in O(N) storage (LinearizeData::dqdd_dx, an ArrowResponse) in place of the
  /// dense lin.dqdd_dq, lin.dqdd_dqd, where the block-arrow KKT solve runs without applied forces
  /// and without constraint_force; elsewhere the dense matrices as usual. LinearizeData::structured
  /// says which one a call gave; dqdd_dx_dense() and dqdd_dx_times() read either.
  bool structured = false;
  /// ∂q̈/∂t, ∂Qc/∂t and ∂μ/∂t (Linearization::dqdd_dt, ...): one more right-hand side of the same
  /// factorisation and one time tangent per component, on the dense, Schur and arrow paths alike.
  bool time = true;
};

/// Everything one linearize() call writes, for one system, owned by the caller (Model / Data: the
/// System stays constant). Built once, it is reused: linearize(system, data, ...) then allocates
/// nothing while the rank of A stays the same (Eigen keeps a buffer of the same size), for systems
/// whose components' tangents allocate nothing (trees, numeric frame constraints, `coordinate`
/// rows); the result is `data.lin`.
struct LinearizeData {
  explicit LinearizeData(const System& system);

  Linearization lin;  ///< the result of the last call
  ForwardData fwd;    ///< forward() at the state (q̈ of the U-K solve, M, Q, A, b)
  // The row choice (independent_rows), the KKT system and its right-hand sides.
  Mat Ms, Xt, R, Rinv;
  Eigen::LLT<Mat> llt;
  Eigen::ColPivHouseholderQR<Mat> qr;
  Eigen::JacobiSVD<Mat> svd;
  Mat K, AR, rhs_all, X, dforce_all, rhs_tau, X_tau;
  Eigen::PartialPivLU<Mat> lu;
  Vec Qa, bR, rhs, sol, lambda, dID, dQa, dres, dforce_c, dq, dqd;
  Vec rhs_t, sol_t, dres_t, dforce_t;  ///< the time column (LinearizeParts::time)
  std::vector<std::size_t> owner;      ///< the subsystem of each coordinate
  /// The block-arrow KKT solve (ukdyn/core/uk_arrow_kkt.hpp), built when the system has the
  /// arrow structure: used when forward() took the arrow path with three robots or more and
  /// every row of A is kept.
  ArrowKktWorkspace arrow;
  bool allow_arrow = true;  ///< false: always the dense KKT factorisation (the reference)
  bool used_arrow = false;  ///< whether the last call solved with the arrow blocks
  // The arrow path's right-hand sides by their structural blocks (src/model/linearize.cpp,
  // arrow_state_columns): one constraint's d(A q̈ − b) along every direction, the arrow group of
  // each row of A (−1: a row on the load alone), and whether rhs_all and dforce_all are zero
  // outside the blocks the arrow path writes (false after a dense call).
  Vec dres_cols;
  std::vector<Index> row_group;
  bool rhs_pattern = false;
  /// ∂q̈/∂(q, q̇) = [∂q̈/∂q  ∂q̈/∂q̇] (n × 2n) as own blocks plus the coupling through the load,
  /// when the last call gave it (`structured`; LinearizeParts::structured).
  ArrowResponse dqdd_dx;
  bool structured = false;
  /// Without the arrow blocks, at full row rank: the KKT solve by the row choice's factors (M =
  /// L Lᵀ and the QR of L⁻¹ Aᵀ, whose R gives the Schur complement A M⁻¹ Aᵀ = P Rᵀ R Pᵀ) in place
  /// of an LU of the whole KKT matrix. false (or allow_arrow false): always that LU (the
  /// reference).
  bool allow_schur = true;
  bool used_schur = false;  ///< whether the last call solved with the Schur complement
};

/// ∂q̈/∂q and ∂q̈/∂q̇ of the last call into `data`, dense: expanded from data.dqdd_dx when the call
/// gave the structured result, else copied from data.lin.
void dqdd_dx_dense(const LinearizeData& data, Mat& dqdd_dq, Mat& dqdd_dqd);

/// out = [∂q̈/∂q  ∂q̈/∂q̇] V for V (2n × k) of the last call into `data`, in O(N k) from the
/// structured result (or a dense product); `scratch` as arrow_response_multiply's.
void dqdd_dx_times(const LinearizeData& data, const Eigen::Ref<const Mat>& V, Eigen::Ref<Mat> out,
                   Mat& scratch);

/// The linearisation at (t, q, q̇, τ) into `data.lin` (see linearize() below for the errors).
void linearize(const System& system, LinearizeData& data, double t, CVecRef q, CVecRef qd,
               CVecRef tau, const UkSettings& settings = {}, LinearizeParts parts = {});

/// The linearisation at (t, q, q̇, τ). Throws ukdyn::Error naming the component when a subsystem,
/// constraint or applied force has no exact derivatives, and std::invalid_argument for wrong
/// sizes. `settings`: the U-K solve the forward call uses (its rank rule decides R).
Linearization linearize(const System& system, double t, CVecRef q, CVecRef qd, CVecRef tau,
                        const UkSettings& settings = {});

/// The components of `system` without exact derivatives ("subsystem 'arm' (mobile_manipulator)",
/// ...); empty when linearize() can run.
std::vector<std::string> components_without_derivatives(const System& system);

}  // namespace ukdyn
