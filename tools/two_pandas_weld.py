#!/usr/bin/env python3
"""Writes the two-Panda weld benchmark pair: one system, twice.

  scenarios/two_pandas_weld.yaml   the ukdyn scenario (the form of scenarios/four_panda_plate.yaml:
                                   robots/panda.urdf on x, y, yaw platforms, the load a free body,
                                   each flange welded to it by a `weld` frame constraint)
  bench/two_pandas_weld.xml        the same system in MJCF for MuJoCo 2.2.2: robots/panda.xml's
                                   body tree copied twice (names prefixed), each on a body with
                                   slide x, slide y, hinge z; the load on a free joint; one
                                   <equality><weld> per flange; contacts disabled

The two Pandas are panda_0 and panda_2 of four_panda_plate.yaml (mounted 1 m either side of the
plate, facing it, at the same joint angles), the platforms (40 kg, inertia 2.0, 2.5, 3.0) and the
plate (5 kg, 0.8 m square: 0.27, 0.27, 0.53) are that scenario's. The weld offsets are the flange
poses at the initial joint angles from the published DH table (tools/check_robot_fk.py), so the
initial state satisfies the welds exactly in both files: the YAML's `b: {frame: load.load, xyz,
rpy}` and the MJCF's `relpose` (the load's pose in the flange frame; MuJoCo would otherwise take
the relative pose at qpos0, where the arms stand straight up). The initial state is the YAML's
`initial.q` and the MJCF's keyframe `grasp` (the same vector: MuJoCo's qpos order is the
scenario's coordinate order).

Usage: tools/two_pandas_weld.py [REPO_DIR]    (default: this repository)
"""
import copy
import math
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import check_robot_fk as fk  # noqa: E402
import robot_scenarios as rs  # noqa: E402

PQ = [0.0, 0.3, 0.0, -1.8, 0.0, 2.1, math.pi / 4]  # four_panda_plate.yaml's arm angles
MOUNTS = [("panda_0", (1.0, 0.0, 0.3), math.pi), ("panda_1", (-1.0, 0.0, 0.3), 0.0)]
LOAD_MASS, LOAD_INERTIA = 5.0, (0.27, 0.27, 0.53)
PLATFORM = {"mass": 40.0, "inertia": (2.0, 2.5, 3.0)}


def quat_of(R):
    """Unit quaternion (w, x, y, z) of a rotation matrix (w >= 0)."""
    w = math.sqrt(max(0.0, 1.0 + R[0, 0] + R[1, 1] + R[2, 2])) / 2
    x = math.sqrt(max(0.0, 1.0 + R[0, 0] - R[1, 1] - R[2, 2])) / 2
    y = math.sqrt(max(0.0, 1.0 - R[0, 0] + R[1, 1] - R[2, 2])) / 2
    z = math.sqrt(max(0.0, 1.0 - R[0, 0] - R[1, 1] + R[2, 2])) / 2
    x = math.copysign(x, R[2, 1] - R[1, 2])
    y = math.copysign(y, R[0, 2] - R[2, 0])
    z = math.copysign(z, R[1, 0] - R[0, 1])
    q = np.array([w, x, y, z])
    return q / np.linalg.norm(q)


def num(v):
    return " ".join(repr(float(x)) for x in v)


def prefixed_arm(panda_xml, prefix):
    """robots/panda.xml's base_link body (the whole arm) with every name prefixed."""
    root = ET.parse(panda_xml).getroot()
    base = copy.deepcopy(root.find("worldbody/body[@name='base_link']"))
    for el in base.iter():
        if "name" in el.attrib:
            el.set("name", prefix + el.get("name"))
    return base


def mjcf(repo, flanges, centre, q0):
    panda_xml = repo / "robots" / "panda.xml"
    src = ET.parse(panda_xml).getroot()
    m = ET.Element("mujoco", model="two_pandas_weld")
    m.append(copy.deepcopy(src.find("compiler")))
    opt = ET.SubElement(m, "option", gravity="0 0 -9.81", timestep="0.001")
    ET.SubElement(opt, "flag", contact="disable")
    m.append(copy.deepcopy(src.find("default")))
    world = ET.SubElement(m, "worldbody")
    for (name, xyz, yaw) in MOUNTS:
        p = ET.SubElement(world, "body", name=name + "_platform", pos=num(xyz),
                          euler="0 0 %r" % float(yaw))
        ET.SubElement(p, "joint", name=name + "_x", type="slide", axis="1 0 0")
        ET.SubElement(p, "joint", name=name + "_y", type="slide", axis="0 1 0")
        ET.SubElement(p, "joint", name=name + "_yaw", type="hinge", axis="0 0 1")
        ET.SubElement(p, "inertial", pos="0 0 0", mass="%g" % PLATFORM["mass"],
                      diaginertia=num(PLATFORM["inertia"]))
        ET.SubElement(p, "geom", name=name + "_platform_geom", type="box", size="0.3 0.25 0.05",
                      pos="0 0 -0.05")
        p.append(prefixed_arm(panda_xml, name + "_"))
    load = ET.SubElement(world, "body", name="load", pos=num(centre))
    ET.SubElement(load, "freejoint", name="load_free")
    ET.SubElement(load, "inertial", pos="0 0 0", mass="%g" % LOAD_MASS, diaginertia=num(LOAD_INERTIA))
    ET.SubElement(load, "geom", name="load_geom", type="box", size="0.4 0.4 0.01")
    eq = ET.SubElement(m, "equality")
    for (name, _, _), (R, p) in zip(MOUNTS, flanges):
        # relpose: the load's pose in the flange frame (MuJoCo 2.2.2: pos, then quat w x y z)
        rel_p = R.T @ (np.asarray(centre) - p)
        rel_q = quat_of(R.T)
        ET.SubElement(eq, "weld", name="grasp_" + name, body1=name + "_flange", body2="load",
                      relpose=num(list(rel_p) + list(rel_q)))
    kf = ET.SubElement(m, "keyframe")
    ET.SubElement(kf, "key", name="grasp", qpos=num(q0))
    ET.indent(m, space="  ")
    head = (
        "<!-- Generated by tools/two_pandas_weld.py (do not edit by hand). Two Franka Pandas on\n"
        "     mobile platforms (slide x, slide y, hinge z about the platform's z) welded to one\n"
        "     free-body plate: the MJCF twin of scenarios/two_pandas_weld.yaml (bench/bench_tree.cpp,\n"
        "     mujoco/two_pandas_weld_mj_forward). Each arm is robots/panda.xml's body tree (sources:\n"
        "     robots/README.md), copied with its names prefixed. The platforms (40 kg, 2.0 2.5 3.0)\n"
        "     and the plate (5 kg, 0.27 0.27 0.53) are those of scenarios/four_panda_plate.yaml.\n"
        "     relpose = the load's pose in the flange frame at keyframe 'grasp' (the scenario's\n"
        "     initial.q), so the welds hold there; qpos0 (arms upright) does NOT satisfy them.\n"
        "     Contacts are disabled and every geom has contype = conaffinity = 0. -->\n")
    return head + ET.tostring(m, encoding="unicode") + "\n"


def main():
    repo = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent.parent
    flanges = [rs.flange(fk.PANDA, PQ, np.array(xyz), yaw) for _, xyz, yaw in MOUNTS]
    centre = sum(p for _, p in flanges) / len(flanges)
    yaml = rs.scenario("two_pandas_weld", "two Franka Pandas on mobile platforms carry a plate",
                       "panda", fk.PANDA, PQ, MOUNTS, LOAD_MASS, LOAD_INERTIA, PLATFORM)
    yaml = yaml.replace("tools/robot_scenarios.py", "tools/two_pandas_weld.py", 1)
    yaml = yaml.replace(
        "\n# The arm is",
        "\n# The MJCF twin (MuJoCo side by side, bench/bench_tree.cpp) is bench/two_pandas_weld.xml."
        "\n# The arm is", 1)
    (repo / "scenarios" / "two_pandas_weld.yaml").write_text(yaml)
    q0 = []
    for _ in MOUNTS:
        q0 += [0.0, 0.0, 0.0] + PQ
    q0 += list(centre) + [1.0, 0.0, 0.0, 0.0]
    (repo / "bench" / "two_pandas_weld.xml").write_text(mjcf(repo, flanges, centre, q0))


if __name__ == "__main__":
    main()
