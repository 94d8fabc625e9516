#include "ukdyn/symbolic/definitions.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <map>
#include <set>
#include <sstream>

#include "symbolic/ex_helpers.hpp"
#include "symbolic/free_body_dynamics.hpp"
#include "symbolic/mass_matrix_size.hpp"
#include "symbolic/tape_work.hpp"
#include "ukdyn/symbolic/canonical.hpp"
#include "ukdyn/symbolic/tape_inputs.hpp"

namespace ukdyn::symbolic {

namespace {

// Doubles tape_columns() takes for a tape over n coordinates, K lanes a pass.
std::size_t tape_columns_size(const Tape& tape, std::size_t n, std::size_t K) {
  return (1 + K) * (tape.outputs() + tape.work_size()) + 2 * n * K;
}

// The tape's output tangents along every direction it reads, e_j of q for j in q_read, then of
// q̇ for j in qd_read: K directions a pass (Tape::eval_tangents: the values once, bitwise the
// one-direction tangents), use(dout, col) for each (col = j along q_j, n + j along q̇_j; dout the
// outputs' tangents). buf: tape_columns_size() doubles (values, tangents, work, the directions).
template <class Use>
void tape_columns(const Tape& tape, double t, CVecRef q, CVecRef qd,
                  const std::vector<Index>& q_read, const std::vector<Index>& qd_read,
                  std::size_t K, double* buf, Use&& use) {
  const std::size_t no = tape.outputs(), nw = tape.work_size();
  const auto n = static_cast<std::size_t>(q.size());
  double* out = buf;
  double* dout = out + no;
  double* work = dout + no * K;
  double* dwork = work + nw;
  double* dq = dwork + nw * K;
  double* dqd = dq + n * K;
  std::fill_n(dq, 2 * n * K, 0.0);
  const std::size_t nq = q_read.size(), total = nq + qd_read.size();
  // Lane k of a pass along direction i: e_j of q (j = q_read[i]) or of q̇.
  auto unit = [&](std::size_t i, std::size_t k) -> double& {
    return i < nq ? dq[static_cast<std::size_t>(q_read[i]) + n * k]
                  : dqd[static_cast<std::size_t>(qd_read[i - nq]) + n * k];
  };
  for (std::size_t first = 0; first < total; first += K) {
    const std::size_t lanes = std::min(K, total - first);
    for (std::size_t k = 0; k < lanes; ++k) unit(first + k, k) = 1.0;
    // (CVecRef is contiguous.)
    tape.eval_tangents(lanes, t, q.data(), qd.data(), nullptr, dq, n, dqd, n, out, dout, work,
                       dwork);
    for (std::size_t k = 0; k < lanes; ++k) {
      const std::size_t i = first + k;
      use(dout + no * k, i < nq ? q_read[i] : q.size() + qd_read[i - nq]);
      unit(i, k) = 0.0;
    }
  }
}

}  // namespace

namespace {

using GiNaC::ex;
using GiNaC::matrix;
using GiNaC::symbol;
using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

// Real numeric value of an expression without symbols, or nullopt.
std::optional<double> real_value(const ex& e) {
  const ex v = e.evalf();
  if (!GiNaC::is_a<GiNaC::numeric>(v) || !GiNaC::ex_to<GiNaC::numeric>(v).is_real())
    return std::nullopt;
  return GiNaC::ex_to<GiNaC::numeric>(v).to_double();
}

bool has_any(const ex& e, const std::vector<symbol>& syms) {
  return std::any_of(syms.begin(), syms.end(), [&](const symbol& s) { return e.has(s); });
}

}  // namespace

ex simplify_trig(const ex& e) {
  ex r = e.expand();
  if (!r.has(GiNaC::sin(GiNaC::wild()))) return r;
  const ex rule =
      GiNaC::pow(GiNaC::sin(GiNaC::wild(0)), 2) == 1 - GiNaC::pow(GiNaC::cos(GiNaC::wild(0)), 2);
  for (int i = 0; i < 8; ++i) {
    const ex s = r.subs(rule, GiNaC::subs_options::algebraic).expand();
    if (s.is_equal(r)) break;
    r = s;
  }
  return r;
}

namespace {

// The substitution sin(x)^2 → 1 − cos(x)^2 term by term, the deadline checked between terms.
class TrigPass : public GiNaC::map_function {
 public:
  TrigPass(const Deadline& deadline, const std::string& where)
      : deadline_(deadline),
        where_(where),
        rule_(GiNaC::pow(GiNaC::sin(GiNaC::wild(0)), 2) ==
              1 - GiNaC::pow(GiNaC::cos(GiNaC::wild(0)), 2)) {}
  ex operator()(const ex& term) override {
    deadline_.check(where_);
    return term.subs(rule_, GiNaC::subs_options::algebraic);
  }

 private:
  const Deadline& deadline_;
  const std::string& where_;
  const ex rule_;
};

}  // namespace

ex simplify_trig(const ex& e, const Deadline& deadline, const std::string& where) {
  ex r = expand_checked(e, deadline, where);
  if (!r.has(GiNaC::sin(GiNaC::wild()))) return r;
  TrigPass pass(deadline, where);
  for (int i = 0; i < 8; ++i) {
    deadline.check(where);
    // A sum of a few hundred terms in one pass (as simplify_trig(e)), a longer one term by term.
    const bool small = !GiNaC::is_a<GiNaC::add>(r) || r.nops() <= 500;
    const ex s = small ? pass(r).expand() : expand_checked(r.map(pass), deadline, where);
    if (s.is_equal(r)) break;
    r = s;
  }
  return r;
}

// ------------------------------------------------------------------------------ DefinitionScope

DefinitionScope::DefinitionScope(std::shared_ptr<SymbolTable> symbols)
    : symbols_(symbols ? std::move(symbols) : std::make_shared<SymbolTable>()) {}

ex DefinitionScope::parameter(const std::string& name, const ex& value) {
  if (!real_value(value)) {
    throw ExpressionError(
        "parameter '" + name + "' must be a real number, got '" + str(value) + "'", 0);
  }
  symbol s = local_symbol(name);
  scope_.add(name, s);
  params_.push_back({name, s, value});
  return s;
}

ex DefinitionScope::parameter(const std::string& name, double value) {
  if (!std::isfinite(value)) throw ExpressionError("parameter '" + name + "' must be finite", 0);
  // Doubles that are short decimals (0.7, 0.855) are taken exactly as the decimal.
  std::ostringstream os;
  os.precision(15);
  os << value;
  ex v;
  try {
    v = Scope().parse(os.str());
    if (std::abs(*real_value(v) - value) > 1e-15 * std::abs(value)) v = exact_rational(value);
  } catch (const ExpressionError&) {
    v = exact_rational(value);  // exact, never a float (canonical.hpp)
  }
  return parameter(name, v);
}

ex DefinitionScope::let(const std::string& name, const ex& value) {
  scope_.add(name, value);
  return value;
}

GiNaC::exmap DefinitionScope::parameter_values() const {
  GiNaC::exmap m;
  for (const auto& p : params_) m[p.symbol] = p.value;
  return m;
}

// ------------------------------------------------------------------------------ SubsystemDef

SubsystemDef::SubsystemDef(std::string name, std::vector<std::string> coordinates,
                           std::shared_ptr<SymbolTable> symbols)
    : DefinitionScope(std::move(symbols)), name_(std::move(name)), coords_(std::move(coordinates)) {
  if (coords_.empty()) throw DefinitionError("subsystem '" + name_ + "' declares no coordinates");
  for (std::size_t i = 0; i < coords_.size(); ++i) {
    const std::string& c = coords_[i];
    std::string why;
    if (!valid_name(c, &why)) throw DefinitionError(why, -1, static_cast<int>(i));
    if (scope_.has(c))
      throw DefinitionError("duplicate coordinate '" + c + "'", -1, static_cast<int>(i));
    if (scope_.has(c + "_dot")) {
      throw DefinitionError("coordinate '" + c + "_dot' clashes with the velocity of '" + c + "'",
                            -1, static_cast<int>(i));
    }
    scope_.add(c, coordinate_symbol(*symbols_, c));
    scope_.add(c + "_dot", velocity_symbol(*symbols_, c));
  }
  // t: a body's mass or inertia may be a function of time (docs/definitions.md, "Time-varying
  // masses"); positions, rotations and angular velocities may not (checked in derive()).
  scope_.add_time(time_symbol(*symbols_));
}

symbol SubsystemDef::q(const std::string& c) const {
  if (std::find(coords_.begin(), coords_.end(), c) == coords_.end()) {
    throw DefinitionError("subsystem '" + name_ + "' has no coordinate '" + c + "'");
  }
  return coordinate_symbol(*symbols_, c);
}

symbol SubsystemDef::qd(const std::string& c) const {
  (void)q(c);
  return velocity_symbol(*symbols_, c);
}

BodyDef& SubsystemDef::add_body(std::string body_name) {
  bodies.emplace_back();
  bodies.back().name = std::move(body_name);
  return bodies.back();
}

// ------------------------------------------------------------------------------ derivation

namespace {

// What every step of derive() reads: the coordinate, velocity and time symbols, the parameter
// values, and which coordinates some body has used so far.
struct DerivationSymbols {
  const SubsystemDef& def;
  std::vector<symbol> q, qd;
  symbol t;
  GiNaC::exmap values;
  std::vector<bool> used;

  explicit DerivationSymbols(const SubsystemDef& d) : def(d), t(time_symbol(d.symbols())) {
    for (const auto& c : d.coordinates()) {
      q.push_back(coordinate_symbol(d.symbols(), c));
      qd.push_back(velocity_symbol(d.symbols(), c));
    }
    values = d.parameter_values();
    used.assign(q.size(), false);
  }
  void mark_used(const ex& e) {
    for (std::size_t j = 0; j < q.size(); ++j) {
      if (e.has(q[j]) || e.has(qd[j])) used[j] = true;
    }
  }
  // d/dt of an expression of q only: Σ_j ∂e/∂q_j q̇_j.
  ex time_derivative(const ex& e) const {
    ex d = 0;
    for (std::size_t j = 0; j < q.size(); ++j) d += e.diff(q[j]) * qd[j];
    return d;
  }
};

// The subsystem's own limits, before any derivation work.
void check_subsystem_size(const SubsystemDef& def) {
  if (def.bodies.empty()) throw DefinitionError("subsystem '" + def.name() + "' has no bodies");
  const std::size_t n = def.coordinates().size();
  if (n > limits::kDerivedCoordinates) {  // bounded work (docs/definitions.md, Limits)
    throw DefinitionError("subsystem '" + def.name() + "' has " + std::to_string(n) +
                          " coordinates; a derived subsystem may have at most " +
                          std::to_string(limits::kDerivedCoordinates));
  }
}

// The number an expression of the parameters and t is at t = 0, or nullopt.
std::optional<double> value_at_t0(const ex& e, const DerivationSymbols& s) {
  return real_value(e.subs(s.values).subs(s.t == 0));
}

// Mass: a non-negative constant or a function m(t) of time only (mass exchanged with a medium at
// rest, docs/definitions.md "Time-varying masses"); m(t) >= 0 is checked here at t = 0 only,
// over a run's time span by negative_mass_over_run (the scenario loader and the in-memory run).
void check_body_mass(const BodyDef& b, const DerivationSymbols& s, const std::string& where,
                     int bidx) {
  if (has_any(b.mass, s.q) || has_any(b.mass, s.qd)) {
    throw DefinitionError(where +
                              ": the mass must be a constant or a function of t only (it depends "
                              "on a coordinate or a velocity)",
                          bidx);
  }
  const auto mv = value_at_t0(b.mass, s);
  if (!mv || !(*mv >= 0.0)) {
    throw DefinitionError(where + ": the mass must be a number >= 0" +
                              (b.mass.has(s.t) ? std::string(" at t = 0") : std::string()) +
                              ", got '" + str(b.mass) + "'",
                          bidx);
  }
}

// Velocity of the centre of mass, ṗ = (∂p/∂q) q̇, for a position p(q).
std::array<ex, 3> com_velocity(const BodyDef& b, DerivationSymbols& s, const std::string& where,
                               int bidx) {
  std::array<ex, 3> v;
  for (std::size_t k = 0; k < 3; ++k) {
    const ex& p = b.com[k];
    if (has_any(p, s.qd))
      throw DefinitionError(where + ": the position may not use velocities (*_dot)", bidx);
    if (p.has(s.t)) throw DefinitionError(where + ": the position may not depend on time t", bidx);
    s.mark_used(p);
    v[k] = s.time_derivative(p);
  }
  return v;
}

// ω from a rotation R(q): Rᵀ Ṙ (body frame) or Ṙ Rᵀ (world frame) is skew, ω its axial vector;
// R must be a rotation, Rᵀ R = 1 identically (checked after simplification).
std::array<ex, 3> rotation_angular_velocity(const BodyDef& b, DerivationSymbols& s,
                                            const std::string& where, int bidx) {
  matrix R(3, 3), Rd(3, 3);
  for (unsigned i = 0; i < 3; ++i) {
    for (unsigned j = 0; j < 3; ++j) {
      const ex& r = (*b.rotation)[3 * i + j];
      if (has_any(r, s.qd) || r.has(s.t)) {
        throw DefinitionError(where + ": the rotation may depend on the coordinates only", bidx);
      }
      s.mark_used(r);
      R(i, j) = r;
      Rd(i, j) = s.time_derivative(r);
    }
  }
  const matrix RtR = R.transpose().mul(R);
  for (unsigned i = 0; i < 3; ++i) {
    for (unsigned j = 0; j < 3; ++j) {
      const ex e = simplify_trig((RtR(i, j) - (i == j ? 1 : 0)).subs(s.values));
      const auto ev = real_value(e);
      if (!(ev && std::abs(*ev) < 1e-12)) {
        throw DefinitionError(
            where + ": the rotation is not orthonormal (R^T R - 1 has entry '" + str(e) + "')",
            bidx);
      }
    }
  }
  const matrix S = b.inertia_frame == Frame::body ? R.transpose().mul(Rd) : Rd.mul(R.transpose());
  return {simplify_trig(S(2, 1)), simplify_trig(S(0, 2)), simplify_trig(S(1, 0))};
}

// The body's angular velocity: given, or from its rotation.
std::array<ex, 3> body_angular_velocity(const BodyDef& b, DerivationSymbols& s,
                                        const std::string& where, int bidx) {
  if (b.angular_velocity) {
    for (const ex& e : *b.angular_velocity) {
      if (e.has(s.t))
        throw DefinitionError(where + ": the angular velocity may not depend on t", bidx);
      s.mark_used(e);
    }
    return *b.angular_velocity;
  }
  if (b.rotation) return rotation_angular_velocity(b, s, where, bidx);
  throw DefinitionError(where + ": an inertia is given but neither angular_velocity nor rotation",
                        bidx);
}

// The inertia at t = 0 (like the mass): a scalar >= 0, a tensor positive semi-definite (its
// smallest eigenvalue >= -1e-12 of its largest |entry|; a planar body's diag(0, 0, Izz) passes —
// the triangle inequality of principal moments is not required). A negative inertia can leave M
// positive definite and the motion silently wrong.
void check_inertia_sign(const BodyDef& b, const DerivationSymbols& s, const std::string& where,
                        int bidx) {
  const std::string when = " (at t = 0)";
  if (b.inertia_kind == BodyDef::InertiaKind::scalar) {
    const auto v = value_at_t0(b.inertia_scalar, s);
    if (!v || !(*v >= 0.0)) {
      throw DefinitionError(where + ": the inertia must be a number >= 0" +
                                (b.inertia_scalar.has(s.t) ? when : std::string()) + ", got '" +
                                str(b.inertia_scalar) + "'",
                            bidx);
    }
    return;
  }
  Eigen::Matrix3d I;
  bool has_t = false;
  for (int k = 0; k < 9; ++k) {
    const ex& e = b.inertia_tensor[static_cast<std::size_t>(k)];
    const auto v = value_at_t0(e, s);
    if (!v || !std::isfinite(*v)) {
      throw DefinitionError(where + ": the inertia tensor entry " + std::to_string(k) +
                                " is not a finite number, got '" + str(e) + "'",
                            bidx);
    }
    I(k / 3, k % 3) = *v;
    has_t = has_t || e.has(s.t);
  }
  const double scale = I.cwiseAbs().maxCoeff();
  const double lmin = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(I, Eigen::EigenvaluesOnly)
                          .eigenvalues()
                          .minCoeff();
  if (lmin < -1e-12 * scale) {
    std::ostringstream os;
    os.precision(6);
    os << where << ": the inertia tensor is not positive semi-definite" << (has_t ? when : "")
       << ": its smallest eigenvalue is " << lmin;
    throw DefinitionError(os.str(), bidx);
  }
}

// ½ ωᵀ I ω, the inertia constant or a function of t only (like the mass).
ex rotational_energy(const BodyDef& b, const std::array<ex, 3>& w, const DerivationSymbols& s,
                     const std::string& where, int bidx) {
  std::vector<ex> parts;
  if (b.inertia_kind == BodyDef::InertiaKind::scalar) {
    parts.push_back(b.inertia_scalar);
  } else {
    parts.assign(b.inertia_tensor.begin(), b.inertia_tensor.end());
  }
  for (const ex& e : parts) {
    if (has_any(e, s.q) || has_any(e, s.qd)) {
      throw DefinitionError(where +
                                ": the inertia must be constant or a function of t only (it "
                                "depends on a coordinate or a velocity)",
                            bidx);
    }
  }
  if (b.inertia_kind == BodyDef::InertiaKind::scalar) {
    check_inertia_sign(b, s, where, bidx);
    return b.inertia_scalar / 2 * (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
  }
  ex T = 0;
  const auto& I = b.inertia_tensor;
  for (std::size_t i = 0; i < 3; ++i) {
    for (std::size_t j = 0; j < 3; ++j) {
      if (!I[3 * i + j].is_equal(I[3 * j + i]))
        throw DefinitionError(where + ": the inertia tensor is not symmetric", bidx);
      T += w[i] * I[3 * i + j] * w[j] / 2;
    }
  }
  check_inertia_sign(b, s, where, bidx);  // symmetric: checked above
  return T;
}

// One body's kinetic energy ½ m |ṗ|² + ½ ωᵀ I ω added to T, its potential −m g·p to V.
void add_body_energy(const BodyDef& b, int bidx, DerivationSymbols& s, ex& T, ex& V) {
  const std::string where = "body '" + b.name + "'";
  check_body_mass(b, s, where, bidx);
  const std::array<ex, 3> v = com_velocity(b, s, where, bidx);
  const auto& g = s.def.gravity;
  T += b.mass / 2 * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  V -= b.mass * (g[0] * b.com[0] + g[1] * b.com[1] + g[2] * b.com[2]);
  if (b.inertia_kind == BodyDef::InertiaKind::none) {
    if (b.angular_velocity || b.rotation) {
      throw DefinitionError(where + ": an angular velocity or rotation is given but no inertia",
                            bidx);
    }
    return;
  }
  T += rotational_energy(b, body_angular_velocity(b, s, where, bidx), s, where, bidx);
}

void check_every_coordinate_used(const DerivationSymbols& s) {
  for (std::size_t j = 0; j < s.used.size(); ++j) {
    if (!s.used[j]) {
      throw DefinitionError(
          "coordinate '" + s.def.coordinates()[j] +
              "' appears in no body (in no position, rotation or angular velocity)",
          -1, static_cast<int>(j));
    }
  }
}

// Refuses an entry of M over limits::kTreeNodes (as check_expression_size() would refuse the
// derived entry) from its size counted in T's terms, before the derivatives: a position of a few
// hundred sines of one coordinate gives an M(x, x) of ~10^5 terms, and T.diff(q̇) of ~10^5 terms
// of nested sines takes seconds (docs/definitions.md, "Limits").
void check_mass_matrix_size(const SubsystemDerivation& d, const DerivationSymbols& s) {
  const std::size_t n = s.qd.size();
  const std::vector<double> nodes = mass_matrix_nodes(d.T, s.qd);
  for (std::size_t i = 0; i < n; ++i) {
    for (std::size_t j = i; j < n; ++j) {
      if (nodes[i * n + j] <= static_cast<double>(limits::kTreeNodes)) continue;
      std::ostringstream os;
      os << "M(" << d.coordinates[i] << ", " << d.coordinates[j]
         << ") would be too large (more than " << limits::kTreeNodes
         << " nodes written out: " << static_cast<long long>(nodes[i * n + j])
         << ", counted from the terms in " << d.coordinates[i] << "_dot*" << d.coordinates[j]
         << "_dot of the kinetic energy T): write the positions with fewer terms or split the "
            "subsystem (a serial_chain: dynamics: tree)";
      throw ExpressionError(os.str(), 0);
    }
  }
}

// M = ∂²T/∂q̇∂q̇ (the paper's Eq. (5) for any T), which must not depend on q̇.
void derive_mass_matrix(SubsystemDerivation& d, const DerivationSymbols& s,
                        const Deadline& deadline) {
  const auto un = static_cast<unsigned>(s.q.size());
  d.M = matrix(un, un);
  std::vector<ex> dTdqd(un);
  for (unsigned i = 0; i < un; ++i) dTdqd[i] = d.T.diff(s.qd[i]);
  for (unsigned i = 0; i < un; ++i) {
    for (unsigned j = i; j < un; ++j) {
      const std::string at = "M(" + d.coordinates[i] + ", " + d.coordinates[j] + ")";
      deadline.check(at);
      const ex m = simplify_trig(dTdqd[i].diff(s.qd[j]), deadline, at);
      check_expression_size(m, at);
      if (has_any(m, s.qd)) {
        throw DefinitionError(
            "the kinetic energy is not quadratic in the velocities (M(" + d.coordinates[i] + ", " +
                d.coordinates[j] +
                ") depends on a velocity): angular velocities must be linear in *_dot",
            -1, static_cast<int>(i));
      }
      d.M(i, j) = m;
      d.M(j, i) = m;
    }
    // M(i, i) = 0 (a coordinate that moves no mass: a massless link) is allowed: the motion is
    // still unique when the constraints fix that direction ([M; A] of full column rank,
    // core/uk_singular.hpp); the scenario loader checks it at initial.q.
  }
}

// C, C q̇ and G = ∂V/∂q from M and V (the paper's Eqs. (8) and (9), for any M(q, t) and V(q)).
void derive_velocity_and_gravity_terms(SubsystemDerivation& d, const DerivationSymbols& s,
                                       const Deadline& deadline) {
  const auto un = static_cast<unsigned>(s.q.size());
  // Christoffel symbols of the first kind: C_ij = Σ_k ½ (∂M_ij/∂q_k + ∂M_ik/∂q_j − ∂M_jk/∂q_i) q̇_k.
  std::vector<matrix> dM(un, matrix(un, un));
  for (unsigned k = 0; k < un; ++k) {
    deadline.check("dM/d" + d.coordinates[k]);
    for (unsigned i = 0; i < un; ++i) {
      for (unsigned j = i; j < un; ++j) {
        const ex e = d.M(i, j).diff(s.q[k]);
        dM[k](i, j) = e;
        dM[k](j, i) = e;
      }
    }
  }
  d.C = matrix(un, un);
  d.Cqd = matrix(un, 1);
  d.G = matrix(un, 1);
  for (unsigned i = 0; i < un; ++i) {
    ex row = 0;
    for (unsigned j = 0; j < un; ++j) {
      const std::string at = "C(" + d.coordinates[i] + ", " + d.coordinates[j] + ")";
      deadline.check(at);
      ex c = 0;
      for (unsigned k = 0; k < un; ++k)
        c += (dM[k](i, j) + dM[j](i, k) - dM[i](j, k)) * s.qd[k] / 2;
      check_expression_size(c, at);
      c = simplify_trig(c, deadline, at);
      d.C(i, j) = c;
      row += c * s.qd[j];
    }
    // A mass of t: d/dt ∂T/∂q̇ = M q̈ + Σ_k (∂M/∂q_k) q̇_k q̇ + (∂M/∂t) q̇, so the velocity terms of
    // Lagrange's equations gain (∂M/∂t) q̇ = ∂²T/∂q̇∂t (docs/definitions.md, "Time-varying
    // masses"). C itself stays the Christoffel matrix of M(q, t) at fixed t.
    if (d.time_varying) {
      ex mt = 0;
      for (unsigned j = 0; j < un; ++j) mt += d.M(i, j).diff(s.t) * s.qd[j];
      row += mt;
    }
    d.Cqd(i, 0) = simplify_trig(row, deadline, "C q_dot(" + d.coordinates[i] + ")");
    d.G(i, 0) = simplify_trig(d.V.diff(s.q[i]), deadline, "G(" + d.coordinates[i] + ")");
  }
}

}  // namespace

namespace {

using VelocityIndex = std::map<ex, std::size_t, GiNaC::ex_is_less>;

// Nodes of e written out, as check_expression_size() counts them (a subexpression at each use),
// or -1 if e holds a velocity.
double nodes_written_out(const ex& e, const VelocityIndex& velocity) {
  if (GiNaC::is_a<GiNaC::symbol>(e) && velocity.count(e)) return -1;
  double n = 1;
  for (std::size_t k = 0; k < e.nops(); ++k) {
    const double c = nodes_written_out(e.op(k), velocity);
    if (c < 0) return -1;
    n += c;
  }
  return n;
}

}  // namespace

std::vector<double> mass_matrix_nodes(const ex& T, const std::vector<symbol>& qd) {
  VelocityIndex velocity;
  for (std::size_t i = 0; i < qd.size(); ++i) velocity[qd[i]] = i;
  const std::size_t n = qd.size();
  std::vector<double> nodes(n * n, 0.0), terms(n * n, 0.0);
  // One term of T: its velocities, its numeric coefficient c and its other factors; GiNaC writes
  // the entry's term as c' f (c' = 2 c for a square), c' f1 · f2 ... as one product (one node, c'
  // one more unless 1), a lone f1 (c' = 1) as f1 and no factor at all as the number c'.
  auto add_term = [&](const ex& term) {
    std::size_t v[2], k = 0, factors = 0;
    double factor_nodes = 0;
    GiNaC::numeric c = 1;
    const bool product = GiNaC::is_a<GiNaC::mul>(term);
    for (std::size_t f = 0; f < (product ? term.nops() : 1); ++f) {
      const ex factor = product ? term.op(f) : term;
      const bool square = GiNaC::is_a<GiNaC::power>(factor) && factor.op(1).is_equal(2);
      if (auto it = velocity.find(square ? factor.op(0) : factor); it != velocity.end()) {
        if (k + (square ? 2 : 1) > 2) return;  // of degree 3 or more in q̇
        v[k++] = it->second;
        if (square) v[k++] = it->second;
      } else if (GiNaC::is_a<GiNaC::numeric>(factor)) {
        c = GiNaC::ex_to<GiNaC::numeric>(factor);
      } else {
        const double size = nodes_written_out(factor, velocity);
        if (size < 0) return;  // a velocity inside a function or a power: not quadratic
        ++factors;
        factor_nodes += size;
      }
    }
    if (k != 2) return;
    if (v[0] == v[1]) c *= 2;
    double entry = 1;  // the number c' alone
    if (factors == 1 && c.is_equal(1))
      entry = factor_nodes;
    else if (factors > 0)
      entry = 1 + factor_nodes + (c.is_equal(1) ? 0 : 1);
    const std::size_t at = std::min(v[0], v[1]) * n + std::max(v[0], v[1]);
    nodes[at] += entry;
    terms[at] += 1;
  };
  if (GiNaC::is_a<GiNaC::add>(T)) {
    for (std::size_t k = 0; k < T.nops(); ++k) add_term(T.op(k));
  } else {
    add_term(T);
  }
  for (std::size_t k = 0; k < n * n; ++k) {
    if (terms[k] == 0) nodes[k] = 1;  // the number 0
    if (terms[k] > 1) nodes[k] += 1;  // the sum
  }
  return nodes;
}

SubsystemDerivation derive(const SubsystemDef& def) { return derive(def, Deadline()); }

SubsystemDerivation derive(const SubsystemDef& def, const Deadline& deadline) {
  const auto t0 = Clock::now();
  DerivationSymbols s(def);
  check_subsystem_size(def);

  ex T = 0, V = 0;
  for (std::size_t bi = 0; bi < def.bodies.size(); ++bi) {
    deadline.check("body '" + def.bodies[bi].name + "'");
    add_body_energy(def.bodies[bi], static_cast<int>(bi), s, T, V);
  }
  check_every_coordinate_used(s);
  V += def.extra_potential;
  if (has_any(V, s.qd) || def.extra_potential.has(s.t)) {
    throw DefinitionError("the potential may depend on the coordinates only");
  }
  check_expression_size(T, "the kinetic energy T");
  check_expression_size(V, "the potential energy V");
  deadline.check("the kinetic energy T");

  SubsystemDerivation d;
  d.coordinates = def.coordinates();
  d.parameter_values = s.values;
  d.symbols = def.symbol_table();
  d.T = expand_checked(T, deadline, "the kinetic energy T");
  d.V = expand_checked(V, deadline, "the potential energy V");
  check_mass_matrix_size(d, s);
  // Time-varying iff ∂T/∂t or ∂V/∂t is not identically 0 (a t that cancels, sin(t)^2 + cos(t)^2,
  // leaves the subsystem time-invariant).
  d.time_varying = (d.T.has(s.t) && !simplify_trig(d.T.diff(s.t)).is_zero()) ||
                   (d.V.has(s.t) && !simplify_trig(d.V.diff(s.t)).is_zero());
  derive_mass_matrix(d, s, deadline);
  derive_velocity_and_gravity_terms(d, s, deadline);
  // ∂L/∂t = ∂T/∂t − ∂V/∂t: the power that the energy balance needs (dE/dt = Q q̇ − ∂L/∂t).
  d.Lt = d.time_varying ? simplify_trig((d.T - d.V).diff(s.t)) : ex(0);
  for (const BodyDef& b : def.bodies) {
    if (!b.mass.has(s.t)) continue;
    d.mass_of_t_bodies.push_back(b.name);
    d.masses_of_t.push_back(b.mass);
  }
  d.derive_seconds = seconds_since(t0);
  return d;
}

// ------------------------------------------------------------------------------ DerivedSubsystem

namespace {

// The subsystem's coordinates and velocities renamed to names of their position alone (q#i, qd#i):
// the tapes of two instances of one robot (coordinates r0_t1, r1_t1, ...) are then compiled from
// the same expressions in the same operand order (canonical.hpp orders by name), so that a
// TapePool finds them identical.
struct PositionalInputs {
  GiNaC::exmap rename;
  InputMap in;
};

// The work of compiling these tapes (outputs, what) together, counted before any of them is
// compiled and refused past limits::kTapeWork (tape_work.hpp): the size of the results, not the
// clock, decides whether they are compiled (docs/definitions.md, "Limits").
void check_tape_work(const std::vector<std::pair<const std::vector<ex>*, std::string>>& tapes) {
  std::size_t done = 0;
  for (const auto& [outputs, what] : tapes)
    done = tape_work(*outputs, limits::kTapeWork, "compiling " + what, done);
}

PositionalInputs positional_inputs(SymbolTable& table, const std::vector<std::string>& coords) {
  PositionalInputs p;
  for (std::size_t i = 0; i < coords.size(); ++i) {
    const GiNaC::symbol q("q#" + std::to_string(i)), qd("qd#" + std::to_string(i));
    const auto index = static_cast<std::int32_t>(i);
    p.rename[coordinate_symbol(table, coords[i])] = q;
    p.rename[velocity_symbol(table, coords[i])] = qd;
    p.in[q] = {TapeInput::Source::q, index};
    p.in[qd] = {TapeInput::Source::qd, index};
  }
  p.in[time_symbol(table)] = {TapeInput::Source::time, 0};
  return p;
}

}  // namespace

DerivedSubsystem::DerivedSubsystem(SubsystemDerivation derivation, std::string name, TapePool* pool)
    : DerivedSubsystem(std::move(derivation), std::move(name), Deadline(), pool) {}

DerivedSubsystem::DerivedSubsystem(SubsystemDerivation derivation, std::string name,
                                   const Deadline& deadline, TapePool* pool)
    : d_(std::move(derivation)),
      name_(std::move(name)),
      n_(static_cast<Index>(d_.coordinates.size())) {
  const auto t0 = Clock::now();
  TapePool own;  // no pool given: tapes shared within this subsystem only
  TapePool& tapes = pool ? *pool : own;
  const PositionalInputs p = positional_inputs(*d_.symbols, d_.coordinates);
  auto num = [&](const ex& e) { return numeric_form(e, d_.parameter_values).subs(p.rename); };
  // Every tape within the derivation's budget (the compilation of a large derivation is work of
  // the same order as the derivation).
  auto tape = [&](const std::vector<ex>& outputs, const std::string& what) {
    return tapes.share(Tape(outputs, p.in, deadline, "compiling " + what));
  };
  const auto un = static_cast<unsigned>(n_);
  std::vector<ex> m, cqd, g, c;
  for (unsigned i = 0; i < un; ++i) {
    deadline.check("compiling row " + d_.coordinates[i] + " of M, C and G");
    for (unsigned j = i; j < un; ++j) m.push_back(num(d_.M(i, j)));
    cqd.push_back(num(d_.Cqd(i, 0)));
    g.push_back(num(d_.G(i, 0)));
    for (unsigned j = 0; j < un; ++j) c.push_back(num(d_.C(i, j)));
  }
  // One tape for forward(): M's upper triangle, C q̇ and G together, so that the subexpressions
  // they share (the sin/cos of the angles, above all) are computed once per evaluation.
  std::vector<ex> all = m;
  all.insert(all.end(), cqd.begin(), cqd.end());
  all.insert(all.end(), g.begin(), g.end());
  // A time-varying subsystem's dynamics tape also gives ∂L/∂t (its last output).
  if (d_.time_varying) all.push_back(num(d_.Lt));
  const std::vector<ex> v{num(d_.V)}, t{num(d_.T)};
  std::vector<ex> masses;
  for (const ex& mt : d_.masses_of_t) masses.push_back(num(mt));
  check_tape_work({{&m, "M"},
                   {&cqd, "C q_dot"},
                   {&g, "G"},
                   {&all, "M, C q_dot and G"},
                   {&c, "C"},
                   {&v, "V"},
                   {&t, "T"},
                   {&masses, "the masses"}});
  mass_ = tape(m, "M");
  cqd_ = tape(cqd, "C q_dot");
  grav_ = tape(g, "G");
  dyn_ = tape(all, "M, C q_dot and G");
  q_read_ = dyn_->inputs_read(TapeInput::Source::q);
  qd_read_ = dyn_->inputs_read(TapeInput::Source::qd);
  lanes_ = std::min(kTapeLanes, q_read_.size() + qd_read_.size());
  cor_ = tape(c, "C");
  pot_ = tape(v, "V");
  kin_ = tape(t, "T");
  masses_of_t_ = tape(masses, "the masses");
  closed_ = free_body_closed_form(d_);
  d_.compile_seconds = seconds_since(t0);
}

MassOfTProblem negative_mass_over_run(const System& system, double t0, double t_end,
                                      double sample_dt) {
  const double per_sample = sample_dt > 0.0 ? (t_end - t0) / sample_dt : 0.0;
  const long samples = std::clamp(
      static_cast<long>(std::ceil(std::min(std::max(per_sample, 0.0), 1e6))) + 1, 1001L, 1000001L);
  const auto& subs = system.subsystems();
  for (std::size_t k = 0; k < subs.size(); ++k) {
    const auto* derived = dynamic_cast<const DerivedSubsystem*>(subs[k].get());
    if (derived == nullptr || !derived->time_varying()) continue;
    std::string why = derived->negative_mass(t0, t_end, samples);
    if (!why.empty()) return {k, "subsystem '" + subs[k]->name() + "', " + why};
  }
  return {};
}

std::string DerivedSubsystem::negative_mass(double t0, double t1, long samples) const {
  const std::size_t nb = masses_of_t_->outputs();
  if (nb == 0) return {};
  if (samples < 2) samples = 2;
  std::vector<double> m(nb), work(masses_of_t_->work_size());
  for (long i = 0; i < samples; ++i) {
    // t1 itself at the last sample (no rounding past the end of the run).
    const double t = i + 1 == samples ? t1
                                      : t0 + (t1 - t0) * static_cast<double>(i) /
                                                 static_cast<double>(samples - 1);
    masses_of_t_->eval(t, nullptr, nullptr, m.data(), work.data());
    for (std::size_t b = 0; b < nb; ++b) {
      if (m[b] >= 0.0) continue;  // also false for NaN
      std::ostringstream os;
      os.precision(6);
      os << "body '" << d_.mass_of_t_bodies[b] << "': the mass '" << d_.masses_of_t[b] << "' is "
         << m[b] << " at t = " << t;
      return os.str();
    }
  }
  return {};
}

namespace {
// M from its upper triangle, row by row (the order of the mass tapes' outputs); returns the number
// of values read.
std::size_t symmetric_from_upper(const double* out, Index n, MatRef M) {
  std::size_t k = 0;
  for (Index i = 0; i < n; ++i) {
    for (Index j = i; j < n; ++j) {
      M(i, j) = out[k];
      M(j, i) = out[k];
      ++k;
    }
  }
  return k;
}
}  // namespace

void DerivedSubsystem::mass(const EvalContext& ctx, CVecRef q, MatRef M) const {
  if (closed_) {
    free_body_mass(*closed_, q, M);
    return;
  }
  double buf[64 * 65 / 2];
  std::vector<double> big;
  double* out = buf;
  if (mass_->outputs() > sizeof(buf) / sizeof(double)) {
    big.resize(mass_->outputs());  // only for subsystems of more than 64 coordinates
    out = big.data();
  }
  mass_->eval(ctx.t, q.data(), nullptr, out);
  symmetric_from_upper(out, n_, M);
}

// The dynamics tape's outputs and work, twice: the tangents' (dynamics_tangent()) follow;
// inverse_dynamics_jacobian() takes tape_columns_size().
Index DerivedSubsystem::slot_size() const {
  return static_cast<Index>(
      std::max({2 * (dyn_->outputs() + dyn_->work_size()), cor_->outputs() + cor_->work_size(),
                tape_columns_size(*dyn_, static_cast<std::size_t>(n_), lanes_)}));
}

namespace {

// The tape's values (returned) and, after them, their tangents along (dt, dq, dq̇) (dq, dqd null:
// zero): in the slot when it has `size` doubles (2 (outputs + work)), else in `own`.
const double* tape_tangent(const Tape& tape, const EvalContext& ctx, Index size, CVecRef q,
                           CVecRef qd, double dt, const double* dq, const double* dqd,
                           std::vector<double>& own) {
  const std::size_t no = tape.outputs(), nw = tape.work_size();
  double* base = ctx.slot.data();
  if (ctx.slot.size() != static_cast<std::size_t>(size)) {
    own.resize(2 * (no + nw));
    base = own.data();
  }
  // (CVecRef is contiguous.)
  tape.eval_tangent(ctx.t, q.data(), qd.data(), dt, dq, dqd, base, base + no, base + 2 * no,
                    base + 2 * no + nw);
  return base;
}

}  // namespace

double DerivedSubsystem::dynamics(const EvalContext& ctx, CVecRef q, CVecRef qd, MatRef M,
                                  VecRef Cqd, VecRef G) const {
  if (closed_) {  // a free body (free_body_dynamics.hpp): not of t, so ∂L/∂t = 0
    free_body_mass(*closed_, q, M);
    free_body_velocity_products(*closed_, q, qd, Cqd);
    free_body_gravity(*closed_, G);
    return 0.0;
  }
  if (ctx.slot.size() != static_cast<std::size_t>(slot_size())) {
    constexpr std::size_t kStack = 32 * 33 / 2 + 2 * 32 + 1;
    double buf[kStack];
    std::vector<double> big;
    double* out = buf;
    if (dyn_->outputs() > kStack) {
      big.resize(dyn_->outputs());  // only for subsystems of more than 32 coordinates
      out = big.data();
    }
    dyn_->eval(ctx.t, q.data(), qd.data(), out);
    return unpack_dynamics(out, M, Cqd, G);
  }
  double* out = ctx.slot.data();
  dyn_->eval(ctx.t, q.data(), qd.data(), out, out + dyn_->outputs());
  return unpack_dynamics(out, M, Cqd, G);
}

double DerivedSubsystem::unpack_dynamics(const double* out, MatRef M, VecRef Cqd, VecRef G) const {
  std::size_t k = symmetric_from_upper(out, n_, M);
  for (Index i = 0; i < n_; ++i) Cqd(i) = out[k++];
  for (Index i = 0; i < n_; ++i) G(i) = out[k++];
  return d_.time_varying ? out[k] : 0.0;
}

void DerivedSubsystem::dynamics_tangent(const EvalContext& ctx, CVecRef q, CVecRef qd, CVecRef dq,
                                        CVecRef dqd, MatRef M, VecRef Cqd, VecRef G, MatRef dM,
                                        VecRef dCqd, VecRef dG) const {
  std::vector<double> own;
  const double* out = tape_tangent(*dyn_, ctx, slot_size(), q, qd, 0.0, dq.data(), dqd.data(), own);
  unpack_dynamics(out, M, Cqd, G);
  unpack_dynamics(out + dyn_->outputs(), dM, dCqd, dG);
  if (closed_) dynamics(ctx, q, qd, M, Cqd, G);  // the values bitwise dynamics()'s
}

bool DerivedSubsystem::inverse_dynamics_tangent(const EvalContext& ctx, CVecRef q, CVecRef qd,
                                                CVecRef qdd, CVecRef dq, CVecRef dqd,
                                                VecRef dID) const {
  std::vector<double> own;
  id_from_tangents(tape_tangent(*dyn_, ctx, slot_size(), q, qd, 0.0, dq.data(), dqd.data(), own) +
                       dyn_->outputs(),
                   qdd, dID);
  return true;
}

bool DerivedSubsystem::inverse_dynamics_time_tangent(const EvalContext& ctx, CVecRef q, CVecRef qd,
                                                     CVecRef qdd, VecRef dID) const {
  if (!d_.time_varying) {  // the tape does not read t
    dID.setZero();
    return true;
  }
  std::vector<double> own;
  id_from_tangents(
      tape_tangent(*dyn_, ctx, slot_size(), q, qd, 1.0, nullptr, nullptr, own) + dyn_->outputs(),
      qdd, dID);
  return true;
}

bool DerivedSubsystem::inverse_dynamics_jacobian(const EvalContext& ctx, CVecRef q, CVecRef qd,
                                                 CVecRef qdd, MatRef dID_dq, MatRef dID_dqd) const {
  if (ctx.slot.size() != static_cast<std::size_t>(slot_size()) || q.size() != n_) return false;
  dID_dq.setZero();  // the directions the tape does not read
  dID_dqd.setZero();
  tape_columns(*dyn_, ctx.t, q, qd, q_read_, qd_read_, lanes_, ctx.slot.data(),
               [&](const double* dout, Index col) {
                 id_from_tangents(dout, qdd, col < n_ ? dID_dq.col(col) : dID_dqd.col(col - n_));
               });
  return true;
}

// dID = dM q̈ + d(C q̇) + dG straight from the tangents of the packed outputs (M's upper triangle
// row by row, then C q̇, G): no matrix is formed.
void DerivedSubsystem::id_from_tangents(const double* dout, CVecRef qdd, VecRef dID) const {
  dID.setZero();
  std::size_t k = 0;
  for (Index i = 0; i < n_; ++i) {
    for (Index j = i; j < n_; ++j) {
      const double v = dout[k++];
      dID(i) += v * qdd(j);
      if (j != i) dID(j) += v * qdd(i);
    }
  }
  for (Index i = 0; i < n_; ++i) dID(i) += dout[k + static_cast<std::size_t>(i)];
  k += static_cast<std::size_t>(n_);
  for (Index i = 0; i < n_; ++i) dID(i) += dout[k + static_cast<std::size_t>(i)];
}

void DerivedSubsystem::coriolis(const EvalContext& ctx, CVecRef q, CVecRef qd, MatRef C) const {
  // The tape gives C row by row: into the context's slot (allocation-free at any size), or without
  // one into a buffer on the stack up to 32 coordinates (the tape's work up to Tape::kStackWork).
  constexpr std::size_t kStack = 32 * 32;
  double buf[kStack];
  std::vector<double> big;
  double* out = buf;
  if (ctx.slot.size() == static_cast<std::size_t>(slot_size())) {
    out = ctx.slot.data();
    cor_->eval(ctx.t, q.data(), qd.data(), out, out + cor_->outputs());
  } else {
    if (cor_->outputs() > kStack) {
      big.resize(cor_->outputs());  // only for subsystems of more than 32 coordinates
      out = big.data();
    }
    cor_->eval(ctx.t, q.data(), qd.data(), out);
  }
  for (Index i = 0; i < n_; ++i)
    for (Index j = 0; j < n_; ++j) C(i, j) = out[i * n_ + j];
}

void DerivedSubsystem::coriolis_times_qd(const EvalContext& ctx, CVecRef q, CVecRef qd,
                                         VecRef Cqd) const {
  if (closed_) {
    free_body_velocity_products(*closed_, q, qd, Cqd);
    return;
  }
  cqd_->eval(ctx.t, q.data(), qd.data(), Cqd.data());
}

void DerivedSubsystem::gravity(const EvalContext& ctx, CVecRef q, VecRef G) const {
  if (closed_) {
    free_body_gravity(*closed_, G);
    return;
  }
  grav_->eval(ctx.t, q.data(), nullptr, G.data());
}

double DerivedSubsystem::potential(const EvalContext& ctx, CVecRef q) const {
  double v = 0.0;
  pot_->eval(ctx.t, q.data(), nullptr, &v);
  return v;
}

double DerivedSubsystem::kinetic(const EvalContext& ctx, CVecRef q, CVecRef qd) const {
  double v = 0.0;
  kin_->eval(ctx.t, q.data(), qd.data(), &v);
  return v;
}

std::shared_ptr<DerivedSubsystem> make_subsystem(const SubsystemDef& def) {
  return make_subsystem(def, Deadline());
}

std::shared_ptr<DerivedSubsystem> make_subsystem(const SubsystemDef& def, const Deadline& deadline,
                                                 TapePool* pool) {
  return std::make_shared<DerivedSubsystem>(derive(def, deadline), def.name(), deadline, pool);
}

std::string mass_matrix_problem(const Subsystem& sub, const Vec& q) {
  const Index n = sub.dof();
  Mat M(n, n);
  sub.mass({}, q, M);
  const auto& names = sub.coordinate_names();
  if (!M.allFinite()) return "the mass matrix is not finite";
  Eigen::SelfAdjointEigenSolver<Mat> es(M);
  const double lmin = es.eigenvalues()(0);
  const double lmax = es.eigenvalues()(n - 1);
  if (lmin > 1e-12 * std::max(1.0, std::abs(lmax))) return {};
  const Vec v = es.eigenvectors().col(0);
  std::vector<Index> idx(static_cast<std::size_t>(n));
  for (Index i = 0; i < n; ++i) idx[static_cast<std::size_t>(i)] = i;
  std::sort(idx.begin(), idx.end(),
            [&](Index a, Index b) { return std::abs(v(a)) > std::abs(v(b)); });
  std::ostringstream os;
  os.precision(3);
  os << "the mass matrix is not positive definite (smallest eigenvalue " << lmin
     << "): nothing resists motion along coordinate";
  int shown = 0;
  for (Index i : idx) {
    if (std::abs(v(i)) < 0.1 || shown == 3) break;
    os << (shown ? ", '" : " '") << names[static_cast<std::size_t>(i)] << "' (" << v(i) << ")";
    ++shown;
  }
  return os.str();
}

// ------------------------------------------------------------------------------ constraints

ConstraintDef::ConstraintDef(std::string name, Kind kind,
                             std::vector<std::string> system_coordinates,
                             std::shared_ptr<SymbolTable> symbols)
    : DefinitionScope(std::move(symbols)),
      name_(std::move(name)),
      kind_(kind),
      coords_(std::move(system_coordinates)) {
  for (const auto& c : coords_) {
    scope_.add(c, coordinate_symbol(*symbols_, c));
    scope_.add(c + "_dot", velocity_symbol(*symbols_, c));
  }
  scope_.add_time(time_symbol(*symbols_));
}

void ConstraintDef::add_row(std::string row_name, ex expression) {
  rows_.emplace_back(std::move(row_name), std::move(expression));
}

ConstraintDerivation derive(const ConstraintDef& def) { return derive(def, Deadline()); }

ConstraintDerivation derive(const ConstraintDef& def, const Deadline& deadline) {
  const auto t0 = Clock::now();
  const std::size_t n = def.system_coordinates().size();
  const std::size_t m = def.rows().size();
  SymbolTable& syms = def.symbols();
  if (m == 0) throw DefinitionError("constraint '" + def.name() + "' has no rows");
  std::vector<symbol> q, qd;
  for (const auto& c : def.system_coordinates()) {
    q.push_back(coordinate_symbol(syms, c));
    qd.push_back(velocity_symbol(syms, c));
  }
  const symbol t = time_symbol(syms);
  const bool hol = def.kind() == ConstraintDef::Kind::holonomic;
  const auto un = static_cast<unsigned>(n), um = static_cast<unsigned>(m);
  ConstraintDerivation d;
  d.holonomic = hol;
  d.coordinates = def.system_coordinates();
  d.parameter_values = def.parameter_values();
  d.symbols = def.symbol_table();
  d.phi = matrix(um, 1);
  d.A = matrix(um, un);
  d.b = matrix(um, 1);
  d.phid = matrix(um, 1);
  for (unsigned r = 0; r < um; ++r) {
    const auto& [rname, expr] = def.rows()[r];
    const int ri = static_cast<int>(r);
    d.row_names.push_back(rname);
    try {
      deadline.check("row '" + rname + "'");
      check_expression_size(expr, "row '" + rname + "'");
    } catch (const Error& x) {
      throw DefinitionError(x.what(), -1, -1, ri);
    }
    // Each simplification checked against the deadline, the refusal tagged with the row.
    // (A named copy: C++20 lets a lambda capture a structured binding, clang 14 does not.)
    const std::string row_where = "row '" + rname + "'";
    const auto simp = [&](const ex& x) {
      try {
        return simplify_trig(x, deadline, row_where);
      } catch (const DerivationTimeout& timeout) {
        throw DefinitionError(timeout.what(), -1, -1, ri);
      }
    };
    const ex e = simp(expr);
    ex vel = 0;
    if (hol) {
      if (has_any(e, qd)) {
        throw DefinitionError(
            "row '" + rname +
                "': a holonomic constraint Phi(q, t) may not use velocities (*_dot); "
                "use type: nonholonomic for B(q,t) qd + c(q,t) = 0",
            -1, -1, ri);
      }
      d.phi(r, 0) = e;
      // A row names a few of the system's n coordinates (a grasp: one robot's and the load's):
      // the others are skipped rather than differentiated, which keeps loading N robots O(N).
      for (unsigned j = 0; j < un; ++j) {
        if (!e.has(q[j])) continue;  // d.A(r, j) stays 0
        d.A(r, j) = simp(e.diff(q[j]));
        vel += d.A(r, j) * qd[j];
      }
      vel += e.diff(t);
    } else {
      d.phi(r, 0) = 0;
      for (unsigned j = 0; j < un; ++j) {
        if (!e.has(qd[j])) continue;  // d.A(r, j) stays 0
        const ex a = simp(e.diff(qd[j]));
        if (has_any(a, qd)) {
          throw DefinitionError("row '" + rname +
                                    "': a nonholonomic constraint must be linear in the velocities "
                                    "(B(q,t) qd + c(q,t)); its coefficient of " +
                                    def.system_coordinates()[j] + "_dot depends on velocities",
                                -1, -1, ri);
        }
        d.A(r, j) = a;
      }
      vel = e;
    }
    bool any = false;
    for (unsigned j = 0; j < un; ++j) any = any || !d.A(r, j).is_zero();
    if (!any) {
      throw DefinitionError("row '" + rname + "' involves no coordinate of the system (" +
                                (hol ? std::string("dPhi/dq = 0") : std::string("no *_dot term")) +
                                ")",
                            -1, -1, ri);
    }
    try {
      check_expression_size(vel, "row '" + rname + "': its velocity form");
      deadline.check("row '" + rname + "': its velocity form");
    } catch (const Error& x) {
      throw DefinitionError(x.what(), -1, -1, ri);
    }
    vel = simp(vel);
    d.phid(r, 0) = vel;
    ex bb = vel.diff(t);
    for (unsigned k = 0; k < un; ++k)
      if (vel.has(q[k])) bb += vel.diff(q[k]) * qd[k];
    d.b(r, 0) = simp(-bb);
  }
  d.derive_seconds = seconds_since(t0);
  return d;
}

namespace {

bool number_input(const ex& e) {
  return GiNaC::is_a<GiNaC::numeric>(e) && GiNaC::ex_to<GiNaC::numeric>(e).is_real() &&
         !GiNaC::ex_to<GiNaC::numeric>(e).is_integer();
}

bool is_spline(const ex& e) {
  return GiNaC::is_a<GiNaC::function>(e) &&
         GiNaC::ex_to<GiNaC::function>(e).get_name() == "ukdyn_spline";
}

// e with every non-integer number (number_input) replaced by one symbol: the shape of e, whatever
// its numbers (exponents kept; splines as they are).
class Blind : public GiNaC::map_function {
 public:
  explicit Blind(const symbol& any) : any_(any) {}
  ex operator()(const ex& e) override {
    if (number_input(e)) return any_;
    if (GiNaC::is_a<GiNaC::power>(e)) return GiNaC::pow((*this)(e.op(0)), e.op(1));
    if (is_spline(e)) return e;
    return e.map(*this);
  }

 private:
  symbol any_;
};

// The non-integer numbers of expressions as tape inputs: each distinct value (bitwise) becomes a
// symbol c#j that reads q[first + j] of Tape::eval (`in` gains it), numbered in an order that does
// not depend on the values themselves: the operands of a sum or product are visited in the
// StructuralOrder of their shape (Blind), ties in the StructuralOrder of the operands. Rows that
// differ only in their numbers (the grasps of N robots: each robot's mount and grasp angle) are
// then the same expressions in the same symbols, which compile to one program (TapePool).
class NumberInputs : public GiNaC::map_function {
 public:
  NumberInputs(InputMap& in, std::int32_t first) : in_(in), first_(first) {}
  ex operator()(const ex& e) override {
    // The double a tape makes of the number (Tape::compile: evalf, then to_double).
    if (number_input(e)) return input(GiNaC::ex_to<GiNaC::numeric>(e.evalf()).to_double());
    if (GiNaC::is_a<GiNaC::power>(e)) {
      const ex expo = GiNaC::is_a<GiNaC::numeric>(e.op(1)) ? e.op(1) : (*this)(e.op(1));
      return GiNaC::pow((*this)(e.op(0)), expo);
    }
    if (is_spline(e)) return e;
    if (!GiNaC::is_a<GiNaC::add>(e) && !GiNaC::is_a<GiNaC::mul>(e)) return e.map(*this);
    std::vector<ex> ops(e.begin(), e.end());
    std::vector<std::uint64_t> keys;
    for (const ex& o : ops) keys.push_back(shape_.hash(Blind(any_)(o)));
    std::vector<std::size_t> at(ops.size());
    for (std::size_t i = 0; i < at.size(); ++i) at[i] = i;
    std::sort(at.begin(), at.end(), [&](std::size_t a, std::size_t b) {
      if (keys[a] != keys[b]) return keys[a] < keys[b];
      return shape_.compare(ops[a], ops[b]) < 0;
    });
    GiNaC::exvector lifted;
    for (std::size_t i : at) lifted.push_back((*this)(ops[i]));
    if (GiNaC::is_a<GiNaC::add>(e)) return GiNaC::dynallocate<GiNaC::add>(lifted);
    return GiNaC::dynallocate<GiNaC::mul>(lifted);
  }
  [[nodiscard]] const std::vector<double>& values() const { return values_; }

 private:
  ex input(double v) {
    const auto bits = std::bit_cast<std::uint64_t>(v);
    if (auto it = index_.find(bits); it != index_.end()) return symbols_[it->second];
    const symbol c("c#" + std::to_string(values_.size()));
    in_[c] = {TapeInput::Source::q, first_ + static_cast<std::int32_t>(values_.size())};
    index_[bits] = values_.size();
    values_.push_back(v);
    symbols_.push_back(c);
    return c;
  }

  InputMap& in_;
  std::int32_t first_;
  symbol any_{"c#"};
  StructuralOrder shape_;
  std::map<std::uint64_t, std::size_t> index_;  // value bits → its input
  std::vector<double> values_;
  std::vector<symbol> symbols_;
};

// The coordinates (indices into `coordinates`) whose position or velocity symbol occurs in `es`,
// ascending.
std::vector<Index> coordinates_read(const std::vector<ex>& es, SymbolTable& table,
                                    const std::vector<std::string>& coordinates) {
  const InputMap in = coordinate_inputs(table, coordinates);
  std::set<Index> cols;
  for (const ex& e : es) {
    for (auto it = e.preorder_begin(); it != e.preorder_end(); ++it) {
      if (!GiNaC::is_a<symbol>(*it)) continue;
      const auto f = in.find(*it);
      if (f != in.end() && f->second.source != TapeInput::Source::time)
        cols.insert(f->second.index);
    }
  }
  return {cols.begin(), cols.end()};
}

// The tapes' q and q̇ at (q, q̇): with positional inputs, q of the coordinates cols[i] then the
// numbers (null: zeros, for tangents), then q̇ of cols[i], written into `in` (2 |cols| + |numbers|
// doubles); qd may be null (a position residual). Without, q and qd as given.
struct TapeArgs {
  const double* q;
  const double* qd;
};
TapeArgs tape_args(bool positional, const std::vector<Index>& cols, const double* numbers,
                   std::size_t count, const double* q, const double* qd, double* in) {
  if (!positional) return {q, qd};
  const std::size_t nc = cols.size();
  for (std::size_t i = 0; i < nc; ++i) in[i] = q[cols[i]];
  for (std::size_t j = 0; j < count; ++j) in[nc + j] = numbers ? numbers[j] : 0.0;
  double* v = in + nc + count;
  if (qd == nullptr) return {in, nullptr};
  for (std::size_t i = 0; i < nc; ++i) v[i] = qd[cols[i]];
  return {in, v};
}

// Room for the tapes' inputs without a slot: `stack` (kInputStack doubles) or, beyond, `heap`.
constexpr std::size_t kInputStack = 256;
double* input_room(std::size_t size, double* stack, std::vector<double>& heap) {
  if (size <= kInputStack) return stack;
  heap.resize(size);
  return heap.data();
}

}  // namespace

DerivedConstraint::DerivedConstraint(ConstraintDerivation derivation)
    : DerivedConstraint(std::move(derivation), Deadline()) {}

DerivedConstraint::DerivedConstraint(ConstraintDerivation derivation, const Deadline& deadline,
                                     TapePool* pool)
    : d_(std::move(derivation)), m_(static_cast<Index>(d_.row_names.size())) {
  const auto& pv = d_.parameter_values;
  std::vector<ex> ab, phi, phid;
  for (unsigned r = 0; r < d_.A.rows(); ++r) {
    deadline.check("compiling row '" + d_.row_names[r] + "'");
    for (unsigned j = 0; j < d_.A.cols(); ++j) {
      if (!d_.A(r, j).is_zero()) {
        nz_.emplace_back(static_cast<Index>(r), static_cast<Index>(j));
        ab.push_back(numeric_form(d_.A(r, j), pv));
      }
    }
  }
  for (unsigned r = 0; r < d_.A.rows(); ++r) {
    ab.push_back(numeric_form(d_.b(r, 0), pv));
    phi.push_back(numeric_form(d_.phi(r, 0), pv));
    phid.push_back(numeric_form(d_.phid(r, 0), pv));
  }
  by_column_.resize(nz_.size());
  for (std::size_t k = 0; k < nz_.size(); ++k) by_column_[k] = k;
  std::stable_sort(by_column_.begin(), by_column_.end(),
                   [this](std::size_t a, std::size_t b) { return nz_[a].second < nz_[b].second; });
  check_tape_work({{&ab, "A and b"}, {&phi, "Phi"}, {&phid, "the velocity form"}});
  if (pool == nullptr) {
    const InputMap in = coordinate_inputs(*d_.symbols, d_.coordinates);
    ab_ = std::make_shared<const Tape>(ab, in, deadline, "compiling A and b");
    phi_ = std::make_shared<const Tape>(phi, in, deadline, "compiling Phi");
    phid_ = std::make_shared<const Tape>(phid, in, deadline, "compiling the velocity form");
    q_read_ = ab_->inputs_read(TapeInput::Source::q);
    qd_read_ = ab_->inputs_read(TapeInput::Source::qd);
    lanes_ = std::min(kTapeLanes, q_read_.size() + qd_read_.size());
    return;
  }
  // Positional inputs: the coordinates read renamed q#i, q̇#i by their position among them, then
  // the numbers as inputs after them (NumberInputs), all three tapes numbered together.
  std::vector<ex> all = ab;
  all.insert(all.end(), phi.begin(), phi.end());
  all.insert(all.end(), phid.begin(), phid.end());
  positional_ = true;
  cols_ = coordinates_read(all, *d_.symbols, d_.coordinates);
  std::vector<std::string> names;
  for (Index c : cols_) names.push_back(d_.coordinates[static_cast<std::size_t>(c)]);
  PositionalInputs p = positional_inputs(*d_.symbols, names);
  NumberInputs lift(p.in, static_cast<std::int32_t>(cols_.size()));
  for (ex& e : all) e = lift(e.subs(p.rename));
  numbers_ = lift.values();
  const auto part = [&](std::size_t first, std::size_t count) {
    return std::vector<ex>(all.begin() + static_cast<std::ptrdiff_t>(first),
                           all.begin() + static_cast<std::ptrdiff_t>(first + count));
  };
  const std::size_t na = ab.size(), nr = phi.size();
  ab_ = pool->share(Tape(part(0, na), p.in, deadline, "compiling A and b"));
  phi_ = pool->share(Tape(part(na, nr), p.in, deadline, "compiling Phi"));
  phid_ = pool->share(Tape(part(na + nr, nr), p.in, deadline, "compiling the velocity form"));
  // The directions: positions among cols_ (the numbers after them are no direction).
  const auto nc = static_cast<Index>(cols_.size());
  for (Index j : ab_->inputs_read(TapeInput::Source::q))
    if (j < nc) q_read_.push_back(j);
  qd_read_ = ab_->inputs_read(TapeInput::Source::qd);
  lanes_ = std::min(kTapeLanes, q_read_.size() + qd_read_.size());
}

// The tapes' inputs (positional: q of cols_ with the numbers, q̇ of cols_), then the A, b tape's
// outputs and work, twice: tangent() puts the inputs' tangents and the outputs' tangents in the
// second halves; tangent_columns() takes tape_columns_size() after the inputs.
Index DerivedConstraint::slot_size() const {
  const std::size_t ow = ab_->outputs() + ab_->work_size();
  const std::size_t n =
      positional_ ? cols_.size() + numbers_.size() : static_cast<std::size_t>(d_.A.cols());
  const std::size_t lanes = tape_columns_size(*ab_, n, lanes_);
  return 2 * input_size() +
         static_cast<Index>(std::max({2 * ow, lanes, phi_->work_size(), phid_->work_size()}));
}

// A, b from the tape: its outputs and work buffer in this constraint's slot, or (no slot: the
// evaluations without data) in a local buffer, on the stack up to 512 outputs. With
// ctx.structural_only only the structurally non-zero entries of A are written (no O(n) zeroing of
// every row).
void DerivedConstraint::evaluate(const ConstraintContext& ctx, CVecRef q, CVecRef qd, MatRef A,
                                 VecRef b) const {
  const Slot own = ctx.slots.own();
  constexpr std::size_t kStack = 512;
  double buf[kStack], in[kInputStack];
  std::vector<double> big, heap;
  const auto ni = static_cast<std::size_t>(input_size());
  const bool slotted = own.size() == static_cast<std::size_t>(slot_size());
  const TapeArgs x = tape_args(positional_, cols_, numbers_.data(), numbers_.size(), q.data(),
                               qd.data(), slotted ? own.data() : input_room(ni, in, heap));
  double* out = slotted ? own.data() + ni : nullptr;  // (no offset from a null slot: UBSan)
  if (slotted) {
    ab_->eval(ctx.t, x.q, x.qd, out, out + ab_->outputs());
  } else {
    out = buf;
    if (ab_->outputs() > kStack) {
      big.resize(ab_->outputs());
      out = big.data();
    }
    ab_->eval(ctx.t, x.q, x.qd, out);
  }
  if (!ctx.structural_only) zero_rows(A);
  std::size_t k = 0;
  for (const auto& [r, c] : nz_) A(r, c) = out[k++];
  for (Index r = 0; r < m_; ++r) b(r) = out[k++];
}

bool DerivedConstraint::tangent(const ConstraintContext& ctx, CVecRef q, CVecRef qd, CVecRef qdd,
                                CVecRef lambda, CVecRef dq, CVecRef dqd, VecRef d_residual,
                                VecRef d_force) const {
  tangent_along(ctx, q, qd, qdd, lambda, 0.0, dq.data(), dqd.data(), d_residual, d_force);
  return true;
}

bool DerivedConstraint::time_tangent(const ConstraintContext& ctx, CVecRef q, CVecRef qd,
                                     CVecRef qdd, CVecRef lambda, VecRef d_residual,
                                     VecRef d_force) const {
  tangent_along(ctx, q, qd, qdd, lambda, 1.0, nullptr, nullptr, d_residual, d_force);
  return true;
}

void DerivedConstraint::tangent_along(const ConstraintContext& ctx, CVecRef q, CVecRef qd,
                                      CVecRef qdd, CVecRef lambda, double dt, const double* dq,
                                      const double* dqd, VecRef d_residual, VecRef d_force) const {
  // The inputs and their tangents, then the tape's outputs: A's structural entries (nz_), then b;
  // with their tangents and the work buffers in this constraint's slot, or (no slot) in a buffer
  // of its own. (CVecRef is contiguous.)
  const std::size_t no = ab_->outputs(), nw = ab_->work_size();
  const auto ni = static_cast<std::size_t>(input_size());
  const Slot own = ctx.slots.own();
  std::vector<double> buffer;
  double* base = own.data();
  if (own.size() != static_cast<std::size_t>(slot_size())) {
    buffer.resize(2 * (ni + no + nw));
    base = buffer.data();
  }
  const TapeArgs x =
      tape_args(positional_, cols_, numbers_.data(), numbers_.size(), q.data(), qd.data(), base);
  // (Along t alone no input moves: null tangents, zero to the tape.)
  const TapeArgs dx =
      dq == nullptr ? TapeArgs{nullptr, nullptr}
                    : tape_args(positional_, cols_, nullptr, numbers_.size(), dq, dqd, base + ni);
  double* out = base + 2 * ni;
  double* dout = out + no;
  double* work = dout + no;
  double* dwork = work + nw;
  ab_->eval_tangent(ctx.t, x.q, x.qd, dt, dx.q, dx.qd, out, dout, work, dwork);
  for (Index r = 0; r < m_; ++r) d_residual(r) = 0.0;
  std::size_t k = 0;
  for (const auto& [r, c] : nz_) {
    const double dA = dout[k++];
    d_residual(r) += dA * qdd(c);
    d_force(c) += dA * lambda(r);
  }
  for (Index r = 0; r < m_; ++r) d_residual(r) -= dout[k++];
}

void DerivedConstraint::column_from_tangents(const double* dout, CVecRef qdd, CVecRef lambda,
                                             MatRef d_residual, MatRef d_force, Index col) const {
  // In tangent()'s order: d(A q̈) row by row over nz_, then − db; d(Aᵀλ) summed per column over
  // nz_ from 0 and then added (as linearize() adds tangent()'s d_force): the same bits.
  auto res = d_residual.col(col);
  std::size_t k = 0;
  for (const auto& [r, c] : nz_) res(r) += dout[k++] * qdd(c);
  for (Index r = 0; r < m_; ++r) res(r) -= dout[k++];
  auto force = d_force.col(col);
  for (std::size_t i = 0; i < by_column_.size();) {
    const Index c = nz_[by_column_[i]].second;
    double sum = 0.0;
    for (; i < by_column_.size() && nz_[by_column_[i]].second == c; ++i) {
      const std::size_t e = by_column_[i];
      sum += dout[e] * lambda(nz_[e].first);
    }
    force(c) += sum;
  }
}

bool DerivedConstraint::tangent_columns(const ConstraintContext& ctx, CVecRef q, CVecRef qd,
                                        CVecRef qdd, CVecRef lambda, MatRef d_residual,
                                        MatRef d_force) const {
  const Slot own = ctx.slots.own();
  if (own.size() != static_cast<std::size_t>(slot_size()) || q.size() != d_.A.cols()) return false;
  d_residual.setZero();  // the directions the tape does not read: zero columns
  if (!positional_) {
    tape_columns(*ab_, ctx.t, q, qd, q_read_, qd_read_, lanes_, own.data(),
                 [&](const double* dout, Index col) {
                   column_from_tangents(dout, qdd, lambda, d_residual, d_force, col);
                 });
    return true;
  }
  // Positional inputs (tapes shared through a pool): the tape's q is (q of cols_, the numbers),
  // its q̇ q̇ of cols_; its column j (j < nx along q, nx + j along q̇) is cols_[j] of the system.
  const auto ni = static_cast<std::size_t>(input_size());
  const TapeArgs x = tape_args(positional_, cols_, numbers_.data(), numbers_.size(), q.data(),
                               qd.data(), own.data());
  const auto nc = static_cast<Index>(cols_.size());
  const Index nx = nc + static_cast<Index>(numbers_.size()), N = d_.A.cols();
  tape_columns(*ab_, ctx.t, Eigen::Map<const Vec>(x.q, nx), Eigen::Map<const Vec>(x.qd, nc),
               q_read_, qd_read_, lanes_, own.data() + 2 * ni, [&](const double* dout, Index col) {
                 const Index c = col < nx ? cols_[static_cast<std::size_t>(col)]
                                          : N + cols_[static_cast<std::size_t>(col - nx)];
                 column_from_tangents(dout, qdd, lambda, d_residual, d_force, c);
               });
  return true;
}

std::vector<std::vector<Index>> DerivedConstraint::row_columns() const {
  std::vector<std::vector<Index>> cols(static_cast<std::size_t>(m_));
  for (const auto& [r, c] : nz_) cols[static_cast<std::size_t>(r)].push_back(c);
  for (auto& v : cols) std::sort(v.begin(), v.end());
  return cols;
}

void DerivedConstraint::position_residual(const ConstraintContext& ctx, CVecRef q,
                                          VecRef phi) const {
  const Slot own = ctx.slots.own();
  const auto ni = static_cast<std::size_t>(input_size());
  double in[kInputStack];
  std::vector<double> heap;
  const bool slotted = own.size() == static_cast<std::size_t>(slot_size());
  const TapeArgs x = tape_args(positional_, cols_, numbers_.data(), numbers_.size(), q.data(),
                               nullptr, slotted ? own.data() : input_room(ni, in, heap));
  if (!slotted) {
    phi_->eval(ctx.t, x.q, nullptr, phi.data());
    return;
  }
  phi_->eval(ctx.t, x.q, nullptr, phi.data(), own.data() + ni);
}

void DerivedConstraint::velocity_residual(const ConstraintContext& ctx, CVecRef q, CVecRef qd,
                                          VecRef phid) const {
  const Slot own = ctx.slots.own();
  const auto ni = static_cast<std::size_t>(input_size());
  double in[kInputStack];
  std::vector<double> heap;
  const bool slotted = own.size() == static_cast<std::size_t>(slot_size());
  const TapeArgs x = tape_args(positional_, cols_, numbers_.data(), numbers_.size(), q.data(),
                               qd.data(), slotted ? own.data() : input_room(ni, in, heap));
  if (!slotted) {
    phid_->eval(ctx.t, x.q, x.qd, phid.data());
    return;
  }
  phid_->eval(ctx.t, x.q, x.qd, phid.data(), own.data() + ni);
}

std::shared_ptr<DerivedConstraint> make_constraint(const ConstraintDef& def, TapePool* pool) {
  const Deadline deadline;  // bounded work (docs/definitions.md, Limits): derivation + compilation
  return std::make_shared<DerivedConstraint>(derive(def, deadline), deadline, pool);
}

}  // namespace ukdyn::symbolic
