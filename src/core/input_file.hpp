// The one reader of the files ukdyn reads (scenarios, plants, sweep files and their base scenario,
// URDF and MJCF models and their includes, problem files, guess and shard tables, journals, a run
// folder's summary.json). Internal, included as "core/input_file.hpp" by the libraries; the rules
// are documented once, in docs/scenario-format.md ("Files ukdyn reads").
#pragma once

#include <cstddef>
#include <filesystem>
#include <istream>
#include <streambuf>
#include <string>

#include "ukdyn/core/types.hpp"

namespace ukdyn::detail {

/// A file ukdyn cannot read as input; what() names it ("NAME: is a FIFO (named pipe), not a
/// scenario file"). `missing`: it does not exist (some callers treat that as "none").
class InputFileError : public Error {
 public:
  InputFileError(const std::string& message, bool missing) : Error(message), missing_(missing) {}
  [[nodiscard]] bool missing() const { return missing_; }

 private:
  bool missing_;
};

inline constexpr std::size_t kMiB = std::size_t{1} << 20;

/// What is read and how much of it may be: `what` names it in messages ("scenario file"),
/// `shown` is the name printed for it (already made printable by the caller; the path if empty).
struct InputFileSpec {
  std::string what = {};
  std::size_t max_bytes = 4 * kMiB;
  std::string shown = {};
  /// Resolve relative to this open folder and never follow a symbolic link at the last step
  /// (files inside an output folder); -1: relative to the working folder, links followed.
  int dir_fd = -1;
};

/// The whole text of a regular file. Opened O_RDONLY | O_NONBLOCK | O_NOCTTY | O_CLOEXEC (a FIFO
/// without a writer never blocks) and checked with fstat on the open descriptor (no window
/// between the check and the read): a folder, FIFO, socket or device is refused and named as
/// what it is, a file larger than max_bytes is refused from its size and again while reading (a
/// file that grows). Throws InputFileError.
std::string read_input_file(const std::filesystem::path& path, const InputFileSpec& spec);

/// The open, checked descriptor of an input file (the checks of read_input_file, the size from
/// fstat only): for a file read as a stream (a trajectory.csv of any size). Closed on destruction.
class InputFd {
 public:
  InputFd(const std::filesystem::path& path, const InputFileSpec& spec);
  ~InputFd();
  InputFd(const InputFd&) = delete;
  InputFd& operator=(const InputFd&) = delete;
  [[nodiscard]] int get() const { return fd_; }

 private:
  int fd_ = -1;
};

/// An input file as a std::istream, read through its checked descriptor (no second open by name).
class InputStream : public std::istream {
 public:
  InputStream(const std::filesystem::path& path, const InputFileSpec& spec);

 private:
  class Buf : public std::streambuf {
   public:
    explicit Buf(int fd) : fd_(fd) {}

   protected:
    int_type underflow() override;

   private:
    int fd_;
    char buf_[65536];
  };
  InputFd fd_;
  Buf buf_;
};

}  // namespace ukdyn::detail
