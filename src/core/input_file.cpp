// The one reader of input files (input_file.hpp).
#include "core/input_file.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace ukdyn::detail {

namespace {

const char* kind_of(mode_t mode) {
  if (S_ISDIR(mode)) return "is a folder";
  if (S_ISFIFO(mode)) return "is a FIFO (named pipe)";
  if (S_ISSOCK(mode)) return "is a socket";
  if (S_ISCHR(mode) || S_ISBLK(mode)) return "is a device";
  return "is not a regular file";
}

std::string too_large(const std::string& name, const InputFileSpec& spec) {
  const std::size_t mib = spec.max_bytes / kMiB;
  return name + ": larger than " +
         (mib > 0 ? std::to_string(mib) + " MiB" : std::to_string(spec.max_bytes) + " bytes") +
         ", not a readable " + spec.what;
}

}  // namespace

InputFd::InputFd(const std::filesystem::path& path, const InputFileSpec& spec) {
  const std::string name = spec.shown.empty() ? path.string() : spec.shown;
  int flags = O_RDONLY | O_NONBLOCK | O_NOCTTY | O_CLOEXEC;
  if (spec.dir_fd >= 0) flags |= O_NOFOLLOW;
  fd_ = ::openat(spec.dir_fd >= 0 ? spec.dir_fd : AT_FDCWD, path.c_str(), flags);
  if (fd_ < 0) {
    const int e = errno;
    if (e == ENOENT) throw InputFileError(name + ": no such " + spec.what, true);
    if (e == ELOOP && spec.dir_fd >= 0)
      throw InputFileError(name + ": is a symbolic link, not a " + spec.what, false);
    throw InputFileError(name + ": cannot open the " + spec.what + ": " + std::strerror(e), false);
  }
  struct stat st {};
  std::string why;
  if (::fstat(fd_, &st) != 0) {
    why = name + ": cannot read the " + spec.what + ": " + std::strerror(errno);
  } else if (!S_ISREG(st.st_mode)) {
    why = name + ": " + kind_of(st.st_mode) + ", not a " + spec.what;
  } else if (static_cast<std::size_t>(st.st_size) > spec.max_bytes) {
    why = too_large(name, spec);
  }
  if (!why.empty()) {
    ::close(fd_);
    fd_ = -1;
    throw InputFileError(why, false);
  }
  // Reads block from here on (a regular file never waits; O_NONBLOCK only kept a FIFO's open
  // from waiting for a writer).
  ::fcntl(fd_, F_SETFL, ::fcntl(fd_, F_GETFL) & ~O_NONBLOCK);
}

InputFd::~InputFd() {
  if (fd_ >= 0) ::close(fd_);
}

std::string read_input_file(const std::filesystem::path& path, const InputFileSpec& spec) {
  const InputFd fd(path, spec);
  const std::string name = spec.shown.empty() ? path.string() : spec.shown;
  std::string text;
  char buf[65536];
  while (true) {
    const ssize_t got = ::read(fd.get(), buf, sizeof buf);
    if (got < 0) {
      if (errno == EINTR) continue;
      throw InputFileError(name + ": cannot read the " + spec.what + ": " + std::strerror(errno),
                           false);
    }
    if (got == 0) break;
    text.append(buf, static_cast<std::size_t>(got));
    if (text.size() > spec.max_bytes) throw InputFileError(too_large(name, spec), false);
  }
  return text;
}

InputStream::InputStream(const std::filesystem::path& path, const InputFileSpec& spec)
    : std::istream(nullptr), fd_(path, spec), buf_(fd_.get()) {
  rdbuf(&buf_);
}

InputStream::Buf::int_type InputStream::Buf::underflow() {
  if (gptr() < egptr()) return traits_type::to_int_type(*gptr());
  ssize_t got = 0;
  do {
    got = ::read(fd_, buf_, sizeof buf_);
  } while (got < 0 && errno == EINTR);
  if (got <= 0) return traits_type::eof();
  setg(buf_, buf_, buf_ + got);
  return traits_type::to_int_type(*gptr());
}

}  // namespace ukdyn::detail
