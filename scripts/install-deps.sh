#!/usr/bin/env bash
# Installs the Debian packages ukdyn needs (only those missing). Idempotent.
#   scripts/install-deps.sh            build + run + test dependencies
#   scripts/install-deps.sh --bench    also the benchmark dependencies (MuJoCo, Simbody)
#   scripts/install-deps.sh --fuzz     also clang 14 and its runtime (libFuzzer: -fsanitize=fuzzer)
set -euo pipefail
pkgs=(cmake make g++ pkg-config libeigen3-dev libboost-dev libyaml-cpp-dev libcli11-dev
      libfmt-dev nlohmann-json3-dev gnuplot-nox libgtest-dev libgmock-dev
      libginac-dev liburdfdom-dev libsundials-dev
      libmujoco-dev                                  # MJCF files (ukdyn/symbolic/mjcf.hpp)
      python3-dev python3-pybind11 python3-numpy python3-pytest  # the Python module (python/)
      libopenmpi-dev openmpi-bin)  # MPI: the optional backend of `ukdyn sweep` (docs/sweeps.md)
for arg in "$@"; do
  case "$arg" in
    --bench) pkgs+=(libbenchmark-dev libsimbody-dev) ;;
    --fuzz) pkgs+=(clang-14 libclang-rt-14-dev) ;;
  esac
done
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]} == 0)); then
  exit 0
fi
echo "install-deps: installing ${missing[*]}" >&2
SUDO=""
if [[ $(id -u) -ne 0 ]]; then SUDO="sudo"; fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
