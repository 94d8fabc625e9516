#include "ukdyn/output/trajectory_table.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "core/input_file.hpp"
#include "output/csv_reader.hpp"
#include "ukdyn/core/types.hpp"

namespace ukdyn {

namespace {

// A trajectory table of any size, with the type checks of every input file (a FIFO or a folder in
// its place is named as what it is and never blocks).
detail::InputFileSpec csv_spec(const std::filesystem::path& csv) {
  return {"trajectory table", std::numeric_limits<std::size_t>::max(), csv.string()};
}

using io_detail::CsvLines;

// One row of `n` numbers ("nan", "inf" and "-inf" included, as {:.17g} writes them).
void parse_row(const std::string& line, std::size_t n, std::vector<double>& out,
               const std::filesystem::path& csv, std::size_t line_no) {
  out.resize(n);
  const char* p = line.data();
  const char* end = p + line.size();
  const char* stop = p;
  for (std::size_t k = 0; k < n; ++k) {
    stop = std::find(p, end, ',');
    if (!io_detail::parse_csv_number(std::string_view(p, static_cast<std::size_t>(stop - p)),
                                     out[k])) {
      throw Error(fmt::format("{}:{}: column {}: not a number", csv.string(), line_no, k + 1));
    }
    if (k + 1 < n && stop == end) {
      throw Error(fmt::format("{}:{}: {} values, expected {}", csv.string(), line_no, k + 1, n));
    }
    if (stop != end) p = stop + 1;
  }
  if (stop != end) {
    throw Error(fmt::format("{}:{}: more than {} values", csv.string(), line_no, n));
  }
}

}  // namespace

std::size_t count_csv_rows(const std::filesystem::path& csv) {
  detail::InputStream in(csv, csv_spec(csv));
  CsvLines lines_in(in);
  std::size_t lines = 0;
  std::string line;
  while (lines_in.next(line)) {
    if (!line.empty()) ++lines;
  }
  return lines > 0 ? lines - 1 : 0;
}

TrajectoryTable read_trajectory(const std::filesystem::path& csv, std::size_t stride) {
  stride = std::max<std::size_t>(stride, 1);
  const std::size_t total = count_csv_rows(csv);
  detail::InputStream in(csv, csv_spec(csv));
  CsvLines lines(in);
  TrajectoryTable t;
  std::string line;
  if (!lines.next(line)) throw Error(fmt::format("{}: empty (no header)", csv.string()));
  t.header = io_detail::split_csv_line(line);
  std::vector<double> row;
  std::size_t i = 0;
  while (lines.next(line)) {
    if (line.empty()) continue;
    if (i % stride == 0 || i + 1 == total) {
      parse_row(line, t.header.size(), row, csv, lines.line_no());
      t.rows.push_back(row);
    }
    ++i;
  }
  t.source_rows = i;
  return t;
}

TrajectoryTable read_trajectory_minmax(const std::filesystem::path& csv, std::size_t buckets) {
  buckets = std::max<std::size_t>(buckets, 1);
  const std::size_t total = count_csv_rows(csv);
  if (total <= 2 * buckets) return read_trajectory(csv, 1);
  detail::InputStream in(csv, csv_spec(csv));
  CsvLines lines(in);
  TrajectoryTable t;
  std::string line;
  lines.next(line);
  t.header = io_detail::split_csv_line(line);
  const std::size_t n = t.header.size();
  std::vector<double> row, lo(n), hi(n), first(n);
  std::vector<std::size_t> at_lo(n), at_hi(n);
  std::size_t i = 0, bucket = 0, in_bucket = 0;
  auto flush = [&](double t_last) {
    std::vector<double> a(n), b(n);
    a[0] = first[0];
    b[0] = t_last;
    for (std::size_t k = 1; k < n; ++k) {
      const bool lo_first = at_lo[k] <= at_hi[k];
      a[k] = lo_first ? lo[k] : hi[k];
      b[k] = lo_first ? hi[k] : lo[k];
    }
    t.rows.push_back(std::move(a));
    t.rows.push_back(std::move(b));
  };
  double t_last = 0.0;
  while (lines.next(line)) {
    if (line.empty()) continue;
    parse_row(line, n, row, csv, lines.line_no());
    // Row i belongs to bucket floor(i · buckets / total).
    const std::size_t b = i * buckets / total;
    if (b != bucket && in_bucket > 0) {
      flush(t_last);
      in_bucket = 0;
    }
    bucket = b;
    if (in_bucket == 0) {
      first = row;
      lo = row;
      hi = row;
      std::fill(at_lo.begin(), at_lo.end(), 0);
      std::fill(at_hi.begin(), at_hi.end(), 0);
    } else {
      for (std::size_t k = 1; k < n; ++k) {
        // NaN is kept (it must show in a figure as a gap, never be hidden by decimation).
        if (row[k] < lo[k] || std::isnan(row[k])) {
          lo[k] = row[k];
          at_lo[k] = in_bucket;
        }
        if (row[k] > hi[k] || std::isnan(row[k])) {
          hi[k] = row[k];
          at_hi[k] = in_bucket;
        }
      }
    }
    t_last = row[0];
    ++in_bucket;
    ++i;
  }
  if (in_bucket > 0) flush(t_last);
  t.source_rows = i;
  return t;
}

}  // namespace ukdyn
