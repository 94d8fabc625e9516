#include "ukdyn/scenario/scenario_file.hpp"

#include <string>

#include "core/input_file.hpp"
#include "scenario/yaml_loader.hpp"
#include "ukdyn/text/safe_text.hpp"

namespace ukdyn {

Scenario load_scenario_file(const std::filesystem::path& path, const LoadOptions& options) {
  return load_scenario_text(read_scenario_text(path), path, options);
}

std::string read_input_text(const std::filesystem::path& path, const std::string& what,
                            std::size_t max_bytes) {
  try {
    return detail::read_input_file(path, {what, max_bytes, printable(path.string())});
  } catch (const detail::InputFileError& e) {
    throw ScenarioError(e.what());
  }
}

std::string read_scenario_text(const std::filesystem::path& path) {
  return read_input_text(path, "scenario file");
}

std::string scenario_text_hash(const std::string& text) {
  return io_detail::scenario_text_hash(text);
}

}  // namespace ukdyn
