"""Compensation: the leg commands that put the platform (or a tool on it) at target poses with a
calibrated robot, in the frame the calibration's data determine; and the status a calibration
file records, which decides whether it may be used at all.

Pose data (the platform pose measured in the world frame {0}) determine {0}: targets are poses
in {0}. Laser-tracker data determine the robot only in the tracker frame {T}: the registration
and the carriage's base share null directions (docs/tracker.md), so {0} of a tracker calibration
is one arbitrary choice among many, and targets in {0} would be commanded to a frame nobody
measured. Targets are then poses in {T}, carried into the calibrated robot's {0} through its
calibrated registration; the platform frame they place is the one the calibration file fixes
(``[provenance] platform_frame``: the frame in which the reflectors sit at their nominal
positions, or the probe at its nominal pose; :func:`iwr.tracker.fix_platform_frame`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from . import kinds
from .measurements import MAX_LENGTH_MM, as_matrix, as_vector
from .problem import predict_legs
from .robot import Robot
from .transforms import pose_from_matrix, pose_matrix

if TYPE_CHECKING:  # scipy.optimize's OptimizeResult: not for `import iwr`
    from .result import IdentificationResult

__all__ = ["CALIBRATION_STATUSES", "FRAMES", "CalibrationStatusError", "FrameError",
           "LegCommands", "NominalMismatchError", "TargetError", "calibration_status",
           "check_calibration", "check_nominal", "determined_frame", "implied_errors",
           "leg_commands", "with_measured_workspace"]

#: What ``[provenance] status`` of a calibration file can say; only ``success`` is used without
#: being told to (``allow_unverified``).
CALIBRATION_STATUSES = {
    "success": "the method converged and the model fits the data (or no fit test was possible)",
    "failed fit test": "the model does not fit the data (chi-square test or implausible errors)",
    "interrupted": "Ctrl-C (or a signal) ended the identification: its best point so far",
    "not converged": "a limit (evaluations, generations, time) ended the identification first",
    "not calibrated": "the method converged, but the data cannot identify the robot's errors "
                      "(degenerate data) or the calibrated robot is no better than the nominal "
                      "one: more budget would not help; measure more, and more varied, poses",
    "failed": "the identification failed, or its result is not finite",
}

#: A target within this fraction of a range beyond the joint limits or the workspace is not
#: flagged out of the workspace (as measurement files are checked).
WORKSPACE_TOLERANCE = 0.01

#: The frames targets may be given in: the key, and what it is.
FRAMES = {"0": "the robot's world frame {0}", "T": "the laser tracker's frame {T}"}


class CalibrationStatusError(ValueError):
    """A calibration file that is not a success, used without ``allow_unverified``."""


class FrameError(ValueError):
    """Targets in a frame the calibration's data do not determine."""


class TargetError(ValueError):
    """A target value out of the plausible range; ``index`` (0-based) and ``column`` name it."""

    def __init__(self, index: int, column: str, message: str) -> None:
        super().__init__(f"target {index + 1}, {column}: {message}")
        self.index, self.column, self.detail = index, column, message


def calibration_status(result: IdentificationResult) -> str:
    """The status a calibration file records for an identification ``result``
    (:data:`CALIBRATION_STATUSES`): interrupted, then not calibrated (the job's verdict on
    degenerate data, whose fit test says nothing, or on no improvement), then a failed fit
    test, then not converged or failed, else success."""
    status = result.status
    if status in ("interrupted", "not calibrated"):  # iwr.calibration.NOT_CALIBRATED
        return str(status)
    fit = result.fit
    if fit is not None and not fit.fit_ok:
        return "failed fit test"
    if not result.success:
        return "failed" if status == "failed" else "not converged"
    return "success"


def check_calibration(robot: Robot, *, allow_unverified: bool = False,
                      where: str = "robot") -> str:
    """Check the status a robot file records before it is used for compensation.

    Returns a note for the user ("" when there is nothing to say). Raises
    :class:`CalibrationStatusError` for a calibration whose ``[provenance] status`` is not
    ``success``, or a calibration that records none (written by an iwr before statuses, or by
    hand), unless ``allow_unverified``. A robot description that is no calibration (no
    ``[provenance] method``) is used as it is."""
    prov = robot.provenance
    status = prov.get("status")
    if status is None and "method" not in prov:
        return ""
    if status == "success":
        return ""
    what = (f"records status {status!r} ({CALIBRATION_STATUSES.get(str(status), 'unknown')})"
            if status is not None else "records no calibration status (an older iwr, or edited)")
    detail = prov.get("status_detail")
    what += f": {detail}" if detail else ""
    if not allow_unverified:
        raise CalibrationStatusError(
            f"{where}: [provenance] {what}; it is not a verified calibration. Fix the "
            "calibration (its report says why), or use it anyway with --allow-unverified "
            "(allow_unverified=True in Python)")
    return f"warning: {where} {what}; used because --allow-unverified was given"


class NominalMismatchError(ValueError):
    """The robot given as a calibration's nominal model is not one it can be relative to."""


#: How far (times the default bounds' half-widths, as the fit test's size check) a calibrated
#: robot's geometry may sit from the nominal robot it is compared with.
NOMINAL_PLAUSIBLE = 10.0


def implied_errors(nominal: Robot, calibrated: Robot) -> np.ndarray:
    """The error vector ``x`` with ``nominal.with_errors(x)`` of ``calibrated``'s geometry (the
    same joint types); the DH angles' differences within +-pi (:meth:`iwr.Robot.with_errors`
    keeps an angle that passes 2 pi as the same rotation within +-pi)."""
    if nominal.joint_types != calibrated.joint_types:
        raise NominalMismatchError(f"joints {nominal.joint_types!r} and "
                                   f"{calibrated.joint_types!r}: not the same robot")
    ddh = calibrated.dh - nominal.dh
    ddh[:, [0, 3]] = np.remainder(ddh[:, [0, 3]] + np.pi, 2 * np.pi) - np.pi
    return np.concatenate([
        ddh.ravel(),
        (calibrated.base_joints - nominal.base_joints).ravel(),
        (calibrated.platform_joints - nominal.platform_joints).ravel(),
        calibrated.leg_offsets - nominal.leg_offsets])


def check_nominal(calibrated: Robot, nominal: Robot, *, where: str = "calibrated",
                  nominal_where: str = "nominal") -> str:
    """Check that ``nominal`` can be the model a calibration's corrections are relative to.

    Returns a note ("" when there is nothing to say). A calibration file records the fingerprint
    of its nominal geometry (``[provenance] nominal_geometry``); that nominal passes. Raises
    :class:`NominalMismatchError` for the calibrated robot itself (the same geometry: every
    correction would be zero) and, after a calibration from data that determine {0} (pose
    data), for another robot: a geometry more than :data:`NOMINAL_PLAUSIBLE` times the default
    bounds from the calibrated one in some parameter, which no calibration moves. Tracker and
    ballbar data leave {0} or {5} to a gauge choice that moves the base or platform joints by
    millimetres (7 mm in a tracker calibration's base joint z, seen), so there such a difference
    gives a note only. Another plausible nominal (the controller's own model) gives a note.
    """
    x = implied_errors(nominal, calibrated)
    prov = calibrated.provenance
    recorded = prov.get("nominal_geometry")
    from .robot_fingerprint import geometry_fingerprint

    if recorded is not None and recorded == geometry_fingerprint(nominal):
        return ""
    made_from = f" ({where} was calibrated from {prov['robot']})" if prov.get("robot") else ""
    lead = (f"note: {nominal_where} is not the robot file {where} was calibrated from{made_from}"
            if recorded is not None else
            f"note: {where} records no fingerprint of its nominal robot (an older iwr wrote it), "
            f"so {nominal_where} could not be checked to be it")
    if not np.any(x) and prov.get("method") is not None:
        raise NominalMismatchError(
            f"{nominal_where} has the geometry of {where} itself, not of the nominal robot it "
            f"was calibrated from{made_from}: every correction would be zero")
    limit = NOMINAL_PLAUSIBLE * nominal.default_bounds("default")[1]
    ratio = np.abs(x) / limit
    worst = int(np.argmax(ratio))
    if ratio[worst] > 1.0:
        name = nominal.parameter_names[worst]
        unit = "rad" if nominal.angle_parameters[worst] else "mm"
        differs = (f"{name} differs by {x[worst]:.6g} {unit} between them, more than "
                   f"{limit[worst]:.3g} {unit} ({NOMINAL_PLAUSIBLE:g} times the default bounds)")
        if determined_frame(calibrated) == "0":
            raise NominalMismatchError(f"{nominal_where} is not the nominal robot of {where}"
                                       f"{made_from}: {differs}, which no calibration moves")
        return (f"{lead}: {differs}, which its data's gauge allows; check that it is the model "
                "your controller uses for this robot")
    if recorded is None:
        return ""
    return f"{lead}: the corrections are relative to {nominal_where}'s geometry"


def determined_frame(robot: Robot) -> str | None:
    """The frame a robot's calibration data determine, as its kind of data says
    (:attr:`iwr.kinds.MeasurementKind.frame`): ``"T"`` for a robot with a ``[tracker]`` table
    (tracker data), ``"0"`` for pose data; None for data that determine no frame (a ballbar's
    distances: neither {0} nor {5}, docs/ballbar.md)."""
    kind = kinds.for_robot(robot)
    if kind.frame == "{0}" and not kind.determines_world_frame:
        return None
    return kind.frame.strip("{}")


def gauge_note(robot: Robot, where: str) -> str:
    """What leg commands in {0} mean after a calibration from data that determine no frame."""
    return (f"{where} was calibrated from {kinds.for_robot(robot).description} data, which "
            "determine neither the world frame {0} nor the platform frame {5} (docs/ballbar.md): "
            "the calibration keeps both where the nominal robot has them, so the leg commands "
            "are right relative to one another, but off by whatever the actual base and tool "
            "placement differ from the nominal (register them by other means)")


def _check_frame(robot: Robot, frame: str | None, where: str) -> str:
    own = determined_frame(robot)
    if frame is None and own is not None:
        return own
    if frame is not None and frame not in FRAMES:
        raise FrameError(f"frame {frame!r}: expected one of {', '.join(FRAMES)} "
                         f"({'; '.join(f'{k}: {v}' for k, v in FRAMES.items())})")
    if own is None:
        if frame == "0":  # given explicitly: the nominal placement of {0} and {5} accepted
            return frame
        raise FrameError(
            f"targets in {FRAMES['0' if frame is None else frame]}: {gauge_note(robot, where)}. "
            "Give --frame 0 (frame='0') to accept the nominal placement of {0} and {5}")
    if frame == own:
        return frame
    if frame == "0":
        raise FrameError(
            f"targets in {FRAMES['0']}: {where} was calibrated from laser-tracker data, which "
            "do not determine {0} (the registration and the carriage's base share null "
            "directions, docs/tracker.md), so its {0} is arbitrary and the legs would be wrong "
            "by millimetres; give the targets in the tracker frame {T} (--frame T, "
            "frame='T'), where the tracker measures them")
    raise FrameError(
        f"targets in {FRAMES['T']}: {where} has no [tracker] table (its calibration used poses "
        "measured in {0}), so {T} is unknown; give the targets in {0} (--frame 0, frame='0')")


def _check_targets(q: np.ndarray, poses: np.ndarray, joint_columns: list[str]) -> None:
    """Refuse values no target can have: positions beyond 100 m, pose angles beyond 2 pi
    (degrees written for radians), as data files are checked."""
    names = ("x_mm", "y_mm", "z_mm", "alpha_rad", "beta_rad", "gamma_rad")
    for k in range(len(poses)):
        for c in range(6):
            v = float(poses[k, c])
            if not math.isfinite(v):
                raise TargetError(k, names[c], f"{v!r} is not finite")
            if c < 3 and abs(v) > MAX_LENGTH_MM:
                raise TargetError(k, names[c], f"{v:g} mm is beyond {MAX_LENGTH_MM:g} mm: "
                                  "not millimetres?")
            if c >= 3 and abs(v) > 2 * math.pi:
                raise TargetError(k, names[c], f"{v:g} rad is beyond 2 pi: angles are in "
                                  f"radians ({v:g} deg = {math.radians(v):.6g} rad)")
        for c, name in enumerate(joint_columns):
            if not math.isfinite(float(q[k, c])):
                raise TargetError(k, name, f"{q[k, c]!r} is not finite")


@dataclass(frozen=True)
class LegCommands:
    """The leg commands for a list of targets (:func:`leg_commands`).

    Attributes
    ----------
    legs : ndarray (N, 6)
        Leg sensor readings (mm; leg length = reading + l0) that put the target frame at each
        target with the robot.
    frame : str
        The frame the targets were given in (:data:`FRAMES`).
    platform_poses : ndarray (N, 6)
        The platform frame {5} in the robot's {0} that the commands give.
    out_of_stroke : ndarray (N, 6) of bool
        Legs whose command is outside ``robot.leg_stroke``.
    out_of_workspace : ndarray (N,) of bool
        Targets outside the robot's workspace: a carriage joint reading outside
        ``robot.joint_limits``, or the platform's pose in {4} outside ``home_pose +-
        workspace`` (where the robot was sampled and calibrated: beyond, the model is an
        extrapolation), each widened by :data:`WORKSPACE_TOLERANCE` of its range.
    beyond_joint_limits : ndarray (N,) of bool
        Of those, the targets with a carriage joint reading outside its limits: the robot
        cannot reach them (the others only outside the box, it can: the commands extrapolate).
    """

    legs: np.ndarray
    frame: str
    platform_poses: np.ndarray
    out_of_stroke: np.ndarray
    out_of_workspace: np.ndarray
    beyond_joint_limits: np.ndarray

    @property
    def unreachable(self) -> np.ndarray:
        """(N,) targets needing any leg outside its stroke (a carriage joint beyond its limit:
        :attr:`beyond_joint_limits`; neither can be reached)."""
        return self.out_of_stroke.any(axis=1)

    @property
    def n_flagged(self) -> int:
        """Targets out of stroke or out of workspace."""
        return int(np.count_nonzero(self.unreachable | self.out_of_workspace))


def frame_from_points(origin: Any, on_x: Any, in_xy: Any) -> np.ndarray:
    """A user frame from three points measured in the frame the data determine, as tracker
    software builds one ("frame from 3 points", 3-2-1): its origin at ``origin``, its x axis
    towards ``on_x``, its xy plane through ``in_xy`` (on the +y side). The 4x4 pose of the user
    frame in the measured frame; ValueError for points that fix no frame (coincident, or on one
    line to within 1e-6 of their spread)."""
    o, px, pxy = (np.asarray(p, dtype=float).reshape(3) for p in (origin, on_x, in_xy))
    if not all(np.all(np.isfinite(p)) for p in (o, px, pxy)):
        raise ValueError("user frame: the points must be finite")
    ex = px - o
    size = max(float(np.linalg.norm(ex)), float(np.linalg.norm(pxy - o)))
    if float(np.linalg.norm(ex)) <= 1e-6 * max(size, 1.0):
        raise ValueError("user frame: the point on x coincides with the origin")
    ex = ex / np.linalg.norm(ex)
    ez = np.cross(ex, pxy - o)
    if float(np.linalg.norm(ez)) <= 1e-6 * size:
        raise ValueError("user frame: the three points are on one line; the point in the xy "
                         "plane must be off the x axis")
    ez = ez / np.linalg.norm(ez)
    out = np.eye(4)
    out[:3, :3] = np.column_stack([ex, np.cross(ez, ex), ez])
    out[:3, 3] = o
    return out


def rigid_transform(value: Any, name: str) -> np.ndarray:
    """``value`` as a 4x4 rigid transform (a rotation, not a reflection, and the bottom row
    ``[0, 0, 0, 1]``), else a ValueError naming ``name``."""
    m = as_matrix(value, 4, name, rows=4)
    r = m[:3, :3]
    if not (np.allclose(r @ r.T, np.eye(3), atol=1e-9) and np.linalg.det(r) > 0
            and np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], rtol=0.0, atol=1e-12)):
        raise ValueError(f"{name}: expected a 4x4 rigid transform (an orthonormal rotation "
                         "with determinant +1, not a reflection, and the bottom row 0 0 0 1)")
    return m


def _from_home(robot: Robot, q: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(N, 6): the platform's pose in {4} at each of ``target`` (4x4 poses of {5} in {0}) at
    joint readings ``q``, minus ``robot.home_pose`` (angles within +-pi): what the workspace
    bounds."""
    local = np.array([pose_from_matrix(np.linalg.solve(robot.carriage_transform(qk), t))
                      for qk, t in zip(q, target, strict=True)]).reshape(-1, 6)
    dev = local - robot.home_pose
    dev[:, 3:] = (dev[:, 3:] + math.pi) % (2 * math.pi) - math.pi
    return dev


def with_measured_workspace(robot: Robot, *data: Any) -> Robot:
    """``robot`` (a calibrated one) with its workspace, ``home_pose +- workspace`` in {4}, widened
    where it does not hold the poses of ``data`` (each at the platform pose its joint and leg
    readings give by ``robot``'s forward kinematics; a pose whose forward kinematics fails is
    left out): what the calibration job writes in ``calibrated.toml``, so that
    :func:`leg_commands` flags no pose the robot was measured at.

    The box is the robot file's, about the nominal {4}; the calibrated {4} is placed by the data
    only up to the directions they cannot identify (parameters held at nominal; {0}, {5} of
    tracker data), and the measured poses may sit beyond the box in it: 4 of the 60 poses of a
    simulated calibration were flagged (at 1.025-1.045 of the box there, 0.98-0.997 in the true
    {4}). A box no wider than the data needs is left as it is."""
    from .forward import ForwardKinematicsError, forward_kinematics

    geometric = robot.with_effects()
    width = np.array(robot.workspace, dtype=float)
    for d in data:
        for k in range(len(d)):
            try:
                world = forward_kinematics(geometric, None, d.q[k:k + 1], d.legs[k:k + 1])
            except ForwardKinematicsError:
                continue
            dev = _from_home(robot, d.q[k:k + 1], pose_matrix(world))[0]
            width = np.maximum(width, np.abs(dev))
    return robot if np.array_equal(width, robot.workspace) else robot.with_workspace(width)


def leg_commands(robot: Robot, q: Any, poses: Any, *, frame: str | None = None,
                 tool: Any = None, user_frame: Any = None, joint_columns: list[str] | None = None,
                 where: str = "robot") -> LegCommands:
    """The leg commands that put a tool frame at target poses, with a (calibrated) robot.

    Parameters
    ----------
    robot : Robot
        The calibrated robot (``calibrated.toml``): its errors are part of its geometry. Its
        status is checked separately (:func:`check_calibration`).
    q : array_like (N, n_joints)
        Carriage joint readings at each target.
    poses : array_like (N, 6)
        Target poses ``(x, y, z, alpha, beta, gamma)`` (mm, rad) of the tool frame in ``frame``.
    frame : {"0", "T"}, optional
        The frame of the targets; default (and the only one allowed) the frame the robot's
        calibration data determine (:func:`determined_frame`): {0} for pose data, the tracker
        frame {T} for tracker data. Another raises :class:`FrameError` saying which to give.
        After a calibration from data that determine no frame (ballbar data), only an explicit
        ``"0"``: the nominal placement of {0} and {5} accepted (:func:`gauge_note`).
    tool : array_like (6,), optional
        The tool frame's pose in the platform frame {5} (mm, rad); default {5} itself. For
        tracker data, {5} is the frame the calibration file fixes (its reflectors at their
        nominal positions, or its probe at its nominal pose); the probe's own pose as ``tool``
        makes the targets the probe's poses in {T}.
    user_frame : array_like (4, 4), optional
        The targets are in this user frame, given by its pose in ``frame``
        (:func:`frame_from_points` from three points measured with the instrument).
    joint_columns : list of str, optional
        Names of ``q``'s columns, for messages.

    Raises
    ------
    FrameError, TargetError (a value no target can have: a pose angle beyond 2 pi, ...)
    """
    # One target may be given as a single row; anything else must have the documented shape
    # (a (4, N) q reshaped to (N, 4) would command other poses).
    poses = as_matrix(np.atleast_2d(poses), 6, "poses")
    q = as_matrix(np.atleast_2d(q) if np.ndim(q) == 1 and robot.n_joints else q,
                  robot.n_joints, "q", rows=poses.shape[0])  # a hexapod alone: q = []
    if not len(poses):
        raise ValueError("poses: no target poses")
    cols = joint_columns or [f"q{i + 1}" for i in range(robot.n_joints)]
    _check_targets(q, poses, cols)
    frame = _check_frame(robot, frame, where)
    target = pose_matrix(poses)
    if user_frame is not None:
        target = rigid_transform(user_frame, "user_frame") @ target
    if tool is not None:
        tool_m = pose_matrix(as_vector(tool, 6, "tool"))
        target = target @ np.linalg.inv(tool_m)
    if frame == "T":  # the frame the robot's instrument gives its data in (_check_frame)
        target = np.linalg.solve(kinds.for_robot(robot).registration(robot), target)
    world = pose_from_matrix(target)
    legs = predict_legs(robot, None, q, world)
    lo, hi = robot.leg_stroke[:, 0], robot.leg_stroke[:, 1]
    stroke = (legs < lo) | (legs > hi)
    dev = _from_home(robot, q, target)
    # Widened by 1 % of each range, as measurement files are checked (Measurements.check): a
    # target the data could have held is not flagged.
    lo, hi = robot.joint_limits[:, 0], robot.joint_limits[:, 1]
    slack = WORKSPACE_TOLERANCE * (hi - lo)
    limits = np.any((q < lo - slack) | (q > hi + slack), axis=1)
    workspace = (np.any(np.abs(dev) > robot.workspace * (1 + 2 * WORKSPACE_TOLERANCE), axis=1)
                 | limits)
    return LegCommands(legs=legs, frame=frame, platform_poses=world, out_of_stroke=stroke,
                       out_of_workspace=workspace, beyond_joint_limits=limits)
