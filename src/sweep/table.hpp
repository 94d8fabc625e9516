// Internal to the sweep (src/sweep/): the table of a sweep (results.csv, its rows by sample), what
// is written from it (summary.json, figures/) and the names of the files in the output folder.
#pragma once

#include <atomic>
#include <cstddef>
#include <limits>
#include <map>
#include <string>
#include <string_view>
#include <vector>

#include "output/csv_reader.hpp"
#include "ukdyn/output/output_dir.hpp"
#include "ukdyn/sweep/sweep.hpp"

namespace ukdyn::sweep_detail {

inline constexpr const char* kTable = "results.csv";
inline constexpr const char* kSummary = "summary.json";
inline constexpr const char* kJournal = "journal.csv";

struct Table {
  std::vector<std::string> header;
  std::map<long, std::string> rows;  // by sample index
};

/// The first metric column (after sample, parameters, status, reason, t_reached, steps).
inline std::size_t first_metric(const Sweep& sw) { return 1 + sw.parameters.size() + 4; }

/// A cell of the table as a number; NaN if it is empty or not a number.
inline double parse_cell(std::string_view cell) {
  double v = std::numeric_limits<double>::quiet_NaN();
  io_detail::parse_csv_number(cell, v);  // v unchanged if it is not a number
  return v;
}
/// The header as a line of the table (without its newline).
std::string header_line(const std::vector<std::string>& h);

/// results.csv and summary.json (with the figures when the table is complete and the sweep draws
/// them); opt: null when merging shards. Fills rep's table, summary, failed, failures and figures.
void write_outputs(const OutputDir& out, const Sweep& sw, const Table& t, const SweepOptions* opt,
                   bool complete, SweepReport& rep, const std::atomic<bool>* cancel);

/// Histograms of each metric (completed samples), and a heat map of each metric over a 2-D grid:
/// figures/ (figures.cpp). Sets rep.figures and rep.figure_error.
void draw_figures(const OutputDir& out, const Sweep& sw, const Table& t, SweepReport& rep,
                  const std::atomic<bool>* cancel);

}  // namespace ukdyn::sweep_detail
