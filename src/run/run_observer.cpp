#include "run/run_observer.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "model/slot_energy.hpp"
#include "ukdyn/run/closed_loop_derivatives.hpp"

namespace ukdyn::io_detail {

SampleRecorder::SampleRecorder(const System& system, RunReport& rep, bool balance,
                               std::size_t row_size, Needs needs)
    : sys_(system),
      rep_(rep),
      balance_(balance),
      needs_(needs),
      row_(row_size, 0.0),
      scratch_(system),
      vel_(velocity_level_rows(system)),
      any_vel_(std::find(vel_.begin(), vel_.end(), true) != vel_.end()),
      phi_(Vec::Zero(system.rows())),
      phid_(Vec::Zero(system.rows())) {
  const auto m = static_cast<std::size_t>(system.rows());
  rep.max_abs_residual.assign(m, 0.0);
  rep.max_abs_velocity_residual.assign(m, 0.0);
  rep.rank_min = static_cast<int>(system.rows());
  rep.sigma_min = std::numeric_limits<double>::infinity();
  rep.energy_balance = balance;
  for (const auto& s : system.subsystems())
    trees_.push_back(dynamic_cast<const tree::TreeSubsystem*>(s.get()));
}

double SampleRecorder::potential(double t, CVecRef q, const ForwardData& d) {
  const auto& subs = sys_.subsystems();
  return detail::potential_sum(sys_, q, [&](std::size_t k, CVecRef qk) {
    const Slot scratch = scratch_.subsystem_slot(k);
    if (trees_[k] == nullptr || d.built_for() != &sys_) return subs[k]->potential({t, scratch}, qk);
    const auto b = d.slot_start[k], e = d.slot_start[k + 1];
    return trees_[k]->potential(qk, ConstSlot(d.slots.data() + b, static_cast<std::size_t>(e - b)),
                                scratch);
  });
}

std::size_t SampleRecorder::record(double t, CVecRef q, CVecRef qd, const ForwardData& d) {
  const Index n = sys_.dof();
  const Index m = sys_.rows();
  // Φ̇ when the report or the row's vres_ columns need it, with Φ in one call.
  const bool phid = needs_.velocity_residuals || (needs_.row && any_vel_);
  if (m > 0 && phid) {
    residuals(sys_, scratch_, t, q, qd, phi_, phid_);
  } else if (m > 0) {
    position_residuals(sys_, scratch_, t, q, phi_);
  }
  const double T = kinetic_energy(d, qd);
  const double V = potential(t, q, d);
  const double E = T + V;
  if (count_++ == 0) {
    rep_.E0 = E;
    balance0_ = E - d.work;
  }
  if (balance_) {
    rep_.energy_balance_drift = nanmax(rep_.energy_balance_drift, std::abs(E - d.work - balance0_));
    rep_.work_final = d.work;
  }
  rep_.max_energy_drift = nanmax(rep_.max_energy_drift, std::abs(E - rep_.E0));
  rep_.max_T = nanmax(rep_.max_T, T);
  for (Index i = 0; i < m; ++i) {
    auto& r = rep_.max_abs_residual[static_cast<std::size_t>(i)];
    r = nanmax(r, std::abs(phi_(i)));
    if (needs_.velocity_residuals) {
      auto& v = rep_.max_abs_velocity_residual[static_cast<std::size_t>(i)];
      v = nanmax(v, std::abs(phid_(i)));
    }
  }
  rep_.max_acc_residual = nanmax(rep_.max_acc_residual, d.result.residual);
  rep_.rank_min = std::min(rep_.rank_min, d.result.rank);
  rep_.rank_max = std::max(rep_.rank_max, d.result.rank);
  if (d.result.rank > 0) rep_.sigma_min = std::min(rep_.sigma_min, d.result.sigma_min_kept);
  if (!needs_.row) return 0;
  std::size_t k = 0;
  auto& row = row_;
  row[k++] = t;
  for (Index i = 0; i < n; ++i) row[k++] = q(i);
  for (Index i = 0; i < n; ++i) row[k++] = qd(i);
  for (Index i = 0; i < n; ++i) row[k++] = d.qdd(i);
  for (Index i = 0; i < n; ++i) row[k++] = d.Qc(i);
  for (Index i = 0; i < m; ++i) row[k++] = vel_[static_cast<std::size_t>(i)] ? phid_(i) : phi_(i);
  row[k++] = T;
  row[k++] = V;
  row[k++] = E;
  // Diagnostics: rank of A, free DOF n − rank, the smallest kept singular value of A M^{-1/2}
  // (the solve's estimate: the square root of its smallest kept pivot; exact by an SVD at the
  // sample with Needs::sigma_svd), ‖A q̈ − b‖.
  row[k++] = d.result.rank;
  row[k++] = static_cast<double>(n - d.result.rank);
  if (m > 0 && d.result.rank > 0 && needs_.sigma_svd) {
    // M singular (core/uk_singular.hpp): of the augmented M_a = M + A^T alpha A it solved with.
    const Vec sv = singular_values_A_Minvhalf(solved_mass(sys_, d), d.A);
    row[k++] = sv(d.result.rank - 1);
  } else {
    row[k++] = m > 0 && d.result.rank > 0 ? d.result.sigma_min_kept : 0.0;
  }
  row[k++] = d.result.residual;
  if (balance_) {
    row[k++] = d.work;
    row[k++] = E - d.work;
  }
  return k;
}

ForceFunction run_forces(const Scenario& sc, const ControlRun* ctl, SimulationSettings& settings) {
  if (ctl) {
    // The law's exact ∂τ/∂(q, q̇) (docs/derivatives.md, "Exact Jacobians in the implicit
    // integrators"); where its model has none, no tau_jacobian: difference quotients, said.
    if (law_jacobian_gap(*ctl).empty()) settings.tau_jacobian = law_force_jacobian(*ctl);
    return ctl->loop->force_function();
  }
  settings.tau_jacobian = zero_force_jacobian;
  return [&sc](double, CVecRef, CVecRef, VecRef o) { o = sc.tau; };
}

}  // namespace ukdyn::io_detail
