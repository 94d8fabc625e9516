#!/usr/bin/env python3
"""LQR in minimal coordinates for a closed chain: the redundantly actuated five-bar
(scenarios/five_bar_redundant.yaml: 4 joint angles, 2 closure rows, 2 degrees of freedom).

    PYTHONPATH=build/release/python /usr/bin/python3 python/examples/lqr_minimal.py

1. Holding torques tau0 = G(q0) make the initial pose an equilibrium (qdd = 0, Qc = 0).
2. Scenario.linearize(minimal=True) gives the model of z = (N^T dq, N^T dqd) on the constraint
   manifold, N an orthonormal basis of null(A) (docs/derivatives.md, "Minimal coordinates").
3. scipy.linalg.solve_continuous_are gives the LQR gain K of (F_min, G_min); the Python controller
   u = -K z(q, qd) runs closed loop through the nonlinear U-K dynamics (Scenario.simulate).
4. From two runs started with small velocity kicks along the manifold, the closed-loop matrix is
   identified by least squares over the samples (z_{k+1} = Phi z_k); its eigenvalues,
   log(mu)/dt, are compared with those of F_min - G_min K. The error is O(kick) (the nonlinear
   terms) plus the integrator's: it prints the worst relative difference.
"""
import pathlib
import sys

import numpy as np
import scipy.linalg

import ukdyn

ROOT = pathlib.Path(__file__).resolve().parents[2]


def closed_loop_check(kick=1e-5, t_end=2.0, dt=0.01, verbose=True):
    """Returns (predicted eigenvalues, identified eigenvalues, worst relative difference)."""
    sc = ukdyn.load_scenario(ROOT / "scenarios" / "five_bar_redundant.yaml")
    n = sc.dof
    q0 = np.array(sc.q0)
    zero = np.zeros(n)
    # Holding torques: at rest C qd = 0, so tau0 = G gives M qdd = 0 with Qc = 0.
    tau0 = np.array(sc.forward(0.0, q0, zero).G)
    lin = sc.linearize(0.0, q0, zero, tau0, minimal=True, dt=dt)
    assert lin.trusted, lin.message
    assert np.max(np.abs(lin.qdd)) < 1e-10, "not an equilibrium"
    N, F, G = lin.N, lin.F_min, lin.G_min
    k = N.shape[1]
    # LQR weights: unit on z, 0.1 on each joint torque.
    Qw, Rw = np.eye(2 * k), 0.1 * np.eye(n)
    P = scipy.linalg.solve_continuous_are(F, G, Qw, Rw)
    K = np.linalg.solve(Rw, G.T @ P)
    predicted = np.linalg.eigvals(F - G @ K)

    def z_of(q, qd):
        return np.concatenate([N.T @ (q - q0), N.T @ qd])

    def controller(t, q, qd):
        return -K @ z_of(np.asarray(q), np.asarray(qd))

    sc.tau = tau0
    sc.t_end = t_end
    sc.sample_dt = dt
    names = sc.coordinate_names
    X0, X1 = [], []
    for j in range(k):  # a kick along each direction of the manifold: A qd0 = 0 exactly
        sc.qd0 = kick * N[:, j]
        run = sc.simulate(controller=controller)
        assert run.status == "completed", run.message
        q = np.column_stack([run[c] for c in names])
        qd = np.column_stack([run[c + "_dot"] for c in names])
        Z = np.array([z_of(a, b) for a, b in zip(q, qd)])
        X0.append(Z[:-1])
        X1.append(Z[1:])
    X0, X1 = np.vstack(X0), np.vstack(X1)
    # z_{k+1}^T = z_k^T Phi^T: least squares, weighted to the size of each sample.
    w = 1.0 / np.linalg.norm(X0, axis=1)
    PhiT, *_ = np.linalg.lstsq(X0 * w[:, None], X1 * w[:, None], rcond=None)
    identified = np.log(np.linalg.eigvals(PhiT.T).astype(complex)) / dt

    def key(e):
        return (round(e.real, 6), abs(e.imag))

    predicted = np.array(sorted(predicted, key=key))
    identified = np.array(sorted(identified, key=key))
    # Pair each predicted eigenvalue with the nearest identified one.
    rel = max(np.min(np.abs(identified - p)) / abs(p) for p in predicted)
    if verbose:
        print(f"{sc.name}: n = {n}, rank {lin.rank}, minimal dimension 2k = {2 * k}")
        print("  predicted closed-loop eigenvalues (F_min - G_min K):")
        for p in predicted:
            print(f"    {p.real:+.6f} {p.imag:+.6f}j")
        print(f"  identified from the nonlinear runs (kick {kick:g} rad/s, dt {dt}):")
        for e in identified:
            print(f"    {e.real:+.6f} {e.imag:+.6f}j")
        print(f"  worst relative difference: {rel:.2e}")
    return predicted, identified, rel


if __name__ == "__main__":
    _, _, rel = closed_loop_check()
    sys.exit(0 if rel <= 1e-3 else 1)
