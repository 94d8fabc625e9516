// N planar arms carrying one rigid load, from definitions (tests/test_uk_arrow.cpp,
// tests/test_no_alloc.cpp, bench/bench_arrow.cpp): the block-arrow structure of cooperative
// transport. Robot k is a 3R arm in the vertical x–z plane (coordinates r<k>_t1..t3, link lengths
// 0.5, 0.4, 0.3, masses 2, 1.5, 1, slender-rod inertias) mounted at radius 1.2 around the origin at
// angle α_k = 2πk/N; the load (L_x, L_z, L_phi: mass 3, inertia 0.2) is grasped by each arm's tip
// at the load point 0.3 from its centre at angle α_k (2 rows per robot: tip = grasp point). With
// N ≥ 2 the grasps are redundant (2N rows on 3 load coordinates). tools/n_robots.py writes the same
// model as a scenario with `instances:` (tests/test_uk_arrow.cpp compares the two).
#pragma once

#include <cmath>
#include <memory>
#include <numbers>
#include <string>
#include <vector>

#include "ukdyn/model/system.hpp"
#include "ukdyn/symbolic/definitions.hpp"

namespace uktest {

struct NRobotsOptions {
  int robots = 3;
  /// Robot 0 has a single link (1 joint) for its 2 grasp rows: its S_k is rank 1, one row goes to
  /// the load (uk_arrow.hpp).
  bool one_link_robot = false;
  /// Robot 0's grasp rows added a second time (exactly redundant rows).
  bool duplicate_grasp = false;
  /// A row on the load alone: L_phi = 0.1 sin(t).
  bool load_row = false;
  /// A row on robot 0 alone: r0_t1 = 0.2 t (if robot 0 has 3 links).
  bool robot_row = false;
  /// One more arm that nothing constrains.
  bool free_robot = false;
  /// The grasps compiled into the arms' TapePool (numbers as inputs, one program for grasps
  /// 1..N−1); false: each grasp its own tape with its numbers in it.
  bool share_tapes = true;
};

inline std::string n_robots_num(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "(%.17g)", v);
  return buf;
}

inline std::shared_ptr<ukdyn::System> n_robots_system(const NRobotsOptions& o) {
  namespace sym = ukdyn::symbolic;
  const double l[3] = {0.5, 0.4, 0.3}, m[3] = {2.0, 1.5, 1.0};
  auto system = std::make_shared<ukdyn::System>();
  // The arms share their tapes, as the instances of a scenario do, and so do the grasps of robots
  // 1..N−1 (their numbers are inputs; robot 0's grasp angle 0 leaves a term out of its rows).
  sym::TapePool tapes;
  std::vector<std::string> all;
  const int arms = o.robots + (o.free_robot ? 1 : 0);
  std::vector<int> links(static_cast<std::size_t>(arms), 3);
  if (o.one_link_robot) links[0] = 1;
  auto alpha = [&](int k) { return 2.0 * std::numbers::pi * k / o.robots; };
  // Tip position of arm k as strings (x, z).
  std::vector<std::string> tip_x, tip_z;
  for (int k = 0; k < arms; ++k) {
    const std::string p = "r" + std::to_string(k) + "_";
    std::vector<std::string> q;
    for (int i = 0; i < links[static_cast<std::size_t>(k)]; ++i)
      q.push_back(p + "t" + std::to_string(i + 1));
    sym::SubsystemDef d("robot" + std::to_string(k), q);
    const double bx = 1.2 * std::cos(alpha(k)), bz = 1.2 * std::sin(alpha(k));
    std::string ax = n_robots_num(bx), az = n_robots_num(bz), angle;
    for (std::size_t i = 0; i < q.size(); ++i) {
      angle += (i ? "+" : "") + q[i];
      const std::string c = "cos(" + angle + ")", s = "sin(" + angle + ")";
      auto& body = d.add_body("link" + std::to_string(i + 1));
      body.mass = m[i];
      body.com = {d.parse(ax + "+" + n_robots_num(l[i] / 2) + "*" + c), 0,
                  d.parse(az + "+" + n_robots_num(l[i] / 2) + "*" + s)};
      body.inertia_kind = sym::BodyDef::InertiaKind::scalar;
      body.inertia_scalar = m[i] * l[i] * l[i] / 12.0;
      std::string w;
      for (std::size_t j = 0; j <= i; ++j) w += (j ? "+" : "") + q[j] + "_dot";
      body.angular_velocity = std::array<GiNaC::ex, 3>{0, d.parse(w), 0};
      ax += "+" + n_robots_num(l[i]) + "*" + c;
      az += "+" + n_robots_num(l[i]) + "*" + s;
    }
    d.gravity = {0, 0, -9.81};
    system->add_subsystem(sym::make_subsystem(d, sym::Deadline(), &tapes));
    tip_x.push_back(ax);
    tip_z.push_back(az);
    all.insert(all.end(), q.begin(), q.end());
  }
  {
    sym::SubsystemDef d("load", {"L_x", "L_z", "L_phi"});
    auto& body = d.add_body("load");
    body.mass = 3.0;
    body.com = {d.q("L_x"), 0, d.q("L_z")};
    body.inertia_kind = sym::BodyDef::InertiaKind::scalar;
    body.inertia_scalar = 0.2;
    body.angular_velocity = std::array<GiNaC::ex, 3>{0, d.qd("L_phi"), 0};
    d.gravity = {0, 0, -9.81};
    system->add_subsystem(sym::make_subsystem(d));
    all.insert(all.end(), {"L_x", "L_z", "L_phi"});
  }
  auto grasp = [&](int k, const std::string& name) {
    sym::ConstraintDef c(name, sym::ConstraintDef::Kind::holonomic, all);
    const std::string a = n_robots_num(alpha(k));
    c.add_row(name + "_x",
              c.parse(tip_x[static_cast<std::size_t>(k)] + "-(L_x+0.3*cos(L_phi+" + a + "))"));
    c.add_row(name + "_z",
              c.parse(tip_z[static_cast<std::size_t>(k)] + "-(L_z+0.3*sin(L_phi+" + a + "))"));
    system->add_constraint(sym::make_constraint(c, o.share_tapes ? &tapes : nullptr));
  };
  for (int k = 0; k < o.robots; ++k) grasp(k, "grasp" + std::to_string(k));
  if (o.duplicate_grasp) grasp(0, "grasp0_again");
  if (o.load_row) {
    sym::ConstraintDef c("tilt", sym::ConstraintDef::Kind::holonomic, all);
    c.add_row("tilt", c.parse("L_phi-0.1*sin(t)"));
    system->add_constraint(sym::make_constraint(c));
  }
  if (o.robot_row && links[0] == 3) {
    sym::ConstraintDef c("drive", sym::ConstraintDef::Kind::holonomic, all);
    c.add_row("drive", c.parse("r0_t1-0.2*t"));
    system->add_constraint(sym::make_constraint(c));
  }
  return system;
}

}  // namespace uktest
