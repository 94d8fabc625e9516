// Optimal trajectories of a constrained system by direct collocation on the constraint manifold,
// solved by IPOPT (docs/optimization.md).
//
// Decision variables at every collocation point p (knots, and for Hermite–Simpson the interval
// midpoints): q_p, v_p (n each) and the actuator inputs u_p (k, τ = τ₀ + B u); per interval two
// manifold corrections γ^q, γ^v (r each, r = the independent constraint rows R); optionally the
// duration T. The dynamics at a point is the U-K acceleration a_p = q̈(q_p, v_p, τ₀ + B u_p), which
// keeps the constraints at acceleration level, A a = b; the position and velocity levels,
// Φ_R(q_j, t_j) = 0 and A_R(q_j) v_j + Φ_t,R = 0 (Φ_t: rheonomic rows), at every knot j. Because a collocation step does
// not stay on the manifold, these conditions and the defects together are over-determined; the
// corrections γ make the system square again (Posa, Kuindersma & Tedrake, "Optimization and
// stabilization of trajectories for constrained dynamical systems", ICRA 2016, Eq. (11)–(14)):
//   trapezoidal, interval [a, b], h = T/N:
//     q_b − q_a − h/2 (v_a + v_b) − A_R(q_b)ᵀ γ^q = 0,
//     v_b − v_a − h/2 (a_a + a_b) − A_R(q_b)ᵀ γ^v = 0;
//   Hermite–Simpson (separated form, Betts, "Practical Methods for Optimal Control", 2010, §4.6),
//   with the midpoint c:
//     q_c − (q_a + q_b)/2 − h/8 (v_a − v_b) = 0,   v_c − (v_a + v_b)/2 − h/8 (a_a − a_b) = 0,
//     q_b − q_a − h/6 (v_a + 4 v_c + v_b) − A_R(q_b)ᵀ γ^q = 0,
//     v_b − v_a − h/6 (a_a + 4 a_c + a_b) − A_R(q_b)ᵀ γ^v = 0.
// γ vanishes as the steps shrink (O(h³) trapezoidal, O(h⁵) Hermite–Simpson) and is reported.
// Every Jacobian entry is exact: ∂a/∂(q, v, τ) from linearize(), A_R, ∂(A_R v)/∂q and
// ∂(A_Rᵀγ)/∂q from the constraints' tangents (constraint_jacobians.hpp). IPOPT approximates the
// Hessian of the Lagrangian by L-BFGS.
#pragma once

#include <atomic>
#include <functional>
#include <limits>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "ukdyn/model/system.hpp"

namespace ukdyn {

enum class CollocationMethod { trapezoidal, hermite_simpson };
std::string to_string(CollocationMethod method);

/// |u_j| ≤ u_max (1 − |ω_j| / ω_max), ω_j = (Bᵀ v)_j the actuator's speed: a linear torque–speed
/// envelope (a DC motor's), as four linear inequalities per point.
struct TorqueSpeedEnvelope {
  Index actuator = 0;
  double u_max = 0.0;
  double speed_max = 0.0;
};

/// Weights of the cost, integrated by the method's own quadrature (trapezoidal; Simpson).
struct TrajectoryCosts {
  Vec effort;                     ///< k weights W_j of ∫ Σ W_j u_j² dt (empty: no effort term)
  double power = 0.0;             ///< weight of ∫ (uᵀ Bᵀ v)² dt (mechanical power squared)
  double constraint_force = 0.0;  ///< weight of ∫ ‖Qc‖² dt (all constraint forces)
  /// m weights (one per constraint row; empty: none) of ∫ Σ w_i μ_i² dt, μ the row's multiplier
  /// (Qc = A_Rᵀ μ): the force one row carries, e.g. a grasp's force components. Rows with a
  /// positive weight must be independent (kept by the rank rule).
  Vec multiplier;
  double smoothness = 0.0;  ///< weight of Σ ‖u_{j+1} − u_j‖² / h over the knots (≈ ∫‖u̇‖² h)
  double duration = 0.0;  ///< weight of T (free duration only)
};

/// A waypoint: the position-level rows Φ_w(q) = 0 of a holonomic constraint, imposed at time t
/// (from t0, fixed duration) or at the fraction `fraction` of the duration (fixed or free; when
/// finite it is used, else t). On a knot the rows hold at the knot's q; between knots at the
/// method's own state interpolant on that interval (Hermite–Simpson: the cubic Hermite through
/// q_a, v_a, q_b, v_b; trapezoidal: the quadratic q_a + v_a s + (v_b − v_a) s²/(2h)). A frame (a
/// chain's link or point, a definitions body, a free body) through a given position is a ball
/// constraint between the frame and a world frame at that position; with an orientation too, a
/// weld (ukdyn/scenario/optimization_file.hpp builds them). Its Jacobian is the constraint's own A
/// times the interpolant's coefficients.
struct Waypoint {
  std::string name;
  std::shared_ptr<const Constraint> rows;
  double t = 0.0;
  double fraction = std::numeric_limits<double>::quiet_NaN();
};

/// A bound on the internal (squeeze) wrench of a load held by two or more welds, by [Walker1991]'s
/// decomposition w_int = (I − G⁺G) w of the grasp wrenches w (ukdyn/core/constraint_forces.hpp):
/// per grasp k, |f_int,k|² ≤ max_force² and |m_int,k|² ≤ max_torque² at every point (+inf:
/// none). `walker` gives w_int (6 grasps: [f; m] per grasp, world axes, moment about the grasp) at
/// q and the multipliers λ of every constraint row (m), linear in λ (∂w_int/∂λ is taken exactly
/// by unit λ); `walker_dq` gives w_int and its ∂w_int/∂q at fixed λ (6 grasps × n): exact, also
/// along quaternion coordinates (docs/optimization.md), but for the `differenced` columns.
struct InternalWrenchBound {
  std::string load;
  Index grasps = 0;
  std::vector<std::string> grasp_names;  ///< the welds' names (the CSV's Wint_walker_<name>_*)
  std::function<void(CVecRef q, CVecRef lambda, VecRef w_int)> walker;
  std::function<void(CVecRef q, CVecRef lambda, VecRef w_int, Mat& dw_int_dq)> walker_dq;
  /// the columns of walker_dq by central differences: coordinates that scale a grasp frame's
  /// rotation other than a quaternion's (none in the shipped problems)
  std::vector<Index> differenced;
  double max_force = std::numeric_limits<double>::infinity();
  double max_torque = std::numeric_limits<double>::infinity();
};

struct TrajectoryProblem {
  std::shared_ptr<const System> system;
  Mat B;                                    ///< n × k: τ = tau + B u
  std::vector<std::string> actuator_names;  ///< k
  Vec tau;                                  ///< n: constant generalized forces besides B u
  CollocationMethod method = CollocationMethod::hermite_simpson;
  Index intervals = 50;  ///< N
  double t0 = 0.0;
  double duration = 1.0;  ///< T (the initial guess when free_duration)
  bool free_duration = false;
  double min_duration = 0.0, max_duration = std::numeric_limits<double>::infinity();
  Vec q_start, qd_start;  ///< n each: the fixed start (on the manifold)
  Vec q_end, qd_end;      ///< n each; a NaN entry is free
  /// Bounds at every point; empty: none. n, n and k entries (±inf allowed).
  Vec q_lower, q_upper, qd_lower, qd_upper, u_lower, u_upper;
  std::vector<TorqueSpeedEnvelope> envelopes;
  /// Bounds on the multipliers μ_i of constraint rows at every point (m entries each, ±inf:
  /// none; empty: no bounds): grasp forces, the squeeze force of a weld row. A bounded row must be
  /// independent (kept by the rank rule), else its multiplier is not determined.
  Vec multiplier_lower, multiplier_upper;
  /// Bound on every correction |γ| (+inf: none). A resolved trajectory has γ = O(h³); a large γ
  /// lets the knots jump across the manifold (to another branch of the constraints' roots).
  double max_correction = std::numeric_limits<double>::infinity();
  TrajectoryCosts costs;
  std::vector<Waypoint> waypoints;
  std::vector<InternalWrenchBound> internal_wrench_bounds;
  /// Initial guess at the collocation points (rows: points, as TrajectorySolution::t); empty: the
  /// straight line in q from start to end, each point assembled onto the manifold, u = 0.
  Mat q_guess, qd_guess, u_guess;
  UkSettings uk;
};

struct IpoptSettings {
  double tol = 1e-8;               ///< IPOPT's `tol` (scaled KKT error)
  double dual_inf_tol = 1e-8;      ///< IPOPT's `dual_inf_tol`
  double constr_viol_tol = 1e-10;  ///< IPOPT's `constr_viol_tol` (max defect / manifold residual)
  int max_iter = 1000;
  int lbfgs_memory = 10;
  int print_level = 0;  ///< IPOPT's console output (0: none)
  /// Any other IPOPT option by name, after ukdyn's own (IPOPT checks names and values; a bad one
  /// ends the solve with status Invalid_Option).
  std::vector<std::pair<std::string, std::string>> string_options;
  std::vector<std::pair<std::string, int>> integer_options;
  std::vector<std::pair<std::string, double>> numeric_options;
  /// Set (from a signal handler or another thread) to stop the solve at IPOPT's next iteration:
  /// the iterate so far is returned, status User_Requested_Stop, not trusted. Null: never.
  const std::atomic<bool>* cancel = nullptr;
};

/// Adds `name` = `text` to the extra options of `settings` as the type IPOPT registers for it (a
/// whole number, a number or a string; `number`: the text's value when it is a finite number, else
/// null). Returns why not (empty when added): no such option, a value of the wrong type or out of
/// its range, or an option that makes IPOPT read or write a file or load a library (output_file,
/// option_file_name, hsllib, pardisolib: a problem file chooses no file ukdyn does not check).
/// Without IPOPT: added as a whole number, a number or a string by the text alone.
std::string add_ipopt_option(IpoptSettings& settings, const std::string& name,
                             const std::string& text, const double* number);

struct TrajectorySolution {
  Vec t;                   ///< times of the collocation points
  std::vector<bool> knot;  ///< per point: a knot (false: a Hermite–Simpson midpoint)
  Mat q, qd, qdd, u, Qc;   ///< rows: points; q, qd, qdd, Qc n columns, u k columns
  Mat mu;                  ///< rows: points; the multipliers of the kept rows (kept_rows)
  /// rows: points; per internal-wrench bound its 6 grasps Walker values (in order of the bounds)
  Mat internal_wrench;
  double duration = 0.0;
  double cost = 0.0;
  double max_defect = 0.0;             ///< max |collocation equation| over every interval
  double max_position_residual = 0.0;  ///< max |Φ_R(q_j)| over the knots
  double max_velocity_residual = 0.0;  ///< max |A_R(q_j) v_j| over the knots
  double max_correction = 0.0;         ///< max |γ| (the manifold corrections, → 0 as h → 0)
  /// max over intervals of |A_Rᵀγ| / |step| (position and velocity): > 0.1 is not trusted
  double max_correction_ratio = 0.0;
  /// max |Φ_w| over the waypoints (at their times; 0 without waypoints)
  double max_waypoint_residual = 0.0;
  std::vector<Index> kept_rows;  ///< R
  std::string status;            ///< IPOPT's return status, e.g. "Solve_Succeeded"
  bool converged = false;        ///< IPOPT met its tolerances
  int iterations = 0;
  double dual_infeasibility = 0.0, constraint_violation = 0.0, complementarity = 0.0;
  double kkt_error = 0.0;  ///< IPOPT's overall NLP error (unscaled)
  /// False when ukdyn cannot vouch for the result: not converged, or linearize() did not trust its
  /// derivatives at some point (a rank change); `message` says which.
  bool trusted = false;
  std::string message;
};

/// Whether this build has IPOPT (coinor-libipopt-dev).
bool ipopt_available();

/// Checks the problem (sizes, bounds, the boundary states on the manifold, exact derivatives of
/// every component) and throws ukdyn::Error naming what is wrong.
void validate(const TrajectoryProblem& problem);

/// Solves the problem. Throws ukdyn::Error for a bad problem or a build without IPOPT; an
/// unconverged or infeasible solve returns with converged = false and IPOPT's status.
TrajectorySolution optimize_trajectory(const TrajectoryProblem& problem,
                                       const IpoptSettings& settings = {});

}  // namespace ukdyn
