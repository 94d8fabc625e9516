// The files of an MJCF model as ukdyn's checked reader read them (core/input_file.hpp), and
// MuJoCo's compile of exactly those bytes through its virtual file system (mjVFS), so that MuJoCo
// never opens the model or an <include> by name a second time. Internal (src/robot_files/mjcf.cpp
// and tests/test_mjcf.cpp); needs MuJoCo.
#pragma once

#include <mujoco/mujoco.h>

#include <filesystem>
#include <memory>
#include <string>
#include <vector>

namespace ukdyn::symbolic::mjcf_detail {

/// One file as read: where it was read from and its bytes.
struct MjcfFile {
  std::filesystem::path path;
  std::string bytes;
};

/// The model file and, recursively, every <include file="..."/> (relative to the model file's
/// folder, as MuJoCo resolves them), each read once by the checked reader. Throws
/// DefinitionError naming the file: not a regular file (a FIFO, a folder), missing, larger than
/// 16 MiB, empty, an include cycle or more than 32 levels or 256 files, or two files that MuJoCo's
/// virtual file system could not tell apart (it keys files by their name without the folder,
/// case-insensitively).
std::vector<MjcfFile> read_mjcf_files(const std::filesystem::path& model);

struct MjModelDeleter {
  void operator()(mjModel* m) const { mj_deleteModel(m); }
};
using MjModelPtr = std::unique_ptr<mjModel, MjModelDeleter>;

/// MuJoCo's compile of `files` (from read_mjcf_files(model)): mj_loadXML with a virtual file
/// system holding those bytes. Throws DefinitionError naming the model file with MuJoCo's message.
MjModelPtr compile_mjcf(const std::filesystem::path& model, const std::vector<MjcfFile>& files);

}  // namespace ukdyn::symbolic::mjcf_detail
