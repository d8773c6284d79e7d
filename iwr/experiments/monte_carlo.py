"""Monte-Carlo studies of identification on Dask: methods x poses x noise x error draws x seeds.

A study answers the questions a user plans a calibration with: how many poses, how much measurement
noise is affordable, which method. Each *cell* of the grid is one simulated calibration:

1. an 'actual' robot: the nominal robot plus an error vector drawn uniformly within the default
   bounds (+-0.5 mm, +-0.5 degree), one per *error draw*;
2. ``n_poses`` random reachable measurement poses of that robot, with measurement noise of the
   cell's *noise level* (see :func:`noise_at`), from the cell's *seed*;
3. identification by the cell's method (:func:`iwr.identify`), with the cell's *budget*;
4. validation on fresh, noise-free poses of the same actual robot.

This is the experiment harness's cell (:mod:`iwr.experiments.harness`, which documents the
seeding and the figures of a row); ``iwr compare`` is another use of it.

Cells are independent and idempotent. Each is keyed by a hash of its settings; its result is
written atomically as ``OUT/runs/<key>.json`` as soon as it finishes, and the tidy table
``OUT/results.csv`` (one row per cell, every setting and figure) is rewritten from those files.
A study started again with the same or a larger grid runs only the cells that have no file yet.

Cells run on Dask distributed: by default a local cluster of worker processes (one thread each) on
this machine's cores; ``scheduler=ADDRESS`` sends the same study to an existing cluster (the
workers need iwr installed, not a shared file system: results travel back to this process, which
writes them). A worker that dies loses only the cell it was running, which the scheduler runs again
elsewhere; ``scheduler="synchronous"`` runs every cell in this process, without Dask.
"""

from __future__ import annotations

import csv
import inspect
import io
import itertools
import json
import math
import os
import sys
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._hooks import hook
from .._io import atomic_write_text
from ..robot import Robot
from .executors import ExecutorError, dry_run, run_dask, run_in_process
from .harness import (
    COLUMNS,
    FIGURE_COLUMNS,
    SETTING_COLUMNS,
    TIMING_COLUMNS,
    ArgumentError,
    Cell,
    accepts,
    budget_option,
    canonical,
    check_n_poses,
    check_robot,
    noise_at,
    registered_methods,
    robot_hash,
)

__all__ = [
    "study",
    "StudyResult",
    "StudyError",
    "make_grid",
    "noise_at",
    "budget_option",
    "read_table",
    "write_table",
    "SETTING_COLUMNS",
    "FIGURE_COLUMNS",
    "TIMING_COLUMNS",
]

STUDY_FORMAT = 1
RUNS_FOLDER = "runs"
TABLE_NAME = "results.csv"
STUDY_FILE = "study.json"

_INT_COLUMNS = {"budget", "n_poses", "draw", "seed", "base_seed", "validation_poses", "nfev", "nit"}
_FLOAT_COLUMNS = {
    "noise", "cost", "noise_floor", "rms_fit", "val_rms", "val_max", "val_rms_nominal",
    "param_error_length", "param_error_angle", "raw_error_length", "raw_error_angle",
    "max_raw_error_length", "tool_position_rms", "tool_orientation_rms",
    "tool_position_rms_nominal", "wall_time",
}
_BOOL_COLUMNS = {"success", "at_floor", "within_budget"}

# Options that change how fast a cell runs, never its result: not part of the key.
_RUNTIME_OPTIONS = {"workers", "progress"}


class StudyError(RuntimeError):
    """A study could not run, or some of its cells failed on every attempt."""


# -- the grid -----------------------------------------------------------------------------------


def _json_value(value: Any, where: str) -> Any:
    """``value`` as plain JSON (numbers, strings, booleans, lists, dicts), else ValueError."""
    if isinstance(value, (bool, str)) or value is None:
        return value
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        if not math.isfinite(value):
            raise ArgumentError(f"{where}: {value!r} is not finite")
        return float(value)
    if isinstance(value, (list, tuple)):
        return [_json_value(v, where) for v in value]
    if isinstance(value, Mapping):
        return {str(k): _json_value(v, f"{where}.{k}") for k, v in value.items()}
    raise ArgumentError(f"{where}: {value!r} is not a number, string, boolean, list or table")


def _int_list(value: Any, name: str, minimum: int) -> list[int]:
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        if name in ("draws", "seeds"):
            if value < 1:
                raise ArgumentError(
                    f"{name}: {value!r}; expected a count >= 1 or a list of indices")
            return list(range(int(value)))
        value = [value]
    try:
        items = list(value)
    except TypeError:
        raise ArgumentError(
            f"{name}: {value!r}; expected an integer or a list of integers") from None
    out: list[int] = []
    for v in items:
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < minimum:
            raise ArgumentError(f"{name}: {v!r}; expected integers >= {minimum}")
        out.append(int(v))
    if not out:
        raise ArgumentError(f"{name}: empty")
    return list(dict.fromkeys(out))


def make_grid(
    methods: Sequence[str],
    poses: Sequence[int],
    noise: Sequence[float],
    draws: Sequence[int],
    seeds: Sequence[int],
    budgets: Mapping[str, tuple[str | None, Sequence[int | None]]],
    options: Mapping[str, Mapping[str, Any]],
    base_seed: int,
    validation_poses: int,
    robot: str,
) -> list[Cell]:
    """The cells of a study, in table order (method, budget, poses, noise, draw, seed)."""
    cells = []
    for method in methods:
        opts = {k: v for k, v in options.get(method, {}).items() if k not in _RUNTIME_OPTIONS}
        option, values = budgets.get(method, (None, [None]))
        for budget, n, level, draw, seed in itertools.product(values, poses, noise, draws, seeds):
            cells.append(
                Cell(method, canonical(opts), budget, n, level, draw, seed, base_seed,
                     validation_poses, robot, option if budget is not None else None)
            )
    return cells


# -- files ----------------------------------------------------------------------------------------


def _format(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return "" if math.isnan(value) else repr(value)
    return str(value)


def _parse(column: str, text: str) -> Any:
    if text == "":
        return math.nan if column in _FLOAT_COLUMNS else None
    if column in _INT_COLUMNS:
        return int(text)
    if column in _FLOAT_COLUMNS:
        return float(text)
    if column in _BOOL_COLUMNS:
        return text == "True"
    return text


def _parses(column: str, text: Any) -> bool:
    try:
        _parse(column, text)
    except (ValueError, AttributeError, TypeError):
        return False
    return isinstance(text, str)


def write_table(path: str | os.PathLike[str], rows: Iterable[Mapping[str, Any]]) -> None:
    """Write rows as the tidy CSV table (atomically); floats at full precision."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(COLUMNS)
    for row in rows:
        writer.writerow([_format(row.get(c)) for c in COLUMNS])
    atomic_write_text(path, buf.getvalue())


def read_table(path: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """Read a study's table (``results.csv``, or the study folder) as a list of rows (dicts)."""
    path = Path(path)
    if path.is_dir():
        path = path / TABLE_NAME
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            missing = [c for c in ("key", "method", "n_poses", "noise") if c not in
                       (reader.fieldnames or [])]
            if missing:
                raise StudyError(f"{path}: not a study table (no column {missing[0]!r})")
            rows = []
            for r in reader:
                try:
                    rows.append({c: _parse(c, v) for c, v in r.items()})
                except (ValueError, AttributeError):
                    bad = next((c, v) for c, v in r.items() if not _parses(c, v))
                    raise StudyError(
                        f"{path}, line {reader.line_num}: column {bad[0]!r}: {bad[1]!r} is not a "
                        "valid value"
                    ) from None
            return rows
    except FileNotFoundError:
        raise StudyError(f"{path}: no such file") from None


def _load_runs(folder: Path) -> dict[str, dict[str, Any]]:
    """The rows already written in ``folder``, by key. Unreadable files are ignored (redone)."""
    rows = {}
    if folder.is_dir():
        for path in folder.glob("*.json"):
            try:
                row = json.loads(path.read_text(encoding="utf-8"))
            except (OSError, ValueError):
                continue
            if isinstance(row, dict) and row.get("key") == path.stem:
                rows[path.stem] = row
    return rows


def _write_run(folder: Path, row: Mapping[str, Any]) -> None:
    text = json.dumps(row, indent=1, allow_nan=True) + "\n"
    atomic_write_text(folder / f"{row['key']}.json", text)


# -- running the grid ---------------------------------------------------------------------------


@dataclass
class StudyResult:
    """What :func:`study` did.

    Attributes
    ----------
    out : Path
        The study folder.
    table : Path
        The tidy table, ``out/results.csv``.
    rows : list of dict
        The table's rows, in grid order (method, budget, poses, noise, draw, seed).
    executed, reused : int
        Cells computed by this call, and cells whose result was already in ``out/runs/``.
    failed : int
        Cells whose computation raised an error (recorded in their row's ``message``).
    plots : list of Path
        The figures written by the report, and the summary ``out/summary.md``.
    """

    out: Path
    table: Path
    rows: list[dict[str, Any]]
    executed: int
    reused: int
    failed: int
    plots: list[Path] = field(default_factory=list)


def _progress_bar(total: int, progress: bool | None) -> Any:
    from tqdm import tqdm

    disable = (not sys.stderr.isatty()) if progress is None else not progress
    return tqdm(total=total, disable=disable, desc="study", unit="cell", leave=False)


def study(
    methods: Sequence[str] | str = ("lm",),
    poses: Sequence[int] | int = (20, 50, 100),
    noise: Sequence[float] | float = (0.0, 0.02),
    draws: Sequence[int] | int = 3,
    seeds: Sequence[int] | int = 3,
    *,
    budgets: Mapping[str, Sequence[int | None]] | Sequence[int] | None = None,
    out: str | os.PathLike[str] = "study",
    robot: Robot | str | os.PathLike[str] | None = None,
    options: Mapping[str, Mapping[str, Any]] | None = None,
    validation_poses: int = 50,
    base_seed: int = 0,
    scheduler: Any = None,
    workers: int | None = None,
    retries: int = 2,
    report: bool = True,
    progress: bool | None = None,
) -> StudyResult:
    """Run a Monte-Carlo study of identification over a grid of settings (see the module doc).

    Parameters
    ----------
    methods : str or list of str
        Identification methods, names of ``iwr.methods.METHODS`` (``"lm"``, ``"de"``, ...).
    poses : int or list of int
        Numbers of measurement poses N, each at least :func:`~iwr.experiments.harness.min_poses`
        (9 for the IWR).
    noise : float or list of float
        Noise levels: the tracker's position standard deviation in mm, the other channels in the
        proportions of :meth:`iwr.Noise.realistic` (:func:`noise_at`). 0 is the paper's setting.
        On tracker data the level scales the leg and joint noise the same way and the tracker's
        :meth:`iwr.tracker.TrackerNoise.leica` by level / 0.02.
    draws : int or list of int
        Error draws (the 'actual' robots): a count n for draws 0..n-1, or the indices.
    seeds : int or list of int
        Seeds of the poses, the noise and the method: a count or the indices.
    budgets : list of int, or {method: list of int}, optional
        Budget axis: generations for ``"de"``, evaluations for ``"lm"``, ``"crs2"``, ``"bobyqa"``
        (:func:`budget_option`). A list applies to every method; ``None`` in a list (or a method
        left out of the mapping) means the method's default. A key ``"METHOD.OPTION"`` makes the
        budget set that option instead, e.g. ``{"de.max_evaluations": [...]}`` for jSO and
        L-SHADE, whose schedules run over an evaluation budget.
    out : path
        The study folder: ``runs/`` (one JSON file per cell), ``results.csv``, ``study.json``, and
        the report (``summary.md`` and PNG figures).
    robot : Robot or path of a robot TOML file, optional
        The nominal robot (default: :meth:`iwr.Robot.default`). Its kind of data
        (:func:`iwr.kinds.for_robot`: the platform pose in {0}, or reflector points or a probe
        in {T} for a robot with a ``[tracker]`` setup) is simulated, identified and validated
        (:attr:`iwr.kinds.MeasurementKind.experiment_text` says what each figure measures).
    options : {method: {option: value}}, optional
        Options of each method (e.g. ``{"de": {"strategy": "lshade"}}``); part of the cells' keys,
        except ``workers`` (threads per identification, default 1: a study parallelises across
        cells) and ``progress``.
    validation_poses : int
        Fresh poses per (draw, seed) on which the calibrated model is validated.
    base_seed : int
        Root of every random stream of the study.
    scheduler : None, "synchronous", an address or a ``distributed.Client``
        None: a local Dask cluster of ``workers`` processes (default: one per core). An address
        (``"tcp://host:8786"``) or a Client: that cluster. ``"synchronous"``: this process, no Dask.
    workers : int, optional
        Worker processes of the local cluster.
    retries : int
        Extra attempts of a cell whose worker died or that raised an unexpected error.
    report : bool
        Write the plots, ``summary.md`` and ``report.html`` (:func:`iwr.reporting.study.report`)
        at the end.
    progress : bool, optional
        A progress bar (default: when standard error is a terminal).

    Returns
    -------
    StudyResult

    Raises
    ------
    StudyError
        Some cells failed on every attempt (their rows are missing; run the study again to
        retry them), or the scheduler cannot be reached.
    """
    if isinstance(methods, str):
        methods = [m.strip() for m in methods.split(",") if m.strip()]
    methods = list(dict.fromkeys(methods))
    if not methods:
        raise ArgumentError("methods: empty")
    registered = registered_methods()
    for m in methods:
        if m not in registered:
            raise ArgumentError(f"methods: {m!r}; available: {', '.join(sorted(registered))}")
    poses_l = _int_list(poses, "poses", 1)
    draws_l = _int_list(draws, "draws", 0)
    seeds_l = _int_list(seeds, "seeds", 0)
    noise_l = []
    for v in np.atleast_1d(np.asarray(noise, dtype=object)).tolist():
        try:
            level = float(v)
        except (TypeError, ValueError):
            raise ArgumentError(f"noise: {v!r}; expected numbers >= 0 (mm)") from None
        noise_at(level)
        noise_l.append(level)
    noise_l = list(dict.fromkeys(noise_l))
    if not noise_l:
        raise ArgumentError("noise: empty")
    budgets_d = _budgets(budgets, methods)
    options_d: dict[str, dict[str, Any]] = {}
    for m, opts in (options or {}).items():
        if m not in methods:
            raise ArgumentError(
                f"options: method {m!r} is not one of the study's methods {methods}")
        options_d[m] = _json_value(dict(opts), f"options.{m}")
    for m, opts in options_d.items():
        params = inspect.signature(registered[m]).parameters
        if not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
            known = [n for n, p in params.items() if p.kind is inspect.Parameter.KEYWORD_ONLY
                     and n not in ("x0", "active", "seed", "callback", "progress")]
            for name in opts:
                if name not in known:
                    raise ArgumentError(
                        f"options.{m}.{name}: not an option of method {m!r} "
                        f"(options: {', '.join(known)})"
                    )
        option, values = budgets_d.get(m, (None, [None]))
        option = option or (budget_option(m) if values != [None] else None)
        if option is not None and option in opts:
            raise ArgumentError(f"options.{m}.{option}: set by the budget axis too")
    if isinstance(validation_poses, bool) or not isinstance(validation_poses, int) or \
            validation_poses < 1:
        raise ArgumentError(f"validation_poses: {validation_poses!r}; expected an integer >= 1")
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise ArgumentError(f"retries: {retries!r}; expected an integer >= 0")
    if (isinstance(base_seed, bool) or not isinstance(base_seed, (int, np.integer))
            or not 0 <= base_seed < 2**64):
        # NumPy's seeds; a negative one failed every cell with NumPy's message, and exit 0.
        raise ArgumentError(f"base_seed: {base_seed!r}; expected an integer in [0, 2^64)")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers < 1):
        raise ArgumentError(f"workers: {workers!r}; expected an integer >= 1")
    if workers is not None and scheduler is not None:
        raise ArgumentError("workers: only for the local cluster; an existing cluster has its own")
    if robot is None:
        robot = Robot.default()
    elif not isinstance(robot, Robot):
        robot = Robot.from_toml(robot)
    kind = check_robot(robot)
    for n in poses_l:
        check_n_poses(robot, n, "poses")
    for m, opts in options_d.items():
        try:  # the options' values, by the method's own checks, before any cell runs
            dry_run(robot, m, opts)
        except (ValueError, TypeError) as exc:
            raise ArgumentError(f"options.{m}.{exc}") from None
    for m, (option, values) in budgets_d.items():
        # The smallest budget too (DE's engine refuses one below its initial population): a
        # study whose every cell of it fails, exit 0, was the alternative.
        given = [v for v in values if v is not None]
        if not given:
            continue
        name = option or budget_option(m)
        try:
            dry_run(robot, m, {**options_d.get(m, {}), name: min(given)})
        except (ValueError, TypeError) as exc:
            raise ArgumentError(f"budgets: {m}.{name} = {min(given)}: {exc}") from None

    out = Path(out)
    runs = out / RUNS_FOLDER
    runs.mkdir(parents=True, exist_ok=True)
    rhash = robot_hash(robot)
    cells = make_grid(methods, poses_l, noise_l, draws_l, seeds_l, budgets_d, options_d,
                      int(base_seed), validation_poses, rhash)
    atomic_write_text(out / STUDY_FILE, json.dumps({
        "format": STUDY_FORMAT,
        "methods": methods, "poses": poses_l, "noise": noise_l, "draws": draws_l,
        "seeds": seeds_l, "budgets": budgets_d, "options": options_d,
        "validation_poses": validation_poses, "base_seed": int(base_seed),
        "noise_model": "level: " + kind.experiment_text["noise_level"],
        "kind": {"name": kind.name, "description": kind.description, "frame": kind.frame,
                 **kind.experiment_text},
        "robot": robot.to_dict(), "robot_hash": rhash, "cells": len(cells),
    }, indent=1) + "\n")

    done = _load_runs(runs)
    todo = [c for c in cells if c.key not in done]
    by_key = {c.key: c for c in cells}
    reused = len(cells) - len(todo)
    table = out / TABLE_NAME
    keys = [c.key for c in cells]
    bar = _progress_bar(len(todo), progress)
    last_table = [time.monotonic()]

    def on_done(row: dict[str, Any]) -> None:
        _write_run(runs, row)
        done[row["key"]] = row
        bar.update(1)
        if time.monotonic() - last_table[0] > 10.0:  # the table in flight, for long studies
            write_table(table, ({**done[k], **by_key[k].columns()} for k in keys if k in done))
            last_table[0] = time.monotonic()

    runtime = {"workers": 1}
    try:
        if not todo:
            failures: list[tuple[Cell, BaseException]] = []
        elif scheduler == "synchronous":
            failures = run_in_process(todo, robot, on_done, runtime)
        else:
            try:
                failures = run_dask(todo, robot, on_done, runtime, scheduler=scheduler,
                                    workers=workers, retries=retries)
            except ExecutorError as exc:
                raise StudyError(str(exc)) from None
    finally:
        bar.close()
        # Settings from the grid (a row written by an older version may lack a column).
        write_table(table, ({**done[k], **by_key[k].columns()} for k in keys if k in done))
    rows = read_table(table)
    result = StudyResult(
        out=out, table=table, rows=rows, executed=len(todo) - len(failures), reused=reused,
        failed=sum(r.get("status") == "failed" for r in rows),
    )
    if failures:
        cell, exc = failures[0]
        if any("scheduler-connection-lost" in str(e) for _, e in failures):
            raise StudyError(
                f"scheduler: lost the connection to {scheduler!r}; {len(failures)} of "
                f"{len(cells)} cells did not finish; the others are in {table}; run the study "
                "again to compute the missing ones"
            )
        raise StudyError(
            f"{len(failures)} of {len(cells)} cells failed on every attempt (first: {cell.method}, "
            f"N={cell.n_poses}, noise={cell.noise}, draw={cell.draw}, seed={cell.seed}: "
            f"{type(exc).__name__}: {exc}); the others are in {table}; run the study again to "
            "retry the missing ones"
        )
    if report:
        result.plots = hook("study_report")(out)  # iwr.reporting.study, a layer up
    return result


def _budgets(budgets: Any, methods: list[str]) -> dict[str, tuple[str | None, list[int | None]]]:
    """{method: (option or None for the default, values)} from the ``budgets`` argument."""
    if budgets is None:
        return {}
    if isinstance(budgets, Mapping):
        items = dict(budgets)
    else:
        listed = list(np.atleast_1d(np.asarray(budgets, dtype=object)).tolist())
        items = {m: listed for m in methods}
    out: dict[str, tuple[str | None, list[int | None]]] = {}
    for name, values in items.items():
        m, _, option = str(name).partition(".")
        if m not in methods:
            raise ArgumentError(
                f"budgets: method {m!r} is not one of the study's methods {methods}")
        if m in out:
            raise ArgumentError(f"budgets: two budget axes for method {m!r}")
        vals: list[int | None] = []
        for v in np.atleast_1d(np.asarray(values, dtype=object)).tolist():
            if isinstance(v, float) and v.is_integer():
                v = int(v)
            if v is None:
                vals.append(None)
            elif isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ArgumentError(f"budgets: {v!r} for method {m!r}; expected integers >= 1")
            else:
                vals.append(int(v))
        if not vals:
            raise ArgumentError(f"budgets: empty for method {m!r}")
        if option:
            if not accepts(m, option) and not any(
                p.kind is inspect.Parameter.VAR_KEYWORD
                for p in inspect.signature(registered_methods()[m]).parameters.values()
            ):
                raise ArgumentError(f"budgets: {option!r} is not an option of method {m!r}")
            if option == budget_option(m):
                option = ""
        elif vals != [None]:
            budget_option(m)
        out[m] = (option or None, list(dict.fromkeys(vals)))
    return out


