#include "ukdyn/symbolic/forces.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "symbolic/ex_helpers.hpp"
#include "ukdyn/symbolic/tape_inputs.hpp"

namespace ukdyn::symbolic {

namespace {

using GiNaC::ex;

}  // namespace

ForceDef::ForceDef(std::vector<std::string> system_coordinates, std::string name,
                   std::shared_ptr<SymbolTable> symbols)
    : DefinitionScope(std::move(symbols)),
      name_(std::move(name)),
      coords_(std::move(system_coordinates)),
      nc_(coords_.size(), 0) {
  for (const auto& c : coords_) {
    scope_.add(c, coordinate_symbol(*symbols_, c));
    scope_.add(c + "_dot", velocity_symbol(*symbols_, c));
  }
  scope_.add_time(time_symbol(*symbols_));
}

std::size_t ForceDef::index_of(const std::string& coordinate, const std::string& where) const {
  const auto it = std::find(coords_.begin(), coords_.end(), coordinate);
  if (it == coords_.end())
    throw DefinitionError(where + ": no coordinate named '" + coordinate + "'");
  return static_cast<std::size_t>(it - coords_.begin());
}

double ForceDef::constant_value(const ex& e, const std::string& where) const {
  const ex v = e.subs(parameter_values()).evalf();
  if (!GiNaC::is_a<GiNaC::numeric>(v) || !GiNaC::ex_to<GiNaC::numeric>(v).is_real())
    throw DefinitionError(where + " must be a constant (a number or parameters), got '" + str(e) +
                          "'");
  return GiNaC::ex_to<GiNaC::numeric>(v).to_double();
}

void ForceDef::check_state_expression(const ex& e, const std::string& where) const {
  // Every symbol must be a coordinate, a velocity, t or a parameter of this definition.
  GiNaC::exset syms;
  const ex x = e.subs(parameter_values());
  for (GiNaC::const_preorder_iterator it = x.preorder_begin(); it != x.preorder_end(); ++it) {
    if (!GiNaC::is_a<GiNaC::symbol>(*it)) continue;
    bool known = it->is_equal(time_symbol(*symbols_));
    for (const auto& c : coords_) {
      known = known || it->is_equal(coordinate_symbol(*symbols_, c)) ||
              it->is_equal(velocity_symbol(*symbols_, c));
    }
    if (!known) {
      throw DefinitionError(where + ": unknown symbol '" + str(*it) +
                            "' (not a coordinate, velocity, t or parameter)");
    }
  }
}

void ForceDef::add_generalized(const std::string& coordinate, const ex& value) {
  const std::string where = "generalized force on '" + coordinate + "'";
  const std::size_t i = index_of(coordinate, where);
  check_state_expression(value, where);
  nc_[i] += value;
  elements_.push_back("generalized." + coordinate);
}

void ForceDef::add_spring_damper(const std::string& element, const Vec3Ex& a, const Vec3Ex& b,
                                 const ex& stiffness, const ex& damping, const ex& rest_length) {
  const std::string where = "spring_damper '" + element + "'";
  const double k = constant_value(stiffness, where + ": stiffness");
  const double c = constant_value(damping, where + ": damping");
  const double l0 = constant_value(rest_length, where + ": rest_length");
  if (!(k >= 0.0)) throw DefinitionError(where + ": stiffness must be >= 0");
  if (!(c >= 0.0)) throw DefinitionError(where + ": damping must be >= 0");
  if (!(l0 >= 0.0)) throw DefinitionError(where + ": rest_length must be >= 0");
  const GiNaC::symbol t = time_symbol(*symbols_);
  Spring sp{element, {0, 0, 0}, k, c, l0, false};
  for (std::size_t k3 = 0; k3 < 3; ++k3) {
    check_state_expression(a[k3], where + ": point a");
    check_state_expression(b[k3], where + ": point b");
    sp.d[k3] = a[k3] - b[k3];
    for (const auto& cn : coords_) {
      if (sp.d[k3].has(velocity_symbol(*symbols_, cn)))
        throw DefinitionError(where + ": a point may not depend on velocities (*_dot)");
    }
    sp.moving = sp.moving || sp.d[k3].has(t);
  }
  springs_.push_back(std::move(sp));
  elements_.push_back(element);
}

void ForceDef::add_joint_friction(const std::string& element, const std::string& coordinate,
                                  const ex& viscous, const ex& coulomb, const ex& velocity_scale) {
  const std::string where = "joint_friction '" + element + "'";
  const std::size_t i = index_of(coordinate, where);
  if (!(constant_value(viscous, where + ": viscous") >= 0.0))
    throw DefinitionError(where + ": viscous must be >= 0");
  const double mu = constant_value(coulomb, where + ": coulomb");
  if (!(mu >= 0.0)) throw DefinitionError(where + ": coulomb must be >= 0");
  const ex v = velocity_symbol(*symbols_, coordinate);
  nc_[i] += -viscous * v;
  if (mu > 0.0) {
    if (!(constant_value(velocity_scale, where + ": velocity_scale") > 0.0))
      throw DefinitionError(where + ": velocity_scale must be > 0");
    nc_[i] += -coulomb * GiNaC::tanh(v / velocity_scale);
  }
  elements_.push_back(element);
}

void ForceDef::add_torque(const std::string& element, const std::string& coordinate,
                          const ex& value) {
  const std::string where = "torque '" + element + "'";
  const std::size_t i = index_of(coordinate, where);
  check_state_expression(value, where);
  nc_[i] += value;
  elements_.push_back(element);
}

ForceDerivation derive(const ForceDef& def) {
  const auto n = static_cast<unsigned>(def.system_coordinates().size());
  ForceDerivation d;
  d.coordinates = def.system_coordinates();
  d.parameter_values = def.parameter_values();
  d.symbols = def.symbol_table();
  SymbolTable& syms = def.symbols();
  d.Q = GiNaC::matrix(n, 1);
  for (unsigned i = 0; i < n; ++i) d.Q(i, 0) = def.nonconservative()[i];
  const GiNaC::symbol t = time_symbol(syms);
  for (const auto& sp : def.springs()) {
    ForceDerivation::Spring s{sp.name,
                              GiNaC::matrix(3, 1),
                              GiNaC::matrix(3, 1),
                              GiNaC::matrix(3, n),
                              sp.k,
                              sp.c,
                              sp.rest_length,
                              sp.moving};
    for (unsigned k = 0; k < 3; ++k) {
      s.d(k, 0) = sp.d[k];
      ex dd = sp.d[k].diff(t);
      for (unsigned j = 0; j < n; ++j) {
        s.J(k, j) = sp.d[k].diff(coordinate_symbol(syms, d.coordinates[j]));
        dd += s.J(k, j) * velocity_symbol(syms, d.coordinates[j]);
      }
      s.dd(k, 0) = dd;
    }
    d.springs.push_back(std::move(s));
  }
  return d;
}

DerivedAppliedForce::DerivedAppliedForce(ForceDerivation derivation, std::string name)
    : d_(std::move(derivation)), name_(std::move(name)) {
  const InputMap in = coordinate_inputs(*d_.symbols, d_.coordinates);
  const auto& pv = d_.parameter_values;
  std::vector<ex> out;
  for (unsigned i = 0; i < d_.Q.rows(); ++i) {
    const ex e = numeric_form(d_.Q(i, 0), pv);
    if (e.is_zero()) continue;
    q_index_.push_back(static_cast<Index>(i));
    out.push_back(e);
  }
  q_ = Tape(out, in);
  std::vector<ex> sp_out, d_out;
  for (const auto& s : d_.springs) {
    CompiledSpring c{s.k, s.c, s.rest_length, s.moving, {}, sp_out.size(), d_out.size()};
    for (unsigned k = 0; k < 3; ++k) {
      sp_out.push_back(numeric_form(s.d(k, 0), pv));
      d_out.push_back(numeric_form(s.d(k, 0), pv));
    }
    for (unsigned k = 0; k < 3; ++k) sp_out.push_back(numeric_form(s.dd(k, 0), pv));
    for (unsigned j = 0; j < s.J.cols(); ++j) {
      for (unsigned k = 0; k < 3; ++k) {
        const ex e = numeric_form(s.J(k, j), pv);
        if (e.is_zero()) continue;
        c.jac.emplace_back(static_cast<Index>(j), static_cast<int>(k));
        sp_out.push_back(e);
      }
    }
    has_potential_ = has_potential_ || (!s.moving && s.k != 0.0);
    springs_.push_back(std::move(c));
  }
  springs_tape_ = Tape(sp_out, in);
  d_only_ = Tape(d_out, in);
}

bool DerivedAppliedForce::add_tangent(double t, CVecRef q, CVecRef qd, CVecRef dq, CVecRef dqd,
                                      VecRef dQ) const {
  add_tangent_along(t, q, qd, 0.0, dq, dqd, dQ);
  return true;
}

bool DerivedAppliedForce::add_time_tangent(double t, CVecRef q, CVecRef qd, VecRef dQ) const {
  const Vec zero = Vec::Zero(q.size());
  add_tangent_along(t, q, qd, 1.0, zero, zero, dQ);
  return true;
}

void DerivedAppliedForce::add_tangent_along(double t, CVecRef q, CVecRef qd, double dt, CVecRef dq,
                                            CVecRef dqd, VecRef dQ) const {
  const Vec qc = q, qdc = qd, dqc = dq, dqdc = dqd;
  std::vector<double> out(q_.outputs()), dout(q_.outputs()), work(q_.work_size()),
      dwork(q_.work_size());
  q_.eval_tangent(t, qc.data(), qdc.data(), dt, dqc.data(), dqdc.data(), out.data(), dout.data(),
                  work.data(), dwork.data());
  std::size_t k = 0;
  for (const Index i : q_index_) dQ(i) += dout[k++];
  if (!springs_.empty()) add_spring_tangent(t, qc, qdc, dt, dqc, dqdc, dQ);
}

// The spring-dampers' dQ along (dt, dq, dq̇) (t: the ends of a moving spring): forward mode on the d, ḋ, J_d tape (Tape::eval_tangent)
// gives δd, δḋ, δJ; then the chain rule through add_to()'s formulas, with u_e = d_axis J_e / L:
//   δL = d·δd / L,  δL̇ = (δd·ḋ + d·δḋ) / L − L̇ δL / L,  δg = k δL + c δL̇  (g = k (L − L0) + c L̇),
//   δu_e = (δd_axis J_e + d_axis δJ_e) / L − u_e δL / L,   δQ_j −= δg u_e + g δu_e.
void DerivedAppliedForce::add_spring_tangent(double t, const Vec& q, const Vec& qd, double dt,
                                             const Vec& dq, const Vec& dqd, VecRef dQ) const {
  const std::size_t m = springs_tape_.outputs(), w = springs_tape_.work_size();
  std::vector<double> out(m), dout(m), work(w), dwork(w);
  springs_tape_.eval_tangent(t, q.data(), qd.data(), dt, dq.data(), dqd.data(), out.data(),
                             dout.data(), work.data(), dwork.data());
  for (const auto& s : springs_) {
    const double* d = out.data() + s.first;
    const double* dd = d + 3;
    const double* J = d + 6;
    const double* td = dout.data() + s.first;  // δd, δḋ, δJ
    const double* tdd = td + 3;
    const double* tJ = td + 6;
    const double L = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    const double Ld = (d[0] * dd[0] + d[1] * dd[1] + d[2] * dd[2]) / L;
    const double dL = (d[0] * td[0] + d[1] * td[1] + d[2] * td[2]) / L;
    const double dLd = (td[0] * dd[0] + td[1] * dd[1] + td[2] * dd[2] + d[0] * tdd[0] +
                        d[1] * tdd[1] + d[2] * tdd[2]) /
                           L -
                       Ld * dL / L;
    const double g = s.k * (L - s.l0) + s.c * Ld;
    const double dg = s.k * dL + s.c * dLd;
    for (std::size_t e = 0; e < s.jac.size(); ++e) {
      const auto [j, axis] = s.jac[e];
      const double u = d[axis] * J[e] / L;
      const double du = (td[axis] * J[e] + d[axis] * tJ[e]) / L - u * dL / L;
      dQ(j) -= dg * u + g * du;
    }
  }
}

double DerivedAppliedForce::add_to(double t, CVecRef q, CVecRef qd, VecRef Q) const {
  constexpr std::size_t kStack = 512;
  double buf[kStack];
  std::vector<double> big;
  double* out = buf;
  const std::size_t need = std::max(q_.outputs(), springs_tape_.outputs());
  if (need > kStack) {
    big.resize(need);  // only for very large force definitions
    out = big.data();
  }
  double power = 0.0;
  q_.eval(t, q.data(), qd.data(), out);
  std::size_t k = 0;
  for (const Index i : q_index_) {
    Q(i) += out[k];
    power += out[k] * qd(i);
    ++k;
  }
  if (springs_.empty()) return power;
  springs_tape_.eval(t, q.data(), qd.data(), out);
  for (const auto& s : springs_) {
    const double* d = out + s.first;
    const double* dd = d + 3;
    const double* J = d + 6;
    // L = |d|, L̇ = d·ḋ / L, force magnitude along d/L: −(k (L − L0) + c L̇).
    const double L = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    const double Ld = (d[0] * dd[0] + d[1] * dd[1] + d[2] * dd[2]) / L;
    const double fs = s.k * (L - s.l0), fd = s.c * Ld;
    // Q_j += −(fs + fd) ∂L/∂q_j with ∂L/∂q_j = d·J_j / L, accumulated over the nonzero J entries.
    for (std::size_t e = 0; e < s.jac.size(); ++e) {
      const auto [j, axis] = s.jac[e];
      const double dLj = d[axis] * J[e] / L;
      Q(j) -= (fs + fd) * dLj;
      power -= (fd + (s.moving ? fs : 0.0)) * dLj * qd(j);
    }
  }
  return power;
}

double DerivedAppliedForce::potential(CVecRef q) const {
  if (!has_potential_) return 0.0;
  double d[256];
  std::vector<double> big;
  double* out = d;
  if (d_only_.outputs() > 256) {
    big.resize(d_only_.outputs());
    out = big.data();
  }
  d_only_.eval(0.0, q.data(), nullptr, out);
  double V = 0.0;
  for (const auto& s : springs_) {
    if (s.moving) continue;
    const double* x = out + s.first_d;
    const double L = std::sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
    V += 0.5 * s.k * (L - s.l0) * (L - s.l0);
  }
  return V;
}

std::shared_ptr<DerivedAppliedForce> make_applied_force(const ForceDef& def) {
  return std::make_shared<DerivedAppliedForce>(derive(def), def.name());
}

}  // namespace ukdyn::symbolic
