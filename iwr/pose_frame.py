"""Is a pose measured in the robot's world frame {0}? A check of pose data before identification.

Poses measured in another frame (an instrument not registered to the robot, a mirrored frame)
or with two columns swapped cannot be fitted by the kinematic model: an identification then
absorbs what it can into implausible errors, and the forward kinematics of the resulting robot
may fail outright, which reads as unreachable readings. This check compares, before anything is
identified, the measured poses with the nominal robot's forward kinematics of the joint and leg
readings (which does not involve the poses): the nominal robot is within millimetres and a
degree of the real one, so a frame or column mistake shows as a residual far larger than that,
which a rigid transform (a frame), a reflection (a mirrored frame) or a swap of two columns
explains.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .forward import ForwardKinematicsError, forward_kinematics
from .measurements import Measurements
from .robot import Robot
from .transforms import euler_zyx, rotation_angle

__all__ = ["PoseFrameCheck", "PoseFrameError", "check_pose_frame", "FRAME_POSITION_MM",
           "FRAME_ORIENTATION_DEG", "MODEL_POSITION_MM", "MODEL_ORIENTATION_DEG"]

#: The RMS differences between measured poses and the robot's forward kinematics above which the
#: poses are not taken as measured in {0} (mm, degrees). Errors of the default bounds (+-0.5 mm,
#: +-0.5 degree) make about 11 mm and 0.9 degree on the IWR; the fit check accepts errors up to
#: ten times those bounds.
FRAME_POSITION_MM = 100.0
FRAME_ORIENTATION_DEG = 10.0
#: An explanation (a frame, a reflection, swapped columns) is accepted when it brings the poses
#: within these RMS differences of the forward kinematics: what a robot's errors make.
MODEL_POSITION_MM = 30.0
MODEL_ORIENTATION_DEG = 3.0

_POSITION_COLUMNS = ("x_mm", "y_mm", "z_mm")
_ANGLE_COLUMNS = ("alpha_rad", "beta_rad", "gamma_rad")


class PoseFrameError(ValueError):
    """Poses that are not in the robot's world frame, or have two columns swapped."""


@dataclass(frozen=True)
class PoseFrameCheck:
    """What :func:`check_pose_frame` found.

    Attributes
    ----------
    position_rms, orientation_rms : float
        RMS difference between the measured poses and the nominal robot's forward kinematics
        (mm, degrees), as measured.
    diagnosis : str
        ``"ok"``; ``"frame"`` (a rigid transform explains the poses), ``"mirrored"`` (a
        reflection does), ``"columns"`` (two columns swapped do), or ``"unexplained"``.
    message : str
        One sentence for the user ("" when ``ok``).
    transform : ndarray (4, 4) or None
        For ``"frame"``: the pose of {0} in the poses' frame.
    n_poses : int
        Poses compared (those whose forward kinematics converged).
    """

    position_rms: float
    orientation_rms: float
    diagnosis: str
    message: str
    transform: np.ndarray | None
    n_poses: int

    @property
    def ok(self) -> bool:
        return self.diagnosis == "ok"

    @property
    def refused(self) -> bool:
        """Whether a command refuses the data: a frame, a reflection or two columns swapped
        explain how far they are from the robot (what no identification should absorb)."""
        return self.diagnosis in ("frame", "mirrored", "columns")


def _rms(v: np.ndarray) -> float:
    return float(math.sqrt(np.mean(v**2))) if v.size else 0.0


def _angle_deg(r: np.ndarray) -> np.ndarray:
    """Rotation angles (degrees) of matrices (..., 3, 3)."""
    return np.degrees(rotation_angle(r))


def _differences(p_meas: np.ndarray, r_meas: np.ndarray, p_pred: np.ndarray,
                 r_pred: np.ndarray) -> tuple[float, float]:
    pos = np.linalg.norm(p_meas - p_pred, axis=1)
    ang = _angle_deg(np.swapaxes(r_pred, -1, -2) @ r_meas)
    return _rms(pos), _rms(ang)


def _orthogonal_fit(a: np.ndarray, b: np.ndarray, proper: bool) -> tuple[np.ndarray, np.ndarray]:
    """``R``, ``t`` minimising ``sum |R a_i + t - b_i|^2`` over rotations (``proper``) or over
    orthogonal matrices of determinant -1 (reflections)."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    r = vt.T @ np.diag([1.0, 1.0, d if proper else -d]) @ u.T
    return r, cb - r @ ca


def _chordal_mean(r: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(r.mean(axis=0))
    return u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0]) @ vt


def check_pose_frame(robot: Robot, measurements: Measurements, x: Any = None) -> PoseFrameCheck:
    """Compare the measured poses with the forward kinematics of the readings by the robot with
    errors ``x`` (default: the nominal robot), and say whether a frame or column mistake
    explains a difference larger than a robot's errors can make (:data:`FRAME_POSITION_MM`,
    :data:`FRAME_ORIENTATION_DEG` RMS).

    Tried in order, each accepted when it brings both RMS differences within what a robot's
    errors make (:data:`MODEL_POSITION_MM`, :data:`MODEL_ORIENTATION_DEG`): two
    position or two angle columns swapped; a rigid transform (Kabsch on the positions, the
    chordal mean of the rotations: the measuring frame not registered to {0}); a reflection of
    the positions (a mirrored, left-handed frame). Poses whose forward kinematics does not
    converge are left out (more than half: ``"unexplained"``, the readings' own problem).
    """
    x = np.zeros(robot.n_params) if x is None else np.ascontiguousarray(x, dtype=float)
    q = np.ascontiguousarray(measurements.q, dtype=float)
    legs = np.ascontiguousarray(measurements.legs, dtype=float)
    ok = np.ones(len(q), dtype=bool)
    try:
        poses = forward_kinematics(robot, x, q, legs)
    except ForwardKinematicsError:  # pose by pose, leaving out those that fail
        poses = np.full((len(q), 6), np.nan)
        for k in range(len(q)):
            try:
                poses[k] = forward_kinematics(robot, x, q[k:k + 1], legs[k:k + 1])[0]
            except ForwardKinematicsError:
                ok[k] = False
    n = int(ok.sum())
    meas = np.asarray(measurements.poses, dtype=float)[ok]
    pred = poses[ok]
    if n < 3:
        return PoseFrameCheck(math.nan, math.nan, "unexplained",
                              f"the forward kinematics of the readings converged at {n} of "
                              f"{len(ok)} poses only: the leg or joint readings (or the robot "
                              "description) are wrong, not the poses' frame", None, n)
    p_pred, r_pred = pred[:, :3], euler_zyx(pred[:, 3], pred[:, 4], pred[:, 5])
    p_meas, r_meas = meas[:, :3], euler_zyx(meas[:, 3], meas[:, 4], meas[:, 5])
    pos, ang = _differences(p_meas, r_meas, p_pred, r_pred)

    def fits(p: float, a: float) -> bool:
        return p <= MODEL_POSITION_MM and a <= MODEL_ORIENTATION_DEG

    def result(diagnosis: str, message: str, transform: Any = None) -> PoseFrameCheck:
        return PoseFrameCheck(pos, ang, diagnosis, message, transform, n)

    if pos <= FRAME_POSITION_MM and ang <= FRAME_ORIENTATION_DEG:
        return result("ok", "")
    seen = (f"the measured poses are {pos:.4g} mm and {ang:.4g} deg (RMS over {n} poses) from "
            "the robot's forward kinematics of the joint and leg readings, far more than a "
            "robot's errors make")
    # Two columns swapped: positions, or angles (the other half as measured).
    for cols, names in ((range(3), _POSITION_COLUMNS), (range(3, 6), _ANGLE_COLUMNS)):
        for i, j in itertools.combinations(cols, 2):
            swapped = meas.copy()
            swapped[:, [i, j]] = swapped[:, [j, i]]
            p2, a2 = _differences(swapped[:, :3], euler_zyx(*swapped[:, 3:].T), p_pred, r_pred)
            if fits(p2, a2):
                a, b = names[i % 3], names[j % 3]
                return result("columns", (
                    f"{seen}; with columns {a} and {b} exchanged they are {p2:.3g} mm and "
                    f"{a2:.3g} deg from it: columns {a} and {b} look swapped (check the file's "
                    "header against its values)"))
    # A rigid transform: the poses in another frame.
    rot, t = _orthogonal_fit(p_pred, p_meas, proper=True)
    d = _chordal_mean(r_meas @ np.swapaxes(r_pred, -1, -2))
    p2, a2 = _differences(p_meas, r_meas, p_pred @ rot.T + t, d @ r_pred)
    if fits(p2, a2) and _angle_deg(rot @ d.T) <= 2 * MODEL_ORIENTATION_DEG:
        tr = np.eye(4)
        tr[:3, :3], tr[:3, 3] = rot, t
        return result("frame", (
            f"{seen}; one rigid transform, {np.linalg.norm(t):.4g} mm and "
            f"{float(_angle_deg(rot)):.4g} deg, brings them within {p2:.3g} mm and {a2:.3g} deg: "
            "the poses are measured in another frame than the robot's world frame {0} (an "
            "unregistered measuring instrument). Express them in {0}, or give laser-tracker "
            "data with a [tracker] table, whose registration is identified (docs/tracker.md)"),
            tr)
    # A reflection: a mirrored (left-handed) frame.
    rot_m, t_m = _orthogonal_fit(p_pred, p_meas, proper=False)
    pm = _rms(np.linalg.norm(p_pred @ rot_m.T + t_m - p_meas, axis=1))
    if pm <= MODEL_POSITION_MM:
        return result("mirrored", (
            f"{seen}; the positions fit it within {pm:.3g} mm only through a reflection: the "
            "poses are measured in a mirrored (left-handed) frame, or with an axis reversed. "
            "Express them in the robot's world frame {0}"))
    return result("unexplained", (
        f"{seen}, and neither a frame (rigid or mirrored) nor two swapped columns explain it: "
        "check the robot description and the readings (leg columns swapped, a wrong unit, a "
        "tool offset left out)"))
