// Printing with sums and products in a canonical order (canonical_print.hpp).
//
// The layout follows GiNaC 1.8's own printers (add::print_add / do_print_csrc, mul::do_print /
// do_print_latex / do_print_csrc, power::do_print_dflt / do_print_latex / do_print_csrc: the
// precedences 40, 50, 60, a sum's number first, a product's numeric factor first, negative powers
// as fractions in LaTeX and as divisions in C); only the order of the operands is ours. Anything
// that is not a sum, product or power is printed by GiNaC, its operands replaced by placeholder
// symbols that are then replaced by their own canonical text.
#include "symbolic/canonical_print.hpp"

#include <algorithm>
#include <functional>
#include <sstream>
#include <utility>
#include <vector>

namespace ukdyn::symbolic {

namespace {

using GiNaC::ex;
using GiNaC::ex_to;
using GiNaC::is_a;
using GiNaC::numeric;

constexpr unsigned kAdd = 40, kMul = 50, kPower = 60;  // GiNaC's precedences

bool leaf(const ex& e) {
  return is_a<numeric>(e) || is_a<GiNaC::symbol>(e) || is_a<GiNaC::constant>(e);
}

// The factors of a product in canonical order: those in a symbol, then in a function, then the
// rest (sums, ...), each group by its text.
int rank(const ex& factor) {
  const ex base = is_a<GiNaC::power>(factor) ? factor.op(0) : factor;
  if (leaf(base)) return 0;
  if (is_a<GiNaC::function>(base)) return 1;
  return 2;
}

std::string joined(const std::vector<std::string>& parts, const std::string& sep) {
  std::string s;
  for (std::size_t i = 0; i < parts.size(); ++i) s += (i ? sep : "") + parts[i];
  return s;
}

// The numeric factor k of a product and its other factors.
numeric split(const ex& e, std::vector<ex>& factors) {
  numeric k = 1;
  for (std::size_t i = 0; i < e.nops(); ++i) {
    if (is_a<numeric>(e.op(i))) {
      k = k.mul(ex_to<numeric>(e.op(i)));
    } else {
      factors.push_back(e.op(i));
    }
  }
  return k;
}

bool negative(const numeric& k) { return k.is_real() && k.is_negative(); }

// A sum to an integer power.
bool sum_power(const ex& e) {
  return is_a<GiNaC::power>(e) && is_a<GiNaC::add>(e.op(0)) && is_a<numeric>(e.op(1)) &&
         ex_to<numeric>(e.op(1)).is_integer();
}

class Printer {
 public:
  explicit Printer(Format f) : f_(f) {}

  std::string print(const ex& e, unsigned level) {
    if (is_a<GiNaC::add>(e)) return sum(e, level);
    if (is_a<GiNaC::mul>(e)) return product(e, level);
    if (sum_power(e)) {  // through the product path, where its sign is made canonical
      numeric k = 1;
      const Texts t = texts({e}, k);
      const std::string s = assemble(k, t);
      return kMul <= level ? open() + s + close() : s;
    }
    if (is_a<GiNaC::power>(e)) return power(e.op(0), e.op(1), level, nullptr);
    if (leaf(e) || e.nops() == 0) return ginac(e, level);
    return other(e, level);
  }

 private:
  bool latex() const { return f_ == Format::latex; }
  bool c() const { return f_ == Format::c; }

  // GiNaC's own printing of e at `level` in this format.
  std::string ginac(const ex& e, unsigned level) const {
    std::ostringstream os;
    if (latex()) {
      GiNaC::print_latex ctx(os);
      e.print(ctx, level);
    } else if (c()) {
      GiNaC::print_csrc_double ctx(os);
      e.print(ctx, level);
    } else {
      GiNaC::print_dflt ctx(os);
      e.print(ctx, level);
    }
    return os.str();
  }

  std::string open() const { return latex() ? "{(" : "("; }
  std::string close() const { return latex() ? ")}" : ")"; }

  // A function (or any other object with operands): GiNaC prints it with placeholder symbols for
  // its operands (names no valid symbol can have), which are then replaced by the operands' text.
  std::string other(const ex& e, unsigned level) {
    ex copy = e;
    std::vector<std::pair<std::string, std::string>> parts;
    for (std::size_t i = 0; i < e.nops(); ++i) {
      const std::string name = "\x1f" + std::to_string(placeholders_++) + "\x1f";
      parts.emplace_back(name, print(e.op(i), 0));
      copy.let_op(i) = GiNaC::symbol(name, name);
    }
    std::string s = ginac(copy, level);
    for (const auto& [name, text] : parts) {
      for (std::size_t at = s.find(name); at != std::string::npos;
           at = s.find(name, at + text.size()))
        s.replace(at, name.size(), text);
    }
    return s;
  }

  // A factor's text; a sum (or an integer power of one) whose first term is negative is printed
  // negated, its sign moved into k. GiNaC picks the sign of such a sum by its own term order
  // (1/(a − b) or −1/(b − a)), so that the sign, too, would differ between processes.
  std::string factor_text(const ex& x, unsigned level, numeric& k) {
    if (is_a<GiNaC::add>(x)) {
      const Sum s = sum_parts(x);
      const bool flip = leading_negative(s);
      if (flip) k = k.mul(-1);
      return render(s, flip, level);
    }
    if (sum_power(x)) {
      const Sum s = sum_parts(x.op(0));
      const bool flip = leading_negative(s);
      if (flip && !ex_to<numeric>(x.op(1)).is_even()) k = k.mul(-1);
      const auto base = [&](unsigned l) { return render(s, flip, l); };
      return power(x.op(0), x.op(1), level, base);
    }
    return print(x, level);
  }

  std::vector<std::string> sorted_factors(const std::vector<ex>& factors, unsigned level,
                                          numeric& k) {
    std::vector<std::pair<int, std::string>> keyed;
    keyed.reserve(factors.size());
    for (const ex& x : factors) keyed.emplace_back(rank(x), factor_text(x, level, k));
    std::sort(keyed.begin(), keyed.end());
    std::vector<std::string> out;
    out.reserve(keyed.size());
    for (auto& kv : keyed) out.push_back(std::move(kv.second));
    return out;
  }

  // The numeric factor before the other factors: "-", "2*", "-1/2*" (GiNaC's
  // mul::print_overall_coeff; a rational at level 0, any other number at the product's level).
  std::string coefficient(const numeric& k, const std::string& mul_sym) const {
    std::string s = negative(k) ? "-" : "";
    const numeric a = negative(k) ? k.mul(-1) : k;
    if (a.is_equal(1)) return s;
    return s + ginac(a, a.is_rational() ? 0 : kMul) + mul_sym;
  }

  std::string product(const ex& e, unsigned level) {
    std::vector<ex> factors;
    numeric k = split(e, factors);
    const Texts t = texts(factors, k);
    const std::string s = assemble(k, t);
    return kMul <= level ? open() + s + close() : s;
  }

  // True for a factor x^n with n a negative number (LaTeX: in the denominator) or a negative
  // integer (C: a division).
  bool divides(const ex& x) const {
    if (!is_a<GiNaC::power>(x) || !is_a<numeric>(x.op(1))) return false;
    const numeric& n = ex_to<numeric>(x.op(1));
    return c() ? n.is_integer() && n.is_negative() : negative(n);
  }

  // The texts of a product's factors, sorted: the numerator and (LaTeX, C) the denominator.
  struct Texts {
    std::vector<std::string> num, den;
  };

  Texts texts(const std::vector<ex>& factors, numeric& k) {
    std::vector<ex> num, den;
    for (const ex& x : factors) {
      if ((latex() || c()) && divides(x)) {
        den.push_back(GiNaC::pow(x.op(0), -x.op(1)));
      } else {
        num.push_back(x);
      }
    }
    // LaTeX: a lone numerator or denominator of \frac at level 0 (GiNaC prints mul(others)).
    const bool frac = latex() && !den.empty();
    Texts t;
    t.num = sorted_factors(num, frac && num.size() == 1 ? 0 : kMul, k);
    t.den = sorted_factors(den, frac && den.size() == 1 ? 0 : kMul, k);
    return t;
  }

  // The product k · factors, without the parentheses of its level.
  std::string assemble(const numeric& k, const Texts& t) const {
    if (latex()) {
      if (t.den.empty()) return coefficient(k, " ") + joined(t.num, " ");
      return coefficient(k, " ") + "\\frac{" + (t.num.empty() ? "1" : joined(t.num, " ")) + "}{" +
             joined(t.den, " ") + "}";
    }
    if (!c()) return coefficient(k, "*") + joined(t.num, "*");
    // C: "-(2.0/3.0)*x*y/z/(w*w)", each divisor one operand of '/'.
    std::string s;
    const std::string num = joined(t.num, "*");
    if (k.is_equal(-1)) {
      s = "-" + (num.empty() ? std::string("1.0") : num);
    } else if (k.is_equal(1)) {
      s = num.empty() ? std::string("1.0") : num;
    } else {
      s = ginac(k, kMul) + (num.empty() ? "" : "*" + num);
    }
    for (const std::string& d : t.den) s += "/" + d;
    return s;
  }

  // A sum: its number and its terms, sorted by the text of their factors, then their numeric
  // factor (the text holds the term without its sign).
  struct Term {
    std::string key, text;
    bool negative;
    bool operator<(const Term& o) const {
      if (key != o.key) return key < o.key;
      return text != o.text ? text < o.text : negative < o.negative;
    }
  };
  struct Sum {
    numeric constant = 0;
    std::vector<Term> terms;
  };

  Sum sum_parts(const ex& e) {
    Sum out;
    for (std::size_t i = 0; i < e.nops(); ++i) {
      const ex& t = e.op(i);
      if (is_a<numeric>(t)) {
        out.constant = out.constant.add(ex_to<numeric>(t));
        continue;
      }
      std::vector<ex> factors;
      numeric k = 1;
      if (is_a<GiNaC::mul>(t)) {
        k = split(t, factors);
      } else {
        factors.push_back(t);
      }
      const Texts tx = texts(factors, k);
      const bool neg = negative(k);
      out.terms.push_back({joined(tx.num, "*") + "/" + joined(tx.den, "*"),
                           assemble(neg ? k.mul(-1) : k, tx), neg});
    }
    std::sort(out.terms.begin(), out.terms.end());
    return out;
  }

  // The sum, or with flip its negation, at `level`.
  std::string render(const Sum& sum, bool flip, unsigned level) const {
    std::string s;
    const numeric constant = flip ? sum.constant.mul(-1) : sum.constant;
    const bool has_constant = !constant.is_zero();
    if (has_constant && !c()) s = ginac(constant, 0);  // GiNaC: the number first (C: last)
    for (const Term& t : sum.terms) {
      if (t.negative != flip) {
        s += "-";
      } else if (!s.empty()) {
        s += "+";
      }
      s += t.text;
    }
    if (has_constant && c()) {
      if (!negative(constant) && !s.empty()) s += "+";
      s += ginac(constant, kAdd);
    }
    return kAdd <= level ? open() + s + close() : s;
  }

  std::string sum(const ex& e, unsigned level) { return render(sum_parts(e), false, level); }

  // The first term in the canonical order is negative (the number alone: it is negative).
  bool leading_negative(const Sum& s) const {
    return s.terms.empty() ? negative(s.constant) : s.terms.front().negative;
  }

  // base^expo; base_text(level) prints the base (the base itself when null).
  std::string power(const ex& base, const ex& expo, unsigned level,
                    const std::function<std::string(unsigned)>& base_text) {
    if (!base_text && leaf(base) && leaf(expo))
      return ginac(GiNaC::pow(base, expo), level);  // no sum or product inside
    const auto b = [&](unsigned l) { return base_text ? base_text(l) : print(base, l); };
    const bool half = expo.is_equal(GiNaC::numeric(1, 2));
    if (latex()) {
      if (is_a<numeric>(expo) && negative(ex_to<numeric>(expo)))
        return "\\frac{1}{" + power(base, -expo, 0, base_text) + "}";
      if (half) return "\\sqrt{" + b(0) + "}";
      const std::string s = b(kPower) + "^{" + print(expo, kPower) + "}";
      return kPower <= level ? open() + s + close() : s;
    }
    if (c()) {
      if (expo.is_equal(-1)) {
        const std::string s = "1.0/(" + b(0) + ")";
        return kMul <= level ? "(" + s + ")" : s;
      }
      return "pow(" + b(0) + "," + print(expo, 0) + ")";
    }
    if (half) return "sqrt(" + b(0) + ")";
    const std::string s = b(kPower) + "^" + print(expo, kPower);
    return kPower <= level ? open() + s + close() : s;
  }

  Format f_;
  std::size_t placeholders_ = 0;
};

}  // namespace

std::string canonical_print(const ex& e, Format f) {
  Printer p(f);
  return p.print(e, 0);
}

}  // namespace ukdyn::symbolic
