"""Simulated calibration data: an 'actual' robot (nominal + errors), reachable poses, noise."""

from __future__ import annotations

from typing import Any

import numpy as np

from . import kinds
from .measurements import Measurements
from .noise import Noise
from .problem import predict_legs
from .robot import Robot
from .transforms import euler_zyx, pose_from_matrix, pose_matrix, rotvec_matrix

__all__ = ["Noise", "simulate", "sample_poses", "UnreachableError"]


class UnreachableError(RuntimeError):
    """Too few reachable poses were found in the robot's workspace."""


def sample_poses(
    robot: Robot,
    n_poses: int,
    rng: np.random.Generator,
    x: Any = None,
    max_tries: int = 200,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random reachable measurement poses of the robot with error vector ``x`` (default: nominal).

    Joint readings are uniform within the joint limits; the platform pose relative to frame {4}
    is uniform within ``robot.workspace`` around ``robot.home_pose``. A pose is kept only when
    every leg reading is within the stroke.

    Returns ``(q, poses, legs)``: joint readings (N, n_joints), world poses (N, 6), exact leg
    readings (N, 6).
    """
    x = np.zeros(robot.n_params) if x is None else np.asarray(x, dtype=float)
    qs, ps, ls = [], [], []
    have, tries = 0, 0
    batch = max(16, 2 * n_poses)
    while have < n_poses:
        tries += 1
        if tries > max_tries:
            raise UnreachableError(
                f"only {have} of {n_poses} random poses were reachable after {tries - 1} batches "
                f"of {batch}: check joint_limits, leg_stroke, home_pose and workspace"
            )
        lo, hi = robot.joint_limits[:, 0], robot.joint_limits[:, 1]
        q = lo + (hi - lo) * rng.random((batch, robot.n_joints))
        local = robot.home_pose + robot.workspace * (2.0 * rng.random((batch, 6)) - 1.0)
        t4 = np.array([robot.carriage_transform(qk, x) for qk in q])
        poses = pose_from_matrix(t4 @ pose_matrix(local))
        legs = predict_legs(robot, x, q, poses)
        ok = np.all((legs >= robot.leg_stroke[:, 0]) & (legs <= robot.leg_stroke[:, 1]), axis=1)
        take = np.flatnonzero(ok)[: n_poses - have]
        qs.append(q[take])
        ps.append(poses[take])
        ls.append(legs[take])
        have += take.size
    return np.vstack(qs), np.vstack(ps), np.vstack(ls)


def simulate(
    robot: Robot,
    n_poses: int,
    *,
    seed: int | None,
    x: Any = None,
    noise: Noise | None = None,
) -> tuple[Measurements, np.ndarray]:
    """Simulate a calibration experiment (the paper's section 4, with optional noise).

    Parameters
    ----------
    robot : Robot
        The nominal robot.
    n_poses : int
        Number of measurement poses N.
    seed : int or None
        Seed of the random generator; the same seed gives the same data (None: a fresh one).
    x : array_like, optional
        The 'actual' robot's error vector. Default: uniform within the default bounds
        (+-0.5 mm, +-0.5 degree).
    noise : Noise, optional
        Measurement noise; default none (the paper's simulation). For a robot with a tracker
        (``Robot.with_tracker``): None, an ``iwr.Noise`` (readings), an
        ``iwr.tracker.TrackerNoise`` or a pair of both; the data are then
        :class:`iwr.tracker.TrackerMeasurements` and ``x_true`` covers the setup's parameters
        too (docs/tracker.md).

    Returns
    -------
    measurements : Measurements
        Joint readings, measured poses and leg readings of the actual robot, with noise.
    x_true : ndarray, shape (n_params,)
        The actual robot's error vector.
    """
    if not isinstance(robot, Robot):
        raise TypeError(f"robot: expected an iwr.Robot, got {type(robot).__name__}")
    # The kind of data the robot's description measures (a [tracker] table: points or probe
    # poses in {T}, docs/tracker.md) simulates them.
    return kinds.for_robot(robot).simulate(robot, n_poses, seed=seed, x=x, noise=noise)


def simulate_poses(robot: Robot, n_poses: int, *, seed: int | None, x: Any = None,
                   noise: Noise | None = None) -> tuple[Measurements, np.ndarray]:
    """:func:`simulate` for pose data (the paper's): the platform pose measured in {0}."""
    if isinstance(n_poses, bool) or not isinstance(n_poses, (int, np.integer)) or n_poses < 1:
        raise ValueError(f"n_poses: {n_poses!r}; expected a positive integer")
    noise = noise if noise is not None else Noise()
    if not isinstance(noise, Noise):
        raise TypeError(f"noise: expected an iwr.Noise, got {type(noise).__name__}")
    rng = np.random.default_rng(seed)
    lower, upper = robot.default_bounds()
    if x is None:
        x = lower + (upper - lower) * rng.random(robot.n_params)
    else:
        x = np.array(x, dtype=float)
        if x.shape != (robot.n_params,) or not np.all(np.isfinite(x)):
            raise ValueError(
                f"x: expected {robot.n_params} finite values, got shape {x.shape}"
            )
    q, poses, legs = sample_poses(robot, int(n_poses), rng, x)
    return add_noise(robot, q, poses, legs, noise, rng), x


def add_noise(robot: Robot, q: np.ndarray, poses: np.ndarray, legs: np.ndarray, noise: Noise,
              rng: np.random.Generator) -> Measurements:
    """Exact readings made noisy, as measured: Gaussian joint readings (``joint_lengths`` for
    prismatic joints, ``joint_angles`` for revolute ones) and leg readings; the measured
    orientation is the true one times a small random rotation (rotation vector with Gaussian
    components of ``orientation``), the measured position the true one plus Gaussian noise of
    ``position``. Draws from ``rng`` in that order; no draws when the noise is zero."""
    n = len(poses)
    if not noise.is_zero:
        sigma_q = np.where(np.array([c == "P" for c in robot.joint_types], dtype=bool),
                           noise.joint_lengths, noise.joint_angles)
        q = q + sigma_q * rng.standard_normal(q.shape)
        legs = legs + noise.legs * rng.standard_normal(legs.shape)
        r = euler_zyx(poses[:, 3], poses[:, 4], poses[:, 5])
        r = r @ rotvec_matrix(noise.orientation * rng.standard_normal((n, 3)))
        t = pose_matrix(poses)
        t[:, :3, :3] = r
        t[:, :3, 3] += noise.position * rng.standard_normal((n, 3))
        poses = pose_from_matrix(t)
    return Measurements(q, poses, legs, joint_types=robot.joint_types)
