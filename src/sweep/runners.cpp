// Running a sweep (docs/sweeps.md): this shard's samples, resumed from the journal, computed by a
// pool of threads (and, under MPI, by the ranks, gathered on rank 0), then the table written; and
// the merge of the tables of shards.
#include <fmt/format.h>

#include <algorithm>
#include <charconv>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <sstream>
#include <thread>

#include "core/input_file.hpp"
#include "output/csv_reader.hpp"
#include "sweep/journal.hpp"
#include "sweep/report.hpp"
#include "sweep/sample.hpp"
#include "sweep/scenario_tree.hpp"
#include "sweep/table.hpp"
#include "ukdyn/scenario/scenario_file.hpp"
#include "ukdyn/sweep/sweep.hpp"
#include "ukdyn/text/safe_text.hpp"

namespace ukdyn {

namespace sweep_detail {
namespace {

// The samples of this shard (k % shards == shard).
std::vector<long> shard_sample_indices(const Sweep& sw, const SweepOptions& opt) {
  std::vector<long> shard_samples;
  for (long k = opt.shard; k < sw.samples; k += opt.shards) shard_samples.push_back(k);
  return shard_samples;
}

// The summary and table of an earlier run go first, the summary before anything is checked:
// nothing on disk may describe another run, even when this one is refused.
void clear_previous_sweep(const OutputDir& out) {
  for (const char* f : {kSummary, kTable}) {
    out.require_file_or_absent(out.fd(), "", f);
    out.remove_file(out.fd(), f);
  }
}

// Rank 0's output folder: the earlier table and summary removed, the rows of an interrupted run of
// this shard read back from its journal (`done`), and the journal opened (one process only).
void open_sweep_output(const Sweep& sw, const SweepOptions& opt,
                       const std::filesystem::path& out_dir, const std::string& head,
                       const std::vector<std::string>& header, int size,
                       std::optional<OutputDir>& out, std::map<long, std::string>& done,
                       std::optional<Journal>& journal) {
  out.emplace(out_dir);
  clear_previous_sweep(*out);
  if (opt.resume && size == 1) done = read_journal(*out, head, sw, header);
  for (auto it = done.begin(); it != done.end();) {  // rows of this shard only
    it = (it->first % opt.shards == opt.shard && it->first < sw.samples) ? std::next(it)
                                                                         : done.erase(it);
  }
  if (size == 1) journal.emplace(*out, head, done);
}

// This rank's share of the shard's samples, less those already done.
std::vector<long> rank_todo(const std::vector<long>& shard_samples,
                            const std::map<long, std::string>& done, int rank, int size) {
  std::vector<long> todo;
  for (std::size_t i = 0; i < shard_samples.size(); ++i) {
    if (static_cast<int>(i % static_cast<std::size_t>(size)) != rank) continue;
    if (!done.count(shard_samples[i])) todo.push_back(shard_samples[i]);
  }
  return todo;
}

// Worker threads: opt.threads (or every core), at most one per sample to compute.
int pool_threads(const SweepOptions& opt, std::size_t todo) {
  int threads = opt.threads > 0
                    ? opt.threads
                    : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  threads = static_cast<int>(
      std::min<std::size_t>(static_cast<std::size_t>(threads), std::max<std::size_t>(todo, 1)));
  return threads;
}

// The rows of the samples `todo` (empty: cancelled), computed by a pool of threads, each appended
// to the journal (if any) as it is done; progress from this thread while the pool works.
std::vector<std::string> compute_rows(SampleRunner& runner, const std::vector<long>& todo,
                                      Journal* journal, const SweepOptions& opt, int rank,
                                      std::chrono::steady_clock::time_point start) {
  const int threads = pool_threads(opt, todo.size());
  std::vector<std::string> rows(todo.size());
  std::atomic<std::size_t> next{0}, finished{0};
  {
    std::vector<std::jthread> pool;
    for (int t = 0; t < threads; ++t) {
      pool.emplace_back([&] {
        while (!(opt.cancel && opt.cancel->load())) {
          const std::size_t i = next.fetch_add(1);
          if (i >= todo.size()) break;
          rows[i] = runner.row(todo[i], opt.cancel);
          if (!rows[i].empty() && journal) journal->append(rows[i]);
          finished.fetch_add(1);
        }
      });
    }
    // Progress from this thread while the pool works.
    auto last = std::chrono::steady_clock::now();
    while (finished.load() < todo.size() && !(opt.cancel && opt.cancel->load())) {
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
      const auto now = std::chrono::steady_clock::now();
      const double every = opt.progress_tty ? 0.2 : opt.progress_every;
      if (std::chrono::duration<double>(now - last).count() >= every) {
        report_sweep_progress(opt, rank, start, finished, todo.size(), false);
        last = now;
      }
    }
    for (auto& th : pool) th.join();
    if (opt.progress_tty || finished.load() > 0)
      report_sweep_progress(opt, rank, start, finished, todo.size(), true);
  }
  return rows;
}

// Gather (MPI): every rank's rows into rank 0's table t. Returns false on the other ranks (their
// part is done).
// Each row is checked as a resumed one is (row_problem); one that fails is left out and named.
bool gather_rows(SweepComm& comm, int rank, const std::vector<std::string>& rows, const Sweep& sw,
                 Table& t, SweepReport& rep) {
  std::string mine;
  if (rank != 0)
    for (const auto& r : rows)
      if (!r.empty()) mine += r + "\n";
  const auto all = comm.gather(mine);
  if (rank != 0) return false;
  for (const auto& blob : all) {
    std::istringstream is(blob);
    io_detail::CsvLines lines(is);
    std::string line;
    while (lines.next(line)) {
      long k = -1;
      if (const std::string why = row_problem(sw, t.header, line, k); !why.empty()) {
        rep.failures.push_back("a rank's row refused: " + why);
        continue;
      }
      t.rows[k] = line;
      ++rep.computed;
    }
  }
  return true;
}

// The rows of shard i of n (its results.csv) into t, each checked against the sweep file
// (row_problem), in this shard and given once; a bad one is refused naming the file, line and
// column.
void merge_shard_rows(const Sweep& sw, const std::filesystem::path& table, int i, int n, Table& t) {
  const std::string shown = printable(table.string());
  std::istringstream is(read_text(table, "shard table", 1024 * detail::kMiB));
  io_detail::CsvLines lines(is);
  std::string line;
  lines.next(line);
  if (line != header_line(t.header)) throw ScenarioError(shown + ":1: another header");
  while (lines.next(line)) {
    if (line.empty()) continue;
    long k = -1;
    std::string why = row_problem(sw, t.header, line, k);
    if (why.empty() && k % n != i)
      why = fmt::format("column 1: sample {} belongs to shard {}/{}, not to shard {}/{}", k, k % n,
                        n, i, n);
    if (why.empty() && t.rows.count(k)) why = fmt::format("column 1: sample {} given twice", k);
    if (!why.empty()) throw ScenarioError(fmt::format("{}:{}: {}", shown, lines.line_no(), why));
    t.rows[k] = line;
  }
}

}  // namespace
}  // namespace sweep_detail

using sweep_detail::clear_previous_sweep;
using sweep_detail::compute_rows;
using sweep_detail::gather_rows;
using sweep_detail::header_line;
using sweep_detail::Journal;
using sweep_detail::journal_head;
using sweep_detail::kSummary;
using sweep_detail::kTable;
using sweep_detail::merge_shard_rows;
using sweep_detail::open_sweep_output;
using sweep_detail::rank_todo;
using sweep_detail::read_text;
using sweep_detail::SampleRunner;
using sweep_detail::shard_sample_indices;
using sweep_detail::Table;
using sweep_detail::write_outputs;

SweepReport run_sweep(const Sweep& sw, const std::filesystem::path& out_dir,
                      const SweepOptions& opt) {
  const auto start = std::chrono::steady_clock::now();
  if (opt.shards < 1 || opt.shard < 0 || opt.shard >= opt.shards)
    throw ScenarioError("--shard: expected i/N with 0 <= i < N");
  if (opt.threads < 0 || opt.threads > max_sweep_threads())
    throw ScenarioError(
        fmt::format("--threads: expected 1 to {} (4 per hardware thread, at least "
                    "16, at most 256), got {}",
                    max_sweep_threads(), opt.threads));
  const Scenario base = load_scenario_text(sw.base_text, sw.base_path, LoadOptions{false});
  SampleRunner runner(sw, base);
  const auto& header = runner.header();
  const int rank = opt.comm ? opt.comm->rank() : 0;
  const int size = opt.comm ? opt.comm->size() : 1;

  // This shard's samples; then this rank's share of them.
  const std::vector<long> shard_samples = shard_sample_indices(sw, opt);
  SweepReport rep;
  rep.samples = static_cast<long>(shard_samples.size());

  std::optional<OutputDir> out;
  std::map<long, std::string> done;
  std::optional<Journal> journal;
  const std::string head = journal_head(sw, opt);
  if (rank == 0) {
    open_sweep_output(sw, opt, out_dir, head, header, size, out, done, journal);
    rep.resumed = static_cast<long>(done.size());
  }
  const std::vector<long> todo = rank_todo(shard_samples, done, rank, size);

  const std::vector<std::string> rows =
      compute_rows(runner, todo, journal ? &*journal : nullptr, opt, rank, start);
  rep.computed = 0;
  for (const auto& r : rows) rep.computed += r.empty() ? 0 : 1;

  // Gather (MPI) on rank 0, in sample order.
  Table t;
  t.header = header;
  t.rows = done;
  for (std::size_t i = 0; i < todo.size(); ++i)
    if (!rows[i].empty()) t.rows[todo[i]] = rows[i];
  if (opt.comm && size > 1 && !gather_rows(*opt.comm, rank, rows, sw, t, rep)) return rep;
  const std::string journal_error = journal ? journal->error() : std::string();
  journal.reset();
  rep.complete = static_cast<long>(t.rows.size()) == rep.samples && journal_error.empty() &&
                 rep.failures.empty();
  if (!journal_error.empty()) rep.failures.push_back("journal: " + journal_error);
  write_outputs(*out, sw, t, &opt, rep.complete, rep, opt.cancel);
  rep.wall_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return rep;
}

int max_sweep_threads() {
  const int hw = static_cast<int>(std::thread::hardware_concurrency());
  return std::clamp(4 * hw, 16, 256);
}

bool parse_shard(const std::string& text, int& index, int& count) {
  const std::size_t slash = text.find('/');
  if (slash == std::string::npos) return false;
  auto digits = [](const char* b, const char* e, int& v) {
    if (b == e || !std::all_of(b, e, [](char c) { return c >= '0' && c <= '9'; })) return false;
    const auto r = std::from_chars(b, e, v);
    return r.ec == std::errc() && r.ptr == e;
  };
  int i = 0, n = 0;
  const char* s = text.data();
  if (!digits(s, s + slash, i) || !digits(s + slash + 1, s + text.size(), n)) return false;
  if (!(n >= 1 && i < n)) return false;
  index = i;
  count = n;
  return true;
}

SweepReport merge_sweep(const Sweep& sw, const std::vector<std::filesystem::path>& dirs,
                        const std::filesystem::path& out_dir) {
  const auto start = std::chrono::steady_clock::now();
  const Scenario base = load_scenario_text(sw.base_text, sw.base_path, LoadOptions{false});
  const auto header = sweep_header(sw, base);
  for (const auto& d : dirs) {
    std::error_code ec;
    if (std::filesystem::equivalent(d, out_dir, ec))
      throw ScenarioError(printable(out_dir.string()) +
                          ": the merge's output folder is one of the shards' (give another)");
  }
  OutputDir out(out_dir);  // a refused merge leaves no earlier summary behind
  clear_previous_sweep(out);
  Table t;
  t.header = header;
  int shards = -1;
  std::set<int> seen;
  for (const auto& d : dirs) {
    const auto where = printable((d / kSummary).string());
    nlohmann::json j;
    try {
      j = nlohmann::json::parse(read_text(d / kSummary, "shard summary"));
    } catch (const nlohmann::json::exception& e) {
      throw ScenarioError(where + ": not a sweep summary: " + e.what());
    }
    if (j.value(nlohmann::json::json_pointer("/sweep/hash_fnv1a64"), std::string()) != sw.hash)
      throw ScenarioError(where + ": from another sweep (or another version of it)");
    if (!j.value("complete", false)) throw ScenarioError(where + ": the shard is incomplete");
    const std::string sh = j.value("shard", std::string("0/1"));
    int i = 0, n = 0;
    if (!parse_shard(sh, i, n)) throw ScenarioError(where + ": bad shard '" + printable(sh) + "'");
    if (shards >= 0 && n != shards) throw ScenarioError(where + ": shards of different splits");
    shards = n;
    if (!seen.insert(i).second) throw ScenarioError(where + ": shard " + sh + " given twice");
    merge_shard_rows(sw, d / kTable, i, n, t);
  }
  if (shards < 0 || static_cast<int>(seen.size()) != shards)
    throw ScenarioError(
        fmt::format("merge: {} of {} shards given", seen.size(), std::max(shards, 0)));
  SweepReport rep;
  rep.samples = sw.samples;
  rep.resumed = static_cast<long>(t.rows.size());
  rep.complete = static_cast<long>(t.rows.size()) == sw.samples;
  if (!rep.complete) throw ScenarioError("merge: the shards do not hold every sample");
  write_outputs(out, sw, t, nullptr, true, rep, nullptr);
  rep.wall_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return rep;
}

}  // namespace ukdyn
