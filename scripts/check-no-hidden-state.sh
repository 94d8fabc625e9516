#!/usr/bin/env bash
# No hidden mutable state in the library (docs/architecture.md, "Model and data"): every
# `thread_local` and every `static` that is not `static const` / `static constexpr` (a `static
# constinit`, `static char`, ... is caught) in the library (include/, src/), the CLI (apps/), the tools
# (tools/) and the Python module (python/src/) (and every `static const T*` pointer that is not
# itself const) must be on the
# allow-list below, with its reason. Models are constant; what an
# evaluation changes lives in caller-owned data (ForwardData and its slots).
#
#   scripts/check-no-hidden-state.sh [SOURCE_DIR]     exit 0: clean, 1: a hit not allowed
# Run by ctest (hidden_state) and so by `make test`.
set -euo pipefail
root="${1:-$(cd "$(dirname "$0")/.." && pwd)}"
cd "$root"

# file:text-of-the-line (a fixed substring of the line) | reason. Static member *functions* are
# stateless; a mutex that only serialises calls into a third-party global holds no state of ours.
allow=(
  "include/ukdyn/model/time_function.hpp:static TimeFunction make_|static member functions (named constructors), no state"
  "include/ukdyn/core/uk_solve.hpp:static BlockLayout single|static member function (a named constructor), no state"
  "src/scenario/yaml_loader.hpp:static bool parse_number|static member function, no state"
  "include/ukdyn/output/csv_writer.hpp:static std::string incomplete_name|static member function, no state"
  "src/output/write_faults.hpp:static void set_hook|static member function, no state"
  "src/output/write_faults.hpp:static bool inject|static member function, no state"
  "src/symbolic/spline.cpp:static bool struct_is_equal|static member function (GiNaC comparison policy), no state"
  "src/symbolic/spline.cpp:static int struct_compare|static member function (GiNaC comparison policy), no state"
  'src/symbolic/expression.cpp:"sizeof", "static", "struct"|a string in the table of C keywords, not a declaration'
  "python/src/module.cpp:static void release_with_gil|static member function, no state"
  "python/src/module.cpp:static py::exception<|pybind11's documented way to register an exception type: set once when the module is imported, never changed"
  "src/robot_files/urdf.cpp:static std::mutex mutex;|serialises urdfdom's parser, whose console_bridge output handler is a global of that library; holds no value"
)

dirs=(include src apps tools python/src)
status=0
while IFS= read -r hit; do
  [[ -z "$hit" ]] && continue
  file="${hit%%:*}"
  rest="${hit#*:}"
  line="${rest#*:}"
  trimmed="${line#"${line%%[![:space:]]*}"}"
  [[ "$trimmed" == //* ]] && continue  # a comment
  ok=0
  for entry in "${allow[@]}"; do
    spec="${entry%%|*}"
    afile="${spec%%:*}"
    atext="${spec#*:}"
    if [[ "$file" == "$afile" && "$line" == *"$atext"* ]]; then ok=1; break; fi
  done
  if ((ok == 0)); then
    echo "hidden state: $hit" >&2
    status=1
  fi
done < <(
  grep -rnE --include='*.[ch]pp' '\bthread_local\b|\bstatic\b' "${dirs[@]}" |
    grep -vE '\bstatic (inline )?(const|constexpr)\b' || true
  # `static const T* p` is a mutable pointer (to constant data): it must be `static const T* const`.
  grep -rn --include='*.[ch]pp' 'static const[^=;(]*\*[[:space:]]*[A-Za-z_]' "${dirs[@]}" |
    grep -v '\*[[:space:]]*const' || true
)

if ((status == 0)); then
  echo "check-no-hidden-state: no thread_local and no mutable static in ${dirs[*]} (${#allow[@]} allowed entries)"
else
  echo "check-no-hidden-state: move the state above into caller-owned data, or allow-list it with a reason" >&2
fi
exit $status
