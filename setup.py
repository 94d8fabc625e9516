"""Packaging of the Python module ukdyn for `pip install .` (docs/python.md, "Installing").

The extension is built by CMake from python/CMakeLists.txt (the same build as `cmake --build`);
this file only runs CMake and puts its result, with python/ukdyn/*, into the wheel.

Where CMake builds:
  UKDYN_CMAKE_BUILD_DIR=DIR  an existing build tree (e.g. build/release): only its target
                             ukdyn_python is brought up to date; nothing is reconfigured.
  otherwise                  <checkout>/build/pip, configured on first use (Release, no tests,
                             this Python), then built incrementally.
UKDYN_BUILD_JOBS sets the parallel jobs (default: the CPUs).
"""
import importlib.machinery
import os
import pathlib
import re
import shutil
import subprocess
import sys

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

ROOT = pathlib.Path(__file__).resolve().parent


def project_version():
    # The one version number: project(ukdyn VERSION x.y.z ...) of the top CMakeLists.txt.
    text = (ROOT / "CMakeLists.txt").read_text(encoding="utf-8")
    m = re.search(r"project\(\s*ukdyn\s+VERSION\s+([0-9.]+)", text)
    if not m:
        sys.exit("setup.py: no `project(ukdyn VERSION ...)` in %s" % (ROOT / "CMakeLists.txt"))
    return m.group(1)


def run(cmd):
    print("setup.py: " + " ".join(str(c) for c in cmd), flush=True)
    subprocess.run([str(c) for c in cmd], check=True)


class CMakeBuild(build_ext):
    """Builds the target ukdyn_python with CMake and copies the module it lays out in
    <build>/python/ukdyn/ to where setuptools packs the extension."""

    def run(self):
        cmake = shutil.which("cmake")
        if not cmake:
            sys.exit("setup.py: cmake not found (Debian: cmake; scripts/install-deps.sh installs it)")
        given = os.environ.get("UKDYN_CMAKE_BUILD_DIR")
        build = pathlib.Path(given).resolve() if given else ROOT / "build" / "pip"
        if not (build / "CMakeCache.txt").is_file():
            if given:
                sys.exit("setup.py: UKDYN_CMAKE_BUILD_DIR=%s is not a configured build tree "
                         "(no CMakeCache.txt)" % given)
            run([cmake, "-S", ROOT, "-B", build, "-DCMAKE_BUILD_TYPE=Release",
                 "-DUKDYN_BUILD_TESTS=OFF", "-DUKDYN_BUILD_PYTHON=ON",
                 "-DPython_EXECUTABLE=" + sys.executable])
        jobs = os.environ.get("UKDYN_BUILD_JOBS") or str(os.cpu_count() or 1)
        run([cmake, "--build", build, "--target", "ukdyn_python", "-j", jobs])
        suffix = importlib.machinery.EXTENSION_SUFFIXES[0]
        built = build / "python" / "ukdyn" / ("_ukdyn" + suffix)
        if not built.is_file():
            found = sorted(p.name for p in (build / "python" / "ukdyn").glob("_ukdyn*"))
            sys.exit("setup.py: CMake made no %s for this Python (%s) in %s (found: %s); CMake's "
                     "output above says why (pybind11, python3-dev)"
                     % (built.name, sys.executable, built.parent, ", ".join(found) or "nothing"))
        for ext in self.extensions:
            dest = pathlib.Path(self.get_ext_fullpath(ext.name))
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(built, dest)


# setuptools' own work folders under build/ (ignored by git), not beside the sources.
(ROOT / "build" / "setuptools").mkdir(parents=True, exist_ok=True)
setup(
    version=project_version(),
    packages=["ukdyn"],
    package_dir={"ukdyn": "python/ukdyn"},
    package_data={"ukdyn": ["__init__.pyi", "py.typed"]},
    ext_modules=[Extension("ukdyn._ukdyn", sources=[])],
    cmdclass={"build_ext": CMakeBuild},
    zip_safe=False,
    options={"build": {"build_base": "build/setuptools"},
             "egg_info": {"egg_base": "build/setuptools"}},
)
