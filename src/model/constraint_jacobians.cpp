#include "ukdyn/model/constraint_jacobians.hpp"

#include <algorithm>
#include <cmath>

namespace ukdyn {

void constraint_state_jacobians(const System& system, ForwardData& d, double t, CVecRef q,
                                CVecRef v, const std::vector<Index>& kept,
                                const std::vector<Vec>& lambdas, Mat& D,
                                std::vector<Mat>& dforce_dq) {
  const Index n = system.dof(), m = system.rows(), r = static_cast<Index>(kept.size());
  const auto& cons = system.constraints();
  const auto& offs = system.constraint_row_offsets();
  D.resize(r, n);
  dforce_dq.resize(lambdas.size());
  for (auto& F : dforce_dq) F.setZero(n, n);
  // λ over all rows (0 on the rows not kept), one per multiplier vector; the first tangent call
  // carries λ_0, the second λ_1 (two calls per direction are needed anyway).
  std::vector<Vec> full(std::max<std::size_t>(lambdas.size(), 2), Vec::Zero(m));
  for (std::size_t k = 0; k < lambdas.size(); ++k)
    for (Index i = 0; i < r; ++i) full[k](kept[static_cast<std::size_t>(i)]) = lambdas[k](i);
  Vec res_v(m), res_0(m), force(n), e = Vec::Zero(n);
  const Vec zero = Vec::Zero(n);
  for (Index j = 0; j < n; ++j) {
    e(j) = 1.0;
    res_v.setZero();
    res_0.setZero();
    for (std::size_t c = 0; c < cons.size(); ++c) {
      const Index rows = cons[c]->rows();
      const ConstraintContext ctx{t, d.constraint_slots(c)};
      force.setZero();
      bool ok = cons[c]->tangent(ctx, q, v, v, full[0].segment(offs[c], rows), e, zero,
                                 res_v.segment(offs[c], rows), force);
      if (ok && !dforce_dq.empty()) dforce_dq[0].col(j) += force;
      force.setZero();
      ok = ok && cons[c]->tangent(ctx, q, v, zero, full[1].segment(offs[c], rows), e, zero,
                                  res_0.segment(offs[c], rows), force);
      if (ok && dforce_dq.size() > 1) dforce_dq[1].col(j) += force;
      if (!ok)
        throw Error("constraint derivatives: constraint rows '" +
                    system.constraint_row_names()[static_cast<std::size_t>(offs[c])] +
                    "…' have no exact derivatives");
      // Further multiplier vectors: one more call each, at x = 0.
      for (std::size_t k = 2; k < lambdas.size(); ++k) {
        force.setZero();
        Vec scratch(rows);
        cons[c]->tangent(ctx, q, v, zero, full[k].segment(offs[c], rows), e, zero, scratch, force);
        dforce_dq[k].col(j) += force;
      }
    }
    for (Index i = 0; i < r; ++i) {
      const Index row = kept[static_cast<std::size_t>(i)];
      D(i, j) = res_v(row) - res_0(row);
    }
    e(j) = 0.0;
  }
}

Index first_velocity_level_row(const System& system, ForwardData& d, double t, CVecRef q,
                               const Mat& AR, const std::vector<Index>& kept) {
  const Index m = system.rows();
  Vec phi_p(m), phi_m(m);
  const double h = 1e-6 * (1.0 + q.cwiseAbs().maxCoeff());
  for (Index k = 0; k < AR.rows(); ++k) {
    const double norm = AR.row(k).norm();
    if (norm == 0.0) continue;
    const Vec v = AR.row(k).transpose() / norm;
    const Index row = kept[static_cast<std::size_t>(k)];
    position_residuals(system, d, t, q + h * v, phi_p);
    position_residuals(system, d, t, q - h * v, phi_m);
    const double slope = (phi_p(row) - phi_m(row)) / (2.0 * h);
    if (!(std::abs(slope) > 1e-3 * norm)) return k;
  }
  return -1;
}

}  // namespace ukdyn
