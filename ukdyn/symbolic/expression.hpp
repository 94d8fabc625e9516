// Symbols and the expression parser of ukdyn::symbolic.
//
// Coordinates, their velocities and time are global, named GiNaC symbols: the coordinate `theta1`
// is the same symbol in every subsystem and constraint, its velocity is `theta1_dot`, time is `t`.
// Parameters are local to a definition (two subsystems may both have an `l1`).
//
// The parser reads  + - * / ^ (or **), parentheses, numbers (decimals are read exactly as
// rationals: 0.855 = 171/200), the constant pi, and the functions sin cos tan asin acos atan atan2
// exp log sqrt sinh cosh tanh abs. Unlike GiNaC's own reader it reports the column of every error.
#pragma once

#include <ginac/ginac.h>

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

/// The global symbol of coordinate `name` (created on first use).
GiNaC::symbol coordinate_symbol(const std::string& name);
/// The global symbol of the velocity of coordinate `name`, printed `name_dot`.
GiNaC::symbol velocity_symbol(const std::string& name);
/// The global time symbol `t`.
GiNaC::symbol time_symbol();
/// A new local symbol (a parameter or a let-name), with a LaTeX name derived from `name`.
GiNaC::symbol local_symbol(const std::string& name);
/// LaTeX for a name: theta1 → \theta_{1}, l_r → l_{r}, theta1_dot → \dot{\theta}_{1}.
std::string latex_name(const std::string& name);

/// Names the parser knows: name → expression (a symbol, or an expression for a let-name).
class Scope {
 public:
  /// Adds a name; throws ExpressionError (offset 0) if the name is taken or invalid.
  void add(const std::string& name, const GiNaC::ex& value);
  [[nodiscard]] bool has(const std::string& name) const { return names_.count(name) != 0; }
  [[nodiscard]] const std::map<std::string, GiNaC::ex>& names() const { return names_; }
  /// Parses `text`; throws ExpressionError with the offset of the problem.
  [[nodiscard]] GiNaC::ex parse(const std::string& text) const;

 private:
  std::map<std::string, GiNaC::ex> names_;
};

/// True if `name` is a valid identifier that is not reserved (t, pi, a function name).
bool valid_name(const std::string& name, std::string* why = nullptr);

}  // namespace ukdyn::symbolic
