// A deterministic order of the operands of GiNaC sums and products.
//
// GiNaC keeps the operands of an add or mul sorted by its own hash values, and the hash of every
// class is seeded from the ADDRESS of the class's type name (ginac/hash_seed.h, unless GiNaC was
// built with GINAC_HASH_USE_MANGLED_NAME): with address-space randomisation the order of the terms
// of one expression differs from process to process. Anything that walks e.op(i) of a sum in that
// order and adds floating-point numbers (a compiled tape) then gives results that differ in the
// last bits between runs. StructuralOrder orders expressions by a hash computed from their
// structure only (names of symbols and functions, exact numbers, the multiset of the operands of a
// sum or product), with a full structural comparison on ties: the same expression gives the same
// order in every process.
#pragma once

#include <ginac/ginac.h>

#include <cstdint>
#include <map>
#include <vector>

namespace ukdyn::symbolic {

/// The exact value of a finite double as a GiNaC rational (m · 2^e). Floats inside expressions
/// would make GiNaC's own arithmetic depend on its (process-dependent) operand order; exact
/// rationals cannot. Throws ukdyn::Error for NaN or infinity.
GiNaC::ex exact_rational(double v);

/// e with every non-integer rational whose numerator and denominator together exceed max_bits
/// replaced by the exact rational of its nearest double (exact_rational()). The rounding of an
/// exact number does not depend on any operand order, so the result is the same in every process;
/// it bounds the growth of the numbers when rotations by constant angles are composed
/// (symbolic/chain.cpp).
GiNaC::ex round_long_rationals(const GiNaC::ex& e, long max_bits = 256);

class StructuralOrder {
 public:
  /// A 64-bit hash of e's structure, independent of GiNaC's hash and of addresses. Invariant
  /// under reordering the operands of sums and products.
  std::uint64_t hash(const GiNaC::ex& e);
  /// A total order (−1, 0, 1) on expressions that depends on their structure only; 0 for
  /// structurally equal expressions.
  int compare(const GiNaC::ex& a, const GiNaC::ex& b);
  /// The operands of e (e.op(0..nops)) in the order of compare().
  std::vector<GiNaC::ex> sorted_operands(const GiNaC::ex& e);

 private:
  // Looked up only (never iterated), so GiNaC's hash-based ordering of the keys does not matter.
  std::map<GiNaC::ex, std::uint64_t, GiNaC::ex_is_less> memo_;
};

}  // namespace ukdyn::symbolic
