// Opening the scenario file named on the command line: what it is is checked before it is read, so
// that a FIFO, a folder or a device is reported as what it is and never blocks the run.
#pragma once

#include <cstddef>
#include <filesystem>
#include <string>

#include "ukdyn/scenario/scenario.hpp"

namespace ukdyn {

/// As load_scenario(), but opens the file non-blocking and checks its type first: "is a folder",
/// "is a FIFO (named pipe)", "is a device", "is a socket", "no such file", "permission denied"
/// (ScenarioError naming the path). Reads it through the descriptor that was checked.
Scenario load_scenario_file(const std::filesystem::path& path, const LoadOptions& options = {});

/// The text of an input file, with the checks of every file ukdyn reads (docs/scenario-format.md,
/// "Files ukdyn reads": a regular file, opened non-blocking, its type checked on the descriptor
/// read, at most max_bytes): `what` names it in messages ("sweep file"). A ScenarioError naming
/// the path otherwise.
std::string read_input_text(const std::filesystem::path& path, const std::string& what,
                            std::size_t max_bytes = std::size_t{4} << 20);

/// The text of a scenario file, read with the same checks as load_scenario_file() (a regular
/// file of at most 4 MiB); a ScenarioError naming the path otherwise.
std::string read_scenario_text(const std::filesystem::path& path);

/// The content hash of a scenario's text: Scenario::hash of load_scenario_text(text, ...), and the
/// `hash_fnv1a64` of a run's summary.json (`ukdyn replay` compares them before it reads a file a
/// summary names).
std::string scenario_text_hash(const std::string& text);

}  // namespace ukdyn
