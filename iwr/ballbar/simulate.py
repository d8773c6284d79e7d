"""Simulated double-ballbar data, and the bar's noise."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..noise import check_sigmas, split_instrument_noise
from ..robot import Robot
from ..simulation import Noise, UnreachableError, sample_poses
from ..transforms import pose_matrix
from .data import BallbarMeasurements
from .setup import BallbarSetup

__all__ = ["BallbarNoise", "sample_setup_poses", "simulate_ballbar", "true_distances",
           "split_noise"]


@dataclass(frozen=True)
class BallbarNoise:
    """One-sigma noise of a bar reading (mm): ``distance``. The default, 1 um, is the order of
    a telescoping ballbar's displacement sensor (e.g. Renishaw's QC20-W states +-(0.7 um +
    0.3 % of the displacement) of accuracy, and 0.1 um of resolution)."""

    distance: float = 0.001

    def __post_init__(self) -> None:
        check_sigmas(self)

    @property
    def is_zero(self) -> bool:
        return not self.distance


def split_noise(noise: Any) -> tuple[Noise | None, BallbarNoise | None]:
    """``noise`` for ballbar data: None, an :class:`iwr.Noise` (the leg and joint readings'; its
    ``position`` and ``orientation``, a pose measured in {0}, must be 0), a
    :class:`BallbarNoise`, or a pair ``(Noise, BallbarNoise)``."""
    return split_instrument_noise(noise, BallbarNoise, "ballbar data",
                                  "iwr.ballbar.BallbarNoise(distance=...)")


def true_distances(setup: BallbarSetup, x_setup: Any, bar: np.ndarray,
                   poses: np.ndarray) -> np.ndarray:
    """Centre distances plus length offsets for world poses of {5} (N, 6) in set-ups ``bar``
    (indices): ``|0T5 P_s - F_s| + o_s``, in NumPy from the poses (no forward kinematics), so
    that the simulation and :class:`BallbarProblem` check each other."""
    p, f, o = setup.split(x_setup)
    t = pose_matrix(np.asarray(poses, dtype=float))
    ball = np.einsum("nij,nj->ni", t[:, :3, :3], p[bar]) + t[:, :3, 3]
    return np.linalg.norm(ball - f[bar], axis=1) + o[bar]


def simulate_ballbar(robot: Robot, setup: BallbarSetup, n_poses: int = 100, *,
                     seed: int | None = 0, x: Any = None, noise: Any = None,
                     max_batches: int = 200) -> tuple[BallbarMeasurements, np.ndarray]:
    """Simulate a double-ballbar calibration: ``(BallbarMeasurements, x_true)``.

    The poses are shared out among the set-ups in order (the first ``n_poses % S`` set-ups get
    one more); each set-up's poses are the robot's random reachable poses
    (:func:`iwr.simulation.sample_poses`) whose centre distance lies in the set-up's ``range``
    (any, without one). ``x``: the truth, the robot's errors then the set-ups' parameters;
    default uniform within the robot's default bounds and the set-ups'
    (:meth:`BallbarSetup.default_bounds`). ``noise``: see :func:`split_noise`; default none.
    Draws from one generator in this order: x (when not given), the poses set-up by set-up, the
    reading noise, the bar noise."""
    if not isinstance(robot, Robot):
        raise TypeError(f"robot: expected an iwr.Robot, got {type(robot).__name__}")
    if not isinstance(setup, BallbarSetup):
        raise TypeError(f"setup: expected a BallbarSetup, got {type(setup).__name__}")
    if isinstance(n_poses, bool) or not isinstance(n_poses, (int, np.integer)) or n_poses < 1:
        raise ValueError(f"n_poses: {n_poses!r}; expected a positive integer")
    split_noise(noise)  # its types checked before anything is drawn
    rng = np.random.default_rng(seed)
    n_all = robot.n_params + setup.n_params
    if x is None:
        lo_r, hi_r = robot.default_bounds()
        lo_s, hi_s = setup.default_bounds()
        lo, hi = np.concatenate([lo_r, lo_s]), np.concatenate([hi_r, hi_s])
        x_true = lo + (hi - lo) * rng.random(n_all)
    else:
        x_true = np.array(x, dtype=float)
        if x_true.shape != (n_all,) or not np.all(np.isfinite(x_true)):
            raise ValueError(f"x: expected {n_all} finite values (the robot's {robot.n_params} "
                             f"then the set-ups' {setup.n_params}), got shape {x_true.shape}")
    xr, xs = x_true[: robot.n_params], x_true[robot.n_params:]
    q, poses, legs, bar_idx = sample_setup_poses(robot, setup, xr, xs, int(n_poses), rng,
                                                 max_batches)
    return measured(robot, setup, xs, bar_idx, q, poses, legs, noise, rng), x_true


def sample_setup_poses(robot: Robot, setup: BallbarSetup, xr: np.ndarray, xs: np.ndarray,
                       n: int, rng: np.random.Generator, max_batches: int = 200
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(q, poses, legs, bar)``: ``n`` random reachable poses of the robot with geometric errors
    ``xr`` shared out among the set-ups in order (the first ``n % S`` set-ups get one more), each
    set-up's within its ``range`` at the set-ups' parameters ``xs`` (:func:`simulate_ballbar`);
    exact joint readings, platform poses in {0}, the geometry's leg readings and each pose's
    set-up index, drawn from ``rng``."""
    s_count = setup.n_setups
    counts = [n // s_count + (1 if i < n % s_count else 0) for i in range(s_count)]
    offsets = setup.split(xs)[2]
    qs, ps, ls, bars = [], [], [], []
    for i, (bar, count) in enumerate(zip(setup.bars, counts, strict=True)):
        have, batches = 0, 0
        while have < count:
            batches += 1
            if batches > max_batches:
                raise UnreachableError(
                    f"ballbar set-up {bar.name!r}: only {have} of {count} random reachable poses "
                    f"put the balls within its range {list(bar.range or ())} mm after "
                    f"{max_batches} batches: move the fixed ball nearer the platform's "
                    "workspace or widen the range")
            q, poses, legs = sample_poses(robot, max(16, 4 * count), rng, xr)
            d = true_distances(setup, xs, np.full(len(poses), i), poses)
            lo_d, hi_d = (-np.inf, np.inf) if bar.range is None else bar.range
            centre = d - offsets[i]  # the centre distance, which the range limits
            ok = np.flatnonzero((centre >= lo_d) & (centre <= hi_d))[: count - have]
            qs.append(q[ok])
            ps.append(poses[ok])
            ls.append(legs[ok])
            bars.append(np.full(ok.size, i))
            have += ok.size
    return np.vstack(qs), np.vstack(ps), np.vstack(ls), np.concatenate(bars)


def measured(robot: Robot, setup: BallbarSetup, x_setup: Any, bar: np.ndarray, q: np.ndarray,
             poses: np.ndarray, legs: np.ndarray, noise: Any,
             rng: np.random.Generator, **conditions: Any) -> BallbarMeasurements:
    """The readings at exact joint readings ``q``, platform poses in {0} and leg readings
    ``legs``, in set-ups ``bar`` (indices) whose parameters are ``x_setup``: the bar's
    :func:`true_distances`, then the leg and joint readings' noise and the bar's
    (:func:`split_noise`), drawn from ``rng`` in that order (:func:`simulate_ballbar`,
    :func:`iwr.planning.measure`). ``conditions``: the ``payload`` and ``temperatures`` the
    data carry (issue 23: the legs given are then those of the robot with its effects)."""
    readings, bar_noise = split_noise(noise)
    distance = true_distances(setup, x_setup, bar, poses)
    if readings is not None and not readings.is_zero:
        sigma_q = np.where(np.array([c == "P" for c in robot.joint_types], dtype=bool),
                           readings.joint_lengths, readings.joint_angles)
        q = q + sigma_q * rng.standard_normal(q.shape)
        legs = legs + readings.legs * rng.standard_normal(legs.shape)
    if bar_noise is not None and not bar_noise.is_zero:
        distance = distance + bar_noise.distance * rng.standard_normal(distance.shape)
    names = np.array(setup.names, dtype=object)[bar]
    return BallbarMeasurements(q, legs, names, distance, joint_types=robot.joint_types,
                               **conditions)
