// The collocation NLP (transcription.hpp; the equations in ukdyn/optimize/trajectory.hpp).
#include "optimize/transcription.hpp"

#include <algorithm>
#include <cmath>

#include "ukdyn/model/constraint_jacobians.hpp"
#include "ukdyn/simulate/simulate.hpp"

namespace ukdyn::optimize {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

Vec or_fill(const Vec& v, Index n, double fill) {
  return v.size() == 0 ? Vec::Constant(n, fill) : v;
}

// The coefficients of (q_a, h v_a, q_b, h v_b) in the method's state interpolant at the fraction
// tau of an interval: Hermite–Simpson's cubic Hermite (H00, H10, H01, H11), or the trapezoidal
// method's quadratic q_a + h (tau v_a + tau²/2 (v_b − v_a)) (its q̇ linear between v_a and v_b)
// (Kelly, "An introduction to trajectory optimization", SIAM Review 59(4), 2017, §3.4, §4.4).
void interpolant_coefficients(bool hermite_simpson, double tau, double c[4]) {
  const double t2 = tau * tau, t3 = t2 * tau;
  if (hermite_simpson) {
    c[0] = 2 * t3 - 3 * t2 + 1, c[1] = t3 - 2 * t2 + tau, c[2] = -2 * t3 + 3 * t2, c[3] = t3 - t2;
  } else {
    c[0] = 1.0, c[1] = tau - 0.5 * t2, c[2] = 0.0, c[3] = 0.5 * t2;
  }
}

}  // namespace

Transcription::Transcription(const TrajectoryProblem& problem)
    : problem_(problem), data_(*problem.system) {
  validate(problem);
  const System& sys = *problem.system;
  n_ = sys.dof();
  k_ = problem.B.cols();
  N_ = problem.intervals;
  P_ = hs() ? 2 * N_ + 1 : N_ + 1;
  stride_ = 2 * n_ + k_;
  // The independent rows R, chosen once at the start (the rank is assumed constant along the
  // path; every point's linearize() checks it and the solution says where it is not).
  const Linearization lin0 =
      linearize(sys, problem.t0, problem.q_start, problem.qd_start, problem.tau, problem.uk);
  kept_ = lin0.kept_rows;
  r_ = static_cast<Index>(kept_.size());
  nv_ = P_ * stride_ + N_ * 2 * r_ + (problem.free_duration ? 1 : 0);
  constrain_end_q_ = !problem.q_end.allFinite();
  constrain_end_v_ = constrain_end_q_ || !problem.qd_end.allFinite();
  interval_rows_ = (hs() ? 4 : 2) * n_;
  knot_rows_start_ = N_ * interval_rows_;
  Index row = knot_rows_start_;
  knot_row_.assign(static_cast<std::size_t>(N_ + 1), -1);
  knot_phi_.assign(static_cast<std::size_t>(N_ + 1), false);
  knot_phid_.assign(static_cast<std::size_t>(N_ + 1), false);
  for (Index j = 1; j <= N_; ++j) {
    const auto js = static_cast<std::size_t>(j);
    knot_phi_[js] = j < N_ || constrain_end_q_;
    knot_phid_[js] = j < N_ || constrain_end_v_;
    knot_row_[js] = row;
    row += (knot_phi_[js] ? r_ : 0) + (knot_phid_[js] ? r_ : 0);
  }
  envelope_rows_start_ = row;
  multiplier_rows_start_ = row + 4 * static_cast<Index>(problem.envelopes.size()) * P_;
  select_multiplier_rows();
  ng_ = multiplier_rows_start_ + static_cast<Index>(bounded_.size()) * P_;
  waypoint_rows_start_ = ng_;
  for (const auto& w : problem.waypoints) {
    waypoint_place_.push_back(place_waypoint(w));
    ng_ += w.rows->rows();
  }
  wint_rows_start_ = ng_;
  for (const auto& b : problem.internal_wrench_bounds) {
    wint_size_ += 6 * b.grasps;
    wint_rows_per_point_ +=
        b.grasps * ((std::isfinite(b.max_force) ? 1 : 0) + (std::isfinite(b.max_torque) ? 1 : 0));
  }
  ng_ += wint_rows_per_point_ * P_;
  eval_.resize(static_cast<std::size_t>(P_));
}

// The kept positions of the rows that carry a multiplier bound or weight; a row that the rank rule
// dropped has no determined multiplier and is refused by name.
void Transcription::select_multiplier_rows() {
  const auto& pr = problem_;
  const auto& names = pr.system->constraint_row_names();
  auto position = [&](Index row) {
    const auto it = std::find(kept_.begin(), kept_.end(), row);
    if (it == kept_.end())
      throw Error("optimize: constraint row '" + names[static_cast<std::size_t>(row)] +
                  "' is redundant at the start (the rank rule dropped it): its force is not "
                  "determined, so it can carry no bound or cost");
    return static_cast<Index>(it - kept_.begin());
  };
  for (Index i = 0; i < pr.multiplier_lower.size(); ++i)
    if (std::isfinite(pr.multiplier_lower(i)) || std::isfinite(pr.multiplier_upper(i)))
      bounded_.push_back(position(i));
  for (Index i = 0; i < pr.costs.multiplier.size(); ++i)
    if (pr.costs.multiplier(i) > 0.0) weighted_.push_back(position(i));
}

double Transcription::duration(const Vec& x) const {
  return problem_.free_duration ? x(time_index()) : problem_.duration;
}

double Transcription::point_time(const Vec& x, Index p) const {
  const double h = duration(x) / static_cast<double>(N_);
  return problem_.t0 + (hs() ? 0.5 * h : h) * static_cast<double>(p);
}

Vec Transcription::quadrature_weights(double h) const {
  Vec w(P_);
  if (hs()) {  // Simpson: h/6 (1, 4, 1) per interval
    for (Index p = 0; p < P_; ++p) w(p) = (p % 2 == 1) ? 4.0 * h / 6.0 : 2.0 * h / 6.0;
  } else {
    w.setConstant(h);
  }
  w(0) *= 0.5;
  w(P_ - 1) *= 0.5;
  return w;
}

void Transcription::bounds(Vec& xl, Vec& xu, Vec& gl, Vec& gu) const {
  const auto& pr = problem_;
  xl.setConstant(nv_, -kInf);
  xu.setConstant(nv_, kInf);
  const Vec ql = or_fill(pr.q_lower, n_, -kInf), qu = or_fill(pr.q_upper, n_, kInf);
  const Vec vl = or_fill(pr.qd_lower, n_, -kInf), vu = or_fill(pr.qd_upper, n_, kInf);
  const Vec ul = or_fill(pr.u_lower, k_, -kInf), uu = or_fill(pr.u_upper, k_, kInf);
  for (Index p = 0; p < P_; ++p) {
    xl.segment(q_of(p), n_) = ql;
    xu.segment(q_of(p), n_) = qu;
    xl.segment(v_of(p), n_) = vl;
    xu.segment(v_of(p), n_) = vu;
    xl.segment(u_of(p), k_) = ul;
    xu.segment(u_of(p), k_) = uu;
  }
  xl.segment(q_of(0), n_) = xu.segment(q_of(0), n_) = pr.q_start;
  xl.segment(v_of(0), n_) = xu.segment(v_of(0), n_) = pr.qd_start;
  for (Index i = 0; i < n_; ++i) {
    if (std::isfinite(pr.q_end(i))) xl(q_of(P_ - 1) + i) = xu(q_of(P_ - 1) + i) = pr.q_end(i);
    if (std::isfinite(pr.qd_end(i))) xl(v_of(P_ - 1) + i) = xu(v_of(P_ - 1) + i) = pr.qd_end(i);
  }
  if (std::isfinite(pr.max_correction) && r_ > 0) {
    xl.segment(gq_of(0), N_ * 2 * r_).setConstant(-pr.max_correction);
    xu.segment(gq_of(0), N_ * 2 * r_).setConstant(pr.max_correction);
  }
  if (pr.free_duration) {
    xl(time_index()) = pr.min_duration;
    xu(time_index()) = pr.max_duration;
  }
  gl.setZero(ng_);
  gu.setZero(ng_);
  for (Index p = 0; p < P_; ++p)
    for (std::size_t b = 0; b < bounded_.size(); ++b) {
      const Index row =
          multiplier_rows_start_ + p * static_cast<Index>(bounded_.size()) + static_cast<Index>(b);
      const Index orig = kept_[static_cast<std::size_t>(bounded_[b])];
      gl(row) = pr.multiplier_lower(orig);
      gu(row) = pr.multiplier_upper(orig);
    }
  for (Index p = 0, row = wint_rows_start_; p < P_; ++p)
    for (const auto& b : pr.internal_wrench_bounds)
      for (Index k = 0; k < b.grasps; ++k)
        for (const double bound : {b.max_force, b.max_torque})
          if (std::isfinite(bound)) {
            gl(row) = -kInf;
            gu(row++) = bound * bound;
          }
  for (Index row = envelope_rows_start_; row < multiplier_rows_start_; ++row) {
    const auto e = static_cast<std::size_t>((row - envelope_rows_start_) / 4 %
                                            static_cast<Index>(pr.envelopes.size()));
    gl(row) = -kInf;
    gu(row) = pr.envelopes[e].u_max;
  }
}

Mat Transcription::straight_line_guess(Mat& qd) const {
  const auto& pr = problem_;
  Vec q_end = pr.q_end;
  for (Index i = 0; i < n_; ++i)
    if (!std::isfinite(q_end(i))) q_end(i) = pr.q_start(i);
  const Vec slope = (q_end - pr.q_start) / pr.duration;
  Mat q(P_, n_);
  qd.resize(P_, n_);
  const std::vector<bool> held(static_cast<std::size_t>(n_), false);
  for (Index p = 0; p < P_; ++p) {
    const double s = static_cast<double>(p) / static_cast<double>(P_ - 1);
    const Vec line = (1.0 - s) * pr.q_start + s * q_end;
    const AssemblyResult a =
        assemble(*pr.system, pr.t0 + s * pr.duration, line, slope, held, 1e-13);
    q.row(p) = (a.success ? a.q : line).transpose();
    qd.row(p) = (a.success ? a.qd : slope).transpose();
  }
  q.row(0) = pr.q_start.transpose();
  qd.row(0) = pr.qd_start.transpose();
  return q;
}

Vec Transcription::initial_guess() const {
  const auto& pr = problem_;
  Vec x = Vec::Zero(nv_);
  Mat qd;
  const Mat q = pr.q_guess.size() ? pr.q_guess : straight_line_guess(qd);
  if (pr.qd_guess.size())
    qd = pr.qd_guess;
  else if (pr.q_guess.size())
    qd.setZero(P_, n_);
  for (Index p = 0; p < P_; ++p) {
    x.segment(q_of(p), n_) = q.row(p).transpose();
    x.segment(v_of(p), n_) = qd.row(p).transpose();
    if (pr.u_guess.size()) x.segment(u_of(p), k_) = pr.u_guess.row(p).transpose();
  }
  if (pr.free_duration) x(time_index()) = pr.duration;
  return x;
}

void Transcription::evaluate(const Vec& x) {
  if (last_x_.size() == x.size() && last_x_ == x) return;
  const auto& pr = problem_;
  const System& sys = *pr.system;
  const Index m = sys.rows();
  Vec phi_full(m), phid_full(m), tau(n_);
  for (Index p = 0; p < P_; ++p) {
    PointEval& e = eval_[static_cast<std::size_t>(p)];
    const double t = point_time(x, p);
    const auto q = x.segment(q_of(p), n_), v = x.segment(v_of(p), n_);
    tau = pr.tau + pr.B * x.segment(u_of(p), k_);
    e.lin = linearize(sys, t, q, v, tau, pr.uk);
    e.dadu = e.lin.dqdd_dtau * pr.B;
    if (pr.costs.constraint_force > 0.0) e.dQcdu = e.lin.dQc_dtau * pr.B;
    if (!bounded_.empty() || !weighted_.empty() || wint_size_ > 0) e.dmudu = e.lin.dmu_dtau * pr.B;
    if (wint_size_ > 0) internal_wrenches(q, e);
    const bool is_knot = !hs() || p % 2 == 0;
    if (!is_knot) continue;
    const Index j = hs() ? p / 2 : p;
    position_residuals(sys, data_, t, q, phi_full);
    velocity_residuals(sys, data_, t, q, v, phid_full);  // A v + Φ_t (rheonomic rows: Φ_t ≠ 0)
    evaluate_dynamics(sys, data_, t, q, v);  // the subsystems' slots the constraints read
    evaluate_constraints(sys, data_, t, q, v);
    e.phi.resize(r_);
    e.phid.resize(r_);
    e.AR.resize(r_, n_);
    for (Index i = 0; i < r_; ++i) {
      e.phi(i) = phi_full(kept_[static_cast<std::size_t>(i)]);
      e.phid(i) = phid_full(kept_[static_cast<std::size_t>(i)]);
      e.AR.row(i) = data_.A.row(kept_[static_cast<std::size_t>(i)]);
    }
    if (j >= 1) {
      std::vector<Mat> forces;
      constraint_state_jacobians(sys, data_, t, q, v, kept_,
                                 {x.segment(gq_of(j - 1), r_), x.segment(gv_of(j - 1), r_)}, e.D,
                                 forces);
      e.Fq = std::move(forces[0]);
      e.Fv = std::move(forces[1]);
    }
  }
  last_x_ = x;
}

// The bounded loads' internal wrenches at (q, μ) and their derivatives: ∂/∂μ exactly (w_int is
// linear in the multipliers: one evaluation per kept row at a unit multiplier), ∂/∂q at fixed μ by
// walker_dq (the weld maps' derivatives and Walker's projection's, [GolubPereyra1973]; central
// differences in the columns of quaternion coordinates).
void Transcription::internal_wrenches(const Vec& q, PointEval& e) const {
  const auto& bounds = problem_.internal_wrench_bounds;
  const Index m = problem_.system->rows();
  Vec lambda = Vec::Zero(m);
  for (Index i = 0; i < r_; ++i) lambda(kept_[static_cast<std::size_t>(i)]) = e.lin.mu(i);
  e.wint.resize(wint_size_);
  e.dwint_dq.resize(wint_size_, n_);
  e.dwint_dmu.resize(wint_size_, r_);
  Vec unit = Vec::Zero(m);
  Mat d;
  Index off = 0;
  for (const auto& b : bounds) {
    const Index rows = 6 * b.grasps;
    b.walker_dq(q, lambda, e.wint.segment(off, rows), d);
    e.dwint_dq.middleRows(off, rows) = d;
    for (Index i = 0; i < r_; ++i) {
      unit(kept_[static_cast<std::size_t>(i)]) = 1.0;
      b.walker(q, unit, e.dwint_dmu.col(i).segment(off, rows));
      unit(kept_[static_cast<std::size_t>(i)]) = 0.0;
    }
    off += rows;
  }
}

void Transcription::internal_wrench_rows(Index p, Index& row, Vec* g, JacobianSink* sink) const {
  const PointEval& e = eval_[static_cast<std::size_t>(p)];
  Index off = 0;
  for (const auto& b : problem_.internal_wrench_bounds) {
    for (Index k = 0; k < b.grasps; ++k, off += 6) {
      for (const Index part : {0, 3}) {  // force, moment
        if (!std::isfinite(part == 0 ? b.max_force : b.max_torque)) continue;
        const auto w = e.wint.segment(off + part, 3);
        if (g) (*g)(row) = w.squaredNorm();
        if (sink) {  // 2 wᵀ ∂w/∂x, through μ(q, v, u) and q directly
          const Vec dmu = 2.0 * e.dwint_dmu.middleRows(off + part, 3).transpose() * w;
          const Vec dq = 2.0 * e.dwint_dq.middleRows(off + part, 3).transpose() * w;
          sink->dense(row, q_of(p), (dq + e.lin.dmu_dq.transpose() * dmu).transpose());
          sink->dense(row, v_of(p), (e.lin.dmu_dqd.transpose() * dmu).transpose());
          if (k_ > 0) sink->dense(row, u_of(p), (e.dmudu.transpose() * dmu).transpose());
        }
        ++row;
      }
    }
  }
}

double Transcription::running_cost(Index p, const Vec& x, Vec* gq, Vec* gv, Vec* gu) const {
  const auto& c = problem_.costs;
  const PointEval& e = eval_[static_cast<std::size_t>(p)];
  const auto u = x.segment(u_of(p), k_), v = x.segment(v_of(p), n_);
  double L = 0.0;
  if (gq) gq->setZero(n_), gv->setZero(n_), gu->setZero(k_);
  if (c.effort.size()) {
    L += (c.effort.array() * u.array().square()).sum();
    if (gu) *gu += 2.0 * c.effort.cwiseProduct(u);
  }
  if (c.power > 0.0) {
    const Vec omega = problem_.B.transpose() * v;
    const double s = u.dot(omega);
    L += c.power * s * s;
    if (gu) {
      *gu += 2.0 * c.power * s * omega;
      *gv += 2.0 * c.power * s * (problem_.B * u);
    }
  }
  if (c.constraint_force > 0.0) {
    const Vec& Qc = e.lin.Qc;
    L += c.constraint_force * Qc.squaredNorm();
    if (gq) {
      *gq += 2.0 * c.constraint_force * e.lin.dQc_dq.transpose() * Qc;
      *gv += 2.0 * c.constraint_force * e.lin.dQc_dqd.transpose() * Qc;
      *gu += 2.0 * c.constraint_force * e.dQcdu.transpose() * Qc;
    }
  }
  for (const Index k : weighted_) {
    const double w = c.multiplier(kept_[static_cast<std::size_t>(k)]), mu = e.lin.mu(k);
    L += w * mu * mu;
    if (gq) {
      *gq += 2.0 * w * mu * e.lin.dmu_dq.row(k).transpose();
      *gv += 2.0 * w * mu * e.lin.dmu_dqd.row(k).transpose();
      *gu += 2.0 * w * mu * e.dmudu.row(k).transpose();
    }
  }
  return L;
}

double Transcription::cost(const Vec& x) {
  evaluate(x);
  const double T = duration(x), h = T / static_cast<double>(N_);
  const Vec w = quadrature_weights(h);
  double J = 0.0;
  for (Index p = 0; p < P_; ++p) J += w(p) * running_cost(p, x, nullptr, nullptr, nullptr);
  if (problem_.costs.smoothness > 0.0) {
    for (Index j = 0; j < N_; ++j) {
      const Vec du = x.segment(u_of(knot_point(j + 1)), k_) - x.segment(u_of(knot_point(j)), k_);
      J += problem_.costs.smoothness * du.squaredNorm() / h;
    }
  }
  if (problem_.free_duration) J += problem_.costs.duration * T;
  return J;
}

void Transcription::cost_gradient(const Vec& x, Vec& grad) {
  evaluate(x);
  grad.setZero(nv_);
  const double T = duration(x), h = T / static_cast<double>(N_);
  const Vec w = quadrature_weights(h);
  Vec gq(n_), gv(n_), gu(k_);
  double dJdT = 0.0;
  for (Index p = 0; p < P_; ++p) {
    const double L = running_cost(p, x, &gq, &gv, &gu);
    grad.segment(q_of(p), n_) += w(p) * gq;
    grad.segment(v_of(p), n_) += w(p) * gv;
    grad.segment(u_of(p), k_) += w(p) * gu;
    dJdT += w(p) / T * L;  // w_p ∝ h = T/N
  }
  if (const double s = problem_.costs.smoothness; s > 0.0) {
    for (Index j = 0; j < N_; ++j) {
      const Index a = u_of(knot_point(j)), b = u_of(knot_point(j + 1));
      const Vec du = x.segment(b, k_) - x.segment(a, k_);
      grad.segment(b, k_) += 2.0 * s * du / h;
      grad.segment(a, k_) -= 2.0 * s * du / h;
      dJdT -= s * du.squaredNorm() / (h * T);
    }
  }
  if (problem_.free_duration) grad(time_index()) = dJdT + problem_.costs.duration;
}

void Transcription::interval_values(const Vec& x, Index i, double h, Vec& g) const {
  const Index a = knot_point(i), b = knot_point(i + 1), row = i * interval_rows_;
  auto q = [&](Index p) { return x.segment(q_of(p), n_); };
  auto v = [&](Index p) { return x.segment(v_of(p), n_); };
  auto acc = [&](Index p) -> const Vec& { return eval_[static_cast<std::size_t>(p)].lin.qdd; };
  const Mat& ARb = eval_[static_cast<std::size_t>(b)].AR;
  const auto gq = x.segment(gq_of(i), r_), gv = x.segment(gv_of(i), r_);
  if (!hs()) {
    g.segment(row, n_) = q(b) - q(a) - 0.5 * h * (v(a) + v(b)) - ARb.transpose() * gq;
    g.segment(row + n_, n_) = v(b) - v(a) - 0.5 * h * (acc(a) + acc(b)) - ARb.transpose() * gv;
    return;
  }
  const Index c = a + 1;
  g.segment(row, n_) = q(c) - 0.5 * (q(a) + q(b)) - h / 8.0 * (v(a) - v(b));
  g.segment(row + n_, n_) = v(c) - 0.5 * (v(a) + v(b)) - h / 8.0 * (acc(a) - acc(b));
  g.segment(row + 2 * n_, n_) =
      q(b) - q(a) - h / 6.0 * (v(a) + 4.0 * v(c) + v(b)) - ARb.transpose() * gq;
  g.segment(row + 3 * n_, n_) =
      v(b) - v(a) - h / 6.0 * (acc(a) + 4.0 * acc(c) + acc(b)) - ARb.transpose() * gv;
}

void Transcription::constraint_values(const Vec& x, Vec& g) {
  evaluate(x);
  g.setZero(ng_);
  const double h = duration(x) / static_cast<double>(N_);
  for (Index i = 0; i < N_; ++i) interval_values(x, i, h, g);
  for (Index j = 1; j <= N_; ++j) {
    const auto js = static_cast<std::size_t>(j);
    const PointEval& e = eval_[static_cast<std::size_t>(knot_point(j))];
    Index row = knot_row_[js];
    if (knot_phi_[js]) g.segment(row, r_) = e.phi, row += r_;
    if (knot_phid_[js]) g.segment(row, r_) = e.phid;
  }
  Index row = envelope_rows_start_;
  for (Index p = 0; p < P_; ++p) {
    for (const auto& env : problem_.envelopes) {
      const double u = x(u_of(p) + env.actuator);
      const double omega = problem_.B.col(env.actuator).dot(x.segment(v_of(p), n_));
      const double c = env.u_max / env.speed_max;
      for (const double s1 : {1.0, -1.0})
        for (const double s2 : {1.0, -1.0}) g(row++) = s1 * u + s2 * c * omega;
    }
  }
  for (Index p = 0; p < P_; ++p)
    for (const Index k : bounded_) g(row++) = eval_[static_cast<std::size_t>(p)].lin.mu(k);
  Vec phi;
  for (std::size_t w = 0; w < waypoint_place_.size(); ++w) {
    waypoint_rows(x, w, phi, nullptr);
    g.segment(row, phi.size()) = phi;
    row += phi.size();
  }
  for (Index p = 0; p < P_ && wint_rows_per_point_ > 0; ++p)
    internal_wrench_rows(p, row, &g, nullptr);
}

// A waypoint at a knot (to 1e-9 of a step) is imposed there; between knots on its interval's
// interpolant, at the same fraction of the interval whatever T (so T enters through h only).
Transcription::WaypointPlace Transcription::place_waypoint(const Waypoint& w) const {
  WaypointPlace at;
  at.fraction = std::isnan(w.fraction) ? w.t / problem_.duration : w.fraction;
  const double steps = at.fraction * static_cast<double>(N_), knot = std::round(steps);
  if (std::abs(steps - knot) <= 1e-9 * static_cast<double>(N_)) {
    at.point = knot_point(static_cast<Index>(knot));
    return at;
  }
  at.interval = std::min<Index>(static_cast<Index>(std::floor(steps)), N_ - 1);
  interpolant_coefficients(hs(), steps - static_cast<double>(at.interval), at.c);
  return at;
}

Vec Transcription::waypoint_q(const Vec& x, std::size_t w) const {
  const WaypointPlace& at = waypoint_place_[w];
  if (at.point >= 0) return x.segment(q_of(at.point), n_);
  const Index a = knot_point(at.interval), b = knot_point(at.interval + 1);
  const double h = duration(x) / static_cast<double>(N_);
  return at.c[0] * x.segment(q_of(a), n_) + at.c[1] * h * x.segment(v_of(a), n_) +
         at.c[2] * x.segment(q_of(b), n_) + at.c[3] * h * x.segment(v_of(b), n_);
}

void Transcription::waypoint_rows(const Vec& x, std::size_t w, Vec& phi, Mat* A) const {
  const Constraint& c = *problem_.waypoints[w].rows;
  ConstraintContext ctx;
  ctx.t = problem_.t0 + waypoint_place_[w].fraction * duration(x);
  const Vec q = waypoint_q(x, w);
  phi.resize(c.rows());
  c.position_residual(ctx, q, phi);
  if (!A) return;
  // A holonomic row's A is ∂Φ/∂q (b is not needed: evaluated at q̇ = 0).
  A->setZero(c.rows(), n_);
  Vec b(c.rows());
  c.evaluate(ctx, q, Vec::Zero(n_), *A, b);
}

// ∂Φ_w/∂x = A_w ∂q_w/∂x: at a knot its q; between knots the interpolant's coefficients of q_a,
// v_a, q_b, v_b (times h for the velocities), and along a free T, h = T/N in the velocity terms.
void Transcription::waypoint_jacobian(const Vec& x, std::size_t w, Index row,
                                      JacobianSink& sink) const {
  const WaypointPlace& at = waypoint_place_[w];
  Vec phi;
  Mat A;
  waypoint_rows(x, w, phi, &A);
  if (at.point >= 0) {
    sink.dense(row, q_of(at.point), A);
    return;
  }
  const Index a = knot_point(at.interval), b = knot_point(at.interval + 1);
  const double h = duration(x) / static_cast<double>(N_);
  sink.dense(row, q_of(a), at.c[0] * A);
  sink.dense(row, v_of(a), at.c[1] * h * A);
  if (hs()) sink.dense(row, q_of(b), at.c[2] * A);  // (the trapezoidal quadratic has no q_b)
  sink.dense(row, v_of(b), at.c[3] * h * A);
  if (problem_.free_duration)
    sink.column(row, time_index(),
                A * (at.c[1] * x.segment(v_of(a), n_) + at.c[3] * x.segment(v_of(b), n_)) /
                    static_cast<double>(N_));
}

void Transcription::interval_jacobian(const Vec& x, Index i, double h, JacobianSink& sink) const {
  const Index a = knot_point(i), b = knot_point(i + 1), row = i * interval_rows_;
  const auto& ea = eval_[static_cast<std::size_t>(a)];
  const auto& eb = eval_[static_cast<std::size_t>(b)];
  const Mat I = Mat::Identity(n_, n_);
  const double dh = 1.0 / static_cast<double>(N_);  // dh/dT
  const bool T = problem_.free_duration;
  auto v = [&](Index p) { return Vec(x.segment(v_of(p), n_)); };
  // One row block of velocity defects: Σ_p c_p h a_p with the weights c (a, [mid], b).
  auto acc_block = [&](Index r0, Index p, double cw, const Mat& self) {
    const auto& e = eval_[static_cast<std::size_t>(p)];
    sink.dense(r0, q_of(p), -cw * h * e.lin.dqdd_dq + (p == b ? Mat(-eb.Fv) : Mat::Zero(n_, n_)));
    sink.dense(r0, v_of(p), self - cw * h * e.lin.dqdd_dqd);
    if (k_ > 0) sink.dense(r0, u_of(p), -cw * h * e.dadu);
  };
  if (!hs()) {
    sink.identity(row, q_of(a), n_, -1.0);
    sink.identity(row, v_of(a), n_, -0.5 * h);
    sink.dense(row, q_of(b), I - eb.Fq);
    sink.identity(row, v_of(b), n_, -0.5 * h);
    sink.dense(row, gq_of(i), -eb.AR.transpose());
    if (T) sink.column(row, time_index(), -0.5 * dh * (v(a) + v(b)));
    acc_block(row + n_, a, 0.5, -I);
    acc_block(row + n_, b, 0.5, I);
    sink.dense(row + n_, gv_of(i), -eb.AR.transpose());
    if (T) sink.column(row + n_, time_index(), -0.5 * dh * (ea.lin.qdd + eb.lin.qdd));
    return;
  }
  const Index c = a + 1;
  const auto& ec = eval_[static_cast<std::size_t>(c)];
  // q_c − (q_a + q_b)/2 − h/8 (v_a − v_b)
  sink.identity(row, q_of(a), n_, -0.5);
  sink.identity(row, v_of(a), n_, -h / 8.0);
  sink.identity(row, q_of(c), n_, 1.0);
  sink.identity(row, q_of(b), n_, -0.5);
  sink.identity(row, v_of(b), n_, h / 8.0);
  if (T) sink.column(row, time_index(), -dh / 8.0 * (v(a) - v(b)));
  // v_c − (v_a + v_b)/2 − h/8 (a_a − a_b)
  const Index r1 = row + n_;
  sink.dense(r1, q_of(a), -h / 8.0 * ea.lin.dqdd_dq);
  sink.dense(r1, v_of(a), -0.5 * I - h / 8.0 * ea.lin.dqdd_dqd);
  if (k_ > 0) sink.dense(r1, u_of(a), -h / 8.0 * ea.dadu);
  sink.identity(r1, v_of(c), n_, 1.0);
  sink.dense(r1, q_of(b), h / 8.0 * eb.lin.dqdd_dq);
  sink.dense(r1, v_of(b), -0.5 * I + h / 8.0 * eb.lin.dqdd_dqd);
  if (k_ > 0) sink.dense(r1, u_of(b), h / 8.0 * eb.dadu);
  if (T) sink.column(r1, time_index(), -dh / 8.0 * (ea.lin.qdd - eb.lin.qdd));
  // q_b − q_a − h/6 (v_a + 4 v_c + v_b) − A_R(q_b)ᵀ γ^q
  const Index r2 = row + 2 * n_;
  sink.identity(r2, q_of(a), n_, -1.0);
  sink.identity(r2, v_of(a), n_, -h / 6.0);
  sink.identity(r2, v_of(c), n_, -4.0 * h / 6.0);
  sink.dense(r2, q_of(b), I - eb.Fq);
  sink.identity(r2, v_of(b), n_, -h / 6.0);
  sink.dense(r2, gq_of(i), -eb.AR.transpose());
  if (T) sink.column(r2, time_index(), -dh / 6.0 * (v(a) + 4.0 * v(c) + v(b)));
  // v_b − v_a − h/6 (a_a + 4 a_c + a_b) − A_R(q_b)ᵀ γ^v
  const Index r3 = row + 3 * n_;
  acc_block(r3, a, 1.0 / 6.0, -I);
  acc_block(r3, c, 4.0 / 6.0, Mat::Zero(n_, n_));
  acc_block(r3, b, 1.0 / 6.0, I);
  sink.dense(r3, gv_of(i), -eb.AR.transpose());
  if (T) sink.column(r3, time_index(), -dh / 6.0 * (ea.lin.qdd + 4.0 * ec.lin.qdd + eb.lin.qdd));
}

void Transcription::knot_jacobian(Index j, JacobianSink& sink) const {
  const auto js = static_cast<std::size_t>(j);
  const Index p = knot_point(j);
  const PointEval& e = eval_[static_cast<std::size_t>(p)];
  Index row = knot_row_[js];
  if (knot_phi_[js]) sink.dense(row, q_of(p), e.AR), row += r_;
  if (knot_phid_[js]) {
    sink.dense(row, q_of(p), e.D);
    sink.dense(row, v_of(p), e.AR);
  }
}

void Transcription::envelope_jacobian(Index p, JacobianSink& sink) const {
  Index row = envelope_rows_start_ + 4 * static_cast<Index>(problem_.envelopes.size()) * p;
  for (const auto& env : problem_.envelopes) {
    const double c = env.u_max / env.speed_max;
    for (const double s1 : {1.0, -1.0})
      for (const double s2 : {1.0, -1.0}) {
        sink.dense(row, v_of(p), s2 * c * problem_.B.col(env.actuator).transpose());
        sink.identity(row, u_of(p) + env.actuator, 1, s1);
        ++row;
      }
  }
}

void Transcription::jacobian(const Vec& x, JacobianSink& sink) {
  evaluate(x);
  const double h = duration(x) / static_cast<double>(N_);
  for (Index i = 0; i < N_; ++i) interval_jacobian(x, i, h, sink);
  for (Index j = 1; j <= N_; ++j) knot_jacobian(j, sink);
  if (!problem_.envelopes.empty())
    for (Index p = 0; p < P_; ++p) envelope_jacobian(p, sink);
  if (!bounded_.empty())
    for (Index p = 0; p < P_; ++p) multiplier_jacobian(p, sink);
  Index row = waypoint_rows_start_;
  for (std::size_t w = 0; w < waypoint_place_.size(); ++w) {
    waypoint_jacobian(x, w, row, sink);
    row += problem_.waypoints[w].rows->rows();
  }
  for (Index p = 0; p < P_ && wint_rows_per_point_ > 0; ++p)
    internal_wrench_rows(p, row, nullptr, &sink);
}

void Transcription::multiplier_jacobian(Index p, JacobianSink& sink) const {
  const PointEval& e = eval_[static_cast<std::size_t>(p)];
  Index row = multiplier_rows_start_ + p * static_cast<Index>(bounded_.size());
  for (const Index k : bounded_) {
    sink.dense(row, q_of(p), e.lin.dmu_dq.row(k));
    sink.dense(row, v_of(p), e.lin.dmu_dqd.row(k));
    if (k_ > 0) sink.dense(row, u_of(p), e.dmudu.row(k));
    ++row;
  }
}

namespace {
class CountingSink final : public JacobianSink {
 public:
  Index count = 0;
  void dense(Index, Index, const Mat& b) override { count += b.size(); }
  void identity(Index, Index, Index size, double) override { count += size; }
  void column(Index, Index, const Vec& v) override { count += v.size(); }
};
}  // namespace

Index Transcription::jacobian_nonzeros() {
  if (nnz_ < 0) {
    CountingSink sink;
    jacobian(initial_guess(), sink);
    nnz_ = sink.count;
  }
  return nnz_;
}

TrajectorySolution Transcription::solution(const Vec& x) {
  evaluate(x);
  TrajectorySolution s;
  const auto& pr = problem_;
  s.duration = duration(x);
  s.t.resize(P_);
  s.q.resize(P_, n_), s.qd.resize(P_, n_), s.qdd.resize(P_, n_), s.Qc.resize(P_, n_);
  s.u.resize(P_, k_);
  s.mu.resize(P_, r_);
  s.internal_wrench.resize(P_, wint_size_);
  s.trusted = true;
  for (Index p = 0; p < P_; ++p) {
    const PointEval& e = eval_[static_cast<std::size_t>(p)];
    s.t(p) = point_time(x, p);
    s.knot.push_back(!hs() || p % 2 == 0);
    s.q.row(p) = x.segment(q_of(p), n_).transpose();
    s.qd.row(p) = x.segment(v_of(p), n_).transpose();
    s.u.row(p) = x.segment(u_of(p), k_).transpose();
    s.qdd.row(p) = e.lin.qdd.transpose();
    s.Qc.row(p) = e.lin.Qc.transpose();
    if (e.lin.mu.size() == r_) s.mu.row(p) = e.lin.mu.transpose();
    if (wint_size_ > 0) s.internal_wrench.row(p) = e.wint.transpose();
    if (s.trusted && (!e.lin.trusted || e.lin.kept_rows != kept_)) {
      s.trusted = false;
      s.message = "at t = " + std::to_string(s.t(p)) + ": " +
                  (e.lin.trusted ? std::string("the independent constraint rows differ from the "
                                               "start's (a rank change along the path)")
                                 : e.lin.message);
    }
    if (s.knot.back() && r_ > 0) {  // (no rows: nothing to keep)
      s.max_position_residual = std::max(s.max_position_residual, e.phi.cwiseAbs().maxCoeff());
      s.max_velocity_residual = std::max(s.max_velocity_residual, e.phid.cwiseAbs().maxCoeff());
    }
  }
  Vec g;
  constraint_values(x, g);
  if (knot_rows_start_ > 0) s.max_defect = g.head(knot_rows_start_).cwiseAbs().maxCoeff();
  if (wint_rows_start_ > waypoint_rows_start_)
    s.max_waypoint_residual =
        g.segment(waypoint_rows_start_, wint_rows_start_ - waypoint_rows_start_)
            .cwiseAbs()
            .maxCoeff();
  if (r_ > 0) s.max_correction = x.segment(gq_of(0), N_ * 2 * r_).cwiseAbs().maxCoeff();
  // The corrections against the steps they correct: a resolved trajectory has |A_Rᵀγ| = O(h³)
  // against steps O(h); a correction of a tenth of its step means the knots jump across the
  // manifold (an unresolved motion, or another branch of the constraints' roots).
  for (Index i = 0; i < N_ && r_ > 0; ++i) {
    const Index a = knot_point(i), b = knot_point(i + 1);
    const Mat& AR = eval_[static_cast<std::size_t>(b)].AR;
    const double cq = (AR.transpose() * x.segment(gq_of(i), r_)).cwiseAbs().maxCoeff();
    const double cv = (AR.transpose() * x.segment(gv_of(i), r_)).cwiseAbs().maxCoeff();
    const double dq = (x.segment(q_of(b), n_) - x.segment(q_of(a), n_)).cwiseAbs().maxCoeff();
    const double dv = (x.segment(v_of(b), n_) - x.segment(v_of(a), n_)).cwiseAbs().maxCoeff();
    s.max_correction_ratio =
        std::max({s.max_correction_ratio, cq / (dq + 1e-12), cv / (dv + 1e-12)});
  }
  if (s.trusted && s.max_correction_ratio > 0.1) {
    s.trusted = false;
    s.message = "the manifold corrections reach " + std::to_string(s.max_correction_ratio) +
                " of the steps they correct: the knots jump across the constraint manifold (the "
                "mesh does not resolve the motion, or the path changes branch of the "
                "constraints' roots); use more intervals or bound max_correction";
  }
  s.kept_rows = kept_;
  s.cost = cost(x);
  (void)pr;
  return s;
}

}  // namespace ukdyn::optimize
