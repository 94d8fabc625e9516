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

// UKDYN_TEST_SANITIZED: built with AddressSanitizer or ThreadSanitizer, whose runtimes replace
// malloc and keep freed memory in a quarantine. gcc says so with __SANITIZE_ADDRESS__ /
// __SANITIZE_THREAD__, clang 14 only through __has_feature.
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define UKDYN_TEST_SANITIZED 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
#define UKDYN_TEST_SANITIZED 1
#endif
#endif
