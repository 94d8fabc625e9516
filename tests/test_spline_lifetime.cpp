// Splines belong to the expressions and tapes that use them, and die with them (issue 10, item 1):
// no registry keeps them alive. Shown twice: directly (a weak_ptr to the spline expires once the
// system is dropped) and by resident memory staying flat over 10 000 built-and-dropped definition
// systems with splines (/proc/self/statm).
#include <gtest/gtest.h>

#include <fstream>
#include <memory>
#include <vector>

#include "ukdyn/model/system.hpp"
#include "ukdyn/symbolic/constraint_kinds.hpp"
#include "ukdyn/symbolic/definitions.hpp"
#include "ukdyn/symbolic/spline.hpp"

namespace {

namespace sym = ukdyn::symbolic;
using ukdyn::Vec;

// A point mass on a line whose coordinate follows a spline through `knots` points.
std::shared_ptr<ukdyn::System> spline_system(
    int knots, double shift, std::weak_ptr<const sym::CubicSpline>* seen = nullptr) {
  std::vector<double> t, y;
  for (int i = 0; i < knots; ++i) {
    t.push_back(0.01 * i);
    y.push_back(shift + 0.1 * ((i * 7) % 5));
  }
  sym::SubsystemDef d("mass", {"life_x"});
  auto& b = d.add_body("b");
  b.mass = d.parameter("m", 1.5);
  b.com = {d.q("life_x"), 0, 0};
  auto system = std::make_shared<ukdyn::System>();
  system->add_subsystem(sym::make_subsystem(d));
  sym::ConstraintDef c("follow", sym::ConstraintDef::Kind::holonomic, {"life_x"});
  const GiNaC::ex f = sym::spline_expression(sym::CubicSpline(t, y), c.symbols().time());
  if (seen) *seen = sym::spline_of(f.op(0));
  sym::add_coordinate(c, "follow", "life_x", f);
  system->add_constraint(sym::make_constraint(c));
  return system;
}

// Resident set size in bytes (second field of /proc/self/statm, in pages).
long resident_bytes() {
  std::ifstream in("/proc/self/statm");
  long size = 0, resident = 0;
  in >> size >> resident;
  return resident * 4096;
}

TEST(SplineLifetime, SplineDiesWithItsSystem) {
  std::weak_ptr<const sym::CubicSpline> seen;
  {
    auto system = spline_system(8, 0.0, &seen);
    ASSERT_FALSE(seen.expired());  // held by the tapes (and the derivation)
    ukdyn::ForwardData data(*system);
    const Vec q = Vec::Constant(1, 0.1), qd = Vec::Zero(1), tau = Vec::Zero(1);
    ukdyn::forward(*system, data, 0.035, q, qd, tau);
    EXPECT_TRUE(data.result.finite);
    EXPECT_FALSE(seen.expired());
  }
  EXPECT_TRUE(seen.expired()) << "a spline outlived the system that used it";
}

TEST(SplineLifetime, ResidentMemoryFlatOverTenThousandSystems) {
  if (!std::ifstream("/proc/self/statm")) GTEST_SKIP() << "no /proc/self/statm";
#ifdef UKDYN_TEST_SANITIZED
  GTEST_SKIP() << "a sanitizer's quarantine keeps freed memory resident (make sanitize)";
#endif
  // 64-knot splines: about 2.6 kB of knots and coefficients each, so a registry keeping them would
  // grow by ~25 MB over the 9 500 measured systems (more with GiNaC's objects around them).
  constexpr int kKnots = 64;
  const Vec q = Vec::Constant(1, 0.1), qd = Vec::Zero(1), tau = Vec::Zero(1);
  double checksum = 0.0;
  auto build_and_drop = [&](int k) {
    auto system = spline_system(kKnots, 1e-3 * k);
    ukdyn::ForwardData data(*system);
    ukdyn::forward(*system, data, 0.2, q, qd, tau);
    checksum += data.b(0);
  };
  for (int k = 0; k < 500; ++k) build_and_drop(k);  // warm-up: allocator pools, GiNaC tables
  const long warm = resident_bytes();
  std::vector<long> at;
  for (int k = 500; k < 10000; ++k) {
    build_and_drop(k);
    if ((k + 1) % 2375 == 0 || k == 9999) at.push_back(resident_bytes());
  }
  EXPECT_TRUE(std::isfinite(checksum));
  std::string trace;
  for (long r : at) trace += " " + std::to_string((r - warm) / 1024) + " kB";
  // Flat: growth after warm-up well under what 9 500 kept splines would take (~25 MB).
  EXPECT_LT(at.back() - warm, 4L * 1024 * 1024) << "resident growth after warm-up:" << trace;
  RecordProperty("resident_growth_kB", std::to_string((at.back() - warm) / 1024));
  std::cout << "[ resident growth over 9500 systems after warm-up:" << trace << " ]\n";
}

}  // namespace
