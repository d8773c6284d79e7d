"""The public API on tracker data: what :func:`iwr.simulate`, :func:`iwr.identify`,
:func:`iwr.accuracy`, :func:`iwr.identifiability` and :func:`iwr.forward_kinematics` do when the
robot carries a tracker setup (``Robot.with_tracker``) and the data are
:class:`TrackerMeasurements` (docs/tracker.md, "The public API")."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np

from .. import kinds
from ..analysis.accuracy import Accuracy, PoseErrors
from ..forward import in_data_frame
from ..noise import split_noise
from ..robot import Robot
from ..transforms import rotation_angle
from .analysis import NullSpace, null_space, tool_pose_errors
from .data import TrackerMeasurements
from .problem import TrackerProblem
from .registration import kabsch
from .simulate import simulate_tracker
from .start import _setup, before_problem, registration_guess, tracker_problem

__all__ = [
    "tracker_accuracy",
    "tracker_forward_kinematics",
    "tracker_identifiability",
    "tracker_identify",
    "registration_guess",
    "tracker_problem",
    "tracker_simulate",
]


def tracker_simulate(robot: Robot, n_poses: int, *, seed: int | None, x: Any = None,
                     noise: Any = None, hidden: float = 0.0
                     ) -> tuple[TrackerMeasurements, np.ndarray]:
    """:func:`iwr.simulate` for a robot with a tracker: ``(TrackerMeasurements, x_true)``, where
    ``x_true`` covers the robot's ``n_params`` then the setup's parameters. ``noise``: None
    (noise-free), an ``iwr.Noise`` (leg and joint readings only), a ``TrackerNoise``, or a pair
    ``(Noise, TrackerNoise)``."""
    setup = _setup(robot)
    readings, tracker = split_noise(noise)
    return simulate_tracker(robot, setup, n_poses, seed=seed, x=x, noise=readings,
                            tracker_noise=tracker, hidden=hidden)


def tracker_identify(robot: Robot, measurements: TrackerMeasurements, method: str = "lm", *,
                     noise: Any = None, weighted: bool | None = None, bounds: Any = None,
                     x0: Any = None, active: Any = None, max_evaluations: int | None = None,
                     seed: int | None = None, callback: Callable[..., Any] | None = None,
                     progress: bool | None = None, **options: Any) -> Any:
    """:func:`iwr.identify` on tracker data: every method of the registry on the point (or probe)
    objective, from the nominal robot with the closed-form registration guess (default ``x0``).
    ``x`` of the result holds the robot's ``n_params`` then the setup's parameters
    (``result.parameter_names``). DE runs on ``TrackerProblem.cost_batch`` and is polished by LM
    (``polish=False``: DE alone). A result at which a pose's forward kinematics fails is never a
    success (``problem.check`` names the pose).

    With a ``noise`` model ``(iwr.Noise, TrackerNoise)`` a method other than ``"efficient"``
    minimises the noise-weighted point objective (``weighted``, default True with a noise
    model; :class:`TrackerProblem`'s ``noise``: a probe's four points by the pseudo-inverse of
    their rank-6 covariance): ``fun`` is then that
    weighted cost, ``cost_eq10`` the unweighted one at ``x``. ``weighted=False`` with a noise
    model minimises the unweighted point objective. Either way a noise model adds the
    chi-square test of the fit (:func:`iwr.estimation.fit_check`: the noise-weighted statistic
    minimised to first order around ``x``) to "converged"."""
    from ..methods import METHODS

    if method not in METHODS:
        raise ValueError(f"method: {method!r}; available: {', '.join(sorted(METHODS))}")

    def base(problem: Any, start: Any) -> list[bool]:
        left_out = set(null_space(problem, start).left_out)
        return [n not in left_out for n in problem.parameter_names]

    return identify_with(
        robot, measurements, method,
        lambda noise: tracker_problem(robot, measurements, bounds, x0, noise=noise), base,
        noise=noise, weighted=weighted, x0=x0, active=active, bounds=bounds,
        max_evaluations=max_evaluations, seed=seed, callback=callback, progress=progress,
        **options)


def identify_with(robot: Any, measurements: Any, method: str,
                  problem_of: Callable[[Any], tuple[Any, Any]],
                  base_of: Callable[[Any, Any], Any], *, noise: Any, weighted: bool | None,
                  x0: Any, active: Any, bounds: Any, max_evaluations: int | None,
                  seed: int | None, callback: Any, progress: Any, **options: Any) -> Any:
    """:func:`iwr.identify` on tracker data with ``method`` (checked by the caller) on the
    problem ``problem_of(noise)`` makes (``(problem, start)``; the noise-weighted one for a
    noise model, :func:`tracker_identify`'s docstring; ``problem_of(None)`` the unweighted one,
    the efficient estimator's start); ``active="base"`` the active parameters
    ``base_of(problem, start)`` gives. The robot with or without effects
    (:func:`iwr.effects.tracker.identify`) differ only in those two."""
    from ..methods import run_method, settle
    from ..methods.reduced import active_mask

    if method == "efficient":
        # Every instrument weighted by its noise (docs/estimation.md, "Tracker data"): its own
        # start (LM on the points from the registration guess), base parameters and fit test.
        from ..methods.efficient import efficient_on

        return efficient_on(robot, measurements, noise, lambda: problem_of(None)[0],
                            noise_hint="(iwr.Noise(...), iwr.tracker.TrackerNoise(...))",
                            x0=x0, active=active, bounds=bounds, callback=callback,
                            weighted=weighted, max_evaluations=max_evaluations, **options)
    if weighted is None:
        weighted = noise is not None
    if weighted and noise is None:
        raise ValueError("weighted=True needs a noise model: noise=(iwr.Noise(...), "
                         "iwr.tracker.TrackerNoise(...))")
    problem, start_x = problem_of(noise if weighted else None)
    if isinstance(active, str) and active == "base":
        active = base_of(problem, start_x)
    mask = active_mask(problem, active)
    result = run_method(problem, method, mask, start_x, max_evaluations=max_evaluations,
                        seed=seed, callback=callback, progress=progress,
                        **options)
    if weighted:
        result["cost_eq10"] = problem.cost_unweighted(result.x)
        # Said in the settings too, so that a saved result's fun is not read as unweighted.
        result["settings"] = {**dict(result.settings), "objective": {
            "weighted": True, "cost_eq10": float(result["cost_eq10"]),
            **kinds.of(measurements).noise_record(problem.noise)}}
    settle(result, problem, noise, mask)
    return result


def _point_errors(problem: TrackerProblem, x: np.ndarray) -> PoseErrors:
    """Per pose: the largest distance (mm) between a predicted and a measured point, and the
    angle (degrees) of the rigid rotation between them (the probe's orientation error, or the
    Kabsch fit of K >= 3 points; NaN for fewer points: one or two points have no orientation)."""
    m = problem.measurements
    pred = problem.predicted_points(x)
    meas = m.tracker_points(problem.setup).reshape(pred.shape)
    dist = np.linalg.norm(pred - meas, axis=2)
    position = np.nanmax(np.where(np.isnan(dist), -np.inf, dist), axis=1)
    angle = np.full(len(m), np.nan)
    for k in range(len(m)):
        ok = ~np.isnan(meas[k, :, 0]) & ~np.isnan(pred[k, :, 0])
        if ok.sum() >= 3:
            r, _ = kabsch(pred[k, ok], meas[k, ok])
            angle[k] = np.degrees(rotation_angle(r))
    poses = problem.platform_poses(x)
    return PoseErrors(position, angle, poses)


def tracker_accuracy(robot: Robot, measurements: TrackerMeasurements, x: Any, *,
                     truth: Any = None, tool: Any = None, start: Any = None) -> Accuracy:
    """:func:`iwr.accuracy` on tracker data, before (the nominal robot with the registration
    guess ``start``, the :class:`iwr.tracker.registration.RegistrationGuess` the identification
    started from; default the guess on these data, and where they have none (fewer than 3
    points, or on one line, or a nominal robot too far from them) the nominal robot with the
    registration and offsets of ``x``) and after (``x``, robot then setup parameters). A guess
    fitted to validation poses flatters the nominal robot: a correct re-calibration of a
    calibrated robot was judged "not calibrated" against it.

    With ``truth`` (the simulation's true vector): tool pose errors against the truth by forward
    kinematics of the readings, in {T} modulo the gauge (:func:`tool_pose_errors`). Without it:
    per validation pose, the largest distance between predicted and measured points (mm) and
    the angle of their best rigid rotation (degrees; NaN with fewer than 3 points)."""
    setup = _setup(robot)
    x = np.asarray(x, dtype=float)
    n = robot.n_params + setup.n_params
    if x.shape != (n,):
        raise ValueError(f"x: shape {x.shape}; expected ({n},): the robot's {robot.n_params} "
                         f"then the tracker setup's {setup.n_params}")
    # Without a guess of their own (fewer than 3 validation points, or on one line, or a nominal
    # robot too far from them), "before" is the nominal robot in the identified registration.
    problem, start = before_problem(partial(tracker_problem, robot, measurements),
                                    robot.n_params, start, x)
    if truth is not None:
        setup, m = problem.setup, measurements
        return Accuracy(
            tool_pose_errors(robot, setup, start, truth, m.q, m.legs, tool=tool),
            tool_pose_errors(robot, setup, x, truth, m.q, m.legs, tool=tool))
    return Accuracy(_point_errors(problem, start), _point_errors(problem, x))


def tracker_identifiability(robot: Robot, measurements: TrackerMeasurements,
                            x: Any = None, *, rtol: float | None = None) -> NullSpace:
    """:func:`iwr.identifiability` on tracker data: the null directions of the point (or probe)
    objective's column-scaled Jacobian at ``x`` (default: the nominal robot with the registration
    guess), one per left-out parameter (:class:`NullSpace`; ``left_out``, ``rank``,
    ``describe(k)``)."""
    problem, start = tracker_problem(robot, measurements)
    return null_space(problem, start if x is None else x, rtol)


def tracker_forward_kinematics(robot: Robot, x: Any, q: Any, legs: Any) -> np.ndarray:
    """:func:`iwr.forward_kinematics` with a tracker ``x`` (robot then setup parameters): the
    platform poses in the tracker frame {T}, ``(N, 6)``, by forward kinematics of the readings
    with the robot's part of ``x`` and the identified registration. (Modulo the gauge of
    docs/tracker.md: what tracker data determine.)"""
    _setup(robot)
    return in_data_frame(robot, x, q, legs)
