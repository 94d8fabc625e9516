#include "ukdyn/scenario/scenario_file.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <string>

#include "ukdyn/text/safe_text.hpp"

namespace ukdyn {

namespace {
// The same bound as load_scenario() (src/scenario/scenario.cpp).
constexpr std::size_t kMaxScenarioBytes = std::size_t{4} << 20;

class Fd {
 public:
  explicit Fd(int fd) : fd_(fd) {}
  ~Fd() {
    if (fd_ >= 0) ::close(fd_);
  }
  Fd(const Fd&) = delete;
  Fd& operator=(const Fd&) = delete;
  [[nodiscard]] int get() const { return fd_; }

 private:
  int fd_;
};
}  // namespace

Scenario load_scenario_file(const std::filesystem::path& path, const LoadOptions& options) {
  return load_scenario_text(read_scenario_text(path), path, options);
}

std::string read_scenario_text(const std::filesystem::path& path) {
  const std::string name = printable(path.string());
  // O_NONBLOCK: opening a FIFO with no writer returns at once instead of waiting.
  const Fd fd(::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_NOCTTY | O_CLOEXEC));
  if (fd.get() < 0) {
    const int e = errno;
    if (e == ENOENT) throw ScenarioError(name + ": no such scenario file");
    throw ScenarioError(name + ": cannot open the scenario file: " + std::strerror(e));
  }
  struct stat st {};
  if (::fstat(fd.get(), &st) != 0) {
    throw ScenarioError(name + ": cannot read the scenario file: " + std::strerror(errno));
  }
  if (!S_ISREG(st.st_mode)) {
    const char* what = S_ISDIR(st.st_mode)                            ? "is a folder"
                       : S_ISFIFO(st.st_mode)                         ? "is a FIFO (named pipe)"
                       : S_ISSOCK(st.st_mode)                         ? "is a socket"
                       : (S_ISCHR(st.st_mode) || S_ISBLK(st.st_mode)) ? "is a device"
                                                                      : "is not a regular file";
    throw ScenarioError(name + ": " + what + ", not a scenario file (give a YAML file)");
  }
  if (static_cast<std::size_t>(st.st_size) > kMaxScenarioBytes) {
    throw ScenarioError(name + ": not a readable scenario (larger than 4 MiB)");
  }
  std::string text;
  char buf[65536];
  while (true) {
    const ssize_t got = ::read(fd.get(), buf, sizeof buf);
    if (got < 0) {
      if (errno == EINTR) continue;
      throw ScenarioError(name + ": cannot read the scenario file: " + std::strerror(errno));
    }
    if (got == 0) break;
    text.append(buf, static_cast<std::size_t>(got));
    if (text.size() > kMaxScenarioBytes) {
      throw ScenarioError(name + ": not a readable scenario (larger than 4 MiB)");
    }
  }
  return text;
}

}  // namespace ukdyn
