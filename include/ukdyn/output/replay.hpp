// The 3D replay page of a run (docs/replay.md): OUT/replay.html, one self-contained HTML file with
// three.js (from npm, embedded into ukdyn at build time) inlined, the model drawn from its geometry
// (ukdyn/output/geometry.hpp) at every output sample, and plots of the CSV's columns.
#pragma once

#include <cstddef>
#include <filesystem>
#include <string>
#include <vector>

#include "ukdyn/output/output_dir.hpp"
#include "ukdyn/scenario/scenario.hpp"

namespace ukdyn {

/// Name of the page in an output folder.
inline constexpr const char* kReplayFile = "replay.html";

struct ReplayOptions {
  /// At most this many frames: a longer run is shown every k-th sample (the first and last kept).
  std::size_t max_frames = 5000;
  std::string status = "complete";  ///< shown on the page (the run's status)
};

struct ReplayResult {
  std::filesystem::path file;
  std::size_t bytes = 0;
  std::size_t frames = 0, source_rows = 0, stride = 1;
  /// What the page does not draw: subsystems (by name), and robot-file shapes as "NAME.LINK (why)"
  /// (meshes, which are not loaded; planes; ...).
  std::vector<std::string> left_out;
};

/// Whether this ukdyn was built with three.js (web/node_modules present at configure time).
bool replay_available();

/// Writes OUT/replay.html from OUT/trajectory.csv (or trajectory.incomplete.csv) of a run of
/// `scenario`. Throws ukdyn::Error with a clear message if three.js was not built in, if there is
/// no CSV or its columns are not this scenario's; OutputRefused for a folder ukdyn will not use.
ReplayResult write_replay(const Scenario& scenario, const std::filesystem::path& out_dir,
                          const ReplayOptions& options = {});

}  // namespace ukdyn
