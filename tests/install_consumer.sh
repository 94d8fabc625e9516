#!/usr/bin/env bash
# Installs the build tree into a temporary prefix, then configures, builds and runs a consumer
# project against it with find_package(ukdyn COMPONENTS ...): the export sets must work.
#   install_consumer.sh BUILD_DIR SOURCE_DIR CXX_FLAGS [CONSUMER [ARGS...]]
# CONSUMER: examples/consumer (core only, the default) or examples/consumer_io; ARGS go to it.
set -euo pipefail
build_dir=$1
source_dir=$2
# The consumer must use the same architecture flags as ukdyn (Eigen's fixed-size types change their
# alignment with e.g. -march=native; mixing them breaks the ABI).
cxx_flags=${3:-}
consumer=${4:-consumer}
shift $(( $# < 4 ? $# : 4 ))
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
cmake --install "$build_dir" --prefix "$tmp/prefix" >/dev/null
# Internal headers must not be installed.
for internal in src/scenario/yaml_loader.hpp src/scenario/definitions_loader.hpp; do
  if [[ -e "$tmp/prefix/include/$internal" ]]; then
    echo "install_consumer: internal header $internal was installed" >&2
    exit 1
  fi
done
cmake -S "$source_dir/examples/$consumer" -B "$tmp/build" -DCMAKE_PREFIX_PATH="$tmp/prefix" \
      -DCMAKE_BUILD_TYPE=Release -DCMAKE_CXX_FLAGS="$cxx_flags" >/dev/null
cmake --build "$tmp/build" >/dev/null
"$tmp/build/consumer" "$@"
