#include "ukdyn/core/uk_arrow.hpp"

#include "ukdyn/core/dense_kernels.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

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

// Pivoted LDLᵀ (symmetric diagonal pivoting, a pivoted Cholesky: [Higham2002] ch. 10) of the
// lower triangle of the m × m matrix W (leading dimension ldw), in place, as in uk_solve.cpp: each
// step takes the largest remaining diagonal; it stops at the first pivot ≤ tol2 · (largest pivot).
// Returns the number kept; piv holds the transpositions, L below the diagonal, D on it.
Index pivoted_ldlt(double* W, Index ldw, Index m, double tol2, double ref, Index* piv, double* t,
                   double& d_max, double& d_min_kept) {
  d_max = 0.0;
  d_min_kept = std::numeric_limits<double>::infinity();
  double cutoff = 0.0;
  Index kept = 0;
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
      cutoff = tol2 * std::max(d_max, ref);
    }
    if (!(d_max > 0.0 && dp > cutoff)) break;
    piv[k] = p;
    if (p != k) {
      for (Index j = 0; j < k; ++j) std::swap(W[k + j * ldw], W[p + j * ldw]);
      std::swap(W[k + k * ldw], W[p + p * ldw]);
      for (Index j = k + 1; j < p; ++j) std::swap(W[j + k * ldw], W[p + j * ldw]);
      for (Index i = p + 1; i < m; ++i) std::swap(W[i + k * ldw], W[i + p * ldw]);
    }
    const double inv_d = 1.0 / dp;
    double* colk = W + k * ldw;
    for (Index i = k + 1; i < m; ++i) {
      t[i] = colk[i];
      colk[i] *= inv_d;
    }
    for (Index j = k + 1; j < m; ++j) {
      const double tj = t[j];
      double* colj = W + j * ldw;
      for (Index i = j; i < m; ++i) colj[i] -= colk[i] * tj;
    }
    d_min_kept = std::min(d_min_kept, dp);
    ++kept;
  }
  return kept;
}

// x ← L^{-1} x and x ← L^{-ᵀ} x for a lower factor L (ldl) with 1/L_ii in inv_diag, runtime size.
void l_solve(const double* L, Index ldl, const double* inv_diag, double* x, Index n) {
  detail::l_solve<0>(L, ldl, inv_diag, x, n);
}
void lt_solve(const double* L, Index ldl, const double* inv_diag, double* x, Index n) {
  detail::lt_solve<0>(L, ldl, inv_diag, x, n);
}

// Rows k and p of a column-major matrix (m rows, c columns) swapped.
void swap_rows(Mat& X, Index k, Index p) {
  if (k == p) return;
  for (Index j = 0; j < X.cols(); ++j) std::swap(X(k, j), X(p, j));
}

}  // namespace

bool uk_solve_arrow(const ArrowStructure& st, const Mat& M, const Mat& A, const Vec& b,
                    const Vec& Q, const UkWorkspace& dws, ArrowWorkspace& ws, Vec& qdd, Vec& Qc,
                    const UkSettings& settings, UkResult& res) {
  const Index n = dws.layout.dof();
  const Index sL = st.load_start, nL = st.load_size;
  const Index ldl = dws.L.rows();
  const double* Ld = dws.L.data();
  const double* idg = dws.inv_diag.data();
  const double tol2 = settings.rank_rel_tol * settings.rank_rel_tol;
  double piv_max = 0.0, piv_min = std::numeric_limits<double>::infinity();
  Index rank = 0;

  // H = M_L, g = Q_L (the load's own inertia and forces), lower triangle.
  for (Index j = 0; j < nL; ++j) {
    for (Index i = j; i < nL; ++i) ws.H(i, j) = M(sL + i, sL + j);
    ws.gL[j] = Q[sL + j];
  }

  Index mD = 0;
  double w_ref = 0.0;  // max diag W
  for (std::size_t gi = 0; gi < st.groups.size(); ++gi) {
    const auto& grp = st.groups[gi];
    auto& gb = ws.g[gi];
    const Index mk = static_cast<Index>(grp.rows.size()), s = grp.start, nk = grp.size;
    const double* Lk = Ld + s + s * ldl;
    const double* id = idg + s;
    // The group's rows of A: B (robot columns), C (load columns), b.
    for (Index i = 0; i < mk; ++i) {
      const Index row = grp.rows[static_cast<std::size_t>(i)];
      for (Index j = 0; j < nk; ++j) gb.B(i, j) = A(row, s + j);
      for (Index j = 0; j < nL; ++j) gb.C(i, j) = A(row, sL + j);
      gb.bb[i] = b[row];
    }
    // Xᵀ = B L_k^{-ᵀ} column by column, y = L_k⁻¹ Q_k, r = b − Xᵀ y (= b − B M_k⁻¹ Q_k).
    double* y = gb.w.data();
    for (Index j = 0; j < nk; ++j) y[j] = Q[s + j];
    l_solve(Lk, ldl, id, y, nk);
    for (Index l = 0; l < nk; ++l) {
      for (Index i = 0; i < mk; ++i) {
        double v = gb.B(i, l);
        for (Index p = 0; p < l; ++p) v -= Lk[l + p * ldl] * gb.Xt(i, p);
        gb.Xt(i, l) = v * id[l];
      }
    }
    for (Index i = 0; i < mk; ++i) {
      double v = gb.bb[i];
      for (Index l = 0; l < nk; ++l) v -= gb.Xt(i, l) * y[l];
      gb.r[i] = v;
    }
    // S = Xᵀ X (lower), and the diagonal of W = A M⁻¹Aᵀ, W_ii = S_ii + C_i M_L⁻¹ C_iᵀ: the scale of
    // every rank decision below, as the dense solve's (max diag W).
    for (Index j = 0; j < mk; ++j)
      for (Index i = j; i < mk; ++i) {
        double v = 0.0;
        for (Index l = 0; l < nk; ++l) v += gb.Xt(i, l) * gb.Xt(j, l);
        gb.S(i, j) = v;
      }
    for (Index i = 0; i < mk; ++i) {
      for (Index j = 0; j < nL; ++j) ws.tmp[j] = gb.C(i, j);
      double c2 = 0.0;
      if (nL > 0) {
        l_solve(Ld + sL + sL * ldl, ldl, idg + sL, ws.tmp.data(), nL);
        for (Index j = 0; j < nL; ++j) c2 += ws.tmp[j] * ws.tmp[j];
      }
      w_ref = std::max(w_ref, gb.S(i, i) + c2);
    }
  }
  for (const Index row : st.load_rows) {
    for (Index j = 0; j < nL; ++j) ws.tmp[j] = A(row, sL + j);
    l_solve(Ld + sL + sL * ldl, ldl, idg + sL, ws.tmp.data(), nL);
    double c2 = 0.0;
    for (Index j = 0; j < nL; ++j) c2 += ws.tmp[j] * ws.tmp[j];
    w_ref = std::max(w_ref, c2);
  }
  for (std::size_t gi = 0; gi < st.groups.size(); ++gi) {
    const auto& grp = st.groups[gi];
    auto& gb = ws.g[gi];
    const Index mk = static_cast<Index>(grp.rows.size());
    // Pivoted LDLᵀ of S, pivots under rank_rel_tol² · max diag W dropped.
    double dmax = 0.0, dmin = 0.0;
    gb.kept = pivoted_ldlt(gb.S.data(), gb.S.rows(), mk, tol2, w_ref, gb.piv.data(), ws.tmp.data(),
                           dmax, dmin);
    const Index kp = gb.kept;
    rank += kp;
    if (kp > 0) {
      piv_max = std::max(piv_max, dmax);
      piv_min = std::min(piv_min, dmin);
    }
    // The same row order for C (into T), r and b (into z, lam as scratch).
    gb.T = gb.C;  // same size: no allocation
    for (Index i = 0; i < mk; ++i) gb.z[i] = gb.r[i];
    for (Index i = 0; i < mk; ++i) gb.lam[i] = gb.bb[i];
    for (Index k = 0; k < kp; ++k) {
      const Index p = gb.piv[static_cast<std::size_t>(k)];
      swap_rows(gb.T, k, p);
      std::swap(gb.z[k], gb.z[p]);
      std::swap(gb.lam[k], gb.lam[p]);
    }
    // Kept rows: T1 = L11⁻¹ C1, z = L11⁻¹ r1, lam1 = L11⁻¹ b1 (unit lower). Dropped rows i: the
    // combinations e_i = row_i − L21 L11⁻¹ (kept rows): T_i = e_i C, lam_i = e_i b (no robot part).
    for (Index i = 1; i < mk; ++i) {
      const Index pe = std::min(i, kp);
      for (Index p = 0; p < pe; ++p) {
        const double l = gb.S(i, p);
        if (l == 0.0) continue;
        for (Index j = 0; j < nL; ++j) gb.T(i, j) -= l * gb.T(p, j);
        if (i < kp) gb.z[i] -= l * gb.z[p];
        gb.lam[i] -= l * gb.lam[p];
      }
    }
    // H += Σ_kept T_iᵀ T_i / D_i,  g += Σ_kept T_iᵀ z_i / D_i  (C1ᵀ S11⁻¹ C1 and C1ᵀ S11⁻¹ r1).
    for (Index i = 0; i < kp; ++i) {
      const double inv = 1.0 / gb.S(i, i);
      for (Index jj = 0; jj < nL; ++jj) {
        const double tj = gb.T(i, jj) * inv;
        if (tj == 0.0) continue;
        for (Index ii = jj; ii < nL; ++ii) ws.H(ii, jj) += gb.T(i, ii) * tj;
        ws.gL[jj] += tj * gb.z[i];
      }
    }
    // Dropped rows become rows on the load.
    for (Index i = kp; i < mk; ++i) {
      for (Index j = 0; j < nL; ++j) ws.Dt(mD, j) = gb.T(i, j);
      ws.d[mD] = gb.lam[i];
      ws.d_from[static_cast<std::size_t>(mD)] = {static_cast<Index>(gi), i};
      ++mD;
    }
  }
  for (std::size_t j = 0; j < st.load_rows.size(); ++j) {
    const Index row = st.load_rows[j];
    for (Index c = 0; c < nL; ++c) ws.Dt(mD, c) = A(row, sL + c);
    ws.d[mD] = b[row];
    ws.d_from[static_cast<std::size_t>(mD)] = {-1, static_cast<Index>(j)};
    ++mD;
  }

  // Cholesky of H in place (lower); 1/L_ii into tmp's head is not needed: divide directly.
  for (Index j = 0; j < nL; ++j) {
    double dj = ws.H(j, j);
    for (Index k = 0; k < j; ++k) dj -= ws.H(j, k) * ws.H(j, k);
    if (!(dj > 0.0)) return false;
    const double ljj = std::sqrt(dj);
    ws.H(j, j) = ljj;
    for (Index i = j + 1; i < nL; ++i) {
      double v = ws.H(i, j);
      for (Index k = 0; k < j; ++k) v -= ws.H(i, k) * ws.H(j, k);
      ws.H(i, j) = v / ljj;
    }
  }
  auto h_solve = [&](double* x) {
    for (Index i = 0; i < nL; ++i) {
      double v = x[i];
      for (Index k = 0; k < i; ++k) v -= ws.H(i, k) * x[k];
      x[i] = v / ws.H(i, i);
    }
  };
  auto ht_solve = [&](double* x) {
    for (Index i = nL - 1; i >= 0; --i) {
      double v = x[i];
      for (Index k = i + 1; k < nL; ++k) v -= ws.H(k, i) * x[k];
      x[i] = v / ws.H(i, i);
    }
  };
  // The load's own U-K with H: yH = L_H⁻¹ g, X_D = D L_H^{-ᵀ}, W_D = X_D X_Dᵀ, r_D = d − X_D yH.
  double* yH = ws.qddL.data();
  for (Index j = 0; j < nL; ++j) yH[j] = ws.gL[j];
  h_solve(yH);
  for (Index i = 0; i < mD; ++i) {
    for (Index j = 0; j < nL; ++j) ws.tmp[j] = ws.Dt(i, j);
    h_solve(ws.tmp.data());
    double v = ws.d[i];
    for (Index j = 0; j < nL; ++j) {
      ws.Dt(i, j) = ws.tmp[j];
      v -= ws.tmp[j] * yH[j];
    }
    ws.rD[i] = v;
  }
  for (Index j = 0; j < mD; ++j)
    for (Index i = j; i < mD; ++i) {
      double v = 0.0;
      for (Index l = 0; l < nL; ++l) v += ws.Dt(i, l) * ws.Dt(j, l);
      ws.WD(i, j) = v;
    }
  double dmaxD = 0.0, dminD = 0.0;
  const Index keptD = pivoted_ldlt(ws.WD.data(), ws.WD.rows(), mD, tol2, w_ref, ws.pivD.data(),
                                   ws.tmp.data(), dmaxD, dminD);
  rank += keptD;
  if (keptD > 0) {
    piv_max = std::max(piv_max, dmaxD);
    piv_min = std::min(piv_min, dminD);
  }
  // Basic solution μ of W_D μ = r_D (as in uk_solve.cpp).
  double* lam = ws.lamD.data();
  const double* W = ws.WD.data();
  const Index ldw = ws.WD.rows();
  for (Index i = 0; i < mD; ++i) lam[i] = ws.rD[i];
  for (Index k = 0; k < keptD; ++k) std::swap(lam[k], lam[ws.pivD[static_cast<std::size_t>(k)]]);
  for (Index i = 0; i < keptD; ++i) {
    double v = lam[i];
    for (Index k = 0; k < i; ++k) v -= W[i + k * ldw] * lam[k];
    lam[i] = v;
  }
  for (Index i = 0; i < keptD; ++i) lam[i] /= W[i + i * ldw];
  for (Index i = keptD; i < mD; ++i) lam[i] = 0.0;
  for (Index i = keptD - 1; i >= 0; --i) {
    double v = lam[i];
    for (Index k = i + 1; k < keptD; ++k) v -= W[k + i * ldw] * lam[k];
    lam[i] = v;
  }
  for (Index k = keptD - 1; k >= 0; --k)
    std::swap(lam[k], lam[ws.pivD[static_cast<std::size_t>(k)]]);
  // q̈_L = L_H^{-ᵀ}(yH + X_Dᵀ μ).
  for (Index j = 0; j < nL; ++j) {
    double v = yH[j];
    for (Index i = 0; i < mD; ++i) v += ws.Dt(i, j) * lam[i];
    yH[j] = v;
  }
  ht_solve(yH);
  const double* qL = ws.qddL.data();

  // Multipliers: load-only rows and the dropped rows of each group from μ.
  for (Index i = 0; i < mD; ++i) {
    const auto [grp, k] = ws.d_from[static_cast<std::size_t>(i)];
    if (grp < 0) {
      ws.lambda[st.load_rows[static_cast<std::size_t>(k)]] = lam[i];
    } else {
      ws.g[static_cast<std::size_t>(grp)].lam[k] = lam[i];
    }
  }
  Qc.setZero();
  for (std::size_t gi = 0; gi < st.groups.size(); ++gi) {
    const auto& grp = st.groups[gi];
    auto& gb = ws.g[gi];
    const Index mk = static_cast<Index>(grp.rows.size()), kp = gb.kept;
    // u = (z − T1 q̈_L) / D, v = u − L21ᵀ λ_E, λ1 = L11^{-ᵀ} v: robot k's kept rows
    // (λ = S⁻¹(r − C q̈_L) with the dropped rows' λ_E moved over, see the header).
    for (Index i = 0; i < kp; ++i) {
      double v = gb.z[i];
      for (Index j = 0; j < nL; ++j) v -= gb.T(i, j) * qL[j];
      gb.lam[i] = v / gb.S(i, i);
    }
    for (Index e = kp; e < mk; ++e) {
      const double le = gb.lam[e];
      for (Index p = 0; p < kp; ++p) gb.lam[p] -= gb.S(e, p) * le;
    }
    for (Index p = kp - 1; p >= 0; --p) {
      double v = gb.lam[p];
      for (Index i = p + 1; i < kp; ++i) v -= gb.S(i, p) * gb.lam[i];
      gb.lam[p] = v;
    }
    for (Index k = kp - 1; k >= 0; --k)
      std::swap(gb.lam[k], gb.lam[gb.piv[static_cast<std::size_t>(k)]]);
    // Qc = Aᵀ λ on the robot and the load.
    const Index s = grp.start, nk = grp.size;
    for (Index i = 0; i < mk; ++i) {
      const double li = gb.lam[i];
      ws.lambda[grp.rows[static_cast<std::size_t>(i)]] = li;
      if (li == 0.0) continue;
      for (Index j = 0; j < nk; ++j) Qc[s + j] += gb.B(i, j) * li;
      for (Index j = 0; j < nL; ++j) Qc[sL + j] += gb.C(i, j) * li;
    }
  }
  for (const Index row : st.load_rows) {
    const double li = ws.lambda[row];
    for (Index j = 0; j < nL; ++j) Qc[sL + j] += A(row, sL + j) * li;
  }
  // q̈ = M⁻¹(Q + Qc), block by block (every block, free ones too), paper Eq. (18).
  for (std::size_t k = 0; k < dws.layout.blocks(); ++k) {
    const Index s = dws.layout.start[k], nk = dws.layout.size[k];
    for (Index j = 0; j < nk; ++j) qdd[s + j] = Q[s + j] + Qc[s + j];
    l_solve(Ld + s + s * ldl, ldl, idg + s, qdd.data() + s, nk);
    lt_solve(Ld + s + s * ldl, ldl, idg + s, qdd.data() + s, nk);
  }

  // ‖A q̈ − b‖, ‖A‖_∞, consistency (as uk_solve.cpp's).
  double r2 = 0.0, b2 = 0.0, a_inf = 0.0;
  for (std::size_t gi = 0; gi < st.groups.size(); ++gi) {
    const auto& grp = st.groups[gi];
    const auto& gb = ws.g[gi];
    const Index s = grp.start, nk = grp.size;
    for (Index i = 0; i < static_cast<Index>(grp.rows.size()); ++i) {
      double v = -gb.bb[i], ab = 0.0;
      for (Index j = 0; j < nk; ++j) {
        v += gb.B(i, j) * qdd[s + j];
        ab += std::abs(gb.B(i, j));
      }
      for (Index j = 0; j < nL; ++j) {
        v += gb.C(i, j) * qdd[sL + j];
        ab += std::abs(gb.C(i, j));
      }
      r2 += v * v;
      b2 += gb.bb[i] * gb.bb[i];
      a_inf = std::max(a_inf, ab);
    }
  }
  for (const Index row : st.load_rows) {
    double v = -b[row], ab = 0.0;
    for (Index j = 0; j < nL; ++j) {
      v += A(row, sL + j) * qdd[sL + j];
      ab += std::abs(A(row, sL + j));
    }
    r2 += v * v;
    b2 += b[row] * b[row];
    a_inf = std::max(a_inf, ab);
  }
  double q2 = 0.0;
  bool finite = true;
  for (Index j = 0; j < n; ++j) {
    q2 += qdd[j] * qdd[j];
    finite = finite && std::isfinite(qdd[j]) && std::isfinite(Qc[j]);
  }
  res = UkResult{};
  res.rank = static_cast<int>(rank);
  res.sigma_max = std::sqrt(piv_max);
  res.sigma_min_kept = rank > 0 ? std::sqrt(piv_min) : 0.0;
  res.residual = std::sqrt(r2);
  res.consistent =
      res.residual <= settings.consistency_rel_tol * (std::sqrt(b2) + a_inf * std::sqrt(q2) + 1.0);
  res.finite = finite && std::isfinite(res.residual);
  return true;
}

}  // namespace ukdyn
