// Drift-control study (docs/drift-control.md): runs a scenario with each drift control and two
// integrators over a long horizon and prints, for prefixes of the run, the largest constraint
// residual, the energy drift relative to max T, and the cost. Usage:
//   ukdyn_drift_study SCENARIO [T_END=100]
#include <fmt/format.h>

#include <chrono>
#include <cmath>
#include <iostream>

#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/simulate/simulate.hpp"

int main(int argc, char** argv) {
  using namespace ukdyn;
  if (argc < 2) {
    std::cerr << "usage: ukdyn_drift_study SCENARIO [T_END]\n";
    return 2;
  }
  try {
    const Scenario sc = load_scenario(argv[1]);
    const double t_end = argc > 2 ? std::stod(argv[2]) : 100.0;
    const double horizons[3] = {5.0, 20.0, t_end};
    std::cout << fmt::format("Scenario {} ({}), t = 0 .. {} s\n\n", sc.name, argv[1], t_end);
    std::cout
        << "| integrator | drift control | horizon [s] | max abs(Phi) | max abs(E - E0) / max T | "
           "steps | wall [s] |\n|---|---|---|---|---|---|---|\n";
    struct Setup {
      IntegratorKind kind;
      double tol_or_step;
    };
    for (const Setup setup :
         {Setup{IntegratorKind::dopri5, 1e-12}, Setup{IntegratorKind::rk4, 1e-3}}) {
      for (DriftControl drift :
           {DriftControl::none, DriftControl::baumgarte, DriftControl::projection}) {
        SimulationSettings s = sc.sim;
        s.t_end = t_end;
        s.sample_dt = 0.01;
        s.integrator = setup.kind;
        s.adaptive = true;
        if (setup.kind == IntegratorKind::rk4) {
          s.step = setup.tol_or_step;
        } else {
          s.abs_tol = s.rel_tol = setup.tol_or_step;
        }
        s.drift.kind = drift;
        double max_res[3] = {0, 0, 0}, max_dE[3] = {0, 0, 0}, max_T[3] = {0, 0, 0};
        long steps_at[3] = {0, 0, 0};
        double wall_at[3] = {0, 0, 0};
        double E0 = std::nan("");
        Vec phi(sc.system->rows());
        const auto start = std::chrono::steady_clock::now();
        long samples = 0;
        const ForceFunction tau;
        const auto st = simulate(*sc.system, sc.q0, sc.qd0, tau, s,
                                 [&](double t, CVecRef q, CVecRef qd, const ForwardData& d) {
                                   const double T = kinetic_energy(d, qd);
                                   const double E = T + potential_energy(*sc.system, q);
                                   if (std::isnan(E0)) E0 = E;
                                   position_residuals(*sc.system, t, q, phi);
                                   const double r = phi.cwiseAbs().maxCoeff();
                                   ++samples;
                                   for (int h = 0; h < 3; ++h) {
                                     if (t <= horizons[h] + 1e-9) {
                                       max_res[h] = std::max(max_res[h], r);
                                       max_dE[h] = std::max(max_dE[h], std::abs(E - E0));
                                       max_T[h] = std::max(max_T[h], T);
                                       wall_at[h] = std::chrono::duration<double>(
                                                        std::chrono::steady_clock::now() - start)
                                                        .count();
                                       steps_at[h] = samples;
                                     }
                                   }
                                   return true;
                                 });
        for (int h = 0; h < 3; ++h) {
          if (h < 2 && horizons[h] >= t_end) continue;
          std::cout << fmt::format(
              "| {} {} | {} | {:g} | {:.2e} | {:.2e} | {} | {:.2f} |\n", to_string(setup.kind),
              setup.kind == IntegratorKind::rk4 ? fmt::format("h = {:g}", setup.tol_or_step)
                                                : fmt::format("tol {:g}", setup.tol_or_step),
              to_string(drift), horizons[h], max_res[h], max_dE[h] / max_T[h],
              h == 2 ? fmt::format("{}", st.steps) : "", wall_at[h]);
        }
        if (st.status != RunStatus::completed) {
          std::cout << fmt::format("|  | {} stopped: {} | | | | | |\n", to_string(drift),
                                   st.message);
        }
        (void)steps_at;
      }
    }
  } catch (const std::exception& e) {
    std::cerr << "ukdyn_drift_study: error: " << e.what() << "\n";
    return 2;
  }
  return 0;
}
