// What the replay page draws besides points and sticks (docs/replay.md): a robot file's shapes on
// its links (URDF <visual> primitives, MJCF geoms), a free body's `shape:`, and the orientation of
// the frame constraints' axes. Every pose is checked against one computed here by other means:
// the closed form of the URDF's joints, MuJoCo's own forward kinematics (mj_kinematics), the
// quaternion of the free body and, for the grasp axes, the robot's wrist in closed form.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>

#include "cli_run.hpp"
#include "ukdyn/output/geometry.hpp"
#include "ukdyn/output/replay.hpp"
#include "ukdyn/output/trajectory_table.hpp"
#include "ukdyn/robot_files/mjcf.hpp"
#include "ukdyn/robot_files/urdf.hpp"
#include "ukdyn/run/run.hpp"
#include "ukdyn/scenario/scenario.hpp"

#ifdef UKDYN_TEST_HAVE_MUJOCO
#include <mujoco/mujoco.h>
#endif

namespace {

using namespace ukdyn;
namespace fs = std::filesystem;
using Mat3 = Eigen::Matrix3d;

void write_file(const fs::path& p, const std::string& text) {
  std::ofstream out(p);
  out << text;
}

// Writes dir/s.yaml, one serial chain `arm` (coordinates a, s) read from a robot file (`robot`:
// "urdf: shapes.urdf", "mjcf: shapes.xml") with `dynamics` (tree or symbolic), and loads it.
Scenario chain_scenario(const fs::path& dir, const std::string& name, const std::string& robot,
                        const char* dynamics) {
  write_file(dir / "s.yaml", fmt::format(R"(ukdyn: 1
name: {}
subsystems:
  - {{name: arm, type: serial_chain, coordinates: [a, s], {}, dynamics: {}}}
initial: {{q: [0, 0], qd: zeros}}
simulation: {{t_end: 1, sample_dt: 0.1}}
)",
                                         name, robot, dynamics));
  return load_scenario(dir / "s.yaml");
}

// R = Rz(yaw) Ry(pitch) Rx(roll) (URDF's rpy).
Mat3 rpy(double r, double p, double y) {
  return (Eigen::AngleAxisd(y, Vec3::UnitZ()) * Eigen::AngleAxisd(p, Vec3::UnitY()) *
          Eigen::AngleAxisd(r, Vec3::UnitX()))
      .toRotationMatrix();
}

// The rotation of the (not necessarily unit) quaternion (w, x, y, z), written out.
Mat3 quat_matrix(double w, double x, double y, double z) {
  const double n = std::sqrt(w * w + x * x + y * y + z * z);
  w /= n, x /= n, y /= n, z /= n;
  Mat3 R;
  R << 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),  //
      2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),   //
      2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y);
  return R;
}

Vec vec2(double a, double b) {
  Vec q(2);
  q << a, b;
  return q;
}

struct Drawn {
  const GeometrySolid* solid = nullptr;
  Vec3 centre;
  Mat3 R;  // solid axes → world
};

// Solid `name` of g at q: its centre point and its orientation as a matrix.
Drawn drawn(const Geometry& g, CVecRef q, const std::string& name) {
  std::vector<Vec3> xyz;
  std::vector<std::array<double, 4>> rot;
  g.evaluate(q, xyz);
  g.evaluate_orientations(q, rot);
  for (std::size_t i = 0; i < g.solids().size(); ++i) {
    if (g.solids()[i].name != name) continue;
    const auto& o = rot[i];
    return {&g.solids()[i], xyz[g.solids()[i].point],
            Eigen::Quaterniond(o[0], o[1], o[2], o[3]).toRotationMatrix()};
  }
  ADD_FAILURE() << "no solid " << name;
  return {};
}

const char* kUrdf = R"(<robot name="shapes">
  <link name="base"/>
  <link name="upper">
    <inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual><origin xyz="0.2 0 0" rpy="0 0 0.4"/><geometry><box size="0.4 0.1 0.05"/></geometry></visual>
    <visual><origin xyz="0.1 0.05 0" rpy="1.2 0.3 0"/><geometry><cylinder radius="0.03" length="0.2"/></geometry></visual>
    <visual><origin xyz="0.4 0 0"/><geometry><sphere radius="0.05"/></geometry></visual>
    <visual><geometry><mesh filename="package://shapes/upper.stl"/></geometry></visual>
  </link>
  <link name="slider">
    <inertial><mass value="0.5"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual><origin xyz="0 0 0.02" rpy="0.1 -0.2 0.3"/><geometry><box size="0.1 0.06 0.04"/></geometry></visual>
  </link>
  <joint name="turn" type="revolute">
    <parent link="base"/><child link="upper"/><origin xyz="0 0 0.5" rpy="0 0.2 0"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="10" velocity="5"/>
  </joint>
  <joint name="slide" type="prismatic">
    <parent link="upper"/><child link="slider"/><origin xyz="0.4 0 0"/>
    <axis xyz="1 0 0"/><limit lower="-1" upper="1" effort="10" velocity="5"/>
  </joint>
</robot>
)";

// URDF <visual> box, cylinder and sphere drawn at their link frames: centre p + R xyz and axes
// R R_visual, against the closed form of the two joints (turn: Ry(0.2) Rz(a) at height 0.5;
// slide: 0.4 + s along the upper link's x), on the tree algorithms and on the symbolic chain. The
// mesh is named in what is not drawn.
TEST(ReplayShapes, UrdfVisualsAtTheirLinkFrames) {
  if (!symbolic::urdf_supported()) GTEST_SKIP() << "built without urdfdom";
  ukdyn_test::ScratchDir dir("ukdyn_urdf_shapes");
  write_file(dir.path / "shapes.urdf", kUrdf);
  for (const char* dynamics : {"tree", "symbolic"}) {
    const Scenario sc = chain_scenario(dir.path, "urdf_shapes", "urdf: shapes.urdf", dynamics);
    std::vector<std::string> left_out;
    const Geometry g = build_geometry(sc, &left_out);
    ASSERT_EQ(left_out.size(), 1u) << dynamics;
    EXPECT_EQ(left_out[0], "arm.upper (mesh package://shapes/upper.stl: meshes are not loaded)");
    ASSERT_EQ(g.solids().size(), 4u) << dynamics;
    struct Expected {
      const char* name;
      const char* shape;
      Vec3 size, xyz;
      Mat3 R;
      bool on_slider;
    };
    const std::vector<Expected> want{
        {"arm.upper.visual0", "box", {0.4, 0.1, 0.05}, {0.2, 0, 0}, rpy(0, 0, 0.4), false},
        {"arm.upper.visual1",
         "cylinder",
         {0.06, 0.06, 0.2},
         {0.1, 0.05, 0},
         rpy(1.2, 0.3, 0),
         false},
        {"arm.upper.visual2", "sphere", {0.1, 0.1, 0.1}, {0.4, 0, 0}, Mat3::Identity(), false},
        {"arm.slider.visual0", "box", {0.1, 0.06, 0.04}, {0, 0, 0.02}, rpy(0.1, -0.2, 0.3), true}};
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> u(-1.5, 1.5);
    for (int k = 0; k < 8; ++k) {
      const double a = u(rng), s = u(rng) / 3;
      const Mat3 Ru = rpy(0, 0.2, 0) * Eigen::AngleAxisd(a, Vec3::UnitZ()).toRotationMatrix();
      const Vec3 pu(0, 0, 0.5);
      const Vec3 ps = pu + Ru * Vec3(0.4 + s, 0, 0);
      for (const auto& e : want) {
        const Drawn d = drawn(g, vec2(a, s), e.name);
        ASSERT_NE(d.solid, nullptr);
        EXPECT_EQ(d.solid->shape, e.shape);
        EXPECT_EQ(d.solid->kind, "link");
        EXPECT_LT((d.solid->size - e.size).norm(), 1e-15) << e.name;
        const Vec3 p = e.on_slider ? ps : pu;
        EXPECT_LT((d.centre - (p + Ru * e.xyz)).norm(), 1e-12) << dynamics << " " << e.name;
        EXPECT_LT((d.R - Ru * e.R).norm(), 1e-12) << dynamics << " " << e.name;
      }
    }
  }
}

const char* kMjcf = R"(<mujoco model="shapes">
  <compiler angle="radian" inertiafromgeom="false"/>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.1"/>
    <geom name="post" type="cylinder" pos="0 0 0.25" size="0.03 0.25"/>
    <body name="arm" pos="0 0 0.5" euler="0.1 0.2 0.3">
      <joint name="hinge" type="hinge" axis="0 0 1" pos="0.01 0 0"/>
      <inertial pos="0.2 0 0" mass="1" diaginertia="0.01 0.02 0.03"/>
      <geom name="upper" type="capsule" fromto="0 0 0 0.4 0.1 0" size="0.04"/>
      <geom name="elbow" type="sphere" pos="0.4 0.1 0" size="0.05"/>
      <body name="forearm" pos="0.4 0.1 0" quat="0.9 0.1 0.3 0.2">
        <joint name="slide" type="slide" axis="1 0 0.2"/>
        <inertial pos="0.1 0 0" mass="0.5" diaginertia="0.01 0.01 0.01"/>
        <geom name="block" type="box" pos="0.15 0 0" euler="0.3 0 0.2" size="0.15 0.03 0.02"/>
        <geom name="egg" type="ellipsoid" pos="0.3 0 0" size="0.05 0.03 0.02"/>
      </body>
    </body>
  </worldbody>
</mujoco>
)";

// MJCF geoms (cylinder on the world body, a capsule given by fromto, sphere, box, ellipsoid)
// drawn where MuJoCo's own mj_kinematics puts them (geom_xpos, geom_xmat) at random qpos, with
// MuJoCo's half-sizes as full extents; the plane is named in what is not drawn.
TEST(ReplayShapes, MjcfGeomsWhereMuJoCoPutsThem) {
#ifndef UKDYN_TEST_HAVE_MUJOCO
  GTEST_SKIP() << "tests built without MuJoCo";
#else
  if (!symbolic::mjcf_supported()) GTEST_SKIP() << "built without MuJoCo";
  ukdyn_test::ScratchDir dir("ukdyn_mjcf_shapes");
  write_file(dir.path / "shapes.xml", kMjcf);
  char err[1000] = "";
  mjModel* m = mj_loadXML((dir.path / "shapes.xml").c_str(), nullptr, err, sizeof err);
  ASSERT_NE(m, nullptr) << err;
  mjData* md = mj_makeData(m);
  for (const char* dynamics : {"tree", "symbolic"}) {
    const Scenario sc = chain_scenario(dir.path, "mjcf_shapes", "mjcf: shapes.xml", dynamics);
    std::vector<std::string> left_out;
    const Geometry g = build_geometry(sc, &left_out);
    ASSERT_EQ(left_out.size(), 1u);
    EXPECT_EQ(
        left_out[0],
        "arm.root (plane: only boxes, spheres, ellipsoids, cylinders and capsules are drawn)");
    ASSERT_EQ(g.solids().size(), 5u);
    // geom id (MuJoCo) → the solid drawn for it, and its extents from the half-sizes
    const std::vector<std::pair<int, std::string>> geoms{{1, "arm.root.visual0"},
                                                         {2, "arm.arm.visual0"},
                                                         {3, "arm.arm.visual1"},
                                                         {4, "arm.forearm.visual0"},
                                                         {5, "arm.forearm.visual1"}};
    const double cap = std::sqrt(0.4 * 0.4 + 0.1 * 0.1);
    const std::vector<Vec3> sizes{{0.06, 0.06, 0.5},
                                  {0.08, 0.08, cap + 0.08},
                                  {0.1, 0.1, 0.1},
                                  {0.3, 0.06, 0.04},
                                  {0.1, 0.06, 0.04}};
    std::mt19937 rng(9);
    std::uniform_real_distribution<double> u(-1.5, 1.5);
    for (int k = 0; k < 8; ++k) {
      const double a = u(rng), s = u(rng) / 3;
      const Vec q = vec2(a, s);
      md->qpos[0] = q(0);
      md->qpos[1] = q(1);
      mj_kinematics(m, md);
      for (std::size_t i = 0; i < geoms.size(); ++i) {
        const auto& [id, name] = geoms[i];
        const Drawn d = drawn(g, q, name);
        ASSERT_NE(d.solid, nullptr);
        EXPECT_LT((d.solid->size - sizes[i]).norm(), 1e-12) << name;
        const Vec3 xpos(md->geom_xpos[3 * id], md->geom_xpos[3 * id + 1],
                        md->geom_xpos[3 * id + 2]);
        const Mat3 xmat =
            Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(md->geom_xmat + 9 * id);
        EXPECT_LT((d.centre - xpos).norm(), 1e-12) << dynamics << " " << name;
        EXPECT_LT((d.R - xmat).norm(), 1e-12) << dynamics << " " << name;
      }
    }
  }
  mj_deleteData(md);
  mj_deleteModel(m);
#endif
}

// An MJCF mesh geom (its vertices inline: no mesh file) drawn as its bounding box: at random qpos,
// every vertex as written in the file, placed by MuJoCo's own body pose (mj_kinematics xpos, xmat)
// and the geom's pos and quat, lies inside the drawn box, and each of the box's 6 faces touches a
// vertex (the box is tight in its own axes). The mesh is named as drawn as its bounding box.
TEST(ReplayShapes, MjcfMeshIsDrawnAsItsBoundingBox) {
#ifndef UKDYN_TEST_HAVE_MUJOCO
  GTEST_SKIP() << "tests built without MuJoCo";
#else
  if (!symbolic::mjcf_supported()) GTEST_SKIP() << "built without MuJoCo";
  const std::vector<Vec3> vertices{{0, 0, 0},   {0.3, 0, 0},      {0, 0.2, 0},
                                   {0, 0, 0.1}, {0.3, 0.2, 0.05}, {0.1, 0.15, 0.12}};
  std::string list;
  for (const auto& v : vertices) list += fmt::format("{} {} {}  ", v.x(), v.y(), v.z());
  const Vec3 gpos(0.1, -0.05, 0.02);
  const Eigen::Quaterniond gquat = Eigen::Quaterniond(0.9, 0.1, -0.2, 0.3).normalized();
  ukdyn_test::ScratchDir dir("ukdyn_mjcf_mesh");
  write_file(dir.path / "mesh.xml", fmt::format(R"(<mujoco model="meshy">
  <compiler angle="radian" inertiafromgeom="false"/>
  <asset><mesh name="wedge" vertex="{}"/></asset>
  <worldbody>
    <body name="arm" pos="0 0 0.5" euler="0.1 0.2 0.3">
      <joint name="hinge" type="hinge" axis="0 1 1"/>
      <inertial pos="0.1 0 0" mass="1" diaginertia="0.01 0.02 0.03"/>
      <geom name="shell" type="mesh" mesh="wedge" pos="{} {} {}" quat="{} {} {} {}"/>
    </body>
  </worldbody>
</mujoco>
)",
                                                list, gpos.x(), gpos.y(), gpos.z(), gquat.w(),
                                                gquat.x(), gquat.y(), gquat.z()));
  write_file(dir.path / "s.yaml", R"(ukdyn: 1
name: mjcf_mesh
subsystems:
  - {name: arm, type: serial_chain, coordinates: [a], mjcf: mesh.xml}
initial: {q: [0], qd: zeros}
simulation: {t_end: 1, sample_dt: 0.1}
)");
  char err[1000] = "";
  mjModel* m = mj_loadXML((dir.path / "mesh.xml").c_str(), nullptr, err, sizeof err);
  ASSERT_NE(m, nullptr) << err;
  mjData* md = mj_makeData(m);
  const Scenario sc = load_scenario(dir.path / "s.yaml");
  std::vector<std::string> left_out;
  const Geometry g = build_geometry(sc, &left_out);
  ASSERT_EQ(left_out.size(), 1u);
  EXPECT_EQ(left_out[0], "arm.arm (mesh wedge: drawn as its bounding box)");
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(-2.0, 2.0);
  double outside = 0, loose = 0;
  for (int k = 0; k < 6; ++k) {
    const Vec q = Vec::Constant(1, u(rng));
    md->qpos[0] = q(0);
    mj_kinematics(m, md);
    const Drawn d = drawn(g, q, "arm.arm.visual0");
    ASSERT_NE(d.solid, nullptr);
    EXPECT_EQ(d.solid->shape, "box");
    const Vec3 xpos(md->xpos[3], md->xpos[4], md->xpos[5]);  // body 1
    const Mat3 xmat = Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(md->xmat + 9);
    Vec3 lo = Vec3::Constant(1e9), hi = -lo;
    for (const auto& v : vertices) {
      const Vec3 world = xpos + xmat * (gpos + gquat * v);
      const Vec3 in_box = d.R.transpose() * (world - d.centre);  // in the box's own axes
      lo = lo.cwiseMin(in_box);
      hi = hi.cwiseMax(in_box);
    }
    const Vec3 half = 0.5 * d.solid->size;
    outside = std::max({outside, (hi - half).maxCoeff(), (-half - lo).maxCoeff()});
    loose = std::max({loose, (half - hi).cwiseAbs().maxCoeff(), (lo + half).cwiseAbs().maxCoeff()});
  }
  std::cout << fmt::format(
      "mesh bounding box: vertices outside by at most {:.2e} m, faces off "
      "the nearest vertex by at most {:.2e} m\n",
      outside, loose);
  EXPECT_LT(outside, 1e-6);  // MuJoCo keeps mesh vertices as floats
  EXPECT_LT(loose, 1e-6);
  mj_deleteData(md);
  mj_deleteModel(m);
#endif
}

// shape: {box | sphere | cylinder} of a free body: that solid, its extents, at the body's (x, y, z)
// with the axes of the body (R of the normalised quaternion, not the principal axes).
TEST(ReplayShapes, FreeBodyShapeReplacesTheInertiaBox) {
  const std::vector<std::tuple<std::string, std::string, Vec3>> cases{
      {"{box: [0.3, 0.2, 0.1]}", "box", {0.3, 0.2, 0.1}},
      {"{sphere: 0.15}", "sphere", {0.3, 0.3, 0.3}},
      {"{cylinder: [0.05, 0.4]}", "cylinder", {0.1, 0.1, 0.4}}};
  for (const auto& [yaml, shape, size] : cases) {
    const Scenario sc = load_scenario_text(fmt::format(R"(ukdyn: 1
name: shaped
subsystems:
  - name: can
    type: free_body
    mass: 2
    inertia: [[0.30, 0.04, -0.02], [0.04, 0.25, 0.03], [-0.02, 0.03, 0.12]]
    shape: {}
initial: {{q: [0, 0, 0, 1, 0, 0, 0], qd: zeros}}
simulation: {{t_end: 1, sample_dt: 0.1}}
)",
                                                       yaml),
                                           "shaped.yaml");
    std::vector<std::string> left_out;
    const Geometry g = build_geometry(sc, &left_out);
    EXPECT_TRUE(left_out.empty());
    ASSERT_EQ(g.solids().size(), 1u);
    std::mt19937 rng(2);
    std::uniform_real_distribution<double> u(-2.0, 2.0);
    for (int k = 0; k < 5; ++k) {
      Vec q(7);
      for (Index i = 0; i < 7; ++i) q(i) = u(rng);
      const Drawn d = drawn(g, q, "can");
      ASSERT_NE(d.solid, nullptr);
      EXPECT_EQ(d.solid->shape, shape);
      EXPECT_EQ(d.solid->kind, "load");
      EXPECT_LT((d.solid->size - size).norm(), 1e-15);
      EXPECT_EQ(d.centre, Vec3(q(0), q(1), q(2)));
      EXPECT_LT((d.R - quat_matrix(q(3), q(4), q(5), q(6))).norm(), 1e-12) << yaml;
    }
  }
}

// The page's embedded JSON data block of a written replay page.
nlohmann::json page_data(const fs::path& dir) {
  const std::string page = ukdyn_test::slurp(dir / kReplayFile);
  const std::string open = "<script type=\"application/json\" id=\"ukdyn-data\">";
  const auto a = page.find(open) + open.size();
  return nlohmann::json::parse(page.substr(a, page.find("</script>", a) - a));
}

// Runs sc into dir (no figures), writes its replay page there and returns the page's data block.
nlohmann::json run_and_replay(const Scenario& sc, const fs::path& dir) {
  RunOptions ro;
  ro.figures = false;
  EXPECT_TRUE(run_scenario(sc, dir, ro).complete());
  write_replay(sc, dir);
  return page_data(dir);
}

// Bodies of a definitions subsystem drawn as their inertia-equivalent boxes (docs/replay.md): a
// pendulum about the world x axis, CoM (0, l sin θ, −l cos θ) and rotation Rx(θ), with a diagonal
// inertia of three different moments, and a bob with a scalar inertia and no rotation (a cube,
// axis-aligned). At every frame of a run the page's embedded position of the pendulum's box is the
// closed form at the CSV's θ, and its embedded orientation B satisfies B J_box Bᵀ = Rx(θ) J Rx(θ)ᵀ
// (J_box the inertia of the drawn box, J the body's): the box has the body's inertia, turned.
TEST(ReplayShapes, DefinitionsBodiesAreTheirInertiaBoxesAtTheirCom) {
  if (!replay_available()) GTEST_SKIP() << "built without three.js (web/node_modules missing)";
  const double l = 0.6, m = 2.0, mb = 0.5, Ib = 0.004;
  const Vec3 Id(0.02, 0.05, 0.06);
  const std::string text = R"(ukdyn: 1
name: pendulum_box
subsystems:
  - name: pend
    type: definitions
    coordinates: [th, y]
    parameters: {l: 0.6, m: 2}
    bodies:
      - name: rod
        mass: m
        com: [0, l*sin(th), -l*cos(th)]
        rotation: [[1, 0, 0], [0, cos(th), -sin(th)], [0, sin(th), cos(th)]]
        inertia: [0.02, 0.05, 0.06]
      - name: bob
        mass: 0.5
        com: [0.3, y, 0]
        inertia: 0.004
        angular_velocity: [0, 0, 0]
initial: {q: [1.2, 0], qd: [0, 0.4]}
simulation: {t_end: 2, sample_dt: 0.05}
)";
  const Scenario sc = load_scenario_text(text, "pendulum_box.yaml");
  std::vector<std::string> left_out;
  const Geometry g = build_geometry(sc, &left_out);
  EXPECT_TRUE(left_out.empty());
  ukdyn_test::ScratchDir dir("ukdyn_definitions_boxes");
  const auto data = run_and_replay(sc, dir.path);
  const auto index = [&](const nlohmann::json& list, const std::string& name) {
    for (std::size_t i = 0; i < list.size(); ++i)
      if (list[i]["name"] == name) return i;
    ADD_FAILURE() << "no " << name;
    return std::size_t{0};
  };
  const std::size_t rod = index(data["solids"], "pend.rod"),
                    bob = index(data["solids"], "pend.bob");
  ASSERT_EQ(data["solids"][rod]["shape"], "box");
  const std::size_t rp = data["solids"][rod]["point"], bp = data["solids"][bob]["point"];
  const auto box_inertia = [](const nlohmann::json& size, double mass) {
    const Vec3 e(size[0].get<double>(), size[1].get<double>(), size[2].get<double>());
    const Vec3 e2 = e.cwiseProduct(e);
    return Mat3(Vec3(e2(1) + e2(2), e2(0) + e2(2), e2(0) + e2(1)).asDiagonal() * (mass / 12.0));
  };
  const Mat3 Jrod = box_inertia(data["solids"][rod]["size"], m);
  const Mat3 Jbob = box_inertia(data["solids"][bob]["size"], mb);
  const TrajectoryTable tab = read_trajectory(dir.path / "trajectory.csv");
  const auto col = [&](const std::string& n) {
    return static_cast<std::size_t>(std::find(tab.header.begin(), tab.header.end(), n) -
                                    tab.header.begin());
  };
  ASSERT_EQ(data["pos"].size(), tab.rows.size());
  double worst_p = 0, worst_J = 0, worst_bob = 0, swing = 0, unturned = 0;
  for (std::size_t f = 0; f < tab.rows.size(); ++f) {
    const double th = tab.rows[f][col("th")], y = tab.rows[f][col("y")];
    const auto& pos = data["pos"][f];
    const auto& rot = data["rot"][f];
    const auto at = [&](std::size_t p) {
      return Vec3(pos[3 * p].get<double>(), pos[3 * p + 1].get<double>(),
                  pos[3 * p + 2].get<double>());
    };
    const auto turn = [&](std::size_t s) {
      return quat_matrix(rot[4 * s].get<double>(), rot[4 * s + 1].get<double>(),
                         rot[4 * s + 2].get<double>(), rot[4 * s + 3].get<double>());
    };
    const Mat3 R = Eigen::AngleAxisd(th, Vec3::UnitX()).toRotationMatrix();
    worst_p = std::max(worst_p, (at(rp) - Vec3(0, l * std::sin(th), -l * std::cos(th))).norm());
    const Mat3 B = turn(rod);
    worst_J =
        std::max(worst_J, (B * Jrod * B.transpose() - R * Id.asDiagonal() * R.transpose()).norm());
    const Mat3 Bb = turn(bob);
    worst_bob = std::max({worst_bob, (at(bp) - Vec3(0.3, y, 0)).norm(),
                          (Bb * Jbob * Bb.transpose() - Ib * Mat3::Identity()).norm()});
    swing = std::max(swing, std::abs(th - 1.2));
    // what a box drawn axis-aligned (its rotation left out) would be off by
    unturned =
        std::max(unturned, (Mat3(Id.asDiagonal()) - R * Id.asDiagonal() * R.transpose()).norm());
  }
  std::cout << fmt::format(
      "definitions boxes: {} frames, θ swings up to {:.3f} rad from its start; rod centre vs "
      "closed form {:.2e} m, inertia of the drawn box vs Rx(θ) J Rx(θ)ᵀ {:.2e} kg m² (drawn "
      "unturned: {:.2e}), bob {:.2e}\n",
      tab.rows.size(), swing, worst_p, worst_J, unturned, worst_bob);
  EXPECT_GT(swing, 1.0);     // it swings: not a comparison of constant poses
  EXPECT_LT(worst_p, 1e-5);  // 6 significant digits in the page
  EXPECT_LT(worst_J, 1e-6);  // of moments ~0.05
  EXPECT_LT(worst_bob, 1e-5);
}

// The wheels of a wheeled platform (docs/wheeled-platforms.md) as cylinders (docs/replay.md): a
// three-wheel omni platform whose wheels have headings π/2, 7π/6 and −π/6, driven so that it
// moves and turns. At every frame of a run the page's embedded centre of each wheel is its mount
// (a, b) carried by the CSV's platform pose, (x + a cos ψ − b sin ψ, y + a sin ψ + b cos ψ, r),
// the cylinder's axis (its own z, turned by the embedded orientation) is the axle Rz(ψ) (−sin β,
// cos β, 0), and its diameter is 2 r.
TEST(ReplayShapes, PlatformWheelsAreCylindersOnTheirAxles) {
  if (!replay_available()) GTEST_SKIP() << "built without three.js (web/node_modules missing)";
  const double r = 0.1;
  const std::vector<std::array<double, 3>> wheels{// a, b, β
                                                  {0.3, 0.0, M_PI / 2},
                                                  {-0.15, 0.2598, 7 * M_PI / 6},
                                                  {-0.15, -0.2598, -M_PI / 6}};
  const std::string text = R"(ukdyn: 1
name: kiwi
subsystems:
  - name: base
    type: omni
    mass: 20
    yaw_inertia: 1.2
    wheel_radius: 0.1
    wheel_inertia: 0.005
    wheels:
      - {position: [0.3, 0], heading: pi/2}
      - {position: [-0.15, 0.2598], heading: 7*pi/6}
      - {position: [-0.15, -0.2598], heading: -pi/6}
initial: {q: [0.5, -0.2, 0.3, 0, 0, 0], qd: zeros}
forces:
  elements:
    - {type: torque, name: t1, coordinate: base_phi1, value: 0.3}
    - {type: torque, name: t2, coordinate: base_phi2, value: 0.1 + 0.2*cos(t)}
    - {type: torque, name: t3, coordinate: base_phi3, value: -0.2}
simulation: {t_end: 2, sample_dt: 0.05}
)";
  const Scenario sc = load_scenario_text(text, "kiwi.yaml");
  ukdyn_test::ScratchDir dir("ukdyn_platform_wheels");
  const auto data = run_and_replay(sc, dir.path);
  const TrajectoryTable tab = read_trajectory(dir.path / "trajectory.csv");
  const auto col = [&](const std::string& n) {
    return static_cast<std::size_t>(std::find(tab.header.begin(), tab.header.end(), n) -
                                    tab.header.begin());
  };
  ASSERT_EQ(data["pos"].size(), tab.rows.size());
  double worst_p = 0, worst_axis = 0, turned = 0, moved = 0;
  for (std::size_t k = 0; k < wheels.size(); ++k) {
    const std::string name = "base.wheel" + std::to_string(k + 1);
    std::size_t s = data["solids"].size();
    for (std::size_t i = 0; i < data["solids"].size(); ++i)
      if (data["solids"][i]["name"] == name) s = i;
    ASSERT_LT(s, data["solids"].size()) << "no solid " << name;
    const auto& solid = data["solids"][s];
    EXPECT_EQ(solid["shape"], "cylinder");
    EXPECT_NEAR(solid["size"][0].get<double>(), 2 * r, 1e-12);
    EXPECT_NEAR(solid["size"][1].get<double>(), 2 * r, 1e-12);
    const std::size_t p = solid["point"];
    const auto [a, b, beta] = wheels[k];
    for (std::size_t f = 0; f < tab.rows.size(); ++f) {
      const auto& row = tab.rows[f];
      const double x = row[col("base_x")], y = row[col("base_y")], psi = row[col("base_yaw")];
      const auto& pos = data["pos"][f];
      const auto& rot = data["rot"][f];
      const Vec3 centre(pos[3 * p].get<double>(), pos[3 * p + 1].get<double>(),
                        pos[3 * p + 2].get<double>());
      const Vec3 want(x + a * std::cos(psi) - b * std::sin(psi),
                      y + a * std::sin(psi) + b * std::cos(psi), r);
      worst_p = std::max(worst_p, (centre - want).norm());
      const Vec3 axis = quat_matrix(rot[4 * s].get<double>(), rot[4 * s + 1].get<double>(),
                                    rot[4 * s + 2].get<double>(), rot[4 * s + 3].get<double>())
                            .col(2);
      const Vec3 axle(-std::sin(beta + psi), std::cos(beta + psi), 0.0);  // Rz(ψ) s
      worst_axis = std::max(worst_axis, std::min((axis - axle).norm(), (axis + axle).norm()));
      turned = std::max(turned, std::abs(psi - 0.3));
      moved = std::max(moved, std::hypot(x - 0.5, y + 0.2));
    }
  }
  // the platform's deck: a square slab of yaw moment m (s² + s²) / 12 = I at (x, y, r), turned by ψ
  std::size_t deck = data["solids"].size();
  for (std::size_t i = 0; i < data["solids"].size(); ++i)
    if (data["solids"][i]["name"] == "base.platform") deck = i;
  ASSERT_LT(deck, data["solids"].size()) << "no solid base.platform";
  const double side = data["solids"][deck]["size"][0].get<double>();
  EXPECT_NEAR(20 * (side * side + std::pow(data["solids"][deck]["size"][1].get<double>(), 2)) / 12,
              1.2, 1e-5);
  const std::size_t dp = data["solids"][deck]["point"];
  double worst_deck = 0;
  for (std::size_t f = 0; f < tab.rows.size(); ++f) {
    const auto& row = tab.rows[f];
    const double psi = row[col("base_yaw")];
    const auto& pos = data["pos"][f];
    const auto& rot = data["rot"][f];
    const Vec3 centre(pos[3 * dp].get<double>(), pos[3 * dp + 1].get<double>(),
                      pos[3 * dp + 2].get<double>());
    const Mat3 R = quat_matrix(rot[4 * deck].get<double>(), rot[4 * deck + 1].get<double>(),
                               rot[4 * deck + 2].get<double>(), rot[4 * deck + 3].get<double>());
    worst_deck =
        std::max({worst_deck, (centre - Vec3(row[col("base_x")], row[col("base_y")], r)).norm(),
                  (R - Eigen::AngleAxisd(psi, Vec3::UnitZ()).toRotationMatrix()).norm()});
  }
  EXPECT_LT(worst_deck, 1e-5);
  std::cout << fmt::format(
      "platform wheels: {} frames, the platform moved {:.3f} m and turned {:.3f} rad; wheel "
      "centres vs the CSV pose {:.2e} m, axes vs the axles {:.2e}; the deck {:.2e}\n",
      tab.rows.size(), moved, turned, worst_p, worst_axis, worst_deck);
  EXPECT_GT(moved, 0.05);  // it moves and turns: not a comparison of constant poses
  EXPECT_GT(turned, 0.1);
  EXPECT_LT(worst_p, 1e-5);  // 6 significant digits in the page
  EXPECT_LT(worst_axis, 1e-5);
}

// The frame constraints' axes on the page (docs/replay.md): the page poses them by the pose_<c>_*
// columns it embeds. A free-body load welded to a 3-joint wrist swings in 3D under gravity; at every
// frame the embedded quaternion's rotation must equal (1) the load's rotation R(qw, qx, qy, qz)
// times the weld's offset on the load, Rz Ry Rx of its rpy (frame b), and (2) the wrist in closed
// form, R_mount Rz(r1) Ry(r2) Rx(r3), times the offset on the hand (frame a: the same frame while
// the weld holds). A transposed rotation is several tenths away from both (checked too).
TEST(ReplayFrames, GraspAxesHaveTheGraspFramesOrientation) {
  if (!replay_available()) GTEST_SKIP() << "built without three.js (web/node_modules missing)";
  const Mat3 Rm = rpy(0.2, -0.1, 0.3), Ra = rpy(-0.2, 0.1, 0.4), Rb = rpy(0.3, -0.4, 0.5);
  const Vec3 pm(0, 0, 1), xa(0.1, 0, 0), xb(0.1, 0.05, -0.02);
  const auto wrist = [&](double r1, double r2, double r3) {
    return Mat3(Rm * Eigen::AngleAxisd(r1, Vec3::UnitZ()) * Eigen::AngleAxisd(r2, Vec3::UnitY()) *
                Eigen::AngleAxisd(r3, Vec3::UnitX()));
  };
  // The welded start: R_load Rb = R_hand Ra, p_load + R_load xb = p_mount + R_hand xa.
  const double r1 = 0.3, r2 = -0.2, r3 = 0.5;
  const Mat3 Rh = wrist(r1, r2, r3);
  const Mat3 Rl = Rh * Ra * Rb.transpose();
  const Vec3 pl = pm + Rh * xa - Rl * xb;
  const Eigen::Quaterniond ql(Rl);
  const std::string text =
      fmt::format(R"(ukdyn: 1
name: grasp_axes
gravity: 9.81
subsystems:
  - name: wrist
    type: serial_chain
    coordinates: [r1, r2, r3]
    gravity: [0, 0, 0]
    mount: {{xyz: [0, 0, 1], rpy: [0.2, -0.1, 0.3]}}
    joints:
      - {{name: w1, type: revolute, link: l1, axis: [0, 0, 1], coordinate: r1, mass: 0.3,
         inertia: [0.002, 0.002, 0.003]}}
      - {{name: w2, type: revolute, link: l2, axis: [0, 1, 0], coordinate: r2, mass: 0.3,
         inertia: [0.002, 0.003, 0.002]}}
      - {{name: w3, type: revolute, link: hand, axis: [1, 0, 0], coordinate: r3, mass: 0.5,
         com: [0.05, 0, 0], inertia: [0.003, 0.002, 0.002]}}
  - {{name: load, type: free_body, mass: 2, inertia: [0.02, 0.03, 0.04]}}
constraints:
  - {{type: weld, name: grasp, a: {{frame: wrist.hand, xyz: [0.1, 0, 0], rpy: [-0.2, 0.1, 0.4]}},
     b: {{frame: load.load, xyz: [0.1, 0.05, -0.02], rpy: [0.3, -0.4, 0.5]}}}}
initial:
  q: [{}, {}, {}, {:.17g}, {:.17g}, {:.17g}, {:.17g}, {:.17g}, {:.17g}, {:.17g}]
  qd: zeros
simulation: {{t_end: 0.6, sample_dt: 0.02, integrator: dopri5, abs_tol: 1e-11, rel_tol: 1e-11}}
)",
                  r1, r2, r3, pl.x(), pl.y(), pl.z(), ql.w(), ql.x(), ql.y(), ql.z());
  const Scenario sc = load_scenario_text(text, "grasp_axes.yaml");
  ukdyn_test::ScratchDir dir("ukdyn_grasp_axes");
  const auto data = run_and_replay(sc, dir.path);
  const auto& col = data["columns"];
  const TrajectoryTable tab = read_trajectory(dir.path / "trajectory.csv");
  const auto& names = sc.system->coordinate_names();
  const auto qcol = [&](const std::string& n) {
    return static_cast<std::size_t>(std::find(tab.header.begin(), tab.header.end(), n) -
                                    tab.header.begin());
  };
  ASSERT_EQ(col["pose_grasp_qw"].size(), tab.rows.size());
  double worst_b = 0, worst_a = 0, least_transposed = 1e9, turned = 0;
  for (std::size_t f = 0; f < tab.rows.size(); ++f) {
    const auto v = [&](const char* k) {
      return col[std::string("pose_grasp_") + k][f].get<double>();
    };
    const Mat3 drawn_R = quat_matrix(v("qw"), v("qx"), v("qy"), v("qz"));
    const auto& row = tab.rows[f];
    double q[10];
    for (std::size_t i = 0; i < 10; ++i) q[i] = row[qcol(names[i])];
    const Mat3 Rload = quat_matrix(q[6], q[7], q[8], q[9]);
    const Mat3 frame_b = Rload * Rb, frame_a = wrist(q[0], q[1], q[2]) * Ra;
    worst_b = std::max(worst_b, (drawn_R - frame_b).norm());
    worst_a = std::max(worst_a, (drawn_R - frame_a).norm());
    least_transposed = std::min(least_transposed, (drawn_R.transpose() - frame_b).norm());
    turned = std::max(turned, Eigen::AngleAxisd(Rload.transpose() * Rl).angle());
    const Vec3 pb = Vec3(q[3], q[4], q[5]) + Rload * xb;
    EXPECT_LT((Vec3(v("x"), v("y"), v("z")) - pb).norm(), 1e-5) << f;
  }
  std::cout << fmt::format(
      "grasp axes: {} frames, the load turned up to {:.3f} rad; drawn vs frame b {:.2e}, vs "
      "frame a (wrist closed form) {:.2e}; a transposed rotation would be >= {:.3f} off\n",
      tab.rows.size(), turned, worst_b, worst_a, least_transposed);
  EXPECT_GT(turned, 0.2);    // the load does turn: the comparison is not of constant rotations
  EXPECT_LT(worst_b, 2e-5);  // 6 significant digits in the page
  EXPECT_LT(worst_a, 2e-5);
  EXPECT_GT(least_transposed, 0.1);
}

}  // namespace
