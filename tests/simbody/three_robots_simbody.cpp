// scenarios/n_robots_3_weld.yaml built in Simbody 3.7 ([Sherman2011]), for
// tests/test_simbody_three_robots.cpp: three 6-DoF robots welded to a free-body load, q̈ from
// realize(Stage::Acceleration) (Simbody's own O(n) articulated-body recursion and its multiplier
// solve), nothing shared with ukdyn's derivation but the mechanism's numbers.
//
// Built apart, as bench/bench_simbody.cpp (object library ukdyn_test_simbody,
// tests/CMakeLists.txt): C++17 (Simbody 3.7's headers do not compile as C++20: C++20's reversed
// operator== candidates make comparisons of its index types ambiguous), so no ukdyn header is
// included (the interface is the plain struct of three_robots_simbody.hpp); and WITHOUT NDEBUG
// (Debian builds Simbody without it, and its headers change inline code with it: code including
// them with -DNDEBUG crashed in realizeTopology).
//
// Model, per robot k (one mobilizer per ukdyn coordinate, each with q̇ = u):
//   Ground -Slider-> cx (4 kg) -Slider-> cy (3 kg) -Slider-> cz (2 kg) -Pin-> wl1 -Pin-> wl2 -Pin->
//   hand
// Simbody's Slider moves along its F frame's x axis and the Pin turns about its z axis; the F and
// M frames of each mobilizer are rotated alike (x -> y, x -> z, z -> y, z -> x), so every body
// frame stays parallel to its parent's at q = 0, as ukdyn's serial_chain links with no joint
// origin. The first slider's F frame is the mount: (cos a_k, sin a_k, 0), yawed by a_k + π. Masses,
// centres of mass and central inertias are the scenario's (the carriages are point masses, the hand
// has its CoM 0.05 m out on x). The load is a MobilizedBody::Free (quaternion + position of its
// CoM, u = angular velocity and CoM velocity in Ground), 3 kg, central inertia diag(0.05, 0.06,
// 0.08). Each hand's tool frame (0.1, 0, 0) is held to the load's grasp frame by a Constraint::Weld
// (6 rows). Gravity (0, 0, −9.81) acts on the load only: the scenario's robots are
// gravity-compensated (gravity [0, 0, 0] on the arm subsystem), so Force::Gravity excludes every
// robot body (setDefaultBodyIsExcluded).
#include "three_robots_simbody.hpp"

#include <Simbody.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <exception>
#include <vector>

namespace ukdyn_simbody_test {

struct ThreeRobots::Impl {
  SimTK::MultibodySystem system;
  SimTK::SimbodyMatterSubsystem matter{system};
  SimTK::GeneralForceSubsystem forces{system};
  std::vector<SimTK::MobilizedBody> joint;  ///< 6 per robot, in ukdyn's coordinate order
  SimTK::MobilizedBody::Free load;
  SimTK::State state;
  std::string error;
};

namespace {

SimTK::Body::Rigid rigid(double m, const SimTK::Vec3& com, const SimTK::Inertia& central) {
  // MassProperties takes the inertia about the body origin: shift the central one by −com.
  return SimTK::Body::Rigid(SimTK::MassProperties(m, com, central.shiftFromMassCenter(-com, m)));
}

double max_abs(const SimTK::Vector& v) {
  double r = 0.0;
  for (int i = 0; i < v.size(); ++i) r = std::max(r, std::abs(v[i]));
  return r;
}

}  // namespace

ThreeRobots::ThreeRobots() : impl_(std::make_unique<Impl>()) {
  using namespace SimTK;
  Impl& m = *impl_;
  try {
    const Rotation x_to_y(Pi / 2, ZAxis), x_to_z(-Pi / 2, YAxis);  // Slider axis x -> y, z
    const Rotation z_to_y(-Pi / 2, XAxis), z_to_x(Pi / 2, YAxis);  // Pin axis z -> y, x
    const Vec3 zero(0);
    Force::Gravity gravity(m.forces, m.matter, Vec3(0, 0, -kGravity));
    m.load = MobilizedBody::Free(
        m.matter.updGround(), Transform(),
        rigid(kLoadMass, zero, Inertia(kLoadInertia[0], kLoadInertia[1], kLoadInertia[2])),
        Transform());
    for (int k = 0; k < kRobots; ++k) {
      const double a = robot_angle(k);
      const Transform mount(Rotation(a + Pi, ZAxis),
                            Vec3(kMountRadius * std::cos(a), kMountRadius * std::sin(a), 0));
      MobilizedBody::Slider cx(m.matter.updGround(), mount, rigid(4, zero, Inertia(0)),
                               Transform());
      MobilizedBody::Slider cy(cx, Transform(x_to_y), rigid(3, zero, Inertia(0)),
                               Transform(x_to_y));
      MobilizedBody::Slider cz(cy, Transform(x_to_z), rigid(2, zero, Inertia(0)),
                               Transform(x_to_z));
      MobilizedBody::Pin w1(cz, Transform(), rigid(0.3, zero, Inertia(0.002, 0.002, 0.003)),
                            Transform());
      MobilizedBody::Pin w2(w1, Transform(z_to_y), rigid(0.3, zero, Inertia(0.002, 0.003, 0.002)),
                            Transform(z_to_y));
      MobilizedBody::Pin hand(w2, Transform(z_to_x),
                              rigid(0.5, Vec3(0.05, 0, 0), Inertia(0.003, 0.002, 0.002)),
                              Transform(z_to_x));
      for (const MobilizedBody& b : {MobilizedBody(cx), MobilizedBody(cy), MobilizedBody(cz),
                                     MobilizedBody(w1), MobilizedBody(w2), MobilizedBody(hand)}) {
        m.joint.push_back(b);
        gravity.setDefaultBodyIsExcluded(b.getMobilizedBodyIndex(), true);
      }
      const Transform grasp(Rotation(a + Pi, ZAxis),
                            Vec3(kGraspRadius * std::cos(a), kGraspRadius * std::sin(a), 0));
      Constraint::Weld(hand, Transform(Vec3(kTool, 0, 0)), m.load, grasp);
    }
    m.system.realizeTopology();
    m.state = m.system.getDefaultState();
    m.system.realizeModel(m.state);
  } catch (const std::exception& e) {
    m.error = std::string("Simbody model: ") + e.what();
  }
}

ThreeRobots::~ThreeRobots() = default;

const std::string& ThreeRobots::build_error() const { return impl_->error; }

Accelerations ThreeRobots::accelerations(const State& s) {
  using namespace SimTK;
  Impl& m = *impl_;
  Accelerations out;
  if (!m.error.empty()) {
    out.error = m.error;
    return out;
  }
  try {
    SimTK::State& st = m.state;
    for (std::size_t i = 0; i < m.joint.size(); ++i) {
      m.joint[i].setOneQ(st, 0, s.q[i]);
      m.joint[i].setOneU(st, 0, s.qd[i]);
    }
    const auto& p = s.load_position;
    const auto& e = s.load_quaternion;
    m.load.setQToFitTransform(
        st, Transform(Rotation(Quaternion(e[0], e[1], e[2], e[3])), Vec3(p[0], p[1], p[2])));
    const auto& w = s.load_angular_velocity;
    const auto& v = s.load_velocity;
    m.load.setUToFitVelocity(st, SpatialVec(Vec3(w[0], w[1], w[2]), Vec3(v[0], v[1], v[2])));
    m.system.realize(st, Stage::Acceleration);
    for (std::size_t i = 0; i < m.joint.size(); ++i) out.qdd[i] = m.joint[i].getOneUDot(st, 0);
    const Vec3& a = m.load.getBodyOriginAcceleration(st);  // the body origin is the CoM
    const Vec3& b = m.load.getBodyAngularAcceleration(st);
    for (int i = 0; i < 3; ++i) {
      out.load_acceleration[static_cast<std::size_t>(i)] = a[i];
      out.load_angular_acceleration[static_cast<std::size_t>(i)] = b[i];
    }
    out.position_error = max_abs(st.getQErr());
    out.velocity_error = max_abs(st.getUErr());
    out.constraint_acceleration_error = max_abs(st.getUDotErr());
  } catch (const std::exception& ex) {
    out.error = std::string("Simbody realize: ") + ex.what();
  }
  return out;
}

}  // namespace ukdyn_simbody_test
