#!/usr/bin/env python3
"""A control law written in Python, in place of ukdyn's built-in one (docs/python.md, "Control laws
in Python"): the paper's trajectory on the exact-inertia plant (scenarios/paper_control.yaml), the
controller on the paper's model, starting 0.02 m and 0.05 rad off the trajectory.

The law below is ukdyn's `stabilized` law (docs/control.md) re-written with numpy: the model's U-K
force (paper Eq. (4)) for the servo rows with a corrected right-hand side b_s + v,
v = -2 w phid - w^2 phi (Udwadia's stabilised servo constraints), realised by the actuators as the
least-norm u with B u + A_p^T mu = Qc. Its run equals the built-in law's to round-off.

    PYTHONPATH=build/release/python /usr/bin/python3 python/examples/control_law.py [--t-end 2]
"""
import argparse
import pathlib
import tempfile

import numpy as np

import ukdyn

ROOT = pathlib.Path(__file__).resolve().parents[2]
SCENARIOS = ROOT / "scenarios"


class Stabilized:
    """u(t, q, qd, data) from the controller's model at the measured state (data: ukdyn.ControlData:
    M, Q, A, b, Qc, phi, phid of every row of the model, the servo-row mask, B)."""

    def __init__(self, omega):
        self.omega = omega
        self.calls = 0

    def control(self, t, q, qd, d):
        self.calls += 1
        s = d.servo
        b = d.b.copy()
        b[s] += -2 * self.omega * d.phid[s] - self.omega ** 2 * d.phi[s]
        L = np.linalg.cholesky(d.M)  # M = L L^T; Qc = L (A L^-T)^+ (b - A M^-1 Q)
        Qc = L @ (np.linalg.pinv(d.A @ np.linalg.inv(L).T, rcond=1e-10)
                  @ (b - d.A @ np.linalg.solve(d.M, d.Q)))
        Ap = d.A[~s]  # the physical rows: the plant's own constraints react
        P = np.eye(len(q)) - Ap.T @ np.linalg.pinv(Ap.T, rcond=1e-10)
        return np.linalg.pinv(P @ d.B, rcond=1e-10) @ (P @ Qc)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t-end", type=float, default=2.0, help="end of the run [s] (file: 4 s)")
    args = ap.parse_args()

    # paper_control.yaml with the stabilized law and a shorter horizon.
    text = (SCENARIOS / "paper_control.yaml").read_text()
    start, end = text.index("  law: robust"), text.index("  plant:")
    text = text[:start] + "  law: stabilized\n  omega: 5\n" + text[end:]
    text = text.replace("  t_end: 4\n", "  t_end: %r\n" % args.t_end)
    text = text.replace("plant: paper_generic_exact_inertia.yaml",
                        "plant: %s" % (SCENARIOS / "paper_generic_exact_inertia.yaml"))
    with tempfile.TemporaryDirectory() as tmp:
        path = pathlib.Path(tmp) / "paper_control_stabilized.yaml"
        path.write_text(text)
        sc = ukdyn.load_scenario(path)

    law = Stabilized(omega=5.0)
    mine = sc.simulate(control_law=law)          # the Python law
    builtin = sc.simulate()                      # the YAML law, for comparison
    print(f"{sc.name}: {mine.status}, {len(mine)} samples, {law.calls} calls of the Python law")
    e = np.abs(mine["e_traj_x"])
    print(f"  |e_traj_x|: {e[0]:.4f} m at t = 0 -> {e[-1]:.2e} m at t = {mine['t'][-1]:g} s")
    print(f"  max |u| = {mine.summary['control']['max_abs_u']:.3f} (actuators "
          f"{', '.join(sc.actuator_names[:3])}, ...)")
    # Every column of the Python law's run but act_residual (NaN for a Python law: ukdyn did not
    # solve for u; the built-in run also has servo_uncertainty, which needs the built-in law's own
    # correction); vectors (u, Qc, Qp, Qs, qdd) normwise: relative to their largest element.
    cols = [c for c in mine.columns if c != "act_residual"]

    def group(c):
        return next((p for p in ("u_", "Qc_", "Qp_", "Qs_") if c.startswith(p)),
                    "_ddot" if c.endswith("_ddot") else c)

    scale = {}
    for c in cols:
        scale[group(c)] = max(scale.get(group(c), 1.0), float(np.max(np.abs(builtin[c]))))
    diff = max(float(np.max(np.abs(mine[c] - builtin[c]))) / scale[group(c)] for c in cols)
    print(f"  against the built-in stabilized law: max difference {diff:.2e} (normwise, "
          f"{len(cols)} columns)")


if __name__ == "__main__":
    main()
