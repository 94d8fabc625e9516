// Symbols and the expression parser of ukdyn::symbolic.
//
// Coordinates, their velocities and time are named GiNaC symbols interned in the SymbolTable of the
// system being derived: the coordinate `theta1` is the same symbol in every subsystem and
// constraint of that system, its velocity is `theta1_dot`, time is `t`. Parameters are local to a
// definition (two subsystems may both have an `l1`).
//
// The parser reads  + - * / ^ (or **), parentheses, numbers (decimals are read exactly as
// rationals: 0.855 = 171/200), the constant pi, and the functions sin cos tan asin acos atan atan2
// exp log sqrt sinh cosh tanh abs. Unlike GiNaC's own reader it reports the column of every error.
#pragma once

#include <ginac/ginac.h>

#include <cstdint>
#include <map>
#include <string>

#include "ukdyn/core/types.hpp"

namespace ukdyn::symbolic {

/// An error in an expression: `offset` is the 0-based character position in the text.
class ExpressionError : public Error {
 public:
  ExpressionError(const std::string& message, std::size_t offset_)
      : Error(message), offset(offset_) {}
  std::size_t offset;
};

/// The coordinate, velocity and time symbols of one system's derivation, interned by name: within
/// one table the coordinate `theta1` is one GiNaC symbol in every subsystem, constraint and force
/// that uses the table. A table belongs to whoever derives a system (docs/architecture.md,
/// "Symbols"): the scenario loader makes one per load; a definition (DefinitionScope) makes its own
/// unless it is given one; the definitions and the derivations that use a table hold it by
/// shared_ptr, so it is freed with the last of them (with the system). Not synchronised: one
/// derivation runs on one thread; two systems derived on two threads have two tables.
class SymbolTable {
 public:
  /// The symbol of coordinate `name` (created on first use).
  GiNaC::symbol coordinate(const std::string& name);
  /// The symbol of the velocity of coordinate `name`, printed `name_dot`.
  GiNaC::symbol velocity(const std::string& name);
  /// The time symbol `t`.
  GiNaC::symbol time();
  /// True if coordinate `name` has a symbol (a lookup that adds nothing).
  [[nodiscard]] bool has_coordinate(const std::string& name) const {
    return symbols_.count("q:" + name) != 0;
  }
  /// Symbols interned so far.
  [[nodiscard]] std::size_t size() const { return symbols_.size(); }

 private:
  GiNaC::symbol interned(const std::string& key, const std::string& print, const std::string& tex);
  std::map<std::string, GiNaC::symbol> symbols_;
};

/// table.coordinate(name), table.velocity(name), table.time().
GiNaC::symbol coordinate_symbol(SymbolTable& table, const std::string& name);
GiNaC::symbol velocity_symbol(SymbolTable& table, const std::string& name);
GiNaC::symbol time_symbol(SymbolTable& table);
/// A new local symbol (a parameter or a let-name), with a LaTeX name derived from `name`.
GiNaC::symbol local_symbol(const std::string& name);
/// LaTeX for a name: theta1 → \theta_{1}, l_r → l_{r}, theta1_dot → \dot{\theta}_{1}.
std::string latex_name(const std::string& name);

/// Names the parser knows: name → expression (a symbol, or an expression for a let-name).
class Scope {
 public:
  /// Adds a name; throws ExpressionError (offset 0) if the name is taken or invalid.
  void add(const std::string& name, const GiNaC::ex& value);
  /// Adds the time symbol of a SymbolTable as `t` (a name add() refuses).
  void add_time(const GiNaC::symbol& t);
  [[nodiscard]] bool has(const std::string& name) const { return names_.count(name) != 0; }
  [[nodiscard]] const std::map<std::string, GiNaC::ex>& names() const { return names_; }
  /// Parses `text`; throws ExpressionError with the offset of the problem.
  [[nodiscard]] GiNaC::ex parse(const std::string& text) const;

 private:
  std::map<std::string, GiNaC::ex> names_;
};

/// True if `name` is a valid identifier that is not reserved: [A-Za-z_][A-Za-z0-9_]{0,63}, not t,
/// pi or a function name, not a GiNaC constant (Pi, E, Euler, Catalan; I is allowed), not a keyword
/// of C or MATLAB nor a MATLAB constant (i, j, eps, Inf, NaN, ...), not starting with "__", "_" + a
/// capital letter (reserved in C) or "ukdyn_" (names of generated code). See docs/definitions.md,
/// "Names and limits".
bool valid_name(const std::string& name, std::string* why = nullptr);

/// The bounds on the work one input may cause (docs/definitions.md, "Limits"). Constants: raise one
/// here and rebuild.
namespace limits {
/// Characters in one expression.
inline constexpr std::size_t kExpressionChars = 10000;
/// Nesting of parentheses, function calls, unary signs and powers in one expression.
inline constexpr std::size_t kNesting = 100;
/// Digits in one number literal.
inline constexpr std::size_t kNumberDigits = 100;
/// Bits of an exact number (numerator plus denominator) made by the parser or a derivation.
inline constexpr long kNumberBits = 4096;
/// |exponent| of a power whose base is not a number (x^65 is fine, x^(2^65) is refused).
inline constexpr long kExponent = 1000;
/// Nodes of an expression written out as a tree (let-names count once per use).
inline constexpr std::size_t kTreeNodes = 200000;
/// Terms an expression may expand to (an upper bound: (a+b)^2 * (c+d) counts 8).
inline constexpr double kExpandedTerms = 200000;
/// Seconds for the derivation of one subsystem or constraint (M, C, G or A, b) from its text.
/// Wall-clock backstop for one derivation. The size limits above bound the work deterministically
/// (every bomb of tests/hostile/ ends under them in < 0.4 s); this one only stops what slips past
/// them. It is generous because wall time depends on the machine's load and on sanitizers: a 3 s
/// budget refused the Bricard benchmark on a loaded 2-core machine, and the same input must not
/// load or fail by the load of the machine.
inline constexpr double kDeriveSeconds = 60.0;
/// Coordinates of one derived subsystem (the derivation is cubic in them).
inline constexpr std::size_t kDerivedCoordinates = 120;
}  // namespace limits

/// Throws ExpressionError (offset 0) naming `what` if `e` exceeds limits::kTreeNodes,
/// limits::kExpandedTerms or limits::kNumberBits. Linear in the size of e as a DAG.
void check_expression_size(const GiNaC::ex& e, const std::string& what);

/// A derivation stopped by its Deadline; what() says where it stopped.
class DerivationTimeout : public Error {
 public:
  using Error::Error;
};

/// A time budget for one derivation; check() throws DerivationTimeout naming `where` once it is
/// spent. GiNaC's own operations cannot be interrupted, so a derivation checks between steps that
/// are each small: every entry and row, every term of an expansion (expand_checked).
class Deadline {
 public:
  explicit Deadline(double seconds = limits::kDeriveSeconds);
  void check(const std::string& where) const;

 private:
  double seconds_;
  std::int64_t end_ns_;
};

/// e.expand(), the same expression, built one term at a time (a product of sums: one term of the
/// first sum times the rest at a time) with deadline.check(where) between the terms, so that a
/// large expansion stops within about one term's work of the deadline.
GiNaC::ex expand_checked(const GiNaC::ex& e, const Deadline& deadline, const std::string& where);

}  // namespace ukdyn::symbolic
