// Reading back a run's CSV (trajectory.csv as csv_writer.hpp writes it: a header line, then rows of
// numbers separated by commas): whole, every k-th row, or decimated to a bounded number of rows
// that keeps every column's extrema (for the figures of long runs and the replay page).
#pragma once

#include <cstddef>
#include <filesystem>
#include <string>
#include <vector>

namespace ukdyn {

struct TrajectoryTable {
  std::vector<std::string> header;
  std::vector<std::vector<double>> rows;
  std::size_t source_rows = 0;  ///< data rows in the file (rows may hold fewer)
};

/// Number of data rows of a CSV file (lines after the header). Throws ukdyn::Error if unreadable.
std::size_t count_csv_rows(const std::filesystem::path& csv);

/// Reads the header and every `stride`-th row (the first and the last always). Throws ukdyn::Error
/// naming file:line for a row that is not `header.size()` numbers.
TrajectoryTable read_trajectory(const std::filesystem::path& csv, std::size_t stride = 1);

/// At most about 2·buckets rows (after [Jugel2014]'s M4, without its first/last rows): the rows
/// split by index into `buckets` runs of consecutive rows; each run gives two rows, at its first
/// and last time (column 0), holding for every other column its minimum and maximum over the run in
/// the order they occur (so a curve drawn through them reaches every extreme of the original,
/// within one bucket in time). Files with at most 2·buckets rows are returned whole.
TrajectoryTable read_trajectory_minmax(const std::filesystem::path& csv, std::size_t buckets);

}  // namespace ukdyn
