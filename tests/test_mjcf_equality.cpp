// MJCF weld and connect equalities (ukdyn/robot_files/mjcf.hpp: ChainDef::link_constraints, added by
// the scenario as weld / ball frame constraints) against MuJoCo's own equality rows, on
// tests/mjcf/two_arms_load.xml (two 3-joint arms holding a free-body load: a weld to one, a connect
// to the other). Independent evidence, all from MuJoCo 2.2's mj_forward:
//   1. the position rows equal MuJoCo's efc_pos (frame a − frame b, world) at random states;
//   2. at qpos0 (where MuJoCo's compiler made both hold) the rows vanish, and the row space of
//      ukdyn's A, mapped to MuJoCo's velocities by q̇ = H(q) v, is the row space of efc_J;
//   3. the constrained acceleration: MuJoCo's M, qfrc_bias and efc_J with the KKT system
//      [M Jᵀ; J 0][v̇; −λ] = [−bias; −J̇ v] (J̇ v by central differences of efc_J along v,
//      mj_integratePos) against ukdyn's U-K q̈ mapped back, v̇ = H⁺(q̈ − Ḣ v).
// MuJoCo's own solution is soft (solref / solimp), so it is not compared; its ideal-constraint
// quantities are.
#include <gtest/gtest.h>

#ifdef UKDYN_HAVE_IO
#ifdef UKDYN_TEST_HAVE_MUJOCO
#include <mujoco/mujoco.h>

#include <Eigen/Dense>
#include <fstream>
#include <random>

#include "ukdyn/model/system.hpp"
#include "ukdyn/robot_files/mjcf.hpp"
#include "ukdyn/scenario/scenario.hpp"

namespace {

using ukdyn::ForwardData;
using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;

const std::string kFile = std::string(UKDYN_SOURCE_DIR) + "/tests/mjcf/two_arms_load.xml";

std::string scenario_text(const Vec& q0) {
  std::string q = "[";
  for (Index i = 0; i < q0.size(); ++i) {
    char buf[40];
    std::snprintf(buf, sizeof buf, "%s%.17g", i ? ", " : "", q0[i]);
    q += buf;
  }
  q += "]";
  return "ukdyn: 1\nname: two_arms_load\ngravity: 9.81\nsubsystems:\n"
         "  - name: m\n    type: serial_chain\n"
         "    coordinates: [a1, a2, a3, b1, b2, b3, x, y, z, qw, qx, qy, qz]\n"
         "    mjcf: " +
         kFile + "\ninitial:\n  q: " + q +
         "\n  qd: [0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]\nsimulation:\n  t_end: 1\n  sample_dt: "
         "0.01\n";
}

struct MuJoCo {
  mjModel* m = nullptr;
  mjData* d = nullptr;
  MuJoCo() {
    char err[1000] = "";
    m = mj_loadXML(kFile.c_str(), nullptr, err, sizeof err);
    if (m) d = mj_makeData(m);
  }
  ~MuJoCo() {
    if (d) mj_deleteData(d);
    if (m) mj_deleteModel(m);
  }
  MuJoCo(const MuJoCo&) = delete;
  MuJoCo& operator=(const MuJoCo&) = delete;
  void set(const Vec& q, const Vec& v) {
    for (int i = 0; i < m->nq; ++i) d->qpos[i] = q[i];
    for (int i = 0; i < m->nv; ++i) d->qvel[i] = v[i];
    mj_forward(m, d);
  }
  // The equality rows (efc_type == equality, in order), their Jacobian and position error.
  void equality(Mat& J, Vec& pos) const {
    std::vector<int> rows;
    for (int i = 0; i < d->nefc; ++i)
      if (d->efc_type[i] == mjCNSTR_EQUALITY) rows.push_back(i);
    J.resize(static_cast<Index>(rows.size()), m->nv);
    pos.resize(static_cast<Index>(rows.size()));
    for (std::size_t r = 0; r < rows.size(); ++r) {
      for (int c = 0; c < m->nv; ++c) J(static_cast<Index>(r), c) = d->efc_J[rows[r] * m->nv + c];
      pos[static_cast<Index>(r)] = d->efc_pos[rows[r]];
    }
  }
};

// q̇ = H(q) v: hinges and slides one to one, the free joint's position to its world velocity and
// its quaternion by ½ q ⊗ (0, ω_body).
// ½ q ⊗ (0, ω) = Q(q) ω for a quaternion (w, x, y, z).
Eigen::Matrix<double, 4, 3> quat_rate(const Vec& q4) {
  Eigen::Matrix<double, 4, 3> Q;
  Q << -q4(1), -q4(2), -q4(3), q4(0), -q4(3), q4(2), q4(3), q4(0), -q4(1), -q4(2), q4(1), q4(0);
  return 0.5 * Q;
}

Mat velocity_map(const Vec& q) {
  Mat H = Mat::Zero(13, 12);
  H.topLeftCorner(9, 9).setIdentity();
  const Eigen::Matrix<double, 4, 3> Q = quat_rate(q.segment(9, 4));
  for (Index i = 0; i < 4; ++i)
    for (Index j = 0; j < 3; ++j) H(9 + i, 9 + j) = Q(i, j);
  return H;
}

// The projector onto the row space of X (rows of X up to rank r by a rank-revealing SVD).
Mat row_projector(const Mat& X, Index& rank) {
  Eigen::JacobiSVD<Mat> svd(X, Eigen::ComputeFullV);
  const auto& s = svd.singularValues();
  rank = 0;
  while (rank < s.size() && s[rank] > 1e-10 * s[0]) ++rank;
  const Mat V = svd.matrixV().leftCols(rank);
  return V * V.transpose();
}

TEST(MjcfEquality, RowsAndJacobianAndAccelerationMatchMuJoCo) {
  ASSERT_TRUE(ukdyn::symbolic::mjcf_supported());
  MuJoCo mj;
  ASSERT_NE(mj.m, nullptr);
  ASSERT_EQ(mj.m->nq, 13);
  ASSERT_EQ(mj.m->nv, 12);
  ASSERT_EQ(mj.m->neq, 2);
  Vec q0(13);
  for (int i = 0; i < 13; ++i) q0[i] = mj.m->qpos0[i];
  const auto sc = ukdyn::load_scenario_text(scenario_text(q0), "two_arms_load.yaml");
  const auto& sys = *sc.system;
  ASSERT_EQ(sys.dof(), 13);
  // Constraint blocks: the load's unit quaternion, the weld (6 rows), the connect (3 rows).
  const ukdyn::Constraint* weld = nullptr;
  const ukdyn::Constraint* ball = nullptr;
  for (const auto& c : sys.constraints()) {
    if (c->row_names().front() == "m_grip1_x") weld = c.get();
    if (c->row_names().front() == "m_grip2_x") ball = c.get();
  }
  ASSERT_NE(weld, nullptr);
  ASSERT_NE(ball, nullptr);
  ASSERT_EQ(weld->rows(), 6);
  ASSERT_EQ(ball->rows(), 3);

  // 1. Position rows against efc_pos at random states.
  std::mt19937 rng(7u);
  std::normal_distribution<double> nd;
  double worst_pos = 0.0;
  Mat J;
  Vec pos;
  for (int k = 0; k < 50; ++k) {
    Vec q(13);
    for (int i = 0; i < 13; ++i) q[i] = nd(rng);
    q.segment(9, 4).normalize();
    mj.set(q, Vec::Zero(12));
    mj.equality(J, pos);
    ASSERT_EQ(J.rows(), 9);
    Vec pw(6), pb(3);
    weld->position_residual({}, q, pw);
    ball->position_residual({}, q, pb);
    worst_pos = std::max(worst_pos, (pw.head(3) - pos.head(3)).cwiseAbs().maxCoeff());
    worst_pos = std::max(worst_pos, (pb - pos.tail(3)).cwiseAbs().maxCoeff());
  }
  EXPECT_LE(worst_pos, 1e-12);

  // 2. At qpos0: the rows vanish, and the row spaces agree.
  Vec pw(6), pb(3);
  weld->position_residual({}, q0, pw);
  ball->position_residual({}, q0, pb);
  EXPECT_LE(pw.cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LE(pb.cwiseAbs().maxCoeff(), 1e-12);
  mj.set(q0, Vec::Zero(12));
  mj.equality(J, pos);
  const Mat H = velocity_map(q0);
  ForwardData data(sys);
  ukdyn::forward(sys, data, 0.0, q0, Vec::Zero(13), Vec::Zero(13));
  const Mat AH = data.A * H;  // the unit-quaternion row maps to zero
  Index r_uk = 0, r_mj = 0;
  const Mat P_uk = row_projector(AH, r_uk);
  const Mat P_mj = row_projector(J, r_mj);
  EXPECT_EQ(r_uk, 9);
  EXPECT_EQ(r_mj, 9);
  const double space =
      std::max((J - J * P_uk).norm() / J.norm(), (AH - AH * P_mj).norm() / AH.norm());
  EXPECT_LE(space, 1e-12);

  // 3. The constrained acceleration at qpos0, for velocities that keep the constraints.
  Eigen::FullPivLU<Mat> lu(J);
  const Mat N = lu.kernel();  // 12 × 3
  ASSERT_EQ(N.cols(), 3);
  std::vector<mjtNum> full(144);
  double worst_acc = 0.0;
  for (int k = 0; k < 5; ++k) {
    Vec v = N * Vec::NullaryExpr(3, [&] { return nd(rng); });
    mj.set(q0, v);
    mj_fullM(mj.m, full.data(), mj.d->qM);
    Mat M(12, 12);
    for (int i = 0; i < 12; ++i)
      for (int j = 0; j < 12; ++j) M(i, j) = full[static_cast<std::size_t>(12 * i + j)];
    Vec bias(12);
    for (int i = 0; i < 12; ++i) bias[i] = mj.d->qfrc_bias[i];
    Mat J0;
    mj.equality(J0, pos);
    // J̇ v by central differences of J along v (4th order: h and 2h).
    auto J_at = [&](double h) {
      std::vector<mjtNum> qp(q0.data(), q0.data() + 13);
      std::vector<mjtNum> vv(v.data(), v.data() + 12);
      mj_integratePos(mj.m, qp.data(), vv.data(), h);
      Vec qh(13);
      for (int i = 0; i < 13; ++i) qh[i] = qp[static_cast<std::size_t>(i)];
      mj.set(qh, v);
      Mat Jh;
      Vec ph;
      mj.equality(Jh, ph);
      return Jh;
    };
    const double h = 1e-4;
    const Mat Jdot = (8.0 * (J_at(h) - J_at(-h)) - (J_at(2 * h) - J_at(-2 * h))) / (12.0 * h);
    Mat K = Mat::Zero(21, 21);
    K.topLeftCorner(12, 12) = M;
    K.topRightCorner(12, 9) = J0.transpose();
    K.bottomLeftCorner(9, 12) = J0;
    Vec rhs(21);
    rhs.head(12) = -bias;
    rhs.tail(9) = -Jdot * v;
    const Vec vdot_mj = K.fullPivLu().solve(rhs).head(12);
    // ukdyn: q̈ at q̇ = H v; v̇ = H⁺ (q̈ − Ḣ v), Ḣ v = ½ Q(q̇_quat) ω.
    const Vec qd = H * v;
    ukdyn::forward(sys, data, 0.0, q0, qd, Vec::Zero(13));
    Vec Hdv = Vec::Zero(13);
    Hdv.segment(9, 4) = quat_rate(qd.segment(9, 4)) * v.segment(9, 3);
    const Vec vdot_uk = H.colPivHouseholderQr().solve(data.qdd - Hdv);
    worst_acc = std::max(worst_acc, (vdot_uk - vdot_mj).norm() / vdot_mj.norm());
  }
  EXPECT_LE(worst_acc, 1e-6);
  std::printf(
      "MJCF weld + connect vs MuJoCo: position rows %.3g (50 states), row space %.3g, "
      "constrained acceleration %.3g (relative, 5 velocities)\n",
      worst_pos, space, worst_acc);
}

// Two bodies on hinges with one <equality> entry, written to the test's temporary folder.
std::string two_body_model(const std::string& name, const std::string& equality) {
  const std::string xml = testing::TempDir() + name;
  std::ofstream(xml) << "<mujoco><worldbody><body name='a'><joint name='ja'/><geom size='0.1'/>"
                        "</body><body name='b' pos='1 0 0'><joint name='jb'/><geom size='0.1'/>"
                        "</body></worldbody><equality>"
                     << equality << "</equality></mujoco>";
  return xml;
}

TEST(MjcfEquality, JointEqualitiesAreRefusedByName) {
  ASSERT_TRUE(ukdyn::symbolic::mjcf_supported());
  const std::string xml =
      two_body_model("joint_equality.xml", "<joint name='couple' joint1='ja' joint2='jb'/>");
  ukdyn::symbolic::ChainDef c("m", {"qa", "qb"});
  try {
    ukdyn::symbolic::append_mjcf(c, xml);
    FAIL() << "no error";
  } catch (const ukdyn::symbolic::DefinitionError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("equality 'couple'"), std::string::npos) << what;
    EXPECT_NE(what.find("only weld and connect"), std::string::npos) << what;
  }
}

// An equality name that would break a CSV header (a comma, a quote, a newline) is refused with
// the file and the equality named, before it becomes a constraint name.
TEST(MjcfEquality, ImportedNamesObeyTheNameRule) {
  const std::string xml =
      two_body_model("bad_equality_name.xml",
                     "<connect name='x,&quot;y&#10;z' body1='a' body2='b' anchor='0 0 0'/>");
  ukdyn::symbolic::ChainDef c("m", {"qa", "qb"});
  try {
    ukdyn::symbolic::append_mjcf(c, xml);
    FAIL() << "no error";
  } catch (const ukdyn::symbolic::DefinitionError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("equality 0 is named 'x,\"y?z': a name must be"), std::string::npos)
        << what;
  }
}

}  // namespace

#endif  // UKDYN_TEST_HAVE_MUJOCO
#endif  // UKDYN_HAVE_IO
