// Printing a GiNaC expression with the operands of every sum and product in a canonical order.
//
// GiNaC's printers walk the operands of a sum or product in GiNaC's own order, which follows hash
// values seeded from addresses (ukdyn/symbolic/canonical.hpp): the same expression printed by two
// processes can list its terms differently. canonical_print() prints the same mathematics in an
// order fixed by the printed text alone: a product is its numeric factor, then its factors (those
// in a symbol first, then those in a function, then the rest, each group by its text); a sum is its
// number, then its terms by the text of each term without its numeric factor. Leaves (numbers,
// symbols, constants) and the names of functions are printed by GiNaC itself, in the format's own
// style (print_dflt, print_latex, print_csrc_double).
#pragma once

#include <ginac/ginac.h>

#include <string>

#include "ukdyn/symbolic/definitions.hpp"

namespace ukdyn::symbolic {

/// e printed in format f (text and matlab: GiNaC's default syntax; latex; c: C99 doubles), the
/// operands of sums and products in the canonical order above: the same bytes in every process.
std::string canonical_print(const GiNaC::ex& e, Format f);

}  // namespace ukdyn::symbolic
