#include "ukdyn/symbolic/expression.hpp"

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <limits>
#include <set>
#include <sstream>
#include <unordered_map>
#include <vector>

namespace ukdyn::symbolic {

namespace {

using GiNaC::ex;

const std::set<std::string>& function_names() {
  static const std::set<std::string> f = {"sin", "cos", "tan",  "asin", "acos", "atan", "atan2",
                                          "exp", "log", "sqrt", "sinh", "cosh", "tanh", "abs"};
  return f;
}

// A character for a message: itself if printable ASCII, else \xNN.
std::string shown_char(char c) {
  const auto u = static_cast<unsigned char>(c);
  static const char* const hex = "0123456789abcdef";
  return u >= 0x20 && u < 0x7f ? std::string(1, c)
                               : std::string{'\\', 'x', hex[u >> 4], hex[u & 15]};
}

bool is_ident_start(char c) { return std::isalpha(static_cast<unsigned char>(c)) || c == '_'; }
bool is_ident_char(char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '_'; }

// Recursive-descent parser over the text, producing GiNaC expressions.
class Parser {
 public:
  Parser(const std::string& text, const std::map<std::string, ex>& names)
      : s_(text), names_(names) {}

  ex parse() {
    if (s_.size() > limits::kExpressionChars) {
      fail("the expression is longer than " + std::to_string(limits::kExpressionChars) +
               " characters",
           limits::kExpressionChars);
    }
    skip();
    if (pos_ >= s_.size()) fail("empty expression", 0);
    ex e;
    try {
      e = expression();
    } catch (const ExpressionError&) {
      throw;
    } catch (const std::exception& x) {  // GiNaC's evaluation errors: log(0), 0^-1, ...
      fail(std::string("cannot evaluate: ") + x.what(), last_start_);
    }
    skip();
    if (pos_ < s_.size()) fail("unexpected '" + shown_char(s_[pos_]) + "'", pos_);
    try {
      check_expression_size(e, "the expression");
    } catch (const ExpressionError& x) {
      fail(x.what(), 0);
    }
    return e;
  }

 private:
  [[noreturn]] void fail(const std::string& msg, std::size_t at) const {
    // Quote at most 80 characters of the text (it may be 10000 long), control bytes as \xNN.
    std::string shown;
    for (std::size_t i = 0; i < s_.size() && i < 80; ++i) {
      const auto u = static_cast<unsigned char>(s_[i]);
      static const char* const hex = "0123456789abcdef";
      shown += u >= 0x20 && u < 0x7f ? std::string(1, s_[i])
                                     : std::string{'\\', 'x', hex[u >> 4], hex[u & 15]};
    }
    if (s_.size() > 80) shown += "...";
    throw ExpressionError(msg + " at column " + std::to_string(at + 1) + " of '" + shown + "'", at);
  }
  // Counts the nesting (parentheses, calls, signs, powers all pass through unary()).
  struct Nest {
    explicit Nest(Parser& p) : p_(p) {
      if (++p_.depth_ > limits::kNesting) {
        p_.fail("nested more than " + std::to_string(limits::kNesting) +
                    " levels deep (parentheses, function calls, signs or powers)",
                p_.pos_);
      }
    }
    ~Nest() { --p_.depth_; }
    Nest(const Nest&) = delete;
    Nest& operator=(const Nest&) = delete;
    Parser& p_;
  };
  // base^expo, refusing exponents that would make a huge number or a huge expansion.
  ex checked_pow(const ex& base, const ex& expo, std::size_t at) {
    last_start_ = at;
    if (GiNaC::is_a<GiNaC::numeric>(expo)) {
      const GiNaC::numeric& n = GiNaC::ex_to<GiNaC::numeric>(expo);
      if (!n.is_real()) fail("the exponent must be real", at);
      const GiNaC::numeric mag = GiNaC::abs(n);
      if (GiNaC::is_a<GiNaC::numeric>(base)) {
        const GiNaC::numeric& b = GiNaC::ex_to<GiNaC::numeric>(base);
        if (b.is_zero() && n.is_negative()) fail("division by zero (0 to a negative power)", at);
        // GiNaC's pow(0, 0) throws from inside its own evaluation and leaks the half-built
        // power (found by fuzz_expression): refused here, before it is built.
        if (b.is_zero() && n.is_zero()) fail("0^0 is undefined", at);
        if (b.is_rational()) {
          // |b|^|n| has about |n|·(log2|numer| + log2|denom|) bits (0, 1 and -1 stay small).
          auto lg = [](const GiNaC::numeric& m) {
            const double d = GiNaC::abs(m).to_double();
            return std::isfinite(d) ? std::log2(d) : static_cast<double>(m.int_length());
          };
          const double bits = lg(b.numer()) + lg(b.denom());
          const bool small_base = GiNaC::abs(b) == 1 || b.is_zero();
          if (!small_base && (mag > limits::kNumberBits ||
                              mag.to_double() * bits > static_cast<double>(limits::kNumberBits))) {
            fail("the number is too large (more than " + std::to_string(limits::kNumberBits) +
                     " bits)",
                 at);
          }
        } else if (mag > limits::kExponent) {
          fail("exponent out of range (|exponent| <= " + std::to_string(limits::kExponent) + ")",
               at);
        }
      } else if (mag > limits::kExponent) {
        fail("exponent out of range (|exponent| <= " + std::to_string(limits::kExponent) + ")", at);
      }
    }
    return GiNaC::pow(base, expo);
  }
  void skip() {
    while (pos_ < s_.size() && std::isspace(static_cast<unsigned char>(s_[pos_]))) ++pos_;
  }
  bool accept(char c) {
    skip();
    if (pos_ < s_.size() && s_[pos_] == c) {
      ++pos_;
      return true;
    }
    return false;
  }
  void expect(char c, const char* what) {
    skip();
    if (pos_ >= s_.size())
      fail(std::string("expected ") + what + ", got the end of the expression", pos_);
    if (s_[pos_] != c)
      fail(std::string("expected ") + what + ", got '" + shown_char(s_[pos_]) + "'", pos_);
    ++pos_;
  }

  ex expression() {
    ex e = term();
    for (;;) {
      if (accept('+')) {
        e = e + term();
      } else if (accept('-')) {
        e = e - term();
      } else {
        return e;
      }
    }
  }
  ex term() {
    ex e = unary();
    for (;;) {
      skip();
      if (pos_ + 1 < s_.size() && s_[pos_] == '*' && s_[pos_ + 1] == '*')
        return e;  // handled in power
      if (accept('*')) {
        e = e * unary();
      } else if (accept('/')) {
        const std::size_t at = pos_;
        ex d = unary();
        if (d.is_zero()) fail("division by zero", at);
        last_start_ = at;
        e = e / d;
      } else {
        return e;
      }
    }
  }
  ex unary() {
    const Nest nest(*this);
    if (accept('-')) return -unary();
    if (accept('+')) return unary();
    return power();
  }
  ex power() {
    const std::size_t start = pos_;
    ex base = primary();
    skip();
    if (accept('^')) {
      const ex e = unary();
      return checked_pow(base, e, start);
    }
    if (pos_ + 1 < s_.size() && s_[pos_] == '*' && s_[pos_ + 1] == '*') {
      pos_ += 2;
      const ex e = unary();
      return checked_pow(base, e, start);
    }
    return base;
  }
  ex primary() {
    skip();
    if (pos_ >= s_.size())
      fail("expected a number, a name or '(', got the end of the expression", pos_);
    const char c = s_[pos_];
    if (c == '(') {
      ++pos_;
      ex e = expression();
      expect(')', "')'");
      return e;
    }
    if (std::isdigit(static_cast<unsigned char>(c)) || c == '.') return number();
    if (is_ident_start(c)) return identifier();
    fail("unexpected '" + shown_char(c) + "'", pos_);
  }
  ex number() {
    const std::size_t start = pos_;
    GiNaC::numeric mant = 0;
    long frac_digits = 0;
    bool digits = false, dot = false;
    std::size_t ndigits = 0;
    while (pos_ < s_.size()) {
      const char c = s_[pos_];
      if (std::isdigit(static_cast<unsigned char>(c))) {
        if (++ndigits > limits::kNumberDigits) {
          fail("a number of more than " + std::to_string(limits::kNumberDigits) + " digits", start);
        }
        mant = mant * 10 + (c - '0');
        if (dot) ++frac_digits;
        digits = true;
      } else if (c == '.' && !dot) {
        dot = true;
      } else {
        break;
      }
      ++pos_;
    }
    if (!digits) fail("malformed number", start);
    long expo = 0;
    if (pos_ < s_.size() && (s_[pos_] == 'e' || s_[pos_] == 'E')) {
      std::size_t p = pos_ + 1;
      int sign = 1;
      if (p < s_.size() && (s_[p] == '+' || s_[p] == '-')) {
        sign = s_[p] == '-' ? -1 : 1;
        ++p;
      }
      if (p >= s_.size() || !std::isdigit(static_cast<unsigned char>(s_[p]))) {
        fail("malformed exponent in number", pos_);
      }
      while (p < s_.size() && std::isdigit(static_cast<unsigned char>(s_[p]))) {
        expo = expo * 10 + (s_[p] - '0');
        if (expo > 400) fail("exponent out of range", pos_);
        ++p;
      }
      expo *= sign;
      pos_ = p;
    }
    if (pos_ < s_.size() && is_ident_start(s_[pos_])) {
      fail("a number directly followed by a name (write '2*x', not '2x')", pos_);
    }
    const long e10 = expo - frac_digits;
    GiNaC::numeric scale = GiNaC::pow(GiNaC::numeric(10), GiNaC::numeric(e10 < 0 ? -e10 : e10));
    return e10 < 0 ? ex(mant / scale) : ex(mant * scale);
  }
  ex identifier() {
    const std::size_t start = pos_;
    last_start_ = start;
    while (pos_ < s_.size() && is_ident_char(s_[pos_])) ++pos_;
    const std::string name = s_.substr(start, pos_ - start);
    skip();
    const bool call = pos_ < s_.size() && s_[pos_] == '(';
    if (call) {
      if (!function_names().count(name)) {
        if (names_.count(name)) fail("'" + name + "' is not a function", start);
        fail("unknown function '" + name + "'", start);
      }
      ++pos_;
      std::vector<ex> args;
      args.push_back(expression());
      while (accept(',')) args.push_back(expression());
      expect(')', "')' or ','");
      const std::size_t want = name == "atan2" ? 2 : 1;
      if (args.size() != want) {
        fail("function '" + name + "' takes " + std::to_string(want) + " argument(s), got " +
                 std::to_string(args.size()),
             start);
      }
      const ex& a = args[0];
      last_start_ = start;
      if (name == "sin") return GiNaC::sin(a);
      if (name == "cos") return GiNaC::cos(a);
      if (name == "tan") return GiNaC::tan(a);
      if (name == "asin") return GiNaC::asin(a);
      if (name == "acos") return GiNaC::acos(a);
      if (name == "atan") return GiNaC::atan(a);
      if (name == "atan2") return GiNaC::atan2(a, args[1]);
      if (name == "exp" || name == "sinh" || name == "cosh") {
        // CLN evaluates exp of a huge number to a wrong finite value; a double overflows past 709.
        const ex v = a.evalf();
        if (GiNaC::is_a<GiNaC::numeric>(v) && GiNaC::ex_to<GiNaC::numeric>(v).is_real() &&
            GiNaC::abs(GiNaC::ex_to<GiNaC::numeric>(v)) > 709) {
          fail("'" + name + "' of a number beyond 709 overflows a double", start);
        }
      }
      if (name == "exp") return GiNaC::exp(a);
      if (name == "log") return GiNaC::log(a);
      if (name == "sqrt") return GiNaC::sqrt(a);
      if (name == "sinh") return GiNaC::sinh(a);
      if (name == "cosh") return GiNaC::cosh(a);
      if (name == "tanh") return GiNaC::tanh(a);
      return GiNaC::abs(a);
    }
    if (name == "pi") return GiNaC::Pi;
    auto it = names_.find(name);
    if (it == names_.end()) {
      if (function_names().count(name)) fail("function '" + name + "' needs arguments", start);
      std::string known;
      int k = 0;
      for (const auto& kv : names_) {
        if (k++ == 12) {
          known += ", ...";
          break;
        }
        known += (known.empty() ? "" : ", ") + kv.first;
      }
      fail("unknown symbol '" + name + "' (known here: " + (known.empty() ? "none" : known) + ")",
           start);
    }
    return it->second;
  }

  const std::string& s_;
  const std::map<std::string, ex>& names_;
  std::size_t pos_ = 0;
  std::size_t depth_ = 0;
  std::size_t last_start_ = 0;  // where the last function call or power began (for GiNaC errors)
};

const std::set<std::string>& greek() {
  static const std::set<std::string> g = {
      "alpha",  "beta",  "gamma", "delta", "epsilon", "zeta",  "eta",   "theta", "iota", "kappa",
      "lambda", "mu",    "nu",    "xi",    "rho",     "sigma", "tau",   "phi",   "chi",  "psi",
      "omega",  "Gamma", "Delta", "Theta", "Lambda",  "Xi",    "Sigma", "Phi",   "Psi",  "Omega"};
  return g;
}

// Words a name may not be: they would print as something else in a generated file (GiNaC's
// constants, MATLAB's constants) or make it invalid (keywords of C and MATLAB, C's math functions
// that GiNaC's C output calls).
const std::set<std::string>& reserved_words() {
  static const std::set<std::string> r = {
      // GiNaC constants and printer names ("I", GiNaC's imaginary unit, stays allowed: a common
      // name
      // for an inertia, and a derivation's output never holds an imaginary number)
      "Pi", "E", "Euler", "Catalan", "M_PI",
      // C (C11) keywords and common macros
      "auto", "break", "case", "char", "const", "continue", "default", "do", "double", "else",
      "enum", "extern", "float", "for", "goto", "if", "inline", "int", "long", "register",
      "restrict", "return", "short", "signed", "sizeof", "static", "struct", "switch", "typedef",
      "union", "unsigned", "void", "volatile", "while", "bool", "true", "false", "NULL", "_Bool",
      "_Complex", "_Imaginary", "main",
      // C math functions GiNaC's C printer emits, or a user's C code needs
      "pow", "fabs", "floor", "ceil", "fmod", "hypot", "exp2", "log10", "log2",
      // MATLAB keywords and constants
      "classdef", "elseif", "end", "function", "global", "otherwise", "parfor", "persistent",
      "spmd", "try", "catch", "i", "j", "eps", "Inf", "inf", "NaN", "nan", "zeros", "ans"};
  return r;
}

}  // namespace

bool valid_name(const std::string& name, std::string* why) {
  auto no = [&](const std::string& w) {
    if (why) *why = w;
    return false;
  };
  if (name.empty()) return no("a name must not be empty");
  if (!is_ident_start(name[0])) return no("'" + name + "' must start with a letter or '_'");
  for (char c : name) {
    if (!is_ident_char(c)) {
      std::string shown;  // never print a control byte of the name raw
      for (char ch : name.substr(0, 40)) {
        const auto u = static_cast<unsigned char>(ch);
        static const char* const hex = "0123456789abcdef";
        shown += u >= 0x20 && u < 0x7f ? std::string(1, ch)
                                       : std::string{'\\', 'x', hex[u >> 4], hex[u & 15]};
      }
      return no("'" + shown + "' may hold only letters, digits and '_'");
    }
  }
  if (name.size() > 64) return no("'" + name.substr(0, 40) + "...' is longer than 64 characters");
  if (name == "t" || name == "pi") return no("'" + name + "' is reserved (time, the constant pi)");
  if (function_names().count(name)) return no("'" + name + "' is the name of a function");
  if (reserved_words().count(name)) {
    return no("'" + name +
              "' is reserved (a constant or keyword of GiNaC, C or MATLAB output; see "
              "docs/definitions.md, Limits)");
  }
  if (name.rfind("__", 0) == 0 ||
      (name[0] == '_' &&
       std::isupper(static_cast<unsigned char>(name.size() > 1 ? name[1] : 'a'))) ||
      name.rfind("ukdyn_", 0) == 0) {
    return no("'" + name +
              "' is reserved (names starting with __, _ and a capital letter, or "
              "ukdyn_)");
  }
  return true;
}

namespace {

// Memoised over the DAG (shared subexpressions are visited once): tree nodes and an upper bound on
// the number of terms of the expansion, both saturating.
struct SizeInfo {
  double nodes = 0;
  double terms = 0;
};

class Sizer {
 public:
  explicit Sizer(const std::string& what) : what_(what) {}
  SizeInfo visit(const ex& e) {
    const GiNaC::basic* key = &GiNaC::ex_to<GiNaC::basic>(e);
    if (auto it = memo_.find(key); it != memo_.end()) return it->second.second;
    SizeInfo r;
    if (GiNaC::is_a<GiNaC::numeric>(e)) {
      const GiNaC::numeric& n = GiNaC::ex_to<GiNaC::numeric>(e);
      if (n.is_rational() &&
          n.numer().int_length() + n.denom().int_length() > limits::kNumberBits) {
        throw ExpressionError(
            what_ + " holds a number of more than " + std::to_string(limits::kNumberBits) + " bits",
            0);
      }
      r = {1, 1};
    } else if (e.nops() == 0) {
      r = {1, 1};
    } else {
      r.nodes = 1;
      const bool sum = GiNaC::is_a<GiNaC::add>(e), product = GiNaC::is_a<GiNaC::mul>(e);
      r.terms = product ? 1 : 0;
      for (std::size_t k = 0; k < e.nops(); ++k) {
        const SizeInfo c = visit(e.op(k));
        r.nodes += c.nodes;
        if (sum) r.terms += c.terms;
        if (product) r.terms *= c.terms;
      }
      if (GiNaC::is_a<GiNaC::power>(e)) {
        const ex expo = e.op(1);
        const double b = visit(e.op(0)).terms;
        r.terms = 1;
        if (GiNaC::is_a<GiNaC::numeric>(expo) && GiNaC::ex_to<GiNaC::numeric>(expo).is_integer())
          r.terms = std::pow(b, std::abs(GiNaC::ex_to<GiNaC::numeric>(expo).to_double()));
      } else if (!sum && !product) {
        r.terms = 1;  // a function: its arguments expand on their own
      }
      if (!(r.nodes <= static_cast<double>(limits::kTreeNodes))) {
        throw ExpressionError(what_ + " is too large (more than " +
                                  std::to_string(limits::kTreeNodes) + " nodes written out)",
                              0);
      }
      if (!(r.terms <= limits::kExpandedTerms)) {
        std::ostringstream os;
        os << what_ << " would expand to more than " << limits::kExpandedTerms << " terms";
        throw ExpressionError(os.str(), 0);
      }
    }
    memo_.emplace(key, std::make_pair(e, r));  // keeps e alive: op() of a sum may be a temporary
    return r;
  }

 private:
  std::string what_;
  std::unordered_map<const GiNaC::basic*, std::pair<ex, SizeInfo>> memo_;
};

std::int64_t now_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

}  // namespace

void check_expression_size(const GiNaC::ex& e, const std::string& what) {
  Sizer sizer(what);
  (void)sizer.visit(e);
}

Deadline::Deadline(double seconds)
    : seconds_(seconds), end_ns_(now_ns() + static_cast<std::int64_t>(seconds * 1e9)) {}

void Deadline::check(const std::string& where) const {
  if (now_ns() > end_ns_) {
    std::ostringstream os;
    os << "the derivation took longer than " << seconds_ << " s (stopped at " << where
       << "): simplify the definitions or split the subsystem";
    throw DerivationTimeout(os.str());
  }
}

namespace {

// A sum built from expanded parts: kept as a list and combined (like terms added) once the parts
// added since the last combination hold about 10^4 terms and at least as many as the combined sum,
// with the deadline checked at each combination, so no one combination is large, a list of many
// small parts is not combined term by term, and a sum of N distinct terms costs O(N log N) in all
// (a threshold of 10^4 alone re-combined the whole sum at every part once it held more: 55 s for
// the 20100 terms of a sum of 200 sines' M(x, x), docs/definitions.md "Limits").
class CheckedSum {
 public:
  CheckedSum(const Deadline& deadline, const std::string& where)
      : deadline_(deadline), where_(where) {}
  void add(const ex& part) {
    pending_ += GiNaC::is_a<GiNaC::add>(part) ? part.nops() : 1;
    parts_.push_back(part);
    if (pending_ > std::max<std::size_t>(10000, folded_)) {
      deadline_.check(where_);
      const ex folded = sum();
      parts_.assign(1, folded);
      folded_ = GiNaC::is_a<GiNaC::add>(folded) ? folded.nops() : 1;
      pending_ = 0;
    }
  }
  [[nodiscard]] ex sum() const { return GiNaC::dynallocate<GiNaC::add>(parts_); }

 private:
  const Deadline& deadline_;
  const std::string& where_;
  GiNaC::exvector parts_;
  std::size_t folded_ = 0;   // terms of the combined sum parts_[0] (0: none yet)
  std::size_t pending_ = 0;  // terms of the parts added since
};

// A · B of two expanded expressions, expanded: a monomial times anything at once (linear in the
// other's size), a sum times a sum one term of the shorter at a time, the deadline checked between.
ex multiply_expanded(const ex& a, const ex& b, const Deadline& deadline, const std::string& where) {
  const bool sa = GiNaC::is_a<GiNaC::add>(a), sb = GiNaC::is_a<GiNaC::add>(b);
  if (!sa || !sb) return (a * b).expand();
  const bool a_shorter = a.nops() <= b.nops();
  const ex& few = a_shorter ? a : b;
  const ex& many = a_shorter ? b : a;
  CheckedSum acc(deadline, where);
  for (std::size_t k = 0; k < few.nops(); ++k) {
    deadline.check(where);
    acc.add((few.op(k) * many).expand());
  }
  return acc.sum();
}

// The Sizer's upper bound on the terms of e's expansion, or +inf once `budget` nodes have been
// visited (no memo: a shared subexpression counts at each use, so the budget bounds the work).
double expansion_bound(const ex& e, int& budget) {
  if (--budget < 0) return std::numeric_limits<double>::infinity();
  const bool sum = GiNaC::is_a<GiNaC::add>(e);
  if (sum || GiNaC::is_a<GiNaC::mul>(e)) {
    double r = sum ? 0.0 : 1.0;
    for (std::size_t k = 0; k < e.nops() && budget >= 0; ++k)
      r = sum ? r + expansion_bound(e.op(k), budget) : r * expansion_bound(e.op(k), budget);
    return budget < 0 ? std::numeric_limits<double>::infinity() : r;
  }
  if (GiNaC::is_a<GiNaC::power>(e) && GiNaC::is_a<GiNaC::numeric>(e.op(1)) &&
      GiNaC::ex_to<GiNaC::numeric>(e.op(1)).is_integer()) {
    return std::pow(expansion_bound(e.op(0), budget),
                    std::abs(GiNaC::ex_to<GiNaC::numeric>(e.op(1)).to_double()));
  }
  return 1.0;
}

}  // namespace

ex expand_checked(const ex& e, const Deadline& deadline, const std::string& where) {
  deadline.check(where);
  // Already expanded, or small (at most 5·10^4 terms by the bound, found within 2·10^4 nodes):
  // GiNaC's expand() at once, which is faster than going term by term (docs/definitions.md,
  // "Limits": the checked derivation of a small chain costs about 10 % more CPU than before).
  int budget = 20000;
  if (e.info(GiNaC::info_flags::expanded) || expansion_bound(e, budget) <= 5e4) return e.expand();
  if (GiNaC::is_a<GiNaC::add>(e)) {
    // A sum of expanded terms is expanded: add's evaluation combines the like terms.
    CheckedSum acc(deadline, where);
    for (std::size_t k = 0; k < e.nops(); ++k) acc.add(expand_checked(e.op(k), deadline, where));
    return acc.sum();
  }
  if (GiNaC::is_a<GiNaC::mul>(e)) {
    ex acc = 1;
    for (std::size_t k = 0; k < e.nops(); ++k)
      acc = multiply_expanded(acc, expand_checked(e.op(k), deadline, where), deadline, where);
    return acc;
  }
  if (GiNaC::is_a<GiNaC::power>(e) && GiNaC::is_a<GiNaC::numeric>(e.op(1))) {
    const GiNaC::numeric& n = GiNaC::ex_to<GiNaC::numeric>(e.op(1));
    const ex base = expand_checked(e.op(0), deadline, where);
    if (n.is_pos_integer() && GiNaC::is_a<GiNaC::add>(base)) {
      // (a + b + ...)^n as n − 1 checked products (n ≤ limits::kExponent).
      ex acc = base;
      for (long k = 1; k < n.to_long(); ++k) acc = multiply_expanded(acc, base, deadline, where);
      return acc;
    }
    return GiNaC::pow(base, e.op(1)).expand();
  }
  return e.expand();
}

std::string latex_name(const std::string& name) {
  std::string base = name;
  bool dot = false;
  if (base.size() > 4 && base.compare(base.size() - 4, 4, "_dot") == 0) {
    dot = true;
    base.resize(base.size() - 4);
  }
  std::string head = base, sub;
  if (auto u = base.find('_'); u != std::string::npos) {
    head = base.substr(0, u);
    sub = base.substr(u + 1);
  } else {
    std::size_t k = base.size();
    while (k > 0 && std::isdigit(static_cast<unsigned char>(base[k - 1]))) --k;
    if (k > 0 && k < base.size()) {
      head = base.substr(0, k);
      sub = base.substr(k);
    }
  }
  if (greek().count(head))
    head = "\\" + head;
  else if (head.size() > 1)
    head = "\\mathrm{" + head + "}";
  std::string out = dot ? "\\dot{" + head + "}" : head;
  if (!sub.empty()) {
    std::string s;
    for (char c : sub) s += c == '_' ? ',' : c;
    out += "_{" + s + "}";
  }
  return out;
}

GiNaC::symbol SymbolTable::interned(const std::string& key, const std::string& print,
                                    const std::string& tex) {
  auto it = symbols_.find(key);
  if (it == symbols_.end()) it = symbols_.emplace(key, GiNaC::symbol(print, tex)).first;
  return it->second;
}

GiNaC::symbol SymbolTable::coordinate(const std::string& name) {
  return interned("q:" + name, name, latex_name(name));
}

GiNaC::symbol SymbolTable::velocity(const std::string& name) {
  return interned("qd:" + name, name + "_dot", latex_name(name + "_dot"));
}

GiNaC::symbol SymbolTable::time() { return interned("t", "t", "t"); }

GiNaC::symbol coordinate_symbol(SymbolTable& table, const std::string& name) {
  return table.coordinate(name);
}

GiNaC::symbol velocity_symbol(SymbolTable& table, const std::string& name) {
  return table.velocity(name);
}

GiNaC::symbol time_symbol(SymbolTable& table) { return table.time(); }

GiNaC::symbol local_symbol(const std::string& name) {
  return GiNaC::symbol(name, latex_name(name));
}

void Scope::add(const std::string& name, const GiNaC::ex& value) {
  std::string why;
  if (!valid_name(name, &why)) throw ExpressionError(why, 0);
  if (names_.count(name)) throw ExpressionError("the name '" + name + "' is defined twice", 0);
  names_.emplace(name, value);
}

void Scope::add_time(const GiNaC::symbol& t) {
  // The time symbol of a table, under the name t that no parameter or let-name may take.
  if (names_.count("t")) throw ExpressionError("the name 't' is defined twice", 0);
  names_.emplace("t", t);
}

GiNaC::ex Scope::parse(const std::string& text) const { return Parser(text, names_).parse(); }

}  // namespace ukdyn::symbolic
