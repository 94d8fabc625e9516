#!/usr/bin/env bash
# Fuzzes the scenario loader (fuzz/fuzz_scenario.cpp), the eval protocol (fuzz/fuzz_eval.cpp), the
# expression parser + derivation (fuzz/fuzz_expression.cpp), the sweep file loader
# (fuzz/fuzz_sweep.cpp), the MJCF reader (fuzz/fuzz_mjcf.cpp) and the optimisation problem loader
# (fuzz/fuzz_optimize.cpp) with libFuzzer, AddressSanitizer and
# UndefinedBehaviorSanitizer for a bounded time each. Builds with clang 14 in build/asan, the build `make sanitize` uses (asserts on).
# Seeds: scenarios/*.yaml and tests/hostile/*.yaml (scenario), fuzz/eval_seeds, fuzz/expression_seeds;
# new inputs go to build/asan/corpus_<target>.
# Exits non-zero on any finding (crash, sanitizer report, exception other than ukdyn::Error, timeout,
# out of memory); the reproducer is written to build/asan/artifacts_<target>/.
#   scripts/fuzz.sh [SECONDS]          (scenario loader; default: FUZZ_SECONDS or 60)
#   EVAL_FUZZ_SECONDS=N                (eval lines; default 20; seeds fuzz/eval_seeds)
#   EXPRESSION_FUZZ_SECONDS=N          (expression parser + derivation; default 30)
#   SWEEP_FUZZ_SECONDS=N               (sweep files; default 30; seeds fuzz/sweep_seeds, scenarios/sweeps)
#   MJCF_FUZZ_SECONDS=N                (MJCF models; default 30; seeds fuzz/mjcf_seeds)
#   OPTIMIZE_FUZZ_SECONDS=N            (optimisation problem files; default 30; seeds
#                                       fuzz/optimize_seeds, tests/hostile/optimize_*.yaml)
#   build/asan/fuzz/fuzz_scenario build/asan/artifacts_fuzz_scenario/crash-...   replays one finding
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh --fuzz

seconds=${1:-${FUZZ_SECONDS:-60}}
jobs=${JOBS:-2}
# The instrumented clang build shared with `make sanitize` (build/asan, scripts/asan-configure.sh).
# shellcheck source=asan-configure.sh
source scripts/asan-configure.sh
build=$asan_build
cmake --build "$build" --target fuzz_scenario fuzz_eval fuzz_expression fuzz_sweep fuzz_mjcf fuzz_optimize -j "$jobs"

export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:detect_stack_use_after_return=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
export LSAN_OPTIONS=${LSAN_OPTIONS:-suppressions=$PWD/scripts/lsan.supp:print_suppressions=0}

# fuzz TARGET WHAT SECONDS MAX_LEN DICT SEEDS...: runs one libFuzzer target for SECONDS with new
# inputs in build/asan/corpus_TARGET and reproducers in build/asan/artifacts_TARGET/; exits the
# script non-zero on a finding.
fuzz() {
  local target=$1 what=$2 secs=$3 max_len=$4 dict=$5
  shift 5
  local corpus="$build/corpus_$target" artifacts="$build/artifacts_$target"
  rm -rf "$artifacts"
  mkdir -p "$corpus" "$artifacts"
  local status=0
  # Seeds are staged into one folder, leaving out files longer than MAX_LEN: libFuzzer would cut
  # them at MAX_LEN, and a cut 40-loop benchmark (scenarios/benchmarks/n_four_bar_N40.yaml, 18 KB,
  # 2.4 s to derive in a release build, about 11 s here) only reports itself as a slow unit.
  local seeds="$build/seeds_$target"
  rm -rf "$seeds"
  mkdir -p "$seeds"
  local f n=0
  while IFS= read -r -d '' f; do
    if (($(stat -c %s "$f") <= max_len)); then
      n=$((n + 1))
      cp "$f" "$seeds/$n.$(basename "$f")"
    fi
  done < <(find "$@" -type f -print0 | sort -z)
  # -timeout / -report_slow_units 90 s: above the derivation's documented 60 s limit
  # (limits::kDeriveSeconds, a wall-clock deadline that stops the derivation with a ScenarioError),
  # so an input the loader refuses at that limit is not a finding, and a hang past it still is. The
  # largest accepted seed (Bricard, 0.9 s in a release build) derives in about 5 s under ASan +
  # UBSan on a loaded 2-core machine; a sum of ~500 sines in one body's position (a mutation of
  # tests/hostile's 600-sine case) took the whole 60 s before it was refused, and is now refused
  # from the size of its M before the derivatives (380 sines: 3.0 s of CPU here, docs/definitions.md
  # "Limits").
  "$build/fuzz/$target" "$corpus" "$seeds" -dict="$dict" -max_total_time="$secs" -timeout=90 \
    -report_slow_units=90 \
    -rss_limit_mb=2048 -max_len="$max_len" -artifact_prefix="$artifacts/" -print_final_stats=1 ||
    status=$?
  if ((status != 0)) || [[ -n "$(ls -A "$artifacts")" ]]; then
    echo "fuzz: $what: FINDING (libFuzzer exit $status); reproducers in $artifacts:" >&2
    ls -l "$artifacts" >&2
    exit 1
  fi
  echo "fuzz: $what: no finding in ${secs} s" >&2
}

fuzz fuzz_scenario "scenario loader" "$seconds" 16384 fuzz/scenario.dict scenarios tests/hostile
fuzz fuzz_eval "eval protocol" "${EVAL_FUZZ_SECONDS:-20}" 8192 fuzz/eval.dict fuzz/eval_seeds
# The expression parser + derivation (fuzz/fuzz_expression.cpp).
fuzz fuzz_expression "expression parser" "${EXPRESSION_FUZZ_SECONDS:-30}" 4096 \
  fuzz/expression.dict fuzz/expression_seeds
# Sweep files, with a control base scenario and its plant beside them (fuzz/fuzz_sweep.cpp).
fuzz fuzz_sweep "sweep file loader" "${SWEEP_FUZZ_SECONDS:-30}" 8192 fuzz/scenario.dict \
  fuzz/sweep_seeds scenarios/sweeps
# MJCF models as a serial chain's mjcf: (fuzz/fuzz_mjcf.cpp).
fuzz fuzz_mjcf "MJCF reader" "${MJCF_FUZZ_SECONDS:-30}" 16384 fuzz/scenario.dict fuzz/mjcf_seeds
# Optimisation problem files, with a scenario and a guess table beside them (fuzz/fuzz_optimize.cpp).
fuzz fuzz_optimize "optimisation problem loader" "${OPTIMIZE_FUZZ_SECONDS:-30}" 8192 \
  fuzz/optimize.dict fuzz/optimize_seeds
