// The journal of a run (journal.hpp): written as rows finish, read back on resume.
#include "sweep/journal.hpp"

#include <fcntl.h>
#include <fmt/format.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <sstream>

#include "core/input_file.hpp"
#include "output/csv_reader.hpp"
#include "output/write_faults.hpp"
#include "sweep/scenario_tree.hpp"
#include "sweep/table.hpp"
#include "ukdyn/text/safe_text.hpp"

namespace ukdyn::sweep_detail {

std::string journal_head(const Sweep& sw, const SweepOptions& opt) {
  return fmt::format("# ukdyn sweep journal {} shard {}/{}", sw.hash, opt.shard, opt.shards);
}

namespace {

bool known_status(const std::string& s) {
  for (const char* k : {"error", "assembly_failed", "inconsistent_initial", "invalid_scenario"})
    if (s == k) return true;
  for (const RunStatus r :
       {RunStatus::completed, RunStatus::non_finite, RunStatus::inconsistent_constraints,
        RunStatus::step_failure, RunStatus::stopped, RunStatus::branch_switch})
    if (s == to_string(r)) return true;
  return false;
}

}  // namespace

std::string row_problem(const Sweep& sw, const std::vector<std::string>& header,
                        const std::string& line, long& k) {
  const auto cells = io_detail::split_csv_line(line);
  if (cells.size() != header.size())
    return fmt::format("column {}: {} cells, the sweep's table has {}",
                       std::min(cells.size(), header.size()) + 1, cells.size(), header.size());
  const auto col = [&](std::size_t c) { return fmt::format("column {} ({})", c + 1, header[c]); };
  const std::string& ks = cells[0];
  if (ks.empty() || ks.size() > 18 ||
      !std::all_of(ks.begin(), ks.end(), [](char c) { return c >= '0' && c <= '9'; }))
    return col(0) + ": '" + printable(ks) + "' is not a sample index";
  k = std::strtol(ks.c_str(), nullptr, 10);
  if (k >= sw.samples)
    return fmt::format("{}: sample {}, but the sweep file has samples 0..{}", col(0), k,
                       sw.samples - 1);
  const std::vector<double> vals = sample_values(sw, k);
  for (std::size_t i = 0; i < vals.size(); ++i) {
    double v = 0.0;
    const std::string& cell = cells[1 + i];
    if (!io_detail::parse_csv_number(cell, v) || !(v == vals[i]))
      return fmt::format("{}: '{}', but the sweep file gives sample {} the value {}", col(1 + i),
                         printable(cell), k, num(vals[i]));
  }
  const std::size_t st = 1 + vals.size();
  if (!known_status(cells[st]))
    return col(st) + ": '" + printable(cells[st]) + "' is not a status of a sample";
  for (std::size_t c = st + 2; c < cells.size(); ++c) {
    double v = 0.0;
    if (!cells[c].empty() && !io_detail::parse_csv_number(cells[c], v))
      return col(c) + ": '" + printable(cells[c]) + "' is not a number";
  }
  return {};
}

std::map<long, std::string> read_journal(const OutputDir& out, const std::string& head,
                                         const Sweep& sw, const std::vector<std::string>& header) {
  std::map<long, std::string> rows;
  std::string text;
  try {  // the checks of every input file, inside the held folder and never through a link
    text = detail::read_input_file(
        kJournal, {"sweep journal", 1024 * detail::kMiB, out.display(kJournal), out.fd()});
  } catch (const detail::InputFileError& e) {
    if (e.missing()) return rows;
    throw ScenarioError(e.what());
  }
  std::istringstream is(text);
  io_detail::CsvLines lines(is, true);  // whole lines only: a torn last one is recomputed
  std::string line;
  if (!lines.next(line) || line != head) return rows;
  while (lines.next(line)) {
    long k = -1;
    std::string why = row_problem(sw, header, line, k);
    if (why.empty() && rows.count(k)) why = fmt::format("column 1: sample {} given twice", k);
    if (!why.empty())
      throw ScenarioError(
          fmt::format("{}:{}: {}; not a row of this sweep (run with --fresh to "
                      "start over)",
                      out.display(kJournal), lines.line_no(), why));
    rows[k] = line;
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
