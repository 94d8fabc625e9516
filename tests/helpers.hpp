// Shared helpers of the tests: random states and parameters with fixed seeds, tolerances, builders.
#pragma once

#include <gtest/gtest.h>

#include <Eigen/Core>
#include <Eigen/SVD>
#include <array>
#include <cmath>
#include <memory>
#include <numbers>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "ukdyn/model/system.hpp"
#include "ukdyn/paper_robot/cooperative_constraints.hpp"
#include "ukdyn/paper_robot/mobile_manipulator.hpp"

namespace uktest {

using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;
using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;

inline constexpr double kPi = std::numbers::pi;

inline double uniform(std::mt19937_64& rng, double lo, double hi) {
  return std::uniform_real_distribution<double>(lo, hi)(rng);
}

/// A random configuration of one arm: platform in [-2, 2]², yaw in (−π, π), pitches in ±1.4 rad.
inline Vector6d random_q(std::mt19937_64& rng) {
  Vector6d q;
  q << uniform(rng, -2, 2), uniform(rng, -2, 2), uniform(rng, -kPi, kPi), uniform(rng, -1.4, 1.4),
      uniform(rng, -1.4, 1.4), uniform(rng, -1.4, 1.4);
  return q;
}

/// A random velocity of one arm, every component in [-2, 2].
inline Vector6d random_qd(std::mt19937_64& rng) {
  Vector6d v;
  for (int i = 0; i < 6; ++i) v(i) = uniform(rng, -2, 2);
  return v;
}

/// A random but physical parameter set (all masses, inertias, lengths positive).
inline ukdyn::MobileManipulatorParams random_params(std::mt19937_64& rng) {
  ukdyn::MobileManipulatorParams p;
  p.platform_mass = uniform(rng, 10, 80);
  p.base_mass = uniform(rng, 0.5, 5);
  p.base_inertia = uniform(rng, 0.01, 0.5);
  p.base_length = uniform(rng, 0.2, 1.0);
  for (std::size_t k = 0; k < 3; ++k) {
    p.link_mass[k] = uniform(rng, 0.5, 6);
    p.link_inertia[k] = uniform(rng, 0.01, 1.0);
    p.link_length[k] = uniform(rng, 0.2, 1.2);
  }
  p.gravity = uniform(rng, 9.0, 10.0);
  return p;
}

/// ‖a − b‖ / max(‖b‖, floor): a relative error with a floor for quantities that may vanish.
template <class A, class B>
double rel_err(const A& a, const B& b, double floor = 1.0) {
  return (a - b).norm() / std::max(b.norm(), floor);
}

inline std::vector<std::string> arm_names(int i) {
  const std::string s = std::to_string(i);
  return {"dx" + s, "dy" + s, "delta" + s, "th" + s + "a", "th" + s + "b", "th" + s + "c"};
}

inline std::shared_ptr<ukdyn::MobileManipulator> make_arm(
    int i, const ukdyn::MobileManipulatorParams& p = {}) {
  return std::make_shared<ukdyn::MobileManipulator>("robot" + std::to_string(i), p, arm_names(i));
}

/// The paper's initial configuration (12 coordinates).
inline Vec paper_q0() {
  Vec q(12);
  q << 0, 0, 0, kPi / 2, -kPi / 3, 0, 1.6, 0, -kPi, kPi / 2, -kPi / 3, 0;
  return q;
}

/// The two-arm system of the paper; constraints are added by the caller.
struct TwoArms {
  std::shared_ptr<ukdyn::MobileManipulator> left, right;
  std::shared_ptr<ukdyn::System> system;
  explicit TwoArms(const ukdyn::MobileManipulatorParams& pl = {},
                   const ukdyn::MobileManipulatorParams& pr = {})
      : left(make_arm(1, pl)), right(make_arm(2, pr)), system(std::make_shared<ukdyn::System>()) {
    system->add_subsystem(left);
    system->add_subsystem(right);
  }
  std::shared_ptr<ukdyn::ClosureConstraint> add_closure(ukdyn::ClosureConstraint::Options o = {}) {
    auto c = std::make_shared<ukdyn::ClosureConstraint>(left, 0, right, 6, o);
    system->add_constraint(c);
    return c;
  }
  /// The paper's trajectory constraints, Eq. (19), relative to the cut point at q0.
  void add_paper_trajectory(const Vec& q0) {
    const Eigen::Vector3d origin = left->cut_point(q0.head<6>());
    std::array<std::optional<ukdyn::TimeFunction>, 3> axes{
        ukdyn::TimeFunction::make_constant(0.0), ukdyn::TimeFunction::make_cosine(0.5, -0.5, kPi),
        ukdyn::TimeFunction::make_cosine(0.5, -0.5, kPi)};
    system->add_constraint(
        std::make_shared<ukdyn::CutPointTrajectory>(left, 0, axes, origin, "traj"));
    system->add_constraint(std::make_shared<ukdyn::CoordinateConstraint>(
        0, ukdyn::TimeFunction::make_constant(q0(0)), "hold_dx1"));
    system->add_constraint(std::make_shared<ukdyn::CoordinateConstraint>(
        6, ukdyn::TimeFunction::make_constant(q0(6)), "hold_dx2"));
    system->add_constraint(std::make_shared<ukdyn::CoordinateConstraint>(
        2, ukdyn::TimeFunction::make_constant(q0(2)), "hold_delta1"));
  }
};

/// An orthonormal basis of null(A) (n × (n − rank)) by a full SVD.
inline Mat null_space(const Mat& A, double rel_tol = 1e-10) {
  Eigen::JacobiSVD<Mat> svd(A, Eigen::ComputeFullV);
  const auto& s = svd.singularValues();
  Index r = 0;
  for (Index i = 0; i < s.size(); ++i)
    if (s(i) > rel_tol * s(0)) ++r;
  return svd.matrixV().rightCols(A.cols() - r);
}

// max |a − b| / max(max |b|, 1e-300): the relative error of the largest entry.
inline double rel(const Eigen::Ref<const Mat>& a, const Eigen::Ref<const Mat>& b) {
  const double scale = std::max(b.cwiseAbs().maxCoeff(), 1e-300);
  return (a - b).cwiseAbs().maxCoeff() / scale;
}

inline Vec random_vec(std::mt19937_64& rng, Index n, double lo, double hi) {
  Vec v(n);
  for (Index i = 0; i < n; ++i) v(i) = uniform(rng, lo, hi);
  return v;
}

// Two systems with the same coordinates and constraint rows, evaluated at `samples` random states
// (q ∈ [−3.2, 3.2], q̇ ∈ [−3, 3], t ∈ [0, 4]): the largest relative difference of each quantity.
// Potentials may differ by a constant, so differences V(q) − V(q2) are compared.
struct SystemDifference {
  static constexpr const char* names[9] = {"M", "Cqd", "C", "G", "A", "b", "Phi", "Phid", "V"};
  double worst[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0};
};

inline SystemDifference compare_systems(const ukdyn::System& ref, const ukdyn::System& other,
                                        int samples, std::uint64_t seed) {
  const Index n = ref.dof(), m = ref.rows();
  ukdyn::ForwardData d0(ref), d(other);
  Mat C0(n, n), C(n, n);
  Vec r0(m), r(m);
  std::mt19937_64 rng(seed);
  SystemDifference diff;
  double* worst = diff.worst;
  for (int k = 0; k < samples; ++k) {
    const Vec q = random_vec(rng, n, -3.2, 3.2), qd = random_vec(rng, n, -3, 3);
    const double t = uniform(rng, 0, 4);
    ukdyn::evaluate_dynamics(ref, d0, t, q, qd);
    ukdyn::evaluate_dynamics(other, d, t, q, qd);
    ukdyn::evaluate_constraints(ref, d0, t, q, qd);
    ukdyn::evaluate_constraints(other, d, t, q, qd);
    ukdyn::coriolis_matrix(ref, q, qd, C0);
    ukdyn::coriolis_matrix(other, q, qd, C);
    const double e[6] = {rel(d.M, d0.M), rel(d.Cqd, d0.Cqd), rel(C, C0),
                         rel(d.G, d0.G), rel(d.A, d0.A),     rel(d.b, d0.b)};
    for (int i = 0; i < 6; ++i) worst[i] = std::max(worst[i], e[i]);
    ukdyn::position_residuals(ref, t, q, r0);
    ukdyn::position_residuals(other, t, q, r);
    worst[6] = std::max(worst[6],
                        (r - r0).cwiseAbs().maxCoeff() / std::max(1.0, r0.cwiseAbs().maxCoeff()));
    ukdyn::velocity_residuals(ref, t, q, qd, r0);
    ukdyn::velocity_residuals(other, t, q, qd, r);
    worst[7] = std::max(worst[7], rel(r, r0));
    const Vec q2 = random_vec(rng, n, -3.2, 3.2);
    const double dv0 = ukdyn::potential_energy(ref, q) - ukdyn::potential_energy(ref, q2);
    const double dv = ukdyn::potential_energy(other, q) - ukdyn::potential_energy(other, q2);
    worst[8] = std::max(worst[8], std::abs(dv - dv0) / std::max(1.0, std::abs(dv0)));
  }
  return diff;
}

}  // namespace uktest
