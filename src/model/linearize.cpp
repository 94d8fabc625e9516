// Exact derivatives of the constrained forward dynamics by implicit differentiation of the KKT
// form of Gauss's principle (ukdyn/model/linearize.hpp, docs/derivatives.md).
#include "ukdyn/model/linearize.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "core/dense_kernels.hpp"
#include "model/linearize_corrected.hpp"
#include "ukdyn/core/uk_singular.hpp"
#include "ukdyn/model/column_derivatives.hpp"
#include "ukdyn/model/parameter_sensitivity.hpp"

namespace ukdyn {

namespace {

std::string sci(double v) {
  std::ostringstream os;
  os.precision(3);
  os << v;
  return os.str();
}

void check_size(const char* what, Index expected, Index got) {
  if (expected != got) {
    throw std::invalid_argument(std::string("linearize: ") + what + " has " + std::to_string(got) +
                                " entries, the system has " + std::to_string(expected));
  }
}

// The independent rows of A under the solve's rank rule (σ_k(A M^{-1/2}) > rank_rel_tol σ_1),
// chosen by a column-pivoted QR of (A L^{-T})ᵀ, M = L Lᵀ (the singular values of A L^{-T} are
// those of A M^{-1/2}); and how far the state is from a change of rank. The singular values are
// those of the QR's triangular factor R (Xᵀ P = Q R: the same singular values), so that the one
// factorisation serves both (JacobiSVD would otherwise factorise Xᵀ again as its preconditioner).
// The kept rows go to d.lin.kept_rows; d's buffers are reused (no allocation at the same size).
struct RowChoice {
  double sigma_ratio_kept = 1.0;     // σ_r / σ_1
  double sigma_ratio_dropped = 0.0;  // σ_{r+1} / σ_1
};

// The common case without an SVD: R square (m ≤ n) and so well conditioned that every row is kept
// and none of vouch()'s rank tests can fire. σ_min(R) = 1/‖R⁻¹‖₂ ≥ 1/‖R⁻¹‖_F and σ_max(R) ≤
// ‖R‖_F (Golub & Van Loan, Matrix Computations, 4th ed., §2.3.2), so 1/(‖R⁻¹‖_F ‖R‖_F) is a lower
// bound of σ_m/σ_1; above 200 rank_rel_tol (twice vouch()'s 100, for the round-off of R⁻¹) the SVD
// would keep all m rows and raise no flag: the same rows, the same result. rc.sigma_ratio_kept gets
// the bound. False (the SVD decides) otherwise.
bool bound_keeps_all(double bound, double rel_tol, RowChoice& rc) {
  if (!(std::isfinite(bound) && bound > 200.0 * rel_tol)) return false;
  rc.sigma_ratio_kept = bound;
  return true;
}

bool all_rows_kept(LinearizeData& d, double rel_tol, RowChoice& rc) {
  const Index m = d.R.rows();
  d.Rinv.setIdentity(m, m);
  d.R.triangularView<Eigen::Upper>().solveInPlace(d.Rinv);
  return bound_keeps_all(1.0 / (d.Rinv.norm() * d.R.norm()), rel_tol, rc);
}

// The row choice of the arrow path (forward() took it): the arrow KKT factors, reusing forward()'s
// block Cholesky factors of M (of M_a with a free-body load), and the same bound as
// all_rows_kept(): ‖R‖_F² = tr W and ‖R⁻¹‖_F² = tr W⁻¹ for W = A M⁻¹ Aᵀ = Rᵀ R (permuted), from
// the blocks (ukdyn/core/uk_arrow_kkt.hpp). True with every row kept; false (the dense row choice
// and KKT decide) when a piece cannot be eliminated or the bound does not keep every row.
bool arrow_rows(const System& system, LinearizeData& d, double rel_tol, RowChoice& rc) {
  // From three robots on: with two the dense KKT (50 rows on the shipped systems) costs the same
  // to within the noise (docs/derivatives.md, "Cost") and stays the reference it has been.
  constexpr std::size_t kMinRobots = 3;
  if (!d.allow_arrow || !d.fwd.used_arrow || !d.arrow.built() ||
      system.arrow()->groups.size() < kMinRobots ||
      !arrow_kkt_factor(*system.arrow(), d.fwd.A, d.fwd.uk, rel_tol, d.arrow))
    return false;
  if (!bound_keeps_all(1.0 / std::sqrt(d.arrow.trace_w * d.arrow.trace_w_inv), rel_tol, rc))
    return false;
  d.lin.kept_rows.clear();
  for (Index j = 0; j < system.rows(); ++j) d.lin.kept_rows.push_back(j);
  return true;
}

RowChoice independent_rows(LinearizeData& d, const Mat& Ms, const Mat& A, double rel_tol) {
  RowChoice rc;
  d.lin.kept_rows.clear();
  const Index m = A.rows(), n = A.cols();
  if (m == 0) return rc;
  d.llt.compute(Ms);
  if (d.llt.info() != Eigen::Success)
    throw Error("linearize: the mass matrix is not positive definite");
  // X = A L^{-T}: Xᵀ = L^{-1} Aᵀ.
  d.Xt = A.transpose();
  d.llt.matrixL().solveInPlace(d.Xt);
  d.qr.compute(d.Xt);
  const Index k = std::min(n, m);
  d.R = d.qr.matrixQR().topRows(k).triangularView<Eigen::Upper>();
  if (k == m && all_rows_kept(d, rel_tol, rc)) {
    for (Index j = 0; j < m; ++j) d.lin.kept_rows.push_back(j);
    return rc;
  }
  d.svd.compute(d.R);
  const Vec& s = d.svd.singularValues();
  const double top = s.size() > 0 ? s(0) : 0.0;
  Index r = 0;
  while (r < s.size() && top > 0.0 && s(r) > rel_tol * top) ++r;
  if (r > 0) rc.sigma_ratio_kept = s(r - 1) / top;
  if (r < s.size() && top > 0.0) rc.sigma_ratio_dropped = s(r) / top;
  for (Index j = 0; j < r; ++j) d.lin.kept_rows.push_back(d.qr.colsPermutation().indices()(j));
  std::sort(d.lin.kept_rows.begin(), d.lin.kept_rows.end());
  return rc;
}

void mark(Linearization& lin, const std::string& why) {
  lin.trusted = false;
  lin.message += (lin.message.empty() ? "" : "; ") + why;
}

// Where the derivatives may not be those of the motion: lin.trusted and lin.message
// (docs/derivatives.md, "When ukdyn cannot vouch for them").
void vouch(Linearization& lin, const RowChoice& rc, const UkResult& result,
           const UkSettings& settings, Index m) {
  const Index r = static_cast<Index>(lin.kept_rows.size());
  if (r > 0 && rc.sigma_ratio_kept < 1e2 * settings.rank_rel_tol) {
    mark(lin, "near a singular position: the smallest kept singular value of A M^-1/2 is " +
                  sci(rc.sigma_ratio_kept) + " of the largest, the rank of A may change");
  }
  // Rows dropped as redundant must be so to round-off: a dropped singular value above ~1e4 ε
  // means the rows are nearly, not exactly, dependent (a singular position a step away).
  if (r < m && rc.sigma_ratio_dropped > 1e-12) {
    mark(lin,
         "near a singular position: a dropped row is not redundant to round-off (singular "
         "value " +
             sci(rc.sigma_ratio_dropped) + " of the largest), the rank of A may change");
  }
  if (r != result.rank) {
    mark(lin, "the forward solve kept " + std::to_string(result.rank) + " rows, the derivatives " +
                  std::to_string(r));
  }
  if (result.damping > 0.0 || settings.method == UkMethod::regularized)
    mark(lin,
         "the forward solve was damped (regularized or near a singular position): the "
         "derivatives are those of the exact solution");
  if (!result.consistent) mark(lin, "the constraints are inconsistent at this state");
}

}  // namespace

std::vector<std::string> components_without_derivatives(const System& system) {
  std::vector<std::string> out;
  for (const auto& s : system.subsystems()) {
    if (!s->has_derivatives()) out.push_back("subsystem '" + s->name() + "'");
  }
  const auto& names = system.constraint_row_names();
  const auto& offs = system.constraint_row_offsets();
  for (std::size_t c = 0; c < system.constraints().size(); ++c) {
    if (system.constraints()[c]->has_derivatives()) continue;
    const auto row = static_cast<std::size_t>(offs[c]);
    out.push_back("constraint of row '" + (row < names.size() ? names[row] : std::string("?")) +
                  "'");
  }
  for (const auto& f : system.applied_forces()) {
    if (!f->has_derivatives()) out.push_back("applied force '" + f->name() + "'");
  }
  return out;
}

void state_space(const Linearization& lin, Mat& F, Mat& G) {
  const Index n = lin.dqdd_dq.rows();
  F = Mat::Zero(2 * n, 2 * n);
  F.topRightCorner(n, n).setIdentity();
  F.bottomLeftCorner(n, n) = lin.dqdd_dq;
  F.bottomRightCorner(n, n) = lin.dqdd_dqd;
  G = Mat::Zero(2 * n, n);
  G.bottomRows(n) = lin.dqdd_dtau;
}

LinearizeData::LinearizeData(const System& system)
    : fwd(system),
      Xt(system.dof(), system.rows()),
      llt(system.dof()),
      qr(system.dof(), system.rows()),
      svd(std::min(system.dof(), system.rows()), system.rows()),
      lambda(system.rows()),
      dID(system.dof()),
      dQa(system.dof()),
      dres(system.rows()),
      dforce_c(system.dof()),
      dq(Vec::Zero(system.dof())),
      dqd(Vec::Zero(system.dof())),
      owner(static_cast<std::size_t>(system.dof()), 0),
      arrow(system.arrow() ? ArrowKktWorkspace(*system.arrow(), system.layout(), 2 * system.dof())
                           : ArrowKktWorkspace()) {
  const auto& L = system.layout();
  for (std::size_t k = 0; k < system.subsystems().size(); ++k)
    for (Index i = 0; i < L.size[k]; ++i) owner[static_cast<std::size_t>(L.start[k] + i)] = k;
}

namespace {

// With a structurally singular block augmented (core/uk_singular.hpp; forward() factored M_a),
// M X − Aᵀ Y = F with A_own X = G_own is M_a X − Aᵀ Y = F + A_ownᵀ α G_own: α_i of
// augmented_blocks() (max diag M_k / |a_i|²) on the block's own rows. Every row is kept on the
// arrow path, so row i of G is row i of A. `own_columns` (the arrow path's state columns, 2n of
// them: G's row of a block's own row is zero outside the block's directions of q and of q̇):
// those columns alone, not F's whole rows.
void augment_columns(const System& system, const ForwardData& f, Eigen::Ref<Mat> F,
                     const Eigen::Ref<const Mat>& G, bool own_columns = false) {
  const UkSingularWorkspace& sw = f.singular;
  if (!sw.active) return;
  const auto& lay = system.layout();
  for (std::size_t k = 0; k < lay.blocks(); ++k) {
    if (!sw.structural[k]) continue;
    const Index s = lay.start[k], nk = lay.size[k];
    double scale = f.M.diagonal().segment(s, nk).maxCoeff();
    if (!(scale > 0.0)) scale = 1.0;
    for (const Index i : sw.own_rows[k]) {
      const double nn = f.A.row(i).segment(s, nk).squaredNorm();
      if (!(nn > 0.0)) continue;
      for (Index c = 0; c < nk; ++c) {
        const double coef = scale / nn * f.A(i, s + c);
        if (coef == 0.0) continue;
        if (!own_columns) {
          F.row(s + c) += coef * G.row(i);
          continue;
        }
        for (const Index o : {Index{0}, F.cols() / 2})
          F.row(s + c).segment(o + s, nk) += coef * G.row(i).segment(o + s, nk);
      }
    }
  }
}

// K⁻¹ rhs by the Schur complement (the range-space method: Nocedal & Wright, Numerical
// Optimization, 2nd ed., §16.2), every row kept, with the row choice's factors M = L Lᵀ and
// L⁻¹ Aᵀ = Q R Pᵀ (d.Xt, d.qr, d.R): M x − Aᵀ y = f, A x = g give u = L⁻¹ f,
// y = (A M⁻¹ Aᵀ)⁻¹ (g − (L⁻¹ Aᵀ)ᵀ u) = P R⁻¹ R⁻ᵀ Pᵀ (g − (L⁻¹ Aᵀ)ᵀ u), x = L⁻ᵀ (u + L⁻¹ Aᵀ y).
// rhs is overwritten.
template <class Out>
void schur_solve(LinearizeData& d, Eigen::Ref<Mat> rhs, Out& X) {
  const Index n = d.Xt.rows(), r = rhs.rows() - n;
  auto F = rhs.topRows(n);
  auto G = rhs.bottomRows(r);
  d.llt.matrixL().solveInPlace(F);
  G.noalias() -= d.Xt.transpose() * F;
  auto Y = X.bottomRows(r);
  Y = d.qr.colsPermutation().transpose() * G;
  d.R.transpose().triangularView<Eigen::Lower>().solveInPlace(Y);
  d.R.triangularView<Eigen::Upper>().solveInPlace(Y);
  G = d.qr.colsPermutation() * Y;  // (not in place: Eigen's in-place permutation allocates)
  Y = G;
  F.noalias() += d.Xt * G;
  d.llt.matrixU().solveInPlace(F);
  X.topRows(n) = F;
}

// X = K⁻¹ rhs for the KKT matrix K = [M −A_Rᵀ; A_R 0]: the arrow blocks (rhs's top rows are
// changed by the augmentation), the Schur complement with M_a where forward() augmented M (rhs
// augmented likewise, then overwritten) or the dense LU.
template <class Out>
void kkt_solve(const System& system, LinearizeData& d, Eigen::Ref<Mat> rhs, Out& X) {
  X.resize(rhs.rows(), rhs.cols());
  if (d.used_schur) {
    const Index n = system.dof(), r = rhs.rows() - n;
    augment_columns(system, d.fwd, rhs.topRows(n), rhs.bottomRows(r));
    schur_solve(d, rhs, X);
    return;
  }
  if (!d.used_arrow) {
    X = d.lu.solve(rhs);
    return;
  }
  const Index n = system.dof(), r = rhs.rows() - n;
  augment_columns(system, d.fwd, rhs.topRows(n), rhs.bottomRows(r));
  arrow_kkt_solve(*system.arrow(), d.fwd.uk, d.arrow, rhs.topRows(n), rhs.bottomRows(r),
                  X.topRows(n), X.bottomRows(r));
}

// out += A_Rᵀ Y: by the arrow blocks (every row kept) or the dense product.
void add_at_times(const System& system, const LinearizeData& d, const Eigen::Ref<const Mat>& Y,
                  Eigen::Ref<Mat> out) {
  if (d.used_arrow) {
    arrow_add_at_times(*system.arrow(), d.arrow, Y, out);
  } else {
    out.noalias() += d.AR.transpose() * Y;
  }
}

// Whether augment_columns() augments the right-hand sides as forward()'s singular solve augmented
// the M_a the row choice factorised (after an arrow forward() solve dense_rows() augments with the
// own rows itself: they agree): forward() augments each singular block with
// the rows lying in it alone at the state (row_block), or all of M when it went dense;
// augment_columns() adds the structural blocks' declared own rows. They agree when forward() did
// not go dense, augmented no block but the structural ones, and each structural block's rows are
// its own rows. (A row on a free body alone that declares no sparsity, a `coordinate` row on its z
// say, is in row_block but not in own_rows: the Schur solve would then miss its augmentation.)
bool augmentation_matches(const System& system, const ForwardData& f) {
  const UkSingularWorkspace& sw = f.singular;
  if (!sw.active || f.used_arrow) return true;  // after the arrow solve: dense_rows()' own rows
  if (sw.dense_used) return false;
  const auto& lay = system.layout();
  for (std::size_t k = 0; k < lay.blocks(); ++k) {
    const Index s = lay.start[k], nk = lay.size[k];
    if (!sw.structural[k]) {
      if (sw.Ma.block(s, s, nk, nk) != f.M.block(s, s, nk, nk)) return false;
      continue;
    }
    std::size_t in_block = 0;
    for (std::size_t i = 0; i < sw.row_block.size(); ++i) {
      if (sw.row_block[i] != static_cast<Index>(k)) continue;
      ++in_block;
      const auto& own = sw.own_rows[k];
      if (std::find(own.begin(), own.end(), static_cast<Index>(i)) == own.end()) return false;
    }
    if (in_block != sw.own_rows[k].size()) return false;
  }
  return true;
}

// Whether the dense KKT system can be solved by the row choice's factors (schur_solve): every
// row kept, R square, and A M^{-1/2} far enough from singular (σ_m/σ_1 ≥ 1e-3) that solving with
// R twice loses no more than an LU of K would. (With a structurally singular block the row choice
// factorised the augmented M_a: kkt_solve augments the right-hand sides to match, where it can:
// augmentation_matches().)
bool schur_applies(const System& system, const LinearizeData& d, const RowChoice& rc, Index r) {
  const Index m = d.fwd.A.rows();
  return d.allow_schur && d.allow_arrow && !d.used_arrow && m > 0 && r == m && d.R.rows() == m &&
         d.R.cols() == m && d.Xt.cols() == m && rc.sigma_ratio_kept >= 1e-3 &&
         augmentation_matches(system, d.fwd);
}

// The KKT matrix of the kept rows, [M −A_Rᵀ; A_R 0], factorised (unless the arrow blocks or the
// row choice's factors solve it), and [q̈; μ] at the state (d.sol); Qc, μ, q̈ and the agreement
// with forward()'s q̈ into d.lin. `v`: a correction of b (m; linearize_corrected()), or null.
void solve_kkt(const System& system, LinearizeData& d, Index n, const RowChoice& rc,
               const Vec* v = nullptr) {
  const ForwardData& f = d.fwd;
  Linearization& lin = d.lin;
  const auto r = static_cast<Index>(lin.kept_rows.size());
  // Every row kept (kept_rows ascend): b_R = b, and A_R = A is read by its blocks on the arrow
  // path (arrow_add_at_times, not copied), else copied whole.
  d.AR.resize(d.used_arrow ? 0 : r, n);
  d.bR.resize(r);
  if (r == f.A.rows()) {
    if (!d.used_arrow) d.AR = f.A;
    d.bR = f.b;
    if (v != nullptr) d.bR += *v;
  }
  for (Index k = 0; k < r && r < f.A.rows(); ++k) {
    d.AR.row(k) = f.A.row(lin.kept_rows[static_cast<std::size_t>(k)]);
    d.bR(k) = f.b(lin.kept_rows[static_cast<std::size_t>(k)]);
    if (v != nullptr) d.bR(k) += (*v)(lin.kept_rows[static_cast<std::size_t>(k)]);
  }
  d.used_schur = schur_applies(system, d, rc, r);
  if (!d.used_arrow && !d.used_schur) {
    d.K.resize(n + r, n + r);
    d.K.setZero();
    d.K.topLeftCorner(n, n) = f.M;
    d.K.topRightCorner(n, r) = -d.AR.transpose();
    d.K.bottomLeftCorner(r, n) = d.AR;
    d.lu.compute(d.K);
  }
  d.rhs.resize(n + r);
  d.rhs.head(n) = f.Q;
  d.rhs.tail(r) = d.bR;
  kkt_solve(system, d, d.rhs, d.sol);
  if (!d.sol.allFinite()) throw Error("linearize: the KKT matrix of the constraints is singular");
  lin.qdd = d.sol.head(n);
  lin.mu = d.sol.tail(r);
  lin.Qc.setZero(n);
  add_at_times(system, d, Eigen::Map<const Mat>(lin.mu.data(), r, 1),
               Eigen::Map<Mat>(lin.Qc.data(), n, 1));
  lin.kkt_agreement =
      v != nullptr ? 0.0
                   : (lin.qdd - f.qdd).cwiseAbs().maxCoeff() / (1.0 + f.qdd.cwiseAbs().maxCoeff());
  if (!(lin.kkt_agreement <= 1e-8)) {
    mark(lin, "the U-K and KKT accelerations differ by " + sci(lin.kkt_agreement));
  }
  // λ over all rows (0 on the dropped ones) for the constraints' tangents.
  d.lambda.setZero();
  for (Index k = 0; k < r; ++k) d.lambda(lin.kept_rows[static_cast<std::size_t>(k)]) = lin.mu(k);
}

// The right-hand sides of the differentiated KKT system, column j < n along e_j of q, column n + j
// along e_j of q̇ (d.rhs_all), and d(Aᵀλ) (d.dforce_all), from the components' tangents. A
// subsystem's inverse dynamics depends on its own coordinates only (M, C, G are block-diagonal,
// paper Eq. (10)-(11)): its derivatives fill its diagonal blocks, in one call of
// inverse_dynamics_jacobian() where it has one (a tree: every direction on the lanes of one pass),
// else one inverse_dynamics_tangent() per direction of its coordinates.
void subsystem_columns(const System& system, LinearizeData& d, double t, CVecRef q, CVecRef qd,
                       std::size_t k) {
  const Index n = system.dof(), s = system.layout().start[k], nk = system.layout().size[k];
  const Subsystem& sub = *system.subsystems()[k];
  const EvalContext ctx{t, d.fwd.subsystem_slot(k)};
  const Vec& qdd = d.lin.qdd;
  auto dq = d.rhs_all.block(s, s, nk, nk), dqd = d.rhs_all.block(s, n + s, nk, nk);
  const auto* all = dynamic_cast<const SubsystemColumns*>(&sub);
  if (all != nullptr && all->inverse_dynamics_jacobian(ctx, q.segment(s, nk), qd.segment(s, nk),
                                                       qdd.segment(s, nk), dq, dqd)) {
    dq = -dq;
    dqd = -dqd;
    return;
  }
  for (Index j = s; j < s + nk; ++j) {
    for (const bool rate : {false, true}) {
      (rate ? d.dqd : d.dq)(j) = 1.0;
      auto dID = d.dID.segment(s, nk);
      if (!sub.inverse_dynamics_tangent(ctx, q.segment(s, nk), qd.segment(s, nk),
                                        qdd.segment(s, nk), d.dq.segment(s, nk),
                                        d.dqd.segment(s, nk), dID))
        throw Error("linearize: subsystem '" + sub.name() + "' has no exact derivatives");
      d.rhs_all.col(rate ? n + j : j).segment(s, nk) = -dID;
      (rate ? d.dqd : d.dq)(j) = 0.0;
    }
  }
}

// The applied forces' dQa along each direction, added to the columns.
void applied_force_columns(const System& system, LinearizeData& d, double t, CVecRef q,
                           CVecRef qd) {
  const Index n = system.dof();
  if (system.applied_forces().empty()) return;
  for (Index col = 0; col < 2 * n; ++col) {
    VecRef dir = col < n ? d.dq : d.dqd;
    dir(col % n) = 1.0;
    d.dQa.setZero();
    for (const auto& f : system.applied_forces()) {
      if (!f->add_tangent(t, q, qd, d.dq, d.dqd, d.dQa))
        throw Error("linearize: applied force '" + f->name() + "' has no exact derivatives");
    }
    d.rhs_all.col(col).head(n) += d.dQa;
    dir(col % n) = 0.0;
  }
}

// Constraint c's d(A q̈ − b) (its rows of dres_all: m × 2n) and d(Aᵀλ) (added to dforce_all) at
// (q̈, λ) along every direction: in one tangent_columns() call where it has one, else one
// tangent() each.
void constraint_columns(const System& system, LinearizeData& d, double t, CVecRef q, CVecRef qd,
                        std::size_t c, CVecRef qdd, CVecRef lambda_all, Eigen::Ref<Mat> dres_all,
                        Mat& dforce_all) {
  const Index n = system.dof();
  const Constraint& con = *system.constraints()[c];
  const Index rows = con.rows(), off = system.constraint_row_offsets()[c];
  const ConstraintContext ctx{t, d.fwd.constraint_slots(c)};
  const auto lambda = lambda_all.segment(off, rows);
  auto dres = dres_all.middleRows(off, rows);
  const auto* all = dynamic_cast<const ConstraintColumns*>(&con);
  if (all != nullptr && all->tangent_columns(ctx, q, qd, qdd, lambda, dres, dforce_all)) return;
  for (Index col = 0; col < 2 * n; ++col) {
    VecRef dir = col < n ? d.dq : d.dqd;
    dir(col % n) = 1.0;
    d.dforce_c.setZero();
    if (!con.tangent(ctx, q, qd, qdd, lambda, d.dq, d.dqd, dres.col(col), d.dforce_c))
      throw Error("linearize: a constraint has no exact derivatives");
    dforce_all.col(col) += d.dforce_c;
    dir(col % n) = 0.0;
  }
}

// With lin.dmu_dq, lin.dmu_dqd stored (constraint_force): ∂Qc/∂(q, q̇), and the τ columns, solved
// here with the same factorisation.
void store_force_and_tau(const System& system, LinearizeData& d, Index n, LinearizeParts parts);

// The derivatives from the solved columns X = K⁻¹ [rhs along e_j of q | of q̇] (n + r rows: dq̈
// over dμ) and the τ columns, solved here with the same factorisation.
void store_solutions(const System& system, LinearizeData& d, Index n, LinearizeParts parts) {
  Linearization& lin = d.lin;
  const auto r = static_cast<Index>(d.lin.kept_rows.size());
  const Mat& X = d.X;
  lin.dqdd_dq = X.topLeftCorner(n, n);
  lin.dqdd_dqd = X.topRightCorner(n, n);
  if (parts.constraint_force) {
    lin.dmu_dq = X.bottomLeftCorner(r, n);
    lin.dmu_dqd = X.bottomRightCorner(r, n);
  }
  store_force_and_tau(system, d, n, parts);
}

void store_force_and_tau(const System& system, LinearizeData& d, Index n, LinearizeParts parts) {
  Linearization& lin = d.lin;
  const auto r = static_cast<Index>(d.lin.kept_rows.size());
  if (parts.constraint_force) {
    // dQc = (dA_R)ᵀ μ + A_Rᵀ dμ
    lin.dQc_dq = d.dforce_all.leftCols(n);
    add_at_times(system, d, lin.dmu_dq, lin.dQc_dq);
    lin.dQc_dqd = d.dforce_all.rightCols(n);
    add_at_times(system, d, lin.dmu_dqd, lin.dQc_dqd);
  } else {
    lin.dQc_dq.resize(0, 0);
    lin.dQc_dqd.resize(0, 0);
    lin.dmu_dq.resize(0, 0);
    lin.dmu_dqd.resize(0, 0);
  }
  if (!parts.tau || !parts.constraint_force) {
    lin.dQc_dtau.resize(0, 0);
    lin.dmu_dtau.resize(0, 0);
  }
  if (!parts.tau) {
    lin.dqdd_dtau.resize(0, 0);
    return;
  }
  // τ enters Q alone: M dq̈ − A_Rᵀ dμ = e_j, A_R dq̈ = 0.
  d.rhs_tau.resize(n + r, n);
  d.rhs_tau.setZero();
  d.rhs_tau.topRows(n).setIdentity();
  kkt_solve(system, d, d.rhs_tau, d.X_tau);
  lin.dqdd_dtau = d.X_tau.topRows(n);
  if (!parts.constraint_force) return;
  lin.dQc_dtau.setZero(n, n);
  add_at_times(system, d, d.X_tau.bottomRows(r), lin.dQc_dtau);
  lin.dmu_dtau = d.X_tau.bottomRows(r);
}

void check_sizes(const System& system, double t, CVecRef q, CVecRef qd, CVecRef tau) {
  const Index n = system.dof();
  check_size("q", n, q.size());
  check_size("qd", n, qd.size());
  check_size("tau", n, tau.size());
  if (!(std::isfinite(t) && q.allFinite() && qd.allFinite() && tau.allFinite()))
    throw std::invalid_argument("linearize: t, q, qd and tau must be finite");
}

void require_derivatives(const System& system) {
  if (const auto missing = components_without_derivatives(system); !missing.empty()) {
    std::string list;
    for (const auto& s : missing) list += (list.empty() ? "" : ", ") + s;
    throw Error("linearize: no exact derivatives for " + list +
                " (docs/derivatives.md lists the kinds that have them)");
  }
}

void check_inputs(const System& system, double t, CVecRef q, CVecRef qd, CVecRef tau) {
  check_sizes(system, t, q, qd, tau);
  require_derivatives(system);
}

// The dense row choice with M, or the augmented M_a the solve used (solved_mass(), formed here in
// d.Ms after the arrow solve).
RowChoice dense_rows(const System& system, LinearizeData& d, const UkSettings& settings) {
  const ForwardData& f = d.fwd;
  const Mat* Ms = &f.M;
  if (f.singular.active && !f.used_arrow) Ms = &f.singular.Ma;
  if (f.singular.active && f.used_arrow) {
    d.Ms = f.M;
    d.Qa = f.Q;
    augmented_blocks(system.layout(), f.A, f.b, f.singular, d.Ms, d.Qa);
    Ms = &d.Ms;
  }
  return independent_rows(d, *Ms, f.A, settings.rank_rel_tol);
}

// forward() at the state, the kept rows, the trust of the result and the KKT solve: what every
// column of the derivatives (state directions, parameters) is solved with.
void prepare_kkt(const System& system, LinearizeData& d, double t, CVecRef q, CVecRef qd,
                 CVecRef tau, const UkSettings& settings, const Vec* v = nullptr) {
  const Index n = system.dof(), m = system.rows();
  check_data_for(system, d.fwd, "linearize");
  Linearization& lin = d.lin;
  lin.trusted = true;
  lin.message.clear();
  forward(system, d.fwd, t, q, qd, tau, settings);
  if (!d.fwd.result.finite)
    throw Error("linearize: the forward dynamics is not finite at this state");
  RowChoice rc;
  d.used_arrow = arrow_rows(system, d, settings.rank_rel_tol, rc);
  if (!d.used_arrow) rc = dense_rows(system, d, settings);
  lin.rank = static_cast<int>(lin.kept_rows.size());
  vouch(lin, rc, d.fwd.result, settings, m);
  solve_kkt(system, d, n, rc, v);
}

// The structural pattern of the arrow path's right-hand sides (no applied forces; every row of A
// kept, so row i of G is row i of A): a robot's rows of A touch its own and the load's
// coordinates, so along a direction of another robot its F_k (= −dID_k + d(Aᵀλ)_k) and G_k
// (= −d(A q̈ − b)_k) are zero; the load's F_L takes every direction. Calls f(row start, rows,
// column start, columns) for robot k's rows of F (n × 2n) by its own and the load's directions
// of q and of q̇, and for the load's rows by every direction.
template <class Fn>
void for_arrow_pattern(const ArrowStructure& st, Index n, Fn&& f) {
  for (const auto& grp : st.groups) {
    for (const Index o : {Index{0}, n}) {
      f(grp.start, grp.size, o + grp.start, grp.size);
      f(grp.start, grp.size, o + st.load_start, st.load_size);
    }
  }
  f(st.load_start, st.load_size, Index{0}, 2 * n);
}

// The blocks constraint c's rows touch on the arrow path: f(start, size) for each robot of their
// groups (once each) and for the load.
template <class Fn>
void for_constraint_blocks(const ArrowStructure& st, const LinearizeData& d, Index off, Index rows,
                           Fn&& f) {
  for (Index i = 0; i < rows; ++i) {
    const Index g = d.row_group[static_cast<std::size_t>(off + i)];
    bool seen = g < 0;
    for (Index j = 0; j < i && !seen; ++j)
      seen = d.row_group[static_cast<std::size_t>(off + j)] == g;
    if (!seen)
      f(st.groups[static_cast<std::size_t>(g)].start, st.groups[static_cast<std::size_t>(g)].size);
  }
  f(st.load_start, st.load_size);
}

// Constraint c's tangents on the arrow path: d(A q̈ − b) into the contiguous d.dres_cols, whose
// columns of the blocks its rows touch (its groups' robots and the load, what is read below) are
// zeroed first and then written by a structural_only tangent_columns() pass (its row_columns()'
// directions alone: O(columns), not O(n) per constraint), then −d(A q̈ − b) of each row by its
// group's directions into G; d(Aᵀλ) added to d.dforce_all. Without tangent_columns(), tangent()
// along the directions of those blocks only (the others move none of its coordinates: zero).
void arrow_constraint_columns(const System& system, LinearizeData& d, double t, CVecRef q,
                              CVecRef qd, std::size_t c) {
  const Index n = system.dof();
  const ArrowStructure& st = *system.arrow();
  const Constraint& con = *system.constraints()[c];
  const Index rows = con.rows(), off = system.constraint_row_offsets()[c];
  const ConstraintContext ctx{t, d.fwd.constraint_slots(c), /*structural_only=*/true};
  const auto lambda = d.lambda.segment(off, rows);
  if (d.dres_cols.size() < rows * 2 * n) d.dres_cols.resize(rows * 2 * n);
  Eigen::Map<Mat> dres(d.dres_cols.data(), rows, 2 * n);
  for_constraint_blocks(st, d, off, rows, [&](Index s0, Index nb) {
    for (const Index o : {Index{0}, n}) dres.middleCols(o + s0, nb).setZero();
  });
  const auto* all = dynamic_cast<const ConstraintColumns*>(&con);
  if (all == nullptr || !all->tangent_columns(ctx, q, qd, d.lin.qdd, lambda, dres, d.dforce_all)) {
    for_constraint_blocks(st, d, off, rows, [&](Index s0, Index nb) {
      for (const Index col : {Index{0}, n}) {
        for (Index j = s0; j < s0 + nb; ++j) {
          VecRef dir = col == 0 ? d.dq : d.dqd;
          dir(j) = 1.0;
          d.dforce_c.setZero();
          if (!con.tangent(ctx, q, qd, d.lin.qdd, lambda, d.dq, d.dqd, dres.col(col + j),
                           d.dforce_c))
            throw Error("linearize: a constraint has no exact derivatives");
          for_constraint_blocks(st, d, off, rows, [&](Index r0, Index nr) {
            d.dforce_all.col(col + j).segment(r0, nr) += d.dforce_c.segment(r0, nr);
          });
          dir(j) = 0.0;
        }
      }
    });
  }
  auto G = d.rhs_all.bottomRows(system.rows());
  for (Index i = 0; i < rows; ++i) {
    const Index g = d.row_group[static_cast<std::size_t>(off + i)];
    for (const Index o : {Index{0}, n}) {
      if (g >= 0) {
        const auto& grp = st.groups[static_cast<std::size_t>(g)];
        G.row(off + i).segment(o + grp.start, grp.size) =
            -dres.row(i).segment(o + grp.start, grp.size);
      }
      G.row(off + i).segment(o + st.load_start, st.load_size) =
          -dres.row(i).segment(o + st.load_start, st.load_size);
    }
  }
}

// The arrow path's state columns without touching the (n + m) × 2n right-hand sides outside their
// structural pattern (for_arrow_pattern; the entries outside it were zeroed once and nothing
// writes them while d.rhs_pattern holds): O(N) blocks zeroed, summed and signed, in place of
// O(N²) entries. The subsystems assign their diagonal blocks of F, the constraints write their
// rows of G by their groups' directions (arrow_constraint_columns) and add d(Aᵀλ) into
// d.dforce_all, summed into F after (as the dense path sums them: the same bits). Then either the
// dense ∂q̈/∂(q, q̇) straight into lin.dqdd_dq, lin.dqdd_dqd (one solve per half: X_k = own − Q_k X_L
// written there; the robots' dμ only with constraint_force) or the structured d.dqdd_dx.
void arrow_state_columns(const System& system, LinearizeData& d, double t, CVecRef q, CVecRef qd,
                         LinearizeParts parts) {
  const Index n = system.dof(), m = system.rows();
  const ArrowStructure& st = *system.arrow();
  if (!d.rhs_pattern || d.rhs_all.rows() != n + m || d.rhs_all.cols() != 2 * n ||
      d.dforce_all.rows() != n || d.dforce_all.cols() != 2 * n) {
    d.rhs_all.setZero(n + m, 2 * n);
    d.dforce_all.setZero(n, 2 * n);
    d.row_group.assign(static_cast<std::size_t>(m), -1);
    for (std::size_t k = 0; k < st.groups.size(); ++k)
      for (const Index i : st.groups[k].rows)
        d.row_group[static_cast<std::size_t>(i)] = static_cast<Index>(k);
    d.rhs_pattern = true;
  }
  for_arrow_pattern(st, n, [&](Index r0, Index nr, Index c0, Index nc) {
    d.dforce_all.block(r0, c0, nr, nc).setZero();
    if (r0 == st.load_start || c0 % n == st.load_start) d.rhs_all.block(r0, c0, nr, nc).setZero();
  });
  for (std::size_t k = 0; k < system.subsystems().size(); ++k)
    subsystem_columns(system, d, t, q, qd, k);
  for (std::size_t c = 0; c < system.constraints().size(); ++c)
    arrow_constraint_columns(system, d, t, q, qd, c);
  for_arrow_pattern(st, n, [&](Index r0, Index nr, Index c0, Index nc) {
    d.rhs_all.block(r0, c0, nr, nc) += d.dforce_all.block(r0, c0, nr, nc);
  });
  auto G = d.rhs_all.bottomRows(m);
  auto F = d.rhs_all.topRows(n);
  augment_columns(system, d.fwd, F, G, /*own_columns=*/true);
  Linearization& lin = d.lin;
  d.structured = parts.structured && !parts.constraint_force;
  if (d.structured) {
    arrow_kkt_solve_response(st, d.fwd.uk, d.arrow, F, G, d.dqdd_dx);
    lin.dqdd_dq.resize(0, 0);
    lin.dqdd_dqd.resize(0, 0);
  } else {
    lin.dqdd_dq.resize(n, n);
    lin.dqdd_dqd.resize(n, n);
    const Index ry = parts.constraint_force ? m : 0;
    lin.dmu_dq.resize(ry, ry > 0 ? n : 0);
    lin.dmu_dqd.resize(ry, ry > 0 ? n : 0);
    arrow_kkt_solve(st, d.fwd.uk, d.arrow, F.leftCols(n), G.leftCols(n), lin.dqdd_dq, lin.dmu_dq,
                    ArrowColumns::structural);
    arrow_kkt_solve(st, d.fwd.uk, d.arrow, F.rightCols(n), G.rightCols(n), lin.dqdd_dqd,
                    lin.dmu_dqd, ArrowColumns::structural);
  }
  store_force_and_tau(system, d, n, parts);
}

// The state columns (∂/∂q, ∂/∂q̇ and, as `parts` asks, ∂/∂τ) from the components' exact tangents.
void state_columns(const System& system, LinearizeData& d, double t, CVecRef q, CVecRef qd,
                   LinearizeParts parts, const RhsCorrection* corr = nullptr) {
  d.structured = false;
  if (corr == nullptr && d.used_arrow && system.applied_forces().empty()) {
    arrow_state_columns(system, d, t, q, qd, parts);
    return;
  }
  d.rhs_pattern = false;
  const Index n = system.dof(), r = static_cast<Index>(d.lin.kept_rows.size());
  // The directions e_j of q and of q̇: the right-hand sides of the differentiated KKT system, one
  // column each, solved together with the one factorisation.
  // Rows n .. n + m − 1 of d.rhs_all take d(A q̈ − b) of every row, then −d(A_R q̈ − b_R) of the
  // kept rows moves up to rows n .. n + r − 1 (kept_rows ascend: a row is read before it is
  // overwritten), what the solve reads; its size stays (n + m) × 2n (no allocation).
  d.rhs_all.setZero(n + system.rows(), 2 * n);
  d.dforce_all.setZero(n, 2 * n);
  for (std::size_t k = 0; k < system.subsystems().size(); ++k)
    subsystem_columns(system, d, t, q, qd, k);
  applied_force_columns(system, d, t, q, qd);
  const Index m = system.rows();
  for (std::size_t c = 0; c < system.constraints().size(); ++c)
    constraint_columns(system, d, t, q, qd, c, d.lin.qdd, d.lambda, d.rhs_all.middleRows(n, m),
                       d.dforce_all);
  d.rhs_all.topRows(n) += d.dforce_all;
  if (corr != nullptr) {  // b + v: d(A q̈ − b − v) with dv = ∂v/∂Φ dΦ + ∂v/∂Φ̇ dΦ̇ (holonomic rows)
    const Mat dphid_dq = 0.5 * d.rhs_all.block(n, n, m, n);  // ∂Φ̇/∂q = −½ ∂b/∂q̇
    d.rhs_all.block(n, 0, m, n) -= corr->dv_dphi * d.fwd.A + corr->dv_dphid * dphid_dq;
    d.rhs_all.block(n, n, m, n) -= corr->dv_dphid * d.fwd.A;
  }
  if (r == system.rows()) {  // every row kept: in place, a block at a time
    d.rhs_all.middleRows(n, r) *= -1.0;
  } else {
    for (Index i = 0; i < r; ++i)
      d.rhs_all.row(n + i) = -d.rhs_all.row(n + d.lin.kept_rows[static_cast<std::size_t>(i)]);
  }
  kkt_solve(system, d, d.rhs_all.topRows(n + r), d.X);
  store_solutions(system, d, n, parts);
}

// X ← M⁻¹ X (at most 2n columns) with forward()'s block Cholesky factors of M (d.fwd.uk: L_k L_kᵀ
// per subsystem). Each block's two triangular solves run on Y = X_kᵀ (columns × n_k, in d.X, kept
// 2n × n), whose columns are X's rows as contiguous vectors: y_i ← (y_i − Σ_l L_il y_l) / L_ii
// forward, then with Lᵀ backward, every step one vectorised update of all the columns at once (not
// a dependency chain per column).
void mass_solve_columns(const System& system, LinearizeData& d, Eigen::Ref<Mat> X) {
  const auto& lay = system.layout();
  const UkWorkspace& uk = d.fwd.uk;
  const Index ldl = uk.L.rows(), c = X.cols(), n = system.dof();
  d.X.resize(2 * n, n);
  const Index ld = d.X.rows();
  for (std::size_t k = 0; k < lay.blocks(); ++k) {
    const Index s = lay.start[k], nk = lay.size[k];
    const double* Lk = uk.L.data() + s + s * ldl;
    const double* inv = uk.inv_diag.data() + s;
    auto Y = d.X.topLeftCorner(c, nk);
    Y = X.middleRows(s, nk).transpose();
    double* y = d.X.data();                    // column i of Y at y + i ld
    detail::with_block_size(nk, [&](auto N) {  // the loops over the block unrolled for its size
      const Index nb = decltype(N)::value > 0 ? Index{decltype(N)::value} : nk;
      const auto update = [&](Index i, Index l, double a) {
        double* yi = y + i * ld;
        const double* yl = y + l * ld;
        for (Index r = 0; r < c; ++r) yi[r] -= a * yl[r];
      };
      const auto scale = [&](Index i) {
        double* yi = y + i * ld;
        for (Index r = 0; r < c; ++r) yi[r] *= inv[i];
      };
      for (Index i = 0; i < nb; ++i) {
        for (Index l = 0; l < i; ++l) update(i, l, Lk[i + l * ldl]);
        scale(i);
      }
      for (Index i = nb; i-- > 0;) {
        for (Index l = i + 1; l < nb; ++l) update(i, l, Lk[l + i * ldl]);
        scale(i);
      }
    });
    X.middleRows(s, nk) = Y.transpose();
  }
}

// Without constraint rows (m = 0) there is no KKT system: M q̈ = Q, so
//   ∂q̈/∂x = M⁻¹ (∂Q_a/∂x − ∂ID/∂x)|_q̈,   ∂q̈/∂τ = M⁻¹,   Qc = 0, μ empty, rank 0
// (the ABA's derivatives as M⁻¹ times the RNEA's: J. Carpentier, N. Mansard, "Analytical
// Derivatives of Rigid Body Dynamics Algorithms", RSS 2018, §III), every column solved with
// forward()'s own Cholesky factors of M. Taken unless the reference is asked for (allow_schur or
// allow_arrow false: the LU of K = M below) or forward() solved with an augmented M (a
// structurally singular block); false then, and the general path runs. Allocation-free after the
// first call.
bool linearize_without_rows(const System& system, LinearizeData& d, double t, CVecRef q, CVecRef qd,
                            CVecRef tau, const UkSettings& settings, LinearizeParts parts) {
  const Index n = system.dof();
  if (system.rows() != 0 || !d.allow_schur || !d.allow_arrow) return false;
  check_data_for(system, d.fwd, "linearize");
  forward(system, d.fwd, t, q, qd, tau, settings);
  if (!d.fwd.result.finite)
    throw Error("linearize: the forward dynamics is not finite at this state");
  if (d.fwd.used_arrow || d.fwd.singular.active) return false;
  Linearization& lin = d.lin;
  lin.trusted = true;
  lin.message.clear();
  lin.kept_rows.clear();
  lin.rank = 0;
  vouch(lin, RowChoice{}, d.fwd.result, settings, 0);
  d.used_arrow = d.used_schur = d.structured = d.rhs_pattern = false;
  lin.qdd = d.fwd.qdd;
  lin.Qc.setZero(n);
  lin.mu.resize(0);
  lin.kkt_agreement = 0.0;
  // rhs_all (n × 2n): −∂ID/∂(q, q̇) in the subsystems' diagonal blocks, plus ∂Q_a.
  d.rhs_all.resize(n, 2 * n);
  if (system.subsystems().size() > 1) d.rhs_all.setZero();
  for (std::size_t k = 0; k < system.subsystems().size(); ++k)
    subsystem_columns(system, d, t, q, qd, k);
  applied_force_columns(system, d, t, q, qd);
  mass_solve_columns(system, d, d.rhs_all);
  lin.dqdd_dq = d.rhs_all.leftCols(n);
  lin.dqdd_dqd = d.rhs_all.rightCols(n);
  const bool force = parts.constraint_force;
  lin.dmu_dq.resize(0, force ? n : 0);
  lin.dmu_dqd.resize(0, force ? n : 0);
  lin.dmu_dtau.resize(0, force && parts.tau ? n : 0);
  if (force) {
    lin.dQc_dq.setZero(n, n);
    lin.dQc_dqd.setZero(n, n);
  } else {
    lin.dQc_dq.resize(0, 0);
    lin.dQc_dqd.resize(0, 0);
  }
  if (force && parts.tau) {
    lin.dQc_dtau.setZero(n, n);
  } else {
    lin.dQc_dtau.resize(0, 0);
  }
  if (!parts.tau) {
    lin.dqdd_dtau.resize(0, 0);
    return true;
  }
  lin.dqdd_dtau.setIdentity(n, n);
  mass_solve_columns(system, d, lin.dqdd_dtau);
  return true;
}

// The right-hand side of the time column (dt = 1, dq = dq̇ = dτ = 0) into d.rhs_t (n + r):
// −∂ID/∂t + ∂Q_a/∂t + ∂(Aᵀλ)/∂t over −∂(A_R q̈ − b_R)/∂t, and ∂(Aᵀλ)/∂t into d.dforce_t, from
// the components' time tangents. False with lin.time_message naming the first component without
// an exact ∂/∂t.
bool time_rhs(const System& system, LinearizeData& d, double t, CVecRef q, CVecRef qd) {
  const Index n = system.dof(), m = system.rows();
  const auto r = static_cast<Index>(d.lin.kept_rows.size());
  Linearization& lin = d.lin;
  d.rhs_t.setZero(n + r);
  d.dforce_t.setZero(n);
  d.dres_t.resize(m);
  const auto& lay = system.layout();
  for (std::size_t k = 0; k < system.subsystems().size(); ++k) {
    const Subsystem& sub = *system.subsystems()[k];
    const Index s = lay.start[k], nk = lay.size[k];
    auto dID = d.dID.segment(s, nk);
    if (!sub.inverse_dynamics_time_tangent(EvalContext{t, d.fwd.subsystem_slot(k)},
                                           q.segment(s, nk), qd.segment(s, nk),
                                           lin.qdd.segment(s, nk), dID)) {
      lin.time_message = "no exact d/dt for subsystem '" + sub.name() + "'";
      return false;
    }
    d.rhs_t.segment(s, nk) = -dID;
  }
  for (const auto& f : system.applied_forces()) {
    if (!f->add_time_tangent(t, q, qd, d.rhs_t.head(n))) {
      lin.time_message = "no exact d/dt for applied force '" + f->name() + "'";
      return false;
    }
  }
  const auto& offs = system.constraint_row_offsets();
  for (std::size_t c = 0; c < system.constraints().size(); ++c) {
    const Constraint& con = *system.constraints()[c];
    const Index rows = con.rows(), off = offs[c];
    if (!con.time_tangent(ConstraintContext{t, d.fwd.constraint_slots(c)}, q, qd, lin.qdd,
                          d.lambda.segment(off, rows), d.dres_t.segment(off, rows), d.dforce_t)) {
      const auto& names = system.constraint_row_names();
      const auto row = static_cast<std::size_t>(off);
      lin.time_message = "no exact d/dt for constraint of row '" +
                         (row < names.size() ? names[row] : std::string("?")) + "'";
      return false;
    }
  }
  d.rhs_t.head(n) += d.dforce_t;
  for (Index i = 0; i < r; ++i)
    d.rhs_t(n + i) = -d.dres_t(d.lin.kept_rows[static_cast<std::size_t>(i)]);
  return true;
}

// ∂q̈/∂t, ∂μ/∂t and ∂Qc/∂t (dQc = ∂(Aᵀλ)/∂t + A_Rᵀ dμ) as `parts` asks: one more right-hand side
// of the factorisation the state columns used (dense LU, Schur complement or arrow blocks alike;
// `without_rows`: linearize_without_rows() ran, M⁻¹ with forward()'s Cholesky factors of M).
// `dv_dt`: ∂v/∂t of a correction b + v (m; linearize_corrected_time()), or null.
void time_column(const System& system, LinearizeData& d, double t, CVecRef q, CVecRef qd,
                 LinearizeParts parts, bool without_rows = false, const Vec* dv_dt = nullptr) {
  Linearization& lin = d.lin;
  lin.time_message.clear();
  const Index n = system.dof(), r = static_cast<Index>(lin.kept_rows.size());
  if (!parts.time || !time_rhs(system, d, t, q, qd)) {
    lin.dqdd_dt.resize(0);
    lin.dQc_dt.resize(0);
    lin.dmu_dt.resize(0);
    return;
  }
  for (Index i = 0; i < r && dv_dt != nullptr; ++i)  // A q̈ = b + v: ∂(A q̈ − b − v)/∂t
    d.rhs_t(n + i) += (*dv_dt)(lin.kept_rows[static_cast<std::size_t>(i)]);
  if (without_rows) {  // r = 0: rhs_t is −∂ID/∂t + ∂Q_a/∂t alone
    mass_solve_columns(system, d, Eigen::Map<Mat>(d.rhs_t.data(), n, 1));
    d.sol_t = d.rhs_t;
  } else {
    kkt_solve(system, d, d.rhs_t, d.sol_t);
  }
  lin.dqdd_dt = d.sol_t.head(n);
  lin.dmu_dt = d.sol_t.tail(r);
  lin.dQc_dt = d.dforce_t;
  if (r == 0) return;  // no kept row (no A_R: without rows, A_R was never formed)
  add_at_times(system, d, Eigen::Map<const Mat>(lin.dmu_dt.data(), r, 1),
               Eigen::Map<Mat>(lin.dQc_dt.data(), n, 1));
}
}  // namespace

void linearize(const System& system, LinearizeData& d, double t, CVecRef q, CVecRef qd, CVecRef tau,
               const UkSettings& settings, LinearizeParts parts) {
  check_inputs(system, t, q, qd, tau);
  if (linearize_without_rows(system, d, t, q, qd, tau, settings, parts)) {
    time_column(system, d, t, q, qd, parts, true);
    return;
  }
  prepare_kkt(system, d, t, q, qd, tau, settings);
  state_columns(system, d, t, q, qd, parts);
  time_column(system, d, t, q, qd, parts);
}

void dqdd_dx_dense(const LinearizeData& data, Mat& dqdd_dq, Mat& dqdd_dqd) {
  if (!data.structured) {
    dqdd_dq = data.lin.dqdd_dq;
    dqdd_dqd = data.lin.dqdd_dqd;
    return;
  }
  const Index n = data.dqdd_dx.rows;
  Mat both(n, 2 * n);
  arrow_response_expand(data.dqdd_dx, both);
  dqdd_dq = both.leftCols(n);
  dqdd_dqd = both.rightCols(n);
}

void dqdd_dx_times(const LinearizeData& data, const Eigen::Ref<const Mat>& V, Eigen::Ref<Mat> out,
                   Mat& scratch) {
  if (data.structured) {
    arrow_response_multiply(data.dqdd_dx, V, out, scratch);
    return;
  }
  const Index n = data.lin.dqdd_dq.rows();
  out.noalias() = data.lin.dqdd_dq * V.topRows(n);
  out.noalias() += data.lin.dqdd_dqd * V.bottomRows(n);
}

void linearize_corrected(const System& system, LinearizeData& d, double t, CVecRef q, CVecRef qd,
                         CVecRef tau, const RhsCorrection& correction, const UkSettings& settings) {
  check_inputs(system, t, q, qd, tau);
  const Index m = system.rows();
  if (correction.v.size() != m || correction.dv_dphi.rows() != m ||
      correction.dv_dphi.cols() != m || correction.dv_dphid.rows() != m ||
      correction.dv_dphid.cols() != m)
    throw std::invalid_argument("linearize_corrected: v and its Jacobians need m rows");
  d.allow_arrow = false;
  prepare_kkt(system, d, t, q, qd, tau, settings, &correction.v);
  state_columns(system, d, t, q, qd, LinearizeParts{}, &correction);
  LinearizeParts no_time;  // (the correction v depends on t through Φ, Φ̇: not differentiated)
  no_time.time = false;
  time_column(system, d, t, q, qd, no_time);
}

void linearize_corrected_time(const System& system, LinearizeData& d, double t, CVecRef q,
                              CVecRef qd, const Vec& dv_dt) {
  if (dv_dt.size() != system.rows())
    throw std::invalid_argument("linearize_corrected_time: dv_dt needs m rows");
  time_column(system, d, t, q, qd, LinearizeParts{}, false, &dv_dt);
}

bool constraint_time_tangent(const System& system, LinearizeData& d, double t, CVecRef q,
                             CVecRef qd, CVecRef qdd, CVecRef lambda, Vec& dres, Vec& dforce) {
  dres.setZero(system.rows());
  dforce.setZero(system.dof());
  const auto& offs = system.constraint_row_offsets();
  for (std::size_t c = 0; c < system.constraints().size(); ++c) {
    const Constraint& con = *system.constraints()[c];
    const Index rows = con.rows(), off = offs[c];
    if (!con.time_tangent(ConstraintContext{t, d.fwd.constraint_slots(c)}, q, qd, qdd,
                          lambda.segment(off, rows), dres.segment(off, rows), dforce))
      return false;
  }
  return true;
}

void constraint_tangent_columns(const System& system, LinearizeData& d, double t, CVecRef q,
                                CVecRef qd, CVecRef qdd, CVecRef lambda, Mat& dres, Mat& dforce) {
  const Index n = system.dof();
  dres.setZero(system.rows(), 2 * n);
  dforce.setZero(n, 2 * n);
  for (std::size_t c = 0; c < system.constraints().size(); ++c)
    constraint_columns(system, d, t, q, qd, c, qdd, lambda, dres, dforce);
}

Linearization linearize(const System& system, double t, CVecRef q, CVecRef qd, CVecRef tau,
                        const UkSettings& settings) {
  check_inputs(system, t, q, qd, tau);
  LinearizeData d(system);
  linearize(system, d, t, q, qd, tau, settings);
  return std::move(d.lin);
}

ParameterLinearization linearize_parameters(const System& system, double t, CVecRef q, CVecRef qd,
                                            CVecRef tau,
                                            const std::vector<ModelParameterDerivative>& dp,
                                            const UkSettings& settings, bool with_state,
                                            bool with_time) {
  check_sizes(system, t, q, qd, tau);
  if (with_state) require_derivatives(system);
  const Index n = system.dof(), m = system.rows();
  for (const auto& p : dp) {
    if (p.dM.rows() != n || p.dM.cols() != n || p.dQ.size() != n || p.dA.rows() != m ||
        p.dA.cols() != n || p.db.size() != m)
      throw std::invalid_argument(
          "linearize_parameters: a parameter's dM, dQ, dA, db do not match the system's sizes");
  }
  LinearizeData d(system);
  prepare_kkt(system, d, t, q, qd, tau, settings);
  if (with_state) state_columns(system, d, t, q, qd, LinearizeParts{});
  if (with_state && with_time) {  // the time column as linearize() gives it
    time_column(system, d, t, q, qd, LinearizeParts{});
  } else {
    d.lin.time_message = "not computed: linearize_parameters without with_state and with_time";
  }
  // Implicit differentiation of the KKT system in p at fixed (t, q, q̇):
  //   M ∂q̈ − A_Rᵀ ∂μ = ∂Q − ∂M q̈ + (∂A_R)ᵀ μ,   A_R ∂q̈ = ∂b_R − ∂A_R q̈,
  //   ∂Qc = (∂A_R)ᵀ μ + A_Rᵀ ∂μ   (the same factorisation as the state columns).
  const Index r = static_cast<Index>(d.lin.kept_rows.size()), P = static_cast<Index>(dp.size());
  const Vec& qdd = d.lin.qdd;
  Mat rhs(n + r, P), dforce(n, P);
  for (Index j = 0; j < P; ++j) {
    const auto& p = dp[static_cast<std::size_t>(j)];
    dforce.col(j) = p.dA.transpose() * d.lambda;
    rhs.col(j).head(n) = p.dQ - p.dM * qdd + dforce.col(j);
    const Vec dres = p.dA * qdd - p.db;
    for (Index i = 0; i < r; ++i)
      rhs(n + i, j) = -dres(d.lin.kept_rows[static_cast<std::size_t>(i)]);
  }
  Mat X;
  kkt_solve(system, d, rhs, X);
  ParameterLinearization out;
  out.dqdd_dp = X.topRows(n);
  out.dmu_dp = X.bottomRows(r);
  out.dQc_dp = dforce;
  add_at_times(system, d, out.dmu_dp, out.dQc_dp);
  out.lin = std::move(d.lin);
  return out;
}

}  // namespace ukdyn
