// The table of a sweep and what is written from it: results.csv, and summary.json with the
// statistics of the completed samples and the failures (docs/sweeps.md).
#include "sweep/table.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <nlohmann/json.hpp>

#include "ukdyn/run/run.hpp"
#include "ukdyn/text/safe_text.hpp"

namespace ukdyn::sweep_detail {

std::string header_line(const std::vector<std::string>& h) {
  std::string s;
  for (std::size_t i = 0; i < h.size(); ++i) s += (i ? "," : "") + csv_field(h[i]);
  return s;
}

namespace {

// Linear interpolation between closest ranks ([Hyndman1996], definition 7) of sorted values.
double percentile(const std::vector<double>& sorted, double p) {
  if (sorted.empty()) return NAN;
  const double h = (static_cast<double>(sorted.size()) - 1.0) * p;
  const auto lo = static_cast<std::size_t>(std::floor(h));
  const std::size_t hi = std::min(lo + 1, sorted.size() - 1);
  return sorted[lo] + (h - static_cast<double>(lo)) * (sorted[hi] - sorted[lo]);
}

nlohmann::json jnum(double v) {
  return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr);
}

nlohmann::json summary_json(const Sweep& sw, const Table& t, const SweepOptions* opt, bool complete,
                            SweepReport& rep) {
  nlohmann::json j;
  j["ukdyn_version"] = version();
  j["sweep"] = {{"name", sw.name},
                {"path", sw.path.string()},
                {"hash_fnv1a64", sw.hash},
                {"mode", sw.mode == Sweep::Mode::grid   ? "grid"
                         : sw.mode == Sweep::Mode::list ? "list"
                                                        : "random"},
                {"seed", sw.seed},
                {"samples", sw.samples}};
  j["base_scenario"] = sw.base_path.string();
  if (opt && opt->shards > 1) j["shard"] = fmt::format("{}/{}", opt->shard, opt->shards);
  j["complete"] = complete;
  const std::size_t st = 1 + sw.parameters.size();
  long completed = 0;
  nlohmann::json fails = nlohmann::json::array();
  std::map<std::string, long> by_status;
  std::vector<std::vector<double>> cols(t.header.size());
  for (const auto& [k, line] : t.rows) {
    const auto cells = io_detail::split_csv_line(line);
    if (cells.size() != t.header.size()) continue;
    const std::string& status = cells[st];
    ++by_status[status];
    if (status != "completed") {
      fails.push_back({{"sample", k}, {"status", status}, {"reason", cells[st + 1]}});
      rep.failures.push_back(fmt::format("sample {}: {}: {}", k, status, cells[st + 1]));
      continue;
    }
    ++completed;
    for (std::size_t c = 1; c < cells.size(); ++c) {
      if (c == st || c == st + 1) continue;
      const double v = parse_cell(cells[c]);
      if (std::isfinite(v)) cols[c].push_back(v);
    }
  }
  rep.failed = static_cast<long>(t.rows.size()) - completed;
  j["samples_in_table"] = t.rows.size();
  j["completed"] = completed;
  j["failed"] = rep.failed;
  j["status_counts"] = by_status;
  j["failures"] = fails;
  nlohmann::json stats = nlohmann::json::object();
  for (std::size_t c = 1; c < t.header.size(); ++c) {
    if (c == st || c == st + 1) continue;
    auto v = cols[c];
    std::sort(v.begin(), v.end());
    double sum = 0.0;
    for (double x : v) sum += x;
    stats[t.header[c]] = {{"count", v.size()},
                          {"min", jnum(v.empty() ? NAN : v.front())},
                          {"p01", jnum(percentile(v, 0.01))},
                          {"p05", jnum(percentile(v, 0.05))},
                          {"p50", jnum(percentile(v, 0.50))},
                          {"p95", jnum(percentile(v, 0.95))},
                          {"p99", jnum(percentile(v, 0.99))},
                          {"max", jnum(v.empty() ? NAN : v.back())},
                          {"mean", jnum(v.empty() ? NAN : sum / static_cast<double>(v.size()))}};
  }
  j["statistics_of_completed_samples"] = stats;
  return j;
}

}  // namespace

void write_outputs(const OutputDir& out, const Sweep& sw, const Table& t, const SweepOptions* opt,
                   bool complete, SweepReport& rep, const std::atomic<bool>* cancel) {
  {
    AtomicFile f(out, out.fd(), "", kTable);
    f.write(header_line(t.header) + "\n");
    for (const auto& [k, line] : t.rows) f.write(line + "\n");
    f.commit();
  }
  rep.table = out.path() / kTable;
  nlohmann::json j = summary_json(sw, t, opt, complete, rep);
  if (complete && sw.figures) draw_figures(out, sw, t, rep, cancel);
  nlohmann::json figs = nlohmann::json::array();
  for (const auto& f : rep.figures) figs.push_back(f.lexically_relative(out.path()).string());
  j["figures"] = figs;
  if (!rep.figure_error.empty()) j["figure_error"] = rep.figure_error;
  if (!rep.figure_notes.empty()) j["figures_left_out"] = rep.figure_notes;
  {
    AtomicFile f(out, out.fd(), "", kSummary);
    f.write(j.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n");
    f.commit();
  }
  rep.summary = out.path() / kSummary;
  out.sync();
}

}  // namespace ukdyn::sweep_detail
