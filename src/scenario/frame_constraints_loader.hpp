// Internal to ukdyn::io: constraints between frames (type: weld, ball, hinge, level, distance),
// docs/frame-constraints.md. Frames are "<subsystem>.<link-or-body-or-point>" of the serial_chain
// and definitions subsystems defined before, optionally moved by an offset {xyz, rpy}.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "scenario/definitions_loader.hpp"
#include "ukdyn/symbolic/frame_constraints.hpp"

namespace ukdyn::io_detail {

/// True for weld, ball, hinge, level and distance.
bool is_frame_constraint(const std::string& type);

/// A constraint node of one of the kinds above (a symbolic::FrameConstraint); `q0` is the initial
/// state (length: initial).
std::shared_ptr<const Constraint> load_frame_constraint(
    const Loader& L, const Node& c, const std::string& name, const std::string& type,
    const std::vector<std::string>& system_coordinates, DefinitionContext& context,
    const Vec& q0);

/// The weld / ball constraint of a chain's link constraint (an MJCF equality), named
/// SUBSYSTEM_NAME, between the frames "SUBSYSTEM.LINK" moved by the offsets. Throws
/// symbolic::DefinitionError naming the constraint and the frame. `symbols`: the table the chain
/// was derived with (the scenario's).
std::shared_ptr<const Constraint> make_link_constraint(
    const std::string& subsystem, const symbolic::LinkConstraintDef& lc,
    const std::vector<std::string>& system_coordinates, DefinitionContext& context,
    std::shared_ptr<symbolic::SymbolTable> symbols);

}  // namespace ukdyn::io_detail
