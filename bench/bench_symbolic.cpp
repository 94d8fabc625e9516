// ukdyn::symbolic benchmarks: deriving the paper's arm from definitions (GiNaC) and evaluating the
// compiled tapes against the hand-written closed form (src/paper_robot/mobile_manipulator.cpp).
//   Symbolic/DerivePaperArm        derive M, C, G, C q̇ of one arm and compile its tapes
//   Symbolic/DynamicsDerived       M + C q̇ + G of one arm from the tapes (dynamics(): one tape)
//   Symbolic/DynamicsClosedForm    the same from the closed form (dynamics(): shared trig)
//   Symbolic/ClosureDerived        A, b of the 6 closure rows (Eq. 12) from the tapes
//   Symbolic/ClosureClosedForm     the same from ukdyn::ClosureConstraint
//   forward/closure_definitions    forward() of the whole paper system built from definitions (two
//                                  derived arms + the derived closure), at the state of
//                                  forward/closure (bench_ukdyn.cpp): the ratio of the two is the
//                                  cost of forward dynamics from definitions
//   Symbolic/Chain7MassEval        the mass tape of a derived 7-link spatial chain (M's upper
//                                  triangle, 28 outputs): Tape::eval
//   Symbolic/Chain7MassTangent1    the same with its tangent along one direction of q
//                                  (Tape::eval_tangent)
//   Symbolic/Chain7MassTangent7    the same along the 7 unit directions at once: every ∂M/∂q_j
//                                  (Tape::eval_tangents, K = 7)
#include <benchmark/benchmark.h>

#include <algorithm>
#include <memory>
#include <random>
#include <string>

#include "bench_common.hpp"
#include "paper_model.hpp"
#include "ukdyn/model/system.hpp"
#include "ukdyn/paper_robot/cooperative_constraints.hpp"
#include "ukdyn/paper_robot/mobile_manipulator.hpp"
#include "ukdyn/symbolic/chain.hpp"
#include "ukdyn/symbolic/definitions.hpp"
#include "ukdyn/symbolic/tape_inputs.hpp"

namespace {

namespace sym = ukdyn::symbolic;
using ukdyn::Mat;
using ukdyn::Vec;

// The paper's arm (Table 1) by definitions, coordinates suffixed by `s`.
sym::SubsystemDef paper_arm(const std::string& s) {
  const std::string dx = "bx" + s, dy = "by" + s, de = "bdelta" + s, t1 = "bth1" + s,
                    t2 = "bth2" + s, t3 = "bth3" + s;
  sym::SubsystemDef d("arm" + s, {dx, dy, de, t1, t2, t3});
  for (const auto& [n, v] : std::vector<std::pair<std::string, double>>{{"mv", 50},
                                                                        {"mr", 2},
                                                                        {"Ir", 0.0625},
                                                                        {"lr", 0.5},
                                                                        {"m1", 3},
                                                                        {"m2", 4},
                                                                        {"m3", 1},
                                                                        {"I1", 0.49},
                                                                        {"I2", 0.855},
                                                                        {"I3", 0.08},
                                                                        {"l1", 0.7},
                                                                        {"l2", 0.8},
                                                                        {"l3", 0.4}}) {
    d.parameter(n, v);
  }
  const std::string r[3] = {"l1/2*cos(" + t1 + ")", "l1*cos(" + t1 + ") + l2/2*cos(" + t2 + ")",
                            "l1*cos(" + t1 + ") + l2*cos(" + t2 + ") + l3/2*cos(" + t3 + ")"};
  const std::string h[3] = {"lr + l1/2*sin(" + t1 + ")",
                            "lr + l1*sin(" + t1 + ") + l2/2*sin(" + t2 + ")",
                            "lr + l1*sin(" + t1 + ") + l2*sin(" + t2 + ") + l3/2*sin(" + t3 + ")"};
  auto& p = d.add_body("platform");
  p.mass = d.parse("mv");
  p.com = {d.parse(dx), d.parse(dy), 0};
  auto& j = d.add_body("joint_r");
  j.mass = d.parse("mr");
  j.com = {d.parse(dx), d.parse(dy), d.parse("lr/2")};
  j.inertia_kind = sym::BodyDef::InertiaKind::scalar;
  j.inertia_scalar = d.parse("Ir");
  j.angular_velocity = std::array<GiNaC::ex, 3>{0, 0, d.parse(de + "_dot")};
  const std::string th[3] = {t1, t2, t3};
  for (int k = 0; k < 3; ++k) {
    auto& b = d.add_body("link" + std::to_string(k + 1));
    b.mass = d.parse("m" + std::to_string(k + 1));
    b.com = {d.parse(dx + " + (" + r[k] + ")*cos(" + de + ")"),
             d.parse(dy + " + (" + r[k] + ")*sin(" + de + ")"), d.parse(h[k])};
    b.inertia_kind = sym::BodyDef::InertiaKind::scalar;
    b.inertia_scalar = d.parse("I" + std::to_string(k + 1));
    b.angular_velocity = std::array<GiNaC::ex, 3>{0, d.parse(th[k] + "_dot"), d.parse(de + "_dot")};
  }
  d.gravity = {0, 0, d.parse("-9.8")};
  return d;
}

std::shared_ptr<sym::DerivedConstraint> paper_closure() {
  std::vector<std::string> coords;
  for (const std::string s : {"L", "R"}) {
    for (const char* c : {"bx", "by", "bdelta", "bth1", "bth2", "bth3"}) coords.push_back(c + s);
  }
  sym::ConstraintDef c("closure", sym::ConstraintDef::Kind::holonomic, coords);
  c.parameter("l1", 0.7);
  c.parameter("l2", 0.8);
  c.parameter("l3", 0.4);
  c.let("k1", c.parse("l1*cos(bth1L) + l2*cos(bth2L) + l3*cos(bth3L)"));
  c.let("k2", c.parse("l1*cos(bth1R) + l2*cos(bth2R) + l3*cos(bth3R)"));
  c.add_row("x", c.parse("bxL + k1*cos(bdeltaL) - bxR - k2*cos(bdeltaR)"));
  c.add_row("y", c.parse("byL + k1*sin(bdeltaL) - byR - k2*sin(bdeltaR)"));
  c.add_row("z", c.parse("l1*sin(bth1L) + l2*sin(bth2L) + l3*sin(bth3L) - l1*sin(bth1R) - "
                         "l2*sin(bth2R) - l3*sin(bth3R)"));
  c.add_row("yaw", c.parse("bdeltaL - bdeltaR - pi"));
  c.add_row("load1", c.parse("bth3L"));
  c.add_row("load2", c.parse("bth3R"));
  return sym::make_constraint(c);
}

Vec random_state(std::mt19937_64& rng, ukdyn::Index n) {
  std::uniform_real_distribution<double> u(-1.5, 1.5);
  Vec v(n);
  for (ukdyn::Index i = 0; i < n; ++i) v(i) = u(rng);
  return v;
}

void Symbolic_DerivePaperArm(benchmark::State& state) {
  const sym::SubsystemDef d = paper_arm("D");
  for (auto _ : state) {
    auto sub = sym::make_subsystem(d);
    benchmark::DoNotOptimize(sub);
  }
}
BENCHMARK(Symbolic_DerivePaperArm)->Unit(benchmark::kMillisecond)->Apply(ukbench::add_min_max);

template <class Make>
void dynamics(benchmark::State& state, Make make) {
  const auto sub = make();
  std::mt19937_64 rng(1);
  const Vec q = random_state(rng, 6), qd = random_state(rng, 6);
  Mat M(6, 6);
  Vec c(6), g(6);
  for (auto _ : state) {
    sub->dynamics({}, q, qd, M, c, g);  // what forward() calls
    benchmark::DoNotOptimize(M.data());
    benchmark::DoNotOptimize(c.data());
    benchmark::DoNotOptimize(g.data());
  }
}

void Symbolic_DynamicsDerived(benchmark::State& state) {
  dynamics(state, [] {
    return std::shared_ptr<const ukdyn::Subsystem>(sym::make_subsystem(paper_arm("E")));
  });
}
BENCHMARK(Symbolic_DynamicsDerived)->Apply(ukbench::add_min_max);

void Symbolic_DynamicsClosedForm(benchmark::State& state) {
  dynamics(state, [] {
    return std::shared_ptr<const ukdyn::Subsystem>(std::make_shared<ukdyn::MobileManipulator>(
        "arm", ukdyn::MobileManipulatorParams{},
        std::vector<std::string>{"a", "b", "c", "d", "e", "f"}));
  });
}
BENCHMARK(Symbolic_DynamicsClosedForm)->Apply(ukbench::add_min_max);

void closure(benchmark::State& state, const ukdyn::Constraint& c) {
  std::mt19937_64 rng(2);
  const Vec q = random_state(rng, 12), qd = random_state(rng, 12);
  Mat A(6, 12);
  Vec b(6);
  for (auto _ : state) {
    A.setZero();
    c.evaluate({}, q, qd, A, b);
    benchmark::DoNotOptimize(A.data());
    benchmark::DoNotOptimize(b.data());
  }
}

void Symbolic_ClosureDerived(benchmark::State& state) {
  const auto c = paper_closure();
  closure(state, *c);
}
BENCHMARK(Symbolic_ClosureDerived)->Apply(ukbench::add_min_max);

void Symbolic_ClosureClosedForm(benchmark::State& state) {
  auto l = std::make_shared<ukdyn::MobileManipulator>(
      "l", ukdyn::MobileManipulatorParams{},
      std::vector<std::string>{"a", "b", "c", "d", "e", "f"});
  auto r = std::make_shared<ukdyn::MobileManipulator>(
      "r", ukdyn::MobileManipulatorParams{},
      std::vector<std::string>{"g", "h", "i", "j", "k", "m"});
  const ukdyn::ClosureConstraint c(l, 0, r, 6, {});
  closure(state, c);
}
BENCHMARK(Symbolic_ClosureClosedForm)->Apply(ukbench::add_min_max);

// The paper's closure system from definitions only; the same equations as ukbench::paper_model()
// (scalar inertias, Table 1), so forward() must give the same q̈ (checked before timing).
const ukdyn::System& definitions_closure_system() {
  static const ukdyn::System sys = [] {
    ukdyn::System s;
    s.add_subsystem(sym::make_subsystem(paper_arm("L")));
    s.add_subsystem(sym::make_subsystem(paper_arm("R")));
    s.add_constraint(paper_closure());
    return s;
  }();
  return sys;
}

void Forward_ClosureDefinitions(benchmark::State& state) {
  const ukdyn::System& sys = definitions_closure_system();
  const ukbench::PaperModel& pm = ukbench::paper_model();
  ukdyn::ForwardData data(sys), ref(pm.closure);
  const Vec tau = Vec::Zero(12);
  ukdyn::forward(pm.closure, ref, 0.0, pm.q0, pm.qd0_spatial, tau);
  ukdyn::forward(sys, data, 0.0, pm.q0, pm.qd0_spatial, tau);
  const double diff = (data.qdd - ref.qdd).cwiseAbs().maxCoeff();
  if (!(diff <= 1e-10 * (1.0 + ref.qdd.cwiseAbs().maxCoeff()))) {
    state.SkipWithError("definitions and closed form disagree on q̈");
    return;
  }
  for (auto _ : state) {
    ukdyn::forward(sys, data, 0.0, pm.q0, pm.qd0_spatial, tau);
    benchmark::DoNotOptimize(data.qdd.data());
    benchmark::ClobberMemory();
  }
  state.counters["rank"] = data.result.rank;
  state.counters["qdd_diff"] = diff;
}
BENCHMARK(Forward_ClosureDefinitions)
    ->Name("forward/closure_definitions")
    ->Apply(ukbench::add_min_max);

// A 7-link spatial chain, derived (revolute joints about z and y in turn, 0.3 m apart along x, as
// tree/chain_7 of bench_tree.cpp): the tape of its mass matrix's upper triangle.
sym::Tape chain7_mass_tape() {
  using JT = sym::JointDef::Type;
  std::vector<std::string> q;
  for (int i = 0; i < 7; ++i) q.push_back("tq" + std::to_string(i));
  sym::ChainDef c("tangent_chain", q);
  c.gravity = {0, 0, GiNaC::numeric(-981, 100)};
  for (int i = 0; i < 7; ++i) {
    auto& j = c.add_joint("j" + std::to_string(i), JT::revolute, "l" + std::to_string(i));
    j.origin.xyz = {i == 0 ? GiNaC::ex(0) : GiNaC::numeric(3, 10), 0, 0};
    j.axis = i % 2 == 0 ? sym::Vec3Ex{0, 0, 1} : sym::Vec3Ex{0, 1, 0};
    j.coordinate = q[static_cast<std::size_t>(i)];
    j.inertial.mass = 1;
    j.inertial.com = {GiNaC::numeric(15, 100), 0, 0};
    j.inertial.inertia = {GiNaC::numeric(1, 100), 0, 0, 0, GiNaC::numeric(2, 100), 0, 0, 0,
                          GiNaC::numeric(2, 100)};
  }
  const sym::SubsystemDerivation d = sym::derive(sym::build_chain(c).def);
  std::vector<GiNaC::ex> m;
  for (unsigned i = 0; i < 7; ++i) {
    for (unsigned j = i; j < 7; ++j) m.push_back(d.M(i, j).subs(d.parameter_values).expand());
  }
  return sym::Tape(m, sym::coordinate_inputs(*d.symbols, d.coordinates, sym::InputSet::q));
}

// Derived once per process (about a minute of GiNaC on a loaded machine), on first use: a run
// filtered to other benchmarks does not pay for it.
const sym::Tape& chain7_mass() {
  static const sym::Tape tape = chain7_mass_tape();
  return tape;
}

// K = 0: eval; K = 1: eval_tangent along a random direction; K = 7: eval_tangents along the unit
// directions e_0 .. e_6 (the whole Jacobian of M).
void chain7_mass(benchmark::State& state, std::size_t K) {
  const sym::Tape& tape = chain7_mass();
  std::mt19937_64 rng(1);
  const Vec q = random_state(rng, 7);
  const std::size_t m = tape.outputs(), W = tape.work_size(), lanes = std::max<std::size_t>(K, 1);
  std::vector<double> out(m), dout(m * lanes), work(W), dwork(W * lanes);
  Mat dirs = Mat::Identity(7, 7);
  if (K == 1) dirs.col(0) = random_state(rng, 7);
  for (auto _ : state) {
    if (K == 0) {
      tape.eval(0.0, q.data(), nullptr, out.data(), work.data());
    } else if (K == 1) {
      tape.eval_tangent(0.0, q.data(), nullptr, 0.0, dirs.data(), nullptr, out.data(), dout.data(),
                        work.data(), dwork.data());
    } else {
      tape.eval_tangents(K, 0.0, q.data(), nullptr, nullptr, dirs.data(), 7, nullptr, 0, out.data(),
                         dout.data(), work.data(), dwork.data());
    }
    benchmark::DoNotOptimize(out.data());
    benchmark::DoNotOptimize(dout.data());
    benchmark::ClobberMemory();
  }
  state.counters["instructions"] = static_cast<double>(tape.executed_instructions());
}
void Symbolic_Chain7MassEval(benchmark::State& state) { chain7_mass(state, 0); }
void Symbolic_Chain7MassTangent1(benchmark::State& state) { chain7_mass(state, 1); }
void Symbolic_Chain7MassTangent7(benchmark::State& state) { chain7_mass(state, 7); }
BENCHMARK(Symbolic_Chain7MassEval)->Apply(ukbench::add_min_max);
BENCHMARK(Symbolic_Chain7MassTangent1)->Apply(ukbench::add_min_max);
BENCHMARK(Symbolic_Chain7MassTangent7)->Apply(ukbench::add_min_max);

}  // namespace
