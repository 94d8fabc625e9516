// Serial chains (and trees) from MJCF files, read with MuJoCo's own parser and compiler (Debian's
// libmujoco-dev): the compiled mjModel's body tree, hinge and slide joints and inertias become a
// ChainDef, derived exactly like every other chain (docs/definitions.md).
//
// Per body: its frame relative to the parent (body_pos, body_quat), then each of its joints in
// order (hinge: a rotation about jnt_axis through the anchor jnt_pos; slide: a translation along
// jnt_axis; both in the body frame, by q − qpos0, so `ref` is honoured), then its inertia
// (body_mass, body_ipos, body_iquat, the principal body_inertia). Free joints (qpos: the body
// origin in the world, its quaternion) become floating joints and ball joints (qpos: a quaternion)
// ball joints of the chain (ChainModel::quaternions: their unit-norm rows). Weld and connect
// equalities become ChainDef::link_constraints (weld and ball frame constraints, ideal: MuJoCo's
// solref / solimp softness is not modelled); joint and tendon equalities and inactive ones are
// refused (an error names the file and the equality); contacts are not read. Limits: a limited
// joint's range (as compiled: `limited` / `autolimits` resolved, degrees turned to radians per
// <compiler angle>) and the force bound of the actuators on it (forcerange, or the ctrlrange of a
// plain motor, times the gear) go to JointDef::limits (MuJoCo 2.2 has no actuatorfrcrange).
// Bodies are checked (mass >= 0, principal moments A + B >= C; the message names the body).
// Mesh geoms are counted in one line of ChainDef::notes. Numbers are MuJoCo's
// compiled doubles (orientations as roll-pitch-yaw of its quaternions), so agreement with MuJoCo is
// to round-off, not exact.
#pragma once

#include <string>

#include "ukdyn/symbolic/chain.hpp"

namespace ukdyn::symbolic {

/// True if ukdyn was built with MuJoCo.
bool mjcf_supported();

/// Appends the MJCF model's bodies and joints to `chain` (bodies on the world attach to
/// chain.root_link, or to the mobile base if chain.base.enabled). Movable joints take the chain's
/// coordinates that are not base coordinates, in MuJoCo's joint order (= its qpos order). If
/// `gravity` is set, chain.gravity becomes the model's option/gravity. Throws DefinitionError
/// naming the file (and the joint) for a file MuJoCo cannot read, an unsupported joint, or a wrong
/// number of coordinates; also when ukdyn was built without MuJoCo.
void append_mjcf(ChainDef& chain, const std::string& path, bool gravity = false);

}  // namespace ukdyn::symbolic
