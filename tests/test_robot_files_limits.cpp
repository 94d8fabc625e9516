// Real robot files as they are published: joint limits read from URDF <limit> and MJCF range /
// actuator force ranges (into JointDef::limits, ChainDef::coordinate_limits and
// Scenario::coordinate_limits), the joint_limit warnings of simulate, meshes noted and ignored,
// invalid inertias named. Every expected number is worked out by hand from the XML written here.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <numbers>

#include "ukdyn/robot_files/mjcf.hpp"
#include "ukdyn/robot_files/urdf.hpp"
#include "ukdyn/symbolic/expression.hpp"
#ifdef UKDYN_HAVE_IO
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/simulate/simulate.hpp"
#endif

namespace {

namespace sym = ukdyn::symbolic;

constexpr double kInf = std::numeric_limits<double>::infinity();

// A fresh folder for this test's files.
std::filesystem::path test_dir(const std::string& name) {
  const auto d = std::filesystem::temp_directory_path() /
                 ("ukdyn_limits_" + name + "_" + std::to_string(::getpid()));
  std::filesystem::create_directories(d);
  return d;
}

std::string write(const std::filesystem::path& dir, const std::string& file,
                  const std::string& text) {
  const auto p = dir / file;
  std::ofstream(p) << text;
  return p.string();
}

// A URDF tree: j1 revolute, j2 continuous, j3 prismatic (from the base), j4 mimics j1 (2 j1 +
// 0.1), a fixed tool; two meshes (a visual and a collision).
const char* kUrdf = R"(<?xml version="1.0"?>
<robot name="limits">
  <link name="base"/>
  <link name="l1">
    <inertial><mass value="1"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial>
    <visual><geometry><mesh filename="package://x/l1.stl"/></geometry></visual>
    <collision><geometry><mesh filename="package://x/l1_c.stl"/></geometry></collision>
  </link>
  <link name="l2">
    <inertial><mass value="1"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial>
    <visual><geometry><box size="0.1 0.1 0.1"/></geometry></visual>
  </link>
  <link name="l3">
    <inertial><mass value="1"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial>
  </link>
  <link name="l4">
    <inertial><mass value="1"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial>
  </link>
  <link name="tool"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/>
    <limit lower="-1.5" upper="2.0" velocity="3" effort="40"/></joint>
  <joint name="j2" type="continuous"><parent link="base"/><child link="l2"/><axis xyz="0 0 1"/>
    <limit velocity="5" effort="10"/></joint>
  <joint name="j3" type="prismatic"><parent link="base"/><child link="l3"/><axis xyz="1 0 0"/>
    <limit lower="0" upper="0.3" velocity="0.2" effort="100"/></joint>
  <joint name="j4" type="revolute"><parent link="l1"/><child link="l4"/><axis xyz="0 0 1"/>
    <origin xyz="0.5 0 0"/><mimic joint="j1" multiplier="2" offset="0.1"/>
    <limit lower="-3" upper="3" velocity="6" effort="7"/></joint>
  <joint name="tip" type="fixed"><parent link="l4"/><child link="tool"/></joint>
</robot>
)";

const sym::JointDef& joint(const sym::ChainDef& c, const std::string& name) {
  for (const auto& j : c.joints)
    if (j.name == name) return j;
  throw std::runtime_error("no joint " + name);
}

void expect_limits(const ukdyn::CoordinateLimits& l, double lo, double hi, double vel, double eff) {
  EXPECT_EQ(l.lower, lo);
  EXPECT_EQ(l.upper, hi);
  EXPECT_EQ(l.velocity, vel);
  EXPECT_EQ(l.effort, eff);
}

TEST(RobotFileLimits, UrdfLimitsMimicAndMeshes) {
  if (!sym::urdf_supported()) GTEST_SKIP() << "built without urdfdom";
  const auto dir = test_dir("urdf");
  const std::string file = write(dir, "limits.urdf", kUrdf);
  sym::ChainDef c("arm", {"q1", "q2", "q3"});
  sym::append_urdf(c, file);
  expect_limits(joint(c, "j1").limits, -1.5, 2.0, 3.0, 40.0);
  expect_limits(joint(c, "j2").limits, -kInf, kInf, 5.0, 10.0);  // continuous: no range
  expect_limits(joint(c, "j3").limits, 0.0, 0.3, 0.2, 100.0);
  // The mimic joint keeps its limits (on its own value 2 q1 + 0.1) but maps them to nothing.
  expect_limits(joint(c, "j4").limits, -3.0, 3.0, 6.0, 7.0);
  EXPECT_EQ(joint(c, "j4").mimic, "j1");
  const auto L = c.coordinate_limits();
  ASSERT_EQ(L.size(), 3u);
  expect_limits(L[0], -1.5, 2.0, 3.0, 40.0);
  expect_limits(L[1], -kInf, kInf, 5.0, 10.0);
  expect_limits(L[2], 0.0, 0.3, 0.2, 100.0);
  ASSERT_EQ(c.notes.size(), 1u);
  EXPECT_NE(c.notes[0].find("2 meshes ignored"), std::string::npos) << c.notes[0];
  EXPECT_NE(c.notes[0].find(file), std::string::npos) << c.notes[0];
  std::filesystem::remove_all(dir);
}

// θ = −2 q + 0.5 with θ in [−1.5, 2]: q in [(2 − 0.5)/−2, (−1.5 − 0.5)/−2] = [−0.75, 1], |q̇| ≤ 3/2,
// |Q| ≤ 40 · 2.
TEST(RobotFileLimits, AffineJointValuesMapTheirLimits) {
  sym::ChainDef c("arm", {"a", "b"});
  auto& j = c.add_joint("j", sym::JointDef::Type::revolute, "l");
  j.value = -2 * sym::coordinate_symbol(c.symbols(), "a") + GiNaC::numeric(1, 2);
  j.limits = {-1.5, 2.0, 3.0, 40.0};
  auto& k = c.add_joint("k", sym::JointDef::Type::revolute, "m");  // two coordinates: unmapped
  k.value = sym::coordinate_symbol(c.symbols(), "a") + sym::coordinate_symbol(c.symbols(), "b");
  k.limits = {-0.1, 0.1, 0.1, 0.1};
  const auto L = c.coordinate_limits();
  expect_limits(L[0], -0.75, 1.0, 1.5, 80.0);
  expect_limits(L[1], -kInf, kInf, kInf, kInf);
}

// An <inertial> block with `body` inside a one-joint URDF.
std::string one_link_urdf(const std::string& inertial) {
  return R"(<?xml version="1.0"?>
<robot name="bad"><link name="base"/><link name="heavy">)" +
         inertial + R"(</link>
<joint name="j" type="continuous"><parent link="base"/><child link="heavy"/></joint></robot>
)";
}

TEST(RobotFileLimits, UrdfInvalidInertiaNamesFileAndLink) {
  if (!sym::urdf_supported()) GTEST_SKIP() << "built without urdfdom";
  const auto dir = test_dir("urdf_bad");
  const struct {
    const char* inertial;
    const char* says;
  } cases[] = {
      {R"(<inertial><mass value="-1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial>)",
       ">= 0, got -1"},
      // eigenvalues −1, 1, 3
      {R"(<inertial><mass value="1"/><inertia ixx="1" ixy="2" ixz="0" iyy="1" iyz="0" izz="1"/></inertial>)",
       "not positive semi-definite"},
  };
  for (const auto& k : cases) {
    SCOPED_TRACE(k.says);
    const std::string file = write(dir, "bad.urdf", one_link_urdf(k.inertial));
    sym::ChainDef c("arm", {"q"});
    try {
      sym::append_urdf(c, file);
      ADD_FAILURE() << "accepted";
    } catch (const sym::DefinitionError& e) {
      const std::string m = e.what();
      EXPECT_NE(m.find(file), std::string::npos) << m;
      EXPECT_NE(m.find("link 'heavy'"), std::string::npos) << m;
      EXPECT_NE(m.find(k.says), std::string::npos) << m;
    }
  }
  // Principal moments 1 + 1 < 3 (no rigid body has them, but M stays positive semi-definite, and
  // the paper's arm writes such an inertia on purpose): taken, and noted with file and link.
  {
    const std::string file = write(
        dir, "triangle.urdf",
        one_link_urdf(
            R"(<inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="3"/></inertial>)"));
    sym::ChainDef c("arm", {"q"});
    ASSERT_NO_THROW(sym::append_urdf(c, file));
    ASSERT_EQ(c.notes.size(), 1u);
    EXPECT_NE(c.notes[0].find(file + ": link 'heavy'"), std::string::npos) << c.notes[0];
    EXPECT_NE(c.notes[0].find("triangle inequality of a rigid body: principal moments 1 + 1 < 3"),
              std::string::npos)
        << c.notes[0];
  }
  // A valid one (1 + 1 >= 2) is taken without a note.
  const std::string file = write(
      dir, "ok.urdf",
      one_link_urdf(
          R"(<inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="2"/></inertial>)"));
  sym::ChainDef c("arm", {"q"});
  EXPECT_NO_THROW(sym::append_urdf(c, file));
  EXPECT_TRUE(c.notes.empty());
  std::filesystem::remove_all(dir);
}

// MJCF: compiler angle degree (MuJoCo's default), a ref of 30°, a slide, two actuators; a mesh
// given by its vertices.
const char* kMjcf = R"(<mujoco model="limits">
  <compiler angle="degree"/>
  <asset><mesh name="tet" vertex="0 0 0  0.1 0 0  0 0.1 0  0 0 0.1"/></asset>
  <worldbody>
    <body name="a">
      <joint name="h1" type="hinge" axis="0 0 1" limited="true" range="-90 45" ref="30"/>
      <inertial pos="0 0 0" mass="1" diaginertia="0.1 0.1 0.1"/>
      <geom type="mesh" mesh="tet" contype="0" conaffinity="0"/>
      <body name="b" pos="0.5 0 0">
        <joint name="s2" type="slide" axis="1 0 0" limited="true" range="0 0.5"/>
        <inertial pos="0 0 0" mass="1" diaginertia="0.1 0.1 0.1"/>
        <body name="c" pos="0.5 0 0">
          <joint name="h3" type="hinge" axis="0 1 0"/>
          <inertial pos="0 0 0" mass="1" diaginertia="0.1 0.1 0.1"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor joint="h1" gear="2" ctrllimited="true" ctrlrange="-3 3"/>
    <motor joint="s2" gear="1" forcelimited="true" forcerange="-10 8"/>
  </actuator>
</mujoco>
)";

TEST(RobotFileLimits, MjcfRangesInRadiansActuatorsAndMeshes) {
  if (!sym::mjcf_supported()) GTEST_SKIP() << "built without MuJoCo";
  const auto dir = test_dir("mjcf");
  const std::string file = write(dir, "limits.xml", kMjcf);
  sym::ChainDef c("arm", {"q1", "q2", "q3"});
  sym::append_mjcf(c, file);
  const double pi = std::numbers::pi;
  // On the joint's value θ = q − qpos0 (qpos0 = ref = π/6).
  EXPECT_NEAR(joint(c, "h1").limits.lower, -pi / 2 - pi / 6, 1e-15);
  EXPECT_NEAR(joint(c, "h1").limits.upper, pi / 4 - pi / 6, 1e-15);
  const auto L = c.coordinate_limits();
  ASSERT_EQ(L.size(), 3u);
  EXPECT_NEAR(L[0].lower, -pi / 2, 1e-15);  // on qpos: the range in radians
  EXPECT_NEAR(L[0].upper, pi / 4, 1e-15);
  EXPECT_EQ(L[0].velocity, kInf);             // MJCF has no velocity limit
  EXPECT_EQ(L[0].effort, 6.0);                // a motor: |gear| · max |ctrlrange| = 2 · 3
  expect_limits(L[1], 0.0, 0.5, kInf, 10.0);  // forcerange: max(10, 8)
  expect_limits(L[2], -kInf, kInf, kInf, kInf);
  ASSERT_EQ(c.notes.size(), 1u);
  EXPECT_NE(c.notes[0].find("1 mesh ignored"), std::string::npos) << c.notes[0];
  std::filesystem::remove_all(dir);
}

TEST(RobotFileLimits, MjcfInvalidInertiaNamesFileAndBody) {
  if (!sym::mjcf_supported()) GTEST_SKIP() << "built without MuJoCo";
  const auto dir = test_dir("mjcf_bad");
  for (const char* inertial :
       {R"(mass="1" diaginertia="1 1 3")", R"(mass="-1" diaginertia="1 1 1")"}) {
    SCOPED_TRACE(inertial);
    const std::string file = write(dir, "bad.xml",
                                   std::string(R"(<mujoco><worldbody><body name="heavy">
<joint type="hinge" axis="0 0 1"/><inertial pos="0 0 0" )") +
                                       inertial + "/></body></worldbody></mujoco>\n");
    sym::ChainDef c("arm", {"q"});
    try {
      sym::append_mjcf(c, file);
      ADD_FAILURE() << "accepted";
    } catch (const sym::DefinitionError& e) {
      const std::string m = e.what();
      EXPECT_NE(m.find(file), std::string::npos) << m;
      EXPECT_NE(m.find("heavy"), std::string::npos) << m;
    }
  }
  std::filesystem::remove_all(dir);
}

#ifdef UKDYN_HAVE_IO
// Two links on the base, both turning about z, no gravity: M constant and diagonal, no C q̇, so
// q(t) = q0 + q̇0 t exactly. j1 in [−0.5, 0.5] with q̇ = 0.8 leaves its range at t = 0.625: the
// first sample outside (Δ = 0.01) is t = 0.63, q = 0.504. j2's |q̇| = 2 > 1.5 from t = 0.
TEST(RobotFileLimits, SimulateWarnsOncePerCoordinate) {
  if (!sym::urdf_supported()) GTEST_SKIP() << "built without urdfdom";
  const auto dir = test_dir("sim");
  write(dir, "two.urdf", R"(<?xml version="1.0"?>
<robot name="two"><link name="base"/>
  <link name="l1"><inertial><origin xyz="0.3 0 0"/><mass value="1"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
  <link name="l2"><inertial><origin xyz="0.2 0 0"/><mass value="2"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/>
    <limit lower="-0.5" upper="0.5" velocity="1" effort="5"/></joint>
  <joint name="j2" type="revolute"><parent link="base"/><child link="l2"/><axis xyz="0 0 1"/>
    <origin xyz="0 0 1"/><limit lower="-10" upper="10" velocity="1.5" effort="5"/></joint>
</robot>
)");
  const std::string yaml = R"(ukdyn: 1
name: limits
gravity: 0
subsystems:
  - {name: arm, type: serial_chain, coordinates: [a, b], urdf: two.urdf}
initial: {q: [0, 0], qd: [0.8, 2]}
simulation: {t_end: 1, sample_dt: 0.01, integrator: rk4, step: 0.001}
)";
  const ukdyn::Scenario sc = ukdyn::load_scenario_text(yaml, dir / "limits.yaml");
  ASSERT_EQ(sc.coordinate_limits().size(), 2u);
  expect_limits(sc.coordinate_limits()[0], -0.5, 0.5, 1.0, 5.0);
  expect_limits(sc.coordinate_limits()[1], -10, 10, 1.5, 5.0);
  const ukdyn::ForceFunction tau = [](double, ukdyn::CVecRef, ukdyn::CVecRef, ukdyn::VecRef o) {
    o.setZero();
  };
  const auto stats = ukdyn::simulate(*sc.system, sc.q0, sc.qd0, tau, sc.sim, nullptr);
  ASSERT_EQ(stats.status, ukdyn::RunStatus::completed) << stats.message;
  std::vector<ukdyn::RunWarning> w;
  for (const auto& x : stats.warnings)
    if (x.kind == "joint_limit") w.push_back(x);
  ASSERT_EQ(w.size(), 2u);  // once per coordinate, though both stay outside
  EXPECT_EQ(w[0].t, 0.0);
  EXPECT_NE(w[0].message.find("coordinate 'b' exceeded its velocity limit 1.5: |qd| = 2"),
            std::string::npos)
      << w[0].message;
  EXPECT_NEAR(w[1].t, 0.63, 1e-12);
  EXPECT_NE(w[1].message.find("coordinate 'a' left its range [-0.5, 0.5]: q = 0.504"),
            std::string::npos)
      << w[1].message;
  std::filesystem::remove_all(dir);
}
#endif

}  // namespace
