// Shared pieces of the benchmark binary: registration helpers, the collecting reporter's results
// and the end-of-run comparison rows.
#pragma once

#include <benchmark/benchmark.h>

#include <algorithm>
#include <array>
#include <map>
#include <string>
#include <vector>

namespace ukbench {

/// Adds min and max to the statistics Google Benchmark computes over --benchmark_repetitions.
inline benchmark::internal::Benchmark* with_min_max(benchmark::internal::Benchmark* b) {
  return b
      ->ComputeStatistics(
          "min", [](const std::vector<double>& v) { return *std::min_element(v.begin(), v.end()); })
      ->ComputeStatistics("max", [](const std::vector<double>& v) {
        return *std::max_element(v.begin(), v.end());
      });
}

/// with_min_max for BENCHMARK(...)->Apply(add_min_max).
inline void add_min_max(benchmark::internal::Benchmark* b) { with_min_max(b); }

/// CPU time per iteration of one benchmark, in nanoseconds.
struct Timing {
  std::vector<double> repetitions;  ///< per-repetition times, when the reporter saw them
  double median = -1, min = -1,
         max = -1;  ///< aggregates (or computed from repetitions); −1 if absent
  [[nodiscard]] bool valid() const { return median > 0; }
};
using Timings = std::map<std::string, Timing>;

/// One row of the "constraint violation held over the same 4 s" table.
struct ViolationRow {
  std::string engine;  ///< "ukdyn" / "MuJoCo 2.2.2" / "Simbody 3.7"
  std::string setup;   ///< integrator, step, tolerance
  std::string start;   ///< "qd0 = 0" or "spatial qd0"
  double wall_ms = 0;  ///< wall time of the 4 s run (median of a few runs, no measuring)
  double max_gap = 0;  ///< max distance between the two cut points [m]
  double max_phi = 0;  ///< max |Φ| over the 6 closure rows (ukdyn's residuals) [m or rad]
  double q_diff = -1;  ///< max |q − q_ref(0.5 s)| against ukdyn dopri5 1e-12 (−1: not computed)
};

/// ukdyn benchmarks (bench_ukdyn.cpp).
void register_ukdyn_benchmarks();
/// Real arms on the tree algorithms, long chains, and the shipped multi-arm scenarios
/// (bench_tree.cpp).
void register_tree_benchmarks();
/// Runs the 4 s closure-only free motions of ukdyn; also fills the reference state at t = 0.5 s.
std::vector<ViolationRow> ukdyn_violation_rows(bool spatial, std::vector<double>& q_ref_05);

#if defined(UKDYN_BENCH_HAVE_MUJOCO) && defined(UKDYN_BENCH_HAVE_IO)
/// Two Pandas welded to a plate (scenarios/two_pandas_weld.yaml, bench/two_pandas_weld.xml): ukdyn's
/// q̈ against MuJoCo's qacc at the initial state, with MuJoCo's default and stiffer welds
/// (bench_tree.cpp). Not timed.
void print_two_pandas_weld_check();
#endif

#ifdef UKDYN_BENCH_HAVE_MUJOCO
/// MuJoCo benchmarks (bench_mujoco.cpp). Returns false if the MJCF cannot be loaded.
bool register_mujoco_benchmarks();
/// The same 4 s runs in MuJoCo (Euler and RK4, default and stiff solref).
std::vector<ViolationRow> mujoco_violation_rows(bool spatial, const std::vector<double>& q_ref_05);
#endif

#ifdef UKDYN_BENCH_HAVE_SIMBODY
/// The paper's mechanism and the few ukdyn results the Simbody part compares with, in plain types:
/// bench_simbody.cpp is compiled as C++17 (Simbody 3.7's headers do not compile as C++20), so it
/// cannot include paper_model.hpp. Filled from ukdyn's model by paper_mechanism() (bench_main.cpp).
struct PaperMechanism {
  struct Arm {  ///< ukdyn::MobileManipulatorParams of one robot (Table 1)
    double platform_mass = 0, base_mass = 0, base_inertia = 0, base_length = 0;
    std::array<double, 3> link_mass{}, link_inertia{}, link_length{};
  };
  std::array<Arm, 2> arm;
  double gravity = 0;           ///< along −z
  std::array<double, 12> q0{};  ///< paper coordinates (absolute pitch angles)
  std::array<double, 12> qd0_spatial{};
  std::array<double, 12> qdd_spatial{};  ///< ukdyn forward() q̈ at (q0, qd0_spatial), τ = 0
  /// max |Φ| over ukdyn's 6 closure position residuals at (t, q), q in paper coordinates.
  double (*max_closure_residual)(double t, const std::array<double, 12>& q) = nullptr;
};
const PaperMechanism& paper_mechanism();

/// Simbody benchmarks (bench_simbody.cpp). Returns false if the Simbody model cannot be built.
bool register_simbody_benchmarks();
/// The same 4 s runs with Simbody's Runge-Kutta-Merson integrator (its default projection).
std::vector<ViolationRow> simbody_violation_rows(bool spatial, const std::vector<double>& q_ref_05);

/// Simbody's state at (q0, spatial q̇0) realized to Stage::Acceleration, against ukdyn's forward().
struct SimbodyModelCheck {
  std::string error;     ///< empty if the check ran
  int rows = 0;          ///< Simbody's constraint equations (multipliers)
  double q_err = -1;     ///< max |position constraint error| (Simbody's own rows)
  double u_err = -1;     ///< max |velocity constraint error|
  double udot_err = -1;  ///< max |acceleration constraint error|
  double qdd_diff = -1;  ///< max |q̈_Simbody − q̈_ukdyn| in the paper's coordinates
  double qdd_max = -1;   ///< max |q̈_ukdyn| (scale of the difference)
};
SimbodyModelCheck simbody_model_check();
#endif

}  // namespace ukbench
