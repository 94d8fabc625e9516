// `ukdyn optimize` (ukdyn/run/optimize_run.hpp).
#include "ukdyn/run/optimize_run.hpp"

#include <chrono>
#include <cmath>
#include <nlohmann/json.hpp>

#include "ukdyn/output/csv_writer.hpp"
#include "ukdyn/output/output_dir.hpp"
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
  if (file.verify) rep.replay = replay(file, rep.solution);
  write_csv(dir, file, rep.solution);
  AtomicFile f(dir, dir.fd(), "", "summary.json");
  f.write(summary(file, rep).dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n");
  f.commit();
  dir.sync();
  return rep;
}

}  // namespace ukdyn
