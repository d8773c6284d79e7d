"""Identification methods behind one registry and one call, and :func:`identify`, their entry point.

Every method is a function ``fn(problem, *, max_evaluations, seed, callback, progress, **options)``
of a :class:`ReducedProblem` (eq. 10 restricted to the active parameters, started from ``x0``)
that returns an :class:`IdentificationResult`. They share:

- ``max_evaluations``: the evaluation budget (a Jacobian counts as one evaluation);
- ``seed``: the same seed gives the same answer;
- ``callback(intermediate_result)``: SciPy's convention, an ``OptimizeResult`` with at least ``x``
  (the best full vector so far), ``fun``, ``nfev`` and ``nit``; a truthy return (``np.True_``
  too) or ``StopIteration`` stops the method, which returns its best point so far with
  ``status="callback"`` and ``success=False``;
- ``progress``: a tqdm bar on standard error (default: when it is a terminal);
- Ctrl-C (``KeyboardInterrupt``) returns the best point so far with ``status="interrupted"``
  (``result.interrupted``), never a success.

:data:`METHODS` is the registry: add a method by adding it there.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from ..measurements import Measurements
from ..problem import Problem
from ..robot import Robot
from .de import de_method
from .lm import levenberg_marquardt
from .nlopt import bobyqa, crs2
from .reduced import ReducedProblem, active_mask
from .result import STATUSES, IdentificationResult, ResultFileError, load_result

__all__ = [
    "DEFAULT_METHOD",
    "METHODS",
    "STATUSES",
    "IdentificationResult",
    "ReducedProblem",
    "ResultFileError",
    "identify",
    "load_result",
]

#: Every identification method, by name.
METHODS: dict[str, Callable[..., IdentificationResult]] = {
    "lm": levenberg_marquardt,
    "de": de_method,
    "crs2": crs2,
    "bobyqa": bobyqa,
}

#: The method used when none is named: the best we have. Levenberg-Marquardt from the nominal
#: robot reaches the noise floor of every data set of docs/compare.md, in about a hundred
#: evaluations (DE, polished by LM, is one argument away).
DEFAULT_METHOD = "lm"


def identify(
    robot: Robot,
    measurements: Measurements,
    method: str = DEFAULT_METHOD,
    *,
    bounds: Any = None,
    x0: Any = None,
    active: Any = None,
    max_evaluations: int | None = None,
    seed: int | None = None,
    callback: Callable[..., Any] | None = None,
    progress: bool | None = None,
    **options: Any,
) -> IdentificationResult:
    """Identify the error parameters of ``robot`` from ``measurements``.

    Parameters
    ----------
    robot : Robot
        The nominal robot.
    measurements : Measurements
    method : str
        A name of :data:`METHODS`: ``"lm"`` (default, Levenberg-Marquardt on the exact Jacobian),
        ``"de"`` (differential evolution, the paper's method, polished by LM unless
        ``polish=False``), ``"crs2"`` or ``"bobyqa"`` (NLopt).
    bounds : None, "default", "paper" or (lower, upper)
        Search bounds; see :class:`iwr.Problem`.
    x0 : array_like, optional
        Starting point (local methods) and the value of parameters that are not ``active``.
        Default: zeros, the nominal robot.
    active : array_like of bool, names or indices, or "base", optional
        The parameters to identify; the rest are held at ``x0``. For example the base parameters
        of :func:`iwr.identifiability` (``active=report.active``, or ``active="base"`` to compute
        them at ``x0``), so that the answer is unique.
    max_evaluations : int, optional
        Evaluation budget; default: the method's.
    seed : int, optional
        Seed of the random generator of stochastic methods.
    callback : callable, optional
        ``callback(intermediate_result)``; see :mod:`iwr.methods`.
    progress : bool, optional
        Show a progress bar (default: when standard error is a terminal).
    **options
        The method's own options.

    Returns
    -------
    IdentificationResult
        ``fun`` is re-evaluated at ``x``; ``success`` only when the method converged and the
        result is finite.
    """
    if method not in METHODS:
        raise ValueError(f"method: {method!r}; available: {', '.join(sorted(METHODS))}")
    if type(measurements).__name__ == "TrackerMeasurements":
        # Tracker data (docs/tracker.md): the point objective, from the registration guess.
        from ..tracker.api import tracker_identify

        return tracker_identify(robot, measurements, method, bounds=bounds, x0=x0,
                                active=active, max_evaluations=max_evaluations, seed=seed,
                                callback=callback, progress=progress, **options)
    problem = Problem(robot, measurements, bounds)
    x0_arr = np.zeros(problem.n_params) if x0 is None else np.array(x0, dtype=float)
    if x0_arr.shape != (problem.n_params,) or not np.all(np.isfinite(x0_arr)):
        raise ValueError(f"x0: expected {problem.n_params} finite values, got shape {x0_arr.shape}")
    if isinstance(active, str) and active == "base":
        # The base parameters of the identifiability analysis at x0: a unique answer.
        from ..identifiability import identifiability

        active = identifiability(robot, measurements, x0_arr).active
    mask = active_mask(problem, active)
    if max_evaluations is not None:
        options["max_evaluations"] = max_evaluations
    start = time.perf_counter()
    result = METHODS[method](
        ReducedProblem(problem, mask, x0_arr), seed=seed, callback=callback, progress=progress,
        **options,
    )
    if not np.isfinite(result.wall_time):
        result["wall_time"] = time.perf_counter() - start
    result["method"] = method
    result["parameter_names"] = problem.parameter_names
    result["active"] = mask
    # Every method's reported cost is re-evaluated here, at the point it returns (a Ctrl-C here
    # keeps the method's own value, and the result, marked interrupted).
    try:
        result["fun"] = problem.cost(result.x)
    except KeyboardInterrupt:
        result.update(success=False, status="interrupted",
                      message=f"{result.message}; interrupted (Ctrl-C)")
    result.check_finite()
    return result
