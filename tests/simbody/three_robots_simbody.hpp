// The plain interface between tests/test_simbody_three_robots.cpp (C++20, ukdyn) and
// tests/simbody/three_robots_simbody.cpp (C++17, Simbody 3.7): no ukdyn and no Simbody type crosses
// it, so each side compiles with its own standard (Simbody 3.7's headers fail as C++20; see
// bench/bench_simbody.cpp and tests/CMakeLists.txt).
//
// The mechanism is scenarios/n_robots_3_weld.yaml (tools/n_robots.py 3 --weld): robot k (k = 0, 1,
// 2) is mounted at a_k = 2πk/3 on the unit circle, yawed by a_k + π (facing the centre); its tool
// point (0.1, 0, 0) on the hand is welded to the grasp frame on the load at 0.3 (cos a_k, sin a_k,
// 0), yawed by a_k + π. The constants below are the generator's; the test checks that states built
// from them satisfy ukdyn's weld rows of the scenario (so a changed scenario fails the test).
#pragma once

#include <array>
#include <memory>
#include <string>

namespace ukdyn_simbody_test {

inline constexpr int kRobots = 3;
inline constexpr double kPi = 3.141592653589793238462643383279502884;
inline constexpr double kMountRadius = 1.0, kGraspRadius = 0.3, kTool = 0.1;
inline constexpr double kLoadMass = 3.0, kGravity = 9.81;
inline constexpr std::array<double, 3> kLoadInertia{0.05, 0.06,
                                                    0.08};  ///< about the CoM, body axes

/// Angle a_k of robot k around the load.
inline double robot_angle(int k) { return 2.0 * kPi * k / kRobots; }

/// One state in world quantities. Robot k's joints are q[6k .. 6k+5] = [px, py, pz, r1, r2, r3]
/// (carriages along the mount's x, y, z; wrist about z, y, x), the same coordinates in ukdyn and
/// Simbody (Slider, Pin: q̇ = u).
struct State {
  std::array<double, 6 * kRobots> q{}, qd{};
  std::array<double, 3> load_position{};              ///< CoM, world
  std::array<double, 4> load_quaternion{1, 0, 0, 0};  ///< w, x, y, z (body -> world)
  std::array<double, 3> load_velocity{};              ///< CoM velocity, world
  std::array<double, 3> load_angular_velocity{};      ///< world axes
};

struct Accelerations {
  std::array<double, 6 * kRobots> qdd{};
  std::array<double, 3> load_acceleration{};          ///< CoM, world
  std::array<double, 3> load_angular_acceleration{};  ///< world axes
  double constraint_acceleration_error = 0;       ///< max |aerr| Simbody reports after the solve
  double position_error = 0, velocity_error = 0;  ///< max |qerr|, |uerr| at the given state
  std::string error;                              ///< non-empty: Simbody threw
};

/// The Simbody model (SimTK::MultibodySystem), built once in the constructor.
class ThreeRobots {
 public:
  ThreeRobots();
  ~ThreeRobots();
  ThreeRobots(const ThreeRobots&) = delete;
  ThreeRobots& operator=(const ThreeRobots&) = delete;
  /// realize(Stage::Acceleration) at s: the robots' q̈ and the load's accelerations.
  Accelerations accelerations(const State& s);
  const std::string& build_error() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace ukdyn_simbody_test
