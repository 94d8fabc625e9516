// Opening the scenario file named on the command line: what it is is checked before it is read, so
// that a FIFO, a folder or a device is reported as what it is and never blocks the run.
#pragma once

#include <filesystem>

#include "ukdyn/io/scenario.hpp"

namespace ukdyn {

/// As load_scenario(), but opens the file non-blocking and checks its type first: "is a folder",
/// "is a FIFO (named pipe)", "is a device", "is a socket", "no such file", "permission denied"
/// (ScenarioError naming the path). Reads it through the descriptor that was checked.
Scenario load_scenario_file(const std::filesystem::path& path, const LoadOptions& options = {});

}  // namespace ukdyn
