#!/usr/bin/env bash
# Fuzzes the scenario loader (fuzz/fuzz_scenario.cpp) and the eval protocol (fuzz/fuzz_eval.cpp)
# with libFuzzer, AddressSanitizer and UndefinedBehaviorSanitizer for a bounded time each. Builds with clang 14 in build/fuzz (asserts on).
# Seeds: scenarios/*.yaml and tests/hostile/*.yaml; new inputs go to build/fuzz/corpus.
# Exits non-zero on any finding (crash, sanitizer report, exception other than ukdyn::Error, timeout,
# out of memory); the reproducer is written to build/fuzz/artifacts/.
#   scripts/fuzz.sh [SECONDS]          (scenario loader; default: FUZZ_SECONDS or 60)
#   EVAL_FUZZ_SECONDS=N                (eval lines; default 20; seeds fuzz/eval_seeds)
#   EXPRESSION_FUZZ_SECONDS=N          (expression parser + derivation; default 30)
#   build/fuzz/fuzz/fuzz_scenario build/fuzz/artifacts/crash-...    replays one finding
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh --fuzz

seconds=${1:-${FUZZ_SECONDS:-60}}
build=build/fuzz
jobs=${JOBS:-2}
cxx=$(command -v clang++-14 || command -v clang++)
san="-fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer"

# Warnings are enforced by the gcc CI build; clang's extra diagnostics must not stop the fuzzer.
cmake -S . -B "$build" -DCMAKE_CXX_COMPILER="$cxx" -DCMAKE_BUILD_TYPE=Debug \
  -DCMAKE_CXX_FLAGS="$san -O1 -g" -DCMAKE_EXE_LINKER_FLAGS="-fsanitize=address,undefined" \
  -DUKDYN_BUILD_FUZZ=ON -DUKDYN_BUILD_TESTS=OFF -DUKDYN_WERROR=OFF >/dev/null
cmake --build "$build" --target fuzz_scenario fuzz_eval -j "$jobs"

rm -rf "$build/artifacts"
mkdir -p "$build/corpus" "$build/artifacts"
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:detect_stack_use_after_return=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
export LSAN_OPTIONS=${LSAN_OPTIONS:-suppressions=$PWD/scripts/lsan.supp:print_suppressions=0}
status=0
"$build/fuzz/fuzz_scenario" "$build/corpus" scenarios tests/hostile \
  -dict=fuzz/scenario.dict -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 \
  -max_len=16384 -artifact_prefix="$build/artifacts/" -print_final_stats=1 || status=$?
if ((status != 0)) || [[ -n "$(ls -A "$build/artifacts")" ]]; then
  echo "fuzz: FINDING (libFuzzer exit $status); reproducers in $build/artifacts:" >&2
  ls -l "$build/artifacts" >&2
  exit 1
fi
echo "fuzz: scenario loader: no finding in ${seconds} s" >&2

eval_seconds=${EVAL_FUZZ_SECONDS:-20}
mkdir -p "$build/corpus_eval"
status=0
"$build/fuzz/fuzz_eval" "$build/corpus_eval" fuzz/eval_seeds \
  -dict=fuzz/eval.dict -max_total_time="$eval_seconds" -timeout=10 -rss_limit_mb=2048 \
  -max_len=8192 -artifact_prefix="$build/artifacts/" -print_final_stats=1 || status=$?
if ((status != 0)) || [[ -n "$(ls -A "$build/artifacts")" ]]; then
  echo "fuzz: eval: FINDING (libFuzzer exit $status); reproducers in $build/artifacts:" >&2
  ls -l "$build/artifacts" >&2
  exit 1
fi
echo "fuzz: eval protocol: no finding in ${eval_seconds} s" >&2

expr_seconds=${EXPRESSION_FUZZ_SECONDS:-30}
# The expression parser + derivation (fuzz/fuzz_expression.cpp): seeds fuzz/expression_seeds, new
# inputs in build/fuzz/corpus_expression, reproducers in build/fuzz/artifacts_expression/.
#   build/fuzz/fuzz/fuzz_expression build/fuzz/artifacts_expression/crash-...   replays one finding
cmake --build "$build" --target fuzz_expression -j "$jobs"
rm -rf "$build/artifacts_expression"
mkdir -p "$build/corpus_expression" "$build/artifacts_expression"
status=0
"$build/fuzz/fuzz_expression" "$build/corpus_expression" fuzz/expression_seeds \
  -dict=fuzz/expression.dict -max_total_time="$expr_seconds" -timeout=10 -rss_limit_mb=2048 \
  -max_len=4096 -artifact_prefix="$build/artifacts_expression/" -print_final_stats=1 || status=$?
if ((status != 0)) || [[ -n "$(ls -A "$build/artifacts_expression")" ]]; then
  echo "fuzz: FINDING in fuzz_expression (libFuzzer exit $status); reproducers in" \
    "$build/artifacts_expression:" >&2
  ls -l "$build/artifacts_expression" >&2
  exit 1
fi
echo "fuzz: fuzz_expression: no finding in ${expr_seconds} s" >&2
