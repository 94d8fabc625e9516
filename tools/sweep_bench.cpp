// Sweep throughput (docs/performance.md, "Sweeps"; `make sweep-bench`): N samples of the paper's
// free motion over t in [0, 2] s (scenarios/sweeps/paper_free_bench.yaml, masses drawn at random),
//  1. plain: the same N sample scenarios, loaded beforehand, each simulate()d with a no-op
//     observer, one after another (what a hand-written loop over the library costs at least);
//  2. `ukdyn sweep` in memory (run_sweep) at 1 thread and at 2 threads, journal and table included.
// Prints samples/s, the speed-up of 2 threads, and the overhead per sample of (2) at 1 thread
// against (1). Usage: ukdyn_sweep_bench [SWEEP.yaml] [N] [OUT_DIR|-] [ROUNDS|only:K]
// With ROUNDS > 0 it then runs ROUNDS interleaved rounds of five ways of computing the N samples
// (the order rotated every round, so that no way always runs first or last on a warm or cold
// machine) and prints the median and spread of each, and the median of the per-round ratios:
//   A plain loop, models loaded beforehand (as above)
//   B `ukdyn sweep` (run_sweep) at 1 thread
//   C plain loop, each model loaded just before its integration (from the sample's text)
//   D plain loop run in one worker std::jthread (as the sweep's single worker runs)
//   E the sweep's per-sample path (run_sample) called in a loop on the main thread
#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <iostream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/sweep/sweep.hpp"

#ifndef UKDYN_SOURCE_DIR
#define UKDYN_SOURCE_DIR "."
#endif

namespace {

using clock_type = std::chrono::steady_clock;
double cpu_now() { return static_cast<double>(std::clock()) / CLOCKS_PER_SEC; }

long plain_loop(const std::vector<ukdyn::Scenario>& scs) {
  long steps = 0;
  for (const auto& sc : scs) {
    const ukdyn::Vec tau = sc.tau;
    const ukdyn::ForceFunction f = [&tau](double, ukdyn::CVecRef, ukdyn::CVecRef, ukdyn::VecRef o) {
      o = tau;
    };
    const auto st = ukdyn::simulate(
        *sc.system, sc.q0, sc.qd0, f, sc.sim,
        [](double, ukdyn::CVecRef, ukdyn::CVecRef, const ukdyn::ForwardData&) { return true; });
    steps += st.steps;
  }
  return steps;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n == 0 ? 0.0 : n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

// One way of computing the sweep's samples (the list in the header). Not inlined, so that an
// instruction count (valgrind --tool=callgrind --toggle-collect=*compute_way*) can take it alone.
[[gnu::noinline]] void compute_way(int way, const ukdyn::Sweep& sw,
                                   const std::vector<ukdyn::Scenario>& scs,
                                   const ukdyn::Scenario& base, const std::filesystem::path& out) {
  const long n = sw.samples;
  switch (way) {
    case 0:
      (void)plain_loop(scs);
      break;
    case 1: {
      ukdyn::SweepOptions opt;
      opt.threads = 1;
      opt.resume = false;
      const auto rep = ukdyn::run_sweep(sw, out / "interleaved", opt);
      if (!rep.complete || rep.failed != 0) throw std::runtime_error("sweep incomplete");
      break;
    }
    case 2:
      for (long k = 0; k < n; ++k) {
        std::vector<ukdyn::Scenario> one;
        one.push_back(ukdyn::load_scenario_text(ukdyn::sample_scenario_text(sw, k), sw.base_path));
        (void)plain_loop(one);
      }
      break;
    case 3: {
      std::jthread worker([&scs] { (void)plain_loop(scs); });
      break;
    }
    case 4:
      for (long k = 0; k < n; ++k) (void)ukdyn::run_sample(sw, base, k);
      break;
  }
}

void interleaved(const ukdyn::Sweep& sw, const std::vector<ukdyn::Scenario>& scs,
                 const std::filesystem::path& out, int rounds) {
  const long n = sw.samples;
  const char* names[5] = {"A plain, preloaded", "B ukdyn sweep, 1 thread",
                          "C plain, loaded just before", "D plain, in a worker thread",
                          "E run_sample loop (main thread)"};
  std::vector<double> wall[5], cpu[5];
  const ukdyn::Scenario base =
      ukdyn::load_scenario_text(sw.base_text, sw.base_path, ukdyn::LoadOptions{false});
  auto run = [&](int way) {
    const double c0 = cpu_now();
    const auto t0 = clock_type::now();
    compute_way(way, sw, scs, base, out);
    wall[way].push_back(std::chrono::duration<double>(clock_type::now() - t0).count());
    cpu[way].push_back(cpu_now() - c0);
  };
  for (int r = 0; r < rounds; ++r) {
    for (int i = 0; i < 5; ++i) run((i + r) % 5);  // rotated: each way in every position
  }
  std::cout << fmt::format("interleaved: {} rounds of {} samples each way (order rotated)\n",
                           rounds, n);
  std::cout << "  way                                  wall median [min, max]        CPU median "
               "[min, max]\n";
  for (int w = 0; w < 5; ++w) {
    const auto [wl, wh] = std::minmax_element(wall[w].begin(), wall[w].end());
    const auto [cl, ch] = std::minmax_element(cpu[w].begin(), cpu[w].end());
    std::cout << fmt::format("  {:<34} {:7.3f} s [{:.3f}, {:.3f}]   {:7.3f} s [{:.3f}, {:.3f}]\n",
                             names[w], median(wall[w]), *wl, *wh, median(cpu[w]), *cl, *ch);
  }
  for (int w = 1; w < 5; ++w) {
    std::vector<double> rw, rc;
    for (int r = 0; r < rounds; ++r) {
      rw.push_back(wall[w][r] / wall[0][r]);
      rc.push_back(cpu[w][r] / cpu[0][r]);
    }
    const auto [wl, wh] = std::minmax_element(rw.begin(), rw.end());
    const auto [cl, ch] = std::minmax_element(rc.begin(), rc.end());
    std::cout << fmt::format(
        "  {} / A per round: wall median {:+.1f} % [{:+.1f}, {:+.1f}], CPU median {:+.1f} % "
        "[{:+.1f}, {:+.1f}]\n",
        names[w][0], 100 * (median(rw) - 1), 100 * (*wl - 1), 100 * (*wh - 1),
        100 * (median(rc) - 1), 100 * (*cl - 1), 100 * (*ch - 1));
  }
}

}  // namespace

int main(int argc, char** argv) {
  namespace fs = std::filesystem;
  const fs::path file = argc > 1
                            ? fs::path(argv[1])
                            : fs::path(UKDYN_SOURCE_DIR) / "scenarios/sweeps/paper_free_bench.yaml";
  const long n_arg = argc > 2 ? std::atol(argv[2]) : 0;
  const fs::path out = argc > 3 && std::string(argv[3]) != "-"
                           ? fs::path(argv[3])
                           : fs::temp_directory_path() / "ukdyn_sweep_bench";
  // ROUNDS "only:K" runs way K (0..4 = A..E) once and nothing else: for an instruction count,
  //   valgrind --tool=callgrind --collect-atstart=no --toggle-collect='*compute_way*'
  //            ukdyn_sweep_bench SWEEP N - only:K
  // which, unlike a time, does not depend on what else the machine runs (docs/performance.md).
  const std::string last = argc > 4 ? std::string(argv[4]) : std::string();
  const int only = last.rfind("only:", 0) == 0 ? std::atoi(last.c_str() + 5) : -1;
  const int rounds = only < 0 && argc > 4 ? std::atoi(argv[4]) : 0;
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
    if (only >= 0) {
      if (only > 4) throw std::invalid_argument("only:K needs K in 0..4");
      const ukdyn::Scenario base =
          ukdyn::load_scenario_text(sw.base_text, sw.base_path, ukdyn::LoadOptions{false});
      compute_way(only, sw, scs, base, out);
      std::cout << fmt::format("sweep bench: way {} once, {} samples\n", only, n);
      return 0;
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
    if (rounds > 0) interleaved(sw, scs, out, rounds);
  } catch (const std::exception& e) {
    std::cerr << "sweep_bench: " << e.what() << "\n";
    return 2;
  }
  return 0;
}
