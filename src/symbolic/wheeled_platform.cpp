// Wheeled platforms (ukdyn/symbolic/wheeled_platform.hpp, docs/wheeled-platforms.md): a generator of
// a definitions subsystem and its nonholonomic rolling rows, so that the derivation, the tapes,
// `ukdyn derive` and the exact derivatives of `linearize` come from the same machinery as a model
// written by hand.
#include "ukdyn/symbolic/wheeled_platform.hpp"

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <sstream>

#include "ukdyn/symbolic/canonical.hpp"

namespace ukdyn::symbolic {

using GiNaC::ex;

namespace {

// cos and sin with the round-off of a multiple of π/2 removed (cos(π/2) is 6.1e-17 in doubles):
// an omni wheel's roller axis is then exactly its rolling direction.
double snap(double v) { return std::abs(v) < 1e-15 ? 0.0 : v; }

// The roller axis e_i in the platform frame: cos γ s_i + sin γ d_i (header).
std::pair<double, double> roller_axis(const PlatformWheel& w) {
  const double cb = snap(std::cos(w.heading)), sb = snap(std::sin(w.heading));
  const double cg = snap(std::cos(w.roller_angle)), sg = snap(std::sin(w.roller_angle));
  return {snap(-cg * sb + sg * cb), snap(cg * cb + sg * sb)};
}

// The number as written in the scenario, exactly: the shortest decimal that reads back to v
// (0.3 → 3/10, not the binary fraction 5404319552844595/18014398509481984), so that `ukdyn derive`
// prints the rows as they would be written by hand.
ex decimal(double v) {
  for (int digits = 1; digits <= 17; ++digits) {
    char buf[40];
    std::snprintf(buf, sizeof buf, "%.*e", digits - 1, v);
    if (std::strtod(buf, nullptr) != v) continue;
    const std::string text(buf);
    const auto e = text.find('e');
    std::string mantissa = text.substr(0, e);
    const long exponent = std::strtol(text.c_str() + e + 1, nullptr, 10);
    const auto dot = mantissa.find('.');
    long scale = exponent;
    if (dot != std::string::npos) {
      scale -= static_cast<long>(mantissa.size() - dot - 1);
      mantissa.erase(dot, 1);
    }
    GiNaC::numeric n(mantissa.c_str());
    return scale >= 0 ? ex(n * GiNaC::pow(GiNaC::numeric(10), GiNaC::numeric(scale)))
                      : ex(n / GiNaC::pow(GiNaC::numeric(10), GiNaC::numeric(-scale)));
  }
  return exact_rational(v);
}

// cos and sin of an angle: exact when it is k π/12 (GiNaC gives cos(π/4) = √2/2, cos(π/2) = 0),
// otherwise the decimal of the double's value.
std::pair<ex, ex> cos_sin(double a) {
  const double k = a / (std::numbers::pi / 12);
  if (std::abs(k - std::round(k)) < 1e-9 && std::abs(k) < 1e6) {
    const ex x = GiNaC::numeric(static_cast<long>(std::round(k)), 12) * GiNaC::Pi;
    return {cos(x), sin(x)};
  }
  return {decimal(std::cos(a)), decimal(std::sin(a))};
}

std::string number_text(double v) {
  std::ostringstream os;
  os.precision(6);
  os << v;
  return os.str();
}

}  // namespace

std::vector<std::string> wheeled_platform_coordinates(const std::string& name, std::size_t wheels) {
  std::vector<std::string> c{name + "_x", name + "_y", name + "_yaw"};
  for (std::size_t i = 0; i < wheels; ++i) c.push_back(name + "_phi" + std::to_string(i + 1));
  return c;
}

std::vector<PlatformWheel> differential_drive_wheels(double track_width) {
  const double h = 0.5 * track_width, quarter = std::acos(0.0);  // γ = π/2: rolls along d
  return {PlatformWheel{0.0, h, 0.0, quarter}, PlatformWheel{0.0, -h, 0.0, quarter}};
}

Mat wheel_rate_matrix(const WheeledPlatformDef& def) {
  Mat H(static_cast<Index>(def.wheels.size()), 3);
  for (std::size_t i = 0; i < def.wheels.size(); ++i) {
    const PlatformWheel& w = def.wheels[i];
    const auto [ex_, ey] = roller_axis(w);
    const double k = def.wheel_radius * std::sin(w.roller_angle);
    const auto r = static_cast<Index>(i);
    H(r, 0) = ex_ / k;
    H(r, 1) = ey / k;
    H(r, 2) = (ey * w.x - ex_ * w.y) / k;
  }
  return H;
}

std::string wheeled_platform_problem(const WheeledPlatformDef& def) {
  const auto positive = [](double v) { return std::isfinite(v) && v > 0.0; };
  if (!positive(def.wheel_radius)) return "wheel_radius must be > 0";
  if (!positive(def.mass)) return "mass must be > 0";
  if (!positive(def.yaw_inertia)) return "yaw_inertia must be > 0";
  if (!positive(def.wheel_inertia)) return "wheel_inertia must be > 0";
  if (def.kind != WheeledPlatformKind::differential_drive && def.wheels.size() < 3)
    return "a platform on Mecanum or omni wheels needs at least 3 wheels, got " +
           std::to_string(def.wheels.size());
  for (std::size_t i = 0; i < def.wheels.size(); ++i) {
    if (std::abs(std::sin(def.wheels[i].roller_angle)) < 1e-3)
      return "wheel " + std::to_string(i + 1) + ": roller_angle " +
             number_text(def.wheels[i].roller_angle) +
             " rad puts the rollers' axes along the axle: the rolling row loses the wheel's rate "
             "(r sin(roller_angle) = 0) and the wheel spins freely (|sin(roller_angle)| must be "
             ">= 1e-3)";
  }
  if (def.kind == WheeledPlatformKind::differential_drive) return {};
  const Mat H = wheel_rate_matrix(def);
  Eigen::JacobiSVD<Mat> svd(H, Eigen::ComputeFullV);
  const Vec s = svd.singularValues();
  if (s(2) <= 1e-9 * s(0)) {
    const Vec v = svd.matrixV().col(2);
    return "the wheels cannot drive every motion of the platform: the twist (u, w, omega) = (" +
           number_text(v(0)) + ", " + number_text(v(1)) + ", " + number_text(v(2)) +
           ") turns no wheel (rank of the wheel-rate matrix < 3; check the positions, headings "
           "and roller angles)";
  }
  return {};
}

SubsystemDef wheeled_platform_definition(const std::string& name, const WheeledPlatformDef& def,
                                         const std::vector<std::string>& coordinates,
                                         std::shared_ptr<SymbolTable> symbols) {
  if (coordinates.size() != def.wheels.size() + 3)
    throw DefinitionError("a wheeled platform with " + std::to_string(def.wheels.size()) +
                          " wheels has " + std::to_string(def.wheels.size() + 3) +
                          " coordinates (x, y, yaw, one angle per wheel)");
  SubsystemDef d(name, coordinates, std::move(symbols));
  // Parameters m, I, J (kept as symbols in `ukdyn derive`), renamed m_, m__, ... if a coordinate
  // has the name.
  const auto free_name = [&](std::string n) {
    while (std::find(coordinates.begin(), coordinates.end(), n) != coordinates.end()) n += "_";
    return n;
  };
  const ex m = d.parameter(free_name("m"), decimal(def.mass));
  const ex I = d.parameter(free_name("I"), decimal(def.yaw_inertia));
  const ex J = d.parameter(free_name("J"), decimal(def.wheel_inertia));
  const ex x = d.q(coordinates[0]), y = d.q(coordinates[1]), psi = d.q(coordinates[2]);
  const ex c = cos(psi), s = sin(psi);
  const ex cx = decimal(def.com_x), cy = decimal(def.com_y);
  BodyDef& p = d.add_body("platform");
  p.mass = m;
  p.com = {x + c * cx - s * cy, y + s * cx + c * cy, 0};
  p.rotation = std::array<ex, 9>{c, -s, 0, s, c, 0, 0, 0, 1};  // Rz(ψ), world from platform
  p.inertia_kind = BodyDef::InertiaKind::scalar;               // ½ I |ω|², ω = ψ̇ e_z
  p.inertia_scalar = I;
  for (std::size_t i = 0; i < def.wheels.size(); ++i) {
    BodyDef& w = d.add_body("wheel" + std::to_string(i + 1));
    w.mass = 0;  // in m; its spin: ½ J φ̇_i² (no cross term with the yaw, header)
    // its hub (massless: only where the replay page draws the wheel)
    const ex a = decimal(def.wheels[i].x), b = decimal(def.wheels[i].y);
    w.com = {x + c * a - s * b, y + s * a + c * b, decimal(def.wheel_radius)};
    w.angular_velocity = std::array<ex, 3>{d.qd(coordinates[3 + i]), 0, 0};
    w.inertia_kind = BodyDef::InertiaKind::scalar;
    w.inertia_scalar = J;
  }
  d.gravity = {0, 0, 0};  // the floor is horizontal: gravity does no work in the plane
  return d;
}

ConstraintDef wheeled_platform_rolling_constraint(
    const std::string& name, const WheeledPlatformDef& def,
    const std::vector<std::string>& coordinates, const std::vector<std::string>& system_coordinates,
    std::shared_ptr<SymbolTable> symbols, const std::string& constraint_name) {
  if (coordinates.size() != def.wheels.size() + 3)
    throw DefinitionError("rolling rows of " + std::to_string(def.wheels.size()) + " wheels need " +
                          std::to_string(def.wheels.size() + 3) +
                          " coordinates (x, y, yaw, one angle per wheel)");
  ConstraintDef c(constraint_name.empty() ? name + "_rolling" : constraint_name,
                  ConstraintDef::Kind::nonholonomic, system_coordinates, std::move(symbols));
  const ex xd = c.parse(coordinates[0] + "_dot"), yd = c.parse(coordinates[1] + "_dot");
  const ex psi = c.parse(coordinates[2]), psid = c.parse(coordinates[2] + "_dot");
  const ex u = cos(psi) * xd + sin(psi) * yd;   // forward velocity, platform frame
  const ex w = -sin(psi) * xd + cos(psi) * yd;  // leftward velocity, platform frame
  const bool diff = def.kind == WheeledPlatformKind::differential_drive;
  if (diff) c.add_row(name + "_lateral", w);
  const ex r = decimal(def.wheel_radius);
  for (std::size_t i = 0; i < def.wheels.size(); ++i) {
    const PlatformWheel& wh = def.wheels[i];
    const ex phid = c.parse(coordinates[3 + i] + "_dot");
    // e = cos γ s + sin γ d (header), exact where γ and β are multiples of π/12
    const auto [cb, sb] = cos_sin(wh.heading);
    const auto [cg, sg] = cos_sin(wh.roller_angle);
    const ex ex_ = (-cg * sb + sg * cb).expand(), ey = (cg * cb + sg * sb).expand();
    const ex row =
        ex_ * u + ey * w + psid * (ey * decimal(wh.x) - ex_ * decimal(wh.y)) - r * sg * phid;
    c.add_row(diff ? name + (i == 0 ? "_roll_left" : "_roll_right")
                   : name + "_wheel" + std::to_string(i + 1),
              row);
  }
  return c;
}

}  // namespace ukdyn::symbolic
