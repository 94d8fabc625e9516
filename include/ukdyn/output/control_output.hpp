// The columns of docs/control.md at the end of trajectory.csv, and the control summary:
//   Qp_<coordinate>, Qs_<coordinate>, role_split_unique   the U-K force split by role (a scenario
//                                                          with at least one servo row)
//   u_<actuator>, act_residual                             the actuators' inputs (`actuators:`):
//                                                          inverse dynamics, or the law's u
//   motor_*_<actuator>                                     the motor behind an actuator
//                                                          (motor_output.hpp, docs/motors.md)
//   e_<row>, ed_<row>                                      servo errors (`control:`)
//   servo_uncertainty                                      ‖δ‖ of the built-in laws (`control:`)
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "ukdyn/output/motor_output.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/simulate/control.hpp"
#include "ukdyn/simulate/control_forces.hpp"

namespace ukdyn {

/// The columns and the run's extrema; the forces themselves are ControlForces'
/// (ukdyn/simulate/control_forces.hpp), computed into buffers allocated once.
class ControlColumns {
 public:
  /// loop: the closed loop of a control run (then u is the law's), or null (inverse dynamics of the
  /// scenario's own system at each sample).
  ControlColumns(const Scenario& scenario, ClosedLoop* loop);
  [[nodiscard]] bool empty() const { return header_.empty(); }
  [[nodiscard]] const std::vector<std::string>& header() const { return header_; }
  /// Writes header().size() values from out[0]; d: the simulated system's data at (t, q, q̇).
  /// Allocates nothing (but the first time the role split is found not unique).
  void fill(double t, CVecRef q, CVecRef qd, const ForwardData& d, double* out);
  /// Warnings of the run (role_force_split, underactuated, saturation), once each.
  [[nodiscard]] std::vector<RunWarning> warnings() const;
  /// summary.json → "control".
  [[nodiscard]] nlohmann::json summary() const;
  [[nodiscard]] std::vector<std::pair<std::string, std::vector<std::string>>> figures() const;
  /// A control run: the simulated system (the plant). If it has the paper's closure rows
  /// (closure_x, closure_y, closure_z), the peak closure and squeeze forces are taken from its
  /// multipliers at every sample (docs/control.md, "The squeeze force").
  void set_plant(const System& plant);
  /// The run's extrema so far (summary.json → control; the metrics of `ukdyn sweep`).
  struct Peaks {
    double max_abs_e = 0.0, max_abs_e_second_half = 0.0, max_abs_u = 0.0, max_abs_udot = 0.0;
    double saturation_time = 0.0;            ///< Σ (t_i − t_{i−1}) over saturated samples i
    double saturation_max_over_limit = 0.0;  ///< 0 if never saturated
    bool closure = false;                    ///< the plant has the closure rows
    double max_closure_force = 0.0;          ///< max ‖(λ_x, λ_y, λ_z)‖
    double max_squeeze_force = 0.0;  ///< max −λ·n (compression > 0); −inf before a sample
  };
  [[nodiscard]] const Peaks& peaks() const { return peaks_; }
  /// The motors behind the actuators (docs/motors.md): summary.json → motors, the console line.
  [[nodiscard]] const MotorColumns& motors() const { return motors_; }

 private:
  double* fill_split(double t, double* out);
  double* fill_actuators(double t, CVecRef qd, double* out);
  double* fill_servo(double t, double* out);

  const Scenario* sc_;
  ControlForces forces_;  // the scenario's system as the model; the loop, if any
  std::vector<std::string> header_, row_names_, servo_names_;
  double t0_ = 0.0, t_half_ = 0.0;
  // accumulated
  bool split_unique_ = true;
  double split_t_ = 0.0;
  std::vector<Index> redundant_;
  double max_residual_ = 0.0, residual_t_ = 0.0;
  bool underactuated_ = false;
  double max_e_ = 0.0, max_e_half_ = 0.0, max_u_ = 0.0, max_udot_ = 0.0;
  bool saturated_ = false;
  double sat_t_ = 0.0, sat_over_ = 0.0;
  // the uncertainty the robust term must dominate (docs/control.md "The uncertainty bound ρ")
  double max_delta_ = 0.0, max_delta_t_ = 0.0;
  bool rho_exceeded_ = false;
  double rho_exceeded_t_ = 0.0, rho_exceeded_delta_ = 0.0;
  Vec u_prev_;
  double t_prev_ = 0.0;
  bool first_ = true;
  Peaks peaks_;
  MotorColumns motors_;
};

}  // namespace ukdyn

namespace ukdyn {

/// A control run (docs/control.md): the plant (its scenario's system with only its physical
/// constraints), the controller's model (the scenario's own system, all rows), the law, the closed
/// loop, and the offset start (q0, q̇0) of the plant.
struct ControlRun {
  std::shared_ptr<System> plant;
  ControlModel model;
  std::unique_ptr<ServoLaw> law;
  std::unique_ptr<ClosedLoop> loop;
  Vec q0, qd0;
};

/// Null if the scenario has no `control:` section. Throws ukdyn::Error if the offset start
/// violates the plant's physical constraints.
std::unique_ptr<ControlRun> make_control_run(const Scenario& scenario);

}  // namespace ukdyn
