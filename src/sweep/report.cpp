// The console side of a sweep: its progress while the samples run and the report at the end.
#include "sweep/report.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <ostream>
#include <string>

#include "ukdyn/run/run.hpp"
#include "ukdyn/text/safe_text.hpp"

namespace ukdyn {

namespace {

std::string duration_text(double s) {
  if (!std::isfinite(s)) return "?";
  const long t = std::lround(s);
  if (t >= 3600) return fmt::format("{}h{:02}m", t / 3600, (t / 60) % 60);
  if (t >= 60) return fmt::format("{}m{:02}s", t / 60, t % 60);
  return fmt::format("{}s", t);
}

}  // namespace

void sweep_detail::report_sweep_progress(const SweepOptions& opt, int rank,
                                         std::chrono::steady_clock::time_point start,
                                         const std::atomic<std::size_t>& finished, std::size_t todo,
                                         bool final) {
  if (!opt.progress || rank != 0) return;
  const double el = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const auto f = static_cast<double>(finished.load());
  const double total = static_cast<double>(todo);
  const double rate = el > 0 ? f / el : 0.0;
  const double eta = rate > 0 ? (total - f) / rate : NAN;
  const double frac = total > 0 ? f / total : 1.0;
  if (opt.progress_tty) {
    const int width = 30, filled = static_cast<int>(frac * width);
    *opt.progress << "\r[" << std::string(static_cast<std::size_t>(filled), '#')
                  << std::string(static_cast<std::size_t>(width - filled), ' ') << "] "
                  << fmt::format("{}/{} samples  {:.1f}/s  ETA {}   ", f, total, rate,
                                 duration_text(eta));
    if (final) *opt.progress << "\n";
  } else {
    *opt.progress << fmt::format(
        "ukdyn: sweep: {}/{} samples ({:.0f}%), {:.2f} samples/s, "
        "ETA {}\n",
        f, total, 100.0 * frac, rate, duration_text(eta));
  }
  *opt.progress << std::flush;
}

void print_sweep_report(std::ostream& os, const Sweep& sw, const SweepReport& rep) {
  os << fmt::format("ukdyn {}: sweep '{}' ({}), base {}\n", version(), printable(sw.name),
                    printable(sw.path.string()), printable(sw.base_path.string()));
  os << fmt::format("  samples             {} ({} computed, {} from the journal), {} failed\n",
                    rep.samples, rep.computed, rep.resumed, rep.failed);
  os << fmt::format("  wall time           {:.3f} s\n", rep.wall_seconds);
  if (!rep.table.empty())
    os << fmt::format("  outputs             {}\n", printable(rep.table.string()));
  if (!rep.summary.empty())
    os << fmt::format("                      {}\n", printable(rep.summary.string()));
  if (!rep.figures.empty())
    os << fmt::format("                      {} figures in {}\n", rep.figures.size(),
                      printable((rep.table.parent_path() / "figures").string()));
  const std::size_t shown = std::min<std::size_t>(rep.failures.size(), 10);
  for (std::size_t i = 0; i < shown; ++i) os << "  failed: " << printable(rep.failures[i]) << "\n";
  if (rep.failures.size() > shown)
    os << fmt::format("  ... and {} more failed samples (summary.json)\n",
                      rep.failures.size() - shown);
  if (!rep.figure_error.empty()) os << "  figures: " << printable(rep.figure_error) << "\n";
  for (const auto& note : rep.figure_notes) os << "  figure not drawn: " << printable(note) << "\n";
}

}  // namespace ukdyn
