// Printing derivations as LaTeX, C or MATLAB (ukdyn derive).
#include <sstream>

#include "ukdyn/symbolic/definitions.hpp"

namespace ukdyn::symbolic {

namespace {

using GiNaC::ex;

std::string print(const ex& e, Format f) {
  std::ostringstream os;
  switch (f) {
    case Format::latex:
      os << GiNaC::latex << e;
      break;
    case Format::c:
      os << GiNaC::csrc_double << e;
      break;
    default:
      os << GiNaC::dflt << e;
      break;
  }
  std::string s = os.str();
  if (f == Format::matlab || f == Format::text) {
    // GiNaC prints the constant π as "Pi".
    std::string out;
    for (std::size_t i = 0; i < s.size(); ++i) {
      const bool word_start =
          i == 0 || !(std::isalnum(static_cast<unsigned char>(s[i - 1])) || s[i - 1] == '_');
      const bool word_end =
          i + 2 >= s.size() ||
          !(std::isalnum(static_cast<unsigned char>(s[i + 2])) || s[i + 2] == '_');
      if (word_start && word_end && s.compare(i, 2, "Pi") == 0) {
        out += "pi";
        ++i;
      } else {
        out += s[i];
      }
    }
    s = out;
  }
  return s;
}

std::string comment(Format f) {
  switch (f) {
    case Format::latex:
      return "% ";
    case Format::c:
      return "// ";
    case Format::matlab:
      return "% ";
    default:
      return "# ";
  }
}

// One entry; indices 1-based in LaTeX/MATLAB/text, 0-based in C.
void entry(std::ostream& os, Format f, const std::string& name, unsigned i, unsigned j, bool vector,
           const ex& e) {
  const std::string v = print(e, f);
  switch (f) {
    case Format::latex:
      os << name << "_{" << (i + 1);
      if (!vector) os << "," << (j + 1);
      os << "} &= " << v << " \\\\\n";
      break;
    case Format::c:
      os << "  " << name << "[" << i << "]";
      if (!vector) os << "[" << j << "]";
      os << " = " << v << ";\n";
      break;
    default:
      os << name << "(" << (i + 1);
      if (!vector) os << "," << (j + 1);
      os << ") = " << v << ";\n";
      break;
  }
}

void header(std::ostream& os, Format f, const std::vector<std::string>& coords,
            const GiNaC::exmap& params, bool time) {
  const std::string c = comment(f);
  os << c << "coordinates q = [";
  for (std::size_t i = 0; i < coords.size(); ++i) os << (i ? ", " : "") << coords[i];
  os << "], velocities <name>_dot" << (time ? ", time t" : "") << "\n";
  if (params.empty()) return;
  if (f == Format::latex) {
    os << c << "parameters:";
    for (const auto& [s, v] : params)
      os << " " << print(s, Format::text) << " = " << print(v, Format::text) << ";";
    os << "\n";
  } else if (f == Format::c) {
    for (const auto& [s, v] : params)
      os << "  const double " << print(s, f) << " = " << print(v, f) << ";\n";
  } else {
    for (const auto& [s, v] : params) os << print(s, f) << " = " << print(v, f) << ";\n";
  }
}

void block(std::ostream& os, Format f, const std::string& name, const GiNaC::matrix& m,
           bool symmetric, bool vector) {
  const std::string c = comment(f);
  os << c << name << (symmetric ? " (symmetric: upper triangle)" : "") << ", nonzero entries\n";
  if (f == Format::latex) os << "\\begin{align*}\n";
  if (f == Format::matlab) {
    os << name << " = zeros(" << m.rows() << (vector ? ", 1" : ", " + std::to_string(m.cols()))
       << ");\n";
  }
  bool any = false;
  for (unsigned i = 0; i < m.rows(); ++i) {
    for (unsigned j = symmetric ? i : 0; j < m.cols(); ++j) {
      if (m(i, j).is_zero()) continue;
      any = true;
      entry(os, f, name, i, j, vector, m(i, j));
      if (symmetric && j != i && f != Format::latex && f != Format::text) {
        if (f == Format::c) {
          os << "  " << name << "[" << j << "][" << i << "] = " << name << "[" << i << "][" << j
             << "];\n";
        } else {
          os << name << "(" << (j + 1) << "," << (i + 1) << ") = " << name << "(" << (i + 1) << ","
             << (j + 1) << ");\n";
        }
      }
    }
  }
  if (!any && f == Format::latex) os << name << " &= 0\n";
  if (f == Format::latex) os << "\\end{align*}\n";
}

}  // namespace

std::string format_derivation(const SubsystemDerivation& d, const std::string& name, Format f) {
  std::ostringstream os;
  const std::string c = comment(f);
  os << c << "subsystem '" << name
     << "': M (Eq. 5), C from Christoffel symbols (Eq. 9), G (Eq. 8)\n";
  header(os, f, d.coordinates, d.parameter_values, false);
  block(os, f, "M", d.M, true, false);
  block(os, f, "C", d.C, false, false);
  block(os, f, "G", d.G, false, true);
  return os.str();
}

std::string format_derivation(const ConstraintDerivation& d, const std::string& name, Format f) {
  std::ostringstream os;
  const std::string c = comment(f);
  os << c << "constraint '" << name << "' (" << (d.holonomic ? "holonomic" : "nonholonomic")
     << "), rows:";
  for (const auto& r : d.row_names) os << " " << r;
  os << "\n" << c << "A qdd = b\n";
  header(os, f, d.coordinates, d.parameter_values, true);
  if (d.holonomic) block(os, f, "Phi", d.phi, false, true);
  block(os, f, "A", d.A, false, false);
  block(os, f, "b", d.b, false, true);
  return os.str();
}

}  // namespace ukdyn::symbolic
