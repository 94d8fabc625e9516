#!/usr/bin/env bash
# Configures build/asan, the one instrumented build shared by `make sanitize` (scripts/sanitize.sh:
# the whole suite) and `make fuzz` (scripts/fuzz.sh: the libFuzzer targets), so that the library is
# compiled once for both. clang 14, AddressSanitizer + UndefinedBehaviorSanitizer
# (-fno-sanitize-recover=all, asserts on), and libFuzzer's coverage instrumentation
# (-fsanitize=fuzzer-no-link: inert in a binary that does not link libFuzzer).
# Why clang: measured on the shared machine, one library file (ukdyn/symbolic/definitions.cpp) compiles
# in 57 s with clang's ASan + UBSan + coverage against 116 s with g++'s ASan + UBSan; the test files
# are built with ASan only (UBSan and coverage instrumentation of their gtest + Eigen code buy nothing).
# Debug info is line tables only (-g1): file:line in every report.
#   scripts/asan-configure.sh          (prints the build folder)
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh --fuzz >&2
build=build/asan
cxx=$(command -v clang++-14 || command -v clang++)
san="-fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer"
# A folder configured by another compiler (g++ before this change) is configured afresh.
if [[ -f $build/CMakeCache.txt ]] && ! grep -q "CMAKE_CXX_COMPILER:[A-Z]*=$cxx\$" "$build/CMakeCache.txt"; then
  rm -rf "$build"
fi
# Warnings are enforced by the gcc CI build; instrumentation and clang's extra diagnostics must not
# stop this one.
cmake -S . -B "$build" -DCMAKE_CXX_COMPILER="$cxx" -DCMAKE_BUILD_TYPE=Debug -DCMAKE_CXX_FLAGS_DEBUG=-g1 \
  -DCMAKE_CXX_FLAGS="$san -O1" -DCMAKE_EXE_LINKER_FLAGS="-fsanitize=address,undefined" \
  -DUKDYN_WERROR=OFF -DUKDYN_BUILD_PYTHON=OFF -DUKDYN_BUILD_FUZZ=ON \
  "-DUKDYN_TEST_COMPILE_OPTIONS=-fno-sanitize=undefined;-fno-sanitize=fuzzer-no-link" >/dev/null
echo "$build"
