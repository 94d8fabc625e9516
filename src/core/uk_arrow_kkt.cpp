#include "ukdyn/core/uk_arrow_kkt.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace ukdyn {

ArrowKktWorkspace::ArrowKktWorkspace(const ArrowStructure& st, const BlockLayout& layout,
                                     Index columns)
    : D0(Mat::Zero(static_cast<Index>(st.load_rows.size()), st.load_size)),
      LL(Mat::Zero(st.load_size, st.load_size)),
      H(Mat::Zero(st.load_size, st.load_size)),
      LH(st.load_size),
      E(Mat::Zero(st.load_size, static_cast<Index>(st.load_rows.size()))),
      Vm(Mat::Zero(static_cast<Index>(st.load_rows.size()),
                   static_cast<Index>(st.load_rows.size()))),
      V(static_cast<Index>(st.load_rows.size())),
      Vinv(Mat::Zero(static_cast<Index>(st.load_rows.size()),
                     static_cast<Index>(st.load_rows.size()))),
      gL(Mat::Zero(st.load_size, columns)),
      Y0(Mat::Zero(static_cast<Index>(st.load_rows.size()), columns)) {
  other.assign(layout.blocks(), 1);
  if (st.load_block >= 0) other[static_cast<std::size_t>(st.load_block)] = 0;
  const Index nL = st.load_size, m0 = static_cast<Index>(st.load_rows.size());
  Index mk_max = 0;
  for (const auto& grp : st.groups) {
    const Index mk = static_cast<Index>(grp.rows.size()), nk = grp.size;
    mk_max = std::max(mk_max, mk);
    GroupBuffers gb;
    gb.B = Mat::Zero(mk, nk);
    gb.C = Mat::Zero(mk, nL);
    gb.Xt = Mat::Zero(mk, nk);
    gb.Sm = Mat::Zero(mk, mk);
    gb.S = Eigen::LLT<Mat>(mk);
    gb.T = Mat::Zero(mk, nL);
    gb.P = Mat::Zero(mk, nL);
    gb.Q = Mat::Zero(nk, nL);
    gb.Z = Mat::Zero(nk, columns);
    gb.Rc = Mat::Zero(mk, columns);
    gb.R = Mat::Zero(mk, columns);
    gb.cols.reserve(static_cast<std::size_t>(columns));
    gb.U = Mat::Zero(nL, mk);
    g.push_back(std::move(gb));
    other[static_cast<std::size_t>(grp.block)] = 0;
  }
  VE = Mat::Zero(m0, mk_max);
  built_ = true;
}

namespace {

// The lower Cholesky factor of layout block k (factor_mass's, in the diagonal block).
auto block_factor(const UkWorkspace& mass, Index s, Index nk) {
  return mass.L.block(s, s, nk, nk).triangularView<Eigen::Lower>();
}

// Its transpose L_kᵀ (upper).
auto block_factor_t(const UkWorkspace& mass, Index s, Index nk) {
  return mass.L.block(s, s, nk, nk).transpose().triangularView<Eigen::Upper>();
}

// Rows `rows` of `from` into the rows of `to` (gather) or back (scatter): one block copy when the
// rows are consecutive (a frame constraint's rows), else row by row.
template <class From, class To>
void gather_rows(const std::vector<Index>& rows, const From& from, To&& to) {
  const auto k = static_cast<Index>(rows.size());
  if (k > 0 && rows.back() - rows.front() == k - 1) {
    to = from.middleRows(rows.front(), k);
    return;
  }
  for (Index i = 0; i < k; ++i) to.row(i) = from.row(rows[static_cast<std::size_t>(i)]);
}
template <class From, class To>
void scatter_rows(const std::vector<Index>& rows, const From& from, To&& to) {
  const auto k = static_cast<Index>(rows.size());
  if (k > 0 && rows.back() - rows.front() == k - 1) {
    to.middleRows(rows.front(), k) = from;
    return;
  }
  for (Index i = 0; i < k; ++i) to.row(rows[static_cast<std::size_t>(i)]) = from.row(i);
}

// The columns where group k's rows of F (its coordinates) or of G are not zero, into gb.cols.
void nonzero_columns(const ArrowStructure::Group& grp, const Eigen::Ref<const Mat>& F,
                     const Eigen::Ref<const Mat>& G, ArrowKktWorkspace::GroupBuffers& gb) {
  gb.cols.clear();
  for (Index c = 0; c < F.cols(); ++c) {
    bool nz = false;
    for (Index i = grp.start; i < grp.start + grp.size && !nz; ++i) nz = F(i, c) != 0.0;
    for (std::size_t i = 0; i < grp.rows.size() && !nz; ++i) nz = G(grp.rows[i], c) != 0.0;
    if (nz) gb.cols.push_back(c);
  }
}

// Those columns of F_k into Z and of G_k into Rc.
template <class Zt, class Rt>
void gather_columns(const ArrowStructure::Group& grp, const Eigen::Ref<const Mat>& F,
                    const Eigen::Ref<const Mat>& G, const ArrowKktWorkspace::GroupBuffers& gb,
                    Zt& Z, Rt& Rc) {
  for (std::size_t j = 0; j < gb.cols.size(); ++j) {
    const Index c = gb.cols[j], jj = static_cast<Index>(j);
    Z.col(jj) = F.col(c).segment(grp.start, grp.size);
    for (std::size_t i = 0; i < grp.rows.size(); ++i)
      Rc(static_cast<Index>(i), jj) = G(grp.rows[i], c);
  }
}

// Smallest squared pivot of an LLT factor (its diagonal squared).
double min_pivot(const Eigen::LLT<Mat>& llt) {
  if (llt.matrixLLT().rows() == 0) return std::numeric_limits<double>::infinity();
  return llt.matrixLLT().diagonal().cwiseAbs2().minCoeff();
}

// Group k's blocks B_k, C_k, Xt = B_k L_k^{-ᵀ}; returns its part of tr W (rows' |L_k⁻¹ b_i|² and
// |L_L⁻¹ c_i|²) and max diag W over its rows.
double reduce_group(const ArrowStructure& st, const Mat& A, const UkWorkspace& mass,
                    ArrowKktWorkspace::GroupBuffers& gb, const ArrowStructure::Group& grp,
                    double& w_max) {
  const Index mk = static_cast<Index>(grp.rows.size()), s = grp.start, nk = grp.size;
  const Index sL = st.load_start, nL = st.load_size;
  for (Index i = 0; i < mk; ++i) {
    const Index row = grp.rows[static_cast<std::size_t>(i)];
    gb.B.row(i) = A.row(row).segment(s, nk);
    gb.C.row(i) = A.row(row).segment(sL, nL);
  }
  gb.Xt = gb.B;
  block_factor_t(mass, s, nk).solveInPlace<Eigen::OnTheRight>(gb.Xt);
  // T as scratch: C_k L_L^{-ᵀ}, whose row norms are the load's part of diag W.
  gb.T = gb.C;
  if (nL > 0 && gb.T.size() > 0) block_factor_t(mass, sL, nL).solveInPlace<Eigen::OnTheRight>(gb.T);
  double tr = 0.0;
  for (Index i = 0; i < mk; ++i) {
    const double wii = gb.Xt.row(i).squaredNorm() + gb.T.row(i).squaredNorm();
    tr += wii;
    w_max = std::max(w_max, wii);
  }
  return tr;
}

}  // namespace

bool arrow_kkt_factor(const ArrowStructure& st, const Mat& A, const UkWorkspace& mass,
                      double rank_rel_tol, ArrowKktWorkspace& ws) {
  const Index sL = st.load_start, nL = st.load_size;
  const Index m0 = static_cast<Index>(st.load_rows.size());
  double w_max = 0.0, tr = 0.0;
  for (std::size_t k = 0; k < st.groups.size(); ++k)
    tr += reduce_group(st, A, mass, ws.g[k], st.groups[k], w_max);
  for (Index i = 0; i < m0; ++i)
    ws.D0.row(i) = A.row(st.load_rows[static_cast<std::size_t>(i)]).segment(sL, nL);
  // E as scratch: L_L⁻¹ D0ᵀ, the load rows' diag W.
  ws.E = ws.D0.transpose();
  // (Eigen's triangular solve takes coeffRef(0, 0) of its right-hand side: none when it is empty.)
  if (nL > 0 && m0 > 0) block_factor(mass, sL, nL).solveInPlace(ws.E);
  for (Index i = 0; i < m0; ++i) {
    const double wii = ws.E.col(i).squaredNorm();
    tr += wii;
    w_max = std::max(w_max, wii);
  }
  ws.trace_w = tr;
  const double floor = rank_rel_tol * rank_rel_tol * w_max;
  // H = M_L + Σ T_kᵀ T_k, T_k = L_S⁻¹ C_k (M_L = L_L L_Lᵀ from the reused factor).
  ws.H.setZero();
  ws.LL = block_factor(mass, sL, nL);
  ws.H.selfadjointView<Eigen::Lower>().rankUpdate(ws.LL);
  for (auto& gb : ws.g) {
    gb.Sm.noalias() = gb.Xt * gb.Xt.transpose();
    gb.S.compute(gb.Sm);
    if (gb.S.info() != Eigen::Success || !(min_pivot(gb.S) > floor)) return false;
    gb.T = gb.C;
    gb.S.matrixL().solveInPlace(gb.T);
    ws.H.selfadjointView<Eigen::Lower>().rankUpdate(gb.T.transpose());
  }
  ws.LH.compute(ws.H);
  if (ws.LH.info() != Eigen::Success) return false;
  ws.E = ws.D0.transpose();
  if (ws.E.size() > 0) ws.LH.matrixL().solveInPlace(ws.E);
  ws.Vm.noalias() = ws.E.transpose() * ws.E;
  ws.V.compute(ws.Vm);
  if (ws.V.info() != Eigen::Success || !(min_pivot(ws.V) > floor)) return false;
  // tr W⁻¹: the load rows' tr V⁻¹, each robot row's (S_k⁻¹)_jj − v_jᵀ P v_j (header):
  // with U = L_H⁻¹ C_kᵀ S_k⁻¹ (columns L_H⁻¹ v_j), v_jᵀ P v_j = |u_j|² − |L_V⁻¹ Eᵀ u_j|².
  ws.Vinv.setIdentity();
  if (m0 > 0) ws.V.matrixL().solveInPlace(ws.Vinv);
  double tri = ws.Vinv.squaredNorm();
  for (auto& gb : ws.g) {
    const Index mk = gb.T.rows();
    // S_k⁻¹ = L_S^{-ᵀ} L_S⁻¹: tr = |L_S⁻¹|_F²; U = L_H⁻¹ T_kᵀ L_S⁻¹.
    gb.U = gb.T.transpose();
    gb.S.matrixL().solveInPlace<Eigen::OnTheRight>(gb.U);
    ws.LH.matrixL().solveInPlace(gb.U);
    Mat& Linv = gb.R;  // scratch: its first mk columns
    Linv.leftCols(mk).setIdentity();
    gb.S.matrixL().solveInPlace(Linv.topLeftCorner(mk, mk));
    tri += Linv.topLeftCorner(mk, mk).squaredNorm() - gb.U.squaredNorm();
    if (m0 > 0) {
      auto ve = ws.VE.leftCols(mk);
      ve.noalias() = ws.E.transpose() * gb.U;
      ws.V.matrixL().solveInPlace(ve);
      tri += ve.squaredNorm();
    }
  }
  ws.trace_w_inv = tri;
  for (std::size_t k = 0; k < ws.g.size(); ++k) {
    auto& gb = ws.g[k];
    const Index s = st.groups[k].start, nk = st.groups[k].size;
    gb.P = gb.T;
    gb.S.matrixU().solveInPlace(gb.P);
    gb.Q.noalias() = gb.Xt.transpose() * gb.P;
    block_factor_t(mass, s, nk).solveInPlace(gb.Q);
  }
  return true;
}

namespace {

// Group k's columns for ArrowColumns::structural: in each set of n columns of F (n = F.rows()),
// the robot's own coordinates and the load's, ascending.
void structural_columns(const ArrowStructure& st, const ArrowStructure::Group& grp, Index n,
                        Index p, std::vector<Index>& cols) {
  cols.clear();
  const bool robot_first = grp.start < st.load_start;
  for (Index o = 0; o + n <= p; o += n) {
    for (const bool robot : {robot_first, !robot_first}) {
      const Index s = robot ? grp.start : st.load_start, sz = robot ? grp.size : st.load_size;
      for (Index i = 0; i < sz; ++i) cols.push_back(o + s + i);
    }
  }
}

// The solve's buffers for p columns (resized once when p exceeds the workspace's columns).
void reserve_columns(const ArrowStructure& st, ArrowKktWorkspace& ws, Index p) {
  if (p <= ws.gL.cols()) return;
  ws.gL.resize(st.load_size, p);
  ws.Y0.resize(static_cast<Index>(st.load_rows.size()), p);
  for (auto& gb : ws.g) {
    gb.Z.resize(gb.Z.rows(), p);
    gb.Rc.resize(gb.Rc.rows(), p);
    gb.R.resize(gb.R.rows(), p);
  }
}

// Everything of the solve but the coupling products: each robot's own elimination on its columns
// (gb.cols), the load's X_L (ws.gL) and Y_0 (ws.Y0), and each robot's own parts on its columns,
// Z = L_k^{-ᵀ} (L_k⁻¹ F_k + Xtᵀ L_S^{-ᵀ} R̃) and Rc = L_S^{-ᵀ} R̃: X_k = Z − Q_k X_L and
// Y_k = Rc − P_k X_L there.
void eliminate(const ArrowStructure& st, const UkWorkspace& mass, ArrowKktWorkspace& ws,
               const Eigen::Ref<const Mat>& F, const Eigen::Ref<const Mat>& G,
               ArrowColumns columns) {
  const Index p = F.cols(), sL = st.load_start, nL = st.load_size;
  const Index m0 = static_cast<Index>(st.load_rows.size());
  reserve_columns(st, ws, p);
  auto gL = ws.gL.leftCols(p);
  auto Y0 = ws.Y0.leftCols(p);
  gL = F.middleRows(sL, nL);
  // Each robot on its columns: Z = L_k⁻¹ F_k, R̃ = L_S⁻¹ (G_k − Xt Z); g += T_kᵀ R̃.
  for (std::size_t k = 0; k < st.groups.size(); ++k) {
    auto& gb = ws.g[k];
    if (columns == ArrowColumns::structural) {
      structural_columns(st, st.groups[k], F.rows(), p, gb.cols);
    } else {
      nonzero_columns(st.groups[k], F, G, gb);
    }
    const auto q = static_cast<Index>(gb.cols.size());
    auto Z = gb.Z.leftCols(q);
    auto Rc = gb.Rc.leftCols(q);
    gather_columns(st.groups[k], F, G, gb, Z, Rc);
    block_factor(mass, st.groups[k].start, st.groups[k].size).solveInPlace(Z);
    Rc.noalias() -= gb.Xt * Z;
    gb.S.matrixL().solveInPlace(Rc);
    for (Index j = 0; j < q; ++j)
      gL.col(gb.cols[static_cast<std::size_t>(j)]).noalias() += gb.T.transpose() * Rc.col(j);
  }
  // The load: h = L_H⁻¹ g, Y_0 = V⁻¹ (G_0 − Eᵀ h), X_L = L_H^{-ᵀ} (h + E Y_0).
  ws.LH.matrixL().solveInPlace(gL);
  gather_rows(st.load_rows, G, Y0);
  if (m0 > 0) {
    Y0.noalias() -= ws.E.transpose() * gL;
    ws.V.solveInPlace(Y0);
    gL.noalias() += ws.E * Y0;
  }
  ws.LH.matrixU().solveInPlace(gL);
  for (std::size_t k = 0; k < st.groups.size(); ++k) {
    auto& gb = ws.g[k];
    const auto q = static_cast<Index>(gb.cols.size());
    auto Z = gb.Z.leftCols(q);
    auto Rc = gb.Rc.leftCols(q);
    gb.S.matrixU().solveInPlace(Rc);
    Z.noalias() += gb.Xt.transpose() * Rc;
    block_factor_t(mass, st.groups[k].start, st.groups[k].size).solveInPlace(Z);
  }
}

// X_b = M_b⁻¹ F_b (in place in X_b) for a block without rows.
template <class Block>
void solve_block(const UkWorkspace& mass, Index s, Index nb, Block&& X) {
  block_factor(mass, s, nb).solveInPlace(X);
  block_factor_t(mass, s, nb).solveInPlace(X);
}

}  // namespace

void arrow_kkt_solve(const ArrowStructure& st, const UkWorkspace& mass, ArrowKktWorkspace& ws,
                     const Eigen::Ref<const Mat>& F, const Eigen::Ref<const Mat>& G,
                     Eigen::Ref<Mat> X, Eigen::Ref<Mat> Y, ArrowColumns columns) {
  const Index p = F.cols(), sL = st.load_start, nL = st.load_size;
  const bool with_y = Y.rows() > 0;
  eliminate(st, mass, ws, F, G, columns);
  const auto gL = ws.gL.leftCols(p);
  X.middleRows(sL, nL) = gL;
  if (with_y) scatter_rows(st.load_rows, ws.Y0.leftCols(p), Y);
  // Each robot: X_k = Z − Q_k X_L, Y_k = Rc − P_k X_L (the products written into X, Y).
  for (std::size_t k = 0; k < st.groups.size(); ++k) {
    const auto& grp = st.groups[k];
    auto& gb = ws.g[k];
    const Index s = grp.start, nk = grp.size, q = static_cast<Index>(gb.cols.size());
    X.middleRows(s, nk).noalias() = -gb.Q * gL;
    for (Index j = 0; j < q; ++j)
      X.col(gb.cols[static_cast<std::size_t>(j)]).segment(s, nk) += gb.Z.col(j);
    if (!with_y) continue;
    auto R = gb.R.leftCols(p);
    R.noalias() = -gb.P * gL;
    for (Index j = 0; j < q; ++j) R.col(gb.cols[static_cast<std::size_t>(j)]) += gb.Rc.col(j);
    scatter_rows(grp.rows, R, Y);
  }
  // Blocks without rows: X_b = M_b⁻¹ F_b.
  const auto& lay = mass.layout;
  for (std::size_t b = 0; b < lay.blocks(); ++b) {
    if (!ws.other[b]) continue;
    const Index s = lay.start[b], nb = lay.size[b];
    X.middleRows(s, nb) = F.middleRows(s, nb);
    solve_block(mass, s, nb, X.middleRows(s, nb));
  }
}

void arrow_kkt_solve_response(const ArrowStructure& st, const UkWorkspace& mass,
                              ArrowKktWorkspace& ws, const Eigen::Ref<const Mat>& F,
                              const Eigen::Ref<const Mat>& G, ArrowResponse& out) {
  const Index n = F.rows(), p = F.cols();
  eliminate(st, mass, ws, F, G, ArrowColumns::structural);
  const auto& lay = mass.layout;
  std::size_t others = 0;
  for (std::size_t b = 0; b < lay.blocks(); ++b) others += ws.other[b] ? 1 : 0;
  out.blocks.resize(st.groups.size() + others);
  out.rows = n;
  out.cols = p;
  out.load_start = st.load_start;
  out.load_size = st.load_size;
  out.XL = ws.gL.leftCols(p);
  for (std::size_t k = 0; k < st.groups.size(); ++k) {
    const auto& gb = ws.g[k];
    auto& blk = out.blocks[k];
    blk.start = st.groups[k].start;
    blk.size = st.groups[k].size;
    blk.cols = gb.cols;
    blk.own = gb.Z.leftCols(static_cast<Index>(gb.cols.size()));
    blk.Q = gb.Q;
  }
  // Blocks without rows: Own_b = M_b⁻¹ F_b on their own directions.
  std::size_t i = st.groups.size();
  for (std::size_t b = 0; b < lay.blocks(); ++b) {
    if (!ws.other[b]) continue;
    auto& blk = out.blocks[i++];
    blk.start = lay.start[b];
    blk.size = lay.size[b];
    blk.cols.clear();
    for (Index o = 0; o + n <= p; o += n)
      for (Index j = 0; j < blk.size; ++j) blk.cols.push_back(o + blk.start + j);
    blk.own.resize(blk.size, static_cast<Index>(blk.cols.size()));
    for (std::size_t j = 0; j < blk.cols.size(); ++j)
      blk.own.col(static_cast<Index>(j)) = F.col(blk.cols[j]).segment(blk.start, blk.size);
    solve_block(mass, blk.start, blk.size, blk.own);
    blk.Q.resize(0, 0);
  }
}

void arrow_response_expand(const ArrowResponse& r, Eigen::Ref<Mat> X) {
  X.middleRows(r.load_start, r.load_size) = r.XL;
  for (const auto& blk : r.blocks) {
    auto Xb = X.middleRows(blk.start, blk.size);
    if (blk.Q.size() > 0) {
      Xb.noalias() = -blk.Q * r.XL;
    } else {
      Xb.setZero();
    }
    for (std::size_t j = 0; j < blk.cols.size(); ++j)
      Xb.col(blk.cols[j]) += blk.own.col(static_cast<Index>(j));
  }
}

void arrow_response_multiply(const ArrowResponse& r, const Eigen::Ref<const Mat>& V,
                             Eigen::Ref<Mat> out, Mat& scratch) {
  scratch.resize(r.load_size, V.cols());
  scratch.noalias() = r.XL * V;
  out.middleRows(r.load_start, r.load_size) = scratch;
  for (const auto& blk : r.blocks) {
    auto ob = out.middleRows(blk.start, blk.size);
    if (blk.Q.size() > 0) {
      ob.noalias() = -blk.Q * scratch;
    } else {
      ob.setZero();
    }
    for (std::size_t j = 0; j < blk.cols.size(); ++j)
      ob.noalias() += blk.own.col(static_cast<Index>(j)) * V.row(blk.cols[j]);
  }
}

void arrow_add_at_times(const ArrowStructure& st, const ArrowKktWorkspace& ws,
                        const Eigen::Ref<const Mat>& Y, Eigen::Ref<Mat> out) {
  const Index sL = st.load_start, nL = st.load_size;
  for (std::size_t k = 0; k < st.groups.size(); ++k) {
    const auto& grp = st.groups[k];
    const auto& gb = ws.g[k];
    for (std::size_t i = 0; i < grp.rows.size(); ++i) {
      const auto ii = static_cast<Index>(i);
      const auto y = Y.row(grp.rows[i]);
      out.middleRows(grp.start, grp.size).noalias() += gb.B.row(ii).transpose() * y;
      out.middleRows(sL, nL).noalias() += gb.C.row(ii).transpose() * y;
    }
  }
  for (std::size_t i = 0; i < st.load_rows.size(); ++i)
    out.middleRows(sL, nL).noalias() +=
        ws.D0.row(static_cast<Index>(i)).transpose() * Y.row(st.load_rows[i]);
}

}  // namespace ukdyn
