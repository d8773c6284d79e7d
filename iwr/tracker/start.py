"""The identification problem of a tracker data set and its starting point: the robot's tracker
setup, the problem's bounds, the closed-form registration guess (made once per data set inside
:func:`iwr.kinds.reuse`) and :func:`tracker_problem`, what every public function on tracker data
(:mod:`iwr.tracker.api`) and the efficient estimator (:mod:`iwr.tracker.estimation`) build."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ..kinds import memo
from ..noise import split_noise
from ..robot import Robot
from . import registration
from .data import TrackerMeasurements
from .problem import TrackerProblem
from .setup import TrackerSetup

__all__ = ["before_problem", "before_x0", "registration_guess", "tracker_problem"]


def _setup(robot: Robot) -> TrackerSetup:
    if not isinstance(robot, Robot):
        raise TypeError(f"robot: expected an iwr.Robot, got {type(robot).__name__}")
    if robot.tracker is None:
        raise ValueError(
            f"robot {robot.name!r} has no tracker setup, but the data are tracker data "
            "(points or probe poses in the tracker frame): describe the setup with "
            "robot.with_tracker(registration=..., reflectors=[...]) or a [tracker] table in the "
            "robot's TOML file (docs/tracker.md)")
    return robot.tracker


def _bounds(robot: Robot, setup: TrackerSetup, bounds: Any, center: np.ndarray) -> Any:
    if bounds is None or (isinstance(bounds, str) and bounds == "default"):
        return None
    if isinstance(bounds, str):
        if bounds != "paper":
            raise ValueError(f"bounds: {bounds!r}; expected None, 'default', 'paper' or "
                             "(lower, upper)")
        lo_r, hi_r = robot.default_bounds("paper")
        lo_s, hi_s = setup.default_bounds()
        return (np.concatenate([lo_r, lo_s + center]), np.concatenate([hi_r, hi_s + center]))
    return bounds


def objective_noise(noise: Any, measurements: Any) -> tuple[Any, Any] | None:
    """``noise`` as the noise-weighted point objective takes it, ``(readings, tracker)``
    (:func:`iwr.noise.split_noise`), or None without one; ValueError when neither the tracker's
    noise nor the data's own point sigmas weigh the points."""
    if noise is None:
        return None
    readings, tracker = split_noise(noise)
    if tracker is None and measurements.point_sigma is None:
        raise ValueError("noise: the weighted objective on tracker data needs the tracker's "
                         "noise: give noise=(iwr.Noise(...), iwr.tracker.TrackerNoise(...))")
    return readings, tracker


def before_x0(n_model: int, start: Any) -> np.ndarray | None:
    """Where "before" (the nominal robot's figures) is evaluated on tracker data: the nominal
    model (``n_model`` zeros: the robot's parameters, and its effects' when it has some) in the
    registration guess ``start`` the identification started from (a
    :class:`iwr.tracker.registration.RegistrationGuess`), or None without one: the guess on the
    data at hand (the problems' ``x0=None``). A guess fitted to validation poses flatters the
    nominal robot. The one rule of :func:`iwr.calibrate`'s "before", compare/study's
    (:meth:`iwr.kinds.MeasurementKind.before`) and the accuracy functions'."""
    if start is None:
        return None
    return np.concatenate([np.zeros(n_model), np.asarray(start.x_setup, dtype=float)])


def before_problem(make: Callable[..., tuple[Any, np.ndarray]], n_model: int, start: Any,
                   x: Any) -> tuple[Any, np.ndarray]:
    """The problem of the accuracy functions' data and the vector their "before" is at:
    ``make(x0=before_x0(n_model, start))`` (a problem function such as :func:`tracker_problem`
    with its data bound) and its start; where that needs a registration guess the nominal model
    is too poor for (or the data too few for one), the problem at ``x`` and the nominal model
    (``n_model`` zeros) in ``x``'s identified registration, so that the calibrated figures never
    depend on whether the nominal robot has a guess of its own. ``x``: the calibrated vector
    (model then setup; its length checked by the caller), ValueError naming it where it is not
    finite."""
    x = np.asarray(x, dtype=float)
    bad = np.flatnonzero(~np.isfinite(x))
    if bad.size:
        raise ValueError(f"x: entry {bad[0]} is {x.flat[bad[0]]}; expected finite values")
    try:
        return make(x0=before_x0(n_model, start))
    except registration.RegistrationError:
        problem, _ = make(x0=x)
        return problem, np.concatenate([np.zeros(n_model), x[n_model:]])


def tracker_problem(robot: Robot, measurements: TrackerMeasurements, bounds: Any = None,
                    x0: Any = None, noise: Any = None) -> tuple[TrackerProblem, np.ndarray]:
    """The problem for these data and its starting point: the nominal robot with the closed-form
    registration guess (:func:`registration_guess`, which raises
    :class:`RegistrationError` when the nominal model is too poor for it), or ``x0``. With a
    ``noise`` model (``(iwr.Noise, TrackerNoise)``, as :func:`iwr.simulate` takes it; the
    tracker's part required) the problem is weighted by it (:class:`TrackerProblem`'s
    ``noise``), its weights evaluated at the nominal robot with the start's set-up.

    Inside :func:`iwr.kinds.reuse` (one calibration job) the guess and the unweighted problem
    of a data set are made once and shared; a call with ``x0`` then takes the problem already
    made for the data (its bounds centred on the guess) with ``x0`` as the start; outside one
    (the job's outlier screen refits a subset of the data) the guess is made for these data, and
    only where the nominal model is too poor for it are the bounds centred on ``x0``'s set-up.
    The fit test measures the registration's plausible size from that centre: centred on the
    nominal registration, a tracker standing 900 mm and 26 degrees from it failed the test of
    data whose fit was exact to the noise (the verdict then depended on the seed)."""
    setup = _setup(robot)
    if isinstance(bounds, str) and bounds == "default":
        bounds = None
    n = robot.n_params + setup.n_params
    if x0 is not None:
        start = np.array(x0, dtype=float)
        if start.shape != (n,) or not np.all(np.isfinite(start)):
            raise ValueError(f"x0: expected {n} finite values (the robot's "
                             f"{robot.n_params}, then the tracker setup's {setup.n_params}), "
                             f"got shape {start.shape}")
    weights = objective_noise(noise, measurements)
    given = not (bounds is None or isinstance(bounds, str))
    held = (robot, measurements, bounds) if given else (robot, measurements)
    key = ("tracker problem", "given" if given else bounds)

    def build(center: Any, at: Any) -> TrackerProblem:
        problem_bounds = _bounds(robot, setup, bounds,
                                 np.zeros(setup.n_params) if center is None else center)
        return TrackerProblem(robot, setup, measurements, problem_bounds, center=center,
                              noise=weights, weights_at=None if weights is None else at)

    if x0 is None:
        guess = registration_guess(robot, measurements)
        start = np.concatenate([np.zeros(robot.n_params), guess.x_setup])
        if weights is not None:  # weighted: its own problem (weights at the guess)
            return build(guess.x_setup, guess.x_setup), start
        return memo((*key, "guess"), held, lambda: build(guess.x_setup, None)), start
    made = None if weights is not None else memo((*key, "guess"), held, None)
    if made is not None:
        return made, start
    centre, guessed = guess_centre(robot, measurements, start[robot.n_params:])
    if weights is not None:
        return build(centre, start[robot.n_params:]), start
    if not guessed:
        return build(centre, None), start
    return memo((*key, "guess"), held, lambda: build(centre, None)), start


def guess_centre(robot: Robot, measurements: TrackerMeasurements, x_setup: Any
                 ) -> tuple[np.ndarray, bool]:
    """Where a problem started from ``x0`` centres the set-up's bounds (and the fit test the
    registration's plausible size): the data's registration guess, as a problem without
    ``x0``; ``x_setup`` (``x0``'s set-up part) where the nominal model is too poor for the
    guess. And whether it is the guess."""
    try:
        return registration_guess(robot, measurements).x_setup, True
    except registration.RegistrationError:
        return np.asarray(x_setup, dtype=float), False


def registration_guess(robot: Robot, measurements: TrackerMeasurements) -> Any:
    """The closed-form registration guess of these data with the nominal robot
    (:func:`iwr.tracker.registration.guess_registration`), made once per data set inside
    :func:`iwr.kinds.reuse`."""
    setup = _setup(robot)
    return memo(("registration guess",), (robot, measurements),
                lambda: registration.guess_registration(robot, setup, measurements))
