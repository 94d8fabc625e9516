#include "ukdyn/model/system.hpp"

#include <limits>

namespace ukdyn {

Index System::add_subsystem(std::shared_ptr<const Subsystem> subsystem) {
  if (!subsystem) throw Error("System::add_subsystem: null subsystem");
  if (!constraints_.empty()) {
    throw Error("System::add_subsystem: add every subsystem before the first constraint");
  }
  const Index offset = dof_;
  const Index n = subsystem->dof();
  if (n <= 0) throw Error("System::add_subsystem: '" + subsystem->name() + "' has no coordinates");
  if (static_cast<Index>(subsystem->coordinate_names().size()) != n) {
    throw Error("System::add_subsystem: '" + subsystem->name() + "' has " + std::to_string(n) +
                " coordinates but " + std::to_string(subsystem->coordinate_names().size()) +
                " names");
  }
  layout_.start.push_back(offset);
  layout_.size.push_back(n);
  for (const auto& nm : subsystem->coordinate_names()) coord_names_.push_back(nm);
  subsystems_.push_back(std::move(subsystem));
  dof_ += n;
  return offset;
}

Index System::add_constraint(std::shared_ptr<const Constraint> constraint) {
  if (!constraint) throw Error("System::add_constraint: null constraint");
  const Index first = rows_;
  row_offsets_.push_back(first);
  for (const auto& nm : constraint->row_names()) row_names_.push_back(nm);
  rows_ += constraint->rows();
  constraints_.push_back(std::move(constraint));
  return first;
}

void System::add_applied_force(std::shared_ptr<const AppliedForce> force) {
  if (!force) throw Error("System::add_applied_force: null force");
  applied_.push_back(std::move(force));
}

ForwardData::ForwardData(const System& system)
    : M(Mat::Zero(system.dof(), system.dof())),
      Cqd(Vec::Zero(system.dof())),
      G(Vec::Zero(system.dof())),
      Q(Vec::Zero(system.dof())),
      A(Mat::Zero(system.rows(), system.dof())),
      b(Vec::Zero(system.rows())),
      Qc(Vec::Zero(system.dof())),
      qdd(Vec::Zero(system.dof())),
      uk(system.layout(), system.rows()) {}

void evaluate_dynamics(const System& system, ForwardData& data, CVecRef q, CVecRef qd) {
  const auto& L = system.layout();
  const auto& subs = system.subsystems();
  for (std::size_t k = 0; k < subs.size(); ++k) {
    const Index s = L.start[k];
    const Index n = L.size[k];
    subs[k]->dynamics(q.segment(s, n), qd.segment(s, n), data.M.block(s, s, n, n),
                      data.Cqd.segment(s, n), data.G.segment(s, n));
  }
}

void evaluate_constraints(const System& system, ForwardData& data, double t, CVecRef q,
                          CVecRef qd) {
  const auto& cons = system.constraints();
  const auto& offs = system.constraint_row_offsets();
  const Index n = system.dof();
  for (std::size_t c = 0; c < cons.size(); ++c) {
    const Index r = cons[c]->rows();
    cons[c]->evaluate(t, q, qd, data.A.block(offs[c], 0, r, n), data.b.segment(offs[c], r));
  }
}

void forward(const System& system, ForwardData& data, double t, CVecRef q, CVecRef qd, CVecRef tau,
             const UkSettings& settings) {
  evaluate_dynamics(system, data, q, qd);
  generalized_forces(system, data, t, q, qd, tau);
  evaluate_constraints(system, data, t, q, qd);
  data.result = uk_solve(data.M, data.A, data.b, data.Q, data.uk, data.qdd, data.Qc, settings);
}

void generalized_forces(const System& system, ForwardData& data, double t, CVecRef q, CVecRef qd,
                        CVecRef tau) {
  // Q = τ + Q_a − C q̇ − G, paper Eq. (11) with the applied forces.
  data.Q = tau - data.Cqd - data.G;
  double power = tau.dot(qd);
  for (const auto& f : system.applied_forces()) power += f->add_to(t, q, qd, data.Q);
  data.applied_power = power;
}

void coriolis_matrix(const System& system, CVecRef q, CVecRef qd, MatRef C) {
  const auto& L = system.layout();
  const auto& subs = system.subsystems();
  C.setZero();
  for (std::size_t k = 0; k < subs.size(); ++k) {
    const Index s = L.start[k];
    const Index n = L.size[k];
    subs[k]->coriolis(q.segment(s, n), qd.segment(s, n), C.block(s, s, n, n));
  }
}

void position_residuals(const System& system, double t, CVecRef q, VecRef phi) {
  const auto& cons = system.constraints();
  const auto& offs = system.constraint_row_offsets();
  for (std::size_t c = 0; c < cons.size(); ++c) {
    cons[c]->position_residual(t, q, phi.segment(offs[c], cons[c]->rows()));
  }
}

void velocity_residuals(const System& system, double t, CVecRef q, CVecRef qd, VecRef phid) {
  const auto& cons = system.constraints();
  const auto& offs = system.constraint_row_offsets();
  for (std::size_t c = 0; c < cons.size(); ++c) {
    cons[c]->velocity_residual(t, q, qd, phid.segment(offs[c], cons[c]->rows()));
  }
}

double kinetic_energy(const ForwardData& data, CVecRef qd) { return 0.5 * qd.dot(data.M * qd); }

double potential_energy(const System& system, CVecRef q) {
  const auto& L = system.layout();
  const auto& subs = system.subsystems();
  double V = 0.0;
  for (std::size_t k = 0; k < subs.size(); ++k)
    V += subs[k]->potential(q.segment(L.start[k], L.size[k]));
  for (const auto& f : system.applied_forces()) V += f->potential(q);
  return V;
}

}  // namespace ukdyn
