// Parameter sweeps and Monte Carlo runs of a scenario (`ukdyn sweep`, docs/sweeps.md).
//
// A sweep file names a base scenario, the parameters to vary (each one or more paths into the
// scenario's YAML, e.g. `subsystems[left].params.link_mass[2]`), how their values are chosen
// (grid, list, or random draws from uniform / normal / truncated-normal distributions with a
// seed) and the metrics kept per sample. Sample k is the base scenario with the values of row k
// written at those paths; it is computed in memory (no per-sample files) and gives one row of
// OUT/results.csv. Every random value is a pure function of (seed, sample index, parameter), so
// the table does not depend on the thread count, the shards or the MPI ranks that computed it.
#pragma once

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <iosfwd>
#include <memory>
#include <string>
#include <vector>

#include "ukdyn/output/output_dir.hpp"
#include "ukdyn/scenario/scenario.hpp"

namespace ukdyn {

/// How the values of one parameter are chosen.
struct SweepDistribution {
  enum class Kind { values, uniform, normal, truncated_normal } kind = Kind::values;
  std::vector<double> values;  ///< grid / list values
  double low = 0.0, high = 0.0, mean = 0.0, sd = 0.0;
};

struct SweepTarget {
  std::string path;     ///< into the base scenario's YAML
  double scale = 1.0;   ///< the value written is scale × parameter
  double offset = 0.0;  ///< ... + offset
};

struct SweepParameter {
  std::string name;  ///< a column of the table
  std::vector<SweepTarget> targets;
  SweepDistribution dist;
};

/// A statistic of one trajectory.csv column, or of the Euclidean norm of several, over the output
/// samples of a run.
struct ColumnMetric {
  std::string column;              ///< the column, or the name of the norm
  std::vector<std::string> stats;  ///< "min", "max", "rms", "max_abs", "final"
  std::vector<std::string> norm;   ///< non-empty: √(Σ c²) over these columns at each sample
};

struct SweepMetrics {
  bool max_residual = true;  ///< max |Φ| over rows and samples (position level)
  bool energy_drift = false;
  bool energy_balance_drift = false;
  bool max_abs_qc = false;   ///< max |Qc| per coordinate
  bool final_state = false;  ///< q, q̇ at the last sample
  /// A control run (docs/control.md): max |e| (whole run, second half), max |u|, max |u̇|, the
  /// saturation time and the largest amount over a limit.
  bool control = false;
  bool squeeze = false;  ///< a control run on the paper's closure: peak closure / squeeze force
  std::vector<ColumnMetric> columns;
};

struct Sweep {
  std::filesystem::path path;       ///< the sweep file
  std::filesystem::path base_path;  ///< the base scenario
  std::string name;
  std::string hash;  ///< FNV-1a 64 over the sweep file and the base scenario, hex
  enum class Mode { grid, list, random } mode = Mode::grid;
  std::uint64_t seed = 0;
  long samples = 0;  ///< number of samples (grid: the product of the value counts)
  std::vector<SweepParameter> parameters;
  std::vector<SweepTarget> fixed;  ///< `set:` paths written in every sample (with values)
  std::vector<double> fixed_values;
  SweepMetrics metrics;
  bool assemble = false;  ///< move each sample's (q0, q̇0) onto the constraints first
  bool figures = true;
  /// The base scenario's YAML (aliases expanded), and its text.
  std::shared_ptr<const void> base_doc;  ///< a YAML::Node, opaque here
  std::string base_text;
};

/// Loads a sweep file. Throws ScenarioError ("FILE:LINE:COL: key 'KEY': ...") for a bad file,
/// including a path that does not exist in the base scenario.
Sweep load_sweep(const std::filesystem::path& path);

/// The parameter values of sample k (in the order of Sweep::parameters).
std::vector<double> sample_values(const Sweep& sweep, long k);

/// Sample k as standalone scenario text (what `--extract K` writes).
std::string sample_scenario_text(const Sweep& sweep, long k);

/// The header of results.csv.
std::vector<std::string> sweep_header(const Sweep& sweep, const Scenario& base);

/// Computes sample k in memory: its table row (without the final newline).
std::string run_sample(const Sweep& sweep, const Scenario& base, long k,
                       const std::atomic<bool>* cancel = nullptr);

/// Where rows go when several processes compute one sweep (MPI): implemented by the CLI.
class SweepComm {
 public:
  virtual ~SweepComm() = default;
  [[nodiscard]] virtual int rank() const = 0;
  [[nodiscard]] virtual int size() const = 0;
  /// Every rank's `mine`, on rank 0 in rank order (other ranks get an empty list).
  virtual std::vector<std::string> gather(const std::string& mine) = 0;
};

struct SweepOptions {
  int threads = 0;  ///< 0: std::thread::hardware_concurrency(); at most max_sweep_threads()
  int shard = 0, shards = 1;  ///< compute the samples k with k % shards == shard
  std::ostream* progress = nullptr;
  bool progress_tty = false;  ///< a bar redrawn in place; else a line every progress_every s
  double progress_every = 5.0;
  const std::atomic<bool>* cancel = nullptr;
  SweepComm* comm = nullptr;  ///< MPI: this rank computes k with k % size == rank (within a shard)
  bool resume = true;         ///< reuse the rows of OUT/journal.csv
};

struct SweepReport {
  long samples = 0;   ///< in this shard
  long computed = 0;  ///< computed now
  long resumed = 0;   ///< taken from the journal
  long failed = 0;
  bool complete = false;  ///< every sample of the shard is in the table
  double wall_seconds = 0.0;
  std::filesystem::path table, summary;
  std::vector<std::filesystem::path> figures;
  std::string figure_error;
  std::vector<std::string> figure_notes;  ///< the figures not drawn, and why
  std::vector<std::string> failures;      ///< "sample K: status: reason"
};

/// The most worker threads a sweep takes: 4 per hardware thread, at least 16, at most 256 (more
/// only contend for the cores and the memory of the samples in flight).
int max_sweep_threads();

/// Runs the sweep into out_dir: results.csv, summary.json, figures/, journal.csv. On MPI ranks
/// other than 0 nothing is written (out_dir is not opened).
SweepReport run_sweep(const Sweep& sweep, const std::filesystem::path& out_dir,
                      const SweepOptions& options);

/// Parses "i/N" (decimal digits only, 0 ≤ i < N, nothing before or after): the --shard option
/// and a shard's summary. False for anything else ("1/2junk", " 1/2", "+1/2", "2/2", "1/0").
bool parse_shard(const std::string& text, int& index, int& count);

/// Merges the results of shards (their output folders) into out_dir: the same table as one run.
/// Throws ScenarioError if a shard is missing, incomplete, or from another sweep.
SweepReport merge_sweep(const Sweep& sweep, const std::vector<std::filesystem::path>& shard_dirs,
                        const std::filesystem::path& out_dir);

/// The console report of a sweep.
void print_sweep_report(std::ostream& os, const Sweep& sweep, const SweepReport& report);

/// SplitMix64's finaliser ([Steele2014]): the counter-based hash of the random streams.
std::uint64_t splitmix64(std::uint64_t x);
/// The uniform double in [0, 1) of (seed, sample, parameter, draw): 53 bits of the hash.
double sweep_uniform(std::uint64_t seed, long sample, int parameter, int draw);
/// A standard normal deviate for (seed, sample, parameter) by Box–Muller.
double sweep_normal(std::uint64_t seed, long sample, int parameter);

}  // namespace ukdyn
