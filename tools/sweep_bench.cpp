// Sweep throughput (docs/performance.md, "Sweeps"; `make sweep-bench`): N samples of the paper's
// free motion over t in [0, 2] s (scenarios/sweeps/paper_free_bench.yaml, masses drawn at random),
//  1. plain: the same N sample scenarios, loaded beforehand, each simulate()d with a no-op
//     observer, one after another (what a hand-written loop over the library costs at least);
//  2. `ukdyn sweep` in memory (run_sweep) at 1 thread and at 2 threads, journal and table included.
// Prints samples/s, the speed-up of 2 threads, and the overhead per sample of (2) at 1 thread
// against (1). Usage: ukdyn_sweep_bench [SWEEP.yaml] [N] [OUT_DIR]
#include <fmt/format.h>

#include <chrono>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <iostream>
#include <string>
#include <thread>

#include "ukdyn/io/scenario.hpp"
#include "ukdyn/io/sweep.hpp"

#ifndef UKDYN_SOURCE_DIR
#define UKDYN_SOURCE_DIR "."
#endif

int main(int argc, char** argv) {
  namespace fs = std::filesystem;
  const fs::path file = argc > 1
                            ? fs::path(argv[1])
                            : fs::path(UKDYN_SOURCE_DIR) / "scenarios/sweeps/paper_free_bench.yaml";
  const long n_arg = argc > 2 ? std::atol(argv[2]) : 0;
  const fs::path out =
      argc > 3 ? fs::path(argv[3]) : fs::temp_directory_path() / "ukdyn_sweep_bench";
  try {
    ukdyn::Sweep sw = ukdyn::load_sweep(file);
    if (n_arg > 0 && n_arg < sw.samples) sw.samples = n_arg;
    sw.figures = false;
    const long n = sw.samples;
    const double nd = static_cast<double>(n);
    using clock = std::chrono::steady_clock;

    // 1. plain simulate() of the same scenarios.
    std::vector<ukdyn::Scenario> scs;
    for (long k = 0; k < n; ++k) {
      scs.push_back(ukdyn::load_scenario_text(ukdyn::sample_scenario_text(sw, k), sw.base_path));
    }
    // Wall time, and the process's CPU time (std::clock: all threads), which a loaded machine
    // disturbs far less than the wall time.
    const auto cpu = [] { return static_cast<double>(std::clock()) / CLOCKS_PER_SEC; };
    const double pc0 = cpu();
    const auto p0 = clock::now();
    long steps = 0;
    for (const auto& sc : scs) {
      const ukdyn::Vec tau = sc.tau;
      const ukdyn::ForceFunction f = [&tau](double, ukdyn::CVecRef, ukdyn::CVecRef,
                                            ukdyn::VecRef o) { o = tau; };
      const auto st = ukdyn::simulate(
          *sc.system, sc.q0, sc.qd0, f, sc.sim,
          [](double, ukdyn::CVecRef, ukdyn::CVecRef, const ukdyn::ForwardData&) { return true; });
      steps += st.steps;
    }
    const double plain = std::chrono::duration<double>(clock::now() - p0).count();
    const double plain_cpu = cpu() - pc0;
    double cpu_sweep[3] = {0, 0, 0};

    // 2. the sweep at 1 and 2 threads (fresh: no journal reuse).
    double t_sweep[3] = {0, 0, 0};
    for (int threads : {1, 2}) {
      ukdyn::SweepOptions opt;
      opt.threads = threads;
      opt.resume = false;
      const fs::path dir = out / fmt::format("threads{}", threads);
      const double c0 = cpu();
      const auto s0 = clock::now();
      const auto rep = ukdyn::run_sweep(sw, dir, opt);
      t_sweep[threads] = std::chrono::duration<double>(clock::now() - s0).count();
      cpu_sweep[threads] = cpu() - c0;
      if (!rep.complete || rep.failed != 0) {
        std::cerr << "sweep_bench: the sweep did not complete every sample\n";
        return 1;
      }
    }
    std::cout << fmt::format(
        "sweep bench: {} samples of '{}' ({} integration steps in all), "
        "{} hardware threads\n",
        n, sw.base_path.filename().string(), steps, std::thread::hardware_concurrency());
    std::cout << fmt::format(
        "  plain simulate loop   {:8.3f} s  {:8.2f} samples/s  {:.3f} ms/sample\n", plain,
        nd / plain, 1e3 * plain / nd);
    std::cout << fmt::format(
        "  ukdyn sweep 1 thread  {:8.3f} s  {:8.2f} samples/s  {:.3f} ms/sample\n", t_sweep[1],
        nd / t_sweep[1], 1e3 * t_sweep[1] / nd);
    std::cout << fmt::format("  ukdyn sweep 2 threads {:8.3f} s  {:8.2f} samples/s\n", t_sweep[2],
                             nd / t_sweep[2]);
    std::cout << fmt::format("  speed-up 2 threads / 1 thread: {:.2f}x\n", t_sweep[1] / t_sweep[2]);
    std::cout << fmt::format(
        "  overhead per sample (sweep 1 thread vs plain): {:+.1f} %  ({:+.3f} ms)\n",
        100.0 * (t_sweep[1] / plain - 1.0), 1e3 * (t_sweep[1] - plain) / nd);
    std::cout << fmt::format(
        "  CPU time: plain {:.3f} s, sweep 1 thread {:.3f} s, sweep 2 threads {:.3f} s\n",
        plain_cpu, cpu_sweep[1], cpu_sweep[2]);
    std::cout << fmt::format(
        "  overhead per sample in CPU time (sweep 1 thread vs plain): {:+.1f} %  ({:+.3f} ms)\n",
        100.0 * (cpu_sweep[1] / plain_cpu - 1.0), 1e3 * (cpu_sweep[1] - plain_cpu) / nd);
  } catch (const std::exception& e) {
    std::cerr << "sweep_bench: " << e.what() << "\n";
    return 2;
  }
  return 0;
}
