// The replay page's geometry and data (docs/replay.md), and the decimated reading of a CSV used by
// the figures of long runs. The page in a real browser: web/test/replay.test.mjs (Browser.Replay).
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>
#include <regex>

#include "cli_run.hpp"
#include "ukdyn/output/geometry.hpp"
#include "ukdyn/output/plots.hpp"
#include "ukdyn/output/replay.hpp"
#include "ukdyn/output/trajectory_table.hpp"
#include "ukdyn/paper_robot/mobile_manipulator.hpp"
#include "ukdyn/run/run.hpp"
#include "ukdyn/scenario/scenario.hpp"

namespace {

using namespace ukdyn;
namespace fs = std::filesystem;
const fs::path kSource = UKDYN_SOURCE_DIR;

Vec random_q(std::mt19937& rng, Index n) {
  std::uniform_real_distribution<double> u(-2.0, 2.0);
  Vec q(n);
  for (Index i = 0; i < n; ++i) q(i) = u(rng);
  return q;
}

Vec3 point(const Geometry& g, CVecRef q, const std::string& name) {
  std::vector<Vec3> xyz;
  g.evaluate(q, xyz);
  const long i = g.find(name);
  EXPECT_GE(i, 0) << name;
  return i >= 0 ? xyz[static_cast<std::size_t>(i)] : Vec3::Constant(std::nan(""));
}

// Two formulations: the page's joint-by-joint sum against MobileManipulator::cut_point (the
// constraints' kinematics, paper Eq. (12)); the platform is where Δx, Δy put it.
TEST(ReplayGeometry, PaperArmCutPointIsTheModelsCutPoint) {
  const Scenario sc = load_scenario(kSource / "scenarios/paper.yaml");
  const Geometry g = build_geometry(sc);
  ASSERT_EQ(g.points().size(), 10u);
  std::mt19937 rng(7);
  for (int k = 0; k < 20; ++k) {
    const Vec q = random_q(rng, sc.system->dof());
    for (std::size_t s = 0; s < 2; ++s) {
      const auto& arm = dynamic_cast<const MobileManipulator&>(*sc.system->subsystems()[s]);
      const Index off = sc.subsystems[s].offset;
      const Vec3 ref = arm.cut_point(q.segment(off, 6));
      EXPECT_LT((point(g, q, sc.subsystems[s].name + ".cut") - ref).norm(), 1e-14);
      const Vec3 plat = point(g, q, sc.subsystems[s].name + ".platform");
      EXPECT_EQ(plat, Vec3(q(off), q(off + 1), 0.0));
    }
  }
}

// The serial-chain build of the same robots (symbolic link transforms, scenarios/paper_chain.yaml)
// puts its cut points and joint frames where the paper's closed form does.
TEST(ReplayGeometry, ChainPointsAgreeWithThePapersClosedForm) {
  const Scenario paper = load_scenario(kSource / "scenarios/paper.yaml");
  const Scenario chain = load_scenario(kSource / "scenarios/paper_chain.yaml");
  ASSERT_EQ(paper.system->coordinate_names(), chain.system->coordinate_names());
  const Geometry gp = build_geometry(paper);
  std::vector<std::string> left_out;
  const Geometry gc = build_geometry(chain, &left_out);
  EXPECT_TRUE(left_out.empty());
  EXPECT_FALSE(gc.segments().empty());
  std::mt19937 rng(11);
  for (int k = 0; k < 20; ++k) {
    const Vec q = random_q(rng, paper.system->dof());
    for (const char* arm : {"left", "right"}) {
      const std::string a = arm;
      EXPECT_LT((point(gc, q, a + ".cut") - point(gp, q, a + ".cut")).norm(), 1e-12) << a;
      EXPECT_LT((point(gc, q, a + ".platform") - point(gp, q, a + ".platform")).norm(), 1e-12);
      // link 2's frame origin is the paper's joint 2 (end of link 1)
      const std::string l2 = a == "left" ? ".link2" : ".link5";
      EXPECT_LT((point(gc, q, a + l2) - point(gp, q, a + ".j2")).norm(), 1e-12) << a;
    }
  }
}

// A free body is drawn as the box of its mass and inertia: the drawn box's own inertia, the uniform
// box's m (b² + c²) / 12, ... about its axes turned by the drawn orientation, equals the body's
// inertia tensor (a full matrix: principal axes off the body axes) turned by R(q) of the
// normalised quaternion, computed here; the box sits at the body's (x, y, z).
TEST(ReplayGeometry, FreeBodyIsItsInertiaEquivalentBox) {
  const std::string text = R"(ukdyn: 1
name: free_box
subsystems:
  - name: box
    type: free_body
    parameters: {m: 2.5}
    mass: m
    inertia: [[0.30, 0.04, -0.02], [0.04, 0.25, 0.03], [-0.02, 0.03, 0.12]]
initial: {q: [0, 0, 0, 1, 0, 0, 0], qd: zeros}
simulation: {t_end: 1, sample_dt: 0.1}
)";
  const Scenario sc = load_scenario_text(text, "free_box.yaml");
  std::vector<std::string> left_out;
  const Geometry g = build_geometry(sc, &left_out);
  EXPECT_TRUE(left_out.empty());
  ASSERT_EQ(g.solids().size(), 1u);
  const GeometrySolid& s = g.solids()[0];
  EXPECT_EQ(s.name, "box");
  EXPECT_EQ(g.points()[s.point].name, "box.box");
  const double m = 2.5;
  Eigen::Matrix3d J;
  J << 0.30, 0.04, -0.02, 0.04, 0.25, 0.03, -0.02, 0.03, 0.12;
  const Vec3 e2 = s.size.cwiseProduct(s.size);
  const Eigen::Matrix3d Jbox =
      Vec3(e2(1) + e2(2), e2(0) + e2(2), e2(0) + e2(1)).asDiagonal() * (m / 12.0);
  std::mt19937 rng(5);
  std::vector<std::array<double, 4>> rot;
  std::vector<Vec3> xyz;
  for (int k = 0; k < 10; ++k) {
    const Vec q = random_q(rng, 7);  // a quaternion off the unit sphere: normalised when drawn
    g.evaluate(q, xyz);
    g.evaluate_orientations(q, rot);
    EXPECT_EQ(xyz[s.point], Vec3(q(0), q(1), q(2)));
    const double n = q.segment(3, 4).norm();
    const double w = q(3) / n, x = q(4) / n, y = q(5) / n, z = q(6) / n;
    Eigen::Matrix3d R;  // the rotation of the unit quaternion (w, x, y, z)
    R << 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),  //
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),   //
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y);
    const Eigen::Matrix3d B =
        Eigen::Quaterniond(rot[0][0], rot[0][1], rot[0][2], rot[0][3]).toRotationMatrix();
    EXPECT_LT((B * Jbox * B.transpose() - R * J * R.transpose()).norm(), 1e-12) << k;
  }
}

// Every column's minimum and maximum survive the decimation; at most 2·buckets rows; times in
// order.
TEST(TrajectoryTable, MinMaxDecimationKeepsEveryExtreme) {
  ukdyn_test::ScratchDir dir("ukdyn_minmax");
  const fs::path csv = dir.path / "t.csv";
  const int n = 100000;
  {
    std::ofstream o(csv);
    o << "t,a,b\n";
    for (int i = 0; i < n; ++i) {
      const double t = 0.01 * i;
      // a: a slow sine with one-sample spikes; b: a ramp
      const double a = std::sin(t) + (i == 31337 ? 5.0 : 0.0) - (i == 77777 ? 7.0 : 0.0);
      o << fmt::format("{:.17g},{:.17g},{:.17g}\n", t, a, 2.0 * i);
    }
  }
  EXPECT_EQ(count_csv_rows(csv), static_cast<std::size_t>(n));
  const TrajectoryTable full = read_trajectory(csv);
  const TrajectoryTable dec = read_trajectory_minmax(csv, 1000);
  EXPECT_EQ(dec.source_rows, static_cast<std::size_t>(n));
  EXPECT_LE(dec.rows.size(), 2000u);
  EXPECT_GE(dec.rows.size(), 1000u);
  for (std::size_t c = 1; c < 3; ++c) {
    double lo = 1e300, hi = -1e300, dlo = 1e300, dhi = -1e300;
    for (const auto& r : full.rows) lo = std::min(lo, r[c]), hi = std::max(hi, r[c]);
    for (const auto& r : dec.rows) dlo = std::min(dlo, r[c]), dhi = std::max(dhi, r[c]);
    EXPECT_EQ(lo, dlo) << c;
    EXPECT_EQ(hi, dhi) << c;
  }
  for (std::size_t i = 1; i < dec.rows.size(); ++i) EXPECT_LE(dec.rows[i - 1][0], dec.rows[i][0]);
  EXPECT_EQ(dec.rows.front()[0], 0.0);
  EXPECT_EQ(dec.rows.back()[0], full.rows.back()[0]);
  // small files come back whole
  EXPECT_EQ(read_trajectory_minmax(csv, 100000).rows.size(), static_cast<std::size_t>(n));
}

// The page of a 10 s run at 100 Hz: under 5 MB, self-contained (no script or link from elsewhere),
// and its point positions are the geometry at the CSV's q (6 significant digits).
TEST(Replay, PageOfATenSecondRunIsSmallSelfContainedAndHoldsTheGeometry) {
  if (!replay_available()) GTEST_SKIP() << "built without three.js (web/node_modules missing)";
  std::ifstream in(kSource / "scenarios/paper.yaml");
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  text = std::regex_replace(text, std::regex("t_end: 4"), "t_end: 10");
  const Scenario sc = load_scenario_text(text, kSource / "scenarios/paper.yaml");
  ukdyn_test::ScratchDir dir("ukdyn_replay");
  RunOptions ro;
  ro.figures = false;
  ASSERT_TRUE(run_scenario(sc, dir.path, ro).complete());
  const ReplayResult r = write_replay(sc, dir.path);
  EXPECT_EQ(r.frames, 1001u);
  EXPECT_LT(r.bytes, 5'000'000u);
  const std::string page = ukdyn_test::slurp(dir.path / kReplayFile);
  EXPECT_EQ(page.size(), r.bytes);
  EXPECT_EQ(page.find("<script src"), std::string::npos);
  EXPECT_EQ(page.find("<link"), std::string::npos);
  EXPECT_NE(page.find("default-src 'none'"), std::string::npos);  // CSP: nothing from elsewhere
  const std::string open = "<script type=\"application/json\" id=\"ukdyn-data\">";
  const auto a = page.find(open) + open.size();
  const auto b = page.find("</script>", a);
  const auto data = nlohmann::json::parse(page.substr(a, b - a));
  const TrajectoryTable tab = read_trajectory(dir.path / "trajectory.csv");
  ASSERT_EQ(data["t"].size(), tab.rows.size());
  const Geometry g = build_geometry(sc);
  std::vector<Vec3> xyz;
  const Index n = sc.system->dof();
  for (std::size_t f = 0; f < tab.rows.size(); f += 97) {
    Vec q(n);
    for (Index i = 0; i < n; ++i) q(i) = tab.rows[f][static_cast<std::size_t>(i) + 1];
    g.evaluate(q, xyz);
    const auto& pos = data["pos"][f];
    ASSERT_EQ(pos.size(), 3 * xyz.size());
    for (std::size_t i = 0; i < xyz.size(); ++i) {
      for (int k = 0; k < 3; ++k) {
        EXPECT_NEAR(pos[3 * i + static_cast<std::size_t>(k)].get<double>(), xyz[i](k),
                    1e-5 * (1.0 + std::abs(xyz[i](k))));
      }
    }
  }
  EXPECT_EQ(data["columns"]["E"].size(), tab.rows.size());
}

// A run of more than kDecimateAbove samples is drawn from a min/max copy that keeps every extreme;
// a shorter one from the CSV itself.
TEST(Figures, LongRunsAreDrawnFromADecimatedCopyKeepingTheExtremes) {
  std::ifstream in(kSource / "scenarios/benchmarks/simple_pendulum.yaml");
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  for (const bool longer : {false, true}) {
    const Scenario sc = load_scenario_text(
        std::regex_replace(text, std::regex("t_end: 10"), longer ? "t_end: 60" : "t_end: 5"),
        kSource / "scenarios/benchmarks/simple_pendulum.yaml");
    ukdyn_test::ScratchDir dir(longer ? "ukdyn_fig_long" : "ukdyn_fig_short");
    const RunReport rep = run_scenario(sc, dir.path, RunOptions{});
    ASSERT_TRUE(rep.complete());
    ASSERT_TRUE(rep.figure_error.empty()) << rep.figure_error;
    EXPECT_EQ(rep.figures.size(), 4u);
    const std::string gp = ukdyn_test::slurp(dir.path / "figures/figures.gp");
    const fs::path copy = dir.path / "figures/figures_data.csv";
    if (!longer) {
      EXPECT_FALSE(fs::exists(copy));
      EXPECT_NE(gp.find("\"../trajectory.csv\""), std::string::npos);
      continue;
    }
    ASSERT_TRUE(fs::exists(copy));
    EXPECT_EQ(gp.find("trajectory.csv"), std::string::npos);
    EXPECT_NE(gp.find("\"figures_data.csv\""), std::string::npos);
    const TrajectoryTable full = read_trajectory(dir.path / "trajectory.csv");
    const TrajectoryTable dec = read_trajectory(copy);
    EXPECT_EQ(full.rows.size(), 6001u);
    EXPECT_LE(dec.rows.size(), 2 * kFigureBuckets);
    for (const char* c : {"x", "y", "E", "res_rod_length"}) {
      const auto ci = static_cast<std::size_t>(
          std::find(full.header.begin(), full.header.end(), c) - full.header.begin());
      const auto di = static_cast<std::size_t>(std::find(dec.header.begin(), dec.header.end(), c) -
                                               dec.header.begin());
      ASSERT_LT(ci, full.header.size()) << c;
      ASSERT_LT(di, dec.header.size()) << c;
      double lo = 1e300, hi = -1e300, dlo = 1e300, dhi = -1e300;
      for (const auto& r : full.rows) lo = std::min(lo, r[ci]), hi = std::max(hi, r[ci]);
      for (const auto& r : dec.rows) dlo = std::min(dlo, r[di]), dhi = std::max(dhi, r[di]);
      EXPECT_EQ(lo, dlo) << c;  // exact: the copy holds the CSV's own values ({:.17g})
      EXPECT_EQ(hi, dhi) << c;
    }
    ASSERT_FALSE(rep.figure_notes.empty());
    EXPECT_NE(rep.figure_notes.back().find("figures_data.csv"), std::string::npos);
    // the next run removes the copy with the other figures (it is in .ukdyn-figures)
    RunOptions nofig;
    nofig.figures = false;
    ASSERT_TRUE(run_scenario(sc, dir.path, nofig).complete());
    EXPECT_FALSE(fs::exists(copy));
  }
}

// A serial chain's mobile base coordinates (metres) are drawn with the platforms, not among the
// joint angles (rad).
TEST(Figures, ChainBaseCoordinatesAreNotJointAngles) {
  const Scenario sc = load_scenario(kSource / "scenarios/paper_chain.yaml");
  ukdyn_test::ScratchDir dir("ukdyn_fig_chain");
  const RunReport rep = run_scenario(sc, dir.path, RunOptions{});
  ASSERT_TRUE(rep.complete());
  const std::string gp = ukdyn_test::slurp(dir.path / "figures/figures.gp");
  const auto figure = [&](const std::string& file) {
    const auto a = gp.find("set output \"" + file + "\"");
    EXPECT_NE(a, std::string::npos) << file;
    return gp.substr(a, gp.find("unset output", a) - a);
  };
  const std::string angles = figure("angles_left.png");
  EXPECT_NE(angles.find("set ylabel \"[rad]\""), std::string::npos) << angles;
  EXPECT_EQ(angles.find("title \"dx1\""), std::string::npos) << angles;
  EXPECT_NE(angles.find("title \"theta1\""), std::string::npos) << angles;
  const std::string plat = figure("platforms.png");
  for (const char* c : {"dx1", "dy1", "dx2", "dy2"}) {
    EXPECT_NE(plat.find(std::string("title \"") + c + "\""), std::string::npos) << c;
  }
  EXPECT_NE(plat.find("set ylabel \"[m]\""), std::string::npos);
}

#ifdef UKDYN_CLI
TEST(Replay, CliNamesWhatIsMissing) {
  ukdyn_test::ScratchDir dir("ukdyn_replay_cli");
  const auto rr = ukdyn_test::run_cli(UKDYN_CLI, dir.path,
                                      "replay " + ukdyn_test::sh((dir.path / "none").string()));
  EXPECT_EQ(rr.exit_code, 2);
  EXPECT_NE(rr.err.find("none/summary.json: no such file: not the output folder of a run"),
            std::string::npos)
      << rr.err;
  // A summary.json that is not JSON, and one without the scenario: each said as what it is.
  fs::create_directories(dir.path / "bad");
  std::ofstream(dir.path / "bad" / "summary.json") << "{ not json";
  const std::string bad = ukdyn_test::sh((dir.path / "bad").string());
  const auto rb = ukdyn_test::run_cli(UKDYN_CLI, dir.path, "replay " + bad);
  EXPECT_EQ(rb.exit_code, 2);
  EXPECT_NE(rb.err.find("bad/summary.json: not JSON"), std::string::npos) << rb.err;
  std::ofstream(dir.path / "bad" / "summary.json") << "{}";
  const auto re = ukdyn_test::run_cli(UKDYN_CLI, dir.path, "replay " + bad);
  EXPECT_EQ(re.exit_code, 2);
  EXPECT_NE(re.err.find("bad/summary.json: no scenario.path and hash_fnv1a64"), std::string::npos)
      << re.err;
}
#endif

}  // namespace
