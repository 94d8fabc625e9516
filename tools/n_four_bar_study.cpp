// N-four-bar study (docs/singular-positions.md): runs a benchmarks/n_four_bar_N*.yaml scenario and
// compares it with the exact parallelogram-branch motion (NFourBarReference,
// tools/benchmark_reference.hpp). Prints one
// table row per run: status, max error of B0 (the first coupler point) against the exact solution,
// max energy drift, max |Φ|, the branch distance max_i |φ_i − φ_0|, steps, CPU time.
// Usage: ukdyn_n_four_bar_study SCENARIO [--speed V] [--tol TOL] [--rank-tol R] [--method M]
//                               [--t-end T] [--regularization EPS]
#include <fmt/format.h>

#include <cmath>
#include <ctime>
#include <iostream>
#include <string>

#include "tools/benchmark_reference.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/simulate/simulate.hpp"

int main(int argc, char** argv) {
  using namespace ukdyn;
  if (argc < 2) {
    std::cerr << "usage: ukdyn_n_four_bar_study SCENARIO [--speed V] [--tol TOL] [--rank-tol R] "
                 "[--method exact|regularized] [--regularization EPS] [--t-end T]\n";
    return 2;
  }
  try {
    const Scenario sc = load_scenario(argv[1]);
    SimulationSettings s = sc.sim;
    double speed = 1.0;
    for (int i = 2; i + 1 < argc; i += 2) {
      const std::string key = argv[i];
      const double v = key == "--method" ? 0.0 : std::stod(argv[i + 1]);
      if (key == "--speed") {
        speed = v;
      } else if (key == "--tol") {
        s.abs_tol = s.rel_tol = v;
      } else if (key == "--rank-tol") {
        s.uk.rank_rel_tol = v;
      } else if (key == "--regularization") {
        s.uk.regularization = v;
      } else if (key == "--method") {
        const std::string mth = argv[i + 1];
        s.uk.method = mth == "exact"         ? UkMethod::exact
                      : mth == "regularized" ? UkMethod::regularized
                      : mth == "adaptive"    ? UkMethod::adaptive
                                             : UkMethod::equilibrated;
      } else if (key == "--band") {
        s.uk.adaptive_band = v;
      } else if (key == "--t-end") {
        s.t_end = v;
      } else {
        std::cerr << "unknown option " << key << "\n";
        return 2;
      }
    }
    const Index n = sc.system->dof();
    const int windows = static_cast<int>((n - 1) / 2);
    const Vec qd0 = sc.qd0 * speed;  // −speed for every crank: dx(B0)/dt = speed
    const ukdyn_bench::NFourBarReference exact(windows, speed);
    double E0 = std::nan(""), max_dE = 0, max_err = 0, max_phi = 0, max_branch = 0;
    Vec phi(sc.system->rows());
    const std::clock_t c0 = std::clock();
    const ForceFunction tau;
    const SimulationStats st = simulate(
        *sc.system, sc.q0, qd0, tau, s, [&](double t, CVecRef q, CVecRef qd, const ForwardData& d) {
          const double E = kinetic_energy(d, qd) + potential_energy(*sc.system, q);
          if (std::isnan(E0)) E0 = E;
          max_dE = std::max(max_dE, std::abs(E - E0));
          double x = 0, y = 0;
          exact.point_B0(t, x, y);
          max_err = std::max(max_err, std::hypot(std::cos(q(0)) - x, std::sin(q(0)) - y));
          position_residuals(*sc.system, t, q, phi);
          max_phi = std::max(max_phi, phi.cwiseAbs().maxCoeff());
          for (int i = 1; i <= windows; ++i) {
            max_branch = std::max(max_branch, std::abs(std::remainder(q(i) - q(0), 2 * M_PI)));
          }
          return true;
        });
    const double cpu = static_cast<double>(std::clock() - c0) / CLOCKS_PER_SEC;
    std::string warnings = fmt::format("dq {:.1e} dqd {:.1e} ratio {:.1e} hmin {:.1e}@{:.6g} ",
                                       st.max_position_correction, st.max_velocity_correction,
                                       st.max_correction_ratio, st.min_step, st.min_step_t);
    for (const auto& w : st.warnings) warnings += fmt::format("{}@{:.6g} ", w.kind, w.t);
    std::cout << fmt::format(
        "| {} | {} | {:g} | {:g} | {:g} | {} | {:.6g} | {:.2e} | {:.2e} | {:.2e} | {:.2e} | {} "
        "({}) "
        "| {:.2f} | {}|\n",
        sc.name, to_string(s.uk.method), s.uk.rank_rel_tol, speed, s.abs_tol, to_string(st.status),
        st.t_reached, max_err, max_dE, max_phi, max_branch, st.steps, st.rejected_steps, cpu,
        warnings);
    if (!st.message.empty()) std::cout << "  " << st.message << "\n";
    return st.status == RunStatus::completed ? 0 : 1;
  } catch (const std::exception& e) {
    std::cerr << e.what() << "\n";
    return 2;
  }
}
