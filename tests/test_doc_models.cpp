// Models a user writes from the docs alone (docs/definitions.md, docs/derivatives.md,
// robots/README.md), each against a closed form or a second, independent formulation:
// - tests/doc_models/double_pendulum.yaml (definitions) against the textbook Lagrange equations
//   of the compound double pendulum [Goldstein2002];
// - tests/doc_models/slider_crank.yaml (definitions, expression rows, a driven coordinate) against
//   the closed-form slider-crank kinematics, and tests/doc_models/slider_crank_mjcf.yaml (the same
//   mechanism as MJCF, a connect equality) against both: kinematics and constraint forces;
// - tests/doc_models/welded_arm.xml (an MJCF weld) against statics; the MJCF equalities the docs
//   say are refused (joint, tendon, inactive) are refused naming the file and the equality;
// - tests/doc_models/cart_pole.yaml through `ukdyn linearize` against the textbook A, B of the
//   cart-pole at its upright equilibrium;
// - scenarios/two_iiwa_load.yaml (two KUKA LBR iiwa 14 from robots/iiwa14.urdf carrying the
//   paper's load): the welds, the energy and the symmetry of the two arms over the run.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>
#include <string>
#include <vector>

#include "cli_run.hpp"
#include "ukdyn/model/system.hpp"
#include "ukdyn/robot_files/mjcf.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/simulate/simulate.hpp"

namespace {

namespace fs = std::filesystem;
using ukdyn::CVecRef;
using ukdyn::Mat;
using ukdyn::Vec;
using ukdyn::VecRef;
const fs::path kModels = fs::path(UKDYN_SOURCE_DIR) / "tests" / "doc_models";

// One run of a scenario with its constant τ: the state, q̈ and Qc at every output sample.
struct Samples {
  std::vector<double> t;
  std::vector<Vec> q, qd, qdd, Qc;
  double max_residual = 0.0;  // max |Φ| over the samples
  double energy_drift = 0.0;  // max |E − E0| (no forces do work here: τ = 0, ideal constraints)
};

Samples run(const ukdyn::Scenario& sc) {
  const ukdyn::System& sys = *sc.system;
  Samples s;
  Vec phi(sys.rows());
  double E0 = 0.0;
  const ukdyn::ForceFunction tau = [&](double, CVecRef, CVecRef, VecRef out) { out = sc.tau; };
  const auto stats = ukdyn::simulate(
      sys, sc.q0, sc.qd0, tau, sc.sim,
      [&](double t, CVecRef q, CVecRef qd, const ukdyn::ForwardData& d) {
        const double E = ukdyn::kinetic_energy(d, qd) + ukdyn::potential_energy(sys, t, q);
        if (s.t.empty()) E0 = E;
        s.energy_drift = std::max(s.energy_drift, std::abs(E - E0));
        s.t.push_back(t);
        s.q.emplace_back(q);
        s.qd.emplace_back(qd);
        s.qdd.emplace_back(d.qdd);
        s.Qc.emplace_back(d.Qc);
        if (sys.rows() > 0) {
          ukdyn::position_residuals(sys, t, q, phi);
          s.max_residual = std::max(s.max_residual, phi.cwiseAbs().maxCoeff());
        }
        return true;
      });
  EXPECT_EQ(stats.status, ukdyn::RunStatus::completed) << stats.message;
  return s;
}

double rel(const Mat& a, const Mat& b) { return (a - b).norm() / std::max(1.0, b.norm()); }

TEST(DocModels, DoublePendulumIsLagrangesClosedForm) {
  const auto sc = ukdyn::load_scenario(kModels / "double_pendulum.yaml");
  const ukdyn::System& sys = *sc.system;
  ukdyn::ForwardData d(sys);
  const double m1 = 2, m2 = 1.5, l1 = 0.8, l2 = 0.6, g = 9.81;
  const double I1 = m1 * l1 * l1 / 12, I2 = m2 * l2 * l2 / 12, h = m2 * l1 * l2 / 2;
  std::mt19937 rng(5u);
  std::uniform_real_distribution<double> u(-3.0, 3.0);
  double worst = 0.0;
  for (int k = 0; k < 100; ++k) {
    Vec q(2), qd(2);
    q << u(rng), u(rng);
    qd << u(rng), u(rng);
    ukdyn::forward(sys, d, 0.0, q, qd, Vec::Zero(2));
    // T = ½ (m1 l1²/4 + I1 + m2 l1²) θ̇1² + h cos(θ1 − θ2) θ̇1 θ̇2 + ½ (m2 l2²/4 + I2) θ̇2²,
    // V = −(m1/2 + m2) g l1 cos θ1 − m2 g l2/2 cos θ2.
    const double c = std::cos(q[0] - q[1]), s = std::sin(q[0] - q[1]);
    Mat M(2, 2);
    M << m1 * l1 * l1 / 4 + I1 + m2 * l1 * l1, h * c, h * c, m2 * l2 * l2 / 4 + I2;
    Vec Cqd(2), G(2);
    Cqd << h * s * qd[1] * qd[1], -h * s * qd[0] * qd[0];
    G << (m1 / 2 + m2) * g * l1 * std::sin(q[0]), m2 * g * l2 / 2 * std::sin(q[1]);
    const Vec qdd = M.ldlt().solve(-Cqd - G);
    worst = std::max({worst, rel(d.M, M), rel(d.Cqd, Cqd), rel(d.G, G), rel(d.qdd, qdd)});
  }
  EXPECT_LE(worst, 1e-13);
  RecordProperty("worst_relative", ::testing::PrintToString(worst));
  std::printf("double pendulum: M, C qd, G, qdd against the closed form: %.2e relative\n", worst);
}

// The crank angle th = 0.5 + 6 t; the slider at s = r cos th + sqrt(l² − r² sin² th).
struct CrankKinematics {
  double th, s, sd;
};
CrankKinematics crank_at(double t) {
  const double r = 0.1, l = 0.35, w = 6.0, th = 0.5 + w * t;
  const double root = std::sqrt(l * l - r * r * std::sin(th) * std::sin(th));
  return {th, r * std::cos(th) + root,
          -r * w * std::sin(th) - r * r * w * std::sin(th) * std::cos(th) / root};
}

TEST(DocModels, SliderCrankFollowsItsClosedFormKinematics) {
  const auto sc = ukdyn::load_scenario(kModels / "slider_crank.yaml");
  const Samples s = run(sc);
  ASSERT_EQ(s.t.size(), 201u);
  double worst = 0.0;
  for (std::size_t k = 0; k < s.t.size(); ++k) {
    const CrankKinematics c = crank_at(s.t[k]);
    worst = std::max({worst, std::abs(s.q[k][0] - c.th), std::abs(s.q[k][2] - c.s),
                      std::abs(s.qd[k][2] - c.sd)});
  }
  EXPECT_LE(worst, 1e-9);
  EXPECT_LE(s.max_residual, 1e-12);
  std::printf("slider-crank (definitions): th, s, sd against the closed form: %.2e\n", worst);
}

TEST(DocModels, MjcfSliderCrankAgreesWithTheDefinitions) {
  if (!ukdyn::symbolic::mjcf_supported()) GTEST_SKIP() << "built without MuJoCo";
  const auto sd = ukdyn::load_scenario(kModels / "slider_crank.yaml");
  const auto sm = ukdyn::load_scenario(kModels / "slider_crank_mjcf.yaml");
  // The connect equality becomes the frame constraint mech_pin (docs/definitions.md, "MJCF").
  ASSERT_EQ(sm.system->rows(), 4);  // pin x, y, z + the drive
  const Samples a = run(sd), b = run(sm);
  ASSERT_EQ(a.t.size(), b.t.size());
  double kin = 0.0, force = 0.0, scale = 0.0;
  for (std::size_t k = 0; k < b.t.size(); ++k) {
    const CrankKinematics c = crank_at(b.t[k]);
    kin = std::max({kin, std::abs(b.q[k][0] - c.th), std::abs(0.45 + b.q[k][2] - c.s),
                    std::abs(b.qd[k][2] - c.sd)});
    // MJCF coordinates (th, psi = ph − th, u = s − 0.45) are q_mjcf = P q_def, so a generalized
    // force maps as Q_mjcf = P^-T Q_def: (Q_th + Q_ph, Q_ph, Q_s).
    Vec mapped(3);
    mapped << a.Qc[k][0] + a.Qc[k][1], a.Qc[k][1], a.Qc[k][2];
    force = std::max(force, (b.Qc[k] - mapped).cwiseAbs().maxCoeff());
    scale = std::max(scale, mapped.cwiseAbs().maxCoeff());
  }
  EXPECT_LE(kin, 1e-9);
  EXPECT_LE(force, 1e-8 * scale);
  EXPECT_GT(scale, 1.0);  // the forces are not trivially zero
  EXPECT_LE(b.max_residual, 1e-12);
  std::printf(
      "slider-crank (MJCF connect): kinematics %.2e, Qc against the definitions %.2e of %.3g\n",
      kin, force, scale);
}

std::string mjcf_scenario(const fs::path& xml) {
  return "ukdyn: 1\nname: m\ngravity: 9.81\nsubsystems:\n  - {name: a, type: serial_chain, "
         "coordinates: [q], mjcf: '" +
         xml.string() +
         "'}\ninitial: {q: [0], qd: zeros}\nsimulation: {t_end: 0.1, sample_dt: 0.01}\n";
}

TEST(DocModels, MjcfWeldCarriesTheWeight) {
  if (!ukdyn::symbolic::mjcf_supported()) GTEST_SKIP() << "built without MuJoCo";
  const auto sc = ukdyn::load_scenario_text(mjcf_scenario(kModels / "welded_arm.xml"), "w.yaml");
  ASSERT_EQ(sc.system->rows(), 6);  // a weld: x, y, z, rx, ry, rz
  ukdyn::ForwardData d(*sc.system);
  ukdyn::forward(*sc.system, d, 0.0, sc.q0, sc.qd0, sc.tau);
  const double G = 2 * 9.81 * 0.3;  // m g lc about the hinge
  EXPECT_NEAR(d.G[0], G, 1e-13);
  EXPECT_NEAR(d.Qc[0], G, 1e-12);
  EXPECT_NEAR(d.qdd[0], 0.0, 1e-13);
}

// docs/definitions.md, "MJCF": joint and tendon equalities and inactive ones are refused with the
// file and the equality named.
TEST(DocModels, MjcfEqualitiesTheDocsRefuseAreRefused) {
  if (!ukdyn::symbolic::mjcf_supported()) GTEST_SKIP() << "built without MuJoCo";
  const ukdyn_test::ScratchDir dir("ukdyn_doc_models_eq");
  const std::string body =
      "<mujoco><compiler inertiafromgeom='false'/><worldbody>"
      "<body name='a'><joint name='ja' type='hinge' axis='0 1 0'/>"
      "<inertial pos='0.3 0 0' mass='1' diaginertia='0.01 0.01 0.01'/>"
      "<site name='sa' pos='0 0 0'/></body>"
      "<body name='b' pos='1 0 0'><joint name='jb' type='hinge' axis='0 1 0'/>"
      "<inertial pos='0.3 0 0' mass='1' diaginertia='0.01 0.01 0.01'/>"
      "<site name='sb' pos='0 0 0'/></body></worldbody>";
  const struct {
    const char* file;
    const char* extra;
    const char* message;
  } cases[] = {
      {"joint_eq.xml", "<equality><joint name='couple' joint1='ja' joint2='jb'/></equality>",
       "equality 'couple': only weld and connect equalities are read"},
      {"tendon_eq.xml",
       "<tendon><fixed name='ta'><joint joint='ja' coef='1'/></fixed>"
       "<fixed name='tb'><joint joint='jb' coef='1'/></fixed></tendon>"
       "<equality><tendon name='tie' tendon1='ta' tendon2='tb'/></equality>",
       "equality 'tie': only weld and connect equalities are read"},
      {"inactive_eq.xml",
       "<equality><connect name='pin' body1='a' body2='b' anchor='0.5 0 0' "
       "active='false'/></equality>",
       "equality 'pin' is inactive"},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(c.file);
    const fs::path xml = dir.path / c.file;
    std::ofstream(xml) << body << c.extra << "</mujoco>";
    std::string yaml = mjcf_scenario(xml);
    yaml.replace(yaml.find("[q]"), 3, "[qa, qb]");
    yaml.replace(yaml.find("q: [0]"), 6, "q: [0, 0]");
    try {
      (void)ukdyn::load_scenario_text(yaml, dir.path / "s.yaml");
      ADD_FAILURE() << "loaded";
    } catch (const std::exception& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find(c.message), std::string::npos) << what;
      EXPECT_NE(what.find(xml.string()), std::string::npos) << what;
      EXPECT_NE(what.find("s.yaml:"), std::string::npos) << what;
      EXPECT_NE(what.find("key 'subsystems[0].mjcf'"), std::string::npos) << what;
    }
  }
}

// Two iiwa 14 on platforms welded to the paper's load, dropped from rest with no torques: the
// welds hold, the energy is constant, and the start is symmetric under a half turn about the
// vertical through the load's centre, so the run stays so: both arms have the same coordinates
// (a base's x, y move along its mount's axes, and arm b's mount is turned by pi).
TEST(DocModels, TwoIiwaCarryTheLoad) {
  const auto sc =
      ukdyn::load_scenario(fs::path(UKDYN_SOURCE_DIR) / "scenarios" / "two_iiwa_load.yaml");
  const auto& names = sc.system->coordinate_names();
  ASSERT_EQ(names.size(), 27u);  // 2 × (x, y, yaw, q1..q7) + the load's 7
  ASSERT_EQ(names[0], "iiwa_a_x");
  ASSERT_EQ(names[10], "iiwa_b_x");
  const Samples s = run(sc);
  double sym = 0.0, moved = 0.0;
  for (std::size_t k = 0; k < s.t.size(); ++k) {
    const Vec& q = s.q[k];
    for (int i = 0; i < 10; ++i) sym = std::max(sym, std::abs(q[i] - q[10 + i]));
    moved = std::max(moved, std::abs(q[4] - sc.q0[4]));
  }
  EXPECT_LE(s.max_residual, 1e-12);
  EXPECT_LE(s.energy_drift, 1e-8);
  EXPECT_LE(sym, 1e-9);   // measured 2.8e-12 (4e-10 with a lighter load): the arms fold over
  EXPECT_GT(moved, 0.1);  // the arms do move: the load falls
  std::printf(
      "two iiwa: weld residual %.2e, |E - E0| %.2e J, symmetry %.2e, joint 2 moved %.3f rad\n",
      s.max_residual, s.energy_drift, sym, moved);
}

#ifdef UKDYN_TEST_HAVE_CLI
// `ukdyn linearize` of the cart-pole at the upright equilibrium: F = [[0, I], [A21, 0]],
// G = [[0], [M^-1]] with, for a point mass m on a massless pole of length l on a cart of mass M,
// ẍ = −(m g / M) θ + u / M, θ̈ = ((M + m) g θ − u) / (M l) for a force u on the cart (and the
// second column of G: a torque on the pole).
TEST(DocModelsCli, CartPoleLinearizeIsTheTextbookModel) {
  const fs::path scratch = ukdyn_test::process_scratch("ukdyn_doc_models_cli");
  const auto r = ukdyn_test::run_cli(
      UKDYN_CLI, scratch, "linearize " + ukdyn_test::sh((kModels / "cart_pole.yaml").string()));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  const double M = 1.5, m = 0.4, l = 0.6, g = 9.81;
  Mat F = Mat::Zero(4, 4), G = Mat::Zero(4, 2);
  F(0, 2) = F(1, 3) = 1.0;
  F(2, 1) = -m * g / M;
  F(3, 1) = (M + m) * g / (M * l);
  // M(q) at θ = 0: [[M + m, m l], [m l, m l²]]; its inverse is the input block.
  G(2, 0) = 1 / M;
  G(2, 1) = G(3, 0) = -1 / (M * l);
  G(3, 1) = (M + m) / (M * m * l * l);
  double worst = 0.0;
  for (int i = 0; i < 4; ++i) {
    for (int k = 0; k < 4; ++k)
      worst = std::max(worst, std::abs(j["F"][i][k].get<double>() - F(i, k)));
    for (int k = 0; k < 2; ++k)
      worst = std::max(worst, std::abs(j["G"][i][k].get<double>() - G(i, k)));
  }
  EXPECT_LE(worst, 1e-12);
  EXPECT_TRUE(j["derivatives"]["trusted"].get<bool>());
  std::printf("cart-pole: ukdyn linearize against the textbook F, G: %.2e\n", worst);
}
#endif

}  // namespace
