"""ukdyn from Python: forward() against `ukdyn eval`, systems built in code against closed forms,
errors as Python exceptions with ukdyn's FILE:LINE:COLUMN messages, `ukdyn assemble`'s paste-ready
initial section, and the GIL released while C++ runs."""
import os
import pathlib
import re
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

import ukdyn
from conftest import SOURCE, cli_eval, max_rel_diff, run_cli, scenario_path

EVAL_KEYS = ["M", "C", "Cqd", "G", "Q", "A", "b", "Qc", "qdd"]


def random_states(sc, count, seed):
    rng = np.random.default_rng(seed)
    n = sc.dof
    for k in range(count):
        q = sc.q0 + 0.05 * rng.standard_normal(n)
        qd = 0.3 * rng.standard_normal(n)
        tau = rng.standard_normal(n) if k % 2 else np.zeros(n)
        yield 0.1 * k, q, qd, tau


@pytest.mark.parametrize("name", ["paper.yaml", "paper_generic.yaml", "rolling_disk.yaml",
                                  "five_bar_redundant.yaml"])
def test_forward_equals_ukdyn_eval(name):
    path = scenario_path(name)
    sc = ukdyn.load_scenario(path)
    states = list(random_states(sc, 6, seed=len(name)))
    answers = cli_eval(path, [{"t": t, "q": q.tolist(), "qd": qd.tolist(), "tau": tau.tolist()}
                              for t, q, qd, tau in states])
    assert len(answers) == len(states)
    for (t, q, qd, tau), ref in zip(states, answers):
        assert "error" not in ref, ref
        r = sc.forward(t, q, qd, tau)
        for key in EVAL_KEYS:
            got = getattr(r, key)
            want = np.array(ref[key], dtype=float).reshape(got.shape)
            assert max_rel_diff(got, want) <= 1e-14, (name, key)
        assert r.rank == ref["rank"]
        assert r.consistent == ref["consistent"]
        assert abs(r.residual - ref["residual"]) <= 1e-14 * max(1.0, abs(ref["residual"]))
        assert r.M.shape == (sc.dof, sc.dof) and r.A.shape == (sc.rows, sc.dof)


def test_forward_satisfies_the_equations():
    # Independent of eval: M qdd = Q + Qc (Eq. (18)) and A qdd = b at a state of the paper's system.
    sc = ukdyn.load_scenario(scenario_path("paper.yaml"))
    _, q, qd, tau = list(random_states(sc, 2, seed=3))[1]
    r = sc.forward(0.3, q, qd, tau)
    assert np.max(np.abs(r.M @ r.qdd - (r.Q + r.Qc))) < 1e-10
    assert np.max(np.abs(r.A @ r.qdd - r.b)) < 1e-9
    assert np.max(np.abs(r.C @ qd - r.Cqd)) < 1e-10
    assert np.allclose(r.M, r.M.T, atol=0, rtol=0)


def cartesian_pendulum(L=1.0, m=1.0, g=9.81):
    d = ukdyn.SubsystemDef("pendulum", ["x", "y"])
    d.parameter("m", m)
    d.add_body("P1", mass="m", com=["x", "y", 0])
    d.gravity = [0, -g, 0]
    c = ukdyn.ConstraintDef("rod", "holonomic", ["x", "y"])
    c.parameter("L", L)
    c.add_row("length", "x^2 + y^2 - L^2")
    s = ukdyn.System()
    assert s.add_subsystem(ukdyn.make_subsystem(d)) == 0
    assert s.add_constraint(ukdyn.make_constraint(c)) == 0
    return s


def test_system_from_definitions_closed_form():
    # A point mass on a massless rod of length L (Cartesian x, y): at the bottom (0, -L) moving at
    # speed v, qdd = (0, v^2 / L) (centripetal); the rod force is m (g + v^2 / L) upwards.
    L, m, g, v = 1.5, 2.0, 9.81, 0.7
    s = cartesian_pendulum(L, m, g)
    assert s.coordinate_names == ["x", "y"] and s.constraint_row_names == ["length"]
    sc = ukdyn.Scenario.from_system(s, q0=[0, -L], qd0=[v, 0], t_end=1.0)
    r = sc.forward(0.0, [0, -L], [v, 0])
    assert np.allclose(r.M, m * np.eye(2), rtol=0, atol=1e-15)
    assert np.allclose(r.qdd, [0, v * v / L], rtol=0, atol=1e-13)
    assert np.allclose(r.Qc, [0, m * (g + v * v / L)], rtol=0, atol=1e-12)
    assert r.rank == 1


def test_system_from_definitions_equals_the_yaml_scenario():
    # The same model written in code and in scenarios/benchmarks/simple_pendulum.yaml.
    sc_yaml = ukdyn.load_scenario(scenario_path("benchmarks/simple_pendulum.yaml"))
    sc_code = ukdyn.Scenario.from_system(cartesian_pendulum(), q0=[1, 0], t_end=10,
                                         sample_dt=0.01)
    for t, q, qd, tau in random_states(sc_yaml, 4, seed=7):
        a, b = sc_yaml.forward(t, q, qd, tau), sc_code.forward(t, q, qd, tau)
        for key in EVAL_KEYS:
            assert max_rel_diff(getattr(a, key), getattr(b, key)) <= 1e-14, key


def test_python_force_in_forward():
    # A Python applied force adds to Q exactly: Q(force) - Q(no force) = f.
    sc = ukdyn.load_scenario(scenario_path("paper.yaml"))
    q, qd = sc.q0, np.linspace(-0.2, 0.3, sc.dof)
    f = np.linspace(1.0, 2.0, sc.dof)
    r0 = sc.forward(0.0, q, qd)
    r1 = sc.forward(0.0, q, qd, forces=[lambda t, q, qd: f])
    assert np.max(np.abs((r1.Q - r0.Q) - f)) <= 1e-13


def test_bad_scenario_raises_with_file_line_column():
    path = SOURCE / "tests" / "hostile" / "com_two_entries.yaml"
    expect = path.read_text().splitlines()[0].removeprefix("# expect: ")
    with pytest.raises(ukdyn.ScenarioError) as info:
        ukdyn.load_scenario(path)
    msg = str(info.value)
    assert re.match(r"^.*com_two_entries\.yaml:\d+:\d+: ", msg), msg
    assert expect in msg
    assert isinstance(info.value, ukdyn.Error)
    # The same message as the CLI's (exit 2).
    code, _, err = run_cli("check", path)
    assert code == 2 and msg in err


def test_bad_scenario_text_names_the_line():
    text = scenario_path("paper.yaml").read_text().replace("t_end: 4", "t_end: -4")
    with pytest.raises(ukdyn.ScenarioError, match=r"^bad\.yaml:\d+:\d+: key 'simulation.t_end'"):
        ukdyn.Scenario.from_text(text, "bad.yaml")


def test_errors_of_definitions_and_sizes():
    d = ukdyn.SubsystemDef("p", ["phi"])
    with pytest.raises(ukdyn.Error, match="column"):
        d.add_body("b", mass="1 +* 2", com=[0, 0, 0])
    d.add_body("b", mass=1, com=["sin(phi)", 0, 0])
    c = ukdyn.ConstraintDef("c", "holonomic", ["phi"])
    c.add_row("bad", "phi_dot")  # a velocity in a holonomic row: refused by the derivation
    with pytest.raises(ukdyn.Error):
        ukdyn.make_constraint(c)
    sc = ukdyn.load_scenario(scenario_path("paper.yaml"))
    with pytest.raises(ValueError, match="12"):
        sc.forward(0.0, [0.0, 1.0], sc.qd0)


def test_assemble_prints_a_pasteable_initial_section(tmp_path):
    # Perturb the paper's q0 off the constraints, assemble with the CLI, paste its initial: block
    # over the scenario's: the pasted file passes `ukdyn check` (the state is consistent) and loads
    # the assembled doubles exactly.
    text = scenario_path("paper.yaml").read_text()
    old = "  q: [0, 0, 0, pi/2, -pi/3, 0, 1.6, 0, -pi, pi/2, -pi/3, 0]\n  qd: zeros\n"
    assert old in text
    guess = text.replace(old, "  q: [0, 0, 0, 1.6, -1.0, 0.01, 1.62, 0.01, -3.1, 1.5, -1.1, 0]\n"
                              "  qd: [0, 0, 0, 0.1, 0, 0, 0, 0, 0, 0, 0, 0]\n")
    p = tmp_path / "guess.yaml"
    p.write_text(guess)
    code, out, err = run_cli("assemble", p)
    assert code == 0, err
    block = out[out.index("initial:\n"):]
    pasted = guess.replace(guess[guess.index("initial:\n"):guess.index("forces:")], block)
    q = tmp_path / "pasted.yaml"
    q.write_text(pasted)
    code, _, err = run_cli("check", q)
    assert code == 0, err
    a = ukdyn.load_scenario(p, check_initial=False).assemble()
    assert a["success"]
    loaded = ukdyn.load_scenario(q)
    assert np.array_equal(loaded.q0, a["q"]) and np.array_equal(loaded.qd0, a["qd"])
    assert not np.array_equal(a["q"], ukdyn.load_scenario(p, check_initial=False).q0)


def test_gil_released_during_simulate():
    # While one thread simulates (5 runs of about 0.1 s each), the main thread spins in Python.
    # With the GIL held during the C++ run, the main thread could not run at all while the worker
    # simulates: its CPU time would be a small fraction of the worker's. Released, both threads
    # are runnable and the scheduler gives them like shares of the cores, however loaded the
    # machine is, so the two CPU times are alike. CPU times, not wall-clock pauses: a pause test
    # failed twice on a loaded machine (the main thread starved by other processes, not the GIL).
    # simulate() runs the integration on a thread of its own (the calling thread waits for it and
    # checks for Ctrl-C): the run's CPU time is the process's minus the main thread's.
    sc = ukdyn.load_scenario(scenario_path("paper.yaml"))
    runs, worker_cpu = [], []

    def work():
        runs.extend(sc.simulate() for _ in range(12))

    worker = threading.Thread(target=work)
    p0 = time.process_time()
    c0 = time.thread_time()
    worker.start()
    spins = 0
    while worker.is_alive():
        spins += 1
    main_cpu = time.thread_time() - c0
    worker.join()
    worker_cpu.append(time.process_time() - p0 - main_cpu)
    assert len(runs) == 12 and all(r.complete for r in runs)
    assert worker_cpu[0] > 0.2, worker_cpu
    assert main_cpu > 0.3 * worker_cpu[0], (main_cpu, worker_cpu[0], spins)


def test_installed_package_imports(tmp_path):
    # `cmake --install` puts the package under the prefix (lib/python3.X/site-packages/ukdyn); it
    # imports from there alone (not from the build tree) and runs.
    build, cmake = os.environ.get("UKDYN_BUILD_DIR"), os.environ.get("CMAKE_COMMAND")
    if not build or not cmake:
        pytest.skip("UKDYN_BUILD_DIR / CMAKE_COMMAND not set (run through ctest)")
    prefix = tmp_path / "prefix"
    p = subprocess.run([cmake, "--install", build, "--prefix", str(prefix)], capture_output=True,
                       text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    site = prefix / "lib" / ("python%d.%d" % sys.version_info[:2]) / "site-packages"
    assert (site / "ukdyn" / "__init__.pyi").is_file() and (site / "ukdyn" / "py.typed").is_file()
    code = ("import ukdyn, sys; sc = ukdyn.load_scenario(sys.argv[1]); "
            "r = sc.forward(0.0, sc.q0, sc.qd0); print(ukdyn.__file__, r.rank)")
    env = dict(os.environ, PYTHONPATH=str(site))
    p = subprocess.run([sys.executable, "-c", code, str(scenario_path("paper.yaml"))],
                       capture_output=True, text=True, env=env, cwd=tmp_path, timeout=60)
    assert p.returncode == 0, p.stderr
    where, rank = p.stdout.split()
    assert pathlib.Path(where).resolve().is_relative_to(site.resolve()) and rank == "12"


def test_cli_says_it_draws_figures_and_labels_platforms_in_metres(tmp_path):
    # Issue 13, item 4: with stderr not a terminal (captured here) the CLI says that it draws the
    # figures and when it is done; the paper's platform coordinates are drawn in metres, apart from
    # the joint angles (rad).
    if not pathlib.Path("/usr/bin/gnuplot").exists():
        pytest.skip("no gnuplot")
    text = scenario_path("paper.yaml").read_text()
    assert "  t_end: 4\n" in text
    p = tmp_path / "paper_short.yaml"
    p.write_text(text.replace("  t_end: 4\n", "  t_end: 0.2\n"))
    code, out, err = run_cli("simulate", p, "--out", tmp_path / "o")
    assert code == 0, err
    m = re.search(r"drawing (\d+) figures \(gnuplot\) \.\.\.\n", err)
    assert m, err
    assert re.search(r"drew %s figures in [0-9.]+ s\n" % m.group(1), err), err
    assert "\r" not in err  # whole lines, no progress bar
    gp = (tmp_path / "o" / "figures" / "figures.gp").read_text()

    def figure(name):
        a = gp.index('set output "%s"' % name)
        return gp[a:gp.index("unset output", a)]

    plat, angles = figure("platforms.png"), figure("angles_left.png")
    assert 'set ylabel "[m]"' in plat and 'title "dx1"' in plat and 'title "dy2"' in plat
    assert 'set ylabel "[rad]"' in angles and 'title "theta1"' in angles
    assert 'title "dx1"' not in angles and 'title "dy1"' not in angles


ARM_YAML = """ukdyn: 1
name: spatial_arm
gravity: 9.81
subsystems:
  - name: arm
    type: serial_chain
    coordinates: [a, b, c]
    joints:
      - {name: j1, type: revolute, link: l1, axis: [0, 0, 1], coordinate: a,
         mass: 2, com: [0.1, 0, 0.2], inertia: [0.02, 0.03, 0.01]}
      - {name: j2, type: revolute, link: l2, origin: {xyz: [0, 0, 0.4]}, axis: [0, 1, 0],
         coordinate: b, mass: 1.5, com: [0.3, 0, 0], inertia: [0.01, 0.04, 0.04]}
      - {name: j3, type: revolute, link: l3, origin: {xyz: [0.6, 0, 0]}, axis: [1, 0, 0],
         coordinate: c, mass: 0.7, com: [0.2, 0.05, 0], inertia: [0.003, 0.01, 0.01]}
initial: {q: [0.3, -0.7, 1.1], qd: [0.5, -1.2, 0.8]}
simulation: {t_end: 1, sample_dt: 0.1}
"""


def test_linearize_matches_differences_of_forward(tmp_path):
    # Exact derivatives (docs/derivatives.md) against central differences of forward(),
    # Richardson-extrapolated (error O(h^4)); F, G in state-space form.
    path = tmp_path / "arm.yaml"
    path.write_text(ARM_YAML)
    sc = ukdyn.load_scenario(path)
    q, qd, tau = np.array([0.3, -0.7, 1.1]), np.array([0.5, -1.2, 0.8]), np.array([0.2, -0.1, 0.05])
    lin = sc.linearize(0.0, q, qd, tau)
    assert lin.trusted, lin.message
    assert lin.kkt_agreement < 1e-12
    n = 3

    def qdd(x, v, u):
        return sc.forward(0.0, x, v, u).qdd

    def diff(k, j):
        def central(h):
            args_p, args_m = [q.copy(), qd.copy(), tau.copy()], [q.copy(), qd.copy(), tau.copy()]
            args_p[k][j] += h
            args_m[k][j] -= h
            return (qdd(*args_p) - qdd(*args_m)) / (2 * h)

        return (4 * central(5e-4) - central(1e-3)) / 3

    for k, exact in enumerate([lin.dqdd_dq, lin.dqdd_dqd, lin.dqdd_dtau]):
        for j in range(n):
            d = diff(k, j)
            assert np.abs(exact[:, j] - d).max() <= 1e-8 * (1 + np.abs(d).max()), (k, j)
    assert lin.F.shape == (6, 6) and lin.G.shape == (6, 3)
    assert np.array_equal(lin.F[3:, :3], lin.dqdd_dq)
    np.testing.assert_allclose(lin.dqdd_dtau, np.linalg.inv(sc.forward(0.0, q, qd, tau).M), rtol=1e-12)
    # Spring-dampers between points have exact tangents too (every shipped component has; a
    # component without them is refused by name: tests/test_linearize.cpp).
    springs = ukdyn.load_scenario(scenario_path("benchmarks/flyball_governor.yaml"))
    lin = springs.linearize(0.0, np.array(springs.q0), np.array(springs.qd0))
    assert lin.trusted and np.all(np.isfinite(lin.dqdd_dq))


def test_linearize_time_column_matches_differences_in_t(tmp_path):
    # d qdd/dt, d Qc/dt at fixed (q, qd, tau) (docs/derivatives.md, "Time"): the paper's cut-point
    # trajectory moves with t; Richardson central differences in t of forward() are the reference.
    sc = ukdyn.load_scenario(scenario_path("paper.yaml"))
    q, qd = np.array(sc.q0), np.array(sc.qd0)
    tau = np.zeros(len(q))
    t = 0.6
    lin = sc.linearize(t, q, qd, tau)
    assert lin.trusted and lin.time_message == "", lin.time_message

    def central(h):
        p, m = sc.forward(t + h, q, qd, tau), sc.forward(t - h, q, qd, tau)
        return (p.qdd - m.qdd) / (2 * h), (p.Qc - m.Qc) / (2 * h)

    (a, ac), (b, bc) = central(5e-4), central(1e-3)
    d, dc = (4 * a - b) / 3, (4 * ac - bc) / 3
    assert np.abs(d).max() > 1e-2
    assert np.abs(lin.dqdd_dt - d).max() <= 1e-7 * np.abs(d).max()
    assert np.abs(lin.dQc_dt - dc).max() <= 1e-7 * np.abs(dc).max()
    assert lin.dmu_dt.shape == (lin.rank,)
    # Nothing of the tree arm depends on t: exactly 0.
    path = tmp_path / "arm.yaml"
    path.write_text(ARM_YAML)
    arm = ukdyn.load_scenario(path)
    still = arm.linearize(0.3, np.array([0.3, -0.7, 1.1]), np.array([0.5, -1.2, 0.8]))
    assert np.array_equal(still.dqdd_dt, np.zeros(3)) and np.array_equal(still.dQc_dt, np.zeros(3))


class ForceOfTime:
    """Q_a = k sin(w t + p) q + c cos(w t + p) qd (elementwise), its exact derivatives as methods."""

    def __init__(self, n, time=True):
        self.k, self.c, self.w, self.p = np.linspace(2.0, 5.0, n), np.linspace(-1.5, 1.0, n), 3.0, 0.7
        if time:
            self.dQ_dt = lambda t, q, qd: self.w * (self.k * np.cos(self.w * t + self.p) * q
                                                    - self.c * np.sin(self.w * t + self.p) * qd)

    def __call__(self, t, q, qd):
        return self.k * np.sin(self.w * t + self.p) * q + self.c * np.cos(self.w * t + self.p) * qd

    def dQ_dq(self, t, q, qd):
        return np.diag(self.k * np.sin(self.w * t + self.p))

    def dQ_dqd(self, t, q, qd):
        return np.diag(self.c * np.cos(self.w * t + self.p))


def test_linearize_with_a_python_force_of_time():
    # A Python force with dQ_dq, dQ_dqd and dQ_dt (docs/python.md): the time column against
    # Richardson central differences in t of forward() with the same force, the state columns
    # against differences in q and qd; without dQ_dt the time column alone is refused (None,
    # time_message naming the force); without dQ_dq / dQ_dqd linearize() raises naming it.
    sc = ukdyn.load_scenario(scenario_path("five_bar_redundant.yaml"))  # 2 degrees of freedom
    q, qd = np.array(sc.q0), np.array(sc.qd0)  # on the constraints
    tau = np.zeros(sc.dof)
    t = 0.4
    f = ForceOfTime(sc.dof)
    lin = sc.linearize(t, q, qd, tau, forces=[f])
    assert lin.trusted and lin.time_message == "", lin.time_message

    def central(h, dt=0.0, dq=None, dqd=None):
        z = np.zeros(sc.dof)
        dq, dqd = (z if dq is None else dq), (z if dqd is None else dqd)
        p = sc.forward(t + dt * h, q + h * dq, qd + h * dqd, tau, forces=[f])
        m = sc.forward(t - dt * h, q - h * dq, qd - h * dqd, tau, forces=[f])
        return (p.qdd - m.qdd) / (2 * h), (p.Qc - m.Qc) / (2 * h)

    def richardson(**kw):
        (a, ac), (b, bc) = central(5e-4, **kw), central(1e-3, **kw)
        return (4 * a - b) / 3, (4 * ac - bc) / 3

    d, dc = richardson(dt=1.0)
    assert np.abs(lin.dqdd_dt - d).max() <= 1e-7 * np.abs(d).max()
    assert np.abs(lin.dQc_dt - dc).max() <= 1e-7 * np.abs(dc).max()
    assert np.abs(d).max() > 1e-2
    # Nothing else of the five-bar depends on t: d qdd/dt is the force's share alone.
    assert np.array_equal(sc.linearize(t, q, qd, tau).dqdd_dt, np.zeros(sc.dof))
    for j in range(sc.dof):
        e = np.eye(sc.dof)[j]
        dq_col, _ = richardson(dq=e)
        dqd_col, _ = richardson(dqd=e)
        assert np.abs(lin.dqdd_dq[:, j] - dq_col).max() <= 1e-6 * (1 + np.abs(dq_col).max())
        assert np.abs(lin.dqdd_dqd[:, j] - dqd_col).max() <= 1e-6 * (1 + np.abs(dqd_col).max())
    no_time = sc.linearize(t, q, qd, tau, forces=[ForceOfTime(sc.dof, time=False)])
    assert no_time.dqdd_dt is None and no_time.dQc_dt is None
    assert "no exact d/dt for applied force 'python_force_0'" in no_time.time_message
    np.testing.assert_allclose(no_time.dqdd_dq, lin.dqdd_dq, rtol=0, atol=1e-13)
    with pytest.raises(ukdyn.Error, match="no exact derivatives for applied force 'python_force_0'"):
        sc.linearize(t, q, qd, tau, forces=[lambda t, q, qd: np.zeros(len(q))])

    class BadShape(ForceOfTime):
        def dQ_dq(self, t, q, qd):
            return np.zeros(len(q))

    shape = rf"dQ_dq at t = .*expected an array of shape \({sc.dof}, {sc.dof}\)"
    with pytest.raises(ukdyn.Error, match=shape):
        sc.linearize(t, q, qd, tau, forces=[BadShape(sc.dof)])


def test_linearize_minimal_and_discrete():
    # Minimal coordinates on the constraint manifold and the zero-order hold (docs/derivatives.md):
    # the five-bar (4 angles, 2 closure rows) held at rest by tau = G.
    sc = ukdyn.load_scenario(scenario_path("five_bar_redundant.yaml"))
    q, zero = np.array(sc.q0), np.zeros(sc.dof)
    tau = np.array(sc.forward(0.0, q, zero).G)
    plain = sc.linearize(0.0, q, zero, tau)
    assert plain.N is None and plain.Fd is None and plain.F_min is None
    lin = sc.linearize(0.0, q, zero, tau, minimal=True, dt=0.02)
    A = sc.forward(0.0, q, zero, tau).A
    assert lin.N.shape == (4, 2)
    assert np.abs(A @ lin.N).max() <= 1e-12
    assert np.abs(lin.N.T @ lin.N - np.eye(2)).max() <= 1e-12
    assert lin.at_rest and not lin.rheonomic and lin.minimal_note == ""
    P = np.zeros((4, 8))
    P[:2, :4], P[2:, 4:] = lin.N.T, lin.N.T
    np.testing.assert_allclose(lin.F_min, P @ lin.F @ lin.T, atol=1e-12)
    # An equilibrium: the tangent space is invariant, F T = T F_min.
    assert np.abs(lin.qdd).max() <= 1e-10
    np.testing.assert_allclose(lin.F @ lin.T, lin.T @ lin.F_min, atol=1e-9)
    # The discrete model: Fd = exp(F dt) (series), Gd = (∫ exp) G.
    def expm_series(X):
        E, term = np.eye(len(X)), np.eye(len(X))
        for k in range(1, 40):
            term = term @ X / k
            E = E + term
        return E

    np.testing.assert_allclose(lin.Fd, expm_series(lin.F * 0.02), atol=1e-12)
    np.testing.assert_allclose(lin.Fd_min, expm_series(lin.F_min * 0.02), atol=1e-12)
    aug = np.zeros((8, 8))
    aug[:4, :4], aug[:4, 4:] = lin.F_min * 0.02, lin.G_min * 0.02
    np.testing.assert_allclose(lin.Gd_min, expm_series(aug)[:4, 4:], atol=1e-12)
    with pytest.raises(ValueError):
        sc.linearize(0.0, q, zero, tau, dt=-1.0)


def moving_state(sc):
    """q0 with a velocity along the constraints (the null space of A) and a non-zero tau."""
    n = sc.dof
    q, tau = np.array(sc.q0), 0.3 * np.sin(1.7 * np.arange(n) + 0.4)
    A = sc.forward(0.0, q, np.zeros(n), tau).A
    _, s, vt = np.linalg.svd(A)
    rank = int((s > 1e-9 * s[0]).sum())
    qd = np.array(sc.qd0) + vt[rank:].T @ (0.3 * np.cos(1.3 * np.arange(rank, n)))
    return q, qd, tau


def test_linearize_structured_matches_the_dense_derivatives():
    # The structured dqdd/d(q, qd) (docs/derivatives.md, "Cost") against the dense one of
    # linearize() (its own KKT solve: X in full, no blocks), <= 1e-12 relative: its blocks put
    # together here in numpy (own on cols minus Q XL), dense() and dqdd_dx_times(V).
    for name, structured in [("n_robots_4_weld.yaml", True), ("two_ur5e_load.yaml", False)]:
        sc = ukdyn.load_scenario(scenario_path(name))
        n = sc.dof
        q, qd, tau = moving_state(sc)
        lin = sc.linearize(0.0, q, qd, tau)
        st = sc.linearize_structured(0.0, q, qd, tau)
        assert st.structured == structured and st.trusted, (name, st.message)
        dense = np.hstack([lin.dqdd_dq, lin.dqdd_dqd])
        scale = np.abs(dense).max()
        assert scale > 0.0
        np.testing.assert_allclose(st.qdd, lin.qdd, rtol=0, atol=1e-12 * (1 + np.abs(lin.qdd).max()))
        dq, dqd = st.dense()
        assert np.abs(np.hstack([dq, dqd]) - dense).max() <= 1e-12 * scale, name
        V = np.cos(np.outer(np.arange(2 * n), [0.3, 1.1, 2.3]))
        assert np.abs(st.dqdd_dx_times(V) - dense @ V).max() <= 1e-12 * scale * 2 * n, name
        assert np.abs(st.dqdd_dx_times(V[:, 0]) - dense @ V[:, 0]).max() <= 1e-12 * scale * 2 * n
        with pytest.raises(ValueError, match="dqdd_dx_times"):
            st.dqdd_dx_times(np.zeros(n))
        if not structured:
            assert st.XL is None and st.blocks == []
            continue
        L0, nL = st.load_start, st.load_size
        assert st.XL.shape == (nL, 2 * n)
        X = np.zeros((n, 2 * n))
        X[L0:L0 + nL] = st.XL
        for b in st.blocks:
            rows = slice(b["start"], b["start"] + b["size"])
            assert b["own"].shape == (b["size"], len(b["cols"]))
            if b["Q"].size:
                X[rows] = -b["Q"] @ st.XL
            X[rows, b["cols"]] += b["own"]
        assert np.abs(X - dense).max() <= 1e-12 * scale
        # O(N) storage: every block's own part on its and the load's 2 (n_k + n_L) columns.
        assert all(len(b["cols"]) <= 2 * (b["size"] + nL) for b in st.blocks)


def test_cli_linearize_npz_matches_json(tmp_path):
    # `ukdyn linearize --out FILE.npz`: numpy reads the uncompressed archive ukdyn writes itself;
    # the arrays equal the JSON's numbers bit for bit.
    import json

    path = scenario_path("five_bar_redundant.yaml")
    code, out, err = run_cli("linearize", path, "--minimal", "--dt", "0.01")
    assert code == 0, err
    j = json.loads(out)
    npz = tmp_path / "lin.npz"
    code, _, err = run_cli("linearize", path, "--minimal", "--dt", "0.01", "--out", npz)
    assert code == 0, err
    with np.load(npz) as z:
        assert np.array_equal(z["F"], np.array(j["F"]))
        assert np.array_equal(z["Fd"], np.array(j["Fd"]))
        assert np.array_equal(z["q"], np.array(j["q"]))
        assert np.array_equal(z["dqdd_dq"], np.array(j["derivatives"]["dqdd_dq"]))
        assert np.array_equal(z["minimal_N"], np.array(j["minimal"]["N"]))
        assert np.array_equal(z["minimal_Fd"], np.array(j["minimal"]["Fd"]))
        assert z["t"].shape == () and float(z["trusted"]) == 1.0 and float(z["rank"]) == 2.0
        assert "coordinates" not in z.files
    code, _, err = run_cli("linearize", path, "--out", tmp_path / "lin.txt")
    assert code == 2 and "FILE.npz" in err


def test_linearize_minimal_away_from_rest():
    # Moving (the heavy top spinning): D = d(A_R qd)/dq from the constraints' tangents against
    # Richardson differences of A(q) qd, and x = T z keeps A_R dqd + D dq = 0.
    sc = ukdyn.load_scenario(scenario_path("heavy_top.yaml"))
    q, qd = np.array(sc.q0), np.array(sc.qd0)
    lin = sc.linearize(0.0, q, qd, minimal=True)
    assert not lin.at_rest and "frozen" in lin.minimal_note
    rows = [sc.constraint_row_names.index(r) for r in lin.kept_rows]
    n = sc.dof

    def a_qd(x):
        return sc.forward(0.0, x, qd).A[rows] @ qd

    def central(j, h):
        e = np.eye(n)[j]
        return (a_qd(q + h * e) - a_qd(q - h * e)) / (2 * h)

    D = np.column_stack([(4 * central(j, 5e-4) - central(j, 1e-3)) / 3 for j in range(n)])
    assert np.abs(lin.D - D).max() <= 1e-9 * (1 + np.abs(D).max())
    AR = sc.forward(0.0, q, qd).A[rows]
    assert np.abs(np.hstack([lin.D, AR]) @ lin.T).max() <= 1e-12 * (1 + np.abs(lin.D).max())


def test_lqr_example_closed_loop_matches_the_minimal_model():
    pytest.importorskip("scipy")
    sys.path.insert(0, str(SOURCE / "python" / "examples"))
    try:
        import lqr_minimal
    finally:
        sys.path.pop(0)
    predicted, identified, rel = lqr_minimal.closed_loop_check(verbose=False)
    assert np.all(predicted.real < 0)
    assert rel <= 1e-3, (predicted, identified)
