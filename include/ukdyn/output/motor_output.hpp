// The motors behind the actuators (docs/motors.md) at every output sample, as trajectory.csv
// columns after u_<actuator>, and the run's figures of merit for sizing (summary.json → motors):
//   motor_torque_<a>   τ_m, the motor's electromagnetic torque (N·m, motor side)
//   motor_speed_<a>    ω_m = n ω_j (rad/s, motor side)
//   motor_current_<a>  i = τ_m / k_t (A)
//   motor_power_<a>    P_el = V i (W; < 0: regenerating)
//   motor_margin_<a>   (T_avail(ω_m) − |τ_m|) / min(T_peak, T_stall) (< 0: outside the envelope)
#pragma once

#include <array>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "ukdyn/output/plots.hpp"
#include "ukdyn/simulate/control.hpp"

namespace ukdyn {

/// ∫ f dt over samples (t_i, f_i) arriving one by one: Simpson's rule on consecutive pairs of
/// intervals (the quadratic through three samples, any spacing), the last interval of an odd count
/// from the quadratic through the last three samples; the trapezoid while there are only two.
/// Exact for quadratics; error O(h⁴) per unit time for smooth f.
class SampleIntegral {
 public:
  void add(double t, double f);
  [[nodiscard]] double value() const;

 private:
  double sum_ = 0.0;                 // over the completed pairs of intervals
  std::array<double, 3> t_{}, f_{};  // the samples of the open pair of intervals
  int count_ = 0;                    // how many of them
  double tp_ = 0.0, fp_ = 0.0;       // the sample before t_[0] (the last pair's middle)
  bool has_prev_ = false;
};

class MotorColumns {
 public:
  explicit MotorColumns(const Actuators& actuators);
  [[nodiscard]] bool empty() const { return index_.empty(); }
  [[nodiscard]] const std::vector<std::string>& header() const { return header_; }
  /// Writes header().size() values from out; returns where the next columns go. u: the actuators'
  /// inputs at the sample, qd: the (plant's) velocities. Allocation-free.
  double* fill(double t, CVecRef qd, CVecRef u, double* out);
  /// summary.json → "motors": per actuator with a motor, peak / RMS torque and speed (motor side),
  /// the energies, the worst margin to the envelope and its time, the RMS torque's margin to the
  /// continuous limit.
  [[nodiscard]] nlohmann::json summary() const;
  /// One console line: the worst margin over the motors, where and when ("" without motors).
  [[nodiscard]] std::string console_line() const;
  [[nodiscard]] std::vector<RunWarning> warnings() const;
  [[nodiscard]] std::vector<std::pair<std::string, std::vector<std::string>>> figures() const;
  /// Per motor, motor_envelope_<a>.png: the operating points |τ_m| against |ω_m| of every sample
  /// over the envelope min(T_p, T_s (1 − |ω_m|/ω_0)) and the continuous torque.
  [[nodiscard]] std::vector<Figure> envelope_figures() const;

  /// The run so far, per actuator with a motor (in actuator order).
  struct Totals {
    double peak_torque = 0.0, peak_torque_t = 0.0, peak_speed = 0.0, peak_speed_t = 0.0;
    double worst_margin = 0.0, worst_margin_t = 0.0;
    bool worst_is_speed = false;  ///< the worst point is above the torque–speed line (vs peak)
    // ∫ over the run: τ_m², ω_m², P_el, max(P_el, 0), R i², gear and friction losses, u ω_j
    std::array<SampleIntegral, 8> integral;
    double t_first = 0.0, t_last = 0.0;
    bool any = false;
  };
  enum Integral : std::size_t { kTau2, kOmega2, kElec, kDrawn, kCopper, kGear, kFriction, kJoint };
  [[nodiscard]] const std::vector<Totals>& totals() const { return totals_; }

 private:
  const Actuators* act_;
  std::vector<Index> index_;  // actuators with a motor
  std::vector<std::string> header_;
  std::vector<Totals> totals_;
};

}  // namespace ukdyn
