// libFuzzer target on the expression parser and the symbolic derivation (issue 15): the input's
// first four lines become a let-name, two coordinates of a body's position and a constraint row of
// a small definitions scenario, which is loaded (parsed, derived, compiled to tapes), evaluated at
// its initial state and printed in every derive format. Any input must either work or throw
// ukdyn::Error (a ScenarioError naming file:line:col); anything else (another exception, a crash, a
// sanitizer report, a timeout past -timeout, memory past -rss_limit_mb) is a finding. Build and
// run: scripts/fuzz.sh.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/symbolic/definitions.hpp"

namespace {

// The line as a YAML double-quoted scalar (every byte survives: control bytes as \xNN).
std::string yaml_quoted(const std::string& s) {
  static const char* hex = "0123456789abcdef";
  std::string out = "\"";
  for (char ch : s) {
    const auto u = static_cast<unsigned char>(ch);
    if (ch == '"' || ch == '\\') {
      out += '\\';
      out += ch;
    } else if (u < 0x20 || u >= 0x7f) {
      out += "\\x";
      out += hex[u >> 4];
      out += hex[u & 15];
    } else {
      out += ch;
    }
  }
  return out + "\"";
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size > 20000) return 0;
  const std::string in(reinterpret_cast<const char*>(data), size);
  std::vector<std::string> lines{"x", "0", "y", "x - y"};
  std::size_t start = 0;
  for (std::size_t k = 0; k < 4 && start <= in.size(); ++k) {
    const std::size_t end = std::min(in.find('\n', start), in.size());
    lines[k] = in.substr(start, end - start);
    start = end + 1;
  }
  const std::string text =
      "ukdyn: 1\nname: fuzz\nsubsystems:\n  - name: s\n    type: definitions\n"
      "    coordinates: [x, y]\n    parameters: {a: 2, b: 0.5}\n    let: {u: " +
      yaml_quoted(lines[0]) + "}\n    bodies:\n      - {name: p, mass: 1, com: [" +
      yaml_quoted(lines[1]) + ", 0, " + yaml_quoted(lines[2]) +
      "]}\n      - {name: r, mass: 1, com: [x, y, 0]}\n"
      "constraints:\n  - {type: expression, name: c, rows: [" +
      yaml_quoted(lines[3]) +
      "]}\ninitial: {q: [0.1, 0.2]}\nsimulation: {t_end: 1, sample_dt: 0.1}\n";
  try {
    ukdyn::LoadOptions options;
    options.check_initial = false;
    const ukdyn::Scenario sc = ukdyn::load_scenario_text(text, "fuzz.yaml", options);
    ukdyn::Mat M(2, 2);
    sc.system->subsystems()[0]->mass({}, sc.q0, M);
    for (auto f : {ukdyn::symbolic::Format::latex, ukdyn::symbolic::Format::c,
                   ukdyn::symbolic::Format::matlab, ukdyn::symbolic::Format::text}) {
      (void)ukdyn::symbolic::format_system(*sc.system, f);
    }
  } catch (const ukdyn::Error&) {
  }
  return 0;
}
