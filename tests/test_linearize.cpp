// Exact derivatives of the constrained dynamics (ukdyn/model/linearize.hpp): the trees' tangents
// against the double pendulum's closed form, linearize() against central differences of forward()
// (Richardson-extrapolated), redundant rows, and the states where ukdyn cannot vouch for them.
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <Eigen/SVD>
#include <cmath>
#include <random>

#include "ukdyn/model/linearize.hpp"
#include "ukdyn/tree/tree.hpp"

namespace {

using namespace ukdyn;

constexpr double m1 = 1.3, m2 = 0.7, l1 = 0.9, l2 = 0.6, g = 9.81;

// The planar double pendulum of Tree.DoublePendulumClosedForm (axes y, links along −z).
std::shared_ptr<const tree::TreeSubsystem> double_pendulum() {
  tree::Model m;
  m.name = "pendulum";
  m.coordinates = {"q1", "q2"};
  m.gravity = {0, 0, -g};
  tree::Link a, b;
  a.name = "link1";
  a.joint = "j1";
  a.type = tree::JointType::revolute;
  a.axis = {0, 1, 0};
  a.terms = {{0, 1.0}};
  a.mass = m1;
  a.com = {0, 0, -l1};
  b.name = "link2";
  b.joint = "j2";
  b.parent = 0;
  b.type = tree::JointType::revolute;
  b.axis = {0, 1, 0};
  b.origin_translation = {0, 0, -l1};
  b.terms = {{1, 1.0}};
  b.mass = m2;
  b.com = {0, 0, -l2};
  m.links = {a, b};
  return tree::make_subsystem(m);
}

// The tip (link 2's centre of mass) held on a line: x_tip = x0 (axis 0) or z_tip = z0 (axis 2),
// with x_tip = −l1 sin q1 − l2 sin(q1 + q2), z_tip = −l1 cos q1 − l2 cos(q1 + q2). A = ∂x/∂q,
// b = −Ȧ q̇, and the exact tangent by hand; `copies` rows of the same (a redundant set).
class TipOnLine final : public Constraint {
 public:
  TipOnLine(double x0, int copies = 1, int axis = 0) : x0_(x0), copies_(copies), axis_(axis) {
    for (int k = 0; k < copies; ++k)
      names_.push_back(std::string(axis == 0 ? "tip_x" : "tip_z") + std::to_string(k));
  }
  Index rows() const override { return copies_; }
  const std::vector<std::string>& row_names() const override { return names_; }
  // The tip coordinate's gradient (a0, a1), its Hessian applied as Ȧ q̇ = −b, and the position.
  struct Terms {
    double a0, a1, acc, pos;
  };
  Terms terms(CVecRef q, CVecRef qd) const {
    const double c1 = std::cos(q(0)), s1 = std::sin(q(0)), c12 = std::cos(q(0) + q(1)),
                 s12 = std::sin(q(0) + q(1)), w = qd(0) + qd(1);
    if (axis_ == 0)
      return {-l1 * c1 - l2 * c12, -l2 * c12, l1 * s1 * qd(0) * qd(0) + l2 * s12 * w * w,
              -l1 * s1 - l2 * s12};
    return {l1 * s1 + l2 * s12, l2 * s12, l1 * c1 * qd(0) * qd(0) + l2 * c12 * w * w,
            -l1 * c1 - l2 * c12};
  }
  void evaluate(const ConstraintContext&, CVecRef q, CVecRef qd, MatRef A,
                VecRef b) const override {
    const Terms t = terms(q, qd);
    for (int k = 0; k < copies_; ++k) {
      A(k, 0) = t.a0;
      A(k, 1) = t.a1;
      b(k) = -t.acc;
    }
  }
  void position_residual(const ConstraintContext&, CVecRef q, VecRef phi) const override {
    const Terms t = terms(q, Vec::Zero(2));
    for (int k = 0; k < copies_; ++k) phi(k) = t.pos - x0_;
  }
  void velocity_residual(const ConstraintContext&, CVecRef q, CVecRef qd,
                         VecRef phid) const override {
    const Terms t = terms(q, qd);
    for (int k = 0; k < copies_; ++k) phid(k) = t.a0 * qd(0) + t.a1 * qd(1);
  }
  bool has_derivatives() const override { return true; }
  bool tangent(const ConstraintContext&, CVecRef q, CVecRef qd, CVecRef qdd, CVecRef lambda,
               CVecRef dq, CVecRef dqd, VecRef dres, VecRef dforce) const override {
    const double c1 = std::cos(q(0)), s1 = std::sin(q(0)), c12 = std::cos(q(0) + q(1)),
                 s12 = std::sin(q(0) + q(1)), w = qd(0) + qd(1);
    // r = A q̈ − b = a0 q̈1 + a1 q̈2 + acc; ∂a/∂q by hand.
    double da0_1, da0_2, da1_2, dacc_1, dacc_2, daccd_1, daccd_2;
    if (axis_ == 0) {
      da0_1 = l1 * s1 + l2 * s12, da0_2 = l2 * s12, da1_2 = l2 * s12;
      dacc_1 = l1 * c1 * qd(0) * qd(0) + l2 * c12 * w * w, dacc_2 = l2 * c12 * w * w;
      daccd_1 = 2 * l1 * s1 * qd(0) + 2 * l2 * s12 * w, daccd_2 = 2 * l2 * s12 * w;
    } else {
      da0_1 = l1 * c1 + l2 * c12, da0_2 = l2 * c12, da1_2 = l2 * c12;
      dacc_1 = -l1 * s1 * qd(0) * qd(0) - l2 * s12 * w * w, dacc_2 = -l2 * s12 * w * w;
      daccd_1 = 2 * l1 * c1 * qd(0) + 2 * l2 * c12 * w, daccd_2 = 2 * l2 * c12 * w;
    }
    const double da1_1 = da1_2;  // a1 depends on q1 + q2 only
    const double r1 = da0_1 * qdd(0) + da1_1 * qdd(1) + dacc_1;
    const double r2 = da0_2 * qdd(0) + da1_2 * qdd(1) + dacc_2;
    double lam = 0.0;
    for (int k = 0; k < copies_; ++k) {
      dres(k) = r1 * dq(0) + r2 * dq(1) + daccd_1 * dqd(0) + daccd_2 * dqd(1);
      lam += lambda(k);
    }
    // Aᵀλ = λ (a0, a1).
    dforce(0) += lam * (da0_1 * dq(0) + da0_2 * dq(1));
    dforce(1) += lam * (da1_1 * dq(0) + da1_2 * dq(1));
    return true;
  }

 private:
  double x0_;
  int copies_;
  int axis_;
  std::vector<std::string> names_;
};

// Central differences of forward()'s q̈ and Qc along coordinate j of q (which = 0), q̇ (1) or τ (2),
// Richardson-extrapolated: (4 D(h/2) − D(h)) / 3, error O(h⁴).
void differences(const System& sys, const Vec& q, const Vec& qd, const Vec& tau, int which, Index j,
                 Vec& dqdd, Vec& dQc) {
  ForwardData d(sys);
  auto at = [&](double h, Vec& a, Vec& f) {
    Vec x[3] = {q, qd, tau};
    x[which](j) += h;
    forward(sys, d, 0.0, x[0], x[1], x[2]);
    a = d.qdd;
    f = d.Qc;
  };
  auto central = [&](double h, Vec& a, Vec& f) {
    Vec ap, fp, am, fm;
    at(h, ap, fp);
    at(-h, am, fm);
    a = (ap - am) / (2 * h);
    f = (fp - fm) / (2 * h);
  };
  const double h = 1e-3;
  Vec a1, f1, a2, f2;
  central(h, a1, f1);
  central(h / 2, a2, f2);
  dqdd = (4 * a2 - a1) / 3;
  dQc = (4 * f2 - f1) / 3;
}

void expect_matches_differences(const System& sys, const Vec& q, const Vec& qd, const Vec& tau,
                                double tol) {
  const Linearization lin = linearize(sys, 0.0, q, qd, tau);
  EXPECT_TRUE(lin.trusted) << lin.message;
  EXPECT_LE(lin.kkt_agreement, 1e-12);
  const Mat* dq[3] = {&lin.dqdd_dq, &lin.dqdd_dqd, &lin.dqdd_dtau};
  const Mat* dc[3] = {&lin.dQc_dq, &lin.dQc_dqd, &lin.dQc_dtau};
  for (int which = 0; which < 3; ++which) {
    for (Index j = 0; j < sys.dof(); ++j) {
      Vec a, f;
      differences(sys, q, qd, tau, which, j, a, f);
      EXPECT_LE((dq[which]->col(j) - a).norm(), tol * (1 + a.norm())) << which << " " << j;
      EXPECT_LE((dc[which]->col(j) - f).norm(), tol * (1 + f.norm())) << which << " " << j;
    }
  }
}

}  // namespace

// The tree's tangent of ID = M q̈ + C q̇ + G against the closed form of the double pendulum.
TEST(Derivatives, TreeInverseDynamicsTangentMatchesTheClosedForm) {
  const auto tr = double_pendulum();
  ASSERT_TRUE(tr->has_derivatives());
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(-3, 3);
  for (int k = 0; k < 50; ++k) {
    Vec q(2), qd(2), qdd(2);
    q << u(rng), u(rng);
    qd << u(rng), u(rng);
    qdd << u(rng), u(rng);
    const double c1 = std::cos(q(0)), c2 = std::cos(q(1)), s2 = std::sin(q(1)),
                 c12 = std::cos(q(0) + q(1));
    const double h = -m2 * l1 * l2 * s2, dh = -m2 * l1 * l2 * c2;
    Mat J(2, 2), Jd(2, 2);  // ∂ID/∂q, ∂ID/∂q̇
    J(0, 0) = (m1 + m2) * g * l1 * c1 + m2 * g * l2 * c12;
    J(1, 0) = m2 * g * l2 * c12;
    J(0, 1) = -2 * m2 * l1 * l2 * s2 * qdd(0) - m2 * l1 * l2 * s2 * qdd(1) +
              dh * (2 * qd(0) * qd(1) + qd(1) * qd(1)) + m2 * g * l2 * c12;
    J(1, 1) = -m2 * l1 * l2 * s2 * qdd(0) - dh * qd(0) * qd(0) + m2 * g * l2 * c12;
    Jd(0, 0) = 2 * h * qd(1);
    Jd(1, 0) = -2 * h * qd(0);
    Jd(0, 1) = h * (2 * qd(0) + 2 * qd(1));
    Jd(1, 1) = 0.0;
    Vec slot(tr->slot_size());
    for (int j = 0; j < 2; ++j) {
      Vec e = Vec::Zero(2), z = Vec::Zero(2), out(2), out2(2);
      e(j) = 1;
      ASSERT_TRUE(tr->inverse_dynamics_tangent(
          {0.0, {slot.data(), static_cast<std::size_t>(slot.size())}}, q, qd, qdd, e, z, out));
      EXPECT_LE((out - J.col(j)).norm(), 1e-12 * (1 + J.norm())) << "dq " << j;
      ASSERT_TRUE(tr->inverse_dynamics_tangent({}, q, qd, qdd, z, e, out2));  // own buffer
      EXPECT_LE((out2 - Jd.col(j)).norm(), 1e-12 * (1 + Jd.norm())) << "dqd " << j;
    }
  }
}

// No constraints: ∂q̈/∂x = −M⁻¹ ∂ID/∂x, ∂q̈/∂τ = M⁻¹, against central differences of forward().
TEST(Derivatives, UnconstrainedTreeMatchesDifferences) {
  System sys;
  sys.add_subsystem(double_pendulum());
  Vec q(2), qd(2), tau(2);
  q << 0.4, -1.1;
  qd << 0.7, 1.9;
  tau << 0.3, -0.8;
  expect_matches_differences(sys, q, qd, tau, 1e-8);
  const Linearization lin = linearize(sys, 0.0, q, qd, tau);
  EXPECT_EQ(lin.rank, 0);
  ForwardData d(sys);
  forward(sys, d, 0.0, q, qd, tau);
  EXPECT_LE((lin.dqdd_dtau - d.M.inverse()).norm(), 1e-12 * d.M.inverse().norm());
  EXPECT_LE(lin.dQc_dq.norm(), 0.0);
  Mat F, G;
  state_space(lin, F, G);
  EXPECT_EQ(F.rows(), 4);
  EXPECT_EQ(G.cols(), 2);
  EXPECT_EQ(F(0, 2), 1.0);
  EXPECT_EQ(F(3, 1), lin.dqdd_dq(1, 1));
}

// The tip held on a line: ∂q̈ and ∂Qc against central differences (the closed-chain derivatives),
// and the same with the row given twice (rank 1 of 2: the redundant row changes nothing).
TEST(Derivatives, ConstrainedAndRedundantRowsMatchDifferences) {
  Vec q(2), qd(2), tau(2);
  q << 0.4, -1.1;
  const double x0 = -l1 * std::sin(q(0)) - l2 * std::sin(q(0) + q(1));
  // q̇ along the line: A q̇ = 0.
  const double a0 = -l1 * std::cos(q(0)) - l2 * std::cos(q(0) + q(1)),
               a1 = -l2 * std::cos(q(0) + q(1));
  qd << a1, -a0;
  tau << 0.3, -0.8;
  System one;
  one.add_subsystem(double_pendulum());
  one.add_constraint(std::make_shared<TipOnLine>(x0));
  expect_matches_differences(one, q, qd, tau, 1e-7);
  System two;
  two.add_subsystem(double_pendulum());
  two.add_constraint(std::make_shared<TipOnLine>(x0, 2));
  const Linearization l1n = linearize(one, 0.0, q, qd, tau), l2n = linearize(two, 0.0, q, qd, tau);
  EXPECT_TRUE(l2n.trusted) << l2n.message;
  EXPECT_EQ(l2n.rank, 1);
  EXPECT_LE((l1n.dqdd_dq - l2n.dqdd_dq).norm(), 1e-12 * (1 + l1n.dqdd_dq.norm()));
  EXPECT_LE((l1n.dqdd_dqd - l2n.dqdd_dqd).norm(), 1e-12 * (1 + l1n.dqdd_dqd.norm()));
  EXPECT_LE((l1n.dQc_dq - l2n.dQc_dq).norm(), 1e-12 * (1 + l1n.dQc_dq.norm()));
  EXPECT_LE((l1n.dqdd_dtau - l2n.dqdd_dtau).norm(), 1e-12 * (1 + l1n.dqdd_dtau.norm()));
  // ∂q̈/∂τ keeps the motion on the line: A ∂q̈/∂τ = 0.
  Mat A(1, 2);
  A << a0, a1;
  EXPECT_LE((A * l1n.dqdd_dtau).norm(), 1e-12);
}

// The tip held at a point (two rows, rank 2: no motion left): the full-rank closed chain against
// differences; where the arm is stretched (q2 = 0) the two rows become dependent (the singular
// position of a 2R arm), and there or near it ukdyn says it cannot vouch for the derivatives.
TEST(Derivatives, SingularStatesAreFlagged) {
  auto pinned = [](const Vec& q) {
    const double x0 = -l1 * std::sin(q(0)) - l2 * std::sin(q(0) + q(1)),
                 z0 = -l1 * std::cos(q(0)) - l2 * std::cos(q(0) + q(1));
    System sys;
    sys.add_subsystem(double_pendulum());
    sys.add_constraint(std::make_shared<TipOnLine>(x0, 1, 0));
    sys.add_constraint(std::make_shared<TipOnLine>(z0, 1, 2));
    return sys;
  };
  Vec q(2), tau(2);
  q << 0.4, -1.1;
  tau << 0.3, -0.8;
  const System regular = pinned(q);
  expect_matches_differences(regular, q, Vec::Zero(2), tau, 1e-7);
  EXPECT_EQ(linearize(regular, 0.0, q, Vec::Zero(2), tau).rank, 2);
  // Stretched and moving: A has rank 1 and b is not in its range (inconsistent).
  q << 0.4, 0.0;
  Vec qd(2);
  qd << 0.5, -0.2;
  const System stretched = pinned(q);
  const Linearization at = linearize(stretched, 0.0, q, qd, tau);
  EXPECT_EQ(at.rank, 1);
  EXPECT_FALSE(at.trusted);
  EXPECT_FALSE(at.message.empty());
  // 1e-10 rad from it, at rest: rank 2, but the smallest singular value is ~1e-10 of the largest.
  q << 0.4, 1e-10;
  const Linearization near = linearize(pinned(q), 0.0, q, Vec::Zero(2), tau);
  EXPECT_FALSE(near.trusted) << "rank " << near.rank;
  EXPECT_NE(near.message.find("singular"), std::string::npos) << near.message;
  // Wrong sizes and non-finite states are refused.
  EXPECT_THROW((void)linearize(stretched, 0.0, Vec::Zero(3), qd, tau), std::invalid_argument);
  qd(0) = std::nan("");
  EXPECT_THROW((void)linearize(stretched, 0.0, q, qd, tau), std::invalid_argument);
}

// A component without exact derivatives is named, never approximated.
// When every row is kept, linearize() skips the SVD of the row choice (a lower bound of
// σ_min/σ_max of A M^{-1/2} from R⁻¹ of its QR, above 200 rank_rel_tol). With rank_rel_tol just
// under σ_min/σ_max / 100 the bound falls below 200 rank_rel_tol and the SVD decides: the same rows
// and the same derivatives, and no flag (the tip of a 2R arm held at a point, two rows, rank 2).
TEST(Derivatives, RowChoiceWithoutTheSvdKeepsTheSameRows) {
  Vec q(2), tau(2);
  q << 0.4, -1.1;
  tau << 0.3, -0.8;
  System sys;
  sys.add_subsystem(double_pendulum());
  sys.add_constraint(
      std::make_shared<TipOnLine>(-l1 * std::sin(q(0)) - l2 * std::sin(q(0) + q(1)), 1, 0));
  sys.add_constraint(
      std::make_shared<TipOnLine>(-l1 * std::cos(q(0)) - l2 * std::cos(q(0) + q(1)), 1, 2));
  ForwardData d(sys);
  forward(sys, d, 0.0, q, Vec::Zero(2), tau);
  Eigen::LLT<Mat> llt(d.M);
  const Mat Xt = llt.matrixL().solve(d.A.transpose());
  const Vec sv = Eigen::JacobiSVD<Mat>(Xt).singularValues();
  const double ratio = sv(1) / sv(0);
  // Far from the stretched arm: W = A M⁻¹ Aᵀ (ratio² between its extreme eigenvalues) stays above
  // the forward solve's cut-off ratio / 150 too, which keeps both rows.
  ASSERT_GT(ratio, 0.02);
  UkSettings svd_decides;
  svd_decides.rank_rel_tol = ratio / 150.0;  // 200 tol > ratio ≥ the bound; ratio > 100 tol
  const Linearization fast = linearize(sys, 0.0, q, Vec::Zero(2), tau);
  const Linearization slow = linearize(sys, 0.0, q, Vec::Zero(2), tau, svd_decides);
  EXPECT_TRUE(fast.trusted) << fast.message;
  EXPECT_TRUE(slow.trusted) << slow.message;
  EXPECT_EQ(fast.rank, 2);
  EXPECT_EQ(slow.rank, 2);
  EXPECT_EQ(fast.kept_rows, slow.kept_rows);
  const double scale = 1.0 + fast.dqdd_dq.cwiseAbs().maxCoeff();
  EXPECT_LE((fast.dqdd_dq - slow.dqdd_dq).cwiseAbs().maxCoeff(), 1e-14 * scale);
  EXPECT_LE((fast.dQc_dq - slow.dQc_dq).cwiseAbs().maxCoeff(),
            1e-14 * (1.0 + fast.dQc_dq.cwiseAbs().maxCoeff()));
}

TEST(Derivatives, ComponentsWithoutDerivativesAreNamed) {
  class Plain final : public Constraint {
   public:
    Index rows() const override { return 1; }
    const std::vector<std::string>& row_names() const override { return names_; }
    void evaluate(const ConstraintContext&, CVecRef, CVecRef, MatRef A, VecRef b) const override {
      A.setZero();
      A(0, 0) = 1;
      b(0) = 0;
    }
    void position_residual(const ConstraintContext&, CVecRef q, VecRef phi) const override {
      phi(0) = q(0);
    }
    void velocity_residual(const ConstraintContext&, CVecRef, CVecRef qd,
                           VecRef phid) const override {
      phid(0) = qd(0);
    }

   private:
    std::vector<std::string> names_{"hold_q1"};
  };
  System sys;
  sys.add_subsystem(double_pendulum());
  sys.add_constraint(std::make_shared<Plain>());
  const auto missing = components_without_derivatives(sys);
  ASSERT_EQ(missing.size(), 1u);
  EXPECT_NE(missing[0].find("hold_q1"), std::string::npos);
  try {
    (void)linearize(sys, 0.0, Vec::Zero(2), Vec::Zero(2), Vec::Zero(2));
    ADD_FAILURE() << "linearize ran without the constraint's derivatives";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("hold_q1"), std::string::npos) << e.what();
  }
}
