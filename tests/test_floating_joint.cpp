// Floating joints of serial chains (ukdyn/symbolic/chain.hpp, JointDef::Type::floating): position
// + unit quaternion, derived with free_body.hpp's rotation and rate. Evidence: (1) a floating root
// whose other links are fixed is one rigid body: it equals a free body of the combined inertia
// (parallel-axis theorem, computed here); (2) an articulated floating chain in free flight keeps
// its linear momentum and its angular momentum about the centre of mass (computed here from an
// independent numeric forward kinematics); (3) the YAML and URDF forms give the same system.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <fstream>
#include <random>

#include "ukdyn/model/system.hpp"
#include "ukdyn/simulate/simulate.hpp"
#include "ukdyn/symbolic/chain.hpp"
#include "ukdyn/symbolic/free_body.hpp"
#include "ukdyn/robot_files/urdf.hpp"
#ifdef UKDYN_HAVE_IO
#include "ukdyn/scenario/scenario.hpp"
#endif

namespace {

using ukdyn::CVecRef;
using ukdyn::ForwardData;
using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::System;
using ukdyn::Vec;
namespace sym = ukdyn::symbolic;
using M3 = Eigen::Matrix3d;
using V3 = Eigen::Vector3d;

const std::vector<std::string> kCoords{"x", "y", "z", "qw", "qx", "qy", "qz"};

// Independent numeric rotations (Eigen): about a unit axis, and roll-pitch-yaw (URDF order).
M3 rot_axis(const V3& a, double t) {
  return Eigen::AngleAxisd(t, a.normalized()).toRotationMatrix();
}
M3 rpy(const V3& r) {
  return rot_axis(V3::UnitZ(), r(2)) * rot_axis(V3::UnitY(), r(1)) * rot_axis(V3::UnitX(), r(0));
}
M3 quat(const Vec& q4) { return Eigen::Quaterniond(q4(0), q4(1), q4(2), q4(3)).toRotationMatrix(); }
V3 omega_body(const Vec& q4, const Vec& qd4) {  // 2 q* ⊗ q̇
  const Eigen::Quaterniond q(q4(0), q4(1), q4(2), q4(3)), qd(qd4(0), qd4(1), qd4(2), qd4(3));
  const Eigen::Quaterniond w = q.conjugate() * qd;
  return 2.0 * V3(w.x(), w.y(), w.z());
}
Vec quat_rate(const Vec& q4, const V3& w) {  // ½ q ⊗ (0, ω)
  const Eigen::Quaterniond r =
      Eigen::Quaterniond(q4(0), q4(1), q4(2), q4(3)) * Eigen::Quaterniond(0, w(0), w(1), w(2));
  Vec v(4);
  v << 0.5 * r.w(), 0.5 * r.x(), 0.5 * r.y(), 0.5 * r.z();
  return v;
}
M3 skew2(const V3& c) { return c.squaredNorm() * M3::Identity() - c * c.transpose(); }

sym::Mat3Ex ex_mat(const M3& m) {
  sym::Mat3Ex r;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) r[static_cast<std::size_t>(3 * i + j)] = m(i, j);
  return r;
}
sym::Vec3Ex ex_vec(const V3& v) { return {v(0), v(1), v(2)}; }

// The rigid pair: body (m1, CoM c1, inertia J1 in a frame turned by r1) on the floating joint and
// a tip (m2, CoM c2, J2) on a fixed joint at (o, ro) from it; c1 is chosen so that the combined
// CoM is the body frame's origin.
struct Rigid {
  double m1 = 2.0, m2 = 0.7;
  V3 r1{0.3, -0.2, 0.5}, o{0.25, -0.1, 0.15}, ro{0.4, 0.1, -0.3}, c2{0.05, 0.12, -0.03};
  M3 J1, J2;
  Rigid() {
    J1 << 0.04, 0.003, -0.002, 0.003, 0.05, 0.001, -0.002, 0.001, 0.07;
    J2 << 0.01, 0.0, 0.002, 0.0, 0.02, -0.001, 0.002, -0.001, 0.015;
  }
  [[nodiscard]] V3 d() const { return o + rpy(ro) * c2; }  // tip CoM in the body frame
  [[nodiscard]] V3 c1() const { return -(m2 / m1) * d(); }
  [[nodiscard]] M3 J() const {  // about the combined CoM (the origin), body frame
    const M3 R1 = rpy(r1), R2 = rpy(ro);
    return R1 * J1 * R1.transpose() + m1 * skew2(c1()) + R2 * J2 * R2.transpose() + m2 * skew2(d());
  }
};

std::shared_ptr<System> with_norm_row(const std::shared_ptr<const ukdyn::Subsystem>& sub,
                                      const std::vector<std::string>& quaternion,
                                      const std::string& name) {
  auto s = std::make_shared<System>();
  s->add_subsystem(sub);
  s->add_constraint(sym::make_constraint(
      sym::free_body_norm_constraint(name, quaternion, s->coordinate_names())));
  return s;
}

struct Chain {
  std::shared_ptr<System> system;
  std::shared_ptr<sym::DerivedSubsystem> sub;
  sym::ChainModel model;
};

Chain rigid_chain(const Rigid& r, double g) {
  sym::ChainDef c("c", kCoords);
  c.gravity = {0, 0, -g};
  auto& f = c.add_joint("float", sym::JointDef::Type::floating, "body");
  f.coordinates = kCoords;
  f.inertial.mass = r.m1;
  f.inertial.com = ex_vec(r.c1());
  f.inertial.rpy = ex_vec(r.r1);
  f.inertial.inertia = ex_mat(r.J1);
  auto& t = c.add_joint("tip", sym::JointDef::Type::fixed, "tip");
  t.origin = {ex_vec(r.o), ex_vec(r.ro)};
  t.inertial.mass = r.m2;
  t.inertial.com = ex_vec(r.c2);
  t.inertial.inertia = ex_mat(r.J2);
  Chain out{nullptr, nullptr, sym::build_chain(c)};
  out.sub = sym::make_subsystem(out.model.def);
  EXPECT_EQ(out.model.quaternions.size(), 1U);
  out.system = with_norm_row(out.sub, out.model.quaternions.at(0).second, "c_float");
  return out;
}

void random_state(std::mt19937_64& rng, Vec& q, Vec& qd) {
  std::normal_distribution<double> nd;
  q.resize(7);
  qd.resize(7);
  for (int i = 0; i < 7; ++i) {
    q(i) = nd(rng);
    qd(i) = nd(rng);
  }
  q.tail(4).normalize();
  qd.tail(4) -= q.tail(4).dot(qd.tail(4)) * q.tail(4);  // tangent to |q| = 1
}

}  // namespace

TEST(FloatingJoint, RigidChainEqualsFreeBodyOfCombinedInertia) {
  const Rigid r;
  const double g = 9.81;
  const Chain ch = rigid_chain(r, g);
  const M3 J = r.J();
  std::array<double, 9> Jf{};
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) Jf[static_cast<std::size_t>(3 * i + j)] = J(i, j);
  const auto fdef = sym::free_body_definition("f", r.m1 + r.m2, Jf, {0, 0, -g}, kCoords);
  auto fsub = sym::make_subsystem(fdef);
  auto fsys = with_norm_row(fsub, {"qw", "qx", "qy", "qz"}, "f");
  // Σ m_i |c_i|²: the chain's M differs from the free body's only by the radial term
  // 4 Σ m_i |c_i|² q qᵀ on the quaternion block (∂(R c)/∂q · q = 2 R c, while E q = 0), which the
  // norm row's multiplier absorbs; so do the radial parts of C q̇ (and G, zero here).
  const double k = 4.0 * (r.m1 * r.c1().squaredNorm() + r.m2 * r.d().squaredNorm());
  std::mt19937_64 rng(11);
  double dM = 0, dC = 0, dG = 0, dqdd = 0;
  for (int trial = 0; trial < 50; ++trial) {
    Vec q, qd;
    random_state(rng, q, qd);
    Mat Mc(7, 7), Mf(7, 7);
    Vec Cc(7), Cf(7), Gc(7), Gf(7);
    ch.sub->dynamics({}, q, qd, Mc, Cc, Gc);
    fsub->dynamics({}, q, qd, Mf, Cf, Gf);
    Mat radial = Mat::Zero(7, 7);
    radial.bottomRightCorner(4, 4) = k * q.tail(4) * q.tail(4).transpose();
    Mat P = Mat::Identity(7, 7);  // projector on the tangent space of |q| = 1
    P.bottomRightCorner(4, 4) -= q.tail(4) * q.tail(4).transpose();
    const double sM = Mf.norm(), sC = std::max(1.0, Cf.norm()), sG = Gf.norm();
    dM = std::max(dM, (Mc - Mf - radial).norm() / sM);
    dC = std::max(dC, (P * (Cc - Cf)).norm() / sC);
    dG = std::max(dG, (Gc - Gf).norm() / sG);
    ForwardData dc(*ch.system), df(*fsys);
    ukdyn::forward(*ch.system, dc, 0.0, q, qd, Vec::Zero(7));
    ukdyn::forward(*fsys, df, 0.0, q, qd, Vec::Zero(7));
    ASSERT_TRUE(dc.result.finite && df.result.finite);
    dqdd = std::max(dqdd, (dc.qdd - df.qdd).norm() / std::max(1.0, df.qdd.norm()));
  }
  EXPECT_LE(dM, 1e-12);
  EXPECT_LE(dC, 1e-12);
  EXPECT_LE(dG, 1e-12);
  EXPECT_LE(dqdd, 1e-12);
  std::printf(
      "floating rigid chain vs free body (50 states): M (less the radial k q q^T) %.3g, "
      "P C %.3g, G %.3g, qdd %.3g (relative)\n",
      dM, dC, dG, dqdd);
}

namespace {

// An articulated floating chain: a body on the floating joint, an arm on a revolute joint about a1
// at o1 (body frame), a forearm on a revolute joint about a2 at o2 (arm frame). Coordinates: the
// floating 7, then th1, th2. No gravity (free flight).
struct Articulated {
  double m0 = 3.0, m1 = 1.2, m2 = 0.8;
  V3 c0{0.02, -0.01, 0.03}, c1{0.2, 0.0, 0.01}, c2{0.15, 0.02, 0.0};
  V3 o1{0.1, 0.05, 0.0}, a1{0.0, 0.0, 1.0}, o2{0.4, 0.0, 0.0}, a2{0.0, 0.6, 0.8};
  M3 J0, J1, J2;
  Articulated() {
    J0 << 0.1, 0.01, 0.0, 0.01, 0.12, -0.005, 0.0, -0.005, 0.15;
    J1 = V3(0.002, 0.02, 0.021).asDiagonal();
    J2 << 0.001, 0.0, 0.0003, 0.0, 0.01, 0.0, 0.0003, 0.0, 0.011;
  }
  // World CoM positions, velocities, rotations and angular velocities of the three bodies.
  struct Body {
    double m;
    V3 p, v, w;
    M3 R;
    M3 J;
  };
  [[nodiscard]] std::array<Body, 3> bodies(const Vec& q, const Vec& qd) const {
    const V3 p(q(0), q(1), q(2)), pd(qd(0), qd(1), qd(2));
    const M3 R0 = quat(q.segment(3, 4));
    const V3 w0 = R0 * omega_body(q.segment(3, 4), qd.segment(3, 4));
    const M3 R1 = R0 * rot_axis(a1, q(7));
    const V3 w1 = w0 + R1 * a1.normalized() * qd(7);
    const V3 j1 = p + R0 * o1;  // joint 1 origin
    const V3 j1d = pd + w0.cross(R0 * o1);
    const M3 R2 = R1 * rot_axis(a2, q(8));
    const V3 w2 = w1 + R2 * a2.normalized() * qd(8);
    const V3 j2 = j1 + R1 * o2;
    const V3 j2d = j1d + w1.cross(R1 * o2);
    return {Body{m0, p + R0 * c0, pd + w0.cross(R0 * c0), w0, R0, J0},
            Body{m1, j1 + R1 * c1, j1d + w1.cross(R1 * c1), w1, R1, J1},
            Body{m2, j2 + R2 * c2, j2d + w2.cross(R2 * c2), w2, R2, J2}};
  }
};

sym::ChainDef articulated_def(const Articulated& a, const std::vector<std::string>& extra = {}) {
  std::vector<std::string> coords = kCoords;
  coords.emplace_back("th1");
  coords.emplace_back("th2");
  coords.insert(coords.end(), extra.begin(), extra.end());
  sym::ChainDef c("c", coords);
  c.gravity = {0, 0, 0};
  auto& f = c.add_joint("float", sym::JointDef::Type::floating, "body");
  f.coordinates = kCoords;
  f.inertial = {a.m0, ex_vec(a.c0), {0, 0, 0}, ex_mat(a.J0)};
  auto& j1 = c.add_joint("j1", sym::JointDef::Type::revolute, "arm");
  j1.origin.xyz = ex_vec(a.o1);
  j1.axis = ex_vec(a.a1);
  j1.coordinate = "th1";
  j1.inertial = {a.m1, ex_vec(a.c1), {0, 0, 0}, ex_mat(a.J1)};
  auto& j2 = c.add_joint("j2", sym::JointDef::Type::revolute, "forearm");
  j2.origin.xyz = ex_vec(a.o2);
  j2.axis = ex_vec(a.a2);
  j2.coordinate = "th2";
  j2.inertial = {a.m2, ex_vec(a.c2), {0, 0, 0}, ex_mat(a.J2)};
  return c;
}

}  // namespace

TEST(FloatingJoint, ArticulatedChainKeepsMomentumInFreeFlight) {
  const Articulated a;
  const sym::ChainModel model = sym::build_chain(articulated_def(a));
  auto sub = sym::make_subsystem(model.def);
  auto system = with_norm_row(sub, model.quaternions.at(0).second, "c_float");
  Vec q0(9), qd0(9);
  q0 << 0.1, -0.2, 0.3, 0, 0, 0, 0, 0.4, -0.7;
  q0.segment(3, 4) << std::cos(0.4), std::sin(0.4) * 0.6, std::sin(0.4) * 0.0, std::sin(0.4) * 0.8;
  qd0 << 0.3, -0.1, 0.2, 0, 0, 0, 0, 2.0, -3.0;
  qd0.segment(3, 4) = quat_rate(q0.segment(3, 4), V3(0.5, -1.0, 0.8));
  // The test's own kinetic energy equals the derived one (the kinematics above are the same).
  auto momenta = [&](const Vec& q, const Vec& qd, V3& P, V3& L, double& T) {
    const auto b = a.bodies(q, qd);
    double m = 0;
    V3 c = V3::Zero(), v = V3::Zero();
    for (const auto& x : b) {
      m += x.m;
      c += x.m * x.p;
      v += x.m * x.v;
    }
    c /= m;
    P = v;
    v /= m;
    L.setZero();
    T = 0;
    for (const auto& x : b) {
      L += x.m * (x.p - c).cross(x.v - v) + x.R * x.J * x.R.transpose() * x.w;
      T += 0.5 * x.m * x.v.squaredNorm() + 0.5 * x.w.dot(x.R * x.J * x.R.transpose() * x.w);
    }
  };
  V3 P0, L0;
  double T0 = 0;
  momenta(q0, qd0, P0, L0, T0);
  ASSERT_NEAR(sub->kinetic({}, q0, qd0), T0, 1e-13 * T0);
  ukdyn::SimulationSettings s;
  s.t_end = 3.0;
  s.sample_dt = 0.05;
  s.integrator = ukdyn::IntegratorKind::rkf78;
  s.abs_tol = 1e-13;
  s.rel_tol = 1e-13;
  double dP = 0, dL = 0, dT = 0;
  const auto st = ukdyn::simulate(*system, q0, qd0, nullptr, s,
                                  [&](double, CVecRef q, CVecRef qd, const ForwardData&) {
                                    V3 P, L;
                                    double T = 0;
                                    momenta(q, qd, P, L, T);
                                    dP = std::max(dP, (P - P0).norm() / P0.norm());
                                    dL = std::max(dL, (L - L0).norm() / L0.norm());
                                    dT = std::max(dT, std::abs(T - T0) / T0);
                                    return true;
                                  });
  ASSERT_EQ(st.status, ukdyn::RunStatus::completed) << st.message;
  EXPECT_LE(dP, 1e-11);
  EXPECT_LE(dL, 1e-10);
  EXPECT_LE(dT, 1e-10);
  std::printf(
      "articulated floating chain, 3 s free flight, rkf78 1e-13: max |dP|/|P| = %.3g, "
      "max |dL_com|/|L| = %.3g, max |dT|/T = %.3g\n",
      dP, dL, dT);
}

TEST(FloatingJoint, CoordinateCountsAndBallJointRows) {
  const Articulated a;
  sym::ChainDef c = articulated_def(a);
  c.joints[0].coordinates.pop_back();
  EXPECT_THROW(sym::build_chain(c), sym::DefinitionError);
  sym::ChainDef d = articulated_def(a, {"bw", "bx", "by", "bz"});
  auto& b = d.add_joint("wrist", sym::JointDef::Type::ball, "hand");  // on the turning forearm
  b.coordinates = {"bw", "bx", "by"};
  EXPECT_THROW(sym::build_chain(d), sym::DefinitionError);
  d.joints.back().coordinates.emplace_back("bz");
  d.joints.back().inertial.mass = 0.1;
  const auto m = sym::build_chain(d);
  ASSERT_EQ(m.quaternions.size(), 2U);
  EXPECT_EQ(m.quaternions[1].first, "wrist");
  EXPECT_EQ(m.quaternions[1].second, (std::vector<std::string>{"bw", "bx", "by", "bz"}));
}

#ifdef UKDYN_HAVE_IO
namespace {

std::string v3(const V3& v) {
  char b[160];
  std::snprintf(b, sizeof b, "[%.17g, %.17g, %.17g]", v(0), v(1), v(2));
  return b;
}

// q̈ of two systems over the same coordinates at random consistent states.
double max_qdd_difference(const System& a, const System& b, int states) {
  std::mt19937_64 rng(5);
  std::normal_distribution<double> nd;
  double worst = 0;
  const Index n = a.dof();
  for (int t = 0; t < states; ++t) {
    Vec q(n), qd(n);
    for (Index i = 0; i < n; ++i) {
      q(i) = nd(rng);
      qd(i) = nd(rng);
    }
    q.segment(3, 4).normalize();
    qd.segment(3, 4) -= q.segment(3, 4).dot(qd.segment(3, 4)) * q.segment(3, 4);
    ForwardData da(a), db(b);
    ukdyn::forward(a, da, 0.0, q, qd, Vec::Zero(n));
    ukdyn::forward(b, db, 0.0, q, qd, Vec::Zero(n));
    if (!da.result.finite || !db.result.finite) return 1e300;
    worst = std::max(worst, (da.qdd - db.qdd).norm() / std::max(1.0, db.qdd.norm()));
  }
  return worst;
}

}  // namespace

TEST(FloatingJoint, YamlAndUrdfFloatingRootMatchTheChain) {
  Articulated a;
  a.J0 = V3(0.1, 0.12, 0.15).asDiagonal();
  // The forearm a point mass (no rotational inertia): three derivations of the full chain take
  // too long for one test.
  a.J2.setZero();
  const sym::ChainModel model = sym::build_chain(articulated_def(a));
  auto ref = with_norm_row(sym::make_subsystem(model.def), model.quaternions.at(0).second, "c");
  auto diag = [](const M3& J) { return v3(J.diagonal()); };
  const std::string head = R"(ukdyn: 1
name: floating
gravity: 0
subsystems:
  - name: c
    type: serial_chain
    coordinates: [x, y, z, qw, qx, qy, qz, th1, th2]
)";
  const std::string tail = R"(initial:
  q: [0, 0, 0, 1, 0, 0, 0, 0, 0]
simulation: {t_end: 0.1, sample_dt: 0.05}
)";
  const std::string yaml = head + "    joints:\n" +
                           "      - {name: float, type: floating, link: body, coordinates: [x, y, "
                           "z, qw, qx, qy, qz], mass: " +
                           std::to_string(a.m0) + ", com: " + v3(a.c0) +
                           ", inertia: " + diag(a.J0) + "}\n" +
                           "      - {name: j1, type: revolute, link: arm, coordinate: th1, "
                           "origin: {xyz: " +
                           v3(a.o1) + "}, axis: " + v3(a.a1) + ", mass: " + std::to_string(a.m1) +
                           ", com: " + v3(a.c1) + ", inertia: " + diag(a.J1) + "}\n" +
                           "      - {name: j2, type: revolute, link: forearm, coordinate: th2, "
                           "origin: {xyz: " +
                           v3(a.o2) + "}, axis: " + v3(a.a2) + ", mass: " + std::to_string(a.m2) +
                           ", com: " + v3(a.c2) + ", inertia: " + diag(a.J2) + "}\n" + tail;
  const auto sc = ukdyn::load_scenario_text(yaml, "floating.yaml");
  ASSERT_EQ(sc.system->rows(), 1);
  EXPECT_EQ(sc.system->constraint_row_names()[0], "c_float_unit");
  const double dy = max_qdd_difference(*sc.system, *ref, 20);
  EXPECT_LE(dy, 1e-12);

  // The same robot as a URDF whose root link is put on a floating joint (floating_root).
  auto inertial = [](double m, const V3& c, const M3& J) {
    char b[400];
    std::snprintf(b, sizeof b,
                  "<inertial><mass value=\"%.17g\"/><origin xyz=\"%.17g %.17g %.17g\"/><inertia "
                  "ixx=\"%.17g\" ixy=\"0\" ixz=\"0\" iyy=\"%.17g\" iyz=\"0\" izz=\"%.17g\"/>"
                  "</inertial>",
                  m, c(0), c(1), c(2), J(0, 0), J(1, 1), J(2, 2));
    return std::string(b);
  };
  auto joint = [](const char* n, const char* p, const char* c, const V3& o, const V3& ax) {
    char b[400];
    std::snprintf(b, sizeof b,
                  "<joint name=\"%s\" type=\"continuous\"><parent link=\"%s\"/><child "
                  "link=\"%s\"/><origin xyz=\"%.17g %.17g %.17g\"/><axis xyz=\"%.17g %.17g "
                  "%.17g\"/></joint>",
                  n, p, c, o(0), o(1), o(2), ax(0), ax(1), ax(2));
    return std::string(b);
  };
  const std::string urdf = "<robot name=\"r\"><link name=\"body\">" + inertial(a.m0, a.c0, a.J0) +
                           "</link><link name=\"arm\">" + inertial(a.m1, a.c1, a.J1) +
                           "</link><link name=\"forearm\">" + inertial(a.m2, a.c2, a.J2) +
                           "</link>" + joint("j1", "body", "arm", a.o1, a.a1) +
                           joint("j2", "arm", "forearm", a.o2, a.a2) + "</robot>\n";
  const std::string dir = ::testing::TempDir();
  const std::string file = dir + "/ukdyn_floating_root.urdf";
  std::ofstream(file) << urdf;
  const std::string yaml_urdf =
      head + "    urdf: " + file + "\n    floating_root: [x, y, z, qw, qx, qy, qz]\n" + tail;
  const auto su = ukdyn::load_scenario_text(yaml_urdf, "floating_urdf.yaml");
  ASSERT_EQ(su.system->rows(), 1);
  EXPECT_EQ(su.system->constraint_row_names()[0], "c_body_floating_unit");
  const double du = max_qdd_difference(*su.system, *ref, 20);
  EXPECT_LE(du, 1e-12);
  std::printf("floating joint: YAML vs C++ qdd %.3g, URDF floating_root vs C++ %.3g\n", dy, du);
  std::remove(file.c_str());
}
#endif
