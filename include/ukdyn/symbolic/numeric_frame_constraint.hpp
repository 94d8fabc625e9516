// Frame constraints (weld, ball, hinge, level, distance: docs/frame-constraints.md) whose rows are
// evaluated in numbers instead of derived: what a frame of a chain on the recursive tree
// algorithms needs (docs/tree-algorithms.md), whose link poses are never written out as
// expressions. The rows Φ are the same functions of the two frames' poses as frame_rows() writes
// (frame_constraints.hpp); A = ∂Φ/∂q and b = −(∂²Φ/∂t² at q̈ = 0) follow by the chain rule from
// each frame's pose x = (p, R), its derivatives ∂x/∂q and its acceleration at q̈ = 0:
//
//   Φ̇ = D ẋ,   A = D ∂x/∂q,   b = −(D ẍ|q̈=0 + ẋᵀ H ẋ),   D = ∂Φ/∂x, H = ∂²Φ/∂x²
//
// where every row is at most bilinear in (p_a, R_a, p_b, R_b), so ẋᵀHẋ is the row evaluated on
// the rates (weld: ½ vee(Z − Zᵀ) with Z = 2 Ṙ_aᵀ Ṙ_b; hinge: 2 (Ṙ_a u)·(Ṙ_b n); distance:
// |ṗ_a − ṗ_b|²). A frame is fixed (world, or an offset of it), fixed in a link of a tree
// (TreeSubsystem::frame_state), or given by expressions of q (a free body, a definitions body:
// compiled to a tape of p, R, ∂x/∂q and ẍ|q̈=0).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "ukdyn/symbolic/frame_constraints.hpp"
#include "ukdyn/tree/tree.hpp"

namespace ukdyn::symbolic {

/// One frame of a numeric frame constraint.
struct NumericFrameEnd {
  enum class Kind { fixed, tree, expressions };
  Kind kind = Kind::fixed;
  /// fixed: the frame's pose; tree: the frame in its link's axes (p = p_link + R_link offset_p,
  /// R = R_link offset_R).
  Eigen::Matrix3d offset_R = Eigen::Matrix3d::Identity();
  Eigen::Vector3d offset_p = Eigen::Vector3d::Zero();
  std::shared_ptr<const tree::TreeSubsystem> tree;  ///< tree
  int link = -1;                                    ///< tree: link index (−1: the root frame)
  Index first_coordinate = 0;  ///< tree: the tree's first coordinate in the system's q
  FramePose pose;              ///< expressions: p(q), R(q), parameter values substituted
};

/// The constraint's kind and numbers (axis, up: unit vectors; length > 0).
struct NumericFrameSpec {
  FrameConstraintDef::Kind kind = FrameConstraintDef::Kind::weld;
  std::string name, frame_a, frame_b;
  Eigen::Vector3d axis{0, 0, 1}, up{0, 0, 1};
  bool vertical = false;
  double length = 0.0;
};

/// The FrameConstraint of f between ends a and b over the system's coordinates (the same row
/// names as make_frame_constraint). Throws DefinitionError for an expression end that depends on
/// t, or a weld / hinge / level whose frame has no rotation.
std::shared_ptr<FrameConstraint> make_numeric_frame_constraint(
    const NumericFrameSpec& f, NumericFrameEnd a, NumericFrameEnd b,
    const std::vector<std::string>& system_coordinates, std::shared_ptr<SymbolTable> symbols);

/// Two unit vectors n1, n2 with (u, n1, n2) orthonormal, as frame_rows() chooses them:
/// n1 ∝ u × e_k for the world axis e_k of the smallest |u_k|, n2 = u × n1.
std::pair<Eigen::Vector3d, Eigen::Vector3d> perpendicular_pair(const Eigen::Vector3d& u);

}  // namespace ukdyn::symbolic
