// Scenario files (YAML): the system, its constraints, the initial state, forces and run settings.
// The format is documented in docs/scenario-format.md. Every error names file:line:column and key.
#pragma once

#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "ukdyn/model/system.hpp"
#include "ukdyn/simulate/control.hpp"
#include "ukdyn/simulate/simulate.hpp"

namespace ukdyn {

/// What the scenario loader keeps of the serial chains and definitions bodies it loaded (link poses,
/// named points, frames) for the replay page and the run's columns: opaque outside ukdyn::io.
struct LoadedDefinitions;

/// An error in a scenario file; what() reads "FILE:LINE:COL: key 'KEY': message".
class ScenarioError : public Error {
 public:
  using Error::Error;
};

struct ControlSpec;

struct SubsystemInfo {
  std::string name;
  std::string type;  ///< "mobile_manipulator"
  Index offset = 0;
  Index dof = 0;
};

struct Scenario {
  std::filesystem::path path;
  std::string name;
  std::string description;
  std::string hash;  ///< FNV-1a 64 of the file's bytes, hex
  std::shared_ptr<const System> system;
  std::vector<SubsystemInfo> subsystems;
  Vec q0, qd0, tau;
  SimulationSettings sim;
  /// simulation.error_estimate: shadow — run_scenario() integrates the scenario a second time at
  /// tighter settings and reports max |q − q_shadow| over the samples (docs/accuracy.md).
  bool error_estimate = false;
  double initial_tolerance = 1e-9;  ///< |Φ(q0, t0)| and |Φ̇(q0, q̇0, t0)| must stay under this
  std::vector<bool> held;           ///< coordinates kept fixed by assembly (initial.hold)
  /// The serial chains' link poses and points, as loaded (what the replay page draws:
  /// ukdyn/output/geometry.hpp); opaque.
  std::shared_ptr<const LoadedDefinitions> definitions;
  /// docs/control.md: the role of every block of system->constraints() (physical or servo), the
  /// actuators (`actuators:`, count 0 if none) and the `control:` section (null if none).
  std::vector<ConstraintRole> constraint_roles;
  Actuators actuators;
  std::shared_ptr<const ControlSpec> control;
  /// What the robot file readers noted and left out (e.g. "N meshes ignored"), one line each:
  /// `ukdyn check` and `ukdyn simulate` print them as notes.
  std::vector<std::string> notes;

  /// Per coordinate (system->dof() entries, in the system's order): the limits its robot file
  /// states (URDF <limit>, MJCF range and actuator force ranges), ±inf where none
  /// (docs/definitions.md, "Joint limits"). They are sim.limits: `simulate` warns (joint_limit)
  /// when a sample leaves them; nothing enforces them.
  [[nodiscard]] const std::vector<CoordinateLimits>& coordinate_limits() const {
    return sim.limits;
  }
};

/// The `control:` section (docs/control.md): the law, the plant (another scenario, same
/// coordinates; the scenario itself if none), a constant disturbance τ_d and the servo rows' offsets
/// at the start.
struct ControlSpec {
  ServoLawSettings law;
  std::shared_ptr<const Scenario> plant;  ///< null: the plant is this scenario's own system
  Vec disturbance;                        ///< n
  Vec initial_offset;                     ///< m (rows of the model), 0 for physical rows
};

struct LoadOptions {
  /// Check that (q0, q̇0) satisfies the constraints at t0. Off for `assemble`, which repairs them.
  bool check_initial = true;
  /// Serial chains, URDF and MJCF arms with `dynamics: auto` derived symbolically instead of run
  /// by the tree algorithms (docs/tree-algorithms.md): `ukdyn derive` prints their M, C, G.
  bool symbolic_chains = false;
};

/// Loads and validates a scenario. Throws ScenarioError naming file, line, column and key.
/// Also checks that (q0, q̇0) satisfies every constraint at t0 (position and velocity level).
Scenario load_scenario(const std::filesystem::path& path, const LoadOptions& options = {});

/// Same, from text (path is used in messages only).
Scenario load_scenario_text(const std::string& text, const std::filesystem::path& path,
                            const LoadOptions& options = {});

}  // namespace ukdyn
