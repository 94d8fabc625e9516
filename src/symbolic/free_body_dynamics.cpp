#include "symbolic/free_body_dynamics.hpp"

#include <optional>

#include "symbolic/ex_helpers.hpp"
#include "ukdyn/symbolic/free_body.hpp"

namespace ukdyn::symbolic {

using GiNaC::ex;

namespace {

// e as a double if it is a real number once evaluated (no symbol left).
std::optional<double> real_number(const ex& e) {
  const ex v = e.evalf();
  if (!GiNaC::is_a<GiNaC::numeric>(v) || !GiNaC::ex_to<GiNaC::numeric>(v).is_real())
    return std::nullopt;
  return GiNaC::ex_to<GiNaC::numeric>(v).to_double();
}

// J read from T at u = (1, 0, 0, 0), ṗ = 0, u̇_w = 0, where ω = 2 (u̇x, u̇y, u̇z) and
// T = 2 Σ_ij J_ij u̇_i u̇_j: J_ii = coeff(u̇_i²) / 2, J_ij = coeff(u̇_i u̇_j) / 4 (i ≠ j).
std::array<ex, 9> inertia_from_energy(const ex& T, const std::array<GiNaC::symbol, 7>& q,
                                      const std::array<GiNaC::symbol, 7>& v) {
  const GiNaC::exmap at{{q[3], 1}, {q[4], 0}, {q[5], 0}, {q[6], 0},
                        {v[0], 0}, {v[1], 0}, {v[2], 0}, {v[3], 0}};
  const ex Tr = T.subs(at).expand();
  std::array<ex, 9> J;
  for (std::size_t i = 0; i < 3; ++i) {
    for (std::size_t j = i; j < 3; ++j) {
      const ex c =
          i == j ? Tr.coeff(v[4 + i], 2) / 2 : Tr.coeff(v[4 + i], 1).coeff(v[4 + j], 1) / 4;
      J[3 * i + j] = c;
      J[3 * j + i] = c;
    }
  }
  return J;
}

}  // namespace

std::shared_ptr<const FreeBodyDynamics> free_body_closed_form(const SubsystemDerivation& d) {
  if (d.coordinates.size() != 7 || d.time_varying || !d.symbols) return nullptr;
  std::array<GiNaC::symbol, 7> q, v;
  for (std::size_t i = 0; i < 7; ++i) {
    q[i] = coordinate_symbol(*d.symbols, d.coordinates[i]);
    v[i] = velocity_symbol(*d.symbols, d.coordinates[i]);
  }
  // Cheap refusals first (a 7-coordinate arm must not pay for expanding its T here): M's first
  // three rows are m I of a constant m, and T does not read p.
  for (unsigned i = 0; i < 3; ++i) {
    for (unsigned j = 0; j < 7; ++j) {
      const ex& e = d.M(i, j);
      if (j == i ? !real_number(numeric_form(e, d.parameter_values)) : !e.is_zero()) return nullptr;
    }
    if (d.T.has(q[i])) return nullptr;
  }
  // What the tapes compile (parameters substituted, exact coefficients): the closed form must be
  // that derivation, checked as an identity of polynomials in (q, q̇), not at sample points.
  const ex T = numeric_form(d.T, d.parameter_values);
  const ex V = numeric_form(d.V, d.parameter_values);
  const ex m = 2 * T.coeff(v[0], 2);
  const std::array<ex, 9> J = inertia_from_energy(T, q, v);
  const auto w = quaternion_body_rate(q[3], q[4], q[5], q[6], v[3], v[4], v[5], v[6]);
  ex Tc = m / 2 * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  for (std::size_t i = 0; i < 3; ++i)
    for (std::size_t j = 0; j < 3; ++j) Tc += w[i] * J[3 * i + j] * w[j] / 2;
  if (!(T - Tc).expand().is_zero()) return nullptr;
  auto f = std::make_shared<FreeBodyDynamics>();
  const auto mass = real_number(m);
  if (!mass) return nullptr;
  f->mass = *mass;
  for (std::size_t k = 0; k < 9; ++k) {
    const auto j = real_number(J[k]);
    if (!j) return nullptr;
    f->inertia4[k] = 4.0 * *j;
  }
  f->diagonal = f->inertia4[1] == 0.0 && f->inertia4[2] == 0.0 && f->inertia4[5] == 0.0;
  for (std::size_t i = 3; i < 7; ++i)
    if (!V.diff(q[i]).expand().is_zero()) return nullptr;
  for (std::size_t i = 0; i < 3; ++i) {
    const auto g = real_number(V.diff(q[i]).expand());
    if (!g) return nullptr;
    f->gravity_force[i] = *g;
  }
  return f;
}

void free_body_mass(const FreeBodyDynamics& f, CVecRef q, MatRef M) {
  const double w = q(3), x = q(4), y = q(5), z = q(6);
  const double E[3][4] = {{-x, w, z, -y}, {-y, -z, w, x}, {-z, y, -x, w}};
  const auto& J = f.inertia4;
  // (4 J) E; the products by J's zeros left out when J is diagonal (the same bits).
  double JE[3][4];
  if (f.diagonal) {
    for (std::size_t i = 0; i < 3; ++i)
      for (std::size_t c = 0; c < 4; ++c) JE[i][c] = J[4 * i] * E[i][c];
  } else {
    for (std::size_t i = 0; i < 3; ++i)
      for (std::size_t c = 0; c < 4; ++c)
        JE[i][c] = J[3 * i] * E[0][c] + J[3 * i + 1] * E[1][c] + J[3 * i + 2] * E[2][c];
  }
  // The quaternion block Eᵀ (4 J) E, its lower triangle mirrored from its upper one (exactly
  // symmetric), column by column (B[b] is column b).
  double B[4][4];
  for (std::size_t b = 0; b < 4; ++b) {
    for (std::size_t a = 0; a <= b; ++a) {
      B[b][a] = E[0][a] * JE[0][b] + E[1][a] * JE[1][b] + E[2][a] * JE[2][b];
      B[a][b] = B[b][a];
    }
  }
  // Through the data pointer (M is a block of the system's M), every entry written once.
  double* const m = M.data();
  const Index s = M.outerStride();
  for (Index j = 0; j < 3; ++j) {
    double* col = m + j * s;
    for (Index i = 0; i < 7; ++i) col[i] = 0.0;
    col[j] = f.mass;
  }
  for (std::size_t b = 0; b < 4; ++b) {
    double* col = m + static_cast<Index>(3 + b) * s;
    col[0] = col[1] = col[2] = 0.0;
    for (std::size_t a = 0; a < 4; ++a) col[3 + a] = B[b][a];
  }
}

void free_body_velocity_products(const FreeBodyDynamics& f, CVecRef q, CVecRef qd, VecRef Cqd) {
  const double w = q(3), x = q(4), y = q(5), z = q(6);
  const double a = qd(3), b = qd(4), c = qd(5), d = qd(6);
  // ω = 2 E(u) u̇, k = 4 J ω, C q̇ = (0, E(u̇)ᵀ k).
  const double o0 = 2.0 * (-x * a + w * b + z * c - y * d);
  const double o1 = 2.0 * (-y * a - z * b + w * c + x * d);
  const double o2 = 2.0 * (-z * a + y * b - x * c + w * d);
  const auto& J = f.inertia4;
  const double k0 = f.diagonal ? J[0] * o0 : J[0] * o0 + J[1] * o1 + J[2] * o2;
  const double k1 = f.diagonal ? J[4] * o1 : J[3] * o0 + J[4] * o1 + J[5] * o2;
  const double k2 = f.diagonal ? J[8] * o2 : J[6] * o0 + J[7] * o1 + J[8] * o2;
  Cqd(0) = 0.0;
  Cqd(1) = 0.0;
  Cqd(2) = 0.0;
  Cqd(3) = -b * k0 - c * k1 - d * k2;
  Cqd(4) = a * k0 - d * k1 + c * k2;
  Cqd(5) = d * k0 + a * k1 - b * k2;
  Cqd(6) = -c * k0 + b * k1 + a * k2;
}

void free_body_gravity(const FreeBodyDynamics& f, VecRef G) {
  for (Index i = 0; i < 3; ++i) G(i) = f.gravity_force[static_cast<std::size_t>(i)];
  for (Index i = 3; i < 7; ++i) G(i) = 0.0;
}

}  // namespace ukdyn::symbolic
