#include "ukdyn/symbolic/free_body.hpp"

#include "ukdyn/symbolic/canonical.hpp"

namespace ukdyn::symbolic {

using GiNaC::ex;

std::vector<std::string> free_body_coordinates(const std::string& name) {
  std::vector<std::string> c;
  for (const char* s : {"_x", "_y", "_z", "_qw", "_qx", "_qy", "_qz"}) c.push_back(name + s);
  return c;
}

std::array<ex, 9> quaternion_rotation(const ex& w, const ex& x, const ex& y, const ex& z) {
  return {
      w * w + x * x - y * y - z * z, 2 * (x * y - w * z),           2 * (x * z + w * y),
      2 * (x * y + w * z),           w * w - x * x + y * y - z * z, 2 * (y * z - w * x),
      2 * (x * z - w * y),           2 * (y * z + w * x),           w * w - x * x - y * y + z * z};
}

std::array<ex, 3> quaternion_body_rate(const ex& w, const ex& x, const ex& y, const ex& z,
                                       const ex& wd, const ex& xd, const ex& yd, const ex& zd) {
  // ω_body = 2 E(q) q̇ ([Udwadia2010b]), = vee(Rᵀ Ṙ) for |q| = 1 (tests/test_free_body.cpp).
  return {2 * (-x * wd + w * xd + z * yd - y * zd), 2 * (-y * wd - z * xd + w * yd + x * zd),
          2 * (-z * wd + y * xd - x * yd + w * zd)};
}

BodyDef& add_free_body(SubsystemDef& def, const ex& mass, const std::array<ex, 9>& inertia) {
  const auto& c = def.coordinates();
  if (c.size() != 7) {
    throw DefinitionError("a free body has 7 coordinates (x, y, z, qw, qx, qy, qz), got " +
                          std::to_string(c.size()));
  }
  const ex w = def.q(c[3]), x = def.q(c[4]), y = def.q(c[5]), z = def.q(c[6]);
  const ex wd = def.qd(c[3]), xd = def.qd(c[4]), yd = def.qd(c[5]), zd = def.qd(c[6]);
  BodyDef& b = def.add_body(def.name());
  b.mass = mass;
  b.com = {def.q(c[0]), def.q(c[1]), def.q(c[2])};
  b.rotation = quaternion_rotation(w, x, y, z);
  b.angular_velocity = quaternion_body_rate(w, x, y, z, wd, xd, yd, zd);
  b.inertia_kind = BodyDef::InertiaKind::tensor;
  b.inertia_tensor = inertia;
  b.inertia_frame = Frame::body;
  return b;
}

SubsystemDef free_body_definition(const std::string& name, double mass,
                                  const std::array<double, 9>& inertia,
                                  const std::array<double, 3>& gravity,
                                  std::vector<std::string> coordinates,
                                  std::shared_ptr<SymbolTable> symbols) {
  if (coordinates.empty()) coordinates = free_body_coordinates(name);
  SubsystemDef def(name, std::move(coordinates), std::move(symbols));
  const ex m = def.parameter("m", mass);
  std::array<ex, 9> J;
  static const char* const names[9] = {"Jxx", "Jxy", "Jxz", "Jxy", "Jyy",
                                       "Jyz", "Jxz", "Jyz", "Jzz"};
  for (int i = 0; i < 3; ++i) {
    for (int j = i; j < 3; ++j) {
      const ex s = def.parameter(names[3 * i + j], inertia[static_cast<std::size_t>(3 * i + j)]);
      J[static_cast<std::size_t>(3 * i + j)] = s;
      J[static_cast<std::size_t>(3 * j + i)] = s;
    }
  }
  for (int i = 0; i < 3; ++i) {
    const auto k = static_cast<std::size_t>(i);
    def.gravity[k] = exact_rational(gravity[k]);
  }
  add_free_body(def, m, J);
  return def;
}

ConstraintDef free_body_norm_constraint(const std::string& name,
                                        const std::vector<std::string>& quaternion,
                                        const std::vector<std::string>& system_coordinates,
                                        std::shared_ptr<SymbolTable> symbols) {
  if (quaternion.size() != 4) throw DefinitionError("a quaternion has 4 coordinates");
  ConstraintDef def(name, ConstraintDef::Kind::holonomic, system_coordinates, std::move(symbols));
  ex s = -1;
  for (const auto& c : quaternion) {
    const ex v = def.parse(c);
    s += v * v;
  }
  def.add_row(name + "_unit", s);
  return def;
}

}  // namespace ukdyn::symbolic
