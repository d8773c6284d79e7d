"""Simulated tracker data with a physical tracker noise model."""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from ..noise import Noise, TrackerNoise, axis_whitening
from ..robot import Robot
from ..simulation import sample_poses
from ..transforms import pose_from_matrix, pose_matrix
from .data import TrackerMeasurements
from .setup import TrackerSetup

__all__ = ["TrackerNoise", "axis_whitening", "simulate_tracker", "true_points"]


def true_points(robot: Robot, setup: TrackerSetup, x: Any, poses: Any) -> np.ndarray:
    """The points the setup measures, in {T}, shape (N, n_points, 3), for world poses of {5}
    (N, 6) and the full parameter vector ``x`` (robot then setup): ``T_T0 0T5 r_i``. Written in
    NumPy, independently of the C++ objective, so the two check each other."""
    x = np.asarray(x, dtype=float)
    xs = x[robot.n_params:]
    t = setup.registration_matrix(xs) @ pose_matrix(np.asarray(poses, dtype=float))
    local = setup.platform_points(xs)
    return np.einsum("nij,pj->npi", t[:, :3, :3], local) + t[:, None, :3, 3]


def simulate_tracker(
    robot: Robot,
    setup: TrackerSetup,
    n_poses: int = 100,
    *,
    seed: int | None = 0,
    x: Any = None,
    noise: Noise | None = None,
    tracker_noise: TrackerNoise | None = None,
    hidden: float = 0.0,
) -> tuple[TrackerMeasurements, np.ndarray]:
    """Simulate a calibration with a laser tracker.

    Parameters
    ----------
    robot, setup : the nominal robot and measurement setup.
    n_poses : int
    seed : int
        The same seed gives the same data.
    x : array_like, shape (robot.n_params + setup.n_params,), optional
        The truth: robot errors, then the setup's parameters. Default: uniform within the robot's
        default bounds (as :func:`iwr.simulate`) and the setup's
        (:meth:`TrackerSetup.default_bounds`).
    noise : iwr.Noise, optional
        Leg and joint reading noise (``legs``, ``joint_lengths``, ``joint_angles``); its
        ``position`` and ``orientation`` (a pose measured in {0}) must be zero here: the tracker's
        noise is ``tracker_noise``.
    tracker_noise : TrackerNoise, optional
        Default none (noise-free); :meth:`TrackerNoise.leica` for a real tracker.
    hidden : float in [0, 1]
        Fraction of poses at which one reflector (drawn at random) is not seen.

    Returns
    -------
    (TrackerMeasurements, x_true)

    Notes
    -----
    Draws from one generator in this order: x (when not given), the poses (as
    :func:`iwr.simulate`), the hidden reflectors, the reading noise, the tracker noise.
    """
    if not isinstance(robot, Robot):
        raise TypeError(f"robot: expected an iwr.Robot, got {type(robot).__name__}")
    if not isinstance(setup, TrackerSetup):
        raise TypeError(f"setup: expected a TrackerSetup, got {type(setup).__name__}")
    if isinstance(n_poses, bool) or not isinstance(n_poses, (int, np.integer)) or n_poses < 1:
        raise ValueError(f"n_poses: {n_poses!r}; expected a positive integer")
    noise = Noise() if noise is None else noise
    if not isinstance(noise, Noise):
        raise TypeError(f"noise: expected an iwr.Noise, got {type(noise).__name__}")
    if noise.position or noise.orientation:
        raise ValueError("noise: position and orientation are the noise of a pose measured in "
                         "{0}; for tracker data give tracker_noise=TrackerNoise(...) instead")
    tnoise = TrackerNoise.none() if tracker_noise is None else tracker_noise
    if not isinstance(tnoise, TrackerNoise):
        raise TypeError(f"tracker_noise: expected a TrackerNoise, got {type(tnoise).__name__}")
    if isinstance(hidden, bool) or not (isinstance(hidden, (int, float)) and 0 <= hidden <= 1):
        raise ValueError(f"hidden: {hidden!r}; expected a fraction in [0, 1]")
    if hidden and setup.kind == "probe":
        raise ValueError("hidden: a probe pose is measured whole or not at all; simulate fewer "
                         "poses instead of hiding some")
    rng = np.random.default_rng(seed)
    n_all = robot.n_params + setup.n_params
    if x is None:
        lo_r, hi_r = robot.default_bounds()
        xr = lo_r + (hi_r - lo_r) * rng.random(robot.n_params)
        lo_s, hi_s = setup.default_bounds()
        x_true = np.concatenate([xr, lo_s + (hi_s - lo_s) * rng.random(setup.n_params)])
    else:
        x_true = np.array(x, dtype=float)
        if x_true.shape != (n_all,) or not np.all(np.isfinite(x_true)):
            raise ValueError(f"x: expected {n_all} finite values (the robot's {robot.n_params} "
                             f"then the setup's {setup.n_params}), got shape {x_true.shape}")
    n = int(n_poses)
    q, poses, legs = sample_poses(robot, n, rng, x_true[: robot.n_params])
    pts = true_points(robot, setup, x_true, poses)
    hide = rng.random(n) < hidden
    which = rng.integers(0, setup.n_points, size=n)
    if not noise.is_zero:
        sigma_q = np.where(np.array([c == "P" for c in robot.joint_types], dtype=bool),
                           noise.joint_lengths, noise.joint_angles)
        q = q + sigma_q * rng.standard_normal(q.shape)
        legs = legs + noise.legs * rng.standard_normal(legs.shape)
    if setup.kind == "points":
        if not tnoise.is_zero:
            pts = tnoise.perturb(pts, rng)
        pts[hide, which[hide]] = np.nan
        return TrackerMeasurements(q, legs, points=pts, joint_types=robot.joint_types), x_true
    # Probe: the probe frame's pose in {T}, its origin with the point noise, its orientation
    # turned by a small random rotation.
    origin, axes = pts[:, 0], (pts[:, 1:] - pts[:, :1]) / setup.probe_length
    rot = np.swapaxes(axes, 1, 2)  # columns: the probe's axes in {T}
    if not tnoise.is_zero:
        origin = tnoise.perturb(origin, rng)
        turn = Rotation.from_rotvec(tnoise.orientation * rng.standard_normal((n, 3)))
        rot = turn.as_matrix() @ rot
    mats = np.tile(np.eye(4), (n, 1, 1))
    mats[:, :3, :3], mats[:, :3, 3] = rot, origin
    probe = np.array([pose_from_matrix(m) for m in mats])
    return TrackerMeasurements(q, legs, probe=probe, joint_types=robot.joint_types), x_true


def perturb_measurements(robot: Robot, clean: TrackerMeasurements, noise: Noise,
                         tracker_noise: TrackerNoise,
                         rng: np.random.Generator) -> TrackerMeasurements:
    """The same poses with fresh noise (a Monte-Carlo over the noise alone): the joint and leg
    readings with ``noise`` (as :func:`simulate_tracker` draws them), the points (or the probe's
    origin) with ``tracker_noise`` and the probe's orientation turned by a small random rotation
    of ``tracker_noise.orientation`` rad per axis. Points not seen stay not seen."""
    sigma_q = np.where([c == "P" for c in robot.joint_types], noise.joint_lengths,
                       noise.joint_angles)
    q = clean.q + sigma_q * rng.standard_normal(clean.q.shape)
    legs = clean.legs + noise.legs * rng.standard_normal(clean.legs.shape)
    loads = {"payload": clean.payload, "temperatures": clean.temperatures}  # issue 23: kept
    if clean.points is not None:
        return TrackerMeasurements(q, legs, points=tracker_noise.perturb(clean.points, rng),
                                   joint_types=clean.joint_types, **loads)
    t = pose_matrix(clean.probe)
    t[:, :3, 3] = tracker_noise.perturb(t[:, :3, 3], rng)
    turn = Rotation.from_rotvec(tracker_noise.orientation * rng.standard_normal((len(clean), 3)))
    t[:, :3, :3] = turn.as_matrix() @ t[:, :3, :3]
    return TrackerMeasurements(q, legs, probe=np.array([pose_from_matrix(m) for m in t]),
                               joint_types=clean.joint_types, **loads)
