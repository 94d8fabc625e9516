#!/usr/bin/env python3
"""Checks robots/ur5e.{urdf,xml} and robots/panda.{urdf,xml} against the published tables they were
written from (robots/README.md), with numpy and xml.etree only (no MuJoCo, no urdfdom).

For each robot and each of a few joint vectors q it compares:
  - the flange (tool0 / flange) pose of the URDF and of the MJCF with the DH forward kinematics
    (standard DH for the UR5e, Craig's modified DH for the Panda);
  - every joint axis (direction and a point on it) of the URDF and of the MJCF with the DH one;
  - every moving link's mass, centre of mass and inertia tensor about the CoM, in world axes, of the
    URDF and of the MJCF with the published numbers placed by the DH frames;
  - the joint-space mass matrix M(q) and gravity torques G(q) (gravity 0 0 -9.81) computed from the
    URDF, from the MJCF and from the published tables.
It also checks that each published inertia tensor is physically valid (positive principal moments
satisfying the triangle inequality). Exits 1 on any difference above TOL.

Usage: tools/check_robot_fk.py [ROBOTS_DIR]    (default: the robots/ folder of this repository)
"""
import math
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

TOL = 1e-9
GRAVITY = np.array([0.0, 0.0, -9.81])
PI = math.pi

# --- The published tables (robots/README.md gives the sources) ---------------------------------

# UR5e: UR's DH article (standard DH: F_i = F_{i-1} Rz(q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)); masses
# and CoMs (in DH frame i) from the same article; inertia tensors about the CoM, axes parallel to
# DH frame i, from UR's ROS 2 description (config/ur5e/physical_parameters.yaml), as
# (ixx, ixy, ixz, iyy, iyz, izz).
UR5E = {
    "convention": "standard",
    "d": [0.1625, 0, 0, 0.1333, 0.0997, 0.0996],
    "a": [0, -0.425, -0.3922, 0, 0, 0],
    "alpha": [PI / 2, 0, 0, PI / 2, -PI / 2, 0],
    "mass": [3.761, 8.058, 2.846, 1.37, 1.3, 0.365],
    "com": [(0, -0.02561, 0.00193), (0.2125, 0, 0.11336), (0.15, 0.0, 0.0265),
            (0, -0.0018, 0.01634), (0, 0.0018, 0.01634), (0, 0, -0.001159)],
    "inertia": [
        (0.00700210, 0.00000073, -0.00001053, 0.00648091, 0.00049994, 0.00657286),
        (0.01505885, -0.00005400, 0.00000563, 0.33388086, -0.00000181, 0.33247207),
        (0.00399632, -0.00001365, 0.00137272, 0.07879254, -0.00000660, 0.07848510),
        (0.00165491, -0.00000282, -0.00000438, 0.00135962, 0.00010157, 0.00126279),
        (0.00135617, -0.00000274, 0.00000444, 0.00127827, -0.00005048, 0.00096614),
        (0.00018694, 0.00000006, -0.00000017, 0.00018908, -0.00000092, 0.00025756),
    ],
    "links": ["shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link", "wrist_2_link",
              "wrist_3_link"],
    "joints": ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
               "wrist_2_joint", "wrist_3_joint"],
    "flange": "tool0",
}

# Panda: Franka's DH table in Craig's (modified) convention, F_i = F_{i-1} Rx(alpha_i) Tx(a_i)
# Rz(q_i) Tz(d_i), flange F = F_7 Tz(0.107); dynamic parameters: Gaz et al., RA-L 2019,
# supplementary material Tables VIII (mass, CoM in link frame i) and IX (barycentric inertia,
# axes parallel to link frame i, (ixx, ixy, ixz, iyy, iyz, izz)). c1z is "don't care": 0.
PANDA = {
    "convention": "modified",
    "a": [0, 0, 0, 0.0825, -0.0825, 0, 0.088],
    "d": [0.333, 0, 0.316, 0, 0.384, 0, 0],
    "alpha": [0, -PI / 2, PI / 2, PI / 2, -PI / 2, PI / 2, PI / 2],
    "d_flange": 0.107,
    "mass": [4.970684, 0.646926, 3.228604, 3.587895, 1.225946, 1.666555, 7.35522e-01],
    "com": [(3.875e-03, 2.081e-03, 0.0), (-3.141e-03, -2.872e-02, 3.495e-03),
            (2.7518e-02, 3.9252e-02, -6.6502e-02), (-5.317e-02, 1.04419e-01, 2.7454e-02),
            (-1.1953e-02, 4.1065e-02, -3.8437e-02), (6.0149e-02, -1.4117e-02, -1.0517e-02),
            (1.0517e-02, -4.252e-03, 6.1597e-02)],
    "inertia": [
        (7.0337e-01, -1.3900e-04, 6.7720e-03, 7.0661e-01, 1.9169e-02, 9.1170e-03),
        (7.9620e-03, -3.9250e-03, 1.0254e-02, 2.8110e-02, 7.0400e-04, 2.5995e-02),
        (3.7242e-02, -4.7610e-03, -1.1396e-02, 3.6155e-02, -1.2805e-02, 1.0830e-02),
        (2.5853e-02, 7.7960e-03, -1.3320e-03, 1.9552e-02, 8.6410e-03, 2.8323e-02),
        (3.5549e-02, -2.1170e-03, -4.0370e-03, 2.9474e-02, 2.2900e-04, 8.6270e-03),
        (1.9640e-03, 1.0900e-04, -1.1580e-03, 4.3540e-03, 3.4100e-04, 5.4330e-03),
        (1.2516e-02, -4.2800e-04, -1.1960e-03, 1.0027e-02, -7.4100e-04, 4.8150e-03),
    ],
    "links": [f"panda_link{i}" for i in range(1, 8)],
    "joints": [f"panda_joint{i}" for i in range(1, 8)],
    "flange": "flange",
}

# --- Rotations and transforms --------------------------------------------------------------------


def rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def rot_rpy(r, p, y):
    """URDF's fixed-axis roll, pitch, yaw: R = Rz(y) Ry(p) Rx(r)."""
    return rot_z(y) @ rot_y(p) @ rot_x(r)


def rot_axis(axis, q):
    """Rotation by q about the unit vector axis (Rodrigues)."""
    k = np.asarray(axis, float)
    k = k / np.linalg.norm(k)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(q) * K + (1 - math.cos(q)) * (K @ K)


def rot_quat(w, x, y, z):
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def hom(R=None, p=(0.0, 0.0, 0.0)):
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    T[:3, 3] = p
    return T


def sym(t):
    xx, xy, xz, yy, yz, zz = t
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]], float)


# --- DH forward kinematics ----------------------------------------------------------------------


def dh_frames(table, q):
    """World frames of the DH table at q: (frames of links 1..n, joint frames (z = axis i, origin on
    axis i) for joints 1..n, flange frame)."""
    n = len(table["a"])
    T = np.eye(4)
    links, joints = [], []
    for i in range(n):
        a, d, al = table["a"][i], table["d"][i], table["alpha"][i]
        if table["convention"] == "standard":  # F_i = F_{i-1} Rz(q) Tz(d) Tx(a) Rx(alpha)
            joints.append(T.copy())  # axis i = z of F_{i-1}
            T = T @ hom(rot_z(q[i])) @ hom(p=(a, 0, d)) @ hom(rot_x(al))
        else:  # modified: F_i = F_{i-1} Rx(alpha) Tx(a) Rz(q) Tz(d)
            T = T @ hom(rot_x(al)) @ hom(p=(a, 0, 0)) @ hom(rot_z(q[i])) @ hom(p=(0, 0, d))
            joints.append(T.copy())  # axis i = z of F_i
        links.append(T.copy())
    flange = T @ hom(p=(0, 0, table.get("d_flange", 0.0)))
    return links, joints, flange


# --- Readers ---------------------------------------------------------------------------------------


def floats(s, n=None, default=None):
    if s is None:
        return default
    v = [float(x) for x in s.split()]
    if n is not None and len(v) != n:
        raise ValueError(f"expected {n} numbers, got '{s}'")
    return v


class Link:
    def __init__(self, name, parent, origin, joint=None, jtype="fixed", axis=(0, 0, 1),
                 anchor=(0, 0, 0), inertial=None):
        self.name, self.parent, self.origin = name, parent, origin  # origin: 4x4 in parent frame
        self.joint, self.jtype = joint, jtype
        self.axis, self.anchor = np.asarray(axis, float), np.asarray(anchor, float)
        self.inertial = inertial  # (mass, com (3), inertia 3x3 about the com) in the link frame


def read_urdf(path):
    root = ET.parse(path).getroot()
    links = {ln.get("name"): ln for ln in root.findall("link")}
    joints = root.findall("joint")
    child_of = {j.find("child").get("link"): j for j in joints}
    roots = [n for n in links if n not in child_of]
    if len(roots) != 1:
        raise ValueError(f"{path}: expected one root link, found {roots}")

    def inertial(el):
        ie = el.find("inertial")
        if ie is None:
            return None
        o = ie.find("origin")
        xyz = floats(o.get("xyz") if o is not None else None, 3, [0, 0, 0])
        rpy = floats(o.get("rpy") if o is not None else None, 3, [0, 0, 0])
        m = float(ie.find("mass").get("value"))
        i = ie.find("inertia")
        I = sym([float(i.get(k)) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")])
        R = rot_rpy(*rpy)
        return m, np.array(xyz), R @ I @ R.T

    out = [Link(roots[0], None, np.eye(4), inertial=inertial(links[roots[0]]))]
    stack = [roots[0]]
    while stack:
        parent = stack.pop()
        for j in joints:
            if j.find("parent").get("link") != parent:
                continue
            child = j.find("child").get("link")
            o = j.find("origin")
            xyz = floats(o.get("xyz") if o is not None else None, 3, [0, 0, 0])
            rpy = floats(o.get("rpy") if o is not None else None, 3, [0, 0, 0])
            ax = j.find("axis")
            axis = floats(ax.get("xyz") if ax is not None else None, 3, [1, 0, 0])
            jtype = j.get("type")
            if jtype not in ("revolute", "continuous", "fixed"):
                raise ValueError(f"{path}: joint type {jtype} not handled here")
            out.append(Link(child, parent, hom(rot_rpy(*rpy), xyz), j.get("name"),
                            "fixed" if jtype == "fixed" else "hinge", axis, (0, 0, 0),
                            inertial(links[child])))
            stack.append(child)
    return out


def read_mjcf(path):
    """Body tree of an MJCF with hinge joints. Handles body/inertial orientation given as quat, euler
    (eulerseq xyz) or axisangle, one hinge per body, and the top-level <default> joint attributes;
    refuses anything else it meets (xyaxes, zaxis, other joint types, other euler sequences)."""
    root = ET.parse(path).getroot()
    comp = root.find("compiler")
    degree = comp is None or comp.get("angle", "degree") == "degree"
    if comp is not None and comp.get("eulerseq", "xyz") != "xyz":
        raise ValueError(f"{path}: only eulerseq xyz is handled")
    if comp is None or comp.get("inertiafromgeom", "auto") != "false":
        raise ValueError(f"{path}: expected inertiafromgeom=\"false\" (geoms must not add inertia)")
    scale = PI / 180 if degree else 1.0
    jdef = {}
    d = root.find("default")
    if d is not None and d.find("joint") is not None:
        jdef = dict(d.find("joint").attrib)

    def orientation(el):
        if el.get("quat") is not None:
            return rot_quat(*floats(el.get("quat"), 4))
        if el.get("euler") is not None:  # xyz: intrinsic (moving) axes x, then y, then z
            e = [scale * v for v in floats(el.get("euler"), 3)]
            return rot_x(e[0]) @ rot_y(e[1]) @ rot_z(e[2])
        if el.get("axisangle") is not None:
            v = floats(el.get("axisangle"), 4)
            return rot_axis(v[:3], scale * v[3])
        for k in ("xyaxes", "zaxis"):
            if el.get(k) is not None:
                raise ValueError(f"{path}: {k} not handled")
        return np.eye(3)

    out = []

    def walk(body, parent):
        name = body.get("name")
        T = hom(orientation(body), floats(body.get("pos"), 3, [0, 0, 0]))
        js = body.findall("joint")
        if len(js) > 1:
            raise ValueError(f"{path}: body {name}: one joint per body handled")
        ie = body.find("inertial")
        inertial = None
        if ie is not None:
            m = float(ie.get("mass"))
            c = np.array(floats(ie.get("pos"), 3))
            R = orientation(ie)
            if ie.get("fullinertia") is not None:
                xx, yy, zz, xy, xz, yz = floats(ie.get("fullinertia"), 6)
                I = sym((xx, xy, xz, yy, yz, zz))
            else:
                I = np.diag(floats(ie.get("diaginertia"), 3))
            inertial = (m, c, R @ I @ R.T)
        if js:
            j = {**jdef, **js[0].attrib}
            if j.get("type", "hinge") != "hinge":
                raise ValueError(f"{path}: joint {j.get('name')}: only hinge joints handled")
            link = Link(name, parent, T, j.get("name"), "hinge", floats(j.get("axis"), 3, [0, 0, 1]),
                        floats(j.get("pos"), 3, [0, 0, 0]), inertial)
        else:
            link = Link(name, parent, T, None, "fixed", inertial=inertial)
        out.append(link)
        for b in body.findall("body"):
            walk(b, name)

    for b in root.find("worldbody").findall("body"):
        walk(b, None)
    return out


# --- Kinematics and dynamics of a read model -------------------------------------------------------


def world_frames(model, qmap):
    """World pose of every link, and the world axis and anchor of every hinge, at joint values qmap."""
    T, axes = {}, {}
    for L in model:  # parents come before children in both readers
        P = T[L.parent] if L.parent is not None else np.eye(4)
        B = P @ L.origin  # the link frame at q = 0
        if L.jtype == "hinge":
            q = qmap[L.joint]
            R = rot_axis(L.axis, q)
            # rotation about the axis through the anchor (anchor and axis in the link frame)
            M = hom(R, L.anchor - R @ L.anchor)
            axes[L.joint] = (B[:3, :3] @ (L.axis / np.linalg.norm(L.axis)),
                             B[:3, :3] @ L.anchor + B[:3, 3])
            B = B @ M
        T[L.name] = B
    return T, axes


def dynamics(bodies, axes, order):
    """M and G from bodies [(mass, world com, world inertia about com, [joints moving it])] and
    hinge axes {joint: (world axis, world point)}, in the joint order `order`."""
    n = len(order)
    M, G = np.zeros((n, n)), np.zeros(n)
    for m, c, I, moved_by in bodies:
        Jv, Jw = np.zeros((3, n)), np.zeros((3, n))
        for k, jn in enumerate(order):
            if jn in moved_by:
                z, p = axes[jn]
                Jv[:, k] = np.cross(z, c - p)
                Jw[:, k] = z
        M += m * Jv.T @ Jv + Jw.T @ I @ Jw
        G += -Jv.T @ (m * GRAVITY)
    return M, G


def model_bodies(model, T):
    by_name = {L.name: L for L in model}
    out = {}
    for L in model:
        if L.inertial is None:
            continue
        m, c, I = L.inertial
        R, p = T[L.name][:3, :3], T[L.name][:3, 3]
        moved, cur = [], L
        while cur is not None:
            if cur.jtype == "hinge":
                moved.append(cur.joint)
            cur = by_name.get(cur.parent)
        out[L.name] = (m, R @ c + p, R @ I @ R.T, moved)
    return out


def published_bodies(table, q):
    links, _, _ = dh_frames(table, q)
    out = {}
    for i, name in enumerate(table["links"]):
        R, p = links[i][:3, :3], links[i][:3, 3]
        out[name] = (table["mass"][i], R @ np.array(table["com"][i], float) + p,
                     R @ sym(table["inertia"][i]) @ R.T, table["joints"][: i + 1])
    return out


# --- The check ---------------------------------------------------------------------------------------


def check_inertias(table):
    worst = math.inf
    for i, name in enumerate(table["links"]):
        ev = np.linalg.eigvalsh(sym(table["inertia"][i]))
        tri = min(ev[0] + ev[1] - ev[2], ev[0] + ev[2] - ev[1], ev[1] + ev[2] - ev[0])
        worst = min(worst, ev[0], tri)
        if ev[0] <= 0 or tri < 0:
            print(f"  INVALID inertia of {name}: principal moments {ev}")
    return worst


def check_robot(label, table, urdf_path, mjcf_path, qs):
    print(f"== {label}: {urdf_path.name} and {mjcf_path.name} "
          f"({table['convention']} DH, {len(table['a'])} joints)")
    urdf, mjcf = read_urdf(urdf_path), read_mjcf(mjcf_path)
    fl = table["flange"]
    ok = True
    for name, model in (("URDF", urdf), ("MJCF", mjcf)):
        got = [L.name for L in model if L.jtype == "hinge"]
        if got != table["links"] or [L.joint for L in model if L.jtype == "hinge"] != table["joints"]:
            print(f"  {name}: moving links/joints {got} differ from {table['links']}")
            ok = False
        missing = [L.name for L in model if L.jtype == "hinge" and L.inertial is None]
        if missing:
            print(f"  {name}: moving links without inertia: {missing}")
            ok = False
    flange_inertial = [L.inertial for L in urdf if L.name == fl]
    print(f"  URDF '{fl}' link: {'no <inertial> block' if flange_inertial == [None] else 'has an <inertial> block'}")
    worst = check_inertias(table)
    print(f"  published inertia tensors: smallest principal moment / triangle margin {worst:.3e} kg m^2"
          f" ({'valid' if worst > 0 else 'INVALID'})")
    ok &= worst > 0
    header = (f"  {'q':<44} {'flange (DH) x y z [m]':<33} {'|URDF-DH|':>9} {'|MJCF-DH|':>9}"
              f" {'axes':>9} {'inertia':>9} {'M, G':>9}")
    print(header)
    for tag, q in qs:
        qmap = dict(zip(table["joints"], q))
        links, jframes, flange = dh_frames(table, q)
        errs = {"URDF": [0.0] * 4, "MJCF": [0.0] * 4}
        pub = published_bodies(table, q)
        Mp, Gp = dynamics(list(pub.values()), {jn: (F[:3, 2], F[:3, 3]) for jn, F in
                                               zip(table["joints"], jframes)}, table["joints"])
        for name, model in (("URDF", urdf), ("MJCF", mjcf)):
            T, axes = world_frames(model, qmap)
            e = errs[name]
            e[0] = np.abs(T[fl] - flange).max()  # flange position and orientation
            for jn, F in zip(table["joints"], jframes):  # same axis line, same direction
                z, p = axes[jn]
                e[1] = max(e[1], np.abs(z - F[:3, 2]).max(),
                           np.linalg.norm(np.cross(F[:3, 2], p - F[:3, 3])))
            bodies = model_bodies(model, T)
            for ln, (m, c, I, _) in pub.items():
                bm, bc, bI, _ = bodies[ln]
                e[2] = max(e[2], abs(bm - m), np.abs(bc - c).max(), np.abs(bI - I).max())
            extra = [b for b in bodies if b not in pub and bodies[b][0] != 0.0]
            if extra:
                print(f"  {name}: bodies with mass not in the table: {extra}")
                ok = False
            M, G = dynamics([bodies[ln] for ln in table["links"]], axes, table["joints"])
            e[3] = max(np.abs(M - Mp).max(), np.abs(G - Gp).max())
        qs_txt = tag + " [" + " ".join(f"{v:+.3f}" for v in q) + "]"
        pos = " ".join(f"{v:+.6f}" for v in flange[:3, 3])
        print(f"  {qs_txt:<44} {pos:<33} {errs['URDF'][0]:9.1e} {errs['MJCF'][0]:9.1e}"
              f" {max(errs['URDF'][1], errs['MJCF'][1]):9.1e}"
              f" {max(errs['URDF'][2], errs['MJCF'][2]):9.1e}"
              f" {max(errs['URDF'][3], errs['MJCF'][3]):9.1e}")
        ok &= max(max(v) for v in errs.values()) < TOL
        if tag == "zero":
            print(f"  {'':<44} M(0) diagonal: " + " ".join(f"{v:.6f}" for v in np.diag(Mp)))
            print(f"  {'':<44} G(0) [N m]:    " + " ".join(f"{v:+.5f}" for v in Gp))
    print(f"  -> {'OK' if ok else 'FAILED'} (tolerance {TOL:g}; |URDF-DH|, |MJCF-DH|: flange pose, "
          "max abs over position [m] and rotation matrix; axes: direction and offset of every joint "
          "axis; inertia: mass, world CoM, world inertia vs the published tables; M, G: mass matrix "
          "[kg m^2] and gravity torques [N m] vs the published tables)")
    return ok


def main():
    here = Path(__file__).resolve().parent.parent / "robots"
    d = Path(sys.argv[1]) if len(sys.argv) > 1 else here
    rng = np.random.default_rng(20190801)
    ur_qs = [("zero", [0.0] * 6), ("home", [0, -PI / 2, PI / 2, -PI / 2, -PI / 2, 0])]
    ur_qs += [(f"rand{k}", list(rng.uniform(-PI, PI, 6))) for k in (1, 2, 3)]
    pa_qs = [("zero", [0.0] * 7), ("ready", [0, -PI / 4, 0, -3 * PI / 4, 0, PI / 2, PI / 4])]
    pa_qs += [(f"rand{k}", list(rng.uniform(-PI, PI, 7))) for k in (1, 2, 3)]
    ok = check_robot("UR5e", UR5E, d / "ur5e.urdf", d / "ur5e.xml", ur_qs)
    ok &= check_robot("Panda", PANDA, d / "panda.urdf", d / "panda.xml", pa_qs)
    print("ALL OK" if ok else "SOME CHECKS FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
