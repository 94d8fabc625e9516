#include "ukdyn/core/uk_arrow.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <type_traits>
#include <utility>

#include "core/dense_kernels.hpp"

namespace ukdyn {

std::optional<ArrowStructure> detect_arrow(const BlockLayout& layout,
                                           const std::vector<std::vector<Index>>& row_blocks,
                                           std::size_t min_groups) {
  // The load: the block common to every row that couples two blocks.
  std::vector<Index> common;  // candidates (at most 2)
  bool any_pair = false;
  for (const auto& rb : row_blocks) {
    if (rb.empty() || rb.size() > 2) return std::nullopt;
    if (rb.size() != 2) continue;
    if (!any_pair) {
      common = rb;
      any_pair = true;
      continue;
    }
    std::vector<Index> keep;
    for (const Index c : common)
      if (c == rb[0] || c == rb[1]) keep.push_back(c);
    common = std::move(keep);
    if (common.empty()) return std::nullopt;
  }
  ArrowStructure s;
  if (any_pair) s.load_block = common.back();  // with a single coupled pair: the later block
  if (s.load_block >= 0) {
    s.load_start = layout.start[static_cast<std::size_t>(s.load_block)];
    s.load_size = layout.size[static_cast<std::size_t>(s.load_block)];
  }
  std::vector<Index> group_of(layout.blocks(), -1);
  std::size_t coupled = 0;
  for (std::size_t i = 0; i < row_blocks.size(); ++i) {
    const auto& rb = row_blocks[i];
    Index robot = -1;
    for (const Index blk : rb)
      if (blk != s.load_block) robot = blk;
    if (robot < 0) {
      s.load_rows.push_back(static_cast<Index>(i));
      continue;
    }
    auto& gi = group_of[static_cast<std::size_t>(robot)];
    if (gi < 0) {
      gi = static_cast<Index>(s.groups.size());
      ArrowStructure::Group g;
      g.block = robot;
      g.start = layout.start[static_cast<std::size_t>(robot)];
      g.size = layout.size[static_cast<std::size_t>(robot)];
      s.groups.push_back(std::move(g));
    }
    s.groups[static_cast<std::size_t>(gi)].rows.push_back(static_cast<Index>(i));
  }
  for (const auto& g : s.groups) {
    for (const Index r : g.rows) {
      if (row_blocks[static_cast<std::size_t>(r)].size() == 2) {
        ++coupled;
        break;
      }
    }
  }
  if (coupled < min_groups) return std::nullopt;
  return s;
}

ArrowWorkspace::ArrowWorkspace(const ArrowStructure& st, Index m) {
  const Index nL = st.load_size;
  Index mD = static_cast<Index>(st.load_rows.size());
  for (const auto& grp : st.groups) {
    const Index mk = static_cast<Index>(grp.rows.size()), nk = grp.size;
    GroupBuffers gb;
    gb.B = Mat::Zero(mk, nk);
    gb.C = Mat::Zero(mk, nL);
    gb.Xt = Mat::Zero(mk, nk);
    gb.S = Mat::Zero(mk, mk);
    gb.T = Mat::Zero(mk, nL);
    gb.r = Vec::Zero(mk);
    gb.bb = Vec::Zero(mk);
    gb.z = Vec::Zero(mk);
    gb.w = Vec::Zero(std::max(mk, nk));
    gb.lam = Vec::Zero(mk);
    gb.piv.assign(static_cast<std::size_t>(mk), 0);
    g.push_back(std::move(gb));
    mD += mk;
  }
  H = Mat::Zero(nL, nL);
  gL = Vec::Zero(nL);
  qddL = Vec::Zero(nL);
  Dt = Mat::Zero(mD, nL);
  d = Vec::Zero(mD);
  WD = Mat::Zero(mD, mD);
  rD = Vec::Zero(mD);
  lamD = Vec::Zero(mD);
  tmp = Vec::Zero(std::max(mD, nL));
  pivD.assign(static_cast<std::size_t>(mD), 0);
  d_from.assign(static_cast<std::size_t>(mD), {0, 0});
  lambda = Vec::Zero(m);
  built_ = true;
}

namespace {

// Every rank decision here is the pivoted LDLᵀ of dense_kernels.hpp with its rank rule, on the
// scale of the whole W = A M⁻¹Aᵀ (RankRule::scale = max diag W): the dense solve's decision.
using detail::LdltPivots;
using detail::pivoted_ldlt;
using detail::RankRule;

// The lower triangle of G = X Xᵀ for the leading rows × cols of X (a Gram matrix: S, W_D).
void lower_gram(const Mat& X, Index rows, Index cols, Mat& G) {
  for (Index j = 0; j < rows; ++j)
    for (Index i = j; i < rows; ++i) {
      double v = 0.0;
      for (Index l = 0; l < cols; ++l) v += X(i, l) * X(j, l);
      G(i, j) = v;
    }
}

// What every step of uk_solve_arrow reads: the problem, the robots' Cholesky factors (the dense
// workspace's L, 1/L_ii) and the arrow workspace the steps write.
struct ArrowProblem {
  const ArrowStructure& st;
  const Mat& M;
  const Mat& A;
  const Vec& b;
  const Vec& Q;
  const UkWorkspace& dws;
  ArrowWorkspace& ws;
  Index sL, nL, ldl;
  const double* Ld;
  const double* idg;
  double tol2;

  ArrowProblem(const ArrowStructure& st_, const Mat& M_, const Mat& A_, const Vec& b_,
               const Vec& Q_, const UkWorkspace& dws_, ArrowWorkspace& ws_,
               const UkSettings& settings)
      : st(st_),
        M(M_),
        A(A_),
        b(b_),
        Q(Q_),
        dws(dws_),
        ws(ws_),
        sL(st_.load_start),
        nL(st_.load_size),
        ldl(dws_.L.rows()),
        Ld(dws_.L.data()),
        idg(dws_.inv_diag.data()),
        tol2(settings.rank_rel_tol * settings.rank_rel_tol) {}
  // The rank rule on the scale of the whole W (w_ref = max diag W, reduce_groups).
  [[nodiscard]] RankRule rule(double w_ref) const { return RankRule{tol2, 0.0, w_ref}; }
  // Whether a piece factored on the scale lo (≤ max diag W) made the decisions it makes on any
  // scale up to hi (≥ max diag W): every kept pivot above τ² max(D_0, hi). The stop, if any, was
  // at a pivot under τ² max(D_0, lo), under the larger scale's cut-off too (RankScale).
  [[nodiscard]] bool same_decisions(const LdltPivots& pv, double hi) const {
    return pv.kept == 0 || pv.d_min_kept > tol2 * std::max(pv.d_max, hi);
  }
  // x ← L_L⁻¹ x with the load's own factor (M_L = L_L L_Lᵀ); NL: the load's size if fixed.
  template <int NL>
  void load_l_solve(double* x) const {
    detail::l_solve<NL>(Ld + sL + sL * ldl, ldl, idg + sL, x, nL);
  }
  // |L_L⁻¹ c|² for row i of A on the load's columns (its part of a diagonal entry of A M⁻¹Aᵀ).
  template <int NL>
  double load_part_of_w(Index i) const {
    const Index n = NL > 0 ? Index{NL} : nL, lda = A.rows();
    const double* a = A.data() + i + sL * lda;
    double* x = ws.tmp.data();
    for (Index j = 0; j < n; ++j) x[j] = a[j * lda];
    double c2 = 0.0;
    if (n > 0) {
      load_l_solve<NL>(x);
      for (Index j = 0; j < n; ++j) c2 += x[j] * x[j];
    }
    return c2;
  }
};

// The scale of the rank decisions, max diag W with W_ii = S_ii + |L_L⁻¹ C_iᵀ|² (the dense solve's,
// dense_kernels.hpp), between bounds: lo = max_i S_ii ≤ max diag W ≤ hi = max_i (S_ii + F |C_i|²),
// F twice ‖L_L⁻¹‖_F² ≥ ‖M_L⁻¹‖₂ (|L_L⁻¹ c|² ≤ ‖L_L⁻¹‖₂² |c|²; the factor 2 covers the round-off of
// both sides). The pieces are factored on lo; when every decision is the same on any scale up to
// hi (ArrowProblem::same_decisions: a pivot would have to lie within τ² of the scale), they are
// the decisions on max diag W itself, which is then never formed; otherwise the solve is redone
// with the exact scale (lo = hi = max diag W, each C_i L_L^{-ᵀ} formed).
struct RankScale {
  double lo = 0.0, hi = 0.0;
  bool exact = false;
  void add(double lo_i, double hi_i) {
    lo = std::max(lo, lo_i);
    hi = std::max(hi, hi_i);
  }
};

// 2 ‖L⁻¹‖_F² = 2 trace(M⁻¹) for M = L Lᵀ (n × n lower factor L, leading dimension ldl, 1/L_ii in
// inv_diag): column j of L⁻¹ by forward substitution from row j down. x: scratch of n.
template <int N>
double twice_inverse_frobenius2(const double* L, Index ldl, const double* inv_diag, double* x,
                                Index n_rt) {
  const Index n = N > 0 ? Index{N} : n_rt;
  double f = 0.0;
  UKDYN_UNROLL
  for (Index j = 0; j < n; ++j) {
    UKDYN_UNROLL
    for (Index i = j; i < n; ++i) {
      double v = i == j ? 1.0 : 0.0;
      UKDYN_UNROLL
      for (Index k = j; k < i; ++k) v -= L[i + k * ldl] * x[k];
      x[i] = v * inv_diag[i];
      f += x[i] * x[i];
    }
  }
  return 2.0 * f;
}

// The same on a fixed size N, L⁻¹ row by row (the rows of L⁻¹ L = I, forward substitution on
// whole rows): row i = (e_i − Σ_{k<i} L_ik row k) / L_ii, row k held in the k + 1 entries rounded
// up to even (the entries past k are 0), each as 16-byte pairs. Entry (i, j) gets the operations of
// the column loop above in their order, plus, for k < j, the subtraction of L_ik · 0 (which leaves
// it as it is); the squares are summed pairwise, so F differs from the column loop's in its last
// bits (F only bounds the scale, RankScale: the factor 2 covers that).
template <int N>
constexpr int kInverseStride = (N + 1) & ~1;
template <int K>
[[gnu::always_inline]] inline void sub_inverse_row(double* v, const double* xk, double l) {
  using Seg = Eigen::Matrix<double, (K + 2) & ~1, 1>;
  Eigen::Map<Seg, Eigen::Aligned16>(v) -= l * Eigen::Map<const Seg, Eigen::Aligned16>(xk);
}
template <int N, int I, std::size_t... K>
[[gnu::always_inline]] inline void inverse_row(const double* L, Index ldl, const double* inv_diag,
                                               double (*x)[kInverseStride<N>],
                                               Eigen::Matrix<double, kInverseStride<N>, 1>& f2,
                                               std::index_sequence<K...> /*rows above*/) {
  using Row = Eigen::Matrix<double, kInverseStride<N>, 1>;
  alignas(16) double v[kInverseStride<N>] = {};
  v[I] = 1.0;
  (sub_inverse_row<static_cast<int>(K)>(v, x[K], L[I + static_cast<Index>(K) * ldl]), ...);
  const Row r = Eigen::Map<const Row, Eigen::Aligned16>(v) * inv_diag[I];
  Eigen::Map<Row, Eigen::Aligned16> xi(x[I]);
  xi = r;
  f2 += r.cwiseProduct(r);
}
template <int N, std::size_t... I>
double twice_inverse_frobenius2_rows(const double* L, Index ldl, const double* inv_diag,
                                     std::index_sequence<I...> /*rows*/) {
  alignas(16) double x[N][kInverseStride<N>] = {};
  Eigen::Matrix<double, kInverseStride<N>, 1> f2 =
      Eigen::Matrix<double, kInverseStride<N>, 1>::Zero();
  (inverse_row<N, static_cast<int>(I)>(L, ldl, inv_diag, x, f2, std::make_index_sequence<I>{}),
   ...);
  return 2.0 * f2.sum();
}
template <int N>
double twice_inverse_frobenius2_fixed(const double* L, Index ldl, const double* inv_diag, double* x,
                                      Index n_rt) {
  if constexpr (N > 0) {
    return twice_inverse_frobenius2_rows<N>(L, ldl, inv_diag, std::make_index_sequence<N>{});
  } else {
    return twice_inverse_frobenius2<N>(L, ldl, inv_diag, x, n_rt);
  }
}

// The rank decisions' pivots: the number kept and the largest and smallest kept.
struct ArrowPivots {
  Index rank = 0;
  double max = 0.0, min = std::numeric_limits<double>::infinity();
  void add(const LdltPivots& pv) {
    rank += pv.rank;
    if (pv.rank > 0) {
      max = std::max(max, pv.d_max);
      min = std::min(min, pv.d_min_kept);
    }
  }
};

// Compile-time sizes. Every step below is a template on the robots' block size NK, their rows MK
// and the load's block size NL; 0 stands for the runtime size (any shape). The shape of two or
// more 7-joint arms on x, y, yaw platforms welded to a free body (n_k = 10, m_k = 6, n_L = 7,
// docs/performance.md, "Two Pandas welded to a plate") runs with all three fixed, so the loops
// unroll into fixed-length vector operations, as solve_impl<MM, NB> does for the paper's shapes
// (uk_solve.cpp). Both instantiations do the same operations in the same order. The triangular
// loops carry UKDYN_UNROLL (`#pragma GCC unroll 16`, dense_kernels.hpp), and the sums that ran
// through pointers the compiler could not tell apart run on fixed-size Eigen vectors: neither
// changes an operation or its order (docs/performance.md, "Unrolled triangular loops").
template <int NK, int MK, int NL>
struct ArrowSizes {
  Index mk, nk, nL;
  ArrowSizes(const ArrowProblem& P, std::size_t gi)
      : mk(MK > 0 ? Index{MK} : static_cast<Index>(P.st.groups[gi].rows.size())),
        nk(NK > 0 ? Index{NK} : P.st.groups[gi].size),
        nL(NL > 0 ? Index{NL} : P.nL) {}
};

// Robot k's rows of A on its own columns (B) and on the load's (C), column j at B + j ld: on the
// fixed shape with the group's rows consecutive in A (a weld's 6) A's own columns (ld = A's rows,
// nothing copied), else the group's buffers that reduce_group gathers them into (ld = m_k).
struct GroupColumns {
  const double* B;
  const double* C;
  Index ld;
};
template <int MK>
bool rows_in_place(const ArrowProblem& P, std::size_t gi) {
  if constexpr (MK > 0) {
    const Index* rows = P.st.groups[gi].rows.data();
    return rows[MK - 1] - rows[0] == MK - 1;
  }
  return false;
}
template <int MK>
GroupColumns group_columns(const ArrowProblem& P, std::size_t gi) {
  const auto& gb = P.ws.g[gi];
  if (rows_in_place<MK>(P, gi)) {
    const Index lda = P.A.rows();
    const double* a = P.A.data() + P.st.groups[gi].rows[0];
    return {a + P.st.groups[gi].start * lda, a + P.sL * lda, lda};
  }
  return {gb.B.data(), gb.C.data(), gb.B.rows()};
}

// A buffer of Eigen's storage (aligned to EIGEN_MAX_ALIGN_BYTES ≥ 16 with SSE2) with columns of
// m_k rows: on the fixed shape with m_k even every column and every pair of rows from an even row
// is 16-byte aligned, so the products on them take their operands from memory without a separate
// unaligned load (reduce_group's Xᵀ).
template <int MK>
double* aligned_columns(double* p) {
  if constexpr (MK > 0 && MK % 2 == 0 && EIGEN_MAX_ALIGN_BYTES >= 16)
    return static_cast<double*>(__builtin_assume_aligned(p, 16));
  return p;
}

// Robot k's rows of A: B (its columns), C (the load's), b; then Xᵀ = B L_k^{-ᵀ} column by column,
// y = L_k⁻¹ Q_k, r = b − Xᵀ y (= b − B M_k⁻¹ Q_k) and S = Xᵀ X (lower) = B M_k⁻¹ Bᵀ. Adds the
// group's rows to the rank scale w (RankScale: with w.exact W_ii = S_ii + |L_L⁻¹ C_iᵀ|², T holding
// the rows C_i L_L^{-ᵀ} as scratch; else the bounds S_ii and S_ii + F |C_i|²). Every loop runs down
// a column of m_k rows.
template <int NK, int MK, int NL>
[[gnu::always_inline]] inline void reduce_group(const ArrowProblem& P, std::size_t gi, double F,
                                                RankScale& w) {
  const auto& grp = P.st.groups[gi];
  auto& gb = P.ws.g[gi];
  const ArrowSizes<NK, MK, NL> z(P, gi);
  const Index mk = z.mk, nk = z.nk, nL = z.nL, s = grp.start, lda = P.A.rows();
  const double* Lk = P.Ld + s + s * P.ldl;
  const double* id = P.idg + s;
  double* Xt = aligned_columns<MK>(gb.Xt.data());
  double* Y = gb.T.data();
  const double* Ad = P.A.data();
  const Index* rows = grp.rows.data();
  // B and C gathered column by column, unless the rows are consecutive in A (group_columns).
  if (!rows_in_place<MK>(P, gi)) {
    double* B = gb.B.data();
    double* C = gb.C.data();
    for (Index j = 0; j < nk; ++j)
      for (Index i = 0; i < mk; ++i) B[i + j * mk] = Ad[rows[i] + (s + j) * lda];
    for (Index j = 0; j < nL; ++j)
      for (Index i = 0; i < mk; ++i) C[i + j * mk] = Ad[rows[i] + (P.sL + j) * lda];
  }
  const GroupColumns bc = group_columns<MK>(P, gi);
  for (Index i = 0; i < mk; ++i) gb.bb[i] = P.b[rows[i]];
  double* y = gb.w.data();
  for (Index j = 0; j < nk; ++j) y[j] = P.Q[s + j];
  detail::l_solve<NK>(Lk, P.ldl, id, y, nk);
  // Xᵀ(:, l) = (B(:, l) − Σ_{p<l} L_lp Xᵀ(:, p)) / L_ll; the same for C and the load's factor.
  // MK > 0: each column a fixed-size vector (the same operations, element by element, in
  // registers).
  auto forward_columns = [mk, ld = MK > 0 ? bc.ld : mk](auto N, const double* L, Index ldl,
                                                        const double* inv, const double* in,
                                                        double* out, Index n) {
    if constexpr (MK > 0 && decltype(N)::value > 0) {
      using Col = Eigen::Matrix<double, MK, 1>;
      UKDYN_UNROLL
      for (Index l = 0; l < decltype(N)::value; ++l) {
        Col c = Eigen::Map<const Col>(in + l * ld);
        UKDYN_UNROLL
        for (Index p = 0; p < l; ++p) c -= L[l + p * ldl] * Eigen::Map<const Col>(out + p * MK);
        Eigen::Map<Col>(out + l * MK) = c * inv[l];
      }
      return;
    }
    for (Index l = 0; l < n; ++l) {
      double col[MK > 0 ? MK : 1];
      double* c = MK > 0 ? col : out + l * mk;
      for (Index i = 0; i < mk; ++i) c[i] = in[i + l * ld];
      for (Index p = 0; p < l; ++p) {
        const double lp = L[l + p * ldl];
        for (Index i = 0; i < mk; ++i) c[i] -= lp * out[i + p * mk];
      }
      for (Index i = 0; i < mk; ++i) out[i + l * mk] = c[i] * inv[l];
    }
  };
  forward_columns(std::integral_constant<int, NK>{}, Lk, P.ldl, id, bc.B, Xt, nk);
  if (w.exact)
    forward_columns(std::integral_constant<int, NL>{}, P.Ld + P.sL + P.sL * P.ldl, P.ldl,
                    P.idg + P.sL, bc.C, Y, nL);
  double* r = gb.r.data();
  if constexpr (MK > 0) {
    using Col = Eigen::Matrix<double, MK, 1>;
    Col rv = gb.bb.template head<MK>();
    for (Index l = 0; l < nk; ++l) rv -= Eigen::Map<const Col>(Xt + l * mk) * y[l];
    Eigen::Map<Col> r_out(r);
    r_out = rv;
  } else {
    for (Index i = 0; i < mk; ++i) r[i] = gb.bb[i];
    for (Index l = 0; l < nk; ++l)
      for (Index i = 0; i < mk; ++i) r[i] -= Xt[i + l * mk] * y[l];
  }
  double* S = gb.S.data();
  const Index lds = MK > 0 ? Index{MK} : gb.S.rows();
  // Each row's part of the rank scale (RankScale): exact, |L_L⁻¹ C_iᵀ|² (down Y's columns, each
  // row's terms in the order of l as one row at a time); else |C_i|², down C's columns.
  double c2v[MK > 0 ? MK : 1] = {};
  if constexpr (MK > 0) {
    using Col = Eigen::Matrix<double, MK, 1>;
    Eigen::Map<Col> c2m(c2v);
    const Index ldc = w.exact ? mk : bc.ld;
    const double* X = w.exact ? Y : bc.C;
    for (Index l = 0; l < nL; ++l) {
      const Eigen::Map<const Col> yl(X + l * ldc);
      c2m += yl.cwiseProduct(yl);
    }
  }
  UKDYN_UNROLL
  for (Index j = 0; j < mk; ++j) {
    double acc[MK > 0 ? MK : 1] = {};
    double* a = MK > 0 ? acc : S + j * lds;
    if constexpr (MK == 0)
      for (Index i = j; i < mk; ++i) a[i] = 0.0;
    // MK > 0: the rows from j rounded down to even, so that columns 2t and 2t + 1 run on the same
    // whole pairs of rows (vectorised) and the rows above the diagonal are mostly not formed.
    const Index i0 = MK > 0 ? (j & ~Index{1}) : j;
    for (Index l = 0; l < nk; ++l) {
      const double xj = Xt[j + l * mk];
      UKDYN_UNROLL
      for (Index i = i0; i < mk; ++i) a[i] += Xt[i + l * mk] * xj;
    }
    if constexpr (MK > 0) {
      UKDYN_UNROLL
      for (Index i = j; i < mk; ++i) S[i + j * lds] = a[i];
    }
    double c2 = 0.0;
    if constexpr (MK > 0) {
      c2 = c2v[j];
    } else if (w.exact) {
      for (Index l = 0; l < nL; ++l) c2 += Y[j + l * mk] * Y[j + l * mk];
    } else {
      for (Index l = 0; l < nL; ++l) c2 += bc.C[j + l * mk] * bc.C[j + l * mk];
    }
    const double sjj = S[j + j * lds];
    if (w.exact) {
      w.add(sjj + c2, sjj + c2);
    } else {
      w.add(sjj, sjj + F * c2);
    }
  }
}

// H = M_L, g = Q_L (the load's own inertia and forces, lower triangle), every robot's rows reduced;
// returns the scale of every rank decision below, max diag W of W = A M⁻¹Aᵀ (W_ii = S_ii +
// C_i M_L⁻¹ C_iᵀ, as the dense solve's): itself (exact) or between bounds (RankScale).
template <int NK, int MK, int NL>
RankScale reduce_groups(const ArrowProblem& P, bool exact) {
  auto& ws = P.ws;
  const Index nL = NL > 0 ? Index{NL} : P.nL;
  const Index ldm = P.M.rows(), ldh = NL > 0 ? Index{NL} : ws.H.rows();
  const double* ML = P.M.data() + P.sL + P.sL * ldm;
  double* H = ws.H.data();
  UKDYN_UNROLL
  for (Index j = 0; j < nL; ++j) {
    UKDYN_UNROLL
    for (Index i = j; i < nL; ++i) H[i + j * ldh] = ML[i + j * ldm];
    ws.gL[j] = P.Q[P.sL + j];
  }
  RankScale w;
  w.exact = exact;
  const double F = exact || nL == 0
                       ? 0.0
                       : twice_inverse_frobenius2_fixed<NL>(P.Ld + P.sL + P.sL * P.ldl, P.ldl,
                                                            P.idg + P.sL, ws.tmp.data(), nL);
  for (std::size_t gi = 0; gi < P.st.groups.size(); ++gi) reduce_group<NK, MK, NL>(P, gi, F, w);
  const Index lda = P.A.rows();
  for (const Index row : P.st.load_rows) {
    if (exact) {
      const double c2 = P.load_part_of_w<NL>(row);
      w.add(c2, c2);
    } else {
      const double* a = P.A.data() + row + P.sL * lda;
      double c2 = 0.0;
      for (Index j = 0; j < nL; ++j) c2 += a[j * lda] * a[j * lda];
      w.add(0.0, F * c2);
    }
  }
  return w;
}

// The kept count of a group's rows as a compile-time constant when every row is kept on a fixed
// shape (KP = MK), else at run time (KP = 0): the loops whose bounds are the kept count then unroll
// too. Both do the same operations in the same order.
template <int MK, typename F>
void with_kept(Index kept, F&& f) {
  if constexpr (MK > 0) {
    if (kept == MK) {
      f(std::integral_constant<int, MK>{});
      return;
    }
  }
  f(std::integral_constant<int, 0>{});
}

// H += Σ_kept T_iᵀ t_i and g += Σ_kept t_iᵀ z_i with t_i = T_i / D_i (C1ᵀ S11⁻¹ C1 and
// C1ᵀ S11⁻¹ r1; T transposed, row i at T + i n_L), lower triangle. Column jj of H from row jj down is
// one fixed-size vector of n_L − jj entries: loaded once, every kept row's term added in the order
// of the rows (each entry the sum it was with the rows outer), stored once.
template <int NL, int JJ>
void add_column_to_h(double* H, const double* T, const double* t, Index kp) {
  using Col = Eigen::Matrix<double, NL - JJ, 1>;
  Eigen::Map<Col> h(H + JJ + JJ * NL);
  Col acc = h;
  for (Index i = 0; i < kp; ++i) acc += Eigen::Map<const Col>(T + JJ + i * NL) * t[JJ + i * NL];
  h = acc;
}
template <int NL, std::size_t... JJ>
void add_columns_to_h(double* H, const double* T, const double* t, Index kp,
                      std::index_sequence<JJ...> /*columns*/) {
  (add_column_to_h<NL, static_cast<int>(JJ)>(H, T, t, kp), ...);
}

// Robot k's rows onto the load: pivoted LDLᵀ of S (pivots under rank_rel_tol² · max diag W
// dropped); H += C1ᵀ S11⁻¹ C1, g += C1ᵀ S11⁻¹ r1; the dropped rows become rows D, d on the load
// (appended at mD, which is returned advanced). Runtime sizes; eliminate_rows_fixed below is the
// fixed shape's.
template <int NK, int MK, int NL>
Index eliminate_rows(const ArrowProblem& P, std::size_t gi, Index mD) {
  auto& ws = P.ws;
  auto& gb = ws.g[gi];
  const ArrowSizes<NK, MK, NL> sz(P, gi);
  const Index nL = sz.nL, mk = sz.mk;
  const Index kp = gb.kept;
  const double* S = gb.S.data();  // the factors L (below the diagonal) and D of S_k
  const Index lds = MK > 0 ? Index{MK} : gb.S.rows();
  // The same row order for C (into T), r and b (into z, lam as scratch). T is kept transposed in
  // its buffer (row i at T + i n_L, contiguous), so the row operations below, the rank-1 updates
  // of H and the products with q̈_L (group_multipliers) run down contiguous memory.
  double* T = gb.T.data();
  const double* C = gb.C.data();
  for (Index i = 0; i < mk; ++i)
    for (Index j = 0; j < nL; ++j) T[j + i * nL] = C[i + j * mk];
  for (Index i = 0; i < mk; ++i) gb.z[i] = gb.r[i];
  for (Index i = 0; i < mk; ++i) gb.lam[i] = gb.bb[i];
  for (Index k = 0; k < kp; ++k) {
    const Index p = gb.piv[static_cast<std::size_t>(k)];
    if (p != k)
      for (Index j = 0; j < nL; ++j) std::swap(T[j + k * nL], T[j + p * nL]);
    std::swap(gb.z[k], gb.z[p]);
    std::swap(gb.lam[k], gb.lam[p]);
  }
  // Kept rows: T1 = L11⁻¹ C1, z = L11⁻¹ r1, lam1 = L11⁻¹ b1 (unit lower). Dropped rows i: the
  // combinations e_i = row_i − L21 L11⁻¹ (kept rows): T_i = e_i C, lam_i = e_i b (no robot part).
  for (Index i = 1; i < mk; ++i) {
    const Index pe = std::min(i, kp);
    for (Index p = 0; p < pe; ++p) {
      const double l = S[i + p * lds];
      if (l == 0.0) continue;
      for (Index j = 0; j < nL; ++j) T[j + i * nL] -= l * T[j + p * nL];
      if (i < kp) gb.z[i] -= l * gb.z[p];
      gb.lam[i] -= l * gb.lam[p];
    }
  }
  // H += Σ_kept T_iᵀ T_i / D_i,  g += Σ_kept T_iᵀ z_i / D_i (C1ᵀ S11⁻¹ C1 and C1ᵀ S11⁻¹ r1), the
  // rows outer, a term with T_i(jj) = 0 skipped.
  double* H = ws.H.data();
  const Index ldh = ws.H.rows();
  for (Index i = 0; i < kp; ++i) {
    const double inv = 1.0 / S[i + i * lds];
    for (Index jj = 0; jj < nL; ++jj) {
      const double tj = T[jj + i * nL] * inv;
      if (tj == 0.0) continue;
      for (Index ii = jj; ii < nL; ++ii) H[ii + jj * ldh] += T[ii + i * nL] * tj;
      ws.gL[jj] += tj * gb.z[i];
    }
  }
  for (Index i = kp; i < mk; ++i) {
    for (Index j = 0; j < nL; ++j) ws.Dt(mD, j) = T[j + i * nL];
    ws.d[mD] = gb.lam[i];
    ws.d_from[static_cast<std::size_t>(mD)] = {static_cast<Index>(gi), i};
    ++mD;
  }
  return mD;
}

// The same on the fixed shape (n_L = NL, m_k = MK), KP the kept count when it is MK (with_kept),
// else 0 (at run time). Each row of T is formed in registers: C's row in the pivoted order (the
// transpositions applied to the row indices, not to the rows), less l_ip T_p of the rows before
// it, stored once; for a kept row t_i = T_i / D_i and g += t_i z_i at once; then H column by
// column (add_columns_to_h). Every entry gets the operations of eliminate_rows in their order,
// except that H's and g's terms are added when t_i(jj) = 0 too, and, with every row kept (KP > 0),
// the terms l_ip T_p when l_ip = 0 too (neither changes more than the sign of a zero; no branch).
template <int MK, int NL, int KP>
Index eliminate_rows_fixed(const ArrowProblem& P, std::size_t gi, Index mD) {
  using Row = Eigen::Matrix<double, NL, 1>;
  auto& ws = P.ws;
  auto& gb = ws.g[gi];
  const Index kp = KP > 0 ? Index{KP} : gb.kept;
  const double* S = gb.S.data();
  const GroupColumns bc = group_columns<MK>(P, gi);
  double* T = gb.T.data();
  Index perm[MK];
  UKDYN_UNROLL
  for (Index i = 0; i < MK; ++i) perm[i] = i;
  UKDYN_UNROLL
  for (Index k = 0; k < kp; ++k) std::swap(perm[k], perm[gb.piv[static_cast<std::size_t>(k)]]);
  double z[MK], lam[MK], t[MK * NL];
  alignas(16) double zlam[2 * MK];  // (z_i, lam_i) side by side (KP > 0)
  Row g = ws.gL.template head<NL>();
  UKDYN_UNROLL
  for (Index i = 0; i < MK; ++i) {
    const Index src = perm[i];
    Row ti;
    UKDYN_UNROLL
    for (Index j = 0; j < NL; ++j) ti[j] = bc.C[src + j * bc.ld];
    double zi = gb.r[src], li = gb.bb[src];
    const Index pe = std::min(i, kp);
    if constexpr (KP > 0) {
      // Every row kept: z_i and lam_i as one 2-vector (the same operation on each).
      using Pair = Eigen::Matrix<double, 2, 1>;
      Pair zl(zi, li);
      UKDYN_UNROLL
      for (Index p = 0; p < pe; ++p) {
        const double l = S[i + p * MK];
        ti -= l * Eigen::Map<const Row>(T + p * NL);
        zl -= l * Eigen::Map<const Pair>(zlam + 2 * p);
      }
      Eigen::Map<Pair>(zlam + 2 * i) = zl;
      zi = zl[0];
      li = zl[1];
    } else {
      for (Index p = 0; p < pe; ++p) {
        const double l = S[i + p * MK];
        if (l == 0.0) continue;
        ti -= l * Eigen::Map<const Row>(T + p * NL);
        if (i < kp) zi -= l * z[p];
        li -= l * lam[p];
      }
    }
    Eigen::Map<Row>(T + i * NL) = ti;
    z[i] = zi;
    lam[i] = li;
    if (i < kp) {
      const Row tr = ti * (1.0 / S[i + i * MK]);
      Eigen::Map<Row>(t + i * NL) = tr;
      g += tr * zi;
    }
  }
  ws.gL.template head<NL>() = g;
  add_columns_to_h<NL>(ws.H.data(), T, t, kp, std::make_index_sequence<NL>{});
  UKDYN_UNROLL
  for (Index i = 0; i < MK; ++i) {
    gb.z[i] = z[i];
    gb.lam[i] = lam[i];
  }
  for (Index i = kp; i < MK; ++i) {
    for (Index j = 0; j < NL; ++j) ws.Dt(mD, j) = T[j + i * NL];
    ws.d[mD] = lam[i];
    ws.d_from[static_cast<std::size_t>(mD)] = {static_cast<Index>(gi), i};
    ++mD;
  }
  return mD;
}

template <int NK, int MK, int NL>
[[gnu::always_inline]] inline Index eliminate_group(const ArrowProblem& P, std::size_t gi,
                                                    const RankScale& w, ArrowPivots& pivots,
                                                    Index mD, bool& same) {
  auto& gb = P.ws.g[gi];
  const ArrowSizes<NK, MK, NL> sz(P, gi);
  const LdltPivots pv = pivoted_ldlt(gb.S.data(), MK > 0 ? Index{MK} : gb.S.rows(), sz.mk,
                                     gb.piv.data(), P.ws.tmp.data(), P.rule(w.lo));
  same = same && (w.exact || P.same_decisions(pv, w.hi));
  gb.kept = pv.kept;
  pivots.add(pv);
  if constexpr (MK > 0 && NL > 0) {
    with_kept<MK>(gb.kept, [&](auto KP) {
      mD = eliminate_rows_fixed<MK, NL, decltype(KP)::value>(P, gi, mD);
    });
    return mD;
  } else {
    return eliminate_rows<NK, MK, NL>(P, gi, mD);
  }
}

// Every robot eliminated, then the load-only rows appended to D, d; returns the rows of D. `same`
// is cleared when a decision might differ on the exact scale (RankScale).
template <int NK, int MK, int NL>
Index eliminate_groups(const ArrowProblem& P, const RankScale& w, ArrowPivots& pivots, bool& same) {
  auto& ws = P.ws;
  Index mD = 0;
  for (std::size_t gi = 0; gi < P.st.groups.size() && same; ++gi)
    mD = eliminate_group<NK, MK, NL>(P, gi, w, pivots, mD, same);
  const Index nL = NL > 0 ? Index{NL} : P.nL, lda = P.A.rows(), ldd = ws.Dt.rows();
  double* Dt = ws.Dt.data();
  for (std::size_t j = 0; j < P.st.load_rows.size(); ++j) {
    const Index row = P.st.load_rows[j];
    const double* a = P.A.data() + row + P.sL * lda;
    for (Index c = 0; c < nL; ++c) Dt[mD + c * ldd] = a[c * lda];
    ws.d[mD] = P.b[row];
    ws.d_from[static_cast<std::size_t>(mD)] = {-1, static_cast<Index>(j)};
    ++mD;
  }
  return mD;
}

// Cholesky of H in place (lower, leading dimension n), dividing directly; false if H is not
// positive definite.
template <int NL>
bool cholesky_in_place(double* H, Index n_rt) {
  const Index n = NL > 0 ? Index{NL} : n_rt;
  UKDYN_UNROLL
  for (Index j = 0; j < n; ++j) {
    double dj = H[j + j * n];
    UKDYN_UNROLL
    for (Index k = 0; k < j; ++k) dj -= H[j + k * n] * H[j + k * n];
    if (!(dj > 0.0)) return false;
    const double ljj = std::sqrt(dj);
    H[j + j * n] = ljj;
    Index i0 = j + 1;
    if constexpr (NL > 0) {
      // n_L fixed: the rows below the diagonal in pairs with k outer (H_jk loaded once), as
      // dense_kernels.hpp's chol_block, each entry the same operations in the same order.
      using Pair = Eigen::Matrix<double, 2, 1>;
      const Index np = (n - j - 1) / 2, it = j + 1 + 2 * np;
      Pair acc[NL / 2 > 0 ? NL / 2 : 1];
      UKDYN_UNROLL
      for (Index t = 0; t < np; ++t) acc[t] = Eigen::Map<const Pair>(H + i0 + 2 * t + j * n);
      UKDYN_UNROLL
      for (Index k = 0; k < j; ++k) {
        const double hjk = H[j + k * n];
        UKDYN_UNROLL
        for (Index t = 0; t < np; ++t)
          acc[t] -= Eigen::Map<const Pair>(H + i0 + 2 * t + k * n) * hjk;
      }
      UKDYN_UNROLL
      for (Index t = 0; t < np; ++t) Eigen::Map<Pair>(H + i0 + 2 * t + j * n) = acc[t] / ljj;
      i0 = it;
    }
    UKDYN_UNROLL
    for (Index i = i0; i < n; ++i) {
      double v = H[i + j * n];
      UKDYN_UNROLL
      for (Index k = 0; k < j; ++k) v -= H[i + k * n] * H[j + k * n];
      H[i + j * n] = v / ljj;
    }
  }
  return true;
}

// x ← L_H⁻¹ x and x ← L_H^{-ᵀ} x with the Cholesky factor of H (cholesky_in_place).
template <int NL>
void h_solve(const double* H, Index n_rt, double* x) {
  const Index n = NL > 0 ? Index{NL} : n_rt;
  UKDYN_UNROLL
  for (Index i = 0; i < n; ++i) {
    double v = x[i];
    UKDYN_UNROLL
    for (Index k = 0; k < i; ++k) v -= H[i + k * n] * x[k];
    x[i] = v / H[i + i * n];
  }
}
template <int NL>
void ht_solve(const double* H, Index n_rt, double* x) {
  const Index n = NL > 0 ? Index{NL} : n_rt;
  UKDYN_UNROLL
  for (Index i = n - 1; i >= 0; --i) {
    double v = x[i];
    UKDYN_UNROLL
    for (Index k = i + 1; k < n; ++k) v -= H[k + i * n] * x[k];
    x[i] = v / H[i + i * n];
  }
}

// The load's own U-K with H (factored): yH = L_H⁻¹ g, X_D = D L_H^{-ᵀ}, W_D = X_D X_Dᵀ,
// r_D = d − X_D yH; μ from W_D μ = r_D, q̈_L = L_H^{-ᵀ}(yH + X_Dᵀ μ) into ws.qddL. MD: the rows of
// D when fixed (1: a free-body load's unit-norm row and no dropped row), else 0 (mD at run time);
// the same operations in the same order. Returns false, before q̈_L, when a decision might differ
// on the exact scale (RankScale).
template <int NL, int MD>
bool solve_load(const ArrowProblem& P, Index mD_rt, const RankScale& w, ArrowPivots& pivots) {
  auto& ws = P.ws;
  const Index nL = NL > 0 ? Index{NL} : P.nL, mD = MD > 0 ? Index{MD} : mD_rt;
  const double* H = ws.H.data();
  double* yH = ws.qddL.data();
  double* Dt = ws.Dt.data();
  const Index ldd = ws.Dt.rows(), ldw = ws.WD.rows();
  double* tmp = ws.tmp.data();
  for (Index j = 0; j < nL; ++j) yH[j] = ws.gL[j];
  h_solve<NL>(H, nL, yH);
  for (Index i = 0; i < mD; ++i) {
    for (Index j = 0; j < nL; ++j) tmp[j] = Dt[i + j * ldd];
    h_solve<NL>(H, nL, tmp);
    double v = ws.d[i];
    for (Index j = 0; j < nL; ++j) {
      Dt[i + j * ldd] = tmp[j];
      v -= tmp[j] * yH[j];
    }
    ws.rD[i] = v;
  }
  if constexpr (MD > 0) {
    double* W = ws.WD.data();
    for (Index j = 0; j < mD; ++j)
      for (Index i = j; i < mD; ++i) {
        double v = 0.0;
        for (Index l = 0; l < nL; ++l) v += Dt[i + l * ldd] * Dt[j + l * ldd];
        W[i + j * ldw] = v;
      }
  } else {
    lower_gram(ws.Dt, mD, nL, ws.WD);
  }
  const LdltPivots pv = pivoted_ldlt(ws.WD.data(), ldw, mD, ws.pivD.data(), tmp, P.rule(w.lo));
  if (!w.exact && !P.same_decisions(pv, w.hi)) return false;
  pivots.add(pv);
  double* lam = ws.lamD.data();
  for (Index i = 0; i < mD; ++i) lam[i] = ws.rD[i];
  detail::ldlt_basic_solve(ws.WD.data(), ldw, mD, pv.kept, ws.pivD.data(), lam);
  for (Index j = 0; j < nL; ++j) {
    double v = yH[j];
    for (Index i = 0; i < mD; ++i) v += Dt[i + j * ldd] * lam[i];
    yH[j] = v;
  }
  ht_solve<NL>(H, nL, yH);
  return true;
}

// Robot k's multipliers: u = (z − T1 q̈_L) / D, v = u − L21ᵀ λ_E, λ1 = L11^{-ᵀ} v for the kept rows
// (λ = S⁻¹(r − C q̈_L) with the dropped rows' λ_E moved over, see the header), then its share of
// Qc = Aᵀ λ on the robot and the load.
template <int NK, int MK, int NL>
void group_multipliers(const ArrowProblem& P, std::size_t gi, Vec& Qc) {
  const auto& grp = P.st.groups[gi];
  auto& gb = P.ws.g[gi];
  const ArrowSizes<NK, MK, NL> sz(P, gi);
  const Index mk = sz.mk, nk = sz.nk, nL = sz.nL;
  with_kept<MK>(gb.kept, [&](auto KP) {
    const Index kp = decltype(KP)::value > 0 ? Index{decltype(KP)::value} : gb.kept;
    const double* qL = P.ws.qddL.data();
    const double* T = gb.T.data();  // transposed (eliminate_group)
    const double* S = gb.S.data();
    const Index lds = MK > 0 ? Index{MK} : gb.S.rows();
    UKDYN_UNROLL
    for (Index i = 0; i < kp; ++i) {
      double v = gb.z[i];
      UKDYN_UNROLL
      for (Index j = 0; j < nL; ++j) v -= T[j + i * nL] * qL[j];
      gb.lam[i] = v / S[i + i * lds];
    }
    for (Index e = kp; e < mk; ++e) {
      const double le = gb.lam[e];
      for (Index p = 0; p < kp; ++p) gb.lam[p] -= S[e + p * lds] * le;
    }
    UKDYN_UNROLL
    for (Index p = kp - 1; p >= 0; --p) {
      double v = gb.lam[p];
      UKDYN_UNROLL
      for (Index i = p + 1; i < kp; ++i) v -= S[i + p * lds] * gb.lam[i];
      gb.lam[p] = v;
    }
    UKDYN_UNROLL
    for (Index k = kp - 1; k >= 0; --k)
      std::swap(gb.lam[k], gb.lam[gb.piv[static_cast<std::size_t>(k)]]);
  });
  const Index s = grp.start;
  const GroupColumns bc = group_columns<MK>(P, gi);
  const double* lam = gb.lam.data();
  for (Index i = 0; i < mk; ++i) P.ws.lambda[grp.rows[static_cast<std::size_t>(i)]] = lam[i];
  // Qc += Bᵀ λ_k, Cᵀ λ_k entry by entry down B's and C's contiguous columns: each entry gets its
  // terms in the order of the rows, as one row at a time (a dropped row's λ_i = 0 adds an exact 0).
  // MK > 0: each column's sum a fixed-size dot product (vectorised; the terms summed pairwise, so
  // the last bits differ from the runtime-size path's).
  auto add_columns = [&](const double* X, double* out, Index n) {
    if constexpr (MK > 0) {
      using Col = Eigen::Matrix<double, MK, 1>;
      const Eigen::Map<const Col> lv(lam);
      for (Index j = 0; j < n; ++j) out[j] += Eigen::Map<const Col>(X + j * bc.ld).dot(lv);
      return;
    }
    for (Index j = 0; j < n; ++j) {
      double v = out[j];
      for (Index i = 0; i < mk; ++i) v += X[i + j * mk] * lam[i];
      out[j] = v;
    }
  };
  add_columns(bc.B, Qc.data() + s, nk);
  add_columns(bc.C, Qc.data() + P.sL, nL);
}

// Every multiplier (the load-only and dropped rows' from μ, the robots' kept rows') and Qc = Aᵀ λ.
template <int NK, int MK, int NL>
void multipliers_and_constraint_force(const ArrowProblem& P, Index mD, Vec& Qc) {
  auto& ws = P.ws;
  const double* lam = ws.lamD.data();
  for (Index i = 0; i < mD; ++i) {
    const auto [grp, k] = ws.d_from[static_cast<std::size_t>(i)];
    if (grp < 0) {
      ws.lambda[P.st.load_rows[static_cast<std::size_t>(k)]] = lam[i];
    } else {
      ws.g[static_cast<std::size_t>(grp)].lam[k] = lam[i];
    }
  }
  Qc.setZero();
  for (std::size_t gi = 0; gi < P.st.groups.size(); ++gi) group_multipliers<NK, MK, NL>(P, gi, Qc);
  const Index nL = NL > 0 ? Index{NL} : P.nL, lda = P.A.rows();
  double* qcL = Qc.data() + P.sL;
  for (const Index row : P.st.load_rows) {
    const double li = ws.lambda[row];
    const double* a = P.A.data() + row + P.sL * lda;
    for (Index j = 0; j < nL; ++j) qcL[j] += a[j * lda] * li;
  }
}

// q̈ = M⁻¹(Q + Qc), block by block, paper Eq. (18). A robot's block reuses y = L_k⁻¹ Q_k and
// Xᵀ = B L_k^{-ᵀ} of reduce_group: q̈_k = L_k^{-ᵀ}(y + X λ_k) (L_k⁻¹ Qc_k = L_k⁻¹ Bᵀ λ_k = X λ_k, as
// the dense solve forms q̈, uk_solve.hpp), independent sums instead of a forward substitution; the
// load's is solve_load's q̈_L; any other block (no rows) q̈ = L⁻ᵀ L⁻¹ (Q + Qc).
template <int NK, int MK, int NL>
void accelerations(const ArrowProblem& P, const Vec& Qc, Vec& qdd) {
  const auto& layout = P.dws.layout;
  for (std::size_t gi = 0; gi < P.st.groups.size(); ++gi) {
    const auto& gb = P.ws.g[gi];
    const ArrowSizes<NK, MK, NL> sz(P, gi);
    const Index s = P.st.groups[gi].start, mk = sz.mk, nk = sz.nk;
    const double* Xt = gb.Xt.data();
    const double* y = gb.w.data();
    double* x = qdd.data() + s;
    for (Index l = 0; l < nk; ++l) {
      if constexpr (MK > 0) {  // a fixed-size dot product, as in group_multipliers
        using Col = Eigen::Matrix<double, MK, 1>;
        // Xᵀ's columns and λ_k: Eigen's storage, 16-byte aligned for an even m_k (reduce_group).
        constexpr int kAl =
            MK % 2 == 0 && EIGEN_MAX_ALIGN_BYTES >= 16 ? Eigen::Aligned16 : Eigen::Unaligned;
        x[l] =
            y[l] +
            Eigen::Map<const Col, kAl>(Xt + l * mk).dot(Eigen::Map<const Col, kAl>(gb.lam.data()));
        continue;
      }
      double v = y[l];
      for (Index i = 0; i < mk; ++i) v += Xt[i + l * mk] * gb.lam[i];
      x[l] = v;
    }
    detail::lt_solve<NK>(P.Ld + s + s * P.ldl, P.ldl, P.idg + s, x, nk);
  }
  const Index nL = NL > 0 ? Index{NL} : P.nL;
  for (Index j = 0; j < nL; ++j) qdd[P.sL + j] = P.ws.qddL[j];
  // Blocks without rows: only when the robots and the load are not all of them.
  const std::size_t with_rows = P.st.groups.size() + (P.st.load_block >= 0 ? 1 : 0);
  for (std::size_t k = 0; k < layout.blocks() && with_rows < layout.blocks(); ++k) {
    bool done = static_cast<Index>(k) == P.st.load_block;
    for (const auto& g : P.st.groups) done = done || g.block == static_cast<Index>(k);
    if (done) continue;
    const Index s = layout.start[k], nk = layout.size[k];
    for (Index j = 0; j < nk; ++j) qdd[s + j] = P.Q[s + j] + Qc[s + j];
    const double* Lk = P.Ld + s + s * P.ldl;
    detail::with_block_size(nk, [&](auto N) {
      detail::l_solve<decltype(N)::value>(Lk, P.ldl, P.idg + s, qdd.data() + s, nk);
      detail::lt_solve<decltype(N)::value>(Lk, P.ldl, P.idg + s, qdd.data() + s, nk);
    });
  }
}

// Row i of A q̈ − b (with_abs false) or Σ_j |A_ij| (true) for the rows of group gi into out, each
// row's terms in the order of j as one row at a time would add them, side by side down B's and C's
// columns.
template <int NK, int MK, int NL, bool with_abs>
void group_row_sums(const ArrowProblem& P, std::size_t gi, const Vec& qdd, double* out) {
  const auto& gb = P.ws.g[gi];
  const ArrowSizes<NK, MK, NL> sz(P, gi);
  const Index s = P.st.groups[gi].start, mk = sz.mk, nk = sz.nk, nL = sz.nL;
  const GroupColumns bc = group_columns<MK>(P, gi);
  for (Index i = 0; i < mk; ++i) out[i] = with_abs ? 0.0 : -gb.bb[i];
  auto add_block = [&](const double* X, const double* x, Index n) {
    if constexpr (MK > 0) {  // fixed-size columns: the same operations, vectorised
      using Col = Eigen::Matrix<double, MK, 1>;
      Eigen::Map<Col> o(out);
      for (Index j = 0; j < n; ++j) {
        const Eigen::Map<const Col> xj(X + j * bc.ld);
        if constexpr (with_abs) {
          o += xj.cwiseAbs();
        } else {
          o += xj * x[j];
        }
      }
      return;
    }
    for (Index j = 0; j < n; ++j)
      for (Index i = 0; i < mk; ++i)
        out[i] += with_abs ? std::abs(X[i + j * mk]) : X[i + j * mk] * x[j];
  };
  add_block(bc.B, qdd.data() + s, nk);
  add_block(bc.C, qdd.data() + P.sL, nL);
}

// Row `row` (on the load alone) of A q̈ − b, or Σ_j |A_ij| (with_abs).
template <int NL, bool with_abs>
double load_row_sum(const ArrowProblem& P, Index row, const Vec& qdd) {
  const Index nL = NL > 0 ? Index{NL} : P.nL, lda = P.A.rows();
  const double* a = P.A.data() + row + P.sL * lda;
  const double* qL = qdd.data() + P.sL;
  double v = with_abs ? 0.0 : -P.b[row];
  for (Index j = 0; j < nL; ++j) v += with_abs ? std::abs(a[j * lda]) : a[j * lda] * qL[j];
  return v;
}

// ‖A q̈ − b‖, consistency and finiteness (as uk_solve.cpp's) with the pivots into res. The test
// ‖A q̈ − b‖ ≤ tol (‖b‖ + ‖A‖_∞ ‖q̈‖ + 1) holds whenever it holds without the middle term (≥ 0 for
// a finite ‖q̈‖, and every rounding is monotone), so ‖A‖_∞ is summed only when it does not.
template <int NK, int MK, int NL>
void arrow_result(const ArrowProblem& P, const Vec& qdd, const Vec& Qc, const ArrowPivots& pivots,
                  const UkSettings& settings, UkResult& res) {
  double r2 = 0.0, b2 = 0.0;
  for (std::size_t gi = 0; gi < P.st.groups.size(); ++gi) {
    const auto& gb = P.ws.g[gi];
    // Runtime sizes: r is free by now.
    double v_buf[MK > 0 ? MK : 1];
    double* v = MK > 0 ? v_buf : P.ws.g[gi].r.data();
    group_row_sums<NK, MK, NL, false>(P, gi, qdd, v);
    for (Index i = 0; i < ArrowSizes<NK, MK, NL>(P, gi).mk; ++i) {
      r2 += v[i] * v[i];
      b2 += gb.bb[i] * gb.bb[i];
    }
  }
  for (const Index row : P.st.load_rows) {
    const double v = load_row_sum<NL, false>(P, row, qdd);
    r2 += v * v;
    b2 += P.b[row] * P.b[row];
  }
  // q̈ and Qc finite: x · 0 is ±0 for a finite x and NaN for ±inf and NaN, so the sum of them is
  // 0 exactly when all are finite (without a test and branch per entry). |q̈|² and that sum as
  // Eigen's vectorised reductions (two partial sums: |q̈|² differs from the sum in order in its
  // last bits, which only the consistency test's scale reads).
  const double q2 = qdd.squaredNorm();
  const bool finite = (qdd.array() * 0.0 + Qc.array() * 0.0).sum() == 0.0;
  res = UkResult{};
  res.rank = static_cast<int>(pivots.rank);
  res.sigma_max = std::sqrt(pivots.max);
  res.sigma_min_kept = pivots.rank > 0 ? std::sqrt(pivots.min) : 0.0;
  res.residual = std::sqrt(r2);
  const double tol = settings.consistency_rel_tol;
  res.consistent = std::isfinite(q2) && res.residual <= tol * (std::sqrt(b2) + 1.0);
  if (!res.consistent) {
    double a_inf = 0.0;  // ‖A‖_∞, the largest absolute row sum
    for (std::size_t gi = 0; gi < P.st.groups.size(); ++gi) {
      double ab_buf[MK > 0 ? MK : 1];
      double* ab = MK > 0 ? ab_buf : P.ws.g[gi].r.data();
      group_row_sums<NK, MK, NL, true>(P, gi, qdd, ab);
      for (Index i = 0; i < ArrowSizes<NK, MK, NL>(P, gi).mk; ++i) a_inf = std::max(a_inf, ab[i]);
    }
    for (const Index row : P.st.load_rows)
      a_inf = std::max(a_inf, load_row_sum<NL, true>(P, row, qdd));
    res.consistent = res.residual <= tol * (std::sqrt(b2) + a_inf * std::sqrt(q2) + 1.0);
  }
  res.finite = finite && std::isfinite(res.residual);
}

// Every group n_k = NK coordinates and m_k = MK rows, the load n_L = NL.
template <int NK, int MK, int NL>
bool arrow_shape_is(const ArrowStructure& st) {
  if (st.load_size != NL) return false;
  for (const auto& g : st.groups)
    if (g.size != NK || static_cast<Index>(g.rows.size()) != MK) return false;
  return true;
}

// The steps of the solve in order, with the sizes of arrow_shape_is<NK, MK, NL> (0: runtime).
// First on the rank scale's bounds, then, only if a decision might differ on max diag W itself,
// again from the start on the exact scale (RankScale): the same decisions either way.
template <int NK, int MK, int NL>
bool arrow_steps(const ArrowProblem& P, Vec& qdd, Vec& Qc, const UkSettings& settings,
                 UkResult& res) {
  for (const bool exact : {false, true}) {
    ArrowPivots pivots;
    const RankScale w = reduce_groups<NK, MK, NL>(P, exact);
    bool same = true;
    const Index mD = eliminate_groups<NK, MK, NL>(P, w, pivots, same);
    if (!same) continue;
    if (!cholesky_in_place<NL>(P.ws.H.data(), P.nL)) return false;
    constexpr int kOneRow = NL > 0 ? 1 : 0;  // the runtime sizes keep mD at run time
    const bool solved = kOneRow > 0 && mD == 1 ? solve_load<NL, kOneRow>(P, mD, w, pivots)
                                               : solve_load<NL, 0>(P, mD, w, pivots);
    if (!solved) continue;
    multipliers_and_constraint_force<NK, MK, NL>(P, mD, Qc);
    accelerations<NK, MK, NL>(P, Qc, qdd);
    arrow_result<NK, MK, NL>(P, qdd, Qc, pivots, settings, res);
    return true;
  }
  return false;  // not reached: the exact pass makes its decisions itself
}

}  // namespace

bool uk_solve_arrow(const ArrowStructure& st, const Mat& M, const Mat& A, const Vec& b,
                    const Vec& Q, const UkWorkspace& dws, ArrowWorkspace& ws, Vec& qdd, Vec& Qc,
                    const UkSettings& settings, UkResult& res) {
  const ArrowProblem P(st, M, A, b, Q, dws, ws, settings);
  if (arrow_shape_is<10, 6, 7>(st)) return arrow_steps<10, 6, 7>(P, qdd, Qc, settings, res);
  return arrow_steps<0, 0, 0>(P, qdd, Qc, settings, res);
}

}  // namespace ukdyn
