// Paths into a scenario's YAML tree, `a.b[2].c[left]` (keys separated by dots, list elements by
// [index] or by [name], the element whose `name:` is that): used by the sweep (src/sweep/, its
// parameters' `path:`) and by control.plant_set (src/scenario/control_loader.cpp). Internal to ukdyn::io.
#pragma once

#include <yaml-cpp/yaml.h>

#include <cstddef>
#include <optional>
#include <string>

namespace ukdyn::io_detail {

/// At most this many nodes once every alias is expanded, and at most this depth: a document that
/// is larger (a "billion laughs" of nested aliases, a few hundred bytes that expand to gigabytes)
/// is refused where it is parsed, before anything walks or copies it (parse_scenario_yaml).
inline constexpr std::size_t kMaxYamlNodes = 1'000'000;
inline constexpr std::size_t kMaxYamlDepth = 500;

/// Empty if the document stays within kMaxYamlNodes and kMaxYamlDepth with its aliases expanded;
/// otherwise why not, with `at` the node where the count ran out. Visits at most kMaxYamlNodes
/// nodes (an explicit stack: no recursion).
std::string yaml_expansion_problem(const YAML::Node& root, YAML::Mark& at);

/// A deep copy, node by node: an alias (`*table1`) becomes a copy of its own, so that a value
/// written at one path changes that path only.
YAML::Node clone_yaml(const YAML::Node& n);

/// The scalar node at `path` in doc (a handle into doc: assigning it changes doc), or nullopt with
/// the reason in `why` ("'subsystems[left].params' has no key 'mass'", "... is not a number ...").
std::optional<YAML::Node> find_scalar(YAML::Node doc, const std::string& path, std::string& why);

/// As find_scalar, and the scalar must be a number (as the scenario loader reads one, a multiple
/// of pi included): a path into an expression is refused, so that a number written there never
/// silently replaces the expression.
std::optional<YAML::Node> find_number(YAML::Node doc, const std::string& path, std::string& why);

/// Whether `name` can name a number of a scenario file (docs/derivatives.md, "Sensitivities to
/// parameters"): 1 to 200 characters from A-Z a-z 0-9 _ . [ ] -, as kParameterNameRule says.
bool parameter_name_ok(const std::string& name);
inline constexpr const char* kParameterNameRule =
    "a parameter is a key or a path: 1 to 200 characters from A-Z a-z 0-9 _ . [ ] -";

}  // namespace ukdyn::io_detail
