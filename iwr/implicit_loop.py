"""The implicit loop model of pose data: the readings of a pose (legs, joints, measured position
and orientation), their standard deviations under a noise model, and the leg readings predicted
at corrected readings with their exact derivatives (``cpp/src/implicit_loop.cpp``). What the
efficient estimator (:mod:`iwr.estimation`), the noise-weighted objective
(:func:`iwr.problem.gls_whitening`) and the tracker's point covariances share."""

from __future__ import annotations

from typing import Any

import numpy as np

from . import _core
from .measurements import Measurements, as_matrix
from .noise import Noise
from .robot import Robot

__all__ = ["loop_jacobians", "reading_names", "sigma_matrix"]


def reading_names(robot: Robot) -> list[str]:
    """Names of the readings of one pose, in the column order of the estimator's residuals:
    ``leg1 .. leg6``, ``q1 .. qn``, ``position.x .. position.z``, ``orientation.x ..
    orientation.z`` (a rotation vector in the platform frame)."""
    return ([f"leg{j + 1}" for j in range(6)] + [f"q{i + 1}" for i in range(robot.n_joints)]
            + [f"position.{c}" for c in "xyz"] + [f"orientation.{c}" for c in "xyz"])


def _component_columns(robot: Robot) -> dict[str, np.ndarray]:
    nj = robot.n_joints
    prism = np.array([c == "P" for c in robot.joint_types], dtype=bool)
    return {
        "legs": np.arange(6),
        "joint_lengths": 6 + np.flatnonzero(prism),
        "joint_angles": 6 + np.flatnonzero(~prism),
        "position": np.arange(6 + nj, 9 + nj),
        "orientation": np.arange(9 + nj, 12 + nj),
    }


def sigma_matrix(robot: Robot, measurements: Measurements, noise: Noise) -> np.ndarray:
    """Standard deviation of every reading, shape (N, 12 + n_joints), columns as
    :func:`reading_names`. Leg weights of the measurements (if any) scale the leg sigma by
    ``1 / sqrt(w)``, so relative weights act as inverse relative variances."""
    if not isinstance(noise, Noise):
        raise TypeError(f"noise: expected an iwr.Noise, got {type(noise).__name__}")
    n = len(measurements)
    s = np.zeros((n, 12 + robot.n_joints))
    for name, cols in _component_columns(robot).items():
        s[:, cols] = getattr(noise, name)
    if measurements.weights is not None:
        w = measurements.weights
        if np.any(w <= 0):
            r, c = (int(i) for i in np.argwhere(w <= 0)[0])
            raise ValueError(
                f"weights: row {r}, column {c} is {w[r, c]}; the efficient estimator reads a "
                "weight as an inverse relative variance and needs it > 0 (drop the pose instead)"
            )
        s[:, :6] = s[:, :6] / np.sqrt(w)
    return s


def loop_jacobians(
    robot: Robot, x: Any, q: Any, poses: Any, corrections: Any = None, *, data: Any = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Predicted leg readings at corrected readings and their exact derivatives.

    The joint readings are ``q + dq`` and the platform pose ``(p + dp, R(pose) exp([w]x))`` (the
    rotation vector ``w`` in the platform frame, as :func:`iwr.simulate` applies orientation
    noise), with ``corrections`` rows ``(dq, dp, w)`` (default zeros).

    A robot with effects (docs/effects.md): ``x`` holds the geometric errors then the effects'
    parameters, ``data`` (the :class:`iwr.Measurements`, or any object with their ``payload``
    and ``temperatures``) gives each pose's load and temperature, and the predicted readings are
    the geometry's minus the effects' change of each leg (:func:`iwr.effects.loop.loop_jacobians`).

    Returns
    -------
    legs : ndarray, shape (N, 6)
    d_x : ndarray, shape (N, 6, n_params)
        Derivatives with respect to the error parameters (and the effects' parameters).
    d_corrections : ndarray, shape (N, 6, n_joints + 6)
        Derivatives with respect to ``(dq, dp, w)``.
    """
    poses = as_matrix(poses, 6, "poses")
    n = poses.shape[0]
    q = as_matrix(q, robot.n_joints, "q", rows=n)
    if robot.effects:  # issue 23: the effects' change of the legs on top of the geometry
        return _effect_loop_jacobians(robot, x, q, poses, corrections, data)
    x = np.ascontiguousarray(x, dtype=float)
    if x.shape != (robot.n_params,):
        raise ValueError(f"x: shape {x.shape}; expected ({robot.n_params},)")
    corr = (np.zeros((0, 0)) if corrections is None
            else as_matrix(corrections, robot.n_joints + 6, "corrections", rows=n))
    legs, jx, jy = _core.loop_jacobians(robot._geometry, x, q, poses, corr)
    return legs, jx.reshape(n, 6, -1), jy.reshape(n, 6, -1)


def _effect_loop_jacobians(robot: Robot, x: Any, q: np.ndarray, poses: np.ndarray,
                           corrections: Any, data: Any) -> tuple[np.ndarray, np.ndarray,
                                                                 np.ndarray]:
    from .effects import parameter_names
    from .effects.loop import loop_jacobians as effect_loop

    if data is None:
        names = ", ".join(e.name for e in robot.effects)
        raise ValueError(f"data: robot {robot.name!r} has effects on ({names}); give the "
                         "poses' loads and temperatures (data=the iwr.Measurements)")
    n_all = robot.n_params + len(parameter_names(robot.effects))
    x = np.ascontiguousarray(x, dtype=float)
    if x.shape != (n_all,):
        raise ValueError(f"x: shape {x.shape}; expected ({n_all},): {robot.n_params} geometric "
                         "errors, then " + ", ".join(parameter_names(robot.effects)))
    corr = (None if corrections is None
            else as_matrix(corrections, robot.n_joints + 6, "corrections", rows=len(poses)))
    return effect_loop(robot, x, q, poses, data, corr)


def _core_rotations(poses: np.ndarray) -> np.ndarray:
    from .transforms import euler_zyx

    return euler_zyx(poses[:, 3], poses[:, 4], poses[:, 5])


def _check_noise(noise: Noise) -> None:
    if noise.legs <= 0:
        if noise.is_zero:
            raise ValueError(
                "noise: every standard deviation is 0; the efficient estimator weighs each "
                "instrument by its noise: give the instruments' noise (e.g. iwr.Noise.realistic()"
                ", or noise='estimate'), or use eq. (10), iwr.identify(method='lm')"
            )
        raise ValueError(
            "noise.legs: 0; the leg readings close the loop and need a standard deviation > 0 (at "
            "least their resolution, e.g. 0.001 mm)"
        )
