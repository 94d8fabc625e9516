// The exact against the difference-quotient Jacobian of bdf and esdirk (docs/derivatives.md,
// "Exact Jacobians in the implicit integrators"): for one scenario, each implicit integrator with
// simulation.jacobian difference and exact at the scenario's tolerance (or --tol), and a reference
// run (rkf78 at --ref-tol). Prints one markdown row per run: steps, evaluations of f, Jacobian
// evaluations (and fallbacks), the CPU time of simulate() alone (std::clock, the scenario's loading
// and symbolic derivation excluded; best of --reps), and the end state's distance to the reference.
// A control scenario: its plant under the closed loop, the law's exact ∂τ/∂(q, q̇) in `exact`.
//
// Usage: ukdyn_jacobian_bench SCENARIO [--tol T] [--ref-tol T] [--t-end T] [--reps N]
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <ctime>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "ukdyn/output/control_output.hpp"
#include "ukdyn/run/closed_loop_derivatives.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/simulate/simulate.hpp"

namespace {

struct Outcome {
  ukdyn::SimulationStats stats;
  ukdyn::Vec q, qd;
  double cpu = 0.0;
};

// A scenario with `control:` runs its plant under the closed loop from the offset start, with the
// law's exact ∂τ/∂(q, q̇) (law_force_jacobian()); else the system under the constant forces.tau.
Outcome run(const ukdyn::Scenario& sc, const ukdyn::ControlRun* ctl, ukdyn::SimulationSettings s,
            int reps) {
  Outcome o;
  ukdyn::ForceFunction tau = [&sc](double, ukdyn::CVecRef, ukdyn::CVecRef, ukdyn::VecRef f) {
    f = sc.tau;
  };
  s.tau_jacobian = ukdyn::zero_force_jacobian;  // constant τ
  if (ctl != nullptr) {
    tau = ctl->loop->force_function();
    s.tau_jacobian = ukdyn::law_jacobian_gap(*ctl).empty() ? ukdyn::law_force_jacobian(*ctl)
                                                           : ukdyn::ForceJacobian();
  }
  const ukdyn::System& sys = ctl != nullptr ? *ctl->plant : *sc.system;
  o.cpu = 1e300;
  for (int r = 0; r < reps; ++r) {
    const std::clock_t c0 = std::clock();
    o.stats = ukdyn::simulate(
        sys, ctl != nullptr ? ctl->q0 : sc.q0, ctl != nullptr ? ctl->qd0 : sc.qd0, tau, s,
        [&o](double, ukdyn::CVecRef q, ukdyn::CVecRef qd, const ukdyn::ForwardData&) {
          o.q = q;
          o.qd = qd;
          return true;
        });
    o.cpu = std::min(o.cpu, static_cast<double>(std::clock() - c0) / CLOCKS_PER_SEC);
  }
  return o;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::cerr << "usage: ukdyn_jacobian_bench SCENARIO [--tol T] [--ref-tol T] [--t-end T] "
                 "[--reps N]\n";
    return 2;
  }
  double tol = 0.0, ref_tol = 1e-13, t_end = 0.0;
  int reps = 3;
  for (int i = 2; i + 1 < argc; i += 2) {
    const std::string k = argv[i];
    const double v = std::stod(argv[i + 1]);
    if (k == "--tol") tol = v;
    if (k == "--ref-tol") ref_tol = v;
    if (k == "--t-end") t_end = v;
    if (k == "--reps") reps = static_cast<int>(v);
  }
  const ukdyn::Scenario sc = ukdyn::load_scenario(argv[1]);
  const std::unique_ptr<ukdyn::ControlRun> ctl = ukdyn::make_control_run(sc);
  ukdyn::SimulationSettings base = sc.sim;
  if (t_end > 0.0) base.t_end = t_end;
  if (tol > 0.0) base.abs_tol = base.rel_tol = tol;
  ukdyn::SimulationSettings ref_s = base;
  ref_s.integrator = ukdyn::IntegratorKind::rkf78;
  ref_s.adaptive = true;
  ref_s.abs_tol = ref_s.rel_tol = ref_tol;
  const Outcome ref = run(sc, ctl.get(), ref_s, 1);
  fmt::print("{} (n = {}{}), t = {} .. {} s, tol {:g}; reference rkf78 at {:g} ({})\n\n", sc.name,
             sc.system->dof(), ctl ? ", the plant under the control law" : "", base.t0, base.t_end,
             base.abs_tol, ref_tol, ukdyn::to_string(ref.stats.status));
  fmt::print(
      "| integrator | jacobian | steps | f evaluations | Jacobians (fallbacks) | CPU [s] | "
      "max abs(q - q_ref) | max abs(qd - qd_ref) |\n|---|---|---|---|---|---|---|---|\n");
  for (auto kind : {ukdyn::IntegratorKind::bdf, ukdyn::IntegratorKind::esdirk}) {
    for (auto jac : {ukdyn::JacobianKind::difference, ukdyn::JacobianKind::exact}) {
      ukdyn::SimulationSettings s = base;
      s.integrator = kind;
      s.jacobian = jac;
      const Outcome o = run(sc, ctl.get(), s, reps);
      fmt::print("| {} | {} | {} | {} | {} ({}) | {:.3f} | {:.1e} | {:.1e} |\n",
                 ukdyn::to_string(kind), o.stats.jacobian, o.stats.steps, o.stats.rhs_evaluations,
                 o.stats.jacobian_evaluations, o.stats.jacobian_fallbacks, o.cpu,
                 (o.q - ref.q).cwiseAbs().maxCoeff(), (o.qd - ref.qd).cwiseAbs().maxCoeff());
    }
  }
  return 0;
}
