// Servo-constraint control on top of the Udwadia–Kalaba solve (docs/control.md): actuators
// (τ = B u), the inverse dynamics of the constrained system (core/force_split.hpp), and a closed
// loop in which a plant (its own System with only its physical constraints, driven by τ = B u) is
// controlled by a law that sees only the measured (t, q, q̇) and evaluates its own model.
#pragma once

#include <functional>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "ukdyn/core/force_split.hpp"
#include "ukdyn/model/motor.hpp"
#include "ukdyn/simulate/simulate.hpp"

namespace ukdyn {

/// k actuators: τ = B u (B: n × k); limit(j) = |u_j| allowed (+inf: none); motors[j]: the motor
/// and gearbox behind actuator j, if given (docs/motors.md; its rotor inertia and friction are in
/// the System already, ukdyn/model/motor.hpp).
struct Actuators {
  std::vector<std::string> names;
  Mat B;
  Vec limit;
  std::vector<std::optional<MotorSpec>> motors;
  [[nodiscard]] Index count() const { return static_cast<Index>(names.size()); }
};

/// One flag per row of `system`: true for the rows of servo blocks (block_roles: one per
/// System::constraints() entry).
std::vector<bool> servo_row_flags(const System& system, const std::vector<ConstraintRole>& roles);

/// A System with the same subsystems and applied forces as `system` and only its physical
/// constraint blocks (the plant).
std::shared_ptr<System> physical_system(const System& system,
                                        const std::vector<ConstraintRole>& roles);

/// What a control law knows: the controller's model (its System, with physical and servo rows),
/// which rows are servo rows, the actuators, the model's own constant τ and solver settings.
struct ControlModel {
  std::shared_ptr<const System> system;
  std::vector<bool> row_servo;
  Actuators actuators;
  Vec tau;  ///< the model's constant generalized forces (forces.tau)
  UkSettings uk;
};

/// A user's law: from the measured state and the model's forward data (forward() of the model at
/// (t, q, q̇) with tau, all rows), write u (actuators.count()). May keep state of its own.
class ControlLaw {
 public:
  virtual ~ControlLaw() = default;
  virtual void control(const ControlModel& model, double t, CVecRef q, CVecRef qd,
                       const ForwardData& model_data, VecRef u) = 0;
};

/// The built-in laws (docs/control.md). All realise the model's U-K force for the servo rows with
/// a corrected right-hand side b_s + v and hand it to solve_actuation():
///  feedforward: v = 0 (the nominal U-K servo force);
///  stabilized:  v = −2ω ė − ω² e, so e obeys ë + 2ω ė + ω² e = 0 on the model ([Udwadia2003],
///               [Udwadia2008]);
///  robust:      v = −λ ė − κ β − ρ γ μ with β = ė + λ e, μ = ρ β, γ = 1/‖μ‖ if ‖μ‖ > ε else 1/ε
///               (the nominal term, the feedback on β and the smoothed robust term of [Chen1998],
///               [Zhao2018]); ρ = 0 is the feedback-only baseline.
/// e = Φ_s(q, t), ė = Φ̇_s = A_s q̇ + ∂Φ_s/∂t (the servo rows' residuals).
enum class ControlLawKind { feedforward, stabilized, robust };
std::string to_string(ControlLawKind kind);

struct ServoLawSettings {
  ControlLawKind kind = ControlLawKind::stabilized;
  double omega = 5.0;     ///< stabilized [1/s]
  double lambda = 5.0;    ///< robust: β = ė + λ e [1/s]
  double kappa = 5.0;     ///< robust: feedback gain on β [1/s]
  double rho = 0.0;       ///< robust: uncertainty bound [m/s² per unit of β's rate], 0: none
  double epsilon = 1e-2;  ///< robust: smoothing (boundary layer of ‖μ‖)
};

class ServoLaw : public ControlLaw {
 public:
  ServoLaw(const ControlModel& model, ServoLawSettings settings);
  void control(const ControlModel& model, double t, CVecRef q, CVecRef qd,
               const ForwardData& model_data, VecRef u) override;
  /// The residual of the last actuation solve (underactuation if not round-off).
  [[nodiscard]] const Actuation& last_actuation() const { return act_.result; }
  [[nodiscard]] const ServoLawSettings& settings() const { return s_; }
  /// The uncertainty the robust term must dominate (docs/control.md "The uncertainty bound ρ"),
  /// at the state of the last control() call: ‖δ‖₂ over the servo rows with
  /// δ = A_s q̈ − (b_s + v), q̈ the plant's acceleration under the u just returned (so that
  /// β̇ = −κβ − ργμ + δ on the plant). Allocates nothing.
  [[nodiscard]] double servo_uncertainty(const ControlModel& model, CVecRef qdd_plant) const;

 private:
  ServoLawSettings s_;
  ForwardData work_;
  Vec phi_, phid_, b_;
  ActuationWorkspace act_;  // the inverse dynamics' buffers, allocated once
};

/// Inverse dynamics at one state: the least-norm u with B u = Qc − A_pᵀμ for the model's Qc
/// (model_data after forward()). Allocates.
Actuation actuation_for(const ControlModel& model, const ForwardData& model_data);

/// The buffers of actuation_for() for the model: n coordinates, k actuators, its physical rows.
ActuationWorkspace actuation_workspace(const ControlModel& model);
/// actuation_for() into ws.result (ws from actuation_workspace(model)): the physical rows of
/// model_data.A into ws.Ap, then solve_actuation() in ws. Allocates nothing.
void actuation_for(const ControlModel& model, const ForwardData& model_data,
                   ActuationWorkspace& ws);

/// Servo residuals e = Φ_s, ė = Φ̇_s of the model at (t, q, q̇) (allocates).
void servo_errors(const ControlModel& model, double t, CVecRef q, CVecRef qd, Vec& e, Vec& ed);

/// The closed loop: the plant's applied forces τ_plant + B sat(u) + disturbance(t), u from the law
/// at every right-hand-side evaluation (a continuous-time controller).
struct ClosedLoop {
  ClosedLoop(const ControlModel& model, ControlLaw& law, Vec plant_tau,
             std::function<void(double, VecRef)> disturbance = {});
  /// Computes u at (t, q, q̇): forward() of the model, then the law; u_raw before saturation.
  void evaluate(double t, CVecRef q, CVecRef qd);
  /// The plant's τ for the state last evaluated.
  void plant_tau(VecRef tau);
  [[nodiscard]] ForceFunction force_function();

  const ControlModel& model;
  ControlLaw& law;
  Vec tau_plant;
  std::function<void(double, VecRef)> disturbance;
  ForwardData model_data;
  Vec u_raw, u;  ///< k: the law's u, and u clipped at the actuators' limits
  bool saturated = false;
  Vec d;  ///< n: the disturbance at the last evaluation

 private:
  Vec Bu_;  // n: B u (a buffer, so that plant_tau() allocates nothing)
};

/// Gauss–Newton from q: q with the physical rows Φ_p = 0 and the servo rows Φ_s = offset
/// (least-norm steps); q̇ projected onto Φ̇_p = 0, Φ̇_s = 0 (nearest to qd). For an offset start.
/// Throws ukdyn::Error if it does not converge to 1e-13.
void offset_start(const ControlModel& model, double t, const Vec& offset, Vec& q, Vec& qd);

}  // namespace ukdyn
