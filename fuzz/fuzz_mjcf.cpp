// libFuzzer target on the MJCF reader (robot_files/mjcf.cpp): the input is an MJCF model file,
// loaded as the `mjcf:` of a serial chain (the include and asset checks, MuJoCo's parser, the chain
// built from its bodies and joints). A mesh file tet.obj lies beside it (seed mesh_asset.xml), so
// the asset reader and MuJoCo's compile of a mesh from its virtual file system are reached. Any input must load or throw ukdyn::Error; anything else is a
// finding. Without MuJoCo (mjcf_supported() false) every input is skipped. Build and run:
// scripts/fuzz.sh.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>

#include "ukdyn/robot_files/mjcf.hpp"
#include "ukdyn/scenario/scenario.hpp"

namespace {

std::filesystem::path work_folder() {
  const auto dir =
      std::filesystem::temp_directory_path() / ("ukdyn_fuzz_mjcf_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  std::ofstream(dir / "tet.obj") << "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
                                    "f 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n";
  return dir;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (!ukdyn::symbolic::mjcf_supported() || size > (std::size_t{1} << 20)) return 0;
  static const std::filesystem::path dir = work_folder();  // NOLINT: one folder per process
  std::ofstream(dir / "model.xml", std::ios::binary | std::ios::trunc)
      .write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  const std::string scenario =
      "ukdyn: 1\nname: fuzz\nsubsystems:\n  - name: arm\n    type: serial_chain\n"
      "    coordinates: [a, b]\n    mjcf: model.xml\ninitial: {q: [0, 0]}\n"
      "simulation: {t_end: 0.1, sample_dt: 0.05}\n";
  try {
    const ukdyn::Scenario sc = ukdyn::load_scenario_text(scenario, dir / "s.yaml");
    (void)sc;
  } catch (const ukdyn::Error&) {
  }
  return 0;
}
