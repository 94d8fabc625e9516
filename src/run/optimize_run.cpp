// `ukdyn optimize` (ukdyn/run/optimize_run.hpp).
#include "ukdyn/run/optimize_run.hpp"

#include <yaml-cpp/yaml.h>

#include <Eigen/LU>
#include <Eigen/QR>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>

#include "scenario/yaml_loader.hpp"
#include "ukdyn/output/csv_writer.hpp"
#include "ukdyn/output/output_dir.hpp"
#include "ukdyn/scenario/scenario_file.hpp"
#include "ukdyn/simulate/simulate.hpp"
#include "ukdyn/version.hpp"

namespace ukdyn {

namespace {

double finite_or_nan(double v) { return std::isfinite(v) ? v : std::nan(""); }

void write_csv(const OutputDir& dir, const OptimizationFile& f, const TrajectorySolution& s) {
  const auto& names = f.scenario->system->coordinate_names();
  std::vector<std::string> header{"t", "knot"};
  for (const auto& c : names) header.push_back(c);
  for (const auto& c : names) header.push_back(c + "_dot");
  for (const auto& c : names) header.push_back(c + "_ddot");
  for (const auto& a : f.problem.actuator_names) header.push_back("u_" + a);
  for (const auto& c : names) header.push_back("Qc_" + c);
  const auto& rows = f.scenario->system->constraint_row_names();
  for (const Index k : s.kept_rows) header.push_back("mu_" + rows[static_cast<std::size_t>(k)]);
  for (const auto& b : f.problem.internal_wrench_bounds)  // as `simulate` names them
    for (const auto& g : b.grasp_names)
      for (const char* w : {"fx", "fy", "fz", "mx", "my", "mz"})
        header.push_back("Wint_walker_" + g + "_" + w);
  CsvWriter csv(dir, "trajectory.csv", header);
  std::vector<double> row;
  for (Index p = 0; p < s.t.size(); ++p) {
    row.assign({s.t(p), s.knot[static_cast<std::size_t>(p)] ? 1.0 : 0.0});
    for (const Mat* m : {&s.q, &s.qd, &s.qdd, &s.u, &s.Qc, &s.mu, &s.internal_wrench})
      for (Index j = 0; j < m->cols(); ++j) row.push_back((*m)(p, j));
    csv.row(row);
  }
  csv.commit();
}

nlohmann::json summary(const OptimizationFile& f, const OptimizeReport& rep) {
  const TrajectorySolution& s = rep.solution;
  const TrajectoryProblem& p = f.problem;
  nlohmann::json j;
  j["ukdyn_version"] = version();
  j["problem"] = f.path.filename().string();
  j["problem_hash"] = f.hash;
  j["name"] = f.name;
  j["scenario"] = f.scenario->path.filename().string();
  j["method"] = to_string(p.method);
  j["intervals"] = p.intervals;
  j["duration"] = s.duration;
  j["cost"] = s.cost;
  j["ipopt"] = {{"status", s.status},
                {"converged", s.converged},
                {"iterations", s.iterations},
                {"dual_infeasibility", s.dual_infeasibility},
                {"constraint_violation", s.constraint_violation},
                {"complementarity", s.complementarity},
                {"kkt_error", s.kkt_error}};
  j["max_defect"] = s.max_defect;
  j["max_position_residual"] = s.max_position_residual;
  j["max_velocity_residual"] = s.max_velocity_residual;
  j["max_correction"] = s.max_correction;
  j["max_correction_ratio"] = s.max_correction_ratio;
  if (!p.waypoints.empty()) j["max_waypoint_residual"] = s.max_waypoint_residual;
  j["constraint_rank"] = s.kept_rows.size();
  j["trusted"] = s.trusted;
  j["message"] = s.message;
  nlohmann::json acts = nlohmann::json::object();
  for (Index a = 0; a < s.u.cols(); ++a)
    acts[p.actuator_names[static_cast<std::size_t>(a)]] = {
        {"peak_abs_u", s.u.col(a).cwiseAbs().maxCoeff()}};
  j["actuators"] = acts;
  j["replay_scenario"] = {{"file", "replay.yaml"},
                          {"open_loop_file", "replay_open_loop.yaml"},
                          {"warning", rep.replay_scenario_note}};
  if (rep.replay.done)
    j["replay"] = {{"status", rep.replay.status},
                   {"max_q_deviation", finite_or_nan(rep.replay.max_q_deviation)},
                   {"max_position_residual", finite_or_nan(rep.replay.max_position_residual)}};
  return j;
}

ReplayCheck replay(const OptimizationFile& f, const TrajectorySolution& s) {
  const TrajectoryProblem& p = f.problem;
  const System& sys = *p.system;
  ReplayCheck rc;
  SimulationSettings set = f.scenario->sim;
  set.t0 = p.t0;
  set.t_end = p.t0 + s.duration;
  set.sample_dt = (s.t(1) - s.t(0));
  if (!adaptive_steps(set)) {  // a fixed step must divide the sample step
    set.step = set.sample_dt / std::ceil(set.sample_dt / set.step - 1e-9);
  }
  Vec u(p.B.cols());
  const ForceFunction tau = [&](double t, CVecRef, CVecRef, VecRef out) {
    interpolate_u(s, p.method, t, u);
    out.noalias() = p.B * u;
    out += p.tau;
  };
  Vec phi(sys.rows());
  Index compared = 0;
  const SampleObserver obs = [&](double t, CVecRef q, CVecRef, const ForwardData&) {
    if (sys.rows() > 0) {
      position_residuals(sys, t, q, phi);
      rc.max_position_residual = std::max(rc.max_position_residual, phi.cwiseAbs().maxCoeff());
    }
    // The point at this sample's time (samples fall on the points: sample_dt is their spacing).
    const double spacing = s.t(1) - s.t(0);
    const auto pt = static_cast<Index>(std::llround((t - s.t(0)) / spacing));
    if (pt >= 0 && pt < s.t.size() && std::abs(s.t(pt) - t) <= 1e-9 * (1.0 + std::abs(t))) {
      const double dev = (q - s.q.row(pt).transpose()).cwiseAbs().maxCoeff();
      rc.max_q_deviation = std::max(rc.max_q_deviation, dev);
      ++compared;
    }
    return true;
  };
  const SimulationStats st = simulate(sys, p.q_start, p.qd_start, tau, set, obs);
  rc.status = to_string(st.status);
  rc.done = true;
  if (compared != s.t.size()) {  // never a deviation of 0 from points that were not compared
    rc.max_q_deviation = std::nan("");
    rc.status += " (compared at " + std::to_string(compared) + " of " + std::to_string(s.t.size()) +
                 " points)";
  }
  return rc;
}

std::string exact_number(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

YAML::Node flow_list(const std::vector<double>& v) {
  YAML::Node n(YAML::NodeType::Sequence);
  for (const double x : v) n.push_back(exact_number(x));
  n.SetStyle(YAML::EmitterStyle::Flow);
  return n;
}

// A cubic spline of time through (times, values) (docs/definitions.md, time functions); clamped to
// the end slopes if given, else natural.
YAML::Node spline(const Vec& times, const Vec& values, const double* end_slopes) {
  YAML::Node n;
  n["type"] = "spline";
  n["times"] = flow_list(std::vector<double>(times.data(), times.data() + times.size()));
  n["values"] = flow_list(std::vector<double>(values.data(), values.data() + values.size()));
  if (end_slopes) {
    n["end"] = "clamped";
    n["slopes"] = flow_list({end_slopes[0], end_slopes[1]});
  }
  n.SetStyle(YAML::EmitterStyle::Flow);
  return n;
}

// The coordinates the replay servo tracks: n − r of them, chosen at the start so that with the
// kept rows they fix q (greedily, in the order of q: [A_R; e_jᵀ] gains rank); then checked at
// every point. Returns a message naming the first point where they do not fix q (else empty).
std::string tracked_coordinates(const TrajectoryProblem& p, const TrajectorySolution& s,
                                std::vector<Index>& tracked) {
  const System& sys = *p.system;
  const Index n = sys.dof();
  ForwardData d(sys);
  auto stacked = [&](Index point, const std::vector<Index>& coords) {
    const Vec q = s.q.row(point).transpose(), v = s.qd.row(point).transpose();
    evaluate_dynamics(sys, d, s.t(point), q, v);
    evaluate_constraints(sys, d, s.t(point), q, v);
    Mat S(static_cast<Index>(s.kept_rows.size() + coords.size()), n);
    Index r = 0;
    for (const Index k : s.kept_rows) S.row(r++) = d.A.row(k);
    for (const Index j : coords) S.row(r++) = Mat::Identity(n, n).row(j);
    return S;
  };
  auto rank = [](const Mat& S) {
    return Eigen::ColPivHouseholderQR<Mat>(S).setThreshold(1e-9).rank();
  };
  tracked.clear();
  for (Index j = 0; j < n && static_cast<Index>(s.kept_rows.size() + tracked.size()) < n; ++j) {
    std::vector<Index> trial = tracked;
    trial.push_back(j);
    if (rank(stacked(0, trial)) == static_cast<Index>(s.kept_rows.size() + trial.size()))
      tracked = std::move(trial);
  }
  // At every point the stacked rows must have rank n, and between points their determinant must
  // keep its sign (a change: they pass through a singular position between the points).
  double previous = 0.0;
  for (Index point = 0; point < s.t.size(); ++point) {
    const Mat S = stacked(point, tracked);
    if (rank(S) < n)
      return "the tracked coordinates and the constraints do not fix q at t = " +
             exact_number(s.t(point)) + ": the servo rows are redundant there";
    const double det = S.rows() == n ? Eigen::FullPivLU<Mat>(S).determinant() : 0.0;
    if (point > 0 && det * previous < 0.0)
      return "the tracked coordinates and the constraints do not fix q at t = " +
             exact_number(s.t(point - 1)) + " .. " + exact_number(s.t(point)) +
             " (a singular position between the points): the servo rows are redundant there";
    previous = det;
  }
  return {};
}

// The robot files a scenario names by relative path (a serial chain's `urdf:` or `mjcf:`, relative
// to the scenario's folder: definitions_loader.cpp), made relative to the folder the replay is
// written to (`to`), so that the replay runs from any working directory: the scenario's folder
// `from` may have been given relative to the working directory of `ukdyn optimize`.
void rebase_robot_files(YAML::Node doc, const std::filesystem::path& from,
                        const std::filesystem::path& to) {
  namespace fs = std::filesystem;
  YAML::Node subsystems = doc["subsystems"];
  if (!subsystems.IsSequence()) return;
  const fs::path base = fs::weakly_canonical(fs::absolute(to));
  for (YAML::Node s : subsystems) {
    const YAML::Node& read = s;  // const: a missing key is not added
    for (const char* key : {"urdf", "mjcf"}) {
      if (!read.IsMap() || !read[key] || !read[key].IsScalar()) continue;
      const fs::path file = read[key].Scalar();
      if (file.is_absolute()) continue;
      const fs::path target = fs::weakly_canonical(fs::absolute(from / file));
      const fs::path relative = target.lexically_relative(base);
      s[key] = (relative.empty() ? target : relative).generic_string();
    }
  }
}

// replay.yaml and replay_open_loop.yaml (docs/optimization.md, "Replay scenario"): the problem's
// scenario with the optimal τ₀ + B u(t) as time functions (torque elements, splines through dense
// samples); replay.yaml also tracks the optimal path (angle_relation rows of role servo on n − r
// coordinates, splines clamped to the end velocities) with the stabilised law.
std::string write_replay_scenarios(const OutputDir& dir, const OptimizationFile& f,
                                   const TrajectorySolution& s) {
  const TrajectoryProblem& p = f.problem;
  const Scenario& sc = *f.scenario;
  const auto& names = p.system->coordinate_names();
  YAML::Node doc =
      YAML::Clone(io_detail::parse_scenario_yaml(read_scenario_text(sc.path), sc.path));
  doc["name"] = f.name + "_replay";
  rebase_robot_files(doc, sc.path.parent_path(), dir.path());
  // Every constraint of the problem's system is the plant's own (a `coordinate` row would default
  // to servo: docs/control.md, "Roles").
  if (YAML::Node cs = doc["constraints"]; cs.IsSequence())
    for (YAML::Node c : cs)
      if (c.IsMap()) c["role"] = "physical";
  doc["description"] = "The optimum of " + f.path.filename().string() +
                       " replayed: its u(t) as feedforward (ukdyn optimize, replay scenario)";
  const bool own_actuators =
      sc.actuators.count() > 0 && sc.actuators.B.cols() == p.B.cols() && sc.actuators.B == p.B;
  if (!own_actuators) {  // the problem's inputs (`actuated:`, or one per coordinate)
    YAML::Node acts(YAML::NodeType::Sequence);
    for (Index j = 0; j < p.B.cols(); ++j) {
      YAML::Node a;
      a["name"] = p.actuator_names[static_cast<std::size_t>(j)];
      a["gains"] =
          flow_list(std::vector<double>(p.B.col(j).data(), p.B.col(j).data() + p.B.rows()));
      acts.push_back(a);
    }
    doc["actuators"] = acts;
  }
  // τ₀ + B u(t) sampled 4 times per point spacing on the method's own u(t) (interpolate_u: the
  // quadratic per Hermite–Simpson interval), so that the spline through the samples follows it.
  constexpr Index kSub = 4;
  const Index P = s.t.size(), S = (P - 1) * kSub + 1;
  // The path likewise, on the cubic Hermite interpolant of (q, q̇) between points (the
  // Hermite–Simpson state polynomial is that cubic).
  Vec times(S), u(p.B.cols());
  Mat tau(S, p.B.rows()), path(S, p.B.rows());
  for (Index i = 0; i < S; ++i) {
    const Index a = std::min(i / kSub, P - 2);
    const double w = static_cast<double>(i - a * kSub) / static_cast<double>(kSub);
    const double h = s.t(a + 1) - s.t(a);
    times(i) = (1.0 - w) * s.t(a) + w * s.t(a + 1);
    interpolate_u(s, p.method, times(i), u);
    tau.row(i) = (p.tau + p.B * u).transpose();
    path.row(i) = (2 * w * w * w - 3 * w * w + 1) * s.q.row(a) +
                  (w * w * w - 2 * w * w + w) * h * s.qd.row(a) +
                  (-2 * w * w * w + 3 * w * w) * s.q.row(a + 1) +
                  (w * w * w - w * w) * h * s.qd.row(a + 1);
  }
  doc["forces"].remove("tau");
  for (Index i = 0; i < tau.cols(); ++i) {
    if (tau.col(i).cwiseAbs().maxCoeff() == 0.0) continue;
    YAML::Node e;
    e["type"] = "torque";
    e["name"] = "feedforward_" + names[static_cast<std::size_t>(i)];
    e["coordinate"] = names[static_cast<std::size_t>(i)];
    e["value"] = spline(times, tau.col(i), nullptr);
    doc["forces"]["elements"].push_back(e);
  }
  YAML::Node sim = doc["simulation"];
  sim["t_end"] = exact_number(s.t(s.t.size() - 1));
  sim["sample_dt"] = exact_number(s.t(1) - s.t(0));
  {
    YAML::Emitter out;
    out << doc;
    AtomicFile file(dir, dir.fd(), "", "replay_open_loop.yaml");
    file.write(
        std::string("# ukdyn optimize: the optimal u(t) open loop (docs/optimization.md)\n") +
        out.c_str() + "\n");
    file.commit();
  }
  std::vector<Index> tracked;
  const std::string note = tracked_coordinates(p, s, tracked);
  for (const Index j : tracked) {
    const double slopes[2] = {s.qd(0, j), s.qd(s.qd.rows() - 1, j)};
    YAML::Node c;
    c["type"] = "angle_relation";
    c["name"] = "track_" + names[static_cast<std::size_t>(j)];
    c["role"] = "servo";
    YAML::Node terms;
    terms[names[static_cast<std::size_t>(j)]] = 1;
    terms.SetStyle(YAML::EmitterStyle::Flow);
    c["terms"] = terms;
    c["value"] = spline(times, path.col(j), slopes);
    doc["constraints"].push_back(c);
  }
  doc["control"]["law"] = "stabilized";
  doc["control"]["omega"] = 10;
  // The plant: the open-loop file (the system without the servo rows; a `plant_set` added here
  // perturbs it).
  doc["control"]["plant"] = "replay_open_loop.yaml";
  YAML::Emitter out;
  out << doc;
  AtomicFile file(dir, dir.fd(), "", "replay.yaml");
  file.write(std::string("# ukdyn optimize: the optimal u(t) as feedforward plus the stabilised "
                         "servo on the optimal path (docs/optimization.md)\n") +
             out.c_str() + "\n");
  file.commit();
  return note;
}

}  // namespace

void interpolate_u(const TrajectorySolution& s, CollocationMethod method, double t, VecRef u) {
  const Index P = s.t.size();
  const bool hs = method == CollocationMethod::hermite_simpson;
  const Index step = hs ? 2 : 1, intervals = (P - 1) / step;
  const double h = (s.t(P - 1) - s.t(0)) / static_cast<double>(intervals);
  const double x = std::clamp((t - s.t(0)) / h, 0.0, static_cast<double>(intervals));
  const Index i = std::min<Index>(static_cast<Index>(x), intervals - 1);
  const double tau = x - static_cast<double>(i);  // in [0, 1] on interval i
  const Index a = i * step;
  if (!hs) {
    u = (1.0 - tau) * s.u.row(a).transpose() + tau * s.u.row(a + 1).transpose();
    return;
  }
  // Lagrange basis on the nodes 0, 1/2, 1.
  const double la = 2.0 * (tau - 0.5) * (tau - 1.0), lc = -4.0 * tau * (tau - 1.0),
               lb = 2.0 * tau * (tau - 0.5);
  u = la * s.u.row(a).transpose() + lc * s.u.row(a + 1).transpose() +
      lb * s.u.row(a + 2).transpose();
}

OptimizeReport run_optimization(const OptimizationFile& file, const std::filesystem::path& out) {
  OutputDir dir(out);  // refused before the solve, not after it
  // An earlier run's summary goes first: a solve that throws, or a trajectory.csv that is refused,
  // must not leave it describing this folder.
  dir.remove_file(dir.fd(), "summary.json");
  OptimizeReport rep;
  const auto t0 = std::chrono::steady_clock::now();
  rep.solution = optimize_trajectory(file.problem, file.ipopt);
  rep.wall_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  // An interrupted solve (IpoptSettings::cancel) is written as it stands, untrusted, unreplayed.
  const bool interrupted = file.ipopt.cancel && file.ipopt.cancel->load();
  if (file.verify && !interrupted) rep.replay = replay(file, rep.solution);
  write_csv(dir, file, rep.solution);
  rep.replay_scenario_note = write_replay_scenarios(dir, file, rep.solution);
  AtomicFile f(dir, dir.fd(), "", "summary.json");
  f.write(summary(file, rep).dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n");
  f.commit();
  dir.sync();
  return rep;
}

}  // namespace ukdyn
