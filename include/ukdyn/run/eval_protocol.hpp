// The `ukdyn eval` protocol: JSON lines {"t", "q", "qd", "tau"} in, one JSON line out per input
// line with M, C, C q̇, G, Q, A, b, Qc, q̈, rank, residual, consistent (docs/scenario-format.md,
// "ukdyn eval"). A line that cannot be answered (invalid JSON, an unknown key, wrong sizes, a
// non-finite number, a singular mass matrix, a non-finite result) gets an error object
// {"line": N, "error": "SOURCE:N: ..."} instead; results are only ever printed when finite.
#pragma once

#include <cstddef>
#include <iosfwd>
#include <string>

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
bool write_linearization(const Scenario& scenario, double t, const Vec& q, const Vec& qd,
                         const Vec& tau, std::ostream& out);

}  // namespace ukdyn
