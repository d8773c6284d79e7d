"""``iwr.identify``: one entry point for every identification method, on one objective.

Every method sees the same :class:`iwr.Problem` (eq. 10) and returns an
:class:`iwr.IdentificationResult`. A method is a function
``run(problem, *, x0, active, seed, callback, progress, **options)`` registered in ``METHODS``;
``active`` is a boolean mask of the parameters being identified (the others stay at ``x0``).
"""

from __future__ import annotations

import math
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


#: Tikhonov weights of the first Levenberg-Marquardt solves, before the final ``regularization``.
_LM_CONTINUATION = (1e-4, 1e-8, 1e-12)
#: The final weight of ``regularization="auto"`` on a rank-deficient problem.
_AUTO_REGULARIZATION = 1e-16


def _rank_deficient(jac: np.ndarray, norms: np.ndarray, rtol: float = 1e-9) -> bool:
    """Is the column-scaled Jacobian numerically rank deficient, or not taller than wide?

    (MINPACK needs more residuals than parameters, and it gets one parameter more than the problem
    has, see _guard_column: a square Jacobian is regularised too.)"""
    if jac.shape[0] <= jac.shape[1]:
        return True
    from ._blas import single_thread

    with single_thread():
        s = np.linalg.svd(jac / np.where(norms > 0, norms, 1.0), compute_uv=False)
    return bool(s.size == 0 or s[-1] <= rtol * s[0])


def _guard_column(jac: np.ndarray) -> np.ndarray:
    """The Jacobian with a zero column appended, for SciPy's MINPACK.

    SciPy's C translation of MINPACK (seen with SciPy 1.17.1) has an off-by-one in ``qrfac``: when
    a column's norm is recomputed during column pivoting (which happens when it collapses, as in a
    rank-deficient or tightly regularised Jacobian), the norm takes one element too many, the first
    of the next column. For the last stored column that element lies past the end of MINPACK's
    buffer (valgrind: "Invalid read of size 8 ... 0 bytes after a block", in ``enorm`` from
    ``qrfac``): heap garbage, which made the same problem give different answers from one call to
    the next (74 or 80 evaluations, results differing from the 6th digit). A zero column is never
    recomputed (its norm is 0) and never pivoted away from the end, so no element past the buffer
    is read and the results are reproducible. This does not fix the off-by-one for the other
    columns (it reads a wrong but deterministic element, which only affects pivoting). The extra
    parameter has no effect on the residuals and a zero gradient, so its step is 0; but MINPACK
    now always sees a singular R, which changes its path (its Levenberg-Marquardt parameter search
    skips the Newton lower bound), not the solution it converges to.
    """
    return np.hstack([jac, np.zeros((jac.shape[0], 1))])


class _StopLM(Exception):
    """Raised from inside the residual function to end a Levenberg-Marquardt run early."""


@register_method("lm")
def levenberg_marquardt(
    problem: Problem,
    *,
    x0: np.ndarray,
    active: np.ndarray,
    seed: int | None = None,
    callback: Callable[..., Any] | None = None,
    progress: bool | None = None,
    max_evaluations: int | None = None,
    max_nfev: int | None = None,
    xtol: float = 1e-15,
    ftol: float = 1e-15,
    gtol: float = 1e-15,
    regularization: float | str = "auto",
) -> IdentificationResult:
    """Levenberg-Marquardt (MINPACK, through ``scipy.optimize.least_squares(method="lm")``) on the
    exact Jacobian of :meth:`Problem.jacobian`.

    Parameters
    ----------
    problem : Problem
    x0 : ndarray
        The starting point; the value of inactive parameters.
    active : ndarray of bool
    seed, progress
        Accepted for a uniform interface, unused (the method is deterministic and fast).
    callback : callable, optional
        ``callback(x, cost)`` after every residual evaluation (``x`` the full vector); returning
        ``True`` stops the run with the best point so far.
    max_evaluations : int, optional
        Evaluation budget: residual evaluations plus Jacobian evaluations (one each), respected
        exactly; default ``100 (n + 1)``.
    max_nfev : int, optional
        MINPACK's own limit on residual evaluations (Jacobians not counted).
    xtol, ftol, gtol : float
        MINPACK's tolerances.
    regularization : float or "auto"
        Weight ``lambda`` of a Tikhonov term ``lambda sum_i (d_i (z_i - z0_i))^2`` added to the
        sum of squares, with ``d_i`` the norm of column i of the Jacobian at ``x0``: 0 disables
        it. Solved by continuation: weights 1e-4, 1e-8, 1e-12, then ``regularization``, each
        solve started from the previous answer. ``"auto"`` (default): 1e-16 when the column-scaled
        Jacobian at ``x0`` is rank deficient (a singular value below 1e-9 of the largest), else
        0, so that a full-rank problem (``active="base"``) gets the plain, unbiased solution. See
        the notes.

    Notes
    -----
    Unbounded: the search bounds are not imposed, since a least-squares solution of a calibration
    should not be clipped.

    Not every parameter is identifiable (the Jacobian is rank deficient: 58 parameters, about 52
    identifiable directions). MINPACK copes with the singular normal equations through its
    damping, but the set of equally good solutions is curved, and without regularisation the
    iterates slide along it: from the nominal start, noise-free, the unregularised solver ends up
    to 10 mm away from the truth in unidentifiable combinations (at the same, zero, cost). The tiny
    Tikhonov term makes the problem full rank and picks, among the equally good solutions, the one
    nearest ``x0`` in the column-scaled metric (about 1 mm from the truth instead of 10 in the
    same test). Its bias on the identifiable part is of order ``lambda / s_min^2`` relative,
    with ``s_min`` ~ 1e-3 the smallest identifiable singular value of the column-scaled
    Jacobian: about 1e-10 relative at the default, far below any noise. (It also lets MINPACK
    run with fewer readings than parameters.) Hold the unidentifiable parameters fixed with
    ``active`` (the base parameters) for the unregularised answer.

    Starting far from the valley of equal-cost solutions, a single solve at a tiny weight crawls
    along it (thousands of evaluations from the bad start of ``iwr compare``); the continuation
    (weights 1e-4, 1e-8, 1e-12, then ``regularization``) gets there in about a hundred.
    """
    from scipy.optimize import least_squares

    auto = isinstance(regularization, str) and regularization == "auto"
    if not auto and not (isinstance(regularization, (int, float))
                         and not isinstance(regularization, bool)
                         and math.isfinite(regularization) and regularization >= 0):
        raise ValueError(
            f"regularization: {regularization!r}; expected 'auto' or a finite number >= 0"
        )
    reduced = ReducedProblem(problem, active, x0)
    n_res = 6 * problem.n_poses
    if not auto and regularization == 0 and n_res <= reduced.n:
        raise ValueError(
            f"method 'lm': {n_res} residuals for {reduced.n} parameters; MINPACK's LM needs "
            "more residuals than parameters (one parameter more than the problem's is passed, "
            "see _guard_column): measure more poses, fix parameters with 'active', or use "
            "regularization > 0"
        )
    if max_evaluations is None:
        max_evaluations = 100 * (reduced.n + 1)
    if (isinstance(max_evaluations, bool) or not isinstance(max_evaluations, (int, np.integer))
            or max_evaluations < 2):
        raise ValueError(f"max_evaluations: {max_evaluations!r}; expected an integer >= 2")
    if max_nfev is not None and (isinstance(max_nfev, bool)
                                 or not isinstance(max_nfev, (int, np.integer)) or max_nfev < 1):
        raise ValueError(f"max_nfev: {max_nfev!r}; expected a positive integer or None")

    z0 = reduced.reduce(x0)
    start = time.perf_counter()
    state: dict[str, Any] = {"n": 0, "nit": 0, "best_f": np.inf, "best_z": z0.copy(), "stop": ""}
    history_nfev: list[int] = []
    history_best: list[float] = []

    def count() -> None:
        if state["n"] >= max_evaluations:
            state["stop"] = f"evaluation budget exhausted (max_evaluations={max_evaluations})"
            raise _StopLM
        state["n"] += 1

    # First evaluation: residuals and Jacobian at the start (the Jacobian scales the
    # regularisation); both are handed to MINPACK for its first call, so nothing is wasted.
    first: dict[str, Any] = {}
    weights = np.zeros(reduced.n)

    # MINPACK sees one more parameter than the problem has, last, whose Jacobian column is zero
    # (see _guard_column): z_ext = [z, guard].
    def fun(z_ext: np.ndarray) -> np.ndarray:
        z = z_ext[:-1]
        if "r" in first and np.array_equal(z, z0):
            r = first.pop("r")
        else:
            count()
            r = reduced.residuals(z)
        c = float(r @ r)
        if c < state["best_f"]:
            state["best_f"] = c
            state["best_z"] = np.array(z, dtype=float)
        history_nfev.append(state["n"])
        history_best.append(state["best_f"])
        if callback is not None and callback(reduced.full(z), c) is True:
            state["stop"] = "stopped by the callback"
            raise _StopLM
        if regularization:
            return np.concatenate([r, weights * (z - z0)])
        return r

    def jac(z_ext: np.ndarray) -> np.ndarray:
        z = z_ext[:-1]
        if "J" in first and np.array_equal(z, z0):
            j = first.pop("J")
        else:
            count()
            j = reduced.jacobian(z)
        if regularization:
            j = np.vstack([j, np.diag(weights)])
        return _guard_column(j)

    sol = None
    stages: list[float] = []
    # Continuation on the Tikhonov weight: a strongly regularised first solve finds the region
    # quickly; the later ones, each started from the previous answer, remove its bias. A single
    # solve at the final, tiny weight crawls along the curved valley of equally good solutions when
    # the start is far from it (thousands of evaluations from a bad start, instead of ~100).
    try:
        count()
        r_first, j_full = problem.residuals_and_jacobian(reduced.full(z0))
        first["r"], first["J"] = r_first, j_full[:, reduced.index]
        norms = np.linalg.norm(first["J"], axis=0)
        floor = 1e-12 * (norms.max() if norms.size and norms.max() > 0 else 1.0)
        if auto:
            regularization = _AUTO_REGULARIZATION if _rank_deficient(first["J"], norms) else 0.0
        stages = [float(regularization)]
        if regularization > 0:
            stages = [s for s in _LM_CONTINUATION if s > regularization] + stages
        z = np.append(z0, 0.0)
        for lam in stages:
            weights = math.sqrt(lam) * np.maximum(norms, floor)
            sol = least_squares(
                fun,
                z,
                jac=jac,
                method="lm",
                xtol=xtol,
                ftol=ftol,
                gtol=gtol,
                max_nfev=max_nfev if max_nfev is not None else 100 * (reduced.n + 1),
                x_scale="jac",
            )
            z = sol.x
            state["nit"] += int(sol.nfev)
    except _StopLM:
        pass
    except KeyboardInterrupt:
        state["stop"] = "interrupted (Ctrl-C)"
    if sol is not None and not state["stop"]:
        x = reduced.full(sol.x[:-1])
        success = bool(sol.status > 0)
        message = str(sol.message)
    else:
        x = reduced.full(state["best_z"])
        success = False
        message = state["stop"]
    if not history_nfev or history_nfev[-1] != state["n"]:
        history_nfev.append(state["n"])
        history_best.append(state["best_f"])
    return IdentificationResult(
        x=x,
        fun=problem.cost(x),
        nfev=int(state["n"]),
        nit=int(state["nit"]),
        success=success,
        message=message,
        history={"nfev": np.array(history_nfev, dtype=np.int64), "best": np.array(history_best)},
        wall_time=time.perf_counter() - start,
        settings={"max_evaluations": int(max_evaluations), "max_nfev": max_nfev, "xtol": xtol,
                  "ftol": ftol, "gtol": gtol, "regularization": stages[-1] if stages else None,
                  "regularization_option": regularization if not auto else "auto"},
    )
