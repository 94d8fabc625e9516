// The `ukdyn eval` protocol: JSON lines {"t", "q", "qd", "tau"} in, one JSON line out per input
// line with M, C, C q̇, G, Q, A, b, Qc, q̈, rank, residual, consistent (docs/scenario-format.md,
// "ukdyn eval"). A line that cannot be answered (invalid JSON, an unknown key, wrong sizes, a
// non-finite number, a singular mass matrix, a non-finite result) gets an error object
// {"line": N, "error": "SOURCE:N: ..."} instead; results are only ever printed when finite.
#pragma once

#include <cstddef>
#include <iosfwd>
#include <string>
#include <vector>

#include "ukdyn/scenario/scenario.hpp"

namespace ukdyn {

struct EvalOptions {
  std::string source = "stdin";                       ///< named in the error messages
  std::size_t max_line_bytes = std::size_t{1} << 20;  ///< longer lines are an error
  /// M with a reciprocal condition estimate (LLT) under this counts as singular.
  double min_rcond = 1e-13;
};

struct EvalCounts {
  long lines = 0;     ///< non-blank lines read
  long failures = 0;  ///< lines answered with an error object
};

/// Answers every line of `in` on `out`; each error is also written, escaped, to `err` if set.
/// `ukdyn eval` exits 1 if failures > 0.
EvalCounts run_eval_protocol(const Scenario& scenario, std::istream& in, std::ostream& out,
                             std::ostream* err, const EvalOptions& options = {});

/// `ukdyn linearize`: the exact derivatives of q̈ and Qc at (t, q, q̇, τ) (ukdyn/model/linearize.hpp)
/// and the state-space matrices F, G of x = (q, q̇), as one JSON object on `out`
/// (docs/derivatives.md). Returns whether ukdyn vouches for them (the object's "trusted"; its
/// "message" says why not). Throws ukdyn::Error when a component has no exact derivatives.
/// With options.minimal the object also holds "minimal": the reduced model in minimal coordinates
/// on the constraint manifold (ukdyn/model/minimal_linearize.hpp); with options.dt > 0 the
/// zero-order-hold discrete matrices "Fd", "Gd" (and the minimal model's). Throws ukdyn::Error when
/// a component has no exact derivatives or a row is velocity-level (minimal).
struct LinearizeOptions {
  bool minimal = false;
  double dt = 0.0;  ///< > 0: also the discrete model with this step
  /// Named parameters of the scenario file (ukdyn/run/sensitivity.hpp): also the object
  /// "parameters" with ∂q̈/∂p, ∂Qc/∂p and d(q0, q̇0)/dp (docs/derivatives.md, "Sensitivities to
  /// parameters").
  std::vector<std::string> parameters = {};
  /// A control scenario's closed loop (ukdyn/run/closed_loop_derivatives.hpp): the plant (physical
  /// rows only) under the law's τ(t, q, q̇), F and the minimal model with the law's ∂τ/∂(q, q̇)
  /// folded in, and the object "closed_loop" (τ, u, ∂τ/∂q, ∂τ/∂q̇, the eigenvalues of the
  /// minimal F, the law's kinks). τ is the law's, not the state's; not with parameters.
  bool closed_loop = false;
  /// Where to say that the state is off the constraints (|Φ| or |A q̇ + Φ_t| above the scenario's
  /// initial_tolerance: a hand-written --state, a quaternion not of unit norm); null: the JSON's
  /// "constraint_residuals" only.
  std::ostream* warnings = nullptr;
};
bool write_linearization(const Scenario& scenario, double t, const Vec& q, const Vec& qd,
                         const Vec& tau, std::ostream& out, const LinearizeOptions& options = {});

/// The state to linearise at, from a JSON file {"t": T, "q": [...], "qd": [...], "tau": [...]}
/// (t and tau optional: the scenario's t0 and τ) or from data row `row` (0: the first row after
/// the header) of a run's trajectory.csv (t, the coordinates by name and <name>_dot; τ is the
/// scenario's, the CSV does not hold it). Throws ukdyn::Error naming the file, the line and the key.
struct LinearizeState {
  double t = 0.0;
  Vec q, qd, tau;
};
/// The same numbers as numpy's .npz (uncompressed; numpy.load reads it): every number, boolean,
/// vector and matrix of the JSON object as a float64 array under its key, the "derivatives" ones
/// under their own names, the "minimal" ones as minimal_<key>, the "parameters" ones as
/// parameters_<key>; names and messages are JSON only.
bool write_linearization_npz(const Scenario& scenario, double t, const Vec& q, const Vec& qd,
                             const Vec& tau, std::ostream& out,
                             const LinearizeOptions& options = {});

/// How far (t, q, q̇) is off the constraints: the largest |Φ| and |A q̇ + Φ_t| over every row and
/// the row of the larger; `warning` says so when that exceeds `tolerance` (empty otherwise).
struct ConstraintOffset {
  double position = 0.0, velocity = 0.0;
  std::string row, warning;
};
ConstraintOffset constraint_offset(const System& system, double t, const Vec& q, const Vec& qd,
                                   double tolerance);

LinearizeState read_state_json(const Scenario& scenario, const std::string& path);
LinearizeState read_state_csv_row(const Scenario& scenario, const std::string& path, long row);

}  // namespace ukdyn
