// Internal to the sweep (src/sweep/): its progress on the console while the samples run (the
// report at the end is print_sweep_report(), ukdyn/sweep/sweep.hpp).
#pragma once

#include <atomic>
#include <chrono>
#include <cstddef>

#include "ukdyn/sweep/sweep.hpp"

namespace ukdyn::sweep_detail {

/// One progress report of rank 0 (`finished` of `todo` samples since `start`) to opt.progress: a
/// bar redrawn in place on a terminal (final: ended by a newline), else a line.
void report_sweep_progress(const SweepOptions& opt, int rank,
                           std::chrono::steady_clock::time_point start,
                           const std::atomic<std::size_t>& finished, std::size_t todo, bool final);

}  // namespace ukdyn::sweep_detail
