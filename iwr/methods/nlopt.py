"""NLopt baselines on the objective of eq. (10): CRS2 (global) and BOBYQA (local, derivative-free).

Both call the C++ objective through :class:`iwr.ReducedProblem`, so they see exactly the cost that
DE and Levenberg-Marquardt see: ``iwr.identify(..., method="crs2" | "bobyqa")``.

NLopt's own stopping rules are always set (an evaluation limit and tolerances), the random generator
is seeded with ``nlopt.srand``, and the point returned is the best one the objective wrapper has
seen: NLopt (BOBYQA in particular) has been seen returning a point that was not its best.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.optimize import OptimizeResult

from ..result import IdentificationResult
from ._run import INT32_MAX, Monitor, Stop, check_budget, int_arg
from .reduced import ReducedProblem

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


def _run_nlopt(
    reduced: ReducedProblem,
    name: str,
    algorithm_name: str,
    *,
    seed: Any,
    callback: Callable[[OptimizeResult], Any] | None,
    progress: bool | None,
    max_evaluations: Any,
    xtol: Any,
    ftol: Any,
    stopval: Any,
    configure: Callable[[Any, ReducedProblem, np.ndarray], dict[str, Any]],
) -> IdentificationResult:
    import nlopt

    max_evaluations = check_budget(max_evaluations, 1, INT32_MAX)  # NLopt's maxeval: a C int
    xtol = _float_option("xtol", xtol, 0.0)
    ftol = _float_option("ftol", ftol, 0.0)
    if stopval is not None:
        stopval = _float_option("stopval", stopval, -math.inf)
    seed = _seed(seed)

    lower, upper = reduced.lower, reduced.upper
    z_start = reduced.z0
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

    mon = Monitor(reduced, name, max_evaluations, callback, progress)

    def objective(z: np.ndarray, grad: np.ndarray) -> float:
        # NLopt cannot end a run from an exception in the objective: force_stop, and return the
        # best cost so far to its last calls.
        if mon.status:  # NLopt may call again before it notices the forced stop
            return mon.best_f
        try:
            # NLopt's own maxeval is also set; spend() makes the budget exact whatever the
            # algorithm does in its initialisation.
            mon.spend()
            f = reduced.cost(z)
            mon.observe(z, f)
        except Stop:
            opt.force_stop()
            return mon.best_f if math.isfinite(mon.best_f) else 1e300
        except KeyboardInterrupt:
            # Ctrl-C while the objective runs: stop NLopt cleanly, keep the best point so far.
            mon.interrupted()
            opt.force_stop()
            return mon.best_f if math.isfinite(mon.best_f) else 1e300
        return f if math.isfinite(f) else 1e300  # NLopt cannot handle nan; steer away from it

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
        # Ctrl-C outside the objective (between two evaluations): same outcome.
        mon.interrupted()
        code = -5
    except RuntimeError as exc:  # nlopt's generic failure
        code = -1
        mon.stop("failed", f"NLopt failure: {exc}")
    finally:
        mon.close()
    wall = time.perf_counter() - start

    # The answer: the better of NLopt's returned point and the best point the wrapper saw,
    # each cost re-evaluated (not an algorithm evaluation: outside the budget).
    candidates = []
    if mon.best_z is not None:
        candidates.append(mon.best_z)
    if z_ret is not None and z_ret.shape == (reduced.n,) and np.all(np.isfinite(z_ret)):
        candidates.append(z_ret)
    if not candidates:
        candidates.append(z0)
    costs = [reduced.problem.cost(reduced.full(z)) for z in candidates]
    k = int(np.argmin(costs))
    x = reduced.full(candidates[k])
    fun = costs[k]
    returned_not_best = len(candidates) == 2 and k == 0 and costs[1] > costs[0]

    if mon.status:
        status, message = mon.status, mon.message
    else:
        message = _RESULT_TEXT.get(code, f"nlopt result {code}") if code is not None else "?"
        ok = code is not None and 1 <= code <= 4
        status = "converged" if ok else ("stopped" if code in (5, 6) else "failed")
        if code == 5:
            message = f"evaluation budget exhausted (max_evaluations={max_evaluations})"
    if returned_not_best:
        message += f"; NLopt returned a point of cost {costs[1]:.6g}, the best seen was better"

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
        nfev=mon.nfev,
        nit=mon.nfev,
        success=status == "converged",
        status=status,
        message=message,
        history=mon.history(),
        wall_time=wall,
        settings=settings,
    )


def crs2(
    problem: ReducedProblem,
    *,
    max_evaluations: int = DEFAULT_MAX_EVALUATIONS,
    seed: int | None = None,
    callback: Callable[[OptimizeResult], Any] | None = None,
    progress: bool | None = None,
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
    problem : ReducedProblem
        The active parameters; its start ``x0`` (clipped into the bounds) is a member of the
        initial population, and the value of the inactive parameters.
    max_evaluations : int
        Evaluation budget (NLopt's ``maxeval``), respected exactly.
    seed : int, optional
        Passed to ``nlopt.srand``; the same seed gives the same result.
    callback : callable, optional
        ``callback(intermediate_result)`` after every evaluation, with an ``OptimizeResult`` of
        the best point so far (``x`` the full vector, ``fun``, ``nfev``, ``nit``). A truthy return
        or ``StopIteration`` stops the run, which returns that point.
    progress : bool, optional
        A tqdm bar of evaluations against the budget (default: when standard error is a
        terminal).
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
            pop = int_arg("population", population, reduced.n + 1, INT32_MAX)
            opt.set_population(pop)
        return {"population": population if population is not None else 10 * (reduced.n + 1)}

    return _run_nlopt(
        problem, "crs2", "GN_CRS2_LM", seed=seed, callback=callback,
        progress=progress, max_evaluations=max_evaluations, xtol=xtol, ftol=ftol,
        stopval=stopval, configure=configure,
    )


def bobyqa(
    problem: ReducedProblem,
    *,
    max_evaluations: int = DEFAULT_MAX_EVALUATIONS,
    seed: int | None = None,
    callback: Callable[[OptimizeResult], Any] | None = None,
    progress: bool | None = None,
    initial_step: float = 0.1,
    xtol: float = 1e-12,
    ftol: float = 1e-15,
    stopval: float | None = None,
) -> IdentificationResult:
    """Powell's BOBYQA (NLopt ``LN_BOBYQA``): a local, derivative-free trust-region method on
    quadratic models, within the search bounds.

    Parameters
    ----------
    problem : ReducedProblem
        The active parameters; its start ``x0`` is clipped into the bounds.
    max_evaluations, seed, callback, progress, xtol, ftol, stopval
        As for :func:`crs2` (BOBYQA itself is deterministic; the seed is still set).
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
        problem, "bobyqa", "LN_BOBYQA", seed=seed, callback=callback,
        progress=progress, max_evaluations=max_evaluations, xtol=xtol, ftol=ftol,
        stopval=stopval, configure=configure,
    )
