// libFuzzer target on the scenario loader: any input must either load or throw ukdyn::Error (a
// ScenarioError naming file:line:col). Anything else (another exception, a crash, a sanitizer
// report, a timeout) is a finding. Build and run: scripts/fuzz.sh.
#include <cstddef>
#include <cstdint>
#include <string>

#include "ukdyn/scenario/scenario.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  // ukdyn::load_scenario refuses files over 4 MiB before parsing; the text loader is only ever
  // given what it accepted.
  if (size > (std::size_t{4} << 20)) return 0;
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    const ukdyn::Scenario scenario = ukdyn::load_scenario_text(text, "fuzz.yaml");
    (void)scenario;
  } catch (const ukdyn::Error&) {
  }
  return 0;
}
