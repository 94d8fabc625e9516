// Small helpers on GiNaC expressions shared by the symbolic sources (definitions.cpp, forces.cpp,
// chain.cpp, frame_constraints.cpp). Internal to ukdyn::symbolic (not installed).
#pragma once

#include <ginac/ginac.h>

#include <sstream>
#include <string>

namespace ukdyn::symbolic {

/// e as GiNaC prints it (for messages).
inline std::string str(const GiNaC::ex& e) {
  std::ostringstream os;
  os << e;
  return os.str();
}

/// Parameters substituted, expanded: polynomials in the coordinates' functions with exact
/// coefficients, whose form does not depend on GiNaC's hash order. What a tape compiles.
inline GiNaC::ex numeric_form(const GiNaC::ex& e, const GiNaC::exmap& values) {
  return e.subs(values).expand();
}

}  // namespace ukdyn::symbolic
