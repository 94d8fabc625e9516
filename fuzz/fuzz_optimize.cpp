// libFuzzer target on the trajectory-optimisation problem file loader (docs/optimization.md): the
// input is a problem file whose `scenario:` may name rail.yaml (a slider on a sloped rail, one
// actuator) written beside it, and whose `guess:` may name guess.csv (a two-row previous run of
// it), so that end states, bounds, costs, envelopes, IPOPT options, waypoints and the guess table
// are checked against a real system; nothing is solved. Any input must load or throw ukdyn::Error;
// anything else (another exception, a crash, a sanitizer report, a timeout) is a finding. Build
// and run: scripts/fuzz.sh.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>

#include "ukdyn/scenario/optimization_file.hpp"

namespace {

constexpr const char* kRail = R"(ukdyn: 1
name: rail
gravity: 9.81
subsystems:
  - name: slider
    type: definitions
    coordinates: [x, z]
    parameters: {m: 2}
    bodies:
      - {name: mass, mass: m, com: [x, 0, z]}
constraints:
  - {type: expression, name: rail, rows: {r: z - 0.5773502691896258*x}}
actuators:
  - {name: fx, coordinate: x, limit: 100}
initial:
  q: [0, 0]
  qd: [0, 0]
simulation:
  t_end: 2
  sample_dt: 0.01
)";

constexpr const char* kGuess =
    "t,knot,x,z,x_dot,z_dot,u_fx\n0,1,0,0,0,0,1\n2,1,1,0.5773502691896258,0,0,-1\n";

// The folder of the fuzzed files, made once per process (a fresh name under the temp folder).
std::filesystem::path work_folder() {
  const auto dir = std::filesystem::temp_directory_path() /
                   ("ukdyn_fuzz_optimize_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  std::ofstream(dir / "rail.yaml") << kRail;
  std::ofstream(dir / "guess.csv") << kGuess;
  return dir;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const std::filesystem::path dir = work_folder();  // NOLINT: one folder per process
  if (size > (std::size_t{1} << 20)) return 0;
  const auto file = dir / "problem.yaml";
  std::ofstream(file, std::ios::binary | std::ios::trunc)
      .write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  try {
    (void)ukdyn::load_optimization_file(file);
  } catch (const ukdyn::Error&) {
  }
  return 0;
}
