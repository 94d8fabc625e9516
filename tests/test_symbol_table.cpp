// Symbols belong to the system whose derivation made them (issue 10, item 1; docs/architecture.md,
// "Symbols"): within one SymbolTable a name is one symbol (a subsystem and a constraint of one
// system share their coordinates), another table gives another symbol, and the table dies with the
// last definition or derived block that holds it. Resident memory stays flat over thousands of
// built-and-dropped systems with names never seen before (a table kept by name, as the global map
// it replaces was, would grow with every new name).
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "symbolic_systems.hpp"
#include "ukdyn/model/system.hpp"
#include "ukdyn/symbolic/constraint_kinds.hpp"
#include "ukdyn/symbolic/definitions.hpp"

namespace {

namespace sym = ukdyn::symbolic;
using ukdyn::Vec;

TEST(SymbolTable, SameNameSameSymbolInOneTableOnly) {
  sym::SymbolTable a, b;
  EXPECT_TRUE(a.coordinate("x").is_equal(a.coordinate("x")));
  EXPECT_TRUE(a.velocity("x").is_equal(a.velocity("x")));
  EXPECT_TRUE(a.time().is_equal(a.time()));
  EXPECT_FALSE(a.coordinate("x").is_equal(a.velocity("x")));
  EXPECT_FALSE(a.coordinate("x").is_equal(b.coordinate("x")));
  EXPECT_FALSE(a.time().is_equal(b.time()));
  EXPECT_EQ(a.size(), 3u);  // x, x_dot, t
  EXPECT_TRUE(a.has_coordinate("x"));
  EXPECT_FALSE(a.has_coordinate("y"));
  EXPECT_EQ(a.size(), 3u);  // the lookup added nothing
  EXPECT_EQ(a.velocity("x").get_name(), "x_dot");
}

// A pendulum on a cart, the cart held at x = 0.2 by a constraint written with the subsystem's own
// symbol (an expression crossing from one definition into another): one table, so the constraint
// sees its coordinate, A = [1 0] and Φ = x − 0.2 exactly.
std::shared_ptr<ukdyn::System> cart(const std::shared_ptr<sym::SymbolTable>& symbols,
                                    const std::string& x, const std::string& phi) {
  const sym::SubsystemDef d = uktest::cart_pendulum_def(x, phi, symbols);
  auto system = std::make_shared<ukdyn::System>();
  system->add_subsystem(sym::make_subsystem(d));
  sym::ConstraintDef c("hold", sym::ConstraintDef::Kind::holonomic, {x, phi}, symbols);
  c.add_row("x", d.q(x) - GiNaC::numeric(1, 5));
  system->add_constraint(sym::make_constraint(c));
  return system;
}

const sym::DerivedSubsystem& derived_subsystem(const ukdyn::System& s) {
  return dynamic_cast<const sym::DerivedSubsystem&>(*s.subsystems().front());
}
const sym::DerivedConstraint& derived_constraint(const ukdyn::System& s) {
  return dynamic_cast<const sym::DerivedConstraint&>(*s.constraints().front());
}

TEST(SymbolTable, SubsystemAndConstraintOfOneSystemShareItsTable) {
  const auto symbols = std::make_shared<sym::SymbolTable>();
  const auto system = cart(symbols, "x", "phi");
  EXPECT_EQ(derived_subsystem(*system).derivation().symbols.get(), symbols.get());
  EXPECT_EQ(derived_constraint(*system).derivation().symbols.get(), symbols.get());
  ukdyn::ForwardData data(*system);
  const Vec q = (Vec(2) << 0.5, 0.3).finished(), qd = Vec::Zero(2);
  ukdyn::evaluate_constraints(*system, data, 0.0, q, qd);
  EXPECT_EQ(data.A(0, 0), 1.0);
  EXPECT_EQ(data.A(0, 1), 0.0);
  Vec phi(1);
  system->constraints().front()->position_residual({}, q, phi);
  EXPECT_EQ(phi(0), 0.5 - 0.2);
}

// The test can fail: two definitions with tables of their own have two different symbols x.
TEST(SymbolTable, TwoTablesDoNotShareCoordinates) {
  sym::SubsystemDef d("cart", {"x"});
  sym::ConstraintDef c("hold", sym::ConstraintDef::Kind::holonomic, {"x"});
  EXPECT_NE(d.symbol_table().get(), c.symbol_table().get());
  EXPECT_FALSE(GiNaC::ex(d.q("x")).is_equal(c.parse("x")));
}

TEST(SymbolTable, TableDiesWithItsSystem) {
  std::weak_ptr<sym::SymbolTable> seen;
  {
    auto symbols = std::make_shared<sym::SymbolTable>();
    seen = symbols;
    auto system = cart(symbols, "x", "phi");
    symbols.reset();
    ASSERT_FALSE(seen.expired());  // held by the derived subsystem and constraint
    EXPECT_GE(seen.lock()->size(), 5u);
  }
  EXPECT_TRUE(seen.expired()) << "a symbol table outlived the system that used it";
}

long resident_bytes() {
  std::ifstream in("/proc/self/statm");
  long size = 0, resident = 0;
  in >> size >> resident;
  return resident * 4096;
}

TEST(SymbolTable, ResidentMemoryFlatOverSystemsWithNewNames) {
  if (!std::ifstream("/proc/self/statm")) GTEST_SKIP() << "no /proc/self/statm";
#ifdef UKDYN_TEST_SANITIZED
  GTEST_SKIP() << "a sanitizer's quarantine keeps freed memory resident (make sanitize)";
#endif
  // Every system has coordinate names of its own (60 characters): a table kept beyond its system
  // would keep 5 symbols with their names (~1 kB) per system, ~4 MB over the 4 000 measured.
  const std::string pad(52, 'n');
  const Vec q = (Vec(2) << 0.2, 0.3).finished(), qd = Vec::Zero(2), tau = Vec::Zero(2);
  double checksum = 0.0;
  std::weak_ptr<sym::SymbolTable> last;
  auto build_and_drop = [&](int k) {
    auto symbols = std::make_shared<sym::SymbolTable>();
    last = symbols;
    const std::string id = std::to_string(100000 + k);
    auto system = cart(symbols, "x" + pad + id, "p" + pad + id);
    symbols.reset();
    ukdyn::ForwardData data(*system);
    ukdyn::forward(*system, data, 0.0, q, qd, tau);
    checksum += data.qdd(1);
  };
  for (int k = 0; k < 500; ++k) build_and_drop(k);  // warm-up: allocator pools, GiNaC tables
  EXPECT_TRUE(last.expired());
  const long warm = resident_bytes();
  for (int k = 500; k < 4500; ++k) build_and_drop(k);
  const long grown = resident_bytes() - warm;
  EXPECT_TRUE(last.expired());
  EXPECT_TRUE(std::isfinite(checksum));
  EXPECT_LT(grown, 2L * 1024 * 1024) << "resident growth after warm-up: " << grown / 1024 << " kB";
  std::cout << "[ resident growth over 4000 systems after warm-up: " << grown / 1024 << " kB ]\n";
}

}  // namespace
