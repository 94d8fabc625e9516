// Generated code (issue 15, class 1): `ukdyn derive --format c` output compiles with the system C
// compiler, and the compiled M, C and G agree with ukdyn's own evaluation of the same scenario (the
// tapes of symbolic/tape.cpp: a second, independent way from the same derivation to numbers). Names
// that collide with the generated code (a parameter M, a coordinate b) are renamed, not
// miscompiled; comment text can never end its comment early, whatever it holds.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "cli_run.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/symbolic/definitions.hpp"

#if defined(UKDYN_CLI) && defined(UKDYN_HAVE_IO)

namespace {

namespace fs = std::filesystem;
using ukdyn_test::shell;
using ukdyn_test::slurp;
const fs::path kSource = UKDYN_SOURCE_DIR;

const fs::path& scratch() { return ukdyn_test::process_scratch("ukdyn_generated_code"); }

bool have_cc() { return shell("command -v cc > /dev/null 2>&1") == 0; }

// A definitions scenario whose names collide with the generated C (M, C, G, q, b, A, Phi, qd).
const char* kCollidingNames = R"(ukdyn: 1
name: colliding
subsystems:
  - name: cart
    type: definitions
    coordinates: [b, A]
    parameters: {M: 5, C: 2, G: 0.8, q: 0.3, qd: 1.5, Phi: 0.25}
    bodies:
      - {name: cart, mass: M, com: [b, 0, 0]}
      - {name: bob, mass: C, com: [b + G*sin(A), 0, -G*cos(A)], inertia: q, angular_velocity: [0, A_dot, 0]}
    potential: Phi*qd*A^2 + pi*b^2
constraints:
  - {type: expression, name: row, parameters: {G: 0.8, M: 2}, rows: ["b + G*sin(A) - 0.1*M*t - pi/10"]}
initial: {q: [0.3141592653589793, 0], qd: [0.2, 0]}
simulation: {t_end: 1, sample_dt: 0.1}
)";

// Compiles SCENARIO's C output with a main() that evaluates the first subsystem's dynamics at q,
// qd and prints M, C, G; returns the numbers (empty on failure, with the reason in `why`).
std::vector<double> compiled_dynamics(const fs::path& scenario, const std::string& function,
                                      const std::vector<double>& q, const std::vector<double>& qd,
                                      std::string& why) {
  const std::string stem = scenario.stem().string();
  const fs::path c = scratch() / (stem + ".c"), exe = scratch() / stem,
                 err = scratch() / (stem + ".err");
  if (shell(std::string("'") + UKDYN_CLI + "' derive '" + scenario.string() + "' --format c > '" +
         c.string() + "' 2> '" + err.string() + "'") != 0) {
    why = "derive failed: " + slurp(err);
    return {};
  }
  const std::size_t n = q.size();
  std::ostringstream main;
  main << "\n#include <stdio.h>\nint main(void) {\n  double q[" << n << "] = {";
  for (std::size_t i = 0; i < n; ++i) main << (i ? ", " : "") << q[i];
  main << "}, qd[" << n << "] = {";
  for (std::size_t i = 0; i < n; ++i) main << (i ? ", " : "") << qd[i];
  main << "};\n  double M[" << n << "][" << n << "], C[" << n << "][" << n << "], G[" << n
       << "];\n  " << function << "(q, qd, M, C, G);\n"
       << "  for (int i = 0; i < " << n << "; ++i) for (int j = 0; j < " << n
       << "; ++j) printf(\"%.17g\\n\", M[i][j]);\n"
       << "  for (int i = 0; i < " << n << "; ++i) for (int j = 0; j < " << n
       << "; ++j) printf(\"%.17g\\n\", C[i][j]);\n"
       << "  for (int i = 0; i < " << n << "; ++i) printf(\"%.17g\\n\", G[i]);\n  return 0;\n}\n";
  std::ofstream(c, std::ios::app) << main.str();
  if (shell("cc -std=c99 -Wall -Wextra -Werror -O1 -o '" + exe.string() + "' '" + c.string() +
         "' -lm 2> '" + err.string() + "'") != 0) {
    why = "cc failed:\n" + slurp(err) + "\n" + slurp(c).substr(0, 4000);
    return {};
  }
  const fs::path out = scratch() / (stem + ".out");
  if (shell("'" + exe.string() + "' > '" + out.string() + "'") != 0) {
    why = "the compiled program failed";
    return {};
  }
  std::istringstream in(slurp(out));
  std::vector<double> v;
  for (double x = 0; in >> x;) v.push_back(x);
  return v;
}

void expect_agrees(const fs::path& scenario, const std::string& function) {
  const ukdyn::Scenario sc = ukdyn::load_scenario(scenario);
  const auto& sub = *sc.system->subsystems()[0];
  const ukdyn::Index n = sub.dof();
  ukdyn::Vec q(n), qd(n);
  for (ukdyn::Index i = 0; i < n; ++i) {
    q(i) = 0.3 + 0.17 * static_cast<double>(i);
    qd(i) = -0.4 + 0.23 * static_cast<double>(i);
  }
  std::string why;
  const std::vector<double> v =
      compiled_dynamics(scenario, function, std::vector<double>(q.data(), q.data() + n),
                        std::vector<double>(qd.data(), qd.data() + n), why);
  ASSERT_EQ(v.size(), static_cast<std::size_t>(2 * n * n + n)) << why;
  ukdyn::Mat M(n, n), C(n, n);
  ukdyn::Vec G(n);
  sub.mass({}, q, M);
  sub.coriolis({}, q, qd, C);
  sub.gravity({}, q, G);
  std::size_t k = 0;
  auto near = [](double a, double b) { return std::abs(a - b) <= 1e-10 * (1 + std::abs(b)); };
  for (ukdyn::Index i = 0; i < n; ++i)
    for (ukdyn::Index j = 0; j < n; ++j, ++k)
      EXPECT_TRUE(near(v[k], M(i, j)))
          << "M(" << i << "," << j << "): " << v[k] << " vs " << M(i, j);
  for (ukdyn::Index i = 0; i < n; ++i)
    for (ukdyn::Index j = 0; j < n; ++j, ++k)
      EXPECT_TRUE(near(v[k], C(i, j)))
          << "C(" << i << "," << j << "): " << v[k] << " vs " << C(i, j);
  for (ukdyn::Index i = 0; i < n; ++i, ++k)
    EXPECT_TRUE(near(v[k], G(i))) << "G(" << i << "): " << v[k] << " vs " << G(i);
}

TEST(GeneratedCode, DeriveCCompilesAndAgreesWithTheTapes) {
  if (!have_cc()) GTEST_SKIP() << "no C compiler (cc)";
  expect_agrees(kSource / "scenarios" / "paper_generic.yaml", "left_dynamics");
  expect_agrees(kSource / "scenarios" / "paper_chain.yaml", "left_dynamics");
  expect_agrees(kSource / "scenarios" / "paper_urdf.yaml", "left_dynamics");
  expect_agrees(kSource / "scenarios" / "five_bar_redundant.yaml", "left_arm_dynamics");
  expect_agrees(kSource / "scenarios" / "rolling_disk.yaml", "disk_dynamics");
}

TEST(GeneratedCode, NamesThatCollideWithTheGeneratedCodeAreRenamed) {
  if (!have_cc()) GTEST_SKIP() << "no C compiler (cc)";
  const fs::path file = scratch() / "colliding.yaml";
  std::ofstream(file) << kCollidingNames;
  expect_agrees(file, "cart_dynamics");
  // MATLAB: the parameter M must not be the matrix M.
  const fs::path m = scratch() / "colliding.m";
  ASSERT_EQ(shell(std::string("'") + UKDYN_CLI + "' derive '" + file.string() +
               "' --format matlab > '" + m.string() + "'"),
            0);
  const std::string text = slurp(m);
  EXPECT_NE(text.find("M_ = 5"), std::string::npos) << text;
  EXPECT_EQ(text.find("\nM = 5"), std::string::npos) << text;
  EXPECT_NE(text.find("pi"), std::string::npos) << text;
}

// Comment text is reduced to printable ASCII and a C comment cannot be closed from inside: a row
// name (checked on loading; here built directly) with CR, LF and "*/" stays inside its comment.
TEST(GeneratedCode, CommentTextCannotEndItsComment) {
  namespace sym = ukdyn::symbolic;
  sym::ConstraintDef def("c", sym::ConstraintDef::Kind::holonomic, {"x"});
  def.add_row("r\r\n*/ int evil; /*\n// x", sym::coordinate_symbol(def.symbols(), "x"));
  const sym::ConstraintDerivation d = sym::derive(def);
  for (auto f : {sym::Format::c, sym::Format::latex, sym::Format::matlab, sym::Format::text}) {
    const std::string out = sym::format_derivation(d, "c\r\nevil", f);
    EXPECT_EQ(out.find('\r'), std::string::npos);
    std::istringstream lines(out);
    for (std::string line; std::getline(lines, line);) {
      if (line.find("evil") == std::string::npos) continue;
      // The line holding the text is a comment from its first character to its last.
      if (f == sym::Format::c) {
        EXPECT_EQ(line.rfind("/* ", 0), 0u) << line;
        EXPECT_EQ(line.find("*/"), line.size() - 2) << line;
      } else {
        EXPECT_TRUE(line[0] == '%' || line[0] == '#') << line;
      }
    }
  }
}

}  // namespace

#endif
