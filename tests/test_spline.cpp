// Cubic splines (src/symbolic/spline.cpp): interpolation, ends, continuity, and a spline
// trajectory derived exactly through GiNaC and the tapes.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>

#include "helpers.hpp"
#include "ukdyn/symbolic/constraint_kinds.hpp"
#include "ukdyn/symbolic/spline.hpp"

namespace {

using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;
namespace sym = ukdyn::symbolic;

using uktest::random_vec;
using uktest::rel;

// Clamped with the exact end slopes, a cubic spline reproduces a cubic; natural ends have S'' = 0;
// every spline is C2 at its knots.
TEST(ChainSpline, CubicSplinesInterpolate) {
  auto p = [](double t, int d) {
    switch (d) {
      case 0:
        return t * t * t - 2 * t * t + 1;
      case 1:
        return 3 * t * t - 4 * t;
      case 2:
        return 6 * t - 4;
      default:
        return 6.0;
    }
  };
  const std::vector<double> ts{0, 0.5, 1.5, 2, 3};
  std::vector<double> ys;
  for (double t : ts) ys.push_back(p(t, 0));
  const sym::CubicSpline clamped(ts, ys, sym::CubicSpline::End::clamped, p(0, 1), p(3, 1));
  std::mt19937_64 rng(1);
  double worst = 0;
  for (int k = 0; k < 200; ++k) {
    const double t = uktest::uniform(rng, -0.5, 3.5);
    for (int d = 0; d < 4; ++d) worst = std::max(worst, std::abs(clamped.eval(t, d) - p(t, d)));
  }
  EXPECT_LE(worst, 1e-12);
  const sym::CubicSpline natural(ts, {0, 1, -1, 0.5, 2});
  EXPECT_NEAR(natural.eval(0, 2), 0.0, 1e-14);
  EXPECT_NEAR(natural.eval(3, 2), 0.0, 1e-13);
  for (std::size_t i = 0; i < ts.size(); ++i) {
    EXPECT_NEAR(natural.eval(ts[i]), (std::vector<double>{0, 1, -1, 0.5, 2})[i], 1e-14);
    for (int d = 0; d < 3 && i > 0 && i + 1 < ts.size(); ++d) {
      EXPECT_NEAR(natural.eval(ts[i] - 1e-12, d), natural.eval(ts[i] + 1e-12, d), 1e-9) << d;
    }
  }
  EXPECT_THROW(sym::CubicSpline({0, 0}, {1, 2}), ukdyn::Error);
  EXPECT_THROW(sym::CubicSpline({0}, {1}), ukdyn::Error);
}

// A coordinate following a spline: A = 1, Φ̇ = q̇ − S'(t), b = S''(t), exact through GiNaC and the
// tape.
TEST(ChainSpline, SplineTrajectoryDerivesExactly) {
  const sym::CubicSpline s({0, 1, 2.5, 4}, {0, 0.4, 0.1, 1}, sym::CubicSpline::End::clamped, 0, 0);
  sym::ConstraintDef def("follow", sym::ConstraintDef::Kind::holonomic, {"x", "z"});
  const GiNaC::symbol time = def.symbols().time();
  sym::add_coordinate(def, "follow", "x", sym::spline_expression(s, time));
  sym::add_point_trajectory(def, "pz", {0, 0, sym::coordinate_symbol(def.symbols(), "z")},
                            {std::nullopt, std::nullopt, 2 * sym::spline_expression(s, time)});
  const auto c = sym::make_constraint(def);
  std::mt19937_64 rng(2);
  for (int k = 0; k < 50; ++k) {
    const Vec q = random_vec(rng, 2, -1, 1), qd = random_vec(rng, 2, -1, 1);
    const double t = uktest::uniform(rng, -0.5, 4.5);
    Mat A(2, 2);
    Vec b(2), phi(2), phid(2);
    c->evaluate({t}, q, qd, A, b);
    c->position_residual({t}, q, phi);
    c->velocity_residual({t}, q, qd, phid);
    EXPECT_NEAR(A(0, 0), 1.0, 1e-15);
    EXPECT_NEAR(b(0), s.eval(t, 2), 1e-12);
    EXPECT_NEAR(b(1), 2 * s.eval(t, 2), 1e-12);
    EXPECT_NEAR(phi(0), q(0) - s.eval(t), 1e-14);
    EXPECT_NEAR(phid(0), qd(0) - s.eval(t, 1), 1e-14);
  }
}

}  // namespace
