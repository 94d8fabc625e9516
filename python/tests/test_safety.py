"""No silent wrong answer from Python: non-finite inputs refused (as `ukdyn eval` refuses them),
a singular mass matrix or a non-finite result raised, every setter checked on assignment, an
inconsistent start refused (or assembled on request), and Ctrl-C stopping a long simulate()."""
import _thread
import math
import threading

import numpy as np
import pytest

import ukdyn
from conftest import scenario_path

FIVE_BAR = scenario_path("five_bar_redundant.yaml")


def five_bar():
    return ukdyn.load_scenario(FIVE_BAR)


BAD = [math.nan, math.inf, -math.inf]


@pytest.mark.parametrize("bad", BAD)
@pytest.mark.parametrize("which", ["q", "qd", "tau"])
def test_forward_refuses_non_finite_inputs_as_eval_does(which, bad):
    sc = five_bar()
    args = {"q": sc.q0.copy(), "qd": sc.qd0.copy(), "tau": np.zeros(sc.dof)}
    args[which][2] = bad
    with pytest.raises(ValueError, match=r"%s\[2\]: not finite" % which):
        sc.forward(0.0, args["q"], args["qd"], args["tau"])
    d = sc.make_data()
    with pytest.raises(ValueError, match=r"%s\[2\]: not finite" % which):
        sc.forward(args["q"], args["qd"], t=0.0, tau=args["tau"], out=d)
    with pytest.raises(ValueError, match=r"%s\[2\]: not finite" % which):
        sc.forward_qdd(args["q"], args["qd"], tau=args["tau"])
    with pytest.raises(ValueError, match="not finite"):
        sc.linearize(0.0, args["q"], args["qd"], args["tau"])


@pytest.mark.parametrize("bad", BAD)
def test_forward_refuses_a_non_finite_time(bad):
    sc = five_bar()
    with pytest.raises(ValueError, match="t: not finite"):
        sc.forward(bad, sc.q0, sc.qd0)
    with pytest.raises(ValueError, match="t: not finite"):
        sc.forward(sc.q0, sc.qd0, t=bad, out=sc.make_data())
    with pytest.raises(ValueError, match="t: not finite"):
        sc.forward_qdd(sc.q0, sc.qd0, t=bad)


def test_inf_velocity_no_longer_gives_a_finite_answer():
    # Before: qd = inf returned a finite qdd with finite=True. Now refused at the edge; and a state
    # whose result is non-finite (huge but finite velocities overflowing C qd) raises ukdyn.Error.
    sc = five_bar()
    qd = np.full(sc.dof, 1e200)
    with pytest.raises(ukdyn.Error, match="non-finite result"):
        sc.forward(0.0, sc.q0, qd)
    with pytest.raises(ukdyn.Error, match="non-finite result"):
        sc.forward(sc.q0, qd, out=sc.make_data())
    with pytest.raises(ukdyn.Error, match="row 1: non-finite result"):
        sc.forward_qdd(np.array([sc.q0, sc.q0]), np.array([sc.qd0, qd]))


def test_a_singular_mass_matrix_raises():
    # A point mass at height z w: its velocity w z_dot + z w_dot spans one direction of (z_dot,
    # w_dot), so M = m [w^2, z w; z w, z^2] is singular everywhere, and no constraint fixes the
    # other direction.
    d = ukdyn.SubsystemDef("s", ["z", "w"])
    d.parameter("m", 1.0)
    d.add_body("p", mass="m", com=[0, 0, "z*w"])
    s = ukdyn.System()
    s.add_subsystem(ukdyn.make_subsystem(d))
    sc = ukdyn.Scenario.from_system(s, q0=[1.0, 1.0])
    with pytest.raises(ukdyn.Error, match="singular"):
        sc.forward(0.0, [1.0, 1.0], [0.0, 0.0])
    with pytest.raises(ukdyn.Error, match="singular|non-finite"):
        sc.forward([1.0, 1.0], [0.0, 0.0], out=sc.make_data())
    with pytest.raises(ukdyn.Error, match="singular|non-finite"):
        sc.forward_qdd([1.0, 1.0], [0.0, 0.0])


def test_setters_validate_on_assignment():
    sc = five_bar()
    with pytest.raises(ValueError, match="t_end: must be greater than t0"):
        sc.t_end = sc.t0
    with pytest.raises(ValueError, match="t_end: not finite"):
        sc.t_end = math.inf
    with pytest.raises(ValueError, match="t0: must be less than t_end"):
        sc.t0 = sc.t_end + 1
    with pytest.raises(ValueError, match="t0: not finite"):
        sc.t0 = math.nan
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="sample_dt"):
            sc.sample_dt = bad
    for key in ("abs_tol", "rel_tol", "initial_tolerance"):
        for bad in (-1e-12, 0.0, 2.0, math.nan):
            with pytest.raises(ValueError, match=key + ": a tolerance must lie in"):
                setattr(sc, key, bad)
    with pytest.raises(ValueError, match=r"q0\[1\]: not finite"):
        sc.q0 = [0.0, math.nan, 0.0, 0.0]
    with pytest.raises(ValueError, match=r"qd0: expected 4 numbers"):
        sc.qd0 = [0.0]
    with pytest.raises(ValueError, match=r"tau\[3\]: not finite"):
        sc.tau = [0.0, 0.0, 0.0, math.inf]
    # nothing changed by the refused assignments
    fresh = five_bar()
    assert sc.t0 == fresh.t0 and sc.t_end == fresh.t_end and sc.sample_dt == fresh.sample_dt
    assert sc.abs_tol == fresh.abs_tol and np.array_equal(sc.q0, fresh.q0)
    sc.t_end = 0.5
    sc.abs_tol = 1e-10
    assert sc.t_end == 0.5 and sc.abs_tol == 1e-10
    d = ukdyn.SubsystemDef("s", ["z"])
    d.add_body("p", mass=1.0, com=[0, 0, "z"])
    s = ukdyn.System()
    s.add_subsystem(ukdyn.make_subsystem(d))
    for bad in ({"t_end": math.inf}, {"t0": math.nan}, {"abs_tol": -1.0}, {"rel_tol": 0.0}):
        with pytest.raises(ValueError):
            ukdyn.Scenario.from_system(s, q0=[0.0], **bad)


def test_an_inconsistent_start_raises_naming_the_rows():
    sc = five_bar()
    sc.t_end = 0.05
    sc.q0 = sc.q0 + 0.1
    phi = sc.constraints(sc.q0, sc.qd0)["phi"]
    with pytest.raises(ValueError) as e:
        sc.simulate()
    msg = str(e.value)
    assert "q0 violates the constraints" in msg and "assemble=True" in msg
    for name, r in zip(sc.constraint_row_names, phi):  # every row named with its residual
        assert "'%s' = %.3e" % (name, r) in msg
    # velocities too
    sc2 = five_bar()
    sc2.t_end = 0.05
    with pytest.raises(ValueError, match="qd0 violates the velocity constraints"):
        sc2.simulate(qd0=np.ones(sc2.dof))


def test_assemble_true_starts_from_the_assembled_state_and_reports_it():
    sc = five_bar()
    sc.t_end = 0.05
    sc.q0 = sc.q0 + 0.1
    a = sc.assemble()
    run = sc.simulate(assemble=True)
    assert run.complete and run.assembly is not None and run.assembly["success"]
    q_first = np.array([run[c][0] for c in sc.coordinate_names])
    np.testing.assert_array_equal(q_first, a["q"])
    np.testing.assert_array_equal(run.assembly["q"], a["q"])
    # a consistent start runs without assemble and reports nothing
    ok = five_bar()
    ok.t_end = 0.05
    assert ok.simulate().assembly is None


def test_simulate_from_an_explicit_state():
    sc = five_bar()
    ref = sc.simulate(t_end=0.2)  # the scenario's start, to 0.2 s
    i = 10  # restart from the sample at t = 0.1
    q = np.array([ref[c][i] for c in sc.coordinate_names])
    qd = np.array([ref[c + "_dot"][i] for c in sc.coordinate_names])
    run = sc.simulate(q0=q, qd0=qd, t0=ref["t"][i], t_end=0.2)
    assert run.complete and run["t"][0] == ref["t"][i] and run["t"][-1] == pytest.approx(0.2)
    for c in sc.coordinate_names:  # the same motion (different steps: to the tolerance)
        assert np.max(np.abs(run[c] - ref[c][i:])) < 1e-9
    assert sc.t_end == 3.0 and sc.t0 == 0.0  # the scenario is unchanged
    with pytest.raises(ValueError, match="t_end must be greater than t0"):
        sc.simulate(t0=1.0, t_end=0.5)
    with pytest.raises(ValueError, match=r"q0\[0\]: not finite"):
        sc.simulate(q0=[math.nan, 0, 0, 0])


def interrupt_after(seconds):
    timer = threading.Timer(seconds, _thread.interrupt_main)
    timer.start()
    return timer


def test_ctrl_c_stops_a_long_simulate_with_keyboard_interrupt():
    sc = five_bar()
    sc.t_end = 1e7  # hours of integration: only the interrupt ends it within the ctest timeout
    sc.sample_dt = 1.0
    timer = interrupt_after(0.5)
    with pytest.raises(KeyboardInterrupt) as e:
        sc.simulate()
    timer.join()
    # the run so far comes with the exception, incomplete as the CLI's run on Ctrl-C
    run = e.value.run
    assert run.status == "stopped" and not run.complete and run.message
    assert run.summary["status"] == "incomplete"
    assert len(run) >= 1 and 0.0 < run["t"][-1] < sc.t_end
    # the scenario still runs afterwards
    sc.t_end = 0.05
    assert sc.simulate().complete


def test_ctrl_c_with_a_python_controller():
    sc = five_bar()
    sc.t_end = 1e7
    sc.sample_dt = 1.0
    calls = []

    def controller(t, q, qd):
        calls.append(t)
        return np.zeros(4)

    timer = interrupt_after(0.5)
    with pytest.raises(KeyboardInterrupt):
        sc.simulate(controller=controller)
    timer.join()
    assert len(calls) > 0


def long_lift_problem(tmp_path):
    """The paper's lift on 300 intervals: tens of IPOPT iterations of about a second each."""
    text = open(scenario_path("optimize/paper_lift.yaml")).read()
    text = text.replace("intervals: 50", "intervals: 300")
    text = text.replace("../paper_free.yaml", str(scenario_path("paper_free.yaml")))
    problem = tmp_path / "long_lift.yaml"
    problem.write_text(text)
    return str(problem)


@pytest.mark.skipif(not ukdyn.ipopt_available(), reason="built without IPOPT")
def test_ctrl_c_stops_optimize_with_keyboard_interrupt(tmp_path):
    out = tmp_path / "out"
    timer = interrupt_after(0.5)
    with pytest.raises(KeyboardInterrupt):
        ukdyn.optimize(long_lift_problem(tmp_path), str(out))
    timer.join()
    # the folder holds IPOPT's last iterate, marked as such, as the CLI's on Ctrl-C
    import json
    summary = json.loads((out / "summary.json").read_text())
    assert summary["trusted"] is False and "interrupted" in summary["message"]
    assert summary["ipopt"]["status"] == "User_Requested_Stop"
    assert "replay" not in summary


@pytest.mark.skipif(not ukdyn.ipopt_available(), reason="built without IPOPT")
def test_optimize_refuses_ipopt_options_naming_files_and_unknown_ones(tmp_path):
    base = open(scenario_path("optimize/paper_lift.yaml")).read().replace(
        "../paper_free.yaml", str(scenario_path("paper_free.yaml")))
    victim = tmp_path / "victim.txt"
    victim.write_text("mine\n")
    for options, message in [
            ("{output_file: %s}" % victim, "key 'ipopt.options.output_file'"),
            ("{hsllib: %s}" % (tmp_path / "x.so"), "key 'ipopt.options.hsllib'"),
            ("{no_such_option: 1}", "no IPOPT option named 'no_such_option'"),
            ("{max_iter: 2.5}", "takes a whole number")]:
        problem = tmp_path / "p.yaml"
        problem.write_text(base + "ipopt:\n  options: %s\n" % options)
        with pytest.raises(ukdyn.ScenarioError, match=message):
            ukdyn.optimize(str(problem))
    assert victim.read_text() == "mine\n"


def test_linearize_off_the_constraints_warns_naming_the_row():
    sc = five_bar()
    q = np.array([1.0, 2.0, 3.0, 4.0])  # the closure open (as `ukdyn linearize --state` warns)
    with pytest.warns(UserWarning, match=r"off the constraints \(row 'end_[xz]'"):
        lin = sc.linearize(0.0, q, np.zeros(4), np.zeros(4))
    assert lin.F.shape == (8, 8)
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # on the constraints: no warning
        sc.linearize(0.0, sc.q0, sc.qd0, np.zeros(4))
