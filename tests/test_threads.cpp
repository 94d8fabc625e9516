// One System shared by several threads, each with its own ForwardData and its own simulation: the
// results are bit-identical to a single-threaded run (issue 10, item 2). Run under ThreadSanitizer
// by `make tsan` (scripts/tsan.sh), which also reports any data race these runs would have.
//
// Two systems: the paper's closed-form one (its arms hand sin/cos to the constraints through the
// ForwardData slots) and one built from definitions, whose tapes run with slot workspaces and
// whose constraint follows a cubic spline.
#include <gtest/gtest.h>

#include <cstring>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "helpers.hpp"
#include "symbolic_systems.hpp"
#include "ukdyn/simulate/simulate.hpp"
#include "ukdyn/symbolic/definitions.hpp"

namespace {

using ukdyn::Vec;

struct Case {
  std::shared_ptr<const ukdyn::System> system;
  Vec q0, qd0;
  ukdyn::SimulationSettings settings;
};

// The paper's scenario: closure + trajectory constraints (Eqs. (12), (19)), projection drift
// control.
Case paper_case() {
  uktest::TwoArms two;
  Case c;
  c.q0 = uktest::paper_q0();
  two.add_closure();
  two.add_paper_trajectory(c.q0);
  c.system = two.system;
  c.qd0 = Vec::Zero(12);
  c.settings.t_end = 0.5;
  c.settings.sample_dt = 0.05;
  c.settings.integrator = ukdyn::IntegratorKind::dopri5;
  c.settings.abs_tol = c.settings.rel_tol = 1e-10;
  return c;
}

Case definitions_case() {
  Case c;
  c.system = uktest::spline_cart_system("thr_");
  c.q0 = Vec::Zero(2);
  c.q0(1) = 0.3;
  c.qd0 = Vec::Zero(2);
  c.settings.t_end = 1.0;
  c.settings.sample_dt = 0.05;
  c.settings.integrator = ukdyn::IntegratorKind::rkf78;
  c.settings.abs_tol = c.settings.rel_tol = 1e-11;
  return c;
}

// Every sample's t, q, q̇, q̈ and Qc, as bytes (compared with memcmp: bit-identical or not).
struct RunRecord {
  std::vector<double> values;
  ukdyn::RunStatus status = ukdyn::RunStatus::stopped;
  std::string message;
};

RunRecord run(const Case& c) {
  RunRecord r;
  const auto stats = ukdyn::simulate(
      *c.system, c.q0, c.qd0, {}, c.settings,
      [&](double t, ukdyn::CVecRef q, ukdyn::CVecRef qd, const ukdyn::ForwardData& d) {
        r.values.push_back(t);
        r.values.insert(r.values.end(), q.data(), q.data() + q.size());
        r.values.insert(r.values.end(), qd.data(), qd.data() + qd.size());
        r.values.insert(r.values.end(), d.qdd.data(), d.qdd.data() + d.qdd.size());
        r.values.insert(r.values.end(), d.Qc.data(), d.Qc.data() + d.Qc.size());
        return true;
      });
  r.status = stats.status;
  r.message = stats.message;
  return r;
}

bool same_bytes(const std::vector<double>& a, const std::vector<double>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(double)) == 0;
}

void expect_threads_match_single(const Case& c, int threads, int runs_per_thread) {
  const RunRecord ref = run(c);
  ASSERT_EQ(ref.status, ukdyn::RunStatus::completed) << ref.message;
  ASSERT_GT(ref.values.size(), 10u);
  std::vector<std::vector<RunRecord>> got(static_cast<std::size_t>(threads));
  std::vector<std::thread> pool;
  for (int k = 0; k < threads; ++k) {
    pool.emplace_back([&, k] {
      for (int i = 0; i < runs_per_thread; ++i) got[static_cast<std::size_t>(k)].push_back(run(c));
    });
  }
  for (auto& th : pool) th.join();
  for (int k = 0; k < threads; ++k) {
    for (const RunRecord& r : got[static_cast<std::size_t>(k)]) {
      EXPECT_EQ(r.status, ukdyn::RunStatus::completed) << "thread " << k << ": " << r.message;
      EXPECT_TRUE(same_bytes(r.values, ref.values))
          << "thread " << k << " differs from the single-threaded run";
    }
  }
}

TEST(Threads, PaperSystemSharedByFourThreadsIsBitIdentical) {
  expect_threads_match_single(paper_case(), 4, 2);
}

TEST(Threads, DefinitionsSystemWithSplineSharedByFourThreadsIsBitIdentical) {
  expect_threads_match_single(definitions_case(), 4, 2);
}

// The two systems at once, interleaved on the same threads (each thread alternates).
TEST(Threads, BothSystemsInterleavedOnFourThreads) {
  const Case a = paper_case(), b = definitions_case();
  const RunRecord ra = run(a), rb = run(b);
  ASSERT_EQ(ra.status, ukdyn::RunStatus::completed) << ra.message;
  ASSERT_EQ(rb.status, ukdyn::RunStatus::completed) << rb.message;
  std::vector<int> ok(4, 0);
  std::vector<std::thread> pool;
  for (int k = 0; k < 4; ++k) {
    pool.emplace_back([&, k] {
      const bool first_a = k % 2 == 0;
      const RunRecord x = run(first_a ? a : b);
      const RunRecord y = run(first_a ? b : a);
      ok[static_cast<std::size_t>(k)] = same_bytes(x.values, (first_a ? ra : rb).values) &&
                                        same_bytes(y.values, (first_a ? rb : ra).values);
    });
  }
  for (auto& th : pool) th.join();
  for (int k = 0; k < 4; ++k) EXPECT_EQ(ok[static_cast<std::size_t>(k)], 1) << "thread " << k;
}

// Two systems derived on two threads, each with its own symbol table (nothing of ukdyn's shared),
// then simulated on both threads at once: the bytes of the single-threaded derivation and run.
// GiNaC itself is not thread-safe (its shared numeric constants and symbol serials), so the two
// derivations, and the destruction of what they made, take turns on a mutex; the runs do not.
TEST(Threads, SystemsDerivedOnTwoThreadsMatchTheSingleThreadedOne) {
  const Case c = definitions_case();
  const RunRecord ref = run(c);
  ASSERT_EQ(ref.status, ukdyn::RunStatus::completed) << ref.message;
  std::mutex ginac;
  std::vector<Case> cases(2);
  std::vector<RunRecord> got(2);
  std::vector<std::thread> pool;
  for (std::size_t k = 0; k < 2; ++k) {
    pool.emplace_back([&, k] {
      {
        const std::lock_guard<std::mutex> lock(ginac);
        cases[k] = definitions_case();
      }
      got[k] = run(cases[k]);
    });
  }
  for (auto& th : pool) th.join();
  const auto table = [](const Case& x) {
    return dynamic_cast<const ukdyn::symbolic::DerivedSubsystem&>(*x.system->subsystems().front())
        .derivation()
        .symbols.get();
  };
  EXPECT_NE(table(cases[0]), table(cases[1]));
  EXPECT_NE(table(cases[0]), table(c));
  for (std::size_t k = 0; k < 2; ++k) {
    EXPECT_EQ(got[k].status, ukdyn::RunStatus::completed) << got[k].message;
    EXPECT_TRUE(same_bytes(got[k].values, ref.values))
        << "the system derived on thread " << k << " runs differently";
  }
}

// The test can fail: a run with another initial state gives other bytes.
TEST(Threads, ComparisonSeesADifferentRun) {
  Case c = definitions_case();
  const RunRecord ref = run(c);
  c.q0(1) = 0.3000001;
  const RunRecord other = run(c);
  EXPECT_FALSE(same_bytes(ref.values, other.values));
}

}  // namespace
