// Builds the paper's closed chain in code and prints q̈ and the rank at the paper's initial state.
#include <cmath>
#include <iostream>
#include <ukdyn/models/cooperative_constraints.hpp>
#include <ukdyn/simulate/simulate.hpp>

int main() {
  using namespace ukdyn;
  auto left = std::make_shared<MobileManipulator>(
      "left", MobileManipulatorParams{},
      std::vector<std::string>{"dx1", "dy1", "delta1", "theta1", "theta2", "theta3"});
  auto right = std::make_shared<MobileManipulator>(
      "right", MobileManipulatorParams{},
      std::vector<std::string>{"dx2", "dy2", "delta2", "theta4", "theta5", "theta6"});
  System sys;
  const Index lo = sys.add_subsystem(left);
  const Index ro = sys.add_subsystem(right);
  sys.add_constraint(
      std::make_shared<ClosureConstraint>(left, lo, right, ro, ClosureConstraint::Options{}));
  const double pi = std::acos(-1.0);
  Vec q(12), qd = Vec::Zero(12), tau = Vec::Zero(12);
  q << 0, 0, 0, pi / 2, -pi / 3, 0, 1.6, 0, -pi, pi / 2, -pi / 3, 0;
  ForwardData data(sys);
  forward(sys, data, 0.0, q, qd, tau);
  std::cout << "rank " << data.result.rank << " residual " << data.result.residual << "\n";
  return data.result.rank == 6 && data.result.residual < 1e-10 ? 0 : 1;
}
