#!/usr/bin/env bash
# Builds the library, the CLI and the test suite with AddressSanitizer + UndefinedBehaviorSanitizer
# (-fno-sanitize-recover=all, asserts on) in build/asan, the clang build it shares with the fuzzers
# (scripts/asan-configure.sh), and runs ctest. Every process the tests start (the CLI included) is
# instrumented and logs to build/asan/sanitizer-logs/. Exits non-zero on any failing test or any
# sanitizer report. Only the targets the tests run are built (the CLI and ukdyn_tests; not the
# tools). Each test may take 2400 s (UKDYN_TEST_TIMEOUT; 600 in release).
#   scripts/sanitize.sh
#   UKDYN_SANITIZE_ALL=1 scripts/sanitize.sh     also the tests labelled `process` (below)
# Not here: the Python module (an ASan library cannot be loaded by a plain python3 without
# LD_PRELOAD of libasan; the module's tests run in `make test`), the MPI test (label mpi: OpenMPI's
# own allocations at exit are reported by LeakSanitizer; it runs in `make test`) and, unless
# UKDYN_SANITIZE_ALL is set, the tests labelled `process` (tests/CMakeLists.txt: each shipped
# scenario in two CLI processes compared byte for byte, generated C compiled, the install
# consumers): their work is starting processes and compilers; they run in `make test`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh --fuzz

jobs=${JOBS:-2}
# shellcheck source=asan-configure.sh
source scripts/asan-configure.sh
build=$asan_build
san=$asan_flags
exclude="mpi|process"
if [[ -n "${UKDYN_SANITIZE_ALL:-}" ]]; then exclude="mpi"; fi

# Set before building: the build runs the test binary to list its tests (gtest_discover_tests).
logs=$PWD/$build/sanitizer-logs
rm -rf "$logs"
mkdir -p "$logs"
export ASAN_OPTIONS="detect_leaks=1:abort_on_error=1:detect_stack_use_after_return=1:log_path=$logs/asan"
export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1:abort_on_error=1:log_path=$logs/ubsan"
export LSAN_OPTIONS="suppressions=$PWD/scripts/lsan.supp:print_suppressions=0"
status=0
cmake --build "$build" -j "$jobs" --target ukdyn ukdyn_tests || status=$?
if ((status == 0)); then
  # CXXFLAGS/LDFLAGS: the install test configures a downstream project that links the sanitized
  # libraries; CMake takes its initial flags from these variables.
  (cd "$build" && CXXFLAGS="$san" LDFLAGS="-fsanitize=address,undefined" \
    ctest --output-on-failure -j "$jobs" -LE "$exclude") || status=$?
fi
if [[ -n "$(ls -A "$logs")" ]]; then
  echo "sanitize: sanitizer reports:" >&2
  cat "$logs"/* >&2
  status=1
fi
if ((status != 0)); then
  echo "sanitize: FAILED" >&2
  exit 1
fi
echo "sanitize: clean" >&2
