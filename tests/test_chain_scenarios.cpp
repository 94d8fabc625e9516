// Chains, constraint kinds and URDF arms loaded from scenarios (src/scenario/definitions_loader.cpp,
// src/robot_files/urdf.cpp): against the paper's hand-written definitions, and their error messages.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>

#include "helpers.hpp"
#include "ukdyn/symbolic/chain.hpp"
#include "ukdyn/symbolic/constraint_kinds.hpp"
#include "ukdyn/robot_files/urdf.hpp"

#ifdef UKDYN_HAVE_IO
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/simulate/simulate.hpp"
#endif

namespace {

using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;
namespace sym = ukdyn::symbolic;
using JT = sym::JointDef::Type;

using uktest::random_vec;
using uktest::rel;

#ifdef UKDYN_HAVE_IO

const std::string kDir = std::string(UKDYN_SOURCE_DIR) + "/scenarios/";

struct Three {
  ukdyn::Scenario exact = ukdyn::load_scenario(kDir + "paper_generic_exact_inertia.yaml");
  ukdyn::Scenario chain = ukdyn::load_scenario(kDir + "paper_chain.yaml");
  ukdyn::Scenario urdf = ukdyn::load_scenario(kDir + "paper_urdf.yaml");
};

// M, C q̇, C, G (the subsystems) and A, b, Φ, Φ̇ (the constraint kinds) at random states.
TEST(ChainPaper, ChainsAndKindsMatchHandWrittenDefinitions) {
  Three p;
  const auto& S0 = *p.exact.system;
  for (const ukdyn::Scenario* sc : {&p.chain, &p.urdf}) {
    const auto& S = *sc->system;
    ASSERT_EQ(S.coordinate_names(), S0.coordinate_names());
    ASSERT_EQ(S.constraint_row_names(), S0.constraint_row_names());
    EXPECT_LT((sc->q0 - p.exact.q0).norm(), 1e-15);
    const auto diff = uktest::compare_systems(S0, S, 300, 20240602);
    for (int i = 0; i < 9; ++i) {
      EXPECT_LE(diff.worst[i], 1e-12) << sc->name << " " << diff.names[i];
      std::printf("  %s vs hand-written: max relative difference %-4s %.2e\n", sc->name.c_str(),
                  diff.names[i], diff.worst[i]);
    }
  }
}

// q̈ and Qc: the closure only at random states, and all rows along the paper's motion.
TEST(ChainPaper, AccelerationsAndConstraintForcesMatch) {
  Three p;
  auto closure_only = [](const ukdyn::Scenario& sc, std::size_t blocks) {
    auto s = std::make_shared<ukdyn::System>();
    for (const auto& sub : sc.system->subsystems()) s->add_subsystem(sub);
    for (std::size_t i = 0; i < blocks; ++i) s->add_constraint(sc.system->constraints()[i]);
    return s;
  };
  const auto s0 = closure_only(p.exact, 1);
  std::vector<std::tuple<double, Vec, Vec>> states;
  ukdyn::SimulationSettings set = p.exact.sim;
  set.sample_dt = 0.05;
  const auto sim_run = ukdyn::simulate(
      *p.exact.system, p.exact.q0, p.exact.qd0,
      [](double, ukdyn::CVecRef, ukdyn::CVecRef, ukdyn::VecRef tau) { tau.setZero(); }, set,
      [&](double t, ukdyn::CVecRef q, ukdyn::CVecRef qd, const ukdyn::ForwardData&) {
        states.emplace_back(t, q, qd);
        return true;
      });
  ASSERT_EQ(sim_run.status, ukdyn::RunStatus::completed) << sim_run.message;
  ASSERT_GE(states.size(), 60u);
  for (const ukdyn::Scenario* sc : {&p.chain, &p.urdf}) {
    const auto s1 = closure_only(*sc, 4);  // points_coincide, angle_relation, 2 × coordinate
    ASSERT_EQ(s1->constraint_row_names(), s0->constraint_row_names());
    std::mt19937_64 rng(77);
    double wq = 0, wc = 0;
    ukdyn::ForwardData d0(*s0), d1(*s1);
    for (int k = 0; k < 300; ++k) {
      const Vec q = random_vec(rng, 12, -3.2, 3.2), qd = random_vec(rng, 12, -2, 2),
                tau = random_vec(rng, 12, -20, 20);
      ukdyn::forward(*s0, d0, 0.0, q, qd, tau, p.exact.sim.uk);
      ukdyn::forward(*s1, d1, 0.0, q, qd, tau, sc->sim.uk);
      wq = std::max(wq, rel(d1.qdd, d0.qdd));
      wc = std::max(wc, rel(d1.Qc, d0.Qc));
    }
    EXPECT_LE(wq, 1e-12);
    EXPECT_LE(wc, 1e-12);
    std::printf("  %s closure only, 300 random states: max rel. difference qdd %.2e, Qc %.2e\n",
                sc->name.c_str(), wq, wc);
    ukdyn::ForwardData e0(*p.exact.system), e1(*sc->system);
    wq = wc = 0;
    for (const auto& [t, q, qd] : states) {
      ukdyn::forward(*p.exact.system, e0, t, q, qd, Vec::Zero(12), p.exact.sim.uk);
      ukdyn::forward(*sc->system, e1, t, q, qd, Vec::Zero(12), sc->sim.uk);
      wq = std::max(wq, rel(e1.qdd, e0.qdd));
      wc = std::max(wc, rel(e1.Qc, e0.Qc));
    }
    EXPECT_LE(wq, 1e-12);
    EXPECT_LE(wc, 1e-12);
    std::printf("  %s all 12 rows along the motion (%zu states): qdd %.2e, Qc %.2e\n",
                sc->name.c_str(), states.size(), wq, wc);
  }
}

std::string error_of(const std::string& text, const std::string& file = "s.yaml") {
  try {
    (void)ukdyn::load_scenario_text(text, file);
  } catch (const ukdyn::ScenarioError& e) {
    return e.what();
  }
  return "";
}

std::string chain_scenario(const std::string& chain_body, const std::string& constraints = "") {
  return "ukdyn: 1\nname: c\nsubsystems:\n"
         "  - name: arm\n    type: serial_chain\n    coordinates: [a, b]\n" +
         chain_body + constraints +
         "initial: {q: [0.1, 0.2]}\nsimulation: {t_end: 1, sample_dt: 0.1}\n";
}

const std::string kTwoLinks =
    "    joints:\n"
    "      - {name: j1, type: revolute, link: l1, axis: [0, 1, 0], coordinate: a, mass: 1, com: "
    "[1, 0, 0]}\n"
    "      - {name: j2, type: revolute, link: l2, origin: {xyz: [1, 0, 0]}, axis: [0, 1, 0], "
    "coordinate: b, mass: 1, com: [1, 0, 0]}\n"
    "    points: {tip: {link: l2, xyz: [1, 0, 0]}}\n";

TEST(ChainScenario, ErrorsNameTheElement) {
  EXPECT_EQ(error_of(chain_scenario(kTwoLinks)), "");
  std::string e = error_of(chain_scenario(
      kTwoLinks, "constraints:\n  - {type: points_coincide, name: c, a: arm.tip, b: arm.nope}\n"));
  EXPECT_NE(e.find("no point 'nope'"), std::string::npos) << e;
  EXPECT_NE(e.find("s.yaml:"), std::string::npos) << e;
  e = error_of(chain_scenario(
      kTwoLinks, "constraints:\n  - {type: points_coincide, name: c, a: arm.tip, b: other.end}\n"));
  EXPECT_NE(e.find("no serial_chain subsystem named 'other'"), std::string::npos) << e;
  e = error_of(chain_scenario(
      kTwoLinks, "constraints:\n  - {type: angle_relation, name: c, terms: {a: 1, z: 2}}\n"));
  EXPECT_NE(e.find("no coordinate named 'z'"), std::string::npos) << e;
  e = error_of(chain_scenario(
      "    joints:\n      - {name: j1, type: spherical, link: l1, coordinate: a, mass: 1}\n"));
  EXPECT_NE(e.find("unknown joint type 'spherical'"), std::string::npos) << e;
  e = error_of(chain_scenario(
      "    joints:\n      - {name: j1, type: revolute, link: l1, coordinate: c, mass: 1}\n"));
  EXPECT_NE(e.find("'c' is not a coordinate"), std::string::npos) << e;
  // A point trajectory and a points_coincide on one chain load and have the expected rows.
  const auto sc = ukdyn::load_scenario_text(
      chain_scenario(
          kTwoLinks,
          "constraints:\n"
          "  - {type: point_trajectory, name: p, point: arm.tip, origin: initial, "
          "x: {type: polynomial, coefficients: [0, 0, 0.1]}}\n"
          "  - {type: points_coincide, name: q, a: arm.l2, b: [0, 0, -sin(0.1)], axes: [z]}\n"
          "  - {type: angle_relation, name: s, terms: {b: 1}, value: {type: spline, "
          "times: [0, 1, 2], values: [0.2, 0.5, 0.3], end: clamped}}\n"),
      "s.yaml");
  EXPECT_EQ(sc.system->constraint_row_names(), (std::vector<std::string>{"p_x", "q_z", "s"}));
  Vec phi(3);
  ukdyn::position_residuals(*sc.system, 0.0, sc.q0, phi);
  EXPECT_NEAR(phi(0), 0.0, 1e-15);  // origin: initial
  EXPECT_NEAR(phi(2), 0.0, 1e-15);  // the spline starts at b = 0.2
  e = error_of(chain_scenario(
      kTwoLinks,
      "constraints:\n  - {type: angle_relation, name: s, terms: {b: 1}, value: {type: "
      "spline, times: [0, 0], values: [0.2, 0.5]}}\n"));
  EXPECT_NE(e.find("spline times must increase strictly"), std::string::npos) << e;
}

TEST(ChainUrdf, ErrorsNameTheFileAndElement) {
  if (!sym::urdf_supported()) GTEST_SKIP() << "built without urdfdom";
  const auto dir = std::filesystem::temp_directory_path() / "ukdyn_chain_urdf_test";
  std::filesystem::create_directories(dir);
  auto write = [&](const std::string& name, const std::string& joint_type,
                   bool inertial) -> std::string {
    const auto path = (dir / name).string();
    std::ofstream(path) << "<robot name='r'><link name='base'/>"
                           "<joint name='bad_joint' type='"
                        << joint_type
                        << "'><parent link='base'/><child link='arm'/><axis xyz='0 0 1'/>"
                           "<limit lower='-1' upper='1' effort='1' velocity='1'/></joint>"
                           "<link name='arm'>"
                        << (inertial ? "<inertial><mass value='1'/><inertia ixx='0.1' ixy='0' "
                                       "ixz='0' iyy='0.1' iyz='0' izz='0.1'/></inertial>"
                                     : "")
                        << "</link></robot>";
    return path;
  };
  auto err = [](const std::string& urdf) {
    try {
      sym::ChainDef c("c", {"a"});
      sym::append_urdf(c, urdf);
      (void)sym::build_chain(c);
    } catch (const sym::DefinitionError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  const std::string ok = write("ok.urdf", "revolute", true);
  EXPECT_EQ(err(ok), "");
  const std::string floating = write("floating.urdf", "floating", true);
  std::string e = err(floating);
  EXPECT_NE(e.find(floating), std::string::npos) << e;
  // Floating joints are read (7 coordinates, docs/free-bodies.md); this chain has one.
  EXPECT_NE(e.find("joint 'bad_joint': a floating joint needs 7 coordinates"), std::string::npos)
      << e;
  const std::string planar = write("planar.urdf", "planar", true);
  EXPECT_NE(err(planar).find("type planar is not supported"), std::string::npos);
  // A link without <inertial> is massless (optional in the URDF specification): read, no body.
  const std::string noin = write("noin.urdf", "revolute", false);
  EXPECT_EQ(err(noin), "");
  {
    sym::ChainDef c("c", {"a"});
    sym::append_urdf(c, noin);
    EXPECT_TRUE(sym::build_chain(c).def.bodies.empty());
  }
  e = err((dir / "missing.urdf").string());
  EXPECT_NE(e.find("no such URDF file"), std::string::npos) << e;
  { std::ofstream(dir / "garbage.urdf") << "<robot><link"; }
  e = err((dir / "garbage.urdf").string());
  EXPECT_NE(e.find("garbage.urdf: urdfdom could not read"), std::string::npos) << e;
  // Through a scenario: the error points at the urdf key.
  e = error_of(
      "ukdyn: 1\nname: c\nsubsystems:\n  - name: arm\n    type: serial_chain\n"
      "    coordinates: [a]\n    urdf: " +
      planar + "\ninitial: {q: [0]}\nsimulation: {t_end: 1, sample_dt: 0.1}\n");
  EXPECT_NE(e.find("s.yaml:7:"), std::string::npos) << e;
  EXPECT_NE(e.find("type planar is not supported"), std::string::npos) << e;
  std::filesystem::remove_all(dir);
}

// Joint origin rpy and inertial rpy in a URDF: a joint frame turned by Rx(pi/2) with axis z is a
// joint about -y; an inertia frame turned by Rz(pi/2) swaps the x and y moments.
TEST(ChainUrdf, OriginAndInertialRotations) {
  if (!sym::urdf_supported()) GTEST_SKIP() << "built without urdfdom";
  const auto path = (std::filesystem::temp_directory_path() / "ukdyn_chain_rpy.urdf").string();
  std::ofstream(path) << R"(<robot name="r"><link name="base"/>
    <joint name="j" type="revolute"><parent link="base"/><child link="arm"/>
      <origin xyz="0 0 0.5" rpy="1.5707963267948966 0 0"/><axis xyz="0 0 1"/>
      <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
    <link name="arm"><inertial><origin xyz="0.6 0 0" rpy="0 0 1.5707963267948966"/>
      <mass value="2"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.3" iyz="0" izz="0.7"/>
    </inertial></link></robot>)";
  sym::ChainDef u("u", {"q"});
  u.gravity = {0, 0, -10};
  sym::append_urdf(u, path);
  // The same by hand: axis -y, CoM (0.6, 0, 0), moments: Rz swaps x, y: diag(0.3, 0.1, 0.7);
  // then Rx(pi/2) swaps y, z of that: diag(0.3, 0.7, 0.1).
  sym::ChainDef h("h", {"q"});
  h.gravity = {0, 0, -10};
  auto& j = h.add_joint("j", JT::revolute, "arm");
  j.origin.xyz = {0, 0, sym::exact_number(0.5)};
  j.axis = {0, -1, 0};
  j.coordinate = "q";
  j.inertial.mass = 2;
  j.inertial.com = {sym::exact_number(0.6), 0, 0};
  j.inertial.inertia = {sym::exact_number(0.3), 0, 0, 0, sym::exact_number(0.7), 0, 0, 0,
                        sym::exact_number(0.1)};
  const auto su = sym::make_subsystem(sym::build_chain(u).def);
  const auto sh = sym::make_subsystem(sym::build_chain(h).def);
  for (double a : {-2.0, -0.3, 0.4, 1.9}) {
    Vec q(1), qd(1);
    q << a;
    qd << 0.7;
    Mat Mu(1, 1), Mh(1, 1);
    Vec gu(1), gh(1);
    su->mass({}, q, Mu);
    sh->mass({}, q, Mh);
    su->gravity({}, q, gu);
    sh->gravity({}, q, gh);
    EXPECT_NEAR(Mu(0, 0), Mh(0, 0), 1e-14);
    EXPECT_NEAR(Mu(0, 0), 2 * 0.36 + 0.7, 1e-14);  // about y: m d^2 + I_yy
    EXPECT_NEAR(gu(0), gh(0), 1e-13);
  }
  std::filesystem::remove(path);
}

// The URDF arm, the YAML serial chain and the hand-written definitions: one arm, three sources.
TEST(ChainUrdf, PaperArmFromUrdfMatchesChain) {
  if (!sym::urdf_supported()) GTEST_SKIP() << "built without urdfdom";
  Three p;
  const auto& a = *p.urdf.system->subsystems()[0];
  const auto& b = *p.chain.system->subsystems()[0];
  const auto& c = *p.exact.system->subsystems()[0];
  std::mt19937_64 rng(11);
  double worst = 0;
  for (int k = 0; k < 200; ++k) {
    const Vec q = random_vec(rng, 6, -3.2, 3.2), qd = random_vec(rng, 6, -3, 3);
    Mat Ma(6, 6), Mb(6, 6), Mc(6, 6);
    Vec ga(6), gb(6), gc(6), ca(6), cb(6), cc(6);
    a.mass({}, q, Ma), b.mass({}, q, Mb), c.mass({}, q, Mc);
    a.gravity({}, q, ga), b.gravity({}, q, gb), c.gravity({}, q, gc);
    a.coriolis_times_qd({}, q, qd, ca), b.coriolis_times_qd({}, q, qd, cb), c.coriolis_times_qd({}, q, qd, cc);
    worst = std::max(
        {worst, rel(Ma, Mc), rel(Mb, Mc), rel(ga, gc), rel(gb, gc), rel(ca, cc), rel(cb, cc)});
  }
  EXPECT_LE(worst, 1e-12);
  std::printf("  left arm: URDF, serial_chain vs hand-written: max relative difference %.2e\n",
              worst);
}

#endif  // UKDYN_HAVE_IO

}  // namespace
