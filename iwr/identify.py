"""``iwr.identify``: one entry point for every identification method, on one objective.

Every method sees the same :class:`iwr.Problem` (eq. 10) and returns an
:class:`iwr.IdentificationResult`. A method is a function
``run(problem, *, x0, active, seed, callback, progress, **options)`` registered in ``METHODS``;
``active`` is a boolean mask of the parameters being identified (the others stay at ``x0``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from .measurements import Measurements
from .problem import Problem
from .result import IdentificationResult
from .robot import Robot

__all__ = ["identify", "METHODS", "register_method", "ReducedProblem", "levenberg_marquardt"]

METHODS: dict[str, Callable[..., IdentificationResult]] = {}


def register_method(name: str) -> Callable[[Callable[..., IdentificationResult]], Any]:
    """Decorator: register an identification method under ``name``."""

    def deco(fn: Callable[..., IdentificationResult]) -> Callable[..., IdentificationResult]:
        METHODS[name] = fn
        return fn

    return deco


class ReducedProblem:
    """The problem restricted to the ``active`` parameters; the others are held at ``x0``.

    ``cost``, ``residuals``, ``jacobian`` and ``cost_batch`` take reduced vectors z (n_active).
    """

    def __init__(self, problem: Problem, active: np.ndarray, x0: np.ndarray) -> None:
        self.problem = problem
        self.active = active
        self.index = np.flatnonzero(active)
        self.x0 = x0.copy()
        self.lower = problem.lower[self.index]
        self.upper = problem.upper[self.index]
        self.nfev = 0

    @property
    def n(self) -> int:
        return self.index.size

    def full(self, z: Any) -> np.ndarray:
        x = self.x0.copy()
        x[self.index] = z
        return x

    def reduce(self, x: Any) -> np.ndarray:
        return np.asarray(x, dtype=float)[self.index]

    def cost(self, z: Any) -> float:
        self.nfev += 1
        return self.problem.cost(self.full(z))

    def residuals(self, z: Any) -> np.ndarray:
        self.nfev += 1
        return self.problem.residuals(self.full(z))

    def jacobian(self, z: Any) -> np.ndarray:
        return self.problem.jacobian(self.full(z))[:, self.index]

    def cost_batch(self, Z: Any, workers: int | None = None) -> np.ndarray:
        Z = np.atleast_2d(np.asarray(Z, dtype=float))
        X = np.broadcast_to(self.x0, (Z.shape[0], self.x0.size)).copy()
        X[:, self.index] = Z
        self.nfev += Z.shape[0]
        return self.problem.cost_batch(X, workers)


def _active_mask(problem: Problem, active: Any) -> np.ndarray:
    n = problem.n_params
    if active is None:
        return np.ones(n, dtype=bool)
    arr = np.asarray(active)
    if arr.dtype == bool:
        if arr.shape != (n,):
            raise ValueError(f"active: boolean mask of shape {arr.shape}; expected ({n},)")
        mask = arr.copy()
    else:
        mask = np.zeros(n, dtype=bool)
        names = problem.parameter_names
        for item in np.atleast_1d(arr).tolist():
            if isinstance(item, str):
                if item not in names:
                    raise ValueError(f"active: unknown parameter name {item!r}")
                mask[names.index(item)] = True
            elif isinstance(item, int) and 0 <= item < n:
                mask[item] = True
            else:
                raise ValueError(f"active: {item!r} is neither a parameter name nor an index < {n}")
    if not mask.any():
        raise ValueError("active: no parameter is active")
    return mask


def identify(
    robot: Robot,
    measurements: Measurements,
    method: str = "de",
    *,
    bounds: Any = None,
    x0: Any = None,
    active: Any = None,
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
        ``"de"`` (differential evolution, the paper's method), ``"lm"`` (Levenberg-Marquardt on
        the exact Jacobian), ``"crs2"`` or ``"bobyqa"`` (NLopt), where installed.
    bounds : None, "default", "paper" or (lower, upper)
        Search bounds; see :class:`iwr.Problem`.
    x0 : array_like, optional
        Starting point (local methods) and the value of parameters that are not ``active``.
        Default: zeros, the nominal robot.
    active : array_like of bool, names or indices, or "base", optional
        The parameters to identify; the rest are held at ``x0``. For example the base parameters
        of :func:`iwr.identifiability` (``active=report.active``, or ``active="base"`` to compute
        them at ``x0``), so that the answer is unique.
    seed : int, optional
        Seed of the random generator of stochastic methods.
    callback : callable, optional
        Method-specific; see the method's documentation.
    progress : bool, optional
        Show a progress bar (default: when standard error is a terminal).
    **options
        Passed to the method.
    """
    if method not in METHODS:
        raise ValueError(f"method: {method!r}; available: {', '.join(sorted(METHODS))}")
    problem = Problem(robot, measurements, bounds)
    x0_arr = np.zeros(problem.n_params) if x0 is None else np.array(x0, dtype=float)
    if x0_arr.shape != (problem.n_params,) or not np.all(np.isfinite(x0_arr)):
        raise ValueError(f"x0: expected {problem.n_params} finite values, got shape {x0_arr.shape}")
    if isinstance(active, str) and active == "base":
        # The base parameters of the identifiability analysis at x0: a unique answer.
        from .identifiability import identifiability

        active = identifiability(robot, measurements, x0_arr).active
    mask = _active_mask(problem, active)
    start = time.perf_counter()
    result = METHODS[method](
        problem, x0=x0_arr, active=mask, seed=seed, callback=callback, progress=progress, **options
    )
    result.setdefault("wall_time", time.perf_counter() - start)
    result["method"] = method
    result["parameter_names"] = problem.parameter_names
    result["active"] = mask
    # Every method's reported cost is re-evaluated here, at the point it returns.
    result["fun"] = problem.cost(result["x"])
    return result


@register_method("lm")
def levenberg_marquardt(
    problem: Problem,
    *,
    x0: np.ndarray,
    active: np.ndarray,
    seed: int | None = None,
    callback: Callable[..., Any] | None = None,
    progress: bool | None = None,
    max_nfev: int | None = None,
    xtol: float = 1e-15,
    ftol: float = 1e-15,
    gtol: float = 1e-15,
) -> IdentificationResult:
    """Levenberg-Marquardt (MINPACK, through ``scipy.optimize.least_squares(method="lm")``) on the
    exact Jacobian of :meth:`Problem.jacobian`.

    Unbounded: the search bounds are not imposed, since a least-squares solution of a calibration
    should not be clipped. Rank deficiency (parameters the data cannot tell apart) is handled by the
    damping: the step has no component along directions where the Jacobian is zero, so the solver
    does not drift along them. ``seed`` and ``progress`` are accepted for a uniform interface and
    unused (the method is deterministic and fast).
    """
    from scipy.optimize import least_squares

    reduced = ReducedProblem(problem, active, x0)
    history_nfev: list[int] = []
    history_best: list[float] = []
    best = [np.inf]

    def fun(z: np.ndarray) -> np.ndarray:
        r = reduced.residuals(z)
        c = float(r @ r)
        best[0] = min(best[0], c)
        history_nfev.append(reduced.nfev)
        history_best.append(best[0])
        if callback is not None:
            callback(reduced.full(z), c)
        return r

    n_res = 6 * problem.n_poses
    if n_res < reduced.n:
        raise ValueError(
            f"method 'lm': {n_res} residuals for {reduced.n} parameters; MINPACK's LM needs at least "
            "as many residuals as parameters: measure more poses or fix parameters with 'active'"
        )
    start = time.perf_counter()
    sol = least_squares(
        fun,
        reduced.reduce(x0),
        jac=reduced.jacobian,
        method="lm",
        xtol=xtol,
        ftol=ftol,
        gtol=gtol,
        max_nfev=max_nfev if max_nfev is not None else 100 * (reduced.n + 1),
        x_scale="jac",
    )
    x = reduced.full(sol.x)
    return IdentificationResult(
        x=x,
        fun=problem.cost(x),
        nfev=int(sol.nfev) + int(sol.njev or 0),
        nit=int(sol.nfev),
        success=bool(sol.status > 0),
        message=str(sol.message),
        history={"nfev": np.array(history_nfev), "best": np.array(history_best)},
        wall_time=time.perf_counter() - start,
        settings={"max_nfev": max_nfev, "xtol": xtol, "ftol": ftol, "gtol": gtol},
    )
