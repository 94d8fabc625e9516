// The paper's system (two mobile manipulators carrying one load) built in code for the benchmarks,
// with the initial state of docs/paper-notes.md. Shared by every benchmark translation unit.
#pragma once

#include <algorithm>
#include <cmath>
#include <memory>
#include <numbers>
#include <string>
#include <vector>

#include "ukdyn/model/system.hpp"
#include "ukdyn/model/time_function.hpp"
#include "ukdyn/paper_robot/cooperative_constraints.hpp"
#include "ukdyn/paper_robot/mobile_manipulator.hpp"

namespace ukbench {

/// q0 of the paper's Section 3 (the OCR dropped δ1 = 0).
inline ukdyn::Vec paper_q0() {
  constexpr double pi = std::numbers::pi;
  ukdyn::Vec q(12);
  q << 0.0, 0.0, 0.0, pi / 2, -pi / 3, 0.0, 1.6, 0.0, -pi, pi / 2, -pi / 3, 0.0;
  return q;
}

/// A spatial start that satisfies A q̇0 = 0 at paper_q0() (paper-notes.md, "paper_free").
inline ukdyn::Vec spatial_qd0() {
  ukdyn::Vec qd(12);
  qd << 0.19943338785662684, -0.3090685792886618, 0.3238357241108272, 0.6732214266883658,
      -0.10243493969032202, 0.0, 0.09956390871238911, 0.20906857928866182, 0.3238357241108272,
      -0.7333193364981856, -0.10243493969031958, 0.0;
  return qd;
}

struct PaperModel {
  std::shared_ptr<const ukdyn::MobileManipulator> left, right;
  ukdyn::System closure;  ///< 6 closure rows (free motion)
  ukdyn::System full;     ///< closure + trajectory rows (the paper's 4 s scenario), 12 rows
  ukdyn::Vec q0, qd0_spatial, qd0_zero;
};

/// Builds both systems. With `trajectory` rows: the left cut point keeps its initial x and follows
/// y, z = origin + 0.5 − 0.5 cos(πt); Δx1, Δx2 and δ1 stay at their initial values.
inline PaperModel make_paper_model() {
  using namespace ukdyn;
  PaperModel pm;
  pm.q0 = paper_q0();
  pm.qd0_spatial = spatial_qd0();
  pm.qd0_zero = Vec::Zero(12);

  auto left = std::make_shared<const MobileManipulator>(
      "left", MobileManipulatorParams{},
      std::vector<std::string>{"dx1", "dy1", "delta1", "theta1", "theta2", "theta3"});
  auto right = std::make_shared<const MobileManipulator>(
      "right", MobileManipulatorParams{},
      std::vector<std::string>{"dx2", "dy2", "delta2", "theta4", "theta5", "theta6"});
  pm.left = left;
  pm.right = right;

  for (System* sys : {&pm.closure, &pm.full}) {
    const Index lo = sys->add_subsystem(left);
    const Index ro = sys->add_subsystem(right);
    sys->add_constraint(std::make_shared<const ClosureConstraint>(left, lo, right, ro,
                                                                  ClosureConstraint::Options{}));
  }

  const Vec3 origin = left->cut_point(pm.q0.head(6));
  constexpr double pi = std::numbers::pi;
  std::array<std::optional<TimeFunction>, 3> axes{TimeFunction::make_constant(0.0),
                                                  TimeFunction::make_cosine(0.5, -0.5, pi),
                                                  TimeFunction::make_cosine(0.5, -0.5, pi)};
  pm.full.add_constraint(std::make_shared<const CutPointTrajectory>(left, 0, axes, origin, "traj"));
  pm.full.add_constraint(std::make_shared<const CoordinateConstraint>(
      0, TimeFunction::make_constant(pm.q0[0]), "hold_dx1"));
  pm.full.add_constraint(std::make_shared<const CoordinateConstraint>(
      6, TimeFunction::make_constant(pm.q0[6]), "hold_dx2"));
  pm.full.add_constraint(std::make_shared<const CoordinateConstraint>(
      2, TimeFunction::make_constant(pm.q0[2]), "hold_delta1"));
  return pm;
}

/// max_i |v_i| by a plain loop (Eigen's vectorised maxCoeff trips GCC 12's -Wmaybe-uninitialized
/// with AVX-512 intrinsics under -march=native).
inline double max_abs(const ukdyn::Vec& v) {
  double m = 0.0;
  for (ukdyn::Index i = 0; i < v.size(); ++i) m = std::max(m, std::abs(v[i]));
  return m;
}

/// The one model every benchmark uses (built on first use).
inline const PaperModel& paper_model() {
  static const PaperModel pm = make_paper_model();
  return pm;
}

}  // namespace ukbench
