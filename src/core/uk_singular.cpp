#include "ukdyn/core/uk_singular.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "core/augmented_mass.hpp"
#include "core/dense_kernels.hpp"

namespace ukdyn {

using detail::chol_block;
using detail::with_block_size;

UkSingularWorkspace::UkSingularWorkspace(const BlockLayout& layout, Index m)
    : Ma(Mat::Zero(layout.dof(), layout.dof())),
      Qa(Vec::Zero(layout.dof())),
      scratch(Mat::Zero(layout.dof(), layout.dof())),
      row_block(static_cast<std::size_t>(m), -1),
      own_rows(layout.blocks()),
      structural(layout.blocks(), 0),
      dense(BlockLayout::single(layout.dof()), m) {}

namespace {

double max_diagonal(const Mat& M, Index s, Index n) {
  double d = 0.0;
  for (Index i = s; i < s + n; ++i) d = std::max(d, M(i, i));
  return d;
}

// Cholesky of the n × n block of M at (s, s) into L (same place); returns min pivot / max diagonal
// (≤ 0 if a pivot is not positive, NaN included).
double trial_factor(const Mat& M, Mat& L, Index s, Index n) {
  const double dmax = max_diagonal(M, s, n);
  if (!(dmax > 0.0)) return 0.0;
  double pmin = std::numeric_limits<double>::infinity();
  for (Index j = s; j < s + n; ++j) {
    double d = M(j, j);
    for (Index k = s; k < j; ++k) d -= L(j, k) * L(j, k);
    if (!(d > 0.0)) return 0.0;
    pmin = std::min(pmin, d);
    const double ljj = std::sqrt(d);
    L(j, j) = ljj;
    for (Index i = j + 1; i < s + n; ++i) {
      double v = M(i, j);
      for (Index k = s; k < j; ++k) v -= L(i, k) * L(j, k);
      L(i, j) = v / ljj;
    }
  }
  return pmin / dmax;
}

// Ma(s.., s..) += α aᵀa and Qa += α b_i aᵀ over columns [s, s + n) of row i, α = scale / ‖a‖².
bool augment_row(const Mat& A, const Vec& b, Index i, Index s, Index n, double scale, Mat& Ma,
                 Vec& Qa) {
  double nn = 0.0;
  for (Index c = s; c < s + n; ++c) nn += A(i, c) * A(i, c);
  if (!(nn > 0.0)) return false;
  const double alpha = scale / nn;
  for (Index c = s; c < s + n; ++c) {
    const double ac = alpha * A(i, c);
    if (ac == 0.0) continue;
    for (Index r = s; r < s + n; ++r) Ma(r, c) += ac * A(i, r);
    Qa(c) += ac * b(i);
  }
  return true;
}

// The n × n block at (s, s) of `from` into the same place of `to`, and segment s of n of x into y:
// plain loops (Eigen's dynamic-size block assignment peels for alignment per column, which cost
// more than the copy on a free body's 7 × 7 block).
void copy_block(const Mat& from, Mat& to, const Vec& x, Vec& y, Index s, Index n) {
  const Index ldf = from.rows(), ldt = to.rows();
  const double* f = from.data() + s + s * ldf;
  double* t = to.data() + s + s * ldt;
  for (Index j = 0; j < n; ++j)
    for (Index i = 0; i < n; ++i) t[i + j * ldt] = f[i + j * ldf];
  for (Index i = s; i < s + n; ++i) y[i] = x[i];
}

void set_nan(Vec& qdd, Vec& Qc) {
  qdd.setConstant(std::numeric_limits<double>::quiet_NaN());
  Qc.setConstant(std::numeric_limits<double>::quiet_NaN());
}

}  // namespace

bool mass_factor_regular(const Mat& /*M*/, const UkWorkspace& ws) {
  // factor_mass() recorded min_j L_jj² / max_i M_ii per block (its smallest over the blocks) while
  // it had both at hand: one compare here instead of a pass over every diagonal.
  return ws.pivot_ratio >= kSingularPivot;  // false for NaN
}

double mass_condition_estimate(const Mat& M, const UkWorkspace& ws, std::size_t* block) {
  const auto& lay = ws.layout;
  double worst = 0.0;
  for (std::size_t k = 0; k < lay.blocks(); ++k) {
    const Index s = lay.start[k], n = lay.size[k];
    double dmax = 0.0, inv_max = 0.0;
    for (Index i = s; i < s + n; ++i) {
      dmax = std::max(dmax, M(i, i));
      inv_max = std::max(inv_max, ws.inv_diag(i));
    }
    const double c = dmax * inv_max * inv_max;
    if (!(c <= worst)) {  // NaN counts as worst
      worst = c;
      if (block) *block = k;
    }
  }
  return worst;
}

UkResult uk_solve_singular(const Mat& M, const Mat& A, const Vec& b, const Vec& Q, UkWorkspace& ws,
                           UkSingularWorkspace& sw, Vec& qdd, Vec& Qc, const UkSettings& settings) {
  const auto& lay = ws.layout;
  const Index n = lay.dof(), m = A.rows();
  sw.active = true;
  sw.dense_used = false;
  sw.rank_deficient = false;
  sw.Ma = M;
  sw.Qa = Q;
  // The block of each row (−1: it spans blocks, or is zero).
  for (Index i = 0; i < m; ++i) {
    Index found = -1;
    for (std::size_t k = 0; k < lay.blocks() && found != -2; ++k) {
      const Index s = lay.start[k], nk = lay.size[k];
      for (Index c = s; c < s + nk; ++c) {
        if (A(i, c) != 0.0) {
          found = found == -1 ? static_cast<Index>(k) : -2;
          break;
        }
      }
    }
    sw.row_block[static_cast<std::size_t>(i)] = found < 0 ? -1 : found;
  }
  // Block by block: a singular block is augmented with its own rows.
  bool need_dense = false;
  for (std::size_t k = 0; k < lay.blocks() && !need_dense; ++k) {
    const Index s = lay.start[k], nk = lay.size[k];
    if (!sw.structural[k] && trial_factor(sw.Ma, sw.scratch, s, nk) >= kSingularPivot) continue;
    double scale = max_diagonal(M, s, nk);
    if (!(scale > 0.0)) scale = 1.0;
    bool added = false;
    for (Index i = 0; i < m; ++i) {
      if (sw.row_block[static_cast<std::size_t>(i)] == static_cast<Index>(k))
        added = augment_row(A, b, i, s, nk, scale, sw.Ma, sw.Qa) || added;
    }
    if (!added || !(trial_factor(sw.Ma, sw.scratch, s, nk) >= kSingularPivot)) need_dense = true;
  }
  UkResult res;
  if (!need_dense) {
    if (!factor_mass(sw.Ma, ws)) {
      res.finite = false;
      set_nan(qdd, Qc);
      return res;
    }
    sw.cond_estimate = mass_condition_estimate(sw.Ma, ws, &sw.cond_block);
    return uk_solve_factored(A, b, sw.Qa, ws, qdd, Qc, settings);
  }
  // Dense: every row augments all of M.
  sw.dense_used = true;
  sw.Ma = M;
  sw.Qa = Q;
  double scale = max_diagonal(M, 0, n);
  if (!(scale > 0.0)) scale = 1.0;
  for (Index i = 0; i < m; ++i) augment_row(A, b, i, 0, n, scale, sw.Ma, sw.Qa);
  if (!(trial_factor(sw.Ma, sw.scratch, 0, n) >= kSingularPivot) || !factor_mass(sw.Ma, sw.dense)) {
    sw.rank_deficient = true;
    res.finite = false;
    set_nan(qdd, Qc);
    return res;
  }
  sw.cond_block = 0;
  sw.cond_estimate = mass_condition_estimate(sw.Ma, sw.dense);
  return uk_solve_factored(A, b, sw.Qa, sw.dense, qdd, Qc, settings);
}

void augmented_blocks(const BlockLayout& lay, const Mat& A, const Vec& b,
                      const UkSingularWorkspace& sw, Mat& M, Vec& Q) {
  for (std::size_t k = 0; k < lay.blocks(); ++k) {
    if (!sw.structural[k]) continue;
    const Index s = lay.start[k], nk = lay.size[k];
    double scale = max_diagonal(M, s, nk);
    if (!(scale > 0.0)) scale = 1.0;
    for (const Index i : sw.own_rows[k]) augment_row(A, b, i, s, nk, scale, M, Q);
  }
}

bool augment_singular_blocks(const BlockLayout& lay, const Mat& A, const Vec& b, Mat& M, Vec& Q,
                             UkSingularWorkspace& sw) {
  for (std::size_t k = 0; k < lay.blocks(); ++k) {
    if (!sw.structural[k]) continue;
    copy_block(M, sw.scratch, Q, sw.Qa, lay.start[k], lay.size[k]);
  }
  augmented_blocks(lay, A, b, sw, M, Q);
  // A block with no row of its own stays singular. Whether the others came out positive definite
  // is read off the factor the arrow path makes next (factor_mass, mass_factor_regular: every
  // pivot against kSingularPivot of its block's largest diagonal), not from a trial factor here.
  bool ok = true;
  for (std::size_t k = 0; k < lay.blocks() && ok; ++k)
    ok = !sw.structural[k] || !sw.own_rows[k].empty();
  if (!ok) restore_singular_blocks(lay, M, Q, sw);
  return ok;
}

namespace {

// The lower triangle of block (s, s) of M + A_kᵀ α A_k over the rows `rows` into the same place of
// `out`, and Q_a's segment into Qa (which holds Q there on entry): augment_row's sums in its order
// (every product added, as there), on the entries a Cholesky factor reads.
template <int N>
void augmented_lower(const Mat& M, const Mat& A, const Vec& b, const std::vector<Index>& rows,
                     Index s, Index n_rt, Mat& out, Vec& Qa) {
  const Index n = N > 0 ? Index{N} : n_rt;
  const Index ldm = M.rows(), ldo = out.rows(), lda = A.rows();
  const double* Mk = M.data() + s + s * ldm;
  double* Ok = out.data() + s + s * ldo;
  double scale = 0.0;
  UKDYN_UNROLL
  for (Index j = 0; j < n; ++j) {
    scale = std::max(scale, Mk[j + j * ldm]);
    UKDYN_UNROLL
    for (Index i = j; i < n; ++i) Ok[i + j * ldo] = Mk[i + j * ldm];
  }
  if (!(scale > 0.0)) scale = 1.0;
  for (const Index r : rows) {
    const double* a = A.data() + r + s * lda;  // row r on the block's columns, stride lda
    double nn = 0.0;
    UKDYN_UNROLL
    for (Index c = 0; c < n; ++c) nn += a[c * lda] * a[c * lda];
    if (!(nn > 0.0)) continue;
    const double alpha = scale / nn;
    UKDYN_UNROLL
    for (Index c = 0; c < n; ++c) {
      const double ac = alpha * a[c * lda];
      if (ac == 0.0) continue;
      UKDYN_UNROLL
      for (Index i = c; i < n; ++i) Ok[i + c * ldo] += ac * a[i * lda];
      Qa[s + c] += ac * b[r];
    }
  }
}

}  // namespace

bool detail::factor_augmented_mass(const BlockLayout& lay, const Mat& M, const Mat& A, const Vec& b,
                                   const Vec& Q, UkSingularWorkspace& sw, UkWorkspace& ws,
                                   MassCondition& cond) {
  const Index n = lay.dof();
  for (Index i = 0; i < n; ++i) sw.Qa[i] = Q[i];
  const Index ldm = M.rows(), ldl = ws.L.rows(), ldsc = sw.scratch.rows();
  double ratio = std::numeric_limits<double>::infinity();
  cond = MassCondition{};
  for (std::size_t k = 0; k < lay.blocks(); ++k) {
    const Index s = lay.start[k], nk = lay.size[k];
    const bool augment = sw.structural[k] != 0;
    if (augment && sw.own_rows[k].empty()) return false;  // stays singular: the dense solve
    double* Lk = ws.L.data() + s + s * ldl;
    double* id = ws.inv_diag.data() + s;
    bool ok = false;
    double block_ratio = 0.0, c = 0.0;
    with_block_size(nk, [&](auto N) {
      constexpr int NN = decltype(N)::value;
      const double* Mk = M.data() + s + s * ldm;
      Index ld = ldm;
      if (augment) {
        augmented_lower<NN>(M, A, b, sw.own_rows[k], s, nk, sw.scratch, sw.Qa);
        Mk = sw.scratch.data() + s + s * ldsc;
        ld = ldsc;
      }
      ok = chol_block<NN>(Mk, ld, Lk, ldl, id, nk, &block_ratio);
      if (!ok) return;
      // mass_condition_estimate()'s measure of this block, in its order.
      const Index nb = NN > 0 ? Index{NN} : nk;
      double dmax = 0.0, inv_max = 0.0;
      for (Index i = 0; i < nb; ++i) {
        dmax = std::max(dmax, Mk[i + i * ld]);
        inv_max = std::max(inv_max, id[i]);
      }
      c = dmax * inv_max * inv_max;
    });
    if (!ok) return false;
    ratio = std::min(ratio, block_ratio);
    if (!(c <= cond.estimate)) {  // NaN counts as worst
      cond.estimate = c;
      cond.block = k;
    }
  }
  ws.pivot_ratio = ratio;
  return true;
}

void restore_singular_blocks(const BlockLayout& lay, Mat& M, Vec& Q,
                             const UkSingularWorkspace& sw) {
  for (std::size_t k = 0; k < lay.blocks(); ++k) {
    if (!sw.structural[k]) continue;
    copy_block(sw.scratch, M, sw.Qa, Q, lay.start[k], lay.size[k]);
  }
}

std::string undetermined_direction(const Mat& M, const Mat& A,
                                   const std::vector<std::string>& names) {
  const Index n = M.rows();
  if (n == 0) return {};
  if (!M.allFinite() || !A.allFinite())
    return "the mass matrix or the constraint matrix is not finite";
  Mat Ma = 0.5 * (M + M.transpose());
  double scale = Ma.diagonal().maxCoeff();
  if (!(scale > 0.0)) scale = 1.0;
  for (Index i = 0; i < A.rows(); ++i) {
    const double nn = A.row(i).squaredNorm();
    if (nn > 0.0) Ma += (scale / nn) * A.row(i).transpose() * A.row(i);
  }
  Eigen::SelfAdjointEigenSolver<Mat> es(Ma);
  const double lmin = es.eigenvalues()(0), lmax = es.eigenvalues()(n - 1);
  if (lmin >= kSingularPivot * std::max(lmax, 0.0) && lmax > 0.0) return {};
  const Vec v = es.eigenvectors().col(0);
  const double vmax = v.cwiseAbs().maxCoeff();
  std::ostringstream os;
  os.precision(3);
  os << "[M; A] does not have full column rank (M + A^T alpha A has smallest eigenvalue " << lmin
     << " of largest " << lmax
     << "): the mass matrix is singular and no constraint fixes the direction in coordinates [";
  bool first = true;
  for (Index i = 0; i < n; ++i) {
    if (std::abs(v(i)) >= 0.3 * vmax && static_cast<std::size_t>(i) < names.size()) {
      os << (first ? "" : ", ") << names[static_cast<std::size_t>(i)];
      first = false;
    }
  }
  os << "]: the motion is not determined";
  return os.str();
}

}  // namespace ukdyn
