#include "ukdyn/symbolic/constraint_kinds.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "ukdyn/symbolic/canonical.hpp"

namespace ukdyn::symbolic {

using GiNaC::ex;

ex exact_number(double v) {
  if (!std::isfinite(v)) throw DefinitionError("a number must be finite");
  std::ostringstream os;
  os.precision(15);
  os << v;
  try {
    const ex e = Scope().parse(os.str());
    const ex f = e.evalf();
    if (GiNaC::is_a<GiNaC::numeric>(f) &&
        std::abs(GiNaC::ex_to<GiNaC::numeric>(f).to_double() - v) <= 1e-15 * std::abs(v)) {
      return e;
    }
  } catch (const ExpressionError&) {
  }
  return exact_rational(v);  // exact, never a float (canonical.hpp)
}

ex cosine_expression(const ex& mean, const ex& amplitude, const ex& omega, const ex& phase,
                     const GiNaC::symbol& t) {
  return mean + amplitude * GiNaC::cos(omega * t + phase);
}

ex polynomial_expression(const std::vector<ex>& c, const GiNaC::symbol& t) {
  ex r = 0;
  for (std::size_t k = 0; k < c.size(); ++k) r += c[k] * GiNaC::pow(t, static_cast<int>(k));
  return r;
}

ex time_expression(const TimeFunction& f, const GiNaC::symbol& t) {
  switch (f.kind) {
    case TimeFunction::Kind::constant:
      return exact_number(f.coeff[0]);
    case TimeFunction::Kind::cosine:
      return cosine_expression(exact_number(f.mean), exact_number(f.amplitude),
                               exact_number(f.omega), exact_number(f.phase), t);
    case TimeFunction::Kind::polynomial: {
      std::vector<ex> c;
      for (int k = 0; k < f.ncoeff; ++k)
        c.push_back(exact_number(f.coeff[static_cast<std::size_t>(k)]));
      return polynomial_expression(c, t);
    }
  }
  return 0;
}

void add_points_coincide(ConstraintDef& def, const std::string& prefix, const Vec3Ex& a,
                         const Vec3Ex& b, std::array<bool, 3> axes) {
  static const char* const kAxis[3] = {"x", "y", "z"};
  if (!axes[0] && !axes[1] && !axes[2])
    throw DefinitionError("points_coincide '" + prefix + "': no axis selected");
  for (std::size_t k = 0; k < 3; ++k) {
    if (axes[k]) def.add_row(prefix + "_" + kAxis[k], a[k] - b[k]);
  }
}

void add_point_trajectory(ConstraintDef& def, const std::string& prefix, const Vec3Ex& p,
                          const std::array<std::optional<ex>, 3>& f, const Vec3Ex& origin) {
  static const char* const kAxis[3] = {"x", "y", "z"};
  bool any = false;
  for (std::size_t k = 0; k < 3; ++k) {
    if (!f[k]) continue;
    any = true;
    def.add_row(prefix + "_" + kAxis[k], p[k] - (origin[k] + *f[k]));
  }
  if (!any)
    throw DefinitionError("point_trajectory '" + prefix + "': give at least one of x, y, z");
}

void add_angle_relation(ConstraintDef& def, const std::string& row,
                        const std::vector<std::pair<std::string, ex>>& terms, const ex& value) {
  const auto& coords = def.system_coordinates();
  ex phi = 0;
  bool any = false;
  for (const auto& [c, k] : terms) {
    if (std::find(coords.begin(), coords.end(), c) == coords.end())
      throw DefinitionError("angle_relation '" + row + "': no coordinate named '" + c + "'");
    const ex kv = k.subs(def.parameter_values()).evalf();
    if (!GiNaC::is_a<GiNaC::numeric>(kv)) {
      throw DefinitionError("angle_relation '" + row + "': the coefficient of '" + c +
                            "' must be a constant");
    }
    any = any || !kv.is_zero();
    phi += k * coordinate_symbol(def.symbols(), c);
  }
  if (!any) throw DefinitionError("angle_relation '" + row + "': no nonzero coefficient");
  def.add_row(row, phi - value);
}

void add_coordinate(ConstraintDef& def, const std::string& row, const std::string& coordinate,
                    const ex& value) {
  add_angle_relation(def, row, {{coordinate, 1}}, value);
}

}  // namespace ukdyn::symbolic
