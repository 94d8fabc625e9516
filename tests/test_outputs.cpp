// Every force in the outputs (docs/frame-constraints.md, docs/sweeps.md), checked from the files
// alone against independent evidence:
// - n_robots_4_weld.yaml (four robots welded to a free-body load): the grasp wrenches W_ written to
//   trajectory.csv, moved to the load's CoM with the grasp points of the pose_ columns, equal the
//   load's Newton–Euler equations [m (p̈ − g); R (J ω̇ + ω × J ω)] computed from its own q, q̇, q̈
//   columns (quaternion kinematics by Eigen); both internal wrenches Wint_ lie in null(G) (they
//   add up to no net force or moment), and at rest the inertia-weighted one is zero
//   ([Verginis2019], the robots' own grasp accelerations are all zero); the pose_ columns equal
//   the load's pose composed with the weld's offset (the scenario's xyz, rpy).
// - internal_wrenches() (the allocation-free form the writer uses) against the allocating
//   internal_wrench_walker() / internal_wrench_weighted() / task_space_inertia().
// - rolling_disk.yaml, mecanum_platform.yaml: the nonholonomic rows get vres_ columns (no res_),
//   equal to the closed-form rows x_dot − r cos(th) ph_dot, y_dot − r sin(th) ph_dot, and to
//   A(q) q̇ from the system's evaluated A.
// - `ukdyn sweep` over the load's mass: the peak grasp-force magnitude per grasp (a norm metric)
//   equals the max over the rows of √(fx² + fy² + fz²) computed from each extracted sample's own
//   trajectory.csv; a metric naming a missing column is refused at its own line and key; the
//   metric columns beyond the figure cap are listed as not drawn.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>

#include "cli_run.hpp"
#include "output/csv_reader.hpp"
#include "ukdyn/core/constraint_forces.hpp"
#include "ukdyn/model/system.hpp"
#include "ukdyn/run/run.hpp"
#include "ukdyn/scenario/scenario.hpp"

namespace {

namespace fs = std::filesystem;
using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;
using ukdyn::Vec3;
using ukdyn_test::run_cli;
using ukdyn_test::ScratchDir;
using ukdyn_test::sh;
using ukdyn_test::slurp;

const fs::path kSource = UKDYN_SOURCE_DIR;

// A CSV file as its header and rows of numbers.
struct Csv {
  std::vector<std::string> header;
  std::vector<std::vector<double>> rows;
  [[nodiscard]] std::size_t col(const std::string& name) const {
    const auto it = std::find(header.begin(), header.end(), name);
    EXPECT_NE(it, header.end()) << name;
    return it == header.end() ? 0 : static_cast<std::size_t>(it - header.begin());
  }
  [[nodiscard]] bool has(const std::string& name) const {
    return std::find(header.begin(), header.end(), name) != header.end();
  }
};

Csv read_csv(const fs::path& p) {
  std::ifstream in(p);
  ukdyn::io_detail::CsvLines lines(in);
  Csv c;
  std::string l;
  if (!lines.next(l)) return c;
  c.header = ukdyn::io_detail::split_csv_line(l);
  while (lines.next(l)) {
    std::vector<double> row;
    for (const auto& cell : ukdyn::io_detail::split_csv_line(l)) {
      double v = NAN;
      ukdyn::io_detail::parse_csv_number(cell, v);
      row.push_back(v);
    }
    c.rows.push_back(std::move(row));
  }
  return c;
}

Csv csv_of(const ukdyn::MemoryRun& run) {
  Csv c{run.header, {}};
  const std::size_t n = run.header.size();
  for (std::size_t r = 0; r * n < run.values.size(); ++r)
    c.rows.emplace_back(run.values.begin() + static_cast<long>(r * n),
                        run.values.begin() + static_cast<long>((r + 1) * n));
  return c;
}

// n_robots_4_weld.yaml's load (tools/n_robots.py): mass, principal inertia, gravity.
constexpr double kMass = 3.0, kG = 9.81;
const Eigen::Vector3d kJ(0.05, 0.06, 0.08);
const char* const kGrasps[4] = {"grasp0", "grasp1", "grasp2", "grasp3"};

Eigen::Vector3d vec3(const Csv& c, const std::vector<double>& row, const std::string& prefix,
                     const char* a, const char* b, const char* d) {
  return {row[c.col(prefix + a)], row[c.col(prefix + b)], row[c.col(prefix + d)]};
}

Eigen::Quaterniond quat(const Csv& c, const std::vector<double>& row, const std::string& prefix) {
  return {row[c.col(prefix + "qw")], row[c.col(prefix + "qx")], row[c.col(prefix + "qy")],
          row[c.col(prefix + "qz")]};
}

struct LoadCheck {
  double newton_euler = 0, null_walker = 0, null_weighted = 0, weighted_at_rest = 0,
         walker_at_rest = 0, pose = 0;
};

// The checks of one row of n_robots_4_weld's trajectory.csv (the CSV alone).
void check_row(const Csv& c, const std::vector<double>& row, bool at_rest, LoadCheck& out) {
  // The load's Newton–Euler from its own columns: ω = 2 vec(q* ⊗ q̇), ω̇ = 2 vec(q* ⊗ q̈) (body).
  const Eigen::Vector3d p = vec3(c, row, "load_", "x", "y", "z");
  const Eigen::Vector3d pdd = vec3(c, row, "load_", "x_ddot", "y_ddot", "z_ddot");
  const auto qq = [&](const std::string& s) {
    return Eigen::Quaterniond(row[c.col("load_qw" + s)], row[c.col("load_qx" + s)],
                              row[c.col("load_qy" + s)], row[c.col("load_qz" + s)]);
  };
  const Eigen::Quaterniond q = qq(""), qd = qq("_dot"), qdd = qq("_ddot");
  const Eigen::Vector3d w = 2.0 * (q.conjugate() * qd).vec();
  const Eigen::Vector3d wd = 2.0 * (q.conjugate() * qdd).vec();
  const Eigen::Matrix3d R = q.toRotationMatrix();
  Eigen::Matrix<double, 6, 1> ne;
  ne.head<3>() = kMass * (pdd - Eigen::Vector3d(0, 0, -kG));
  ne.tail<3>() = R * (kJ.cwiseProduct(wd) + w.cross(kJ.cwiseProduct(w)));
  // The grasp wrenches about the CoM, and the internal parts' net wrench.
  Eigen::Matrix<double, 6, 1> sum = Eigen::Matrix<double, 6, 1>::Zero(), iw = sum, iv = sum;
  double wnorm = 0.0;
  for (const char* g : kGrasps) {
    const std::string G(g);
    const Eigen::Vector3d at = vec3(c, row, "pose_" + G + "_", "x", "y", "z");
    const auto net = [&](const std::string& pre, Eigen::Matrix<double, 6, 1>& acc) {
      const Eigen::Vector3d f = vec3(c, row, pre, "fx", "fy", "fz");
      const Eigen::Vector3d m = vec3(c, row, pre, "mx", "my", "mz");
      acc.head<3>() += f;
      acc.tail<3>() += m + (at - p).cross(f);
      return std::sqrt(f.squaredNorm() + m.squaredNorm());
    };
    const double wn = net("W_" + G + "_", sum);
    wnorm = std::hypot(wnorm, wn);
    const double walker = net("Wint_walker_" + G + "_", iw);
    const double weighted = net("Wint_weighted_" + G + "_", iv);
    if (at_rest) {
      out.walker_at_rest = std::hypot(out.walker_at_rest, walker);
      out.weighted_at_rest = std::hypot(out.weighted_at_rest, weighted);
    }
  }
  out.newton_euler = std::max(out.newton_euler, (sum - ne).norm() / ne.norm());
  out.null_walker = std::max(out.null_walker, iw.norm() / wnorm);
  out.null_weighted = std::max(out.null_weighted, iv.norm() / wnorm);
}

// The weld offsets of n_robots_4_weld.yaml (b: {frame: load.load, xyz, rpy: [0, 0, yaw]}).
struct Offset {
  Eigen::Vector3d xyz;
  double yaw;
};
const Offset kOffsets[4] = {{{0.3, 0.0, 0.0}, 3.141592653589793},
                            {{0.06470476127563018, 0.24148145657226708, 0.05}, 4.4505895925855405},
                            {{-0.35, 4.286263797015736e-17, -0.04}, 6.283185307179586},
                            {{-0.10260604299770056, -0.2819077862357725, 0.02}, 7.504915783575617}};

double pose_error(const Csv& c, const std::vector<double>& row) {
  const Eigen::Vector3d p = vec3(c, row, "load_", "x", "y", "z");
  const Eigen::Quaterniond q = quat(c, row, "load_");
  double e = 0.0;
  for (int k = 0; k < 4; ++k) {
    const std::string pre = std::string("pose_") + kGrasps[k] + "_";
    const Eigen::Vector3d at = p + q * kOffsets[k].xyz;
    Eigen::Quaterniond r =
        q * Eigen::Quaterniond(Eigen::AngleAxisd(kOffsets[k].yaw, Eigen::Vector3d::UnitZ()));
    if (r.w() < 0.0) r.coeffs() = -r.coeffs();
    e = std::max(e, (vec3(c, row, pre, "x", "y", "z") - at).norm());
    e = std::max(e, (quat(c, row, pre).coeffs() - r.coeffs()).norm());
  }
  return e;
}

TEST(Outputs, GraspWrenchesFromTheCsvAloneObeyTheLoadsNewtonEuler) {
  ScratchDir dir("ukdyn_outputs_weld");
  auto sc = ukdyn::load_scenario(kSource / "scenarios" / "n_robots_4_weld.yaml");
  sc.sim.t_end = 0.3;  // the load falls, the robots are dragged along
  ukdyn::RunOptions opt;
  opt.figures = false;
  const auto rep = ukdyn::run_scenario(sc, dir.path / "o", opt);
  ASSERT_TRUE(rep.complete()) << rep.stats.message;
  const Csv c = read_csv(dir.path / "o" / "trajectory.csv");
  ASSERT_GT(c.rows.size(), 10u);
  for (const char* g : kGrasps) {
    for (const char* form : {"walker", "weighted"})
      for (const char* a : {"fx", "fy", "fz", "mx", "my", "mz"})
        EXPECT_TRUE(c.has(fmt::format("Wint_{}_{}_{}", form, g, a))) << g << form << a;
    for (const char* a : {"x", "y", "z", "qw", "qx", "qy", "qz"})
      EXPECT_TRUE(c.has(fmt::format("pose_{}_{}", g, a)));
  }
  LoadCheck lc;
  for (std::size_t r = 0; r < c.rows.size(); ++r) {
    check_row(c, c.rows[r], r == 0, lc);
    lc.pose = std::max(lc.pose, pose_error(c, c.rows[r]));
  }
  std::printf(
      "n_robots_4_weld CSV, %zu rows: |sum W - NE|/|NE| %.3g; |G Wint|/|W| Walker %.3g, weighted "
      "%.3g; at rest |Wint| Walker %.4g N, weighted %.3g; pose %.3g\n",
      c.rows.size(), lc.newton_euler, lc.null_walker, lc.null_weighted, lc.walker_at_rest,
      lc.weighted_at_rest, lc.pose);
  EXPECT_LE(lc.newton_euler, 1e-12);
  EXPECT_LE(lc.null_walker, 1e-12);
  EXPECT_LE(lc.null_weighted, 1e-12);
  EXPECT_LE(lc.weighted_at_rest, 1e-9 * kMass * kG);  // no squeeze ([Verginis2019])
  EXPECT_GT(lc.walker_at_rest, 0.1);                  // the asymmetric grasps: Walker's is not 0
  EXPECT_LE(lc.pose, 1e-12);
}

// The writer's allocation-free form against the allocating functions of the same formulas.
TEST(Outputs, InternalWrenchesInItsWorkspaceMatchTheAllocatingFunctions) {
  std::mt19937_64 rng(11);
  std::normal_distribution<double> nd;
  // (na < 6N: J M⁻¹ Jᵀ singular, its pseudo-inverse by SVD; else by Cholesky)
  for (const auto& [N, na] : {std::pair<Index, Index>{2, 15}, {3, 21}, {4, 27}, {2, 7}}) {
    ukdyn::InternalWrenchWorkspace ws(N, na);
    for (auto& p : ws.points) p = Vec3(nd(rng), nd(rng), nd(rng));
    for (Index i = 0; i < ws.w.size(); ++i) ws.w(i) = nd(rng);
    for (Index i = 0; i < ws.J.size(); ++i) ws.J.data()[i] = nd(rng);
    Mat X(na, na);
    for (Index i = 0; i < X.size(); ++i) X.data()[i] = nd(rng);
    ws.M = X * X.transpose() + Mat::Identity(na, na);
    ukdyn::internal_wrenches(ws);
    ASSERT_TRUE(ws.weighted_ok);
    const Mat G = ukdyn::grasp_matrix(ws.points, Vec3(0.3, -0.2, 0.1));  // another reference
    const Vec walker = ukdyn::internal_wrench_walker(G, ws.w);
    const Vec weighted =
        ukdyn::internal_wrench_weighted(G, ukdyn::task_space_inertia(ws.M, ws.J), ws.w);
    EXPECT_LE((ws.walker - walker).norm(), 1e-12 * ws.w.norm()) << N << " " << na;
    EXPECT_LE((ws.weighted - weighted).norm(), 1e-10 * ws.w.norm()) << N << " " << na;
    EXPECT_GT(ws.weighted.norm(), 1e-3 * ws.w.norm());  // (not trivially zero)
  }
  // Not positive definite: NaN, said by weighted_ok.
  ukdyn::InternalWrenchWorkspace ws(2, 3);
  ws.points[1] = Vec3(1, 0, 0);
  ws.w.setOnes();
  ws.M.setZero();
  ukdyn::internal_wrenches(ws);
  EXPECT_FALSE(ws.weighted_ok);
  EXPECT_TRUE(std::isnan(ws.weighted(0)));
}

// A short run without drift control at loose tolerances: the velocity residuals grow well above
// round-off, so that the comparisons below see them.
ukdyn::MemoryRun short_run(const std::string& file, double t_end) {
  auto sc = ukdyn::load_scenario(kSource / "scenarios" / file);
  sc.sim.t_end = t_end;
  sc.sim.drift.kind = ukdyn::DriftControl::none;
  sc.sim.abs_tol = sc.sim.rel_tol = 1e-5;
  return ukdyn::run_scenario_in_memory(sc, {});
}

TEST(Outputs, NonholonomicRowsGetVelocityResidualColumns) {
  {  // the rolling disk: its rows in closed form
    const Csv c = csv_of(short_run("rolling_disk.yaml", 2.0));
    EXPECT_FALSE(c.has("res_roll_x"));
    EXPECT_FALSE(c.has("res_roll_y"));
    const std::size_t vx = c.col("vres_roll_x"), vy = c.col("vres_roll_y");
    const double r = 0.3;
    double err = 0.0, peak = 0.0;
    for (const auto& row : c.rows) {
      const double th = row[c.col("th")], ph_dot = row[c.col("ph_dot")];
      const double ex = row[c.col("x_dot")] - r * std::cos(th) * ph_dot;
      const double ey = row[c.col("y_dot")] - r * std::sin(th) * ph_dot;
      err = std::max({err, std::abs(row[vx] - ex), std::abs(row[vy] - ey)});
      peak = std::max({peak, std::abs(ex), std::abs(ey)});
    }
    std::printf("rolling_disk: max |vres - closed form| %.3g (max |closed form| %.3g)\n", err,
                peak);
    EXPECT_GT(peak, 1e-9);  // drift to see
    EXPECT_LE(err, 1e-14 + 1e-9 * peak);
  }
  {  // the Mecanum platform: A(q) q̇ from the system's evaluated A (the rows are scleronomic)
    auto sc = ukdyn::load_scenario(kSource / "scenarios" / "mecanum_platform.yaml");
    const ukdyn::System& sys = *sc.system;
    const auto vel = ukdyn::velocity_level_rows(sys);
    ASSERT_EQ(std::count(vel.begin(), vel.end(), true), sys.rows());
    const Csv c = csv_of(short_run("mecanum_platform.yaml", 1.0));
    ukdyn::ForwardData d(sys);
    double err = 0.0, peak = 0.0;
    const Index n = sys.dof();
    for (const auto& row : c.rows) {
      Vec q(n), qd(n);
      for (Index j = 0; j < n; ++j) {
        const auto& name = sys.coordinate_names()[static_cast<std::size_t>(j)];
        q(j) = row[c.col(name)];
        qd(j) = row[c.col(name + "_dot")];
      }
      ukdyn::evaluate_constraints(sys, d, row[0], q, qd);
      const Vec Aqd = d.A * qd;
      for (Index i = 0; i < sys.rows(); ++i) {
        const auto& rn = sys.constraint_row_names()[static_cast<std::size_t>(i)];
        EXPECT_FALSE(c.has("res_" + rn));
        err = std::max(err, std::abs(row[c.col("vres_" + rn)] - Aqd(i)));
        peak = std::max(peak, std::abs(Aqd(i)));
      }
    }
    std::printf("mecanum_platform: max |vres - A(q) qdot| %.3g (max |A qdot| %.3g)\n", err, peak);
    EXPECT_GT(peak, 1e-9);
    EXPECT_LE(err, 1e-14 + 1e-9 * peak);
  }
}

const fs::path kCli = UKDYN_CLI;

fs::path write(const fs::path& p, const std::string& text) {
  std::ofstream(p) << text;
  return p;
}

std::string weld_sweep(const std::string& extra_metric) {
  std::string norms;
  for (const char* g : kGrasps)
    norms += fmt::format(
        "  - {{norm: [W_{0}_fx, W_{0}_fy, W_{0}_fz], name: {0}_force, stats: [max, min, rms, "
        "max_abs, final]}}\n",
        g);
  return fmt::format(R"(ukdyn_sweep: 1
name: load_mass
base: {}
mode: grid
parameters:
  - name: load_mass
    path: subsystems[load].mass
    values: [2, 3, 5]
set:
  simulation.t_end: 0.1
  simulation.abs_tol: 1e-10
  simulation.rel_tol: 1e-10
metrics:
  - max_residual
{}{})",
                     (kSource / "scenarios" / "n_robots_4_weld.yaml").string(), norms,
                     extra_metric);
}

TEST(OutputsCli, SweepPeakGraspForceIsTheMaxOfTheNormInEachSamplesCsv) {
  ScratchDir dir("ukdyn_outputs_sweep");
  const fs::path f =
      write(dir.path / "s.yaml",
            weld_sweep(
                "  - {column: Wint_weighted_grasp1_fz, stats: [min, max, rms, max_abs, final]}\n"));
  auto r = run_cli(kCli, dir.path, "sweep " + sh(f) + " -o " + sh((dir.path / "o").string()));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const Csv t = read_csv(dir.path / "o" / "results.csv");
  ASSERT_EQ(t.rows.size(), 3u);
  // 1 + 4 × 5 + 5 = 26 metric columns: the last two are beyond the 24 drawn, and said so.
  const auto js = nlohmann::json::parse(slurp(dir.path / "o" / "summary.json"));
  ASSERT_TRUE(js.contains("figures_left_out")) << js.dump(2);
  EXPECT_EQ(js["figures_left_out"].size(), 2u) << js.dump(2);
  EXPECT_NE(r.out.find("figure not drawn: max_abs_Wint_weighted_grasp1_fz"), std::string::npos)
      << r.out;
  std::vector<double> peaks;
  for (long k = 0; k < 3; ++k) {
    auto e = run_cli(kCli, dir.path, fmt::format("sweep {} --extract {}", sh(f.string()), k));
    ASSERT_EQ(e.exit_code, 0) << e.err;
    const fs::path sc = write(dir.path / fmt::format("sample{}.yaml", k), e.out);
    const fs::path out = dir.path / fmt::format("run{}", k);
    auto s = run_cli(kCli, dir.path,
                     "simulate " + sh(sc.string()) + " --no-figures -q -o " + sh(out.string()));
    ASSERT_EQ(s.exit_code, 0) << s.err;
    const Csv c = read_csv(out / "trajectory.csv");
    const auto& row = t.rows[static_cast<std::size_t>(k)];
    for (const char* g : kGrasps) {
      const std::string G(g);
      double peak = 0.0;
      for (const auto& cr : c.rows) {
        const double fx = cr[c.col("W_" + G + "_fx")], fy = cr[c.col("W_" + G + "_fy")],
                     fz = cr[c.col("W_" + G + "_fz")];
        peak = std::max(peak, std::sqrt(fx * fx + fy * fy + fz * fz));
      }
      const double got = row[t.col("max_" + G + "_force")];
      EXPECT_LE(std::abs(got - peak), 1e-15 * peak) << "sample " << k << " " << g;
      if (G == "grasp0") peaks.push_back(got);
    }
    double fz_max = -1e300;
    for (const auto& cr : c.rows) fz_max = std::max(fz_max, cr[c.col("Wint_weighted_grasp1_fz")]);
    EXPECT_EQ(row[t.col("max_Wint_weighted_grasp1_fz")], fz_max) << k;
  }
  // A heavier load pulls harder on its grasps.
  ASSERT_EQ(peaks.size(), 3u);
  EXPECT_LT(peaks[0], peaks[1]);
  EXPECT_LT(peaks[1], peaks[2]);
}

TEST(OutputsCli, BadMetricColumnIsNamedAtItsLineAndKey) {
  ScratchDir dir("ukdyn_outputs_bad");
  // metrics[2] (the second grasp's norm) names a grasp that does not exist.
  std::string text = weld_sweep("  - {norm: [W_grasp9_fx, W_grasp0_fy], name: bad}\n");
  const fs::path f = write(dir.path / "b.yaml", text);
  auto r = run_cli(kCli, dir.path, "sweep " + sh(f) + " -o " + sh((dir.path / "o").string()));
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find(f.string() + ":19:13: key 'metrics[5].norm[0]': no column named "
                                    "'W_grasp9_fx'"),
            std::string::npos)
      << r.err;
  const fs::path g = write(dir.path / "c.yaml", weld_sweep("  - {column: W_grasp0_fx, name: x}\n"));
  r = run_cli(kCli, dir.path, "sweep " + sh(g) + " -o " + sh((dir.path / "o").string()));
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("key 'metrics[5].name': name: goes with norm:"), std::string::npos) << r.err;
}

TEST(OutputsCli, ConsoleLabelsTheVelocityResidual) {
  ScratchDir dir("ukdyn_outputs_console");
  auto r = run_cli(kCli, dir.path,
                   "simulate " + sh((kSource / "scenarios" / "rolling_disk.yaml").string()) +
                       " --no-figures -o " + sh((dir.path / "o").string()));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("max |vel. residual|"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("velocity level"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("max |residual|"), std::string::npos) << r.out;  // no position rows
  const auto js = nlohmann::json::parse(slurp(dir.path / "o" / "summary.json"));
  EXPECT_EQ(js["velocity_level_rows"].size(), 2u);
  EXPECT_LE(js["max_abs_velocity_residual_nonholonomic"].get<double>(), 1e-8);
}

}  // namespace
