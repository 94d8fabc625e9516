// A constrained multibody system: subsystems (block-diagonal M, C, G, paper Eq. (10)-(11)) plus
// constraint blocks stacked by rows (paper: Â = [A; A_t], b̂ = [b; b_t]).
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "ukdyn/core/uk_arrow.hpp"
#include "ukdyn/core/uk_singular.hpp"
#include "ukdyn/core/uk_solve.hpp"
#include "ukdyn/model/applied_force.hpp"
#include "ukdyn/model/constraint.hpp"
#include "ukdyn/model/subsystem.hpp"

namespace ukdyn {

/// Constant description of the system. Build it once; share it between threads.
class System {
 public:
  /// Appends a subsystem; its coordinates follow those already added. Returns its offset in q.
  Index add_subsystem(std::shared_ptr<const Subsystem> subsystem);
  /// Appends a block of constraint rows. Returns its first row.
  Index add_constraint(std::shared_ptr<const Constraint> constraint);
  /// Adds an applied force Q_a(t, q, q̇) over all coordinates (applied_force.hpp).
  void add_applied_force(std::shared_ptr<const AppliedForce> force);
  /// Adds the constant inertia `inertia` · b bᵀ to M (b: n system coordinates), e.g. a motor's
  /// rotor seen through a gear of ratio n: n² J_m b bᵀ (ukdyn/model/motor.hpp, docs/motors.md).
  /// evaluate_dynamics() adds it after the subsystems' M, so forward(), the constraint forces,
  /// the energies, linearize() (a constant: no tangent) and every integrator see it. b's non-zeros
  /// must lie in one subsystem (M stays block-diagonal, paper Eq. (11)); throws
  /// std::invalid_argument otherwise, or for a negative or non-finite inertia, or a wrong size.
  /// Add every subsystem first.
  void add_reflected_inertia(CVecRef b, double inertia);
  /// Adds a constant symmetric matrix to subsystem k's block of M (what add_reflected_inertia()
  /// adds; used to carry those onto a copy of the system, e.g. the plant of a control run).
  void add_block_inertia(std::size_t k, const Mat& added);
  /// Σ of the reflected inertias on subsystem k's block (its dof² entries; empty if none).
  [[nodiscard]] const Mat& added_mass(std::size_t k) const { return added_mass_[k]; }

  [[nodiscard]] Index dof() const { return dof_; }
  [[nodiscard]] Index rows() const { return rows_; }
  [[nodiscard]] const BlockLayout& layout() const { return layout_; }
  [[nodiscard]] const std::vector<std::shared_ptr<const Subsystem>>& subsystems() const {
    return subsystems_;
  }
  [[nodiscard]] const std::vector<std::shared_ptr<const Constraint>>& constraints() const {
    return constraints_;
  }
  [[nodiscard]] const std::vector<Index>& constraint_row_offsets() const { return row_offsets_; }
  [[nodiscard]] const std::vector<std::shared_ptr<const AppliedForce>>& applied_forces() const {
    return applied_;
  }
  [[nodiscard]] const std::vector<std::string>& coordinate_names() const { return coord_names_; }
  [[nodiscard]] const std::vector<std::string>& constraint_row_names() const { return row_names_; }
  /// Named lookups (instead of raw offsets): the index in q of coordinate `name`, the row of A / b
  /// of constraint row `name`. Throw std::invalid_argument for an unknown name.
  [[nodiscard]] Index coordinate_index(const std::string& name) const;
  [[nodiscard]] Index constraint_row_index(const std::string& name) const;
  /// The block-arrow structure of A (robot subsystems each coupled to one shared load subsystem,
  /// ukdyn/core/uk_arrow.hpp), found from the constraints' structural sparsity
  /// (Constraint::row_columns()) as they are added; nullptr when A does not have one (or a
  /// constraint does not declare its sparsity). forward() then solves in O(N).
  [[nodiscard]] const ArrowStructure* arrow() const { return arrow_ ? &*arrow_ : nullptr; }
  /// The blocks each constraint row touches (from Constraint::row_columns(), ascending); empty when
  /// a constraint does not declare its sparsity.
  [[nodiscard]] const std::vector<std::vector<Index>>& row_blocks() const { return row_blocks_; }

 private:
  std::vector<std::shared_ptr<const Subsystem>> subsystems_;
  std::vector<std::shared_ptr<const Constraint>> constraints_;
  std::vector<std::shared_ptr<const AppliedForce>> applied_;
  std::vector<Mat> added_mass_;  // per subsystem: Σ inertia · b bᵀ on its block (empty: none)
  std::vector<Index> row_offsets_;
  std::vector<std::string> coord_names_;
  std::vector<std::string> row_names_;
  BlockLayout layout_;
  std::vector<std::vector<Index>> row_blocks_;  // blocks touched by each row (structural)
  bool structure_known_ = true;                 // every constraint declared row_columns()
  std::optional<ArrowStructure> arrow_;
  Index dof_ = 0;
  Index rows_ = 0;
};

/// Every buffer forward() writes, allocated once for a system (n = system.dof(), m =
/// system.rows()). Read the results from here. All mutable state of an evaluation lives here, none
/// in the System: one System can be shared by threads that each own a ForwardData.
struct ForwardData {
  explicit ForwardData(const System& system);

  Mat M;            ///< n × n, block-diagonal (block k: subsystem k's M at its coordinates)
  Vec Cqd;          ///< n: C(q, q̇) q̇
  Vec G;            ///< n: gravity G(q)
  Vec Q;            ///< n: τ + Q_a − C q̇ − G, paper Eq. (11) with the applied forces Q_a
  Mat A;            ///< m × n, constraint rows stacked (system.constraint_row_offsets())
  Vec b;            ///< m
  Vec Qc;           ///< n: constraint force, paper Eq. (4)
  Vec qdd;          ///< n: q̈ = M^{-1}(Q + Qc), paper Eq. (18)
  UkWorkspace uk;   ///< the U-K solve's buffers for (system.layout(), m)
  UkResult result;  ///< diagnostics of the last solve
  /// The arrow solve's buffers (built when system.arrow() is set) and whether the last forward()
  /// used it (true) or the dense solve (false).
  ArrowWorkspace arrow;
  bool used_arrow = false;
  /// The singular-M solve's buffers (core/uk_singular.hpp); `singular.active` tells whether the
  /// last solve used it.
  UkSingularWorkspace singular;
  /// (τ + Q_nc)ᵀ q̇: the power of τ and of the non-conservative part of the applied forces.
  double applied_power = 0.0;
  /// Σ_k ∂L_k/∂t of the subsystems at the last evaluate_dynamics() (0 unless a subsystem is
  /// time_varying(): a mass of t). The energy balance integrates Ẇ = (τ + Q_nc + Qc)ᵀ q̇ − ∂L/∂t.
  double lagrangian_dt = 0.0;
  /// W(t) = ∫ (τ + Q_nc + Qc)ᵀ q̇ dt, set by simulate() at samples when energy_balance is on.
  double work = 0.0;

  /// Data slots (Subsystem::slot_size(), Constraint::slot_size()) back to back, zero-filled on
  /// construction: subsystem k's is [slot_start[k], slot_start[k + 1]), constraint c's is block
  /// subsystems + c; after slot_start.back() the constraints' shared scratch (the largest
  /// Constraint::shared_slot_size(), ConstraintSlots::shared()). Written and read only within one
  /// evaluation (forward(), the residuals); what a stage leaves there for a later one carries the
  /// state it belongs to (see ConstraintSlots).
  Vec slots;
  std::vector<Index> slot_start;  ///< subsystems + constraints + 1 entries

  /// Subsystem k's slot / constraint c's view of the slots.
  [[nodiscard]] Slot subsystem_slot(std::size_t k);
  [[nodiscard]] ConstraintSlots constraint_slots(std::size_t c);
  /// The system this data was built for (the entry points check it: check_data_for()).
  [[nodiscard]] const System* built_for() const { return system_; }

 private:
  const System* system_ = nullptr;
};

/// Throws std::invalid_argument unless `data` was built for `system` (same object, same n and m).
void check_data_for(const System& system, const ForwardData& data, const char* where);

/// Forward dynamics of the constrained system at (t, q, q̇) with applied forces τ as named stages:
///   evaluate_dynamics (M, C q̇, G per subsystem) → generalized_forces (Q = τ + Q_a − C q̇ − G)
///   → evaluate_constraints (A, b)
///   → uk_solve (q̈, Qc).   Allocation-free.
/// q, qd, tau must have n entries and data must be built for this system: otherwise throws
/// std::invalid_argument naming the expected and actual sizes.
/// If M is not positive definite, data.result.finite is false and q̈ is NaN.
void forward(const System& system, ForwardData& data, double t, CVecRef q, CVecRef qd, CVecRef tau,
             const UkSettings& settings = {});

/// Largest Cholesky-pivot estimate of cond(M_k) over the blocks of the last solve in data (of M_a
/// after a singular solve); `block` gets the worst block (docs/free-bodies.md).
double mass_condition(const ForwardData& data, std::size_t* block = nullptr);
/// The mass matrix the last solve used, for the singular values of A M^{-1/2} (the `sigma_min`
/// column, `ukdyn eval`): M, or when M is singular the augmented M_a = M + Aᵀ α A it solved with
/// (core/uk_singular.hpp; rebuilt from M when the arrow solve took the augmented blocks).
/// Allocates (per output sample, not per forward call).
Mat solved_mass(const System& system, const ForwardData& data);

/// Stage: data.Q = τ + Σ Q_a(t, q, q̇) − C q̇ − G (C q̇ and G already in data) and
/// data.applied_power. Like the other stages below it does not check sizes (forward() does, once,
/// at the edge): q, qd, tau must have n entries and data be built for this system.
void generalized_forces(const System& system, ForwardData& data, double t, CVecRef q, CVecRef qd,
                        CVecRef tau);

/// Stage 1 only: M, C q̇, G (no constraints) at time t, into data (and the subsystems' data
/// slots), and data.lagrangian_dt. t matters only for a time_varying() subsystem.
void evaluate_dynamics(const System& system, ForwardData& data, double t, CVecRef q, CVecRef qd);
/// Stage 2 only: A and b, into data (reading what stage 1 left in the slots, if it was run at the
/// same q).
void evaluate_constraints(const System& system, ForwardData& data, double t, CVecRef q, CVecRef qd);

/// Position residuals Φ(q, t) of every row (m), with data's slots as scratch (allocation-free).
void position_residuals(const System& system, ForwardData& data, double t, CVecRef q, VecRef phi);
/// Velocity residuals Φ̇ = A q̇ + Φ_t of every row (m), with data's slots as scratch.
void velocity_residuals(const System& system, ForwardData& data, double t, CVecRef q, CVecRef qd,
                        VecRef phid);

/// Φ and Φ̇ of every row together (m each), with data's slots as scratch: the values of
/// position_residuals() and velocity_residuals(), the work the two share done once
/// (Constraint::residuals).
void residuals(const System& system, ForwardData& data, double t, CVecRef q, CVecRef qd, VecRef phi,
               VecRef phid);

/// The full C matrix (n × n, block-diagonal) at time t, with data's slots as scratch. Allocates
/// nothing if C has the right size.
void coriolis_matrix(const System& system, ForwardData& data, double t, CVecRef q, CVecRef qd,
                     MatRef C);
/// The same without a time or a ForwardData, for systems whose subsystems do not depend on t;
/// throws std::invalid_argument naming the subsystem when one is time_varying() (its C depends on
/// t: use the overload above).
void coriolis_matrix(const System& system, CVecRef q, CVecRef qd, MatRef C);
/// Position residuals Φ(q, t) of every row (m), without a ForwardData (a block that needs scratch
/// makes its own: may allocate).
void position_residuals(const System& system, double t, CVecRef q, VecRef phi);
/// Velocity residuals Φ̇ = A q̇ + Φ_t of every row (m), without a ForwardData (may allocate).
void velocity_residuals(const System& system, double t, CVecRef q, CVecRef qd, VecRef phid);

/// Kinetic energy ½ q̇ᵀ M q̇ (M from data.M, already evaluated at q).
double kinetic_energy(const ForwardData& data, CVecRef qd);
/// Potential energy Σ V_k(q, t) of the subsystems plus the potentials of the applied forces.
double potential_energy(const System& system, double t, CVecRef q);
/// potential_energy() at t = 0 (the same at any t unless a subsystem is time_varying()).
double potential_energy(const System& system, CVecRef q);
/// Whether any subsystem is time_varying() (a mass or inertia of t).
bool time_varying(const System& system);

}  // namespace ukdyn
