// Streaming CSV writer: rows go to "<name>.part" in the output folder as they are computed (handed
// to the kernel every 64 rows, so a crash keeps what was done); commit() renames it onto its name,
// abandon() onto "<stem>.incomplete.csv" holding whole rows only.
#pragma once

#include <string>
#include <vector>

#include "ukdyn/output/output_dir.hpp"

namespace ukdyn {

class CsvWriter {
 public:
  /// Writes the header. Throws OutputRefused (a link or folder at the name) or WriteFailed.
  CsvWriter(const OutputDir& dir, std::string name, const std::vector<std::string>& header);

  /// Appends one row (size must equal the header's). Each number is written as its shortest text
  /// that reads back to the same double (std::to_chars's). Throws WriteFailed.
  void row(const std::vector<double>& values);
  /// flush + fsync + rename onto the name. Throws WriteFailed (then abandon() may follow).
  void commit();
  /// Renames what was written, cut after the last whole row, onto <stem>.incomplete.csv.
  /// Returns that name, or "" if even that failed (the temporary is then removed). Never throws.
  std::string abandon() noexcept;
  /// Rows in the file (those handed to the kernel; after commit(), all of them).
  [[nodiscard]] long rows_written() const { return rows_flushed_; }
  [[nodiscard]] static std::string incomplete_name(const std::string& name);

 private:
  AtomicFile file_;
  std::size_t columns_ = 0;
  long rows_ = 0, rows_flushed_ = 0;
  std::string buffer_;
};

}  // namespace ukdyn
