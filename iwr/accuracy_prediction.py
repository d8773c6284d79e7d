"""The tool accuracy that an identification predicts from its parameters' covariance
(:func:`predicted_accuracy`, :class:`PredictedAccuracy`): the pose error covariance ``G C G^T``
by the implicit function theorem at each pose, its RMS and 95th percentile."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .effects import parameter_names as effect_names
from .implicit_loop import _core_rotations, loop_jacobians
from .measurements import Measurements
from .robot import Robot

__all__ = ["PredictedAccuracy", "accuracy_from_covariances", "predicted_accuracy"]


@dataclass(frozen=True)
class PredictedAccuracy:
    """Tool pose error predicted from the covariance of the identified parameters.

    The errors are those of the calibrated model's forward kinematics (exact readings) caused by the
    uncertainty of the identified parameters alone: the figure a validation on fresh poses
    measures against the truth.

    Attributes
    ----------
    position_rms : float
        RMS tool position error over the poses (mm).
    position_95 : float
        95th percentile of the tool position error over the poses and the estimation noise (mm).
    orientation_rms, orientation_95 : float
        The same for the orientation error angle (degrees).
    position_cov : ndarray, shape (N, 3, 3)
        Per pose, covariance of the tool position (mm^2, world frame).
    orientation_cov : ndarray, shape (N, 3, 3)
        Per pose, covariance of the orientation error (rad^2, platform frame).
    """

    position_rms: float
    position_95: float
    orientation_rms: float
    orientation_95: float
    position_cov: np.ndarray
    orientation_cov: np.ndarray

    def __str__(self) -> str:
        return (f"predicted tool error on {len(self.position_cov)} poses: position RMS "
                f"{self.position_rms:.4f} mm (95 %: {self.position_95:.4f} mm), orientation RMS "
                f"{self.orientation_rms:.5f} deg (95 %: {self.orientation_95:.5f} deg)")


def predicted_accuracy(
    robot: Robot,
    measurements: Measurements,
    x: Any,
    covariance: Any,
    *,
    active: Any,
    tool: Any = None,
    n_samples: int = 500,
    seed: int = 0,
) -> PredictedAccuracy:
    """Predicted tool pose error of the calibrated robot at the poses of ``measurements``.

    At each pose the calibrated model's forward kinematics from the joint and leg readings gives
    the platform pose (linearised at the measured pose); by the implicit function theorem, a
    parameter error ``dx`` moves it by
    ``-(d legs / d pose)^-1 (d legs / d x) dx``, so the pose error covariance is
    ``G C G^T`` with ``C`` the covariance of the active parameters.

    Parameters
    ----------
    robot : Robot
    measurements : Measurements
        Poses at which to predict (the joint and leg readings, and the poses as linearisation
        points; with effects, their loads and temperatures).
    x : array_like, shape (n_params,)
        The identified parameters.
    covariance : array_like, shape (n_active, n_active)
        Their covariance (``result.covariance``).
    active : array_like of bool, shape (n_params,)
        The identified parameters (``result.active``).
    tool : array_like, shape (3,), optional
        Tool point in the platform frame {5} (mm); default its origin.
    n_samples : int
        Gaussian draws per pose for the 95th percentiles (the same draws at every pose).
    seed : int
        Seed of those draws.
    """
    x = np.asarray(x, dtype=float)
    mask = np.asarray(active, dtype=bool)
    cov = np.asarray(covariance, dtype=float)
    p = int(mask.sum())
    # With effects (issue 23): x and active also cover the effects' parameters, and the loop
    # closure takes each pose's load and temperature from the measurements.
    n_all = robot.n_params + len(effect_names(robot.effects))
    if mask.shape != (n_all,):
        raise ValueError(f"active: shape {mask.shape}; expected ({n_all},)")
    if cov.shape != (p, p):
        raise ValueError(f"covariance: shape {cov.shape}; expected ({p}, {p}) for {p} active "
                         "parameters")
    t = np.zeros(3) if tool is None else np.asarray(tool, dtype=float).reshape(3)
    # Linearised at the measured poses: the calibrated model's forward kinematics would move them
    # by the calibration residual (micrometres), a relative 1e-6 change of the covariance.
    poses = measurements.poses
    _, jx, jy = loop_jacobians(robot, x, measurements.q, poses, data=measurements)
    nj = robot.n_joints
    jpose = jy[:, :, nj:]  # (N, 6, 6): d legs / d (dp, w)
    g = -np.linalg.solve(jpose, jx[:, :, mask])  # (N, 6, p): d (dp, w) / d x
    r = _core_rotations(poses)
    # Tool point p + R t: d = dp + R (w x t) = dp - R [t]x w.
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    gp = g[:, :3] - np.einsum("kij,jl,klp->kip", r, tx, g[:, 3:])
    go = g[:, 3:]
    cp = np.einsum("kip,pq,kjq->kij", gp, cov, gp)
    co = np.einsum("kip,pq,kjq->kij", go, cov, go)
    return accuracy_from_covariances(cp, co, n_samples=n_samples, seed=seed)


def accuracy_from_covariances(cp: np.ndarray, co: np.ndarray, *, n_samples: int = 500,
                              seed: int = 0) -> PredictedAccuracy:
    """:class:`PredictedAccuracy` from per-pose covariances of the tool position (N, 3, 3; mm^2)
    and orientation (N, 3, 3; rad^2): RMS from their traces, 95th percentiles from ``n_samples``
    Gaussian draws per pose (the same draws at every pose, ``seed``)."""
    rng = np.random.default_rng(seed)
    z = rng.standard_normal((3, n_samples))

    def stats_of(c: np.ndarray) -> tuple[float, float]:
        rms = math.sqrt(float(np.mean(np.trace(c, axis1=1, axis2=2))))
        # Draws of each pose's error vector through its Cholesky-like factor (eigen, so that a
        # singular covariance is fine).
        ev, vec = np.linalg.eigh(c)
        f = vec * np.sqrt(np.clip(ev, 0, None))[:, None, :]
        norms = np.sqrt(np.sum((f @ z) ** 2, axis=1))  # (N, n_samples)
        return rms, float(np.quantile(norms, 0.95))

    prms, p95 = stats_of(cp)
    orms, o95 = stats_of(co)
    return PredictedAccuracy(prms, p95, math.degrees(orms), math.degrees(o95), cp, co)
