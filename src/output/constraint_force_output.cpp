#include "ukdyn/output/constraint_force_output.hpp"

#include <Eigen/Geometry>
#include <algorithm>

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
    for (const char* p : {"x", "y", "z", "qw", "qx", "qy", "qz"})
      header_.push_back("pose_" + map->name() + "_" + p);
    figures_.push_back(fig);
    figure_names_.push_back("wrench_" + map->name());
    wrench_ws_.push_back(map->workspace());
  }
  add_loads(sc);
  header_.push_back("split_unique");
  split_.emplace(sys.rows(), sys.dof(), sys.constraint_row_offsets());
  Ja_ = Mat::Zero(6, sys.dof());
  Jb_ = Mat::Zero(6, sys.dof());
  w_out_.assign(frames_.size(), nullptr);
  position_.assign(frames_.size(), Vec3::Zero());
}

// The loads: two or more welds whose frame b is the same named frame of one subsystem (a body),
// docs/frame-constraints.md, "Internal (squeeze) wrench".
void ConstraintForceColumns::add_loads(const Scenario& sc) {
  const System& sys = *sc.system;
  std::vector<std::string> seen;
  for (std::size_t i = 0; i < frames_.size(); ++i) {
    const symbolic::FrameWrenches& m = *frames_[i].second;
    if (m.kind() != symbolic::FrameConstraintDef::Kind::weld) continue;
    const std::string& body = m.frame_b();
    if (std::find(seen.begin(), seen.end(), body) != seen.end()) continue;
    seen.push_back(body);
    std::vector<std::size_t> grasps;
    for (std::size_t j = i; j < frames_.size(); ++j) {
      const symbolic::FrameWrenches& o = *frames_[j].second;
      if (o.kind() == symbolic::FrameConstraintDef::Kind::weld && o.frame_b() == body)
        grasps.push_back(j);
    }
    const std::string sub = body.substr(0, body.find('.'));
    const auto s = std::find_if(sc.subsystems.begin(), sc.subsystems.end(),
                                [&sub](const auto& x) { return x.name == sub; });
    if (grasps.size() < 2 || s == sc.subsystems.end()) continue;
    std::vector<Index> agents;
    for (Index j = 0; j < sys.dof(); ++j)
      if (j < s->offset || j >= s->offset + s->dof) agents.push_back(j);
    const auto N = static_cast<Index>(grasps.size());
    const auto na = static_cast<Index>(agents.size());
    loads_.push_back({body, grasps, agents, InternalWrenchWorkspace(N, na)});
  }
  static const char* const kW[6] = {"fx", "fy", "fz", "mx", "my", "mz"};
  for (const Load& l : loads_) {
    std::vector<std::string> fig;
    for (const char* form : {"walker", "weighted"}) {
      for (std::size_t g : l.grasps) {
        for (const char* w : kW) {
          header_.push_back(std::string("Wint_") + form + "_" + frames_[g].second->name() + "_" +
                            w);
          if (form[1] == 'e' && w[0] == 'f') fig.push_back(header_.back());
        }
      }
    }
    figures_.push_back(fig);
    figure_names_.push_back("internal_" + l.name);
  }
}

void ConstraintForceColumns::fill_loads(CVecRef q, const ForwardData& d, double*& out) {
  for (Load& l : loads_) {
    InternalWrenchWorkspace& ws = l.ws;
    const auto na = static_cast<Index>(l.agents.size());
    for (Index r = 0; r < na; ++r)
      for (Index c = 0; c < na; ++c)
        ws.M(r, c) =
            d.M(l.agents[static_cast<std::size_t>(r)], l.agents[static_cast<std::size_t>(c)]);
    for (std::size_t k = 0; k < l.grasps.size(); ++k) {
      const auto kk = static_cast<Index>(k);
      const std::size_t fi = l.grasps[k];
      const double* w = w_out_[fi];  // the W_ columns: force, moment on frame b (world)
      for (Index i = 0; i < 6; ++i) ws.w(6 * kk + i) = w[i];
      ws.points[k] = position_[fi];
      frames_[fi].second->jacobians(q, wrench_ws_[fi], Ja_, Jb_);
      for (Index r = 0; r < 6; ++r)
        for (Index c = 0; c < na; ++c)
          ws.J(6 * kk + r, c) = Ja_(r, l.agents[static_cast<std::size_t>(c)]);
    }
    internal_wrenches(ws);
    for (const Vec* v : {&ws.walker, &ws.weighted})
      for (Index i = 0; i < v->size(); ++i) *out++ = (*v)(i);
  }
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
    w_out_[fi] = out + k;
    for (const Vec3* v : {&f, &m, &fl, &ml}) {
      for (Index i = 0; i < 3; ++i) out[k++] = (*v)(i);
    }
    position_[fi] = b ? w.position_b : w.position_a;
    Eigen::Quaterniond r(b ? w.rotation_b : w.rotation_a);
    if (r.w() < 0.0) r.coeffs() = -r.coeffs();  // one of ±r: qw ≥ 0
    for (Index i = 0; i < 3; ++i) out[k++] = position_[fi](i);
    for (double v : {r.w(), r.x(), r.y(), r.z()}) out[k++] = v;
  }
  double* o = out + k;
  fill_loads(q, d, o);
  k = static_cast<std::size_t>(o - out);
  out[k++] = split.unique ? 1.0 : 0.0;
  return split.unique;
}

}  // namespace ukdyn
