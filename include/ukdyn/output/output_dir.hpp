// The output folder of a run, handled so that ukdyn only ever touches what it creates
// (docs/scenario-format.md, "Output safety"):
//  - the folder may not be a filesystem root: not `/`, not a direct child of `/` (`/home`, `/tmp`),
//    not a mount point, also when reached through symbolic links;
//  - a lock (OUT/.ukdyn.lock, flock + the holder's pid) keeps a second run out of a busy folder;
//  - every file is written as a temporary `<name>.part` in its folder, opened with
//    O_CREAT|O_EXCL|O_NOFOLLOW (a planted symbolic link is never followed), fsync'ed and renamed
//    onto its name; a name ukdyn uses that holds anything but a regular file (a link, a folder, a
//    FIFO) is refused, never replaced;
//  - nothing is removed recursively: only regular files under ukdyn's own names.
// All operations are relative to a descriptor of the folder opened once (openat, renameat, ...), so
// renaming or replacing a path component during the run cannot redirect them.
#pragma once

#include <atomic>
#include <cstddef>
#include <filesystem>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "ukdyn/core/types.hpp"

namespace ukdyn {

/// An output folder ukdyn refuses to use (a root, a busy folder, a planted link): bad input,
/// exit 2.
class OutputRefused : public Error {
 public:
  using Error::Error;
};

/// A write that failed (disk full, quota, file size limit): the run is incomplete.
class WriteFailed : public Error {
 public:
  using Error::Error;
};

/// Throws OutputRefused if `dir` (resolved through symbolic links as far as it exists) is a
/// filesystem root: `/`, a direct child of `/`, or a mount point.
void check_output_folder(const std::filesystem::path& dir);

class OutputDir;

namespace io_detail {
struct WriteFaults;  // private to ukdyn::io (src/output/write_faults.hpp)
}

/// One file written as `<name>.part` and renamed onto `<name>` by commit(). Destroyed without
/// commit(), the temporary is removed. Writes are buffered; a failed write throws WriteFailed and
/// leaves the temporary truncated to the bytes of the last successful flush (whole records, if
/// the caller flushes between records).
class AtomicFile {
 public:
  AtomicFile(const OutputDir& dir, int dirfd, std::string prefix, std::string name);
  ~AtomicFile();
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  void write(std::string_view bytes);  ///< into the buffer (the caller flushes)
  void flush();                        ///< hands the buffer to the kernel (whole, or throws)
  [[nodiscard]] std::size_t buffered() const { return buffer_.size(); }
  /// flush + fsync + rename onto `name` (or `as`, another name in the same folder). Throws
  /// WriteFailed; after a failure the temporary is still there and commit_truncated() may follow.
  void commit(const std::string& as = {});
  /// Drops the unflushed buffer, truncates to what was flushed and renames onto `as`.
  /// Never throws; returns false if even that failed (the temporary is then removed).
  bool commit_truncated(const std::string& as) noexcept;
  [[nodiscard]] const std::string& name() const { return name_; }

 private:
  void write_all(const char* p, std::size_t n);
  const OutputDir& dir_;
  int dirfd_;
  std::string prefix_;  ///< "" or "figures/" for messages and injected failures
  std::string name_, part_;
  int fd_ = -1;
  std::string buffer_;
  std::size_t flushed_ = 0;
};

class OutputDir {
 public:
  /// Checks the folder rule, creates the folder if needed, opens it and takes its lock.
  /// Throws OutputRefused (root, busy, not a folder, cannot create).
  explicit OutputDir(const std::filesystem::path& dir);
  ~OutputDir();  ///< removes the lock file and releases the lock
  OutputDir(const OutputDir&) = delete;
  OutputDir& operator=(const OutputDir&) = delete;

  [[nodiscard]] const std::filesystem::path& path() const { return path_; }
  [[nodiscard]] int fd() const { return fd_; }

  /// Throws OutputRefused unless `name` in `dirfd` is absent or a regular file.
  void require_file_or_absent(int dirfd, const std::string& prefix, const std::string& name) const;
  /// Removes `name` if it is a regular file (never follows or removes a link, a folder, ...).
  void remove_file(int dirfd, const std::string& name) const;
  /// Opens a subfolder, creating it if absent (or returning -1 if absent and !create); refuses a
  /// link or a non-folder. Caller closes.
  int open_subdir(const std::string& name, bool create = true) const;
  /// Creates a fresh private (0700) folder `.ukdyn-render-<pid>[-k]` for a helper program's output.
  /// Returns its descriptor and sets `name`. Caller removes it (remove_private_dir).
  int make_private_dir(std::string& name) const;
  /// Removes the listed regular files from a private folder, then the folder (not recursive).
  void remove_private_dir(int fd, const std::string& name,
                          const std::vector<std::string>& files) const;
  /// Makes the renames done so far durable (fsync of the folder). Never throws.
  void sync() const noexcept;

  /// path()/rel as text, for messages.
  [[nodiscard]] std::string display(const std::string& rel) const;

 private:
  friend struct io_detail::WriteFaults;
  void lock();
  std::filesystem::path path_;
  int fd_ = -1;
  int lock_fd_ = -1;
  /// Write failures injected by ukdyn's own tests (src/output/write_faults.hpp); null otherwise.
  std::unique_ptr<io_detail::WriteFaults> faults_;
};

/// Name of the lock file inside an output folder.
inline constexpr const char* kLockFileName = ".ukdyn.lock";

}  // namespace ukdyn
