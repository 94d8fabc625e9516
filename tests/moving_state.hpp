// A test fixture shared by the derivative tests: a consistent moving state of a scenario and the
// check of ∂q̈/∂(q, q̇) columns against Richardson-extrapolated central differences of forward().
// (Included by tests only; it asserts through gtest.)
#pragma once

#include <gtest/gtest.h>

#include <Eigen/SVD>
#include <cmath>
#include <utility>

#include "ukdyn/model/linearize.hpp"
#include "ukdyn/model/system.hpp"
#include "ukdyn/scenario/scenario.hpp"

namespace ukdyn::test {

struct State {
  Vec q, qd, tau;
};

// The scenario's q0 with a velocity along the constraints (null space of A) and a nonzero τ.
inline State moving_state(const Scenario& sc) {
  const System& sys = *sc.system;
  const Index n = sys.dof();
  State s{sc.q0, sc.qd0, Vec(n)};
  for (Index i = 0; i < n; ++i) s.tau(i) = 0.3 * std::sin(1.7 * static_cast<double>(i) + 0.4);
  ForwardData fd(sys);
  forward(sys, fd, sc.sim.t0, s.q, s.qd, s.tau);
  // Without constraint rows every direction is free (Eigen's SVD of a 0 × n matrix is not used).
  Mat V = Mat::Identity(n, n);
  Index rank = 0;
  if (fd.A.rows() > 0) {
    Eigen::JacobiSVD<Mat> svd(fd.A, Eigen::ComputeFullV);
    V = svd.matrixV();
    while (rank < svd.singularValues().size() && svd.singularValues()(rank) > 1e-9) ++rank;
  }
  for (Index k = rank; k < n; ++k) s.qd += 0.3 * std::cos(1.3 * static_cast<double>(k)) * V.col(k);
  return s;
}

// Every fifth column of ∂q̈/∂q and ∂q̈/∂q̇ against (4 D(h/2) − D(h)) / 3 of central differences of
// forward() (error O(h⁴), h = 1e-3), to 1e-6 of 1 + the column's size.
inline void expect_columns_match_differences(const Scenario& sc, const State& s, const Mat& dq,
                                             const Mat& dqd) {
  const System& sys = *sc.system;
  const Index n = sys.dof();
  ForwardData fd(sys);
  auto qdd_at = [&](const Vec& q, const Vec& qd) {
    forward(sys, fd, sc.sim.t0, q, qd, s.tau, sc.sim.uk);
    return Vec(fd.qdd);
  };
  for (int which = 0; which < 2; ++which) {
    const Mat& exact = which == 0 ? dq : dqd;
    for (Index j = 0; j < n; j += 5) {
      auto central = [&](double h) {
        Vec qp = s.q, qm = s.q, vp = s.qd, vm = s.qd;
        (which == 0 ? qp : vp)(j) += h;
        (which == 0 ? qm : vm)(j) -= h;
        return Vec((qdd_at(qp, vp) - qdd_at(qm, vm)) / (2 * h));
      };
      const Vec c = (4 * central(5e-4) - central(1e-3)) / 3;
      EXPECT_LE((exact.col(j) - c).cwiseAbs().maxCoeff(), 1e-6 * (1.0 + c.cwiseAbs().maxCoeff()))
          << n << " coordinates, which " << which << " column " << j;
    }
  }
}

// Two linearisations of one state by two solves: the same trust, message and rows, every
// derivative matrix and μ within `tol` relative, q̈ within 1e-12.
inline void expect_same_linearization(const Linearization& a, const Linearization& d, double tol) {
  const auto rel = [](const Mat& x, const Mat& y) {
    return (x - y).cwiseAbs().maxCoeff() / (1.0 + y.cwiseAbs().maxCoeff());
  };
  EXPECT_TRUE(a.trusted) << a.message;
  EXPECT_EQ(a.message, d.message);
  EXPECT_EQ(a.kept_rows, d.kept_rows);
  EXPECT_LE(a.kkt_agreement, 1e-10);
  const std::pair<const Mat*, const Mat*> pairs[] = {
      {&a.dqdd_dq, &d.dqdd_dq}, {&a.dqdd_dqd, &d.dqdd_dqd}, {&a.dqdd_dtau, &d.dqdd_dtau},
      {&a.dQc_dq, &d.dQc_dq},   {&a.dQc_dqd, &d.dQc_dqd},   {&a.dQc_dtau, &d.dQc_dtau},
      {&a.dmu_dq, &d.dmu_dq},   {&a.dmu_dqd, &d.dmu_dqd},   {&a.dmu_dtau, &d.dmu_dtau}};
  for (const auto& [x, y] : pairs) {
    ASSERT_EQ(x->rows(), y->rows());
    ASSERT_EQ(x->cols(), y->cols());
    if (x->size() > 0) {  // (no rows: μ and its derivatives empty)
      EXPECT_LE(rel(*x, *y), tol);
    }
  }
  EXPECT_LE(rel(a.qdd, d.qdd), 1e-12);
  ASSERT_EQ(a.mu.size(), d.mu.size());
  if (a.mu.size() > 0) {
    EXPECT_LE(rel(a.mu, d.mu), tol);
  }
}

}  // namespace ukdyn::test
