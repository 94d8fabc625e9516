// Internal to the sweep (src/sweep/): the journal of a run (OUT/journal.csv), its finished rows as
// they are computed, so that an interrupted run resumes where it stopped (docs/sweeps.md).
#pragma once

#include <chrono>
#include <map>
#include <mutex>
#include <string>

#include "ukdyn/output/output_dir.hpp"
#include "ukdyn/sweep/sweep.hpp"

namespace ukdyn::sweep_detail {

/// The journal's first line: the sweep (its hash) and the shard.
std::string journal_head(const Sweep& sw, const SweepOptions& opt);

/// The rows of a previous, interrupted run of the same sweep (whole lines only): none if the
/// journal is missing or its first line is not `head`; rows of another width are dropped.
std::map<long, std::string> read_journal(const OutputDir& out, const std::string& head,
                                         std::size_t columns);

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
