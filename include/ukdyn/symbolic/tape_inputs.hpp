// How a tape's inputs are bound to a system's coordinates: one helper for every tape of
// ukdyn::symbolic (subsystems, constraints, forces, frame constraints) and of its users (the
// scenario loader's points and lengths at initial.q, the replay's geometry).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "ukdyn/symbolic/expression.hpp"
#include "ukdyn/symbolic/tape.hpp"

namespace ukdyn::symbolic {

/// Which symbols coordinate_inputs() binds.
enum class InputSet : std::uint8_t {
  q_qd_time,   ///< each coordinate and its velocity, and time (dynamics, constraints, forces)
  q,           ///< the coordinates only (positions: frames, points)
  q_interned,  ///< the coordinates `table` already has a symbol for (it gains none)
};

/// The inputs of a tape over a system's coordinates: the symbol of coordinates[i] reads q[i] of
/// Tape::eval and, with q_qd_time, its velocity reads q̇[i] and the time symbol reads t. Symbols
/// are interned in `table` as they are met: coordinate, velocity for each i, then time (q_interned
/// interns none: coordinates without a symbol are in no expression of the table).
InputMap coordinate_inputs(SymbolTable& table, const std::vector<std::string>& coordinates,
                           InputSet set = InputSet::q_qd_time);

}  // namespace ukdyn::symbolic
