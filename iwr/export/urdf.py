"""The (calibrated) carriage as URDF: one joint per carriage joint, its origin holding the robot's
DH parameters (identified errors included), and the hexapod's base frame {4} as a fixed link.

Standard DH (docs/model.md): ``A_i = Rz(theta_i + q_i) Tz(d_i + q_i) Tx(a_i) Rx(alpha_i)`` (the
reading ``q_i`` adds to theta for a revolute joint, to d for a prismatic one). As ``Rz`` and ``Tz``
commute, ``A_i = F_i M_i(q_i) G_i`` with ``F_i = Rz(theta_i)``, ``M_i`` the joint's motion along or
about z and ``G_i = Tz(d_i) Tx(a_i) Rx(alpha_i)``; so URDF joint ``i`` has the origin
``G_{i-1} F_i`` (``G_0`` the identity) and the axis z, and the fixed joint to ``hexapod_base``
has the origin ``G_n``. The joint positions are iwr's readings (URDF's units: m and rad).
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET

import numpy as np

from .. import kinds
from .._io import atomic_write_text
from ..robot import Robot
from ..transforms import pose_from_matrix
from .hexapod import data_frame, effects_note

__all__ = ["BASE_LINK", "HEXAPOD_LINK", "carriage_urdf", "link_names", "write_carriage_urdf"]

#: The URDF's root link: the world frame {0} of the carriage.
BASE_LINK = "base_link"
#: The fixed link at the hexapod's base frame {4}.
HEXAPOD_LINK = "hexapod_base"


def _frame_link(robot: Robot) -> tuple[str, np.ndarray] | None:
    """The link of the frame the data were measured in (the kind's ``frame_link``: ``tracker``
    for {T}) and its pose in {0}, ``T_0D``; None for data in {0}."""
    frame = data_frame(robot)
    if frame is None:
        return None
    name, t = frame
    return kinds.for_robot(robot).frame_link or f"frame_{name}", np.linalg.inv(t)


def link_names(robot: Robot) -> list[str]:
    """The names of the URDF's links, root first: ``base_link``, ``carriage_link1`` ..,
    ``hexapod_base``, then ``leg1_base_joint`` .. ``leg6_base_joint`` (the U-joint centres), and
    for a robot calibrated from laser-tracker data ``tracker`` (the tracker frame {T}, fixed in
    ``base_link`` by the calibrated registration)."""
    extra = _frame_link(robot)
    return ([BASE_LINK] + [f"carriage_link{i + 1}" for i in range(robot.n_joints)]
            + [HEXAPOD_LINK] + [f"leg{j + 1}_base_joint" for j in range(6)]
            + ([extra[0]] if extra else []))


def _rz(t: float) -> np.ndarray:
    m = np.eye(4)
    c, s = np.cos(t), np.sin(t)
    m[:2, :2] = [[c, -s], [s, c]]
    return m


def _g(alpha: float, a: float, d: float) -> np.ndarray:
    """``Tz(d) Tx(a) Rx(alpha)``."""
    m = np.eye(4)
    c, s = np.cos(alpha), np.sin(alpha)
    m[1:3, 1:3] = [[c, -s], [s, c]]
    m[:3, 3] = [a, 0.0, d]
    return m


def _num(v: float) -> str:
    return repr(float(v))


def _origin(parent: ET.Element, t: np.ndarray) -> None:
    """A URDF ``<origin>``: ``xyz`` in m from ``t`` in mm, ``rpy`` with R = Rz(y) Ry(p) Rx(r)."""
    pose = pose_from_matrix(t)
    ET.SubElement(parent, "origin", xyz=" ".join(_num(v / 1000.0) for v in pose[:3]),
                  rpy=" ".join(_num(v) for v in (pose[5], pose[4], pose[3])))


def carriage_urdf(robot: Robot, source: str | None = None) -> str:
    """The URDF text of ``robot``'s carriage (its DH parameters as they are: pass the calibrated
    robot, e.g. ``calibrated.toml`` or ``robot.with_errors(x)``)."""
    names = link_names(robot)
    extra = _frame_link(robot)
    root = ET.Element("robot", name=robot.name)
    where = f" ({source})" if source else ""
    text = (
        f" The carriage of robot {robot.name!r}{where}, written by iwr export. Link "
        f"{BASE_LINK} is the world frame {{0}}; {HEXAPOD_LINK} is the hexapod's base frame {{4}} "
        "(the base joints a_i are in it, as legN_base_joint). Joint positions are iwr's carriage "
        "readings q1.. in m (prismatic) and rad (revolute). The link frames between are not the "
        "DH frames: joint i has the origin G_(i-1) Rz(theta_i), with G_i = Tz(d_i) Tx(a_i) "
        "Rx(alpha_i) (docs/cli.md). Limits: iwr's joint limits; effort and velocity are not "
        "known to iwr (0). "
        + (f"Link {extra[0]} is the frame the calibration data were measured in, fixed in "
           f"{BASE_LINK} by the calibrated registration: such data do not fix {{0}}, whose "
           "placement is a gauge choice of the calibration (docs/tracker.md). "
           if extra else "")
        + (effects_note(robot) + ". " if robot.effects else ""))
    root.append(ET.Comment(text.replace("--", "- -")))  # "--" may not appear in an XML comment
    for name in names:
        ET.SubElement(root, "link", name=name)
    prev = np.eye(4)
    for i, (kind, (alpha, a, d, theta)) in enumerate(zip(robot.joint_types, robot.dh,
                                                         strict=True)):
        j = ET.SubElement(root, "joint", name=f"joint{i + 1}",
                          type="prismatic" if kind == "P" else "revolute")
        ET.SubElement(j, "parent", link=names[i])
        ET.SubElement(j, "child", link=names[i + 1])
        _origin(j, prev @ _rz(theta))
        ET.SubElement(j, "axis", xyz="0 0 1")
        scale = 1000.0 if kind == "P" else 1.0
        lo, hi = robot.joint_limits[i]
        ET.SubElement(j, "limit", lower=_num(lo / scale), upper=_num(hi / scale), effort="0",
                      velocity="0")
        prev = _g(alpha, a, d)
    n = robot.n_joints
    fixed = ET.SubElement(root, "joint", name="hexapod_base_joint", type="fixed")
    ET.SubElement(fixed, "parent", link=names[n])
    ET.SubElement(fixed, "child", link=HEXAPOD_LINK)
    _origin(fixed, prev)
    for k in range(6):
        leg = ET.SubElement(root, "joint", name=f"leg{k + 1}_base", type="fixed")
        ET.SubElement(leg, "parent", link=HEXAPOD_LINK)
        ET.SubElement(leg, "child", link=names[n + 2 + k])
        t = np.eye(4)
        t[:3, 3] = robot.base_joints[k]
        _origin(leg, t)
    if extra is not None:
        link, t = extra
        fixed = ET.SubElement(root, "joint", name=f"{link}_joint", type="fixed")
        ET.SubElement(fixed, "parent", link=BASE_LINK)
        ET.SubElement(fixed, "child", link=link)
        _origin(fixed, t)
    ET.indent(root)
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def write_carriage_urdf(path: str | os.PathLike[str], robot: Robot,
                        source: str | None = None) -> None:
    """Write :func:`carriage_urdf` atomically."""
    atomic_write_text(path, carriage_urdf(robot, source))
