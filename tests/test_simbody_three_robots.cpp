// Three robots and a free-body load against Simbody ([Sherman2011]; Debian libsimbody-dev 3.7):
// scenarios/n_robots_3_weld.yaml as ukdyn derives it (symbolic serial chains, a free body in a unit
// quaternion, weld rows ½ vee(R_rel − R_relᵀ), U-K with the singular-M / arrow solve) against the
// same mechanism built from Simbody mobilizers and Constraint::Weld (tests/simbody/). At 100 random
// consistent states (load pose random, robot joints by the closed-form inverse kinematics of the
// xyz carriages + z-y-x wrist, velocities projected onto null(A)) the robots' q̈ and the load's
// CoM acceleration and world angular acceleration (ω̇ = 2 vec(q̈ ⊗ q*)) agree.
// Skipped when ukdyn was built without Simbody (UKDYN_TEST_HAVE_SIMBODY, tests/CMakeLists.txt).
#include <gtest/gtest.h>

#if defined(UKDYN_HAVE_IO) && defined(UKDYN_TEST_HAVE_SIMBODY)
#include <Eigen/Dense>
#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <random>
#include <string>

#include "simbody/three_robots_simbody.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/model/system.hpp"

namespace {

namespace sb = ukdyn_simbody_test;
using Eigen::Matrix3d;
using Eigen::Quaterniond;
using Eigen::Vector3d;
using ukdyn::Index;
using ukdyn::Vec;

Matrix3d rot_z(double a) { return Eigen::AngleAxisd(a, Vector3d::UnitZ()).toRotationMatrix(); }

struct Indices {
  std::array<Index, 18> robot{};
  std::array<Index, 7> load{};  // x, y, z, qw, qx, qy, qz
};

Indices indices(const ukdyn::System& sys) {
  Indices ix;
  const char* joint[6] = {"px", "py", "pz", "r1", "r2", "r3"};
  for (std::size_t k = 0; k < 3; ++k)
    for (std::size_t j = 0; j < 6; ++j)
      ix.robot[6 * k + j] = sys.coordinate_index("r" + std::to_string(k) + "_" + joint[j]);
  const char* load[7] = {"x", "y", "z", "qw", "qx", "qy", "qz"};
  for (std::size_t j = 0; j < 7; ++j)
    ix.load[j] = sys.coordinate_index(std::string("load_") + load[j]);
  return ix;
}

/// A configuration on the welds: the load at (p, R); robot k's tool frame must equal the load's
/// grasp frame k, T_tool = T_load T_grasp; its joints by inverse kinematics: the wrist rotation
/// R_mountᵀ R_tool = Rz(r1) Ry(r2) Rx(r3) (pitch |r2| < π/2 here), the carriages
/// R_mountᵀ (p_tool − R_tool (0.1, 0, 0) − p_mount).
Vec consistent_q(const ukdyn::System& sys, const Indices& ix, const Vector3d& p,
                 const Quaterniond& e) {
  Vec q = Vec::Zero(sys.dof());
  const Matrix3d R = e.toRotationMatrix();
  for (int k = 0; k < sb::kRobots; ++k) {
    const double a = sb::robot_angle(k);
    const Vector3d dir(std::cos(a), std::sin(a), 0);
    const Matrix3d Rm = rot_z(a + sb::kPi);
    const Vector3d pm = sb::kMountRadius * dir;
    const Matrix3d Rt = R * rot_z(a + sb::kPi);
    const Vector3d pt = p + R * (sb::kGraspRadius * dir);
    const Matrix3d W = Rm.transpose() * Rt;
    const Vector3d c = Rm.transpose() * (pt - Rt * Vector3d(sb::kTool, 0, 0) - pm);
    const double r2 = std::asin(-W(2, 0)), r1 = std::atan2(W(1, 0), W(0, 0)),
                 r3 = std::atan2(W(2, 1), W(2, 2));
    const double v[6] = {c.x(), c.y(), c.z(), r1, r2, r3};
    for (std::size_t j = 0; j < 6; ++j) q(ix.robot[6 * static_cast<std::size_t>(k) + j]) = v[j];
  }
  for (int i = 0; i < 3; ++i) q(ix.load[static_cast<std::size_t>(i)]) = p(i);
  q(ix.load[3]) = e.w();
  q(ix.load[4]) = e.x();
  q(ix.load[5]) = e.y();
  q(ix.load[6]) = e.z();
  return q;
}

Quaterniond quat(const Vec& v, const Indices& ix) {
  return Quaterniond(v(ix.load[3]), v(ix.load[4]), v(ix.load[5]), v(ix.load[6]));
}

}  // namespace

TEST(SimbodyThreeRobots, AccelerationsAgreeAtRandomConsistentStates) {
  const auto sc =
      ukdyn::load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/n_robots_3_weld.yaml");
  const ukdyn::System& sys = *sc.system;
  ASSERT_EQ(sys.dof(), 25);
  const Indices ix = indices(sys);
  sb::ThreeRobots simbody;
  ASSERT_TRUE(simbody.build_error().empty()) << simbody.build_error();

  ukdyn::ForwardData d(sys);
  Vec phi(sys.rows()), phid(sys.rows());
  const Vec zero = Vec::Zero(sys.dof());
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::normal_distribution<double> nd;
  double worst_rel = 0, worst_abs = 0, worst_phi = 0, worst_phid = 0, worst_sb_err = 0;
  double smallest_scale = 1e300;
  const int states = 100;
  for (int s = 0; s < states; ++s) {
    // Load: within 0.15 m of the centre per axis, turned by up to 0.6 rad about a random axis.
    const Vector3d p(0.15 * u(rng), 0.15 * u(rng), 0.15 * u(rng));
    const Vector3d axis = Vector3d(nd(rng), nd(rng), nd(rng)).normalized();
    const Quaterniond e(Eigen::AngleAxisd(0.6 * (0.5 * (u(rng) + 1.0)), axis));
    const Vec q = consistent_q(sys, ix, p, e);
    ukdyn::position_residuals(sys, d, 0.0, q, phi);
    worst_phi = std::max(worst_phi, phi.cwiseAbs().maxCoeff());
    // Velocity: a random q̇ (about 1 m/s, 1 rad/s) projected onto null(A(q)).
    ukdyn::forward(sys, d, 0.0, q, zero, zero);
    Vec v(sys.dof());
    for (Index i = 0; i < v.size(); ++i) v(i) = nd(rng);
    const Eigen::CompleteOrthogonalDecomposition<ukdyn::Mat> cod(d.A);
    const Vec qd = v - cod.solve(d.A * v);
    ukdyn::velocity_residuals(sys, d, 0.0, q, qd, phid);
    worst_phid = std::max(worst_phid, phid.cwiseAbs().maxCoeff());

    ukdyn::forward(sys, d, 0.0, q, qd, zero);
    ASSERT_TRUE(d.result.finite) << "state " << s;
    const Vec& qdd = d.qdd;

    sb::State st;
    for (std::size_t i = 0; i < 18; ++i) {
      st.q[i] = q(ix.robot[i]);
      st.qd[i] = qd(ix.robot[i]);
    }
    const Quaterniond eq = quat(q, ix), eqd = quat(qd, ix), eqdd = quat(qdd, ix);
    // World angular velocity and acceleration of a unit quaternion: ω = 2 vec(q̇ ⊗ q*),
    // ω̇ = 2 vec(q̈ ⊗ q*) (q̇ ⊗ q̇* is real).
    const Vector3d w = 2.0 * (eqd * eq.conjugate()).vec();
    const Vector3d wd = 2.0 * (eqdd * eq.conjugate()).vec();
    for (std::size_t i = 0; i < 3; ++i) {
      const auto ii = static_cast<Index>(i);
      st.load_position[i] = q(ix.load[i]);
      st.load_velocity[i] = qd(ix.load[i]);
      st.load_angular_velocity[i] = w(ii);
    }
    st.load_quaternion = {eq.w(), eq.x(), eq.y(), eq.z()};
    const sb::Accelerations a = simbody.accelerations(st);
    ASSERT_TRUE(a.error.empty()) << a.error;
    worst_sb_err = std::max(
        {worst_sb_err, a.position_error, a.velocity_error, a.constraint_acceleration_error});

    // 24 accelerations: 18 joint q̈, the load's CoM acceleration (m/s²), angular (rad/s²).
    Eigen::Matrix<double, 24, 1> uk, ref;
    for (std::size_t i = 0; i < 18; ++i) {
      uk(static_cast<Index>(i)) = qdd(ix.robot[i]);
      ref(static_cast<Index>(i)) = a.qdd[i];
    }
    for (std::size_t i = 0; i < 3; ++i) {
      const auto ii = static_cast<Index>(i);
      uk(18 + ii) = qdd(ix.load[i]);
      uk(21 + ii) = wd(ii);
      ref(18 + ii) = a.load_acceleration[i];
      ref(21 + ii) = a.load_angular_acceleration[i];
    }
    const double scale = ref.cwiseAbs().maxCoeff();
    const double diff = (uk - ref).cwiseAbs().maxCoeff();
    smallest_scale = std::min(smallest_scale, scale);
    worst_abs = std::max(worst_abs, diff);
    worst_rel = std::max(worst_rel, diff / scale);
    EXPECT_LE(diff, 1e-10 * scale)
        << "state " << s << "\nukdyn   " << uk.transpose() << "\nSimbody " << ref.transpose();
  }
  std::printf(
      "ukdyn vs Simbody, %d consistent states: max |dq̈|/max|q̈| = %.3g (max |dq̈| %.3g, smallest "
      "max|q̈| %.3g); ukdyn max |Φ| %.3g, |Φ̇| %.3g; Simbody max |qerr|, |uerr|, |aerr| %.3g\n",
      states, worst_rel, worst_abs, smallest_scale, worst_phi, worst_phid, worst_sb_err);
  // The states are on ukdyn's welds (the mechanism constants shared with the Simbody model are the
  // scenario's) and on Simbody's.
  EXPECT_LE(worst_phi, 1e-12);
  EXPECT_LE(worst_phid, 1e-12);
  EXPECT_LE(worst_sb_err, 1e-10);
}

#else
TEST(SimbodyThreeRobots, AccelerationsAgreeAtRandomConsistentStates) {
  GTEST_SKIP() << "ukdyn built without Simbody (install libsimbody-dev) or without io";
}
#endif
