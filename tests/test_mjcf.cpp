// MJCF read with MuJoCo's own parser (ukdyn/robot_files/mjcf.hpp) into a chain, derived by ukdyn:
// its M and C q̇ + G against MuJoCo's own mj_fullM and qfrc_bias (both exact there: MuJoCo's
// recursive Newton–Euler and composite-rigid-body algorithms) at 100 random states.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include "ukdyn/robot_files/mjcf.hpp"
#include "ukdyn/symbolic/chain.hpp"
#include "ukdyn/symbolic/definitions.hpp"

#ifdef UKDYN_TEST_HAVE_MUJOCO
#include <mujoco/mujoco.h>

#include "robot_files/mjcf_files.hpp"
#endif

namespace {

namespace sym = ukdyn::symbolic;
using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;

const std::string kFile = std::string(UKDYN_SOURCE_DIR) + "/tests/mjcf/open_chain.xml";

TEST(Mjcf, WithoutMuJoCoTheErrorSaysSo) {
  if (sym::mjcf_supported()) GTEST_SKIP() << "built with MuJoCo";
  sym::ChainDef c("m", {"a"});
  try {
    sym::append_mjcf(c, kFile);
    FAIL() << "no error";
  } catch (const sym::DefinitionError& e) {
    EXPECT_NE(std::string(e.what()).find("without MuJoCo"), std::string::npos) << e.what();
  }
}

#ifdef UKDYN_TEST_HAVE_MUJOCO
TEST(Mjcf, MassMatrixAndBiasForcesMatchMuJoCo) {
  ASSERT_TRUE(sym::mjcf_supported());
  const std::vector<std::string> q = {"x", "h1", "h2", "s2", "h3", "sw"};
  sym::ChainDef c("open_chain", q);
  sym::append_mjcf(c, kFile, /*gravity=*/true);
  const auto sub = sym::make_subsystem(sym::build_chain(c).def);
  ASSERT_EQ(sub->dof(), 6);

  char err[1000] = "";
  mjModel* m = mj_loadXML(kFile.c_str(), nullptr, err, sizeof err);
  ASSERT_NE(m, nullptr) << err;
  mjData* d = mj_makeData(m);
  ASSERT_EQ(m->nv, 6);
  std::mt19937 rng(11u);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  double worst_M = 0.0, worst_b = 0.0;
  Mat M(6, 6), Mmj(6, 6);
  Vec Cqd(6), G(6);
  for (int k = 0; k < 100; ++k) {
    Vec qv(6), qd(6);
    for (Index i = 0; i < 6; ++i) {
      qv[i] = 2.0 * u(rng);
      qd[i] = 2.0 * u(rng);
    }
    for (int i = 0; i < 6; ++i) {
      d->qpos[i] = qv[i];
      d->qvel[i] = qd[i];
    }
    mj_forward(m, d);
    std::vector<mjtNum> full(36);
    mj_fullM(m, full.data(), d->qM);
    for (int i = 0; i < 6; ++i)
      for (int j = 0; j < 6; ++j) Mmj(i, j) = full[static_cast<std::size_t>(6 * i + j)];
    sub->mass({}, qv, M);
    sub->coriolis_times_qd({}, qv, qd, Cqd);
    sub->gravity({}, qv, G);
    Vec bias(6);
    for (int i = 0; i < 6; ++i) bias[i] = d->qfrc_bias[i];
    worst_M = std::max(worst_M, (M - Mmj).norm() / Mmj.norm());
    worst_b = std::max(worst_b, (Cqd + G - bias).norm() / std::max(bias.norm(), 1e-300));
  }
  mj_deleteData(d);
  mj_deleteModel(m);
  EXPECT_LE(worst_M, 1e-10);
  EXPECT_LE(worst_b, 1e-10);
  RecordProperty("worst_M_rel", ::testing::PrintToString(worst_M));
  RecordProperty("worst_bias_rel", ::testing::PrintToString(worst_b));
}

// Free and ball joints: ukdyn's coordinates are MuJoCo's qpos (quaternions w, x, y, z), MuJoCo's
// velocities qvel (free: world linear velocity, body angular velocity; ball: body angular
// velocity). With q̇ = H(q) v (H: identity on positions and hinges, ½ q ⊗ (0, ω) on a quaternion),
// MuJoCo's M_v = Hᵀ M H and bias_v = Hᵀ (M Ḣ v + C q̇ + G) (Ḣ v = ½ q̇ ⊗ (0, ω)). Hᵀ removes
// the radial (off |q| = 1) parts of ukdyn's quaternion-coordinate M and C, which the unit-norm
// rows absorb.
TEST(Mjcf, FreeAndBallJointsMatchMuJoCo) {
  ASSERT_TRUE(sym::mjcf_supported());
  const std::string file = std::string(UKDYN_SOURCE_DIR) + "/tests/mjcf/ball_free.xml";
  const std::vector<std::string> names = {"x",  "y",  "z",  "qw", "qx", "qy", "qz", "sw",
                                          "sx", "sy", "sz", "pw", "px", "py", "pz", "el"};
  sym::ChainDef c("ball_free", names);
  sym::append_mjcf(c, file, /*gravity=*/true);
  const auto model = sym::build_chain(c);
  ASSERT_EQ(model.quaternions.size(), 3U);
  const auto sub = sym::make_subsystem(model.def);
  char err[1000] = "";
  mjModel* m = mj_loadXML(file.c_str(), nullptr, err, sizeof err);
  ASSERT_NE(m, nullptr) << err;
  mjData* d = mj_makeData(m);
  const int nq = m->nq, nv = m->nv;
  ASSERT_EQ(nq, 16);
  ASSERT_EQ(nv, 13);
  // Quaternion blocks: (qpos address, qvel address).
  std::vector<std::pair<int, int>> quats;
  for (int j = 0; j < m->njnt; ++j) {
    if (m->jnt_type[j] == mjJNT_FREE)
      quats.emplace_back(m->jnt_qposadr[j] + 3, m->jnt_dofadr[j] + 3);
    if (m->jnt_type[j] == mjJNT_BALL) quats.emplace_back(m->jnt_qposadr[j], m->jnt_dofadr[j]);
  }
  auto qmat = [](const Vec& q4) {  // ½ q ⊗ (0, ω) = Q ω
    Mat Q(4, 3);
    Q << -q4(1), -q4(2), -q4(3), q4(0), -q4(3), q4(2), q4(3), q4(0), -q4(1), -q4(2), q4(1), q4(0);
    return Mat(0.5 * Q);
  };
  std::mt19937 rng(13u);
  std::normal_distribution<double> nd;
  double worst_M = 0.0, worst_b = 0.0;
  Mat M(nq, nq), Mmj(nv, nv);
  Vec Cqd(nq), G(nq);
  for (int k = 0; k < 100; ++k) {
    Vec qv(nq), v(nv);
    for (int i = 0; i < nq; ++i) qv[i] = nd(rng);
    for (int i = 0; i < nv; ++i) v[i] = nd(rng);
    for (const auto& [qa, va] : quats) qv.segment(qa, 4).normalize();
    // H and Ḣ v: hinges and the free joint's position map one to one (qpos and qvel in order).
    Mat H = Mat::Zero(nq, nv);
    Vec Hdv = Vec::Zero(nq);
    {
      int qi = 0, vi = 0;
      for (int j = 0; j < m->njnt; ++j) {
        const int t = m->jnt_type[j];
        if (t == mjJNT_FREE) {
          H.block(qi, vi, 3, 3).setIdentity();
          qi += 3;
          vi += 3;
        }
        if (t == mjJNT_FREE || t == mjJNT_BALL) {
          H.block(qi, vi, 4, 3) = qmat(qv.segment(qi, 4));
          qi += 4;
          vi += 3;
        } else if (t == mjJNT_HINGE || t == mjJNT_SLIDE) {
          H(qi++, vi++) = 1.0;
        }
      }
    }
    const Vec qd = H * v;
    for (const auto& [qa, va] : quats)
      Hdv.segment(qa, 4) = qmat(qd.segment(qa, 4)) * v.segment(va, 3);
    for (int i = 0; i < nq; ++i) d->qpos[i] = qv[i];
    for (int i = 0; i < nv; ++i) d->qvel[i] = v[i];
    mj_forward(m, d);
    std::vector<mjtNum> full(static_cast<std::size_t>(nv * nv));
    mj_fullM(m, full.data(), d->qM);
    for (int i = 0; i < nv; ++i)
      for (int j = 0; j < nv; ++j) Mmj(i, j) = full[static_cast<std::size_t>(nv * i + j)];
    sub->mass({}, qv, M);
    sub->coriolis_times_qd({}, qv, qd, Cqd);
    sub->gravity({}, qv, G);
    Vec bias(nv);
    for (int i = 0; i < nv; ++i) bias[i] = d->qfrc_bias[i];
    const Mat Mv = H.transpose() * M * H;
    const Vec bv = H.transpose() * (M * Hdv + Cqd + G);
    worst_M = std::max(worst_M, (Mv - Mmj).norm() / Mmj.norm());
    worst_b = std::max(worst_b, (bv - bias).norm() / std::max(bias.norm(), 1e-300));
  }
  mj_deleteData(d);
  mj_deleteModel(m);
  EXPECT_LE(worst_M, 1e-10);
  EXPECT_LE(worst_b, 1e-10);
  std::printf("MJCF free + ball + hinge vs MuJoCo (100 states): M %.3g, bias %.3g (relative)\n",
              worst_M, worst_b);
}

// MuJoCo compiles the bytes ukdyn's checked reader read (through its virtual file system), not
// the files opened again by name: the model split into a file and an <include> gives the same
// chain as the one file; an include changed on disk after ukdyn read it is compiled as read; an
// include naming a missing file or a FIFO (also as <Include>, with a '>' in another attribute or
// with its name as character references: MuJoCo reads all of these) is refused naming the file.
TEST(Mjcf, IncludesAreCompiledFromTheBytesUkdynRead) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / ("ukdyn_mjcf_vfs_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const auto write = [&](const std::string& name, const std::string& text) {
    std::ofstream(dir / name) << text;
    return (dir / name).string();
  };
  const std::string body =
      "<body name=\"b\" pos=\"0 0 1\"><joint name=\"h\" type=\"hinge\" axis=\"0 1 0\"/>"
      "<inertial pos=\"0 0 -0.5\" mass=\"MASS\" diaginertia=\"0.1 0.1 0.1\"/></body>";
  const auto with_mass = [&](const char* m) {
    std::string t = body;
    t.replace(t.find("MASS"), 4, m);
    return t;
  };
  const std::string whole =
      write("whole.xml", "<mujoco><worldbody>" + with_mass("2") + "</worldbody></mujoco>");
  write("part.xml", "<mujoco>" + with_mass("2") + "</mujoco>");
  const std::string split =
      write("split.xml", "<mujoco><worldbody><include file=\"part.xml\"/></worldbody></mujoco>");
  const auto chain_text = [](const std::string& file) {
    sym::ChainDef c("m", {"a"});
    sym::append_mjcf(c, file);
    std::ostringstream t;
    for (const auto& j : c.joints) {
      t << j.name << ":" << j.inertial.mass << ";";
      for (const auto& e : j.origin.xyz) t << e << ",";
      for (const auto& e : j.inertial.com) t << e << ",";
    }
    return t.str();
  };
  EXPECT_EQ(chain_text(split), chain_text(whole));
  EXPECT_NE(chain_text(split).find(":2;"), std::string::npos) << chain_text(split);

  // Read, then the include is swapped on disk: MuJoCo compiles what was read (mass 2, not 7).
  const auto files = sym::mjcf_detail::read_mjcf_files(split);
  ASSERT_EQ(files.size(), 2u);
  write("part.xml", "<mujoco>" + with_mass("7") + "</mujoco>");
  const auto m = sym::mjcf_detail::compile_mjcf(split, files);
  ASSERT_EQ(m->nbody, 2);
  EXPECT_DOUBLE_EQ(m->body_mass[1], 2.0);
  char err[1000] = "";
  mjModel* by_name = mj_loadXML(split.c_str(), nullptr, err, sizeof err);  // the file now
  ASSERT_NE(by_name, nullptr) << err;
  EXPECT_DOUBLE_EQ(by_name->body_mass[1], 7.0);
  mj_deleteModel(by_name);

  ASSERT_EQ(::mkfifo((dir / "pipe.xml").c_str(), 0600), 0);
  fs::create_directories(dir / "sub");
  write("sub/SPLIT.xml", "<mujoco/>");  // MuJoCo's name for it: split.xml, as dir/split.xml
  const struct {
    const char* include;
    const char* expect;
  } cases[] = {
      {"<include file=\"gone.xml\"/>", "gone.xml (included from top.xml): no such MJCF file"},
      {"<include file=\"pipe.xml\"/>", "pipe.xml (included from top.xml): is a FIFO"},
      {"<Include file=\"pipe.xml\"/>", "pipe.xml (included from top.xml): is a FIFO"},
      {"<include note=\"a>b\" file='pipe.xml'/>", "pipe.xml (included from top.xml): is a FIFO"},
      {"<include file=\"&#112;ipe&#x2e;xml\"/>", "pipe.xml (included from top.xml): is a FIFO"},
      {"<include file=\"split.xml\"/><include file=\"sub/SPLIT.xml\"/>",
       "SPLIT.xml (included from top.xml): MuJoCo's virtual file system knows a file by its name"},
  };
  for (const auto& c : cases) {
    const std::string top =
        write("top.xml", std::string("<mujoco><worldbody>") + c.include + "</worldbody></mujoco>");
    sym::ChainDef chain("m", {"a"});
    try {
      sym::append_mjcf(chain, top);
      ADD_FAILURE() << c.include << ": no error";
    } catch (const sym::DefinitionError& e) {
      EXPECT_NE(std::string(e.what()).find(c.expect), std::string::npos) << e.what();
    }
  }
  fs::remove_all(dir);
}

// Mesh and other asset files go through the checked reader into MuJoCo's virtual file system as
// well: a mesh (found through the compiler's meshdir, with or without strippath) changed on disk
// after ukdyn read it is compiled as read (4 faces, where MuJoCo opening the file by name finds the
// 12 of the new one); a mesh, skin, height field or texture (a cube's face too) naming a missing file,
// a FIFO, a folder or an empty file, or two assets that MuJoCo's file system could not tell
// apart, is refused naming the file, the element and the model file.
TEST(Mjcf, MeshFilesAreCompiledFromTheBytesUkdynRead) {
  namespace fs = std::filesystem;
  const fs::path dir =
      fs::temp_directory_path() / ("ukdyn_mjcf_mesh_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir / "meshes");
  fs::create_directories(dir / "other");
  const auto write = [&](const std::string& name, const std::string& text) {
    std::ofstream(dir / name) << text;
    return (dir / name).string();
  };
  const std::string tet =
      "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n";
  std::string cube;
  for (int k = 0; k < 8; ++k)
    cube += "v " + std::to_string(k & 1) + " " + std::to_string((k >> 1) & 1) + " " +
            std::to_string((k >> 2) & 1) + "\n";
  cube +=
      "f 1 2 4\nf 1 4 3\nf 5 6 8\nf 5 8 7\nf 1 2 6\nf 1 6 5\nf 3 4 8\nf 3 8 7\nf 1 3 7\n"
      "f 1 7 5\nf 2 4 8\nf 2 8 6\n";
  write("meshes/tet.obj", tet);
  const auto model = [](const std::string& compiler, const std::string& assets) {
    return "<mujoco><compiler " + compiler + "/><asset>" + assets +
           "</asset><worldbody><body name=\"b\"><joint name=\"h\" type=\"hinge\" axis=\"0 1 0\"/>"
           "<geom type=\"box\" size=\"0.1 0.1 0.1\"/>"
           "<inertial pos=\"0 0 -0.5\" mass=\"1\" diaginertia=\"0.1 0.1 0.1\"/></body>"
           "</worldbody></mujoco>";
  };
  // OBJ faces are compiled as separate triangles: 4 faces for the tetrahedron, 12 for the cube.
  const struct {
    const char* compiler;
    const char* mesh;
  } found[] = {{"meshdir=\"meshes\"", "<mesh name=\"m\" file=\"tet.obj\"/>"},
               {"meshdir=\"meshes/\" strippath=\"true\"", "<mesh name=\"m\" file=\"x/tet.obj\"/>"}};
  for (const auto& c : found) {
    const std::string top = write("top.xml", model(c.compiler, c.mesh));
    write("meshes/tet.obj", tet);
    const auto files = sym::mjcf_detail::read_mjcf_files(top);
    ASSERT_EQ(files.size(), 2u) << c.compiler;
    write("meshes/tet.obj", cube);  // swapped on disk after ukdyn read it
    const auto m = sym::mjcf_detail::compile_mjcf(top, files);
    EXPECT_EQ(m->nmesh, 1) << c.compiler;
    EXPECT_EQ(m->nmeshface, 4) << c.compiler;
    char err[1000] = "";
    mjModel* by_name = mj_loadXML(top.c_str(), nullptr, err, sizeof err);  // the file now
    ASSERT_NE(by_name, nullptr) << err;
    EXPECT_EQ(by_name->nmeshface, 12) << c.compiler;
    mj_deleteModel(by_name);
  }
  write("meshes/tet.obj", tet);
  write("meshes/empty.obj", "");
  write("other/tet.obj", cube);
  ASSERT_EQ(::mkfifo((dir / "meshes" / "pipe.obj").c_str(), 0600), 0);
  const struct {
    const char* compiler;
    const char* assets;
    const char* expect;
  } cases[] = {
      {"meshdir=\"meshes\"", "<mesh name=\"m\" file=\"gone.obj\"/>",
       "gone.obj (<mesh file=\"gone.obj\"> in top.xml): no such mesh file"},
      {"meshdir=\"meshes\"", "<mesh name=\"m\" file=\"pipe.obj\"/>",
       "pipe.obj (<mesh file=\"pipe.obj\"> in top.xml): is a FIFO"},
      {"meshdir=\"meshes/\"", "<Mesh name=\"m\" file=\"&#112;ipe.obj\"/>",
       "pipe.obj (<mesh file=\"pipe.obj\"> in top.xml): is a FIFO"},
      {"", "<mesh name=\"m\" file=\"meshes\"/>",
       "meshes (<mesh file=\"meshes\"> in top.xml): is a folder"},
      {"meshdir=\"meshes\"", "<mesh name=\"m\" file=\"empty.obj\"/>",
       "empty.obj (<mesh file=\"empty.obj\"> in top.xml): is empty, not a mesh file"},
      {"", "<mesh name=\"m\" file=\"meshes/tet.obj\"/><mesh name=\"n\" file=\"other/tet.obj\"/>",
       "other/tet.obj (<mesh file=\"other/tet.obj\"> in top.xml): MuJoCo's virtual file system"},
      {"meshdir=\"meshes\" strippath=\"true\"", "<mesh name=\"m\" file=\"/nowhere/pipe.obj\"/>",
       "pipe.obj (<mesh file=\"/nowhere/pipe.obj\"> in top.xml): is a FIFO"},
      {"meshdir=\"meshes\"", "<skin file=\"gone.skn\"/>",
       "gone.skn (<skin file=\"gone.skn\"> in top.xml): no such skin file"},
      {"meshdir=\"meshes\"", "<hfield name=\"h\" file=\"pipe.obj\"/>",
       "pipe.obj (<hfield file=\"pipe.obj\"> in top.xml): is a FIFO"},
      {"texturedir=\"meshes\"", "<texture type=\"cube\" fileright=\"pipe.obj\"/>",
       "pipe.obj (<texture fileright=\"pipe.obj\"> in top.xml): is a FIFO"},
  };
  for (const auto& c : cases) {
    const std::string top = write("top.xml", model(c.compiler, c.assets));
    sym::ChainDef chain("m", {"a"});
    try {
      sym::append_mjcf(chain, top);
      ADD_FAILURE() << c.assets << ": no error";
    } catch (const sym::DefinitionError& e) {
      EXPECT_NE(std::string(e.what()).find(c.expect), std::string::npos) << e.what();
    }
  }
  fs::remove_all(dir);
}

TEST(Mjcf, UnsupportedJointsAndCountsAreNamed) {
  sym::ChainDef c("m", {"a", "b"});
  try {
    sym::append_mjcf(c, kFile);
    FAIL() << "no error";
  } catch (const sym::DefinitionError& e) {
    EXPECT_NE(std::string(e.what()).find("6 qpos coordinates"), std::string::npos) << e.what();
  }
  sym::ChainDef c2("m", {"a"});
  try {
    sym::append_mjcf(c2, kFile + ".missing");
    FAIL() << "no error";
  } catch (const sym::DefinitionError& e) {
    EXPECT_NE(std::string(e.what()).find("open_chain.xml.missing: no such MJCF file"),
              std::string::npos)
        << e.what();
  }
}
#endif

}  // namespace
