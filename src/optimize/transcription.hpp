// The collocation NLP of a TrajectoryProblem (ukdyn/optimize/trajectory.hpp), independent of the
// solver: variables, bounds, cost, constraints and their exact first derivatives in a fixed sparse
// structure. The IPOPT adapter (ipopt_solver.cpp) and the tests drive it.
#pragma once

#include <vector>

#include "ukdyn/model/linearize.hpp"
#include "ukdyn/optimize/trajectory.hpp"

namespace ukdyn::optimize {

/// Receives the Jacobian blocks in a fixed order (the same for every x): the structure pass
/// records positions, the value pass writes values, the dense pass assembles a matrix (tests).
class JacobianSink {
 public:
  virtual ~JacobianSink() = default;
  virtual void dense(Index row, Index col, const Mat& block) = 0;
  virtual void identity(Index row, Index col, Index size, double scale) = 0;
  virtual void column(Index row, Index col, const Vec& values) = 0;
};

/// What is evaluated at one collocation point for the current x.
struct PointEval {
  Linearization lin;  ///< a = lin.qdd and its derivatives
  Mat dadu;           ///< n × k: ∂a/∂τ B
  Mat dQcdu;          ///< n × k: ∂Qc/∂τ B
  Mat dmudu;          ///< r × k: ∂μ/∂τ B
  Vec phi;            ///< r: Φ_R(q) (knots)
  Vec phid;           ///< r: A_R v + Φ_t (knots; Φ_t of rheonomic rows)
  Mat AR;             ///< r × n
  Mat D;              ///< r × n: ∂(A_R v)/∂q (knots)
  Mat Fq, Fv;     ///< n × n: ∂(A_Rᵀγ^q)/∂q, ∂(A_Rᵀγ^v)/∂q (knots ending an interval)
  Vec wint;       ///< the internal wrenches of the bounded loads (6 per grasp)
  Mat dwint_dq;   ///< ∂w_int/∂q at fixed μ
  Mat dwint_dmu;  ///< ∂w_int/∂μ (r columns: the kept rows' multipliers)
};

class Transcription {
 public:
  explicit Transcription(const TrajectoryProblem& problem);

  [[nodiscard]] Index variables() const { return nv_; }
  [[nodiscard]] Index constraints() const { return ng_; }
  [[nodiscard]] Index points() const { return P_; }
  [[nodiscard]] Index rank() const { return r_; }
  [[nodiscard]] const std::vector<Index>& kept_rows() const { return kept_; }

  void bounds(Vec& x_lower, Vec& x_upper, Vec& g_lower, Vec& g_upper) const;
  [[nodiscard]] Vec initial_guess() const;

  /// Evaluates every point at x (skipped when x is the last one evaluated).
  void evaluate(const Vec& x);
  [[nodiscard]] double cost(const Vec& x);
  void cost_gradient(const Vec& x, Vec& grad);
  void constraint_values(const Vec& x, Vec& g);
  void jacobian(const Vec& x, JacobianSink& sink);
  [[nodiscard]] Index jacobian_nonzeros();

  /// The solution in the problem's terms, with the defects and residuals of x.
  [[nodiscard]] TrajectorySolution solution(const Vec& x);

  // The layout of x (public for the tests).
  [[nodiscard]] Index q_of(Index p) const { return p * stride_; }
  [[nodiscard]] Index v_of(Index p) const { return p * stride_ + n_; }
  [[nodiscard]] Index u_of(Index p) const { return p * stride_ + 2 * n_; }
  [[nodiscard]] Index gq_of(Index i) const { return P_ * stride_ + i * 2 * r_; }
  [[nodiscard]] Index gv_of(Index i) const { return gq_of(i) + r_; }
  [[nodiscard]] Index time_index() const { return nv_ - 1; }
  [[nodiscard]] double duration(const Vec& x) const;

 private:
  /// Where a waypoint is: on a knot (point ≥ 0), or inside interval `interval` with the
  /// interpolant's coefficients of q_a, h v_a, q_b, h v_b.
  struct WaypointPlace {
    Index point = -1, interval = 0;
    double fraction = 0.0;  ///< of the duration
    double c[4] = {0, 0, 0, 0};
  };
  [[nodiscard]] WaypointPlace place_waypoint(const Waypoint& w) const;
  [[nodiscard]] bool hs() const { return problem_.method == CollocationMethod::hermite_simpson; }
  [[nodiscard]] Index knot_point(Index j) const { return hs() ? 2 * j : j; }
  [[nodiscard]] double point_time(const Vec& x, Index p) const;
  [[nodiscard]] Vec quadrature_weights(double h) const;  ///< per point, for ∫ dt
  double running_cost(Index p, const Vec& x, Vec* grad_q, Vec* grad_v, Vec* grad_u) const;
  void interval_values(const Vec& x, Index i, double h, Vec& g) const;
  void interval_jacobian(const Vec& x, Index i, double h, JacobianSink& sink) const;
  void knot_jacobian(Index j, JacobianSink& sink) const;
  void envelope_jacobian(Index p, JacobianSink& sink) const;
  void multiplier_jacobian(Index p, JacobianSink& sink) const;
  void internal_wrenches(const Vec& q, PointEval& e) const;
  /// The |f_int,k|², |m_int,k|² rows of point p (values into g from `row`, or the Jacobian).
  void internal_wrench_rows(Index p, Index& row, Vec* g, JacobianSink* sink) const;
  /// Waypoint w's rows Φ_w at its q (a knot's, or the interpolant's between knots), and (A
  /// non-null) their Jacobian ∂Φ_w/∂q = A_w at that q.
  void waypoint_rows(const Vec& x, std::size_t w, Vec& phi, Mat* A) const;
  /// The waypoint's q between knots: Σ c_k z_k over z = (q_a, h v_a, q_b, h v_b) of its interval.
  [[nodiscard]] Vec waypoint_q(const Vec& x, std::size_t w) const;
  void waypoint_jacobian(const Vec& x, std::size_t w, Index row, JacobianSink& sink) const;
  Mat straight_line_guess(Mat& qd) const;
  void select_multiplier_rows();

  const TrajectoryProblem& problem_;
  Index n_ = 0, k_ = 0, r_ = 0, N_ = 0, P_ = 0, stride_ = 0, nv_ = 0, ng_ = 0;
  std::vector<Index> kept_;
  bool constrain_end_q_ = true, constrain_end_v_ = true;
  Index interval_rows_ = 0, knot_rows_start_ = 0, envelope_rows_start_ = 0;
  Index multiplier_rows_start_ = 0, waypoint_rows_start_ = 0;
  std::vector<WaypointPlace> waypoint_place_;
  Index wint_rows_start_ = 0, wint_rows_per_point_ = 0, wint_size_ = 0;
  /// Positions in kept_ of the rows with multiplier bounds, and of the rows with a weight.
  std::vector<Index> bounded_, weighted_;
  std::vector<Index> knot_row_;  ///< per knot: first row of its manifold rows (−1: none)
  std::vector<bool> knot_phi_, knot_phid_;
  Vec last_x_;
  std::vector<PointEval> eval_;
  ForwardData data_;
  Index nnz_ = -1;
};

}  // namespace ukdyn::optimize
