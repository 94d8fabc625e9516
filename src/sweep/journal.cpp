// The journal of a run (journal.hpp): written as rows finish, read back on resume.
#include "sweep/journal.hpp"

#include <fcntl.h>
#include <fmt/format.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <sstream>

#include "output/csv_reader.hpp"
#include "output/write_faults.hpp"
#include "sweep/table.hpp"

namespace ukdyn::sweep_detail {

std::string journal_head(const Sweep& sw, const SweepOptions& opt) {
  return fmt::format("# ukdyn sweep journal {} shard {}/{}", sw.hash, opt.shard, opt.shards);
}

std::map<long, std::string> read_journal(const OutputDir& out, const std::string& head,
                                         std::size_t columns) {
  std::map<long, std::string> rows;
  const int fd = ::openat(out.fd(), kJournal, O_RDONLY | O_NOFOLLOW | O_CLOEXEC | O_NONBLOCK);
  if (fd < 0) return rows;
  std::string text;
  struct stat st {};
  if (::fstat(fd, &st) == 0 && S_ISREG(st.st_mode)) {
    char buf[65536];
    ssize_t got = 0;
    while ((got = ::read(fd, buf, sizeof buf)) > 0) text.append(buf, static_cast<std::size_t>(got));
  }
  ::close(fd);
  std::istringstream is(text);
  io_detail::CsvLines lines(is, true);  // whole lines only: a torn last one is recomputed
  std::string line;
  if (!lines.next(line) || line != head) return rows;
  while (lines.next(line)) {
    const auto cells = io_detail::split_csv_line(line);
    if (cells.size() != columns) continue;
    char* e = nullptr;
    const long k = std::strtol(cells[0].c_str(), &e, 10);
    if (*e == '\0' && !cells[0].empty()) rows[k] = line;
  }
  return rows;
}

Journal::Journal(const OutputDir& out, const std::string& head,
                 const std::map<long, std::string>& keep)
    : out_(out) {
  out.require_file_or_absent(out.fd(), "", kJournal);
  // Rewritten through a temporary, so that it holds exactly the rows kept (whole lines).
  {
    AtomicFile f(out, out.fd(), "", kJournal);
    f.write(head + "\n");
    for (const auto& [k, line] : keep) f.write(line + "\n");
    f.commit();
  }
  fd_ = ::openat(out.fd(), kJournal, O_WRONLY | O_APPEND | O_NOFOLLOW | O_CLOEXEC);
  if (fd_ < 0) throw WriteFailed(out.display(kJournal) + ": " + std::strerror(errno));
  last_sync_ = std::chrono::steady_clock::now();
}

Journal::~Journal() {
  if (fd_ >= 0) {
    ::fdatasync(fd_);
    ::close(fd_);
  }
}

void Journal::append(const std::string& line) {
  const std::string s = line + "\n";
  std::lock_guard<std::mutex> lock(mu_);
  if (!error_.empty()) return;
  std::size_t done = 0;
  while (done < s.size()) {
    if (io_detail::WriteFaults::inject(out_, kJournal, s.size())) {
      error_ = out_.display(kJournal) + ": write failed: No space left on device";
      return;
    }
    const ssize_t w = ::write(fd_, s.data() + done, s.size() - done);
    if (w < 0 && errno == EINTR) continue;
    if (w <= 0) {
      error_ = out_.display(kJournal) + ": write failed: " + std::strerror(errno);
      return;
    }
    done += static_cast<std::size_t>(w);
  }
  const auto now = std::chrono::steady_clock::now();
  if (now - last_sync_ > std::chrono::seconds(1)) {
    ::fdatasync(fd_);
    last_sync_ = now;
  }
}

std::string Journal::error() {
  std::lock_guard<std::mutex> lock(mu_);
  return error_;
}

}  // namespace ukdyn::sweep_detail
