// Subsystems and constraints written as definitions; everything else derived exactly with GiNaC and
// compiled into allocation-free tapes (ukdyn/symbolic/tape.hpp).
//
//   Subsystem:  bodies (mass, CoM position p(q), angular velocity ω(q, q̇) or rotation R(q), inertia)
//               and gravity  →  T = Σ ½ m ṗ·ṗ + ½ ωᵀ I ω,  V = −Σ m g·p (+ an extra potential)
//               →  M = ∂²T/∂q̇² (Eq. 5),  G = ∂V/∂q (Eq. 8),
//                  C_ij = Σ_k ½ (∂M_ij/∂q_k + ∂M_ik/∂q_j − ∂M_jk/∂q_i) q̇_k (Eq. 9),  C q̇.
//   Holonomic constraint rows Φ(q, t) = 0:  A = ∂Φ/∂q,  Φ_t,
//               b = −(∂(A q̇)/∂q q̇ + 2 ∂A/∂t q̇ + Φ_tt).
//   Nonholonomic rows e = B(q, t) q̇ + c(q, t) = 0:  A = B = ∂e/∂q̇,  b = −(∂e/∂q q̇ + ∂e/∂t).
//
// Build a model in C++:
//   symbolic::SubsystemDef d("pendulum", {"phi"});
//   auto l = d.parameter("l", 1);
//   auto& bob = d.add_body("bob");
//   bob.mass = d.parameter("m", 2);
//   bob.com = {l * sin(d.q("phi")), 0, -l * cos(d.q("phi"))};   // or d.parse("l*sin(phi)")
//   d.gravity = {0, 0, -9.81};
//   auto sub = symbolic::make_subsystem(d);   // a ukdyn::Subsystem
#pragma once

#include <ginac/ginac.h>

#include <array>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "ukdyn/model/column_derivatives.hpp"
#include "ukdyn/model/constraint.hpp"
#include "ukdyn/model/subsystem.hpp"
#include "ukdyn/model/system.hpp"
#include "ukdyn/symbolic/expression.hpp"
#include "ukdyn/symbolic/tape.hpp"

namespace ukdyn::symbolic {

/// A definition that cannot be used. `body`, `coordinate` and `row` (−1 if not applicable) tell the
/// loader which part of the file to point at.
class DefinitionError : public Error {
 public:
  explicit DefinitionError(const std::string& message, int body_ = -1, int coordinate_ = -1,
                           int row_ = -1)
      : Error(message), body(body_), coordinate(coordinate_), row(row_) {}
  int body, coordinate, row;
};

struct Parameter {
  std::string name;
  GiNaC::symbol symbol;
  GiNaC::ex value;  ///< a real number (exact if given exactly)
};

/// Names, parameters and let-definitions shared by subsystem and constraint definitions, and the
/// symbol table of the system they belong to (`symbols`: null makes a table of its own; give every
/// definition of one system the same table when expressions of one are used in another).
class DefinitionScope {
 public:
  explicit DefinitionScope(std::shared_ptr<SymbolTable> symbols = nullptr);
  /// Declares a parameter (a named number; it stays a symbol in the printed derivation).
  GiNaC::ex parameter(const std::string& name, const GiNaC::ex& value);
  GiNaC::ex parameter(const std::string& name, double value);
  /// A named intermediate expression, usable by later expressions (substituted, never a symbol).
  GiNaC::ex let(const std::string& name, const GiNaC::ex& value);
  /// Parses an expression over the names known so far.
  [[nodiscard]] GiNaC::ex parse(const std::string& text) const { return scope_.parse(text); }
  [[nodiscard]] const Scope& scope() const { return scope_; }
  [[nodiscard]] const std::vector<Parameter>& parameters() const { return params_; }
  /// parameter symbol → value.
  [[nodiscard]] GiNaC::exmap parameter_values() const;
  /// The table of the coordinate, velocity and time symbols (shared with the derivations).
  [[nodiscard]] SymbolTable& symbols() const { return *symbols_; }
  [[nodiscard]] const std::shared_ptr<SymbolTable>& symbol_table() const { return symbols_; }

 protected:
  std::shared_ptr<SymbolTable> symbols_;
  Scope scope_;
  std::vector<Parameter> params_;
};

enum class Frame { body, world };

struct BodyDef {
  std::string name;
  GiNaC::ex mass = 0;
  std::array<GiNaC::ex, 3> com{0, 0, 0};  ///< centre of mass in the world frame, p(q)
  /// Angular velocity ω(q, q̇) in `inertia_frame`. If empty and `rotation` is given, it follows from
  /// R: body frame ω = vee(Rᵀ Ṙ), world frame ω = vee(Ṙ Rᵀ).
  std::optional<std::array<GiNaC::ex, 3>> angular_velocity;
  /// Rotation body → world (row-major 3×3), optional.
  std::optional<std::array<GiNaC::ex, 9>> rotation;
  enum class InertiaKind { none, scalar, tensor } inertia_kind = InertiaKind::none;
  /// Scalar model (the paper's): T_rot = ½ I ω·ω.
  GiNaC::ex inertia_scalar = 0;
  /// Full tensor about the CoM (row-major, symmetric) in `inertia_frame`: T_rot = ½ ωᵀ I ω.
  std::array<GiNaC::ex, 9> inertia_tensor{0, 0, 0, 0, 0, 0, 0, 0, 0};
  Frame inertia_frame = Frame::body;
};

class SubsystemDef : public DefinitionScope {
 public:
  /// Declares the coordinates (names unique, valid identifiers); their velocities are <name>_dot.
  SubsystemDef(std::string name, std::vector<std::string> coordinates,
               std::shared_ptr<SymbolTable> symbols = nullptr);
  [[nodiscard]] const std::string& name() const { return name_; }
  [[nodiscard]] const std::vector<std::string>& coordinates() const { return coords_; }
  [[nodiscard]] GiNaC::symbol q(const std::string& coordinate) const;
  [[nodiscard]] GiNaC::symbol qd(const std::string& coordinate) const;
  BodyDef& add_body(std::string name);

  std::vector<BodyDef> bodies;
  std::array<GiNaC::ex, 3> gravity{0, 0, 0};  ///< gravitational acceleration (e.g. 0, 0, −9.8)
  GiNaC::ex extra_potential = 0;              ///< added to V (springs, ...)

 private:
  std::string name_;
  std::vector<std::string> coords_;
};

/// The exact derivation of a subsystem: symbolic, parameters kept as symbols. Entries are expanded
/// with sin² → 1 − cos² so that identities such as sin² + cos² = 1 cancel.
struct SubsystemDerivation {
  std::vector<std::string> coordinates;
  GiNaC::ex T, V;
  GiNaC::matrix M, C, G, Cqd;  ///< n×n, n×n, n×1, n×1
  /// A mass or inertia of t (docs/definitions.md, "Time-varying masses"): T, V, M, G depend on t,
  /// Cqd includes (∂M/∂t) q̇ (C does not), and Lt = ∂L/∂t = ∂T/∂t − ∂V/∂t (0 otherwise).
  bool time_varying = false;
  GiNaC::ex Lt = 0;
  /// The bodies whose mass is a function of t, and those masses (parameters kept as symbols).
  std::vector<std::string> mass_of_t_bodies;
  std::vector<GiNaC::ex> masses_of_t;
  GiNaC::exmap parameter_values;
  std::shared_ptr<SymbolTable> symbols;  ///< the definition's (its coordinates, velocities, t)
  double derive_seconds = 0.0;
  double compile_seconds = 0.0;
};

/// Derives M, C, G and C q̇. Throws DefinitionError (a coordinate in no body, a body without mass, a
/// velocity or time in a position, ...).
SubsystemDerivation derive(const SubsystemDef& def);
/// The same within `deadline` (one budget shared with build_chain for a chain): throws
/// DerivationTimeout once it is spent.
SubsystemDerivation derive(const SubsystemDef& def, const Deadline& deadline);

/// Simplification used everywhere: expand, then sin(x)^2 → 1 − cos(x)^2, expand again.
GiNaC::ex simplify_trig(const GiNaC::ex& e);
/// The same, with the expansions and each substitution pass checked against `deadline`.
GiNaC::ex simplify_trig(const GiNaC::ex& e, const Deadline& deadline, const std::string& where);

/// Directions per pass of a tape in the every-direction tangents of DerivedSubsystem and
/// DerivedConstraint (Tape::eval_tangents; docs/derivatives.md, "Cost").
constexpr std::size_t kTapeLanes = 8;

/// A free body's M, C q̇ and G in closed form (src/symbolic/free_body_dynamics.hpp).
struct FreeBodyDynamics;

/// A ukdyn::Subsystem evaluated from compiled tapes of a derivation.
class DerivedSubsystem final : public Subsystem, public SubsystemColumns {
 public:
  /// Compiles the tapes; with a pool, a tape identical to one already in it (another instance of
  /// the same robot, say) is shared instead of kept twice (TapePool).
  explicit DerivedSubsystem(SubsystemDerivation derivation, std::string name,
                            TapePool* pool = nullptr);
  /// The same with the tapes compiled within `deadline` (the derivation's own budget:
  /// make_subsystem), throwing DerivationTimeout once it is spent.
  DerivedSubsystem(SubsystemDerivation derivation, std::string name, const Deadline& deadline,
                   TapePool* pool = nullptr);

  [[nodiscard]] Index dof() const override { return n_; }
  [[nodiscard]] const std::string& name() const override { return name_; }
  [[nodiscard]] const std::vector<std::string>& coordinate_names() const override {
    return d_.coordinates;
  }
  /// A mass of t (docs/definitions.md, "Time-varying masses"): every quantity at the context's t.
  [[nodiscard]] bool time_varying() const override { return d_.time_varying; }
  void mass(const EvalContext& ctx, CVecRef q, MatRef M) const override;
  /// Allocation-free with the context's slot (slot_size() doubles), and without it up to 32
  /// coordinates.
  void coriolis(const EvalContext& ctx, CVecRef q, CVecRef qd, MatRef C) const override;
  void coriolis_times_qd(const EvalContext& ctx, CVecRef q, CVecRef qd, VecRef Cqd) const override;
  void gravity(const EvalContext& ctx, CVecRef q, VecRef G) const override;
  [[nodiscard]] double potential(const EvalContext& ctx, CVecRef q) const override;
  /// Data slot: the dynamics tape's outputs and its work buffer, twice (values and tangents), and
  /// at least the C tape's outputs and work (coriolis()): allocation-free at any size.
  [[nodiscard]] Index slot_size() const override;
  /// M, C q̇, G (and ∂L/∂t, returned) from one tape (shared subexpressions computed once), in the
  /// context's slot if it has one; a free body's from closed_form().
  double dynamics(const EvalContext& ctx, CVecRef q, CVecRef qd, MatRef M, VecRef Cqd,
                  VecRef G) const override;
  /// Directional derivatives of M, C q̇ and G along (dq, dqd) at (ctx.t, q, q̇), t held fixed:
  /// dM = Σ_j ∂M/∂q_j dq_j, dCqd = Σ_j ∂(C q̇)/∂q_j dq_j + ∂(C q̇)/∂q̇_j dq̇_j, dG = Σ_j ∂G/∂q_j dq_j;
  /// exact (forward mode on the dynamics tape, Tape::eval_tangent), and M, C q̇, G themselves
  /// (bitwise dynamics()'s). Allocates its buffers: an analysis path (linearisation, sensitivities),
  /// not the integration hot path.
  void dynamics_tangent(const EvalContext& ctx, CVecRef q, CVecRef qd, CVecRef dq, CVecRef dqd,
                        MatRef M, VecRef Cqd, VecRef G, MatRef dM, VecRef dCqd, VecRef dG) const;
  /// Exact derivatives (docs/derivatives.md): dID = dM q̈ + d(C q̇) + dG from dynamics_tangent().
  [[nodiscard]] bool has_derivatives() const override { return true; }
  bool inverse_dynamics_tangent(const EvalContext& ctx, CVecRef q, CVecRef qd, CVecRef qdd,
                                CVecRef dq, CVecRef dqd, VecRef dID) const override;
  /// ∂ID/∂t: forward mode on the dynamics tape along dt = 1 (t is one of its inputs), dq = dq̇ =
  /// 0; 0 when no mass depends on t. Allocation-free with the context's slot.
  bool inverse_dynamics_time_tangent(const EvalContext& ctx, CVecRef q, CVecRef qd, CVecRef qdd,
                                     VecRef dID) const override;
  /// inverse_dynamics_tangent() along every direction at once, in the context's slot (false
  /// without it): the directions the dynamics tape reads, kTapeLanes at a time on one pass of the
  /// tape (the columns of the others are zero). Bitwise the columns of the one-direction tangents.
  bool inverse_dynamics_jacobian(const EvalContext& ctx, CVecRef q, CVecRef qd, CVecRef qdd,
                                 MatRef dID_dq, MatRef dID_dqd) const override;
  /// Kinetic energy ½ q̇ᵀ M q̇ from its own tape (an independent path from M).
  [[nodiscard]] double kinetic(const EvalContext& ctx, CVecRef q, CVecRef qd) const;
  /// A mass of t must stay >= 0 (derive() checks it at t = 0 only): evaluates every mass of t at
  /// `samples` evenly spaced times from t0 to t1 (both included; samples >= 2) and returns, for the
  /// first time and body where the mass is negative or not finite, "body 'B': the mass is m at
  /// t = T"; empty if none (or no mass depends on t). Between those times it is not checked.
  /// Allocates (a set-up check, not for the integration hot path).
  [[nodiscard]] std::string negative_mass(double t0, double t1, long samples) const;

  [[nodiscard]] const SubsystemDerivation& derivation() const { return d_; }
  /// Instruction counts of the mass, C q̇ and gravity tapes.
  [[nodiscard]] std::array<std::size_t, 3> tape_operations() const {
    return {mass_->operations(), cqd_->operations(), grav_->operations()};
  }
  /// The tape forward() runs (M, C q̇, G): the same object for instances that share it.
  [[nodiscard]] const Tape& dynamics_tape() const { return *dyn_; }
  /// Non-null when the derivation is a free body's (docs/free-bodies.md, "The closed form"):
  /// dynamics(), mass(), coriolis_times_qd(), gravity() and the values of dynamics_tangent() then
  /// evaluate that closed form instead of the tapes (equal to round-off); the tapes stay for the
  /// rest (derivatives, C, T, V, printing).
  [[nodiscard]] const FreeBodyDynamics* closed_form() const { return closed_.get(); }

 private:
  /// M, C q̇, G from the dynamics tape's outputs; returns ∂L/∂t (0 unless time-varying).
  double unpack_dynamics(const double* out, MatRef M, VecRef Cqd, VecRef G) const;
  /// dID = dM q̈ + d(C q̇) + dG from the dynamics tape's output tangents along one direction.
  void id_from_tangents(const double* dout, CVecRef qdd, VecRef dID) const;

  SubsystemDerivation d_;
  std::string name_;
  Index n_;
  // Constant and possibly shared with other instances (TapePool).
  std::shared_ptr<const Tape> mass_, cqd_, grav_, cor_, pot_, kin_, dyn_;
  std::shared_ptr<const Tape> masses_of_t_;         // d_.masses_of_t, one output per body
  std::shared_ptr<const FreeBodyDynamics> closed_;  // closed_form()
  // The directions the dynamics tape reads, and how many of them per pass (kTapeLanes at most).
  std::vector<Index> q_read_, qd_read_;
  std::size_t lanes_ = 0;
};

/// derive + compile.
std::shared_ptr<DerivedSubsystem> make_subsystem(const SubsystemDef& def);
/// derive + compile, both within `deadline`; identical tapes shared through `pool` if given.
std::shared_ptr<DerivedSubsystem> make_subsystem(const SubsystemDef& def, const Deadline& deadline,
                                                 TapePool* pool = nullptr);

/// A mass of t negative during a run: the subsystem (its index in the system) and
/// "subsystem 'S', body 'B': the mass '…' is m at t = T"; message empty if none.
struct MassOfTProblem {
  std::size_t subsystem = 0;
  std::string message;
};
/// Every time-varying DerivedSubsystem of `system`, its masses of t checked by negative_mass() at
/// evenly spaced times from t0 to t_end no further apart than sample_dt, and at no fewer than 1001
/// of them (at most 10^6). The scenario loader and the in-memory run (Python) call it.
MassOfTProblem negative_mass_over_run(const System& system, double t0, double t_end,
                                      double sample_dt);

/// If M(q) is not positive definite, a message naming the coordinate(s) of the weakest direction;
/// empty if it is.
std::string mass_matrix_problem(const Subsystem& subsystem, const Vec& q);

// ------------------------------------------------------------------------------- constraints

class ConstraintDef : public DefinitionScope {
 public:
  enum class Kind { holonomic, nonholonomic };
  /// `system_coordinates`: all coordinates of the system in order (their names become symbols, with
  /// their velocities <name>_dot and the time t).
  ConstraintDef(std::string name, Kind kind, std::vector<std::string> system_coordinates,
                std::shared_ptr<SymbolTable> symbols = nullptr);
  [[nodiscard]] const std::string& name() const { return name_; }
  [[nodiscard]] Kind kind() const { return kind_; }
  [[nodiscard]] const std::vector<std::string>& system_coordinates() const { return coords_; }
  /// Adds a row: Φ(q, t) (holonomic) or B(q, t) q̇ + c(q, t) (nonholonomic); = 0 is implied.
  void add_row(std::string row_name, GiNaC::ex expression);
  [[nodiscard]] const std::vector<std::pair<std::string, GiNaC::ex>>& rows() const { return rows_; }

 private:
  std::string name_;
  Kind kind_;
  std::vector<std::string> coords_;
  std::vector<std::pair<std::string, GiNaC::ex>> rows_;
};

struct ConstraintDerivation {
  std::vector<std::string> row_names;
  std::vector<std::string> coordinates;
  GiNaC::matrix phi;   ///< m×1 (holonomic; zero for nonholonomic rows)
  GiNaC::matrix A;     ///< m×n
  GiNaC::matrix b;     ///< m×1
  GiNaC::matrix phid;  ///< m×1, A q̇ + Φ_t (holonomic) or the row itself (nonholonomic)
  bool holonomic = true;
  GiNaC::exmap parameter_values;
  std::shared_ptr<SymbolTable> symbols;  ///< the definition's (its coordinates, velocities, t)
  double derive_seconds = 0.0;
};

/// Derives A and b. Throws DefinitionError (row index set) for velocities in Φ, rows not linear in
/// q̇, rows that involve no coordinate.
ConstraintDerivation derive(const ConstraintDef& def);
/// The same within `deadline` (DerivationTimeout is reported as a DefinitionError of the row).
ConstraintDerivation derive(const ConstraintDef& def, const Deadline& deadline);

class DerivedConstraint final : public Constraint, public ConstraintColumns {
 public:
  explicit DerivedConstraint(ConstraintDerivation derivation);
  /// The same with the tapes compiled within `deadline` (make_constraint: the derivation's budget).
  /// With a `pool`, the tapes read the coordinates the rows name by position and the rows'
  /// non-integer numbers as inputs, so that constraints which differ only in those numbers and in
  /// which coordinates they read (the grasps of N robots on one load: their mounts and grasp
  /// angles) evaluate one program kept once in the pool, each with its own numbers.
  DerivedConstraint(ConstraintDerivation derivation, const Deadline& deadline,
                    TapePool* pool = nullptr);
  [[nodiscard]] Index rows() const override { return m_; }
  [[nodiscard]] const std::vector<std::string>& row_names() const override { return d_.row_names; }
  /// Data slot: the A, b tape's outputs and the largest work buffer of the three tapes. Without it
  /// (the evaluations without data) the tapes run on a local buffer.
  [[nodiscard]] Index slot_size() const override;
  /// With ctx.structural_only, writes only the structurally non-zero entries of A (and b): no
  /// O(n) zeroing of every row.
  void evaluate(const ConstraintContext& ctx, CVecRef q, CVecRef qd, MatRef A,
                VecRef b) const override;
  void position_residual(const ConstraintContext& ctx, CVecRef q, VecRef phi) const override;
  void velocity_residual(const ConstraintContext& ctx, CVecRef q, CVecRef qd,
                         VecRef phid) const override;
  /// The structurally non-zero entries of the derived A (GiNaC zeros excluded), per row.
  [[nodiscard]] std::vector<std::vector<Index>> row_columns() const override;
  [[nodiscard]] const ConstraintDerivation& derivation() const { return d_; }
  /// Exact derivatives (docs/derivatives.md): forward mode on the A, b tape (Tape::eval_tangent)
  /// gives dA and db along (dq, dqd); d(A q̈ − b) = dA q̈ − db, d(Aᵀλ) = dAᵀ λ. Allocates its
  /// buffers (an analysis path).
  [[nodiscard]] bool has_derivatives() const override { return true; }
  bool tangent(const ConstraintContext& ctx, CVecRef q, CVecRef qd, CVecRef qdd, CVecRef lambda,
               CVecRef dq, CVecRef dqd, VecRef d_residual, VecRef d_force) const override;
  /// ∂(A q̈ − b)/∂t and ∂(Aᵀλ)/∂t: the same forward mode along dt = 1 (t is an input of the A, b
  /// tape: trajectories, splines), dq = dq̇ = 0. Allocation-free with this constraint's slot.
  bool time_tangent(const ConstraintContext& ctx, CVecRef q, CVecRef qd, CVecRef qdd,
                    CVecRef lambda, VecRef d_residual, VecRef d_force) const override;
  /// tangent() along every direction at once, in this constraint's slot (false without it, or
  /// with positional inputs — tapes shared through a TapePool —: then tangent() per direction):
  /// only the directions the A, b tape reads, kTapeLanes at a time on one pass of the tape
  /// (Tape::eval_tangents; the columns of the other directions are zero). Bitwise the columns of
  /// tangent() along each direction.
  bool tangent_columns(const ConstraintContext& ctx, CVecRef q, CVecRef qd, CVecRef qdd,
                       CVecRef lambda, MatRef d_residual, MatRef d_force) const override;
  [[nodiscard]] std::size_t tape_operations() const { return ab_->operations(); }
  /// The A, b tape (the same object for constraints that share it through a TapePool).
  [[nodiscard]] const Tape& ab_tape() const { return *ab_; }

 private:
  // tangent() along (dt, dq, dq̇); dq, dqd null: zero.
  void tangent_along(const ConstraintContext& ctx, CVecRef q, CVecRef qd, CVecRef qdd,
                     CVecRef lambda, double dt, const double* dq, const double* dqd,
                     VecRef d_residual, VecRef d_force) const;
  // d(A q̈ − b) and d(Aᵀλ) from the tape's output tangents along one direction.
  void column_from_tangents(const double* dout, CVecRef qdd, CVecRef lambda, MatRef d_residual,
                            MatRef d_force, Index col) const;
  ConstraintDerivation d_;
  Index m_;
  std::vector<std::pair<Index, Index>> nz_;  // (row, column) of each structurally nonzero A entry
  // Positional inputs (compiled with a pool): the tapes' q is (q[cols_[0]], …, numbers_…) and their
  // q̇ is (q̇[cols_[0]], …); without, cols_ is empty and the tapes read q and q̇ themselves.
  std::vector<Index> cols_;
  std::vector<double> numbers_;
  bool positional_ = false;
  std::shared_ptr<const Tape> ab_, phi_, phid_;
  [[nodiscard]] Index input_size() const {
    return positional_ ? static_cast<Index>(2 * cols_.size() + numbers_.size()) : 0;
  }
  std::vector<std::size_t> by_column_;  // nz_'s entries ordered by column (stable)
  // The directions the A, b tape reads (without positional inputs): q_j for j in q_read_, q̇_j for
  // j in qd_read_; lanes_ of them per pass of tangent_columns().
  std::vector<Index> q_read_, qd_read_;
  std::size_t lanes_ = 0;
};

/// derive + compile, both within one Deadline (limits::kDeriveSeconds); with a `pool`, the tapes
/// in the pool's keeping (DerivedConstraint's constructor).
std::shared_ptr<DerivedConstraint> make_constraint(const ConstraintDef& def,
                                                   TapePool* pool = nullptr);

// ------------------------------------------------------------------------------- printing

enum class Format { latex, c, matlab, text };
/// The derivation of a subsystem (M, C, G) in a format.
std::string format_derivation(const SubsystemDerivation& d, const std::string& name, Format f);
/// The derivation of a constraint block (Φ, A, b) in a format.
std::string format_derivation(const ConstraintDerivation& d, const std::string& name, Format f);
/// "latex", "c", "matlab" or "text"; throws ukdyn::Error otherwise.
Format parse_format(const std::string& name);
/// Every derived subsystem (M, C, G) and constraint block (Φ, A, b) of a system; built-in blocks
/// are named as such. In C, each subsystem becomes a function NAME_dynamics(q, qd, M, C, G).
std::string format_system(const System& system, Format f);

}  // namespace ukdyn::symbolic
