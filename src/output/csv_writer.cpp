#include "ukdyn/output/csv_writer.hpp"

#include <charconv>
#include <system_error>

#include "ukdyn/text/safe_text.hpp"

namespace ukdyn {

CsvWriter::CsvWriter(const OutputDir& dir, std::string name, const std::vector<std::string>& header)
    : file_(dir, dir.fd(), "", std::move(name)), columns_(header.size()) {
  std::string line;
  for (std::size_t i = 0; i < header.size(); ++i) {
    if (i) line += ',';
    line += csv_field(header[i]);
  }
  line += '\n';
  file_.write(line);
  file_.flush();
}

void CsvWriter::row(const std::vector<double>& values) {
  if (values.size() != columns_) throw Error("CsvWriter: row has the wrong number of columns");
  // Each number in its shortest form that reads back to the same double (std::to_chars without a
  // precision: Ryū's shortest round trip, several times faster than 17 fixed significant digits,
  // and exact: the CSV holds the run's doubles bit for bit).
  buffer_.clear();
  char num[32];
  for (std::size_t i = 0; i < values.size(); ++i) {
    if (i) buffer_ += ',';
    const auto r = std::to_chars(num, num + sizeof num, values[i]);
    if (r.ec != std::errc{}) throw Error("CsvWriter: a number does not fit 32 characters");
    buffer_.append(num, r.ptr);
  }
  buffer_ += '\n';
  file_.write(buffer_);
  ++rows_;
  if (rows_ % 64 == 0 || file_.buffered() > (std::size_t{1} << 20)) {
    file_.flush();
    rows_flushed_ = rows_;
  }
}

void CsvWriter::commit() {
  file_.commit();
  rows_flushed_ = rows_;
}

std::string CsvWriter::incomplete_name(const std::string& name) {
  const auto dot = name.rfind('.');
  return (dot == std::string::npos ? name : name.substr(0, dot)) + ".incomplete.csv";
}

std::string CsvWriter::abandon() noexcept {
  try {
    file_.flush();
    rows_flushed_ = rows_;
  } catch (...) {  // the disk is full: keep the rows handed over before
  }
  std::string as;
  try {
    as = incomplete_name(file_.name());
  } catch (...) {
    return {};
  }
  return file_.commit_truncated(as) ? as : std::string{};
}

}  // namespace ukdyn
