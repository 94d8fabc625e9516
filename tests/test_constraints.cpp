// Constraint rows A, b, Φ, Φ̇ of the cooperative constraints checked by differentiation of their own
// position residual Φ(q, t) (central differences with Richardson extrapolation) and against the AD
// reference kinematics (tests/reference_model.hpp).
#include <gtest/gtest.h>

#include <functional>

#include "helpers.hpp"
#include "reference_model.hpp"

namespace {

using ukdyn::Constraint;
using ukdyn::Mat;
using ukdyn::Vec;
using uktest::rel_err;
using uktest::Vector6d;

constexpr int kStates = 50;
constexpr double kFdTol = 1e-7;  // relative, finite differences

Vec residual(const Constraint& c, double t, const Vec& q) {
  Vec phi(c.rows());
  c.position_residual({t}, q, phi);
  return phi;
}

/// Φ along the motion q(s) = q0 + v s + a s²/2 at time t0 + s.
struct Motion {
  double t0;
  Vec q0, v, a;
  [[nodiscard]] Vec q(double s) const { return q0 + v * s + 0.5 * a * s * s; }
};

Vec phi_along(const Constraint& c, const Motion& m, double s) {
  return residual(c, m.t0 + s, m.q(s));
}

/// d/ds and d²/ds² of Φ along the motion at s = 0: central differences, one Richardson step.
Vec dphi_fd(const Constraint& c, const Motion& m) {
  auto D = [&](double h) { return Vec((phi_along(c, m, h) - phi_along(c, m, -h)) / (2 * h)); };
  const double h = 1e-3;
  return (4.0 * D(h / 2) - D(h)) / 3.0;
}
Vec ddphi_fd(const Constraint& c, const Motion& m) {
  auto D = [&](double h) {
    return Vec((phi_along(c, m, h) - 2.0 * phi_along(c, m, 0.0) + phi_along(c, m, -h)) / (h * h));
  };
  const double h = 2e-3;
  return (4.0 * D(h / 2) - D(h)) / 3.0;
}
/// ∂Φ/∂q by central differences with one Richardson step.
Mat jacobian_fd(const Constraint& c, double t, const Vec& q) {
  Mat J(c.rows(), q.size());
  for (Eigen::Index j = 0; j < q.size(); ++j) {
    auto D = [&](double h) {
      Vec qp = q, qm = q;
      qp(j) += h;
      qm(j) -= h;
      return Vec((residual(c, t, qp) - residual(c, t, qm)) / (2 * h));
    };
    const double h = 1e-3;
    J.col(j) = (4.0 * D(h / 2) - D(h)) / 3.0;
  }
  return J;
}

Vec random_q12(std::mt19937_64& rng) {
  Vec q(12);
  q << uktest::random_q(rng), uktest::random_q(rng);
  return q;
}
Vec random_v12(std::mt19937_64& rng) {
  Vec v(12);
  v << uktest::random_qd(rng), uktest::random_qd(rng);
  return v;
}

/// The generic checks: A = ∂Φ/∂q, Φ̇ = A q̇ + Φ_t = dΦ/dt, A q̈ − b = d²Φ/dt² along random motions.
void check_constraint(const Constraint& c, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  const Eigen::Index m = c.rows();
  ASSERT_EQ(static_cast<Eigen::Index>(c.row_names().size()), m);
  Mat A(m, 12);
  Vec b(m), phid(m);
  for (int s = 0; s < kStates; ++s) {
    Motion mo{uktest::uniform(rng, 0.0, 2.0), random_q12(rng), random_v12(rng), random_v12(rng)};
    A.setZero();  // System::evaluate_constraints zeroes the rows before the call
    c.evaluate({mo.t0}, mo.q0, mo.v, A, b);
    const Mat Jfd = jacobian_fd(c, mo.t0, mo.q0);
    EXPECT_LE(rel_err(A, Jfd), kFdTol) << "state " << s << "\nA\n" << A << "\nFD\n" << Jfd;
    c.velocity_residual({mo.t0}, mo.q0, mo.v, phid);
    const Vec d1 = dphi_fd(c, mo);
    EXPECT_LE(rel_err(phid, d1), kFdTol)
        << "state " << s << "\nphid " << phid.transpose() << "\nFD   " << d1.transpose();
    const Vec d2 = ddphi_fd(c, mo);
    const Vec lhs = A * mo.a - b;
    EXPECT_LE(rel_err(lhs, d2), kFdTol)
        << "state " << s << "\nAa-b " << lhs.transpose() << "\nFD   " << d2.transpose();
    // b does not depend on q̈, and A does not depend on q̇ (second-order form A(q, t) q̈ = b).
    Mat A2 = Mat::Zero(m, 12);
    Vec b2(m);
    c.evaluate({mo.t0}, mo.q0, mo.v + random_v12(rng), A2, b2);
    EXPECT_LE((A2 - A).norm(), 1e-15 * (A.norm() + 1.0));
  }
}

TEST(Constraints, ClosureDerivativesByFiniteDifferences) {
  uktest::TwoArms two;
  const auto c = two.add_closure();
  EXPECT_EQ(c->rows(), 6);
  check_constraint(*c, 11);
}

TEST(Constraints, ClosureWithOffsetsDerivativesByFiniteDifferences) {
  std::mt19937_64 rng(12);
  uktest::TwoArms two(uktest::random_params(rng), uktest::random_params(rng));
  ukdyn::ClosureConstraint::Options o;
  o.dz = 0.3;
  o.yaw_offset = 2.5;
  o.load_pitch1 = 0.2;
  o.load_pitch2 = -0.1;
  check_constraint(*two.add_closure(o), 13);
}

TEST(Constraints, CutPointTrajectoryDerivativesByFiniteDifferences) {
  uktest::TwoArms two;
  std::array<std::optional<ukdyn::TimeFunction>, 3> axes{
      ukdyn::TimeFunction::make_constant(0.1),
      ukdyn::TimeFunction::make_cosine(0.5, -0.5, uktest::kPi),
      ukdyn::TimeFunction::make_cosine(0.2, 0.7, 1.3, 0.4)};
  const Eigen::Vector3d origin(0.8, 0.1, 0.3);
  ukdyn::CutPointTrajectory left(two.left, 0, axes, origin, "left");
  EXPECT_EQ(left.rows(), 3);
  check_constraint(left, 21);
  ukdyn::CutPointTrajectory right(two.right, 6, axes, origin, "right");
  check_constraint(right, 22);
  // Unused axes are skipped: only y here.
  std::array<std::optional<ukdyn::TimeFunction>, 3> only_y{
      std::nullopt, ukdyn::TimeFunction::make_cosine(0.5, -0.5, uktest::kPi), std::nullopt};
  ukdyn::CutPointTrajectory y(two.left, 0, only_y, origin, "y");
  EXPECT_EQ(y.rows(), 1);
  check_constraint(y, 23);
}

TEST(Constraints, CoordinateConstraintDerivativesByFiniteDifferences) {
  ukdyn::CoordinateConstraint c0(3, ukdyn::TimeFunction::make_cosine(0.1, 0.4, 2.0, 0.3), "th");
  check_constraint(c0, 31);
  ukdyn::CoordinateConstraint c1(8, ukdyn::TimeFunction::make_constant(-1.2), "delta2");
  check_constraint(c1, 32);
}

// Closure against the reference kinematics:
//   Φ = [p1 − p2 (x, y), z1 − z2 − Δz, δ1 − δ2 − yaw_offset, θ3 − load1, θ6 − load2];
// the x, y, z rows of A are J1 − J2 and b_xyz = −(J̇1 q̇1 − J̇2 q̇2), all by AD.
TEST(Constraints, ClosureEqualsReferenceKinematics) {
  std::mt19937_64 rng(41);
  const auto pl = uktest::random_params(rng);
  const auto pr = uktest::random_params(rng);
  uktest::TwoArms two(pl, pr);
  ukdyn::ClosureConstraint::Options o;
  o.dz = 0.25;
  const auto c = two.add_closure(o);
  Mat A(6, 12);
  Vec b(6), phi(6);
  for (int s = 0; s < kStates; ++s) {
    Vec q = random_q12(rng);
    q(8) = q(2) - o.yaw_offset + uktest::uniform(rng, -0.5, 0.5);  // no 2π ambiguity in the yaw row
    const Vec qd = random_v12(rng);
    const Vector6d q1 = q.head<6>(), q2 = q.tail<6>(), v1 = qd.head<6>(), v2 = qd.tail<6>();
    c->position_residual({}, q, phi);
    const Eigen::Vector3d d = ukref::cut_point<double>(pl, q1) - ukref::cut_point<double>(pr, q2) -
                              Eigen::Vector3d(0, 0, o.dz);
    Vec phi_ref(6);
    phi_ref << d, q(2) - q(8) - o.yaw_offset, q(5) - o.load_pitch1, q(11) - o.load_pitch2;
    EXPECT_LE(rel_err(phi, phi_ref), 1e-14) << "state " << s << "\n"
                                            << phi.transpose() << "\n"
                                            << phi_ref.transpose();
    A.setZero();
    c->evaluate({}, q, qd, A, b);
    Mat Aref = Mat::Zero(3, 12);
    Aref.leftCols(6) = ukref::cut_point_jacobian(pl, q1);
    Aref.rightCols(6) = -ukref::cut_point_jacobian(pr, q2);
    EXPECT_LE(rel_err(Mat(A.topRows(3)), Aref), 1e-14) << "state " << s;
    const Eigen::Vector3d bref =
        -(ukref::cut_point_jdot_qd(pl, q1, v1) - ukref::cut_point_jdot_qd(pr, q2, v2));
    EXPECT_LE(rel_err(Vec(b.head(3)), Vec(bref)), 1e-13) << "state " << s << "\n"
                                                         << b.head(3).transpose() << "\n"
                                                         << bref.transpose();
    EXPECT_LE(b.tail(3).norm(), 0.0);
  }
}

// The trajectory constraint against the reference: Φ = p(q) − origin − f(t), b = f̈ − J̇ q̇.
TEST(Constraints, CutPointTrajectoryEqualsReferenceKinematics) {
  std::mt19937_64 rng(42);
  const auto p = uktest::random_params(rng);
  uktest::TwoArms two(uktest::random_params(rng), p);
  const std::array<ukdyn::TimeFunction, 3> f{
      ukdyn::TimeFunction::make_cosine(0.3, 0.2, 1.1),
      ukdyn::TimeFunction::make_cosine(0.5, -0.5, uktest::kPi),
      ukdyn::TimeFunction::make_constant(-0.4)};
  const Eigen::Vector3d origin(0.8, -0.2, 0.6);
  ukdyn::CutPointTrajectory c(two.right, 6, {f[0], f[1], f[2]}, origin, "traj");
  Mat A(3, 12);
  Vec b(3), phi(3);
  for (int s = 0; s < kStates; ++s) {
    const Vec q = random_q12(rng), qd = random_v12(rng);
    const double t = uktest::uniform(rng, 0, 3);
    const Vector6d q2 = q.tail<6>(), v2 = qd.tail<6>();
    c.position_residual({t}, q, phi);
    const Eigen::Vector3d ft(f[0].eval(t), f[1].eval(t), f[2].eval(t));
    const Eigen::Vector3d ftdd(f[0].eval(t, 2), f[1].eval(t, 2), f[2].eval(t, 2));
    EXPECT_LE(rel_err(Vec(phi), Vec(ukref::cut_point<double>(p, q2) - origin - ft)), 1e-14);
    A.setZero();
    c.evaluate({t}, q, qd, A, b);
    EXPECT_EQ(A.leftCols(6).norm(), 0.0);
    EXPECT_LE(rel_err(Mat(A.rightCols(6)), Mat(ukref::cut_point_jacobian(p, q2))), 1e-14);
    EXPECT_LE(rel_err(Vec(b), Vec(ftdd - ukref::cut_point_jdot_qd(p, q2, v2))), 1e-13);
  }
}

TEST(Constraints, PaperInitialStateSatisfiesClosure) {
  uktest::TwoArms two;
  const auto c = two.add_closure();
  const Vec q0 = uktest::paper_q0();
  Vec phi(6), phid(6);
  c->position_residual({}, q0, phi);
  EXPECT_LE(phi.cwiseAbs().maxCoeff(), 1e-15) << phi.transpose();
  // The cut point is at (0.8, 0, 1.2 − 0.4√3) (paper-notes).
  const Eigen::Vector3d p1 = two.left->cut_point(q0.head<6>());
  EXPECT_LE((p1 - Eigen::Vector3d(0.8, 0.0, 1.2 - 0.4 * std::sqrt(3.0))).norm(), 1e-15);
  c->velocity_residual({}, q0, Vec::Zero(12), phid);
  EXPECT_EQ(phid.norm(), 0.0);
  // The trajectory rows are satisfied at t = 0 too.
  two.add_paper_trajectory(q0);
  Vec all(two.system->rows());
  ukdyn::position_residuals(*two.system, 0.0, q0, all);
  EXPECT_EQ(two.system->rows(), 12);
  EXPECT_LE(all.cwiseAbs().maxCoeff(), 1e-15) << all.transpose();
}

// The paper's velocity-consistent start (paper-notes) satisfies A q̇0 = 0.
TEST(Constraints, PaperSpatialStartIsVelocityConsistent) {
  uktest::TwoArms two;
  const auto c = two.add_closure();
  Vec qd0(12);
  qd0 << 0.19943338785662684, -0.3090685792886618, 0.3238357241108272, 0.6732214266883658,
      -0.10243493969032202, 0, 0.09956390871238911, 0.20906857928866182, 0.3238357241108272,
      -0.7333193364981856, -0.10243493969031958, 0;
  Vec phid(6);
  c->velocity_residual({}, uktest::paper_q0(), qd0, phid);
  EXPECT_LE(phid.norm(), 1e-14) << phid.transpose();
}

// System-level stacking: rows of the system are the constraint blocks in order.
TEST(Constraints, SystemStacksBlocksByRows) {
  uktest::TwoArms two;
  const auto c = two.add_closure();
  const Vec q0 = uktest::paper_q0();
  two.add_paper_trajectory(q0);
  ukdyn::ForwardData data(*two.system);
  std::mt19937_64 rng(51);
  const Vec q = random_q12(rng), qd = random_v12(rng);
  ukdyn::evaluate_constraints(*two.system, data, 0.7, q, qd);
  Mat A = Mat::Zero(6, 12);
  Vec b(6);
  c->evaluate({0.7}, q, qd, A, b);
  EXPECT_EQ((data.A.topRows(6) - A).norm(), 0.0);
  EXPECT_EQ((data.b.head(6) - b).norm(), 0.0);
  const auto& offs = two.system->constraint_row_offsets();
  ASSERT_EQ(offs.size(), 5U);
  EXPECT_EQ(offs[0], 0);
  EXPECT_EQ(offs[1], 6);
  EXPECT_EQ(offs[2], 9);
  Vec phid(12), phid_ref(12);
  ukdyn::velocity_residuals(*two.system, 0.7, q, qd, phid);
  Vec tmp(6);
  for (std::size_t k = 0; k < two.system->constraints().size(); ++k) {
    const auto& ck = two.system->constraints()[k];
    Vec v(ck->rows());
    ck->velocity_residual({0.7}, q, qd, v);
    phid_ref.segment(offs[k], ck->rows()) = v;
  }
  EXPECT_EQ((phid - phid_ref).norm(), 0.0);
}

// Constraint::evaluate "writes rows() rows of A": the result must not depend on what A held before
// (a direct caller need not zero it; System::evaluate_constraints happens to).
TEST(Constraints, EvaluateOverwritesPreviousContentsOfA) {
  uktest::TwoArms two;
  const auto closure = two.add_closure();
  two.add_paper_trajectory(uktest::paper_q0());
  std::mt19937_64 rng(61);
  const Vec q = random_q12(rng), qd = random_v12(rng);
  for (const auto& c : two.system->constraints()) {
    Mat A0 = Mat::Zero(c->rows(), 12), A1 = Mat::Constant(c->rows(), 12, 7.0);
    Vec b0(c->rows()), b1 = Vec::Constant(c->rows(), 7.0);
    c->evaluate({0.3}, q, qd, A0, b0);
    c->evaluate({0.3}, q, qd, A1, b1);
    EXPECT_EQ((A1 - A0).norm(), 0.0) << c->row_names().front();
    EXPECT_EQ((b1 - b0).norm(), 0.0) << c->row_names().front();
  }
}

}  // namespace
