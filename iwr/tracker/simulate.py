"""Simulated tracker data with a physical tracker noise model."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from ..robot import MIN_SIGMA, Robot
from ..simulate import Noise, sample_poses
from ..transforms import pose_from_matrix, pose_matrix
from .data import TrackerMeasurements
from .setup import TrackerSetup

__all__ = ["TrackerNoise", "axis_whitening", "simulate_tracker", "true_points"]


@dataclass(frozen=True)
class TrackerNoise:
    """One-sigma noise of a laser tracker, in its spherical coordinates (mm, mm per m, rad).

    A measured point is off its true position by a radial error (along the line of sight, the
    distance meter's) of sigma ``distance + distance_per_m * d`` and a transverse error (across
    it, the angle encoders') of sigma ``transverse + transverse_per_m * d`` along each of the two
    directions across the line of sight, ``d`` the distance from the tracker (the origin of {T})
    in metres. Across the line of sight the error grows with the distance and dominates: the
    noise ellipsoid is long across, short along. A probe's orientation gets a small random
    rotation of sigma ``orientation`` (rad) about each axis.

    The defaults, :meth:`leica`, are half the maximum permissible errors (MPE, ISO 10360-10:2021
    Annex D) of Leica's laser tracker subsystem as its user manual states them (Leica Absolute
    Tracker AT500 user manual, section 2.8.2): ADM +-(10 um + 0.3 um/m), transverse +-(15 um +
    6 um/m); the manual says that typical results are half the MPE, read here as one sigma. The
    probe's 0.005 degree is half of the +-0.01 degree commonly quoted for 6-DOF probes.
    """

    distance: float = 0.005
    distance_per_m: float = 0.00015
    transverse: float = 0.0075
    transverse_per_m: float = 0.003
    orientation: float = math.radians(0.005)

    def __post_init__(self) -> None:
        for name in ("distance", "distance_per_m", "transverse", "transverse_per_m",
                     "orientation"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v)
                                           and v >= 0):
                raise ValueError(f"TrackerNoise.{name}: {v!r}; expected a finite number >= 0")
            if 0 < v < MIN_SIGMA:
                raise ValueError(f"TrackerNoise.{name}: {v!r} is below any instrument's noise; "
                                 f"expected 0 (none) or at least {MIN_SIGMA:g}")

    @classmethod
    def leica(cls) -> TrackerNoise:
        """The defaults: half the MPE of Leica's absolute tracker (see the class notes)."""
        return cls()

    @classmethod
    def none(cls) -> TrackerNoise:
        return cls(0.0, 0.0, 0.0, 0.0, 0.0)

    @property
    def is_zero(self) -> bool:
        return not any((self.distance, self.distance_per_m, self.transverse,
                        self.transverse_per_m, self.orientation))

    def sigmas(self, d_mm: Any) -> tuple[np.ndarray, np.ndarray]:
        """(radial, transverse) sigma (mm) at distances ``d_mm`` (mm) from the tracker."""
        d_m = np.asarray(d_mm, dtype=float) / 1000.0
        return (self.distance + self.distance_per_m * d_m,
                self.transverse + self.transverse_per_m * d_m)

    @staticmethod
    def basis(points: Any) -> np.ndarray:
        """Per point (..., 3) of {T}, the orthonormal rows (..., 3, 3) ``[e_r, e_1, e_2]``: the line
        of sight from the tracker (the origin of {T}) and the two directions across it (``e_1``
        perpendicular to ``e_r`` and to the axis least aligned with it): the principal axes of
        the point's noise."""
        p = np.asarray(points, dtype=float)
        d = np.linalg.norm(p, axis=-1, keepdims=True)
        er = p / np.where(d > 0, d, 1.0)
        helper = np.zeros_like(er)
        idx = np.argmin(np.abs(er), axis=-1)
        np.put_along_axis(helper, idx[..., None], 1.0, axis=-1)
        e1 = np.cross(er, helper)
        e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
        e2 = np.cross(er, e1)
        return np.stack([er, e1, e2], axis=-2)

    def whitening(self, points: Any) -> np.ndarray:
        """Per point (..., 3) of {T}, the 3x3 matrix ``W`` (..., 3, 3) with ``W^T W`` the inverse
        of the point's noise covariance (``W @ error`` has unit covariance): the rows of
        :meth:`basis` divided by the radial and transverse sigmas at the point's distance."""
        p = np.asarray(points, dtype=float)
        sr, st = self.sigmas(np.linalg.norm(p, axis=-1))
        if np.any(np.asarray(sr) <= 0) or np.any(np.asarray(st) <= 0):
            raise ValueError("tracker noise: the radial and the transverse sigma must be > 0 "
                             f"(distance {self.distance}, transverse {self.transverse}); a "
                             "tracker reading is never exact")
        scale = np.stack([1.0 / sr, 1.0 / st, 1.0 / st], axis=-1)
        return self.basis(p) * scale[..., :, None]

    def covariance(self, points: Any) -> np.ndarray:
        """Per point (..., 3) of {T}, its noise covariance (..., 3, 3) (mm^2): ``sigma_r^2`` along
        the line of sight, ``sigma_t^2`` across it; the law :meth:`perturb` draws from."""
        p = np.asarray(points, dtype=float)
        b = self.basis(p)
        sr, st = self.sigmas(np.linalg.norm(p, axis=-1))
        var = np.stack([np.square(sr), np.square(st), np.square(st)], axis=-1)
        return np.einsum("...ki,...k,...kj->...ij", b, var, b)

    def perturb(self, points: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Points (..., 3) in {T} with tracker noise; three standard normal draws per point
        (radial, then the two transverse directions of :meth:`basis`)."""
        p = np.asarray(points, dtype=float)
        z = rng.standard_normal(p.shape)
        b = self.basis(p)
        sr, st = self.sigmas(np.linalg.norm(p, axis=-1, keepdims=True))
        return (p + sr * z[..., :1] * b[..., 0, :]
                + st * (z[..., 1:2] * b[..., 1, :] + z[..., 2:3] * b[..., 2, :]))


def axis_whitening(points: Any, sigmas: Any) -> np.ndarray:
    """Per point (..., 3) of {T} with standard uncertainties ``sigmas`` (..., 3) along the x, y
    and z axes of {T} (tracker software's per-point uncertainties), the 3x3 ``W`` (..., 3, 3)
    with ``W^T W`` the inverse of ``diag(sigma_x^2, sigma_y^2, sigma_z^2)`` and its rows along the
    line of sight and across it, as :meth:`TrackerNoise.whitening`: ``W = L^-1 B`` with ``B``
    the rows of :meth:`TrackerNoise.basis` and ``L`` the Cholesky factor of ``B C B^T``, so that
    the first row is the distance's alone (with equal sigmas ``W = B / sigma``, as
    ``TrackerNoise(distance=sigma, transverse=sigma)`` gives)."""
    p = np.asarray(points, dtype=float)
    s = np.asarray(sigmas, dtype=float)
    if s.shape != p.shape or not np.all(np.isfinite(s) & (s > 0)):
        raise ValueError(f"sigmas: shape {s.shape} for points {p.shape}; every sigma finite and "
                         "> 0 expected")
    b = TrackerNoise.basis(p)
    cov = np.einsum("...ki,...i,...li->...kl", b, np.square(s), b)
    return np.linalg.solve(np.linalg.cholesky(cov), b)


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
    if clean.points is not None:
        return TrackerMeasurements(q, legs, points=tracker_noise.perturb(clean.points, rng),
                                   joint_types=clean.joint_types)
    t = pose_matrix(clean.probe)
    t[:, :3, 3] = tracker_noise.perturb(t[:, :3, 3], rng)
    turn = Rotation.from_rotvec(tracker_noise.orientation * rng.standard_normal((len(clean), 3)))
    t[:, :3, :3] = turn.as_matrix() @ t[:, :3, :3]
    return TrackerMeasurements(q, legs, probe=np.array([pose_from_matrix(m) for m in t]),
                               joint_types=clean.joint_types)
