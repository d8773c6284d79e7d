"""``iwr compare``: every identification method on the same simulated problems, one evaluation
budget, and a report.

For each scenario (``"near"``: the nominal robot as the start, errors within the default bounds;
``"bad"``: large errors and a start near the bounds) and each seed, a robot with random errors is
simulated at ``n_poses`` poses with measurement noise, and every method identifies it from the same
start under the same evaluation budget. A method is a registered name (``lm``, ``de``, ``crs2``,
``bobyqa``; ``de`` is the paper's DE/rand/1/bin) or ``de:STRATEGY``, a modern DE variant such as
``de:jso``; the default list is :data:`DEFAULT_METHODS`. Per run: the final cost (eq. 10), the
validation RMS of the leg readings on fresh poses, the error of the recovered parameters (on the
identifiable part and raw), evaluations, wall time, and success (cost near the noise floor). The
report in ``out_dir``: ``report.html`` (self-contained), ``report.md`` with the PNG figures beside
it, ``runs.csv``, ``summary.csv`` and ``results.json``.

Run it as ``iwr compare`` or ``python -m iwr.compare``.
"""

from __future__ import annotations

import argparse
import base64
import csv
import html
import io
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ._blas import single_thread
from ._io import atomic_write_bytes, atomic_write_text, jsonable
from .identify import METHODS, identify
from .measurements import Measurements
from .problem import Problem, predict_legs
from .robot import Robot
from .simulate import Noise, sample_poses, simulate

__all__ = [
    "compare_methods",
    "Comparison",
    "SCENARIOS",
    "add_compare_parser",
    "run_compare",
    "main",
    "DEFAULT_BUDGET",
    "DEFAULT_METHODS",
    "default_methods",
    "split_method",
]

#: Scenarios: what is simulated and where the methods start.
SCENARIOS: dict[str, str] = {
    "near": (
        "errors uniform within the default bounds (+-0.5 mm, +-0.5 degree); every method starts "
        "from the nominal robot (all errors zero), the usual calibration situation"
    ),
    "bad": (
        "large errors, uniform within the paper's Table 2 bounds taken literally (+-0.5 mm for "
        "lengths, +-0.5 rad for angles), searched within those bounds; every parameter starts at "
        "90% of its bound on the side opposite to its true value"
    ),
}

#: Evaluation budget of every method, per run, when none is given.
DEFAULT_BUDGET = 20_000
#: Methods compared when none are given (then any other registered method): Levenberg-Marquardt,
#: the paper's DE/rand/1/bin with Storn & Price's defaults, jSO (the DE variant that converges
#: fastest on IWR, docs/de.md), CRS2 and BOBYQA. ``"de:STRATEGY"`` is DE with that strategy.
DEFAULT_METHODS = ("lm", "de", "de:jso", "crs2", "bobyqa")
DEFAULT_SEEDS = (0, 1, 2)
DEFAULT_OUT = "iwr-compare"
_BOUNDS = {"near": "default", "bad": "paper"}
_BAD_START_FRACTION = 0.9
_COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
           "#bcbd22", "#17becf"]

ParamErrorFn = Callable[[Robot, Measurements, np.ndarray, np.ndarray], Any]


# -- parameter error --------------------------------------------------------------------------


def _scaled_null_space(problem: Problem, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Column scale ``d``, the right singular vectors of ``J / d`` (rows, all n) and the rank."""
    jac = problem.jacobian(x)
    d = np.linalg.norm(jac, axis=0)
    d = np.where(d > 0, d, 1.0)
    # Only V is needed: the economic SVD gives all of it unless there are fewer readings than
    # parameters.
    _, s, vt = np.linalg.svd(jac / d, full_matrices=jac.shape[0] < jac.shape[1])
    tol = s[0] * max(jac.shape) * np.finfo(float).eps if s.size else 0.0
    rank = int(np.sum(s > tol))
    return d, vt, rank


class _ProjectedParameterError:
    """Fallback for :func:`iwr.parameter_error`: ``x - truth`` projected, in the column-scaled
    metric, onto the row space of the Jacobian at the truth (its identifiable part), as RMS over
    lengths and angles; and the raw RMS. The decomposition is kept for the last data set, since
    every method of a comparison is judged on the same one."""

    def __init__(self) -> None:
        self._key: Any = None
        self._svd: Any = None

    def __call__(self, robot: Robot, measurements: Measurements, x: Any,
                 truth: Any) -> dict[str, float]:
        truth = np.asarray(truth, dtype=float)
        key = (id(robot), id(measurements), truth.tobytes())
        if key != self._key:
            self._svd = _scaled_null_space(Problem(robot, measurements), truth)
            self._key = key
        d, vt, rank = self._svd
        raw = np.asarray(x, dtype=float) - truth
        vr = vt[:rank].T
        projected = (vr @ (vr.T @ (d * raw))) / d
        ang = robot.angle_parameters
        return {
            "rms_length": _rms(projected[~ang]),
            "rms_angle": _rms(projected[ang]),
            "raw_rms_length": _rms(raw[~ang]),
            "raw_rms_angle": _rms(raw[ang]),
        }


def _projected_parameter_error(
    robot: Robot, measurements: Measurements, x: Any, truth: Any
) -> dict[str, float]:
    """See :class:`_ProjectedParameterError` (no caching)."""
    return _ProjectedParameterError()(robot, measurements, x, truth)


def _default_parameter_error() -> ParamErrorFn:
    """``iwr.parameter_error`` (the identifiability module) when this build has it."""
    import iwr

    fn = getattr(iwr, "parameter_error", None)
    return fn if callable(fn) else _ProjectedParameterError()


def _error_fields(value: Any) -> dict[str, float]:
    keys = ("rms_length", "rms_angle", "raw_rms_length", "raw_rms_angle")
    out = {}
    for k in keys:
        v = value.get(k, math.nan) if isinstance(value, dict) else getattr(value, k, math.nan)
        out[k] = float(v) if v is not None else math.nan
    return out


def unidentifiable_parameters(problem: Problem, x: Any) -> np.ndarray:
    """Boolean mask of the parameters that take part in an unidentifiable combination at ``x``
    (a nonzero coefficient in the null space of the column-scaled Jacobian): they cannot be
    judged one by one."""
    d, vt, rank = _scaled_null_space(problem, np.asarray(x, dtype=float))
    null = vt[rank:].T
    if null.size == 0:
        return np.zeros(problem.n_params, dtype=bool)
    return np.linalg.norm(null, axis=1) > 1e-6


def _rms(v: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(v)))) if np.size(v) else math.nan


# -- the comparison -----------------------------------------------------------------------------


@dataclass
class Comparison:
    """The outcome of :func:`compare_methods`.

    Attributes
    ----------
    runs : list of dict
        One per (scenario, seed, method): the metrics of ``runs.csv`` plus ``x``, ``truth``,
        ``history_nfev``, ``history_best``, ``unidentifiable``.
    summary : list of dict
        One per (scenario, method): medians, ranges and the success rate (``summary.csv``).
    settings : dict
        Everything the comparison was run with.
    files : dict of str to Path
        The files written (empty without ``out_dir``).
    """

    runs: list[dict[str, Any]]
    summary: list[dict[str, Any]]
    settings: dict[str, Any]
    files: dict[str, Path] = field(default_factory=dict)

    def summary_markdown(self) -> str:
        """The summary table as Markdown."""
        return _markdown_table(_summary_table(self.summary))


def _check_int(name: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name}: {value!r}; expected an integer >= {minimum}")
    return int(value)


def _check_noise(noise: Any) -> Noise:
    if noise is None or noise == "none":
        return Noise()
    if isinstance(noise, Noise):
        return noise
    if noise == "realistic":
        return Noise.realistic()
    raise ValueError(f"noise: {noise!r}; expected an iwr.Noise, 'realistic', 'none' or None")


def _check_starts(start: Any) -> list[str]:
    starts = [start] if isinstance(start, str) else list(start) if start is not None else []
    if start == "both":
        starts = list(SCENARIOS)
    if not starts or any(s not in SCENARIOS for s in starts) or len(set(starts)) != len(starts):
        raise ValueError(
            f"start: {start!r}; expected 'near', 'bad', 'both' or a sequence of distinct ones"
        )
    return starts


def _de_strategies() -> tuple[str, ...]:
    from .de import STRATEGIES

    return tuple(STRATEGIES)


def _available() -> str:
    text = ", ".join(sorted(METHODS))
    if "de" in METHODS:
        text += "; or de:STRATEGY with STRATEGY one of " + ", ".join(_de_strategies())
    return text


def split_method(spec: Any) -> tuple[str, dict[str, Any]]:
    """The registered method and its fixed options of a method spec: a registered name as it is
    (``"lm"`` -> ``("lm", {})``), or ``"de:STRATEGY"``, differential evolution with that strategy
    (``"de:jso"`` -> ``("de", {"strategy": "jso"})``). Raises ValueError naming a bad spec."""
    if not isinstance(spec, str):
        raise ValueError(f"methods: {spec!r}; expected a method name; available: {_available()}")
    if spec in METHODS:
        return spec, {}
    base, sep, variant = spec.partition(":")
    if sep and base == "de" and "de" in METHODS:
        strategies = _de_strategies()
        if variant not in strategies:
            raise ValueError(f"methods: {spec!r}: unknown DE strategy {variant!r}; available: "
                             + ", ".join(strategies))
        return "de", {"strategy": variant}
    if sep and base in METHODS:
        raise ValueError(f"methods: {spec!r}: only de takes a variant (de:STRATEGY)")
    raise ValueError(f"methods: {spec!r} is not registered; available: {_available()}")


def default_methods() -> list[str]:
    """The methods compared when none are given: :data:`DEFAULT_METHODS` (those registered), then
    any other registered method."""
    names = [m for m in DEFAULT_METHODS if m.partition(":")[0] in METHODS]
    return names + sorted(m for m in METHODS if m not in names)


def _check_methods(methods: Any) -> list[str]:
    if methods is None:
        return default_methods()
    names = [methods] if isinstance(methods, str) else list(methods)
    if not names:
        raise ValueError(f"methods: empty; expected one or more of: {_available()}")
    for m in names:
        split_method(m)
    if len(set(names)) != len(names):
        raise ValueError(f"methods: {names!r} has duplicates")
    return names


def _check_seeds(seeds: Any) -> list[int]:
    if isinstance(seeds, (int, np.integer)) and not isinstance(seeds, bool):
        seeds = [seeds]
    try:
        out = list(seeds)
    except TypeError:
        raise ValueError(
            f"seeds: {seeds!r}; expected a sequence of non-negative integers"
        ) from None
    if not out:
        raise ValueError("seeds: empty; expected one or more non-negative integers")
    for s in out:
        if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0:
            raise ValueError(f"seeds: {s!r} is not a non-negative integer")
    if len(set(out)) != len(out):
        raise ValueError(f"seeds: {out!r} has duplicates")
    return [int(s) for s in out]


def _scenario_problem(
    robot: Robot, scenario: str, seed: int, n_poses: int, noise: Noise, n_validation: int
) -> dict[str, Any]:
    """The simulated data, truth, start, bounds and validation poses of one (scenario, seed)."""
    # One random stream per (scenario, seed), independent of the methods and of each other.
    ss = np.random.SeedSequence([seed, list(SCENARIOS).index(scenario)])
    rng_truth, rng_data, rng_val = (np.random.default_rng(s) for s in ss.spawn(3))
    bounds = _BOUNDS[scenario]
    lower, upper = robot.default_bounds(bounds)
    truth = lower + (upper - lower) * rng_truth.random(robot.n_params)
    data, _ = simulate(robot, n_poses, seed=int(rng_data.integers(2**63)), x=truth,
                       noise=noise)
    if scenario == "near":
        x0 = np.zeros(robot.n_params)
    else:
        # The opposite side of each parameter's range, near its bound.
        half = 0.5 * (upper - lower)
        mid = 0.5 * (upper + lower)
        side = np.where(truth >= mid, -1.0, 1.0)
        x0 = mid + side * _BAD_START_FRACTION * half
    # Validation: fresh poses of the actual robot and its exact readings (no noise), so that the
    # validation RMS measures the calibration, not the noise.
    q, poses, legs = sample_poses(robot, n_validation, rng_val, truth)
    problem = Problem(robot, data, bounds)
    return {
        "data": data,
        "truth": truth,
        "x0": x0,
        "bounds": bounds,
        "problem": problem,
        "floor": problem.cost(truth),
        "val": (q, poses, legs),
        "unidentifiable": unidentifiable_parameters(problem, truth),
    }


def _method_options(
    spec: str, budget: int, extra: dict[str, dict[str, Any]]
) -> tuple[str, dict[str, Any]]:
    """The registered method of ``spec`` and the options it runs with. Every method gets the
    budget as ``max_evaluations``; for ``lshade`` and ``jso`` this is also the budget their
    population-size and parameter schedules are planned over, so they end with the budget."""
    method, fixed = split_method(spec)
    opts: dict[str, Any] = {"max_evaluations": budget}
    if method == "de":
        # Pure DE: no Levenberg-Marquardt polish, whose evaluations would not be DE's.
        opts["polish"] = False
    opts.update(fixed)
    opts.update(extra.get(spec, {}))
    return method, opts


def _check_de_budget(robot: Robot, n_poses: int, names: list[str], budget: int,
                     extra: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """The resolved settings of every DE spec (strategy, NP, F, CR, ...), from a run of its
    initial population alone on a small noise-free problem: bad options fail here, before the
    comparison, and so does a budget smaller than the initial population (the DE engine refuses
    it; the message here adds how to fix it)."""
    out: dict[str, dict[str, Any]] = {}
    data = None
    for spec in names:
        method, opts = _method_options(spec, budget, extra)
        if method != "de":
            continue
        if data is None:
            data, _ = simulate(robot, n_poses, seed=0)
        try:
            res = identify(robot, data, "de", x0=np.zeros(robot.n_params), seed=0,
                           progress=False, **{**opts, "generations": 0})
        except (ValueError, TypeError) as exc:
            hint = ""
            if str(exc).startswith("max_evaluations:"):  # the budget: here, the only source of it
                hint = (f"; raise the budget or give a smaller population_size in "
                        f"method_options={{{spec!r}: {{...}}}}")
            raise ValueError(f"method {spec!r}: {exc}{hint}") from None
        st = dict(res.settings)
        keys = ["strategy", "population_size", "F", "CR"]
        if st.get("min_population_size"):
            keys.append("min_population_size")
        out[spec] = {k: st[k] for k in keys if k in st}
    return out


def compare_methods(
    robot: Robot | None = None,
    n_poses: int = 100,
    noise: Noise | str | None = "realistic",
    seeds: Sequence[int] | int = DEFAULT_SEEDS,
    methods: Sequence[str] | str | None = None,
    budget: int = DEFAULT_BUDGET,
    start: str | Sequence[str] = "both",
    out_dir: str | Path | None = DEFAULT_OUT,
    *,
    n_validation: int = 200,
    success_rtol: float = 0.1,
    success_atol: float = 1e-3,
    parameter_error: ParamErrorFn | None = None,
    method_options: dict[str, dict[str, Any]] | None = None,
    progress: bool | None = None,
) -> Comparison:
    """Compare identification methods on simulated problems under one evaluation budget.

    Parameters
    ----------
    robot : Robot, optional
        The nominal robot (default :meth:`Robot.default`).
    n_poses : int
        Measurement poses per identification (the paper: 100).
    noise : Noise, "realistic", "none" or None
        Measurement noise of the identification data (default: :meth:`Noise.realistic`).
    seeds : sequence of int
        One simulated problem per seed and scenario; the same seeds give the same numbers.
    methods : sequence of str, optional
        Method specs, each also its label in the report: a name registered in
        ``iwr.identify.METHODS`` (``"de"`` is the paper's DE/rand/1/bin with its defaults), or
        ``"de:STRATEGY"``, DE with a strategy of ``iwr.de.STRATEGIES`` (``"de:jso"``,
        ``"de:lshade"``, ...). Default: :data:`DEFAULT_METHODS` (``lm``, ``de``, ``de:jso``,
        ``crs2``, ``bobyqa``), then any other registered method.
    budget : int
        Evaluation budget of every run, passed as ``max_evaluations`` (a Jacobian counts as one
        evaluation); lshade and jso plan their schedules over it. DE never exceeds it, but it
        evaluates its initial population whole: a DE spec whose population is larger than the
        budget is refused.
    start : "near", "bad", "both" or a sequence of them
        The scenarios; see :data:`SCENARIOS`.
    out_dir : path, optional
        Where to write the report (created if needed); None: no files.
    n_validation : int
        Fresh poses for the validation RMS.
    success_rtol, success_atol : float
        A run succeeds when its cost is at most ``(1 + success_rtol) * floor + 6 N success_atol^2``,
        where ``floor`` is the cost of the true parameters on the same (noisy) data: within
        ``success_rtol`` of the noise floor, or within ``success_atol`` mm RMS of the readings.
    parameter_error : callable, optional
        ``f(robot, measurements, x, truth)`` returning an object or dict with ``rms_length``,
        ``rms_angle`` (error on the identifiable part), ``raw_rms_length`` and ``raw_rms_angle``.
        Default: :func:`iwr.parameter_error` where available, else a projection onto the row space
        of the column-scaled Jacobian.
    method_options : dict, optional
        Extra options per method label, e.g. ``{"crs2": {"population": 1000}}`` or
        ``{"de:jso": {"population_size": 200}}``.
    progress : bool, optional
        Progress bars (default: when standard error is a terminal).

    Returns
    -------
    Comparison
    """
    robot = Robot.default() if robot is None else robot
    if not isinstance(robot, Robot):
        raise ValueError(f"robot: expected an iwr.Robot or None, got {type(robot).__name__}")
    n_poses = _check_int("n_poses", n_poses, 1)
    n_validation = _check_int("n_validation", n_validation, 1)
    budget = _check_int("budget", budget, 2)
    noise = _check_noise(noise)
    seeds = _check_seeds(seeds)
    names = _check_methods(methods)
    starts = _check_starts(start)
    for label, v in (("success_rtol", success_rtol), ("success_atol", success_atol)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise ValueError(f"{label}: {v!r}; expected a finite number >= 0")
    if parameter_error is not None and not callable(parameter_error):
        raise ValueError(f"parameter_error: {parameter_error!r} is not callable")
    extra = dict(method_options or {})
    for k, v in extra.items():
        if k not in names or not isinstance(v, dict):
            raise ValueError(
                f"method_options: {k!r}; expected a dict of options per compared method (keyed "
                "by its label, e.g. 'de:jso')"
            )
        base, fixed = split_method(k)
        if base == "de" and "strategy" in v:
            # The label says which strategy ran: 'de' is rand1bin, 'de:jso' is jso.
            named = fixed.get("strategy", "rand1bin")
            if v["strategy"] != named:
                raise ValueError(f"method_options: {k!r} sets strategy {v['strategy']!r}; "
                                 f"use the label 'de:{v['strategy']}' instead")
    out_path = None if out_dir is None else Path(out_dir)
    if out_path is not None and out_path.exists() and not out_path.is_dir():
        raise ValueError(f"out_dir: {str(out_path)!r} exists and is not a folder")
    param_err = parameter_error or _default_parameter_error()
    show = sys.stderr.isatty() if progress is None else bool(progress)

    settings = {
        "robot": robot.name,
        "n_params": robot.n_params,
        "n_poses": n_poses,
        "n_validation": n_validation,
        "noise": {k: getattr(noise, k) for k in
                  ("legs", "joint_lengths", "joint_angles", "position", "orientation")},
        "seeds": seeds,
        "methods": names,
        "budget": budget,
        "scenarios": {s: SCENARIOS[s] for s in starts},
        "bounds": {s: _BOUNDS[s] for s in starts},
        "success_rtol": success_rtol,
        "success_atol": success_atol,
        "parameter_error": getattr(param_err, "__module__", "") + "."
        + getattr(param_err, "__qualname__", type(param_err).__qualname__),
        "method_options": {m: _method_options(m, budget, extra)[1] for m in names},
        "de_settings": _check_de_budget(robot, n_poses, names, budget, extra),
    }

    with single_thread():
        return _compare(robot, n_poses, noise, seeds, names, budget, starts, out_path,
                        n_validation, success_rtol, success_atol, param_err, extra, show, settings)


def _compare(robot: Robot, n_poses: int, noise: Noise, seeds: list[int], names: list[str],
             budget: int, starts: list[str], out_path: Path | None, n_validation: int,
             success_rtol: float, success_atol: float, param_err: ParamErrorFn,
             extra: dict[str, dict[str, Any]], show: bool, settings: dict[str, Any]) -> Comparison:
    from tqdm.auto import tqdm

    runs: list[dict[str, Any]] = []
    total = len(starts) * len(seeds) * len(names)
    with tqdm(total=total, desc="compare", unit="run", disable=not show) as bar:
        for scenario in starts:
            for seed in seeds:
                bar.set_postfix_str(f"{scenario} seed {seed}: simulating")
                sp = _scenario_problem(robot, scenario, seed, n_poses, noise, n_validation)
                q_val, poses_val, legs_val = sp["val"]
                nominal_val = _rms(predict_legs(robot, np.zeros(robot.n_params), q_val, poses_val)
                                   - legs_val)
                threshold = (1 + success_rtol) * sp["floor"] + 6 * n_poses * success_atol**2
                for spec in names:
                    bar.set_postfix_str(f"{scenario} seed {seed}: {spec}")
                    method, opts = _method_options(spec, budget, extra)
                    t0 = time.perf_counter()
                    res = identify(robot, sp["data"], method, bounds=sp["bounds"], x0=sp["x0"],
                                   seed=seed, progress=show, **opts)
                    wall = time.perf_counter() - t0
                    x = np.asarray(res.x, dtype=float)
                    val_rms = _rms(predict_legs(robot, x, q_val, poses_val) - legs_val)
                    perr = _error_fields(param_err(robot, sp["data"], x, sp["truth"]))
                    hist = dict(res.get("history", {}))
                    runs.append({
                        "scenario": scenario,
                        "seed": seed,
                        "method": spec,
                        "cost": float(res.fun),
                        "noise_floor": float(sp["floor"]),
                        "success_threshold": float(threshold),
                        "success": bool(res.fun <= threshold),
                        "rms_residual_mm": math.sqrt(max(float(res.fun), 0.0) / (6 * n_poses)),
                        "validation_rms_mm": val_rms,
                        "nominal_validation_rms_mm": nominal_val,
                        "param_err_length_mm": perr["rms_length"],
                        "param_err_angle_rad": perr["rms_angle"],
                        "raw_err_length_mm": perr["raw_rms_length"],
                        "raw_err_angle_rad": perr["raw_rms_angle"],
                        "max_raw_err_length_mm": float(np.max(np.abs(
                            (x - sp["truth"])[~robot.angle_parameters]))),
                        "nfev": int(res.nfev),
                        "within_budget": bool(res.nfev <= budget),
                        "wall_time_s": wall,
                        "method_success": bool(res.success),
                        "message": str(res.message),
                        "x": x.tolist(),
                        "truth": sp["truth"].tolist(),
                        "x0": sp["x0"].tolist(),
                        "unidentifiable": sp["unidentifiable"].tolist(),
                        "history_nfev": np.asarray(hist.get("nfev", []), dtype=float).tolist(),
                        "history_best": np.asarray(hist.get("best", []), dtype=float).tolist(),
                    })
                    bar.update(1)
    summary = _summarise(runs, starts, names)
    comparison = Comparison(runs=runs, summary=summary, settings=settings)
    if out_path is not None:
        comparison.files = write_report(comparison, out_path, robot)
    return comparison


def _median(values: list[float]) -> float:
    arr = np.array([v for v in values if not math.isnan(v)], dtype=float)
    return float(np.median(arr)) if arr.size else math.nan


def _summarise(runs: list[dict[str, Any]], starts: list[str], names: list[str]) -> list[dict]:
    out = []
    for scenario in starts:
        for method in names:
            rs = [r for r in runs if r["scenario"] == scenario and r["method"] == method]
            if not rs:
                continue
            costs = [r["cost"] for r in rs]
            out.append({
                "scenario": scenario,
                "method": method,
                "runs": len(rs),
                "successes": sum(r["success"] for r in rs),
                "success_rate": sum(r["success"] for r in rs) / len(rs),
                "median_cost": _median(costs),
                "min_cost": float(np.min(costs)),
                "max_cost": float(np.max(costs)),
                "median_noise_floor": _median([r["noise_floor"] for r in rs]),
                "median_validation_rms_mm": _median([r["validation_rms_mm"] for r in rs]),
                "median_nominal_validation_rms_mm": _median(
                    [r["nominal_validation_rms_mm"] for r in rs]),
                "median_param_err_length_mm": _median([r["param_err_length_mm"] for r in rs]),
                "median_param_err_angle_rad": _median([r["param_err_angle_rad"] for r in rs]),
                "median_raw_err_length_mm": _median([r["raw_err_length_mm"] for r in rs]),
                "median_raw_err_angle_rad": _median([r["raw_err_angle_rad"] for r in rs]),
                "median_nfev": _median([float(r["nfev"]) for r in rs]),
                "max_nfev": int(max(r["nfev"] for r in rs)),
                "all_within_budget": all(r["within_budget"] for r in rs),
                "median_wall_time_s": _median([r["wall_time_s"] for r in rs]),
            })
    return out


# -- the report ---------------------------------------------------------------------------------

_RUN_COLUMNS = [
    "scenario", "seed", "method", "success", "cost", "noise_floor", "success_threshold",
    "rms_residual_mm", "validation_rms_mm", "nominal_validation_rms_mm", "param_err_length_mm",
    "param_err_angle_rad", "raw_err_length_mm", "raw_err_angle_rad", "max_raw_err_length_mm",
    "nfev", "within_budget", "wall_time_s", "method_success", "message",
]


def _fmt(v: Any, digits: int = 3) -> str:
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, float):
        if math.isnan(v):
            return "n/a"
        return f"{v:.{digits}g}"
    return str(v)


def _summary_table(summary: list[dict[str, Any]]) -> tuple[list[str], list[list[str]]]:
    head = [
        "scenario", "method", "success", "median cost (mm^2)", "cost range", "noise floor",
        "validation RMS (mm)", "param. error, identifiable part: lengths (mm) / angles (mrad)",
        "raw param. error: lengths (mm) / angles (mrad)", "evaluations (median / max)",
        "wall time (s)",
    ]
    rows = []
    for s in summary:
        rows.append([
            s["scenario"],
            s["method"],
            f"{s['successes']}/{s['runs']}",
            _fmt(s["median_cost"]),
            f"{_fmt(s['min_cost'], 2)} .. {_fmt(s['max_cost'], 2)}",
            _fmt(s["median_noise_floor"]),
            _fmt(s["median_validation_rms_mm"]),
            f"{_fmt(s['median_param_err_length_mm'])} / "
            f"{_fmt(1e3 * s['median_param_err_angle_rad'])}",
            f"{_fmt(s['median_raw_err_length_mm'])} / {_fmt(1e3 * s['median_raw_err_angle_rad'])}",
            f"{_fmt(int(round(s['median_nfev'])))} / {s['max_nfev']}"
            + ("" if s["all_within_budget"] else " (over budget!)"),
            _fmt(s["median_wall_time_s"], 2),
        ])
    return head, rows


def _markdown_table(table: tuple[list[str], list[list[str]]]) -> str:
    head, rows = table
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _html_table(table: tuple[list[str], list[list[str]]]) -> str:
    head, rows = table
    out = ["<table>", "<tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>"]
    for r in rows:
        out.append("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def _figure(width: float, height: float) -> Any:
    # A Figure with its own Agg canvas: no pyplot, no global backend state.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def _png(fig: Any) -> bytes:
    buf = io.BytesIO()
    # Fixed metadata: the same numbers give the same bytes.
    fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()


_FIXED_COLORS = {"lm": "#1f77b4", "de": "#d62728", "crs2": "#2ca02c", "bobyqa": "#ff7f0e",
                 "de:jso": "#9467bd"}


def _colors(names: list[str]) -> dict[str, str]:
    """One color per method, the same in every report for the usual methods."""
    others = [c for c in _COLORS if c not in _FIXED_COLORS.values()]
    out, k = {}, 0
    for m in names:
        if m in _FIXED_COLORS:
            out[m] = _FIXED_COLORS[m]
        else:
            out[m] = others[k % len(others)]
            k += 1
    return out


def _plot_convergence(comp: Comparison, scenario: str) -> bytes:
    names = comp.settings["methods"]
    colors = _colors(names)
    runs = [r for r in comp.runs if r["scenario"] == scenario]
    fig = _figure(8.0, 5.0)
    ax = fig.add_subplot()
    for method in names:
        for i, r in enumerate(x for x in runs if x["method"] == method):
            n = np.asarray(r["history_nfev"], dtype=float)
            b = np.asarray(r["history_best"], dtype=float)
            ok = (n > 0) & np.isfinite(b) & (b > 0)
            if not ok.any():
                continue
            ax.step(n[ok], b[ok], where="post", color=colors[method], lw=1.3, alpha=0.85,
                    label=method if i == 0 else None)
            ax.plot(n[ok][-1], b[ok][-1], "o", color=colors[method], ms=4)
    floors = [r["noise_floor"] for r in runs]
    thresholds = [r["success_threshold"] for r in runs]
    if floors and np.median(floors) > 0:
        ax.axhline(float(np.median(floors)), color="k", ls="--", lw=1,
                   label="noise floor (cost of the truth)")
    if thresholds:
        ax.axhline(float(np.median(thresholds)), color="0.5", ls=":", lw=1,
                   label="success threshold")
    ax.axvline(comp.settings["budget"], color="0.7", lw=1)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("objective evaluations (a Jacobian counts as one)")
    ax.set_ylabel("best cost so far, eq. (10) (mm$^2$)")
    ax.set_title(f"Best cost against evaluations, scenario '{scenario}' "
                 f"({len(comp.settings['seeds'])} seeds, one line each)")
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return _png(fig)


def _plot_parameters(comp: Comparison, scenario: str, robot: Robot) -> bytes:
    names = comp.settings["methods"]
    colors = _colors(names)
    seed = comp.settings["seeds"][0]
    runs = {r["method"]: r for r in comp.runs if r["scenario"] == scenario and r["seed"] == seed}
    lower, upper = robot.default_bounds(_BOUNDS[scenario])
    half = 0.5 * (upper - lower)
    ncol = min(len(names), 3)
    nrow = math.ceil(len(names) / ncol)
    fig = _figure(4.0 * ncol, 3.9 * nrow)
    lim = 1.6
    for k, method in enumerate(names):
        ax = fig.add_subplot(nrow, ncol, k + 1)
        r = runs.get(method)
        if r is None:
            continue
        t = np.asarray(r["truth"]) / half
        x = np.asarray(r["x"]) / half
        un = np.asarray(r["unidentifiable"], dtype=bool)
        xc = np.clip(x, -lim, lim)
        out = np.abs(x) > lim
        ax.plot([-1, 1], [-1, 1], color="0.6", lw=1)
        ax.scatter(t[~un & ~out], xc[~un & ~out], s=14, color=colors[method],
                   label="identifiable one by one")
        ax.scatter(t[un & ~out], xc[un & ~out], s=22, facecolors="none", edgecolors="k",
                   linewidths=0.9, label="in an unidentifiable combination")
        if out.any():
            ax.scatter(t[out], xc[out], s=30, marker="^", color="0.3",
                       label=f"off the plot ({int(out.sum())})")
        ax.set_xlim(-1.1, 1.1)
        ax.set_ylim(-lim - 0.1, lim + 0.1)
        ax.set_title(f"{method}: cost {r['cost']:.3g}", fontsize=10)
        ax.set_xlabel("true error / bound")
        ax.set_ylabel("recovered error / bound")
        ax.grid(True, alpha=0.3)
        if k == 0:
            ax.legend(fontsize=7, loc="upper left")
    fig.suptitle(f"Recovered against true parameters, scenario '{scenario}', seed {seed} "
                 "(each parameter divided by its bound)", fontsize=11)
    fig.tight_layout()
    return _png(fig)


def _plot_metrics(comp: Comparison) -> bytes:
    names = comp.settings["methods"]
    colors = _colors(names)
    scenarios = list(comp.settings["scenarios"])
    fig = _figure(4.2 * len(scenarios), 6.5)
    for j, scenario in enumerate(scenarios):
        for i, (key, label) in enumerate([("cost", "final cost (mm$^2$)"),
                                          ("validation_rms_mm", "validation RMS (mm)")]):
            ax = fig.add_subplot(2, len(scenarios), i * len(scenarios) + j + 1)
            for k, method in enumerate(names):
                vals = [r[key] for r in comp.runs
                        if r["scenario"] == scenario and r["method"] == method]
                ok = [r["success"] for r in comp.runs
                      if r["scenario"] == scenario and r["method"] == method]
                for v, s in zip(vals, ok, strict=True):
                    ax.plot(k, max(v, 1e-30), "o" if s else "x", color=colors[method], ms=6)
            if key == "cost":
                fl = [r["noise_floor"] for r in comp.runs if r["scenario"] == scenario]
                if fl and np.median(fl) > 0:
                    ax.axhline(float(np.median(fl)), color="k", ls="--", lw=1)
            else:
                nv = [r["nominal_validation_rms_mm"] for r in comp.runs
                      if r["scenario"] == scenario]
                if nv:
                    ax.axhline(float(np.median(nv)), color="0.5", ls=":", lw=1)
            ax.set_yscale("log")
            ax.set_xticks(range(len(names)), names)
            ax.set_title(f"{scenario}: {label}", fontsize=10)
            ax.grid(True, axis="y", alpha=0.3)
    fig.suptitle("Per run: o success, x failure; dashed: noise floor; dotted: the nominal "
                 "robot's validation RMS", fontsize=9)
    fig.tight_layout()
    return _png(fig)


def _figures(comp: Comparison, robot: Robot) -> list[tuple[str, str, bytes]]:
    """(file name, caption, PNG bytes) of every figure."""
    out = []
    for scenario in comp.settings["scenarios"]:
        out.append((f"convergence_{scenario}.png",
                    f"Best cost against evaluations, scenario '{scenario}' (the paper's Fig. 5, "
                    "extended to every method), log scales", _plot_convergence(comp, scenario)))
    for scenario in comp.settings["scenarios"]:
        out.append((f"parameters_{scenario}.png",
                    f"Recovered against true parameters, scenario '{scenario}'; hollow: parameters "
                    "in an unidentifiable combination", _plot_parameters(comp, scenario, robot)))
    out.append(("metrics.png", "Final cost and validation RMS of every run",
                _plot_metrics(comp)))
    return out


def _definitions(settings: dict[str, Any]) -> list[str]:
    n = settings["n_poses"]
    return [
        f"Robot {settings['robot']} ({settings['n_params']} error parameters), {n} measurement "
        f"poses per identification, noise {settings['noise']} (mm, rad), seeds "
        f"{settings['seeds']}, evaluation budget {settings['budget']} per run (a Jacobian counts "
        "as one evaluation).",
        *(f"Scenario '{k}': {v}." for k, v in settings["scenarios"].items()),
        "Cost: eq. (10), the sum of squared leg residuals (mm^2), re-evaluated at the returned "
        "point. Noise floor: the cost of the true parameters on the same noisy data.",
        f"Success: cost <= (1 + {settings['success_rtol']}) x noise floor + 6 N x "
        f"({settings['success_atol']} mm)^2, i.e. within {100 * settings['success_rtol']:.0f}% of "
        f"the noise floor or {1e3 * settings['success_atol']:.3g} um RMS of the readings.",
        f"Validation RMS: leg readings predicted with the recovered parameters at "
        f"{settings['n_validation']} fresh poses of the actual robot, against their exact "
        "(noise-free) values; the nominal robot's is given for scale.",
        *_de_text(settings),
        _parameter_error_text(settings["parameter_error"]),
        "Medians over seeds. Wall times depend on the machine and its load; everything else is "
        "the same for the same seeds.",
    ]


def _de_text(settings: dict[str, Any]) -> list[str]:
    """One line on the DE runs' settings, when there are any."""
    de = settings.get("de_settings") or {}
    if not de:
        return []
    parts = []
    for spec, st in de.items():
        np_text = f"NP {st['population_size']}"
        if st.get("min_population_size"):
            np_text += f" reduced linearly to {st['min_population_size']} over the budget"
        parts.append(f"{spec}: {st['strategy']}, {np_text}, F {st['F']:g}, CR {st['CR']:g}"
                     + (" (initial values, adapted)" if st["strategy"] not in
                        ("rand1bin", "best1bin") else ""))
    return ["Differential evolution, without polish (DE never exceeds the budget: its last "
            "generation may evaluate only part of the population): " + "; ".join(parts) + "."]


def _parameter_error_text(name: str) -> str:
    common = (
        "RMS over lengths (mm) and over angles (mrad in the tables). Raw: x - truth as it is. "
        "Unidentifiable combinations cost nothing, so a method may land anywhere along them: raw "
        "errors there say nothing about the method."
    )
    if name.endswith("identifiability.parameter_error"):
        return (
            "Parameter error, identifiable part (iwr.parameter_error): x minus the parameter "
            "vector nearest to x that predicts exactly the truth's readings at the identification "
            "poses, projected onto the identifiable directions; the part of the error that the "
            "readings can see. " + common
        )
    if name.endswith("_ProjectedParameterError"):
        return (
            "Parameter error, identifiable part: x - truth projected onto the row space of the "
            "column-scaled Jacobian at the truth. First order: where a method ends far along a "
            "curved unidentifiable combination (large errors, the bad start), part of that remains "
            "and the number overstates the real error; the validation RMS has no such limit. "
            + common
        )
    return f"Parameter error, identifiable part: as computed by {name}. " + common


def write_report(comp: Comparison, out_dir: str | Path, robot: Robot) -> dict[str, Path]:
    """Write ``report.html``, ``report.md``, the PNG figures, ``runs.csv``, ``summary.csv`` and
    ``results.json`` into ``out_dir`` (created if needed), each atomically."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, Path] = {}
    figures = _figures(comp, robot)
    for name, _, png in figures:
        atomic_write_bytes(out / name, png)
        files[name] = out / name

    # CSV: one row per run, one per (scenario, method).
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(_RUN_COLUMNS)
    for r in comp.runs:
        w.writerow([_csv_value(r[c]) for c in _RUN_COLUMNS])
    atomic_write_text(out / "runs.csv", buf.getvalue())
    files["runs.csv"] = out / "runs.csv"
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    cols = list(comp.summary[0]) if comp.summary else []
    w.writerow(cols)
    for s in comp.summary:
        w.writerow([_csv_value(s[c]) for c in cols])
    atomic_write_text(out / "summary.csv", buf.getvalue())
    files["summary.csv"] = out / "summary.csv"

    data = {
        "format": "iwr-compare",
        "version": 1,
        "settings": comp.settings,
        "parameter_names": robot.parameter_names,
        "summary": comp.summary,
        "runs": comp.runs,
    }
    atomic_write_text(out / "results.json",
                      json.dumps(jsonable(data, finite_only=True), indent=1) + "\n")
    files["results.json"] = out / "results.json"

    table = _summary_table(comp.summary)
    defs = _definitions(comp.settings)
    # Markdown, with the PNGs beside it.
    md = ["# iwr compare: identification methods on one objective, one budget", ""]
    md += [f"- {d}" for d in defs]
    md += ["", "## Summary", "", _markdown_table(table)]
    md += ["## Figures", ""]
    md += ["| figure | file |", "|---|---|"]
    md += [f"| {cap} | [{name}]({name}) |" for name, cap, _ in figures]
    md += [""]
    for name, cap, _ in figures:
        md += [f"![{cap}]({name})", ""]
    md += ["Raw numbers: `runs.csv` (one row per run), `summary.csv`, `results.json` (everything, "
           "with the recovered parameters and the convergence histories).", ""]
    atomic_write_text(out / "report.md", "\n".join(md))
    files["report.md"] = out / "report.md"

    # HTML, self-contained: the PNGs embedded as base64.
    runs_table = ([c for c in _RUN_COLUMNS if c != "message"],
                  [[_fmt(r[c]) for c in _RUN_COLUMNS if c != "message"] for r in comp.runs])
    h = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        "<title>iwr compare</title>",
        "<style>body{font-family:sans-serif;max-width:1200px;margin:2em auto;padding:0 1em}"
        "table{border-collapse:collapse;font-size:0.85em;margin:1em 0}"
        "td,th{border:1px solid #bbb;padding:3px 6px;text-align:right}"
        "th{background:#eee}td:first-child,td:nth-child(2){text-align:left}"
        "figure{margin:1.5em 0}img{max-width:100%}figcaption{font-size:0.9em;color:#333}"
        "</style></head><body>",
        "<h1>iwr compare: identification methods on one objective, one budget</h1>",
        "<ul>" + "".join(f"<li>{html.escape(d)}</li>" for d in defs) + "</ul>",
        "<h2>Summary</h2>",
        _html_table(table),
        "<h2>Figures</h2>",
        _html_table((["figure", "file"], [[cap, name] for name, cap, _ in figures])),
    ]
    for name, cap, png in figures:
        b64 = base64.b64encode(png).decode("ascii")
        h.append(f'<figure id="{html.escape(name)}"><img alt="{html.escape(cap)}" '
                 f'src="data:image/png;base64,{b64}"><figcaption>{html.escape(cap)} '
                 f"({html.escape(name)})</figcaption></figure>")
    h += ["<h2>Every run</h2>", _html_table(runs_table),
          "<p>Raw numbers: runs.csv, summary.csv, results.json beside this page.</p>",
          "</body></html>", ""]
    atomic_write_text(out / "report.html", "\n".join(h))
    files["report.html"] = out / "report.html"
    return files


def _csv_value(v: Any) -> Any:
    if isinstance(v, float):
        return repr(v)
    return v




# -- command line ---------------------------------------------------------------------------------


def _parse_noise(text: str) -> Noise:
    if text in ("none", "realistic"):
        return _check_noise(text)
    values: dict[str, float] = {}
    for item in text.split(","):
        key, sep, val = item.partition("=")
        key = key.strip()
        if not sep or key not in Noise.__dataclass_fields__:
            raise ValueError(
                f"--noise: {text!r}; expected 'none', 'realistic' or key=value pairs with keys "
                + ", ".join(Noise.__dataclass_fields__)
            )
        try:
            values[key] = float(val)
        except ValueError:
            raise ValueError(f"--noise: {key}={val!r} is not a number") from None
    return Noise(**values)


def _parse_ints(text: str, name: str) -> list[int]:
    try:
        if ".." in text:
            a, b = text.split("..")
            return list(range(int(a), int(b) + 1))
        return [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise ValueError(f"{name}: {text!r}; expected integers like '0,1,2' or '0..4'") from None


def add_compare_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``compare`` subcommand to an argparse ``subparsers`` object; returns its parser.
    Its ``func`` default is :func:`run_compare`."""
    p = subparsers.add_parser(
        "compare",
        help="compare the identification methods on simulated problems, one budget; write a report",
        description=(
            "Every identification method on the same simulated problems (several seeds; a start "
            "near the nominal robot and a deliberately bad one) under one evaluation budget. "
            "Writes report.html (self-contained), report.md with its PNG figures, runs.csv, "
            "summary.csv and results.json."
        ),
    )
    _add_arguments(p)
    p.set_defaults(func=run_compare)
    return p


def _add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--robot", metavar="TOML", help="robot description (default: the built-in IWR)")
    p.add_argument("--poses", type=int, default=100, metavar="N",
                   help="measurement poses per identification (default: %(default)s)")
    p.add_argument("--noise", default="realistic",
                   help="'none', 'realistic' (default) or key=value pairs, e.g. "
                        "'legs=0.002,position=0.02' (mm, rad)")
    p.add_argument("--seeds", default=",".join(map(str, DEFAULT_SEEDS)),
                   help="seeds, '0,1,2' or '0..4' (default: %(default)s)")
    p.add_argument("--methods", default=None,
                   help="comma-separated methods: registered names ("
                        + ", ".join(sorted(METHODS)) + "; de is the paper's DE/rand/1/bin) or "
                        "de:STRATEGY (e.g. de:jso, de:lshade); default: "
                        + ",".join(default_methods()))
    p.add_argument("--budget", type=int, default=DEFAULT_BUDGET, metavar="EVALS",
                   help="evaluation budget per run (default: %(default)s)")
    p.add_argument("--start", choices=["near", "bad", "both"], default="both",
                   help="scenario(s) (default: %(default)s)")
    p.add_argument("--validation-poses", type=int, default=200, metavar="N",
                   help="fresh poses for the validation RMS (default: %(default)s)")
    p.add_argument("-o", "--out", default=DEFAULT_OUT, metavar="DIR",
                   help="output folder (default: %(default)s)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def run_compare(args: argparse.Namespace) -> int:
    """Run ``iwr compare`` with parsed arguments; print the summary table; return the exit code
    (0 ok, 1 an input or run error, 130 interrupted)."""
    try:
        robot = Robot.from_toml(args.robot) if args.robot else None
        methods = None if args.methods is None else [
            m.strip() for m in args.methods.split(",") if m.strip()]
        comp = compare_methods(
            robot=robot,
            n_poses=args.poses,
            noise=_parse_noise(args.noise),
            seeds=_parse_ints(args.seeds, "--seeds"),
            methods=methods,
            budget=args.budget,
            start=args.start,
            out_dir=args.out,
            n_validation=args.validation_poses,
            progress=False if args.no_progress else None,
        )
    except KeyboardInterrupt:
        print("iwr compare: interrupted", file=sys.stderr)
        return 130
    except (ValueError, TypeError, OSError, RuntimeError) as exc:
        print(f"iwr compare: error: {exc}", file=sys.stderr)
        return 1
    print(comp.summary_markdown())
    print(f"wrote {args.out}/: " + ", ".join(sorted(comp.files)))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m iwr.compare``."""
    parser = argparse.ArgumentParser(
        prog="python -m iwr.compare",
        description="Compare the identification methods on simulated problems under one "
                    "evaluation budget and write a report (the 'iwr compare' command).",
    )
    _add_arguments(parser)
    return run_compare(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
