// Printing derivations as LaTeX, C or MATLAB (ukdyn derive).
#include <sstream>

#include "ukdyn/symbolic/definitions.hpp"

namespace ukdyn::symbolic {

namespace {

using GiNaC::ex;

// Gather the coordinate-dependent factors (functions, velocities, time) of an expanded sum, so that
// each monomial in them carries one coefficient in the parameters: −(m1/2 + m2 + m3) l1 sin θ1 cos
// δ1.
ex collected(const ex& e) {
  GiNaC::exset kernels;
  e.find(GiNaC::sin(GiNaC::wild()), kernels);
  e.find(GiNaC::cos(GiNaC::wild()), kernels);
  GiNaC::lst vars;
  for (const ex& k : kernels) vars.append(k);
  GiNaC::exset syms;
  for (GiNaC::const_preorder_iterator it = e.preorder_begin(); it != e.preorder_end(); ++it) {
    if (GiNaC::is_a<GiNaC::symbol>(*it)) {
      const std::string n = GiNaC::ex_to<GiNaC::symbol>(*it).get_name();
      if (n == "t" || (n.size() > 4 && n.compare(n.size() - 4, 4, "_dot") == 0)) syms.insert(*it);
    }
  }
  for (const ex& s : syms) vars.append(s);
  if (vars.nops() == 0) return e;
  return e.collect(vars, true);
}

std::string print(const ex& e0, Format f) {
  const ex e = collected(e0);
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

namespace ukdyn::symbolic {

Format parse_format(const std::string& name) {
  if (name == "latex") return Format::latex;
  if (name == "c") return Format::c;
  if (name == "matlab") return Format::matlab;
  if (name == "text") return Format::text;
  throw Error("unknown format '" + name + "' (expected latex, c, matlab or text)");
}

std::string format_system(const System& system, Format f) {
  std::ostringstream os;
  const std::string c = f == Format::c ? "// " : f == Format::text ? "# " : "% ";
  const auto& subs = system.subsystems();
  for (std::size_t k = 0; k < subs.size(); ++k) {
    if (const auto* d = dynamic_cast<const DerivedSubsystem*>(subs[k].get())) {
      if (f == Format::c)
        os << "void " << d->name() << "_dynamics(const double* q, const double* qd, double M["
           << d->dof() << "][" << d->dof() << "], double C[" << d->dof() << "][" << d->dof()
           << "], double G[" << d->dof() << "]) {\n";
      if (f == Format::c) {
        for (Index i = 0; i < d->dof(); ++i) {
          const auto& nm = d->coordinate_names()[static_cast<std::size_t>(i)];
          os << "  const double " << nm << " = q[" << i << "], " << nm << "_dot = qd[" << i
             << "];\n";
        }
        os << "  (void)qd;\n";
      }
      os << format_derivation(d->derivation(), d->name(), f);
      if (f == Format::c) os << "}\n";
    } else {
      os << c << "subsystem '" << subs[k]->name() << "': built-in closed-form model, not derived\n";
    }
    os << "\n";
  }
  const auto& cons = system.constraints();
  for (std::size_t k = 0; k < cons.size(); ++k) {
    const auto& rn = cons[k]->row_names();
    if (const auto* d = dynamic_cast<const DerivedConstraint*>(cons[k].get())) {
      std::string name = rn.size() == 1 ? rn[0] : rn[0].substr(0, rn[0].rfind('_'));
      for (const auto& r : rn) {
        if (r.compare(0, name.size(), name) != 0) name = "constraint_" + std::to_string(k + 1);
      }
      os << format_derivation(d->derivation(), name, f);
    } else {
      os << c << "constraint rows";
      for (const auto& r : rn) os << " " << r;
      os << ": built-in closed form, not derived\n";
    }
    os << "\n";
  }
  return os.str();
}

}  // namespace ukdyn::symbolic
