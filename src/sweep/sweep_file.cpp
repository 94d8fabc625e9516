// The sweep file (docs/sweeps.md): load_sweep() reads and checks it against its base scenario.
#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <iterator>
#include <limits>
#include <optional>
#include <set>
#include <utility>

#include "core/fnv1a.hpp"
#include "run/run_observer.hpp"
#include "scenario/yaml_loader.hpp"
#include "scenario/yaml_paths.hpp"
#include "sweep/sampling.hpp"
#include "sweep/scenario_tree.hpp"
#include "ukdyn/output/control_output.hpp"
#include "ukdyn/run/run.hpp"
#include "ukdyn/scenario/scenario_file.hpp"
#include "ukdyn/sweep/sweep.hpp"
#include "ukdyn/text/safe_text.hpp"

namespace ukdyn {

namespace {

using io_detail::find_number;
using io_detail::Loader;
using io_detail::Node;
using sweep_detail::clone;
using sweep_detail::kPlantPrefix;
using sweep_detail::normal_cdf;
using sweep_detail::plant_path;
using sweep_detail::plant_tree;
using sweep_detail::read_text;

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
    if (!find_number(copy, rest, why)) L.fail(e, "'" + path + "': in the plant: " + why);
    return;
  }
  YAML::Node copy = clone(doc);
  if (!find_number(copy, path, why)) L.fail(e, "'" + path + "': " + why);
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

// The metrics named by a word, each a flag of SweepMetrics.
constexpr std::pair<const char*, bool SweepMetrics::*> kMetricFlags[] = {
    {"max_residual", &SweepMetrics::max_residual},
    {"energy_drift", &SweepMetrics::energy_drift},
    {"energy_balance_drift", &SweepMetrics::energy_balance_drift},
    {"max_abs_Qc", &SweepMetrics::max_abs_qc},
    {"final_state", &SweepMetrics::final_state},
    {"control", &SweepMetrics::control},
    {"squeeze_force", &SweepMetrics::squeeze}};

void load_metrics(const Loader& L, const Node& m, SweepMetrics& mx) {
  if (!m.node.IsSequence()) L.fail(m, "expected a list of metrics");
  mx.max_residual = false;
  std::set<std::string> seen;
  for (std::size_t i = 0; i < m.node.size(); ++i) {
    const Node e{m.node[i], m.key + "[" + std::to_string(i) + "]"};
    if (e.node.IsScalar()) {
      const std::string s = e.node.Scalar();
      if (!seen.insert(s).second) L.fail(e, "duplicate metric '" + s + "'");
      const auto* flag = std::find_if(std::begin(kMetricFlags), std::end(kMetricFlags),
                                      [&s](const auto& f) { return s == f.first; });
      if (flag != std::end(kMetricFlags)) {
        mx.*(flag->second) = true;
      } else {
        L.fail(e, "unknown metric '" + s +
                      "' (expected max_residual, energy_drift, energy_balance_drift, "
                      "max_abs_Qc, final_state, control, squeeze_force, {column: NAME, stats: "
                      "[min, max, rms, max_abs, final]} or {norm: [COLUMN, ...], name: NAME, "
                      "stats: [...]})");
      }
      continue;
    }
    L.only_keys(e, {"column", "norm", "name", "stats"});
    ColumnMetric c;
    const Node col = L.child(e, "column", false), nm = L.child(e, "norm", false);
    if (col.node.IsDefined() == nm.node.IsDefined())
      L.fail(e, "a column metric takes either column: NAME or norm: [COLUMN, ...] with name: NAME");
    if (col.node.IsDefined()) {
      if (L.child(e, "name", false).node.IsDefined())
        L.fail(L.child(e, "name", false),
               "name: goes with norm: (a column metric is named by its column)");
      c.column = L.string(col);
    } else {
      if (!nm.node.IsSequence() || nm.node.size() == 0) L.fail(nm, "expected a list of columns");
      for (std::size_t k = 0; k < nm.node.size(); ++k)
        c.norm.push_back(L.string(Node{nm.node[k], nm.key + "[" + std::to_string(k) + "]"}));
      c.column = L.name(L.child(e, "name", true));
    }
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
  return io_detail::parse_scenario_yaml(text, path);  // syntax, depth, aliases expanded
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
    *t.doc = clone(io_detail::parse_scenario_yaml(sw.base_text, sw.base_path));
  } catch (const ScenarioError& e) {
    L.fail(bn, std::string("the base scenario: ") + e.what());
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
  std::vector<std::string> h;
  // A sweep runs no shadow per sample (docs/accuracy.md): refused rather than silently left out.
  if (base.error_estimate)
    L.fail(bn,
           "the base scenario asks for simulation.error_estimate: shadow, which a sweep does not "
           "run per sample (extract a sample with --extract N and run it with ukdyn simulate)");
  if (!base.control) {  // as trajectory.csv of `ukdyn simulate`
    const ConstraintForceColumns forces(base);
    return io_detail::run_csv_header(*base.system, base.sim.energy_balance, &forces,
                                     ControlColumns(base, nullptr));
  }
  {
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

// Every column a column metric names (column:, the entries of norm:) must be one of the run's
// columns `h`; the error names the metric's own line and key.
void check_metric_columns(const Loader& L, const Node& m, const std::vector<std::string>& h) {
  if (!m.node.IsDefined()) return;
  const auto check = [&](const Node& n) {
    const std::string c = L.string(n);
    if (std::find(h.begin(), h.end(), c) != h.end()) return;
    std::string near;  // the columns of the same family (up to the first '_'), a few of them
    const std::string family = c.substr(0, c.find('_') + 1);
    int shown = 0;
    for (const auto& x : h) {
      if (x.rfind(family, 0) != 0 || family.size() < 2) continue;
      if (shown++ < 8) near += (near.empty() ? "" : ", ") + x;
    }
    L.fail(n, "no column named '" + c + "' in the base scenario's trajectory.csv" +
                  (near.empty() ? std::string(" (docs/sweeps.md lists the column families)")
                                : " (columns like it: " + near + (shown > 8 ? ", ..." : "") + ")"));
  };
  for (std::size_t i = 0; i < m.node.size(); ++i) {
    const Node e{m.node[i], m.key + "[" + std::to_string(i) + "]"};
    if (!e.node.IsMap()) continue;
    if (const Node c = L.child(e, "column", false); c.node.IsDefined()) check(c);
    if (const Node n = L.child(e, "norm", false); n.node.IsDefined())
      for (std::size_t k = 0; k < n.node.size(); ++k)
        check(Node{n.node[k], n.key + "[" + std::to_string(k) + "]"});
  }
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
  check_metric_columns(L, L.child(root, "metrics", false), h);
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
  sw.hash = detail::Fnv1a64(detail::kUkdynHashBasis)
                .add(version())
                .add("\n")
                .add(text)
                .add("\n")
                .add(sw.base_text)
                .hex();

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

}  // namespace ukdyn
