// Internal to ukdyn::io: YAML access that names file:line:column and the key path in every error.
// Used by the scenario loader and by the loaders of definition-based subsystems and constraints.
#pragma once

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <filesystem>
#include <initializer_list>
#include <limits>
#include <locale>
#include <memory>
#include <numbers>
#include <set>
#include <sstream>
#include <string>

#include "ukdyn/core/types.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/text/safe_text.hpp"

namespace ukdyn::symbolic {
class SymbolTable;
}

namespace ukdyn::io_detail {

// A YAML node with the dotted key path that led to it, for messages.
struct Node {
  YAML::Node node;
  std::string key;
};

class Loader {
 public:
  /// `symbols`: the symbol table of the system the file defines (docs/architecture.md, "Symbols"):
  /// every definition the loaders make for it shares this table.
  explicit Loader(std::filesystem::path path,
                  std::shared_ptr<symbolic::SymbolTable> symbols = nullptr)
      : path_(std::move(path)), symbols_(std::move(symbols)) {}

  [[noreturn]] void fail(const Node& at, const std::string& message) const {
    std::ostringstream os;
    os << path_.string();
    const YAML::Mark mark = at.node.IsDefined() ? at.node.Mark() : YAML::Mark::null_mark();
    if (mark.line >= 0) os << ":" << (mark.line + 1) << ":" << (mark.column + 1);
    os << ": key '" << at.key << "': " << message;
    // Every control byte (and DEL) shown as \xNN: a key or a name quoted in a message never
    // reaches the terminal raw (ukdyn/text/safe_text.hpp).
    throw ScenarioError(escape_controls(os.str()));
  }

  Node child(const Node& parent, const std::string& key, bool required) const {
    if (!parent.node.IsMap()) fail(parent, "expected a mapping");
    YAML::Node c = parent.node[key];
    const std::string full = parent.key.empty() ? key : parent.key + "." + key;
    if (!c.IsDefined() || c.IsNull()) {
      if (required) fail(parent, "missing required key '" + full + "'");
      // `key:` with nothing after it (or `~`, `null`) is a value left out, most often by mistake:
      // refused rather than read as the default the key would have had without it.
      // The key's own position: a null value's mark is where the next token starts.
      if (c.IsDefined()) {
        for (const auto& kv : parent.node)
          if (kv.first.IsScalar() && kv.first.Scalar() == key)
            fail(Node{kv.first, full},
                 "no value (give one, or remove the key to take its default)");
        fail(Node{c, full}, "no value (give one, or remove the key to take its default)");
      }
      return Node{YAML::Node(YAML::NodeType::Undefined), full};
    }
    return Node{c, full};
  }

  // Unknown keys are errors: a mistyped key must not be silently ignored.
  void only_keys(const Node& n, std::initializer_list<const char*> allowed) const {
    if (!n.node.IsMap()) fail(n, "expected a mapping");
    std::set<std::string> ok(allowed.begin(), allowed.end()), seen;
    for (const auto& kv : n.node) {
      if (!kv.first.IsScalar()) fail(Node{kv.first, n.key}, "a key must be a plain string");
      const std::string k = kv.first.Scalar();
      if (!seen.insert(k).second)
        fail(Node{kv.first, n.key.empty() ? k : n.key + "." + k}, "duplicate key '" + k + "'");
      if (!ok.count(k)) {
        std::string list;
        for (const auto& a : ok) list += (list.empty() ? "" : ", ") + a;
        fail(Node{kv.first, n.key.empty() ? k : n.key + "." + k},
             "unknown key (allowed here: " + list + ")");
      }
    }
  }

  // A number, or an expression of pi: "pi", "-pi/3", "2*pi", "pi/2", "0.5*pi".
  double number(const Node& n) const {
    if (!n.node.IsScalar()) fail(n, "expected a number");
    const std::string s = n.node.Scalar();
    double v = 0.0;
    if (!parse_number(s, v)) fail(n, "expected a number (or a multiple of pi), got '" + s + "'");
    if (!std::isfinite(v)) fail(n, "must be finite, got '" + s + "'");
    return v;
  }

  double number_or(const Node& parent, const std::string& key, double fallback) const {
    Node c = child(parent, key, false);
    return c.node.IsDefined() ? number(c) : fallback;
  }

  double positive(const Node& n) const {
    const double v = number(n);
    if (!(v > 0.0)) fail(n, "must be > 0, got " + n.node.Scalar());
    return v;
  }

  std::string string(const Node& n) const {
    if (!n.node.IsScalar()) fail(n, "expected a string");
    return n.node.Scalar();
  }

  // A name that becomes a CSV column and part of a file name (figures): 1 to 64 characters from
  // A-Z a-z 0-9 _ . -, not starting with '.' or '-', so never a path, '..', an option or a control.
  std::string name(const Node& n) const {
    const std::string s = string(n);
    bool ok = !s.empty() && s.size() <= 64 && s[0] != '.' && s[0] != '-';
    std::string shown;  // the first 40 characters, non-printable bytes as \xNN
    for (std::size_t i = 0; i < s.size(); ++i) {
      const char ch = s[i];
      const auto u = static_cast<unsigned char>(ch);
      ok = ok && ((ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') ||
                  (ch >= '0' && ch <= '9') || ch == '_' || ch == '.' || ch == '-');
      if (i < 40) {
        static const char* const hex = "0123456789abcdef";
        shown += u >= 0x20 && u < 0x7f ? std::string(1, ch)
                                       : std::string{'\\', 'x', hex[u >> 4], hex[u & 15]};
      }
    }
    if (!ok) {
      fail(n,
           "a name must be 1 to 64 characters from A-Z a-z 0-9 _ . - and not start with '.' or "
           "'-', got '" +
               shown + (s.size() > 40 ? "...'" : "'"));
    }
    return s;
  }

  // The key of a mapping entry as text (yaml-cpp's as<std::string>() throws without a place).
  std::string key(const Node& parent, const YAML::Node& k) const {
    if (!k.IsScalar()) fail(Node{k, parent.key}, "a key must be a plain string");
    return k.Scalar();
  }

  // A label that only appears in messages (a body, joint or link name): 1 to 64 printable
  // characters, so never a control byte on the user's terminal.
  std::string label(const Node& n) const {
    const std::string s = string(n);
    bool ok = !s.empty() && s.size() <= 64;
    for (char ch : s) ok = ok && static_cast<unsigned char>(ch) >= 0x20 && ch != 0x7f;
    if (!ok) fail(n, "a name here must be 1 to 64 printable characters (no control characters)");
    return s;
  }

  Vec vector(const Node& n, Index expected) const {
    if (!n.node.IsSequence())
      fail(n, "expected a list of " + std::to_string(expected) + " numbers");
    if (static_cast<Index>(n.node.size()) != expected) {
      fail(n, "expected " + std::to_string(expected) + " numbers, got " +
                  std::to_string(n.node.size()));
    }
    Vec v(expected);
    for (Index i = 0; i < expected; ++i) {
      v(i) =
          number(Node{n.node[static_cast<std::size_t>(i)], n.key + "[" + std::to_string(i) + "]"});
    }
    return v;
  }

  static bool parse_number(std::string s, double& out) {
    std::string t;
    for (char ch : s) {
      if (ch != ' ') t += ch;
    }
    if (t.empty()) return false;
    // Plain number.
    {
      std::istringstream is(t);
      is.imbue(std::locale::classic());
      double v = 0.0;
      if ((is >> v) && is.eof()) {
        out = v;
        return true;
      }
      if (t == ".nan" || t == ".NaN" || t == ".NAN" || t == "nan") {
        out = std::numeric_limits<double>::quiet_NaN();
        return true;
      }
      if (t == ".inf" || t == ".Inf" || t == ".INF" || t == "inf" || t == "-.inf" || t == "-.Inf" ||
          t == "-.INF" || t == "-inf") {
        out = t[0] == '-' ? -std::numeric_limits<double>::infinity()
                          : std::numeric_limits<double>::infinity();
        return true;
      }
    }
    // [sign][factor*]pi[/divisor]
    double sign = 1.0;
    std::size_t i = 0;
    if (t[0] == '-' || t[0] == '+') {
      sign = t[0] == '-' ? -1.0 : 1.0;
      i = 1;
    }
    const std::size_t p = t.find("pi", i);
    if (p == std::string::npos) return false;
    double factor = 1.0;
    if (p > i) {
      const std::string f = t.substr(i, p - i);
      if (f.back() != '*') return false;
      std::istringstream is(f.substr(0, f.size() - 1));
      is.imbue(std::locale::classic());
      if (!(is >> factor) || !is.eof()) return false;
    }
    double divisor = 1.0;
    const std::string rest = t.substr(p + 2);
    if (!rest.empty()) {
      if (rest[0] != '/') return false;
      std::istringstream is(rest.substr(1));
      is.imbue(std::locale::classic());
      if (!(is >> divisor) || !is.eof() || divisor == 0.0) return false;
    }
    out = sign * factor * std::numbers::pi / divisor;
    return true;
  }

  const std::filesystem::path& path() const { return path_; }
  /// The table (shared with the definitions), and a reference to it (the loader must have one).
  const std::shared_ptr<symbolic::SymbolTable>& symbol_table() const { return symbols_; }
  symbolic::SymbolTable& symbols() const { return *symbols_; }

 private:
  std::filesystem::path path_;
  std::shared_ptr<symbolic::SymbolTable> symbols_;
};

/// load_scenario_text() of an already parsed document (the sweep parses its base scenario once,
/// src/sweep/sample.cpp). `hash` becomes Scenario::hash; path is used in messages only. The document is
/// only read (yaml-cpp's const access), so it must not be shared with a thread that writes it.
Scenario load_scenario_yaml(const YAML::Node& root, const std::string& hash,
                            const std::filesystem::path& path, const LoadOptions& options = {});

/// The YAML document of a scenario's text, or a ScenarioError at the line and column (as
/// load_scenario_text()), and the hash that load_scenario_text() gives Scenario::hash.
YAML::Node parse_scenario_yaml(const std::string& text, const std::filesystem::path& path);
std::string scenario_text_hash(const std::string& text);

}  // namespace ukdyn::io_detail
