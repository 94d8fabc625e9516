// Serial chains (and trees) from URDF files, read with Debian's urdfdom (liburdfdom-dev).
//
// Supported joints: revolute, continuous (both turn about the axis), prismatic, fixed, floating
// (position + unit quaternion, 7 coordinates; ChainDef::floating_root puts the root on one); mimic
// joints (value = multiplier · other + offset; JointDef::mimic names the other). A link's
// <inertial> block (mass, origin xyz/rpy of the CoM frame, inertia about the CoM) is optional: a
// link without one is a massless frame. Every <inertial> is checked (mass >= 0, inertia positive
// semi-definite), the message naming the file and the link; principal moments with A + B < C are
// kept and noted (ChainDef::notes). Joint
// <limit> (lower, upper: revolute and prismatic; velocity, effort) goes to JointDef::limits.
// Dynamics, safety controllers and visual and collision elements are ignored; meshes among them
// are counted in one line of ChainDef::notes. Numbers that are short decimals are kept exact
// (0.7 = 7/10); angles within 1e-12 of a multiple of π/4 become that multiple exactly.
#pragma once

#include <map>
#include <string>

#include "ukdyn/symbolic/chain.hpp"

namespace ukdyn::symbolic {

/// True if ukdyn was built with urdfdom.
bool urdf_supported();

/// Appends the URDF's links and joints to `chain`: the URDF root link is attached to the mobile
/// base (by a fixed joint, if chain.base.enabled) or becomes chain.root_link. A movable joint's
/// variable is joint_values[joint name] if given, else the next coordinate of the chain that is
/// neither a base coordinate nor the whole value of another joint, in depth-first order from the
/// root. Throws DefinitionError naming the file and the element (joint or link) for unsupported
/// joints, missing inertials, too few coordinates, or a file urdfdom cannot read.
void append_urdf(ChainDef& chain, const std::string& path,
                 const std::map<std::string, GiNaC::ex>& joint_values = {});

}  // namespace ukdyn::symbolic
