// Checks at the public edge (issue 10, item 7): forward, uk_solve and simulate reject wrong sizes
// and a ForwardData built for another system with std::invalid_argument naming the expected and
// the actual sizes; named lookups replace raw offsets.
#include <gtest/gtest.h>

#include <stdexcept>
#include <string>

#include "helpers.hpp"
#include "ukdyn/simulate/simulate.hpp"

namespace {

using ukdyn::Mat;
using ukdyn::Vec;

// The message of the std::invalid_argument f() throws ("" if it throws none).
template <class F>
std::string invalid_argument_of(F&& f) {
  try {
    f();
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

bool has(const std::string& s, const std::string& part) {
  return s.find(part) != std::string::npos;
}

TEST(EdgeChecks, ForwardRejectsWrongSizesWithExpectedAndActual) {
  uktest::TwoArms two;
  two.add_closure();
  const ukdyn::System& sys = *two.system;
  ukdyn::ForwardData data(sys);
  const Vec q = uktest::paper_q0(), qd = Vec::Zero(12), tau = Vec::Zero(12);
  EXPECT_EQ(invalid_argument_of([&] { ukdyn::forward(sys, data, 0.0, q, qd, tau); }), "");
  const Vec short_q = Vec::Zero(11);
  const std::string e =
      invalid_argument_of([&] { ukdyn::forward(sys, data, 0.0, short_q, qd, tau); });
  EXPECT_TRUE(has(e, "forward") && has(e, "q has 11 entries, expected 12")) << e;
  const Vec long_tau = Vec::Zero(13);
  const std::string e2 =
      invalid_argument_of([&] { ukdyn::forward(sys, data, 0.0, q, qd, long_tau); });
  EXPECT_TRUE(has(e2, "tau has 13 entries, expected 12")) << e2;
}

TEST(EdgeChecks, ForwardRejectsDataBuiltForAnotherSystem) {
  uktest::TwoArms a, b;
  a.add_closure();
  b.add_closure();
  ukdyn::ForwardData data_b(*b.system);
  const Vec q = uktest::paper_q0(), z = Vec::Zero(12);
  const std::string e =
      invalid_argument_of([&] { ukdyn::forward(*a.system, data_b, 0.0, q, z, z); });
  EXPECT_TRUE(has(e, "built for another System")) << e;
  // The same system, grown after the data was built.
  ukdyn::ForwardData early(*a.system);
  a.system->add_constraint(std::make_shared<ukdyn::CoordinateConstraint>(
      0, ukdyn::TimeFunction::make_constant(0.0), "hold"));
  const std::string e2 =
      invalid_argument_of([&] { ukdyn::forward(*a.system, early, 0.0, q, z, z); });
  EXPECT_TRUE(has(e2, "A rows") && has(e2, "expected 7")) << e2;
}

TEST(EdgeChecks, UkSolveRejectsWrongShapes) {
  const ukdyn::BlockLayout layout = ukdyn::BlockLayout::single(3);
  ukdyn::UkWorkspace ws(layout, 2);
  const Mat M = Mat::Identity(3, 3), A = Mat::Ones(2, 3);
  const Vec b = Vec::Zero(2), Q = Vec::Ones(3);
  Vec qdd(3), Qc(3);
  EXPECT_EQ(invalid_argument_of([&] { ukdyn::uk_solve(M, A, b, Q, ws, qdd, Qc); }), "");
  const std::string eM =
      invalid_argument_of([&] { ukdyn::uk_solve(Mat::Identity(4, 4), A, b, Q, ws, qdd, Qc); });
  EXPECT_TRUE(has(eM, "M is 4 x 4, expected 3 x 3")) << eM;
  const std::string eA = invalid_argument_of(
      [&] { ukdyn::uk_solve(M, Mat::Ones(3, 3), Vec::Zero(3), Q, ws, qdd, Qc); });
  EXPECT_TRUE(has(eA, "A (rows) is 3 x 3, expected 2 x 3")) << eA;
  const std::string eb =
      invalid_argument_of([&] { ukdyn::uk_solve(M, A, Vec::Zero(1), Q, ws, qdd, Qc); });
  EXPECT_TRUE(has(eb, "b is 1 x 1, expected 2 x 1")) << eb;
  const std::string eQ =
      invalid_argument_of([&] { ukdyn::uk_solve(M, A, b, Vec::Ones(2), ws, qdd, Qc); });
  EXPECT_TRUE(has(eQ, "Q is 2 x 1, expected 3 x 1")) << eQ;
}

TEST(EdgeChecks, SimulateRejectsWrongInitialSizes) {
  uktest::TwoArms two;
  two.add_closure();
  ukdyn::SimulationSettings s;
  const std::string e = invalid_argument_of(
      [&] { (void)ukdyn::simulate(*two.system, Vec::Zero(6), Vec::Zero(12), {}, s, nullptr); });
  EXPECT_TRUE(has(e, "q0 has 6 and qd0 12 entries, expected 12")) << e;
}

TEST(EdgeChecks, NamedLookups) {
  uktest::TwoArms two;
  two.add_closure();
  const ukdyn::System& sys = *two.system;
  EXPECT_EQ(sys.coordinate_index("dx1"), 0);
  EXPECT_EQ(sys.coordinate_index("dx2"), 6);
  EXPECT_EQ(sys.constraint_row_index("closure_z"), 2);
  const std::string e = invalid_argument_of([&] { (void)sys.coordinate_index("nope"); });
  EXPECT_TRUE(has(e, "no coordinate named 'nope'")) << e;
  EXPECT_THROW((void)sys.constraint_row_index("closure_w"), std::invalid_argument);
}

}  // namespace
