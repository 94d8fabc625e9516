// libFuzzer target on the `ukdyn eval` protocol (src/run/eval_protocol.cpp), with the paper's
// free-base scenario (12 coordinates, 6 constraint rows). Any input must be answered with exactly
// one JSON object per non-blank line: either an error object {"line", "error"}, or a result whose
// every number is finite. Anything else (an exception escaping, a crash, a sanitizer report, a
// timeout, a result with null numbers) is a finding. Build and run: scripts/fuzz.sh.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>

#include "ukdyn/run/eval_protocol.hpp"
#include "ukdyn/scenario/scenario.hpp"

namespace {

std::unique_ptr<ukdyn::Scenario> g_scenario;  // set once by LLVMFuzzerInitialize

bool all_numbers_finite(const nlohmann::json& j) {
  if (j.is_null()) return false;
  if (j.is_number_float()) return std::isfinite(j.get<double>());
  if (j.is_array() || j.is_object()) {
    for (const auto& e : j) {
      if (!all_numbers_finite(e)) return false;
    }
  }
  return true;
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int* /*argc*/, char*** /*argv*/) {
  g_scenario = std::make_unique<ukdyn::Scenario>(
      ukdyn::load_scenario(std::string(UKDYN_SOURCE_DIR) + "/scenarios/paper_free.yaml"));
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  std::istringstream in(text);
  std::ostringstream out;
  ukdyn::EvalOptions opt;
  opt.max_line_bytes = 4096;
  const ukdyn::EvalCounts counts = ukdyn::run_eval_protocol(*g_scenario, in, out, nullptr, opt);
  std::istringstream answers(out.str());
  long lines = 0, failures = 0;
  for (std::string l; std::getline(answers, l);) {
    ++lines;
    const auto j = nlohmann::json::parse(l);  // must be valid JSON (throws: a finding)
    if (!j.is_object()) std::abort();
    if (j.contains("error")) {
      ++failures;
      if (!j.contains("line") || !j["line"].is_number_integer()) std::abort();
    } else if (!j.contains("qdd") || !j.contains("consistent") || !all_numbers_finite(j)) {
      std::abort();  // a result with a missing or non-finite number
    }
  }
  if (lines != counts.lines || failures != counts.failures) std::abort();
  return 0;
}
