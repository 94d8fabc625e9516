// Builds the paper's closed chain in code and prints q̈ and the rank at the paper's initial state.
// Coordinates and constraint rows are addressed by name (System::coordinate_index,
// System::constraint_row_index), never by raw offsets.
#include <cmath>
#include <iostream>
#include <ukdyn/paper_robot/cooperative_constraints.hpp>
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
  // add_subsystem returns the subsystem's handle: the offset of its first coordinate in q.
  const Index lo = sys.add_subsystem(left);
  const Index ro = sys.add_subsystem(right);
  sys.add_constraint(
      std::make_shared<ClosureConstraint>(left, lo, right, ro, ClosureConstraint::Options{}));
  const double pi = std::acos(-1.0);
  Vec q = Vec::Zero(sys.dof()), qd = Vec::Zero(sys.dof()), tau = Vec::Zero(sys.dof());
  auto set = [&](const char* name, double v) { q(sys.coordinate_index(name)) = v; };
  set("theta1", pi / 2);
  set("theta2", -pi / 3);
  set("dx2", 1.6);
  set("delta2", -pi);
  set("theta4", pi / 2);
  set("theta5", -pi / 3);
  ForwardData data(sys);
  forward(sys, data, 0.0, q, qd, tau);
  const Index z = sys.constraint_row_index("closure_z");
  std::cout << "rank " << data.result.rank << " residual " << data.result.residual << " theta1'' "
            << data.qdd(sys.coordinate_index("theta1")) << " b[closure_z] " << data.b(z) << "\n";
  return data.result.rank == 6 && data.result.residual < 1e-10 ? 0 : 1;
}
