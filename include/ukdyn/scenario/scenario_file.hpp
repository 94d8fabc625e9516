// Opening the scenario file named on the command line: what it is is checked before it is read, so
// that a FIFO, a folder or a device is reported as what it is and never blocks the run.
#pragma once

#include <filesystem>
#include <string>

#include "ukdyn/scenario/scenario.hpp"

namespace ukdyn {

/// As load_scenario(), but opens the file non-blocking and checks its type first: "is a folder",
/// "is a FIFO (named pipe)", "is a device", "is a socket", "no such file", "permission denied"
/// (ScenarioError naming the path). Reads it through the descriptor that was checked.
Scenario load_scenario_file(const std::filesystem::path& path, const LoadOptions& options = {});

/// The text of a scenario file, read with the same checks as load_scenario_file() (a regular
/// file of at most 4 MiB); a ScenarioError naming the path otherwise.
std::string read_scenario_text(const std::filesystem::path& path);

}  // namespace ukdyn
