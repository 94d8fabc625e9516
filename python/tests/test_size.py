"""ukdyn.size (docs/sizing.md): a link held still by a servo row, where each candidate's margin is
1 - m g l / (n eta T_p) in closed form; the outputs with out=; a bad catalogue."""
import json
import pathlib

import pytest

import ukdyn
from conftest import SOURCE

# The held link, shared with tests/test_sizing.cpp.
LINK = (SOURCE / "tests" / "sizing" / "held_link.yaml").read_text()

CATALOGUE = """ukdyn_catalogue: 1
name: test
motors:
  - {name: A, mass: 0.1, torque_constant: 0.02, stall_torque: 0.2, peak_torque: 0.05}
  - {name: C, mass: 0.4, torque_constant: 0.05, stall_torque: 1.0, peak_torque: 0.3}
gearboxes:
  - {name: g10, mass: 0.05, ratio: 10, efficiency: 0.9}
  - {name: g50, mass: 0.1, ratio: 50, efficiency: 0.8}
"""

SIZING = """ukdyn_sizing: 1
name: held
catalogue: cat.yaml
scenario: link.yaml
actuators: [shoulder]
margin: 0.1
"""

HOLD = 2 * 9.81 * 0.4  # |u| = m g l holds the link horizontal


def write(tmp_path, catalogue=CATALOGUE):
    (tmp_path / "link.yaml").write_text(LINK)
    (tmp_path / "cat.yaml").write_text(catalogue)
    (tmp_path / "s.yaml").write_text(SIZING)
    return tmp_path / "s.yaml"


def test_choice_matches_closed_form(tmp_path):
    r = ukdyn.size(write(tmp_path), out=tmp_path / "out")
    assert r["all_found"] and r["converged"]
    a = r["actuators"][0]
    # by mass: A+g10 (0.15), A+g50 (0.2), C+g10 (0.45), C+g50 (0.5); only C+g50 keeps 10 %
    assert (a["choice"]["motor"], a["choice"]["gearbox"]) == ("C", "g50")
    assert a["binding"]["margin"] == pytest.approx(1 - HOLD / (50 * 0.8) / 0.3, abs=1e-6)
    assert a["next_smaller"]["gearbox"] == "g10"
    assert a["next_smaller"]["fails_at"]["margin"] == pytest.approx(1 - HOLD / (10 * 0.9) / 0.3,
                                                                    abs=1e-6)
    on_disk = json.loads((tmp_path / "out" / "sizing.json").read_text())
    assert on_disk["actuators"][0]["choice"] == a["choice"]
    assert (tmp_path / "out" / "candidates.csv").read_text().startswith("actuator,candidate,")


def test_bad_catalogue_names_file_line_key(tmp_path):
    with pytest.raises(ukdyn.ScenarioError, match=r"cat.yaml:7:36: key 'gearboxes\[0\].ratio'"):
        ukdyn.size(write(tmp_path, CATALOGUE.replace("ratio: 10", "ratio: -1")))
