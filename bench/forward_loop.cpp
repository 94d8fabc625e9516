// ukdyn_forward_loop: the driver behind the instruction counts of docs/performance.md ("Two Pandas
// welded to a plate"). It loads a scenario and either calls forward() N times at the scenario's
// initial state with τ = 0 ("loop N", for callgrind:
//   valgrind --tool=callgrind --toggle-collect='ukdyn::forward(*'
//       build/release/bench/ukdyn_forward_loop scenarios/two_pandas_weld.yaml loop 2000,
// then the total over N is the instructions per call), or prints q̈, Qc, the rank and M's diagonal,
// C q̇, G in hexadecimal at the initial state and at four random states around it ("print": diff
// the output of two builds to see whether a change is bitwise).
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <random>
#include <string>

#include "ukdyn/model/system.hpp"
#include "ukdyn/scenario/scenario.hpp"

namespace {

void print_states(const ukdyn::Scenario& sc, ukdyn::ForwardData& data) {
  const ukdyn::System& sys = *sc.system;
  const ukdyn::Vec tau0 = ukdyn::Vec::Zero(sys.dof());
  std::mt19937_64 rng(12345);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int s = 0; s < 5; ++s) {
    ukdyn::Vec q = sc.q0, qd = sc.qd0, tau = tau0;
    if (s > 0) {  // every coordinate moved by up to 0.05, random rates and forces
      for (Eigen::Index i = 0; i < q.size(); ++i) q(i) += 0.05 * u(rng);
      for (Eigen::Index i = 0; i < q.size(); ++i) qd(i) = u(rng);
      for (Eigen::Index i = 0; i < q.size(); ++i) tau(i) = 5 * u(rng);
    }
    ukdyn::forward(sys, data, sc.sim.t0, q, qd, tau, sc.sim.uk);
    std::printf("state %d rank %d\n", s, static_cast<int>(data.result.rank));
    for (Eigen::Index i = 0; i < q.size(); ++i) std::printf("%a %a\n", data.qdd(i), data.Qc(i));
    for (Eigen::Index i = 0; i < q.size(); ++i)
      std::printf("M %a %a %a\n", data.M(i, i), data.Cqd(i), data.G(i));
  }
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: ukdyn_forward_loop SCENARIO.yaml [loop N | print]\n");
    return 2;
  }
  try {
    const ukdyn::Scenario sc = ukdyn::load_scenario(argv[1]);
    const ukdyn::System& sys = *sc.system;
    ukdyn::ForwardData data(sys);
    const std::string mode = argc > 2 ? argv[2] : "print";
    if (mode == "loop") {
      const int n = argc > 3 ? std::atoi(argv[3]) : 2000;
      const ukdyn::Vec tau0 = ukdyn::Vec::Zero(sys.dof());
      for (int i = 0; i < n; ++i)
        ukdyn::forward(sys, data, sc.sim.t0, sc.q0, sc.qd0, tau0, sc.sim.uk);
      std::printf("%a\n", data.qdd(0));
      return 0;
    }
    print_states(sc, data);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "ukdyn_forward_loop: %s\n", e.what());
    return 2;
  }
  return 0;
}
