"""A closed-form first guess of the registration {0} -> {T}: Kabsch (Horn) between the nominal
forward kinematics of the readings and the measured points."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import _core
from ..robot import Robot
from ..transforms import pose_from_matrix
from .data import TrackerMeasurements
from .setup import TrackerSetup

__all__ = ["RegistrationGuess", "RegistrationError", "guess_registration", "kabsch"]

#: Default largest RMS (mm) of the rigid fit accepted by guess_registration.
MAX_RMS_MM = 20.0


class RegistrationError(ValueError):
    """The registration guess is impossible (too few or collinear points) or its rigid fit is
    too poor to start from (RMS above ``max_rms``)."""


@dataclass(frozen=True)
class RegistrationGuess:
    """The registration that best maps the nominal model's points onto the measured ones.

    Attributes
    ----------
    matrix : ndarray, shape (4, 4)
        ``T_T0``: a point ``p`` in {0} is at ``matrix @ [p, 1]`` in {T}.
    registration : ndarray, shape (6,)
        The same as a pose ``(x, y, z, alpha, beta, gamma)``, for :class:`TrackerSetup`.
    x_setup : ndarray, shape (setup.n_params,)
        The setup's parameters that give this registration from the setup's nominal one (zero
        offsets): the starting point of an identification, and a centre for its bounds.
    rms, max : float
        RMS and largest distance (mm) between the fitted and the measured points: what the
        rigid fit cannot explain (the nominal model's errors, the offsets' errors, noise).
    n_points : int
        Points used (seen points of poses whose forward kinematics converged).
    """

    matrix: np.ndarray
    registration: np.ndarray
    x_setup: np.ndarray
    rms: float
    max: float
    n_points: int

    def __str__(self) -> str:
        r = self.registration
        return (f"registration guess from {self.n_points} points: ({r[0]:.3f}, {r[1]:.3f}, "
                f"{r[2]:.3f}) mm, ({math.degrees(r[3]):.4f}, {math.degrees(r[4]):.4f}, "
                f"{math.degrees(r[5]):.4f}) deg; fit RMS {self.rms:.4g} mm, max {self.max:.4g} mm")


def kabsch(a: Any, b: Any) -> tuple[np.ndarray, np.ndarray]:
    """The rotation ``R`` and translation ``t`` minimising ``sum |R a_i + t - b_i|^2`` (Kabsch;
    Horn's closed form), for points ``a``, ``b`` of shape (M, 3); a proper rotation (det +1) even
    when the best orthogonal matrix would be a reflection."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    h = (a - ca).T @ (b - cb)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, cb - r @ ca


def guess_registration(robot: Robot, setup: TrackerSetup, measurements: TrackerMeasurements,
                       x: Any = None, *, max_rms: float = MAX_RMS_MM) -> RegistrationGuess:
    """Closed-form first guess of the registration ``T_T0``, so a user need not know it.

    The platform poses come from forward kinematics of the joint and leg readings with the robot
    error vector ``x`` (default zeros: the nominal robot); the points at the setup's nominal
    offsets are carried into {0}, and the rigid transform that best maps them onto the measured
    points in {T} is found by Kabsch's SVD, with the reflection fix.

    Raises
    ------
    RegistrationError
        Fewer than 3 points, or all on a line (no rotation is determined); or the fit's RMS is
        above ``max_rms`` (mm, default 20): the nominal model (the robot, the reflector offsets,
        or which reflector is which) is then too far from the data for the guess to be a
        starting point, and the message says so with the RMS and the worst pose.
    """
    measurements.check_setup(setup)
    xr = np.zeros(robot.n_params) if x is None else np.ascontiguousarray(x, dtype=float)
    if xr.shape != (robot.n_params,):
        raise ValueError(f"x: shape {xr.shape}; expected ({robot.n_params},) (the robot's errors)")
    if isinstance(max_rms, bool) or not (isinstance(max_rms, (int, float)) and max_rms > 0):
        raise ValueError(f"max_rms: {max_rms!r}; expected a length > 0 (mm)")
    n = len(measurements)
    poses = np.full((n, 6), np.nan)
    # Pose by pose, so that a pose whose forward kinematics fails is left out, not fatal.
    for k in range(n):
        try:
            poses[k] = _core.forward_kinematics(
                robot._geometry, xr, measurements.q[k:k + 1], measurements.legs[k:k + 1],
                np.zeros((0, 6)), robot.home_pose)[0][0]
        except _core.ForwardKinematicsError:
            pass
    from ..transforms import pose_matrix

    t5 = pose_matrix(poses)  # NaN for failed poses
    local = setup.platform_points()  # (P, 3) in {5}
    world = t5[:, None, :3, :3] @ local[None, :, :, None]
    world = world[..., 0] + t5[:, None, :3, 3]  # (N, P, 3)
    measured = measurements.tracker_points(setup).reshape(n, -1, 3)
    ok = ~np.isnan(measured[:, :, 0]) & ~np.isnan(world[:, :, 0])
    a, b = world[ok], measured[ok]
    if a.shape[0] < 3:
        raise RegistrationError(f"registration guess: {a.shape[0]} usable points; at least 3 "
                                "non-collinear points are needed")
    s = np.linalg.svd(a - a.mean(axis=0), compute_uv=False)
    if s[1] <= 1e-9 * max(s[0], 1e-300):
        raise RegistrationError("registration guess: every point lies on one line, so the "
                                "rotation about it is undetermined")
    r, t = kabsch(a, b)
    dist = np.linalg.norm(a @ r.T + t - b, axis=1)
    rms = float(math.sqrt(np.mean(dist**2)))
    mat = np.eye(4)
    mat[:3, :3], mat[:3, 3] = r, t
    if rms > max_rms:
        pose_of = np.nonzero(ok)[0]
        worst = int(pose_of[int(np.argmax(dist))])
        raise RegistrationError(
            f"registration guess: the best rigid fit of the nominal model's {a.shape[0]} points "
            f"to the measured ones leaves an RMS of {rms:.4g} mm (largest {dist.max():.4g} mm, "
            f"at {measurements.where(worst)}) > max_rms = {max_rms:g} mm: the nominal robot, "
            "the reflector offsets or the pairing of reflectors is too far from the data "
            "(check units, reflector order and the robot description), or raise max_rms")
    reg = pose_from_matrix(mat)
    x_setup = np.zeros(setup.n_params)
    x_setup[:6] = setup.correction_for(mat)
    return RegistrationGuess(matrix=mat, registration=reg, x_setup=x_setup, rms=rms,
                             max=float(dist.max()), n_points=int(a.shape[0]))
