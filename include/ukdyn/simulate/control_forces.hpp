// The forces of a control scenario at one output sample (docs/control.md), what the control
// columns of trajectory.csv and the metrics of `ukdyn sweep` report:
//   the U-K force of the model split by role, Qc = Qp + Qs (core/force_split.hpp);
//   the actuators' inputs u: the law's (a control run) or the inverse dynamics of the model;
//   the servo errors e = Φ_s, ė = Φ̇_s and the uncertainty ‖δ‖ of a built-in law (a control run);
//   on a plant with the paper's closure rows, the closure force and the squeeze of the load.
// Every buffer is allocated at construction (and by set_plant()): evaluate() allocates nothing
// (tests/test_no_alloc.cpp).
#pragma once

#include <optional>
#include <vector>

#include "ukdyn/core/force_split.hpp"
#include "ukdyn/simulate/control.hpp"

namespace ukdyn {

/// The force the paper's closure Φ = p1 − p2 (rows closure_x, closure_y, closure_z) applies at
/// robot 1's cut point (world axes; −λ at robot 2's): λ of those rows, the least-norm multipliers
/// of the plant (A_pᵀλ = Qc, every row physical).
struct ClosureForce {
  double magnitude = 0.0;  ///< ‖(λ_x, λ_y, λ_z)‖
  /// −(λ_x n_x + λ_y n_y): its component against n, the horizontal unit vector from platform 1 to
  /// platform 2 (the paper's dx1, dy1, dx2, dy2; world x without them); compression > 0
  /// (docs/control.md, "The squeeze force").
  double squeeze = 0.0;
};

class ControlForces {
 public:
  /// model: the controller's model (the scenario's own system, every row). loop: the closed loop
  /// of a control run (u is then the law's, and e, ė are computed), or null (u is the inverse
  /// dynamics of the model at each sample).
  ControlForces(const ControlModel& model, ClosedLoop* loop);

  /// A control run: the simulated system. If it has the paper's closure rows the closure force is
  /// computed at every sample (has_closure()).
  void set_plant(const System& plant);

  /// At one sample: d is the simulated system's forward data at (t, q, q̇). With a loop, the law is
  /// evaluated at the sample first (the same u as the integrator's).
  void evaluate(double t, CVecRef q, CVecRef qd, const ForwardData& d);

  [[nodiscard]] const ControlModel& model() const { return model_; }
  [[nodiscard]] ClosedLoop* loop() const { return loop_; }
  /// The loop's law if it is a built-in one (ServoLaw), else null (no loop, or a user's law).
  [[nodiscard]] const ServoLaw* servo_law() const { return servo_law_; }

  /// The model has servo rows: split() holds Qp, Qs, whether the split is unique and the
  /// redundant rows.
  [[nodiscard]] bool has_split() const { return split_.has_value(); }
  [[nodiscard]] const RoleForceSplit& split() const { return split_->result; }

  /// The model has actuators: u(), actuation_residual() (‖B u + A_pᵀμ − Qc‖; NaN for a user's
  /// law, whose solve is not ukdyn's) and underactuated().
  [[nodiscard]] bool actuated() const { return model_.actuators.count() > 0; }
  [[nodiscard]] const Vec& u() const { return u_; }
  [[nodiscard]] double actuation_residual() const { return residual_; }
  [[nodiscard]] bool underactuated() const { return underactuated_; }
  /// The loop clipped u at the actuators' limits, and by how much at most: max_j |u_raw_j| − limit_j.
  [[nodiscard]] bool saturated() const { return saturated_; }
  [[nodiscard]] double over_limit() const { return over_limit_; }

  /// A loop: the servo errors e = Φ_s, ė = Φ̇_s of the model at the sample (one per servo row).
  [[nodiscard]] const Vec& e() const { return e_; }
  [[nodiscard]] const Vec& ed() const { return ed_; }
  /// A built-in law: ‖δ‖, δ = A_s q̈_plant − (b_s + v) (ServoLaw::servo_uncertainty()).
  [[nodiscard]] double uncertainty() const { return uncertainty_; }

  [[nodiscard]] bool has_closure() const { return closure_.has_value(); }
  [[nodiscard]] const ClosureForce& closure() const { return closure_force_; }

 private:
  void evaluate_actuation(const ForwardData& model_data);
  void evaluate_servo_errors(double t, CVecRef q, CVecRef qd, const ForwardData& d);
  void evaluate_closure(CVecRef q, const ForwardData& d);

  ControlModel model_;
  ClosedLoop* loop_;
  const ServoLaw* servo_law_ = nullptr;  // the dynamic_cast of loop->law, once
  std::optional<RoleSplitWorkspace> split_;
  std::optional<ActuationWorkspace> actuation_;  // inverse dynamics (no loop)
  Vec u_;
  double residual_ = 0.0;
  bool underactuated_ = false, saturated_ = false;
  double over_limit_ = 0.0;
  // the servo errors (a loop): the model's residuals with a ForwardData of its own
  std::optional<ForwardData> work_;
  Vec phi_, phid_, e_, ed_;
  double uncertainty_ = 0.0;
  // the closure force (set_plant)
  std::optional<RoleSplitWorkspace> closure_;
  std::vector<bool> no_servo_;                       // the plant's rows: all physical
  Index cx_ = -1, cy_ = -1, cz_ = -1;                // rows closure_x, _y, _z of the plant
  Index px1_ = -1, py1_ = -1, px2_ = -1, py2_ = -1;  // coordinates dx1, dy1, dx2, dy2
  ClosureForce closure_force_;
};

}  // namespace ukdyn
