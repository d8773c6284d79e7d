"""NLopt baselines on the objective of eq. (10): CRS2 (global) and BOBYQA (local, derivative-free).

Both call the C++ objective through :class:`iwr.ReducedProblem`, so they see exactly the cost that
DE and Levenberg-Marquardt see. Registered as ``iwr.identify(..., method="crs2" | "bobyqa")``.

NLopt's own stopping rules are always set (an evaluation limit and tolerances), the random generator
is seeded with ``nlopt.srand``, and the point returned is the best one the objective wrapper has
seen: NLopt (BOBYQA in particular) has been seen returning a point that was not its best.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from .identify import ReducedProblem, register_method
from .problem import Problem
from .result import IdentificationResult

__all__ = ["crs2", "bobyqa", "DEFAULT_MAX_EVALUATIONS"]

#: Evaluation budget of the NLopt methods when none is given.
DEFAULT_MAX_EVALUATIONS = 100_000

# nlopt result codes (nlopt.h): >0 success of some kind, <0 failure.
_RESULT_TEXT = {
    1: "success",
    2: "stopval reached",
    3: "ftol reached",
    4: "xtol reached",
    5: "evaluation budget exhausted",
    6: "time limit reached",
    -1: "generic failure",
    -2: "invalid arguments",
    -3: "out of memory",
    -4: "roundoff errors limited progress",
    -5: "forced stop",
}


def _int_option(name: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name}: {value!r}; expected an integer >= {minimum}")
    return int(value)


def _float_option(name: str, value: Any, lo: float, hi: float = math.inf,
                  lo_open: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: {value!r}; expected a number") from None
    bad = not math.isfinite(v) or v > hi or v < lo or (lo_open and v == lo)
    if bad:
        lo_text = f"> {lo}" if lo_open else f">= {lo}"
        hi_text = f" and <= {hi}" if math.isfinite(hi) else ""
        raise ValueError(f"{name}: {value!r}; expected a finite number {lo_text}{hi_text}")
    return v


def _seed(seed: Any) -> int:
    """An explicit seed, or a fresh one drawn from the OS (recorded in the result's settings)."""
    if seed is None:
        return int(np.random.SeedSequence().entropy % (2**32))
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**64:
        raise ValueError(f"seed: {seed!r}; expected a non-negative integer or None")
    return int(seed) % (2**32)  # nlopt.srand takes an unsigned long; keep it portable


class _Objective:
    """The function NLopt minimises: counts evaluations, keeps the best point and its history,
    enforces the budget, calls the user's callback, updates the progress bar, turns Ctrl-C into
    ``opt.force_stop()``."""

    def __init__(self, reduced: ReducedProblem, max_evaluations: int,
                 callback: Callable[..., Any] | None, bar: Any) -> None:
        self.reduced = reduced
        self.max_evaluations = max_evaluations
        self.callback = callback
        self.bar = bar
        self.opt: Any = None
        self.nfev = 0
        self.best_f = math.inf
        self.best_z: np.ndarray | None = None
        self.hist_nfev: list[int] = []
        self.hist_best: list[float] = []
        self.stop_reason = ""
        self._bar_pending = 0

    def _force_stop(self, reason: str) -> None:
        if not self.stop_reason:
            self.stop_reason = reason
        if self.opt is not None:
            self.opt.force_stop()

    def __call__(self, z: np.ndarray, grad: np.ndarray) -> float:
        try:
            return self._evaluate(z)
        except KeyboardInterrupt:
            # Ctrl-C while the objective runs: stop NLopt cleanly, keep the best point so far.
            self._force_stop("interrupted (Ctrl-C)")
            return self.best_f if math.isfinite(self.best_f) else 1e300

    def _evaluate(self, z: np.ndarray) -> float:
        if self.stop_reason:  # NLopt may call again before it notices the forced stop
            return self.best_f
        if self.nfev >= self.max_evaluations:
            # NLopt's own maxeval is also set; this guard makes the budget exact whatever the
            # algorithm does in its initialisation.
            self._force_stop(
                f"evaluation budget exhausted (max_evaluations={self.max_evaluations})"
            )
            return self.best_f
        f = self.reduced.cost(z)
        self.nfev += 1
        if not math.isfinite(f):
            f = 1e300  # NLopt's algorithms cannot handle nan; a huge cost steers them away
        if f < self.best_f:
            self.best_f = f
            self.best_z = np.array(z, dtype=float)
            self.hist_nfev.append(self.nfev)
            self.hist_best.append(f)
        if self.bar is not None:
            self._bar_pending += 1
            if self._bar_pending >= 512:
                self.bar.update(self._bar_pending)
                self.bar.set_postfix_str(f"best {self.best_f:.4g}", refresh=False)
                self._bar_pending = 0
        if self.callback is not None and self.callback(self.reduced.full(z), f) is True:
            self._force_stop("stopped by the callback")
        return f

    def close_bar(self) -> None:
        if self.bar is not None:
            self.bar.update(self._bar_pending)
            self.bar.set_postfix_str(f"best {self.best_f:.4g}", refresh=False)
            self.bar.close()


def _run_nlopt(
    problem: Problem,
    name: str,
    algorithm_name: str,
    *,
    x0: np.ndarray,
    active: np.ndarray,
    seed: Any,
    callback: Callable[..., Any] | None,
    progress: bool | None,
    max_evaluations: Any,
    xtol: Any,
    ftol: Any,
    stopval: Any,
    configure: Callable[[Any, ReducedProblem, np.ndarray], dict[str, Any]],
) -> IdentificationResult:
    import nlopt

    max_evaluations = _int_option("max_evaluations", max_evaluations, 1)
    xtol = _float_option("xtol", xtol, 0.0)
    ftol = _float_option("ftol", ftol, 0.0)
    if stopval is not None:
        stopval = _float_option("stopval", stopval, -math.inf)
    seed = _seed(seed)

    reduced = ReducedProblem(problem, active, x0)
    lower, upper = reduced.lower, reduced.upper
    z_start = reduced.reduce(x0)
    # The start must lie within the bounds for NLopt; a point outside them is clipped, and said so.
    z0 = np.clip(z_start, lower, upper)
    clipped = int(np.count_nonzero(z0 != z_start))

    opt = nlopt.opt(getattr(nlopt, algorithm_name), reduced.n)
    opt.set_lower_bounds(lower)
    opt.set_upper_bounds(upper)
    opt.set_maxeval(max_evaluations)
    # Tolerances: on x relative to the width of each parameter's bounds (the parameters mix mm and
    # rad, so a relative tolerance on x itself would be meaningless near zero), on f relative.
    opt.set_xtol_abs(xtol * (upper - lower))
    opt.set_ftol_rel(ftol)
    if stopval is not None:
        opt.set_stopval(stopval)
    extra = configure(opt, reduced, z0)

    show = sys.stderr.isatty() if progress is None else bool(progress)
    bar = None
    if show:
        from tqdm.auto import tqdm

        bar = tqdm(total=max_evaluations, desc=name, unit="eval", unit_scale=True, leave=False)
    objective = _Objective(reduced, max_evaluations, callback, bar)
    objective.opt = opt
    opt.set_min_objective(objective)

    nlopt.srand(seed)  # CRS2's random population and mutations; BOBYQA is deterministic
    start = time.perf_counter()
    z_ret: np.ndarray | None = None
    code: int | None = None
    try:
        z_ret = np.asarray(opt.optimize(z0), dtype=float)
        code = int(opt.last_optimize_result())
    except nlopt.ForcedStop:
        code = -5
    except nlopt.RoundoffLimited:
        code = -4
    except KeyboardInterrupt:
        # Ctrl-C outside the objective's try block (between two evaluations): same outcome.
        objective.stop_reason = objective.stop_reason or "interrupted (Ctrl-C)"
        code = -5
    except RuntimeError as exc:  # nlopt's generic failure
        code = -1
        objective.stop_reason = objective.stop_reason or f"NLopt failure: {exc}"
    finally:
        objective.close_bar()
    wall = time.perf_counter() - start

    # The answer: the better of NLopt's returned point and the best point the wrapper saw,
    # each cost re-evaluated (not an algorithm evaluation: outside the budget).
    candidates = []
    if objective.best_z is not None:
        candidates.append(objective.best_z)
    if z_ret is not None and z_ret.shape == (reduced.n,) and np.all(np.isfinite(z_ret)):
        candidates.append(z_ret)
    if not candidates:
        candidates.append(z0)
    costs = [problem.cost(reduced.full(z)) for z in candidates]
    k = int(np.argmin(costs))
    x = reduced.full(candidates[k])
    fun = costs[k]
    returned_not_best = len(candidates) == 2 and k == 0 and costs[1] > costs[0]

    if objective.stop_reason:
        message = objective.stop_reason
        success = False
    else:
        message = _RESULT_TEXT.get(code, f"nlopt result {code}") if code is not None else "?"
        success = code is not None and 1 <= code <= 4
        if code == 5:
            message = f"evaluation budget exhausted (max_evaluations={max_evaluations})"
    if returned_not_best:
        message += f"; NLopt returned a point of cost {costs[1]:.6g}, the best seen was better"

    hist_nfev = list(objective.hist_nfev)
    hist_best = list(objective.hist_best)
    if not hist_nfev or hist_nfev[-1] != objective.nfev:
        # Close the curve at the last evaluation, so a plot shows where the run ended.
        hist_nfev.append(objective.nfev)
        hist_best.append(objective.best_f)
    settings = {
        "algorithm": algorithm_name,
        "max_evaluations": max_evaluations,
        "xtol": xtol,
        "ftol": ftol,
        "stopval": stopval,
        "seed": seed,
        "x0_clipped_to_bounds": clipped,
        "nlopt_result": code,
        **extra,
    }
    return IdentificationResult(
        x=x,
        fun=fun,
        nfev=objective.nfev,
        nit=objective.nfev,
        success=bool(success),
        message=message,
        history={"nfev": np.array(hist_nfev, dtype=np.int64), "best": np.array(hist_best)},
        wall_time=wall,
        settings=settings,
    )


@register_method("crs2")
def crs2(
    problem: Problem,
    *,
    x0: np.ndarray,
    active: np.ndarray,
    seed: int | None = None,
    callback: Callable[..., Any] | None = None,
    progress: bool | None = None,
    max_evaluations: int = DEFAULT_MAX_EVALUATIONS,
    population: int | None = None,
    xtol: float = 1e-12,
    ftol: float = 1e-15,
    stopval: float | None = None,
) -> IdentificationResult:
    """Controlled random search with local mutation (NLopt ``GN_CRS2_LM``, Kaelo & Ali 2006).

    A global method within the search bounds: a random population (``x0``, clipped into the bounds,
    is one of its points) evolves by reflections of simplexes through their centroid.

    Parameters
    ----------
    problem : Problem
    x0 : ndarray
        A member of the initial population; the value of inactive parameters.
    active : ndarray of bool
    seed : int, optional
        Passed to ``nlopt.srand``; the same seed gives the same result.
    callback : callable, optional
        ``callback(x, cost)`` after every evaluation (``x`` the full parameter vector); returning
        ``True`` stops the run (the best point so far is returned).
    progress : bool, optional
        A tqdm bar over evaluations (default: when standard error is a terminal).
    max_evaluations : int
        Evaluation budget (NLopt's ``maxeval``), respected exactly.
    population : int, optional
        Population size; NLopt's default is ``10 (n + 1)``.
    xtol : float
        Stop when the best point moves by less than ``xtol`` times the width of the bounds, in
        every parameter.
    ftol : float
        Stop when the best cost improves by less than ``ftol`` relative.
    stopval : float, optional
        Stop when the cost reaches this value.

    Returns
    -------
    IdentificationResult
        ``history`` has the best cost after each improvement (``nfev``, ``best``). ``success``
        is True when a tolerance or ``stopval`` ended the run, False when the budget did.
    """

    def configure(opt: Any, reduced: ReducedProblem, z0: np.ndarray) -> dict[str, Any]:
        if population is not None:
            pop = _int_option("population", population, reduced.n + 1)
            opt.set_population(pop)
        return {"population": population if population is not None else 10 * (reduced.n + 1)}

    return _run_nlopt(
        problem, "crs2", "GN_CRS2_LM", x0=x0, active=active, seed=seed, callback=callback,
        progress=progress, max_evaluations=max_evaluations, xtol=xtol, ftol=ftol,
        stopval=stopval, configure=configure,
    )


@register_method("bobyqa")
def bobyqa(
    problem: Problem,
    *,
    x0: np.ndarray,
    active: np.ndarray,
    seed: int | None = None,
    callback: Callable[..., Any] | None = None,
    progress: bool | None = None,
    max_evaluations: int = DEFAULT_MAX_EVALUATIONS,
    initial_step: float = 0.1,
    xtol: float = 1e-12,
    ftol: float = 1e-15,
    stopval: float | None = None,
) -> IdentificationResult:
    """Powell's BOBYQA (NLopt ``LN_BOBYQA``): a local, derivative-free trust-region method on
    quadratic models, within the search bounds.

    Parameters
    ----------
    problem : Problem
    x0 : ndarray
        The starting point (clipped into the bounds); the value of inactive parameters.
    active : ndarray of bool
    seed : int, optional
        Passed to ``nlopt.srand`` (BOBYQA itself is deterministic).
    callback, progress, max_evaluations, xtol, ftol, stopval
        As for :func:`crs2`.
    initial_step : float
        Initial trust-region radius per parameter, as a fraction of the width of its bounds
        (0 < initial_step <= 0.5). NLopt rescales the parameters by these steps, so lengths (mm)
        and angles (rad) are treated alike.

    Notes
    -----
    BOBYQA's own linear algebra (``2 n + 1`` interpolation points) costs about a millisecond per
    evaluation at n = 58, a hundred times the objective: its wall time is mostly its own.
    """

    def configure(opt: Any, reduced: ReducedProblem, z0: np.ndarray) -> dict[str, Any]:
        step = _float_option("initial_step", initial_step, 0.0, 0.5, lo_open=True)
        opt.set_initial_step(step * (reduced.upper - reduced.lower))
        return {"initial_step": step}

    return _run_nlopt(
        problem, "bobyqa", "LN_BOBYQA", x0=x0, active=active, seed=seed, callback=callback,
        progress=progress, max_evaluations=max_evaluations, xtol=xtol, ftol=ftol,
        stopval=stopval, configure=configure,
    )
