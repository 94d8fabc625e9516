// Printing derivations as LaTeX, C or MATLAB (ukdyn derive).
//
// Names are checked when a scenario is loaded (expression.hpp, valid_name), and printed here as
// safely as if they were not: comment text is reduced to printable ASCII (a CR or LF can never end
// a comment; C comments are /* */ with "*/" broken up), a C function name is made an identifier, a
// symbol whose name is one of the generated names (q, qd, t, M, C, G, Phi, A, b) is renamed with a
// trailing '_' in C and MATLAB, and the constant pi prints as M_PI in C and pi in MATLAB.
#include <algorithm>
#include <map>
#include <set>
#include <sstream>

#include "symbolic/canonical_print.hpp"
#include "ukdyn/symbolic/canonical.hpp"
#include "ukdyn/symbolic/definitions.hpp"
#include "ukdyn/symbolic/frame_constraints.hpp"
#include "ukdyn/tree/tree.hpp"

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
  // The kernels in a process-independent order (GiNaC's exset is ordered by address-seeded hashes).
  std::vector<ex> sorted(kernels.begin(), kernels.end());
  StructuralOrder order;
  std::stable_sort(sorted.begin(), sorted.end(),
                   [&](const ex& a, const ex& b) { return order.compare(a, b) < 0; });
  GiNaC::lst vars;
  for (const ex& k : sorted) vars.append(k);
  std::map<std::string, ex> syms;  // by name, not in GiNaC's (process-dependent) walk order
  for (GiNaC::const_preorder_iterator it = e.preorder_begin(); it != e.preorder_end(); ++it) {
    if (GiNaC::is_a<GiNaC::symbol>(*it)) {
      const std::string n = GiNaC::ex_to<GiNaC::symbol>(*it).get_name();
      if (n == "t" || (n.size() > 4 && n.compare(n.size() - 4, 4, "_dot") == 0))
        syms.emplace(n, *it);
    }
  }
  for (const auto& [n, s] : syms) vars.append(s);
  if (vars.nops() == 0) return e;
  // Collecting is cosmetic: GiNaC refuses to collect a polynomial in t or a velocity that the
  // expression holds with a non-integer exponent (sqrt(1 − t²) from d/dt acos(t): "mul::ldegree()
  // undefined degree because of non-integer exponent"); the expression is then printed as it is.
  try {
    return e.collect(vars, true);
  } catch (const std::exception&) {
    return e;
  }
}

// The parameters by name (an exmap is ordered by GiNaC's process-dependent hashes).
std::vector<std::pair<ex, ex>> by_name(const GiNaC::exmap& params) {
  std::vector<std::pair<ex, ex>> v(params.begin(), params.end());
  const auto name = [](const ex& e) {
    return GiNaC::is_a<GiNaC::symbol>(e) ? GiNaC::ex_to<GiNaC::symbol>(e).get_name()
                                         : canonical_print(e, Format::text);
  };
  std::stable_sort(v.begin(), v.end(),
                   [&](const auto& a, const auto& b) { return name(a.first) < name(b.first); });
  return v;
}

// Printable ASCII only: a control byte (CR, LF, ...) is shown as '?'.
std::string printable(const std::string& s) {
  std::string out;
  for (char ch : s) {
    const auto u = static_cast<unsigned char>(ch);
    out += u >= 0x20 && u < 0x7f ? ch : '?';
  }
  return out;
}

// A C identifier made from `name` (invalid characters become '_').
std::string c_identifier(const std::string& name) {
  std::string out;
  for (char ch : name) out += std::isalnum(static_cast<unsigned char>(ch)) ? ch : '_';
  if (out.empty() || std::isdigit(static_cast<unsigned char>(out[0]))) out = "_" + out;
  return out;
}

const std::set<std::string>& generated_names() {
  static const std::set<std::string> g = {"q", "qd", "t", "M", "C", "G", "Phi", "A", "b"};
  return g;
}

// Renames, for C and MATLAB, the symbols whose names the generated code uses itself.
GiNaC::exmap renames(const ex& e, Format f) {
  GiNaC::exmap m;
  if (f != Format::c && f != Format::matlab) return m;
  std::set<std::string> taken;
  std::vector<GiNaC::symbol> clash;
  for (GiNaC::const_preorder_iterator it = e.preorder_begin(); it != e.preorder_end(); ++it) {
    if (!GiNaC::is_a<GiNaC::symbol>(*it)) continue;
    const auto& sy = GiNaC::ex_to<GiNaC::symbol>(*it);
    taken.insert(sy.get_name());
    if (sy.get_name() != "t" && generated_names().count(sy.get_name())) clash.push_back(sy);
  }
  for (const auto& sy : clash) {
    std::string n = sy.get_name() + "_";
    while (taken.count(n) || generated_names().count(n)) n += "_";
    taken.insert(n);
    m[sy] = GiNaC::symbol(n);
  }
  return m;
}

std::string print(const ex& e0, Format f, const GiNaC::exmap& rename = {}) {
  ex e = collected(e0);
  if (!rename.empty()) e = e.subs(rename);
  // Sums and products in a canonical order, not GiNaC's (canonical_print.hpp).
  std::string s =
      canonical_print(f == Format::c ? e.subs(GiNaC::Pi == GiNaC::symbol("M_PI")) : e, f);
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

// One comment line holding `text` (printable ASCII; in C a /* */ comment that "*/" cannot end).
std::string comment_line(Format f, const std::string& text) {
  std::string t = printable(text);
  switch (f) {
    case Format::latex:
    case Format::matlab:
      return "% " + t + "\n";
    case Format::c: {
      std::string out;
      for (std::size_t i = 0; i < t.size(); ++i) {
        out += t[i];
        if (t[i] == '*' && i + 1 < t.size() && t[i + 1] == '/') out += ' ';
        if (t[i] == '/' && i + 1 < t.size() && t[i + 1] == '*') out += ' ';
      }
      return "/* " + out + " */\n";
    }
    default:
      return "# " + t + "\n";
  }
}

// One entry; indices 1-based in LaTeX/MATLAB/text, 0-based in C.
void entry(std::ostream& os, Format f, const std::string& name, unsigned i, unsigned j, bool vector,
           const ex& e, const GiNaC::exmap& rename) {
  const std::string v = print(e, f, rename);
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
            const GiNaC::exmap& params, bool time, const GiNaC::exmap& rename) {
  std::string line = "coordinates q = [";
  for (std::size_t i = 0; i < coords.size(); ++i) line += (i ? ", " : "") + coords[i];
  line += std::string("], velocities <name>_dot") + (time ? ", time t" : "");
  os << comment_line(f, line);
  if (params.empty()) return;
  if (f == Format::latex) {
    line = "parameters:";
    for (const auto& [s, v] : by_name(params))
      line += " " + print(s, Format::text) + " = " + print(v, Format::text) + ";";
    os << comment_line(f, line);
  } else if (f == Format::c) {
    for (const auto& [s, v] : by_name(params)) {
      const std::string n = print(s, f, rename);
      os << "  const double " << n << " = " << print(v, f) << ";\n  (void)" << n << ";\n";
    }
  } else {
    for (const auto& [s, v] : by_name(params))
      os << print(s, f, rename) << " = " << print(v, f) << ";\n";
  }
}

void block(std::ostream& os, Format f, const std::string& name, const GiNaC::matrix& m,
           bool symmetric, bool vector, const GiNaC::exmap& rename) {
  os << comment_line(
      f, name + (symmetric ? " (symmetric: upper triangle)" : "") + ", nonzero entries");
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
      entry(os, f, name, i, j, vector, m(i, j), rename);
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

namespace {

// Every symbol the derivation's output holds (for renames()).
ex all_symbols(SymbolTable& symbols, const std::vector<std::string>& coords,
               const GiNaC::exmap& params) {
  GiNaC::lst l;
  for (const auto& c : coords) {
    l.append(coordinate_symbol(symbols, c));
    l.append(velocity_symbol(symbols, c));
  }
  for (const auto& [s, v] : by_name(params)) l.append(s);
  return l;
}

// The name a coordinate (or its velocity) prints as.
std::string printed_name(const GiNaC::symbol& s, Format f, const GiNaC::exmap& rename) {
  return print(s, f, rename);
}

}  // namespace

std::string format_derivation(const SubsystemDerivation& d, const std::string& name, Format f) {
  std::ostringstream os;
  const GiNaC::exmap rename =
      renames(all_symbols(*d.symbols, d.coordinates, d.parameter_values), f);
  os << comment_line(
      f, "subsystem '" + name + "': M (Eq. 5), C from Christoffel symbols (Eq. 9), G (Eq. 8)");
  header(os, f, d.coordinates, d.parameter_values, false, rename);
  block(os, f, "M", d.M, true, false, rename);
  block(os, f, "C", d.C, false, false, rename);
  block(os, f, "G", d.G, false, true, rename);
  return os.str();
}

std::string format_derivation(const ConstraintDerivation& d, const std::string& name, Format f) {
  std::ostringstream os;
  const GiNaC::exmap rename =
      renames(all_symbols(*d.symbols, d.coordinates, d.parameter_values), f);
  std::string line =
      "constraint '" + name + "' (" + (d.holonomic ? "holonomic" : "nonholonomic") + "), rows:";
  for (const auto& r : d.row_names) line += " " + r;
  os << comment_line(f, line) << comment_line(f, "A qdd = b");
  header(os, f, d.coordinates, d.parameter_values, true, rename);
  if (d.holonomic) block(os, f, "Phi", d.phi, false, true, rename);
  block(os, f, "A", d.A, false, false, rename);
  block(os, f, "b", d.b, false, true, rename);
  return os.str();
}

namespace {

// The C function around a derivation: the coordinate and velocity variables, the outputs zeroed.
void c_variables(std::ostream& os, SymbolTable& symbols, const std::vector<std::string>& coords,
                 const GiNaC::exmap& rename) {
  for (std::size_t i = 0; i < coords.size(); ++i) {
    const std::string qn = printed_name(coordinate_symbol(symbols, coords[i]), Format::c, rename);
    const std::string vn = printed_name(velocity_symbol(symbols, coords[i]), Format::c, rename);
    os << "  const double " << qn << " = q[" << i << "], " << vn << " = qd[" << i << "];\n";
    os << "  (void)" << qn << ";\n  (void)" << vn << ";\n";
  }
  os << "  (void)q;\n  (void)qd;\n";
}

void c_zero(std::ostream& os, const std::string& array, std::size_t count) {
  os << "  for (int k = 0; k < " << count << "; ++k) (&" << array << ")[k] = 0.0;\n";
}

// A unique C function name made from `name` and `suffix`.
std::string c_function_name(const std::string& name, const std::string& suffix,
                            std::set<std::string>& used) {
  std::string base = c_identifier(name) + suffix, n = base;
  for (int k = 2; used.count(n); ++k) n = base + "_" + std::to_string(k);
  used.insert(n);
  return n;
}

}  // namespace

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
  std::set<std::string> functions;  // C function names used so far
  if (f == Format::c) {
    os << comment_line(f, "generated by ukdyn derive: C99, link with -lm") << "#include <math.h>\n"
       << "#ifndef M_PI\n#define M_PI 3.14159265358979323846\n#endif\n\n";
  }
  const auto& subs = system.subsystems();
  for (std::size_t k = 0; k < subs.size(); ++k) {
    if (const auto* d = dynamic_cast<const DerivedSubsystem*>(subs[k].get())) {
      const auto& dv = d->derivation();
      if (dv.time_varying) {
        // A mass of t (docs/definitions.md, "Time-varying masses"): the generated C function has
        // no t, and C below is the Christoffel matrix without the (∂M/∂t) q̇ term.
        if (f == Format::c) {
          throw Error("subsystem '" + d->name() +
                      "' has a mass or inertia of t: the C output does not support time-varying "
                      "subsystems (use latex, matlab or text)");
        }
        os << comment_line(f, "subsystem '" + d->name() +
                                  "' has a mass or inertia of t: its equations are M(q,t) qdd + "
                                  "C qd + (dM/dt) qd + G(q,t) = tau; C below excludes the "
                                  "(dM/dt) qd term");
      }
      if (f == Format::c) {
        const auto n = static_cast<std::size_t>(d->dof());
        os << "void " << c_function_name(d->name(), "_dynamics", functions)
           << "(const double* q, const double* qd, double M[" << n << "][" << n << "], double C["
           << n << "][" << n << "], double G[" << n << "]) {\n";
        c_variables(os, *dv.symbols, dv.coordinates,
                    renames(all_symbols(*dv.symbols, dv.coordinates, dv.parameter_values), f));
        c_zero(os, "M[0][0]", n * n);
        c_zero(os, "C[0][0]", n * n);
        c_zero(os, "G[0]", n);
      }
      os << format_derivation(dv, d->name(), f);
      if (f == Format::c) os << "}\n";
    } else if (dynamic_cast<const tree::TreeSubsystem*>(subs[k].get()) != nullptr) {
      os << comment_line(f,
                         "subsystem '" + subs[k]->name() +
                             "': dynamics: tree (recursive algorithms, docs/tree-algorithms.md), "
                             "not derived; dynamics: auto or symbolic derives it");
    } else {
      os << comment_line(
          f, "subsystem '" + subs[k]->name() + "': built-in closed-form model, not derived");
    }
    os << "\n";
  }
  const auto& cons = system.constraints();
  for (std::size_t k = 0; k < cons.size(); ++k) {
    const auto& rn = cons[k]->row_names();
    const auto* d = dynamic_cast<const DerivedConstraint*>(cons[k].get());
    if (const auto* fc = dynamic_cast<const FrameConstraint*>(cons[k].get())) d = fc->derived();
    if (d != nullptr) {
      std::string name = rn.size() == 1 ? rn[0] : rn[0].substr(0, rn[0].rfind('_'));
      for (const auto& r : rn) {
        if (r.compare(0, name.size(), name) != 0) name = "constraint_" + std::to_string(k + 1);
      }
      const auto& dv = d->derivation();
      if (f == Format::c) {
        const std::size_t m = dv.row_names.size(), n = dv.coordinates.size();
        os << "void " << c_function_name(name, "_constraint", functions)
           << "(const double* q, const double* qd, double t, ";
        if (dv.holonomic) os << "double Phi[" << m << "], ";
        os << "double A[" << m << "][" << n << "], double b[" << m << "]) {\n";
        c_variables(os, *dv.symbols, dv.coordinates,
                    renames(all_symbols(*dv.symbols, dv.coordinates, dv.parameter_values), f));
        os << "  (void)t;\n";
        if (dv.holonomic) c_zero(os, "Phi[0]", m);
        c_zero(os, "A[0][0]", m * n);
        c_zero(os, "b[0]", m);
      }
      os << format_derivation(dv, name, f);
      if (f == Format::c) os << "}\n";
    } else {
      std::string line = "constraint rows";
      for (const auto& r : rn) line += " " + r;
      os << comment_line(f, line + ": built-in closed form, not derived");
    }
    os << "\n";
  }
  return os.str();
}

}  // namespace ukdyn::symbolic
