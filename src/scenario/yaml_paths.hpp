// Paths into a scenario's YAML tree, `a.b[2].c[left]` (keys separated by dots, list elements by
// [index] or by [name], the element whose `name:` is that): used by the sweep (src/sweep/, its
// parameters' `path:`) and by control.plant_set (io/control_loader.cpp). Internal to ukdyn::io.
#pragma once

#include <yaml-cpp/yaml.h>

#include <optional>
#include <string>

namespace ukdyn::io_detail {

/// A deep copy, node by node: an alias (`*table1`) becomes a copy of its own, so that a value
/// written at one path changes that path only.
YAML::Node clone_yaml(const YAML::Node& n);

/// The scalar node at `path` in doc (a handle into doc: assigning it changes doc), or nullopt with
/// the reason in `why` ("'subsystems[left].params' has no key 'mass'", "... is not a number ...").
std::optional<YAML::Node> find_scalar(YAML::Node doc, const std::string& path, std::string& why);

}  // namespace ukdyn::io_detail
