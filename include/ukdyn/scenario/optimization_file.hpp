// Trajectory-optimisation problem files (YAML; docs/optimization.md): a scenario (the system, its
// constraints and actuators; its initial state is the start) plus the method, the end state, costs,
// bounds, envelopes and IPOPT's settings.
#pragma once

#include <filesystem>
#include <memory>
#include <string>

#include "ukdyn/optimize/trajectory.hpp"
#include "ukdyn/scenario/scenario.hpp"

namespace ukdyn {

struct OptimizationFile {
  std::filesystem::path path;
  std::string name;
  std::string hash;                          ///< FNV-1a 64 of the file's bytes, hex
  std::shared_ptr<const Scenario> scenario;  ///< the system; problem.system is its system
  TrajectoryProblem problem;
  IpoptSettings ipopt;
  /// Re-integrate the true dynamics under the optimal u(t) (docs/optimization.md, "Checks").
  bool verify = true;
};

/// Loads and checks a problem file; throws ScenarioError naming file, line, column and key
/// (validate() of the problem included, its message placed at the file).
OptimizationFile load_optimization_file(const std::filesystem::path& path);
OptimizationFile load_optimization_text(const std::string& text, const std::filesystem::path& path);

}  // namespace ukdyn
