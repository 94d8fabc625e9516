// Singular causes are named (issue 15 class 5): a mass matrix that becomes singular during a run,
// and an assembly that "converges" by sending a coordinate to 1e14.
#include <gtest/gtest.h>

#include <string>

#include "ukdyn/simulate/simulate.hpp"

#ifdef UKDYN_HAVE_IO
#include "ukdyn/scenario/scenario.hpp"

namespace {

// T = ½ (2a)² ȧ² (a point mass at x = a²): M = 4a² vanishes at a = 0, which the motion from
// a = 1, ȧ = −1 reaches (p = 2a²ȧ... the velocity of the mass, 2aȧ, is constant: a² = 1 − 2t).
TEST(SingularDiagnostics, SingularMassMatrixIsNamed) {
  const std::string text = R"(ukdyn: 1
name: singular_mass
gravity: 0
subsystems:
  - name: s
    type: definitions
    coordinates: [a, b]
    gravity: [0, 0, 0]
    bodies:
      - {name: p, mass: 1, com: [a^2, 0, 0]}
      - {name: r, mass: 1, com: [0, b, 0]}
initial:
  q: [1, 0]
  qd: [-1, 0]
simulation:
  t_end: 1
  sample_dt: 0.01
)";
  const ukdyn::Scenario sc = ukdyn::load_scenario_text(text, "singular_mass.yaml");
  const auto st =
      ukdyn::simulate(*sc.system, sc.q0, sc.qd0, ukdyn::ForceFunction{}, sc.sim, nullptr);
  ASSERT_NE(st.status, ukdyn::RunStatus::completed);
  EXPECT_NE(st.message.find("mass matrix"), std::string::npos) << st.message;
  EXPECT_NE(st.message.find("[a]"), std::string::npos) << st.message;
  EXPECT_LT(st.t_reached, 0.51);
}

// Φ = 1/x: Gauss–Newton doubles x each iteration and |Φ| falls under any tolerance once x ~ 1e14;
// that is not an assembly near the guess and must be reported as a failure naming x.
TEST(SingularDiagnostics, AssemblyRefusesAnUnboundedMove) {
  const std::string text = R"(ukdyn: 1
name: runaway
gravity: 0
subsystems:
  - name: s
    type: definitions
    coordinates: [x]
    gravity: [0, 0, 0]
    bodies:
      - {name: p, mass: 1, com: [x, 0, 0]}
constraints:
  - {type: expression, name: c, rows: [1/x]}
initial:
  q: [1]
simulation:
  t_end: 1
  sample_dt: 0.01
)";
  ukdyn::LoadOptions opt;
  opt.check_initial = false;
  const ukdyn::Scenario sc = ukdyn::load_scenario_text(text, "runaway.yaml", opt);
  const auto a = ukdyn::assemble(*sc.system, 0.0, sc.q0, sc.qd0, sc.held);
  EXPECT_FALSE(a.success);
  EXPECT_NE(a.message.find("'x'"), std::string::npos) << a.message;
  EXPECT_NE(a.message.find("beyond the bound"), std::string::npos) << a.message;
}

}  // namespace
#endif
