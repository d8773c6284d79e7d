"""Differential evolution: the paper's DE/rand/1/bin and modern variants, on the C++ engine.

Two entry points share one engine (``cpp/src/de.cpp``, documented in ``cpp/include/iwr/de.hpp``):

- ``iwr.identify(robot, measurements, method="de", ...)``: the calibration on any kind of data,
  the engine running on the problem's own C++ objective (``problem.engine_objective()``: eq.
  (10), the tracker's points or probe, the ballbar's distances, with effects, weighted or not)
  with no Python in the loop, as ``iwr-engine`` runs it on the problem's file;
- :func:`differential_evolution`: any function that takes an (M, D) population and returns M costs,
  called once per generation; its result is shaped like ``scipy.optimize.differential_evolution``'s.

Strategies (``strategy=``), each with its published defaults (``None`` arguments take them):

========  ============================================================  ======================
name      rule                                                          reference
========  ============================================================  ======================
rand1bin  eq. (11)-(14): m = x_r1 + F (x_r2 - x_r3), binomial crossover  Storn & Price 1997
best1bin  m = x_best + F (x_r1 - x_r2)                                  Storn & Price 1997
jade      current-to-pbest/1 with archive, adaptive mu_F, mu_CR         Zhang & Sanderson 2009
jde       rand/1/bin with self-adapted F_i, CR_i                        Brest et al. 2006
shade     current-to-pbest/1, success-history memories of F and CR      Tanabe & Fukunaga 2013
lshade    SHADE with linear population size reduction                   Tanabe & Fukunaga 2014
jso       L-SHADE with weighted mutation and parameter schedules        Brest et al. 2017
========  ============================================================  ======================

Full references: R. Storn, K. Price, J. Global Optim. 11:341-359 (1997); J. Zhang, A. C. Sanderson,
IEEE TEC 13(5):945-958 (2009); J. Brest et al., IEEE TEC 10(6):646-657 (2006); R. Tanabe,
A. Fukunaga, IEEE CEC 2013, 71-78; IEEE CEC 2014, 1658-1665; J. Brest, M. S. Maucec, B. Boskovic,
IEEE CEC 2017, 1311-1318.

Every strategy updates the population by generations (deferred update), selects by ``<=``
(eq. 14) and repairs a trial component that leaves the bounds by the midpoint between the parent's
component and the violated bound (JADE's rule; ``bound_rule="reinit"`` draws it uniformly again as
SciPy does, ``"reflect"`` and ``"clip"`` also exist). Runs are reproducible: the same ``seed`` gives
bit-identical results with any number of ``workers``.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.optimize import Bounds, OptimizeResult

from .. import _core
from ..result import IdentificationResult
from ._run import INT32_MAX, INT64_MAX, call_back, check_budget, int_arg
from .lm import levenberg_marquardt
from .reduced import ReducedProblem

__all__ = ["differential_evolution", "de_method", "STRATEGIES", "PAPER_PRESET"]

STRATEGIES = ("rand1bin", "best1bin", "jade", "jde", "shade", "lshade", "jso")

#: The paper's Table 2: DE/rand/1/bin with NP = 600, F = 0.9, CR = 1.0 for 60000 generations.
PAPER_PRESET = {"population_size": 600, "F": 0.9, "CR": 1.0, "generations": 60000}

#: Generations run when no limit is given, for the strategies without an evaluation budget.
DEFAULT_GENERATIONS = 1000

# Strategy parameters passed to the engine as they are (see cpp/include/iwr/de.hpp).
_STRATEGY_OPTIONS = (
    "p_best", "c", "archive_rate", "memory_size", "tau1", "tau2", "F_lower", "F_upper",
    "min_population_size",
)
_BUDGETED = ("lshade", "jso")  # their schedules run to an evaluation budget
_INTERVAL = 0.1  # seconds between Ctrl-C checks and progress-bar updates


def _float_arg(name: str, value: Any) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: {value!r}; expected a number") from None
    if math.isnan(out):
        raise ValueError(f"{name}: nan; expected a number")
    return out


def _seed_arg(seed: Any) -> int:
    if seed is None:
        # A fresh seed, recorded in the result's settings so the run can be repeated.
        return int(np.random.SeedSequence().generate_state(1, np.uint64)[0])
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)):
        raise ValueError(f"seed: {seed!r}; expected an integer in [0, 2**64) or None")
    if not 0 <= int(seed) < 2**64:
        raise ValueError(f"seed: {seed}; expected an integer in [0, 2**64) or None")
    return int(seed)


def _bounds_arg(bounds: Any) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(bounds, Bounds):
        lower = np.atleast_1d(np.asarray(bounds.lb, dtype=float))
        upper = np.atleast_1d(np.asarray(bounds.ub, dtype=float))
        lower, upper = np.broadcast_arrays(lower, upper)
    else:
        try:
            arr = np.asarray(bounds, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f"bounds: {bounds!r}; expected (D, 2) pairs (min, max)") from None
        if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] < 1:
            raise ValueError(f"bounds: shape {arr.shape}; expected (D, 2) pairs (min, max)")
        lower, upper = arr[:, 0], arr[:, 1]
    for j, (lo, hi) in enumerate(zip(lower, upper, strict=True)):
        if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
            raise ValueError(
                f"bounds: parameter {j} has (min, max) = ({lo}, {hi}); expected finite min < max"
            )
    return np.ascontiguousarray(lower, dtype=float), np.ascontiguousarray(upper, dtype=float)


class _Run:
    """Arguments checked and defaults chosen once, for both entry points."""

    def __init__(
        self,
        dim: int,
        *,
        strategy: str,
        population_size: Any,
        F: Any,
        CR: Any,
        generations: Any,
        seed: Any,
        workers: Any,
        options: dict[str, Any],
    ) -> None:
        if not isinstance(strategy, str) or strategy not in STRATEGIES:
            raise ValueError(f"strategy: {strategy!r}; expected one of {', '.join(STRATEGIES)}")
        self.strategy = strategy
        self.population_size = (
            0 if population_size is None
            else int_arg("population_size", population_size, 1, INT32_MAX)
        )
        self.F = math.nan if F is None else _float_arg("F", F)
        if F is not None and not self.F > 0:
            raise ValueError(f"F: {F!r}; expected F > 0")
        self.CR = math.nan if CR is None else _float_arg("CR", CR)
        if CR is not None and not 0 <= self.CR <= 1:
            raise ValueError(f"CR: {CR!r}; expected 0 <= CR <= 1")
        self.seed = _seed_arg(seed)
        if workers is None:
            self.threads = 0
        else:
            self.threads = int_arg("workers", workers, 1, INT32_MAX)
        options = dict(options)
        self.bound_rule = options.pop("bound_rule", "midpoint")
        if self.bound_rule not in ("midpoint", "reinit", "reflect", "clip"):
            raise ValueError(
                f"bound_rule: {self.bound_rule!r}; expected 'midpoint', 'reinit', 'reflect' or "
                "'clip'"
            )
        self.extra: dict[str, Any] = {}
        for key in _STRATEGY_OPTIONS:
            if key in options:
                value = options.pop(key)
                if value is not None:
                    if key in ("memory_size", "min_population_size"):
                        value = int_arg(key, value, 1, INT32_MAX)
                    else:
                        value = _float_arg(key, value)
                    self.extra[key] = value
        max_evaluations = options.pop("max_evaluations", None)
        if max_evaluations is not None:
            max_evaluations = int_arg("max_evaluations", max_evaluations, 1, INT64_MAX)
        if generations is not None:
            generations = int_arg("generations", generations, 0, INT64_MAX)
        # lshade and jso plan their schedules over an evaluation budget (default 10000 D, the CEC
        # budget); the other strategies run DEFAULT_GENERATIONS unless told otherwise.
        if strategy in _BUDGETED:
            if max_evaluations is None:
                max_evaluations = 10000 * dim
            self.extra["max_evaluations"] = max_evaluations
        elif generations is None and max_evaluations is None:
            generations = DEFAULT_GENERATIONS
        self.generations = generations
        self.max_evaluations = max_evaluations
        target = options.pop("target_cost", None)
        self.target_cost = -math.inf if target is None else _float_arg("target_cost", target)
        self.tol = _float_arg("tol", options.pop("tol", 0.0))
        self.atol = _float_arg("atol", options.pop("atol", 0.0))
        stag = options.pop("stagnation_generations", None)
        self.stagnation_generations = 0 if stag is None else int_arg(
            "stagnation_generations", stag, 1, INT64_MAX
        )
        self.stagnation_tol = _float_arg("stagnation_tol", options.pop("stagnation_tol", 0.0))
        max_seconds = options.pop("max_seconds", None)
        self.max_seconds = (
            math.inf if max_seconds is None else _float_arg("max_seconds", max_seconds)
        )
        self.resume = options.pop("resume", None)
        self.return_state = bool(options.pop("return_state", False))
        if options:
            raise TypeError(f"unexpected option(s): {', '.join(sorted(options))}")

    def core_args(self, lower: np.ndarray, upper: np.ndarray) -> dict[str, Any]:
        return {
            "strategy": self.strategy,
            "lower": lower,
            "upper": upper,
            "seed": self.seed,
            "population_size": self.population_size,
            "F": self.F,
            "CR": self.CR,
            "bound_rule": self.bound_rule,
            "extra": self.extra,
            "max_generations": -1 if self.generations is None else self.generations,
            "max_evaluations": -1 if self.max_evaluations is None else self.max_evaluations,
            "target_cost": self.target_cost,
            "tol": self.tol,
            "atol": self.atol,
            "stagnation_generations": self.stagnation_generations,
            "stagnation_tol": self.stagnation_tol,
            "max_seconds": self.max_seconds,
            "threads": self.threads,
            "interval": _INTERVAL,
            "resume": self.resume,
            "return_state": self.return_state,
        }

    def stop_settings(self) -> dict[str, Any]:
        return {
            "generations": self.generations,
            "max_evaluations": self.max_evaluations,
            # None for "not set", so that the settings are plain JSON (no infinities).
            "target_cost": None if math.isinf(self.target_cost) else self.target_cost,
            "tol": self.tol,
            "atol": self.atol,
            "stagnation_generations": self.stagnation_generations or None,
            "stagnation_tol": self.stagnation_tol,
            "max_seconds": None if math.isinf(self.max_seconds) else self.max_seconds,
            "workers": self.threads or None,
        }

    def settings(self, raw: dict[str, Any]) -> dict[str, Any]:
        """A run's settings: the engine's resolved ones, the stopping criteria, ``workers`` as
        given and ``threads``, the engine's (the calling thread included)."""
        return {**raw["settings"], **self.stop_settings(), "threads": int(raw["threads"])}

    def execute(
        self,
        core: Callable[..., dict[str, Any]],
        core_args: dict[str, Any],
        x_map: Callable[[np.ndarray], np.ndarray],
        callback: Callable[..., Any] | None,
        progress: bool | None,
    ) -> dict[str, Any]:
        show = sys.stderr.isatty() if progress is None else bool(progress)
        bar = None
        if show:
            from tqdm import tqdm

            if self.generations is not None:
                bar = tqdm(total=self.generations, unit="gen", desc=f"DE {self.strategy}",
                           file=sys.stderr, dynamic_ncols=True)
            else:
                bar = tqdm(total=self.max_evaluations, unit="ev", unit_scale=True,
                           desc=f"DE {self.strategy}", file=sys.stderr, dynamic_ncols=True)

        def monitor(s: dict[str, Any]) -> bool:
            if bar is not None:
                done = s["generation"] if self.generations is not None else s["nfev"]
                bar.update(max(0, min(done, bar.total) - bar.n))
                bar.set_postfix(best=f"{s['best']:.3e}", refresh=False)
            if callback is None:
                return False
            info = OptimizeResult(
                x=x_map(s["x"]), fun=s["best"], nit=s["generation"], nfev=s["nfev"],
                mean=s["mean"], spread=s["spread"], population_size=s["population_size"],
                elapsed=s["elapsed"],
            )
            return call_back(callback, info)

        use_monitor = bar is not None or callback is not None
        try:
            raw = core(
                **core_args,
                monitor=monitor if use_monitor else None,
                every_generation=callback is not None,
            )
        finally:
            if bar is not None:
                bar.close()
        return raw


def differential_evolution(
    func: Callable[[np.ndarray], Any],
    bounds: Any,
    *,
    strategy: str = "rand1bin",
    population_size: int | None = None,
    F: float | None = None,
    CR: float | None = None,
    generations: int | None = None,
    seed: int | None = None,
    workers: int | None = None,
    callback: Callable[[OptimizeResult], Any] | None = None,
    progress: bool | None = False,
    **options: Any,
) -> OptimizeResult:
    """Minimise ``func`` over a box by differential evolution (C++ engine).

    Parameters
    ----------
    func : callable
        ``func(X)`` with ``X`` an (M, D) float array, one candidate per row, returns M costs. It is
        called once per generation with the whole population (M = NP; the initial population is
        the first call), except that the last generation of an evaluation budget
        (``max_evaluations``) may pass fewer rows. NaN costs count as +infinity (the worst); a
        cost of -infinity is a ValueError naming the vector (it is no minimum).
    bounds : sequence of (min, max) pairs, or scipy.optimize.Bounds
        The search box; finite, ``min < max``.
    strategy : str
        One of ``"rand1bin"`` (the paper's DE/rand/1/bin), ``"best1bin"``, ``"jade"``, ``"jde"``,
        ``"shade"``, ``"lshade"``, ``"jso"``; see the module docstring.
    population_size : int, optional
        NP (the initial NP of ``lshade`` and ``jso``). Unlike SciPy's ``popsize``, this is the
        number of individuals, not a multiplier of D. Default: the strategy's published one
        (rand1bin, best1bin: 10 D; jade: 30/100/400; jde, shade: 100; lshade: 18 D;
        jso: 25 ln(D) sqrt(D)).
    F, CR : float, optional
        rand1bin, best1bin: the scale factor (> 0) and crossover rate (in [0, 1]); default 0.5, 0.9
        (Storn & Price). Adaptive strategies: the initial value of what they adapt.
    generations : int, optional
        Stop after this many generations. Default: 1000, except for ``lshade`` and ``jso``, which
        stop at their evaluation budget ``max_evaluations`` (default 10000 D).
    seed : int, optional
        The same seed gives bit-identical results whatever ``workers``. Default: a fresh seed,
        recorded in ``result.settings["seed"]``.
    workers : int, optional
        Threads of the engine (the trial generation; a Python ``func`` runs in the calling thread).
        Default: all cores.
    callback : callable, optional
        ``callback(intermediate_result)``, every generation, with an ``OptimizeResult`` holding
        ``x``, ``fun`` (the best so far), ``nit``, ``nfev``, ``mean``, ``spread``. Returning True
        or raising ``StopIteration`` stops the run (as in SciPy).
    progress : bool, optional
        A tqdm progress bar on standard error (default off here; ``None``: when it is a terminal).
    **options
        ``max_evaluations``; ``target_cost`` (stop when the best cost, finite, is <= it; no target
        by default); ``tol``, ``atol``
        (SciPy's test ``std(costs) <= atol + tol |mean(costs)|``, off by default);
        ``stagnation_generations`` and ``stagnation_tol`` (stop when the best improved by no more
        than ``stagnation_tol |best|`` over that many generations); ``max_seconds``;
        ``bound_rule``; strategy parameters ``p_best``, ``c``, ``archive_rate``, ``memory_size``,
        ``tau1``, ``tau2``, ``F_lower``, ``F_upper``, ``min_population_size``; ``return_state``
        (the engine's serialized state in ``result.state``) and ``resume`` (such a state, to
        continue a run bit-identically; its settings must be the ones given).

    Returns
    -------
    OptimizeResult
        ``x``, ``fun``, ``nfev``, ``nit`` (generations), ``success`` (True when a target, ``tol``
        or stagnation test stopped the run; a spent budget is not success, as in SciPy, nor a run
        that found no finite cost, which its message says),
        ``message``, ``population``, ``population_energies``, ``history`` (per generation:
        ``generation``, ``nfev``, ``best``, ``mean``, ``spread``, ``elapsed``), ``settings`` and
        ``wall_time``. Ctrl-C stops the run within a fraction of a second and returns the best so
        far, with ``success`` False and ``message`` saying so.

    Raises
    ------
    ValueError
        A bad argument, named with its value (NP below what the strategy needs, F <= 0, CR outside
        [0, 1], an integer argument that is not one or is beyond the engine's integer types or
        the machine's threads, bad bounds, an unknown strategy, a wrong shape returned by
        ``func``, a cost of -inf).
    """
    lower, upper = _bounds_arg(bounds)
    if not callable(func):
        raise ValueError(f"func: {func!r} is not callable")
    run = _Run(
        lower.size, strategy=strategy, population_size=population_size, F=F, CR=CR,
        generations=generations, seed=seed, workers=workers, options=options,
    )
    start = time.perf_counter()
    raw = run.execute(
        _core.de_function, {"func": func, **run.core_args(lower, upper)},
        lambda z: np.array(z), callback, progress,
    )
    out = OptimizeResult(
        x=np.asarray(raw["x"]),
        fun=float(raw["fun"]),
        nfev=int(raw["nfev"]),
        nit=int(raw["nit"]),
        success=bool(raw["success"]),
        message=str(raw["message"]),
        population=np.asarray(raw["population"]),
        population_energies=np.asarray(raw["population_costs"]),
        history={k: np.asarray(v) for k, v in raw["history"].items()},
        settings=run.settings(raw),
        reason=raw["reason"],
        wall_time=time.perf_counter() - start,
    )
    if "state" in raw:
        out["state"] = bytes(raw["state"])
    return out


# How the engine's stop reasons map to IdentificationResult.status.
_STATUS = {
    "target": "converged", "converged": "converged", "stagnation": "converged",
    "generations": "stopped", "evaluations": "stopped", "time": "stopped",
    "callback": "callback", "interrupted": "interrupted",
}


def de_method(
    problem: ReducedProblem,
    *,
    max_evaluations: int | None = None,
    seed: int | None = None,
    callback: Callable[[OptimizeResult], Any] | None = None,
    progress: bool | None = None,
    strategy: str = "rand1bin",
    population_size: int | None = None,
    F: float | None = None,
    CR: float | None = None,
    generations: int | None = None,
    preset: str | None = None,
    workers: int | None = None,
    polish: bool = True,
    **options: Any,
) -> IdentificationResult:
    """``iwr.identify(..., method="de")``: differential evolution on the problem's objective
    (any kind's: eq. (10), the tracker's points or probe, the ballbar's distances; with effects,
    weighted or not), polished by Levenberg-Marquardt.

    The active parameters are searched within the problem's bounds (``identify(bounds=...)``);
    the others stay at ``x0``. The engine runs on the problem's C++ objective
    (``problem.engine_objective()``, the one ``iwr-engine`` runs on the problem's file) on
    ``workers`` threads with no Python in the loop; a problem without one has its
    ``cost_batch`` called once per generation (on ``workers`` threads too).

    Parameters
    ----------
    problem : ReducedProblem
        The problem (a :class:`iwr.problem_base.LeastSquaresProblem` of any kind) over its
        active parameters.
    max_evaluations : int, optional
        Evaluation budget of the evolution (the last generation may be partial). Without it (and
        without ``generations``), 1000 generations; ``lshade`` and ``jso`` plan their schedules
        over it (default 10000 D). The polish adds its own evaluations, at most ``100 (n + 1)``.
    seed : int, optional
        The same seed gives bit-identical results whatever ``workers``; default a fresh one,
        recorded in ``settings["seed"]``.
    callback : callable, optional
        ``callback(intermediate_result)`` every generation, with an ``OptimizeResult`` of the best
        point so far (``x`` the full vector, ``fun``, ``nit``, ``nfev``, ``mean``, ``spread``); a
        truthy return or ``StopIteration`` stops the run (and skips the polish).
    progress : bool, optional
        A tqdm bar (default: when standard error is a terminal).
    strategy, population_size, F, CR, generations, workers, **options
        As for :func:`iwr.differential_evolution` (``target_cost=1e-4`` stops at the paper's final
        cost, for example); ``generations`` stops after that many generations.
    preset : {"paper"}, optional
        The paper's Table 2 for DE/rand/1/bin: NP = 600, F = 0.9, CR = 1.0, 60000 generations
        (36 million evaluations). Explicit arguments override the preset's values. The preset
        leaves the bounds alone: Table 2's literal +-0.5 for every parameter (+-0.5 rad for angles)
        is ``identify(bounds="paper")``; the default bounds are +-0.5 mm and +-0.5 degree.
    polish : bool
        Refine the DE result by Levenberg-Marquardt on the exact Jacobian
        (:func:`iwr.methods.lm.levenberg_marquardt`, unbounded) and keep the better point
        (default). ``success`` and ``status`` are then the polish's. ``polish=False``: DE alone.

    Returns
    -------
    IdentificationResult
        ``history`` is the per-generation log (``generation``, ``nfev``, ``best``, ``mean``,
        ``spread``, ``elapsed``); ``settings`` holds every resolved setting, the seed included,
        and ``threads``, the engine's (the calling thread included); ``reason`` the engine's
        stop reason. Ctrl-C (in the evolution or the polish) returns the
        best point so far, ``status`` "interrupted".
    """
    if preset is not None:
        if preset != "paper":
            raise ValueError(f"preset: {preset!r}; expected 'paper' or None")
        if strategy != "rand1bin":
            raise ValueError(
                f"preset: 'paper' is the paper's DE/rand/1/bin; got strategy {strategy!r}"
            )
        if population_size is None:
            population_size = PAPER_PRESET["population_size"]
        F = PAPER_PRESET["F"] if F is None else F
        CR = PAPER_PRESET["CR"] if CR is None else CR
        if generations is None:
            generations = PAPER_PRESET["generations"]
    if max_evaluations is not None:
        options["max_evaluations"] = check_budget(max_evaluations, 1, INT64_MAX)
    reduced = problem
    run = _Run(
        reduced.n, strategy=strategy, population_size=population_size, F=F, CR=CR,
        generations=generations, seed=seed, workers=workers, options=options,
    )
    start = time.perf_counter()
    box = run.core_args(np.ascontiguousarray(reduced.lower), np.ascontiguousarray(reduced.upper))
    objective = reduced.problem.engine_objective()
    if objective is not None:
        # The problem's own C++ objective, whatever its kind: the engine evaluates each thread's
        # trials as it builds them, on `workers` threads, with no Python in the loop.
        raw = run.execute(_core.de_kernel, {
            "kernel": objective, "active": [bool(a) for a in reduced.active],
            "x0": np.ascontiguousarray(reduced.x0, dtype=float), **box,
        }, reduced.full, callback, progress)
    else:  # a problem without one: its cost_batch once per generation, on the same threads
        threads = run.threads or None
        raw = run.execute(_core.de_function, {
            "func": lambda z: reduced.cost_batch(z, threads), **box,
        }, reduced.full, callback, progress)
    x = reduced.full(raw["x"])
    fun = float(raw["fun"])
    nfev = int(raw["nfev"])
    reason = str(raw["reason"])
    status = _STATUS.get(reason, "failed")
    success = bool(raw["success"])
    message = str(raw["message"])
    settings: dict[str, Any] = {
        **run.settings(raw), "preset": preset, "polish": bool(polish),
    }
    # No polish after Ctrl-C or a callback's stop: both ask for the run to end now.
    if polish and status not in ("interrupted", "callback"):
        lm = levenberg_marquardt(ReducedProblem(reduced.problem, reduced.active, x),
                                 progress=progress)
        settings["polish_result"] = {
            "fun_before": fun, "fun": float(lm.fun), "nfev": int(lm.nfev),
            "nit": int(lm.nit), "success": bool(lm.success), "message": str(lm.message),
        }
        nfev += int(lm.nfev)
        success, status = bool(lm.success), str(lm.status)
        message = f"{message}; polished by Levenberg-Marquardt: {lm.message}"
        if lm.fun <= fun:
            x, fun = lm.x, float(lm.fun)
    out = IdentificationResult(
        x=x,
        fun=fun,
        nfev=nfev,
        nit=int(raw["nit"]),
        success=success,
        status=status,
        message=message,
        history={k: np.asarray(v) for k, v in raw["history"].items()},
        wall_time=time.perf_counter() - start,
        settings=settings,
        reason=reason,
    )
    if "state" in raw:
        out["state"] = bytes(raw["state"])
    return out
