// Private to ukdyn: potential_energy() (include/ukdyn/model/system.hpp) evaluated with a
// ForwardData's slots as scratch, for the per-sample recorder of the run layer
// (src/run/run_observer.cpp): a subsystem that needs a workspace (a tree's placement) then
// allocates none per call. Not installed.
#pragma once

#include "ukdyn/model/system.hpp"

namespace ukdyn::detail {

/// Σ V_k(q, t) of the subsystems plus the potentials of the applied forces, as
/// potential_energy(system, t, q), subsystem k evaluated in data.subsystem_slot(k).
double potential_energy_in_slots(const System& system, ForwardData& data, double t, CVecRef q);

}  // namespace ukdyn::detail
