"""Accuracy before and after calibration: the tool's pose error, in millimetres and degrees."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import kinds
from ..effects import refuse as refuse_effects
from ..forward import ForwardKinematicsError, forward_kinematics
from ..measurements import Measurements, as_matrix, tool_point
from ..robot import Robot
from ..transforms import pose_matrix, rotation_angle

__all__ = ["accuracy", "Accuracy", "PoseErrors", "pose_errors"]


def pose_errors(poses: Any, reference: Any, tool: Any = None) -> tuple[np.ndarray, np.ndarray]:
    """Position (mm) and orientation (degrees) errors of ``poses`` against ``reference``.

    Parameters
    ----------
    poses, reference : array_like, shape (N, 6)
        World poses ``(x, y, z, alpha, beta, gamma)`` (mm, rad).
    tool : array_like, shape (3,), optional
        The tool point in the platform frame {5} (mm); default its origin.

    Returns
    -------
    position : ndarray, shape (N,)
        Distance between the two tool points (mm).
    orientation : ndarray, shape (N,)
        Angle of the rotation between the two orientations (degrees), computed from the matrices,
        so independent of the Euler angles' gimbal lock.
    """
    poses = as_matrix(np.atleast_2d(poses), 6, "poses")
    reference = as_matrix(np.atleast_2d(reference), 6, "reference", rows=poses.shape[0])
    a, b = pose_matrix(poses), pose_matrix(reference)
    t = tool_point(tool)
    pa = a[:, :3, 3] + a[:, :3, :3] @ t
    pb = b[:, :3, 3] + b[:, :3, :3] @ t
    position = np.linalg.norm(pa - pb, axis=1)
    orientation = np.degrees(rotation_angle(np.swapaxes(a[:, :3, :3], 1, 2) @ b[:, :3, :3]))
    return position, orientation


def _stats(v: np.ndarray) -> dict[str, float]:
    return {
        "mean": float(np.mean(v)),
        "rms": float(math.sqrt(np.mean(v**2))),
        "max": float(np.max(v)),
    }


@dataclass(frozen=True)
class PoseErrors:
    """Per-pose errors of one robot model against the measured poses.

    Attributes
    ----------
    position : ndarray, shape (N,)
        Tool position error (mm).
    orientation : ndarray, shape (N,)
        Tool orientation error (degrees).
    poses : ndarray, shape (N, 6)
        The poses given by forward kinematics.
    """

    position: np.ndarray
    orientation: np.ndarray
    poses: np.ndarray

    def summary(self) -> dict[str, dict[str, float]]:
        """``{"position_mm": {"mean", "rms", "max"}, "orientation_deg": {...}}``."""
        return {"position_mm": _stats(self.position), "orientation_deg": _stats(self.orientation)}


@dataclass(frozen=True)
class Accuracy:
    """The accuracy of the nominal and of the calibrated robot on the same poses.

    Attributes
    ----------
    nominal : PoseErrors
        Errors of the nominal robot (x = 0).
    calibrated : PoseErrors
        Errors of the calibrated robot (the identified errors).
    """

    nominal: PoseErrors
    calibrated: PoseErrors

    @property
    def n_poses(self) -> int:
        return int(self.nominal.position.size)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able summary (mean, RMS and max of each error, both robots)."""
        return {
            "n_poses": self.n_poses,
            "nominal": self.nominal.summary(),
            "calibrated": self.calibrated.summary(),
        }

    def table(self) -> str:
        """A plain-text table of mean, RMS and max errors, before and after."""
        rows = [
            f"{'':18}{'position error (mm)':^30}  {'orientation error (deg)':^30}",
            f"{'':18}" + "".join(f"{h:>10}" for h in ("mean", "RMS", "max")) + "  "
            + "".join(f"{h:>10}" for h in ("mean", "RMS", "max")),
        ]
        for label, e in (("nominal robot", self.nominal), ("calibrated robot", self.calibrated)):
            s = e.summary()
            p, o = s["position_mm"], s["orientation_deg"]
            rows.append(
                f"{label:18}"
                + "".join(f"{p[k]:10.4f}" for k in ("mean", "rms", "max"))
                + "  "
                + "".join(f"{o[k]:10.5f}" for k in ("mean", "rms", "max"))
            )
        return "\n".join(rows)

    def __str__(self) -> str:
        return f"accuracy on {self.n_poses} poses\n{self.table()}"


def accuracy(
    robot: Robot,
    measurements: Measurements,
    x: Any,
    *,
    tool: Any = None,
    truth: Any = None,
    tolerance: float = 1e-9,
    max_iterations: int = 50,
    start: Any = None,
) -> Accuracy:
    """How accurately the nominal and the calibrated robot know where their tool is.

    For each measurement, the platform pose is computed by forward kinematics
    (:func:`iwr.forward_kinematics`) from the joint and leg readings, once with the nominal robot
    and once with the calibrated one (nominal plus ``x``), and compared with the measured
    pose. Use measurements that were **not** used for identification (validation poses): on the
    identification poses the figure is optimistic.

    Parameters
    ----------
    robot : Robot
        The nominal robot.
    measurements : Measurements
        Validation measurements: joint readings, leg readings and the measured poses.
    x : array_like, shape (n_params,)
        The identified error parameters (for example ``result.x``).
    tool : array_like, shape (3,), optional
        The tool point in the platform frame {5} (mm); default its origin.
    truth : array_like, optional
        Tracker data only: the simulation's true vector; the errors are then tool pose errors
        against it (else point residuals). See docs/tracker.md.
    tolerance, max_iterations
        Of the forward kinematics.
    start : optional
        What the identification started from beyond the nominal robot
        (:meth:`iwr.kinds.MeasurementKind.start` of the identification data: tracker data's
        registration guess). The "before" figure is the nominal robot in it; default the
        kind's start on ``measurements`` themselves (tracker data: a registration fitted to
        the validation poses, which flatters the nominal robot).

    Returns
    -------
    Accuracy
        ``nominal`` and ``calibrated`` per-pose errors; ``table()``, ``to_dict()`` summarise them
        (mean, RMS, max).

    Notes
    -----
    The figure does not depend on the unidentifiable combinations of parameters: by definition
    they do not change the leg readings predicted at any pose, hence not the pose that forward
    kinematics finds from the readings either.
    """
    # What accuracy means is the kind's (tracker data: tool pose errors against `truth` when
    # known, else point residuals).
    return kinds.of(measurements).accuracy(robot, measurements, x, tool=tool, truth=truth,
                                           tolerance=tolerance, max_iterations=max_iterations,
                                           start=start)


def pose_accuracy(robot: Robot, measurements: Measurements, x: Any, *, tool: Any = None,
                  truth: Any = None, tolerance: float = 1e-9, max_iterations: int = 50
                  ) -> Accuracy:
    """:func:`accuracy` on pose data (the platform pose measured in {0})."""
    # Issue 23: the geometry's forward kinematics; a robot with effects goes to
    # iwr.effects.job.accuracy (PoseKind.accuracy, what iwr.accuracy calls).
    refuse_effects(robot, "pose_accuracy")
    if truth is not None:
        raise ValueError("truth: only for tracker data (iwr.tracker.TrackerMeasurements)")
    if not isinstance(measurements, Measurements):
        raise TypeError(
            f"measurements: expected an iwr.Measurements, got {type(measurements).__name__}"
        )
    x = np.zeros(robot.n_params) if x is None else np.asarray(x, dtype=float)
    out = {}
    for label, xe in (("nominal", np.zeros(robot.n_params)), ("calibrated", x)):
        try:
            poses = forward_kinematics(
                robot, xe, measurements.q, measurements.legs,
                tolerance=tolerance, max_iterations=max_iterations,
            )
        except ForwardKinematicsError as exc:
            k = getattr(exc, "pose", None)
            where = measurements.where(k) if k is not None else "a pose"
            msg = str(exc).split(": ", 2)[-1] if k is not None else str(exc)
            err = ForwardKinematicsError(
                f"forward kinematics of the {label} robot at {where}: {msg}"
            )
            err.pose = k
            raise err from None
        pos, ori = pose_errors(poses, measurements.poses, tool)
        out[label] = PoseErrors(position=pos, orientation=ori, poses=poses)
    return Accuracy(nominal=out["nominal"], calibrated=out["calibrated"])
