"""``iwr compare``: every identification method on the same simulated problems, one evaluation
budget, and a report. A preset grid of the experiment harness (:mod:`iwr.experiments.harness`).

For each scenario (``"near"``: the nominal robot as the start, errors within the default bounds;
``"bad"``: large errors and a start near the bounds) and each seed, a robot with random errors is
simulated at ``n_poses`` poses with measurement noise, and every method identifies it from the same
start under the same evaluation budget. A method is a registered name (``lm``, ``de``, ``crs2``,
``bobyqa``; ``de`` is the paper's DE/rand/1/bin) or ``de:STRATEGY``, a modern DE variant such as
``de:jso``; the default list is :data:`DEFAULT_METHODS`. Seed ``k`` of a comparison is the
harness's error draw ``k`` (data seed 0, base seed 0): a comparison's run and a study's cell of the
same draw and settings are the same identification. The report (:mod:`iwr.reporting.compare`) in
``out``: ``report.html`` (self-contained), ``report.md`` with the PNG figures beside it,
``runs.csv``, ``summary.csv`` and ``results.json``.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._hooks import hook
from ..noise import Noise
from ..robot import Robot
from .executors import ExecutorError, dry_run, run_dask, run_in_process
from .harness import (
    FIGURE_COLUMNS,
    FLOOR_ATOL,
    FLOOR_RTOL,
    SCENARIOS,
    ArgumentError,
    Cell,
    budget_option,
    canonical,
    check_n_poses,
    check_robot,
    leg_sigma,
    percentiles_worst,
    registered_methods,
    robot_hash,
    split_method,
)
from .harness import available_methods as _available

__all__ = [
    "compare_methods",
    "Comparison",
    "SCENARIOS",
    "DEFAULT_BUDGET",
    "DEFAULT_METHODS",
    "DEFAULT_SEEDS",
    "default_methods",
    "split_method",
]

#: Evaluation budget of every method, per run, when none is given.
DEFAULT_BUDGET = 20_000
#: Methods compared when none are given (then any other registered method): Levenberg-Marquardt,
#: the paper's DE/rand/1/bin with Storn & Price's defaults, jSO (the DE variant that converges
#: fastest on IWR, docs/de.md), CRS2, BOBYQA and the efficient estimator (weighted by each
#: scenario's noise model; with no noise it cannot run). ``"de:STRATEGY"`` is DE with that
#: strategy.
DEFAULT_METHODS = ("lm", "de", "de:jso", "crs2", "bobyqa", "efficient")
DEFAULT_SEEDS = (0, 1, 2)
DEFAULT_OUT = "iwr-compare"
_BOUNDS = {"near": "default", "bad": "paper"}


@dataclass
class Comparison:
    """The outcome of :func:`compare_methods`.

    Attributes
    ----------
    runs : list of dict
        One per (scenario, seed, method): the harness's row (``runs.csv``) plus ``x``, ``truth``,
        ``x0``, ``history_nfev``, ``history_best``, ``unidentifiable``.
    summary : list of dict
        One per (scenario, method): medians, ranges, the successes (the method's own ``success``:
        converged, and with a noise model its fit tested) and the runs at the noise floor
        (``summary.csv``).
    settings : dict
        Everything the comparison was run with.
    files : dict of str to Path
        The files written (empty without ``out``).
    """

    runs: list[dict[str, Any]]
    summary: list[dict[str, Any]]
    settings: dict[str, Any]
    files: dict[str, Path] = field(default_factory=dict)

    def summary_markdown(self) -> str:
        """The summary table as Markdown."""
        # The reports' tables (iwr.reporting, a layer up).
        return hook("markdown_table")(hook("compare_summary_table")(self.summary))


def _check_int(name: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ArgumentError(f"{name}: {value!r}; expected an integer >= {minimum}")
    return int(value)


def _check_noise(noise: Any) -> Any:
    if noise is None or (isinstance(noise, str) and noise == "none"):
        return Noise()
    if isinstance(noise, Noise):
        return noise
    if isinstance(noise, tuple) and len(noise) == 2:  # a kind's own model, e.g. a tracker's
        return noise
    if isinstance(noise, str) and noise == "realistic":
        return Noise.realistic()
    raise ArgumentError(f"noise: {noise!r}; expected an iwr.Noise, a pair (iwr.Noise, "
                     "iwr.tracker.TrackerNoise) for a robot with a tracker, 'realistic', 'none' "
                     "or None")


def _check_starts(start: Any) -> list[str]:
    starts = [start] if isinstance(start, str) else list(start) if start is not None else []
    if start == "both":
        starts = list(SCENARIOS)
    if not starts or any(s not in SCENARIOS for s in starts) or len(set(starts)) != len(starts):
        raise ArgumentError(
            f"start: {start!r}; expected 'near', 'bad', 'both' or a sequence of distinct ones"
        )
    return starts


def default_methods(noise: Noise | None = None) -> list[str]:
    """The methods compared when none are given: :data:`DEFAULT_METHODS` (those registered), then
    any other registered method; with a ``noise`` model whose leg noise is 0 (noise-free data)
    without the efficient estimator, which weighs the instruments by their noise."""
    names = [m for m in DEFAULT_METHODS if m.partition(":")[0] in registered_methods()]
    names += sorted(m for m in registered_methods() if m not in names)
    if noise is not None and not _weighted(noise):
        names = [m for m in names if m != "efficient"]
    return names


def _weighted(noise: Any) -> bool:
    """Whether the efficient estimator can weigh the data by ``noise`` (it needs the legs')."""
    return leg_sigma(noise) > 0


def _check_methods(methods: Any, noise: Noise) -> list[str]:
    if methods is None:
        return default_methods(noise)
    names = [methods] if isinstance(methods, str) else list(methods)
    if not names:
        raise ArgumentError(f"methods: empty; expected one or more of: {_available()}")
    for m in names:
        split_method(m)
    if len(set(names)) != len(names):
        raise ArgumentError(f"methods: {names!r} has duplicates")
    if "efficient" in names and not _weighted(noise):
        raise ArgumentError("methods: 'efficient' weighs every instrument by the data's noise "
                            "model, and this noise has no leg noise (legs = "
                            f"{leg_sigma(noise)}); give a noise model with legs > 0 (e.g. "
                            "'realistic') or leave 'efficient' out")
    return names


def _check_seeds(seeds: Any) -> list[int]:
    if isinstance(seeds, (int, np.integer)) and not isinstance(seeds, bool):
        seeds = [seeds]
    try:
        out = list(seeds)
    except TypeError:
        raise ArgumentError(
            f"seeds: {seeds!r}; expected a sequence of non-negative integers"
        ) from None
    if not out:
        raise ArgumentError("seeds: empty; expected one or more non-negative integers")
    for s in out:
        if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0:
            raise ArgumentError(f"seeds: {s!r} is not a non-negative integer")
    if len(set(out)) != len(out):
        raise ArgumentError(f"seeds: {out!r} has duplicates")
    return [int(s) for s in out]


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


def _check_de_budget(robot: Robot, names: list[str], budget: int,
                     extra: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """The resolved settings of every DE spec (strategy, NP, F, CR, ...), from a dry run of its
    initial population (the other methods' stopped at their first evaluation): bad options fail
    here, by the method's own checks, before the comparison (ArgumentError naming
    ``method_options``), and so does a budget smaller than DE's initial population (the DE
    engine refuses it; the message here names ``budget`` and adds how to fix it)."""
    out: dict[str, dict[str, Any]] = {}
    for spec in names:
        method, opts = _method_options(spec, budget, extra)
        try:
            st = dry_run(robot, method, opts)
        except (ValueError, TypeError) as exc:
            if str(exc).startswith("max_evaluations:") and "max_evaluations" not in \
                    extra.get(spec, {}):  # the budget: the only source of it here
                raise ArgumentError(
                    f"budget: method {spec!r}: {exc}; raise the budget or give a smaller "
                    f"population_size in method_options={{{spec!r}: {{...}}}}") from None
            raise ArgumentError(f"method_options: method {spec!r}: {exc}") from None
        if method != "de":
            continue
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
    out: str | Path | None = DEFAULT_OUT,
    *,
    n_validation: int = 200,
    success_rtol: float = FLOOR_RTOL,
    success_atol: float = FLOOR_ATOL,
    method_options: dict[str, dict[str, Any]] | None = None,
    scheduler: Any = "synchronous",
    progress: bool | None = None,
) -> Comparison:
    """Compare identification methods on simulated problems under one evaluation budget.

    Parameters
    ----------
    robot : Robot, optional
        The nominal robot (default :meth:`Robot.default`); its kind of data
        (:func:`iwr.kinds.for_robot`: the platform pose in {0}, or with a ``[tracker]`` setup
        reflector points or a probe in {T}) is what is simulated and identified.
    n_poses : int
        Measurement poses per identification (the paper: 100); at least
        :func:`~iwr.experiments.harness.min_poses` (9 for the IWR).
    noise : Noise, (Noise, TrackerNoise), "realistic", "none" or None
        Measurement noise of the identification data (default: :meth:`Noise.realistic`). For a
        robot with a tracker, an :class:`iwr.Noise` gives the leg and joint readings' noise and,
        by its ``position``, the tracker's (:meth:`iwr.tracker.TrackerNoise.leica` scaled by
        ``position / 0.02``); a pair gives both.
    seeds : sequence of int
        One simulated problem per seed and scenario; the same seeds give the same numbers.
    methods : sequence of str, optional
        Method specs, each also its label in the report: a name registered in
        ``iwr.methods.METHODS`` (``"de"`` is the paper's DE/rand/1/bin with its defaults), or
        ``"de:STRATEGY"``, DE with a strategy of ``iwr.de.STRATEGIES`` (``"de:jso"``,
        ``"de:lshade"``, ...). Default: :data:`DEFAULT_METHODS` (``lm``, ``de``, ``de:jso``,
        ``crs2``, ``bobyqa``, ``efficient``), then any other registered method.
    budget : int
        Evaluation budget of every run, passed as ``max_evaluations`` (a Jacobian counts as one
        evaluation); lshade and jso plan their schedules over it. DE never exceeds it, but it
        evaluates its initial population whole: a DE spec whose population is larger than the
        budget is refused.
    start : "near", "bad", "both" or a sequence of them
        The scenarios; see :data:`SCENARIOS`.
    out : path, optional
        Where to write the report (created if needed); None: no files.
    n_validation : int
        Fresh, noise-free poses of the actual robot for the validation figures; they are also
        the yardstick of :func:`iwr.parameter_error` (what is identifiable).
    success_rtol, success_atol : float
        A run is *at the floor* when its cost is at most ``(1 + success_rtol) * floor + 6 N
        success_atol^2``, where ``floor`` is the cost of the true parameters on the same (noisy)
        data: within ``success_rtol`` of the noise floor, or within ``success_atol`` mm RMS of the
        readings. A run *succeeds* when the method says so (``success``: it converged and, with a
        noise model, passed the fit test of :func:`iwr.estimation.fit_check`); the two are
        counted side by side.
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
    kind = check_robot(robot)
    n_poses = check_n_poses(robot, n_poses)
    n_validation = _check_int("n_validation", n_validation, 1)
    budget = _check_int("budget", budget, 2)
    noise = _check_noise(noise)
    kind.experiment_noise(robot, noise)  # a model the robot's kind cannot take fails here
    seeds = _check_seeds(seeds)
    names = _check_methods(methods, noise)
    starts = _check_starts(start)
    for label, v in (("success_rtol", success_rtol), ("success_atol", success_atol)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise ArgumentError(f"{label}: {v!r}; expected a finite number >= 0")
    extra = dict(method_options or {})
    for k, v in extra.items():
        if k not in names or not isinstance(v, dict):
            raise ArgumentError(
                f"method_options: {k!r}; expected a dict of options per compared method (keyed "
                "by its label, e.g. 'de:jso')"
            )
        base, fixed = split_method(k)
        if base == "de" and "strategy" in v:
            # The label says which strategy ran: 'de' is rand1bin, 'de:jso' is jso.
            named = fixed.get("strategy", "rand1bin")
            if v["strategy"] != named:
                raise ArgumentError(f"method_options: {k!r} sets strategy {v['strategy']!r}; "
                                 f"use the label 'de:{v['strategy']}' instead")
    out_path = None if out is None else Path(out)
    if out_path is not None and out_path.exists() and not out_path.is_dir():
        raise ArgumentError(f"out: {str(out_path)!r} exists and is not a folder")
    show = sys.stderr.isatty() if progress is None else bool(progress)

    from ..effects import parameter_names as effect_names

    # The robot's, its effects' (issue 23), then the set-up's: the layout of every run's x.
    parameter_names = (robot.parameter_names + effect_names(robot.effects)
                       + kind.setup_parameter_names(robot))
    settings = {
        "robot": robot.name,
        "n_params": len(parameter_names),
        "n_poses": n_poses,
        "n_validation": n_validation,
        "noise": _noise_settings(kind.experiment_noise(robot, noise)),
        "kind": {"name": kind.name, "description": kind.description, "frame": kind.frame,
                 "parameter_names": parameter_names,
                 "chi2_fit_test": kind.chi2_fit_test, **kind.experiment_text},
        "seeds": seeds,
        "methods": names,
        "budget": budget,
        "scenarios": {s: SCENARIOS[s] for s in starts},
        "bounds": {s: _BOUNDS[s] for s in starts},
        "success_rtol": success_rtol,
        "success_atol": success_atol,
        "parameter_error": "iwr.parameter_error on the validation poses",
        "method_options": {m: _method_options(m, budget, extra)[1] for m in names},
        "de_settings": _check_de_budget(robot, names, budget, extra),
    }

    cells = _grid(robot, n_poses, noise, seeds, names, budget, starts, n_validation, extra)
    rows: dict[str, dict[str, Any]] = {}
    from tqdm.auto import tqdm

    with tqdm(total=len(cells), desc="compare", unit="run", disable=not show) as bar:
        def on_done(row: dict[str, Any]) -> None:
            rows[row["key"]] = row
            bar.set_postfix_str(f"{row['scenario']} seed {row['draw']}: {row['method']}")
            bar.update(1)

        floor = {"floor_rtol": success_rtol, "floor_atol": success_atol, "details": True}
        if scheduler == "synchronous":
            run_in_process(cells, robot, on_done, **floor)
            failures: list[tuple[Cell, BaseException]] = []
        else:
            try:
                failures = run_dask(cells, robot, on_done, scheduler=scheduler, **floor)
            except ExecutorError as exc:
                raise RuntimeError(str(exc)) from None
    if failures:
        cell, exc = failures[0]
        raise RuntimeError(f"{len(failures)} runs failed on every attempt (first: {cell.method}, "
                           f"seed {cell.draw}: {type(exc).__name__}: {exc})")
    runs = [_run_row(rows[c.key]) for c in cells]
    # A method that failed on every run never ran (bad options, or no start it can take): an
    # error. A run that failed among others (e.g. the efficient estimator from a start where a
    # pose has no forward kinematics) is a result: kept, not a success, its figures nan.
    for method in names:
        mine = [r for r in runs if r["method"] == method]
        if all(r["status"] != "ok" for r in mine):
            r = mine[0]
            raise ValueError(f"method {r['method']!r}, scenario {r['scenario']}, seed "
                             f"{r['seed']}: {r['message']}")
    comparison = Comparison(runs=runs, summary=_summarise(runs, starts, names), settings=settings)
    if out_path is not None:
        comparison.files = hook("compare_report")(comparison, out_path, robot)
    return comparison


def _noise_settings(noise: Any) -> dict[str, Any]:
    """The noise model as the settings say it: an iwr.Noise's fields, or a pair's as
    ``{"readings": {...}, "tracker": {...}}`` (``"ballbar"`` for a bar's: the instrument named
    after its noise class, as :func:`iwr.cli.robot_noise.describe` names it; a ballbar's report
    said "tracker"), with ``legs`` (the leg sigma) on top."""
    import dataclasses

    if isinstance(noise, tuple):
        readings, other = (dataclasses.asdict(p) if p is not None else {} for p in noise)
        name = ("tracker" if noise[1] is None
                else type(noise[1]).__name__.removesuffix("Noise").lower())
        return {"legs": leg_sigma(noise), "readings": readings, name: other}
    return {k: getattr(noise, k) for k in
            ("legs", "joint_lengths", "joint_angles", "position", "orientation")}


def _grid(robot: Robot, n_poses: int, noise: Any, seeds: list[int], names: list[str],
          budget: int, starts: list[str], n_validation: int,
          extra: dict[str, dict[str, Any]]) -> list[Cell]:
    """The cells of a comparison, in report order (scenario, seed, method). Seed k is the
    harness's error draw k, data seed 0."""
    rh = robot_hash(robot)
    cells = []
    for scenario in starts:
        for seed in seeds:
            for spec in names:
                method, opts = _method_options(spec, budget, extra)
                fixed = split_method(spec)[1]
                own = {k: v for k, v in opts.items() if k != "max_evaluations" and
                       fixed.get(k, object()) != v}
                option = None if budget_option(method) == "max_evaluations" else "max_evaluations"
                cells.append(Cell(spec, canonical(own), budget, n_poses, noise, seed, 0, 0,
                                  n_validation, rh, option, scenario))
    return cells


def _run_row(row: dict[str, Any]) -> dict[str, Any]:
    """A harness row as a run of the comparison: ``seed`` is the comparison's seed (the draw);
    a failed run's figures nan (counts 0), not a success."""
    out = {**row, "seed": row["draw"]}
    if out["status"] != "ok":
        for c in FIGURE_COLUMNS:
            out.setdefault(c, math.nan)
        out.update(nfev=0, nit=0, success=False, at_floor=False, within_budget=None)
        for c in ("x", "truth", "x0", "history_nfev", "history_best", "unidentifiable"):
            out.setdefault(c, [])
        out.setdefault("floor_threshold", math.nan)
    return out


def _median(values: list[float]) -> float:
    arr = np.array([v for v in values if not math.isnan(v)], dtype=float)
    return float(np.median(arr)) if arr.size else math.nan


def _median_worst(values: list[float]) -> float:
    """The median of a cost or an error over every run, a run without it counted as the worst
    (:func:`iwr.experiments.harness.percentiles_worst`)."""
    return float(percentiles_worst(values, 50)[0])


def _extreme(f: Any, values: list[float]) -> float:
    """``f`` (nanmin, nanmax) of the values that are numbers; nan when none is."""
    arr = np.asarray(values, dtype=float)
    return float(f(arr)) if np.isfinite(arr).any() else math.nan


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
                # The method's own verdict (converged, and its fit tested), then the cost alone.
                "successes": sum(bool(r["success"]) for r in rs),
                "success_rate": sum(bool(r["success"]) for r in rs) / len(rs),
                "at_floor": sum(bool(r["at_floor"]) for r in rs),
                "at_floor_rate": sum(bool(r["at_floor"]) for r in rs) / len(rs),
                "median_cost": _median_worst(costs),
                "min_cost": _extreme(np.nanmin, costs),
                "max_cost": _extreme(np.nanmax, costs),
                "median_noise_floor": _median([r["noise_floor"] for r in rs]),
                "median_val_rms": _median_worst([r["val_rms"] for r in rs]),
                "median_val_rms_nominal": _median([r["val_rms_nominal"] for r in rs]),
                "median_param_error_length": _median_worst([r["param_error_length"] for r in rs]),
                "median_param_error_angle": _median_worst([r["param_error_angle"] for r in rs]),
                "median_raw_error_length": _median_worst([r["raw_error_length"] for r in rs]),
                "median_raw_error_angle": _median_worst([r["raw_error_angle"] for r in rs]),
                "median_tool_position_rms": _median_worst([r["tool_position_rms"] for r in rs]),
                "median_tool_position_rms_nominal": _median([r["tool_position_rms_nominal"]
                                                             for r in rs]),
                "median_nfev": _median([float(r["nfev"]) for r in rs]),
                "max_nfev": int(max(r["nfev"] for r in rs)),
                "all_within_budget": all(r["within_budget"] for r in rs if r["status"] == "ok"),
                "failed": sum(r["status"] != "ok" for r in rs),
                "median_wall_time": _median([r["wall_time"] for r in rs]),
            })
    return out


