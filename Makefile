# The README's two commands: `make run` and `make test`. Each installs missing Debian packages
# (scripts/install-deps.sh), configures with CMake presets and builds.
PRESET ?= $(if $(CI),ci,release)
BUILD_DIR := build/$(PRESET)
JOBS ?= 2
SCENARIO ?= scenarios/paper.yaml
OUT ?= out/paper

# ccache (the compiler launcher, CMakeLists.txt): paths relative to the checkout, so that a fresh clone
# in another folder (CI) reuses what an earlier build compiled.
export CCACHE_BASEDIR := $(CURDIR)
export CCACHE_NOHASHDIR := 1
export CCACHE_MAXSIZE ?= 8G

.PHONY: all deps configure build run test test-noapp bench benchmarks sweep-bench drift-study sanitize tsan check-state fuzz clean format
FUZZ_SECONDS ?= 60

all: build

deps:
	@bash scripts/install-deps.sh

configure: deps
	@cmake --preset $(PRESET) >/dev/null

build: configure
	@cmake --build $(BUILD_DIR) -j $(JOBS)

# Also OUT/replay.html, the run in 3D (docs/replay.md): open it in a browser.
run: build
	$(BUILD_DIR)/ukdyn simulate $(SCENARIO) --out $(OUT) --html

test: build
	cd $(BUILD_DIR) && ctest --output-on-failure -j $(JOBS)

# The library without the CLI and io (-DUKDYN_BUILD_APP=OFF, build/ci-noapp): core + symbolic and
# their tests build on their own (the io / CLI test files are left out, tests/CMakeLists.txt), and a
# core-only consumer links them from an installed tree (ctest label install). The tests themselves
# run in `make test`.
test-noapp: deps
	@cmake --preset ci-noapp >/dev/null
	@cmake --build build/ci-noapp -j $(JOBS)
	cd build/ci-noapp && ctest --output-on-failure -j $(JOBS) -L install

bench:
	@bash scripts/install-deps.sh --bench
	@cmake --preset bench >/dev/null
	@cmake --build build/bench -j $(JOBS)
	build/bench/bench/ukdyn_bench --benchmark_min_time=0.2 $(BENCH_ARGS)

# The IFToMM benchmark problems over their full durations (docs/benchmarks.md), release build.
benchmarks: deps
	@cmake --preset release >/dev/null
	@cmake --build build/release -j $(JOBS) --target ukdyn_benchmarks
	build/release/ukdyn_benchmarks $(BENCHMARKS_ARGS)

# Sweep throughput: samples/s at 1 and 2 threads, overhead vs plain simulate (docs/performance.md).
sweep-bench: deps
	@cmake --preset release >/dev/null
	@cmake --build build/release -j $(JOBS) --target ukdyn_sweep_bench
	build/release/ukdyn_sweep_bench $(SWEEP_BENCH_ARGS)

drift-study: build
	$(BUILD_DIR)/ukdyn_drift_study scenarios/paper_free.yaml 100

# The test suite under AddressSanitizer + UndefinedBehaviorSanitizer (build/asan).
sanitize:
	@bash scripts/sanitize.sh

# The threaded tests under ThreadSanitizer (build/tsan).
tsan:
	@bash scripts/tsan.sh

# No thread_local and no mutable static in include/, src/, apps/, tools/ and python/src/ (also a ctest entry: Lint.NoHiddenState), and no
# function over 120 lines without a reason in its file (Lint.FunctionLength).
check-state:
	@bash scripts/check-no-hidden-state.sh
	@python3 scripts/check-function-length.py

# libFuzzer on the scenario loader for FUZZ_SECONDS (build/asan, the instrumented clang-14 build make sanitize uses).
fuzz:
	@bash scripts/fuzz.sh $(FUZZ_SECONDS)

format:
	clang-format -i $$(git ls-files '*.cpp' '*.hpp')

clean:
	rm -rf build out
