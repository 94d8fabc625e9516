#include "ukdyn/run/eval_protocol.hpp"

#include <fmt/format.h>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <cctype>
#include <cmath>
#include <istream>
#include <limits>
#include <nlohmann/json.hpp>
#include <optional>
#include <ostream>

#include "core/input_file.hpp"
#include "output/csv_reader.hpp"
#include "output/npz.hpp"
#include "ukdyn/model/linearize.hpp"
#include "ukdyn/model/minimal_linearize.hpp"
#include "ukdyn/run/closed_loop_derivatives.hpp"
#include "ukdyn/run/sensitivity.hpp"
#include "ukdyn/text/safe_text.hpp"

namespace ukdyn {

namespace {

using json = nlohmann::json;

json rows_of(const Mat& M) {
  json out = json::array();
  for (Index i = 0; i < M.rows(); ++i) {
    json r = json::array();
    for (Index j = 0; j < M.cols(); ++j) r.push_back(M(i, j));
    out.push_back(r);
  }
  return out;
}

json vec_of(const Vec& v) {
  json out = json::array();
  for (Index i = 0; i < v.size(); ++i) out.push_back(v(i));
  return out;
}

bool all_finite(const Mat& m) { return m.allFinite(); }

Vec read_vec(const json& j, const char* key, Index n, bool required) {
  const auto it = j.find(key);
  if (it == j.end()) {
    if (required) throw Error(fmt::format("missing key '{}'", key));
    return Vec::Zero(n);
  }
  const json& a = *it;
  if (!a.is_array() || static_cast<Index>(a.size()) != n) {
    throw Error(fmt::format("key '{}': expected a list of {} numbers{}", key, n,
                            a.is_array() ? fmt::format(", got {}", a.size()) : ""));
  }
  Vec v(n);
  for (Index i = 0; i < n; ++i) {
    const json& e = a[static_cast<std::size_t>(i)];
    if (!e.is_number()) throw Error(fmt::format("key '{}[{}]': expected a number", key, i));
    v(i) = e.get<double>();
    if (!std::isfinite(v(i))) throw Error(fmt::format("key '{}[{}]': not finite", key, i));
  }
  return v;
}

// Reads one line (without '\n') into `line`, at most `max` bytes kept; returns false at the end.
// `too_long` is set if the line was longer (the rest of it is skipped).
bool read_line(std::istream& in, std::string& line, std::size_t max, bool& too_long) {
  line.clear();
  too_long = false;
  std::streambuf* sb = in.rdbuf();
  if (!sb) return false;
  bool any = false;
  while (true) {
    const auto c = sb->sbumpc();
    if (c == std::char_traits<char>::eof()) return any;
    any = true;
    if (c == '\n') return true;
    if (line.size() < max) {
      line.push_back(static_cast<char>(c));
    } else {
      too_long = true;
    }
  }
}

// The derivatives of one state as JSON (docs/derivatives.md, "From the command line").
json linearization_json(const System& sys, const Linearization& lin) {
  json out;
  json kept = json::array();
  for (Index r : lin.kept_rows)
    kept.push_back(sys.constraint_row_names()[static_cast<std::size_t>(r)]);
  out["trusted"] = lin.trusted;
  out["message"] = lin.message;
  out["rank"] = lin.rank;
  out["kept_rows"] = kept;
  out["kkt_agreement"] = lin.kkt_agreement;
  out["dqdd_dq"] = rows_of(lin.dqdd_dq);
  out["dqdd_dqd"] = rows_of(lin.dqdd_dqd);
  out["dqdd_dtau"] = rows_of(lin.dqdd_dtau);
  out["dQc_dq"] = rows_of(lin.dQc_dq);
  out["dQc_dqd"] = rows_of(lin.dQc_dqd);
  out["dQc_dtau"] = rows_of(lin.dQc_dtau);
  // ∂/∂t at fixed (q, q̇, τ) (docs/derivatives.md, "Time"): null, with time_message saying why,
  // when a component has no exact ∂/∂t.
  const bool timed = lin.dqdd_dt.size() == lin.qdd.size();
  out["dqdd_dt"] = timed ? vec_of(lin.dqdd_dt) : json(nullptr);
  out["dQc_dt"] = timed ? vec_of(lin.dQc_dt) : json(nullptr);
  out["time_message"] = lin.time_message;
  return out;
}

// The reduced model in minimal coordinates (docs/derivatives.md, "Minimal coordinates").
json minimal_json(const System& sys, double t, const Vec& q, const Vec& qd, const Vec& tau,
                  const Linearization& lin, double dt) {
  const MinimalModel mm = minimal_model(sys, t, q, qd, tau, lin);
  json j;
  j["basis"] =
      "N: last n-r right singular vectors of A_R, each column's largest entry positive; "
      "z = (N^T dq, N^T dqd), x = T z";
  j["dof"] = mm.N.cols();
  j["N"] = rows_of(mm.N);
  j["T"] = rows_of(mm.T);
  j["D"] = rows_of(mm.D);
  j["F"] = rows_of(mm.F_min);
  j["G"] = rows_of(mm.G_min);
  j["null_residual"] = mm.null_residual;
  j["ortho_residual"] = mm.ortho_residual;
  j["position_residual"] = mm.position_residual;
  j["velocity_residual"] = mm.velocity_residual;
  j["at_rest"] = mm.at_rest;
  j["rheonomic"] = mm.rheonomic;
  j["note"] = mm.note;
  if (dt > 0.0) {
    Mat Fd, Gd;
    discretize_zoh(mm.F_min, mm.G_min, dt, Fd, Gd);
    j["Fd"] = rows_of(Fd);
    j["Gd"] = rows_of(Gd);
  }
  return j;
}

// The answer to one request, or throws ukdyn::Error saying why there is none.
json answer(const Scenario& sc, ForwardData& data, Mat& C, const std::string& line,
            const EvalOptions& opt) {
  const System& sys = *sc.system;
  const Index n = sys.dof();
  json in;
  try {
    in = json::parse(line);
  } catch (const json::exception& e) {
    throw Error(std::string("invalid JSON: ") + e.what());
  }
  if (!in.is_object()) throw Error(R"(expected a JSON object {"t", "q", "qd", "tau"})");
  for (const auto& [key, value] : in.items()) {
    if (key != "t" && key != "q" && key != "qd" && key != "tau" && key != "derivatives") {
      throw Error(fmt::format("unknown key '{}' (the keys are t, q, qd, tau, derivatives)",
                              printable(key)));
    }
  }
  double t = 0.0;
  if (const auto it = in.find("t"); it != in.end()) {
    if (!it->is_number()) throw Error("key 't': expected a number");
    t = it->get<double>();
    if (!std::isfinite(t)) throw Error("key 't': not finite");
  }
  const Vec q = read_vec(in, "q", n, true);
  const Vec qd = read_vec(in, "qd", n, true);
  const Vec tau = read_vec(in, "tau", n, false);
  bool derivatives = false;
  if (const auto it = in.find("derivatives"); it != in.end()) {
    if (!it->is_boolean()) throw Error("key 'derivatives': expected true or false");
    derivatives = it->get<bool>();
  }
  forward(sys, data, t, q, qd, tau, sc.sim.uk);
  if (!all_finite(data.M)) throw Error("the mass matrix M is not finite at this state");
  // A singular M is fine when [M; A] has full column rank (core/uk_singular.hpp): then the
  // checks below apply to the augmented M_a the solve used.
  if (data.singular.rank_deficient) {
    throw Error(undetermined_direction(data.M, data.A, sys.coordinate_names()));
  }
  const Mat Ms = solved_mass(sys, data);  // M, or the augmented M_a the solve used
  const Eigen::LLT<Mat> llt(Ms);
  if (llt.info() != Eigen::Success) {
    throw Error("the mass matrix M is singular (not positive definite) at this state");
  }
  if (const double rc = llt.rcond(); !(rc >= opt.min_rcond)) {
    throw Error(fmt::format(
        "the mass matrix M is singular to round-off at this state (reciprocal condition {:.3e})",
        rc));
  }
  coriolis_matrix(sys, data, t, q, qd, C);
  if (!data.result.finite || !all_finite(data.qdd) || !all_finite(data.Qc) || !all_finite(data.A) ||
      !all_finite(data.b) || !all_finite(data.G) || !all_finite(data.Q) || !all_finite(data.Cqd) ||
      !all_finite(C)) {
    throw Error("non-finite result at this state (M, A, b, forces or accelerations)");
  }
  json out;
  out["t"] = t;
  out["M"] = rows_of(data.M);
  out["C"] = rows_of(C);
  out["Cqd"] = vec_of(data.Cqd);
  out["G"] = vec_of(data.G);
  out["Q"] = vec_of(data.Q);
  out["A"] = rows_of(data.A);
  out["b"] = vec_of(data.b);
  out["Qc"] = vec_of(data.Qc);
  out["qdd"] = vec_of(data.qdd);
  out["rank"] = data.result.rank;
  out["residual"] = data.result.residual;
  out["consistent"] = data.result.consistent;
  if (sys.rows() > 0) {
    const Vec sv =  // of M_a = M + A^T alpha A when M is singular (core/uk_singular.hpp)
        singular_values_A_Minvhalf(Ms, data.A);
    if (!all_finite(sv)) throw Error("non-finite singular values of A M^-1/2 at this state");
    out["singular_values"] = vec_of(sv);
  }
  if (derivatives)
    out["derivatives"] = linearization_json(sys, linearize(sys, t, q, qd, tau, sc.sim.uk));
  return out;
}

}  // namespace

namespace {

// The derivatives with respect to the named parameters (docs/derivatives.md, "Sensitivities to
// parameters"); trusted becomes false when they cannot be vouched for at the state.
json parameters_json(const Scenario& sc, double t, const Vec& q, const Vec& qd, const Vec& tau,
                     const LinearizeOptions& opt, bool& trusted) {
  const auto ps = scenario_parameters(sc, opt.parameters);
  const ParameterLinearization pl = state_sensitivities(sc, ps, t, q, qd, tau);
  Mat dq0, dqd0;
  initial_state_derivatives(sc, ps, dq0, dqd0);
  json j;
  json names = json::array(), paths = json::array(), values = json::array(), steps = json::array();
  for (const auto& p : ps) {
    names.push_back(p.name);
    std::string where;  // the places written, one string (the npz keeps numbers only)
    for (const auto& w : p.paths) where += (where.empty() ? "" : ", ") + w;
    paths.push_back(where);
    values.push_back(p.value);
    steps.push_back(p.step);
  }
  j["names"] = names;
  j["paths"] = paths;
  j["values"] = values;
  j["steps"] = steps;
  j["dqdd_dp"] = rows_of(pl.dqdd_dp);
  j["dQc_dp"] = rows_of(pl.dQc_dp);
  j["dq0_dp"] = rows_of(dq0);
  j["dqd0_dp"] = rows_of(dqd0);
  j["trusted"] = pl.lin.trusted;
  j["message"] = pl.lin.message;
  trusted = trusted && pl.lin.trusted;
  return j;
}

// The closed loop's own entries (docs/derivatives.md, "Closed-loop linearisation"): the law's τ,
// u and ∂τ/∂(q, q̇) (and how they were taken), the eigenvalues of the closed-loop minimal F, and
// the kinks of the law.
json closed_loop_json(const System& plant, double t, const Vec& q, const Vec& qd,
                      const ClosedLoopLinearization& cl, const std::string& law) {
  json j;
  j["law"] = law;
  j["tau"] = vec_of(cl.law.tau);
  j["u"] = vec_of(cl.law.u);
  j["dtau_dq"] = rows_of(cl.law.dtau_dq);
  j["dtau_dqd"] = rows_of(cl.law.dtau_dqd);
  j["dtau_dt"] = vec_of(cl.law.dtau_dt);
  const MinimalModel mm = minimal_model(plant, t, q, qd, cl.law.tau, cl.lin);
  const Eigen::EigenSolver<Mat> es(mm.F_min, false);
  Mat ev(mm.F_min.rows(), 2);
  if (es.info() == Eigen::Success) {
    ev.col(0) = es.eigenvalues().real();
    ev.col(1) = es.eigenvalues().imag();
  } else {
    ev.setConstant(std::nan(""));
  }
  j["eigenvalues"] = rows_of(ev);  // of the minimal F: [re, im] per row
  j["kinks"] = cl.law.kinks;
  j["dtau_method"] = cl.law.method;
  j["dtau_dt_method"] = cl.law.dtau_dt_method;
  j["note"] =
      "dtau_dq, dtau_dqd: exact when dtau_method is \"exact\", else (dtau_method says why) "
      "Richardson central differences of the law (step 1e-6 max(1, |x_j|)); dtau_dt: the same "
      "as dtau_dt_method says; F, derivatives.dqdd_dq/dqdd_dqd, minimal.F: the plant's exact "
      "derivatives "
      "with them; derivatives.dqdd_dt/dQc_dt: the plant's exact d/dt plus dqdd_dtau dtau_dt";
  return j;
}

// constraint_offset() in the JSON, and said (options.warnings) above `tolerance`.
json constraint_residuals(const System& sys, double t, const Vec& q, const Vec& qd,
                          double tolerance, const LinearizeOptions& opt) {
  const ConstraintOffset c = constraint_offset(sys, t, q, qd, tolerance);
  if (opt.warnings && !c.warning.empty())
    *opt.warnings << printable("ukdyn: warning: " + c.warning, true) << "\n";
  return json{{"position", c.position}, {"velocity", c.velocity}, {"row", c.row}};
}

// The object `ukdyn linearize` writes (docs/derivatives.md) and whether ukdyn vouches for it.
json linearization_object(const Scenario& sc, double t, const Vec& q, const Vec& qd,
                          const Vec& tau_in, const LinearizeOptions& opt, bool& trusted) {
  std::optional<ClosedLoopLinearization> cl;
  std::shared_ptr<const System> plant = sc.system;
  Vec tau = tau_in;
  if (opt.closed_loop) {
    if (!opt.parameters.empty())
      throw Error("the closed loop's linearisation does not take parameters (--param)");
    cl = closed_loop_linearization(sc, t, q, qd);
    plant = make_control_run(sc)->plant;
    tau = cl->law.tau;
  }
  const System& sys = *plant;
  const Linearization lin = cl ? cl->lin : linearize(sys, t, q, qd, tau, sc.sim.uk);
  Mat F, G;
  state_space(lin, F, G);
  json j;
  j["t"] = t;
  j["coordinates"] = sys.coordinate_names();
  j["q"] = vec_of(q);
  j["qd"] = vec_of(qd);
  j["tau"] = vec_of(tau);
  j["qdd"] = vec_of(lin.qdd);
  j["Qc"] = vec_of(lin.Qc);
  j["derivatives"] = linearization_json(sys, lin);
  j["F"] = rows_of(F);
  j["G"] = rows_of(G);
  j["constraint_residuals"] = constraint_residuals(sys, t, q, qd, sc.initial_tolerance, opt);
  if (opt.dt > 0.0) {
    Mat Fd, Gd;
    try {
      discretize_zoh(F, G, opt.dt, Fd, Gd);
    } catch (const std::invalid_argument& e) {  // expm of a matrix F dt that is not finite
      throw Error(fmt::format("--dt {:g}: the discrete model: {}", opt.dt, e.what()));
    }
    j["dt"] = opt.dt;
    j["Fd"] = rows_of(Fd);
    j["Gd"] = rows_of(Gd);
  }
  if (opt.minimal || cl) j["minimal"] = minimal_json(sys, t, q, qd, tau, lin, opt.dt);
  trusted = lin.trusted;
  if (opt.warnings && !lin.time_message.empty())
    *opt.warnings << printable("ukdyn: warning: dqdd_dt, dQc_dt not given: " + lin.time_message,
                               true)
                  << "\n";
  if (cl) {
    j["closed_loop"] = closed_loop_json(sys, t, q, qd, *cl, to_string(sc.control->law.kind));
    if (!cl->law.kinks.empty()) {
      trusted = false;
      j["derivatives"]["trusted"] = false;
      j["derivatives"]["message"] =
          "the control law is not differentiable at the state (" + cl->law.kinks.front() + ")";
    }
  }
  if (!opt.parameters.empty()) j["parameters"] = parameters_json(sc, t, q, qd, tau, opt, trusted);
  return j;
}

// The numbers of the object as float64 arrays: a number or a boolean → shape (), a list of
// numbers → (n,), a list of rows → (r, c); the "derivatives" entries by their own names, the
// "minimal" ones as minimal_<name>, the "parameters" ones as parameters_<name>; strings (names,
// messages) are left out.
void collect_arrays(const json& j, const std::string& prefix,
                    std::vector<io_detail::NpyArray>& out) {
  for (const auto& [key, v] : j.items()) {
    io_detail::NpyArray a;
    a.name = prefix + key;
    if (v.is_object()) {
      collect_arrays(v,
                     key == "minimal"                ? "minimal_"
                     : key == "closed_loop"          ? "closed_loop_"
                     : key == "parameters"           ? "parameters_"
                     : key == "constraint_residuals" ? "constraint_residuals_"
                                                     : "",
                     out);
      continue;
    }
    if (v.is_number() || v.is_boolean()) {
      a.values.push_back(v.is_boolean() ? (v.get<bool>() ? 1.0 : 0.0) : v.get<double>());
    } else if (v.is_array() && !v.empty() && v[0].is_array()) {
      a.shape = {v.size(), v[0].size()};
      for (const auto& row : v)
        for (const auto& x : row) a.values.push_back(x.get<double>());
    } else if (v.is_array() && (v.empty() || v[0].is_number())) {
      a.shape = {v.size()};
      for (const auto& x : v) a.values.push_back(x.get<double>());
    } else {
      continue;
    }
    out.push_back(std::move(a));
  }
}

}  // namespace

bool write_linearization(const Scenario& sc, double t, const Vec& q, const Vec& qd, const Vec& tau,
                         std::ostream& out, const LinearizeOptions& opt) {
  bool trusted = false;
  const json j = linearization_object(sc, t, q, qd, tau, opt, trusted);
  out << j.dump(1, ' ', false, json::error_handler_t::replace) << "\n";
  return trusted;
}

bool write_linearization_npz(const Scenario& sc, double t, const Vec& q, const Vec& qd,
                             const Vec& tau, std::ostream& out, const LinearizeOptions& opt) {
  bool trusted = false;
  const json j = linearization_object(sc, t, q, qd, tau, opt, trusted);
  std::vector<io_detail::NpyArray> arrays;
  collect_arrays(j, "", arrays);
  out << io_detail::npz_bytes(arrays);
  return trusted;
}

namespace {

// The top-level keys of a JSON object's text with their lines (1-based), in order: a key is a
// string at depth 1 followed by ':'. (nlohmann's parser keeps the last of two equal keys and gives
// no positions.)
std::vector<std::pair<std::string, std::size_t>> top_level_keys(const std::string& text) {
  std::vector<std::pair<std::string, std::size_t>> keys;
  std::size_t line = 1, depth = 0, start = 0;
  bool in_string = false;
  for (std::size_t i = 0; i < text.size(); ++i) {
    const char c = text[i];
    if (c == '\n') ++line;
    if (in_string) {
      if (c == '\\') {
        ++i;
      } else if (c == '"') {
        in_string = false;
        std::size_t k = i + 1;
        while (k < text.size() && std::isspace(static_cast<unsigned char>(text[k]))) ++k;
        if (depth == 1 && k < text.size() && text[k] == ':') {
          const json key = json::parse(text.substr(start, i + 1 - start), nullptr, false);
          if (key.is_string()) keys.emplace_back(key.get<std::string>(), line);
        }
      }
    } else if (c == '"') {
      in_string = true;
      start = i;
    } else if (c == '{' || c == '[') {
      ++depth;
    } else if (c == '}' || c == ']') {
      --depth;
    }
  }
  return keys;
}

}  // namespace

ConstraintOffset constraint_offset(const System& sys, double t, const Vec& q, const Vec& qd,
                                   double tolerance) {
  Vec phi(sys.rows()), phid(sys.rows());
  position_residuals(sys, t, q, phi);
  velocity_residuals(sys, t, q, qd, phid);
  ConstraintOffset c;
  double worst = 0.0;
  for (Index i = 0; i < sys.rows(); ++i) {
    c.position = std::max(c.position, std::abs(phi(i)));
    c.velocity = std::max(c.velocity, std::abs(phid(i)));
    if (std::max(std::abs(phi(i)), std::abs(phid(i))) > worst) {
      worst = std::max(std::abs(phi(i)), std::abs(phid(i)));
      c.row = sys.constraint_row_names()[static_cast<std::size_t>(i)];
    }
  }
  // Linearised all the same (the derivatives of the equations at that state), but said.
  if (!(worst <= tolerance))
    c.warning = fmt::format(
        "the state is off the constraints (row '{}': |Phi| {:.3g}, |Phi'| {:.3g} > "
        "initial_tolerance {:.3g}): linearised all the same, the derivatives of the equations at "
        "this state, not of a motion on the constraints (`ukdyn assemble` moves a state onto "
        "them)",
        c.row, c.position, c.velocity, tolerance);
  return c;
}

LinearizeState read_state_json(const Scenario& sc, const std::string& path) {
  const std::string text =
      detail::read_input_file(path, {"state file", detail::kMiB, printable(path)});
  json j;
  try {
    j = json::parse(text);
  } catch (const json::exception& e) {
    throw Error(fmt::format("{}: invalid JSON: {}", printable(path), e.what()));
  }
  if (!j.is_object())
    throw Error(
        fmt::format(R"({}: expected a JSON object {{"t", "q", "qd", "tau"}})", printable(path)));
  const auto keys = top_level_keys(text);
  auto at = [&](const std::string& key) {  // FILE:LINE of a key
    for (const auto& [k, line] : keys)
      if (k == key) return fmt::format("{}:{}", printable(path), line);
    return printable(path);
  };
  for (std::size_t i = 0; i < keys.size(); ++i) {
    const std::string& key = keys[i].first;
    if (key != "t" && key != "q" && key != "qd" && key != "tau")
      throw Error(fmt::format("{}:{}: unknown key '{}' (the keys are t, q, qd, tau)",
                              printable(path), keys[i].second, printable(key)));
    for (std::size_t k = 0; k < i; ++k)
      if (keys[k].first == key)
        throw Error(fmt::format("{}:{}: key '{}' twice (first at line {})", printable(path),
                                keys[i].second, key, keys[k].second));
  }
  const Index n = sc.system->dof();
  LinearizeState st;
  st.t = sc.sim.t0;
  auto field = [&](const char* key, auto read) {
    try {
      read();
    } catch (const Error& e) {
      throw Error(fmt::format("{}: {}", at(key), e.what()));
    }
  };
  if (const auto it = j.find("t"); it != j.end()) {
    field("t", [&] {
      if (!it->is_number() || !std::isfinite(it->get<double>()))
        throw Error("key 't': expected a finite number");
      st.t = it->get<double>();
    });
  }
  field("q", [&] { st.q = read_vec(j, "q", n, true); });
  field("qd", [&] { st.qd = read_vec(j, "qd", n, true); });
  st.tau = sc.tau;
  if (j.contains("tau")) field("tau", [&] { st.tau = read_vec(j, "tau", n, true); });
  return st;
}

LinearizeState read_state_csv_row(const Scenario& sc, const std::string& path, long row) {
  detail::InputStream in(
      path, {"trajectory file", std::numeric_limits<std::size_t>::max(), printable(path)});
  if (row < 0) throw Error(fmt::format("{}: row {} (rows count from 0)", printable(path), row));
  io_detail::CsvLines lines(in);
  std::string line;
  if (!lines.next(line)) throw Error(fmt::format("{}: empty file", printable(path)));
  const auto header = io_detail::split_csv_line(line);
  auto column = [&](const std::string& name) {
    bool twice = false;
    const std::size_t c = io_detail::csv_column(header, name, twice);
    if (c == header.size())
      throw Error(fmt::format("{}:1: no column '{}' (a trajectory.csv of this scenario has it)",
                              printable(path), printable(name)));
    if (twice)
      throw Error(fmt::format("{}:1: column '{}' twice (which one is the state?)", printable(path),
                              printable(name)));
    return c;
  };
  const auto& names = sc.system->coordinate_names();
  const Index n = sc.system->dof();
  std::vector<std::size_t> cols{column("t")};
  for (const auto& nm : names) cols.push_back(column(nm));
  for (const auto& nm : names) cols.push_back(column(nm + "_dot"));
  for (long k = 0; k <= row; ++k) {
    if (!lines.next(line))
      throw Error(fmt::format("{}: no data row {} (the file has {})", printable(path), row, k));
  }
  const auto cells = io_detail::split_csv_line(line);
  if (cells.size() != header.size())
    throw Error(fmt::format("{}:{}: {} cells, the header has {} (a torn or edited row)",
                            printable(path), lines.line_no(), cells.size(), header.size()));
  std::vector<double> v(cols.size());
  for (std::size_t c = 0; c < cols.size(); ++c) {
    if (cols[c] >= cells.size() || !io_detail::parse_csv_number(cells[cols[c]], v[c]) ||
        !std::isfinite(v[c]))
      throw Error(fmt::format("{}:{}: column '{}': not a finite number", printable(path),
                              lines.line_no(), printable(header[cols[c]])));
  }
  LinearizeState st;
  st.t = v[0];
  st.q = Eigen::Map<const Vec>(v.data() + 1, n);
  st.qd = Eigen::Map<const Vec>(v.data() + 1 + n, n);
  st.tau = sc.tau;
  return st;
}

EvalCounts run_eval_protocol(const Scenario& sc, std::istream& in, std::ostream& out,
                             std::ostream* err, const EvalOptions& opt) {
  const Index n = sc.system->dof();
  ForwardData data(*sc.system);
  Mat C(n, n);
  EvalCounts counts;
  std::string line;
  long lineno = 0;
  bool too_long = false;
  while (read_line(in, line, opt.max_line_bytes, too_long)) {
    ++lineno;
    if (!too_long && line.find_first_not_of(" \t\r") == std::string::npos) continue;
    ++counts.lines;
    std::string text;
    try {
      if (too_long) throw Error(fmt::format("line longer than {} bytes", opt.max_line_bytes));
      json a = answer(sc, data, C, line, opt);
      a["line"] = lineno;  // every answer names its input line, as an error does
      text = a.dump();
    } catch (const std::exception& e) {
      ++counts.failures;
      const std::string msg = fmt::format("{}:{}: {}", opt.source, lineno, e.what());
      if (err) *err << "ukdyn eval: " << printable(msg) << "\n";
      text = json{{"line", lineno}, {"error", msg}}.dump(-1, ' ', false,
                                                         json::error_handler_t::replace);
    }
    out << text << "\n";
  }
  out.flush();
  return counts;
}

}  // namespace ukdyn
