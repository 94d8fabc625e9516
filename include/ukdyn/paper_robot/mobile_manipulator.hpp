// The paper's mobile manipulator (one half of the cooperative system, cut at the load's centre):
// an omnidirectional platform translating in world X/Y, a base joint r rotating about the vertical
// by δ, and three links pitching by θ1..θ3 (from the horizontal, positive up). Link 3 is half of
// the load. Coordinates: [Δx, Δy, δ, θ1, θ2, θ3]. M, C, G are the paper's appendix, corrected as in
// docs/paper-errata.md (each correction cited at its line in the .cpp).
#pragma once

#include <array>
#include <string>
#include <vector>

#include "ukdyn/model/subsystem.hpp"

namespace ukdyn {

struct MobileManipulatorParams {
  double platform_mass = 50.0;   ///< m_v
  double base_mass = 2.0;        ///< m_r (joint r)
  double base_inertia = 0.0625;  ///< I_r about the vertical
  double base_length = 0.5;      ///< l_r: height of link 1's root above the platform
  std::array<double, 3> link_mass{3.0, 4.0, 1.0};         ///< m_1..m_3
  std::array<double, 3> link_inertia{0.49, 0.855, 0.08};  ///< I_1..I_3 (paper's scalar model)
  std::array<double, 3> link_length{0.7, 0.8, 0.4};       ///< l_1..l_3
  double gravity = 9.8;                                   ///< g, acting along −Z

  /// Throws ukdyn::Error naming the first invalid parameter (negative or non-finite values, zero
  /// lengths or a zero total mass).
  void validate(const std::string& where) const;
};

/// Kinematic quantities of one arm at (q, q̇), paper notation below Eq. (13):
/// ĉ_k = l_k cos θ_k, ŝ_k = l_k sin θ_k, κ̂ = Σĉ, ρ̂ = Σŝ, ζ̂ = (Σ ŝ θ̇) δ̇, ψ̂ = Σ ĉ θ̇², γ̂ = Σ ŝ θ̇².
/// Templated on the scalar so that the same expressions run on dual numbers for the exact tangents
/// (MobileManipulator::cut_point_jacobian_tangent); ArmKinematics is the double instance.
template <class T>
struct ArmKinematicsT {
  std::array<T, 3> c{}, s{};
  T kappa = T(0), rho = T(0), zeta = T(0), psi = T(0), gamma = T(0);
  T cos_delta = T(1), sin_delta = T(0);
};
using ArmKinematics = ArmKinematicsT<double>;

class MobileManipulator final : public Subsystem {
 public:
  MobileManipulator(std::string name, MobileManipulatorParams params,
                    std::vector<std::string> coordinate_names);

  [[nodiscard]] Index dof() const override { return 6; }
  [[nodiscard]] const std::string& name() const override { return name_; }
  [[nodiscard]] const std::vector<std::string>& coordinate_names() const override { return names_; }
  [[nodiscard]] const MobileManipulatorParams& params() const { return p_; }

  void mass(const EvalContext& c, CVecRef q, MatRef M) const override;
  void coriolis(const EvalContext& c, CVecRef q, CVecRef qd, MatRef C) const override;
  void coriolis_times_qd(const EvalContext& c, CVecRef q, CVecRef qd, VecRef Cqd) const override;
  void gravity(const EvalContext& c, CVecRef q, VecRef G) const override;
  /// Data slot (kSlotSize doubles): [filled, δ, θ1, θ2, θ3, cos ×4, sin ×4] — the sin/cos of the
  /// four angles, next to the angles they belong to. dynamics() writes it; the constraints'
  /// cut-point kinematics (below, given the slot) read it when the angles match bit for bit and
  /// compute the sin/cos otherwise. The values are a pure function of the angles, so the slot
  /// changes the cost (one sin/cos per arm and forward()), never a value.
  static constexpr Index kSlotSize = 13;
  [[nodiscard]] Index slot_size() const override { return kSlotSize; }
  /// M, C q̇ and G from one set of sin/cos (4 angles, the differences by identities), recorded in
  /// the slot of `c` if it has one. Time-invariant: returns ∂L/∂t = 0.
  double dynamics(const EvalContext& c, CVecRef q, CVecRef qd, MatRef M, VecRef Cqd,
                  VecRef G) const override;
  [[nodiscard]] double potential(const EvalContext& c, CVecRef q) const override;

  /// ĉ, ŝ, κ̂, ρ̂, ζ̂, ψ̂, γ̂ of this arm; q, qd are this subsystem's 6 coordinates. `slot`: this
  /// arm's data slot from the same ForwardData (optional; see kSlotSize).
  [[nodiscard]] ArmKinematics kinematics(CVecRef q, CVecRef qd, ConstSlot slot = {}) const;
  /// The cut point (end of link 3, the load's centre) relative to the world origin, with the
  /// platform at height 0: (Δx + κ̂ cos δ, Δy + κ̂ sin δ, l_r + ρ̂).
  [[nodiscard]] Vec3 cut_point(CVecRef q, ConstSlot slot = {}) const;
  /// Jacobian J (3 × 6) of the cut point and its acceleration bias c = J̇ q̇, so that the cut point's
  /// acceleration is J q̈ + c. These are the per-arm halves of paper Eqs. (13), (15), (16), (20):
  ///   c_x = −(ψ̂ + κ̂ δ̇²) cos δ + 2 ζ̂ sin δ,  c_y = −(ψ̂ + κ̂ δ̇²) sin δ − 2 ζ̂ cos δ,  c_z = −γ̂.
  void cut_point_jacobian(CVecRef q, CVecRef qd, Eigen::Matrix<double, 3, 6>& J, Vec3& c,
                          ConstSlot slot = {}) const;

  /// The directional derivatives along (dq, dq̇) of J and c of cut_point_jacobian(), exact: the same
  /// closed-form expressions evaluated once on dual numbers (forward-mode automatic differentiation,
  /// Griewank & Walther 2008, ch. 3). No allocation.
  void cut_point_jacobian_tangent(CVecRef q, CVecRef qd, CVecRef dq, CVecRef dqd,
                                  Eigen::Matrix<double, 3, 6>& dJ, Vec3& dc) const;

  /// Exact derivatives (docs/derivatives.md): d(M q̈ + C q̇ + G) at fixed q̈ along (dq, dq̇), the
  /// closed forms of mass(), coriolis_times_qd() and gravity() evaluated once on dual numbers.
  [[nodiscard]] bool has_derivatives() const override { return true; }
  bool inverse_dynamics_tangent(const EvalContext& c, CVecRef q, CVecRef qd, CVecRef qdd,
                                CVecRef dq, CVecRef dqd, VecRef dID) const override;

 private:
  /// The closed-form M, C, C q̇, G are free function templates on the scalar type in the .cpp (one
  /// source for the double evaluation and its dual-number tangent).
  std::string name_;
  MobileManipulatorParams p_;
  std::vector<std::string> names_;
  // Mass sums of the appendix: a_1 = m1/2 + m2 + m3, a_2 = m2/2 + m3, a_3 = m3/2.
  std::array<double, 3> a_{};
};

}  // namespace ukdyn
