// Loads a scenario file (argv[1]) with ukdyn::io and simulates its first 0.1 s; exit 0 if the run
// completed with the constraints held.
#include <iostream>
#include <ukdyn/scenario/scenario.hpp>
#include <ukdyn/simulate/simulate.hpp>

int main(int argc, char** argv) {
  if (argc < 2) {
    std::cerr << "usage: consumer SCENARIO.yaml\n";
    return 2;
  }
  const ukdyn::Scenario sc = ukdyn::load_scenario(argv[1]);
  ukdyn::SimulationSettings s = sc.sim;
  s.t_end = s.t0 + 0.1;
  double worst = 0.0;
  ukdyn::Vec phi(sc.system->rows());
  const auto stats =
      ukdyn::simulate(*sc.system, sc.q0, sc.qd0, {}, s,
                      [&](double t, ukdyn::CVecRef q, ukdyn::CVecRef, const ukdyn::ForwardData&) {
                        ukdyn::position_residuals(*sc.system, t, q, phi);
                        worst = std::max(worst, phi.cwiseAbs().maxCoeff());
                        return true;
                      });
  std::cout << sc.name << ": " << ukdyn::to_string(stats.status) << ", " << stats.samples
            << " samples, max |Phi| " << worst << "\n";
  return stats.status == ukdyn::RunStatus::completed && worst < 1e-9 ? 0 : 1;
}
