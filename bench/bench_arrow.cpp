// N arms carrying one load (tests/n_robots_model.hpp): µs per forward() with the block-arrow solve
// (ukdyn/core/uk_arrow.hpp, O(N)) and with the same stages followed by the dense solve
// (uk_solve.hpp, O(N³) in the factorisation of A M⁻¹Aᵀ), N = 2 … 64 (docs/performance.md).
#include <benchmark/benchmark.h>

#include <map>
#include <memory>

#include "bench_common.hpp"
#include "n_robots_model.hpp"
#include "ukdyn/model/system.hpp"

namespace ukbench {
namespace {

using ukdyn::Index;
using ukdyn::Vec;

struct NRobotsCase {
  std::shared_ptr<ukdyn::System> system;
  Vec q, qd, tau;
};

const NRobotsCase& n_robots_case(int robots) {
  static std::map<int, NRobotsCase> cache;  // bench only: built once per N
  auto it = cache.find(robots);
  if (it != cache.end()) return it->second;
  uktest::NRobotsOptions o;
  o.robots = robots;
  NRobotsCase c;
  c.system = uktest::n_robots_system(o);
  const Index n = c.system->dof();
  c.q = Vec::LinSpaced(n, -0.8, 0.9);
  c.qd = Vec::LinSpaced(n, 0.4, -0.3);
  c.tau = Vec::Zero(n);
  return cache.emplace(robots, std::move(c)).first->second;
}

void Forward_NRobotsArrow(benchmark::State& state) {
  const auto& c = n_robots_case(static_cast<int>(state.range(0)));
  ukdyn::ForwardData data(*c.system);
  ukdyn::forward(*c.system, data, 0.0, c.q, c.qd, c.tau);
  if (!data.used_arrow) state.SkipWithError("the arrow solve was not used");
  for (auto _ : state) {
    ukdyn::forward(*c.system, data, 0.0, c.q, c.qd, c.tau);
    benchmark::DoNotOptimize(data.qdd.data());
  }
  state.counters["dof"] = static_cast<double>(c.system->dof());
  state.counters["rows"] = static_cast<double>(c.system->rows());
}
BENCHMARK(Forward_NRobotsArrow)
    ->Arg(2)
    ->Arg(4)
    ->Arg(8)
    ->Arg(16)
    ->Arg(32)
    ->Arg(64)
    ->Unit(benchmark::kMicrosecond)
    ->Apply(add_min_max);

// The solve alone (factor_mass + uk_solve_arrow) on the A, b, Q of one forward().
void Solve_NRobotsArrow(benchmark::State& state) {
  const auto& c = n_robots_case(static_cast<int>(state.range(0)));
  const auto* arrow = c.system->arrow();
  ukdyn::ForwardData data(*c.system);
  ukdyn::forward(*c.system, data, 0.0, c.q, c.qd, c.tau);
  const ukdyn::UkSettings settings;
  for (auto _ : state) {
    ukdyn::factor_mass(data.M, data.uk);
    ukdyn::uk_solve_arrow(*arrow, data.M, data.A, data.b, data.Q, data.uk, data.arrow, data.qdd,
                          data.Qc, settings, data.result);
    benchmark::DoNotOptimize(data.qdd.data());
  }
}
BENCHMARK(Solve_NRobotsArrow)
    ->Arg(2)
    ->Arg(4)
    ->Arg(8)
    ->Arg(16)
    ->Arg(32)
    ->Arg(64)
    ->Unit(benchmark::kMicrosecond)
    ->Apply(add_min_max);

// The model stages alone (M, C q̇, G, Q; A, b with the structural writes): what forward() adds.
void Stages_NRobots(benchmark::State& state) {
  const auto& c = n_robots_case(static_cast<int>(state.range(0)));
  const auto& sys = *c.system;
  ukdyn::ForwardData data(sys);
  for (auto _ : state) {
    ukdyn::evaluate_dynamics(sys, data, 0.0, c.q, c.qd);
    ukdyn::generalized_forces(sys, data, 0.0, c.q, c.qd, c.tau);
    benchmark::DoNotOptimize(data.Q.data());
  }
}
BENCHMARK(Stages_NRobots)
    ->Arg(2)
    ->Arg(8)
    ->Arg(64)
    ->Unit(benchmark::kMicrosecond)
    ->Apply(add_min_max);

// The constraint stage alone (A, b with the structural writes, as forward() does them).
void Constraints_NRobots(benchmark::State& state) {
  const auto& c = n_robots_case(static_cast<int>(state.range(0)));
  const auto& sys = *c.system;
  ukdyn::ForwardData data(sys);
  const auto& cons = sys.constraints();
  const auto& offs = sys.constraint_row_offsets();
  const Index n = sys.dof();
  for (auto _ : state) {
    for (std::size_t k = 0; k < cons.size(); ++k) {
      const Index r = cons[k]->rows();
      cons[k]->evaluate({0.0, data.constraint_slots(k), /*structural_only=*/true}, c.q, c.qd,
                        data.A.block(offs[k], 0, r, n), data.b.segment(offs[k], r));
    }
    benchmark::DoNotOptimize(data.b.data());
  }
}
BENCHMARK(Constraints_NRobots)
    ->Arg(2)
    ->Arg(8)
    ->Arg(64)
    ->Unit(benchmark::kMicrosecond)
    ->Apply(add_min_max);

// The same stages as forward(), then the dense solve.
void Forward_NRobotsDense(benchmark::State& state) {
  const auto& c = n_robots_case(static_cast<int>(state.range(0)));
  const auto& sys = *c.system;
  ukdyn::ForwardData data(sys);
  for (auto _ : state) {
    ukdyn::evaluate_dynamics(sys, data, 0.0, c.q, c.qd);
    ukdyn::generalized_forces(sys, data, 0.0, c.q, c.qd, c.tau);
    ukdyn::evaluate_constraints(sys, data, 0.0, c.q, c.qd);
    data.result = ukdyn::uk_solve(data.M, data.A, data.b, data.Q, data.uk, data.qdd, data.Qc);
    benchmark::DoNotOptimize(data.qdd.data());
  }
}
BENCHMARK(Forward_NRobotsDense)
    ->Arg(2)
    ->Arg(4)
    ->Arg(8)
    ->Arg(16)
    ->Arg(32)
    ->Arg(64)
    ->Unit(benchmark::kMicrosecond)
    ->Apply(add_min_max);

}  // namespace
}  // namespace ukbench
