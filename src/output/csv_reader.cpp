#include "output/csv_reader.hpp"

#include <charconv>
#include <limits>

namespace ukdyn::io_detail {

bool CsvLines::next(std::string& line) {
  if (!std::getline(in_, line)) return false;
  if (whole_only_ && in_.eof()) return false;  // the last line has no newline
  ++line_no_;
  return true;
}

std::vector<std::string> split_csv_line(std::string_view line) {
  std::vector<std::string> out;
  std::string cur;
  bool quoted = false;
  for (std::size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (quoted) {
      if (c == '"' && i + 1 < line.size() && line[i + 1] == '"') {
        cur += '"';
        ++i;
      } else if (c == '"') {
        quoted = false;
      } else {
        cur += c;
      }
    } else if (c == '"') {
      quoted = true;
    } else if (c == ',') {
      out.push_back(cur);
      cur.clear();
    } else {
      cur += c;
    }
  }
  out.push_back(cur);
  return out;
}

std::size_t csv_column(const std::vector<std::string>& header, std::string_view name, bool& twice) {
  std::size_t found = header.size();
  twice = false;
  for (std::size_t c = 0; c < header.size(); ++c) {
    if (header[c] != name) continue;
    if (found != header.size()) twice = true;
    if (found == header.size()) found = c;
  }
  return found;
}

bool parse_csv_number(std::string_view cell, double& v) {
  double x = 0.0;
  const char* end = cell.data() + cell.size();
  const auto r = std::from_chars(cell.data(), end, x);
  if (r.ec == std::errc() && r.ptr == end) {
    v = x;
    return true;
  }
  if (cell == "nan" || cell == "-nan") {
    v = std::numeric_limits<double>::quiet_NaN();
  } else if (cell == "inf") {
    v = std::numeric_limits<double>::infinity();
  } else if (cell == "-inf") {
    v = -std::numeric_limits<double>::infinity();
  } else {
    return false;
  }
  return true;
}

}  // namespace ukdyn::io_detail
