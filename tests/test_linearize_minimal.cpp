// Minimal coordinates on the constraint manifold and the discrete model
// (ukdyn/model/minimal_linearize.hpp): a point mass on a sphere (the spherical pendulum, whose small
// oscillations have ω = √(g/L) in closed form), the null-space basis, the embedding x = T z away
// from rest, velocity-level rows refused, expm and the zero-order hold against closed forms, and
// the `ukdyn linearize` options.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cmath>
#include <complex>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>

#include "ukdyn/model/minimal_linearize.hpp"
#include "ukdyn/tree/tree.hpp"

#ifdef UKDYN_HAVE_IO
#include "output/npz.hpp"
#endif
#ifdef UKDYN_CLI
#include <nlohmann/json.hpp>

#include "cli_run.hpp"
#endif

namespace {

using namespace ukdyn;

constexpr double g = 9.81, L = 0.8, mass = 1.7;

// A point mass at (x, y, z): three prismatic joints, the mass on the last (massless first two).
std::shared_ptr<const tree::TreeSubsystem> point_mass() {
  tree::Model m;
  m.name = "mass";
  m.coordinates = {"x", "y", "z"};
  m.gravity = {0, 0, -g};
  const std::array<Eigen::Vector3d, 3> axes = {Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(0, 1, 0),
                                               Eigen::Vector3d(0, 0, 1)};
  for (int k = 0; k < 3; ++k) {
    tree::Link l;
    l.name = "l" + std::to_string(k);
    l.joint = "j" + std::to_string(k);
    if (k > 0) l.parent = k - 1;
    l.type = tree::JointType::prismatic;
    l.axis = axes[static_cast<std::size_t>(k)];
    l.terms = {{k, 1.0}};
    l.mass = k == 2 ? mass : 0.0;
    m.links.push_back(l);
  }
  return tree::make_subsystem(m);
}

// |p|² = L²: Φ = (pᵀp − L²)/2, A = pᵀ, b = −ṗᵀṗ; tangent d(A q̈ − b) = q̈ᵀdp + 2ṗᵀdṗ, d(Aᵀλ) = λ dp.
class OnSphere final : public Constraint {
 public:
  Index rows() const override { return 1; }
  const std::vector<std::string>& row_names() const override { return names_; }
  void evaluate(const ConstraintContext&, CVecRef q, CVecRef qd, MatRef A,
                VecRef b) const override {
    A.row(0) = q.transpose();
    b(0) = -qd.squaredNorm();
  }
  void position_residual(const ConstraintContext&, CVecRef q, VecRef phi) const override {
    phi(0) = 0.5 * (q.squaredNorm() - L * L);
  }
  void velocity_residual(const ConstraintContext&, CVecRef q, CVecRef qd,
                         VecRef phid) const override {
    phid(0) = q.dot(qd);
  }
  bool has_derivatives() const override { return true; }
  bool tangent(const ConstraintContext&, CVecRef, CVecRef qd, CVecRef qdd, CVecRef lambda,
               CVecRef dq, CVecRef dqd, VecRef dres, VecRef dforce) const override {
    dres(0) = qdd.dot(dq) + 2.0 * qd.dot(dqd);
    dforce += lambda(0) * dq;
    return true;
  }

 private:
  std::vector<std::string> names_{"sphere"};
};

// A velocity-level row ẋ − y ż = 0 (A = [1, 0, −y], b = ẏ ż): no position residual.
class Skate final : public Constraint {
 public:
  Index rows() const override { return 1; }
  const std::vector<std::string>& row_names() const override { return names_; }
  void evaluate(const ConstraintContext&, CVecRef q, CVecRef qd, MatRef A,
                VecRef b) const override {
    A.row(0) << 1.0, 0.0, -q(1);
    b(0) = qd(1) * qd(2);
  }
  void position_residual(const ConstraintContext&, CVecRef, VecRef phi) const override {
    phi(0) = 0.0;
  }
  void velocity_residual(const ConstraintContext&, CVecRef q, CVecRef qd,
                         VecRef phid) const override {
    phid(0) = qd(0) - q(1) * qd(2);
  }
  bool has_derivatives() const override { return true; }
  bool tangent(const ConstraintContext&, CVecRef, CVecRef qd, CVecRef qdd, CVecRef lambda,
               CVecRef dq, CVecRef dqd, VecRef dres, VecRef dforce) const override {
    dres(0) = -dq(1) * qdd(2) - dqd(1) * qd(2) - qd(1) * dqd(2);
    dforce(2) -= lambda(0) * dq(1);
    return true;
  }

 private:
  std::vector<std::string> names_{"skate"};
};

// A rheonomic row: the sphere's centre moves, c(t) = (s t, 0, 0): Φ = (|p − c|² − L²)/2,
// A = (p − c)ᵀ, Φ_t = −(p − c)·ċ, b = −|ṗ − ċ|² (c̈ = 0).
constexpr double kCentreSpeed = 0.6;
Vec rel(double t, CVecRef q) { return q - Eigen::Vector3d(kCentreSpeed * t, 0, 0); }
Vec rel_rate(CVecRef qd) { return qd - Eigen::Vector3d(kCentreSpeed, 0, 0); }

class MovingSphere final : public Constraint {
 public:
  Index rows() const override { return 1; }
  const std::vector<std::string>& row_names() const override { return names_; }
  void evaluate(const ConstraintContext& c, CVecRef q, CVecRef qd, MatRef A,
                VecRef b) const override {
    A.row(0) = rel(c.t, q).transpose();
    b(0) = -rel_rate(qd).squaredNorm();
  }
  void position_residual(const ConstraintContext& c, CVecRef q, VecRef phi) const override {
    phi(0) = 0.5 * (rel(c.t, q).squaredNorm() - L * L);
  }
  void velocity_residual(const ConstraintContext& c, CVecRef q, CVecRef qd,
                         VecRef phid) const override {
    phid(0) = rel(c.t, q).dot(rel_rate(qd));
  }
  bool has_derivatives() const override { return true; }
  bool tangent(const ConstraintContext&, CVecRef, CVecRef qd, CVecRef qdd, CVecRef lambda,
               CVecRef dq, CVecRef dqd, VecRef dres, VecRef dforce) const override {
    dres(0) = qdd.dot(dq) + 2.0 * rel_rate(qd).dot(dqd);
    dforce += lambda(0) * dq;
    return true;
  }

 private:
  std::vector<std::string> names_{"moving_sphere"};
};

System pendulum() {
  System s;
  s.add_subsystem(point_mass());
  s.add_constraint(std::make_shared<OnSphere>());
  return s;
}

// The eigenvalues of X sorted by (imaginary, real) part.
std::vector<std::complex<double>> eigenvalues(const Mat& X) {
  const Eigen::EigenSolver<Mat> es(X);
  std::vector<std::complex<double>> v(es.eigenvalues().data(),
                                      es.eigenvalues().data() + es.eigenvalues().size());
  std::sort(v.begin(), v.end(), [](auto a, auto b) {
    return a.imag() != b.imag() ? a.imag() < b.imag() : a.real() < b.real();
  });
  return v;
}

TEST(MinimalCoordinates, SphericalPendulumOscillatesAtSqrtGOverL) {
  const System sys = pendulum();
  Vec q(3), qd = Vec::Zero(3), tau = Vec::Zero(3);
  q << 0.0, 0.0, -L;  // hanging at rest
  const Linearization lin = linearize(sys, 0.0, q, qd, tau);
  ASSERT_TRUE(lin.trusted) << lin.message;
  const MinimalModel mm = minimal_model(sys, 0.0, q, qd, tau, lin);
  ASSERT_EQ(mm.N.rows(), 3);
  ASSERT_EQ(mm.N.cols(), 2);
  EXPECT_LE(mm.null_residual, 1e-12);
  EXPECT_LE(mm.ortho_residual, 1e-12);
  EXPECT_TRUE(mm.at_rest);
  EXPECT_EQ(mm.position_residual, 0.0);
  EXPECT_TRUE(mm.note.empty()) << mm.note;
  // Off the sphere the model is still built, and the note says where the state is.
  const Vec off = 1.1 * q;
  const MinimalModel mo = minimal_model(sys, 0.0, off, qd, tau, linearize(sys, 0.0, off, qd, tau));
  EXPECT_NEAR(mo.position_residual, 0.5 * (1.21 - 1.0) * L * L, 1e-15);
  EXPECT_NE(mo.note.find("off the constraint manifold"), std::string::npos) << mo.note;
  // Closed form: z̈ = −(g/L) z in each horizontal direction, the input 1/m.
  const double w = std::sqrt(g / L);
  const auto ev = eigenvalues(mm.F_min);
  ASSERT_EQ(ev.size(), 4u);
  for (std::size_t k = 0; k < 4; ++k) {
    EXPECT_NEAR(ev[k].real(), 0.0, 1e-12);
    EXPECT_NEAR(std::abs(ev[k].imag()), w, 1e-12 * w);
  }
  EXPECT_LE((mm.F_min.bottomLeftCorner(2, 2) + (g / L) * Mat::Identity(2, 2)).norm(), 1e-12);
  EXPECT_LE((mm.G_min.bottomRows(2) * mm.N - Mat::Identity(2, 2) / mass).norm(), 1e-12);
  // The deterministic sign rule: each column's largest entry is positive.
  for (Index j = 0; j < 2; ++j) {
    Index i = 0;
    mm.N.col(j).cwiseAbs().maxCoeff(&i);
    EXPECT_GT(mm.N(i, j), 0.0);
  }
}

// An equilibrium away from the bottom: τ = m g (e_z + p̂) leaves the constant force m g p̂ (a
// gravity along −p̂, the hanging pendulum turned): ω = √(g/L) again; the tangent space is invariant
// (F T = T F_min) and the full spectrum is the minimal one plus 2r zeros.
TEST(MinimalCoordinates, AtAnEquilibriumTheManifoldIsInvariantAndTheSpectrumSplits) {
  const System sys = pendulum();
  Vec q(3), qd = Vec::Zero(3), tau(3);
  q << L * std::sin(0.7) * std::cos(0.3), L * std::sin(0.7) * std::sin(0.3), -L * std::cos(0.7);
  tau = mass * g * (Eigen::Vector3d(0, 0, 1) + q / L);
  const Linearization lin = linearize(sys, 0.0, q, qd, tau);
  ASSERT_TRUE(lin.trusted) << lin.message;
  const MinimalModel mm = minimal_model(sys, 0.0, q, qd, tau, lin);
  EXPECT_LE(mm.null_residual, 1e-12);
  EXPECT_LE(mm.ortho_residual, 1e-12);
  EXPECT_LE((mm.F * mm.T - mm.T * mm.F_min).norm(), 1e-11 * (1 + mm.F.norm()));
  const auto full = eigenvalues(mm.F), small = eigenvalues(mm.F_min);
  std::vector<std::complex<double>> rest = full;
  for (const auto& e : small) {  // remove each minimal eigenvalue from the full list
    const auto it = std::min_element(rest.begin(), rest.end(), [&](auto a, auto b) {
      return std::abs(a - e) < std::abs(b - e);
    });
    EXPECT_LE(std::abs(*it - e), 1e-6 * (1 + std::abs(e)));
    rest.erase(it);
  }
  ASSERT_EQ(rest.size(), 2u);  // 2r zeros, r = 1 (a double zero: ~√ε-perturbed)
  for (const auto& e : rest) EXPECT_LE(std::abs(e), 1e-6);
  for (const auto& e : small) EXPECT_NEAR(std::abs(e.imag()), std::sqrt(g / L), 1e-12);
  EXPECT_LE(lin.qdd.norm(), 1e-12);
}

// Moving: D = ∂(A q̇)/∂q = q̇ᵀ for the sphere, and x = T z satisfies the linearised velocity
// constraint A δq̇ + D δq = 0.
TEST(MinimalCoordinates, AwayFromRestTheEmbeddingKeepsTheVelocityConstraint) {
  const System sys = pendulum();
  Vec q(3), qd(3), tau = Vec::Zero(3);
  q << L * std::sin(0.5), 0.0, -L * std::cos(0.5);
  qd << 1.3 * std::cos(0.5), 0.4, 1.3 * std::sin(0.5);  // q · q̇ = 0
  const Linearization lin = linearize(sys, 0.0, q, qd, tau);
  const MinimalModel mm = minimal_model(sys, 0.0, q, qd, tau, lin);
  EXPECT_FALSE(mm.at_rest);
  EXPECT_FALSE(mm.note.empty());
  EXPECT_LE((mm.D - qd.transpose()).norm(), 1e-14);
  Mat DA(1, 6);
  DA << mm.D, mm.AR;
  EXPECT_LE((DA * mm.T).norm(), 1e-14);
  EXPECT_LE((mm.AR * mm.T.topRows(3)).norm(), 1e-14);
  // ż₁ = z₂ exactly (Nᵀ A_R⁺ = 0).
  const Index k = mm.N.cols();
  EXPECT_LE((mm.F_min.topLeftCorner(k, k)).norm(), 1e-14);
  EXPECT_LE((mm.F_min.topRightCorner(k, k) - Mat::Identity(k, k)).norm(), 1e-14);
}

// Rheonomic: D = ∂(A q̇ + Φ_t)/∂q = (q̇ − ċ)ᵀ, at rest −ċᵀ = (−s, 0, 0) (the ∂Φ_t/∂q part):
// exact, ½ ∂(A q̈ − b)/∂q̇ of the row's tangent, b = −|q̇ − ċ|².
TEST(MinimalCoordinates, RheonomicRowsGetThePhiTTerm) {
  System sys;
  sys.add_subsystem(point_mass());
  sys.add_constraint(std::make_shared<MovingSphere>());
  const double t = 0.5, s = kCentreSpeed;
  Vec q(3), qd = Vec::Zero(3), tau = Vec::Zero(3);
  q << s * t + L * std::sin(0.4), 0.0, -L * std::cos(0.4);
  qd << s, 0.0, 0.0;  // moving with the centre: A q̇ + Φ_t = 0
  for (const bool moving : {false, true}) {
    const Vec v = moving ? qd : Vec(Vec::Zero(3));
    const Linearization lin = linearize(sys, t, q, v, tau);
    const MinimalModel mm = minimal_model(sys, t, q, v, tau, lin);
    EXPECT_TRUE(mm.rheonomic);
    EXPECT_NE(mm.note.find("rheonomic"), std::string::npos);
    Vec expect = v - Eigen::Vector3d(s, 0, 0);
    EXPECT_LE((mm.D.transpose() - expect).norm(), 1e-15) << moving;
    Mat DA(1, 6);
    DA << mm.D, mm.AR;
    EXPECT_LE((DA * mm.T).norm(), 1e-14);
  }
  // A scleronomic row is not rheonomic.
  const System plain = pendulum();
  Vec p(3);
  p << 0.0, 0.0, -L;
  const Vec z = Vec::Zero(3);
  EXPECT_FALSE(minimal_model(plain, 0.0, p, z, z, linearize(plain, 0.0, p, z, z)).rheonomic);
}

TEST(MinimalCoordinates, VelocityLevelRowsAreRefused) {
  System sys;
  sys.add_subsystem(point_mass());
  sys.add_constraint(std::make_shared<Skate>());
  Vec q(3), qd = Vec::Zero(3), tau = Vec::Zero(3);
  q << 0.1, 0.3, -0.2;
  const Linearization lin = linearize(sys, 0.0, q, qd, tau);
  try {
    (void)minimal_model(sys, 0.0, q, qd, tau, lin);
    ADD_FAILURE() << "expected ukdyn::Error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("'skate' is velocity-level"), std::string::npos)
        << e.what();
  }
}

TEST(MinimalCoordinates, NullSpaceBasisOfRandomRows) {
  std::mt19937 rng(7);
  std::normal_distribution<double> nd;
  for (int trial = 0; trial < 20; ++trial) {
    const Index n = 3 + trial % 6, r = trial % 3;
    Mat A(r, n);
    for (Index i = 0; i < r; ++i)
      for (Index j = 0; j < n; ++j) A(i, j) = nd(rng);
    const Mat N = null_space_basis(A);
    ASSERT_EQ(N.cols(), n - r);
    if (r > 0) {
      EXPECT_LE((A * N).cwiseAbs().maxCoeff(), 1e-12 * (1 + A.norm()));
    }
    EXPECT_LE((N.transpose() * N - Mat::Identity(n - r, n - r)).cwiseAbs().maxCoeff(), 1e-12);
  }
  EXPECT_THROW((void)null_space_basis(Mat::Ones(3, 2)), std::invalid_argument);
}

// exp of the harmonic oscillator in closed form, at small and large ‖F h‖ (no scaling, 2^s
// scaling), and the zero-order-hold input matrix ∫₀ʰ e^{Fs} ds G.
TEST(DiscreteTime, ZeroOrderHoldOfTheOscillatorMatchesTheClosedForm) {
  for (double w : {0.3, 2.0, 60.0}) {
    for (double h : {0.01, 0.5, 3.0}) {
      Mat F(2, 2), G(2, 1), Fd, Gd;
      F << 0, 1, -w * w, 0;
      G << 0, 1;
      discretize_zoh(F, G, h, Fd, Gd);
      const double c = std::cos(w * h), s = std::sin(w * h);
      Mat Fe(2, 2), Ge(2, 1);
      Fe << c, s / w, -w * s, c;
      Ge << (1 - c) / (w * w), s / w;
      const double scale = 1 + Fe.cwiseAbs().maxCoeff();
      EXPECT_LE((Fd - Fe).cwiseAbs().maxCoeff(), 1e-12 * scale * (1 + w * h)) << w << " " << h;
      EXPECT_LE((Gd - Ge).cwiseAbs().maxCoeff(), 1e-12 * scale * (1 + w * h)) << w << " " << h;
    }
  }
  // A defective block: exp([[a, 1], [0, a]] h) = e^{ah} [[1, h], [0, 1]].
  Mat J(2, 2);
  J << -4.0, 1.0, 0.0, -4.0;
  const Mat E = expm(J * 2.5);
  Mat Ee(2, 2);
  Ee << 1.0, 2.5, 0.0, 1.0;
  EXPECT_LE((E - std::exp(-10.0) * Ee).cwiseAbs().maxCoeff(), 1e-17);
  Mat Fd, Gd;
  EXPECT_THROW(discretize_zoh(J, Mat::Zero(2, 1), 0.0, Fd, Gd), std::invalid_argument);
  EXPECT_THROW(discretize_zoh(J, Mat::Zero(3, 1), 0.1, Fd, Gd), std::invalid_argument);
}

// What expm cannot vouch for is refused, not returned: a norm that overflows, and one so large
// that the squarings' rounding (2^s ε) would exceed 1e-6 (a nilpotent X h = [[0, h], [0, 0]] has
// e^{X h} = I + X h exactly; with h = 1e308 the squarings returned zeros). Below the limit the
// nilpotent case is I + X h to 2^s ε relative.
TEST(DiscreteTime, ExpmRefusesWhatItCannotVouchFor) {
  Mat X = Mat::Zero(2, 2);
  X(0, 1) = 1e308;
  EXPECT_THROW(expm(X), std::invalid_argument);
  X(0, 1) = 1e12;
  EXPECT_THROW(expm(X), std::invalid_argument);
  X(0, 0) = X(1, 1) = 1.7e308;  // a norm of 3.4e308: inf
  EXPECT_THROW(expm(X), std::invalid_argument);
  X = Mat::Zero(2, 2);
  X(0, 1) = 1e6;  // 18 squarings
  const Mat E = expm(X);
  EXPECT_LE((E - (Mat::Identity(2, 2) + X)).cwiseAbs().maxCoeff(),
            1e6 * std::ldexp(1.0, 18) * 1e-15);
  EXPECT_LE(std::abs(E(0, 0) - 1.0), std::ldexp(1.0, 18) * 1e-15);
}

// expm against its defining property e^{X} e^{−X} = I and the Taylor series for a small norm.
TEST(DiscreteTime, ExpmOfARandomMatrix) {
  std::mt19937 rng(3);
  std::normal_distribution<double> nd;
  Mat X(6, 6);
  for (Index i = 0; i < 6; ++i)
    for (Index j = 0; j < 6; ++j) X(i, j) = 0.05 * nd(rng);
  Mat taylor = Mat::Identity(6, 6), term = Mat::Identity(6, 6);
  for (int k = 1; k < 30; ++k) {
    term = term * X / k;
    taylor += term;
  }
  EXPECT_LE((expm(X) - taylor).cwiseAbs().maxCoeff(), 1e-15);
  const Mat Y = 40.0 * X;
  EXPECT_LE((expm(Y) * expm(-Y) - Mat::Identity(6, 6)).cwiseAbs().maxCoeff(), 1e-9);
}

#ifdef UKDYN_HAVE_IO
// The .npz writer's parts: CRC-32's check value (ITU-T V.42: "123456789" → 0xCBF43926), a .npy
// 1.0 header padded to 64 bytes with the shape as Python writes it, and the zip records.
TEST(DiscreteTime, NpzWriterParts) {
  EXPECT_EQ(io_detail::crc32("123456789"), 0xCBF43926u);
  EXPECT_EQ(io_detail::crc32(""), 0u);
  const std::string npy = io_detail::npy_bytes({"a", {2, 3}, {1, 2, 3, 4, 5, 6}});
  ASSERT_EQ(npy.size(), 128u + 6 * 8);  // 10 + 60 + 1 header bytes padded to 128
  EXPECT_EQ(npy.substr(0, 8), std::string("\x93NUMPY\x01\x00", 8));
  EXPECT_NE(npy.find("'shape': (2, 3), }"), std::string::npos);
  EXPECT_EQ(npy[127], '\n');
  double v = 0.0;
  std::memcpy(&v, npy.data() + 128 + 5 * 8, 8);
  EXPECT_EQ(v, 6.0);
  EXPECT_NE(io_detail::npy_bytes({"v", {4}, {1, 2, 3, 4}}).find("(4,)"), std::string::npos);
  EXPECT_NE(io_detail::npy_bytes({"s", {}, {7}}).find("'shape': ()"), std::string::npos);
  EXPECT_THROW((void)io_detail::npy_bytes({"x", {2}, {1}}), std::invalid_argument);
  const std::string zip = io_detail::npz_bytes({{"a", {1}, {1.5}}, {"b", {}, {2}}});
  EXPECT_EQ(zip.substr(0, 4), std::string("PK\x03\x04", 4));
  EXPECT_EQ(zip.substr(zip.size() - 22, 4), std::string("PK\x05\x06", 4));  // end record
  EXPECT_NE(zip.find("a.npy"), std::string::npos);
  EXPECT_NE(zip.find("b.npy"), std::string::npos);
}
#endif

#ifdef UKDYN_CLI
using nlohmann::json;
namespace fs = std::filesystem;

Mat mat_of(const json& j) {
  Mat M(static_cast<Index>(j.size()), static_cast<Index>(j.empty() ? 0 : j[0].size()));
  for (Index i = 0; i < M.rows(); ++i)
    for (Index k = 0; k < M.cols(); ++k)
      M(i, k) = j[static_cast<std::size_t>(i)][static_cast<std::size_t>(k)].get<double>();
  return M;
}

TEST(MinimalCoordinates, CliOptions) {
  const fs::path src = UKDYN_SOURCE_DIR, scratch = ukdyn_test::process_scratch("ukdyn_minimal");
  const std::string scen = ukdyn_test::sh((src / "scenarios" / "five_bar_redundant.yaml").string());
  auto run = [&](const std::string& args) {
    return ukdyn_test::run_cli(UKDYN_CLI, scratch, "linearize " + scen + " " + args);
  };
  const auto r = run("--minimal --dt 0.01");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const json j = json::parse(r.out);
  const Mat F = mat_of(j["F"]), Fd = mat_of(j["Fd"]);
  EXPECT_LE((Fd - expm(F * 0.01)).cwiseAbs().maxCoeff(), 1e-12);
  const json& mn = j["minimal"];
  EXPECT_LE(mn["null_residual"].get<double>(), 1e-12);
  EXPECT_LE(mn["ortho_residual"].get<double>(), 1e-12);
  const Mat Fm = mat_of(mn["F"]), Fdm = mat_of(mn["Fd"]);
  EXPECT_EQ(Fm.rows(), 2 * mn["dof"].get<Index>());
  EXPECT_LE((Fdm - expm(Fm * 0.01)).cwiseAbs().maxCoeff(), 1e-12);
  // --state: the same state from a file gives the same F; --out writes the same object.
  const auto q = j["q"], qd = j["qd"];
  std::ofstream(scratch / "state.json") << json{{"t", j["t"]}, {"q", q}, {"qd", qd}}.dump();
  const auto r2 = run("--state " + ukdyn_test::sh((scratch / "state.json").string()) + " --out " +
                      ukdyn_test::sh((scratch / "lin.json").string()));
  ASSERT_EQ(r2.exit_code, 0) << r2.err;
  const json j2 = json::parse(ukdyn_test::slurp(scratch / "lin.json"));
  EXPECT_EQ(mat_of(j2["F"]), F);
  // Bad input: the file and the key named, exit 2.
  std::ofstream(scratch / "bad.json") << R"({"q": [1, 2], "qd": []})";
  const auto r3 = run("--state " + ukdyn_test::sh((scratch / "bad.json").string()));
  EXPECT_EQ(r3.exit_code, 2);
  EXPECT_NE(r3.err.find("bad.json:1: key 'q'"), std::string::npos) << r3.err;
  const auto r4 = run("--row " + ukdyn_test::sh((scratch / "none.csv").string() + ":x"));
  EXPECT_EQ(r4.exit_code, 2);
  EXPECT_NE(r4.err.find("RUN.csv:N"), std::string::npos) << r4.err;
  const auto r5 = run("--dt -1");
  EXPECT_NE(r5.exit_code, 0);
  // An error once --out is named (a parameter that is not one, here) leaves no FILE behind.
  for (const char* name : {"half.json", "half.npz"}) {
    const auto rb = run("--param nope --out " + ukdyn_test::sh((scratch / name).string()));
    EXPECT_EQ(rb.exit_code, 2);
    EXPECT_NE(rb.err.find("parameter 'nope'"), std::string::npos) << rb.err;
    EXPECT_FALSE(fs::exists(scratch / name)) << name;
  }
  // A model that is not finite at the state (a mass of 1.7e308 times gravity): exit 2, the
  // scenario named, no FILE.
  const fs::path big = scratch / "huge_mass.yaml";
  std::ofstream(big) << "ukdyn: 1\nname: huge\nsubsystems:\n  - name: p\n    type: definitions\n"
                        "    coordinates: [x, y]\n    parameters: {m: 1.7e308}\n"
                        "    gravity: [0, -9.81, 0]\n    bodies:\n"
                        "      - {name: P1, mass: m, com: [x, y, 0]}\n"
                        "initial:\n  q: [1, 0]\nsimulation: {t_end: 0.1, sample_dt: 0.01}\n";
  const auto rh = ukdyn_test::run_cli(UKDYN_CLI, scratch,
                                      "linearize " + ukdyn_test::sh(big.string()) + " --out " +
                                          ukdyn_test::sh((scratch / "huge.json").string()));
  EXPECT_EQ(rh.exit_code, 2);
  EXPECT_NE(rh.err.find("huge_mass.yaml: linearize: the forward dynamics is not finite"),
            std::string::npos)
      << rh.err;
  EXPECT_FALSE(fs::exists(scratch / "huge.json"));
  // --row: a trajectory.csv with t, the coordinates and their _dot columns.
  std::string header = "t", row = "0.25";
  for (std::size_t i = 0; i < j["coordinates"].size(); ++i) {
    header += "," + j["coordinates"][i].get<std::string>();
    row += "," + json(q[i]).dump();
  }
  for (std::size_t i = 0; i < j["coordinates"].size(); ++i) {
    header += "," + j["coordinates"][i].get<std::string>() + "_dot";
    row += "," + json(qd[i]).dump();
  }
  std::ofstream(scratch / "run.csv") << header << "\n" << row << "\n" << row << "\n";
  const auto r6 = run("--row " + ukdyn_test::sh((scratch / "run.csv").string() + ":1"));
  ASSERT_EQ(r6.exit_code, 0) << r6.err;
  const json j6 = json::parse(r6.out);
  EXPECT_EQ(j6["t"].get<double>(), 0.25);
  EXPECT_EQ(mat_of(j6["F"]), F);
  const auto r7 = run("--row " + ukdyn_test::sh((scratch / "run.csv").string() + ":2"));
  EXPECT_EQ(r7.exit_code, 2);
  EXPECT_NE(r7.err.find("no data row 2"), std::string::npos) << r7.err;
}

// A state off the constraints (the five-bar's closure open by a hand-written q) is linearised, but
// said: a warning naming the row, and "constraint_residuals" equal to the closure's gap computed
// here by hand from the link lengths (d = 0.25, l1 = 0.3, l2 = 0.4 in five_bar_redundant.yaml).
TEST(LinearizeCli, AStateOffTheConstraintsIsLinearisedWithAWarning) {
  const fs::path src = UKDYN_SOURCE_DIR, scratch = ukdyn_test::process_scratch("ukdyn_minimal");
  const std::string scen = ukdyn_test::sh((src / "scenarios" / "five_bar_redundant.yaml").string());
  const double a1 = 1.0, a2 = 2.0, b1 = 3.0, b2 = 4.0, d = 0.25, l1 = 0.3, l2 = 0.4;
  std::ofstream(scratch / "open.json") << json{{"q", {a1, a2, b1, b2}}, {"qd", {0, 0, 0, 0}}};
  const auto r = ukdyn_test::run_cli(
      UKDYN_CLI, scratch,
      "linearize " + scen + " --state " + ukdyn_test::sh((scratch / "open.json").string()));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const double gap_x =
      (-d + l1 * std::cos(a1) + l2 * std::cos(a2)) - (d + l1 * std::cos(b1) + l2 * std::cos(b2));
  const double gap_z =
      (l1 * std::sin(a1) + l2 * std::sin(a2)) - (l1 * std::sin(b1) + l2 * std::sin(b2));
  const json j = json::parse(r.out);
  EXPECT_NEAR(j["constraint_residuals"]["position"].get<double>(),
              std::max(std::abs(gap_x), std::abs(gap_z)), 1e-12);
  const std::string row = std::abs(gap_x) > std::abs(gap_z) ? "end_x" : "end_z";
  EXPECT_EQ(j["constraint_residuals"]["row"], row);
  EXPECT_NE(r.err.find("warning: the state is off the constraints (row '" + row + "'"),
            std::string::npos)
      << r.err;
  // On the constraints (the scenario's own start): no warning, a residual at rounding level.
  const auto on = ukdyn_test::run_cli(UKDYN_CLI, scratch, "linearize " + scen);
  ASSERT_EQ(on.exit_code, 0) << on.err;
  EXPECT_EQ(on.err.find("warning"), std::string::npos) << on.err;
  EXPECT_LT(json::parse(on.out)["constraint_residuals"]["position"].get<double>(), 1e-12);
}

// --out FILE is the whole object or nothing: refused before the work when its folder is missing
// or FILE is a FIFO (whose open would block: no hang), a folder or a symbolic link (its target
// untouched); written through FILE.part renamed into place otherwise (no .part left behind).
TEST(LinearizeCli, OutIsWrittenWholeOrRefused) {
  const fs::path src = UKDYN_SOURCE_DIR, scratch = ukdyn_test::process_scratch("ukdyn_minimal");
  const std::string scen = ukdyn_test::sh((src / "scenarios" / "five_bar_redundant.yaml").string());
  auto out_to = [&](const fs::path& file) {
    return ukdyn_test::run_cli(UKDYN_CLI, scratch,
                               "linearize " + scen + " --out " + ukdyn_test::sh(file.string()), "",
                               "timeout -k 5 60 ");
  };
  const fs::path fifo = scratch / "pipe.json", link = scratch / "link.json",
                 target = scratch / "target.json";
  ASSERT_EQ(ukdyn_test::shell("mkfifo " + ukdyn_test::sh(fifo.string())), 0);
  std::ofstream(target) << "mine\n";
  fs::create_symlink(target, link);
  fs::create_directories(scratch / "folder.json");
  const std::pair<fs::path, const char*> refused[] = {
      {scratch / "missing" / "lin.json", "does not exist"},
      {fifo, "(a FIFO): refusing to replace it"},
      {scratch / "folder.json", "(a folder): refusing to replace it"},
      {link, "(a symbolic link): refusing to replace it"}};
  for (const auto& [file, why] : refused) {
    const auto r = out_to(file);
    EXPECT_EQ(r.exit_code, 2) << file << ": " << r.err;
    EXPECT_NE(r.err.find(why), std::string::npos) << r.err;
  }
  EXPECT_EQ(ukdyn_test::slurp(target), "mine\n");
  // A FIFO where FILE.part goes: refused, not opened (that would block until a reader came).
  ASSERT_EQ(ukdyn_test::shell("mkfifo " + ukdyn_test::sh((scratch / "trap.json.part").string())),
            0);
  const auto trap = out_to(scratch / "trap.json");
  EXPECT_EQ(trap.exit_code, 2) << trap.err;
  EXPECT_NE(trap.err.find("trap.json.part: exists and is not a regular file"), std::string::npos)
      << trap.err;
  EXPECT_FALSE(fs::exists(scratch / "trap.json"));
  const auto ok = out_to(scratch / "whole.npz");
  ASSERT_EQ(ok.exit_code, 0) << ok.err;
  EXPECT_TRUE(fs::is_regular_file(scratch / "whole.npz"));
  EXPECT_FALSE(fs::exists(scratch / "whole.npz.part"));
}
#endif

}  // namespace
