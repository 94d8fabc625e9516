#!/usr/bin/env bash
# Installs the build tree into a temporary prefix, then configures, builds and runs
# examples/consumer against it with find_package(ukdyn): the export set must work.
set -euo pipefail
build_dir=$1
source_dir=$2
# The consumer must use the same architecture flags as ukdyn (Eigen's fixed-size types change their
# alignment with e.g. -march=native; mixing them breaks the ABI).
cxx_flags=${3:-}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
cmake --install "$build_dir" --prefix "$tmp/prefix" >/dev/null
cmake -S "$source_dir/examples/consumer" -B "$tmp/build" -DCMAKE_PREFIX_PATH="$tmp/prefix" \
      -DCMAKE_BUILD_TYPE=Release -DCMAKE_CXX_FLAGS="$cxx_flags" >/dev/null
cmake --build "$tmp/build" >/dev/null
"$tmp/build/consumer"
