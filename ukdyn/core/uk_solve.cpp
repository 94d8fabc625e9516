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

// ---- Small dense kernels on raw column-major storage. N > 0: the size is known at compile time
// (the loops unroll); N == 0: the runtime size n is used. Every routine works for any size, so the
// solve is correct for large systems too; it is tuned for the small blocks of multibody models.

// Cholesky M = L Lᵀ of one n × n block (lower triangle of M read). Writes L's lower triangle and
// 1/L_ii. Returns false when a pivot is not > 0 (not positive definite, or NaN).
template <int N>
bool chol_block(const double* M, Index ldm, double* L, Index ldl, double* inv_diag, Index n_rt) {
  const Index n = N > 0 ? Index{N} : n_rt;
  for (Index j = 0; j < n; ++j) {
    double d = M[j + j * ldm];
    for (Index k = 0; k < j; ++k) d -= L[j + k * ldl] * L[j + k * ldl];
    if (!(d > 0.0)) return false;
    const double ljj = std::sqrt(d);
    const double inv = 1.0 / ljj;
    L[j + j * ldl] = ljj;
    inv_diag[j] = inv;
    for (Index i = j + 1; i < n; ++i) {
      double s = M[i + j * ldm];
      for (Index k = 0; k < j; ++k) s -= L[i + k * ldl] * L[j + k * ldl];
      L[i + j * ldl] = s * inv;
    }
  }
  return true;
}

// x ← L^{-1} x (forward substitution), x contiguous.
template <int N>
void l_solve(const double* L, Index ldl, const double* inv_diag, double* x, Index n_rt) {
  const Index n = N > 0 ? Index{N} : n_rt;
  for (Index i = 0; i < n; ++i) {
    double s = x[i];
    for (Index k = 0; k < i; ++k) s -= L[i + k * ldl] * x[k];
    x[i] = s * inv_diag[i];
  }
}

// x ← L^{-T} x (back substitution with the columns of L), x contiguous.
template <int N>
void lt_solve(const double* L, Index ldl, const double* inv_diag, double* x, Index n_rt) {
  const Index n = N > 0 ? Index{N} : n_rt;
  for (Index i = n - 1; i >= 0; --i) {
    double s = x[i];
    for (Index k = i + 1; k < n; ++k) s -= L[k + i * ldl] * x[k];
    x[i] = s * inv_diag[i];
  }
}

// The same three kernels for P blocks of one compile-time size N at once, in lockstep. One block's
// Cholesky or substitution is a chain of dependent steps (sqrt, division, multiply-adds); the
// blocks are independent, so running them side by side overlaps their latencies. Each block gets
// exactly the operations of chol_block<N> / l_solve<N> / lt_solve<N>.
template <int N, int P>
bool chol_lockstep(const std::array<const double*, P>& M, Index ldm,
                   const std::array<double*, P>& L, Index ldl,
                   const std::array<double*, P>& inv_diag) {
  for (Index j = 0; j < N; ++j) {
    double d[P], inv[P];
    bool ok = true;
    for (int p = 0; p < P; ++p) {
      double v = M[p][j + j * ldm];
      for (Index k = 0; k < j; ++k) v -= L[p][j + k * ldl] * L[p][j + k * ldl];
      d[p] = v;
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

// Calls f(std::integral_constant<int, 6>) for blocks of size 6 (the paper's arms) and
// f(std::integral_constant<int, 0>) (runtime size) for any other size.
template <typename F>
void with_block_size(Index n, F&& f) {
  if (n == 6) {
    f(std::integral_constant<int, 6>{});
  } else {
    f(std::integral_constant<int, 0>{});
  }
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

// Residual ‖A q̈ − b‖, the consistency flag and the finiteness flag (allocation-free).
void finish(const Mat& A, const Vec& b, const Vec& qdd, const Vec& Qc, const UkSettings& s,
            Vec& scratch_m, UkResult& res) {
  const Index m = A.rows(), n = A.cols();
  if (m > 0) {
    double* rr = scratch_m.data();
    const double* Ad = A.data();
    for (Index i = 0; i < m; ++i) rr[i] = -b[i];
    for (Index j = 0; j < n; ++j) {
      const double x = qdd[j];
      const double* col = Ad + j * m;
      for (Index i = 0; i < m; ++i) rr[i] += col[i] * x;
    }
    double r2 = 0.0, b2 = 0.0, q2 = 0.0;
    for (Index i = 0; i < m; ++i) r2 += rr[i] * rr[i];
    for (Index i = 0; i < m; ++i) b2 += b[i] * b[i];
    for (Index j = 0; j < n; ++j) q2 += qdd[j] * qdd[j];
    // ‖A‖_∞: the largest absolute row sum.
    for (Index i = 0; i < m; ++i) rr[i] = 0.0;
    for (Index j = 0; j < n; ++j) {
      const double* col = Ad + j * m;
      for (Index i = 0; i < m; ++i) rr[i] += std::abs(col[i]);
    }
    double a_inf = 0.0;
    for (Index i = 0; i < m; ++i) a_inf = std::max(a_inf, rr[i]);
    res.residual = std::sqrt(r2);
    const double scale = std::sqrt(b2) + a_inf * std::sqrt(q2) + 1.0;
    res.consistent = res.residual <= s.consistency_rel_tol * scale;
  }
  res.finite = all_finite(qdd.data(), qdd.size()) && all_finite(Qc.data(), Qc.size()) &&
               std::isfinite(res.residual);
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
                               {id, id + 6});
  }
  for (std::size_t k = 0; k < lay.blocks(); ++k) {
    const Index s = lay.start[k], n = lay.size[k];
    const double* Mk = M.data() + s + s * ldm;
    double* Lk = ws.L.data() + s + s * ldl;
    double* id = ws.inv_diag.data() + s;
    bool ok = false;
    with_block_size(n,
                    [&](auto N) { ok = chol_block<decltype(N)::value>(Mk, ldm, Lk, ldl, id, n); });
    if (!ok) return false;
  }
  return true;
}

namespace {

// The solve. MM > 0: m == MM is known at compile time (the loops down a column of m rows unroll
// and vectorise). NB > 0: the layout is NB blocks of size 6 at 0, 6, …, so n == 6 NB. MM == 0 /
// NB == 0: runtime sizes, any layout. Every instantiation forms the same sums in the same order
// (the fixed path also adds W's zero products and upper triangle, which change no value), so the
// results agree to rounding where the compiler contracts a different set of a·b + c into FMAs,
// e.g. with -march=native (UkSolve.FixedSizePathAgreesWithGenericPath).
template <int MM, int NB>
UkResult solve_impl(const Mat& A, const Vec& b, const Vec& Q, UkWorkspace& ws, Vec& qdd, Vec& Qc,
                    const UkSettings& settings) {
  UkResult res;
  const Index m = MM > 0 ? Index{MM} : A.rows();
  const auto& lay = ws.layout;
  const Index n = NB > 0 ? Index{6} * NB : lay.dof();
  const std::size_t nb = NB > 0 ? std::size_t{NB} : lay.blocks();
  const Index ldl = ws.L.rows();
  static_assert((MM > 0) == (NB > 0), "fixed m comes with a fixed layout");
  // y = L^{-1} Q. The unconstrained acceleration of paper Eq. (1) is a = M^{-1} Q = L^{-ᵀ} y; it is
  // never formed: A a = Xᵀ y below, and q̈ = L^{-ᵀ}(y + X λ) at the end, so each block is
  // substituted forward once and backward once.
  double* y = ws.Linv_Q.data();
  double* Xt = ws.A_Linvt.data();
  double* r = ws.r.data();
  double* W = ws.A_Minv_At.data();
  double* t = ws.tmp_m.data();
  double* lam = ws.lambda.data();
  double* rr = ws.tmp_m.data();
  Index* piv = ws.piv.data();
  for (Index j = 0; j < n; ++j) y[j] = Q[j];
  substitute_blocks<true, NB>(ws, y);
  const double* Ad = A.data();

  // Xᵀ = A L^{-ᵀ} (m × n), so that W = A M^{-1} Aᵀ = Xᵀ X with X = L^{-1} Aᵀ. Block by block, a
  // forward substitution on whole columns: Xᵀ(:, s+l) = (A(:, s+l) − Σ_{p<l} L_lp Xᵀ(:, s+p)) /
  // L_ll. Every operation runs down a contiguous column of m rows (vectorised, no dependency
  // chain). The same pass accumulates the absolute row sums of A (for ‖A‖_∞) while the column of A
  // is at hand, and r = b − A a = b − Xᵀ y, the bracket of paper Eq. (4), once a column of Xᵀ is
  // done.
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

  // W = Xᵀ X, lower triangle only: W(j:m, j) = Σ_l Xᵀ(j:m, l) Xᵀ(j, l). Constraint rows are sparse
  // (a trajectory row touches one arm, so its entries of Xᵀ in the other block are 0): zero
  // multipliers are skipped.
  const Index ldw = MM > 0 ? Index{MM} : ws.A_Minv_At.rows();
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

  // Pivoted LDLᵀ of W, i.e. a pivoted Cholesky: P W Pᵀ = L D Lᵀ where every step takes as pivot
  // the largest remaining diagonal of the Schur complement, so D is non-increasing (up to
  // round-off) and D_0 = max diag W = max D. A pivot is kept while D_k > rel_tol² · D_0; the
  // factorisation stops at the first one that is not: what remains is round-off of redundant rows,
  // and those rows get λ = 0 in the basic solution below.
  //
  // Regularized method: the same factorisation of W + μ I, μ = ε² max diag W (ε =
  // settings.regularization). Every pivot is then ≥ μ in exact arithmetic, so none is dropped
  // (the cut-off is μ/2, against round-off) and λ = (W + μ I)^{-1} r is continuous in W. The
  // reported rank counts the pivots with D_k − μ > rank_tol² (D_0 − μ), as the exact method would.
  const double tol2 = settings.rank_rel_tol * settings.rank_rel_tol;
  double mu = 0.0;
  double* dsc = ws.row_scale.data();
  const bool equilibrate = settings.method == UkMethod::equilibrated;
  if (equilibrate) {
    // Ŵ = D W D with D_ii = W_ii^{-1/2}: unit diagonal; r̂ = D r; λ = D λ̂ below.
    double w_max = 0.0;
    for (Index i = 0; i < m; ++i) w_max = std::max(w_max, W[i + i * ldw]);
    const double floor2 = settings.row_floor * settings.row_floor * w_max;
    for (Index i = 0; i < m; ++i) {
      const double wi = W[i + i * ldw];
      dsc[i] = wi > floor2 && wi > 0.0 ? 1.0 / std::sqrt(wi) : 0.0;
    }
    for (Index j = 0; j < m; ++j) {
      const double dj = dsc[j];
      double* wj = W + j * ldw;
      for (Index i = j; i < m; ++i) wj[i] *= dsc[i] * dj;
    }
  } else if (settings.method == UkMethod::regularized) {
    double w_max = 0.0;
    for (Index i = 0; i < m; ++i) w_max = std::max(w_max, W[i + i * ldw]);
    mu = settings.regularization * settings.regularization * w_max;
    for (Index i = 0; i < m; ++i) W[i + i * ldw] += mu;
  }
  double d_max = 0.0, cutoff = 0.0, d_min_kept = std::numeric_limits<double>::infinity();
  Index rank = 0, kept = 0;
  for (Index k = 0; k < m; ++k) {
    Index p = k;
    double dp = W[k + k * ldw];
    for (Index i = k + 1; i < m; ++i) {
      if (W[i + i * ldw] > dp) {
        dp = W[i + i * ldw];
        p = i;
      }
    }
    if (k == 0) {
      d_max = std::max(dp, 0.0);
      cutoff = mu > 0.0 ? 0.5 * mu : tol2 * d_max;
    }
    if (!(d_max > 0.0 && dp > cutoff)) break;
    piv[k] = p;
    if (p != k) {
      // Symmetric swap of rows/columns k and p in lower storage.
      for (Index j = 0; j < k; ++j) std::swap(W[k + j * ldw], W[p + j * ldw]);
      std::swap(W[k + k * ldw], W[p + p * ldw]);
      for (Index j = k + 1; j < p; ++j) std::swap(W[j + k * ldw], W[p + j * ldw]);
      for (Index i = p + 1; i < m; ++i) std::swap(W[i + k * ldw], W[i + p * ldw]);
    }
    const double inv_d = 1.0 / dp;
    double* colk = W + k * ldw;
    for (Index i = k + 1; i < m; ++i) {
      t[i] = colk[i];
      colk[i] *= inv_d;  // L_ik
    }
    // Schur complement, lower triangle: W_ij −= L_ik D_k L_jk.
    for (Index j = k + 1; j < m; ++j) {
      const double tj = t[j];
      double* colj = W + j * ldw;
      for (Index i = j; i < m; ++i) colj[i] -= colk[i] * tj;
    }
    if (dp - mu > tol2 * (d_max - mu)) {
      d_min_kept = std::min(d_min_kept, dp - mu);
      ++rank;
    }
    ++kept;
  }

  // Basic solution of W λ = r: λ = Pᵀ L^{-ᵀ} D⁺ L^{-1} P r. Only the leading rank × rank part of
  // L and D enters (the components past the rank are 0), so stopping early changes nothing.
  if (equilibrate) {
    for (Index i = 0; i < m; ++i) lam[i] = dsc[i] * r[i];
  } else {
    for (Index i = 0; i < m; ++i) lam[i] = r[i];
  }
  for (Index k = 0; k < kept; ++k) std::swap(lam[k], lam[piv[k]]);
  for (Index i = 0; i < kept; ++i) {
    double s = lam[i];
    for (Index k = 0; k < i; ++k) s -= W[i + k * ldw] * lam[k];
    lam[i] = s;
  }
  for (Index i = 0; i < kept; ++i) lam[i] /= W[i + i * ldw];
  for (Index i = kept; i < m; ++i) lam[i] = 0.0;
  for (Index i = kept - 1; i >= 0; --i) {
    double s = lam[i];
    const double* coli = W + i * ldw;
    for (Index k = i + 1; k < kept; ++k) s -= coli[k] * lam[k];
    lam[i] = s;
  }
  for (Index k = kept - 1; k >= 0; --k) std::swap(lam[k], lam[piv[k]]);
  if (equilibrate) {
    for (Index i = 0; i < m; ++i) lam[i] *= dsc[i];
  }

  // Qc = Aᵀ λ  (= M^{1/2}(A M^{-1/2})^+ r, paper Eq. (4));  q̈ = M^{-1}(Q + Qc), paper Eq. (18),
  // as q̈ = L^{-ᵀ}(L^{-1} Q + L^{-1} Aᵀ λ) = L^{-ᵀ}(y + X λ).
  double* qc = Qc.data();
  double* q = qdd.data();
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

  res.rank = static_cast<int>(rank);
  res.sigma_max = std::sqrt(std::max(d_max - mu, 0.0));
  res.sigma_min_kept = rank > 0 ? std::sqrt(d_min_kept) : 0.0;

  // The honest residual ‖A q̈ − b‖ of the returned q̈, and the consistency and finiteness flags
  // (as finish(), with ‖A‖_∞ from the Xᵀ pass).
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
  Vec scratch(A.rows());
  finish(A, b, qdd, Qc, settings, scratch, res);
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
