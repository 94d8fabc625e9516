// The exact ∂τ/∂(q, q̇) of the built-in servo laws (docs/derivatives.md, "Controlled runs"),
// composed from the model's exact pieces: the KKT derivatives of its U-K solve with the law's
// corrected right-hand side (model/linearize_corrected.hpp), the constraints' tangents for the
// actuation solve's projector, the derivative of a pseudo-inverse of constant rank
// ([GolubPereyra1973]) and the actuators' saturation.
#pragma once

#include <string>
#include <vector>

#include "ukdyn/model/linearize.hpp"
#include "ukdyn/output/control_output.hpp"

namespace ukdyn {

/// The kink messages of the law (one wording for the exact and the difference paths).
std::string boundary_layer_kink(double epsilon);
std::string actuator_kink(const std::string& name, double limit);
/// Appends `kink` to `kinks` unless it is there already.
void add_kink(std::vector<std::string>& kinks, const std::string& kink);

/// ∂τ/∂t at fixed (q, q̇) of exact_law_jacobian(), when asked for: t one more direction of the
/// same composition (the corrected KKT system's time column with ∂v/∂t, the physical rows'
/// ∂A_p/∂t in the projector; τ_plant and τ_d constant, as make_control_run() builds them).
struct LawTimeDerivative {
  bool exact = false;  ///< dtau_dt holds it; else why_not says why not (a component without ∂/∂t)
  Vec dtau_dt;
  std::string why_not;
};

/// ∂τ/∂q and ∂τ/∂q̇ (n × n each) of run's law at (t, q, q̇), u_raw the law's u there (before
/// saturation); ld: a workspace for the law's model (LinearizeData(*run.model.system)). Adds the
/// kinks within 1e-6 (relative) of the state: the boundary layer ‖μ‖ = ε, an actuator at its limit
/// (the derivative given is that of the side the state is on). False, with the reason in why_not,
/// when a part cannot be made exact (law_jacobian_gap(), ukdyn cannot vouch for the model's KKT
/// derivatives, or the KKT solve and the law's own U-K solve disagree): the caller takes
/// differences instead. `dt`: also ∂τ/∂t (LawTimeDerivative), or null.
bool exact_law_jacobian(const ControlRun& run, LinearizeData& ld, double t, CVecRef q, CVecRef qd,
                        CVecRef u_raw, Mat& dtau_dq, Mat& dtau_dqd, std::vector<std::string>& kinks,
                        std::string& why_not, LawTimeDerivative* dt = nullptr);

}  // namespace ukdyn
