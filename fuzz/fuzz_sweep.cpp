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

#include "control_systems.hpp"
#include "ukdyn/sweep/sweep.hpp"

namespace {

// The short run of the base and its plant (tests/control_systems.hpp's servo pendulum).
constexpr const char* kRun = "{t_end: 0.1, sample_dt: 0.05}";

// The folder of the fuzzed files, made once per process (a fresh name under the temp folder).
std::filesystem::path work_folder() {
  const auto dir =
      std::filesystem::temp_directory_path() / ("ukdyn_fuzz_sweep_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  std::ofstream(dir / "plant.yaml") << uktest::pendulum_servo_yaml(1.0, "", kRun);
  std::ofstream(dir / "base.yaml") << uktest::pendulum_servo_yaml(
      1.0, "control:\n  law: stabilized\n  plant: plant.yaml\n", kRun);
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
