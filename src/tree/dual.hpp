// Dual numbers along one tangent direction: a value and one directional derivative on Eigen's
// forward-mode scalar with a fixed one-entry derivative (no heap, trivially copyable). Every
// arithmetic operation and sin/cos applies its derivative rule, so an expression evaluated on
// Duals seeded with (x, dx) gives its value and its exact directional derivative along dx
// (forward-mode automatic differentiation, Griewank & Walther, Evaluating Derivatives, SIAM 2008,
// ch. 3). Internal (header-only), included as "tree/dual.hpp" by the tree's derivatives
// (src/tree/tree.cpp) and the numeric frame constraints (src/symbolic/numeric_frame_constraint.cpp).
#pragma once

#include <unsupported/Eigen/AutoDiff>

namespace ukdyn::detail {

using Dual = Eigen::AutoDiffScalar<Eigen::Matrix<double, 1, 1>>;

/// The dual number of `value` with directional derivative `tangent`.
inline Dual dual(double value, double tangent) {
  return Dual(value, Eigen::Matrix<double, 1, 1>::Constant(tangent));
}

/// The directional derivative of x (0 for a Dual that carries none).
inline double tangent_of(const Dual& x) {
  return x.derivatives().size() > 0 ? x.derivatives()(0) : 0.0;
}

}  // namespace ukdyn::detail
