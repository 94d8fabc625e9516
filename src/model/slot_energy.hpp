// Private to ukdyn: potential_energy() (include/ukdyn/model/system.hpp) evaluated with a
// ForwardData's slots as scratch, for the per-sample recorder of the run layer
// (src/run/run_observer.cpp): a subsystem that needs a workspace (a tree's placement) then
// allocates none per call. Not installed.
#pragma once

#include "ukdyn/model/system.hpp"

namespace ukdyn::detail {

/// Σ_k v(k, q_k) over the subsystems (q_k: subsystem k's coordinates in q) plus the potentials
/// of the applied forces: potential_energy() with V_k given by the caller.
template <class V>
double potential_sum(const System& system, CVecRef q, V&& v) {
  const auto& L = system.layout();
  double sum = 0.0;
  for (std::size_t k = 0; k < system.subsystems().size(); ++k)
    sum += v(k, q.segment(L.start[k], L.size[k]));
  for (const auto& f : system.applied_forces()) sum += f->potential(q);
  return sum;
}

/// Σ V_k(q, t) of the subsystems plus the potentials of the applied forces, as
/// potential_energy(system, t, q), subsystem k evaluated in data.subsystem_slot(k).
double potential_energy_in_slots(const System& system, ForwardData& data, double t, CVecRef q);

}  // namespace ukdyn::detail
