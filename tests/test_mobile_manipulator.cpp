// The closed-form M, C, G of MobileManipulator against the independent AD reference
// (tests/reference_model.hpp), plus structural properties and the paper's C34/C43 erratum.
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <cmath>

#include "helpers.hpp"
#include "reference_model.hpp"
#include "ukdyn/model/system.hpp"
#include "ukdyn/paper_robot/mobile_manipulator.hpp"

namespace {

using uktest::Matrix6d;
using uktest::rel_err;
using uktest::Vector6d;

constexpr int kStates = 60;
constexpr double kTol = 1e-12;  // relative, closed form vs AD

Matrix6d lib_mass(const ukdyn::MobileManipulator& arm, const Vector6d& q) {
  Matrix6d M;
  ukdyn::Mat Mx(6, 6);
  arm.mass({}, q, Mx);
  M = Mx;
  return M;
}
Matrix6d lib_coriolis(const ukdyn::MobileManipulator& arm, const Vector6d& q, const Vector6d& qd) {
  ukdyn::Mat C(6, 6);
  arm.coriolis({}, q, qd, C);
  return C;
}
Vector6d lib_cqd(const ukdyn::MobileManipulator& arm, const Vector6d& q, const Vector6d& qd) {
  ukdyn::Vec c(6);
  arm.coriolis_times_qd({}, q, qd, c);
  return c;
}
Vector6d lib_gravity(const ukdyn::MobileManipulator& arm, const Vector6d& q) {
  ukdyn::Vec g(6);
  arm.gravity({}, q, g);
  return g;
}

std::vector<ukdyn::MobileManipulatorParams> param_sets() {
  std::mt19937_64 rng(20240611);
  return {ukdyn::MobileManipulatorParams{}, uktest::random_params(rng)};
}

TEST(MobileManipulator, MassIsSymmetricPositiveDefinite) {
  for (const auto& p : param_sets()) {
    const auto arm = uktest::make_arm(1, p);
    std::mt19937_64 rng(1);
    for (int s = 0; s < kStates; ++s) {
      const Vector6d q = uktest::random_q(rng);
      const Matrix6d M = lib_mass(*arm, q);
      EXPECT_LE((M - M.transpose()).norm(), 1e-14 * M.norm()) << "state " << s;
      Eigen::SelfAdjointEigenSolver<Matrix6d> eig(M);
      EXPECT_GT(eig.eigenvalues().minCoeff(), 1e-8 * eig.eigenvalues().maxCoeff()) << "state " << s;
      EXPECT_EQ(Eigen::LLT<Matrix6d>(M).info(), Eigen::Success);
    }
  }
}

TEST(MobileManipulator, MassEqualsReference) {
  for (const auto& p : param_sets()) {
    const auto arm = uktest::make_arm(1, p);
    std::mt19937_64 rng(2);
    for (int s = 0; s < kStates; ++s) {
      const Vector6d q = uktest::random_q(rng);
      const Matrix6d Mref = ukref::mass_matrix<double>(p, q);
      EXPECT_LE(rel_err(lib_mass(*arm, q), Mref), kTol) << "state " << s << "\nlib\n"
                                                        << lib_mass(*arm, q) << "\nref\n"
                                                        << Mref;
    }
  }
}

TEST(MobileManipulator, CoriolisTimesQdEqualsEulerLagrangeReference) {
  for (const auto& p : param_sets()) {
    const auto arm = uktest::make_arm(1, p);
    std::mt19937_64 rng(3);
    for (int s = 0; s < kStates; ++s) {
      const Vector6d q = uktest::random_q(rng);
      const Vector6d qd = uktest::random_qd(rng);
      const Vector6d ref = ukref::coriolis_times_qd(p, q, qd);
      EXPECT_LE(rel_err(lib_cqd(*arm, q, qd), ref), kTol)
          << "state " << s << "\nlib " << lib_cqd(*arm, q, qd).transpose() << "\nref "
          << ref.transpose();
      EXPECT_LE(rel_err(Vector6d(lib_coriolis(*arm, q, qd) * qd), ref), kTol)
          << "state " << s << "\nlib C*qd " << (lib_coriolis(*arm, q, qd) * qd).transpose()
          << "\nref " << ref.transpose();
    }
  }
}

// The reference itself: Euler–Lagrange C q̇ equals Christoffel C q̇ and J̇q̇ (d'Alembert) form.
TEST(MobileManipulator, ReferenceIsSelfConsistent) {
  const ukdyn::MobileManipulatorParams p;
  std::mt19937_64 rng(4);
  for (int s = 0; s < 10; ++s) {
    const Vector6d q = uktest::random_q(rng);
    const Vector6d qd = uktest::random_qd(rng);
    const Vector6d el = ukref::coriolis_times_qd(p, q, qd);
    EXPECT_LE(rel_err(Vector6d(ukref::christoffel_coriolis(p, q, qd) * qd), el), 1e-13);
    // d'Alembert: C q̇ = Σ m Jvᵀ (J̇v q̇) (the rotational Jacobians of the paper's model are
    // constant).
    const auto J = ukref::com_jacobians<double>(p, q);
    const auto a = ukref::com_jdot_qd(p, q, qd);
    Vector6d dal = Vector6d::Zero();
    for (std::size_t b = 0; b < 5; ++b)
      dal += ukref::body_mass(p, static_cast<int>(b)) * J[b].transpose() * a[b];
    EXPECT_LE(rel_err(dal, el), 1e-13);
  }
}

// Paper Eq. (9): C is built from the Christoffel symbols of M.
TEST(MobileManipulator, CoriolisMatrixEqualsChristoffelOfReference) {
  for (const auto& p : param_sets()) {
    const auto arm = uktest::make_arm(1, p);
    std::mt19937_64 rng(5);
    for (int s = 0; s < kStates; ++s) {
      const Vector6d q = uktest::random_q(rng);
      const Vector6d qd = uktest::random_qd(rng);
      const Matrix6d ref = ukref::christoffel_coriolis(p, q, qd);
      EXPECT_LE(rel_err(lib_coriolis(*arm, q, qd), ref), kTol)
          << "state " << s << "\nlib\n"
          << lib_coriolis(*arm, q, qd) << "\nref\n"
          << ref;
    }
  }
}

TEST(MobileManipulator, MdotMinusTwoCIsSkewSymmetric) {
  for (const auto& p : param_sets()) {
    const auto arm = uktest::make_arm(1, p);
    std::mt19937_64 rng(6);
    for (int s = 0; s < kStates; ++s) {
      const Vector6d q = uktest::random_q(rng);
      const Vector6d qd = uktest::random_qd(rng);
      const Matrix6d C = lib_coriolis(*arm, q, qd);
      // Ṁ by AD of the reference.
      const Matrix6d Md = ukref::mass_dot(p, q, qd);
      const Matrix6d S = Md - 2.0 * C;
      EXPECT_LE((S + S.transpose()).norm(), 1e-12 * (Md.norm() + 1.0)) << "state " << s;
      // Ṁ by central differences of the library's own M (independent of the reference).
      const double h = 1e-5;
      const Matrix6d Mfd = (lib_mass(*arm, q + h * qd) - lib_mass(*arm, q - h * qd)) / (2.0 * h);
      const Matrix6d Sfd = Mfd - 2.0 * C;
      EXPECT_LE((Sfd + Sfd.transpose()).norm(), 1e-7 * (Md.norm() + 1.0)) << "state " << s;
    }
  }
}

TEST(MobileManipulator, GravityEqualsReference) {
  for (const auto& p : param_sets()) {
    const auto arm = uktest::make_arm(1, p);
    std::mt19937_64 rng(7);
    for (int s = 0; s < kStates; ++s) {
      const Vector6d q = uktest::random_q(rng);
      const Vector6d Gref = ukref::gravity(p, q);
      EXPECT_LE(rel_err(lib_gravity(*arm, q), Gref), kTol)
          << "state " << s << "\nlib " << lib_gravity(*arm, q).transpose() << "\nref "
          << Gref.transpose();
      // The library's potential: its gradient (central differences) is G, and its differences
      // between two states equal the reference's (V is defined up to a constant).
      Vector6d grad;
      const double h = 1e-6;
      for (int i = 0; i < 6; ++i) {
        const Vector6d e = Vector6d::Unit(i) * h;
        grad(i) = (arm->potential({}, q + e) - arm->potential({}, q - e)) / (2.0 * h);
      }
      EXPECT_LE(rel_err(grad, Gref), 1e-8) << "state " << s;
      const Vector6d q2 = uktest::random_q(rng);
      const double dV = arm->potential({}, q2) - arm->potential({}, q);
      const double dVref = ukref::potential<double>(p, q2) - ukref::potential<double>(p, q);
      EXPECT_NEAR(dV, dVref, 1e-12 * (std::abs(dVref) + 1.0)) << "state " << s;
    }
  }
}

TEST(MobileManipulator, CutPointEqualsReference) {
  for (const auto& p : param_sets()) {
    const auto arm = uktest::make_arm(1, p);
    std::mt19937_64 rng(8);
    for (int s = 0; s < kStates; ++s) {
      const Vector6d q = uktest::random_q(rng);
      EXPECT_LE(rel_err(arm->cut_point(q), ukref::cut_point<double>(p, q)), 1e-14);
    }
  }
}

// System level: M, C q̇, G of the 12-coordinate system are block-diagonal copies of the reference.
TEST(MobileManipulator, SystemDynamicsAreBlockDiagonalReference) {
  std::mt19937_64 rng(9);
  const auto pr = uktest::random_params(rng);
  const ukdyn::MobileManipulatorParams pl;
  uktest::TwoArms two(pl, pr);
  ukdyn::ForwardData data(*two.system);
  for (int s = 0; s < 20; ++s) {
    ukdyn::Vec q(12), qd(12);
    q << uktest::random_q(rng), uktest::random_q(rng);
    qd << uktest::random_qd(rng), uktest::random_qd(rng);
    ukdyn::evaluate_dynamics(*two.system, data, 0.0, q, qd);
    ukdyn::Mat Mref = ukdyn::Mat::Zero(12, 12);
    Mref.topLeftCorner<6, 6>() = ukref::mass_matrix<double>(pl, Vector6d(q.head<6>()));
    Mref.bottomRightCorner<6, 6>() = ukref::mass_matrix<double>(pr, Vector6d(q.tail<6>()));
    ukdyn::Vec Cref(12), Gref(12);
    Cref << ukref::coriolis_times_qd(pl, q.head<6>(), qd.head<6>()),
        ukref::coriolis_times_qd(pr, q.tail<6>(), qd.tail<6>());
    Gref << ukref::gravity(pl, q.head<6>()), ukref::gravity(pr, q.tail<6>());
    EXPECT_LE(rel_err(data.M, Mref), kTol);
    EXPECT_LE(rel_err(data.Cqd, Cref), kTol);
    EXPECT_LE(rel_err(data.G, Gref), kTol);
    ukdyn::Mat C(12, 12);
    ukdyn::coriolis_matrix(*two.system, q, qd, C);
    EXPECT_LE(rel_err(ukdyn::Vec(C * qd), Cref), kTol);
    EXPECT_EQ((C.topRightCorner(6, 6).norm()), 0.0);
    EXPECT_EQ((C.bottomLeftCorner(6, 6).norm()), 0.0);
    const double T = ukdyn::kinetic_energy(data, qd);
    const double Tref = ukref::kinetic_energy<double>(pl, q.head<6>(), qd.head<6>()) +
                        ukref::kinetic_energy<double>(pr, q.tail<6>(), qd.tail<6>());
    EXPECT_NEAR(T, Tref, 1e-12 * Tref);
  }
}

// The paper's printed C34 / C43 carry m1 ĉ1/2 where the correct value is m1 ĉ1/4 (paper-notes #5).
// The printed value changes C q̇ (caught by the reference), yet keeps Ṁ − 2C skew-symmetric, so the
// skew-symmetry check alone would not catch it.
TEST(MobileManipulator, PrintedC34C43ErratumIsCaught) {
  const ukdyn::MobileManipulatorParams p;
  const auto arm = uktest::make_arm(1, p);
  Vector6d q, qd;
  q << 0.3, -0.2, 0.4, 0.9, -0.6, 0.2;
  qd << 0.2, -0.1, 0.8, 0.7, -0.3, 0.4;  // δ̇ ≠ 0
  const double m1 = p.link_mass[0], m2 = p.link_mass[1], m3 = p.link_mass[2];
  const double c1 = p.link_length[0] * std::cos(q(3)), s1 = p.link_length[0] * std::sin(q(3));
  const double c2 = p.link_length[1] * std::cos(q(4));
  const double c3 = p.link_length[2] * std::cos(q(5));
  const double dd = qd(2);
  const double tail = m2 * (c1 + c2 / 2) + m3 * (c1 + c2 + c3 / 2);
  const double C34_printed = -(m1 * c1 / 2 + tail) * s1 * dd;
  const double C34_correct = -(m1 * c1 / 4 + tail) * s1 * dd;

  const Matrix6d C = lib_coriolis(*arm, q, qd);
  const Matrix6d Cchr = ukref::christoffel_coriolis(p, q, qd);
  // The reference's Christoffel entries agree with the corrected formula, not with the printed one.
  EXPECT_NEAR(Cchr(2, 3), C34_correct, 1e-12);
  EXPECT_NEAR(Cchr(3, 2), -C34_correct, 1e-12);
  EXPECT_GT(std::abs(Cchr(2, 3) - C34_printed), 1e-2);
  // Ours agrees with the corrected formula.
  EXPECT_NEAR(C(2, 3), C34_correct, 1e-12);
  EXPECT_NEAR(C(3, 2), -C34_correct, 1e-12);

  Matrix6d Cp = C;
  Cp(2, 3) = C34_printed;
  Cp(3, 2) = -C34_printed;
  const Vector6d ref = ukref::coriolis_times_qd(p, q, qd);
  EXPECT_LE(rel_err(Vector6d(C * qd), ref), kTol);
  const double printed_err = rel_err(Vector6d(Cp * qd), ref);
  EXPECT_GT(printed_err, 1e-3) << "the printed C34/C43 should change C q̇";
  // … but Ṁ − 2C stays skew-symmetric with the printed entries.
  const Matrix6d Md = ukref::mass_dot(p, q, qd);
  const Matrix6d S = Md - 2.0 * Cp;
  EXPECT_LE((S + S.transpose()).norm(), 1e-12 * Md.norm());
}

// Subsystem::dynamics (M, C q̇, G in one call): the closed-form override shares one set of sin/cos
// and must match the three separate calls and the AD reference; it writes every entry of its
// outputs (stale values in the caller's storage must not survive).
TEST(MobileManipulator, DynamicsMatchesSeparateCallsAndReference) {
  for (const auto& p : param_sets()) {
    const auto arm = uktest::make_arm(1, p);
    std::mt19937_64 rng(7);
    for (int s = 0; s < kStates; ++s) {
      const Vector6d q = uktest::random_q(rng);
      const Vector6d qd = uktest::random_qd(rng);
      ukdyn::Mat M = ukdyn::Mat::Constant(6, 6, 123.0);
      ukdyn::Vec cqd = ukdyn::Vec::Constant(6, 123.0), g = ukdyn::Vec::Constant(6, 123.0);
      arm->dynamics({}, q, qd, M, cqd, g);
      EXPECT_LE(rel_err(M, lib_mass(*arm, q)), 1e-15) << "state " << s;
      EXPECT_LE(rel_err(cqd, lib_cqd(*arm, q, qd)), 1e-15) << "state " << s;
      EXPECT_LE(rel_err(g, lib_gravity(*arm, q)), 1e-15) << "state " << s;
      EXPECT_LE(rel_err(M, ukref::mass_matrix<double>(p, q)), kTol) << "state " << s;
      EXPECT_LE(rel_err(cqd, ukref::coriolis_times_qd(p, q, qd)), kTol) << "state " << s;
      EXPECT_LE(rel_err(g, ukref::gravity(p, q)), kTol) << "state " << s;
    }
  }
}

namespace {
// A one-coordinate pendulum that does not override dynamics(): the default must call the three.
class PlainPendulum final : public ukdyn::Subsystem {
 public:
  [[nodiscard]] ukdyn::Index dof() const override { return 1; }
  [[nodiscard]] const std::string& name() const override { return name_; }
  [[nodiscard]] const std::vector<std::string>& coordinate_names() const override { return names_; }
  void mass(const ukdyn::EvalContext& /*c*/, ukdyn::CVecRef /*q*/, ukdyn::MatRef M) const override {
    M(0, 0) = 2.0;
  }
  void coriolis(const ukdyn::EvalContext& /*c*/, ukdyn::CVecRef /*q*/, ukdyn::CVecRef /*qd*/,
                ukdyn::MatRef C) const override {
    C(0, 0) = 0.0;
  }
  void coriolis_times_qd(const ukdyn::EvalContext& /*c*/, ukdyn::CVecRef /*q*/, ukdyn::CVecRef qd,
                         ukdyn::VecRef Cqd) const override {
    Cqd(0) = 3.0 * qd(0);
  }
  void gravity(const ukdyn::EvalContext& /*c*/, ukdyn::CVecRef q, ukdyn::VecRef G) const override {
    G(0) = 5.0 * std::sin(q(0));
  }
  [[nodiscard]] double potential(const ukdyn::EvalContext& /*c*/, ukdyn::CVecRef q) const override {
    return -5.0 * std::cos(q(0));
  }

 private:
  std::string name_ = "pendulum";
  std::vector<std::string> names_{"phi"};
};
}  // namespace

TEST(Subsystem, DefaultDynamicsCallsMassCoriolisGravity) {
  const PlainPendulum pend;
  ukdyn::Vec q(1), qd(1), cqd(1), g(1);
  q << 0.3;
  qd << -1.5;
  ukdyn::Mat M(1, 1);
  pend.dynamics({}, q, qd, M, cqd, g);
  EXPECT_EQ(M(0, 0), 2.0);
  EXPECT_EQ(cqd(0), -4.5);
  EXPECT_EQ(g(0), 5.0 * std::sin(0.3));
}

}  // namespace
