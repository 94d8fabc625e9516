#!/usr/bin/env bash
# Installs the Debian packages ukdyn needs (only those missing). Idempotent.
#   scripts/install-deps.sh            build + run + test dependencies
#   scripts/install-deps.sh --bench    also the benchmark dependencies (Google Benchmark; MuJoCo and
#                                      Simbody are in the base list)
#   scripts/install-deps.sh --fuzz     also clang 14 and its runtime (libFuzzer: -fsanitize=fuzzer)
set -euo pipefail
pkgs=(cmake make g++ ccache pkg-config libeigen3-dev libboost-dev libyaml-cpp-dev libcli11-dev
      libfmt-dev nlohmann-json3-dev gnuplot-nox libgtest-dev libgmock-dev
      libginac-dev liburdfdom-dev libsundials-dev
      libmujoco-dev                                  # MJCF files (ukdyn/robot_files/mjcf.hpp)
      libsimbody-dev  # tests/test_simbody_three_robots.cpp (skipped without it) and the bench
      python3-dev python3-pybind11 python3-numpy python3-pytest  # the Python module (python/)
      python3-venv python3-setuptools python3-wheel  # `pip install .` of it (pyproject.toml)
      python3-scipy  # python/examples/lqr_minimal.py (solve_continuous_are)
      coinor-libipopt-dev  # IPOPT: `ukdyn optimize` (docs/optimization.md), optional at build time
      libopenmpi-dev openmpi-bin  # MPI: the optional backend of `ukdyn sweep` (docs/sweeps.md)
      nodejs chromium)  # the replay page: three.js from npm (web/), its browser test
for arg in "$@"; do
  case "$arg" in
    --bench) pkgs+=(libbenchmark-dev) ;;
    --fuzz) pkgs+=(clang-14 libclang-rt-14-dev) ;;
  esac
done
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]} > 0)); then
  echo "install-deps: installing ${missing[*]}" >&2
  SUDO=""
  if [[ $(id -u) -ne 0 ]]; then SUDO="sudo"; fi
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

# web/: three.js (inlined into the replay page at build time) and playwright-core (its browser
# test), pinned by web/package-lock.json; `npm ci` only when node_modules is missing or older than
# the lock file. A failure here is a warning: the build stays green without them (docs/replay.md).
if ! command -v npm >/dev/null; then  # Debian's nodejs comes without npm (NodeSource's has it)
  SUDO=""
  if [[ $(id -u) -ne 0 ]]; then SUDO="sudo"; fi
  $SUDO apt-get install -y -qq --no-install-recommends npm ||
    echo "install-deps: warning: cannot install npm" >&2
fi
web="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)/web"
stamp="$web/node_modules/.package-lock.json"
if command -v npm >/dev/null && { [[ ! -f $stamp ]] || [[ $web/package-lock.json -nt $stamp ]]; }; then
  echo "install-deps: npm ci in $web" >&2
  (cd "$web" && npm ci --no-audit --no-fund --loglevel=error) ||
    echo "install-deps: warning: npm ci failed: the replay page and its test are left out" >&2
fi
