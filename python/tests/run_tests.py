"""Runs pytest on the given test files (ctest entries Python.*); exits 77 (ctest: skipped) with
a message if numpy or pytest is missing, so that `make test` passes without them."""
import sys

missing = []
for name in ("numpy", "pytest"):
    try:
        __import__(name)
    except ImportError:
        missing.append(name)
if missing:
    print("Python tests skipped: %s not installed (Debian: %s; scripts/install-deps.sh installs them)"
          % (", ".join(missing), " ".join("python3-" + m for m in missing)))
    sys.exit(77)

import pytest  # noqa: E402

sys.exit(pytest.main(["-q", "-p", "no:cacheprovider", *sys.argv[1:]]))
