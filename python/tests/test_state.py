"""The quantities of one state and the fast path: forward(..., out=data), forward_qdd and batches
bit for bit the single call, no allocation per call (tracemalloc); T, V, E, Phi, Phi_dot, A, b
against closed forms, finite differences and `ukdyn eval`; the constrained inverse dynamics
against forward dynamics."""
import tracemalloc

import numpy as np
import pytest

import ukdyn
from conftest import cli_eval, max_rel_diff, scenario_path

FIVE_BAR = scenario_path("five_bar_redundant.yaml")
PAPER = scenario_path("paper.yaml")
EVAL_KEYS = ["M", "Cqd", "G", "Q", "A", "b", "Qc", "qdd"]


def states(sc, count, seed):
    rng = np.random.default_rng(seed)
    n = sc.dof
    for k in range(count):
        yield 0.1 * k, sc.q0 + 0.05 * rng.standard_normal(n), 0.3 * rng.standard_normal(n), \
            rng.standard_normal(n)


def pendulum(m=1.3, L=0.7, g=9.81):
    """A point mass on a rod in Cartesian coordinates (x, y), built in code."""
    d = ukdyn.SubsystemDef("pendulum", ["x", "y"])
    d.parameter("m", m)
    d.add_body("bob", mass="m", com=["x", "y", 0])
    d.gravity = [0, -g, 0]
    c = ukdyn.ConstraintDef("rod", "holonomic", ["x", "y"])
    c.parameter("L", L)
    c.add_row("length", "x^2 + y^2 - L^2")
    s = ukdyn.System()
    s.add_subsystem(ukdyn.make_subsystem(d))
    s.add_constraint(ukdyn.make_constraint(c))
    return ukdyn.Scenario.from_system(s, q0=[L, 0.0])


# ---------------------------------------------------------------------------- fast path


@pytest.mark.parametrize("path", [FIVE_BAR, PAPER])
def test_forward_into_data_equals_the_allocating_forward_bit_for_bit(path):
    sc = ukdyn.load_scenario(path)
    d = sc.make_data()
    views = [d.M, d.qdd, d.Qc, d.A]
    for t, q, qd, tau in states(sc, 4, seed=1):
        r = sc.forward(t, q, qd, tau)
        assert sc.forward(q, qd, t=t, tau=tau, out=d) is d
        for key in EVAL_KEYS:
            np.testing.assert_array_equal(getattr(d, key), getattr(r, key), err_msg=key)
        assert d.rank == r.rank and d.residual == r.residual and d.t == t
    # the arrays are views of the same buffers, refreshed in place
    assert all(v is w for v, w in zip(views, [d.M, d.qdd, d.Qc, d.A]))
    other = ukdyn.load_scenario(path)
    with pytest.raises(ValueError, match="another scenario"):
        other.forward(sc.q0, sc.qd0, out=d)


def test_forward_qdd_and_batches_are_bit_for_bit_k_single_calls():
    sc = ukdyn.load_scenario(FIVE_BAR)
    rows = list(states(sc, 7, seed=2))
    t = np.array([r[0] for r in rows])
    q = np.array([r[1] for r in rows])
    qd = np.array([r[2] for r in rows])
    tau = np.array([r[3] for r in rows])
    single = [sc.forward(ti, qi, qdi, taui) for ti, qi, qdi, taui in rows]
    want_qdd = np.array([r.qdd for r in single])
    want_Qc = np.array([r.Qc for r in single])
    np.testing.assert_array_equal(sc.forward_qdd(q, qd, t=t, tau=tau), want_qdd)
    out = np.empty_like(q)
    d = sc.make_data()
    assert sc.forward_qdd(q, qd, t=t, tau=tau, out=out, data=d) is out
    np.testing.assert_array_equal(out, want_qdd)
    b = sc.forward_batch(q, qd, t=t, tau=tau)
    np.testing.assert_array_equal(b["qdd"], want_qdd)
    np.testing.assert_array_equal(b["Qc"], want_Qc)
    assert list(b["rank"]) == [r.rank for r in single]
    assert list(b["residual"]) == [r.residual for r in single]
    one = np.empty(sc.dof)
    sc.forward_qdd(q[3], qd[3], t=t[3], tau=tau[3], out=one)
    np.testing.assert_array_equal(one, want_qdd[3])
    # one tau for every row, and a scalar t
    b0 = sc.forward_batch(q, qd, t=0.2, tau=tau[0])
    np.testing.assert_array_equal(b0["qdd"][5], sc.forward(0.2, q[5], qd[5], tau[0]).qdd)
    with pytest.raises(ValueError, match="out: expected a writeable C-contiguous float64"):
        sc.forward_qdd(q, qd, out=np.empty((7, 4), dtype=np.float32))
    with pytest.raises(ValueError, match="t: expected a number or one number per row"):
        sc.forward_qdd(q, qd, t=np.zeros(3))


def traced(calls):
    """(retained, peak above the start) bytes of Python allocations over calls(), after a warm-up."""
    calls(100)  # warm up (caches of pybind11 and numpy)
    tracemalloc.start()
    try:
        calls(10)
        before, _ = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        calls(10000)
        after, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return after - before, peak - before


def test_no_allocation_per_call():
    sc = ukdyn.load_scenario(PAPER)
    d = sc.make_data()
    q, qd, tau = sc.q0.copy(), sc.qd0.copy(), np.zeros(sc.dof)
    out = np.empty(sc.dof)

    def noop(k):  # the loop alone: the baseline of the peak
        for _ in range(k):
            pass

    def positional(k):
        for _ in range(k):
            sc.forward(q, qd, d, 0.1, tau)
            sc.forward_qdd(q, qd, 0.1, tau, out, d)

    def keywords(k):
        for _ in range(k):
            sc.forward(q, qd, t=0.1, tau=tau, out=d)
            sc.forward_qdd(q, qd, t=0.1, out=out, data=d)

    _, base_peak = traced(noop)
    # 2 x 10^4 calls: nothing kept (under 0.05 byte per call), and, positionally, no temporary
    # numpy array or dict made and freed per call (a 0-d numpy array alone is over 100 bytes, an
    # empty dict 64; measured: 16 bytes over the loop's own peak)
    kept, peak = traced(positional)
    assert kept < 1024 and peak <= base_peak + 64, (kept, peak, base_peak)
    # with keywords: only the dict Python builds for the keywords of a call (freed at once;
    # measured: 157 bytes over the loop's peak)
    kept, peak = traced(keywords)
    assert kept < 1024 and peak <= base_peak + 400, (kept, peak, base_peak)


# ---------------------------------------------------------------------------- quantities


def test_energies_and_constraints_of_a_pendulum_in_closed_form():
    m, L, g = 1.3, 0.7, 9.81
    sc = pendulum(m, L, g)
    q = np.array([0.3, -0.5])
    qd = np.array([0.7, -1.1])
    e = sc.energies(q, qd, t=0.0)
    assert e["T"] == pytest.approx(0.5 * m * (qd @ qd), rel=1e-15)
    assert e["V"] == pytest.approx(m * g * q[1], rel=1e-15)
    assert e["E"] == e["T"] + e["V"]
    c = sc.constraints(q, qd)
    assert c["phi"][0] == pytest.approx(q @ q - L**2, rel=1e-15)
    assert c["phid"][0] == pytest.approx(2 * q @ qd, rel=1e-15)
    np.testing.assert_allclose(c["A"], [2 * q], rtol=1e-15)
    assert c["b"][0] == pytest.approx(-2 * qd @ qd, rel=1e-15)
    assert c["rank"] == 1 and c["rank_uk"] == 1 and c["free_dof"] == 1 and c["rows"] == ["length"]


def central(f, x, h):
    return (f(x + h) - f(x - h)) / (2 * h)


@pytest.mark.parametrize("path", [FIVE_BAR, PAPER])
def test_constraints_against_finite_differences(path):
    # A = dPhi/dq, Phi_dot = A qd + dPhi/dt, and b = -d/de Phi_dot(q + e qd, qd, t + e) (at qdd = 0:
    # A qdd - b = d^2 Phi / dt^2 along the motion), by central differences (h = 1e-6).
    sc = ukdyn.load_scenario(path)
    for t, q, qd, _ in states(sc, 3, seed=5):
        c = sc.constraints(q, qd, t=t)
        h = 1e-6
        A_fd = np.column_stack([
            central(lambda s, j=j: sc.constraints(q + s * np.eye(sc.dof)[j], qd, t=t)["phi"], 0.0, h)
            for j in range(sc.dof)])
        phi_t = central(lambda s: sc.constraints(q, qd, t=t + s)["phi"], 0.0, h)
        b_fd = -central(lambda s: sc.constraints(q + s * qd, qd, t=t + s)["phid"], 0.0, h)
        scale = 1.0 + np.max(np.abs(c["A"]))
        assert np.max(np.abs(c["A"] - A_fd)) <= 1e-7 * scale
        assert np.max(np.abs(c["phid"] - (c["A"] @ qd + phi_t))) <= 1e-7 * scale
        assert np.max(np.abs(c["b"] - b_fd)) <= 1e-7 * (1.0 + np.max(np.abs(c["b"])))


@pytest.mark.parametrize("path", [FIVE_BAR, PAPER])
def test_constraints_against_ukdyn_eval(path):
    sc = ukdyn.load_scenario(path)
    rows = list(states(sc, 3, seed=9))
    answers = cli_eval(path, [{"t": t, "q": q.tolist(), "qd": qd.tolist()} for t, q, qd, _ in rows])
    for (t, q, qd, _), ref in zip(rows, answers):
        c = sc.constraints(q, qd, t=t)
        assert max_rel_diff(c["A"], np.array(ref["A"]).reshape(c["A"].shape)) <= 1e-14
        assert max_rel_diff(c["b"], np.array(ref["b"])) <= 1e-14
        assert c["rank_uk"] == ref["rank"]


def test_energies_equal_the_runs_T_V_E_columns():
    sc = ukdyn.load_scenario(FIVE_BAR)
    run = sc.simulate(t_end=0.3)
    names = sc.coordinate_names
    for i in (0, 7, len(run) - 1):
        q = np.array([run[c][i] for c in names])
        qd = np.array([run[c + "_dot"][i] for c in names])
        e = sc.energies(q, qd, t=run["t"][i])
        for key in ("T", "V", "E"):
            assert e[key] == pytest.approx(run[key][i], rel=1e-14, abs=1e-14)


def test_points_of_the_five_bar_in_closed_form():
    # The centres of mass of the definitions bodies (docs: the file's com expressions): the
    # proximal links at (-+d + l1/2 cos, 0, l1/2 sin), the distal ones from the elbows.
    sc = ukdyn.load_scenario(FIVE_BAR)
    d, l1, l2 = 0.25, 0.3, 0.4
    a1, a2, b1, b2 = q = np.array([1.1, 0.7, 2.0, 2.5])
    p = sc.points(q)
    want = {
        "left_arm.proximal": [-d + l1 / 2 * np.cos(a1), 0, l1 / 2 * np.sin(a1)],
        "left_arm.distal": [-d + l1 * np.cos(a1) + l2 / 2 * np.cos(a2), 0,
                            l1 * np.sin(a1) + l2 / 2 * np.sin(a2)],
        "right_arm.proximal": [d + l1 / 2 * np.cos(b1), 0, l1 / 2 * np.sin(b1)],
        "right_arm.distal": [d + l1 * np.cos(b1) + l2 / 2 * np.cos(b2), 0,
                             l1 * np.sin(b1) + l2 / 2 * np.sin(b2)],
    }
    assert sorted(p) == sorted(want)
    for name, w in want.items():
        np.testing.assert_allclose(p[name], w, rtol=0, atol=1e-15, err_msg=name)
    with pytest.raises(ValueError, match=r"q\[0\]: not finite"):
        sc.points([np.nan, 0, 0, 0])


# ---------------------------------------------------------------------------- inverse dynamics


def null_space(A):
    if A.shape[0] == 0:
        return np.eye(A.shape[1])
    _, s, vt = np.linalg.svd(A)
    rank = int(np.sum(s > 1e-10 * s[0]))
    return vt[rank:].T


@pytest.mark.parametrize("path", [FIVE_BAR, scenario_path("paper_free.yaml"), PAPER])
def test_inverse_then_forward_returns_qdd(path):
    sc = ukdyn.load_scenario(path)
    rng = np.random.default_rng(11)
    for t, q, qd, tau in states(sc, 3, seed=13):
        r = sc.forward(t, q, qd, tau)
        N = null_space(r.A)
        qdd = r.qdd + N @ rng.standard_normal(N.shape[1])  # on the manifold: A qdd = b
        inv = sc.inverse_dynamics(q, qd, qdd, t=t)
        back = sc.forward(t, q, qd, inv["tau"])
        assert np.max(np.abs(back.qdd - qdd)) <= 1e-12 * (1.0 + np.max(np.abs(qdd)))
        # M qdd = tau + Q(0) + Qc, Qc = A^T lambda, and tau has no component along the rows of A
        Q0 = sc.forward(t, q, qd).Q
        scale = 1.0 + np.max(np.abs(r.M @ qdd))
        assert np.max(np.abs(r.M @ qdd - (inv["tau"] + Q0 + inv["Qc"]))) <= 1e-12 * scale
        assert np.max(np.abs(r.A.T @ inv["lambda"] - inv["Qc"])) <= 1e-10 * scale
        assert np.max(np.abs(r.A @ inv["tau"])) <= 1e-10 * scale
        # least norm: the tau that produced r.qdd realises it too, and is not shorter
        inv0 = sc.inverse_dynamics(q, qd, r.qdd, t=t)
        assert np.linalg.norm(inv0["tau"]) <= np.linalg.norm(tau) + 1e-12
    with pytest.raises(ValueError, match="not on the constraint manifold"):
        sc.inverse_dynamics(q, qd, qdd + r.A[0], t=t)  # A qdd - b = A A[0]^T, not 0


def test_inverse_dynamics_of_a_pendulum_in_closed_form():
    # M = m I, Q(0) = (0, -m g), A = 2 q^T: tau = P r with r = m qdd - Q(0) and P = I - q q^T/|q|^2
    # (the tangential part), Qc = (q q^T/|q|^2) r = A^T lambda with lambda = q.r / (2 |q|^2).
    m, L, g = 1.3, 0.7, 9.81
    sc = pendulum(m, L, g)
    th, w = 0.4, 1.7
    q = L * np.array([np.sin(th), -np.cos(th)])
    qd = L * w * np.array([np.cos(th), np.sin(th)])
    tangent = np.array([np.cos(th), np.sin(th)])
    qdd = -w**2 * q + 2.5 * tangent  # centripetal + any tangential: on the manifold
    inv = sc.inverse_dynamics(q, qd, qdd)
    r = m * qdd - np.array([0.0, -m * g])
    P = np.eye(2) - np.outer(q, q) / (q @ q)
    np.testing.assert_allclose(inv["tau"], P @ r, rtol=0, atol=1e-13)
    np.testing.assert_allclose(inv["Qc"], r - P @ r, rtol=0, atol=1e-13)
    assert inv["lambda"][0] == pytest.approx(q @ r / (2 * q @ q), rel=1e-13)
    assert "u" not in inv  # no actuators: no actuation


def test_inverse_dynamics_with_the_actuators_of_a_control_scenario():
    # paper_control.yaml: tau = B u (8 drives), servo rows and physical (closure) rows. For the qdd
    # that some u0 produces, the actuation of the control code gives a u with B u + A_p^T mu = r and
    # forward(B u) returns qdd (the KKT solution is unique, and qdd satisfies every row).
    sc = ukdyn.load_scenario(scenario_path("paper_control.yaml"))
    rng = np.random.default_rng(17)
    t, q, qd = 0.2, sc.q0, sc.qd0 + 0.0
    d0 = sc.forward(t, q, qd)
    B = np.zeros((sc.dof, len(sc.actuator_names)))
    for j, name in enumerate(sc.actuator_names):  # "one drive per coordinate" in that file
        B[sc.coordinate_names.index(name), j] = 1.0
    u0 = rng.standard_normal(B.shape[1])
    qdd = sc.forward(t, q, qd, B @ u0).qdd
    inv = sc.inverse_dynamics(q, qd, qdd, t=t)
    assert not inv["underactuated"] and inv["actuation_residual"] < 1e-10 * (1 + np.abs(inv["u"]).max())
    back = sc.forward(t, q, qd, B @ inv["u"]).qdd
    assert np.max(np.abs(back - qdd)) <= 1e-12 * (1.0 + np.max(np.abs(qdd)))
    assert d0.A.shape[0] == sc.rows


def test_data_views_outlive_the_data_and_the_scenario():
    sc = ukdyn.load_scenario(FIVE_BAR)
    d = sc.make_data()
    sc.forward(sc.q0, sc.qd0, d)
    qdd, M = d.qdd, d.M
    want = qdd.copy(), M.copy()
    del d, sc
    import gc
    gc.collect()
    np.testing.assert_array_equal(qdd, want[0])
    np.testing.assert_array_equal(M, want[1])


URDF = scenario_path("paper_urdf.yaml")


@pytest.mark.parametrize("path", [URDF, scenario_path("two_ur5e_load.yaml")])
def test_frames_against_finite_differences(path):
    # p, R of every link frame; Jp = dp/dq and Jw (column j = vee(dR/dq_j R^T)) against central
    # differences (h = 1e-6, <= 1e-7); v = Jp qd and omega = Jw qd; R a rotation.
    sc = ukdyn.load_scenario(path)
    assert sc.frame_names
    rng = np.random.default_rng(3)
    q = sc.q0 + 0.1 * rng.standard_normal(sc.dof)
    qd = rng.standard_normal(sc.dof)
    h = 1e-6

    def vee(S):
        return np.array([S[2, 1], S[0, 2], S[1, 0]])

    for name in sc.frame_names:
        f = sc.frame(name, q, qd)
        R = f["R"]
        assert np.max(np.abs(R @ R.T - np.eye(3))) < 1e-14 and np.linalg.det(R) > 0
        for j in range(sc.dof):
            e = np.zeros(sc.dof)
            e[j] = h
            fp, fm = sc.frame(name, q + e), sc.frame(name, q - e)
            dp = (fp["p"] - fm["p"]) / (2 * h)
            dR = (fp["R"] - fm["R"]) / (2 * h)
            assert np.max(np.abs(f["Jp"][:, j] - dp)) <= 1e-7 * (1 + np.max(np.abs(dp))), (name, j)
            assert np.max(np.abs(f["Jw"][:, j] - vee(dR @ R.T))) <= 1e-7, (name, j)
        np.testing.assert_allclose(f["v"], f["Jp"] @ qd, rtol=0, atol=1e-12)
        np.testing.assert_allclose(f["omega"], f["Jw"] @ qd, rtol=0, atol=1e-12)
    with pytest.raises(KeyError, match="no such frame"):
        sc.frame("nowhere.link", q)


def test_frame_origins_equal_the_replay_geometry():
    # A second formulation: the replay geometry places link frame origins by link_poses().
    sc = ukdyn.load_scenario(URDF)
    q = sc.q0 + 0.05
    pts = sc.points(q)
    common = [n for n in sc.frame_names if n in pts]
    assert len(common) >= 4, (sc.frame_names, list(pts))
    for name in common:
        np.testing.assert_allclose(sc.frame(name, q)["p"], pts[name], rtol=0, atol=1e-14)
