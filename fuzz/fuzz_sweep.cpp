// libFuzzer target on the sweep file loader (docs/sweeps.md): the input is a sweep file whose
// `base:` may name base.yaml (a control scenario) or plant.yaml (its plant) written beside it, so
// that parameter paths, `plant.` paths, `set:` and the metrics are checked against a real base
// scenario; sample 0 is then written out as scenario text (`--extract 0`). Any input must load or
// throw ukdyn::Error; anything else (another exception, a crash, a sanitizer report, a timeout, an
// alias bomb that expands) is a finding. Build and run: scripts/fuzz.sh.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>

#include "ukdyn/sweep/sweep.hpp"

namespace {

constexpr const char* kPlant = R"(ukdyn: 1
name: plant
gravity: 9.8
subsystems:
  - name: bob
    type: definitions
    coordinates: [x, z]
    parameters: {m: 1}
    bodies:
      - {name: bob, mass: m, com: [x, 0, z]}
constraints:
  - type: expression
    name: rod
    rows: {circle: (x^2 + z^2 - 1)/2}
  - type: expression
    name: swing
    let: {th: 0.3*(1 - cos(2*t))}
    rows: {angle: x*cos(th) + z*sin(th)}
initial:
  q: [0, -1]
simulation: {t_end: 0.1, sample_dt: 0.05}
)";

// The folder of the fuzzed files, made once per process (a fresh name under the temp folder).
std::filesystem::path work_folder() {
  const auto dir =
      std::filesystem::temp_directory_path() / ("ukdyn_fuzz_sweep_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  std::ofstream(dir / "plant.yaml") << kPlant;
  std::string base = kPlant;
  base.replace(base.find("name: plant"), 11, "name: base");
  std::ofstream(dir / "base.yaml") << base << "actuators:\n  - {name: fx, coordinate: x}\n"
                                   << "control:\n  law: stabilized\n  plant: plant.yaml\n";
  return dir;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const std::filesystem::path dir = work_folder();  // NOLINT: one folder per process
  if (size > (std::size_t{4} << 20)) return 0;
  const auto file = dir / "sweep.yaml";
  std::ofstream(file, std::ios::binary | std::ios::trunc)
      .write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  try {
    const ukdyn::Sweep sweep = ukdyn::load_sweep(file);
    if (sweep.samples > 0) (void)ukdyn::sample_scenario_text(sweep, 0);
  } catch (const ukdyn::Error&) {
  }
  return 0;
}
