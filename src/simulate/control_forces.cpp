#include "ukdyn/simulate/control_forces.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

namespace ukdyn {

namespace {

Index count_servo_rows(const std::vector<bool>& row_servo) {
  return static_cast<Index>(std::count(row_servo.begin(), row_servo.end(), true));
}

// The index of `name` in names, or -1.
Index index_of(const std::vector<std::string>& names, const char* name) {
  const auto it = std::find(names.begin(), names.end(), name);
  return it == names.end() ? Index{-1} : static_cast<Index>(it - names.begin());
}

}  // namespace

ControlForces::ControlForces(const ControlModel& model, ClosedLoop* loop)
    : model_(model), loop_(loop), u_(Vec::Zero(model.actuators.count())) {
  const System& sys = *model_.system;
  if (count_servo_rows(model_.row_servo) > 0) split_.emplace(sys.rows(), sys.dof());
  if (loop_ != nullptr) {
    servo_law_ = dynamic_cast<const ServoLaw*>(&loop_->law);
    const System& msys = *loop_->model.system;
    work_.emplace(msys);
    phi_ = Vec::Zero(msys.rows());
    phid_ = Vec::Zero(msys.rows());
    e_ = Vec::Zero(count_servo_rows(loop_->model.row_servo));
    ed_ = Vec::Zero(e_.size());
  } else if (actuated()) {
    actuation_.emplace(actuation_workspace(model_));
  }
}

void ControlForces::set_plant(const System& plant) {
  const auto& rows = plant.constraint_row_names();
  cx_ = index_of(rows, "closure_x");
  cy_ = index_of(rows, "closure_y");
  cz_ = index_of(rows, "closure_z");
  closure_.reset();
  if (loop_ != nullptr && cx_ >= 0 && cy_ >= 0 && cz_ >= 0) {
    closure_.emplace(plant.rows(), plant.dof());
    no_servo_.assign(static_cast<std::size_t>(plant.rows()), false);
  }
  const auto& names = plant.coordinate_names();
  px1_ = index_of(names, "dx1");
  py1_ = index_of(names, "dy1");
  px2_ = index_of(names, "dx2");
  py2_ = index_of(names, "dy2");
  if (px1_ < 0 || py1_ < 0 || px2_ < 0 || py2_ < 0) px1_ = -1;
}

void ControlForces::evaluate(double t, CVecRef q, CVecRef qd, const ForwardData& d) {
  const ForwardData* md = &d;
  if (loop_ != nullptr) {
    loop_->evaluate(t, q, qd);  // the law at the sample: the same u as the integrator's
    md = &loop_->model_data;
  }
  if (split_) split_by_role(md->A, md->Qc, model_.row_servo, *split_);
  if (actuated()) evaluate_actuation(d);
  if (loop_ != nullptr) evaluate_servo_errors(t, q, qd, d);
  if (closure_) evaluate_closure(q, d);
}

void ControlForces::evaluate_actuation(const ForwardData& d) {
  if (loop_ == nullptr) {
    actuation_for(model_, d, *actuation_);
    const Actuation& a = actuation_->result;
    u_ = a.u;
    residual_ = a.residual;
    underactuated_ = a.underactuated;
    return;
  }
  u_ = loop_->u;
  if (servo_law_ != nullptr) {
    residual_ = servo_law_->last_actuation().residual;
    underactuated_ = servo_law_->last_actuation().underactuated;
  } else {  // a user's law (MemoryRunOptions::law): no actuation solve of ukdyn's to report
    residual_ = std::numeric_limits<double>::quiet_NaN();
    underactuated_ = false;
  }
  saturated_ = loop_->saturated;
  over_limit_ = 0.0;
  if (saturated_) {
    for (Index j = 0; j < u_.size(); ++j)
      over_limit_ = std::max(over_limit_, std::abs(loop_->u_raw(j)) - model_.actuators.limit(j));
  }
}

void ControlForces::evaluate_servo_errors(double t, CVecRef q, CVecRef qd, const ForwardData& d) {
  const ControlModel& m = loop_->model;
  const System& sys = *m.system;
  position_residuals(sys, *work_, t, q, phi_);
  velocity_residuals(sys, *work_, t, q, qd, phid_);
  Index k = 0;
  for (Index i = 0; i < sys.rows(); ++i) {
    if (!m.row_servo[static_cast<std::size_t>(i)]) continue;
    e_(k) = phi_(i);
    ed_(k++) = phid_(i);
  }
  // δ = A_s q̈_plant − (b_s + v): d is the plant's forward() at this sample under the u of the
  // evaluate() above (the same state, so the same u as the integrator's).
  if (servo_law_ != nullptr) uncertainty_ = servo_law_->servo_uncertainty(m, d.qdd);
}

void ControlForces::evaluate_closure(CVecRef q, const ForwardData& d) {
  // The plant's multipliers: the least-norm λ with A_pᵀλ = Qc (its rows are all physical).
  // λ_{x,y,z} of Φ = p1 − p2 is the force (world axes) the closure applies at robot 1's cut
  // point, −λ at robot 2's (Qc = J1ᵀλ on robot 1's coordinates). The squeeze is its component
  // against n, the horizontal unit vector from platform 1 to platform 2 (world x without the
  // paper's dx1, dy1, dx2, dy2): compression > 0 (docs/control.md, "The squeeze force").
  split_by_role(d.A, d.Qc, no_servo_, *closure_);
  const Vec& lambda = closure_->result.lambda;
  const double fx = lambda(cx_), fy = lambda(cy_), fz = lambda(cz_);
  double nx = 1.0, ny = 0.0;
  if (px1_ >= 0) {
    const double ax = q(px2_) - q(px1_), ay = q(py2_) - q(py1_), l = std::hypot(ax, ay);
    if (l > 0.0) {
      nx = ax / l;
      ny = ay / l;
    }
  }
  closure_force_.magnitude = std::sqrt(fx * fx + fy * fy + fz * fz);
  closure_force_.squeeze = -(fx * nx + fy * ny);
}

}  // namespace ukdyn
