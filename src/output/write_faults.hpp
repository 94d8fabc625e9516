// Internal to ukdyn::io, for ukdyn's own tests: writes into an output folder made to fail as on a
// full disk, at chosen moments (tests/test_output_safety.cpp, InjectedFailure). The seam is private
// and never installed: the public OutputDir only holds an opaque pointer to a WriteFaults (null
// outside these tests) and befriends it; run_scenario() reaches it through src/run/run_faults.hpp.
#pragma once

#include <cstddef>
#include <functional>
#include <string_view>

#include "ukdyn/output/output_dir.hpp"

namespace ukdyn::io_detail {

/// Called before every write(2) into the output folder with the file's name (relative to the
/// output folder, e.g. "trajectory.csv") and the number of bytes; returning true makes that write
/// fail as a full disk would (ENOSPC). Empty: no injection.
using WriteFailureHook = std::function<bool(std::string_view name, std::size_t bytes)>;

struct WriteFaults {
  WriteFailureHook hook;

  /// From now on, the writes into `dir` that `hook` chooses fail (an empty hook: none).
  static void set_hook(OutputDir& dir, WriteFailureHook hook);
  /// True (with errno ENOSPC) if the hook set on `dir` asks this write to fail; false without one.
  [[nodiscard]] static bool inject(const OutputDir& dir, std::string_view name, std::size_t bytes);
};

}  // namespace ukdyn::io_detail
