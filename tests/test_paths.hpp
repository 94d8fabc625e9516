// The absolute paths the tests need: the source tree (scenarios, data) and, when it is built, the
// CLI. tests/CMakeLists.txt generates their definitions into one small file in the build tree and
// force-includes this header into every test source, so that no other test source's compile line
// carries an absolute path: a fresh clone elsewhere then gets ccache hits (base_dir) for them.
#pragma once

namespace uktest_paths {
/// The ukdyn source tree (PROJECT_SOURCE_DIR).
const char* source_dir();
/// The ukdyn CLI (only when UKDYN_TEST_HAVE_CLI: the CLI target is built).
const char* cli();
}  // namespace uktest_paths

#define UKDYN_SOURCE_DIR (::uktest_paths::source_dir())
#ifdef UKDYN_TEST_HAVE_CLI
#define UKDYN_CLI (::uktest_paths::cli())
#endif
