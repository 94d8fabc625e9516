#!/usr/bin/env bash
# The threaded tests (tests/test_threads.cpp: one System shared by 4 threads, results compared
# byte for byte) under ThreadSanitizer, in build/tsan. Only the libraries they need and that one
# test file are built (a full instrumented suite takes far longer on two cores), without the CLI.
# Exits non-zero on a failing test or any ThreadSanitizer report.
#   scripts/tsan.sh
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh

build=build/tsan
jobs=${JOBS:-2}
cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O2 -g1 -DNDEBUG" \
  -DCMAKE_CXX_FLAGS="-fsanitize=thread -fno-omit-frame-pointer" \
  -DCMAKE_EXE_LINKER_FLAGS="-fsanitize=thread" -DUKDYN_WERROR=OFF -DUKDYN_BUILD_APP=OFF \
  -DUKDYN_BUILD_THREAD_TESTS=ON -DUKDYN_BUILD_PYTHON=OFF >/dev/null
cmake --build "$build" -j "$jobs" --target ukdyn_thread_tests
logs=$PWD/$build/tsan-logs
rm -rf "$logs"
mkdir -p "$logs"
status=0
TSAN_OPTIONS="halt_on_error=1:second_deadlock_stack=1:log_path=$logs/tsan" \
  "$build/tests/ukdyn_thread_tests" || status=$?
if compgen -G "$logs/tsan*" >/dev/null; then
  echo "tsan: ThreadSanitizer reports:" >&2
  cat "$logs"/tsan* >&2
  status=1
fi
if ((status == 0)); then echo "tsan: threaded tests clean under ThreadSanitizer"; fi
exit $status
