// Actuator sizing from a catalogue (`ukdyn size`, docs/sizing.md).
//
// A catalogue file lists motors (the motor keys of an actuator's `motor:` block, docs/motors.md)
// and gearboxes (ratio, efficiency, inertia, output torque limits, input speed limit). A sizing
// file names a catalogue, a scenario or a sweep file (the operating conditions: load masses,
// speeds, model errors ...), the actuators to size, the margin to keep free and the order that
// defines "smallest". For each actuator, the candidates (every motor × gearbox allowed) are tried
// in ascending order; a candidate is evaluated exactly: every sample is re-run with its motor in
// the model (its reflected rotor inertia and friction change the dynamics), and it holds when every
// operating point of every sample keeps at least the margin to every limit. Several actuators are
// sized together, each one at a time with the others held at their current choice, iterated to a
// fixed point (run_sizing).
#pragma once

#include <atomic>
#include <filesystem>
#include <iosfwd>
#include <limits>
#include <string>
#include <vector>

#include "ukdyn/model/motor.hpp"
#include "ukdyn/sweep/sweep.hpp"

namespace ukdyn {

/// A motor of a catalogue: its name, mass (kg, NaN if not given) and the motor keys of MotorSpec
/// (ratio and efficiency unused: they come from the gearbox).
struct CatalogueMotor {
  std::string name;
  double mass = std::numeric_limits<double>::quiet_NaN();
  MotorSpec spec;
};

/// A gearbox of a catalogue. Torques on the output (joint) side, speeds on the input (motor) side.
struct CatalogueGearbox {
  std::string name;
  double ratio = 1.0;       ///< n = ω_m / ω_j
  double efficiency = 1.0;  ///< η
  double inertia = 0.0;     ///< at the input (motor side), added to the rotor's (kg·m²)
  double mass = std::numeric_limits<double>::quiet_NaN();              ///< kg, NaN if not given
  double continuous_torque = std::numeric_limits<double>::infinity();  ///< RMS |u| limit
  double peak_torque = std::numeric_limits<double>::infinity();        ///< |u| limit
  double max_input_speed = std::numeric_limits<double>::infinity();    ///< |ω_m| limit
};

struct Catalogue {
  std::filesystem::path path;
  std::string name;
  std::vector<CatalogueMotor> motors;
  std::vector<CatalogueGearbox> gearboxes;
};

/// Reads a catalogue file (`ukdyn_catalogue: 1`). Throws ScenarioError naming the file, line and
/// key of the first bad entry.
Catalogue load_catalogue(const std::filesystem::path& path);

/// One motor + gearbox of the catalogue.
struct SizingCandidate {
  std::size_t motor = 0, gearbox = 0;  ///< indices into the catalogue
  double size = 0.0;                   ///< the ordering key (SizingFile::order_by)
};

/// The actuator's `motor:` block for a candidate: the motor's keys, the gearbox's ratio and
/// efficiency, the rotor inertia plus the gearbox's input inertia.
MotorSpec candidate_spec(const Catalogue& c, const SizingCandidate& k);
/// "MOTOR + GEARBOX".
std::string candidate_name(const Catalogue& c, const SizingCandidate& k);

struct SizingActuator {
  std::string name;
  std::vector<SizingCandidate> candidates;  ///< ascending: smallest first
};

struct SizingFile {
  std::filesystem::path path;
  std::string name;
  Catalogue catalogue;
  /// The samples: a sweep file's, or a scenario alone as one sample without parameters.
  Sweep sweep;
  bool from_sweep = false;
  std::vector<SizingActuator> actuators;
  double margin = 0.1;       ///< kept free of every limit (0.1: 10 % of the envelope)
  bool continuous = true;    ///< also the RMS limits (motor and gearbox continuous torque)
  std::string order_by;      ///< mass | continuous_torque | peak_torque
  std::string order_reason;  ///< why (default: mass if every entry has one)
  int max_rounds = 50;       ///< of the fixed-point iteration
};

/// Reads a sizing file (`ukdyn_sizing: 1`), its catalogue and its scenario or sweep. Throws
/// ScenarioError naming the file, line and key of the first problem.
SizingFile load_sizing_file(const std::filesystem::path& path);

/// Where a candidate comes closest to (or crosses) a limit over the samples.
struct SizingPoint {
  long sample = -1;                                     ///< -1: no sample ran
  std::vector<double> values;                           ///< the sample's parameter values
  double t = std::numeric_limits<double>::quiet_NaN();  ///< NaN: a limit over the whole run (RMS)
  double margin = -std::numeric_limits<double>::infinity();
  std::string limit;  ///< "peak torque", "torque-speed line", "motor continuous torque", ...
  double u = 0.0, omega_j = 0.0;       ///< joint side (RMS limits: the RMS value in u / torque)
  double torque = 0.0, omega_m = 0.0;  ///< motor side: τ_m, ω_m
  std::string failure;  ///< a sample that did not run to the end: its status and reason
};

/// One actuator's result in one evaluated configuration.
struct SizingEvaluation {
  std::size_t actuator = 0;   ///< into SizingFile::actuators
  std::size_t candidate = 0;  ///< into its candidates
  bool holds = false;
  SizingPoint worst;
  int configuration = 0;            ///< which configuration (0, 1, ... in the order run)
  std::vector<std::size_t> others;  ///< every actuator's candidate in that configuration
};

struct SizingChoice {
  bool found = false;
  std::size_t candidate = 0;  ///< the choice (found), or the last one tried
  SizingPoint binding;        ///< its worst point
  bool has_smaller = false;   ///< a smaller candidate was re-run with the others at their choice
  std::size_t smaller = 0;
  SizingPoint smaller_fails;                                      ///< where it fails
  double best_margin = -std::numeric_limits<double>::infinity();  ///< !found: the best seen
  std::size_t best_candidate = 0;
};

struct SizingResult {
  std::vector<SizingChoice> choices;  ///< per actuator
  std::vector<SizingEvaluation> evaluations;
  int configurations = 0;
  long runs = 0;
  bool converged = false;  ///< the iteration reached its fixed point within max_rounds
  double wall_seconds = 0.0;
  [[nodiscard]] bool all_found() const;
};

struct SizingOptions {
  int threads = 0;  ///< 0: every core
  std::ostream* progress = nullptr;
  const std::atomic<bool>* cancel = nullptr;
};

/// Sizes every actuator of the file (see the top of this header and docs/sizing.md). Throws
/// ScenarioError when a run cannot give the operating points (no u computed for an actuator).
SizingResult run_sizing(const SizingFile& file, const SizingOptions& options = {});

/// Writes sizing.json and candidates.csv into out_dir (through OutputDir).
void write_sizing(const SizingFile& file, const SizingResult& result,
                  const std::filesystem::path& out_dir);
/// sizing.json as text.
std::string sizing_json(const SizingFile& file, const SizingResult& result);
/// candidates.csv as text: actuator, candidate, motor, gearbox, size, holds, worst_margin, limit,
/// sample, t, configuration.
std::string sizing_csv(const SizingFile& file, const SizingResult& result);
/// The console table.
void print_sizing_report(std::ostream& os, const SizingFile& file, const SizingResult& result);

}  // namespace ukdyn
