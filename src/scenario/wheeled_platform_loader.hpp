// Internal to ukdyn::io: subsystems of type mecanum, omni and differential_drive
// (docs/wheeled-platforms.md). Each is generated as a definitions subsystem
// (symbolic/wheeled_platform.hpp) and brings its nonholonomic rolling rows, which the scenario
// loader adds with the constraints.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "scenario/definitions_loader.hpp"
#include "scenario/yaml_loader.hpp"
#include "ukdyn/model/constraint.hpp"
#include "ukdyn/model/subsystem.hpp"
#include "ukdyn/symbolic/wheeled_platform.hpp"

namespace ukdyn::io_detail {

/// True for mecanum, omni and differential_drive.
bool is_wheeled_platform(const std::string& type);

/// Its default coordinates (PREFIX x, y, yaw, phi1, ...; PREFIX is NAME_, or an instance's
/// prefix) when `coordinates` is not given: as many wheel angles as the `wheels` list has entries
/// (2 for a differential drive).
std::vector<std::string> wheeled_platform_default_coordinates(const Loader& L, const Node& s,
                                                              const std::string& type,
                                                              const std::string& prefix);

/// A loaded platform: its definition, for the rolling rows added with the constraints.
struct LoadedPlatform {
  std::string name;
  symbolic::WheeledPlatformDef def;
  std::vector<std::string> coordinates;
  Node at;
};

/// The subsystem node `s` of a wheeled platform type; every bad value named at its key. Its
/// platform body is registered as the frame NAME.platform in `context` (frame constraints). An
/// instance (`instances:`) may replace mass, yaw_inertia, wheel_radius and wheel_inertia by its
/// `parameters`.
std::shared_ptr<const Subsystem> load_wheeled_platform(
    const Loader& L, const Node& s, const std::string& type, const std::string& name,
    const std::vector<std::string>& coordinates, DefinitionContext* context, LoadedPlatform& out,
    const InstanceSpec* instance = nullptr);

/// A constraint node of type rolling_wheels (docs/wheeled-platforms.md, "A platform as the base
/// of a chain"): the rolling rows NAME_wheelK on coordinates x, y, yaw and one angle per wheel of
/// any subsystem (a serial_chain's mobile base and its wheel joints).
std::shared_ptr<const Constraint> load_rolling_wheels(
    const Loader& L, const Node& c, const std::string& name,
    const std::vector<std::string>& system_coordinates);

}  // namespace ukdyn::io_detail
