"""What tracker data determine: the tool pose error modulo the gauge the data cannot see, and the
null directions of the tracker problem."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..analysis.accuracy import PoseErrors
from ..robot import Robot
from ..transforms import pose_from_matrix, pose_matrix, rotation_angle
from .gauge import NullSpace, _align, _fk, null_space
from .registration import kabsch
from .setup import TrackerSetup

__all__ = ["tool_frames", "tool_pose_errors", "NullSpace", "null_space", "fix_platform_frame",
           "calibrated_robot"]


def tool_frames(robot: Robot, setup: TrackerSetup, x: Any, q: Any, legs: Any,
                gauge: bool = True) -> np.ndarray:
    """4x4 transforms (N, 4, 4) of the platform, by forward kinematics of the readings ``q``,
    ``legs`` with the full parameter vector ``x`` (robot then setup).

    ``gauge=True`` (default): the platform frame as its six spherical joints fix it (the frame
    in which the joints ``b_j(x)`` best match their nominal positions, by Kabsch), expressed in
    the tracker frame {T}. Tracker data cannot tell {0} from a frame turned about and moved along
    the first joint's axis, nor {5} from a frame rigidly moved on the platform (the registration
    and the offsets absorb both: docs/tracker.md), so only this frame's pose is determined and
    comparable between two parameter vectors. ``gauge=False``: {5} in {0}, as
    :func:`iwr.forward_kinematics` gives it (gauge dependent for tracker data)."""
    x = np.asarray(x, dtype=float)
    nr = robot.n_params
    poses = _fk(robot, x[:nr], np.asarray(q, dtype=float), np.asarray(legs, dtype=float))
    t = pose_matrix(poses)
    if not gauge:
        return t
    n = robot.n_joints
    b = robot.platform_joints + x[4 * n + 18: 4 * n + 36].reshape(6, 3)
    r, c = kabsch(robot.platform_joints, b)
    k = np.eye(4)
    k[:3, :3], k[:3, 3] = r, c
    return setup.registration_matrix(x[nr:]) @ t @ k


def fix_platform_frame(robot: Robot, setup: TrackerSetup, x: Any) -> tuple[np.ndarray, str]:
    """The parameter vector equivalent to ``x`` (robot then setup: the same leg lengths, points
    and residuals) whose platform frame {5} is the one the measured points fix, and its name.

    Tracker data do not fix {5} on the platform (a rigid motion of the joints ``b_j`` and the
    reflectors together changes nothing measured: 6 null directions, docs/tracker.md), so an
    identified {5} is one arbitrary choice. Moving it to a frame defined by what the tracker
    measures makes a pose of {5} in {T} mean what a user measures:

    - ``"reflectors"``: the frame in which the calibrated reflectors best fit their nominal
      positions (least squares, Kabsch): the platform pose a user computes from measured
      reflectors and their nominal coordinates (3 or more reflectors not on one line);
    - ``"probe"``: the frame in which the calibrated probe sits at its nominal pose;
    - ``"joints"``: with fewer than 3 reflectors (or all on one line), which fix no frame, the
      frame in which the spherical joints best fit their nominal positions.
    """
    x, kind, _ = _moved_platform_frame(robot, setup, x)
    return x, kind


def _moved_platform_frame(robot: Robot, setup: TrackerSetup, x: Any
                          ) -> tuple[np.ndarray, str, np.ndarray]:
    """:func:`fix_platform_frame`, and the move (4, 4): a point of the old {5} at ``c`` is at
    ``move[:3, :3] @ c + move[:3, 3]`` in the new one."""
    x = np.array(x, dtype=float, copy=True)
    nr, n = robot.n_params, robot.n_joints
    joints = slice(4 * n + 18, 4 * n + 36)
    b = robot.platform_joints + x[joints].reshape(6, 3)
    xs = x[nr:]
    g = np.eye(4)
    if setup.kind == "probe":
        assert setup.probe is not None
        calibrated = pose_matrix(setup.with_parameters(xs).probe)
        g = pose_matrix(setup.probe) @ np.linalg.inv(calibrated)
        kind = "probe"
    else:
        assert setup.reflectors is not None
        nominal = setup.reflectors
        s = np.linalg.svd(nominal - nominal.mean(axis=0), compute_uv=False)
        if len(nominal) >= 3 and s[1] > 1e-6 * s[0]:
            g[:3, :3], g[:3, 3] = kabsch(setup.platform_points(xs), nominal)
            kind = "reflectors"
        else:
            g[:3, :3], g[:3, 3] = kabsch(b, robot.platform_joints)
            kind = "joints"
    rot, shift = g[:3, :3], g[:3, 3]
    x[joints] = (b @ rot.T + shift - robot.platform_joints).ravel()
    if setup.kind == "probe":
        x[nr + 6:nr + 12] = 0.0  # the probe at its nominal pose in the new frame
    else:
        x[nr + 6:] = (setup.platform_points(xs) @ rot.T + shift - setup.reflectors).ravel()
    return x, kind, g


def calibrated_robot(robot: Robot, x: Any) -> tuple[Robot, str]:
    """The calibrated robot of ``x`` (the robot's errors, its effects' parameters if it has
    effects, then the tracker setup's), as ``calibrated.toml`` holds it, and the name of its
    platform frame: {5} moved to the frame the measured points fix (:func:`fix_platform_frame`),
    and what each effect holds in {5} (the platform's centre of mass) moved with it
    (:meth:`iwr.effects.Effect.in_platform_frame`), so that the written robot predicts what
    ``x`` predicts. The loads' centres of the data (``payload_*`` columns) are in the frame the
    robot file's {5} is: with the calibrated robot, in the new one (a centre ``c`` given in the
    frame ``x`` was identified in is at ``R c + t`` there, ``(R, t)`` the move)."""
    from ..effects import parameter_names as effect_names

    setup = robot.tracker
    assert setup is not None
    x = np.asarray(x, dtype=float)
    nr, ne = robot.n_params, len(effect_names(robot.effects))
    xf, kind, g = _moved_platform_frame(robot, setup, np.concatenate([x[:nr], x[nr + ne:]]))
    out = robot.with_errors(xf[:nr]).with_tracker(setup=setup.with_parameters(xf[nr:]))
    if robot.effects:
        effects, k = [], nr
        for e in robot.effects:
            m = len(e.parameter_names())
            e = e.with_values(e.values() + x[k: k + m]) if m else e
            effects.append(e.in_platform_frame(g[:3, :3], g[:3, 3]))
            k += m
        out = out.with_effects(*effects)
    return out, kind


def tool_pose_errors(robot: Robot, setup: TrackerSetup, x: Any, truth: Any, q: Any, legs: Any,
                     *, tool: Any = None, gauge: str | None = "fit") -> PoseErrors:
    """Tool pose errors (position mm, orientation degrees) of the model ``x`` against ``truth``
    at readings ``q``, ``legs`` (fresh poses of the true robot), in the tracker frame {T}.

    Tracker data determine the platform frame {5} only up to a rigid motion on the platform
    (docs/tracker.md), so the platform frames of the two models are compared modulo that gauge:

    - ``"fit"`` (default): the model's frame is moved on its platform by the one rigid transform
      that best aligns it with the truth's over these poses (the chordal mean of the pose-wise
      differences): what is left is the error no choice of tool frame removes;
    - ``"joints"``: each model's frame as its six spherical joints fix it (:func:`tool_frames`);
      exact for noise-free data, but the identified joints' own scatter then tilts it;
    - ``None``: {5} in {0} as forward kinematics gives it, with no gauge removed (and no
      registration: the registration's gauge stays in), for comparison.

    ``tool``: a tool point in the compared frame (mm). ``poses`` of the result are the model's
    compared frames as poses ({T}, or {0} for ``gauge=None``)."""
    if gauge not in ("fit", "joints", None):
        raise ValueError(f"gauge: {gauge!r}; expected 'fit', 'joints' or None")
    a = tool_frames(robot, setup, x, q, legs, gauge is not None)
    b = tool_frames(robot, setup, truth, q, legs, gauge is not None)
    if gauge == "fit":
        a = a @ _align(a, b)
    p = np.zeros(3) if tool is None else np.asarray(tool, dtype=float).reshape(3)
    position = np.linalg.norm((a[:, :3, :3] - b[:, :3, :3]) @ p + a[:, :3, 3] - b[:, :3, 3], axis=1)
    angle = np.degrees(rotation_angle(np.swapaxes(a[:, :3, :3], 1, 2) @ b[:, :3, :3]))
    return PoseErrors(position, angle, np.array([pose_from_matrix(m) for m in a]))


def rms(values: Any) -> float:
    v = np.asarray(values, dtype=float)
    return float(math.sqrt(np.mean(v**2))) if v.size else 0.0
