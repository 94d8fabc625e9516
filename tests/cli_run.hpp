// Running the ukdyn executable from a test: exit code, stdout, stderr; scratch folders; snapshots
// of a folder tree (bytes of every file, targets of links) to show that a run left them untouched.
#pragma once

#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>

namespace ukdyn_test {

namespace fs = std::filesystem;

struct CliResult {
  int exit_code = -1;
  std::string out, err;
};

inline std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream os;
  os << in.rdbuf();
  return os.str();
}

/// A fresh folder for this test process, under the system's temporary folder, removed at exit
/// (std::filesystem::remove_all removes links, never what they point to).
struct ScratchDir {
  fs::path path;
  explicit ScratchDir(const std::string& tag)
      : path(fs::temp_directory_path() / (tag + "_" + std::to_string(::getpid()))) {
    fs::create_directories(path);
  }
  ~ScratchDir() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
  ScratchDir(const ScratchDir&) = delete;
  ScratchDir& operator=(const ScratchDir&) = delete;
};

/// Single-quoted for the POSIX shell.
inline std::string sh(const std::string& s) {
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

/// Runs a shell command; its exit status (-1 if it did not exit normally).
inline int shell(const std::string& cmd) {
  const int rc = std::system(cmd.c_str());
  return WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
}

/// One scratch folder per test process and tag, made on first use, removed at exit.
inline const fs::path& process_scratch(const std::string& tag) {
  static const ScratchDir dir(tag);  // tests only: one folder for the whole process
  return dir.path;
}

/// Runs `prefix ukdyn args` through /bin/sh with stdin_text on stdin.
inline CliResult run_cli(const fs::path& cli, const fs::path& scratch, const std::string& args,
                         const std::string& stdin_text = "", const std::string& prefix = "") {
  const fs::path in = scratch / "stdin.txt", out = scratch / "stdout.txt",
                 err = scratch / "stderr.txt";
  std::ofstream(in, std::ios::binary) << stdin_text;
  const std::string cmd = prefix + sh(cli.string()) + " " + args + " < " + sh(in.string()) + " > " +
                          sh(out.string()) + " 2> " + sh(err.string());
  const int rc = std::system(cmd.c_str());
  CliResult r;
  r.exit_code = WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
  r.out = slurp(out);
  r.err = slurp(err);
  return r;
}

/// Every entry under root (not following links): files by content, links by target, folders.
inline std::map<std::string, std::string> snapshot(const fs::path& root) {
  std::map<std::string, std::string> snap;
  std::error_code ec;
  if (!fs::exists(fs::symlink_status(root, ec))) return snap;
  for (auto it = fs::recursive_directory_iterator(root, ec);
       it != fs::recursive_directory_iterator(); it.increment(ec)) {
    const auto rel = fs::relative(it->path(), root).string();
    const auto st = it->symlink_status();
    if (fs::is_symlink(st)) {
      snap[rel] = "link -> " + fs::read_symlink(it->path()).string();
    } else if (fs::is_directory(st)) {
      snap[rel] = "folder";
    } else {
      snap[rel] = "file: " + slurp(it->path());
    }
  }
  return snap;
}

}  // namespace ukdyn_test
