// End-to-end checks of the shipped scenarios (paper Section 3 and the free motions), run
// in-process.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "core/fnv1a.hpp"
#include "ukdyn/core/uk_solve.hpp"
#include "ukdyn/model/system.hpp"
#include "ukdyn/paper_robot/mobile_manipulator.hpp"
#include "ukdyn/run/run.hpp"
#include "ukdyn/scenario/scenario.hpp"

namespace {

using namespace ukdyn;
const std::filesystem::path kSource = UKDYN_SOURCE_DIR;

std::filesystem::path temp_dir(const std::string& name) {
  auto p = std::filesystem::temp_directory_path() /
           ("ukdyn_test_" + name + "_" +
            std::to_string(::testing::UnitTest::GetInstance()->random_seed()));
  std::filesystem::remove_all(p);
  return p;
}

// Total horizontal momentum and vertical angular momentum (about the world Z axis) of the system.
// For the mobile manipulator, (M q̇) at Δx, Δy is the subsystem's linear momentum (Δx, Δy translate
// the whole subsystem) and (M q̇) at δ its angular momentum about the vertical axis through the
// platform (δ turns the whole arm about it): L_O = L_platform + r_platform × P.
struct Momenta {
  double Px = 0, Py = 0, Lz = 0;
};
Momenta momenta(const Scenario& sc, const ForwardData& d, CVecRef q, CVecRef qd) {
  const Vec p = d.M * qd;
  Momenta m;
  for (const auto& s : sc.subsystems) {
    const Index o = s.offset;
    m.Px += p(o);
    m.Py += p(o + 1);
    m.Lz += p(o + 2) + q(o) * p(o + 1) - q(o + 1) * p(o);
  }
  return m;
}

struct FreeRun {
  double max_dE = 0, max_T = 0, max_res = 0;
  Momenta m0, max_dm;
  long samples = 0;
  SimulationStats stats;
};

FreeRun run_free(const std::string& file) {
  const Scenario sc = load_scenario(kSource / "scenarios" / file);
  FreeRun r;
  const System& sys = *sc.system;
  Vec phi(sys.rows());
  double E0 = 0;
  bool first = true;
  const ForceFunction tau = [&](double, CVecRef, CVecRef, VecRef out) { out = sc.tau; };
  r.stats = simulate(sys, sc.q0, sc.qd0, tau, sc.sim,
                     [&](double t, CVecRef q, CVecRef qd, const ForwardData& d) {
                       const double E = kinetic_energy(d, qd) + potential_energy(sys, q);
                       const Momenta m = momenta(sc, d, q, qd);
                       if (first) {
                         E0 = E;
                         r.m0 = m;
                         first = false;
                       }
                       r.max_dE = std::max(r.max_dE, std::abs(E - E0));
                       r.max_T = std::max(r.max_T, kinetic_energy(d, qd));
                       r.max_dm.Px = std::max(r.max_dm.Px, std::abs(m.Px - r.m0.Px));
                       r.max_dm.Py = std::max(r.max_dm.Py, std::abs(m.Py - r.m0.Py));
                       r.max_dm.Lz = std::max(r.max_dm.Lz, std::abs(m.Lz - r.m0.Lz));
                       position_residuals(sys, t, q, phi);
                       r.max_res = std::max(r.max_res, phi.cwiseAbs().maxCoeff());
                       ++r.samples;
                       return true;
                     });
  return r;
}

// The one FNV-1a of the library (src/core/fnv1a.hpp): the published test vectors, bytes added in
// pieces hash as their concatenation, and Scenario::hash is it with ukdyn's basis over the file.
TEST(ContentHash, Fnv1a64OfTheScenarioFile) {
  using detail::Fnv1a64;
  static_assert(Fnv1a64().add("").value() == 0xcbf29ce484222325ull);
  EXPECT_EQ(Fnv1a64().add("a").value(), 0xaf63dc4c8601ec8cull);
  EXPECT_EQ(Fnv1a64().add("foobar").hex(), "85944171f73967e8");
  EXPECT_EQ(Fnv1a64().add("foo").add("").add("bar").hex(), "85944171f73967e8");
  EXPECT_EQ(Fnv1a64(detail::kUkdynHashBasis).add("foobar").hex(), "88fad7c0a8ff07f2");
  const auto path = kSource / "scenarios" / "paper.yaml";
  std::ifstream in(path, std::ios::binary);
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_EQ(load_scenario_text(text, path).hash, Fnv1a64(detail::kUkdynHashBasis).add(text).hex());
}
TEST(PaperScenario, ResidualsStayBelow1e12AndRankIs12) {
  const Scenario sc = load_scenario(kSource / "scenarios" / "paper.yaml");
  ASSERT_EQ(sc.system->dof(), 12);
  ASSERT_EQ(sc.system->rows(), 12);
  const auto dir = temp_dir("paper");
  RunOptions opt;
  opt.figures = false;
  const RunReport rep = run_scenario(sc, dir, opt);
  ASSERT_EQ(rep.stats.status, RunStatus::completed) << rep.stats.message;
  EXPECT_EQ(rep.stats.samples, 401);
  EXPECT_EQ(rep.rank_min, 12);
  EXPECT_EQ(rep.rank_max, 12);
  for (std::size_t i = 0; i < rep.max_abs_residual.size(); ++i) {
    EXPECT_LE(rep.max_abs_residual[i], 1e-12) << sc.system->constraint_row_names()[i];
  }
  // The CSV has the documented header and one row per sample.
  std::ifstream in(dir / "trajectory.csv");
  std::string header;
  std::getline(in, header);
  EXPECT_EQ(
      header.rfind(
          "t,dx1,dy1,delta1,theta1,theta2,theta3,dx2,dy2,delta2,theta4,theta5,theta6,dx1_dot", 0),
      0u);
  EXPECT_NE(header.find(",Qc_theta6,res_closure_x,"), std::string::npos);
  EXPECT_NE(header.find("res_hold_delta1,T,V,E"), std::string::npos);
  long lines = 0;
  for (std::string l; std::getline(in, l);) ++lines;
  EXPECT_EQ(lines, 401);
  std::ifstream js(dir / "summary.json");
  const auto summary = nlohmann::json::parse(js);
  EXPECT_EQ(summary["status"], "complete");
  EXPECT_EQ(summary["rank"]["free_dof_min"], 0);
  std::filesystem::remove_all(dir);
}

TEST(PaperScenario, TrajectoryFollowsTheCosineProfile) {
  // Independent of the solver: the cut point of robot 1 must be at y_i + 0.5 − 0.5 cos(πt),
  // z_i + 0.5 − 0.5 cos(πt) and x_i at every sample (paper Eq. (19)); Δx1, Δx2, δ1 stay put.
  const Scenario sc = load_scenario(kSource / "scenarios" / "paper.yaml");
  const auto* arm = dynamic_cast<const MobileManipulator*>(sc.system->subsystems()[0].get());
  ASSERT_NE(arm, nullptr);
  const Vec3 p0 = arm->cut_point(sc.q0.head(6));
  EXPECT_NEAR(p0(0), 0.8, 1e-15);
  EXPECT_NEAR(p0(2), 1.2 - 0.4 * std::sqrt(3.0), 1e-15);  // paper notes: (0.8, 0, 1.2 − 0.4√3)
  double worst = 0;
  const ForceFunction tau;
  const auto sim_run =
      simulate(*sc.system, sc.q0, sc.qd0, tau, sc.sim,
               [&](double t, CVecRef q, CVecRef, const ForwardData&) {
                 const Vec3 p = arm->cut_point(q.head(6));
                 const double f = 0.5 - 0.5 * std::cos(M_PI * t);
                 worst = std::max({worst, std::abs(p(0) - p0(0)), std::abs(p(1) - p0(1) - f),
                                   std::abs(p(2) - p0(2) - f), std::abs(q(0)), std::abs(q(6) - 1.6),
                                   std::abs(q(2))});
                 return true;
               });
  ASSERT_EQ(sim_run.status, RunStatus::completed) << sim_run.message;
  EXPECT_LE(worst, 1e-12);
}

TEST(PaperFree, EnergyAndMomentaAreConserved) {
  const FreeRun r = run_free("paper_free.yaml");
  ASSERT_EQ(r.stats.status, RunStatus::completed) << r.stats.message;
  EXPECT_EQ(r.samples, 501);
  EXPECT_GT(r.max_T, 10.0);  // it really moves
  EXPECT_LE(r.max_dE, 1e-9 * r.max_T);
  EXPECT_LE(r.max_dm.Px, 1e-9);
  EXPECT_LE(r.max_dm.Py, 1e-9);
  EXPECT_LE(r.max_dm.Lz, 1e-9);
  EXPECT_LE(r.max_res, 1e-10);
}

TEST(PaperFreeSpatial, EnergyAndMomentaAreConservedInASpatialMotion) {
  const FreeRun r = run_free("paper_free_spatial.yaml");
  ASSERT_EQ(r.stats.status, RunStatus::completed) << r.stats.message;
  EXPECT_GT(r.max_T, 10.0);
  EXPECT_LE(r.max_dE, 1e-9 * r.max_T);
  // The spatial start has non-zero momenta; they must stay at their initial values.
  EXPECT_LE(r.max_dm.Px, 1e-9);
  EXPECT_LE(r.max_dm.Py, 1e-9);
  EXPECT_LE(r.max_dm.Lz, 1e-9);
  EXPECT_LE(r.max_res, 1e-10);
}

TEST(PaperFreeSpatial, YawReallySwings) {
  // From rest the free motion stays planar; the spatial start must exercise the yaw terms.
  const Scenario sc = load_scenario(kSource / "scenarios" / "paper_free_spatial.yaml");
  double dmax = 0;
  const ForceFunction tau;
  const auto sim_run = simulate(*sc.system, sc.q0, sc.qd0, tau, sc.sim,
                                [&](double, CVecRef q, CVecRef, const ForwardData&) {
                                  dmax = std::max(dmax, std::abs(q(2) - sc.q0(2)));
                                  return true;
                                });
  ASSERT_EQ(sim_run.status, RunStatus::completed) << sim_run.message;
  EXPECT_GT(dmax, 2.0);
}

}  // namespace

namespace {

// The column `name` of a run kept in memory.
std::vector<double> memory_column(const ukdyn::MemoryRun& run, const std::string& name) {
  const auto it = std::find(run.header.begin(), run.header.end(), name);
  EXPECT_NE(it, run.header.end()) << name;
  const std::size_t c = static_cast<std::size_t>(it - run.header.begin()), w = run.header.size();
  std::vector<double> out;
  for (std::size_t r = 0; r * w < run.values.size(); ++r) out.push_back(run.values[r * w + c]);
  return out;
}

}  // namespace

// The sigma_min column: by default the solve's pivot estimate, which (exact solve) is never below
// the smallest kept singular value of A M^-1/2 and within a small factor of it; with
// simulation.sigma_min: svd, that singular value itself, checked here against an SVD of A M^-1/2
// computed from the row's own state.
TEST(PaperScenario, SigmaMinColumnIsTheSolvesEstimateOrTheSvd) {
  Scenario sc = load_scenario(kSource / "scenarios" / "paper.yaml");
  sc.sim.t_end = 0.5;
  ASSERT_FALSE(sc.sim.sigma_min_svd);
  const MemoryRun est = run_scenario_in_memory(sc);
  sc.sim.sigma_min_svd = true;
  const MemoryRun svd = run_scenario_in_memory(sc);
  ASSERT_EQ(est.report.stats.status, RunStatus::completed);
  ASSERT_EQ(svd.report.stats.status, RunStatus::completed);
  const std::vector<double> e = memory_column(est, "sigma_min"),
                            s = memory_column(svd, "sigma_min");
  ASSERT_EQ(e.size(), s.size());
  ASSERT_GT(e.size(), 10u);
  const System& sys = *sc.system;
  const Index n = sys.dof();
  ForwardData d(sys);
  const std::size_t w = svd.header.size();
  for (std::size_t r = 0; r < s.size(); r += 7) {
    EXPECT_GE(e[r], s[r] * (1 - 1e-12)) << "row " << r;
    EXPECT_LE(e[r], 10 * s[r]) << "row " << r;
    const double t = svd.values[r * w];
    const Eigen::Map<const Vec> q(&svd.values[r * w + 1], n), qd(&svd.values[r * w + 1 + n], n);
    evaluate_dynamics(sys, d, t, q, qd);
    evaluate_constraints(sys, d, t, q, qd);
    const Vec sv = singular_values_A_Minvhalf(d.M, d.A);
    EXPECT_NEAR(s[r], sv(sv.size() - 1), 1e-12 * sv(0)) << "row " << r;
  }
  // The key and its values.
  const std::string base = "\n  sample_dt: 0.01\n";
  std::ifstream in(kSource / "scenarios" / "paper.yaml");
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const auto at = text.find(base);
  ASSERT_NE(at, std::string::npos);
  std::string good = text, bad = text;
  good.replace(at, base.size(), base + "  sigma_min: svd\n");
  bad.replace(at, base.size(), base + "  sigma_min: exact\n");
  EXPECT_TRUE(load_scenario_text(good, kSource / "scenarios" / "paper.yaml").sim.sigma_min_svd);
  try {
    (void)load_scenario_text(bad, kSource / "scenarios" / "paper.yaml");
    ADD_FAILURE() << "sigma_min: exact was accepted";
  } catch (const std::exception& ex) {
    EXPECT_NE(std::string(ex.what()).find("simulation.sigma_min"), std::string::npos) << ex.what();
  }
}
