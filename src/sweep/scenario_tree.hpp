// Internal to the sweep (src/sweep/): the base scenario's YAML tree and a sample's values written
// into a copy of it (`path:` targets, `plant.` paths, `initial.q[i]`), shared by the sweep file's
// checks (sweep_file.cpp) and the runs of the samples (sample.cpp).
#pragma once

#include <yaml-cpp/yaml.h>

#include <filesystem>
#include <string>
#include <vector>

#include "ukdyn/sweep/sweep.hpp"

namespace ukdyn::sweep_detail {

/// Shortest text that reads back as the same double (fmt's default for doubles): the values
/// written into a sample's tree and the cells of the table.
std::string num(double v);

/// A text file whole (at most max_bytes), with the checks of every file ukdyn reads
/// (core/input_file.hpp). Throws ScenarioError naming it if it is missing, not a regular file or
/// larger.
std::string read_text(const std::filesystem::path& p, const std::string& what,
                      std::size_t max_bytes = std::size_t{4} << 20);

/// A deep copy of a YAML tree (io_detail::clone_yaml, scenario/yaml_paths.hpp).
YAML::Node clone(const YAML::Node& n);

/// The base scenario's tree, parsed once by load_sweep (Sweep::base_doc).
const YAML::Node& base_yaml(const Sweep& sw);

/// A path `plant.P` (docs/sweeps.md, "Control scenarios") writes P in the plant of a control
/// scenario: as an entry {path: P, value: v} appended to the sample's control.plant_set
/// (scenario/control_loader.cpp), so the controller's model keeps its value.
inline constexpr const char* kPlantPrefix = "plant.";
bool plant_path(const std::string& path);

/// The plant's tree of a control scenario, as control.plant_set sees it: the plant file, or the
/// scenario's own tree less its control and actuators sections.
YAML::Node plant_tree(const YAML::Node& doc, const std::filesystem::path& base_path);

/// `initial.q[i]` / `initial.qd[i]`: the coordinate i of q0 / q̇0 (velocity: which), or -1.
long state_index(const std::string& path, bool& velocity);

/// Whether the base scenario's system is independent of initial.q (no constraint built from the
/// initial state: `origin: initial`, `value: initial` or their defaults), so that samples that
/// differ only in (q0, q̇0) can share one compiled model.
bool system_independent_of_state(const YAML::Node& doc);

/// The value a target writes for the parameter value v: scale × v + offset.
double target_value(const SweepTarget& t, double v);

/// The base scenario's tree (a copy) with the fixed values and the parameter values `vals` written
/// in; with_state false: the `initial.q[i]` / `initial.qd[i]` targets left out.
YAML::Node sample_doc(const Sweep& sw, const std::vector<double>& vals, bool with_state);

}  // namespace ukdyn::sweep_detail
