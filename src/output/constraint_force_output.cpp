#include "ukdyn/output/constraint_force_output.hpp"

#include "ukdyn/core/constraint_forces.hpp"
#include "ukdyn/symbolic/frame_constraints.hpp"

namespace ukdyn {

namespace {

std::string block_name(const System& sys, std::size_t c) {
  const auto& rows = sys.constraint_row_names();
  const std::string& first = rows[static_cast<std::size_t>(sys.constraint_row_offsets()[c])];
  const auto cut = first.rfind('_');
  return sys.constraints()[c]->rows() == 1 || cut == std::string::npos ? first
                                                                       : first.substr(0, cut);
}

}  // namespace

ConstraintForceColumns::ConstraintForceColumns(const Scenario& sc) : sc_(&sc) {
  const System& sys = *sc.system;
  for (std::size_t c = 0; c < sys.constraints().size(); ++c) {
    if (const auto* f =
            dynamic_cast<const symbolic::FrameConstraint*>(sys.constraints()[c].get())) {
      frames_.emplace_back(c, &f->wrench());
    }
  }
  if (frames_.empty()) return;
  ForwardData d(sys);
  evaluate_constraints(sys, d, sc.sim.t0, sc.q0, sc.qd0);
  const auto& names = sys.coordinate_names();
  const auto& offs = sys.constraint_row_offsets();
  for (std::size_t c = 0; c < sys.constraints().size(); ++c) {
    const Index r0 = offs[c], nr = sys.constraints()[c]->rows();
    std::vector<Index> cols;
    for (const auto& s : sc.subsystems) {
      if (d.A.block(r0, s.offset, nr, s.dof).cwiseAbs().maxCoeff() > 0.0) {
        for (Index j = 0; j < s.dof; ++j) cols.push_back(s.offset + j);
      }
    }
    const std::string b = block_name(sys, c);
    std::vector<std::string> fig;
    for (Index j : cols) {
      header_.push_back("Fc_" + b + "_" + names[static_cast<std::size_t>(j)]);
      fig.push_back(header_.back());
    }
    block_coords_.push_back(std::move(cols));
    figures_.push_back(fig);
    figure_names_.push_back("force_" + b);
  }
  static const char* const kW[6] = {"fx", "fy", "fz", "mx", "my", "mz"};
  for (const auto& [c, map] : frames_) {
    std::vector<std::string> fig;
    for (const char* w : kW) {
      header_.push_back("W_" + map->name() + "_" + w);
      fig.push_back(header_.back());
    }
    for (const char* w : kW) header_.push_back("Wg_" + map->name() + "_" + w);
    figures_.push_back(fig);
    figure_names_.push_back("wrench_" + map->name());
    wrench_ws_.push_back(map->workspace());
  }
  header_.push_back("split_unique");
  split_.emplace(sys.rows(), sys.dof(), sys.constraint_row_offsets());
}

bool ConstraintForceColumns::fill(CVecRef q, const ForwardData& d, double* out) {
  if (header_.empty()) return true;
  split_constraint_force(d.A, d.Qc, *split_);
  const ConstraintForceSplit& split = split_->result;
  std::size_t k = 0;
  for (std::size_t c = 0; c < block_coords_.size(); ++c) {
    for (Index j : block_coords_[c]) out[k++] = split.block_force[c](j);
  }
  for (std::size_t fi = 0; fi < frames_.size(); ++fi) {
    const auto& [c, map] = frames_[fi];
    map->evaluate(q, split.block_lambda[c], wrench_ws_[fi], wrench_);
    const symbolic::FrameWrench& w = wrench_;
    const bool b = map->has_b();
    const Vec3 f = b ? w.force_b : w.force_a, m = b ? w.moment_b : w.moment_a;
    const Vec3 fl = b ? w.force_b_local : w.force_a_local;
    const Vec3 ml = b ? w.moment_b_local : w.moment_a_local;
    for (const Vec3* v : {&f, &m, &fl, &ml}) {
      for (Index i = 0; i < 3; ++i) out[k++] = (*v)(i);
    }
  }
  out[k++] = split.unique ? 1.0 : 0.0;
  return split.unique;
}

}  // namespace ukdyn
