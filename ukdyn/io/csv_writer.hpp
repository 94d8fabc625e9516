// Streaming CSV writer: rows go to "<file>.part" as they are computed (flushed every few rows, so a
// crash keeps what was done); commit() renames it to its final name, abandon() to
// "<stem>.incomplete.csv".
#pragma once

#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

namespace ukdyn {

class CsvWriter {
 public:
  CsvWriter(std::filesystem::path final_path, const std::vector<std::string>& header);
  ~CsvWriter();
  CsvWriter(const CsvWriter&) = delete;
  CsvWriter& operator=(const CsvWriter&) = delete;

  /// Appends one row (size must equal the header's). Numbers are written with 17 significant
  /// digits.
  void row(const std::vector<double>& values);
  /// Closes and renames to the final path. Returns it.
  std::filesystem::path commit();
  /// Closes and renames to <stem>.incomplete.csv. Returns that path.
  std::filesystem::path abandon();
  [[nodiscard]] long rows_written() const { return rows_; }

 private:
  void close();
  std::filesystem::path final_path_, part_path_;
  std::FILE* file_ = nullptr;
  std::size_t columns_ = 0;
  long rows_ = 0;
  std::string buffer_;
};

}  // namespace ukdyn
