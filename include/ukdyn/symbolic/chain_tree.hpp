// A serial chain (joints, URDF, MJCF) as a tree of numbers for the recursive algorithms
// (ukdyn/tree/tree.hpp, docs/tree-algorithms.md), when every number of it is known.
#pragma once

#include <optional>
#include <string>

#include "ukdyn/symbolic/chain.hpp"
#include "ukdyn/tree/tree.hpp"

namespace ukdyn::symbolic {

/// The tree, or why the chain needs the symbolic derivation.
struct ChainTree {
  std::optional<tree::Model> model;
  std::string reason;  ///< when there is no model: what the tree algorithms cannot take
};

/// The chain's tree: the mount as the root frame; a mobile base as two prismatic joints (x, y
/// along the mount's axes) and an optional revolute one (yaw about the mount's z), the base link
/// last; every joint with its origin (xyz, rpy: R = Rz Ry Rx), axis (normalised), variable (a
/// coordinate, or a value affine in the coordinates) and its link's inertial (the inertia turned
/// by the inertial rpy into the link frame); floating and ball joints (a URDF's floating root among
/// them) with their quaternion coordinates. No model (and a reason) when the chain has an extra
/// potential, or a number that is not known (a joint value not affine in the coordinates, an
/// expression of t). Throws DefinitionError for what
/// build_chain refuses too (duplicate joints or links, unknown parents or coordinates, zero axes).
ChainTree chain_tree(const ChainDef& chain);

/// What build_chain checks of a floating or ball joint `j` (shared with chain_tree): 7 (4)
/// coordinates, each a coordinate of the chain, and no coordinate or value. Throws
/// DefinitionError with `where` (the joint) in front.
void check_quaternion_joint(const ChainDef& chain, const JointDef& j, const std::string& where);

}  // namespace ukdyn::symbolic
