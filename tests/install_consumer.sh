#!/usr/bin/env bash
# Installs the build tree into a temporary prefix, then configures, builds and runs a consumer
# project against it with find_package(ukdyn COMPONENTS ...): the export sets must work.
#   install_consumer.sh BUILD_DIR SOURCE_DIR CXX_FLAGS [CONSUMER [ARGS...]]
# CONSUMER: examples/consumer (core only, the default) or examples/consumer_io; ARGS go to it.
# CONSUMER header_check: every installed public header compiled on its own (examples/header_check);
# ARGS: the components to check ("core;symbolic" or "core;symbolic;io").
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
# Private headers (src/) must not be installed: only include/ukdyn/ and the generated version.hpp.
while IFS= read -r -d '' private; do
  name=${private#"$source_dir/src/"}
  for installed in "$tmp/prefix/include/$name" "$tmp/prefix/include/ukdyn/$name"; do
    if [[ -e "$installed" ]]; then
      echo "install_consumer: private header src/$name was installed as $installed" >&2
      exit 1
    fi
  done
done < <(find "$source_dir/src" -name '*.hpp' -print0)
# ccache when installed, with the temporary folder as its base: the same headers at the same
# relative paths hit the cache from one run to the next.
launcher=()
if command -v ccache >/dev/null; then launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache); fi
export CCACHE_BASEDIR=$tmp
if [[ "$consumer" == header_check ]]; then
  cmake -S "$source_dir/examples/header_check" -B "$tmp/build" -DCMAKE_PREFIX_PATH="$tmp/prefix" \
        -DCMAKE_BUILD_TYPE=Release -DCMAKE_CXX_FLAGS="$cxx_flags" -DUKDYN_COMPONENTS="${1:-core;symbolic;io}" \
        "${launcher[@]}" >/dev/null
  cmake --build "$tmp/build" -j "${JOBS:-2}" >/dev/null
  for exe in "$tmp"/build/headers_*; do "$exe"; done
  exit 0
fi
cmake -S "$source_dir/examples/$consumer" -B "$tmp/build" -DCMAKE_PREFIX_PATH="$tmp/prefix" \
      -DCMAKE_BUILD_TYPE=Release -DCMAKE_CXX_FLAGS="$cxx_flags" "${launcher[@]}" >/dev/null
cmake --build "$tmp/build" >/dev/null
"$tmp/build/consumer" "$@"
