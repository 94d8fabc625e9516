// Internal to ukdyn::io: the state-dependent parts of a scenario's `forces` (parameters,
// generalized, elements; docs/scenario-format.md), loaded into one applied force.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "scenario/definitions_loader.hpp"
#include "scenario/yaml_loader.hpp"
#include "ukdyn/model/applied_force.hpp"

namespace ukdyn::io_detail {

/// The applied force of `forces.generalized` and `forces.elements` (null if the node has neither).
/// `system_coordinates` are all coordinates in order; `context` has the serial chains' points.
std::shared_ptr<const AppliedForce> load_applied_forces(
    const Loader& L, const Node& forces, const std::vector<std::string>& system_coordinates,
    DefinitionContext& context);

}  // namespace ukdyn::io_detail
