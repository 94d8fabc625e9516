#include "ukdyn/output/output_dir.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <string>

#include "output/write_faults.hpp"

namespace ukdyn {

namespace fs = std::filesystem;

namespace {

std::string errno_text(int e) { return std::strerror(e); }

const char* kind_of(mode_t mode) {
  if (S_ISLNK(mode)) return "a symbolic link";
  if (S_ISDIR(mode)) return "a folder";
  if (S_ISFIFO(mode)) return "a FIFO";
  if (S_ISSOCK(mode)) return "a socket";
  if (S_ISCHR(mode) || S_ISBLK(mode)) return "a device";
  return "not a regular file";
}

// "/" itself, a direct child of "/" or a mount point (its device differs from its parent's, or it
// is its own parent).
bool is_root_like(const fs::path& canonical, std::string& why) {
  if (canonical == canonical.root_path()) {
    why = "the root of the file system";
    return true;
  }
  if (canonical.parent_path() == canonical.root_path()) {
    why = "a top-level folder";
    return true;
  }
  struct stat self {};
  struct stat parent {};
  if (::stat(canonical.c_str(), &self) == 0 && ::stat((canonical / "..").c_str(), &parent) == 0) {
    if (self.st_dev != parent.st_dev || self.st_ino == parent.st_ino) {
      why = "a mount point (the root of a file system)";
      return true;
    }
  }
  return false;
}

}  // namespace

void check_output_folder(const fs::path& dir) {
  if (dir.empty()) throw OutputRefused("--out: the output folder name is empty");
  std::error_code ec;
  const fs::path abs = fs::absolute(dir, ec);
  if (ec) throw OutputRefused(dir.string() + ": cannot resolve the output folder: " + ec.message());
  const fs::path canon = fs::weakly_canonical(abs, ec);
  if (ec) throw OutputRefused(dir.string() + ": cannot resolve the output folder: " + ec.message());
  std::string why;
  if (is_root_like(canon, why)) {
    throw OutputRefused(dir.string() + ": refusing to write into " + why + " (" + canon.string() +
                        "); ukdyn writes only into a folder at least two levels below / that is "
                        "not a mount point: give a subfolder, e.g. --out " +
                        (canon / "ukdyn-out").string());
  }
}

// ------------------------------------------------------------------------------------ OutputDir

OutputDir::OutputDir(const fs::path& dir) : path_(dir) {
  check_output_folder(dir);
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) throw OutputRefused(dir.string() + ": cannot create the output folder: " + ec.message());
  fd_ = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd_ < 0) {
    throw OutputRefused(dir.string() + ": cannot open the output folder: " + errno_text(errno));
  }
  // Checked again now that it exists (a link to / created meanwhile, or a folder mounted there).
  try {
    const fs::path canon = fs::canonical(dir);
    std::string why;
    struct stat a {};
    struct stat b {};
    if (is_root_like(canon, why) || ::fstat(fd_, &a) != 0 || ::stat(canon.c_str(), &b) != 0 ||
        a.st_dev != b.st_dev || a.st_ino != b.st_ino) {
      throw OutputRefused(dir.string() + ": refusing to write into " +
                          (why.empty() ? "a folder that changed while it was opened" : why) + " (" +
                          canon.string() + ")");
    }
    lock();
  } catch (...) {
    ::close(fd_);
    throw;
  }
}

void OutputDir::lock() {
  for (int attempt = 0; attempt < 20; ++attempt) {
    const int lfd = ::openat(fd_, kLockFileName, O_RDWR | O_CREAT | O_NOFOLLOW | O_CLOEXEC, 0644);
    if (lfd < 0) {
      throw OutputRefused(display(kLockFileName) +
                          ": cannot open the lock file: " + errno_text(errno) +
                          (errno == ELOOP ? " (it is a symbolic link: remove it)" : ""));
    }
    if (::flock(lfd, LOCK_EX | LOCK_NB) != 0) {
      const int e = errno;
      char buf[32] = {};
      const ssize_t got = ::pread(lfd, buf, sizeof buf - 1, 0);
      ::close(lfd);
      std::string pid = got > 0 ? std::string(buf, static_cast<std::size_t>(got)) : "";
      while (!pid.empty() && (pid.back() == '\n' || pid.back() == ' ')) pid.pop_back();
      if (pid.find_first_not_of("0123456789") != std::string::npos) pid.clear();
      if (e == EWOULDBLOCK) {
        throw OutputRefused(path_.string() + ": another ukdyn run" +
                            (pid.empty() ? "" : " (pid " + pid + ")") +
                            " is writing into this folder; wait for it to end or choose another "
                            "--out");
      }
      throw OutputRefused(display(kLockFileName) + ": cannot lock: " + errno_text(e));
    }
    // The holder before us removes the file before releasing it: make sure the file locked is the
    // one at the name (else retry with the new one).
    struct stat held {};
    struct stat named {};
    if (::fstat(lfd, &held) == 0 &&
        ::fstatat(fd_, kLockFileName, &named, AT_SYMLINK_NOFOLLOW) == 0 &&
        held.st_dev == named.st_dev && held.st_ino == named.st_ino && S_ISREG(held.st_mode)) {
      const std::string pid = std::to_string(::getpid()) + "\n";
      if (::ftruncate(lfd, 0) == 0) {
        [[maybe_unused]] const ssize_t w = ::pwrite(lfd, pid.data(), pid.size(), 0);
      }
      lock_fd_ = lfd;
      return;
    }
    ::close(lfd);
  }
  throw OutputRefused(display(kLockFileName) + ": cannot take the lock (it keeps changing)");
}

OutputDir::~OutputDir() {
  if (lock_fd_ >= 0) {
    ::unlinkat(fd_, kLockFileName, 0);
    ::close(lock_fd_);
  }
  if (fd_ >= 0) ::close(fd_);
}

std::string OutputDir::display(const std::string& rel) const { return (path_ / rel).string(); }

void io_detail::WriteFaults::set_hook(OutputDir& dir, WriteFailureHook hook) {
  dir.faults_ = hook ? std::make_unique<WriteFaults>(WriteFaults{std::move(hook)}) : nullptr;
}

bool io_detail::WriteFaults::inject(const OutputDir& dir, std::string_view name,
                                    std::size_t bytes) {
  if (dir.faults_ && dir.faults_->hook(name, bytes)) {
    errno = ENOSPC;
    return true;
  }
  return false;
}

void OutputDir::require_file_or_absent(int dirfd, const std::string& prefix,
                                       const std::string& name) const {
  struct stat st {};
  if (::fstatat(dirfd, name.c_str(), &st, AT_SYMLINK_NOFOLLOW) != 0) {
    if (errno == ENOENT) return;
    throw OutputRefused(display(prefix + name) + ": " + errno_text(errno));
  }
  if (!S_ISREG(st.st_mode)) {
    throw OutputRefused(display(prefix + name) + " is " + kind_of(st.st_mode) +
                        ", not a file ukdyn wrote: refusing to touch it (remove or rename it)");
  }
}

void OutputDir::remove_file(int dirfd, const std::string& name) const {
  require_file_or_absent(dirfd, "", name);
  if (::unlinkat(dirfd, name.c_str(), 0) != 0 && errno != ENOENT) {
    throw OutputRefused(display(name) + ": cannot remove: " + errno_text(errno));
  }
}

int OutputDir::open_subdir(const std::string& name, bool create) const {
  if (!create) {
    struct stat st {};
    if (::fstatat(fd_, name.c_str(), &st, AT_SYMLINK_NOFOLLOW) != 0 && errno == ENOENT) return -1;
  } else if (::mkdirat(fd_, name.c_str(), 0755) != 0 && errno != EEXIST) {
    throw OutputRefused(display(name) + ": cannot create: " + errno_text(errno));
  }
  const int d = ::openat(fd_, name.c_str(), O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC);
  if (d < 0) {
    struct stat st {};
    const bool known = ::fstatat(fd_, name.c_str(), &st, AT_SYMLINK_NOFOLLOW) == 0;
    throw OutputRefused(display(name) + (known ? std::string(" is ") + kind_of(st.st_mode) +
                                                     ", not a folder ukdyn made: refusing to use it"
                                               : ": cannot open: " + errno_text(errno)));
  }
  return d;
}

int OutputDir::make_private_dir(std::string& name) const {
  const std::string base = ".ukdyn-render-" + std::to_string(::getpid());
  for (int k = 0; k < 100; ++k) {
    name = k == 0 ? base : base + "-" + std::to_string(k);
    if (::mkdirat(fd_, name.c_str(), 0700) == 0) {
      const int d = ::openat(fd_, name.c_str(), O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC);
      if (d >= 0) return d;
      throw WriteFailed(display(name) + ": cannot open: " + errno_text(errno));
    }
    if (errno != EEXIST) throw WriteFailed(display(name) + ": cannot create: " + errno_text(errno));
  }
  throw WriteFailed(display(base) + ": cannot create a private folder (100 names taken)");
}

void OutputDir::remove_private_dir(int fd, const std::string& name,
                                   const std::vector<std::string>& files) const {
  for (const auto& f : files) ::unlinkat(fd, f.c_str(), 0);
  ::close(fd);
  ::unlinkat(fd_, name.c_str(), AT_REMOVEDIR);
}

void OutputDir::sync() const noexcept { ::fsync(fd_); }

// ----------------------------------------------------------------------------------- AtomicFile

AtomicFile::AtomicFile(const OutputDir& dir, int dirfd, std::string prefix, std::string name)
    : dir_(dir),
      dirfd_(dirfd),
      prefix_(std::move(prefix)),
      name_(std::move(name)),
      part_(name_ + ".part") {
  dir_.require_file_or_absent(dirfd_, prefix_, name_);
  dir_.require_file_or_absent(dirfd_, prefix_, part_);
  ::unlinkat(dirfd_, part_.c_str(), 0);  // a stale temporary (a regular file: checked above)
  fd_ = ::openat(dirfd_, part_.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0644);
  if (fd_ < 0) {
    const int e = errno;
    if (e == EEXIST || e == ELOOP) {
      throw OutputRefused(dir_.display(prefix_ + part_) +
                          ": appeared while ukdyn was opening it: refusing to touch it");
    }
    throw WriteFailed(dir_.display(prefix_ + part_) + ": cannot create: " + errno_text(e));
  }
}

AtomicFile::~AtomicFile() {
  if (fd_ >= 0) ::close(fd_);
  if (!part_.empty()) ::unlinkat(dirfd_, part_.c_str(), 0);
}

void AtomicFile::write(std::string_view bytes) {
  if (part_.empty()) throw WriteFailed(dir_.display(prefix_ + name_) + ": already closed");
  buffer_.append(bytes);
}

void AtomicFile::write_all(const char* p, std::size_t n) {
  if (io_detail::WriteFaults::inject(dir_, prefix_ + name_, n)) {
    throw WriteFailed(dir_.display(prefix_ + part_) + ": write failed: " + errno_text(ENOSPC) +
                      " (injected)");
  }
  while (n > 0) {
    const ssize_t w = ::write(fd_, p, n);
    if (w < 0) {
      if (errno == EINTR) continue;
      throw WriteFailed(dir_.display(prefix_ + part_) + ": write failed: " + errno_text(errno));
    }
    p += w;
    n -= static_cast<std::size_t>(w);
  }
}

void AtomicFile::flush() {
  if (buffer_.empty() || fd_ < 0) return;
  write_all(buffer_.data(), buffer_.size());
  flushed_ += buffer_.size();
  buffer_.clear();
}

void AtomicFile::commit(const std::string& as) {
  if (part_.empty()) throw WriteFailed(dir_.display(prefix_ + name_) + ": already closed");
  flush();
  if (::fsync(fd_) != 0) {
    throw WriteFailed(dir_.display(prefix_ + part_) + ": fsync failed: " + errno_text(errno));
  }
  const int fd = fd_;
  fd_ = -1;
  if (::close(fd) != 0) {
    throw WriteFailed(dir_.display(prefix_ + part_) + ": close failed: " + errno_text(errno));
  }
  const std::string& target = as.empty() ? name_ : as;
  dir_.require_file_or_absent(dirfd_, prefix_, target);
  if (::renameat(dirfd_, part_.c_str(), dirfd_, target.c_str()) != 0) {
    throw WriteFailed(dir_.display(prefix_ + target) + ": rename failed: " + errno_text(errno));
  }
  part_.clear();
}

bool AtomicFile::commit_truncated(const std::string& as) noexcept {
  if (part_.empty()) return false;
  buffer_.clear();
  bool ok = true;
  if (fd_ >= 0) {
    ok = ::ftruncate(fd_, static_cast<off_t>(flushed_)) == 0;
    ::close(fd_);
    fd_ = -1;
  }
  struct stat st {};
  const bool target_ok = ::fstatat(dirfd_, as.c_str(), &st, AT_SYMLINK_NOFOLLOW) != 0
                             ? errno == ENOENT
                             : S_ISREG(st.st_mode);
  if (ok && target_ok && ::renameat(dirfd_, part_.c_str(), dirfd_, as.c_str()) == 0) {
    part_.clear();
    return true;
  }
  ::unlinkat(dirfd_, part_.c_str(), 0);
  part_.clear();
  return false;
}

}  // namespace ukdyn
