"""ukdyn.Scenario.simulate(): the columns equal the CLI's trajectory.csv, they are views of one C++
buffer, and Python controllers / applied forces give the same runs as their YAML equivalents."""
import math

import numpy as np
import pytest

import ukdyn
from conftest import cli_csv, max_rel_diff, scenario_path

# A double pendulum (point masses) whose tip is driven along x by a time-varying constraint:
# 1 free DOF, constraint forces that work. FORCES is replaced by each test.
W0 = 0.05 / math.cos(0.3)  # qd0 = (w, w) satisfies the velocity level at t = 0
PENDULUM = """ukdyn: 1
name: driven_double_pendulum
gravity: 9.81
subsystems:
  - name: arm
    type: definitions
    coordinates: [phi1, phi2]
    parameters: {m1: 1, m2: 0.5, l1: 1, l2: 1}
    gravity: [0, 0, -9.81]
    bodies:
      - {name: b1, mass: m1, com: [l1*sin(phi1), 0, -l1*cos(phi1)]}
      - {name: b2, mass: m2, com: [l1*sin(phi1) + l2*sin(phi2), 0, -l1*cos(phi1) - l2*cos(phi2)]}
constraints:
  - type: expression
    name: tip
    rows:
      x: sin(phi1) + sin(phi2) - 0.1*sin(t)
initial:
  q: [0.3, -0.3]
  qd: [%r, %r]
FORCES
simulation:
  t_end: 2
  sample_dt: 0.01
  energy_balance: true
""" % (W0, W0)

KP, KD, REF, DAMPING = 20.0, 3.0, 0.5, 0.4


def write(tmp_path, name, forces):
    p = tmp_path / name
    p.write_text(PENDULUM.replace("FORCES", forces))
    return p


def assert_run_equals_csv(run, header, data, tol):
    assert run.columns == header
    assert run.data.shape == data.shape
    for j, name in enumerate(header):
        assert max_rel_diff(run[name], data[:, j]) <= tol, name


@pytest.mark.parametrize("name", ["paper.yaml", "rolling_disk.yaml"])
def test_columns_equal_the_cli_csv(tmp_path, name):
    path = scenario_path(name)
    header, data, summary = cli_csv(path, tmp_path / "out")
    run = ukdyn.load_scenario(path).simulate()
    assert run.complete and run.status == "completed"
    assert_run_equals_csv(run, header, data, 1e-14)
    # The summary is summary.json's, but for what only a run on disk has.
    skip = {"wall_seconds", "trajectory_csv", "figures", "figures_left_out"}
    assert {k: v for k, v in run.summary.items() if k not in skip} == \
        {k: v for k, v in summary.items() if k not in skip}
    assert run.warnings == [{"t": w["t"], "kind": w["kind"], "message": w["message"]}
                            for w in summary["warnings"]]


def test_frame_constraint_columns_equal_the_cli_csv(tmp_path):
    # The Fc_/W_ columns of frame constraints (docs/frame-constraints.md) and their summary
    # section are the CLI's too; a short horizon of paper_load_body.yaml (two welds, redundant).
    text = scenario_path("paper_load_body.yaml").read_text()
    assert "  t_end: 4\n" in text and "urdf: paper_arm.urdf" in text
    text = text.replace("  t_end: 4\n", "  t_end: 0.2\n").replace(
        "urdf: paper_arm.urdf", "urdf: %s" % scenario_path("paper_arm.urdf"))
    path = tmp_path / "load_body_short.yaml"
    path.write_text(text)
    header, data, summary = cli_csv(path, tmp_path / "out")
    run = ukdyn.load_scenario(path).simulate()
    assert any(c.startswith("W_grasp_l") for c in header), header
    assert_run_equals_csv(run, header, data, 1e-14)
    assert run.summary["constraint_forces"] == summary["constraint_forces"]
    assert [w["kind"] for w in run.warnings] == [w["kind"] for w in summary["warnings"]]


def test_wrench_pose_and_velocity_rows(tmp_path):
    # The grasp wrenches, internal wrenches and grasp poses of four robots welded to a load, as
    # views of the columns; the load's net force from the grasps is its m (a - g) (Newton), from
    # the arrays alone. The rolling disk's rows are velocity-level (vres_ columns).
    text = scenario_path("n_robots_4_weld.yaml").read_text()
    assert "  t_end: 1\n" in text
    path = tmp_path / "weld_short.yaml"
    path.write_text(text.replace("  t_end: 1\n", "  t_end: 0.1\n"))
    run = ukdyn.load_scenario(path).simulate()
    assert run.complete
    grasps = ["grasp%d" % k for k in range(4)]
    force = sum(run.wrench(g)[:, :3] for g in grasps)
    acc = np.column_stack([run["load_%s_ddot" % a] for a in "xyz"])
    newton = 3.0 * (acc - np.array([0.0, 0.0, -9.81]))
    assert np.max(np.abs(force - newton)) <= 1e-12 * np.max(np.abs(newton))
    for form in ("internal_walker", "internal_weighted"):
        w = run.wrench("grasp1", form)
        assert w.shape == (len(run), 6) and np.shares_memory(w, run.data)
        assert np.array_equal(w[:, 2], run["Wint_%s_grasp1_fz" % form[len("internal_"):]])
        net = sum(run.wrench(g, form)[:, :3] for g in grasps)
        assert np.max(np.abs(net)) <= 1e-12 * np.max(np.abs(newton))
    pose = run.pose("grasp0")
    assert pose.shape == (len(run), 7)
    assert np.allclose(np.linalg.norm(pose[:, 3:], axis=1), 1.0, atol=1e-14)
    assert (pose[:, 3] >= 0).all()
    with pytest.raises(ValueError):
        run.wrench("grasp0", "sideways")
    with pytest.raises(KeyError):
        run.pose("grasp9")
    assert run.velocity_level_rows == []
    disk = ukdyn.load_scenario(scenario_path("rolling_disk.yaml")).simulate()
    assert disk.velocity_level_rows == ["roll_x", "roll_y"]
    assert "res_roll_x" not in disk and "vres_roll_x" in disk


def test_columns_share_one_buffer():
    run = ukdyn.load_scenario(scenario_path("paper.yaml")).simulate()
    t, th = run["t"], run["theta1"]
    data = run.data
    assert np.shares_memory(t, data) and np.shares_memory(th, data)
    assert np.shares_memory(run["theta1"], th)  # a second view, the same memory
    assert not t.flags.owndata and not th.flags.owndata and not data.flags.owndata
    assert t.base is th.base  # one owner of the C++ buffer for every column
    j = run.columns.index("theta1")
    assert th.ctypes.data == data.ctypes.data + 8 * j * len(run)  # column-major, contiguous
    data[3, j] = 42.0  # a view: the write shows in the column
    assert th[3] == 42.0
    del run, data, t
    assert np.isfinite(th[:3]).all()  # the buffer lives as long as a view does


def test_python_pd_controller_equals_the_yaml_force(tmp_path):
    yaml_pd = write(tmp_path, "pd.yaml", "forces:\n  generalized:\n    phi1: -%r*(phi1 - %r) - %r*phi1_dot\n"
                    % (KP, REF, KD))
    header, data, _ = cli_csv(yaml_pd, tmp_path / "out")
    plain = ukdyn.Scenario.from_text(PENDULUM.replace("FORCES", ""), "plain.yaml")
    calls = []

    def pd(t, q, qd):
        calls.append(t)
        return [-KP * (q[0] - REF) - KD * qd[0], 0.0]

    run = plain.simulate(controller=pd)
    assert run.complete and calls
    assert_run_equals_csv(run, header, data, 1e-12)
    # The controller acts: without it the run differs by far more.
    free = plain.simulate()
    assert np.max(np.abs(free["phi1"] - run["phi1"])) > 1e-2


def test_python_damper_equals_the_yaml_joint_friction(tmp_path):
    yaml_damper = write(tmp_path, "damper.yaml", """forces:
  elements:
    - {type: joint_friction, name: f1, coordinate: phi1, viscous: %r}
    - {type: joint_friction, name: f2, coordinate: phi2, viscous: %r}""" % (DAMPING, DAMPING))
    header, data, _ = cli_csv(yaml_damper, tmp_path / "out")
    plain = ukdyn.Scenario.from_text(PENDULUM.replace("FORCES", ""), "plain.yaml")
    run = plain.simulate(forces=[lambda t, q, qd: -DAMPING * qd])
    assert run.complete
    assert_run_equals_csv(run, header, data, 1e-12)
    # Independent check: E - W stays constant (the damper's work is counted).
    assert np.max(np.abs(run["E_balance"] - run["E_balance"][0])) < 1e-8
    assert run["W"][-1] != 0.0


def test_callback_exception_is_raised_with_its_type():
    sc = ukdyn.Scenario.from_text(PENDULUM.replace("FORCES", ""), "plain.yaml")

    def bad(t, q, qd):
        if t > 0.5:
            raise ZeroDivisionError("controller gave up at t = %g" % t)
        return [0.0, 0.0]

    with pytest.raises(ZeroDivisionError, match="gave up"):
        sc.simulate(controller=bad)
    with pytest.raises(ukdyn.Error, match="expected 2 numbers"):
        sc.simulate(forces=[lambda t, q, qd: [1.0, 2.0, 3.0]])
    with pytest.raises(TypeError):
        sc.simulate(controller=42)


@pytest.mark.parametrize("integrator", ["bdf", "esdirk"])
def test_callback_exception_through_the_implicit_integrator(integrator):
    # bdf is SUNDIALS CVODE, esdirk ARKODE (C): the exception must not cross their frames, and
    # still be raised.
    text = PENDULUM.replace("FORCES", "")
    text = text.replace("energy_balance: true", "integrator: " + integrator)
    try:
        sc = ukdyn.Scenario.from_text(text, integrator + ".yaml")
    except ukdyn.ScenarioError as e:
        pytest.skip("ukdyn built without SUNDIALS: %s" % e)

    def bad(t, q, qd):
        raise RuntimeError("boom")

    with pytest.raises(RuntimeError, match="boom"):
        sc.simulate(controller=bad)
    assert sc.simulate(controller=lambda t, q, qd: [0.0, 0.0]).complete


def test_system_from_code_conserves_energy():
    # Independent evidence for a system built in code: the free pendulum keeps E = T + V.
    d = ukdyn.SubsystemDef("pendulum", ["x", "y"])
    d.add_body("P1", mass=1, com=["x", "y", 0])
    d.gravity = [0, -9.81, 0]
    c = ukdyn.ConstraintDef("rod", "holonomic", ["x", "y"])
    c.add_row("length", "x^2 + y^2 - 1")
    s = ukdyn.System()
    s.add_subsystem(ukdyn.make_subsystem(d))
    s.add_constraint(ukdyn.make_constraint(c))
    sc = ukdyn.Scenario.from_system(s, q0=[1, 0], t_end=2.0, sample_dt=0.01, abs_tol=1e-12,
                                    rel_tol=1e-12)
    run = sc.simulate()
    assert run.complete and len(run) == 201
    assert np.max(np.abs(run["E"] - run["E"][0])) < 1e-8
    assert np.max(np.abs(run["x"] ** 2 + run["y"] ** 2 - 1)) < 1e-12


def test_numerical_trouble_is_a_status_bad_settings_an_error():
    sc = ukdyn.Scenario.from_text(PENDULUM.replace("FORCES", ""), "plain.yaml")
    run = sc.simulate(controller=lambda t, q, qd: [math.nan, 0.0])
    assert not run.complete and run.status == "non_finite" and run.message
    assert run.summary["status"] == "incomplete"
    assert run.data.shape[0] == len(run) and all(run[c].size == len(run) for c in run.columns)
    with pytest.raises(ValueError, match="sample_dt"):  # bad settings: refused on assignment
        sc.sample_dt = -1.0


def test_a_mass_of_t_that_turns_negative_during_the_run_is_an_error():
    # derive() checks a mass of t at t = 0 only; simulate() checks it over t0..t_end (times at most
    # sample_dt apart, >= 1001 times): m(t) = 2 (1 - t) is 0 at t = 1, negative after.
    d = ukdyn.SubsystemDef("s", ["z"])
    d.parameter("m0", 2.0)
    d.add_body("shrinking", mass="m0*(1 - t)", com=[0, 0, "z"])
    d.gravity = [0, 0, -9.81]
    s = ukdyn.System()
    s.add_subsystem(ukdyn.make_subsystem(d))
    sc = ukdyn.Scenario.from_system(s, q0=[1.0], t_end=0.9, sample_dt=0.1)
    assert sc.simulate().complete
    sc.t_end = 1.5
    with pytest.raises(ukdyn.Error, match=r"subsystem 's', body 'shrinking': the mass .* at t = 1\.0"):
        sc.simulate()
