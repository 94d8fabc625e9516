#!/usr/bin/env bash
# Configures build/asan: the one instrumented build shared by `make sanitize` (scripts/sanitize.sh,
# the test suite under AddressSanitizer + UndefinedBehaviorSanitizer) and `make fuzz`
# (scripts/fuzz.sh, libFuzzer). clang 14, asserts on, -O1, line tables only (-g1), and libFuzzer's
# coverage instrumentation (-fsanitize=fuzzer-no-link: harmless in an ordinary executable), so the
# library is compiled once for both. Sourced by those two scripts; sets $asan_build and $asan_flags.
#   source scripts/asan-configure.sh
asan_build=build/asan
asan_flags="-fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer"
_cxx=$(command -v clang++-14 || command -v clang++)
# Warnings are enforced by the gcc CI build; clang's extra diagnostics and the sanitizers' spurious
# ones must not stop these builds. The test files are built with ASan only
# (UKDYN_TEST_COMPILE_OPTIONS=-fno-sanitize=undefined in tests/CMakeLists.txt: UBSan more than
# doubled their compile time); the library, the CLI and the fuzz targets keep ASan + UBSan.
cmake -S . -B "$asan_build" -DCMAKE_CXX_COMPILER="$_cxx" -DCMAKE_BUILD_TYPE=Debug \
  -DCMAKE_CXX_FLAGS_DEBUG=-g1 -DCMAKE_CXX_FLAGS="$asan_flags -O1" \
  -DCMAKE_EXE_LINKER_FLAGS="-fsanitize=address,undefined" -DUKDYN_WERROR=OFF \
  -DUKDYN_BUILD_PYTHON=OFF -DUKDYN_BUILD_FUZZ=ON -DUKDYN_BUILD_TESTS=ON \
  -DUKDYN_TEST_COMPILE_OPTIONS=-fno-sanitize=undefined -DUKDYN_TEST_TIMEOUT=2400 >/dev/null
