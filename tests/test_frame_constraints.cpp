// Constraints between frames (ukdyn/symbolic/frame_constraints.hpp), the split of Qc into the
// force of each block and the internal wrench on a grasped load (ukdyn/core/constraint_forces.hpp),
// against independent evidence: finite differences of Φ, a rigid attachment modelled as one body,
// the closed-form pendulum, Newton's law for the welded body, the weld rows' singular values in
// closed form, zero work of ideal constraints, and the internal-force identities.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <Eigen/LU>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <random>
#include <sstream>

#include "helpers.hpp"
#include "symbolic/numeric_frame_lanes.hpp"
#include "ukdyn/core/constraint_forces.hpp"
#include "ukdyn/model/system.hpp"
#include "ukdyn/symbolic/chain.hpp"
#include "ukdyn/symbolic/constraint_kinds.hpp"
#include "ukdyn/symbolic/frame_constraints.hpp"
#include "ukdyn/symbolic/free_body.hpp"
#include "ukdyn/symbolic/numeric_frame_constraint.hpp"
#ifdef UKDYN_HAVE_IO
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/simulate/simulate.hpp"
#endif

namespace {

using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;
using ukdyn::Vec3;
namespace sym = ukdyn::symbolic;
using K = sym::FrameConstraintDef::Kind;
using uktest::random_vec;

constexpr double kG = 9.81;

// A rigid body in position + roll-pitch-yaw coordinates <p>x, <p>y, <p>z, <p>r, <p>p, <p>w, with
// its CoM at the position and a diagonal inertia in the body frame.
// `symbols`: the table of the system the body is part of (shared with its constraints).
sym::SubsystemDef rigid_body(const std::shared_ptr<sym::SymbolTable>& symbols,
                             const std::string& name, const std::string& p, double m,
                             std::array<double, 3> I, double g = kG) {
  sym::SubsystemDef d(name, {p + "x", p + "y", p + "z", p + "r", p + "p", p + "w"}, symbols);
  auto& b = d.add_body(name);
  b.mass = sym::exact_number(m);
  b.com = {d.q(p + "x"), d.q(p + "y"), d.q(p + "z")};
  b.rotation = sym::rpy_rotation({d.q(p + "r"), d.q(p + "p"), d.q(p + "w")});
  b.inertia_kind = sym::BodyDef::InertiaKind::tensor;
  b.inertia_tensor = {sym::exact_number(I[0]), 0, 0, 0, sym::exact_number(I[1]), 0, 0, 0,
                      sym::exact_number(I[2])};
  d.gravity = {0, 0, sym::exact_number(-g)};
  return d;
}

sym::FrameConstraintDef frame_def(K kind, const std::string& name, const sym::FrameTable& t,
                                  const std::string& a, const std::string& b,
                                  const sym::OriginDef& oa = {}, const sym::OriginDef& ob = {}) {
  sym::FrameConstraintDef f;
  f.kind = kind;
  f.name = name;
  f.frame_a = a;
  f.frame_b = b;
  f.a = sym::offset_frame(t.find(a), oa);
  f.b = sym::offset_frame(t.find(b), ob);
  return f;
}

std::vector<std::string> concat(const std::vector<std::string>& a,
                                const std::vector<std::string>& b) {
  std::vector<std::string> r = a;
  r.insert(r.end(), b.begin(), b.end());
  return r;
}

// ------------------------------------------------------------------------------ A against Φ

// Every kind, between two rigid bodies with offsets on both frames: A = ∂Φ/∂q by central
// differences of the compiled Φ, and Φ̇ = G_a J_a q̇ + G_b J_b q̇ = A q̇ (the wrench maps).
TEST(FrameConstraints, JacobianMatchesFiniteDifferencesOfPhi) {
  const auto symbols = std::make_shared<sym::SymbolTable>();  // this system's
  const auto b1 = rigid_body(symbols, "one", "a", 2.0, {0.1, 0.2, 0.3});
  const auto b2 = rigid_body(symbols, "two", "b", 3.0, {0.3, 0.2, 0.4});
  sym::FrameTable t;
  t.add_bodies(b1);
  t.add_bodies(b2);
  const auto coords = concat(b1.coordinates(), b2.coordinates());
  const sym::OriginDef oa{
      {sym::exact_number(0.3), sym::exact_number(-0.2), sym::exact_number(0.1)},
      {sym::exact_number(0.2), sym::exact_number(-0.4), sym::exact_number(0.7)}};
  const sym::OriginDef ob{{sym::exact_number(-0.5), 0, sym::exact_number(0.25)},
                          {0, sym::exact_number(0.3), 0}};
  std::mt19937_64 rng(11);
  for (K kind : {K::weld, K::ball, K::hinge, K::level, K::distance}) {
    auto f = frame_def(kind, "c", t, "one.one", kind == K::level ? "world" : "two.two", oa, ob);
    f.axis = {1, 2, 2};
    f.length = sym::exact_number(0.8);
    sym::ConstraintDef def("c", sym::ConstraintDef::Kind::holonomic, coords, symbols);
    sym::add_frame_constraint(def, f);
    const auto c = sym::make_constraint(def);
    const sym::FrameWrenchMap wm(f, coords, *symbols);
    const Index m = c->rows();
    EXPECT_EQ(m, wm.rows());
    EXPECT_EQ(m, kind == K::weld    ? 6
                 : kind == K::ball  ? 3
                 : kind == K::hinge ? 5
                                    : 1)
        << sym::to_string(kind);
    for (int trial = 0; trial < 5; ++trial) {
      const Vec q = random_vec(rng, 12, -1.0, 1.0);
      const Vec qd = random_vec(rng, 12, -1.0, 1.0);
      Mat A(m, 12);
      Vec b(m);
      c->evaluate({}, q, qd, A, b);
      Mat Afd(m, 12);
      const double h = 1e-6;
      for (Index j = 0; j < 12; ++j) {
        Vec qp = q, qm = q, pp(m), pm(m);
        qp(j) += h;
        qm(j) -= h;
        c->position_residual({}, qp, pp);
        c->position_residual({}, qm, pm);
        Afd.col(j) = (pp - pm) / (2 * h);
      }
      EXPECT_LT((A - Afd).cwiseAbs().maxCoeff(), 1e-8) << sym::to_string(kind);
      Mat Ga, Gb, Ja, Jb;
      wm.maps(q, Ga, Gb);
      wm.jacobians(q, Ja, Jb);
      const Vec viaG = Ga * (Ja * qd) + Gb * (Jb * qd);
      EXPECT_LT((viaG - A * qd).norm(), 1e-12 * (1 + (A * qd).norm())) << sym::to_string(kind);
    }
  }
}

// A frame on a free body as the numeric rows evaluate it (p = x + R(u) o, R = R(u) R_o in closed
// form from the quaternion u, not its tape) against the rows derived symbolically from the same
// frame expressions: Φ, A and b of a weld and a hinge to a fixed frame, at states with quaternions
// of any norm (the closed form is the polynomial of quaternion_rotation, unit or not).
TEST(FrameConstraints, FreeBodyFrameInClosedFormMatchesTheDerivedRows) {
  const auto symbols = std::make_shared<sym::SymbolTable>();
  const auto body = sym::free_body_definition("load", 5.0, {0.3, 0, 0, 0, 0.2, 0, 0, 0, 0.5},
                                              {0, 0, -kG}, {}, symbols);
  sym::FrameTable t;
  t.add_bodies(body);
  const auto& coords = body.coordinates();
  const sym::OriginDef ob{{sym::exact_number(0.37), sym::exact_number(-0.1), 0},
                          {sym::exact_number(3.1), sym::exact_number(0.2), sym::exact_number(2.4)}};
  std::mt19937_64 rng(12);
  for (K kind : {K::weld, K::hinge}) {
    auto f = frame_def(kind, "c", t, "world", "load.load", {}, ob);
    f.axis = {0, 0, 1};
    sym::ConstraintDef def("c", sym::ConstraintDef::Kind::holonomic, coords, symbols);
    sym::add_frame_constraint(def, f);
    const auto derived = sym::make_constraint(def);
    sym::NumericFrameSpec spec;
    spec.kind = kind;
    spec.name = "c";
    spec.frame_a = "world";
    spec.frame_b = "load.load";
    sym::NumericFrameEnd b;
    b.kind = sym::NumericFrameEnd::Kind::expressions;
    b.pose = f.b;
    const auto numeric = sym::make_numeric_frame_constraint(spec, {}, b, coords, symbols);
    const Index m = derived->rows();
    ASSERT_EQ(numeric->rows(), m);
    for (int trial = 0; trial < 20; ++trial) {
      const Vec q = random_vec(rng, 7, -1.0, 1.0), qd = random_vec(rng, 7, -2.0, 2.0);
      Mat A1(m, 7), A2(m, 7);
      Vec b1(m), b2(m), p1(m), p2(m), v1(m), v2(m);
      derived->evaluate({}, q, qd, A1, b1);
      numeric->evaluate({}, q, qd, A2, b2);
      derived->position_residual({}, q, p1);
      numeric->position_residual({}, q, p2);
      derived->velocity_residual({}, q, qd, v1);
      numeric->velocity_residual({}, q, qd, v2);
      const double sa = 1.0 + A1.cwiseAbs().maxCoeff(), sb = 1.0 + b1.cwiseAbs().maxCoeff();
      EXPECT_LE((A1 - A2).cwiseAbs().maxCoeff(), 1e-13 * sa) << sym::to_string(kind);
      EXPECT_LE((b1 - b2).cwiseAbs().maxCoeff(), 1e-13 * sb) << sym::to_string(kind);
      EXPECT_LE((p1 - p2).cwiseAbs().maxCoeff(), 1e-13 * (1.0 + p1.cwiseAbs().maxCoeff()));
      EXPECT_LE((v1 - v2).cwiseAbs().maxCoeff(), 1e-13 * (1.0 + v1.cwiseAbs().maxCoeff()));
    }
  }
}

// The numeric rows' every-direction tangents with an expressions end whose coordinates are not
// consecutive in q (a free body's seven among two coordinates it does not read, in two orders: the
// frame recognised as a free body's, its J in closed form, and not, its J from its tape): the
// doubles pass of tangent_columns() (by runs of consecutive coordinates) against the rows on lanes
// and against tangent() along each direction (the tape on one-direction dual numbers), to 1e-12 of
// the largest entry.
TEST(FrameConstraints, ColumnsOfAnEndWithScatteredCoordinates) {
  const auto symbols = std::make_shared<sym::SymbolTable>();
  const auto body = sym::free_body_definition("load", 5.0, {0.3, 0, 0, 0, 0.2, 0, 0, 0, 0.5},
                                              {0, 0, -kG}, {}, symbols);
  sym::FrameTable t;
  t.add_bodies(body);
  const auto& c = body.coordinates();
  ASSERT_EQ(c.size(), 7u);
  const std::vector<std::vector<std::string>> orders = {
      {c[0], "e1", c[1], c[2], c[3], "e2", c[4], c[5], c[6]},
      {"e1", c[3], c[4], "e2", c[0], c[1], c[2], c[5], c[6]}};
  const sym::OriginDef ob{{sym::exact_number(0.37), sym::exact_number(-0.1), 0},
                          {sym::exact_number(3.1), sym::exact_number(0.2), sym::exact_number(2.4)}};
  const auto max_rel = [](const Mat& a, const Mat& b) {
    return (a - b).cwiseAbs().maxCoeff() / std::max(b.cwiseAbs().maxCoeff(), 1e-300);
  };
  std::mt19937_64 rng(31);
  double worst = 0.0;
  for (const auto& coords : orders) {
    for (K kind : {K::weld, K::hinge}) {
      auto f = frame_def(kind, "c", t, "world", "load.load", {}, ob);
      sym::NumericFrameSpec spec;
      spec.kind = kind;
      spec.name = "c";
      spec.frame_a = "world";
      spec.frame_b = "load.load";
      spec.axis = Vec3(0.2, -0.3, 1.0).normalized();
      sym::NumericFrameEnd b;
      b.kind = sym::NumericFrameEnd::Kind::expressions;
      b.pose = f.b;
      const auto numeric = sym::make_numeric_frame_constraint(spec, {}, b, coords, symbols);
      const Index m = numeric->rows(), n = 9;
      for (int trial = 0; trial < 5; ++trial) {
        const Vec q = random_vec(rng, n, -1.0, 1.0), qd = random_vec(rng, n, -2.0, 2.0),
                  qdd = random_vec(rng, n, -3.0, 3.0), lambda = random_vec(rng, m, -2.0, 2.0);
        Mat dres(m, 2 * n), dforce = Mat::Zero(n, 2 * n), lres(m, 2 * n), lforce = dforce;
        ASSERT_TRUE(numeric->tangent_columns({}, q, qd, qdd, lambda, dres, dforce));
        ASSERT_TRUE(
            sym::numeric_frame_columns_on_lanes(*numeric, {}, q, qd, qdd, lambda, lres, lforce));
        Mat ores(m, 2 * n), oforce(n, 2 * n);
        for (Index j = 0; j < 2 * n; ++j) {
          Vec dq = Vec::Zero(n), dqd = Vec::Zero(n), r(m), fo = Vec::Zero(n);
          (j < n ? dq(j) : dqd(j - n)) = 1.0;
          ASSERT_TRUE(numeric->tangent({}, q, qd, qdd, lambda, dq, dqd, r, fo));
          ores.col(j) = r;
          oforce.col(j) = fo;
        }
        for (const char* e : {"e1", "e2"}) {  // the coordinates the frame does not read
          const auto k =
              static_cast<Index>(std::find(coords.begin(), coords.end(), e) - coords.begin());
          EXPECT_EQ(dres.col(k).cwiseAbs().maxCoeff() + dres.col(n + k).cwiseAbs().maxCoeff(), 0.0);
        }
        const double e = std::max({max_rel(dres, lres), max_rel(dforce, lforce),
                                   max_rel(dres, ores), max_rel(dforce, oforce)});
        EXPECT_LE(e, 1e-12) << sym::to_string(kind);
        worst = std::max(worst, e);
      }
    }
  }
  RecordProperty("worst_rel", ::testing::PrintToString(worst));
}

// A weld between two twist ends as forward() evaluates it when each end's coordinates are
// consecutive (weld_twist_rows: G's orientation rows as W and g, end b's as −W and g, each end's
// columns written by A's stride, a free body's x, y, z columns as ±e_c) against the same weld with
// the coordinates spread among two it does not read: in each body's order (the ends still free
// bodies', on the general path: G from RowValues' D by rotation_map_row, add_twist_columns,
// b = −(D ẍ + ẋᵀHẋ) from D; A bit for bit) and reordered within each body (no longer recognised
// as free bodies: the ends' tapes, dp and dR, add_columns; A to 1e-14). b to 1e-13 of its largest
// entry. At random states off the constraint and off |u| = 1; frames on two free bodies (disjoint
// columns, set) and two frames on one body (b's columns added onto a's), the offsets turned so
// that R_o is a general rotation (free_body_pose's quaternion u_o).
TEST(FrameConstraints, WeldOfTwistEndsMatchesTheGeneralPath) {
  const auto symbols = std::make_shared<sym::SymbolTable>();
  const auto one = sym::free_body_definition("one", 5.0, {0.3, 0, 0, 0, 0.2, 0, 0, 0, 0.5},
                                             {0, 0, -kG}, {}, symbols);
  const auto two = sym::free_body_definition("two", 2.0, {0.1, 0, 0, 0, 0.3, 0, 0, 0, 0.2},
                                             {0, 0, -kG}, {}, symbols);
  sym::FrameTable t;
  t.add_bodies(one);
  t.add_bodies(two);
  const auto& c1 = one.coordinates();
  const auto& c2 = two.coordinates();
  const std::vector<std::string> packed = concat(c1, c2);
  const std::vector<std::vector<std::string>> spread = {
      {c2[0], "e1", c1[0], c1[1], c2[1], c1[2], c2[2], c2[3], c1[3], "e2", c1[4], c2[4], c2[5],
       c1[5], c1[6], c2[6]},
      {c2[3], "e1", c1[0], c2[0], c1[4], c1[5], c2[1], c1[1], c2[2], c1[2], "e2", c2[4], c1[3],
       c1[6], c2[5], c2[6]}};
  const auto at = [](const std::vector<std::string>& v, const std::string& name) {
    return static_cast<Index>(std::find(v.begin(), v.end(), name) - v.begin());
  };
  const sym::OriginDef oa{
      {sym::exact_number(0.2), sym::exact_number(0.1), sym::exact_number(-0.3)},
      {sym::exact_number(0.7), sym::exact_number(-1.1), sym::exact_number(2.9)}};
  const sym::OriginDef ob{{sym::exact_number(-0.4), 0, sym::exact_number(0.15)},
                          {sym::exact_number(3.1), sym::exact_number(0.2), sym::exact_number(2.4)}};
  const auto max_rel = [](const Mat& a, const Mat& b) {
    return (a - b).cwiseAbs().maxCoeff() / std::max(b.cwiseAbs().maxCoeff(), 1e-300);
  };
  std::mt19937_64 rng(41);
  double worst_A = 0.0, worst_b = 0.0;
  for (const char* fb : {"two.two", "one.one"}) {
    const auto f = frame_def(K::weld, "w", t, "one.one", fb, oa, ob);
    sym::NumericFrameSpec spec;
    spec.name = "w";
    spec.frame_a = "one.one";
    spec.frame_b = fb;
    sym::NumericFrameEnd a, b;
    a.kind = b.kind = sym::NumericFrameEnd::Kind::expressions;
    a.pose = f.a;
    b.pose = f.b;
    const auto fast = sym::make_numeric_frame_constraint(spec, a, b, packed, symbols);
    for (std::size_t order = 0; order < spread.size(); ++order) {
      const auto& sc = spread[order];
      const auto general = sym::make_numeric_frame_constraint(spec, a, b, sc, symbols);
      const Index m = fast->rows(), n = 14, ns = 16;
      for (int trial = 0; trial < 10; ++trial) {
        const Vec q = random_vec(rng, n, -1.0, 1.0), qd = random_vec(rng, n, -2.0, 2.0);
        Vec qs = random_vec(rng, ns, -1.0, 1.0), qds = random_vec(rng, ns, -2.0, 2.0);
        for (Index j = 0; j < n; ++j) {
          const Index k = at(sc, packed[static_cast<std::size_t>(j)]);
          qs(k) = q(j);
          qds(k) = qd(j);
        }
        Mat A1(m, n), A2(m, ns), A2p(m, n);
        Vec b1(m), b2(m);
        fast->evaluate({}, q, qd, A1, b1);
        general->evaluate({}, qs, qds, A2, b2);
        for (Index j = 0; j < n; ++j)
          A2p.col(j) = A2.col(at(sc, packed[static_cast<std::size_t>(j)]));
        EXPECT_EQ(A2.col(at(sc, "e1")).cwiseAbs().maxCoeff(), 0.0);
        EXPECT_EQ(A2.col(at(sc, "e2")).cwiseAbs().maxCoeff(), 0.0);
        if (std::string(fb) == "one.one") {  // the second body's columns stay 0
          EXPECT_EQ(A1.rightCols(7).cwiseAbs().maxCoeff(), 0.0);
        }
        if (order == 0) {
          EXPECT_EQ((A1 - A2p).cwiseAbs().maxCoeff(), 0.0) << fb;
        } else {
          EXPECT_LE(max_rel(A1, A2p), 1e-14) << fb;
          worst_A = std::max(worst_A, max_rel(A1, A2p));
        }
        EXPECT_LE(max_rel(b1, b2), 1e-13) << fb;
        worst_b = std::max(worst_b, max_rel(b1, b2));
      }
    }
  }
  RecordProperty("worst_rel_A_tapes", ::testing::PrintToString(worst_A));
  RecordProperty("worst_rel_b", ::testing::PrintToString(worst_b));
}

// ------------------------------------------------------------------------------ weld range

// The weld's orientation rows as a function of the relative rotation: their Jacobian with respect
// to the relative angular velocity, ½(tr R I − R) in closed form, has the singular values
// |cos θ|, cos(θ/2), cos(θ/2): rank 3 for θ < 90°, rank 2 at 90° (docs/frame-constraints.md).
TEST(FrameConstraints, WeldOrientationRowsRegularBelowNinetyDegrees) {
  const auto symbols = std::make_shared<sym::SymbolTable>();  // this system's
  const auto b2 = rigid_body(symbols, "two", "b", 3.0, {0.3, 0.2, 0.4});
  sym::FrameTable t;
  t.add_bodies(b2);
  const auto f = frame_def(K::weld, "w", t, "world", "two.two");
  const sym::FrameWrenchMap wm(f, b2.coordinates(), *symbols);
  const Vec3 axis = Vec3(0.3, -0.5, 0.8).normalized();
  for (double deg : {0.0, 10.0, 45.0, 80.0, 89.0, 90.0, 100.0, 120.0}) {
    const double th = deg * std::numbers::pi / 180.0;
    const Eigen::Matrix3d R = Eigen::AngleAxisd(th, axis).toRotationMatrix();
    // roll, pitch, yaw of R = Rz(w) Ry(p) Rx(r)
    const double pitch = std::asin(-R(2, 0));
    const double roll = std::atan2(R(2, 1), R(2, 2));
    const double yaw = std::atan2(R(1, 0), R(0, 0));
    Vec q(6);
    q << 0.1, 0.2, 0.3, roll, pitch, yaw;
    Mat Ga, Gb;
    wm.maps(q, Ga, Gb);
    const Eigen::Matrix3d E = Gb.block(3, 3, 3, 3);
    const Eigen::Vector3d s = Eigen::JacobiSVD<Eigen::Matrix3d>(E).singularValues();
    std::array<double, 3> expect{std::abs(std::cos(th)), std::cos(th / 2), std::cos(th / 2)};
    std::sort(expect.begin(), expect.end(), std::greater<>());
    for (int i = 0; i < 3; ++i)
      EXPECT_NEAR(s(i), expect[static_cast<std::size_t>(i)], 1e-12) << deg;
  }
}

// ------------------------------------------------------------------------------ weld = one body

// Two bodies welded (offsets with translation and rotation on both frames) move as the same two
// bodies written as one rigid body: q̈ of the first body agrees; the weld's force on the second
// body is its m (p̈ − g) (Newton); the constraint does no work.
TEST(FrameConstraints, WeldReproducesRigidAttachment) {
  const auto symbols = std::make_shared<sym::SymbolTable>();  // this system's
  const double m1 = 2.0, m2 = 3.5;
  const std::array<double, 3> I1{0.1, 0.2, 0.3}, I2{0.3, 0.25, 0.4};
  const auto b1 = rigid_body(symbols, "one", "a", m1, I1);
  const auto b2 = rigid_body(symbols, "two", "b", m2, I2);
  sym::FrameTable t;
  t.add_bodies(b1);
  t.add_bodies(b2);
  const auto coords = concat(b1.coordinates(), b2.coordinates());
  const sym::Vec3Ex d{sym::exact_number(0.4), sym::exact_number(-0.3), sym::exact_number(0.2)};
  const sym::Vec3Ex r0{sym::exact_number(0.3), sym::exact_number(-0.2), sym::exact_number(0.5)};
  // frame a: body one moved by d and turned by r0; frame b: body two turned by r0 → R2 = R1.
  const auto f = frame_def(K::weld, "w", t, "one.one", "two.two", {d, r0}, {{0, 0, 0}, r0});
  sym::ConstraintDef def("w", sym::ConstraintDef::Kind::holonomic, coords, symbols);
  sym::add_frame_constraint(def, f);
  ukdyn::System welded;
  welded.add_subsystem(sym::make_subsystem(b1));
  welded.add_subsystem(sym::make_subsystem(b2));
  welded.add_constraint(sym::make_constraint(def));
  const sym::FrameWrenchMap wm(f, coords, *symbols);
  // The same as one subsystem: body two at p1 + R1 d with R1.
  auto one = rigid_body(symbols, "both", "a", m1, I1);
  {
    auto& b = one.add_body("two");
    b.mass = sym::exact_number(m2);
    const auto R = *one.bodies[0].rotation;
    for (std::size_t k = 0; k < 3; ++k)
      b.com[k] = one.bodies[0].com[k] + R[3 * k] * d[0] + R[3 * k + 1] * d[1] + R[3 * k + 2] * d[2];
    b.rotation = R;
    b.inertia_kind = sym::BodyDef::InertiaKind::tensor;
    b.inertia_tensor = {sym::exact_number(I2[0]), 0, 0, 0, sym::exact_number(I2[1]), 0, 0, 0,
                        sym::exact_number(I2[2])};
  }
  ukdyn::System single;
  single.add_subsystem(sym::make_subsystem(one));
  ukdyn::ForwardData dw(welded), ds(single);
  std::mt19937_64 rng(5);
  double worst = 0, worst_newton = 0, worst_work = 0;
  for (int trial = 0; trial < 10; ++trial) {
    const Vec q1 = random_vec(rng, 6, -1.0, 1.0);
    const Vec qd1 = random_vec(rng, 6, -1.0, 1.0);
    // q2: p2 = p1 + R1 d, angles of R1 (the same); q̇2 from A q̇ = 0.
    Vec q(12), qd(12);
    q << q1, q1;
    {
      const sym::FramePose& pa = f.a;
      sym::InputMap in;
      for (std::size_t i = 0; i < 6; ++i)
        in[sym::coordinate_symbol(*symbols, coords[i])] = {sym::TapeInput::Source::q,
                                                           static_cast<std::int32_t>(i)};
      const sym::Tape tape({pa.position[0], pa.position[1], pa.position[2]}, in);
      double p[3];
      tape.eval(0.0, q1.data(), nullptr, p);
      q(6) = p[0];
      q(7) = p[1];
      q(8) = p[2];
    }
    qd << qd1, Vec::Zero(6);
    ukdyn::evaluate_constraints(welded, dw, 0.0, q, qd);
    const Mat A2 = dw.A.rightCols(6), A1 = dw.A.leftCols(6);
    qd.tail(6) = -A2.fullPivLu().solve(A1 * qd1);
    Vec phi(6), phid(6);
    ukdyn::position_residuals(welded, dw, 0.0, q, phi);
    ukdyn::velocity_residuals(welded, dw, 0.0, q, qd, phid);
    ASSERT_LT(phi.norm(), 1e-12);
    ASSERT_LT(phid.norm(), 1e-12);
    ukdyn::forward(welded, dw, 0.0, q, qd, Vec::Zero(12));
    ukdyn::forward(single, ds, 0.0, q1, qd1, Vec::Zero(6));
    worst = std::max(worst, (dw.qdd.head(6) - ds.qdd).norm() / (1 + ds.qdd.norm()));
    // Newton for body two: the weld's force on frame b plus gravity is m2 p̈2 (frame b is at the
    // CoM of body two).
    const auto split = ukdyn::split_constraint_force(dw.A, dw.Qc, welded.constraint_row_offsets());
    EXPECT_TRUE(split.unique);
    const auto w = wm.evaluate(q, split.block_lambda[0]);
    const Vec3 newton = m2 * (dw.qdd.segment<3>(6) - Vec3(0, 0, -kG));
    worst_newton = std::max(worst_newton, (w.force_b - newton).norm() / (m2 * kG));
    // Action = reaction at the common point.
    EXPECT_LT((w.force_a + w.force_b).norm(), 1e-10 * m2 * kG);
    worst_work = std::max(worst_work, std::abs(dw.Qc.dot(qd)) / (1 + dw.Qc.norm() * qd.norm()));
  }
  std::printf("weld vs one body: max rel |qdd diff| %.3g, Newton %.3g, work %.3g\n", worst,
              worst_newton, worst_work);
  EXPECT_LT(worst, 1e-10);
  EXPECT_LT(worst_newton, 1e-10);
  EXPECT_LT(worst_work, 1e-12);
}

// ------------------------------------------------------------------------------ ball pendulum

// A rigid body hung from the world by a ball joint l above its CoM, swinging in the y-z plane:
// θ̈ = −m g l sin θ / (I_xx + m l²) in closed form; and the joint's force on the world frame is the
// reaction of m (p̈ − g).
TEST(FrameConstraints, BallPendulumMatchesClosedForm) {
  const auto symbols = std::make_shared<sym::SymbolTable>();  // this system's
  const double m = 1.5, l = 0.7;
  const std::array<double, 3> I{0.04, 0.07, 0.05};
  const auto body = rigid_body(symbols, "bob", "a", m, I);
  sym::FrameTable t;
  t.add_bodies(body);
  const auto f =
      frame_def(K::ball, "pivot", t, "bob.bob", "world", {{0, 0, sym::exact_number(l)}, {0, 0, 0}});
  sym::ConstraintDef def("pivot", sym::ConstraintDef::Kind::holonomic, body.coordinates(), symbols);
  sym::add_frame_constraint(def, f);
  ukdyn::System s;
  s.add_subsystem(sym::make_subsystem(body));
  s.add_constraint(sym::make_constraint(def));
  const sym::FrameWrenchMap wm(f, body.coordinates(), *symbols);
  ukdyn::ForwardData d(s);
  double worst = 0, worst_force = 0, worst_work = 0;
  for (double th : {-2.5, -1.0, 0.2, 1.3, 2.9}) {
    for (double thd : {0.0, 1.7, -3.0}) {
      Vec q(6), qd(6);
      q << 0, l * std::sin(th), -l * std::cos(th), th, 0, 0;
      qd << 0, l * std::cos(th) * thd, l * std::sin(th) * thd, thd, 0, 0;
      ukdyn::forward(s, d, 0.0, q, qd, Vec::Zero(6));
      const double expect = -m * kG * l * std::sin(th) / (I[0] + m * l * l);
      worst = std::max(worst, std::abs(d.qdd(3) - expect) / (kG / l));
      EXPECT_LT(d.qdd.tail(2).norm() + std::abs(d.qdd(0)), 1e-10);
      const auto split = ukdyn::split_constraint_force(d.A, d.Qc, s.constraint_row_offsets());
      const auto w = wm.evaluate(q, split.block_lambda[0]);
      const Vec3 on_body = m * d.qdd.head<3>() - m * Vec3(0, 0, -kG);
      worst_force = std::max(worst_force, (w.force_a - on_body).norm() / (m * kG));
      worst_work = std::max(worst_work, std::abs(d.Qc.dot(qd)) / (1 + d.Qc.norm()));
    }
  }
  std::printf("ball pendulum: max rel |theta_dd - closed form| %.3g, force %.3g, work %.3g\n",
              worst, worst_force, worst_work);
  EXPECT_LT(worst, 1e-12);
  EXPECT_LT(worst_force, 1e-12);
  EXPECT_LT(worst_work, 1e-12);
}

// ------------------------------------------------------------------------------ hinge

// A body hinged to the world about world x: A has rank 5 and its null space turns the body about
// the hinge axis only (ω ∥ x at every state the hinge holds), and q̈ follows the same closed form
// as the planar pendulum.
TEST(FrameConstraints, HingeKeepsTheAxis) {
  const auto symbols = std::make_shared<sym::SymbolTable>();  // this system's
  const double m = 1.2, l = 0.5;
  const std::array<double, 3> I{0.03, 0.08, 0.06};
  const auto body = rigid_body(symbols, "door", "a", m, I);
  sym::FrameTable t;
  t.add_bodies(body);
  auto f =
      frame_def(K::hinge, "h", t, "door.door", "world", {{0, 0, sym::exact_number(l)}, {0, 0, 0}});
  f.axis = {1, 0, 0};
  sym::ConstraintDef def("h", sym::ConstraintDef::Kind::holonomic, body.coordinates(), symbols);
  sym::add_frame_constraint(def, f);
  ukdyn::System s;
  s.add_subsystem(sym::make_subsystem(body));
  s.add_constraint(sym::make_constraint(def));
  const sym::FrameWrenchMap wm(f, body.coordinates(), *symbols);
  ukdyn::ForwardData d(s);
  for (double th : {-1.1, 0.4, 2.0}) {
    Vec q(6), qd(6);
    q << 0, l * std::sin(th), -l * std::cos(th), th, 0, 0;
    qd << 0, l * std::cos(th), l * std::sin(th), 1.0, 0, 0;
    ukdyn::forward(s, d, 0.0, q, qd, Vec::Zero(6));
    EXPECT_EQ(d.result.rank, 5);
    const Mat N = uktest::null_space(d.A);
    ASSERT_EQ(N.cols(), 1);
    Mat Ja, Jb;
    wm.jacobians(q, Ja, Jb);
    const Vec twist = Ja * N.col(0);
    EXPECT_LT(twist.segment<2>(4).norm(), 1e-12 * twist.norm());  // ω_y = ω_z = 0
    EXPECT_LT(twist.head<3>().norm(), 1e-12 * twist.norm());      // the pivot does not move
    const double expect = -m * kG * l * std::sin(th) / (I[0] + m * l * l);
    EXPECT_NEAR(d.qdd(3), expect, 1e-11);
  }
}

// ------------------------------------------------------------------------------ level

// level: a body's x axis kept horizontal (1 row) or vertical (2 rows); a free body under gravity
// with the axis horizontal falls freely (the row needs no force) and the rows hold at q̈.
TEST(FrameConstraints, LevelRowsAndNoForceInFreeFall) {
  const auto symbols = std::make_shared<sym::SymbolTable>();  // this system's
  const auto body = rigid_body(symbols, "tray", "a", 2.0, {0.1, 0.2, 0.3});
  sym::FrameTable t;
  t.add_bodies(body);
  for (bool vertical : {false, true}) {
    auto f = frame_def(K::level, "lv", t, "tray.tray", "world");
    f.axis = {1, 0, 0};
    f.vertical = vertical;
    sym::ConstraintDef def("lv", sym::ConstraintDef::Kind::holonomic, body.coordinates(), symbols);
    sym::add_frame_constraint(def, f);
    ukdyn::System s;
    s.add_subsystem(sym::make_subsystem(body));
    s.add_constraint(sym::make_constraint(def));
    ukdyn::ForwardData d(s);
    Vec q(6);
    // horizontal: pitch 0 (x axis = (cos w, sin w, 0)); vertical: pitch −π/2.
    q << 0.1, 0.2, 0.3, 0.4, vertical ? -std::numbers::pi / 2 + 0.0 : 0.0, 0.5;
    if (vertical) q(4) = -1.2;  // not at the gimbal lock of the coordinates: check rows only
    Vec phi(s.rows());
    ukdyn::position_residuals(s, d, 0.0, q, phi);
    if (!vertical) {
      EXPECT_LT(phi.norm(), 1e-15);
      const Vec qd = Vec::Zero(6);
      ukdyn::forward(s, d, 0.0, q, qd, Vec::Zero(6));
      EXPECT_LT(d.Qc.norm(), 1e-12);
      EXPECT_NEAR(d.qdd(2), -kG, 1e-12);
    } else {
      // x axis of Rz(w) Ry(p) Rx(r) = (cos w cos p, sin w cos p, −sin p)
      EXPECT_EQ(s.rows(), 2);
      EXPECT_NEAR(std::hypot(phi(0), phi(1)), std::cos(-1.2), 1e-14);
    }
  }
}

// ------------------------------------------------------------------------------ split

// Redundant rows: the same ball joint twice. The split is not unique (reported), the least-norm
// choice halves the force between the two identical blocks, and the blocks still sum to Qc.
TEST(ConstraintForces, RedundantRowsAreReportedAndSplitByLeastNorm) {
  const auto symbols = std::make_shared<sym::SymbolTable>();  // this system's
  const auto body = rigid_body(symbols, "bob", "a", 1.0, {0.02, 0.02, 0.02});
  sym::FrameTable t;
  t.add_bodies(body);
  const sym::FrameConstraintDef f =
      frame_def(K::ball, "p1", t, "bob.bob", "world", {{0, 0, 1}, {0, 0, 0}});
  const sym::FrameConstraintDef f2 = [&] {
    sym::FrameConstraintDef g = f;
    g.name = "p2";
    return g;
  }();
  ukdyn::System s;
  s.add_subsystem(sym::make_subsystem(body));
  for (const sym::FrameConstraintDef* fd : {&f, &f2}) {
    sym::ConstraintDef def(fd->name, sym::ConstraintDef::Kind::holonomic, body.coordinates(),
                           symbols);
    sym::add_frame_constraint(def, *fd);
    s.add_constraint(sym::make_constraint(def));
  }
  ukdyn::ForwardData d(s);
  Vec q(6), qd(6);
  q << 0, std::sin(0.5), -std::cos(0.5), 0.5, 0, 0;
  qd << 0, std::cos(0.5), std::sin(0.5), 1.0, 0, 0;
  ukdyn::forward(s, d, 0.0, q, qd, Vec::Zero(6));
  const auto split = ukdyn::split_constraint_force(d.A, d.Qc, s.constraint_row_offsets());
  EXPECT_FALSE(split.unique);
  EXPECT_EQ(split.rank, 3);
  EXPECT_LT((split.block_force[0] + split.block_force[1] - d.Qc).norm(), 1e-12 * d.Qc.norm());
  EXPECT_LT((split.block_force[0] - split.block_force[1]).norm(), 1e-12 * d.Qc.norm());
}

// ------------------------------------------------------------------------------ internal force

// A load held by two agents (free rigid bodies) welded at asymmetric grasps, with gravity on the
// agents only and the system at rest: the agents pull the load by forces proportional to their
// inertia, a motion that does not squeeze. The inertia-weighted decomposition [Verginis2019]
// reports no internal wrench; the Moore–Penrose one [Walker1991] reports one. Both lie in null(G).
TEST(ConstraintForces, WeightedDecompositionReportsNoSqueezeForRigidMotion) {
  const auto symbols = std::make_shared<sym::SymbolTable>();  // this system's
  const double mL = 4.0;
  const auto load = rigid_body(symbols, "load", "l", mL, {0.2, 0.5, 0.6}, 0.0);
  const auto ag1 = rigid_body(symbols, "ag1", "a", 1.0, {0.01, 0.02, 0.03});
  const auto ag2 = rigid_body(symbols, "ag2", "b", 6.0, {0.3, 0.1, 0.2});
  sym::FrameTable t;
  for (const auto* d : {&load, &ag1, &ag2}) t.add_bodies(*d);
  const auto coords = concat(concat(load.coordinates(), ag1.coordinates()), ag2.coordinates());
  // Grasp 1 at +0.6 x of the load, agent 1's CoM 0.1 further out; grasp 2 at −0.3 x, +0.2 y with
  // agent 2's CoM offset 0.25 along its y.
  const auto g1 = frame_def(K::weld, "g1", t, "ag1.ag1", "load.load",
                            {{sym::exact_number(-0.1), 0, 0}, {0, 0, 0}},
                            {{sym::exact_number(0.6), 0, 0}, {0, 0, 0}});
  const auto g2 = frame_def(K::weld, "g2", t, "ag2.ag2", "load.load",
                            {{0, sym::exact_number(-0.25), 0}, {0, 0, 0}},
                            {{sym::exact_number(-0.3), sym::exact_number(0.2), 0}, {0, 0, 0}});
  ukdyn::System s;
  for (const auto* d : {&load, &ag1, &ag2}) s.add_subsystem(sym::make_subsystem(*d));
  std::vector<sym::FrameWrenchMap> maps;
  for (const auto* g : {&g1, &g2}) {
    sym::ConstraintDef def(g->name, sym::ConstraintDef::Kind::holonomic, coords, symbols);
    sym::add_frame_constraint(def, *g);
    s.add_constraint(sym::make_constraint(def));
    maps.emplace_back(*g, coords, *symbols);
  }
  // Consistent pose: load at (0.1, 0.2, 0.3) with angles (0.2, −0.1, 0.3); agents' angles equal.
  Vec q = Vec::Zero(18);
  q.head(6) << 0.1, 0.2, 0.3, 0.2, -0.1, 0.3;
  q.segment(9, 3) = q.segment(3, 3);
  q.segment(15, 3) = q.segment(3, 3);
  ukdyn::ForwardData d(s);
  for (int it = 0; it < 3; ++it) {  // agent positions: p_agent = p_grasp − R offset
    Vec phi(12);
    ukdyn::position_residuals(s, d, 0.0, q, phi);
    q.segment(6, 3) -= phi.segment(0, 3);
    q.segment(12, 3) -= phi.segment(6, 3);
  }
  Vec phi(12);
  ukdyn::position_residuals(s, d, 0.0, q, phi);
  ASSERT_LT(phi.norm(), 1e-14);
  ukdyn::forward(s, d, 0.0, q, Vec::Zero(18), Vec::Zero(18));
  const auto split = ukdyn::split_constraint_force(d.A, d.Qc, s.constraint_row_offsets());
  ASSERT_TRUE(split.unique);
  Vec w(12);
  std::vector<Vec3> points;
  Mat J(12, 18);
  for (std::size_t k = 0; k < 2; ++k) {
    const auto wr = maps[k].evaluate(q, split.block_lambda[k]);
    w.segment<3>(static_cast<Index>(6 * k)) = wr.force_b;
    w.segment<3>(static_cast<Index>(6 * k + 3)) = wr.moment_b;
    points.push_back(wr.position_b);
    Mat Ja, Jb;
    maps[k].jacobians(q, Ja, Jb);
    J.middleRows(static_cast<Index>(6 * k), 6) = Ja;
  }
  const Mat G = ukdyn::grasp_matrix(points, q.head<3>());
  // Newton–Euler of the load (no gravity on it, at rest): G w = [m p̈; I_world ω̇] — check the
  // force part against its m p̈.
  EXPECT_LT((G.topRows(3) * w - mL * d.qdd.head<3>()).norm(), 1e-10 * w.norm());
  // Agents' inertia at the grasps from their own mass matrices.
  const Mat Lambda = ukdyn::task_space_inertia(d.M, J);
  const Vec walker = ukdyn::internal_wrench_walker(G, w);
  const Vec weighted = ukdyn::internal_wrench_weighted(G, Lambda, w);
  std::printf(
      "asymmetric grasp, rigid motion: |w| %.6g N, walker internal %.6g, weighted internal %.3g "
      "(m g = %.4g N); |G f_int| %.3g, %.3g\n",
      w.norm(), walker.norm(), weighted.norm(), mL * kG, (G * walker).norm(),
      (G * weighted).norm());
  EXPECT_LT((G * walker).norm(), 1e-10 * w.norm());
  EXPECT_LT((G * weighted).norm(), 1e-10 * w.norm());
  EXPECT_LT(weighted.norm(), 1e-9 * mL * kG);
  EXPECT_GT(walker.norm(), 1e-2 * mL * kG);
}

#ifdef UKDYN_HAVE_IO
// ------------------------------------------------------------------------------ YAML

// Frame constraints in a scenario: a chain link welded... the errors name file:line:col, the key
// and the frame, and an unknown frame lists the known ones.
TEST(FrameConstraintsYaml, UnknownFrameListsTheKnownOnes) {
  const std::string text = R"(ukdyn: 1
name: weld test
subsystems:
  - name: bob
    type: definitions
    coordinates: [x, y, z, r, p, w]
    bodies:
      - name: body
        mass: 1
        com: [x, y, z]
        rotation: [[cos(w)*cos(p), cos(w)*sin(p)*sin(r) - sin(w)*cos(r), cos(w)*sin(p)*cos(r) + sin(w)*sin(r)],
                   [sin(w)*cos(p), sin(w)*sin(p)*sin(r) + cos(w)*cos(r), sin(w)*sin(p)*cos(r) - cos(w)*sin(r)],
                   [-sin(p), cos(p)*sin(r), cos(p)*cos(r)]]
        inertia: [0.1, 0.1, 0.1]
constraints:
  - name: pivot
    type: ball
    a: {frame: bob.bod, xyz: [0, 0, 1]}
    b: world
initial:
  q: [0, 0, -1, 0, 0, 0]
simulation: {t_end: 0.1, sample_dt: 0.01}
)";
  try {
    (void)ukdyn::load_scenario_text(text, "weld.yaml");
    FAIL() << "no error";
  } catch (const ukdyn::ScenarioError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("weld.yaml:18:"), std::string::npos) << msg;
    EXPECT_NE(msg.find("bob.bod"), std::string::npos) << msg;
    EXPECT_NE(msg.find("known: world, bob.body"), std::string::npos) << msg;
    EXPECT_NE(msg.find("key 'constraints[0].a.frame'"), std::string::npos) << msg;
  }
  std::string good = text;
  good.replace(good.find("bob.bod,"), 8, "bob.body,");
  const auto sc = ukdyn::load_scenario_text(good, "weld.yaml");
  ASSERT_EQ(sc.system->constraints().size(), 1U);
  EXPECT_NE(dynamic_cast<const sym::FrameConstraint*>(sc.system->constraints()[0].get()), nullptr);
  EXPECT_EQ(sc.system->rows(), 3);
}
// A weld holds for any designed relative orientation put in the offsets (a grid of rpy offsets
// with 90° and 180° turns and oblique axes): a free body welded to the world frame turned by the
// offset, started turned with it, stays put under any generalized force (q̈ = 0). Started 180°
// away from the offset about any axis — zero residual there, but the orientation rows' spurious
// root, where they hold no rotation — the scenario is refused naming the weld and the angle.
TEST(FrameConstraintsYaml, WeldHoldsForAnyOffsetAndRefusesItsSpuriousRoot) {
  const double pi = std::numbers::pi;
  const std::vector<Eigen::Vector3d> offsets = {
      {0, 0, 0},      {0, 0, pi},       {pi, 0, 0},       {0, pi / 2, 0},
      {pi / 2, 0, 0}, {0.3, -1.1, 2.5}, {pi, pi / 2, pi}, {-2.0, 0.7, -pi / 2}};
  const std::vector<Eigen::Vector3d> flips = {{1, 0, 0},
                                              {0, 1, 0},
                                              {0, 0, 1},
                                              Eigen::Vector3d(1, 1, 1).normalized(),
                                              Eigen::Vector3d(1, -2, 0.5).normalized()};
  auto text = [](const Eigen::Vector3d& rpy, const Eigen::Quaterniond& q) {
    std::ostringstream os;
    os.precision(17);
    os << "ukdyn: 1\nname: weld grid\nsubsystems:\n  - {name: load, type: free_body, mass: 2, "
          "inertia: [1, 2, 3]}\nconstraints:\n  - {type: weld, name: glue, a: load.load, b: "
          "{frame: world, xyz: [0.1, -0.2, 0.3], rpy: ["
       << rpy.x() << ", " << rpy.y() << ", " << rpy.z() << "]}}\ninitial:\n  q: [0.1, -0.2, 0.3, "
       << q.w() << ", " << q.x() << ", " << q.y() << ", " << q.z()
       << "]\n  qd: [0, 0, 0, 0, 0, 0, 0]\nsimulation: {t_end: 1, sample_dt: 0.1}\n";
    return os.str();
  };
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-5.0, 5.0);
  for (const Eigen::Vector3d& rpy : offsets) {
    const Eigen::Quaterniond target(Eigen::AngleAxisd(rpy.z(), Eigen::Vector3d::UnitZ()) *
                                    Eigen::AngleAxisd(rpy.y(), Eigen::Vector3d::UnitY()) *
                                    Eigen::AngleAxisd(rpy.x(), Eigen::Vector3d::UnitX()));
    const auto sc = ukdyn::load_scenario_text(text(rpy, target), "grid.yaml");
    ukdyn::ForwardData d(*sc.system);
    Vec tau(7);
    for (Index i = 0; i < 7; ++i) tau(i) = u(rng);
    ukdyn::forward(*sc.system, d, 0.0, sc.q0, sc.qd0, tau);
    EXPECT_LE(d.qdd.cwiseAbs().maxCoeff(), 1e-9) << "offset " << rpy.transpose();
    for (const Eigen::Vector3d& axis : flips) {
      const Eigen::Quaterniond spurious = target * Eigen::Quaterniond(Eigen::AngleAxisd(pi, axis));
      try {
        (void)ukdyn::load_scenario_text(text(rpy, spurious), "grid.yaml");
        ADD_FAILURE() << "no error for offset " << rpy.transpose() << ", flip " << axis.transpose();
      } catch (const ukdyn::ScenarioError& e) {
        EXPECT_NE(std::string(e.what()).find("weld 'glue'"), std::string::npos) << e.what();
        EXPECT_NE(std::string(e.what()).find("180 degrees apart"), std::string::npos) << e.what();
      }
    }
  }
}

// The paper's robots holding the load as its own body (welds + level, scenarios/
// paper_load_body.yaml) describe the same motion as the cut model (scenarios/paper_urdf.yaml):
// both are fully prescribed by the same kinematics. Joint angles over 2 s; the redundant roll rows
// are reported as a split that is not unique.
TEST(FrameConstraintsYaml, LoadAsBodyMatchesTheCutModel) {
  auto body =
      ukdyn::load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/paper_load_body.yaml");
  auto cut = ukdyn::load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/paper_urdf.yaml");
  for (auto* sc : {&body, &cut}) {
    sc->sim.t_end = 2.0;
    sc->sim.sample_dt = 0.05;
  }
  std::vector<Vec> qb, qc;
  bool unique_everywhere = true;
  auto run = [&](const ukdyn::Scenario& sc, std::vector<Vec>& out, bool split) {
    const ukdyn::ForceFunction tau = [](double, ukdyn::CVecRef, ukdyn::CVecRef, ukdyn::VecRef o) {
      o.setZero();
    };
    const auto stats =
        ukdyn::simulate(*sc.system, sc.q0, sc.qd0, tau, sc.sim,
                        [&](double, ukdyn::CVecRef q, ukdyn::CVecRef, const ukdyn::ForwardData& d) {
                          out.emplace_back(q.head(12));
                          if (split) {
                            const auto s = ukdyn::split_constraint_force(
                                d.A, d.Qc, sc.system->constraint_row_offsets());
                            unique_everywhere = unique_everywhere && s.unique;
                          }
                          return true;
                        });
    EXPECT_EQ(stats.status, ukdyn::RunStatus::completed) << stats.message;
  };
  run(body, qb, true);
  run(cut, qc, false);
  ASSERT_EQ(qb.size(), qc.size());
  double worst = 0;
  for (std::size_t i = 0; i < qb.size(); ++i)
    worst = std::max(worst, (qb[i] - qc[i]).cwiseAbs().maxCoeff());
  std::printf(
      "load as a body vs the cut model: max |q diff| over 2 s = %.3g (rad or m), %zu samples\n",
      worst, qb.size());
  EXPECT_LT(worst, 1e-10);
  EXPECT_FALSE(unique_everywhere);  // the two welds' roll rows are redundant
}
#endif

}  // namespace
