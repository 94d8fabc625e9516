// Applied forces written as definitions (docs/scenario-format.md, "forces"): generalized forces
// as expressions of (t, q, q̇), spring-dampers between two points, joint friction and drive
// torques. Each generalized force is derived exactly with GiNaC and compiled to a tape
// (tape.hpp); the result is a ukdyn::AppliedForce over all coordinates of the system.
//
//   generalized    Q_i += f(t, q, q̇)
//   spring_damper  d = p_a − p_b, L = |d|, L̇ = d·ḋ / L, ḋ = Σ ∂d/∂q_j q̇_j + ∂d/∂t:
//                  the force on a is f = −(k (L − L0) + c L̇) d/L (on b: −f), so that
//                  Q = J_aᵀ f − J_bᵀ f = J_dᵀ f with J_d = ∂d/∂q derived exactly. d, ḋ and J_d
//                  are compiled (expanded, so that their form does not depend on GiNaC's
//                  hash-ordered sign normalisation of powers of sums); L, L̇ and f are then
//                  evaluated in a fixed order. If the points do not depend on t, the spring part is
//                  the potential V = ½ k (L − L0)² (counted in V), the damper non-conservative.
//   joint_friction Q_i += −c_v q̇_i − μ tanh(q̇_i / v_s)   (Coulomb friction smoothed over v_s)
//   torque         Q_i += τ(t, q, q̇)   (an expression, a time function or a spline)
//
// C++:
//   symbolic::ForceDef f({"phi"});
//   f.add_joint_friction("hinge", "phi", f.parameter("c", 0.5), 0, 1e-3);
//   system.add_applied_force(symbolic::make_applied_force(f));
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "ukdyn/model/applied_force.hpp"
#include "ukdyn/symbolic/chain.hpp"
#include "ukdyn/symbolic/definitions.hpp"

namespace ukdyn::symbolic {

class ForceDef : public DefinitionScope {
 public:
  /// All coordinates of the system in order; their names, <name>_dot and t become known names.
  explicit ForceDef(std::vector<std::string> system_coordinates, std::string name = "forces",
                    std::shared_ptr<SymbolTable> symbols = nullptr);
  [[nodiscard]] const std::string& name() const { return name_; }
  [[nodiscard]] const std::vector<std::string>& system_coordinates() const { return coords_; }

  /// Q_i += value(t, q, q̇) on `coordinate`. Throws DefinitionError for an unknown coordinate.
  void add_generalized(const std::string& coordinate, const GiNaC::ex& value);
  /// A spring-damper between points a and b (expressions of q, and t for a moving anchor).
  /// stiffness, damping, rest_length: constants (parameters allowed), stiffness and damping >= 0.
  void add_spring_damper(const std::string& element, const Vec3Ex& a, const Vec3Ex& b,
                         const GiNaC::ex& stiffness, const GiNaC::ex& damping,
                         const GiNaC::ex& rest_length);
  /// Q_i += −viscous q̇_i − coulomb tanh(q̇_i / velocity_scale); constants, >= 0 (scale > 0).
  void add_joint_friction(const std::string& element, const std::string& coordinate,
                          const GiNaC::ex& viscous, const GiNaC::ex& coulomb,
                          const GiNaC::ex& velocity_scale);
  /// Q_i += value(t, q, q̇).
  void add_torque(const std::string& element, const std::string& coordinate,
                  const GiNaC::ex& value);

  /// The generalized forces given directly (generalized, joint_friction, torque), per coordinate
  /// (exact, parameters as symbols); all non-conservative.
  [[nodiscard]] const std::vector<GiNaC::ex>& nonconservative() const { return nc_; }
  struct Spring {
    std::string name;
    Vec3Ex d;                  ///< p_a − p_b
    double k, c, rest_length;  ///< stiffness, damping, rest length
    bool moving;               ///< d depends on t: no potential
  };
  [[nodiscard]] const std::vector<Spring>& springs() const { return springs_; }
  /// Names of the elements added (for messages).
  [[nodiscard]] const std::vector<std::string>& elements() const { return elements_; }

 private:
  std::size_t index_of(const std::string& coordinate, const std::string& where) const;
  double constant_value(const GiNaC::ex& e, const std::string& where) const;
  void check_state_expression(const GiNaC::ex& e, const std::string& where) const;
  std::string name_;
  std::vector<std::string> coords_;
  std::vector<GiNaC::ex> nc_;
  std::vector<Spring> springs_;
  std::vector<std::string> elements_;
};

/// The derived force: the direct generalized forces Q (n×1) and, per spring, d, ḋ and J_d = ∂d/∂q
/// (exact, parameters as symbols).
struct ForceDerivation {
  std::vector<std::string> coordinates;
  GiNaC::matrix Q;
  struct Spring {
    std::string name;
    GiNaC::matrix d, dd, J;  ///< 3×1, 3×1, 3×n
    double k, c, rest_length;
    bool moving;
  };
  std::vector<Spring> springs;
  GiNaC::exmap parameter_values;
  std::shared_ptr<SymbolTable> symbols;  ///< the definition's (its coordinates, velocities, t)
};
ForceDerivation derive(const ForceDef& def);

class DerivedAppliedForce final : public AppliedForce {
 public:
  DerivedAppliedForce(ForceDerivation derivation, std::string name);
  [[nodiscard]] const std::string& name() const override { return name_; }
  double add_to(double t, CVecRef q, CVecRef qd, VecRef Q) const override;
  [[nodiscard]] double potential(CVecRef q) const override;
  [[nodiscard]] const ForceDerivation& derivation() const { return d_; }
  /// Exact derivatives of the expression forces and of the spring-dampers (forward mode on their
  /// tapes, then the chain rule through L, L̇ and the force; docs/derivatives.md).
  [[nodiscard]] bool has_derivatives() const override { return true; }
  bool add_tangent(double t, CVecRef q, CVecRef qd, CVecRef dq, CVecRef dqd,
                   VecRef dQ) const override;
  /// ∂Q/∂t of the expression forces and the spring-dampers: add_tangent()'s forward mode along
  /// dt = 1 (t is an input of the tapes), dq = dq̇ = 0.
  bool add_time_tangent(double t, CVecRef q, CVecRef qd, VecRef dQ) const override;

 private:
  struct CompiledSpring {
    double k, c, l0;
    bool moving;
    std::vector<std::pair<Index, int>> jac;  // (coordinate j, axis) of each nonzero ∂d_axis/∂q_j
    std::size_t first;                       // first output in springs_ (d, ḋ, then jac entries)
    std::size_t first_d;                     // first output in d_only_ (d)
  };
  ForceDerivation d_;
  std::string name_;
  std::vector<Index> q_index_;  // coordinates with a nonzero direct force
  Tape q_, springs_tape_, d_only_;
  std::vector<CompiledSpring> springs_;
  bool has_potential_ = false;
  /// dQ += the tangent along (dt, dq, dq̇) of the expression forces and the spring-dampers.
  void add_tangent_along(double t, CVecRef q, CVecRef qd, double dt, CVecRef dq, CVecRef dqd,
                         VecRef dQ) const;
  void add_spring_tangent(double t, const Vec& q, const Vec& qd, double dt, const Vec& dq,
                          const Vec& dqd, VecRef dQ) const;
};

std::shared_ptr<DerivedAppliedForce> make_applied_force(const ForceDef& def);

}  // namespace ukdyn::symbolic
