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

**The efficient estimator is a method like the others** (``"efficient"``, :mod:`iwr.estimation`),
so that one call, one result type and the comparison and study harnesses cover it; it differs in
that it needs a noise model: ``identify(..., noise=iwr.Noise(...))`` (or ``noise="estimate"``,
variance components). ``identify`` with a noise model and no method uses it; without a noise
model the default stays eq. (10) (``"lm"``, :data:`DEFAULT_METHOD`); ``method="efficient"``
without a noise model is an error. **A method named with a noise model** (``"lm"``, ``"de"``,
``"crs2"``, ``"bobyqa"``) minimises the noise-weighted objective instead of eq. (10): generalised
least squares with each pose's residuals whitened by their propagated covariance
(:func:`iwr.problem.gls_whitening`); its ``fun`` is that statistic and ``cost_eq10`` eq. (10)'s.
The efficient estimator's ``fun`` is its own objective (the chi-square statistic); eq. (10)'s cost
at its ``x`` is ``result.cost_eq10``.

**"converged" only when the fit is sane.** Every other method's result is checked by
:func:`iwr.estimation.fit_check`: identified errors beyond 10 times the search bounds (modulo
the unidentifiable directions) always, and, when a noise model is given, the chi-square test of
the generalised least squares statistic around ``x``. The efficient estimator runs the same
tests itself, with the same bounds as the yardstick. A method that converged to a point failing the
check returns ``success=False``, ``status="failed"``, the message naming the parameters or the
test; the check is ``result.fit`` (a :class:`iwr.estimation.FitTest`). Without a noise model the
cost itself cannot be judged (a local minimum with plausible parameters passes): see
``docs/estimation.md``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from .. import kinds
from ..measurements import Measurements
from ..problem import Problem
from ..problem_base import bounds_record
from ..result import STATUSES, IdentificationResult, ResultFileError, load_result
from ..robot import Robot
from .de import de_method
from .efficient import efficient_method
from .lm import levenberg_marquardt
from .nlopt import bobyqa, crs2
from .reduced import ReducedProblem, active_mask

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
    "efficient": efficient_method,
}

#: The method used when none is named and no noise model is given (with one: ``"efficient"``).
#: Eq. (10) is the best we have without a noise model. Levenberg-Marquardt from the nominal
#: robot reaches the noise floor of every data set of docs/compare.md, in about a hundred
#: evaluations (DE, polished by LM, is one argument away).
DEFAULT_METHOD = "lm"


def identify(
    robot: Robot,
    measurements: Measurements,
    method: str | None = None,
    *,
    noise: Any = None,
    weighted: bool | None = None,
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
    method : str, optional
        A name of :data:`METHODS`: ``"lm"`` (the default without a noise model,
        Levenberg-Marquardt on eq. (10) with the exact Jacobian), ``"efficient"`` (the default
        with a noise model: :func:`iwr.estimation.efficient`), ``"de"`` (differential
        evolution, the paper's method, polished by LM unless ``polish=False``), ``"crs2"`` or
        ``"bobyqa"`` (NLopt).
    noise : Noise or "estimate", optional
        The instruments' noise. Selects the efficient estimator when ``method`` is not given.
        With a method named, a :class:`iwr.Noise` makes it minimise the noise-weighted
        objective instead of eq. (10): generalised least squares, each pose's six leg
        residuals whitened by their covariance propagated from the legs', the encoders' and
        the measured pose's noise at the nominal robot (:func:`iwr.problem.gls_whitening`);
        ``fun`` is then that weighted cost, ``cost_eq10`` eq. (10)'s at ``x``, and the fit gets
        the chi-square test. ``"estimate"`` with a method other than ``"efficient"`` leaves
        eq. (10) unweighted and tests nothing more.
    weighted : bool, optional
        ``False``: eq. (10) unweighted even with a noise model (which then only adds the
        chi-square test of the fit, to first order around ``x``); ``True``: the weighted
        objective (needs an :class:`iwr.Noise`). Default: weighted when a method is named with
        an :class:`iwr.Noise`.
    bounds : None, "default", "paper" or (lower, upper)
        Search bounds; see :class:`iwr.Problem`.
    x0 : array_like, optional
        Starting point (local methods) and the value of parameters that are not ``active``.
        Default: zeros, the nominal robot.
    active : array_like of bool, names or indices, or "base", optional
        The parameters to identify; the rest are held at ``x0``. For example the base parameters
        of :func:`iwr.identifiability` (``active=report.active``, or ``active="base"`` to compute
        them at ``x0``), so that the answer is unique. Default: all of them, but the base
        parameters for ``"efficient"`` (whose covariance and fit test need a unique answer).
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
        ``fun`` is re-evaluated at ``x`` (eq. 10's cost; the chi-square statistic for
        ``"efficient"``); ``success`` only when the method converged, the result is finite and
        the fit is sane (``result.fit``, see :mod:`iwr.methods`).
    """
    if method is None:
        method = DEFAULT_METHOD if noise is None else "efficient"
    if method not in METHODS:
        raise ValueError(f"method: {method!r}; available: {', '.join(sorted(METHODS))}")
    # The kind of the data identifies (tracker data, docs/tracker.md: the point objective from
    # the registration guess; with a noise model the efficient estimator).
    return kinds.of(measurements).identify(
        robot, measurements, method, noise=noise, weighted=weighted, bounds=bounds, x0=x0,
        active=active, max_evaluations=max_evaluations, seed=seed, callback=callback,
        progress=progress, **options)


def pose_identify(robot: Robot, measurements: Measurements, method: str, *, noise: Any = None,
                  weighted: bool | None = None, bounds: Any = None, x0: Any = None,
                  active: Any = None, max_evaluations: int | None = None, seed: int | None = None,
                  callback: Callable[..., Any] | None = None, progress: bool | None = None,
                  **options: Any) -> IdentificationResult:
    """:func:`identify` on pose data (the platform pose measured in {0}); ``method`` checked."""
    from ..noise import Noise

    if noise is not None and not (isinstance(noise, Noise) or (isinstance(noise, str)
                                                               and noise == "estimate")):
        raise TypeError(f"noise: expected an iwr.Noise or 'estimate', got {noise!r}")
    # An explicit method with a noise model runs on the noise-weighted objective (issue 14, item
    # 3): each pose's six leg residuals whitened by their covariance propagated from every
    # instrument's noise at the nominal robot (iwr.problem.gls_whitening), so that its fun is the
    # generalised least squares statistic and its chi-square test applies.
    if weighted is None:
        weighted = isinstance(noise, Noise) and method != "efficient"
    elif weighted and not isinstance(noise, Noise):
        raise ValueError(f"weighted=True needs a noise model (an iwr.Noise), got noise={noise!r}")
    elif method == "efficient" and not weighted:
        raise ValueError("weighted=False: the efficient estimator always weighs by the noise")
    if method == "efficient":
        weighted = False  # its own weighting (iwr.estimation); Problem stays eq. (10)
    if robot.effects:  # issue 23: the effects' objective (iwr/effects/problem.py)
        from ..effects.problem import EffectProblem, check_method

        check_method(robot, method)
        # LM on the numpy model, DE, CRS2, BOBYQA on the C++ objective with effects (each eq.
        # (10) or noise-weighted); the efficient estimator its own (iwr.effects).
        problem: Any = (Problem if method in ("de", "crs2", "bobyqa") else EffectProblem)(
            robot, measurements, bounds, noise=noise if weighted else None)
    else:
        problem = Problem(robot, measurements, bounds, noise=noise if weighted else None)
    x0_arr = np.zeros(problem.n_params) if x0 is None else np.array(x0, dtype=float)
    if x0_arr.shape != (problem.n_params,) or not np.all(np.isfinite(x0_arr)):
        raise ValueError(f"x0: expected {problem.n_params} finite values, got shape {x0_arr.shape}")
    if method == "efficient" and active is None:
        # The estimator's own default: its covariance and chi-square test need a unique answer.
        active = "base"
    if isinstance(active, str) and active == "base":
        # The base parameters of the identifiability analysis at x0: a unique answer.
        from ..analysis.identifiability import identifiability

        active = identifiability(robot, measurements, x0_arr).active
    mask = active_mask(problem, active)
    if method == "efficient":
        options["noise"] = noise
    result = run_method(problem, method, mask, x0_arr, max_evaluations=max_evaluations,
                        seed=seed, callback=callback, progress=progress, **options)
    if method == "efficient":  # its own objective and its own fit test
        result.check_finite()
        return result
    # Every method's reported cost is re-evaluated here, at the point it returns (a Ctrl-C here
    # keeps the method's own value, and the result, marked interrupted).
    try:
        result["fun"] = problem.cost(result.x)
        if weighted:
            result["cost_eq10"] = (EffectProblem if robot.effects else Problem)(
                robot, measurements, bounds).cost(result.x)
            # Said in the settings too, so that a saved result's fun is not read as eq. (10)'s.
            result["settings"] = {**dict(result.settings), "objective": {
                "weighted": True, **kinds.of(measurements).noise_record(noise),
                "cost_eq10": float(result["cost_eq10"])}}
    except KeyboardInterrupt:
        result.update(success=False, status="interrupted",
                      message=f"{result.message}; interrupted (Ctrl-C)")
    _conclude(result, problem, noise, mask)
    return result


def run_method(problem: Any, method: str, active: np.ndarray, x0: np.ndarray, *,
               max_evaluations: int | None = None, seed: int | None = None,
               callback: Callable[..., Any] | None = None, progress: bool | None = None,
               **options: Any) -> IdentificationResult:
    """Run ``method`` (a name of :data:`METHODS`) on ``problem`` (any kind's,
    :class:`iwr.problem_base.LeastSquaresProblem`) restricted to the ``active`` parameters,
    the others held at ``x0``, and stamp what every result carries: ``method``,
    ``parameter_names``, ``active``, and ``wall_time`` where the method did not measure it.
    Every method runs the same way on every kind (``"de"`` on the problem's C++ objective,
    :meth:`~iwr.problem_base.ProblemBase.engine_objective`)."""
    reduced = ReducedProblem(problem, active, x0)
    start = time.perf_counter()
    if method not in METHODS:
        raise ValueError(f"method: {method!r}; available: {', '.join(sorted(METHODS))}")
    if max_evaluations is not None:
        options["max_evaluations"] = max_evaluations
    result = METHODS[method](reduced, seed=seed, callback=callback, progress=progress, **options)
    if not np.isfinite(result.wall_time):
        result["wall_time"] = time.perf_counter() - start
    result["method"] = method
    result["parameter_names"] = problem.parameter_names
    result["active"] = active
    # The bounds it searched within, recorded as iwr-calibrate's runs record theirs: a polish
    # of the result (iwr.calibration.polish, iwr report --polish) keeps them.
    result["settings"] = {**dict(result.settings), **bounds_record(problem)}
    return result


def settle(result: IdentificationResult, problem: Any, noise: Any, active: np.ndarray) -> None:
    """What a result on a kind's problem is (after :func:`run_method`): ``fun`` re-evaluated at
    ``x`` (``problem.cost``), "failed" where a pose's model cannot be evaluated there
    (``problem.failures``, naming the first pose's line), finite, and "converged" only when
    the fit is sane (:func:`_check_fit` with ``noise``, the chi-square test's model, or None)."""
    result["fun"] = problem.cost(result.x)
    bad = problem.failures(result.x)
    if bad:
        k, msg = bad[0]
        result.update(success=False, status="failed",
                      message=f"{result.message}; {len(bad)} poses have no forward kinematics at "
                      f"the result ({problem.measurements.where(k)}: {msg})")
    _conclude(result, problem, noise, active)


def _conclude(result: IdentificationResult, problem: Any, noise: Any,
              active: np.ndarray) -> None:
    """Refuse a non-finite result; then, unless interrupted, the fit check."""
    result.check_finite()
    if result.status != "interrupted" and np.all(np.isfinite(result.x)):
        # "converged" only when the fit is sane: the identified errors within their plausible
        # size modulo the null directions (iwr.estimation.fit_check), and the noise's test.
        _check_fit(result, problem, noise, active)


def _check_fit(result: IdentificationResult, problem: Any, noise: Any,
               active: np.ndarray) -> None:
    """Issue 16: "converged" only when the fit is sane (:func:`iwr.estimation.fit_check`), with
    the search bounds as the parameters' plausible range. ``problem``: an :class:`iwr.Problem`
    (leg data) or an :class:`iwr.tracker.TrackerProblem` (tracker data: its bounds are centred
    on the registration guess, and the check is modulo its null directions); ``noise``: the
    model the chi-square test weighs the residuals by (None: no chi-square test)."""
    from ..fit_test import fit_check

    if isinstance(noise, str):  # 'estimate': the efficient estimator's, never here
        noise = None
    try:
        fit = fit_check(problem.robot, problem.measurements, result.x, active=active, noise=noise,
                        bounds=(problem.lower, problem.upper))
    except ValueError as exc:
        if noise is None:
            raise
        # A noise model the chi-square test cannot use (all zero; a pose weighted 0, which eq.
        # (10) reads as "left out"): the plausibility check alone, and the reason in the message.
        fit = fit_check(problem.robot, problem.measurements, result.x, active=active, noise=None,
                        bounds=(problem.lower, problem.upper))
        result["message"] = f"{result.message} (no chi-square test: {exc})"
    if result.status == "stopped":  # a budget ended the method: the test is of that point
        fit = fit.stopped()
    result["fit"] = fit
    if result.success and not fit.fit_ok:
        # The method's own message (e.g. "converged") is kept, but no longer as the outcome.
        result.update(success=False, status="failed",
                      message=f"{fit.verdict}: " + "; ".join(fit.causes)
                      + f" (the method: {str(result.message).strip().rstrip('.')})")
