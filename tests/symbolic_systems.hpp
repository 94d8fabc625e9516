// Small systems built from definitions, shared by the tests that need a symbolic system with a
// spline (tests/test_threads.cpp, tests/test_no_alloc.cpp) or a symbol table of their own
// (tests/test_symbol_table.cpp).
#pragma once

#include <memory>

#include "ukdyn/model/system.hpp"
#include "ukdyn/symbolic/constraint_kinds.hpp"
#include "ukdyn/symbolic/definitions.hpp"
#include "ukdyn/symbolic/spline.hpp"

namespace uktest {

/// The definition of a cart (coordinate `x`) carrying a pendulum (`phi`, length 0.8, masses 2 and
/// 0.5, gravity 9.81 along −z), in the symbol table `symbols` (a new one if null).
inline ukdyn::symbolic::SubsystemDef cart_pendulum_def(
    const std::string& x, const std::string& phi,
    std::shared_ptr<ukdyn::symbolic::SymbolTable> symbols = nullptr) {
  namespace sym = ukdyn::symbolic;
  sym::SubsystemDef d("cart", {x, phi}, std::move(symbols));
  const auto l = d.parameter("l", 0.8);
  auto& cart = d.add_body("cart");
  cart.mass = d.parameter("M", 2.0);
  cart.com = {d.q(x), 0, 0};
  auto& bob = d.add_body("bob");
  bob.mass = d.parameter("m", 0.5);
  bob.com = {d.q(x) + l * GiNaC::sin(d.q(phi)), 0, -l * GiNaC::cos(d.q(phi))};
  d.gravity = {0, 0, -9.81};
  return d;
}

/// The cart and pendulum of cart_pendulum_def (coordinates `<prefix>x`, `<prefix>phi`); the cart
/// follows a clamped cubic spline through (0, 0), (0.3, 0.2), (0.7, −0.1), (1, 0.3). One degree of
/// freedom is left: the pendulum.
inline std::shared_ptr<ukdyn::System> spline_cart_system(const std::string& prefix = "sc_") {
  namespace sym = ukdyn::symbolic;
  const std::string x = prefix + "x", phi = prefix + "phi";
  const sym::SubsystemDef d = cart_pendulum_def(x, phi);
  auto system = std::make_shared<ukdyn::System>();
  system->add_subsystem(sym::make_subsystem(d));
  const sym::CubicSpline s({0, 0.3, 0.7, 1.0}, {0, 0.2, -0.1, 0.3}, sym::CubicSpline::End::clamped,
                           0, 0);
  sym::ConstraintDef c("follow", sym::ConstraintDef::Kind::holonomic, {x, phi});
  sym::add_coordinate(c, "follow", x, sym::spline_expression(s, c.symbols().time()));
  system->add_constraint(sym::make_constraint(c));
  return system;
}

}  // namespace uktest
