#!/usr/bin/env bash
# ctest Browser.Replay: the replay page (docs/replay.md) in Debian's chromium, driven headless by
# playwright-core (web/test/replay.test.mjs). Skipped (exit 77, ctest SKIP_RETURN_CODE) with the
# reason when chromium, node, web/node_modules or three.js in this ukdyn are missing; the set-up
# script (scripts/install-deps.sh) installs them all.
#   tests/browser_replay.sh UKDYN SOURCE_DIR
set -euo pipefail
ukdyn=$1
src=$2
chromium=${CHROMIUM:-/usr/bin/chromium}
skip() { echo "SKIPPED: $*" >&2; exit 77; }
[[ -x $chromium ]] || skip "no chromium at $chromium (Debian package chromium; scripts/install-deps.sh)"
command -v node >/dev/null || skip "no node (Debian package nodejs)"
[[ -f $src/web/node_modules/playwright-core/package.json ]] ||
  skip "no web/node_modules/playwright-core (run npm ci in web/; scripts/install-deps.sh does)"
if "$ukdyn" replay /nonexistent-ukdyn-out --scenario /dev/null 2>&1 | grep -q "built without three.js"; then
  skip "this ukdyn was built without three.js (web/node_modules missing when it was configured)"
fi
scratch=$(mktemp -d "${TMPDIR:-/tmp}/ukdyn-browser-XXXXXX")
trap 'rm -rf "$scratch"' EXIT
CHROMIUM=$chromium timeout 90 node "$src/web/test/replay.test.mjs" "$ukdyn" "$src" "$scratch"
