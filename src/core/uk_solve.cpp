#include "ukdyn/core/uk_solve.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <Eigen/SVD>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>

#include "core/dense_kernels.hpp"

namespace ukdyn {

UkWorkspace::UkWorkspace(const BlockLayout& block_layout, Index m)
    : layout(block_layout),
      L(Mat::Zero(block_layout.dof(), block_layout.dof())),
      inv_diag(Vec::Zero(block_layout.dof())),
      Linv_Q(block_layout.dof()),
      A_Linvt(m, block_layout.dof()),
      A_Minv_At(m, m),
      piv(static_cast<std::size_t>(m), 0),
      r(m),
      lambda(m),
      tmp_m(m),
      row_scale(m) {}

namespace {

// The kernels chol_block<N>, l_solve<N>, lt_solve<N> are in dense_kernels.hpp.
using detail::chol_block;
using detail::l_solve;
using detail::lt_solve;
using detail::with_block_size;

// The same three kernels for P blocks of one compile-time size N at once, in lockstep. One block's
// Cholesky or substitution is a chain of dependent steps (sqrt, division, multiply-adds); the
// blocks are independent, so running them side by side overlaps their latencies. Each block gets
// exactly the operations of chol_block<N> / l_solve<N> / lt_solve<N>.
template <int N, int P>
bool chol_lockstep(const std::array<const double*, P>& M, Index ldm,
                   const std::array<double*, P>& L, Index ldl,
                   const std::array<double*, P>& inv_diag, double& pivot_ratio) {
  double d_min[P], m_max[P];
  for (int p = 0; p < P; ++p) {
    d_min[p] = std::numeric_limits<double>::infinity();
    m_max[p] = 0.0;
  }
  for (Index j = 0; j < N; ++j) {
    double d[P], inv[P];
    bool ok = true;
    for (int p = 0; p < P; ++p) {
      double v = M[p][j + j * ldm];
      m_max[p] = std::max(m_max[p], v);
      for (Index k = 0; k < j; ++k) v -= L[p][j + k * ldl] * L[p][j + k * ldl];
      d[p] = v;
      d_min[p] = std::min(d_min[p], v);
      ok = ok && d[p] > 0.0;
    }
    if (!ok) return false;
    for (int p = 0; p < P; ++p) {
      const double ljj = std::sqrt(d[p]);
      inv[p] = 1.0 / ljj;
      L[p][j + j * ldl] = ljj;
      inv_diag[p][j] = inv[p];
    }
    for (Index i = j + 1; i < N; ++i) {
      for (int p = 0; p < P; ++p) {
        double v = M[p][i + j * ldm];
        for (Index k = 0; k < j; ++k) v -= L[p][i + k * ldl] * L[p][j + k * ldl];
        L[p][i + j * ldl] = v * inv[p];
      }
    }
  }
  double ratio = std::numeric_limits<double>::infinity();
  for (int p = 0; p < P; ++p) ratio = std::min(ratio, d_min[p] / m_max[p]);
  pivot_ratio = ratio;
  return true;
}

template <int N, int P>
void l_solve_lockstep(const std::array<const double*, P>& L, Index ldl,
                      const std::array<const double*, P>& inv_diag,
                      const std::array<double*, P>& x) {
  for (Index i = 0; i < N; ++i) {
    for (int p = 0; p < P; ++p) {
      double v = x[p][i];
      for (Index k = 0; k < i; ++k) v -= L[p][i + k * ldl] * x[p][k];
      x[p][i] = v * inv_diag[p][i];
    }
  }
}

template <int N, int P>
void lt_solve_lockstep(const std::array<const double*, P>& L, Index ldl,
                       const std::array<const double*, P>& inv_diag,
                       const std::array<double*, P>& x) {
  for (Index i = N - 1; i >= 0; --i) {
    for (int p = 0; p < P; ++p) {
      double v = x[p][i];
      for (Index k = i + 1; k < N; ++k) v -= L[p][k + i * ldl] * x[p][k];
      x[p][i] = v * inv_diag[p][i];
    }
  }
}

// True when the layout is NB blocks of size 6 at 0, 6, 12, … (the paper's arms).
template <int NB>
bool is_fixed6(const BlockLayout& lay) {
  if (lay.blocks() != std::size_t{NB}) return false;
  for (std::size_t k = 0; k < lay.blocks(); ++k)
    if (lay.start[k] != Index{6} * static_cast<Index>(k) || lay.size[k] != 6) return false;
  return true;
}

// x ← L^{-1} x (Forward) or x ← L^{-ᵀ} x, block by block. NB == 2: the layout is two blocks of 6
// (is_fixed6<2>), substituted in lockstep; otherwise any layout.
// (Always inlined: called out of line, the lockstep pair cost the m6 solve ~20 ns, 5 %.)
template <bool Forward, int NB = 0>
[[gnu::always_inline]] inline void substitute_blocks(const UkWorkspace& ws, double* x) {
  const Index ldl = ws.L.rows();
  if constexpr (NB == 2) {
    const double* Ld = ws.L.data();
    const double* id = ws.inv_diag.data();
    if constexpr (Forward) {
      l_solve_lockstep<6, 2>({Ld, Ld + 6 + 6 * ldl}, ldl, {id, id + 6}, {x, x + 6});
    } else {
      lt_solve_lockstep<6, 2>({Ld, Ld + 6 + 6 * ldl}, ldl, {id, id + 6}, {x, x + 6});
    }
  } else {
    const auto& lay = ws.layout;
    for (std::size_t k = 0; k < lay.blocks(); ++k) {
      const Index s = lay.start[k], n = lay.size[k];
      const double* Lk = ws.L.data() + s + s * ldl;
      const double* id = ws.inv_diag.data() + s;
      with_block_size(n, [&](auto N) {
        if constexpr (Forward) {
          l_solve<decltype(N)::value>(Lk, ldl, id, x + s, n);
        } else {
          lt_solve<decltype(N)::value>(Lk, ldl, id, x + s, n);
        }
      });
    }
  }
}

// x ← M^{-1} x = L^{-ᵀ} L^{-1} x, block by block.
void apply_M_inv(const UkWorkspace& ws, double* x) {
  substitute_blocks<true>(ws, x);
  substitute_blocks<false>(ws, x);
}

bool all_finite(const double* x, Index n) {
  for (Index i = 0; i < n; ++i)
    if (!std::isfinite(x[i])) return false;
  return true;
}

}  // namespace

namespace {
// ---- argument checks at the public edge (a few compares per call, outside every loop).
[[noreturn]] void shape_error(const char* where, const char* what, Index er, Index ec, Index r,
                              Index c) {
  throw std::invalid_argument(std::string(where) + ": " + what + " is " + std::to_string(r) +
                              " x " + std::to_string(c) + ", expected " + std::to_string(er) +
                              " x " + std::to_string(ec) + " (the workspace's layout and rows)");
}
void check_shape(const char* where, const char* what, Index er, Index ec, Index r, Index c) {
  if (r != er || c != ec) shape_error(where, what, er, ec, r, c);
}
}  // namespace

bool factor_mass(const Mat& M, UkWorkspace& ws) {
  const Index n_ws = ws.layout.dof();
  check_shape("factor_mass", "M", n_ws, n_ws, M.rows(), M.cols());
  check_shape("factor_mass", "the workspace's L", n_ws, n_ws, ws.L.rows(), ws.L.cols());
  const auto& lay = ws.layout;
  const Index ldm = M.rows(), ldl = ws.L.rows();
  if (is_fixed6<2>(lay)) {  // the paper's two arms: both blocks in lockstep
    const double* Md = M.data();
    double* Ld = ws.L.data();
    double* id = ws.inv_diag.data();
    return chol_lockstep<6, 2>({Md, Md + 6 + 6 * ldm}, ldm, {Ld, Ld + 6 + 6 * ldl}, ldl,
                               {id, id + 6}, ws.pivot_ratio);
  }
  double ratio = std::numeric_limits<double>::infinity();
  for (std::size_t k = 0; k < lay.blocks(); ++k) {
    const Index s = lay.start[k], n = lay.size[k];
    const double* Mk = M.data() + s + s * ldm;
    double* Lk = ws.L.data() + s + s * ldl;
    double* id = ws.inv_diag.data() + s;
    bool ok = false;
    double block_ratio = 0.0;
    with_block_size(n, [&](auto N) {
      ok = chol_block<decltype(N)::value>(Mk, ldm, Lk, ldl, id, n, &block_ratio);
    });
    if (!ok) return false;
    ratio = std::min(ratio, block_ratio);
  }
  ws.pivot_ratio = ratio;
  return true;
}

namespace {

// ---- The steps of the solve (solve_impl below composes them). Each is always inlined: they are
// one function's loops, split only to be named; the generated code and every sum are as before.

// Step 1: Xᵀ = A L^{-ᵀ} (m × n), so that W = A M^{-1} Aᵀ = Xᵀ X with X = L^{-1} Aᵀ. Block by block,
// a forward substitution on whole columns:
//   Xᵀ(:, s+l) = (A(:, s+l) − Σ_{p<l} L_lp Xᵀ(:, s+p)) / L_ll.
// Every operation runs down a contiguous column of m rows (vectorised, no dependency chain).
// The same pass accumulates the absolute row sums of A (for ‖A‖_∞, returned) while the column of A
// is at hand, and r = b − A a = b − Xᵀ y, the bracket of paper Eq. (4), once a column of Xᵀ is
// done.
template <int MM, int NB>
[[gnu::always_inline]] inline double build_Xt_and_r(const double* Ad, const Vec& b, UkWorkspace& ws,
                                                    Index m) {
  const auto& lay = ws.layout;
  const std::size_t nb = NB > 0 ? std::size_t{NB} : lay.blocks();
  const Index ldl = ws.L.rows();
  const double* y = ws.Linv_Q.data();
  double* Xt = ws.A_Linvt.data();
  double* r = ws.r.data();
  double* rowabs = ws.tmp_m.data();
  double a_inf = 0.0;
  if constexpr (MM > 0) {
    // Fixed m: the column being built and the two row accumulators live in local arrays, which
    // provably alias nothing, so the compiler keeps them in registers.
    double rl[MM], absl[MM];
    for (Index i = 0; i < MM; ++i) {
      rl[i] = b[i];
      absl[i] = 0.0;
    }
    for (std::size_t k = 0; k < nb; ++k) {
      const Index s = NB > 0 ? Index{6} * static_cast<Index>(k) : lay.start[k];
      const Index nk = NB > 0 ? Index{6} : lay.size[k];
      const double* Lk = ws.L.data() + s + s * ldl;
      const double* id = ws.inv_diag.data() + s;
      for (Index l = 0; l < nk; ++l) {
        const double* al = Ad + (s + l) * MM;
        const double yl = y[s + l];
        double x[MM];
        for (Index i = 0; i < MM; ++i) {
          const double v = al[i];
          x[i] = v;
          absl[i] += std::abs(v);
        }
        for (Index p = 0; p < l; ++p) {
          const double c = Lk[l + p * ldl];
          const double* xp = Xt + (s + p) * MM;
          for (Index i = 0; i < MM; ++i) x[i] -= c * xp[i];
        }
        const double inv = id[l];
        double* xl = Xt + (s + l) * MM;
        for (Index i = 0; i < MM; ++i) {
          const double v = x[i] * inv;
          xl[i] = v;
          rl[i] -= v * yl;
        }
      }
    }
    for (Index i = 0; i < MM; ++i) {
      r[i] = rl[i];
      a_inf = std::max(a_inf, absl[i]);
    }
  } else {
    for (Index i = 0; i < m; ++i) {
      r[i] = b[i];
      rowabs[i] = 0.0;
    }
    for (std::size_t k = 0; k < nb; ++k) {
      const Index s = lay.start[k], nk = lay.size[k];
      const double* Lk = ws.L.data() + s + s * ldl;
      const double* id = ws.inv_diag.data() + s;
      for (Index l = 0; l < nk; ++l) {
        double* xl = Xt + (s + l) * m;
        const double* al = Ad + (s + l) * m;
        const double yl = y[s + l];
        for (Index i = 0; i < m; ++i) {
          const double v = al[i];
          xl[i] = v;
          rowabs[i] += std::abs(v);
        }
        for (Index p = 0; p < l; ++p) {
          const double c = Lk[l + p * ldl];
          const double* xp = Xt + (s + p) * m;
          for (Index i = 0; i < m; ++i) xl[i] -= c * xp[i];
        }
        const double inv = id[l];
        for (Index i = 0; i < m; ++i) {
          const double v = xl[i] * inv;
          xl[i] = v;
          r[i] -= v * yl;
        }
      }
    }
    for (Index i = 0; i < m; ++i) a_inf = std::max(a_inf, rowabs[i]);
  }
  return a_inf;
}

// Step 2: W = Xᵀ X, lower triangle only: W(j:m, j) = Σ_l Xᵀ(j:m, l) Xᵀ(j, l). Constraint rows are
// sparse (a trajectory row touches one arm, so its entries of Xᵀ in the other block are 0): zero
// multipliers are skipped.
template <int MM>
[[gnu::always_inline]] inline void build_W(const double* Xt, Index n, Index m, double* W,
                                           Index ldw) {
  if constexpr (MM > 0) {
    // Fixed m: each whole column of W is summed in a local array (registers) and stored once.
    // Summing into W's memory instead chains a store and a reload per term (store forwarding), and
    // that chain was most of the solve's time. The upper triangle is written too and never read.
    for (Index j = 0; j < MM; ++j) {
      double acc[MM] = {};
      for (Index l = 0; l < n; ++l) {
        const double* xl = Xt + l * MM;
        const double c = xl[j];
        for (Index i = 0; i < MM; ++i) acc[i] += xl[i] * c;
      }
      double* wj = W + j * ldw;
      for (Index i = 0; i < MM; ++i) wj[i] = acc[i];
    }
  } else {
    // Runtime m: one rank-1 update of the lower triangle per column of Xᵀ, so that consecutive
    // updates of one entry of W are a whole triangle apart (no store-to-load chain).
    for (Index j = 0; j < m; ++j)
      for (Index i = j; i < m; ++i) W[i + j * ldw] = 0.0;
    for (Index l = 0; l < n; ++l) {
      const double* xl = Xt + l * m;
      for (Index j = 0; j < m; ++j) {
        const double c = xl[j];
        if (c == 0.0) continue;
        double* wj = W + j * ldw;
        for (Index i = j; i < m; ++i) wj[i] += xl[i] * c;
      }
    }
  }
}

double max_diagonal(const double* W, Index ldw, Index m) {
  double w_max = 0.0;
  for (Index i = 0; i < m; ++i) w_max = std::max(w_max, W[i + i * ldw]);
  return w_max;
}

// Step 3a (equilibrated): Ŵ = D W D with D_ii = W_ii^{-1/2}: unit diagonal; r̂ = D r; λ = D λ̂ in
// step 4. Rows under row_floor of the longest get D_ii = 0 (dropped).
void equilibrate_W(double* W, Index ldw, Index m, double row_floor, double* dsc) {
  const double w_max = max_diagonal(W, ldw, m);
  const double floor2 = row_floor * row_floor * w_max;
  for (Index i = 0; i < m; ++i) {
    const double wi = W[i + i * ldw];
    dsc[i] = wi > floor2 && wi > 0.0 ? 1.0 / std::sqrt(wi) : 0.0;
  }
  for (Index j = 0; j < m; ++j) {
    const double dj = dsc[j];
    double* wj = W + j * ldw;
    for (Index i = j; i < m; ++i) wj[i] *= dsc[i] * dj;
  }
}

// Step 3b (regularized, adaptive): W ← W + μ I with μ = ε² max diag W · weight; returns μ.
double shift_W(double* W, Index ldw, Index m, double eps, double weight) {
  const double w_max = max_diagonal(W, ldw, m);
  const double mu = weight == 1.0 ? eps * eps * w_max : weight * (eps * eps * w_max);
  for (Index i = 0; i < m; ++i) W[i + i * ldw] += mu;
  return mu;
}

// Adaptive method: the weight of the damping as a function of ρ = σ_min² / σ_max² (the smallest
// kept pivot of the exact factorisation over the largest). 1 for ρ ≤ ε² (σ_min ≤ ε σ_max: inside
// the band where the exact solve's force is a round-off-sensitive 0/0), 0 for ρ ≥ (band ε)², and
// in between the smoothstep 3x² − 2x³ of x = log(ρ_off/ρ) / log(ρ_off/ρ_on): C¹ in ρ, so q̈ is
// continuous (and its derivative bounded) as a singular value passes into the band.
double damping_weight(double rho, const UkSettings& s) {
  const double e = s.regularization;
  const double rho_on = e * e, rho_off = (s.adaptive_band * e) * (s.adaptive_band * e);
  if (!(rho < rho_off)) return 0.0;
  if (!(rho > rho_on)) return 1.0;
  const double x = std::log(rho_off / rho) / std::log(rho_off / rho_on);
  return x * x * (3.0 - 2.0 * x);
}

// Step 4: the pivoted LDLᵀ of W in place with the rank rule of dense_kernels.hpp (pivoted_ldlt):
// the exact and equilibrated solves drop pivots D_k ≤ rank_tol² D_0, D_0 = max diag W; the
// regularized one keeps every pivot above μ/2; the damped adaptive one drops at
// max(μ/2, rank_tol² s). `rank` counts the pivots with D_k − μ > rank_tol² s, as the exact method
// would.
using detail::LdltPivots;
using detail::pivoted_ldlt;
using detail::RankRule;

// Step 5: basic solution of W λ = r from step 4 (ldlt_basic_solve), times D on both sides when
// equilibrated: λ = D Ŵ⁺ D r.
[[gnu::always_inline]] inline void basic_solve(const double* W, Index ldw, Index m, Index kept,
                                               const Index* piv, const double* r, const double* dsc,
                                               double* lam) {
  if (dsc != nullptr) {
    for (Index i = 0; i < m; ++i) lam[i] = dsc[i] * r[i];
  } else {
    for (Index i = 0; i < m; ++i) lam[i] = r[i];
  }
  detail::ldlt_basic_solve(W, ldw, m, kept, piv, lam);
  if (dsc != nullptr) {
    for (Index i = 0; i < m; ++i) lam[i] *= dsc[i];
  }
}

// Step 6: Qc = Aᵀ λ (= M^{1/2}(A M^{-1/2})^+ r, paper Eq. (4)); q̈ = M^{-1}(Q + Qc), paper Eq.
// (18), as q̈ = L^{-ᵀ}(L^{-1} Q + L^{-1} Aᵀ λ) = L^{-ᵀ}(y + X λ).
template <int NB>
[[gnu::always_inline]] inline void constraint_force_and_qdd(const double* Ad, const UkWorkspace& ws,
                                                            Index m, Index n, double* qc,
                                                            double* q) {
  const double* Xt = ws.A_Linvt.data();
  const double* y = ws.Linv_Q.data();
  const double* lam = ws.lambda.data();
  for (Index j = 0; j < n; ++j) {
    const double* col = Ad + j * m;
    const double* xcol = Xt + j * m;
    double s = 0.0, sx = 0.0;
    for (Index i = 0; i < m; ++i) {
      s += col[i] * lam[i];
      sx += xcol[i] * lam[i];
    }
    qc[j] = s;
    q[j] = y[j] + sx;
  }
  substitute_blocks<false, NB>(ws, q);
}

// Step 7: the honest residual ‖A q̈ − b‖ of the returned q̈, and the consistency and finiteness
// flags, with ‖A‖_∞ from step 1 (uk_solve_textbook too; r is read only when μ > 0).
// Always inlined, so that a compile-time m and n (solve_impl<6, 2>) reach its loops.
[[gnu::always_inline]] inline void residual_and_flags(const double* Ad, const Vec& b, Index m,
                                                      Index n, const double* q, const double* qc,
                                                      const double* r, double a_inf, double mu,
                                                      const UkSettings& settings, double* rr,
                                                      UkResult& res) {
  for (Index i = 0; i < m; ++i) rr[i] = -b[i];
  for (Index j = 0; j < n; ++j) {
    const double x = q[j];
    const double* col = Ad + j * m;
    for (Index i = 0; i < m; ++i) rr[i] += col[i] * x;
  }
  double r2 = 0.0, b2 = 0.0, q2 = 0.0;
  for (Index i = 0; i < m; ++i) r2 += rr[i] * rr[i];
  for (Index i = 0; i < m; ++i) b2 += b[i] * b[i];
  for (Index j = 0; j < n; ++j) q2 += q[j] * q[j];
  res.residual = std::sqrt(r2);
  const double scale = std::sqrt(b2) + a_inf * std::sqrt(q2) + 1.0;
  // Regularized: A q̈ − b = −μ λ exactly; a consistent direction with σ ~ √μ leaves at most
  // ~ ε/2 ‖r‖ of it, a contradiction (σ = 0) all of its part of r. Tolerated: 1e3 ε ‖r‖.
  double band = 0.0;
  if (mu > 0.0) {
    double rn2 = 0.0;
    for (Index i = 0; i < m; ++i) rn2 += r[i] * r[i];
    band = 1e3 * settings.regularization * std::sqrt(rn2);
  }
  res.consistent = res.residual <= settings.consistency_rel_tol * scale + band;
  res.finite = all_finite(q, n) && all_finite(qc, n) && std::isfinite(res.residual);
}

// The solve, composed of the steps above. MM > 0 / NB > 0: compile-time m and NB blocks of 6;
// MM == NB == 0: runtime sizes, any layout. Every instantiation forms the same sums in the same
// order (the fixed path also adds W's zero products and upper triangle, which change no value), so
// the results agree to rounding where the compiler contracts a different set of a·b + c into FMAs,
// e.g. with -march=native (UkSolve.FixedSizePathAgreesWithGenericPath).
template <int MM, int NB>
UkResult solve_impl(const Mat& A, const Vec& b, const Vec& Q, UkWorkspace& ws, Vec& qdd, Vec& Qc,
                    const UkSettings& settings) {
  static_assert((MM > 0) == (NB > 0), "fixed m comes with a fixed layout");
  UkResult res;
  const Index m = MM > 0 ? Index{MM} : A.rows();
  const Index n = NB > 0 ? Index{6} * NB : ws.layout.dof();
  const Index ldw = MM > 0 ? Index{MM} : ws.A_Minv_At.rows();
  double* W = ws.A_Minv_At.data();
  const double* Ad = A.data();
  // y = L^{-1} Q. The unconstrained acceleration of paper Eq. (1) is a = M^{-1} Q = L^{-ᵀ} y; it is
  // never formed: A a = Xᵀ y in step 1, and q̈ = L^{-ᵀ}(y + X λ) in step 6, so each block is
  // substituted forward once and backward once.
  double* y = ws.Linv_Q.data();
  for (Index j = 0; j < n; ++j) y[j] = Q[j];
  substitute_blocks<true, NB>(ws, y);

  const double a_inf = build_Xt_and_r<MM, NB>(Ad, b, ws, m);
  build_W<MM>(ws.A_Linvt.data(), n, m, W, ldw);

  // Regularized: the factorisation of W + μ I, μ = ε² max diag W (ε = settings.regularization).
  // Every pivot is then ≥ μ in exact arithmetic, so none is dropped (the cut-off is μ/2, against
  // round-off) and λ = (W + μ I)^{-1} r is continuous in W.
  const double tol2 = settings.rank_rel_tol * settings.rank_rel_tol;
  double mu = 0.0;
  const bool equilibrate = settings.method == UkMethod::equilibrated;
  const bool regularized = settings.method == UkMethod::regularized;
  if (equilibrate) {
    equilibrate_W(W, ldw, m, settings.row_floor, ws.row_scale.data());
  } else if (regularized) {
    mu = shift_W(W, ldw, m, settings.regularization, 1.0);
  }
  // The regularized solve drops no direction by rank_tol (only round-off under μ/2), unless there
  // is no shift (μ = 0: regularization 0, or W = 0).
  // Adaptive with a structural redundancy r (UkSettings): at most m − r pivots, so that drift off
  // the manifold, which lifts the redundant directions' singular values from 0 to its own size,
  // neither puts a force on them (exact) nor reads as an approaching singular position (damping).
  const bool adaptive = settings.method == UkMethod::adaptive;
  const Index keep_at_most = adaptive && settings.structural_redundancy > 0
                                 ? std::max<Index>(m - settings.structural_redundancy, 0)
                                 : std::numeric_limits<Index>::max();
  LdltPivots pv = pivoted_ldlt(W, ldw, m, ws.piv.data(), ws.tmp_m.data(),
                               RankRule{tol2, mu, 0.0, !(regularized && mu > 0.0), keep_at_most});
  // Adaptive: the exact factorisation above decides. When its smallest kept singular value is
  // within adaptive_band · ε of the largest, W is rebuilt and refactored with the damping
  // μ = weight(ρ) ε² max diag W (damping_weight): exact to round-off away from singular positions,
  // damped (as regularized) inside the band, and continuous in between.
  auto damp = [&](double weight) {
    build_W<MM>(ws.A_Linvt.data(), n, m, W, ldw);
    mu = shift_W(W, ldw, m, settings.regularization, weight);
    pv = pivoted_ldlt(W, ldw, m, ws.piv.data(), ws.tmp_m.data(),
                      RankRule{tol2, mu, 0.0, true, keep_at_most});
    res.damping = weight * settings.regularization;
  };
  if (adaptive && pv.rank > 0 && pv.d_max > 0.0) {
    const double weight = damping_weight(pv.d_min_kept / pv.d_max, settings);
    if (weight > 0.0) damp(weight);
  }
  double* qc = Qc.data();
  double* q = qdd.data();
  // Always inlined: called out of line, the lambda reads m, n and ldw through its captures, and
  // the compile-time sizes no longer reach the loops (+580 instructions per forward/closure call,
  // docs/performance.md).
  auto solve_and_check = [&]() __attribute__((always_inline)) {
    basic_solve(W, ldw, m, pv.kept, ws.piv.data(), ws.r.data(),
                equilibrate ? ws.row_scale.data() : nullptr, ws.lambda.data());
    constraint_force_and_qdd<NB>(Ad, ws, m, n, qc, q);
    res.rank = static_cast<int>(pv.rank);
    res.sigma_max = std::sqrt(std::max(pv.d_max - mu, 0.0));
    res.sigma_min_kept = pv.rank > 0 ? std::sqrt(pv.d_min_kept) : 0.0;
    residual_and_flags(Ad, b, m, n, q, qc, ws.r.data(), a_inf, mu, settings, ws.tmp_m.data(), res);
  };
  solve_and_check();
  // Adaptive, past the exact cut-off: a row whose singular value fell under rank_tol was dropped
  // by the exact factorisation, and if that leaves a residual that is not round-off, the row still
  // asks for a force (the 0/0 limit at a singular position; a redundant consistent row leaves
  // round-off and keeps the exact answer). Then the fully damped solve, which is what the band's
  // inside gives just above the cut-off: continuous across it. Not for the directions of a
  // structural redundancy (keep_at_most, above): their rows are dependent at every configuration,
  // so what they leave is the drift of a state off the manifold, and the least-squares answer of
  // the other rows is the right one.
  if (adaptive && mu == 0.0 && pv.kept < std::min(m, keep_at_most) && !res.consistent &&
      pv.d_max > 0.0) {
    damp(1.0);
    solve_and_check();
  }
  if (mu > 0.0) {
    // What the damping took away: A q̈ − b = −μ λ is the constraint acceleration not applied; in
    // the coordinates it is at most ‖L^{-ᵀ}‖ ‖μ λ‖ / σ for the directions with σ ≥ √μ (the
    // estimate below; inside the core σ < √μ it underestimates, docs/singular-positions.md).
    double inv_l = 0.0;
    for (Index j = 0; j < n; ++j) inv_l = std::max(inv_l, std::abs(ws.inv_diag[j]));
    res.damped_acceleration = res.residual / std::max(res.sigma_min_kept, std::sqrt(mu)) * inv_l;
    if (regularized) res.damping = settings.regularization;
  }
  return res;
}

}  // namespace

UkResult uk_solve_factored(const Mat& A, const Vec& b, const Vec& Q, UkWorkspace& ws, Vec& qdd,
                           Vec& Qc, const UkSettings& settings) {
  const Index m = A.rows();
  const Index n = ws.layout.dof();
  const char* where = "uk_solve";
  check_shape(where, "A (rows)", ws.A_Minv_At.rows(), m == 0 ? A.cols() : n, m, A.cols());
  check_shape(where, "b", m, 1, b.size(), 1);
  check_shape(where, "Q", n, 1, Q.size(), 1);
  if (qdd.size() != n) qdd.resize(n);  // no-op (no allocation) when the caller sized them
  if (Qc.size() != n) Qc.resize(n);
  if (m == 0) {
    // a = M^{-1} Q: the unconstrained acceleration, paper Eq. (1).
    UkResult res;
    double* a = ws.Linv_Q.data();
    for (Index j = 0; j < n; ++j) a[j] = Q[j];
    apply_M_inv(ws, a);
    for (Index j = 0; j < n; ++j) qdd[j] = a[j];
    Qc.setZero();
    res.finite = all_finite(qdd.data(), n);
    return res;
  }
  // Compile-time sizes for the paper's shapes (two arms of 6, 6 or 12 rows); the generic code
  // otherwise.
  const bool ws_m = ws.A_Minv_At.rows() == m && ws.A_Linvt.rows() == m;
  if (ws_m && is_fixed6<2>(ws.layout)) {
    if (m == 6) return solve_impl<6, 2>(A, b, Q, ws, qdd, Qc, settings);
    if (m == 12) return solve_impl<12, 2>(A, b, Q, ws, qdd, Qc, settings);
  }
  return solve_impl<0, 0>(A, b, Q, ws, qdd, Qc, settings);
}

UkResult uk_solve(const Mat& M, const Mat& A, const Vec& b, const Vec& Q, UkWorkspace& ws, Vec& qdd,
                  Vec& Qc, const UkSettings& settings) {
  if (!factor_mass(M, ws)) {
    UkResult res;
    res.finite = false;
    qdd.setConstant(std::numeric_limits<double>::quiet_NaN());
    Qc.setConstant(std::numeric_limits<double>::quiet_NaN());
    return res;
  }
  return uk_solve_factored(A, b, Q, ws, qdd, Qc, settings);
}

namespace {
// Symmetric root and inverse root of an SPD matrix by eigen-decomposition.
void sym_roots(const Mat& M, Mat& M_half, Mat& M_inv_half) {
  Eigen::SelfAdjointEigenSolver<Mat> es(M);
  const Vec ev = es.eigenvalues();
  if (ev.minCoeff() <= 0.0) {
    throw Error("uk_solve_textbook: M is not positive definite");
  }
  M_half = es.eigenvectors() * ev.cwiseSqrt().asDiagonal() * es.eigenvectors().transpose();
  M_inv_half = es.eigenvectors() * ev.cwiseSqrt().cwiseInverse().asDiagonal() *
               es.eigenvectors().transpose();
}
}  // namespace

UkResult uk_solve_textbook(const Mat& M, const Mat& A, const Vec& b, const Vec& Q, Vec& qdd,
                           Vec& Qc, const UkSettings& settings) {
  UkResult res;
  Mat M_half, M_inv_half;
  sym_roots(M, M_half, M_inv_half);
  const Vec M_inv_Q = M.llt().solve(Q);
  if (A.rows() == 0) {
    qdd = M_inv_Q;
    Qc = Vec::Zero(Q.size());
    res.finite = qdd.allFinite();
    return res;
  }
  const Mat B = A * M_inv_half;  // A M^{-1/2}
  Eigen::JacobiSVD<Mat> svd(B, Eigen::ComputeThinU | Eigen::ComputeThinV);
  const Vec& s = svd.singularValues();
  const double cutoff = settings.rank_rel_tol * (s.size() > 0 ? s(0) : 0.0);
  Vec s_inv = Vec::Zero(s.size());
  int rank = 0;
  for (Index i = 0; i < s.size(); ++i) {
    if (s(i) > cutoff && s(i) > 0.0) {
      s_inv(i) = 1.0 / s(i);
      ++rank;
    }
  }
  const Mat B_pinv = svd.matrixV() * s_inv.asDiagonal() * svd.matrixU().transpose();
  // Qc = M^{1/2} (A M^{-1/2})^+ (b − A M^{-1} Q), paper Eq. (4), literally.
  Qc = M_half * (B_pinv * (b - A * M_inv_Q));
  qdd = M.llt().solve(Q + Qc);
  res.rank = static_cast<int>(rank);
  res.sigma_max = s.size() > 0 ? s(0) : 0.0;
  res.sigma_min_kept = rank > 0 ? s(rank - 1) : 0.0;
  // The residual, consistency and finiteness of the returned q̈ as the production solve's step 7.
  const Index m = A.rows(), n = A.cols();
  double a_inf = 0.0;  // ‖A‖_∞, the largest absolute row sum
  for (Index i = 0; i < m; ++i) {
    double row = 0.0;
    for (Index j = 0; j < n; ++j) row += std::abs(A(i, j));
    a_inf = std::max(a_inf, row);
  }
  Vec scratch(m);
  residual_and_flags(A.data(), b, m, n, qdd.data(), Qc.data(), nullptr, a_inf, 0.0, settings,
                     scratch.data(), res);
  return res;
}

Vec singular_values_A_Minvhalf(const Mat& M, const Mat& A) {
  Mat M_half, M_inv_half;
  sym_roots(M, M_half, M_inv_half);
  return Eigen::JacobiSVD<Mat>(A * M_inv_half).singularValues();
}

void kkt_solve(const Mat& M, const Mat& A, const Vec& b, const Vec& Q, Vec& qdd, Vec& Qc) {
  const Index n = M.rows();
  const Index m = A.rows();
  Mat K = Mat::Zero(n + m, n + m);
  K.topLeftCorner(n, n) = M;
  K.topRightCorner(n, m) = A.transpose();
  K.bottomLeftCorner(m, n) = A;
  Vec rhs(n + m);
  rhs << Q, b;
  const Vec x = K.fullPivLu().solve(rhs);
  qdd = x.head(n);
  // M q̈ + Aᵀ μ = Q  ⇒  Qc = −Aᵀ μ.
  Qc = -(A.transpose() * x.tail(m));
}

}  // namespace ukdyn
