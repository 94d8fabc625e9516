// The limits of a coordinate as a robot file states them (URDF <limit>, MJCF joint range and
// actuator force ranges): what a trajectory optimiser may read, and what `simulate` warns about
// (warning kind joint_limit). Nothing in the dynamics enforces them.
#pragma once

#include <limits>

namespace ukdyn {

struct CoordinateLimits {
  double lower = -std::numeric_limits<double>::infinity();    ///< position, lower bound
  double upper = std::numeric_limits<double>::infinity();     ///< position, upper bound
  double velocity = std::numeric_limits<double>::infinity();  ///< |q̇| at most
  double effort = std::numeric_limits<double>::infinity();    ///< |generalized force| at most
  /// True if any of the four is finite.
  [[nodiscard]] bool any() const {
    const double inf = std::numeric_limits<double>::infinity();
    return lower != -inf || upper != inf || velocity != inf || effort != inf;
  }
};

}  // namespace ukdyn
