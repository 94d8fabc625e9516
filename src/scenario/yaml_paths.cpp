#include "scenario/yaml_paths.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "scenario/yaml_loader.hpp"

namespace ukdyn::io_detail {

namespace {

struct PathStep {
  bool index = false;
  std::size_t i = 0;
  std::string key;  ///< a map key, or (with index = false in a list) the element's `name`
};

// `a.b[2].c[left]`: keys separated by dots, list elements by [number] or [name].
bool parse_path(const std::string& path, std::vector<PathStep>& steps) {
  std::size_t i = 0;
  while (i < path.size()) {
    if (path[i] == '[') {
      const auto close = path.find(']', i);
      if (close == std::string::npos || close == i + 1) return false;
      const std::string inner = path.substr(i + 1, close - i - 1);
      PathStep s;
      if (std::all_of(inner.begin(), inner.end(), [](char c) { return c >= '0' && c <= '9'; })) {
        if (inner.size() > 6) return false;
        s.index = true;
        s.i = std::stoul(inner);
      } else {
        s.key = "[" + inner;  // marks a list element chosen by name
      }
      steps.push_back(s);
      i = close + 1;
      if (i < path.size() && path[i] == '.') ++i;
      continue;
    }
    std::size_t end = i;
    while (end < path.size() && path[end] != '.' && path[end] != '[') ++end;
    if (end == i) return false;
    steps.push_back({false, 0, path.substr(i, end - i)});
    i = end;
    if (i < path.size() && path[i] == '.') {
      ++i;
      if (i == path.size()) return false;
    }
  }
  return !steps.empty();
}

}  // namespace

std::string yaml_expansion_problem(const YAML::Node& root, YAML::Mark& at) {
  struct Item {
    YAML::Node node;
    std::size_t depth;
  };
  std::vector<Item> stack{{root, 1}};
  std::size_t count = 0;
  while (!stack.empty()) {
    const Item it = stack.back();
    stack.pop_back();
    if (++count > kMaxYamlNodes || it.depth > kMaxYamlDepth) {
      at = it.node.Mark();
      return count > kMaxYamlNodes
                 ? fmt::format(
                       "the YAML expands to more than {} nodes with its aliases (*name) "
                       "written out (an alias bomb?)",
                       kMaxYamlNodes)
                 : fmt::format(
                       "the YAML is nested more than {} levels deep with its aliases "
                       "written out",
                       kMaxYamlDepth);
    }
    if (it.node.IsSequence()) {
      for (const auto& e : it.node) stack.push_back({e, it.depth + 1});
    } else if (it.node.IsMap()) {
      // A key twice in one mapping: YAML forbids it, and yaml-cpp would keep both (a lookup
      // finding the first), so a repeated bound, weight or coordinate would be silently lost.
      std::set<std::string> keys;
      for (const auto& kv : it.node) {
        if (kv.first.IsScalar() && !keys.insert(kv.first.Scalar()).second) {
          at = kv.first.Mark();
          const std::string& k = kv.first.Scalar();
          return "duplicate key '" + escape_controls(k.size() > 64 ? k.substr(0, 64) + "..." : k) +
                 "' in one mapping (YAML allows each key once)";
        }
        stack.push_back({kv.first, it.depth + 1});
        stack.push_back({kv.second, it.depth + 1});
      }
    }
  }
  return {};
}

// The base scenario as a YAML tree: copied node by node, so that an alias (`*table1`) becomes a
// copy of its own and a value written at one path changes that path only.

YAML::Node clone_yaml(const YAML::Node& n) {
  switch (n.Type()) {
    case YAML::NodeType::Scalar:
      return YAML::Node(n.Scalar());
    case YAML::NodeType::Sequence: {
      YAML::Node s(YAML::NodeType::Sequence);
      for (const auto& e : n) s.push_back(clone_yaml(e));
      return s;
    }
    case YAML::NodeType::Map: {
      YAML::Node m(YAML::NodeType::Map);
      for (const auto& kv : n) m[clone_yaml(kv.first)] = clone_yaml(kv.second);
      return m;
    }
    default:
      return YAML::Node(YAML::NodeType::Null);
  }
}

// The scalar node at `path` in doc (a handle into doc), or an error message.
std::optional<YAML::Node> find_scalar(YAML::Node doc, const std::string& path, std::string& why) {
  std::vector<PathStep> steps;
  if (!parse_path(path, steps)) {
    why = "not a path (keys separated by '.', list elements as [index] or [name])";
    return std::nullopt;
  }
  YAML::Node cur;
  cur.reset(doc);
  std::string at;
  for (const auto& s : steps) {
    if (s.index) {
      if (!cur.IsSequence() || s.i >= cur.size()) {
        why = fmt::format("'{}' has no element [{}]", at.empty() ? "(top)" : at, s.i);
        return std::nullopt;
      }
      YAML::Node next = cur[s.i];
      cur.reset(next);
      at += fmt::format("[{}]", s.i);
    } else if (!s.key.empty() && s.key[0] == '[') {
      const std::string nm = s.key.substr(1);
      bool found = false;
      if (cur.IsSequence()) {
        for (std::size_t k = 0; k < cur.size(); ++k) {
          const YAML::Node e = cur[k];
          if (e.IsMap() && e["name"] && e["name"].IsScalar() && e["name"].Scalar() == nm) {
            YAML::Node next = cur[k];
            cur.reset(next);
            found = true;
            break;
          }
        }
      }
      if (!found) {
        why = fmt::format("'{}' has no element named '{}'", at.empty() ? "(top)" : at, nm);
        return std::nullopt;
      }
      at += "[" + nm + "]";
    } else {
      const YAML::Node& ccur = cur;
      if (!cur.IsMap() || !ccur[s.key]) {
        why = fmt::format("'{}' has no key '{}'", at.empty() ? "(top)" : at, s.key);
        return std::nullopt;
      }
      YAML::Node next = cur[s.key];
      cur.reset(next);
      at += (at.empty() ? "" : ".") + s.key;
    }
  }
  if (!cur.IsScalar()) {
    why = "'" + at + "' is not a number in the scenario (a list or mapping)";
    return std::nullopt;
  }
  return cur;
}

std::optional<YAML::Node> find_number(YAML::Node doc, const std::string& path, std::string& why) {
  auto at = find_scalar(std::move(doc), path, why);
  double v = 0.0;
  if (at && !Loader::parse_number(at->Scalar(), v)) {
    why = "'" + path + "' holds '" + escape_controls(at->Scalar()) +
          "', not a number: a number put there would replace it (give the path of a number it "
          "uses, such as a parameter)";
    return std::nullopt;
  }
  return at;
}

bool parameter_name_ok(const std::string& name) {
  return !name.empty() && name.size() <= 200 && std::all_of(name.begin(), name.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_' ||
           c == '.' || c == '[' || c == ']' || c == '-';
  });
}

}  // namespace ukdyn::io_detail
