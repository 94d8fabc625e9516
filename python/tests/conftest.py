"""Shared helpers of the Python tests (ctest entries Python.*): the CLI and the source tree."""
import json
import os
import pathlib
import subprocess

import numpy as np
import pytest

SOURCE = pathlib.Path(os.environ.get("UKDYN_SOURCE_DIR", pathlib.Path(__file__).resolve().parents[2]))
CLI = os.environ.get("UKDYN_CLI", "")


def scenario_path(name):
    return SOURCE / "scenarios" / name


def run_cli(*args, stdin=None):
    """Runs the ukdyn executable; returns (exit code, stdout, stderr)."""
    if not CLI:
        pytest.skip("UKDYN_CLI is not set (run through ctest)")
    p = subprocess.run([CLI, *map(str, args)], input=stdin, capture_output=True, text=True,
                       timeout=120)
    return p.returncode, p.stdout, p.stderr


def cli_eval(path, requests):
    """`ukdyn eval PATH` on JSON lines {t, q, qd, tau}: the answers, parsed."""
    lines = "".join(json.dumps(r) + "\n" for r in requests)
    code, out, err = run_cli("eval", path, stdin=lines)
    assert code == 0, err
    return [json.loads(l) for l in out.splitlines()]


def cli_csv(path, out_dir):
    """`ukdyn simulate PATH --out OUT_DIR --no-figures -q`: (header, rows x columns array,
    summary dict)."""
    code, out, err = run_cli("simulate", path, "--out", out_dir, "--no-figures", "--quiet")
    assert code == 0, err
    csv = pathlib.Path(out_dir) / "trajectory.csv"
    with open(csv) as f:
        header = f.readline().rstrip("\n").split(",")
    data = np.loadtxt(csv, delimiter=",", skiprows=1, ndmin=2)
    summary = json.loads((pathlib.Path(out_dir) / "summary.json").read_text())
    return header, data, summary


def max_rel_diff(a, b):
    """max |a - b| / max(1, |b|), elementwise (0 for empty arrays)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    assert a.shape == b.shape, (a.shape, b.shape)
    if a.size == 0:
        return 0.0
    return float(np.max(np.abs(a - b) / np.maximum(1.0, np.abs(b))))
