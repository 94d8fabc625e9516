#include "ukdyn/symbolic/expression.hpp"

#include <cctype>
#include <mutex>
#include <set>
#include <vector>

namespace ukdyn::symbolic {

namespace {

using GiNaC::ex;

const std::set<std::string>& function_names() {
  static const std::set<std::string> f = {"sin", "cos", "tan",  "asin", "acos", "atan", "atan2",
                                          "exp", "log", "sqrt", "sinh", "cosh", "tanh", "abs"};
  return f;
}

std::mutex& registry_mutex() {
  static std::mutex m;
  return m;
}

std::map<std::string, GiNaC::symbol>& registry() {
  static std::map<std::string, GiNaC::symbol> r;
  return r;
}

GiNaC::symbol registered(const std::string& key, const std::string& print, const std::string& tex) {
  std::lock_guard<std::mutex> lock(registry_mutex());
  auto& r = registry();
  auto it = r.find(key);
  if (it == r.end()) it = r.emplace(key, GiNaC::symbol(print, tex)).first;
  return it->second;
}

bool is_ident_start(char c) { return std::isalpha(static_cast<unsigned char>(c)) || c == '_'; }
bool is_ident_char(char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '_'; }

// Recursive-descent parser over the text, producing GiNaC expressions.
class Parser {
 public:
  Parser(const std::string& text, const std::map<std::string, ex>& names)
      : s_(text), names_(names) {}

  ex parse() {
    skip();
    if (pos_ >= s_.size()) fail("empty expression", 0);
    ex e = expression();
    skip();
    if (pos_ < s_.size()) fail(std::string("unexpected '") + s_[pos_] + "'", pos_);
    return e;
  }

 private:
  [[noreturn]] void fail(const std::string& msg, std::size_t at) const {
    throw ExpressionError(msg + " at column " + std::to_string(at + 1) + " of '" + s_ + "'", at);
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
    if (s_[pos_] != c) fail(std::string("expected ") + what + ", got '" + s_[pos_] + "'", pos_);
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
        e = e / d;
      } else {
        return e;
      }
    }
  }
  ex unary() {
    if (accept('-')) return -unary();
    if (accept('+')) return unary();
    return power();
  }
  ex power() {
    ex base = primary();
    skip();
    if (accept('^')) return GiNaC::pow(base, unary());
    if (pos_ + 1 < s_.size() && s_[pos_] == '*' && s_[pos_ + 1] == '*') {
      pos_ += 2;
      return GiNaC::pow(base, unary());
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
    fail(std::string("unexpected '") + c + "'", pos_);
  }
  ex number() {
    const std::size_t start = pos_;
    GiNaC::numeric mant = 0;
    long frac_digits = 0;
    bool digits = false, dot = false;
    while (pos_ < s_.size()) {
      const char c = s_[pos_];
      if (std::isdigit(static_cast<unsigned char>(c))) {
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
      if (name == "sin") return GiNaC::sin(a);
      if (name == "cos") return GiNaC::cos(a);
      if (name == "tan") return GiNaC::tan(a);
      if (name == "asin") return GiNaC::asin(a);
      if (name == "acos") return GiNaC::acos(a);
      if (name == "atan") return GiNaC::atan(a);
      if (name == "atan2") return GiNaC::atan2(a, args[1]);
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
};

const std::set<std::string>& greek() {
  static const std::set<std::string> g = {
      "alpha",  "beta",  "gamma", "delta", "epsilon", "zeta",  "eta",   "theta", "iota", "kappa",
      "lambda", "mu",    "nu",    "xi",    "rho",     "sigma", "tau",   "phi",   "chi",  "psi",
      "omega",  "Gamma", "Delta", "Theta", "Lambda",  "Xi",    "Sigma", "Phi",   "Psi",  "Omega"};
  return g;
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
    if (!is_ident_char(c)) return no("'" + name + "' may hold only letters, digits and '_'");
  }
  if (name == "t" || name == "pi") return no("'" + name + "' is reserved (time, the constant pi)");
  if (function_names().count(name)) return no("'" + name + "' is the name of a function");
  return true;
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

GiNaC::symbol coordinate_symbol(const std::string& name) {
  return registered("q:" + name, name, latex_name(name));
}

GiNaC::symbol velocity_symbol(const std::string& name) {
  return registered("qd:" + name, name + "_dot", latex_name(name + "_dot"));
}

GiNaC::symbol time_symbol() { return registered("t", "t", "t"); }

GiNaC::symbol local_symbol(const std::string& name) {
  return GiNaC::symbol(name, latex_name(name));
}

void Scope::add(const std::string& name, const GiNaC::ex& value) {
  std::string why;
  const bool is_time = name == "t" && value.is_equal(time_symbol());
  if (!is_time && !valid_name(name, &why)) throw ExpressionError(why, 0);
  if (names_.count(name)) throw ExpressionError("the name '" + name + "' is defined twice", 0);
  names_.emplace(name, value);
}

GiNaC::ex Scope::parse(const std::string& text) const { return Parser(text, names_).parse(); }

}  // namespace ukdyn::symbolic
