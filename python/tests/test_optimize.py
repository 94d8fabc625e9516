"""ukdyn.optimize (docs/optimization.md): the rest-to-rest closed form on a rail, the run folder,
bad problem files."""
import json
import os
import pathlib

import numpy as np
import pytest

import ukdyn

SOURCE = pathlib.Path(os.environ.get("UKDYN_SOURCE_DIR", pathlib.Path(__file__).parents[2]))

RAIL = """ukdyn: 1
name: rail
gravity: 0
subsystems:
  - name: slider
    type: definitions
    coordinates: [x, y]
    parameters: {m: 2}
    bodies:
      - {name: mass, mass: m, com: [x, y, 0]}
constraints:
  - {type: expression, name: rail, rows: {r: 0.5*x - 0.8660254037844386*y}}
initial:
  q: [0, 0]
  qd: [0, 0]
simulation:
  t_end: 1
  sample_dt: 0.01
"""

PROBLEM = """ukdyn: 1
name: rail_move
scenario: rail.yaml
intervals: 10
duration: 2
end:
  q: [1.299038105676658, 0.75]
  qd: zeros
costs:
  effort: 1
"""

needs_ipopt = pytest.mark.skipif(not ukdyn.ipopt_available(), reason="built without IPOPT")


@needs_ipopt
def test_rail_closed_form_and_run_folder(tmp_path):
    # Rest to rest a distance D = 1.5 along the rail in T = 2: the cubic, cost 12 m^2 D^2 / T^3.
    (tmp_path / "rail.yaml").write_text(RAIL)
    (tmp_path / "p.yaml").write_text(PROBLEM)
    r = ukdyn.optimize(tmp_path / "p.yaml", out=tmp_path / "out")
    assert r.converged and r.trusted, r.message
    exact = 12 * 2**2 * 1.5**2 / 2**3
    assert abs(r.cost - exact) / exact < 1e-6
    assert r.q.shape == (21, 2) and r.u.shape == (21, 2) and r.mu.shape == (21, 1)
    assert r.rows == ["rail_r"] and r.actuators == ["x", "y"]
    # The force along the rail is m s'' (the cubic's), the normal part is the rail's.
    along = np.array([np.cos(np.pi / 6), np.sin(np.pi / 6)])
    s_dd = 6 * 1.5 / 4 * (1 - 2 * r.t / 2)
    assert np.max(np.abs(r.u @ along - 2 * s_dd)) < 1e-6
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["trusted"] and summary["ipopt"]["converged"]
    assert r.replay_max_q_deviation is not None and r.replay_max_q_deviation < 1e-6
    header = (tmp_path / "out" / "trajectory.csv").read_text().splitlines()[0]
    assert header.startswith("t,knot,x,y,x_dot,y_dot") and "mu_rail_r" in header


@needs_ipopt
def test_waypoint_and_replay_scenarios(tmp_path):
    # The shipped waypoint problem: the left cut point at (0.8, 0.5, 1.0) at t = 0.5 s (a knot).
    r = ukdyn.optimize(SOURCE / "scenarios" / "optimize" / "paper_lift_waypoint.yaml",
                       out=tmp_path / "out")
    assert r.converged and r.trusted, r.message
    assert r.max_waypoint_residual < 1e-9
    i = int(np.argmin(np.abs(r.t - 0.5)))
    q = r.q[i]
    reach = 0.7 * np.cos(q[3]) + 0.8 * np.cos(q[4]) + 0.4 * np.cos(q[5])
    cut = [q[0] + np.cos(q[2]) * reach, q[1] + np.sin(q[2]) * reach,
           0.5 + 0.7 * np.sin(q[3]) + 0.8 * np.sin(q[4]) + 0.4 * np.sin(q[5])]
    assert np.max(np.abs(np.array(cut) - [0.8, 0.5, 1.0])) < 1e-9
    for name in ("replay.yaml", "replay_open_loop.yaml"):
        assert (tmp_path / "out" / name).is_file()


def test_bad_problem_names_the_key(tmp_path):
    (tmp_path / "rail.yaml").write_text(RAIL)
    (tmp_path / "p.yaml").write_text(PROBLEM.replace("intervals: 10", "intervals: 0"))
    with pytest.raises(ukdyn.ScenarioError, match="key 'intervals'"):
        ukdyn.optimize(tmp_path / "p.yaml")
