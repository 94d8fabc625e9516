// Eigen aliases and small error types shared by every layer.
#pragma once

#include <Eigen/Core>
#include <stdexcept>
#include <string>

namespace ukdyn {

using Vec = Eigen::VectorXd;
using Mat = Eigen::MatrixXd;
using Vec3 = Eigen::Vector3d;
using Eigen::Index;

/// Thrown at the edges (model building, scenario loading) for input that cannot be used.
/// Never thrown from the integration hot path for numerical trouble: that is a status.
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

}  // namespace ukdyn
