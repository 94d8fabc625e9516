// Simbody side by side: the paper's mechanism built with SimTK::MultibodySystem (the same bodies,
// joints, masses and inertias as bench/paper_mechanism.xml), timed with
// realize(state, Stage::Acceleration), its q̈ checked against ukdyn's forward(), and the constraint
// violation it holds over 4 s of free motion.
//
// This file is built apart (object library ukdyn_bench_simbody, bench/CMakeLists.txt):
//   - as C++17: Simbody 3.7's headers do not compile as C++20 (its index types compare through
//     implicit int conversions; C++20's reversed operator== candidates make every comparison of
//     two such indices ambiguous). So nothing of ukdyn (C++20) is included here: the parameters,
//     q0, q̇0, ukdyn's q̈ and closure residuals come through PaperMechanism (bench_common.hpp).
//   - WITHOUT NDEBUG: Debian builds Simbody 3.7 without NDEBUG, and Simbody's headers change inline
//     code with it (the State's cache-entry bookkeeping in SimTKcommon/internal/StateImpl.h, the
//     NaN fill of default-constructed Vec, ...); code including them with -DNDEBUG crashed in
//     realizeTopology.
//
// Model. Per robot, one mobilizer per paper coordinate, as the MJCF has one joint per coordinate:
//   Ground -Slider x-> frame (massless) -Slider y-> platform -Pin z-> base -Pin-> link 1 -Pin->
//   link 2 -Pin-> link 3 (= one half of the load; the cut point is its end).
// MuJoCo puts both slides on the platform body; Simbody has one mobilizer per body, so the x slide
// moves a massless frame (Body::Massless) that carries the y slide. Every mobilizer has q̇ = u, so
// q and u are the MJCF's qpos/qvel: per robot [x, y, yaw, pitch1, pitch2 - pitch1, pitch3 - pitch2]
// (relative pitch angles; the paper's θ are absolute). The pitch pins turn about the link's −y axis
// (F and M frames rotated by +90° about x, so that their z axis is the body's −y), so a positive
// angle lifts the link (+x towards +z) as in the paper. Masses and inertias come from ukdyn's
// MobileManipulatorParams (Table 1, through PaperMechanism): masses at mid-length, SPHERICAL
// central inertia I_k (see the MJCF header: with it the kinetic energy is the paper's ½ I_k (δ̇² +
// θ̇_k²)); base: m_r at half height, I_r; platform 50 (its inertia never enters, it does not
// rotate).
//
// Closure constraints, mirroring the MJCF (weld + two "load level" equalities):
//   - Constraint::Weld between the two load halves at the cut point (frame on link 3 of robot 2
//     turned by π about z, so the two frames coincide at q0): 3 positions + 3 orientations;
//   - one Constraint::ConstantAngle per robot holding link 3's x axis at 90° to the world z axis,
//     i.e. the load half level (θ3 = 0, θ6 = 0); the MJCF's fixed-tendon equality holds the sum of
//     the relative pitches instead, which is the same manifold (sin θ = 0 vs θ = 0 near θ = 0) with
//     the same velocity and acceleration rows at θ = 0. ConstantAngle is a built-in constraint; the
//     exact linear equivalent, a CoordinateCoupler, is a Constraint::Custom evaluated through
//     SimTK::Function (not measured here).
// That is 8 rows of rank 6, as in MuJoCo: the weld's relative-roll row is redundant for this
// mechanism (both halves only pitch about horizontal axes after a yaw), and its relative-pitch row
// is implied by the two level rows. Simbody solves redundant but consistent constraints (its
// multiplier solve is a rank-revealing least-squares factorisation, FactorQTZ);
// simbody_model_check() verifies that q̈ is ukdyn's and that the acceleration constraint errors
// vanish. (A non-redundant 6-row set, Ball + ConstantAngle for the yaw + the two level rows, gave
// the same q̈ and was about 15% faster in realize(Acceleration); kept out to mirror the MJCF.)
#include <Simbody.h>
#include <benchmark/benchmark.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <memory>
#include <string>
#include <vector>

#include "bench_common.hpp"

namespace ukbench {
namespace {

using Coords = std::array<double, 12>;

/// The Simbody system, its default state realized to Stage::Model, and where each paper coordinate
/// lives in q / u. Built once, on first use; a failure is kept in `error`.
struct SbModel {
  SimTK::MultibodySystem system;
  SimTK::SimbodyMatterSubsystem matter{system};
  SimTK::GeneralForceSubsystem forces{system};
  std::array<SimTK::MobilizedBody, 12> coordinate_body;  ///< per robot x, y, yaw, pitch1..3
  std::array<int, 12> qi{}, ui{};                        ///< q and u index of each of them
  std::array<SimTK::MobilizedBody, 2> load;              ///< link 3 of each robot
  std::array<SimTK::Vec3, 2> cut_station;                ///< the cut point on each link 3
  SimTK::State state;
  std::string error;
};

/// A rigid body of mass m with centre of mass com (body frame) and a spherical central inertia i.
SimTK::Body::Rigid rigid(double m, const SimTK::Vec3& com, double i) {
  using SimTK::Inertia;
  return SimTK::Body::Rigid(SimTK::MassProperties(m, com, Inertia(i).shiftFromMassCenter(-com, m)));
}

/// Adds robot r (0, 1): its 6 coordinate bodies from index 6 r, and its load half.
void add_robot(SbModel& m, const PaperMechanism::Arm& p, int r) {
  using namespace SimTK;
  const std::size_t o = static_cast<std::size_t>(6 * r);
  const Rotation x_to_y(Pi / 2, ZAxis);      // a slider along the parent's y axis
  const Rotation z_to_pitch(Pi / 2, XAxis);  // a pin about the body's −y axis
  MobilizedBody::Slider sx(m.matter.updGround(), Transform(), Body::Massless(), Transform());
  MobilizedBody::Slider sy(sx, Transform(x_to_y), rigid(p.platform_mass, Vec3(0), 1.0),
                           Transform(x_to_y));
  MobilizedBody::Pin base(sy, Transform(),
                          rigid(p.base_mass, Vec3(0, 0, p.base_length / 2), p.base_inertia),
                          Transform());
  m.coordinate_body[o + 0] = sx;
  m.coordinate_body[o + 1] = sy;
  m.coordinate_body[o + 2] = base;
  MobilizedBody parent = base;
  Vec3 joint(0, 0, p.base_length);  // link 1 is rooted l_r above the platform
  for (std::size_t k = 0; k < 3; ++k) {
    const double l = p.link_length[k];
    MobilizedBody::Pin link(parent, Transform(z_to_pitch, joint),
                            rigid(p.link_mass[k], Vec3(l / 2, 0, 0), p.link_inertia[k]),
                            Transform(z_to_pitch));
    m.coordinate_body[o + 3 + k] = link;
    parent = link;
    joint = Vec3(l, 0, 0);
  }
  m.load[static_cast<std::size_t>(r)] = parent;
  m.cut_station[static_cast<std::size_t>(r)] = joint;  // end of link 3
}

std::unique_ptr<SbModel> build_model() {
  using namespace SimTK;
  auto m = std::make_unique<SbModel>();
  try {
    const PaperMechanism& pm = paper_mechanism();
    add_robot(*m, pm.arm[0], 0);
    add_robot(*m, pm.arm[1], 1);
    Force::Gravity(m->forces, m->matter, Vec3(0, 0, -pm.gravity));

    // Weld frames: at q0 link 3 of robot 1 points along +x, link 3 of robot 2 (yaw −π) along −x.
    Constraint::Weld(m->load[0], Transform(m->cut_station[0]), m->load[1],
                     Transform(Rotation(Pi, ZAxis), m->cut_station[1]));
    for (MobilizedBody& half : m->load)
      Constraint::ConstantAngle(m->matter.updGround(), UnitVec3(0, 0, 1), half, UnitVec3(1, 0, 0),
                                Pi / 2);

    m->system.realizeTopology();
    m->state = m->system.getDefaultState();
    m->system.realizeModel(m->state);
    for (std::size_t i = 0; i < 12; ++i) {
      m->qi[i] = m->coordinate_body[i].getFirstQIndex(m->state);
      m->ui[i] = m->coordinate_body[i].getFirstUIndex(m->state);
    }
  } catch (const std::exception& e) {
    m->error = std::string("Simbody model: ") + e.what();
  }
  return m;
}

SbModel& model() {
  static const std::unique_ptr<SbModel> m = build_model();
  return *m;
}

/// Paper coordinates (absolute pitch angles) -> Simbody's relative pins; linear, so also for rates.
void paper_to_simbody(const Coords& q, const std::array<int, 12>& index, SimTK::Vector& out) {
  for (int r = 0; r < 2; ++r) {
    const int o = 6 * r;
    const auto i = [&](int k) { return index[static_cast<std::size_t>(o + k)]; };
    const auto p = [&](int k) { return q[static_cast<std::size_t>(o + k)]; };
    out[i(0)] = p(0);
    out[i(1)] = p(1);
    out[i(2)] = p(2);
    out[i(3)] = p(3);
    out[i(4)] = p(4) - p(3);
    out[i(5)] = p(5) - p(4);
  }
}

Coords simbody_to_paper(const SimTK::Vector& in, const std::array<int, 12>& index) {
  Coords q{};
  for (std::size_t o = 0; o < 12; o += 6) {
    const auto v = [&](std::size_t k) { return in[index[o + k]]; };
    q[o + 0] = v(0);
    q[o + 1] = v(1);
    q[o + 2] = v(2);
    q[o + 3] = v(3);
    q[o + 4] = q[o + 3] + v(4);
    q[o + 5] = q[o + 4] + v(5);
  }
  return q;
}

/// q and u of the paper's q0 with q̇0 (spatial or zero), in Simbody's order.
void initial_qu(const SbModel& m, bool spatial, SimTK::Vector& q, SimTK::Vector& u) {
  const PaperMechanism& pm = paper_mechanism();
  q = m.state.getQ();
  u = m.state.getU();
  paper_to_simbody(pm.q0, m.qi, q);
  paper_to_simbody(spatial ? pm.qd0_spatial : Coords{}, m.ui, u);
}

double max_abs(const SimTK::Vector& v) {
  double r = 0.0;
  for (int i = 0; i < v.size(); ++i) r = std::max(r, std::abs(v[i]));
  return r;
}

/// Integrates to time t. Integrator::stepTo() also returns control at other points (the first call
/// after initialize() returns at the start of the continuous interval, t = 0), so it is repeated
/// until the integrator's state is at t.
void advance_to(SimTK::Integrator& integ, double t) {
  while (integ.getTime() < t) integ.stepTo(t);
}

double cut_gap(const SbModel& m, const SimTK::State& s) {
  const SimTK::Vec3 d = m.load[0].findStationLocationInGround(s, m.cut_station[0]) -
                        m.load[1].findStationLocationInGround(s, m.cut_station[1]);
  return d.norm();
}

void bm_realize_acceleration(benchmark::State& state) {
  SbModel& m = model();
  SimTK::State s = m.state;
  SimTK::Vector q, u;
  initial_qu(m, true, q, u);
  const int before = m.system.getNumRealizationsOfThisStage(SimTK::Stage::Acceleration);
  for (auto _ : state) {
    // Writing q and u invalidates Stage::Position and everything above it, so realize() recomputes
    // kinematics, forces, articulated inertias, constraint multipliers and u̇ every iteration.
    s.updQ() = q;
    s.updU() = u;
    m.system.realize(s, SimTK::Stage::Acceleration);
    benchmark::DoNotOptimize(s.getUDot()[0]);
    benchmark::ClobberMemory();
  }
  const int after = m.system.getNumRealizationsOfThisStage(SimTK::Stage::Acceleration);
  state.counters["realize_per_iter"] =
      static_cast<double>(after - before) / static_cast<double>(state.iterations());
  state.counters["udot_err"] = max_abs(s.getUDotErr());
  state.counters["rows"] = s.getNMultipliers();
}

}  // namespace

SimbodyModelCheck simbody_model_check() {
  SimbodyModelCheck c;
  SbModel& m = model();
  if (!m.error.empty()) {
    c.error = m.error;
    return c;
  }
  try {
    const PaperMechanism& pm = paper_mechanism();
    SimTK::State s = m.state;
    SimTK::Vector q, u;
    initial_qu(m, true, q, u);
    s.updQ() = q;
    s.updU() = u;
    m.system.realize(s, SimTK::Stage::Acceleration);
    c.rows = s.getNMultipliers();
    c.q_err = max_abs(s.getQErr());
    c.u_err = max_abs(s.getUErr());
    c.udot_err = max_abs(s.getUDotErr());

    const Coords qdd = simbody_to_paper(s.getUDot(), m.ui);
    c.qdd_diff = c.qdd_max = 0.0;
    for (std::size_t i = 0; i < 12; ++i) {
      c.qdd_diff = std::max(c.qdd_diff, std::abs(qdd[i] - pm.qdd_spatial[i]));
      c.qdd_max = std::max(c.qdd_max, std::abs(pm.qdd_spatial[i]));
    }
  } catch (const std::exception& e) {
    c.error = std::string("Simbody: ") + e.what();
  }
  return c;
}

bool register_simbody_benchmarks() {
  const SbModel& m = model();
  if (!m.error.empty()) {
    std::fprintf(stderr, "ukdyn_bench: Simbody part skipped: %s\n", m.error.c_str());
    return false;
  }
  with_min_max(
      benchmark::RegisterBenchmark("simbody/realize_acceleration", bm_realize_acceleration))
      ->Unit(benchmark::kNanosecond);
  return true;
}

std::vector<ViolationRow> simbody_violation_rows(bool spatial,
                                                 const std::vector<double>& q_ref_05) {
  std::vector<ViolationRow> rows;
  SbModel& m = model();
  if (!m.error.empty()) return rows;
  const PaperMechanism& pm = paper_mechanism();
  const std::string start = spatial ? "spatial qd0" : "qd0 = 0";
  constexpr int kSamples = 4000;  // measured every 1 ms, as the ukdyn and MuJoCo rows
  constexpr double kDt = 1e-3;

  SimTK::State s0 = m.state;
  SimTK::Vector q, u;
  initial_qu(m, spatial, q, u);
  s0.updQ() = q;
  s0.updU() = u;

  // RK Merson (Simbody's usual explicit integrator, error-controlled, projecting onto the
  // constraint manifold when the error exceeds the constraint tolerance) at a common accuracy and
  // a tight one (1e-12, ukdyn's reference tolerance, took about 2.4-3.3 s per 4 s run, which made
  // every bench run 24 s longer; 1e-10 shows the trend). (CPodes/Adams at 1e-12 diverged to NaN
  // here; RK Feldberg at 1e-12 took 4-5x fewer steps than RK Merson but its q(0.5 s) was 50-90x
  // further from the reference.)
  for (const double accuracy : {1e-8, 1e-10}) {
    char setup[96];
    std::snprintf(setup, sizeof setup, "RK Merson acc %.0e", accuracy);
    ViolationRow row{"Simbody 3.7", setup, start, 0, 0, 0, -1};
    try {
      SimTK::RungeKuttaMersonIntegrator integ(m.system);
      integ.setAccuracy(accuracy);  // the constraint tolerance defaults to accuracy / 10
      integ.initialize(s0);
      SimTK::State probe;
      for (int k = 0; k <= kSamples; ++k) {
        if (k > 0) advance_to(integ, k * kDt);
        // The reported state (interpolated, then projected by default) realized to Position here.
        probe = integ.getState();
        m.system.realize(probe, SimTK::Stage::Position);
        row.max_gap = std::max(row.max_gap, cut_gap(m, probe));
        const Coords qp = simbody_to_paper(probe.getQ(), m.qi);
        row.max_phi = std::max(row.max_phi, pm.max_closure_residual(probe.getTime(), qp));
        if (k == 500 && q_ref_05.size() == 12) {
          double dq = 0;
          for (std::size_t i = 0; i < 12; ++i) dq = std::max(dq, std::abs(qp[i] - q_ref_05[i]));
          row.q_diff = dq;
        }
      }
      std::snprintf(setup, sizeof setup, "RK Merson acc %.0e ctol %.0e: %d steps", accuracy,
                    integ.getConstraintToleranceInUse(), integ.getNumStepsTaken());
      row.setup = setup;

      std::vector<double> ms;
      for (int rep = 0; rep < 3; ++rep) {
        SimTK::RungeKuttaMersonIntegrator timed(m.system);
        timed.setAccuracy(accuracy);
        const auto t0 = std::chrono::steady_clock::now();
        timed.initialize(s0);
        advance_to(timed, kSamples * kDt);
        const auto t1 = std::chrono::steady_clock::now();
        ms.push_back(std::chrono::duration<double, std::milli>(t1 - t0).count());
      }
      std::sort(ms.begin(), ms.end());
      row.wall_ms = ms[1];
    } catch (const std::exception& e) {
      std::string what = e.what();  // Simbody's messages span several lines
      std::replace(what.begin(), what.end(), '\n', ' ');
      row.setup += " (failed: " + what + ")";
    }
    rows.push_back(row);
  }
  return rows;
}

}  // namespace ukbench
