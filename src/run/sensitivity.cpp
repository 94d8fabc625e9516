// Sensitivities to the numbers of a scenario file (ukdyn/run/sensitivity.hpp,
// docs/derivatives.md, "Sensitivities to parameters").
#include "ukdyn/run/sensitivity.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <boost/numeric/odeint.hpp>
#include <cmath>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <ostream>
#include <utility>

#include "run/richardson.hpp"
#include "scenario/yaml_loader.hpp"
#include "scenario/yaml_paths.hpp"
#include "ukdyn/output/control_output.hpp"
#include "ukdyn/output/csv_writer.hpp"
#include "ukdyn/output/output_dir.hpp"
#include "ukdyn/run/closed_loop_derivatives.hpp"
#include "ukdyn/scenario/scenario_file.hpp"
#include "ukdyn/text/safe_text.hpp"

namespace ukdyn {

namespace {

bool plain_name(const std::string& s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_';
  });
}

// Every `parameters.KEY` / `params.KEY` scalar under n (the document passed the loader's size and
// depth limits, io_detail::kMaxYamlDepth, so the recursion is bounded).
void find_parameter_keys(const YAML::Node& n, const std::string& at, const std::string& key,
                         std::vector<std::string>& hits, std::size_t depth) {
  if (depth > io_detail::kMaxYamlDepth) return;
  if (n.IsMap()) {
    for (const auto& kv : n) {
      if (!kv.first.IsScalar()) continue;
      const std::string k = kv.first.Scalar();
      const std::string here = at.empty() ? k : at + "." + k;
      if ((k == "parameters" || k == "params") && kv.second.IsMap()) {
        const YAML::Node& m = kv.second;
        if (const YAML::Node v = m[key]; v && v.IsScalar()) hits.push_back(here + "." + key);
      }
      find_parameter_keys(kv.second, here, key, hits, depth + 1);
    }
  } else if (n.IsSequence()) {
    // An element is [name] when its name is plain and its own in the list (a path's [name] takes
    // the first element of that name), else [index].
    auto name_of = [](const YAML::Node& e) {
      return e.IsMap() && e["name"] && e["name"].IsScalar() && plain_name(e["name"].Scalar())
                 ? e["name"].Scalar()
                 : std::string();
    };
    std::map<std::string, int> count;
    for (const auto& e : n) ++count[name_of(e)];
    std::size_t i = 0;
    for (const auto& e : n) {
      const std::string nm = name_of(e);
      const std::string sel =
          !nm.empty() && count[nm] == 1 ? "[" + nm + "]" : "[" + std::to_string(i) + "]";
      find_parameter_keys(e, at + sel, key, hits, depth + 1);
      ++i;
    }
  }
}

// The error for parameter p: at the scenario file (and the line of its number, when known), or at
// the entry of outputs.sensitivities that asked for it.
[[noreturn]] void refuse(const Scenario& sc, const ScenarioParameter& p, const std::string& why) {
  const std::string line = p.line > 0 ? std::to_string(p.line) : std::string();
  const std::string where =
      !p.asked_at.empty()
          ? p.asked_at + ": parameter '" + p.name + "'" +
                (line.empty() ? "" : " (its number at line " + line + ")")
          : sc.path.string() + (line.empty() ? "" : ":" + line) + ": parameter '" + p.name + "'";
  throw ScenarioError(escape_controls(where + ": " + why));
}

// The paths of `name` in doc and its value and line: a path, or a key of parameters / params maps.
void locate(const Scenario& sc, const YAML::Node& doc, ScenarioParameter& p) {
  const std::string& name = p.name;
  std::string why;
  if (name.find_first_of(".[") == std::string::npos) {
    std::vector<std::string> hits;
    find_parameter_keys(doc, "", name, hits, 0);
    // Every place holding the same number (an alias's repetitions, or the same value written in
    // the maps of several blocks, such as a length a body and a constraint share) is the
    // parameter; places with different numbers make the name ambiguous.
    auto number = [&](const std::string& path) {
      const std::string text = io_detail::find_scalar(doc, path, why)->Scalar();
      double v = 0.0;
      return io_detail::Loader::parse_number(text, v) ? fmt::format("{}", v) : text;
    };
    for (const auto& h : hits) {
      if (number(h) != number(hits.front())) {
        std::string list;
        for (const auto& g : hits) list += (list.empty() ? "" : ", ") + g;
        refuse(sc, p, "names different numbers of the file (" + list + "): give the path of one");
      }
      p.paths.push_back(h);
    }
  }
  if (p.paths.empty()) p.paths.push_back(name);  // a path, or a top-level key such as gravity
  const auto node = io_detail::find_number(doc, p.paths.front(), why);
  if (!node) {
    refuse(sc, p,
           (p.paths.front() == name && name.find_first_of(".[") == std::string::npos
                ? "no key '" + name + "' in a parameters: or params: map of the file, and " + why
                : why) +
               " (docs/derivatives.md, \"Sensitivities to parameters\")");
  }
  p.line = node->Mark().line + 1;
  if (!io_detail::Loader::parse_number(node->Scalar(), p.value) || !std::isfinite(p.value))
    refuse(sc, p, "not a finite number");
  p.step = 1e-3 * (p.value != 0.0 ? std::abs(p.value) : 1.0);
}

constexpr std::array<double, 4> kOffsets = {1.0, -1.0, 0.5, -0.5};  // × h

// The scenario re-loaded with each perturbed value.
void reload(const Scenario& sc, const YAML::Node& doc, ScenarioParameter& p) {
  LoadOptions opt;
  opt.check_initial = false;
  for (std::size_t k = 0; k < kOffsets.size(); ++k) {
    YAML::Node copy = io_detail::clone_yaml(doc);
    std::string why;
    for (const auto& path : p.paths) {
      auto node = io_detail::find_number(copy, path, why);
      if (!node) refuse(sc, p, why);
      *node = fmt::format("{}", p.value + kOffsets[k] * p.step);
    }
    std::shared_ptr<Scenario> s;
    try {
      s = std::make_shared<Scenario>(io_detail::load_scenario_yaml(copy, sc.hash, sc.path, opt));
    } catch (const ScenarioError& e) {
      // The file loads as written but not with this number moved by a step (a format version, a
      // count, a number the loader requires exactly): not a parameter of the dynamics.
      refuse(sc, p,
             fmt::format("the file does not load with it changed to {}: {}",
                         p.value + kOffsets[k] * p.step, e.what()));
    }
    if (s->system->dof() != sc.system->dof() || s->system->rows() != sc.system->rows())
      refuse(sc, p, "changes the number of coordinates or constraint rows");
    p.perturbed[k] = std::move(s);
  }
}

// The model derivatives with the forward data of the perturbed systems kept in `data` (4 per
// parameter, built on first use).
std::vector<ModelParameterDerivative> model_derivatives(
    const Scenario& sc, const std::vector<ScenarioParameter>& ps,
    std::vector<std::unique_ptr<ForwardData>>& data, double t, CVecRef q, CVecRef qd, CVecRef tau) {
  std::vector<ModelParameterDerivative> out;
  out.reserve(ps.size());
  if (data.size() != 4 * ps.size()) {
    data.clear();
    for (const auto& p : ps)
      for (const auto& s : p.perturbed) data.push_back(std::make_unique<ForwardData>(*s->system));
  }
  for (std::size_t j = 0; j < ps.size(); ++j) {
    std::array<ForwardData*, 4> d{};
    for (std::size_t k = 0; k < 4; ++k) {
      const Scenario& s = *ps[j].perturbed[k];
      d[k] = data[4 * j + k].get();
      const Vec tau_k = tau + (s.tau - sc.tau);
      forward(*s.system, *d[k], t, q, qd, tau_k, s.sim.uk);
    }
    const double h = ps[j].step;
    ModelParameterDerivative m;
    m.dM = richardson(d[0]->M, d[1]->M, d[2]->M, d[3]->M, h);
    m.dQ = richardson(d[0]->Q, d[1]->Q, d[2]->Q, d[3]->Q, h);
    m.dA = richardson(d[0]->A, d[1]->A, d[2]->A, d[3]->A, h);
    m.db = richardson(d[0]->b, d[1]->b, d[2]->b, d[3]->b, h);
    out.push_back(std::move(m));
  }
  return out;
}

bool all_zero(const ModelParameterDerivative& m) {
  return m.dM.isZero(0.0) && m.dQ.isZero(0.0) && m.dA.isZero(0.0) && m.db.isZero(0.0);
}

// The closed loops of a control scenario re-loaded with each perturbed value (4 per parameter, in
// the order of ScenarioParameter::perturbed). A perturbed start that violates the plant's
// physical rows refuses the parameter by name.
std::vector<std::unique_ptr<ControlRun>> perturbed_control_runs(
    const Scenario& sc, const std::vector<ScenarioParameter>& ps) {
  std::vector<std::unique_ptr<ControlRun>> runs;
  for (const auto& p : ps) {
    for (const auto& s : p.perturbed) {
      try {
        runs.push_back(make_control_run(*s));
      } catch (const Error& e) {
        refuse(sc, p, std::string("the closed loop does not start with it changed: ") + e.what());
      }
    }
  }
  return runs;
}

// A control scenario: the law's tau (the closed loop at the state, τ_plant + B sat(u) + τ_d) and
// its u before saturation at the start and two states near it, and the start itself (the offset
// start), compared bit for bit.
void control_used(const Scenario& sc, const std::vector<ScenarioParameter>& ps,
                  std::vector<bool>& used) {
  const auto nominal = make_control_run(sc);
  const auto runs = perturbed_control_runs(sc, ps);
  const Index n = nominal->plant->dof();
  Vec tau(n), tau_k(n);
  for (int s = 0; s < 3; ++s) {
    Vec q = nominal->q0, qd = nominal->qd0;
    for (Index i = 0; i < n && s > 0; ++i) {
      q(i) += 0.01 * s * std::sin(1.0 + static_cast<double>(i));
      qd(i) += 0.1 * s * std::cos(2.0 + static_cast<double>(i));
    }
    const double t = sc.sim.t0 + 0.1 * s * (sc.sim.t_end - sc.sim.t0);
    nominal->loop->evaluate(t, q, qd);
    nominal->loop->plant_tau(tau);
    for (std::size_t j = 0; j < ps.size(); ++j) {
      for (std::size_t k = 0; k < 4; ++k) {
        ControlRun& r = *runs[4 * j + k];
        r.loop->evaluate(t, q, qd);
        r.loop->plant_tau(tau_k);
        // u before saturation too: a gain of a law clipped at these states is still used
        used[j] = used[j] || tau_k != tau || r.loop->u_raw != nominal->loop->u_raw ||
                  r.q0 != nominal->q0 || r.qd0 != nominal->qd0;
      }
    }
  }
}

// A parameter that changes none of M, Q, A, b (at the initial state and two states near it) nor
// the initial state (nor, in a control scenario, the law's tau and the start) is not used by the
// dynamics: refused by name.
void check_used(const Scenario& sc, const std::vector<ScenarioParameter>& ps) {
  const Index n = sc.system->dof();
  Mat dq0, dqd0;
  initial_state_derivatives(sc, ps, dq0, dqd0);
  std::vector<bool> used(ps.size(), false);
  for (std::size_t j = 0; j < ps.size(); ++j)
    used[j] =
        !dq0.col(static_cast<Index>(j)).isZero(0.0) || !dqd0.col(static_cast<Index>(j)).isZero(0.0);
  std::vector<std::unique_ptr<ForwardData>> data;
  for (int s = 0; s < 3; ++s) {
    Vec q = sc.q0, qd = sc.qd0;
    for (Index i = 0; i < n && s > 0; ++i) {
      q(i) += 0.01 * s * std::sin(1.0 + static_cast<double>(i));
      qd(i) += 0.1 * s * std::cos(2.0 + static_cast<double>(i));
    }
    const double t = sc.sim.t0 + 0.1 * s * (sc.sim.t_end - sc.sim.t0);
    const auto md = model_derivatives(sc, ps, data, t, q, qd, sc.tau);
    for (std::size_t j = 0; j < ps.size(); ++j) used[j] = used[j] || !all_zero(md[j]);
  }
  if (sc.control) control_used(sc, ps, used);
  for (std::size_t j = 0; j < ps.size(); ++j) {
    if (!used[j]) {
      refuse(sc, ps[j],
             sc.control ? "the scenario's dynamics does not use it (it changes none of M, Q, A, b, "
                          "the control law's tau and the initial state; the run's settings are "
                          "not differentiated)"
                        : "the scenario's dynamics does not use it (it changes none of M, Q, A, b "
                          "and the initial state; the run's settings are not differentiated)");
    }
  }
}

}  // namespace

namespace {

// The scenario's file as a YAML document: the text it was loaded from (its hash checked), since
// the parameters are found, and the model re-loaded, there.
YAML::Node scenario_document(const Scenario& sc) {
  if (!sc.system) throw Error("sensitivities: the scenario has no system");
  const std::string text = read_scenario_text(sc.path);
  if (scenario_text_hash(text) != sc.hash) {
    throw ScenarioError(escape_controls(
        sc.path.string() +
        ": the file changed since the scenario was loaded (or it was loaded from other text): "
        "its parameters are read from the file, load it again"));
  }
  return io_detail::parse_scenario_yaml(text, sc.path);
}

// A place of `b` that is also one of `a` (the same node of `expanded`, the document with its
// aliases copied as reload() writes them, however the two paths spell it: `subsystems[0]` and
// `subsystems[left]`, a key and its path), or empty.
std::string shared_place(const YAML::Node& expanded, const ScenarioParameter& a,
                         const ScenarioParameter& b) {
  std::string why;
  for (const auto& pa : a.paths) {
    const auto na = io_detail::find_scalar(expanded, pa, why);
    for (const auto& pb : b.paths) {
      const auto nb = io_detail::find_scalar(expanded, pb, why);
      if (na && nb && na->is(*nb)) return pb;
    }
  }
  return {};
}

// The parameters `asked` (name and asked_at set) of the scenario, resolved in its document.
std::vector<ScenarioParameter> resolve(const Scenario& sc, const YAML::Node& doc,
                                       std::vector<ScenarioParameter> asked) {
  const YAML::Node expanded = io_detail::clone_yaml(doc);
  for (std::size_t i = 0; i < asked.size(); ++i) {
    ScenarioParameter& p = asked[i];
    if (!io_detail::parameter_name_ok(p.name)) {
      // A name given on the command line has not passed the loader's check: not quoted whole
      // (it may be megabytes long).
      ScenarioParameter shown = p;
      if (shown.name.size() > 40) shown.name = shown.name.substr(0, 40) + "...";
      refuse(sc, shown, io_detail::kParameterNameRule);
    }
    for (std::size_t k = 0; k < i; ++k)
      if (asked[k].name == p.name) refuse(sc, p, "named twice");
    locate(sc, doc, p);
    for (std::size_t k = 0; k < i; ++k) {
      if (const std::string at = shared_place(expanded, asked[k], p); !at.empty())
        refuse(sc, p,
               "names the number at '" + at + "', as parameter '" + asked[k].name +
                   "' does: a parameter named twice");
    }
    reload(sc, doc, p);
  }
  check_used(sc, asked);
  return asked;
}

}  // namespace

std::vector<ScenarioParameter> scenario_parameters(const Scenario& sc,
                                                   const std::vector<std::string>& names) {
  const YAML::Node doc = scenario_document(sc);
  std::vector<ScenarioParameter> asked(names.size());
  for (std::size_t i = 0; i < names.size(); ++i) asked[i].name = names[i];
  return resolve(sc, doc, std::move(asked));
}

std::vector<ScenarioParameter> requested_parameters(const Scenario& sc) {
  const YAML::Node doc = scenario_document(sc);
  const YAML::Node outputs = doc["outputs"];
  if (!outputs || !outputs.IsMap() || !outputs["sensitivities"]) return {};
  const YAML::Node list = outputs["sensitivities"];  // its form checked by the loader
  std::vector<ScenarioParameter> asked(list.size());
  for (std::size_t i = 0; i < list.size(); ++i) {
    const YAML::Mark m = list[i].Mark();
    asked[i].name = list[i].Scalar();
    asked[i].asked_at = fmt::format("{}:{}:{}: key 'outputs.sensitivities[{}]'", sc.path.string(),
                                    m.line + 1, m.column + 1, i);
  }
  return resolve(sc, doc, std::move(asked));
}

std::vector<ModelParameterDerivative> model_parameter_derivatives(
    const Scenario& sc, const std::vector<ScenarioParameter>& ps, double t, CVecRef q, CVecRef qd,
    CVecRef tau) {
  std::vector<std::unique_ptr<ForwardData>> data;
  return model_derivatives(sc, ps, data, t, q, qd, tau);
}

void initial_state_derivatives(const Scenario& sc, const std::vector<ScenarioParameter>& ps,
                               Mat& dq0, Mat& dqd0) {
  const Index n = sc.system->dof(), P = static_cast<Index>(ps.size());
  dq0.resize(n, P);
  dqd0.resize(n, P);
  for (Index j = 0; j < P; ++j) {
    const auto& p = ps[static_cast<std::size_t>(j)];
    const auto& s = p.perturbed;
    dq0.col(j) = richardson(s[0]->q0, s[1]->q0, s[2]->q0, s[3]->q0, p.step);
    dqd0.col(j) = richardson(s[0]->qd0, s[1]->qd0, s[2]->qd0, s[3]->qd0, p.step);
  }
}

ParameterLinearization state_sensitivities(const Scenario& sc,
                                           const std::vector<ScenarioParameter>& ps, double t,
                                           CVecRef q, CVecRef qd, CVecRef tau, bool with_state) {
  return linearize_parameters(*sc.system, t, q, qd, tau,
                              model_parameter_derivatives(sc, ps, t, q, qd, tau), sc.sim.uk,
                              with_state);
}

namespace {

using OdeState = std::vector<double>;

// The start of both variational right-hand sides: counts the evaluation and sizes dx; false, with
// dx all NaN, when the state (q, q̇) at the head of x is not finite.
bool start_rhs(const OdeState& x, OdeState& dx, Index n, RunSensitivities& out) {
  ++out.rhs_evaluations;
  dx.resize(x.size());
  const auto end = x.begin() + 2 * n;
  if (std::all_of(x.begin(), end, [](double v) { return std::isfinite(v); })) return true;
  std::fill(dx.begin(), dx.end(), std::nan(""));
  return false;
}

// The right-hand side of x = (q, q̇) and, per parameter j, s_j = (dq/dp_j, dq̇/dp_j):
// q̈ = f(q, q̇, p) and ṡ_j = [s_q̇; ∂q̈/∂q s_q + ∂q̈/∂q̇ s_q̇ + ∂q̈/∂p_j].
struct VariationalRhs {
  const Scenario& sc;
  const std::vector<ScenarioParameter>& ps;
  std::vector<std::unique_ptr<ForwardData>> data;
  RunSensitivities& out;

  void operator()(const OdeState& x, OdeState& dx, double t) {
    const Index n = sc.system->dof();
    if (!start_rhs(x, dx, n, out)) return;
    const Eigen::Map<const Vec> q(x.data(), n), qd(x.data() + n, n);
    const auto md = model_derivatives(sc, ps, data, t, q, qd, sc.tau);
    const auto pl = linearize_parameters(*sc.system, t, q, qd, sc.tau, md, sc.sim.uk, true);
    if (!pl.lin.trusted && out.trusted) {
      out.trusted = false;
      out.message = fmt::format("at t = {:.6g}: {}", t, pl.lin.message);
    }
    Eigen::Map<Vec>(dx.data(), n) = qd;
    Eigen::Map<Vec>(dx.data() + n, n) = pl.lin.qdd;
    for (std::size_t j = 0; j < ps.size(); ++j) {
      const std::size_t o = 2 * static_cast<std::size_t>(n) * (j + 1);
      const Eigen::Map<const Vec> sq(x.data() + o, n), sqd(x.data() + o + n, n);
      Eigen::Map<Vec>(dx.data() + o, n) = sqd;
      Eigen::Map<Vec>(dx.data() + o + n, n) =
          pl.lin.dqdd_dq * sq + pl.lin.dqdd_dqd * sqd + pl.dqdd_dp.col(static_cast<Index>(j));
    }
  }
};

// RunSensitivities::warnings: the parameters whose perturbed scenarios' initial states are off
// their constraints (Richardson derivatives of Φ and Φ̇ at each perturbed scenario's own q0, q̇0).
void initial_constraint_warnings(const Scenario& sc, const std::vector<ScenarioParameter>& ps,
                                 RunSensitivities& rs) {
  const Index m = sc.system->rows();
  if (m == 0) return;
  for (const auto& p : ps) {
    std::array<Vec, 4> phi, phid;
    for (std::size_t k = 0; k < 4; ++k) {
      const Scenario& s = *p.perturbed[k];
      phi[k].resize(m);
      phid[k].resize(m);
      position_residuals(*s.system, s.sim.t0, s.q0, phi[k]);
      velocity_residuals(*s.system, s.sim.t0, s.q0, s.qd0, phid[k]);
    }
    const double dphi = richardson(phi[0], phi[1], phi[2], phi[3], p.step).cwiseAbs().maxCoeff();
    const double dphid =
        richardson(phid[0], phid[1], phid[2], phid[3], p.step).cwiseAbs().maxCoeff();
    if (dphi > 1e-8 || dphid > 1e-8) {
      rs.warnings.push_back(fmt::format(
          "parameter '{}' moves the constraints away from the initial state (max |dPhi/dp| = "
          "{:.3g}, max |dPhidot/dp| = {:.3g}): its perturbed runs start off the constraints, so "
          "dq/dp is that of the motion from the file's q0, qd0 (write initial.q with the "
          "parameter to move q0 with it)",
          p.name, dphi, dphid));
    }
  }
}

}  // namespace

namespace {

// The right-hand side of a control scenario's closed loop (docs/derivatives.md, "Controlled
// runs"): x = (q, q̇) of the plant under τ(t, q, q̇) of the law, and per parameter
// ṡ_j = [s_q̇; ∂q̈/∂q s_q + ∂q̈/∂q̇ s_q̇ + ∂q̈/∂τ (∂τ/∂x s_j) + ∂q̈/∂p_j], ∂q̈/∂(q, q̇, τ) the
// plant's exact ones; ∂τ/∂x the law's exact one (law_jacobian(): one per right-hand side, shared
// by every parameter), or where it has none (a kink, law_jacobian_gap()) Richardson differences of
// the law along s_j (4 evaluations per parameter); ∂q̈/∂p_j Richardson differences of the closed
// loops re-loaded with p ± h, p ± h/2.
struct ClosedLoopVariationalRhs {
  const Scenario& sc;
  const std::vector<ScenarioParameter>& ps;
  ControlRun& run;
  std::vector<std::unique_ptr<ControlRun>> perturbed;  // 4 per parameter
  std::vector<std::unique_ptr<ForwardData>> data;      // their plants' forward data
  RunSensitivities& out;
  std::vector<std::string> kinks;  // the causes met so far, and the first time of each
  std::vector<double> kink_t;
  long kink_evaluations = 0;
  std::optional<LawJacobianWorkspace>
      ws;           // the law's exact ∂τ/∂x, when law_jacobian_gap() is empty
  std::string gap;  // law_jacobian_gap(), or the first state's why_not
  Mat dtau_dq, dtau_dqd;
  long exact_rhs = 0, difference_rhs = 0;

  void operator()(const OdeState& x, OdeState& dx, double t) {
    const Index n = run.plant->dof();
    if (!start_rhs(x, dx, n, out)) return;
    const Eigen::Map<const Vec> q(x.data(), n), qd(x.data() + n, n);
    Vec tau(n), tau_k(n);
    const bool exact = ws && law_jacobian(run, *ws, t, q, qd, dtau_dq, dtau_dqd);  // loop at x
    if (!ws) run.loop->evaluate(t, q, qd);
    if (ws && !exact && gap.empty()) gap = fmt::format("at t = {:.6g}: {}", t, ws->why_not);
    ++(exact ? exact_rhs : difference_rhs);
    run.loop->plant_tau(tau);
    const Linearization lin = linearize(*run.plant, t, q, qd, tau, sc.sim.uk);
    if (!lin.trusted && out.trusted) {
      out.trusted = false;
      out.message = fmt::format("at t = {:.6g}: {}", t, lin.message);
    }
    Eigen::Map<Vec>(dx.data(), n) = qd;
    Eigen::Map<Vec>(dx.data() + n, n) = lin.qdd;
    for (std::size_t j = 0; j < ps.size(); ++j) {
      const std::size_t o = 2 * static_cast<std::size_t>(n) * (j + 1);
      const Eigen::Map<const Vec> sq(x.data() + o, n), sqd(x.data() + o + n, n);
      Vec dtau;
      if (exact) {
        dtau.noalias() = dtau_dq * sq + dtau_dqd * sqd;
      } else {
        std::vector<std::string> found;
        dtau = law_direction(run, t, q, qd, sq, sqd, found);
        note_kinks(found, t);
      }
      std::array<Vec, 4> qdd;
      for (std::size_t k = 0; k < 4; ++k) {
        ControlRun& r = *perturbed[4 * j + k];
        r.loop->evaluate(t, q, qd);
        r.loop->plant_tau(tau_k);
        forward(*r.plant, *data[4 * j + k], t, q, qd, tau_k, ps[j].perturbed[k]->sim.uk);
        qdd[k] = data[4 * j + k]->qdd;
      }
      Eigen::Map<Vec>(dx.data() + o, n) = sqd;
      Eigen::Map<Vec>(dx.data() + o + n, n) =
          lin.dqdd_dq * sq + lin.dqdd_dqd * sqd + lin.dqdd_dtau * dtau +
          richardson(qdd[0], qdd[1], qdd[2], qdd[3], ps[j].step);
    }
  }

  void note_kinks(const std::vector<std::string>& found, double t) {
    if (!found.empty()) ++kink_evaluations;
    for (const auto& f : found) {
      if (std::find(kinks.begin(), kinks.end(), f) != kinks.end()) continue;
      kinks.push_back(f);
      kink_t.push_back(t);
    }
  }

  // RunSensitivities::law_derivative: how many right-hand sides took the exact ∂τ/∂x.
  [[nodiscard]] std::string law_derivative() const {
    const long all = exact_rhs + difference_rhs;
    if (difference_rhs == 0) return fmt::format("exact at {} of {} right-hand sides", all, all);
    return fmt::format(
        "exact at {} of {} right-hand sides, directional differences of the law at {} ({})",
        exact_rhs, all, difference_rhs, gap);
  }

  // RunSensitivities::warnings: each cause of a kink the law's differences met, first time.
  void report_kinks() const {
    const std::string law = to_string(run.law->settings().kind);
    for (std::size_t i = 0; i < kinks.size(); ++i) {
      out.warnings.push_back(fmt::format(
          "the {} control law is not differentiable at t = {:.6g} ({}; {} evaluations of the "
          "run's right-hand side in all met a kink): there its derivative is a difference across "
          "the kink; dq/dp stays continuous through a crossing, but a motion that stays on the "
          "kink (sliding along it) is not covered",
          law, kink_t[i], kinks[i], kink_evaluations));
    }
  }
};

// x0 = (q0, q̇0) and s_j(t0) = d(q0, q̇0)/dp_j, integrated by `rhs` into rs at the samples.
// Thrown from the right-hand side when the caller's cancel flag is set (run_sensitivities).
struct Interrupted {
  double t;
};

template <typename Rhs>
void integrate_variational(const Scenario& sc, CVecRef q0, CVecRef qd0, const Mat& dq0,
                           const Mat& dqd0, Rhs& rhs, RunSensitivities& rs,
                           const std::atomic<bool>* cancel) {
  namespace odeint = boost::numeric::odeint;
  const Index n = q0.size();
  const std::size_t P = static_cast<std::size_t>(dq0.cols()), un = static_cast<std::size_t>(n);
  OdeState x(2 * un * (P + 1));
  Eigen::Map<Vec>(x.data(), n) = q0;
  Eigen::Map<Vec>(x.data() + n, n) = qd0;
  for (std::size_t j = 0; j < P; ++j) {
    Eigen::Map<Vec>(x.data() + 2 * un * (j + 1), n) = dq0.col(static_cast<Index>(j));
    Eigen::Map<Vec>(x.data() + 2 * un * (j + 1) + un, n) = dqd0.col(static_cast<Index>(j));
  }
  const auto& sim = sc.sim;
  std::vector<double> times;
  const auto samples = static_cast<long>(std::floor((sim.t_end - sim.t0) / sim.sample_dt + 1e-9));
  for (long k = 0; k <= samples; ++k)
    times.push_back(sim.t0 + static_cast<double>(k) * sim.sample_dt);
  if (times.back() < sim.t_end - 1e-12 * std::max(1.0, std::abs(sim.t_end)))
    times.push_back(sim.t_end);
  std::vector<OdeState> xs;
  auto observe = [&](const OdeState& xk, double tk) {
    rs.t.push_back(tk);
    xs.push_back(xk);
  };
  auto stepper =
      odeint::make_dense_output(sim.abs_tol, sim.rel_tol, odeint::runge_kutta_dopri5<OdeState>());
  try {
    rs.steps = static_cast<long>(odeint::integrate_times(
        stepper,
        [&rhs, cancel](const OdeState& xs_, OdeState& dx, double t) {
          if (cancel != nullptr && cancel->load(std::memory_order_relaxed)) throw Interrupted{t};
          rhs(xs_, dx, t);
        },
        x, times.begin(), times.end(), std::min(sim.step, sim.sample_dt), observe,
        odeint::max_step_checker(100000)));
  } catch (const odeint::step_adjustment_error& e) {
    rs.trusted = false;
    rs.message = std::string("the run stopped: ") + e.what();
  } catch (const odeint::no_progress_error& e) {
    rs.trusted = false;
    rs.message = std::string("the run stopped: ") + e.what();
  } catch (const Interrupted& i) {
    rs.trusted = false;
    rs.message = fmt::format("interrupted at t = {:g}: the samples before it are returned", i.t);
  }
  const Index T = static_cast<Index>(xs.size());
  rs.q.resize(T, n);
  rs.qd.resize(T, n);
  rs.dq_dp.assign(P, Mat(T, n));
  rs.dqd_dp.assign(P, Mat(T, n));
  for (Index k = 0; k < T; ++k) {
    const auto& xk = xs[static_cast<std::size_t>(k)];
    rs.q.row(k) = Eigen::Map<const Vec>(xk.data(), n).transpose();
    rs.qd.row(k) = Eigen::Map<const Vec>(xk.data() + n, n).transpose();
    for (std::size_t j = 0; j < P; ++j) {
      rs.dq_dp[j].row(k) = Eigen::Map<const Vec>(xk.data() + 2 * un * (j + 1), n).transpose();
      rs.dqd_dp[j].row(k) = Eigen::Map<const Vec>(xk.data() + 2 * un * (j + 1) + un, n).transpose();
    }
  }
  if (T == 0 ||
      !Eigen::Map<const Vec>(xs.back().data(), static_cast<Index>(x.size())).allFinite() ||
      rs.t.back() < sim.t_end - 1e-9) {
    rs.trusted = false;
    if (rs.message.empty()) rs.message = "the run did not reach t_end with a finite state";
  }
}

// The closed loop of a control scenario from its start (the offset start, ControlRun::q0):
// s(t0) the Richardson derivative of the re-loaded closed loops' starts.
void closed_loop_sensitivities(const Scenario& sc, const std::vector<ScenarioParameter>& ps,
                               RunSensitivities& rs, const std::atomic<bool>* cancel) {
  const auto run = make_control_run(sc);
  ClosedLoopVariationalRhs rhs{
      sc, ps, *run, perturbed_control_runs(sc, ps), {}, rs, {}, {}, 0, {}, {}, {}, {}, 0, 0};
  const Index n = run->plant->dof(), P = static_cast<Index>(ps.size());
  Mat dq0(n, P), dqd0(n, P);
  for (Index j = 0; j < P; ++j) {
    const auto& r = rhs.perturbed;
    const std::size_t o = 4 * static_cast<std::size_t>(j);
    const double h = ps[static_cast<std::size_t>(j)].step;
    dq0.col(j) = richardson(r[o]->q0, r[o + 1]->q0, r[o + 2]->q0, r[o + 3]->q0, h);
    dqd0.col(j) = richardson(r[o]->qd0, r[o + 1]->qd0, r[o + 2]->qd0, r[o + 3]->qd0, h);
  }
  for (const auto& r : rhs.perturbed) rhs.data.push_back(std::make_unique<ForwardData>(*r->plant));
  rhs.gap = law_jacobian_gap(*run);
  if (rhs.gap.empty()) rhs.ws.emplace(*run);
  integrate_variational(sc, run->q0, run->qd0, dq0, dqd0, rhs, rs, cancel);
  rhs.report_kinks();
  rs.law_derivative = rhs.law_derivative();
}

}  // namespace

RunSensitivities run_sensitivities(const Scenario& sc, const std::vector<ScenarioParameter>& ps,
                                   const std::atomic<bool>* cancel) {
  RunSensitivities rs;
  for (const auto& p : ps) rs.parameters.push_back(p.name);
  if (sc.control) {
    closed_loop_sensitivities(sc, ps, rs, cancel);
    return rs;
  }
  initial_constraint_warnings(sc, ps, rs);
  Mat dq0, dqd0;
  initial_state_derivatives(sc, ps, dq0, dqd0);
  VariationalRhs rhs{sc, ps, {}, rs};
  integrate_variational(sc, sc.q0, sc.qd0, dq0, dqd0, rhs, rs, cancel);
  return rs;
}

std::vector<std::string> sensitivity_columns(const Scenario& sc, const RunSensitivities& rs) {
  const auto& names = sc.system->coordinate_names();
  std::vector<std::string> h{"t"};
  for (const auto& c : names) h.push_back(c);
  for (const auto& c : names) h.push_back(c + "_dot");
  for (const auto& p : rs.parameters) {
    for (const auto& c : names) h.push_back("dq_" + c + "/d" + p);
    for (const auto& c : names) h.push_back("dqd_" + c + "/d" + p);
  }
  return h;
}

std::vector<double> sensitivity_row(const RunSensitivities& rs, Index k) {
  std::vector<double> row{rs.t[static_cast<std::size_t>(k)]};
  auto add = [&](const Mat& m) {
    for (Index i = 0; i < m.cols(); ++i) row.push_back(m(k, i));
  };
  add(rs.q);
  add(rs.qd);
  for (std::size_t j = 0; j < rs.dq_dp.size(); ++j) {
    add(rs.dq_dp[j]);
    add(rs.dqd_dp[j]);
  }
  return row;
}

bool write_run_sensitivities(const Scenario& sc, const std::vector<ScenarioParameter>& ps,
                             const std::filesystem::path& out_dir, std::ostream& report) {
  OutputDir dir(out_dir);  // refused (a root, a folder in use) before the run
  const RunSensitivities rs = run_sensitivities(sc, ps);
  CsvWriter csv(dir, "sensitivities.csv", sensitivity_columns(sc, rs));
  for (Index k = 0; k < static_cast<Index>(rs.t.size()); ++k) csv.row(sensitivity_row(rs, k));
  csv.commit();
  nlohmann::json j;
  j["file"] = (out_dir / "sensitivities.csv").string();
  j["parameters"] = rs.parameters;
  j["samples"] = rs.t.size();
  j["steps"] = rs.steps;
  j["rhs_evaluations"] = rs.rhs_evaluations;
  j["trusted"] = rs.trusted;
  j["message"] = rs.message;
  j["warnings"] = rs.warnings;
  if (!rs.law_derivative.empty()) j["law_derivative"] = rs.law_derivative;
  report << j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace) << "\n";
  return rs.trusted;
}

}  // namespace ukdyn
