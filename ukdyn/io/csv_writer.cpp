#include "ukdyn/io/csv_writer.hpp"

#include <fmt/format.h>

#include "ukdyn/core/types.hpp"

namespace ukdyn {

CsvWriter::CsvWriter(std::filesystem::path final_path, const std::vector<std::string>& header)
    : final_path_(std::move(final_path)), columns_(header.size()) {
  part_path_ = final_path_;
  part_path_ += ".part";
  file_ = std::fopen(part_path_.c_str(), "wb");
  if (!file_) throw Error(part_path_.string() + ": cannot open for writing");
  std::string line;
  for (std::size_t i = 0; i < header.size(); ++i) {
    if (i) line += ',';
    line += header[i];
  }
  line += '\n';
  if (std::fwrite(line.data(), 1, line.size(), file_) != line.size()) {
    throw Error(part_path_.string() + ": write failed");
  }
  std::fflush(file_);
}

CsvWriter::~CsvWriter() {
  if (file_) abandon();
}

void CsvWriter::row(const std::vector<double>& values) {
  if (values.size() != columns_) throw Error("CsvWriter: row has the wrong number of columns");
  if (!file_) throw Error("CsvWriter: already closed");
  buffer_.clear();
  for (std::size_t i = 0; i < values.size(); ++i) {
    if (i) buffer_ += ',';
    fmt::format_to(std::back_inserter(buffer_), "{:.17g}", values[i]);
  }
  buffer_ += '\n';
  if (std::fwrite(buffer_.data(), 1, buffer_.size(), file_) != buffer_.size()) {
    throw Error(part_path_.string() + ": write failed (disk full?)");
  }
  if (++rows_ % 64 == 0) std::fflush(file_);
}

void CsvWriter::close() {
  if (file_) {
    std::fclose(file_);
    file_ = nullptr;
  }
}

std::filesystem::path CsvWriter::commit() {
  close();
  std::filesystem::rename(part_path_, final_path_);
  return final_path_;
}

std::filesystem::path CsvWriter::abandon() {
  close();
  auto dst = final_path_;
  dst.replace_extension(".incomplete.csv");
  std::error_code ec;
  std::filesystem::rename(part_path_, dst, ec);
  return ec ? part_path_ : dst;
}

}  // namespace ukdyn
