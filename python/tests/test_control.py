"""Control from Python (docs/python.md "Control"): a scenario with a control: section runs its closed
loop in simulate() exactly as `ukdyn simulate` does (every column of trajectory.csv, the summary's
control section), and a control law written in Python, given the model's forward data, replaces the
built-in one: a numpy re-implementation of the stabilized law (docs/control.md) gives the run of
the YAML law."""
import json
import os
import pathlib
import runpy
import subprocess
import sys

import numpy as np
import pytest

import ukdyn
from conftest import SOURCE, cli_csv, max_rel_diff, scenario_path

T_END = 0.3  # a short horizon of scenarios/paper_control.yaml (ctest time)


def paper_control(tmp_path, law=None, t_end=T_END, name="paper_control_short.yaml"):
    """scenarios/paper_control.yaml with t_end overridden (and optionally another law block),
    written next to nothing: the plant file is referred to by its absolute path."""
    text = scenario_path("paper_control.yaml").read_text()
    assert "  t_end: 4\n" in text and "plant: paper_generic_exact_inertia.yaml" in text
    text = text.replace("  t_end: 4\n", "  t_end: %r\n" % t_end)
    text = text.replace("plant: paper_generic_exact_inertia.yaml",
                        "plant: %s" % scenario_path("paper_generic_exact_inertia.yaml"))
    if law is not None:
        start = text.index("  law: robust")
        end = text.index("  plant:")
        text = text[:start] + law + text[end:]
    p = tmp_path / name
    p.write_text(text)
    return p


SKIP = {"wall_seconds", "trajectory_csv", "figures", "figures_left_out"}


def test_control_scenario_equals_the_cli_csv(tmp_path):
    path = paper_control(tmp_path)
    header, data, summary = cli_csv(path, tmp_path / "out")
    run = ukdyn.load_scenario(path).simulate()
    assert run.complete, run.message
    assert run.columns == header
    for c in ("u_theta1", "e_traj_x", "ed_traj_x", "act_residual"):
        assert c in run.columns, c
    assert any(c.startswith("Qp_") for c in header) and any(c.startswith("Qs_") for c in header)
    assert run.data.shape == data.shape
    worst = max(max_rel_diff(run[c], data[:, j]) for j, c in enumerate(header))
    print("paper_control (t_end %g): max relative difference to trajectory.csv %.3g over %d "
          "columns x %d rows" % (T_END, worst, len(header), len(run)))
    assert worst <= 1e-14
    assert {k: v for k, v in run.summary.items() if k not in SKIP} == \
        {k: v for k, v in summary.items() if k not in SKIP}
    ctl = run.summary["control"]
    assert ctl["law"] == "robust" and ctl["max_abs_e"] > 0.019  # the 0.02 m offset start
    assert np.shares_memory(run["u_theta1"], run.data)


def stabilized_law(omega):
    """docs/control.md's `stabilized` law in numpy: the model's U-K force for the servo rows with
    b_s + v, v = -2 omega phid - omega^2 phi, so that e obeys e'' + 2 omega e' + omega^2 e = 0
    ([Udwadia2003]); then the least-norm u with B u + A_p^T mu = Qc (u = (P B)^+ P Qc, P the
    projector onto null(A_p))."""
    calls = []

    def law(t, q, qd, d):
        calls.append(t)
        s = d.servo
        b = d.b.copy()
        b[s] += -2.0 * omega * d.phid[s] - omega ** 2 * d.phi[s]
        # Qc = M^{1/2} (A M^{-1/2})^+ (b - A M^-1 Q), paper Eq. (4), with M = L L^T.
        L = np.linalg.cholesky(d.M)
        Linv = np.linalg.inv(L)
        AL = d.A @ Linv.T
        a = d.M.shape[0]
        Qc = L @ (np.linalg.pinv(AL, rcond=1e-10) @ (b - d.A @ np.linalg.solve(d.M, d.Q)))
        Ap = d.A[~s]
        P = np.eye(a) - Ap.T @ np.linalg.pinv(Ap.T, rcond=1e-10)
        return np.linalg.pinv(P @ d.B, rcond=1e-10) @ (P @ Qc)

    law.calls = calls
    return law


STABILIZED = "  law: stabilized\n  omega: 5\n"


def test_python_stabilized_law_equals_the_yaml_law(tmp_path):
    path = paper_control(tmp_path, law=STABILIZED)
    sc = ukdyn.load_scenario(path)
    assert sc.control_law == "stabilized" and len(sc.actuator_names) == 12
    yaml_run = sc.simulate()
    law = stabilized_law(5.0)
    py_run = sc.simulate(control_law=law)
    assert yaml_run.complete and py_run.complete, py_run.message
    # servo_uncertainty (docs/control.md) needs the built-in law's own correction v: a user's law
    # has none, so its run has every column but that one.
    assert law.calls and py_run.columns == [c for c in yaml_run.columns if c != "servo_uncertainty"]
    # Every column (act_residual: NaN for a user's law, ukdyn did not solve for u). The states
    # and servo errors elementwise; the vectors u, Qc, Qp, Qs, qdd normwise (relative to the
    # largest element of the vector over the run): u comes from pseudo-inverses with |u| up to
    # 3e2, so numpy's and Eigen's round-off differ by ~1e-12 on an element near 0 (1e-14 of the
    # scale of u).
    cols = [c for c in py_run.columns if c != "act_residual"]
    n = sc.dof
    states = yaml_run.columns[:1 + 2 * n] + [c for c in cols if c.startswith(("e_", "ed_"))]
    worst_state = max(max_rel_diff(py_run[c], yaml_run[c]) for c in states)

    def group(c):
        for p in ("u_", "Qc_", "Qp_", "Qs_"):
            if c.startswith(p):
                return p
        return "_ddot" if c.endswith("_ddot") else c

    scale = {}
    for c in cols:
        scale[group(c)] = max(scale.get(group(c), 1.0), float(np.max(np.abs(yaml_run[c]))))
    worst = max(float(np.max(np.abs(py_run[c] - yaml_run[c]))) / scale[group(c)] for c in cols)
    print("Python stabilized law vs YAML: states and servo errors %.3g (elementwise), every "
          "column %.3g (normwise), elementwise %.3g; %d columns, %d rows, %d law calls"
          % (worst_state, worst, max(max_rel_diff(py_run[c], yaml_run[c]) for c in cols),
             len(cols), len(py_run), len(law.calls)))
    assert worst_state <= 1e-12 and worst <= 1e-12
    assert np.isnan(py_run["act_residual"]).all()
    assert py_run.summary["control"]["law"] == "user"
    assert py_run.summary["control"]["max_actuation_residual"] is None
    assert yaml_run.summary["control"]["law"] == "stabilized"
    # The law acts: the feedforward law alone leaves the offset; the stabilized one shrinks it as
    # (1 + w t) e^(-w t) on the model (docs/control.md), here on the exact-inertia plant.
    e = np.abs(py_run["e_traj_x"])
    assert e[0] > 0.019 and e[-1] < 0.7 * e[0]
    ff = sc.simulate(control_law=lambda t, q, qd, d: stabilized_law(0.0)(t, q, qd, d))
    assert abs(ff["e_traj_x"][-1]) > 1.5 * e[-1]


def test_a_law_object_with_a_control_method(tmp_path):
    sc = ukdyn.load_scenario(paper_control(tmp_path, law=STABILIZED, t_end=0.05))

    class Law:
        def __init__(self):
            self.inner = stabilized_law(5.0)
            self.seen = None

        def control(self, t, q, qd, data):
            self.seen = data
            return self.inner(t, q, qd, data)

    law = Law()
    run = sc.simulate(control_law=law)
    assert run.complete and law.seen is not None
    d = law.seen
    n, m = sc.dof, d.A.shape[0]
    assert d.M.shape == (n, n) and d.Q.shape == (n,) and d.b.shape == (m,)
    assert d.Qc.shape == (n,) and d.B.shape == (n, 12) and d.servo.dtype == bool
    # Independent check of the data: M qdd = Q + Qc and A qdd = b on the model.
    assert np.max(np.abs(d.M @ d.qdd - (d.Q + d.Qc))) < 1e-9
    assert np.max(np.abs(d.A @ d.qdd - d.b)) < 1e-8
    assert np.allclose(run["t"][-1], 0.05)


def test_control_law_errors(tmp_path):
    sc = ukdyn.load_scenario(paper_control(tmp_path, law=STABILIZED, t_end=0.05))
    law = stabilized_law(5.0)

    def bad(t, q, qd, d):
        if t > 0.01:
            raise ZeroDivisionError("law gave up at t = %g" % t)
        return law(t, q, qd, d)

    with pytest.raises(ZeroDivisionError, match="gave up"):
        sc.simulate(control_law=bad)
    with pytest.raises(ukdyn.Error, match="expected 12 numbers"):
        sc.simulate(control_law=lambda t, q, qd, d: [0.0, 1.0])
    with pytest.raises(TypeError, match="control_law"):
        sc.simulate(control_law=42)
    with pytest.raises(ukdyn.Error, match="control_law="):
        sc.simulate(controller=lambda t, q, qd: np.zeros(12))
    plain = ukdyn.load_scenario(scenario_path("paper.yaml"))
    with pytest.raises(ukdyn.Error, match="no control: section"):
        plain.simulate(control_law=law)


def test_the_gil_is_free_while_the_loop_runs(tmp_path):
    # Another Python thread runs while the closed loop integrates between the law's calls.
    import threading
    import time

    sc = ukdyn.load_scenario(paper_control(tmp_path, t_end=0.1))
    ticks = []
    stop = threading.Event()

    def ticker():
        while not stop.is_set():
            ticks.append(time.monotonic())
            time.sleep(0.001)

    th = threading.Thread(target=ticker)
    th.start()
    try:
        run = sc.simulate()  # the built-in law: no Python call at all
    finally:
        stop.set()
        th.join()
    assert run.complete and len(ticks) > 5


def test_example_control_law_runs():
    # python/examples/control_law.py, as a newcomer runs it.
    example = SOURCE / "python" / "examples" / "control_law.py"
    env = dict(os.environ)
    p = subprocess.run([sys.executable, str(example), "--t-end", "0.2"], capture_output=True,
                       text=True, timeout=120, env=env)
    assert p.returncode == 0, p.stderr
    assert "max difference" in p.stdout, p.stdout
    diff = float(p.stdout.split("max difference")[1].split()[0])
    assert diff <= 1e-12
