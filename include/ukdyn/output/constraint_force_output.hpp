// The force of each constraint block and the wrenches of the frame constraints as extra columns of
// trajectory.csv, written only for scenarios with frame constraints (docs/frame-constraints.md):
//   Fc_<block>_<coordinate>   A_kᵀλ_k, for the coordinates of every subsystem the block touches
//   W_<c>_fx .. W_<c>_mz      wrench of frame constraint c on its frame b (frame a for level),
//                             world axes, moment about the frame's origin
//   Wg_<c>_fx .. Wg_<c>_mz    the same in that frame's own axes (the grasp frame)
//   pose_<c>_x .. pose_<c>_z, pose_<c>_qw .. pose_<c>_qz
//                             that frame's origin (world) and orientation as a unit quaternion
//                             (frame → world, qw ≥ 0)
//   Wint_walker_<c>_fx .. _mz, Wint_weighted_<c>_fx .. _mz
//                             for the welds that grasp one load (two or more welds with the same
//                             frame b): the internal part of the grasp wrench W_<c> by
//                             internal_wrench_walker() and internal_wrench_weighted()
//                             (core/constraint_forces.hpp), world axes, moment about the grasp
//   split_unique              1 if A has full row rank (the split is the only one), else 0 (the
//                             least-norm λ is reported)
#pragma once

#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "ukdyn/core/constraint_forces.hpp"
#include "ukdyn/model/system.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/symbolic/frame_constraints.hpp"

namespace ukdyn {

class ConstraintForceColumns {
 public:
  /// Empty (no columns) unless the scenario has frame constraints.
  explicit ConstraintForceColumns(const Scenario& scenario);
  [[nodiscard]] bool empty() const { return header_.empty(); }
  [[nodiscard]] const std::vector<std::string>& header() const { return header_; }
  /// Writes header().size() values from out[0]. Returns false if the split is not unique. The
  /// forces are split_constraint_force()'s and the wrenches FrameWrenchMap::evaluate()'s, into
  /// buffers allocated at construction: allocates nothing.
  bool fill(CVecRef q, const ForwardData& d, double* out);
  /// One figure per frame constraint (its world wrench), one per block (its force) and one per
  /// load (the weighted internal forces of its grasps).
  /// (By reference: run.cpp indexes them, `figure_columns()[f]`; a copy would dangle.)
  [[nodiscard]] const std::vector<std::vector<std::string>>& figure_columns() const {
    return figures_;
  }
  [[nodiscard]] const std::vector<std::string>& figure_names() const { return figure_names_; }

 private:
  const Scenario* sc_ = nullptr;
  std::vector<std::pair<std::size_t, const symbolic::FrameWrenches*>> frames_;  // block, map
  std::vector<std::string> header_;
  std::vector<std::vector<Index>> block_coords_;  // per block: the coordinates written
  std::vector<std::vector<std::string>> figures_;
  std::vector<std::string> figure_names_;
  // A load held by two or more welds (same frame b): its grasps (indices into frames_), the
  // agents' coordinates (all but the load subsystem's) and the buffers of its internal wrenches.
  struct Load {
    std::string name;
    std::vector<std::size_t> grasps;
    std::vector<Index> agents;
    InternalWrenchWorkspace ws;
  };
  std::vector<Load> loads_;
  void add_loads(const Scenario& sc);
  void fill_loads(CVecRef q, const ForwardData& d, double*& out);
  // the buffers of fill()
  std::optional<ConstraintForceWorkspace> split_;
  Mat Ja_, Jb_;  // 6 × n: the twist Jacobians of one frame constraint's frames
  std::vector<const double*> w_out_;  // per frame constraint: its W_ columns in fill()'s row
  std::vector<Vec3> position_;        // per frame constraint: frame b's origin (a for level)
  std::vector<symbolic::FrameWrenches::Workspace> wrench_ws_;  // per frame constraint
  symbolic::FrameWrench wrench_;
};

}  // namespace ukdyn
