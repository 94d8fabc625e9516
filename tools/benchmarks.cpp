// `make benchmarks`: the IFToMM library of computational benchmark problems (M. González, D.
// Dopico, U. Lugrís, J. Cuadrado, Multibody Syst. Dyn. 16 (2006) 179–190), each run over its FULL
// duration from its scenario in scenarios/benchmarks/, against its reference. Prints one markdown
// table row per problem: the quantity compared with the reference and the largest error over the
// samples (and the time it happens), the error at the end, the largest constraint residual max|Φ|,
// the energy drift max|E − E0| (or of the balance E − W), the rank of A, the CPU time of the run
// and its steps. docs/benchmarks.md describes the problems and keeps the table of one run.
//
// To add a problem: one entry in problems() below: its scenario, duration and output step, the
// quantity observed (a function of the state) and the reference (a closed form of t, or a second
// formulation sampled at the same times). An entry whose scenario file does not exist is listed as
// skipped, with the reason.
//
// Usage: ukdyn_benchmarks [--root DIR] [--only SUBSTRING] [--short]
//   --root   the source tree holding scenarios/ (default: this build's source tree)
//   --only   run only the problems whose id or title contains SUBSTRING
//   --short  run each problem over at most 2 s (a smoke test of the tool)
#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <ctime>
#include <filesystem>
#include <functional>
#include <iostream>
#include <optional>
#include <string>
#include <vector>

#include "tools/benchmark_reference.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/simulate/simulate.hpp"

#ifndef UKDYN_SOURCE_DIR
#define UKDYN_SOURCE_DIR "."
#endif

namespace {

using namespace ukdyn;
using Point = std::array<double, 3>;

/// What a problem observes at a sample: a point (unused components 0).
using Observer = std::function<Point(double t, CVecRef q, CVecRef qd, const ForwardData& data)>;

struct Problem {
  std::string id;        ///< benchmark id in the library (A01, ...)
  std::string title;     ///< short name
  std::string scenario;  ///< relative to the source tree
  double t_end = 10;     ///< the specification's duration
  double sample_dt = 0.01;
  std::string quantity;  ///< what is compared with the reference
  bool conservative = true;
  /// Builds the observer for a loaded scenario; returns nullopt (and sets why) if the scenario does
  /// not have what it needs. Empty function: no quantity observed (invariants only).
  std::function<std::optional<Observer>(const Scenario&, std::string& why)> observe;
  /// The reference at t (closed form). Empty: use reference_scenario, or none.
  std::function<Point(double t)> reference;
  /// A second formulation of the same problem, observed by the same observer at the same times.
  std::string reference_scenario;
  std::string reference_name;  ///< shown in the table
  /// Changes the scenario's settings (a second row of the same scenario with another integrator).
  std::function<void(SimulationSettings&)> adjust;
};

struct Sample {
  double t;
  Point p;
};

struct Run {
  bool loaded = false;
  std::string error;  ///< load error or missing observable
  std::string note;   ///< how the quantity was observed, if not the default
  SimulationStats stats;
  std::vector<Sample> samples;
  double max_residual = 0, max_dE = 0, E0 = std::nan(""), cpu = 0, wall = 0;
  int rank_min = 1 << 30, rank_max = -1;
  Index rows = 0, dof = 0;
};

/// The work W of τ, of the non-conservative applied forces and of the constraint forces at a
/// sample, where this build of ukdyn integrates it (ForwardData::work, with the energy balance on);
/// else 0. E − W is constant for every problem, E alone for conservative ones.
template <class Data>
constexpr bool has_work = requires(const Data& d) {
  d.work;
};
template <class Data>
double work_of(const Data& d) {
  if constexpr (has_work<Data>) {
    return d.work;
  } else {
    return 0.0;
  }
}

std::optional<Index> find_coordinate(const Scenario& sc, const std::string& name) {
  const auto& names = sc.system->coordinate_names();
  const auto it = std::find(names.begin(), names.end(), name);
  if (it == names.end()) return std::nullopt;
  return static_cast<Index>(it - names.begin());
}

Run run_problem(const std::filesystem::path& file, const Problem& p, double t_end) {
  Run r;
  Scenario sc;
  try {
    sc = load_scenario(file);
  } catch (const std::exception& e) {
    r.error = e.what();
    return r;
  }
  std::optional<Observer> obs;
  if (p.observe) {
    obs = p.observe(sc, r.error);
    if (!obs) return r;
    r.note = r.error;  // an observer built with a remark
    r.error.clear();
  }
  r.loaded = true;
  r.rows = sc.system->rows();
  r.dof = sc.system->dof();
  SimulationSettings s = sc.sim;
  if (t_end > 0) s.t_end = t_end;  // else the scenario's own duration and output step
  if (t_end > 0 && p.sample_dt > 0) s.sample_dt = p.sample_dt;
  if (p.adjust) p.adjust(s);
  Vec phi(sc.system->rows());
  const ForceFunction tau = [&](double, CVecRef, CVecRef, VecRef out) { out = sc.tau; };
  r.samples.reserve(static_cast<std::size_t>((s.t_end - s.t0) / s.sample_dt) + 2);
  const auto wall0 = std::chrono::steady_clock::now();
  const std::clock_t cpu0 = std::clock();
  r.stats = simulate(*sc.system, sc.q0, sc.qd0, tau, s,
                     [&](double t, CVecRef q, CVecRef qd, const ForwardData& d) {
                       const double E =
                           kinetic_energy(d, qd) + potential_energy(*sc.system, q) - work_of(d);
                       if (std::isnan(r.E0)) r.E0 = E;
                       r.max_dE = std::max(r.max_dE, std::abs(E - r.E0));
                       if (phi.size() > 0) {
                         position_residuals(*sc.system, t, q, phi);
                         r.max_residual = std::max(r.max_residual, phi.cwiseAbs().maxCoeff());
                       }
                       r.rank_min = std::min(r.rank_min, d.result.rank);
                       r.rank_max = std::max(r.rank_max, d.result.rank);
                       r.samples.push_back({t, obs ? (*obs)(t, q, qd, d) : Point{0, 0, 0}});
                       return true;
                     });
  r.cpu = static_cast<double>(std::clock() - cpu0) / CLOCKS_PER_SEC;
  r.wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
  return r;
}

double distance(const Point& a, const Point& b) {
  return std::sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) +
                   (a[2] - b[2]) * (a[2] - b[2]));
}

// ---- observers --------------------------------------------------------------------------------

/// A point whose coordinates are scenario coordinates (by name; "" for a component that is 0).
std::function<std::optional<Observer>(const Scenario&, std::string&)> point_of(
    std::vector<std::array<std::string, 3>> candidates) {
  return [candidates](const Scenario& sc, std::string& why) -> std::optional<Observer> {
    for (const auto& names : candidates) {
      std::array<Index, 3> idx{-1, -1, -1};
      bool ok = true;
      for (int k = 0; k < 3; ++k) {
        if (names[k].empty()) continue;
        const auto i = find_coordinate(sc, names[k]);
        if (!i) {
          ok = false;
          break;
        }
        idx[k] = *i;
      }
      if (!ok) continue;
      return Observer([idx](double, CVecRef q, CVecRef, const ForwardData&) {
        Point p{0, 0, 0};
        for (int k = 0; k < 3; ++k)
          if (idx[k] >= 0) p[k] = q(idx[k]);
        return p;
      });
    }
    why = "no coordinates named";
    for (const auto& c : candidates) why += fmt::format(" ({}, {})", c[0], c[1]);
    return std::nullopt;
  };
}

/// Bricard's P3: the end of rod 2 of the chain from O1, from the angles of the joints at O1 (about
/// y) and J2 (about z, at (L, 0, 0) in rod 1): P3 = Ry(a) ((L, 0, 0) + Rz(b) (0, −L, 0)).
std::function<std::optional<Observer>(const Scenario&, std::string&)> bricard_p3(
    std::vector<std::array<std::string, 2>> candidates, double L = 1.0) {
  return [candidates, L](const Scenario& sc, std::string& why) -> std::optional<Observer> {
    for (const auto& c : candidates) {
      const auto ia = find_coordinate(sc, c[0]), ib = find_coordinate(sc, c[1]);
      if (!ia || !ib) continue;
      return Observer([a = *ia, b = *ib, L](double, CVecRef q, CVecRef, const ForwardData&) {
        const double u = L + L * std::sin(q(b));  // rod 1 frame: (L, 0, 0) + Rz(b)(0, −L, 0)
        const double v = -L * std::cos(q(b));
        const double ca = std::cos(q(a)), sa = std::sin(q(a));
        return Point{ca * u, v, -sa * u};  // Ry(a) (u, v, 0)
      });
    }
    why = "no joint-angle coordinates (q1, q2) or (a1, a2)";
    return std::nullopt;
  };
}

// ---- the problems -----------------------------------------------------------------------------

// long function problems: the table of benchmark problems, one entry each, with its source.
std::vector<Problem> problems() {
  using ukdyn_bench::NFourBarReference;
  using ukdyn_bench::SimplePendulumReference;
  std::vector<Problem> list;

  // A01: the simple pendulum in Cartesian coordinates; the specification's 2000 s with its 4000
  // output steps, and its first 10 s sampled finely.
  const auto pendulum_ref = [](double t) {
    static const SimplePendulumReference ref;
    Point p{0, 0, 0};
    ref.point(t, p[0], p[1]);
    return p;
  };
  list.push_back({"A01",
                  "simple pendulum",
                  "scenarios/benchmarks/simple_pendulum.yaml",
                  2000,
                  0.5,
                  "P1 (x, y)",
                  true,
                  point_of({{"x", "y", ""}}),
                  pendulum_ref,
                  "",
                  "exact (Jacobi sn)",
                  {}});
  list.push_back({"A01",
                  "simple pendulum, first 10 s",
                  "scenarios/benchmarks/simple_pendulum.yaml",
                  10,
                  0.01,
                  "P1 (x, y)",
                  true,
                  point_of({{"x", "y", ""}}),
                  pendulum_ref,
                  "",
                  "exact (Jacobi sn)",
                  {}});

  // A02: the N-four-bar, N = 2 over 10 s and N = 40 over 20 s (specification: 400 output steps),
  // against the parallelogram branch. B0 from coordinates with one of the names below, or from
  // the angle phi0 of crank 0.
  const std::vector<std::array<std::string, 3>> b0_names = {
      {"xB0", "yB0", ""}, {"x_B0", "y_B0", ""}, {"B0_x", "B0_y", ""}, {"xb0", "yb0", ""}};
  for (const auto& [N, t_end] : {std::pair{2, 10.0}, std::pair{40, 20.0}}) {
    const NFourBarReference ref(N);
    // Without such coordinates, coordinate-free: on the branch V = G sin φ = (G / L) y_B0 (pivots
    // at height 0), so y_B0 = L V / G is compared (x taken from the reference, contributing 0).
    auto observe = [by_name = point_of(b0_names), ref](
                       const Scenario& sc, std::string& why) -> std::optional<Observer> {
      if (auto o = by_name(sc, why)) return o;
      // The angle of crank 0 from +x, pivoted at the origin: B0 = L (cos φ0, sin φ0).
      for (const char* name : {"phi0", "phi_0"}) {
        if (const auto i = find_coordinate(sc, name)) {
          why.clear();
          return Observer([i = *i, L = ref.L](double, CVecRef q, CVecRef, const ForwardData&) {
            return Point{L * std::cos(q(i)), L * std::sin(q(i)), 0};
          });
        }
      }
      why = "y_B0 = L V/G (no B0 or phi0 coordinates)";
      return Observer(
          [&system = *sc.system, ref](double t, CVecRef q, CVecRef, const ForwardData&) {
            Point p{0, 0, 0};
            ref.point_B0(t, p[0], p[1]);
            p[1] = ref.L * potential_energy(system, q) / ref.G;
            return p;
          });
    };
    list.push_back({"A02",
                    fmt::format("N-four-bar, N = {}", N),
                    fmt::format("scenarios/benchmarks/n_four_bar_N{}.yaml", N),
                    t_end,
                    t_end / 400,
                    "B0 (x, y)",
                    true,
                    observe,
                    [ref](double t) {
                      Point p{0, 0, 0};
                      ref.point_B0(t, p[0], p[1]);
                      return p;
                    },
                    "",
                    "exact (parallelogram branch)",
                    {}});
  }

  // A03: Andrews' squeezer (a constant drive torque and a spring); no independent reference here
  // (the library's published values are not in this tree): invariants only.
  list.push_back({"A03",
                  "Andrews' squeezer",
                  "scenarios/benchmarks/andrews_squeezer.yaml",
                  0,
                  0,
                  "-",
                  false,
                  {},
                  {},
                  "",
                  "none (invariants only)",
                  {}});

  // A04: Bricard's mechanism against a second formulation (two chains closed at J4); again with
  // the loop closed at O2 by a ball and a level whose rows are evaluated in numbers from the tree
  // (bricard_numeric.yaml): the same mechanism at about half the CPU.
  for (const auto& [title, file] :
       {std::pair{"Bricard's mechanism", "bricard.yaml"},
        std::pair{"Bricard's mechanism, numeric rows (ball + level at O2)",
                  "bricard_numeric.yaml"}}) {
    list.push_back({"A04",
                    title,
                    std::string("scenarios/benchmarks/") + file,
                    10,
                    0.01,
                    "P3 (x, y, z)",
                    true,
                    bricard_p3({{"q1", "q2"}, {"a1", "a2"}}),
                    {},
                    "scenarios/benchmarks/bricard_cut_at_j4.yaml",
                    "2nd formulation (cut at J4)",
                    {}});
  }

  // A05: the flyball governor (stiff spring-dampers, prescribed shaft speed): invariants only.
  list.push_back({"A05",
                  "flyball governor",
                  "scenarios/benchmarks/flyball_governor.yaml",
                  0,
                  0,
                  "-",
                  false,
                  {},
                  {},
                  "",
                  "none (invariants only)",
                  {}});
  // The same with the high-order implicit method at the tolerance where the energy balance closes
  // to 1e-8 of the dissipated energy (docs/benchmarks-forces.md).
  if (esdirk_available()) {
    list.push_back(list.back());
    list.back().title = "flyball governor (esdirk, tol 1e-12)";
    list.back().adjust = [](SimulationSettings& s) {
      s.integrator = IntegratorKind::esdirk;
      s.abs_tol = s.rel_tol = 1e-12;
    };
  }
  return list;
}

std::string sci(double v) { return std::isfinite(v) ? fmt::format("{:.2e}", v) : "-"; }

}  // namespace

int main(int argc, char** argv) {
  std::filesystem::path root = UKDYN_SOURCE_DIR;
  std::string only;
  bool short_run = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--root" && i + 1 < argc) {
      root = argv[++i];
    } else if (a == "--only" && i + 1 < argc) {
      only = argv[++i];
    } else if (a == "--short") {
      short_run = true;
    } else {
      std::cerr << "usage: ukdyn_benchmarks [--root DIR] [--only SUBSTRING] [--short]\n";
      return 2;
    }
  }

  std::cout
      << "| id | problem | duration [s] | compared | reference | max error (at t) | error at "
         "end | max abs(Phi) | energy (balance) drift [J] | rank of A | CPU [s] | steps | status "
         "|\n|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  std::vector<std::string> notes;
  int failures = 0;
  for (const Problem& p : problems()) {
    if (!only.empty() && p.id.find(only) == std::string::npos &&
        p.title.find(only) == std::string::npos)
      continue;
    // t_end 0: the scenario's own duration (entries whose specification the scenario carries).
    const double t_end = short_run ? (p.t_end > 0 ? std::min(p.t_end, 2.0) : 2.0) : p.t_end;
    const auto file = root / p.scenario;
    if (!std::filesystem::exists(file)) {
      std::cout << fmt::format("| {} | {} | {} | | | | | | | | | | skipped: {} not found |\n", p.id,
                               p.title, p.t_end > 0 ? fmt::format("{:g}", p.t_end) : "-",
                               p.scenario);
      continue;
    }
    const Run r = run_problem(file, p, t_end);
    if (!r.loaded) {
      std::cout << fmt::format("| {} | {} | {:g} | | | | | | | | | | skipped: {} |\n", p.id,
                               p.title, t_end, r.error);
      continue;
    }
    // Error against the reference at every sample.
    double max_err = std::nan(""), t_max = 0, err_end = std::nan("");
    std::string ref_note = p.reference_name;
    std::vector<Sample> ref_samples;
    bool ref_ok = static_cast<bool>(p.reference);
    if (!p.reference && !p.reference_scenario.empty()) {
      const Run rr = run_problem(root / p.reference_scenario, p, t_end);
      if (rr.loaded && rr.stats.status == RunStatus::completed) {
        ref_samples = rr.samples;
        ref_ok = true;
      } else {
        ref_note += " (failed: " + (rr.loaded ? rr.stats.message : rr.error) + ")";
      }
    }
    if (ref_ok && p.observe) {
      max_err = 0;
      for (std::size_t i = 0; i < r.samples.size(); ++i) {
        const Point ref = p.reference
                              ? p.reference(r.samples[i].t)
                              : (i < ref_samples.size() ? ref_samples[i].p : Point{NAN, NAN, NAN});
        const double e = distance(r.samples[i].p, ref);
        if (!(e <= max_err)) {  // NaN propagates
          max_err = e;
          t_max = r.samples[i].t;
        }
        err_end = e;
      }
    }
    const bool complete = r.stats.status == RunStatus::completed;
    if (!complete) ++failures;
    std::string status = complete ? "complete" : to_string(r.stats.status) + ": " + r.stats.message;
    for (const auto& w : r.stats.warnings)
      status += fmt::format("; warning {} at t = {:g}", w.kind, w.t);
    std::cout
        << fmt::format(
               "| {} | {} | {:g}{} | {} | {} | {} | {} | {} | {} | {} | {:.3f} | {} | {} |\n", p.id,
               p.title, r.stats.t_reached, complete ? "" : fmt::format(" of {:g}", t_end),
               r.note.empty() ? p.quantity : p.quantity + ": " + r.note, ref_note,
               std::isfinite(max_err) ? fmt::format("{} (t = {:g})", sci(max_err), t_max) : "-",
               sci(err_end), sci(r.max_residual),
               p.conservative || has_work<ForwardData> ? sci(r.max_dE) : "n/a (no energy balance)",
               r.rows == 0
                   ? "-"
                   : fmt::format("{}{} of {} rows, {} coords", r.rank_min,
                                 r.rank_max != r.rank_min ? fmt::format("..{}", r.rank_max) : "",
                                 r.rows, r.dof),
               r.cpu, r.stats.steps, status)
        << std::flush;
  }
  std::cout << "\nErrors: Euclidean distance between the observed point and the reference at every "
               "output sample. Energy (balance) drift: max abs((E - W) - (E0 - W0)) over the "
               "samples, W the work of tau, of non-conservative applied forces and of constraint "
               "forces where ukdyn integrates it (else E - E0). CPU: std::clock() over the whole "
               "run (integration, projection, the samples).\n";
  return failures == 0 ? 0 : 1;
}
