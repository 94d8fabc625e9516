#include "ukdyn/sweep/sweep.hpp"

#include <fcntl.h>
#include <fmt/format.h>
#include <sys/stat.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <numbers>
#include <optional>
#include <ostream>
#include <set>
#include <sstream>
#include <thread>

#include "ukdyn/output/control_output.hpp"
#include "ukdyn/output/plots.hpp"
#include "ukdyn/run/run.hpp"
#include "run/run_observer.hpp"
#include "ukdyn/output/safe_text.hpp"
#include "ukdyn/scenario/scenario_file.hpp"
#include "scenario/yaml_loader.hpp"
#include "scenario/yaml_paths.hpp"

namespace ukdyn {

using io_detail::Loader;
using io_detail::Node;

// ---------------------------------------------------------------------------------------------
// Counter-based random streams. Every draw is a hash of (seed, sample, parameter, draw): no state
// is carried from one sample to the next, so any subset of samples can be computed anywhere.

std::uint64_t splitmix64(std::uint64_t x) {
  // SplitMix64's output function ([Steele2014], the constants of its reference implementation).
  x += 0x9e3779b97f4a7c15ull;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}

double sweep_uniform(std::uint64_t seed, long sample, int parameter, int draw) {
  std::uint64_t h = splitmix64(seed);
  h = splitmix64(h ^ static_cast<std::uint64_t>(sample));
  h = splitmix64(h ^
                 (static_cast<std::uint64_t>(parameter) << 32 | static_cast<std::uint32_t>(draw)));
  return static_cast<double>(h >> 11) * 0x1p-53;  // 53 bits: exactly representable, in [0, 1)
}

double sweep_normal(std::uint64_t seed, long sample, int parameter) {
  // Box–Muller ([Box1958]); u1 in (0, 1] so that the logarithm is finite.
  const double u1 = 1.0 - sweep_uniform(seed, sample, parameter, 0);
  const double u2 = sweep_uniform(seed, sample, parameter, 1);
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * std::numbers::pi * u2);
}

namespace {

// Φ, the standard normal distribution function.
double normal_cdf(double x) { return 0.5 * std::erfc(-x / std::numbers::sqrt2); }

// A normal(mean, sd) deviate restricted to [low, high] by the inverse distribution function: u is
// mapped onto [Φ(a), Φ(b)] and Φ⁻¹ found by bisection (deterministic: only erfc and halving).
double truncated_normal(double u, double mean, double sd, double low, double high) {
  double a = std::max((low - mean) / sd, -40.0), b = std::min((high - mean) / sd, 40.0);
  const bool flip = a > 0.0;  // the upper tail: work on the mirrored lower one (more precision)
  if (flip) {
    const double t = a;
    a = -b;
    b = -t;
  }
  const double pa = normal_cdf(a), pb = normal_cdf(b);
  const double p = pa + u * (pb - pa);
  double lo = a, hi = b;
  for (int i = 0; i < 200 && lo < hi; ++i) {
    const double mid = 0.5 * (lo + hi);
    if (mid <= lo || mid >= hi) break;
    (normal_cdf(mid) < p ? lo : hi) = mid;
  }
  const double z = flip ? -0.5 * (lo + hi) : 0.5 * (lo + hi);
  return std::clamp(mean + sd * z, low, high);
}

std::string hash_hex(const std::string& bytes) {
  std::uint64_t h = 1469598103934665603ull;
  for (unsigned char ch : bytes) {
    h ^= ch;
    h *= 1099511628211ull;
  }
  return fmt::format("{:016x}", h);
}

// Shortest text that reads back as the same double (fmt's default for doubles).
std::string num(double v) { return fmt::format("{}", v); }

std::string read_text(const std::filesystem::path& p, const std::string& what) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(p, ec)) {
    throw ScenarioError(printable(p.string()) + ": no such " + what + " (or not a regular file)");
  }
  if (std::filesystem::file_size(p, ec) > (std::size_t{4} << 20)) {
    throw ScenarioError(printable(p.string()) + ": larger than 4 MiB");
  }
  std::ifstream in(p, std::ios::binary);
  std::ostringstream os;
  os << in.rdbuf();
  return os.str();
}

// The base scenario's tree is copied with io_detail::clone_yaml and written at a path with
// io_detail::find_scalar (io/yaml_paths.hpp, shared with control.plant_set).
using io_detail::find_scalar;
YAML::Node clone(const YAML::Node& n) { return io_detail::clone_yaml(n); }

const YAML::Node& base_yaml(const Sweep& sw) {
  return *static_cast<const YAML::Node*>(sw.base_doc.get());
}

// A path `plant.P` (docs/sweeps.md, "Control scenarios") writes P in the plant of a control
// scenario: as an entry {path: P, value: v} appended to the sample's control.plant_set
// (io/control_loader.cpp), so the controller's model keeps its value.
constexpr const char* kPlantPrefix = "plant.";
bool plant_path(const std::string& path) { return path.rfind(kPlantPrefix, 0) == 0; }

// The plant's tree of a control scenario, as control.plant_set sees it: the plant file, or the
// scenario's own tree less its control and actuators sections.
YAML::Node plant_tree(const YAML::Node& doc, const std::filesystem::path& base_path) {
  const YAML::Node pf = doc["control"]["plant"];
  if (pf && pf.IsScalar()) {
    const auto where = base_path.parent_path() / pf.Scalar();
    return clone(YAML::Load(read_text(where, "plant scenario")));
  }
  YAML::Node t = clone(doc);
  t.remove("control");
  t.remove("actuators");
  return t;
}

// `initial.q[i]` / `initial.qd[i]`: the coordinate i of q0 / q̇0, or -1.
long state_index(const std::string& path, bool& velocity) {
  for (const char* pre : {"initial.q[", "initial.qd["}) {
    const std::string p = pre;
    if (path.rfind(p, 0) == 0 && path.back() == ']') {
      const std::string inner = path.substr(p.size(), path.size() - p.size() - 1);
      if (inner.empty() || inner.size() > 6 ||
          !std::all_of(inner.begin(), inner.end(), [](char c) { return c >= '0' && c <= '9'; }))
        return -1;
      velocity = p == "initial.qd[";
      return std::stol(inner);
    }
  }
  return -1;
}

// Whether the base scenario's system is independent of initial.q (no constraint built from the
// initial state: `origin: initial`, `value: initial` or their defaults), so that samples that
// differ only in (q0, q̇0) can share one compiled model.
bool system_independent_of_state(const YAML::Node& doc) {
  const YAML::Node cons = doc["constraints"];
  if (!cons || cons.IsNull()) return true;
  if (!cons.IsSequence()) return false;
  for (const auto& c : cons) {
    if (!c.IsMap() || !c["type"] || !c["type"].IsScalar()) return false;
    const std::string type = c["type"].Scalar();
    if (type == "closure" || type == "expression" || type == "nonholonomic") continue;
    const char* key = type == "coordinate"             ? "value"
                      : type == "cut_point_trajectory" ? "origin"
                                                       : nullptr;
    if (!key) return false;  // the other kinds may take a point's initial position
    const YAML::Node v = c[key];
    if (!v || v.IsNull() || (v.IsScalar() && v.Scalar() == "initial")) return false;
  }
  return true;
}

// ---------------------------------------------------------------------------------------------
// The sweep file.

std::vector<double> load_values(const Loader& L, const Node& p) {
  std::vector<double> vals;
  const Node v = L.child(p, "values", false);
  const Node r = L.child(p, "range", false);
  if (v.node.IsDefined() == r.node.IsDefined()) L.fail(p, "give either values or range");
  if (v.node.IsDefined()) {
    if (!v.node.IsSequence() || v.node.size() == 0 || v.node.size() > 1'000'000)
      L.fail(v, "expected a non-empty list of numbers");
    for (std::size_t i = 0; i < v.node.size(); ++i)
      vals.push_back(L.number(Node{v.node[i], v.key + "[" + std::to_string(i) + "]"}));
    return vals;
  }
  L.only_keys(r, {"from", "to", "count"});
  const double a = L.number(L.child(r, "from", true)), b = L.number(L.child(r, "to", true));
  const Node cn = L.child(r, "count", true);
  const double c = L.number(cn);
  if (!(c >= 1 && c <= 1e6 && c == std::floor(c))) L.fail(cn, "expected an integer in [1, 1e6]");
  const auto count = static_cast<long>(c);
  for (long i = 0; i < count; ++i) {
    // (a (count − 1 − i) + b i) / (count − 1): both ends exact, 0.2..1 by 5 gives 0.6, not
    // 0.6000000000000001 as a + i (b − a) / (count − 1) would.
    const double di = static_cast<double>(i), dn = static_cast<double>(count - 1);
    vals.push_back(count == 1 ? a : i == count - 1 ? b : (a * (dn - di) + b * di) / dn);
  }
  return vals;
}

SweepDistribution load_distribution(const Loader& L, const Node& d) {
  SweepDistribution dist;
  L.only_keys(d, {"type", "low", "high", "mean", "sd"});
  const Node tn = L.child(d, "type", true);
  const std::string type = L.string(tn);
  if (type == "uniform") {
    dist.kind = SweepDistribution::Kind::uniform;
    dist.low = L.number(L.child(d, "low", true));
    dist.high = L.number(L.child(d, "high", true));
    if (!(dist.high > dist.low)) L.fail(L.child(d, "high", true), "must be greater than low");
  } else if (type == "normal" || type == "truncated_normal") {
    dist.kind = type == "normal" ? SweepDistribution::Kind::normal
                                 : SweepDistribution::Kind::truncated_normal;
    dist.mean = L.number(L.child(d, "mean", true));
    dist.sd = L.positive(L.child(d, "sd", true));
    if (dist.kind == SweepDistribution::Kind::truncated_normal) {
      dist.low = L.number_or(d, "low", -std::numeric_limits<double>::infinity());
      dist.high = L.number_or(d, "high", std::numeric_limits<double>::infinity());
      if (!(dist.high > dist.low)) L.fail(d, "high must be greater than low");
      const double mass = normal_cdf((dist.high - dist.mean) / dist.sd) -
                          normal_cdf((dist.low - dist.mean) / dist.sd);
      if (!(mass > 1e-12)) L.fail(d, "[low, high] holds almost none of the distribution");
    } else if (L.child(d, "low", false).node.IsDefined() ||
               L.child(d, "high", false).node.IsDefined()) {
      L.fail(d, "low / high bound a truncated_normal, not a normal");
    }
  } else {
    L.fail(tn, "unknown distribution '" + type + "' (expected uniform, normal, truncated_normal)");
  }
  return dist;
}

// `plant.P`: P must lead to a number in the plant's tree (null: the base has no control section).
void check_path(const Loader& L, const Node& e, const std::string& path, const YAML::Node& doc,
                const YAML::Node* plant) {
  std::string why;
  if (plant_path(path)) {
    if (!plant)
      L.fail(e, "'" + path + "': a 'plant.' path needs a base scenario with a control: section");
    YAML::Node copy = clone(*plant);
    const std::string rest = path.substr(std::strlen(kPlantPrefix));
    if (!find_scalar(copy, rest, why)) L.fail(e, "'" + path + "': in the plant: " + why);
    return;
  }
  YAML::Node copy = clone(doc);
  if (!find_scalar(copy, path, why)) L.fail(e, "'" + path + "': " + why);
}

std::vector<SweepTarget> load_targets(const Loader& L, const Node& p, const YAML::Node& doc,
                                      const YAML::Node* plant) {
  std::vector<SweepTarget> out;
  const Node pn = L.child(p, "path", true);
  auto one = [&](const Node& e) {
    SweepTarget t;
    if (e.node.IsMap()) {
      L.only_keys(e, {"path", "scale", "offset"});
      t.path = L.string(L.child(e, "path", true));
      t.scale = L.number_or(e, "scale", 1.0);
      t.offset = L.number_or(e, "offset", 0.0);
    } else {
      t.path = L.string(e);
    }
    check_path(L, e, t.path, doc, plant);
    out.push_back(t);
  };
  if (pn.node.IsSequence()) {
    if (pn.node.size() == 0) L.fail(pn, "expected a path or a list of paths");
    for (std::size_t i = 0; i < pn.node.size(); ++i)
      one(Node{pn.node[i], pn.key + "[" + std::to_string(i) + "]"});
  } else {
    one(pn);
  }
  return out;
}

void load_metrics(const Loader& L, const Node& m, SweepMetrics& mx) {
  if (!m.node.IsSequence()) L.fail(m, "expected a list of metrics");
  mx.max_residual = false;
  std::set<std::string> seen;
  for (std::size_t i = 0; i < m.node.size(); ++i) {
    const Node e{m.node[i], m.key + "[" + std::to_string(i) + "]"};
    if (e.node.IsScalar()) {
      const std::string s = e.node.Scalar();
      if (!seen.insert(s).second) L.fail(e, "duplicate metric '" + s + "'");
      if (s == "max_residual") {
        mx.max_residual = true;
      } else if (s == "energy_drift") {
        mx.energy_drift = true;
      } else if (s == "energy_balance_drift") {
        mx.energy_balance_drift = true;
      } else if (s == "max_abs_Qc") {
        mx.max_abs_qc = true;
      } else if (s == "final_state") {
        mx.final_state = true;
      } else if (s == "control") {
        mx.control = true;
      } else if (s == "squeeze_force") {
        mx.squeeze = true;
      } else {
        L.fail(e, "unknown metric '" + s +
                      "' (expected max_residual, energy_drift, energy_balance_drift, "
                      "max_abs_Qc, final_state, control, squeeze_force or {column: NAME, stats: "
                      "[min, max, rms, "
                      "max_abs, final]})");
      }
      continue;
    }
    L.only_keys(e, {"column", "stats"});
    ColumnMetric c;
    c.column = L.string(L.child(e, "column", true));
    const Node st = L.child(e, "stats", false);
    if (st.node.IsDefined()) {
      if (!st.node.IsSequence() || st.node.size() == 0) L.fail(st, "expected a list of stats");
      for (std::size_t k = 0; k < st.node.size(); ++k) {
        const Node s{st.node[k], st.key + "[" + std::to_string(k) + "]"};
        const std::string v = L.string(s);
        if (v != "min" && v != "max" && v != "rms" && v != "max_abs" && v != "final")
          L.fail(s, "unknown statistic '" + v + "' (expected min, max, rms, max_abs, final)");
        c.stats.push_back(v);
      }
    } else {
      c.stats = {"min", "max", "rms"};
    }
    mx.columns.push_back(c);
  }
}

// The sweep file's YAML tree (a syntax error names its line and column).
YAML::Node parse_sweep_yaml(const std::string& text, const std::filesystem::path& path) {
  YAML::Node root_node;
  try {
    root_node = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw ScenarioError(fmt::format("{}:{}:{}: YAML syntax error: {}", printable(path.string()),
                                    e.mark.line + 1, e.mark.column + 1, printable(e.msg)));
  }
  return root_node;
}

void check_format_version(const Loader& L, const Node& root) {
  const Node v = L.child(root, "ukdyn_sweep", true);
  if (L.number(v) != 1.0) L.fail(v, "unsupported sweep format version (this ukdyn reads 1)");
}

// The base scenario's tree, and the plant's tree of a control scenario.
struct BaseTrees {
  std::shared_ptr<YAML::Node> doc;
  std::optional<YAML::Node> plant;
};

// `base:`: sets sw.base_path and sw.base_text; the base scenario parsed (not loaded yet).
BaseTrees load_base_trees(const Loader& L, const Node& bn, const std::filesystem::path& path,
                          Sweep& sw) {
  sw.base_path = path.parent_path() / L.string(bn);
  try {
    sw.base_text = read_text(sw.base_path, "base scenario");
  } catch (const ScenarioError& e) {
    L.fail(bn, e.what());
  }
  BaseTrees t;
  t.doc = std::make_shared<YAML::Node>();
  try {
    *t.doc = clone(YAML::Load(sw.base_text));
  } catch (const YAML::Exception& e) {
    L.fail(bn, "the base scenario is not valid YAML: " + e.msg);
  }
  // A control scenario (docs/control.md): each sample runs its closed loop; `plant.` paths lead
  // into the plant's tree.
  if ((*t.doc)["control"].IsDefined()) {
    try {
      t.plant = plant_tree(*t.doc, sw.base_path);
    } catch (const std::exception& e) {
      L.fail(bn, std::string("the base scenario's plant: ") + e.what());
    }
  }
  return t;
}

Sweep::Mode load_mode(const Loader& L, const Node& root) {
  const Node mn = L.child(root, "mode", true);
  const std::string mode = L.string(mn);
  if (mode == "grid") return Sweep::Mode::grid;
  if (mode == "list") return Sweep::Mode::list;
  if (mode == "random") return Sweep::Mode::random;
  L.fail(mn, "unknown mode '" + mode + "' (expected grid, list or random)");
}

// `seed:` (required by a random sweep) into sw.seed.
void load_seed(const Loader& L, const Node& root, Sweep& sw) {
  if (Node s = L.child(root, "seed", false); s.node.IsDefined()) {
    const std::string t = L.string(s);
    char* end = nullptr;
    errno = 0;
    const unsigned long long v = std::strtoull(t.c_str(), &end, 10);
    if (t.empty() || t[0] == '-' || *end != '\0' || errno != 0)
      L.fail(s, "expected an unsigned 64-bit integer");
    sw.seed = v;
  } else if (sw.mode == Sweep::Mode::random) {
    L.fail(root, "missing required key 'seed' (a random sweep needs one)");
  }
}

// One entry of `parameters:` (its name not among `names`, which it joins).
SweepParameter load_parameter(const Loader& L, const Node& p, Sweep::Mode mode,
                              const YAML::Node& doc, const YAML::Node* plant,
                              std::set<std::string>& names) {
  L.only_keys(p, {"name", "path", "values", "range", "distribution"});
  SweepParameter par;
  const Node nn = L.child(p, "name", true);
  par.name = L.name(nn);
  if (!names.insert(par.name).second) L.fail(nn, "duplicate parameter name '" + par.name + "'");
  par.targets = load_targets(L, p, doc, plant);
  const Node dn = L.child(p, "distribution", false);
  if (mode == Sweep::Mode::random) {
    if (!dn.node.IsDefined()) L.fail(p, "missing required key '" + p.key + ".distribution'");
    if (L.child(p, "values", false).node.IsDefined() || L.child(p, "range", false).node.IsDefined())
      L.fail(p, "a random sweep draws values: give distribution, not values / range");
    par.dist = load_distribution(L, dn);
  } else {
    if (dn.node.IsDefined()) L.fail(dn, "only used with mode: random");
    par.dist.values = load_values(L, p);
  }
  return par;
}

void load_parameters(const Loader& L, const Node& ps, const YAML::Node& doc,
                     const YAML::Node* plant, Sweep& sw) {
  if (!ps.node.IsSequence() || ps.node.size() == 0 || ps.node.size() > 64)
    L.fail(ps, "expected a list of 1 to 64 parameters");
  std::set<std::string> names;
  for (std::size_t i = 0; i < ps.node.size(); ++i) {
    const Node p{ps.node[i], ps.key + "[" + std::to_string(i) + "]"};
    sw.parameters.push_back(load_parameter(L, p, sw.mode, doc, plant, names));
  }
}

// The number of samples: `samples:` of a random sweep, else what the parameters' values give.
long load_sample_count(const Loader& L, const Node& root, const Node& ps, const Sweep& sw) {
  const Node sn = L.child(root, "samples", false);
  if (sw.mode == Sweep::Mode::random) {
    if (!sn.node.IsDefined()) L.fail(root, "missing required key 'samples'");
    const double v = L.number(sn);
    if (!(v >= 1 && v <= 1e7 && v == std::floor(v))) L.fail(sn, "expected an integer in [1, 1e7]");
    return static_cast<long>(v);
  }
  if (sn.node.IsDefined()) L.fail(sn, "only used with mode: random (the values set the count)");
  if (sw.mode == Sweep::Mode::grid) {
    double total = 1;
    for (const auto& p : sw.parameters) total *= static_cast<double>(p.dist.values.size());
    if (total > 1e7) L.fail(ps, "the grid has more than 1e7 samples");
    return static_cast<long>(total);
  }
  const auto samples = static_cast<long>(sw.parameters[0].dist.values.size());
  for (std::size_t i = 0; i < sw.parameters.size(); ++i) {
    if (static_cast<long>(sw.parameters[i].dist.values.size()) != samples)
      L.fail(Node{ps.node[i], ps.key + "[" + std::to_string(i) + "]"},
             "mode: list needs the same number of values for every parameter");
  }
  return samples;
}

// `set:` PATH: VALUE into sw.fixed and sw.fixed_values.
void load_fixed(const Loader& L, const Node& root, const YAML::Node& doc, const YAML::Node* plant,
                Sweep& sw) {
  if (Node st = L.child(root, "set", false); st.node.IsDefined()) {
    if (!st.node.IsMap()) L.fail(st, "expected a mapping PATH: VALUE");
    for (const auto& kv : st.node) {
      const std::string p = L.key(st, kv.first);
      const Node e{kv.second, st.key + "." + p};
      SweepTarget t{p, 1.0, 0.0};
      check_path(L, e, p, doc, plant);
      sw.fixed.push_back(t);
      sw.fixed_values.push_back(L.number(e));
    }
  }
}

// A `true` / `false` key of the sweep file, or the fallback if it is absent.
bool load_flag(const Loader& L, const Node& root, const char* key, bool fallback) {
  const Node f = L.child(root, key, false);
  if (!f.node.IsDefined()) return fallback;
  const std::string v = L.string(f);
  if (v != "true" && v != "false") L.fail(f, "expected true or false");
  return v == "true";
}

// No two columns of the table may share a name.
void check_unique_columns(const Loader& L, const Node& root, const Node& ps, const Sweep& sw,
                          const Scenario& base) {
  std::set<std::string> cols;
  for (const auto& c : sweep_header(sw, base)) {
    if (!cols.insert(c).second) {
      L.fail(
          L.child(root, "metrics", false).node.IsDefined() ? L.child(root, "metrics", false) : ps,
          "two columns of the table would be named '" + c +
              "' (a parameter and a metric, or two metrics, share the name)");
    }
  }
}

// The trajectory columns a run of the base scenario has (those the column metrics may name).
std::vector<std::string> base_run_columns(const Loader& L, const Node& bn, const Node& metrics_node,
                                          const Sweep& sw, const Scenario& base) {
  std::vector<std::string> h = trajectory_header(*base.system, base.sim.energy_balance);
  if (base.control) {
    // The columns of a control run: the plant's, then the control columns (as in trajectory.csv).
    std::unique_ptr<ControlRun> ctl;
    try {
      ctl = make_control_run(base);
    } catch (const std::exception& e) {
      L.fail(bn, std::string("the base scenario's control run: ") + e.what());
    }
    h = trajectory_header(*ctl->plant, base.sim.energy_balance);
    ControlColumns cc(base, ctl->loop.get());
    cc.set_plant(*ctl->plant);
    h.insert(h.end(), cc.header().begin(), cc.header().end());
    if (sw.metrics.squeeze && !cc.peaks().closure)
      L.fail(metrics_node,
             "squeeze_force: the plant has no closure rows closure_x, closure_y, "
             "closure_z (the paper's Eq. 12 block named 'closure')");
  }
  return h;
}

// The base scenario itself must load (its own errors name its own file and lines), and the
// metrics must fit it.
void check_against_base(const Loader& L, const Node& root, const Node& ps, const Node& bn,
                        const Sweep& sw) {
  const Scenario base = load_scenario_text(sw.base_text, sw.base_path, {false});
  check_unique_columns(L, root, ps, sw, base);
  const Node metrics_node =
      L.child(root, "metrics", false).node.IsDefined() ? L.child(root, "metrics", false) : root;
  if ((sw.metrics.control || sw.metrics.squeeze) && !base.control)
    L.fail(metrics_node,
           "the metrics control and squeeze_force need a base scenario with a "
           "control: section (docs/control.md)");
  const std::vector<std::string> h = base_run_columns(L, bn, metrics_node, sw, base);
  for (const auto& c : sw.metrics.columns) {
    if (std::find(h.begin(), h.end(), c.column) == h.end())
      L.fail(root, "metrics: no trajectory column named '" + c.column + "'");
  }
}

}  // namespace

Sweep load_sweep(const std::filesystem::path& path) {
  const std::string text = read_text(path, "sweep file");
  Loader L(path);
  const YAML::Node root_node = parse_sweep_yaml(text, path);
  const Node root{root_node, ""};
  if (!root_node.IsMap()) throw ScenarioError(printable(path.string()) + ": expected a mapping");
  L.only_keys(root, {"ukdyn_sweep", "name", "base", "mode", "seed", "samples", "parameters", "set",
                     "metrics", "assemble", "figures"});
  Sweep sw;
  sw.path = path;
  check_format_version(L, root);
  sw.name = L.name(L.child(root, "name", true));
  const Node bn = L.child(root, "base", true);
  const BaseTrees trees = load_base_trees(L, bn, path, sw);
  const YAML::Node& doc = *trees.doc;
  const YAML::Node* plant = trees.plant ? &*trees.plant : nullptr;
  sw.base_doc = trees.doc;
  sw.hash = hash_hex(std::string(version()) + "\n" + text + "\n" + sw.base_text);

  sw.mode = load_mode(L, root);
  load_seed(L, root, sw);
  const Node ps = L.child(root, "parameters", true);
  load_parameters(L, ps, doc, plant, sw);
  sw.samples = load_sample_count(L, root, ps, sw);
  load_fixed(L, root, doc, plant, sw);
  if (Node m = L.child(root, "metrics", false); m.node.IsDefined()) load_metrics(L, m, sw.metrics);
  sw.assemble = load_flag(L, root, "assemble", false);
  sw.figures = load_flag(L, root, "figures", true);
  check_against_base(L, root, ps, bn, sw);
  return sw;
}

std::vector<double> sample_values(const Sweep& sw, long k) {
  std::vector<double> v(sw.parameters.size());
  long rest = k;
  // Grid: the last parameter varies fastest (row-major order).
  for (std::size_t j = sw.parameters.size(); j-- > 0;) {
    const auto& p = sw.parameters[j];
    const auto& d = p.dist;
    const int pj = static_cast<int>(j);
    switch (sw.mode) {
      case Sweep::Mode::grid: {
        const long n = static_cast<long>(d.values.size());
        v[j] = d.values[static_cast<std::size_t>(rest % n)];
        rest /= n;
        break;
      }
      case Sweep::Mode::list:
        v[j] = d.values[static_cast<std::size_t>(k)];
        break;
      case Sweep::Mode::random:
        switch (d.kind) {
          case SweepDistribution::Kind::uniform: {
            const double u = sweep_uniform(sw.seed, k, pj, 0);
            v[j] = d.low + (d.high - d.low) * u;
            break;
          }
          case SweepDistribution::Kind::normal:
            v[j] = d.mean + d.sd * sweep_normal(sw.seed, k, pj);
            break;
          case SweepDistribution::Kind::truncated_normal:
            v[j] = truncated_normal(sweep_uniform(sw.seed, k, pj, 0), d.mean, d.sd, d.low, d.high);
            break;
          case SweepDistribution::Kind::values:
            v[j] = 0.0;
            break;
        }
        break;
    }
  }
  return v;
}

namespace {

double target_value(const SweepTarget& t, double v) { return t.scale * v + t.offset; }

void write_at(YAML::Node& doc, const std::string& path, double value) {
  std::string why;
  auto n = find_scalar(doc, path, why);
  if (n) *n = num(value);  // assigns the node's content in the tree
}

// A `plant.P` target: {path: P, value: v} appended to control.plant_set (applied after the
// entries of the base scenario, so it replaces what they wrote at P).
void write_target(YAML::Node& doc, const std::string& path, double value) {
  if (!plant_path(path)) {
    write_at(doc, path, value);
    return;
  }
  YAML::Node e(YAML::NodeType::Map);
  e["path"] = path.substr(std::strlen(kPlantPrefix));
  e["value"] = num(value);
  if (!doc["control"]["plant_set"].IsSequence())
    doc["control"]["plant_set"] = YAML::Node(YAML::NodeType::Sequence);
  doc["control"]["plant_set"].push_back(e);
}

std::string emit(const YAML::Node& doc) {
  YAML::Emitter e;
  e << doc;
  return std::string(e.c_str()) + "\n";
}

// The base scenario's tree (a copy: the base is parsed once, in load_sweep) with the fixed values
// and the chosen parameters' values written in.
YAML::Node sample_doc(const Sweep& sw, const std::vector<double>& vals, bool with_state) {
  YAML::Node doc = clone(base_yaml(sw));
  for (std::size_t i = 0; i < sw.fixed.size(); ++i)
    write_target(doc, sw.fixed[i].path, sw.fixed_values[i]);
  for (std::size_t j = 0; j < sw.parameters.size(); ++j) {
    for (const auto& t : sw.parameters[j].targets) {
      bool vel = false;
      if (!with_state && state_index(t.path, vel) >= 0) continue;
      write_target(doc, t.path, target_value(t, vals[j]));
    }
  }
  return doc;
}

std::string scenario_text(const Sweep& sw, const std::vector<double>& vals, bool with_state) {
  return emit(sample_doc(sw, vals, with_state));
}

}  // namespace

std::string sample_scenario_text(const Sweep& sw, long k) {
  const auto vals = sample_values(sw, k);
  std::string head = fmt::format(
      "# Sample {} of sweep '{}' ({}), base scenario {}; written by ukdyn {} sweep --extract.\n", k,
      sw.name, printable(sw.path.string()), printable(sw.base_path.string()), version());
  for (std::size_t j = 0; j < vals.size(); ++j)
    head += fmt::format("#   {} = {}\n", sw.parameters[j].name, num(vals[j]));
  return head + scenario_text(sw, vals, true);
}

// ---------------------------------------------------------------------------------------------
// One sample, in memory.

std::vector<std::string> sweep_header(const Sweep& sw, const Scenario& base) {
  std::vector<std::string> h{"sample"};
  for (const auto& p : sw.parameters) h.push_back(p.name);
  h.insert(h.end(), {"status", "reason", "t_reached", "steps"});
  const auto& names = base.system->coordinate_names();
  const auto& m = sw.metrics;
  if (m.max_residual) h.push_back("max_residual");
  if (m.energy_drift) h.push_back("energy_drift");
  if (m.energy_balance_drift) h.push_back("energy_balance_drift");
  if (m.control)
    h.insert(h.end(), {"max_abs_e", "max_abs_e_second_half", "max_abs_u", "max_abs_udot",
                       "saturation_time", "saturation_max_over_limit"});
  if (m.squeeze) h.insert(h.end(), {"max_closure_force", "max_squeeze_force"});
  if (m.max_abs_qc)
    for (const auto& n : names) h.push_back("max_abs_Qc_" + n);
  if (m.final_state) {
    for (const auto& n : names) h.push_back("final_" + n);
    for (const auto& n : names) h.push_back("final_" + n + "_dot");
  }
  for (const auto& c : m.columns)
    for (const auto& s : c.stats) h.push_back(s + "_" + c.column);
  return h;
}

namespace {

using io_detail::nanmax;

// Metrics over the samples of one run: the trajectory.csv quantities and the report's extrema come
// from the SampleRecorder that run_scenario() uses (io/run_observer.hpp); kept here: max |Qc|, the
// final state and the statistics of chosen columns.
struct SampleObserver {
  SampleObserver(const System& s, bool balance, std::size_t row_size, std::vector<std::size_t> cols,
                 bool need_sigma)
      : recorder(s, rep, balance, row_size, {!cols.empty(), false, need_sigma}),
        col_index(std::move(cols)),
        max_qc(Vec::Zero(s.dof())),
        cmin(col_index.size(), NAN),
        cmax(col_index.size(), NAN),
        csq(col_index.size(), 0.0),
        clast(col_index.size(), NAN),
        cabs(col_index.size(), 0.0) {}
  RunReport rep;  // (before the recorder, which writes into it)
  io_detail::SampleRecorder recorder;
  std::vector<std::size_t> col_index;  // into the trajectory row, per ColumnMetric
  Vec max_qc, q_last, qd_last;
  std::vector<double> cmin, cmax, csq, clast, cabs;
  long count = 0;
  // A control run: its columns after the trajectory's (as run_scenario's Observer fills them),
  // and their extrema once the run is over.
  ControlColumns* control = nullptr;
  std::size_t control_at = 0;
  ControlColumns::Peaks peaks;

  [[nodiscard]] double max_residual() const {
    double r = 0.0;
    for (double v : rep.max_abs_residual) r = nanmax(r, v);
    return r;
  }

  bool operator()(double t, CVecRef q, CVecRef qd, const ForwardData& d) {
    recorder.record(t, q, qd, d);
    if (control != nullptr) control->fill(t, q, qd, d, recorder.row().data() + control_at);
    for (Index i = 0; i < max_qc.size(); ++i) max_qc(i) = nanmax(max_qc(i), std::abs(d.Qc(i)));
    q_last = q;
    qd_last = qd;
    const std::vector<double>& row = recorder.row();
    for (std::size_t c = 0; c < col_index.size(); ++c) {
      const double v = row[col_index[c]];
      if (count == 0) {
        cmin[c] = cmax[c] = v;
      } else {
        cmin[c] = std::isnan(v) || std::isnan(cmin[c]) ? NAN : std::min(cmin[c], v);
        cmax[c] = nanmax(cmax[c], v);
      }
      cabs[c] = nanmax(cabs[c], std::abs(v));
      csq[c] += v * v;
      clast[c] = v;
    }
    ++count;
    return true;
  }
};

std::string clean_reason(std::string s) {
  for (char& c : s)
    if (c == '\n' || c == '\r') c = ' ';
  if (s.size() > 400) s = s.substr(0, 400) + "...";
  return csv_field(printable(s));
}

// The loaded scenarios of the sweep, by the values that shape the model (bounded).
struct ModelCache {
  struct Entry {
    std::shared_ptr<const Scenario> sc;
    std::string error;
  };
  std::mutex mu;
  std::map<std::string, Entry> entries;
};

class SampleRunner {
 public:
  SampleRunner(const Sweep& sw, const Scenario& base) : sw_(sw), base_(base) {
    // A control scenario loads each sample whole (its plant and offset start follow q0).
    share_state_ = !base.control && system_independent_of_state(base_yaml(sw));
    for (const auto& p : sw.parameters) {
      for (const auto& t : p.targets) {
        bool vel = false;
        const long i = state_index(t.path, vel);
        // A state path beyond the coordinates cannot be shared (the loader will refuse it).
        if (i >= base.system->dof()) share_state_ = false;
      }
    }
    header_ = sweep_header(sw, base);
  }

  std::string row(long k, const std::atomic<bool>* cancel) {
    const auto vals = sample_values(sw_, k);
    std::string r = fmt::format("{}", k);
    for (double v : vals) r += "," + num(v);
    SampleOutcome out;
    // Building (and dropping) a model from definitions runs GiNaC, which is not thread-safe
    // (docs/architecture.md, "Thread safety"): the sample's scenario and control run are built and
    // released under build_mu_; only the integration runs in parallel.
    std::optional<Scenario> held;
    std::unique_ptr<ControlRun> ctl;
    try {
      {
        std::lock_guard<std::mutex> lock(build_mu_);
        held.emplace(scenario_for(k, vals, out.status, out.reason));
      }
      Scenario& sc = *held;
      if (out.status == "completed" && prepare_initial_state(sc, out)) {
        simulate_sample(sc, ctl, cancel, out);
      }
    } catch (const std::exception& e) {
      out.status = "error";
      out.reason = e.what();
      out.obs.reset();
    }
    {
      std::lock_guard<std::mutex> lock(build_mu_);
      ctl.reset();
      held.reset();
    }
    if (cancel && cancel->load()) return {};  // not recorded: recomputed on resume
    r += "," + out.status + "," + clean_reason(out.reason);
    r += "," + num(out.stats.t_reached) + "," + std::to_string(out.stats.steps);
    const std::size_t fixed = 1 + vals.size() + 4;
    std::vector<std::string> cells;
    if (out.obs) cells = metric_cells(*out.obs);
    // A failed load leaves the metric cells empty (same count as the header).
    cells.resize(header_.size() - fixed);
    for (const auto& c : cells) r += "," + c;
    return r;
  }

  const std::vector<std::string>& header() const { return header_; }

 private:
  // What the run of one sample leaves for its row.
  struct SampleOutcome {
    std::string status = "completed", reason;
    SimulationStats stats;
    std::optional<SampleObserver> obs;  // empty if the sample did not run (or failed)
  };

  // Moves (q0, q̇0) onto the constraints (`assemble: true`), or checks that they meet them.
  // Returns false (with out.status and out.reason saying why) if the sample cannot run.
  bool prepare_initial_state(Scenario& sc, SampleOutcome& out) const {
    const System& sys = *sc.system;
    const Index m = sys.rows();
    if (sw_.assemble) {
      const auto a = assemble(sys, sc.sim.t0, sc.q0, sc.qd0, sc.held);
      if (!a.success) {
        out.status = "assembly_failed";
        out.reason = a.message;
        return false;
      }
      sc.q0 = a.q;
      sc.qd0 = a.qd;
    } else if (m > 0) {
      Vec phi(m), phid(m);
      position_residuals(sys, sc.sim.t0, sc.q0, phi);
      velocity_residuals(sys, sc.sim.t0, sc.q0, sc.qd0, phid);
      const double p = phi.cwiseAbs().maxCoeff(), v = phid.cwiseAbs().maxCoeff();
      if (!(p <= sc.initial_tolerance) || !(v <= sc.initial_tolerance)) {
        out.status = "inconsistent_initial";
        out.reason = fmt::format(
            "initial state violates the constraints: max |Phi| = {:.3e}, "
            "max |Phi_dot| = {:.3e} > initial_tolerance {:g}",
            p, v, sc.initial_tolerance);
        return false;
      }
    }
    return true;
  }

  // The trajectory row's index of each column metric; need_sigma: one of them is sigma_min.
  std::vector<std::size_t> metric_column_indices(const std::vector<std::string>& th,
                                                 bool& need_sigma) const {
    std::vector<std::size_t> cols;
    need_sigma = false;
    for (const auto& c : sw_.metrics.columns) {
      const auto it = std::find(th.begin(), th.end(), c.column);
      if (it == th.end()) throw Error("no trajectory column named '" + c.column + "'");
      cols.push_back(static_cast<std::size_t>(it - th.begin()));
      need_sigma = need_sigma || c.column == "sigma_min";
    }
    return cols;
  }

  // Integrates the sample, its metrics into out.obs. ctl: its control run, built here and released
  // by row() (both under build_mu_).
  void simulate_sample(const Scenario& sc, std::unique_ptr<ControlRun>& ctl,
                       const std::atomic<bool>* cancel, SampleOutcome& out) {
    const System& sys = *sc.system;
    const bool balance = sc.sim.energy_balance;
    // docs/control.md: with `control:` the plant (physical rows only, τ = B u from the
    // law) is integrated, exactly as run_scenario() does it (io/run.cpp).
    {
      std::lock_guard<std::mutex> lock(build_mu_);
      ctl = make_control_run(sc);
    }
    const System& psys = ctl ? *ctl->plant : sys;
    std::optional<ControlColumns> cc;
    auto th = trajectory_header(psys, balance);
    const std::size_t control_at = th.size();
    if (ctl) {
      cc.emplace(sc, ctl->loop.get());
      cc->set_plant(*ctl->plant);
      th.insert(th.end(), cc->header().begin(), cc->header().end());
    }
    bool need_sigma = false;
    std::vector<std::size_t> cols = metric_column_indices(th, need_sigma);
    const Vec& q0 = ctl ? ctl->q0 : sc.q0;
    const Vec& qd0 = ctl ? ctl->qd0 : sc.qd0;
    out.obs.emplace(psys, balance, th.size(), std::move(cols), need_sigma);
    out.obs->q_last = q0;
    out.obs->qd_last = qd0;
    out.obs->control = cc ? &*cc : nullptr;
    out.obs->control_at = control_at;
    SimulationSettings settings = sc.sim;
    settings.cancel = cancel;
    const Vec tau = sc.tau;
    const ForceFunction f =
        ctl ? ctl->loop->force_function()
            : ForceFunction([&tau](double, CVecRef, CVecRef, VecRef o) { o = tau; });
    SampleObserver& o = *out.obs;
    out.stats = simulate(
        psys, q0, qd0, f, settings,
        [&o](double t, CVecRef q, CVecRef qd, const ForwardData& d) { return o(t, q, qd, d); });
    if (cc) out.obs->peaks = cc->peaks();
    out.obs->control = nullptr;
    cc.reset();
    out.status = to_string(out.stats.status);
    out.reason = out.stats.message;
    if (out.stats.status == RunStatus::completed) out.reason.clear();
  }

  // The metric cells of a sample that ran, in the order of sweep_header().
  std::vector<std::string> metric_cells(const SampleObserver& o) const {
    std::vector<std::string> cells;
    const auto& mx = sw_.metrics;
    if (mx.max_residual) cells.push_back(num(o.max_residual()));
    if (mx.energy_drift) cells.push_back(num(o.rep.max_energy_drift));
    if (mx.energy_balance_drift)
      cells.push_back(o.rep.energy_balance ? num(o.rep.energy_balance_drift) : "nan");
    const auto& pk = o.peaks;
    if (mx.control) {
      for (double v : {pk.max_abs_e, pk.max_abs_e_second_half, pk.max_abs_u, pk.max_abs_udot,
                       pk.saturation_time, pk.saturation_max_over_limit})
        cells.push_back(num(v));
    }
    if (mx.squeeze) {
      cells.push_back(o.count > 0 ? num(pk.max_closure_force) : "nan");
      cells.push_back(o.count > 0 ? num(pk.max_squeeze_force) : "nan");
    }
    if (mx.max_abs_qc)
      for (Index i = 0; i < o.max_qc.size(); ++i) cells.push_back(num(o.max_qc(i)));
    if (mx.final_state) {
      for (Index i = 0; i < o.q_last.size(); ++i) cells.push_back(num(o.q_last(i)));
      for (Index i = 0; i < o.qd_last.size(); ++i) cells.push_back(num(o.qd_last(i)));
    }
    std::size_t ci = 0;
    for (const auto& c : mx.columns) {
      for (const auto& s : c.stats) {
        const double cnt = static_cast<double>(std::max(o.count, 1L));
        const double v = s == "min"       ? o.cmin[ci]
                         : s == "max"     ? o.cmax[ci]
                         : s == "rms"     ? std::sqrt(o.csq[ci] / cnt)
                         : s == "max_abs" ? o.cabs[ci]
                                          : o.clast[ci];
        cells.push_back(num(v));
      }
      ++ci;
    }
    return cells;
  }

  Scenario scenario_for(long k, const std::vector<double>& vals, std::string& status,
                        std::string& reason) {
    // The values that shape the model: every target but the state ones when they can be shared.
    std::string key;
    for (std::size_t j = 0; j < vals.size(); ++j) {
      for (const auto& t : sw_.parameters[j].targets) {
        bool vel = false;
        if (share_state_ && state_index(t.path, vel) >= 0) continue;
        key += num(target_value(t, vals[j])) + ";";
      }
    }
    ModelCache::Entry e;
    {
      std::lock_guard<std::mutex> lock(cache_.mu);
      if (auto it = cache_.entries.find(key); it != cache_.entries.end()) e = it->second;
    }
    if (!e.sc && e.error.empty()) {
      // The values are written into a copy of the base scenario's tree, parsed once (load_sweep):
      // no text is emitted and parsed again per sample.
      try {
        e.sc = std::make_shared<const Scenario>(io_detail::load_scenario_yaml(
            sample_doc(sw_, vals, !share_state_), base_hash_, sw_.base_path, LoadOptions{false}));
      } catch (const ScenarioError& err) {
        e.error = err.what();
      }
      std::lock_guard<std::mutex> lock(cache_.mu);
      if (cache_.entries.size() >= 256) cache_.entries.clear();  // bounded; never changes results
      cache_.entries.emplace(key, e);
    }
    if (!e.sc) {
      status = "invalid_scenario";
      reason = fmt::format("sample {}: {}", k, e.error);
      return base_;
    }
    Scenario sc = *e.sc;
    if (share_state_) {
      for (std::size_t j = 0; j < vals.size(); ++j) {
        for (const auto& t : sw_.parameters[j].targets) {
          bool vel = false;
          const long i = state_index(t.path, vel);
          if (i < 0) continue;
          (vel ? sc.qd0 : sc.q0)(static_cast<Index>(i)) = target_value(t, vals[j]);
        }
      }
    }
    return sc;
  }

  const Sweep& sw_;
  const Scenario& base_;
  std::string base_hash_ = base_.hash;  // Scenario::hash of every sample: the base scenario's
  bool share_state_ = false;
  std::vector<std::string> header_;
  ModelCache cache_;
  std::mutex build_mu_;  // model building and release (GiNaC), see row()
};

}  // namespace

std::string run_sample(const Sweep& sw, const Scenario& base, long k,
                       const std::atomic<bool>* cancel) {
  SampleRunner r(sw, base);
  return r.row(k, cancel);
}

// ---------------------------------------------------------------------------------------------
// Tables, summary, figures.

namespace {

std::vector<std::string> split_csv(const std::string& line) {
  std::vector<std::string> out;
  std::string cur;
  bool quoted = false;
  for (std::size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (quoted) {
      if (c == '"' && i + 1 < line.size() && line[i + 1] == '"') {
        cur += '"';
        ++i;
      } else if (c == '"') {
        quoted = false;
      } else {
        cur += c;
      }
    } else if (c == '"') {
      quoted = true;
    } else if (c == ',') {
      out.push_back(cur);
      cur.clear();
    } else {
      cur += c;
    }
  }
  out.push_back(cur);
  return out;
}

std::string header_line(const std::vector<std::string>& h) {
  std::string s;
  for (std::size_t i = 0; i < h.size(); ++i) s += (i ? "," : "") + csv_field(h[i]);
  return s;
}

double parse_cell(const std::string& s) {
  if (s.empty()) return NAN;
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  return *end == '\0' ? v : NAN;
}

// Linear interpolation between closest ranks ([Hyndman1996], definition 7) of sorted values.
double percentile(const std::vector<double>& sorted, double p) {
  if (sorted.empty()) return NAN;
  const double h = (static_cast<double>(sorted.size()) - 1.0) * p;
  const auto lo = static_cast<std::size_t>(std::floor(h));
  const std::size_t hi = std::min(lo + 1, sorted.size() - 1);
  return sorted[lo] + (h - static_cast<double>(lo)) * (sorted[hi] - sorted[lo]);
}

nlohmann::json jnum(double v) {
  return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr);
}

struct Table {
  std::vector<std::string> header;
  std::map<long, std::string> rows;  // by sample index
};

// The first metric column (after sample, parameters, status, reason, t_reached, steps).
std::size_t first_metric(const Sweep& sw) { return 1 + sw.parameters.size() + 4; }

nlohmann::json summary_json(const Sweep& sw, const Table& t, const SweepOptions* opt, bool complete,
                            SweepReport& rep) {
  nlohmann::json j;
  j["ukdyn_version"] = version();
  j["sweep"] = {{"name", sw.name},
                {"path", sw.path.string()},
                {"hash_fnv1a64", sw.hash},
                {"mode", sw.mode == Sweep::Mode::grid   ? "grid"
                         : sw.mode == Sweep::Mode::list ? "list"
                                                        : "random"},
                {"seed", sw.seed},
                {"samples", sw.samples}};
  j["base_scenario"] = sw.base_path.string();
  if (opt && opt->shards > 1) j["shard"] = fmt::format("{}/{}", opt->shard, opt->shards);
  j["complete"] = complete;
  const std::size_t st = 1 + sw.parameters.size();
  long completed = 0;
  nlohmann::json fails = nlohmann::json::array();
  std::map<std::string, long> by_status;
  std::vector<std::vector<double>> cols(t.header.size());
  for (const auto& [k, line] : t.rows) {
    const auto cells = split_csv(line);
    if (cells.size() != t.header.size()) continue;
    const std::string& status = cells[st];
    ++by_status[status];
    if (status != "completed") {
      fails.push_back({{"sample", k}, {"status", status}, {"reason", cells[st + 1]}});
      rep.failures.push_back(fmt::format("sample {}: {}: {}", k, status, cells[st + 1]));
      continue;
    }
    ++completed;
    for (std::size_t c = 1; c < cells.size(); ++c) {
      if (c == st || c == st + 1) continue;
      const double v = parse_cell(cells[c]);
      if (std::isfinite(v)) cols[c].push_back(v);
    }
  }
  rep.failed = static_cast<long>(t.rows.size()) - completed;
  j["samples_in_table"] = t.rows.size();
  j["completed"] = completed;
  j["failed"] = rep.failed;
  j["status_counts"] = by_status;
  j["failures"] = fails;
  nlohmann::json stats = nlohmann::json::object();
  for (std::size_t c = 1; c < t.header.size(); ++c) {
    if (c == st || c == st + 1) continue;
    auto v = cols[c];
    std::sort(v.begin(), v.end());
    double sum = 0.0;
    for (double x : v) sum += x;
    stats[t.header[c]] = {{"count", v.size()},
                          {"min", jnum(v.empty() ? NAN : v.front())},
                          {"p01", jnum(percentile(v, 0.01))},
                          {"p05", jnum(percentile(v, 0.05))},
                          {"p50", jnum(percentile(v, 0.50))},
                          {"p95", jnum(percentile(v, 0.95))},
                          {"p99", jnum(percentile(v, 0.99))},
                          {"max", jnum(v.empty() ? NAN : v.back())},
                          {"mean", jnum(v.empty() ? NAN : sum / static_cast<double>(v.size()))}};
  }
  j["statistics_of_completed_samples"] = stats;
  return j;
}

constexpr const char* kTable = "results.csv";
constexpr const char* kSummary = "summary.json";
constexpr const char* kJournal = "journal.csv";

// Histograms of each metric (completed samples), and a heat map of each metric over a 2-D grid.
void draw_figures(const OutputDir& out, const Sweep& sw, const Table& t, SweepReport& rep,
                  const std::atomic<bool>* cancel) {
  const std::size_t st = 1 + sw.parameters.size();
  const std::size_t m0 = first_metric(sw);
  std::vector<std::size_t> metrics;
  for (std::size_t c = m0; c < t.header.size() && metrics.size() < 24; ++c) metrics.push_back(c);
  std::string gp = "# Generated by ukdyn sweep: cd OUT/figures && gnuplot figures.gp\n";
  gp += "set datafile separator ','\nset terminal pngcairo size 900,600 enhanced font 'sans,11'\n";
  gp += "set grid\nset key off\nset datafile missing 'nan'\n";
  const std::string data = gnuplot_string(std::string("../") + kTable);
  std::vector<std::string> files;
  const bool heat = sw.mode == Sweep::Mode::grid && sw.parameters.size() == 2;
  for (std::size_t c : metrics) {
    std::vector<double> v;
    for (const auto& [k, line] : t.rows) {
      const auto cells = split_csv(line);
      if (cells.size() == t.header.size() && cells[st] == "completed") {
        const double x = parse_cell(cells[c]);
        if (std::isfinite(x)) v.push_back(x);
      }
    }
    if (v.empty()) continue;
    const auto [lo, hi] = std::minmax_element(v.begin(), v.end());
    double w = (*hi - *lo) / 20.0;
    if (!(w > 0.0)) w = std::max(std::abs(*lo) * 1e-3, 1e-300);
    const std::string stem = file_stem("hist_" + t.header[c]);
    files.push_back(stem + ".png");
    gp += "set output " + gnuplot_string(files.back()) + "\n";
    gp += "set title " +
          gnuplot_string(fmt::format("{} over {} completed samples", t.header[c], v.size())) +
          " noenhanced\n";
    gp += "set xlabel " + gnuplot_string(t.header[c]) + " noenhanced\nset ylabel 'samples'\n";
    gp +=
        fmt::format("set style fill solid 0.6\nbin(x) = {} * floor((x - {}) / {}) + {} + {} / 2\n",
                    num(w), num(*lo), num(w), num(*lo), num(w));
    gp += fmt::format(
        "plot {} skip 1 using (strcol({}) eq 'completed' ? bin(column({})) : NaN):(1.0) "
        "smooth freq with boxes\nunset output\n",
        data, st + 1, c + 1);
    if (heat) {
      files.push_back(file_stem("heat_" + t.header[c]) + ".png");
      gp += "set output " + gnuplot_string(files.back()) + "\n";
      gp += "set title " + gnuplot_string(t.header[c] + " over the grid") + " noenhanced\n";
      gp += "set xlabel " + gnuplot_string(sw.parameters[0].name) + " noenhanced\n";
      gp += "set ylabel " + gnuplot_string(sw.parameters[1].name) + " noenhanced\n";
      // One filled square per grid point, coloured by the metric (failed samples left blank).
      const std::size_t cells_max =
          std::max(sw.parameters[0].dist.values.size(), sw.parameters[1].dist.values.size());
      const double ps = std::clamp(60.0 / static_cast<double>(cells_max), 0.5, 8.0);
      gp += "set palette rgbformulae 33,13,10\nset colorbox\n";
      gp += "set offsets graph 0.08, graph 0.08, graph 0.08, graph 0.08\n";
      gp += fmt::format(
          "plot {} skip 1 using 2:3:(strcol({}) eq 'completed' ? column({}) : NaN) "
          "with points pointtype 5 pointsize {} palette\nunset output\n"
          "unset colorbox\nset offsets 0, 0, 0, 0\n",
          data, st + 1, c + 1, num(ps));
    }
  }
  if (files.empty()) return;
  try {
    const FigureResult fr = render_gnuplot_script(out, gp, files, cancel);
    for (const auto& f : fr.written) rep.figures.push_back(out.path() / f);
    rep.figure_error = fr.error;
  } catch (const Error& e) {
    rep.figure_error = e.what();
  }
}

void write_outputs(const OutputDir& out, const Sweep& sw, const Table& t, const SweepOptions* opt,
                   bool complete, SweepReport& rep, const std::atomic<bool>* cancel) {
  {
    AtomicFile f(out, out.fd(), "", kTable);
    f.write(header_line(t.header) + "\n");
    for (const auto& [k, line] : t.rows) f.write(line + "\n");
    f.commit();
  }
  rep.table = out.path() / kTable;
  nlohmann::json j = summary_json(sw, t, opt, complete, rep);
  if (complete && sw.figures) draw_figures(out, sw, t, rep, cancel);
  nlohmann::json figs = nlohmann::json::array();
  for (const auto& f : rep.figures) figs.push_back(f.lexically_relative(out.path()).string());
  j["figures"] = figs;
  if (!rep.figure_error.empty()) j["figure_error"] = rep.figure_error;
  {
    AtomicFile f(out, out.fd(), "", kSummary);
    f.write(j.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n");
    f.commit();
  }
  rep.summary = out.path() / kSummary;
  out.sync();
}

std::string journal_head(const Sweep& sw, const SweepOptions& opt) {
  return fmt::format("# ukdyn sweep journal {} shard {}/{}", sw.hash, opt.shard, opt.shards);
}

// The rows of a previous, interrupted run of the same sweep (whole lines only).
std::map<long, std::string> read_journal(const OutputDir& out, const std::string& head,
                                         std::size_t columns) {
  std::map<long, std::string> rows;
  const int fd = ::openat(out.fd(), kJournal, O_RDONLY | O_NOFOLLOW | O_CLOEXEC | O_NONBLOCK);
  if (fd < 0) return rows;
  std::string text;
  struct stat st {};
  if (::fstat(fd, &st) == 0 && S_ISREG(st.st_mode)) {
    char buf[65536];
    ssize_t got = 0;
    while ((got = ::read(fd, buf, sizeof buf)) > 0) text.append(buf, static_cast<std::size_t>(got));
  }
  ::close(fd);
  std::size_t pos = text.find('\n');
  if (pos == std::string::npos || text.substr(0, pos) != head) return rows;
  ++pos;
  while (pos < text.size()) {
    const auto end = text.find('\n', pos);
    if (end == std::string::npos) break;  // a torn last line: recomputed
    const std::string line = text.substr(pos, end - pos);
    pos = end + 1;
    const auto cells = split_csv(line);
    if (cells.size() != columns) continue;
    char* e = nullptr;
    const long k = std::strtol(cells[0].c_str(), &e, 10);
    if (*e == '\0' && !cells[0].empty()) rows[k] = line;
  }
  return rows;
}

// Append-only journal: each finished row is one write(2) of a whole line (O_APPEND); fdatasync
// at most once a second and at the end (a killed process loses nothing the kernel has).
class Journal {
 public:
  Journal(const OutputDir& out, const std::string& head, const std::map<long, std::string>& keep)
      : out_(out) {
    out.require_file_or_absent(out.fd(), "", kJournal);
    // Rewritten through a temporary, so that it holds exactly the rows kept (whole lines).
    {
      AtomicFile f(out, out.fd(), "", kJournal);
      f.write(head + "\n");
      for (const auto& [k, line] : keep) f.write(line + "\n");
      f.commit();
    }
    fd_ = ::openat(out.fd(), kJournal, O_WRONLY | O_APPEND | O_NOFOLLOW | O_CLOEXEC);
    if (fd_ < 0) throw WriteFailed(out.display(kJournal) + ": " + std::strerror(errno));
    last_sync_ = std::chrono::steady_clock::now();
  }
  ~Journal() {
    if (fd_ >= 0) {
      ::fdatasync(fd_);
      ::close(fd_);
    }
  }
  Journal(const Journal&) = delete;
  Journal& operator=(const Journal&) = delete;
  void append(const std::string& line) {
    const std::string s = line + "\n";
    std::lock_guard<std::mutex> lock(mu_);
    if (!error_.empty()) return;
    std::size_t done = 0;
    while (done < s.size()) {
      if (out_.inject_failure(kJournal, s.size())) {
        error_ = out_.display(kJournal) + ": write failed: No space left on device";
        return;
      }
      const ssize_t w = ::write(fd_, s.data() + done, s.size() - done);
      if (w < 0 && errno == EINTR) continue;
      if (w <= 0) {
        error_ = out_.display(kJournal) + ": write failed: " + std::strerror(errno);
        return;
      }
      done += static_cast<std::size_t>(w);
    }
    const auto now = std::chrono::steady_clock::now();
    if (now - last_sync_ > std::chrono::seconds(1)) {
      ::fdatasync(fd_);
      last_sync_ = now;
    }
  }
  std::string error() {
    std::lock_guard<std::mutex> lock(mu_);
    return error_;
  }

 private:
  const OutputDir& out_;
  int fd_ = -1;
  std::mutex mu_;
  std::string error_;
  std::chrono::steady_clock::time_point last_sync_;
};

std::string duration_text(double s) {
  if (!std::isfinite(s)) return "?";
  const long t = std::lround(s);
  if (t >= 3600) return fmt::format("{}h{:02}m", t / 3600, (t / 60) % 60);
  if (t >= 60) return fmt::format("{}m{:02}s", t / 60, t % 60);
  return fmt::format("{}s", t);
}

// The samples of this shard (k % shards == shard).
std::vector<long> shard_sample_indices(const Sweep& sw, const SweepOptions& opt) {
  std::vector<long> shard_samples;
  for (long k = opt.shard; k < sw.samples; k += opt.shards) shard_samples.push_back(k);
  return shard_samples;
}

// Rank 0's output folder: the earlier table and summary removed, the rows of an interrupted run of
// this shard read back from its journal (`done`), and the journal opened (one process only).
void open_sweep_output(const Sweep& sw, const SweepOptions& opt,
                       const std::filesystem::path& out_dir, const std::string& head,
                       std::size_t columns, int size, std::optional<OutputDir>& out,
                       std::map<long, std::string>& done, std::optional<Journal>& journal) {
  out.emplace(out_dir);
  // A table or summary of an earlier run goes first: nothing on disk may describe another run.
  for (const char* f : {kTable, kSummary}) {
    out->require_file_or_absent(out->fd(), "", f);
    out->remove_file(out->fd(), f);
  }
  if (opt.resume && size == 1) done = read_journal(*out, head, columns);
  for (auto it = done.begin(); it != done.end();) {  // rows of this shard only
    it = (it->first % opt.shards == opt.shard && it->first < sw.samples) ? std::next(it)
                                                                         : done.erase(it);
  }
  if (size == 1) journal.emplace(*out, head, done);
}

// This rank's share of the shard's samples, less those already done.
std::vector<long> rank_todo(const std::vector<long>& shard_samples,
                            const std::map<long, std::string>& done, int rank, int size) {
  std::vector<long> todo;
  for (std::size_t i = 0; i < shard_samples.size(); ++i) {
    if (static_cast<int>(i % static_cast<std::size_t>(size)) != rank) continue;
    if (!done.count(shard_samples[i])) todo.push_back(shard_samples[i]);
  }
  return todo;
}

// Worker threads: opt.threads (or every core), at most one per sample to compute.
int pool_threads(const SweepOptions& opt, std::size_t todo) {
  int threads = opt.threads > 0
                    ? opt.threads
                    : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  threads = static_cast<int>(
      std::min<std::size_t>(static_cast<std::size_t>(threads), std::max<std::size_t>(todo, 1)));
  return threads;
}

// One progress report of rank 0: a bar on a terminal, else a line.
void report_sweep_progress(const SweepOptions& opt, int rank,
                           std::chrono::steady_clock::time_point start,
                           const std::atomic<std::size_t>& finished, std::size_t todo, bool final) {
  if (!opt.progress || rank != 0) return;
  const double el = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const auto f = static_cast<double>(finished.load());
  const double total = static_cast<double>(todo);
  const double rate = el > 0 ? f / el : 0.0;
  const double eta = rate > 0 ? (total - f) / rate : NAN;
  const double frac = total > 0 ? f / total : 1.0;
  if (opt.progress_tty) {
    const int width = 30, filled = static_cast<int>(frac * width);
    *opt.progress << "\r[" << std::string(static_cast<std::size_t>(filled), '#')
                  << std::string(static_cast<std::size_t>(width - filled), ' ') << "] "
                  << fmt::format("{}/{} samples  {:.1f}/s  ETA {}   ", f, total, rate,
                                 duration_text(eta));
    if (final) *opt.progress << "\n";
  } else {
    *opt.progress << fmt::format(
        "ukdyn: sweep: {}/{} samples ({:.0f}%), {:.2f} samples/s, "
        "ETA {}\n",
        f, total, 100.0 * frac, rate, duration_text(eta));
  }
  *opt.progress << std::flush;
}

// The rows of the samples `todo` (empty: cancelled), computed by a pool of threads, each appended
// to the journal (if any) as it is done; progress from this thread while the pool works.
std::vector<std::string> compute_rows(SampleRunner& runner, const std::vector<long>& todo,
                                      Journal* journal, const SweepOptions& opt, int rank,
                                      std::chrono::steady_clock::time_point start) {
  const int threads = pool_threads(opt, todo.size());
  std::vector<std::string> rows(todo.size());
  std::atomic<std::size_t> next{0}, finished{0};
  {
    std::vector<std::jthread> pool;
    for (int t = 0; t < threads; ++t) {
      pool.emplace_back([&] {
        while (!(opt.cancel && opt.cancel->load())) {
          const std::size_t i = next.fetch_add(1);
          if (i >= todo.size()) break;
          rows[i] = runner.row(todo[i], opt.cancel);
          if (!rows[i].empty() && journal) journal->append(rows[i]);
          finished.fetch_add(1);
        }
      });
    }
    // Progress from this thread while the pool works.
    auto last = std::chrono::steady_clock::now();
    while (finished.load() < todo.size() && !(opt.cancel && opt.cancel->load())) {
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
      const auto now = std::chrono::steady_clock::now();
      const double every = opt.progress_tty ? 0.2 : opt.progress_every;
      if (std::chrono::duration<double>(now - last).count() >= every) {
        report_sweep_progress(opt, rank, start, finished, todo.size(), false);
        last = now;
      }
    }
    for (auto& th : pool) th.join();
    if (opt.progress_tty || finished.load() > 0)
      report_sweep_progress(opt, rank, start, finished, todo.size(), true);
  }
  return rows;
}

// Gather (MPI): every rank's rows into rank 0's table t. Returns false on the other ranks (their
// part is done).
bool gather_rows(SweepComm& comm, int rank, const std::vector<std::string>& rows, Table& t,
                 SweepReport& rep) {
  std::string mine;
  if (rank != 0)
    for (const auto& r : rows)
      if (!r.empty()) mine += r + "\n";
  const auto all = comm.gather(mine);
  if (rank != 0) return false;
  for (const auto& blob : all) {
    std::size_t pos = 0;
    while (pos < blob.size()) {
      const auto end = blob.find('\n', pos);
      const std::string line = blob.substr(pos, end - pos);
      pos = end + 1;
      t.rows[std::strtol(line.c_str(), nullptr, 10)] = line;
      ++rep.computed;
    }
  }
  return true;
}

}  // namespace

SweepReport run_sweep(const Sweep& sw, const std::filesystem::path& out_dir,
                      const SweepOptions& opt) {
  const auto start = std::chrono::steady_clock::now();
  if (opt.shards < 1 || opt.shard < 0 || opt.shard >= opt.shards)
    throw ScenarioError("--shard: expected i/N with 0 <= i < N");
  const Scenario base = load_scenario_text(sw.base_text, sw.base_path, LoadOptions{false});
  SampleRunner runner(sw, base);
  const auto& header = runner.header();
  const int rank = opt.comm ? opt.comm->rank() : 0;
  const int size = opt.comm ? opt.comm->size() : 1;

  // This shard's samples; then this rank's share of them.
  const std::vector<long> shard_samples = shard_sample_indices(sw, opt);
  SweepReport rep;
  rep.samples = static_cast<long>(shard_samples.size());

  std::optional<OutputDir> out;
  std::map<long, std::string> done;
  std::optional<Journal> journal;
  const std::string head = journal_head(sw, opt);
  if (rank == 0) {
    open_sweep_output(sw, opt, out_dir, head, header.size(), size, out, done, journal);
    rep.resumed = static_cast<long>(done.size());
  }
  const std::vector<long> todo = rank_todo(shard_samples, done, rank, size);

  const std::vector<std::string> rows =
      compute_rows(runner, todo, journal ? &*journal : nullptr, opt, rank, start);
  rep.computed = 0;
  for (const auto& r : rows) rep.computed += r.empty() ? 0 : 1;

  // Gather (MPI) on rank 0, in sample order.
  Table t;
  t.header = header;
  t.rows = done;
  for (std::size_t i = 0; i < todo.size(); ++i)
    if (!rows[i].empty()) t.rows[todo[i]] = rows[i];
  if (opt.comm && size > 1 && !gather_rows(*opt.comm, rank, rows, t, rep)) return rep;
  const std::string journal_error = journal ? journal->error() : std::string();
  journal.reset();
  rep.complete = static_cast<long>(t.rows.size()) == rep.samples && journal_error.empty();
  if (!journal_error.empty()) rep.failures.push_back("journal: " + journal_error);
  write_outputs(*out, sw, t, &opt, rep.complete, rep, opt.cancel);
  rep.wall_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return rep;
}

SweepReport merge_sweep(const Sweep& sw, const std::vector<std::filesystem::path>& dirs,
                        const std::filesystem::path& out_dir) {
  const auto start = std::chrono::steady_clock::now();
  const Scenario base = load_scenario_text(sw.base_text, sw.base_path, LoadOptions{false});
  const auto header = sweep_header(sw, base);
  Table t;
  t.header = header;
  int shards = -1;
  std::set<int> seen;
  for (const auto& d : dirs) {
    const auto where = printable((d / kSummary).string());
    nlohmann::json j;
    try {
      j = nlohmann::json::parse(read_text(d / kSummary, "shard summary"));
    } catch (const nlohmann::json::exception& e) {
      throw ScenarioError(where + ": not a sweep summary: " + e.what());
    }
    if (j.value(nlohmann::json::json_pointer("/sweep/hash_fnv1a64"), std::string()) != sw.hash)
      throw ScenarioError(where + ": from another sweep (or another version of it)");
    if (!j.value("complete", false)) throw ScenarioError(where + ": the shard is incomplete");
    const std::string sh = j.value("shard", std::string("0/1"));
    int i = 0, n = 0;
    if (std::sscanf(sh.c_str(), "%d/%d", &i, &n) != 2) throw ScenarioError(where + ": bad shard");
    if (shards >= 0 && n != shards) throw ScenarioError(where + ": shards of different splits");
    shards = n;
    if (!seen.insert(i).second) throw ScenarioError(where + ": shard " + sh + " given twice");
    const std::string text = read_text(d / kTable, "shard table");
    std::istringstream is(text);
    std::string line;
    std::getline(is, line);
    if (line != header_line(header))
      throw ScenarioError(printable((d / kTable).string()) + ": another header");
    while (std::getline(is, line)) {
      const long k = std::strtol(line.c_str(), nullptr, 10);
      if (k % n != i)
        throw ScenarioError(printable((d / kTable).string()) + ": a row of another shard");
      t.rows[k] = line;
    }
  }
  if (shards < 0 || static_cast<int>(seen.size()) != shards)
    throw ScenarioError(
        fmt::format("merge: {} of {} shards given", seen.size(), std::max(shards, 0)));
  SweepReport rep;
  rep.samples = sw.samples;
  rep.resumed = static_cast<long>(t.rows.size());
  rep.complete = static_cast<long>(t.rows.size()) == sw.samples;
  if (!rep.complete) throw ScenarioError("merge: the shards do not hold every sample");
  OutputDir out(out_dir);
  write_outputs(out, sw, t, nullptr, true, rep, nullptr);
  rep.wall_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return rep;
}

void print_sweep_report(std::ostream& os, const Sweep& sw, const SweepReport& rep) {
  os << fmt::format("ukdyn {}: sweep '{}' ({}), base {}\n", version(), printable(sw.name),
                    printable(sw.path.string()), printable(sw.base_path.string()));
  os << fmt::format("  samples             {} ({} computed, {} from the journal), {} failed\n",
                    rep.samples, rep.computed, rep.resumed, rep.failed);
  os << fmt::format("  wall time           {:.3f} s\n", rep.wall_seconds);
  if (!rep.table.empty())
    os << fmt::format("  outputs             {}\n", printable(rep.table.string()));
  if (!rep.summary.empty())
    os << fmt::format("                      {}\n", printable(rep.summary.string()));
  if (!rep.figures.empty())
    os << fmt::format("                      {} figures in {}\n", rep.figures.size(),
                      printable((rep.table.parent_path() / "figures").string()));
  const std::size_t shown = std::min<std::size_t>(rep.failures.size(), 10);
  for (std::size_t i = 0; i < shown; ++i) os << "  failed: " << printable(rep.failures[i]) << "\n";
  if (rep.failures.size() > shown)
    os << fmt::format("  ... and {} more failed samples (summary.json)\n",
                      rep.failures.size() - shown);
  if (!rep.figure_error.empty()) os << "  figures: " << printable(rep.figure_error) << "\n";
}

}  // namespace ukdyn
