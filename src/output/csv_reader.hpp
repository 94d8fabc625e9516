// Internal to ukdyn::io: the one reader of the CSV files ukdyn writes, for a run's trajectory.csv
// (trajectory_table.cpp) and a sweep's results.csv and journal.csv (src/sweep/): the lines of a
// file or text, the cells of a line (quoted as csv_field() writes them, ukdyn/text/safe_text.hpp)
// and numbers as {:.17g} and fmt's {} write them.
#pragma once

#include <cstddef>
#include <istream>
#include <string>
#include <string_view>
#include <vector>

namespace ukdyn::io_detail {

/// The lines of a CSV file or text, in order, each without its newline.
class CsvLines {
 public:
  /// whole_lines_only: a last line without its newline (a torn write) is not returned.
  explicit CsvLines(std::istream& in, bool whole_lines_only = false)
      : in_(in), whole_only_(whole_lines_only) {}
  /// The next line (empty lines included); false at the end.
  bool next(std::string& line);
  /// The number of the line last returned (the first is 1).
  [[nodiscard]] std::size_t line_no() const { return line_no_; }

 private:
  std::istream& in_;
  bool whole_only_;
  std::size_t line_no_ = 0;
};

/// The cells of one line: separated by commas; a cell in double quotes may hold commas, and "" in
/// it stands for one quote.
std::vector<std::string> split_csv_line(std::string_view line);

/// The index of the column `name` in `header` (header.size() when there is none); `twice` tells
/// whether it is there more than once (a state or a guess read by name must not pick one silently).
std::size_t csv_column(const std::vector<std::string>& header, std::string_view name, bool& twice);

/// A cell as a number ("nan", "inf" and "-inf" included). False (v unchanged) if it is not one.
bool parse_csv_number(std::string_view cell, double& v);

}  // namespace ukdyn::io_detail
