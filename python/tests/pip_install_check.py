"""`pip install` of the checkout into a fresh venv, offline (ctest Python.pip_install, label
python; docs/python.md, "Installing"):

    python3 -m venv --system-site-packages V
    V/bin/pip install --no-build-isolation --no-index --no-cache-dir SOURCE

with UKDYN_CMAKE_BUILD_DIR set to the ctest build tree, so that setup.py brings the already built
target ukdyn_python up to date there instead of building the library a second time. Then, from an
empty folder, V/bin/python imports ukdyn, checks that it is the venv's copy, and runs one forward
call on a point mass on a rod against its closed form. Exits 77 (ctest: skipped) with the reason
when venv or pip is missing (Debian: python3-venv)."""
import os
import pathlib
import subprocess
import sys
import tempfile

source, build = sys.argv[1], sys.argv[2]


def skip(reason):
    print("Python.pip_install skipped: " + reason)
    sys.exit(77)


try:
    import ensurepip  # noqa: F401  (venv gets pip from it; Debian's python3-venv)
    import venv  # noqa: F401
except ImportError as e:
    skip("%s (Debian: python3-venv)" % e)

# Forward dynamics of a point mass m on a massless rod of length L (Cartesian x, y), at the bottom
# (0, -L) moving at speed v: qdd = (0, v^2 / L) (centripetal), rod force m (g + v^2 / L) upwards.
CHECK = r"""
import pathlib, sys
import numpy as np
import ukdyn
venv = pathlib.Path(sys.argv[1]).resolve()
where = pathlib.Path(ukdyn.__file__).resolve()
assert venv in where.parents, "ukdyn imported from %s, not from the venv %s" % (where, venv)
L, m, g, v = 1.5, 2.0, 9.81, 0.7
d = ukdyn.SubsystemDef("pendulum", ["x", "y"])
d.parameter("m", m)
d.add_body("P1", mass="m", com=["x", "y", 0])
d.gravity = [0, -g, 0]
c = ukdyn.ConstraintDef("rod", "holonomic", ["x", "y"])
c.parameter("L", L)
c.add_row("length", "x^2 + y^2 - L^2")
s = ukdyn.System()
s.add_subsystem(ukdyn.make_subsystem(d))
s.add_constraint(ukdyn.make_constraint(c))
sc = ukdyn.Scenario.from_system(s, q0=[0, -L], qd0=[v, 0], t_end=1.0)
r = sc.forward(0.0, [0, -L], [v, 0])
err = max(np.max(np.abs(r.qdd - [0, v * v / L])), np.max(np.abs(r.Qc - [0, m * (g + v * v / L)])))
assert err < 1e-12, err
print("ukdyn %s from %s: forward() of the rod pendulum within %.1e of the closed form"
      % (ukdyn.__version__, where.parent, err))
"""

with tempfile.TemporaryDirectory(prefix="ukdyn-pip-") as tmp:
    v = pathlib.Path(tmp) / "venv"
    p = subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", str(v)],
                       capture_output=True, text=True)
    if p.returncode != 0:
        if "ensurepip" in p.stdout + p.stderr:
            skip("python3 -m venv cannot install pip (Debian: python3-venv): " + p.stdout.strip())
        sys.exit("python3 -m venv failed:\n" + p.stdout + p.stderr)
    py = v / "bin" / "python"
    if subprocess.run([str(py), "-m", "pip", "--version"], capture_output=True).returncode != 0:
        skip("no pip in the venv (Debian: python3-venv, python3-pip-whl)")
    env = dict(os.environ, UKDYN_CMAKE_BUILD_DIR=build, PIP_DISABLE_PIP_VERSION_CHECK="1")
    env.pop("PYTHONPATH", None)  # the venv alone, not the build tree's package
    p = subprocess.run([str(py), "-m", "pip", "install", "--no-build-isolation", "--no-index",
                        "--no-cache-dir", source], env=env, capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit("pip install failed (%d):\n%s%s" % (p.returncode, p.stdout, p.stderr))
    print(p.stdout.strip().splitlines()[-1])
    empty = pathlib.Path(tmp) / "empty"
    empty.mkdir()
    p = subprocess.run([str(py), "-c", CHECK, str(v)], cwd=empty, env=env, capture_output=True,
                       text=True)
    sys.stdout.write(p.stdout)
    if p.returncode != 0:
        sys.exit("the installed ukdyn failed:\n" + p.stderr)
