"""Scenario.parameter_derivatives and Scenario.sensitivities (docs/derivatives.md, "Sensitivities to
parameters") against independent evidence: central differences of forward() on scenario files
edited here as text, and the CLI's sensitivities.csv (the same numbers through the other door)."""
import _thread
import csv
import json
import threading

import numpy as np
import pytest

import ukdyn
from conftest import run_cli, scenario_path


def edited(tmp_path, name, old, new, tag):
    text = scenario_path(name).read_text()
    assert old in text
    p = tmp_path / f"{tag}_{name}"
    p.write_text(text.replace(old, new))
    return p


def test_parameter_derivatives_match_differences_of_forward(tmp_path):
    sc = ukdyn.load_scenario(scenario_path("five_bar_redundant.yaml"))
    n = sc.dof
    qd = 0.2 * np.cos(np.arange(n) + 0.3)
    tau = 0.3 * np.sin(np.arange(n) + 0.4)
    d = sc.parameter_derivatives(["l1", "m2"], 0.0, sc.q0, qd, tau)
    assert d["trusted"], d["message"]
    assert d["dqdd_dp"].shape == (n, 2) and d["dQc_dp"].shape == (n, 2)
    for j, (key, value) in enumerate([("l1", 0.3), ("m2", 0.8)]):
        h = 1e-3 * value

        def at(v, tag):
            p = edited(tmp_path, "five_bar_redundant.yaml", f"{key}: {value}", f"{key}: {v!r}", tag)
            r = ukdyn.load_scenario(p, check_initial=False).forward(0.0, sc.q0, qd, tau)
            return np.concatenate([r.qdd, r.Qc])

        d1 = (at(value + h, "p1") - at(value - h, "m1")) / (2 * h)
        d2 = (at(value + h / 2, "p2") - at(value - h / 2, "m2")) / h
        fd = (4 * d2 - d1) / 3
        ours = np.concatenate([d["dqdd_dp"][:, j], d["dQc_dp"][:, j]])
        assert np.max(np.abs(ours - fd)) < 1e-6 * np.max(np.abs(fd)), key


def test_ctrl_c_stops_run_sensitivities_with_keyboard_interrupt(tmp_path):
    # a day of motion: only the interrupt ends it within the ctest timeout
    p = edited(tmp_path, "five_bar_redundant.yaml", "t_end: 3\n  sample_dt: 0.01",
               "t_end: 86400\n  sample_dt: 10", "long")
    sc = ukdyn.load_scenario(p)
    timer = threading.Timer(0.5, _thread.interrupt_main)
    timer.start()
    with pytest.raises(KeyboardInterrupt):
        sc.sensitivities(["m1"])
    timer.join()
    q = edited(tmp_path, "five_bar_redundant.yaml", "t_end: 3", "t_end: 0.1", "short")
    assert ukdyn.load_scenario(q).sensitivities(["m1"])["trusted"]  # runs again afterwards


def test_sensitivities_equal_the_cli_csv(tmp_path):
    p = edited(tmp_path, "five_bar_redundant.yaml", "t_end: 3", "t_end: 0.5", "short")
    sc = ukdyn.load_scenario(p)
    s = sc.sensitivities(["m1", "gravity"])
    assert s["trusted"], s["message"]
    assert s["dq_dp"].shape == (2, len(s["t"]), sc.dof)
    # time scaling at rest under gravity alone: dq/dg = qd t / (2 g)
    scale = s["qd"] * s["t"][:, None] / (2 * 9.81)
    assert np.max(np.abs(s["dq_dp"][1] - scale)) < 1e-8 * np.max(np.abs(scale))
    code, out, err = run_cli("sensitivities", str(p), "-p", "m1", "-p", "gravity", "--out",
                             str(tmp_path / "o"))
    assert code == 0, err
    with open(tmp_path / "o" / "sensitivities.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(s["t"])
    col = np.array([float(r["dq_a2/dm1"]) for r in rows])
    assert np.max(np.abs(col - s["dq_dp"][0][:, 1])) <= 1e-15 * np.max(np.abs(col)) + 1e-300


def test_unknown_parameter_is_an_error_naming_it():
    sc = ukdyn.load_scenario(scenario_path("five_bar_redundant.yaml"))
    with pytest.raises(ukdyn.ScenarioError, match="parameter 'm9'"):
        sc.parameter_derivatives(["m9"], 0.0, sc.q0, sc.qd0)


def test_simulate_writes_the_sensitivities_the_scenario_asks_for(tmp_path):
    p = edited(tmp_path, "five_bar_redundant.yaml", "t_end: 3", "t_end: 0.3", "asked")
    p.write_text(p.read_text() + "outputs:\n  sensitivities: [m1]\n")
    code, out, err = run_cli("simulate", str(p), "--out", str(tmp_path / "run"), "--no-figures",
                             "--quiet")
    assert code == 0, err
    with open(tmp_path / "run" / "sensitivities.csv") as f:
        rows = list(csv.DictReader(f))
    s = ukdyn.load_scenario(p).sensitivities(["m1"])
    col = np.array([float(r["dqd_b2/dm1"]) for r in rows])
    assert np.array_equal(col, s["dqd_dp"][0][:, 3])
    # a name the file does not have: exit 2, the list entry named, nothing written
    bad = tmp_path / "bad.yaml"
    bad.write_text(p.read_text().replace("sensitivities: [m1]", "sensitivities: [m1, m7]"))
    code, out, err = run_cli("simulate", str(bad), "--out", str(tmp_path / "bad_run"))
    assert code == 2
    assert "key 'outputs.sensitivities[1]': parameter 'm7'" in err
    assert not (tmp_path / "bad_run").exists()


def test_linearize_param_json_and_npz_equal_python(tmp_path):
    path = scenario_path("five_bar_redundant.yaml")
    code, out, err = run_cli("linearize", str(path), "-p", "gravity", "-p", "l2")
    assert code == 0, err
    j = json.loads(out)["parameters"]
    assert j["names"] == ["gravity", "l2"] and j["values"] == [9.81, 0.4]
    sc = ukdyn.load_scenario(path)
    d = sc.parameter_derivatives(["gravity", "l2"], sc.t0, sc.q0, sc.qd0, sc.tau)
    assert np.array_equal(np.array(j["dqdd_dp"]), d["dqdd_dp"])
    assert np.array_equal(np.array(j["dQc_dp"]), d["dQc_dp"])
    code, out, err = run_cli("linearize", str(path), "-p", "gravity", "--out",
                             str(tmp_path / "l.npz"))
    assert code == 0, err
    z = np.load(tmp_path / "l.npz")
    assert z["parameters_dqdd_dp"].shape == (sc.dof, 1)
    assert z["parameters_trusted"] == 1.0 and z["trusted"] == 1.0
    code, out, err = run_cli("linearize", str(path), "-p", "nope")
    assert code == 2 and "parameter 'nope'" in err


HOLD = """ukdyn: 1
name: pendulum_hold
gravity: 9.8
subsystems:
  - name: bob
    type: definitions
    coordinates: [x, z]
    parameters: {m: 1}
    bodies:
      - {name: bob, mass: m, com: [x, 0, z]}
constraints:
  - {type: expression, name: rod, rows: {circle: (x^2 + z^2 - 1)/2}}
  - {type: expression, name: swing, role: servo, rows: {angle: x*cos(0.3) + z*sin(0.3)}}
actuators:
  - {name: fx, coordinate: x}
control:
  law: robust
  lambda: 2
  kappa: 5
  rho: 0
  initial_offset: {swing_angle: 0.001}
initial:
  q: [0.29552020666133955, -0.955336489125606]
simulation: {t_end: 2, sample_dt: 0.01, abs_tol: 1e-12, rel_tol: 1e-12}
"""


def test_controlled_run_sensitivities_closed_form(tmp_path):
    """A bob held at 0.3 rad by the feedback-only robust law on its exact model: e = sin(theta - 0.3)
    obeys e'' + (lambda + kappa) e' + kappa lambda e = 0 from e0 = 1e-3 at rest, so
    e(t) = e0 (kappa exp(-lambda t) - lambda exp(-kappa t)) / (kappa - lambda): dq/dkappa and
    dq/dlambda in closed form, dq/dm = 0; the closed loop's eigenvalues at the hold are -lambda,
    -kappa (docs/derivatives.md, "Controlled runs")."""
    p = tmp_path / "hold.yaml"
    p.write_text(HOLD)
    sc = ukdyn.load_scenario(p)
    s = sc.sensitivities(["m", "control.kappa", "control.lambda"])
    assert s["trusted"], s["message"]
    assert s["warnings"] == []
    # the law's d tau/dx exact at every right-hand side (no kink: rho = 0, no limit)
    assert s["law_derivative"].startswith("exact at ") and "differences" not in s["law_derivative"]
    t = s["t"]
    lam, kap, e0 = 2.0, 5.0, 1e-3
    a, b, D = np.exp(-lam * t), np.exp(-kap * t), kap - lam
    e = e0 * (kap * a - lam * b) / D
    de = {
        1: e0 * ((a + lam * t * b) / D - (kap * a - lam * b) / D**2),
        2: e0 * ((-kap * t * a - b) / D + (kap * a - lam * b) / D**2),
    }
    th = 0.3 + np.arcsin(e)
    for j, dej in de.items():
        dth = dej / np.sqrt(1 - e * e)
        ref = np.stack([np.cos(th) * dth, np.sin(th) * dth], axis=1)
        assert np.max(np.abs(s["dq_dp"][j] - ref)) < 1e-6 * np.max(np.abs(ref)), j
    assert np.max(np.abs(s["dq_dp"][0])) < 1e-6 * np.max(np.abs(s["dq_dp"][1]))
    hold = sc.closed_loop_linearize(0.0, [np.sin(0.3), -np.cos(0.3)], [0.0, 0.0])
    assert hold["trusted"] and hold["kinks"] == [] and hold["dtau_method"] == "exact"
    assert hold["dtau_dt_method"] == "exact"
    ev = np.sort(np.linalg.eigvals(hold["F_min"]).real)
    assert np.allclose(ev, [-5.0, -2.0], rtol=0, atol=1e-8)
    start = sc.closed_loop_linearize()  # the closed loop's start: 1e-3 off the servo row
    assert abs(np.sin(np.arctan2(start["q"][0], -start["q"][1]) - 0.3) - 1e-3) < 1e-12
    assert start["F"].shape == (4, 4) and start["dtau_dq"].shape == (2, 2)
