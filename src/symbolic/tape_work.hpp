// The work of compiling expressions into a tape, counted before the compilation (tape.cpp): the
// deterministic bound on the compilation of a derivation's results. Internal to ukdyn::symbolic
// (not installed).
#pragma once

#include <ginac/ginac.h>

#include <cstddef>
#include <string>
#include <vector>

namespace ukdyn::symbolic {

namespace limits {
/// Operand visits of the compilation of one derived subsystem's or constraint's tapes together
/// (tape_work()), counted before any is compiled: past it the model is refused whatever the load
/// of the machine (docs/definitions.md, "Limits").
inline constexpr std::size_t kTapeWork = 1'000'000;
}  // namespace limits

/// `done` plus the operand visits compiling `outputs` into a tape makes, the outputs taken as a
/// DAG: one per output and one per operand of each distinct subexpression (a sum or product of n
/// operands gives n, sin(x) 1, a power 2, a symbol or number none). Each visit is one lookup of
/// the compiler's common-subexpression memo, and the compilation with its structural sort is of
/// the order of this count. Independent of GiNaC's (address-seeded) operand order. Throws a
/// DerivationTimeout naming `where` and `limit` as soon as the total passes `limit`: linear in
/// min(count, limit). `done`: the visits of the tapes counted before (one budget for several).
std::size_t tape_work(const std::vector<GiNaC::ex>& outputs, std::size_t limit,
                      const std::string& where, std::size_t done = 0);

}  // namespace ukdyn::symbolic
