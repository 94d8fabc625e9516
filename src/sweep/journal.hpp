// Internal to the sweep (src/sweep/): the journal of a run (OUT/journal.csv), its finished rows as
// they are computed, so that an interrupted run resumes where it stopped (docs/sweeps.md).
#pragma once

#include <chrono>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include "ukdyn/output/output_dir.hpp"
#include "ukdyn/sweep/sweep.hpp"

namespace ukdyn::sweep_detail {

/// The journal's first line: the sweep (its hash) and the shard.
std::string journal_head(const Sweep& sw, const SweepOptions& opt);

/// Why `line` is not a row this sweep would write (empty if it is one), with `k` its sample. The
/// row is checked against the sweep file, not trusted: as many cells as `header`; the sample index
/// a decimal number in 0 .. samples-1; each parameter cell the value the sweep file gives that
/// sample (recomputed, compared exactly); a known status; t_reached, steps and every metric cell
/// a number (or empty, as a sample that did not run leaves them). The reason starts with the
/// column ("column 3 (mass): ..."), for `FILE:LINE:` in front of it.
std::string row_problem(const Sweep& sw, const std::vector<std::string>& header,
                        const std::string& line, long& k);

/// The rows of a previous, interrupted run of the same sweep (whole lines only): none if the
/// journal is missing or its first line is not `head`. Every row is checked (row_problem): one
/// that is not a row of this sweep is refused (ScenarioError naming the file, line and column;
/// `--fresh` starts over), and so is a sample given twice.
std::map<long, std::string> read_journal(const OutputDir& out, const std::string& head,
                                         const Sweep& sw, const std::vector<std::string>& header);

/// Append-only journal: each finished row is one write(2) of a whole line (O_APPEND); fdatasync
/// at most once a second and at the end (a killed process loses nothing the kernel has).
class Journal {
 public:
  /// Rewrites OUT/journal.csv with `head` and the rows `keep`, then opens it for appending.
  /// Throws OutputRefused or WriteFailed.
  Journal(const OutputDir& out, const std::string& head, const std::map<long, std::string>& keep);
  ~Journal();
  Journal(const Journal&) = delete;
  Journal& operator=(const Journal&) = delete;
  /// One finished row (thread-safe). A failed write is kept in error(); later rows are dropped.
  void append(const std::string& line);
  std::string error();

 private:
  const OutputDir& out_;
  int fd_ = -1;
  std::mutex mu_;
  std::string error_;
  std::chrono::steady_clock::time_point last_sync_;
};

}  // namespace ukdyn::sweep_detail
