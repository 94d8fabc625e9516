#include "ukdyn/model/system.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <string>

#include "core/augmented_mass.hpp"
#include "model/slot_energy.hpp"
#include "model/solve_stages.hpp"

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
  added_mass_.emplace_back();
  dof_ += n;
  return offset;
}

void System::add_reflected_inertia(CVecRef b, double inertia) {
  if (b.size() != dof_)
    throw std::invalid_argument("System::add_reflected_inertia: b has " + std::to_string(b.size()) +
                                " entries, the system " + std::to_string(dof_) + " coordinates");
  if (!(inertia >= 0.0) || !std::isfinite(inertia))
    throw std::invalid_argument(
        "System::add_reflected_inertia: the inertia must be >= 0 and "
        "finite (got " +
        std::to_string(inertia) + ")");
  std::size_t block = subsystems_.size();
  for (std::size_t k = 0; k < subsystems_.size(); ++k) {
    if (b.segment(layout_.start[k], layout_.size[k]).cwiseAbs().maxCoeff() == 0.0) continue;
    if (block != subsystems_.size())
      throw std::invalid_argument(
          "System::add_reflected_inertia: the actuator acts on coordinates of two subsystems ('" +
          subsystems_[block]->name() + "' and '" + subsystems_[k]->name() +
          "'); a rotor inertia n² J_m b bᵀ would couple their blocks of M, which stay separate "
          "(paper Eq. (11))");
    block = k;
  }
  if (block == subsystems_.size())
    throw std::invalid_argument("System::add_reflected_inertia: b is zero");
  const Index s = layout_.start[block], n = layout_.size[block];
  const Vec bk = b.segment(s, n);
  add_block_inertia(block, inertia * bk * bk.transpose());
}

void System::add_block_inertia(std::size_t k, const Mat& added) {
  if (k >= subsystems_.size())
    throw std::invalid_argument("System::add_block_inertia: no subsystem " + std::to_string(k));
  const Index n = layout_.size[k];
  if (added.rows() != n || added.cols() != n || !added.allFinite() ||
      (added - added.transpose()).cwiseAbs().maxCoeff() != 0.0)
    throw std::invalid_argument("System::add_block_inertia: expected a finite symmetric " +
                                std::to_string(n) + " x " + std::to_string(n) + " matrix");
  Mat& add = added_mass_[k];
  if (add.size() == 0) add = Mat::Zero(n, n);
  add += added;
}

Index System::add_constraint(std::shared_ptr<const Constraint> constraint) {
  if (!constraint) throw Error("System::add_constraint: null constraint");
  const Index first = rows_;
  // Structural sparsity → the blocks each row touches → the arrow structure (uk_arrow.hpp).
  const auto cols = constraint->row_columns();
  if (static_cast<Index>(cols.size()) != constraint->rows()) structure_known_ = false;
  if (structure_known_) {
    for (const auto& rc : cols) {
      std::vector<Index> blocks;
      for (const Index c : rc) {
        if (c < 0 || c >= dof_)
          throw Error("System::add_constraint: a row names column " + std::to_string(c) + " of " +
                      std::to_string(dof_));
        const auto it = std::upper_bound(layout_.start.begin(), layout_.start.end(), c);
        const Index blk = static_cast<Index>(it - layout_.start.begin()) - 1;
        if (blocks.empty() || blocks.back() != blk) blocks.push_back(blk);
      }
      if (blocks.empty()) structure_known_ = false;
      row_blocks_.push_back(std::move(blocks));
    }
  }
  arrow_.reset();
  if (structure_known_) arrow_ = detect_arrow(layout_, row_blocks_);
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

namespace {
Index index_of(const std::vector<std::string>& names, const std::string& name, const char* what) {
  for (std::size_t i = 0; i < names.size(); ++i) {
    if (names[i] == name) return static_cast<Index>(i);
  }
  throw std::invalid_argument(std::string("System: no ") + what + " named '" + name + "'");
}
}  // namespace

Index System::coordinate_index(const std::string& name) const {
  return index_of(coord_names_, name, "coordinate");
}

Index System::constraint_row_index(const std::string& name) const {
  return index_of(row_names_, name, "constraint row");
}

namespace {
std::vector<Index> slot_starts(const System& system) {
  std::vector<Index> start{0};
  for (const auto& sub : system.subsystems()) start.push_back(start.back() + sub->slot_size());
  for (const auto& con : system.constraints()) start.push_back(start.back() + con->slot_size());
  return start;
}

[[noreturn]] void size_error(const char* where, const char* what, Index expected, Index actual) {
  throw std::invalid_argument(std::string(where) + ": " + what + " has " + std::to_string(actual) +
                              " entries, expected " + std::to_string(expected));
}

void check_size(const char* where, const char* what, Index expected, Index actual) {
  if (expected != actual) size_error(where, what, expected, actual);
}
}  // namespace

ForwardData::ForwardData(const System& system)
    : M(Mat::Zero(system.dof(), system.dof())),
      Cqd(Vec::Zero(system.dof())),
      G(Vec::Zero(system.dof())),
      Q(Vec::Zero(system.dof())),
      A(Mat::Zero(system.rows(), system.dof())),
      b(Vec::Zero(system.rows())),
      Qc(Vec::Zero(system.dof())),
      qdd(Vec::Zero(system.dof())),
      uk(system.layout(), system.rows()),
      arrow(system.arrow() ? ArrowWorkspace(*system.arrow(), system.rows()) : ArrowWorkspace()),
      singular(system.layout(), system.rows()),
      slot_start(slot_starts(system)),
      system_(&system) {
  Index shared = 0;
  for (const auto& con : system.constraints()) shared = std::max(shared, con->shared_slot_size());
  slots = Vec::Zero(slot_start.back() + shared);
  // Blocks whose M is singular at every state (core/uk_singular.hpp): M_k at three fixed
  // pseudo-random states (components in [-1, 1]), smallest eigenvalue under 1e-10 of the largest.
  const auto& subs = system.subsystems();
  for (std::size_t k = 0; k < subs.size(); ++k) {
    const Index nk = subs[k]->dof();
    Mat Mk(nk, nk);
    bool singular_everywhere = true;
    std::uint64_t state = 0x9e3779b97f4a7c15ULL + k;
    for (int trial = 0; trial < 3 && singular_everywhere; ++trial) {
      Vec q(nk);
      for (Index i = 0; i < nk; ++i) {
        state = state * 6364136223846793005ULL + 1442695040888963407ULL;  // LCG, Knuth MMIX
        q(i) = static_cast<double>(state >> 11) * 0x1.0p-52 - 1.0;
      }
      subs[k]->mass({}, q, Mk);
      if (system.added_mass(k).size() != 0) Mk += system.added_mass(k);
      if (!Mk.allFinite()) {
        singular_everywhere = false;
        break;
      }
      const Vec ev = Eigen::SelfAdjointEigenSolver<Mat>(Mk, Eigen::EigenvaluesOnly).eigenvalues();
      singular_everywhere = !(ev(0) > 1e-10 * std::max(ev(nk - 1), 0.0));
    }
    singular.structural[k] = singular_everywhere ? 1 : 0;
    singular.any_structural = singular.any_structural || singular_everywhere;
  }
  // The rows in one block alone, for the arrow solve of a singular block (augment_singular_blocks).
  if (system.arrow()) {
    const auto& rb = system.row_blocks();
    for (std::size_t i = 0; i < rb.size(); ++i) {
      if (rb[i].size() == 1)
        singular.own_rows[static_cast<std::size_t>(rb[i][0])].push_back(static_cast<Index>(i));
    }
  }
}

Slot ForwardData::subsystem_slot(std::size_t k) {
  return {slots.data() + slot_start[k],
          static_cast<std::size_t>(slot_start[k + 1] - slot_start[k])};
}

ConstraintSlots ForwardData::constraint_slots(std::size_t c) {
  const std::size_t subs = system_->subsystems().size();
  const std::size_t i = subs + c;
  const Slot own{slots.data() + slot_start[i],
                 static_cast<std::size_t>(slot_start[i + 1] - slot_start[i])};
  const auto& starts = system_->layout().start;
  const Index end = slot_start.back();
  return {own, slots.data(), std::span<const Index>(starts.data(), starts.size()),
          std::span<const Index>(slot_start.data(), subs + 1),
          Slot{slots.data() + end, static_cast<std::size_t>(slots.size() - end)}};
}

void check_data_for(const System& system, const ForwardData& data, const char* where) {
  if (data.built_for() != &system) {
    throw std::invalid_argument(std::string(where) +
                                ": the ForwardData was built for another System (build one with "
                                "ForwardData(system) for each system)");
  }
  // The system may have grown after the data was built.
  check_size(where, "ForwardData (M columns)", system.dof(), data.M.cols());
  check_size(where, "ForwardData (A rows)", system.rows(), data.A.rows());
  check_size(where, "ForwardData (slots)",
             static_cast<Index>(system.subsystems().size() + system.constraints().size() + 1),
             static_cast<Index>(data.slot_start.size()));
}

void evaluate_dynamics(const System& system, ForwardData& data, double t, CVecRef q, CVecRef qd) {
  const auto& L = system.layout();
  const auto& subs = system.subsystems();
  double Lt = 0.0;
  for (std::size_t k = 0; k < subs.size(); ++k) {
    const Index s = L.start[k];
    const Index n = L.size[k];
    Lt += subs[k]->dynamics({t, data.subsystem_slot(k)}, q.segment(s, n), qd.segment(s, n),
                            data.M.block(s, s, n, n), data.Cqd.segment(s, n), data.G.segment(s, n));
    // Reflected rotor inertias (add_reflected_inertia): constant, so C q̇ and G are unchanged.
    if (const Mat& add = system.added_mass(k); add.size() != 0) data.M.block(s, s, n, n) += add;
  }
  data.lagrangian_dt = Lt;
}

void evaluate_constraints(const System& system, ForwardData& data, double t, CVecRef q,
                          CVecRef qd) {
  const auto& cons = system.constraints();
  const auto& offs = system.constraint_row_offsets();
  const Index n = system.dof();
  for (std::size_t c = 0; c < cons.size(); ++c) {
    const Index r = cons[c]->rows();
    cons[c]->evaluate({t, data.constraint_slots(c)}, q, qd, data.A.block(offs[c], 0, r, n),
                      data.b.segment(offs[c], r));
  }
}

void forward(const System& system, ForwardData& data, double t, CVecRef q, CVecRef qd, CVecRef tau,
             const UkSettings& settings) {
  // The public edge: a few compares, outside the stages' loops.
  check_data_for(system, data, "forward");
  check_size("forward", "q", system.dof(), q.size());
  check_size("forward", "qd", system.dof(), qd.size());
  check_size("forward", "tau", system.dof(), tau.size());
  evaluate_dynamics(system, data, t, q, qd);
  generalized_forces(system, data, t, q, qd, tau);
  constraint_stage(system, data, t, q, qd, settings);
  solve_stage(system, data, settings);
}

void constraint_stage(const System& system, ForwardData& data, double t, CVecRef q, CVecRef qd,
                      const UkSettings& settings) {
  if (!arrow_applies(system, data, settings)) {
    evaluate_constraints(system, data, t, q, qd);
    return;
  }
  // Only A's structural non-zeros are written (the rest of data.A stays 0): O(N) for N robots.
  const auto& cons = system.constraints();
  const auto& offs = system.constraint_row_offsets();
  const Index n = system.dof();
  for (std::size_t c = 0; c < cons.size(); ++c) {
    const Index r = cons[c]->rows();
    cons[c]->evaluate({t, data.constraint_slots(c), /*structural_only=*/true}, q, qd,
                      data.A.block(offs[c], 0, r, n), data.b.segment(offs[c], r));
  }
}

bool arrow_applies(const System& system, const ForwardData& data, const UkSettings& settings) {
  return system.arrow() && data.arrow.built() &&
         (settings.method == UkMethod::exact || settings.method == UkMethod::adaptive);
}

void solve_stage(const System& system, ForwardData& data, const UkSettings& settings) {
  data.result = solve_for(system, data, data.b, data.Q, data.qdd, data.Qc, settings);
}

UkResult solve_for(const System& system, ForwardData& data, const Vec& b, const Vec& Q, Vec& qdd,
                   Vec& Qc, const UkSettings& settings) {
  // The block-arrow path (ukdyn/core/uk_arrow.hpp): O(N) for N robots on one load; the dense
  // solve stays the fallback (other methods, H or M not positive definite). The adaptive method's
  // damping lives in the dense solve: an arrow result whose smallest kept pivot falls inside the
  // adaptive band is redone densely (the pivots of the pieces stand for the singular values).
  // Structurally singular blocks (a free-body load's quaternion block) take the arrow solve in
  // the augmented form (core/uk_singular.hpp): M_a's blocks and Q_a formed beside M and Q, which
  // stay as they are (factor_augmented_mass, core/augmented_mass.hpp); an augmented block that
  // stays singular fails mass_factor_regular and goes to the dense path.
  data.used_arrow = false;
  UkSingularWorkspace& sw = data.singular;
  const bool augment = sw.any_structural;
  if (arrow_applies(system, data, settings)) {
    const ArrowStructure& st = *system.arrow();
    // The arrow solve reads M on the load's block alone (H = M_L + …) and Q everywhere.
    const Mat* Ms = &data.M;
    const Vec* Qs = &Q;
    detail::MassCondition cond;
    bool factored = false;
    if (augment) {
      factored =
          detail::factor_augmented_mass(system.layout(), data.M, data.A, b, Q, sw, data.uk, cond);
      if (st.load_block >= 0 && sw.structural[static_cast<std::size_t>(st.load_block)])
        Ms = &sw.scratch;
      Qs = &sw.Qa;
    } else {
      factored = factor_mass(data.M, data.uk);
    }
    UkResult res;
    if (factored && mass_factor_regular(*Ms, data.uk) &&
        uk_solve_arrow(st, *Ms, data.A, b, *Qs, data.uk, data.arrow, qdd, Qc, settings, res)) {
      const bool in_band =
          settings.method == UkMethod::adaptive &&
          res.sigma_min_kept < settings.adaptive_band * settings.regularization * res.sigma_max;
      if (!in_band) {
        if (augment) {
          sw.cond_estimate = cond.estimate;
          sw.cond_block = cond.block;
        }
        data.used_arrow = true;
        sw.active = augment;  // mass_condition() then reports the augmented blocks' estimate
        sw.dense_used = false;
        sw.rank_deficient = false;
        return res;
      }
    }
  }
  return uk_solve_dispatch(data, b, Q, qdd, Qc, settings);
}

UkResult uk_solve_dispatch(ForwardData& data, const Vec& b, const Vec& Q, Vec& qdd, Vec& Qc,
                           const UkSettings& settings) {
  // The positive-definite fast path (uk_solve() = factor_mass + uk_solve_factored), unless a block
  // is singular: then the augmented form of core/uk_singular.hpp.
  if (!data.singular.any_structural && factor_mass(data.M, data.uk) &&
      mass_factor_regular(data.M, data.uk)) {
    data.singular.active = false;
    return uk_solve_factored(data.A, b, Q, data.uk, qdd, Qc, settings);
  }
  return uk_solve_singular(data.M, data.A, b, Q, data.uk, data.singular, qdd, Qc, settings);
}

double mass_condition(const ForwardData& data, std::size_t* block) {
  if (data.singular.active) {
    if (block) *block = data.singular.cond_block;
    return data.singular.rank_deficient ? std::numeric_limits<double>::infinity()
                                        : data.singular.cond_estimate;
  }
  return mass_condition_estimate(data.M, data.uk, block);
}

Mat solved_mass(const System& system, const ForwardData& data) {
  if (!data.singular.active) return data.M;
  if (!data.used_arrow) return data.singular.Ma;
  Mat Ma = data.M;
  Vec Qa = data.Q;
  augmented_blocks(system.layout(), data.A, data.b, data.singular, Ma, Qa);
  return Ma;
}

void generalized_forces(const System& system, ForwardData& data, double t, CVecRef q, CVecRef qd,
                        CVecRef tau) {
  // Q = τ + Q_a − C q̇ − G, paper Eq. (11) with the applied forces; the input power τ·q̇ in the
  // same pass. One plain loop: Eigen's two expressions on these unaligned Refs (or two loops the
  // compiler vectorises) peel for alignment and cost more than the arithmetic at the paper's 12
  // coordinates (docs/performance.md).
  const Index n = data.Q.size();
  double* Qd = data.Q.data();
  const double* ta = tau.data();
  const double* v = qd.data();
  const double* cq = data.Cqd.data();
  const double* g = data.G.data();
  double power = 0.0;
  for (Index i = 0; i < n; ++i) {
    Qd[i] = ta[i] - cq[i] - g[i];
    power += ta[i] * v[i];
  }
  for (const auto& f : system.applied_forces()) power += f->add_to(t, q, qd, data.Q);
  data.applied_power = power;
}

void position_residuals(const System& system, ForwardData& data, double t, CVecRef q, VecRef phi) {
  const auto& cons = system.constraints();
  const auto& offs = system.constraint_row_offsets();
  for (std::size_t c = 0; c < cons.size(); ++c) {
    cons[c]->position_residual({t, data.constraint_slots(c)}, q,
                               phi.segment(offs[c], cons[c]->rows()));
  }
}

void velocity_residuals(const System& system, ForwardData& data, double t, CVecRef q, CVecRef qd,
                        VecRef phid) {
  const auto& cons = system.constraints();
  const auto& offs = system.constraint_row_offsets();
  for (std::size_t c = 0; c < cons.size(); ++c) {
    cons[c]->velocity_residual({t, data.constraint_slots(c)}, q, qd,
                               phid.segment(offs[c], cons[c]->rows()));
  }
}

void residuals(const System& system, ForwardData& data, double t, CVecRef q, CVecRef qd, VecRef phi,
               VecRef phid) {
  const auto& cons = system.constraints();
  const auto& offs = system.constraint_row_offsets();
  for (std::size_t c = 0; c < cons.size(); ++c) {
    const Index r = cons[c]->rows();
    cons[c]->residuals({t, data.constraint_slots(c)}, q, qd, phi.segment(offs[c], r),
                       phid.segment(offs[c], r));
  }
}

void coriolis_matrix(const System& system, ForwardData& data, double t, CVecRef q, CVecRef qd,
                     MatRef C) {
  const auto& L = system.layout();
  const auto& subs = system.subsystems();
  C.setZero();
  for (std::size_t k = 0; k < subs.size(); ++k) {
    const Index s = L.start[k];
    const Index n = L.size[k];
    subs[k]->coriolis({t, data.subsystem_slot(k)}, q.segment(s, n), qd.segment(s, n),
                      C.block(s, s, n, n));
  }
}

void coriolis_matrix(const System& system, CVecRef q, CVecRef qd, MatRef C) {
  const auto& L = system.layout();
  const auto& subs = system.subsystems();
  C.setZero();
  for (std::size_t k = 0; k < subs.size(); ++k) {
    if (subs[k]->time_varying()) {
      throw std::invalid_argument("coriolis_matrix: subsystem '" + subs[k]->name() +
                                  "' depends on t; give the time (and a ForwardData)");
    }
    const Index s = L.start[k];
    const Index n = L.size[k];
    subs[k]->coriolis({}, q.segment(s, n), qd.segment(s, n), C.block(s, s, n, n));
  }
}

void position_residuals(const System& system, double t, CVecRef q, VecRef phi) {
  const auto& cons = system.constraints();
  const auto& offs = system.constraint_row_offsets();
  for (std::size_t c = 0; c < cons.size(); ++c) {
    cons[c]->position_residual({t}, q, phi.segment(offs[c], cons[c]->rows()));
  }
}

void velocity_residuals(const System& system, double t, CVecRef q, CVecRef qd, VecRef phid) {
  const auto& cons = system.constraints();
  const auto& offs = system.constraint_row_offsets();
  for (std::size_t c = 0; c < cons.size(); ++c) {
    cons[c]->velocity_residual({t}, q, qd, phid.segment(offs[c], cons[c]->rows()));
  }
}

double kinetic_energy(const ForwardData& data, CVecRef qd) { return 0.5 * qd.dot(data.M * qd); }

double potential_energy(const System& system, CVecRef q) {
  return potential_energy(system, 0.0, q);
}

bool time_varying(const System& system) {
  for (const auto& s : system.subsystems()) {
    if (s->time_varying()) return true;
  }
  return false;
}

double potential_energy(const System& system, double t, CVecRef q) {
  const auto& subs = system.subsystems();
  return detail::potential_sum(system, q, [&](std::size_t k, CVecRef qk) {
    return subs[k]->potential({t, Slot{}}, qk);
  });
}

double detail::potential_energy_in_slots(const System& system, ForwardData& data, double t,
                                         CVecRef q) {
  const auto& subs = system.subsystems();
  return detail::potential_sum(system, q, [&](std::size_t k, CVecRef qk) {
    return subs[k]->potential({t, data.subsystem_slot(k)}, qk);
  });
}

}  // namespace ukdyn
