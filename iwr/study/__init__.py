"""Monte-Carlo studies of identification on Dask: methods x poses x noise x error draws x seeds.

A study answers the questions a user plans a calibration with: how many poses, how much measurement
noise is affordable, which method. Each *cell* of the grid is one simulated calibration:

1. an 'actual' robot: the nominal robot plus an error vector drawn uniformly within the default
   bounds (+-0.5 mm, +-0.5 degree), one per *error draw*;
2. ``n_poses`` random reachable measurement poses of that robot, with measurement noise of the
   cell's *noise level* (see :func:`noise_at`), from the cell's *seed*;
3. identification by the cell's method (:func:`iwr.identify`), with the cell's *budget*;
4. validation on fresh, noise-free poses of the same actual robot: the RMS and the maximum of the
   error of the leg readings predicted by the calibrated model, and the same for the nominal model
   (before calibration); the parameter error on the identifiable part (``iwr.parameter_error``)
   and the tool's position/orientation error (``iwr.accuracy``) where those functions exist.

Seeds: the error vector depends on ``(base_seed, draw)`` only, the poses, the noise and the
method's random stream on ``(base_seed, draw, seed)`` only, and the validation poses on
``(base_seed, draw, seed)``. So every method, pose count and noise level of a (draw, seed) pair sees
the same robot and validation poses, and every noise level the same poses with noise of the same
shape, scaled (common random numbers: differences between cells are not sampling noise).

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

import argparse
import csv
import functools
import hashlib
import inspect
import io
import itertools
import json
import math
import os
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._io import atomic_write_text
from ..identify import METHODS, identify
from ..measurements import Measurements
from ..problem import predict_legs
from ..robot import Robot
from ..simulate import Noise, sample_poses, simulate

__all__ = [
    "study",
    "StudyResult",
    "StudyError",
    "noise_at",
    "budget_option",
    "read_table",
    "report",
    "add_study_parser",
    "run_study",
    "main",
    "SETTING_COLUMNS",
    "FIGURE_COLUMNS",
    "TIMING_COLUMNS",
]

STUDY_FORMAT = 1
RUNS_FOLDER = "runs"
TABLE_NAME = "results.csv"
STUDY_FILE = "study.json"

# The tidy table: one row per cell. Settings first, then figures; missing figures are empty.
SETTING_COLUMNS = (
    "key", "method", "options", "budget", "budget_option", "n_poses", "noise", "draw", "seed",
    "base_seed", "validation_poses", "robot",
)
FIGURE_COLUMNS = (
    "status", "message", "cost", "rms_fit", "val_rms", "val_max", "val_rms_nominal",
    "param_error_length", "param_error_angle", "tool_position_rms", "tool_orientation_rms",
    "tool_position_rms_nominal", "nfev", "nit", "success", "wall_time", "notes",
)
# Figures that depend on the machine, not on the settings: left out when tables are compared.
TIMING_COLUMNS = ("wall_time",)
COLUMNS = SETTING_COLUMNS + FIGURE_COLUMNS

_INT_COLUMNS = {"budget", "n_poses", "draw", "seed", "base_seed", "validation_poses", "nfev", "nit"}
_FLOAT_COLUMNS = {
    "noise", "cost", "rms_fit", "val_rms", "val_max", "val_rms_nominal", "param_error_length",
    "param_error_angle", "tool_position_rms", "tool_orientation_rms", "tool_position_rms_nominal",
    "wall_time",
}
_BOOL_COLUMNS = {"success"}

# The option that a cell's budget sets: generations for DE, else the first evaluation limit that
# the method's signature accepts (``max_evaluations`` for lm, crs2 and bobyqa).
BUDGET_OPTIONS = {"de": "generations"}
_BUDGET_CANDIDATES = ("generations", "max_evaluations", "max_nfev", "maxeval", "max_evals",
                      "budget")
# Options that change how fast a cell runs, never its result: not part of the key.
_RUNTIME_OPTIONS = {"workers", "progress"}


class StudyError(RuntimeError):
    """A study could not run, or some of its cells failed on every attempt."""


# -- the grid -----------------------------------------------------------------------------------


def noise_at(level: float) -> Noise:
    """The measurement noise of a study's noise level: ``level`` is the laser tracker's position
    standard deviation (mm); the other channels keep the proportions of :meth:`Noise.realistic`.

    So ``noise_at(0.02) == Noise.realistic()`` (legs 2 um, joints 5 um and 5 urad, tracker 20 um
    and 20 urad) and ``noise_at(0)`` is the paper's noise-free simulation.
    """
    level = float(level)
    if not (math.isfinite(level) and level >= 0):
        raise ValueError(f"noise: {level!r}; expected a finite level >= 0 (mm)")
    ref = Noise.realistic()
    scale = level / ref.position
    return Noise(
        legs=ref.legs * scale,
        joint_lengths=ref.joint_lengths * scale,
        joint_angles=ref.joint_angles * scale,
        position=ref.position * scale,
        orientation=ref.orientation * scale,
    )


def _seed(*entropy: int) -> int:
    """A 63-bit seed drawn from the given integers: independent streams for independent uses."""
    return int(np.random.SeedSequence(list(entropy)).generate_state(1, np.uint64)[0] >> 1)


# Purposes of the random streams of a cell, the second entropy word of _seed.
_ERRORS, _DATA, _VALIDATION, _METHOD = 1, 2, 3, 4


def _canonical(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)


def robot_hash(robot: Robot) -> str:
    """A short hash of the robot's description, part of every cell's key."""
    return hashlib.sha256(_canonical(robot.to_dict()).encode()).hexdigest()[:12]


def budget_option(method: str) -> str:
    """The option of ``method`` that a study's budget sets (``generations`` for DE)."""
    if method in BUDGET_OPTIONS:
        return BUDGET_OPTIONS[method]
    if method not in METHODS:
        raise ValueError(f"method: {method!r}; available: {', '.join(sorted(METHODS))}")
    params = inspect.signature(METHODS[method]).parameters
    for name in _BUDGET_CANDIDATES:
        if name in params:
            return name
    raise ValueError(
        f"budget: method {method!r} has no known budget option ({', '.join(_BUDGET_CANDIDATES)})"
    )


def _accepts(method: str, option: str) -> bool:
    return option in inspect.signature(METHODS[method]).parameters


def _json_value(value: Any, where: str) -> Any:
    """``value`` as plain JSON (numbers, strings, booleans, lists, dicts), else ValueError."""
    if isinstance(value, (bool, str)) or value is None:
        return value
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        if not math.isfinite(value):
            raise ValueError(f"{where}: {value!r} is not finite")
        return float(value)
    if isinstance(value, (list, tuple)):
        return [_json_value(v, where) for v in value]
    if isinstance(value, Mapping):
        return {str(k): _json_value(v, f"{where}.{k}") for k, v in value.items()}
    raise ValueError(f"{where}: {value!r} is not a number, string, boolean, list or table")


def _int_list(value: Any, name: str, minimum: int) -> list[int]:
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        if name in ("draws", "seeds"):
            if value < 1:
                raise ValueError(f"{name}: {value!r}; expected a count >= 1 or a list of indices")
            return list(range(int(value)))
        value = [value]
    try:
        items = list(value)
    except TypeError:
        raise ValueError(f"{name}: {value!r}; expected an integer or a list of integers") from None
    out: list[int] = []
    for v in items:
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < minimum:
            raise ValueError(f"{name}: {v!r}; expected integers >= {minimum}")
        out.append(int(v))
    if not out:
        raise ValueError(f"{name}: empty")
    return list(dict.fromkeys(out))


@dataclass(frozen=True)
class Cell:
    """The settings of one identification of a study; ``key`` identifies its result."""

    method: str
    options: str  # canonical JSON of the method's options (runtime-only options left out)
    budget: int | None
    n_poses: int
    noise: float
    draw: int
    seed: int
    base_seed: int
    validation_poses: int
    robot: str  # robot_hash
    # The option that the budget sets, when not the method's default (budget_option(method)).
    budget_option: str | None = None

    @property
    def settings(self) -> dict[str, Any]:
        extra = {} if self.budget_option is None else {"budget_option": self.budget_option}
        return {
            **extra,
            "format": STUDY_FORMAT,
            "method": self.method,
            "options": json.loads(self.options),
            "budget": self.budget,
            "n_poses": self.n_poses,
            "noise": self.noise,
            "noise_model": "tracker position sd (mm), realistic proportions",
            "draw": self.draw,
            "seed": self.seed,
            "base_seed": self.base_seed,
            "validation_poses": self.validation_poses,
            "robot": self.robot,
        }

    def columns(self) -> dict[str, Any]:
        """The setting columns of the cell's row in the table."""
        row: dict[str, Any] = {c: getattr(self, c) for c in SETTING_COLUMNS if c != "key"}
        row["key"] = self.key
        if self.budget is not None and self.budget_option is None:
            row["budget_option"] = budget_option(self.method)
        return row

    @property
    def key(self) -> str:
        return hashlib.sha256(_canonical(self.settings).encode()).hexdigest()[:20]


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
                Cell(method, _canonical(opts), budget, n, level, draw, seed, base_seed,
                     validation_poses, robot, option if budget is not None else None)
            )
    return cells


# -- one cell, on a worker ----------------------------------------------------------------------


@functools.lru_cache(maxsize=4)
def _robot_from_json(text: str) -> Robot:
    return Robot.from_dict(json.loads(text))


def true_errors(robot: Robot, base_seed: int, draw: int) -> np.ndarray:
    """The 'actual' robot's error vector of an error draw: uniform within the default bounds."""
    rng = np.random.default_rng(_seed(base_seed, _ERRORS, draw))
    lower, upper = robot.default_bounds()
    return lower + (upper - lower) * rng.random(robot.n_params)


# Exceptions that a cell's computation raises deterministically: recorded in its row as a failure
# (running it again would fail again). Anything else (a lost connection, memory) propagates, so
# that Dask retries the cell.
_RECORDED_ERRORS = (ValueError, ArithmeticError, RuntimeError, np.linalg.LinAlgError)


def _validate(
    robot: Robot, x: np.ndarray, truth: np.ndarray, base_seed: int, draw: int, seed: int,
    n_val: int,
) -> dict[str, Any]:
    """Figures of an identified vector ``x`` on fresh, noise-free poses of the actual robot.

    The validation poses also serve as the yardstick of ``iwr.parameter_error`` (what is
    identifiable): the same generic set for every pose count, so that small calibration sets do
    not hide errors in directions that they happen not to see.
    """
    import iwr  # the package, for the optional functions of other modules

    rng = np.random.default_rng(_seed(base_seed, _VALIDATION, draw, seed))
    q, poses, legs = sample_poses(robot, n_val, rng, truth)
    err = predict_legs(robot, x, q, poses) - legs
    err0 = predict_legs(robot, np.zeros_like(x), q, poses) - legs
    out: dict[str, Any] = {
        "val_rms": float(np.sqrt(np.mean(err**2))),
        "val_max": float(np.max(np.abs(err))),
        "val_rms_nominal": float(np.sqrt(np.mean(err0**2))),
    }
    data = Measurements(q, poses, legs, joint_types=robot.joint_types)
    notes = []
    parameter_error = getattr(iwr, "parameter_error", None)
    if parameter_error is not None:
        try:
            pe = parameter_error(robot, data, x, truth)
            out["param_error_length"] = float(pe.rms_length)
            out["param_error_angle"] = float(pe.rms_angle)
        except _RECORDED_ERRORS as exc:
            notes.append(f"parameter_error: {type(exc).__name__}: {exc}")
    accuracy = getattr(iwr, "accuracy", None)
    if accuracy is not None:
        try:
            acc = accuracy(robot, data, x)
            out["tool_position_rms"] = _rms(acc.calibrated.position)
            out["tool_orientation_rms"] = _rms(acc.calibrated.orientation)
            out["tool_position_rms_nominal"] = _rms(acc.nominal.position)
        except _RECORDED_ERRORS as exc:  # e.g. forward kinematics of a poor model diverges
            notes.append(f"accuracy: {type(exc).__name__}: {exc}")
    if notes:
        out["notes"] = "; ".join(notes)
    return out


def _rms(v: Any) -> float:
    return float(np.sqrt(np.mean(np.asarray(v, dtype=float) ** 2)))


def run_cell(cell: Cell, robot_json: str, runtime_options: Mapping[str, Any]) -> dict[str, Any]:
    """Simulate, identify and validate one cell; its row of the table (a plain dict).

    Runs on a worker. Deterministic: the same cell gives the same row (``wall_time`` aside).
    """
    robot = _robot_from_json(robot_json)
    row = cell.columns()
    start = time.perf_counter()
    try:
        truth = true_errors(robot, cell.base_seed, cell.draw)
        data, _ = simulate(
            robot, cell.n_poses, seed=_seed(cell.base_seed, _DATA, cell.draw, cell.seed),
            x=truth, noise=noise_at(cell.noise),
        )
        options = dict(json.loads(cell.options))
        if cell.budget is not None:
            options[row["budget_option"]] = cell.budget
        for name, value in runtime_options.items():
            if _accepts(cell.method, name):
                options.setdefault(name, value)
        result = identify(
            robot, data, method=cell.method,
            seed=_seed(cell.base_seed, _METHOD, cell.draw, cell.seed), progress=False, **options,
        )
        x = np.asarray(result.x, dtype=float)
        row.update(
            cost=float(result.fun),
            rms_fit=math.sqrt(float(result.fun) / (6 * cell.n_poses)),
            nfev=int(result.nfev),
            nit=int(result.get("nit", 0)),
            success=bool(result.success),
        )
        row.update(_validate(robot, x, truth, cell.base_seed, cell.draw, cell.seed,
                             cell.validation_poses))
        row.update(status="ok", message=str(result.get("message", "")))
        row["x"] = x.tolist()
    except _RECORDED_ERRORS as exc:
        row.update(status="failed", message=f"{type(exc).__name__}: {exc}")
    row["wall_time"] = time.perf_counter() - start
    return row


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


def _run_synchronous(
    todo: list[Cell], robot_json: str, runtime: Mapping[str, Any],
    on_done: Callable[[dict[str, Any]], None],
) -> list[tuple[Cell, BaseException]]:
    for cell in todo:
        on_done(run_cell(cell, robot_json, runtime))
    return []


def _run_dask(
    todo: list[Cell], robot_json: str, runtime: Mapping[str, Any],
    on_done: Callable[[dict[str, Any]], None], scheduler: Any, workers: int | None, retries: int,
) -> list[tuple[Cell, BaseException]]:
    try:
        from distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise StudyError(
            "scheduler: Dask distributed is not installed; pip install 'iwr[study]', or run with "
            "scheduler='synchronous'"
        ) from None
    import dask

    cluster = None
    # A worker that dies while running a cell makes the cell 'suspicious'; the scheduler runs it
    # again on another worker up to allowed-failures times (a local cluster's scheduler only: an
    # existing cluster keeps its own setting). `retries` covers exceptions raised by a cell.
    with dask.config.set({"distributed.scheduler.allowed-failures": max(retries, 0) + 1}):
        try:
            if scheduler is None:
                n = workers if workers is not None else (os.cpu_count() or 1)
                cluster = LocalCluster(
                    n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0"
                )
                client = Client(cluster)
            elif isinstance(scheduler, Client):
                client = scheduler
            else:
                client = Client(scheduler)
        except OSError as exc:
            if cluster is not None:
                cluster.close()
            raise StudyError(f"scheduler: cannot connect to {scheduler!r}: {exc}") from None
    failures: list[tuple[Cell, BaseException]] = []
    try:
        futures = {}
        for cell in todo:
            # The robot travels with each cell (a few kB): nothing for a dying worker to lose.
            fut = client.submit(
                run_cell, cell, robot_json, dict(runtime), key=f"iwr-study-{cell.key}",
                retries=retries, pure=False,
            )
            futures[fut] = cell
        try:
            for fut in as_completed(list(futures)):
                try:
                    row = fut.result()
                except Exception as exc:  # noqa: BLE001 - any failure of a cell is reported
                    failures.append((futures[fut], exc))
                else:
                    on_done(row)
                fut.release()
        except BaseException:
            client.cancel(list(futures))
            raise
    finally:
        if client is not scheduler:
            client.close()
        if cluster is not None:
            cluster.close()
    return failures


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
        Identification methods, names of ``iwr.identify.METHODS`` (``"lm"``, ``"de"``, ...).
    poses : int or list of int
        Numbers of measurement poses N.
    noise : float or list of float
        Noise levels: the tracker's position standard deviation in mm, the other channels in the
        proportions of :meth:`iwr.Noise.realistic` (:func:`noise_at`). 0 is the paper's setting.
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
        The nominal robot (default: :meth:`iwr.Robot.default`).
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
        Write the plots and ``summary.md`` (:func:`iwr.study.report`) at the end.
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
        raise ValueError("methods: empty")
    for m in methods:
        if m not in METHODS:
            raise ValueError(f"methods: {m!r}; available: {', '.join(sorted(METHODS))}")
    poses_l = _int_list(poses, "poses", 1)
    draws_l = _int_list(draws, "draws", 0)
    seeds_l = _int_list(seeds, "seeds", 0)
    noise_l = []
    for v in np.atleast_1d(np.asarray(noise, dtype=object)).tolist():
        try:
            level = float(v)
        except (TypeError, ValueError):
            raise ValueError(f"noise: {v!r}; expected numbers >= 0 (mm)") from None
        noise_at(level)
        noise_l.append(level)
    noise_l = list(dict.fromkeys(noise_l))
    if not noise_l:
        raise ValueError("noise: empty")
    budgets_d = _budgets(budgets, methods)
    options_d: dict[str, dict[str, Any]] = {}
    for m, opts in (options or {}).items():
        if m not in methods:
            raise ValueError(f"options: method {m!r} is not one of the study's methods {methods}")
        options_d[m] = _json_value(dict(opts), f"options.{m}")
    for m, opts in options_d.items():
        params = inspect.signature(METHODS[m]).parameters
        if not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
            known = [n for n, p in params.items() if p.kind is inspect.Parameter.KEYWORD_ONLY
                     and n not in ("x0", "active", "seed", "callback", "progress")]
            for name in opts:
                if name not in known:
                    raise ValueError(
                        f"options.{m}.{name}: not an option of method {m!r} "
                        f"(options: {', '.join(known)})"
                    )
        option, values = budgets_d.get(m, (None, [None]))
        option = option or (budget_option(m) if values != [None] else None)
        if option is not None and option in opts:
            raise ValueError(f"options.{m}.{option}: set by the budget axis too")
    if isinstance(validation_poses, bool) or not isinstance(validation_poses, int) or \
            validation_poses < 1:
        raise ValueError(f"validation_poses: {validation_poses!r}; expected an integer >= 1")
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise ValueError(f"retries: {retries!r}; expected an integer >= 0")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers < 1):
        raise ValueError(f"workers: {workers!r}; expected an integer >= 1")
    if workers is not None and scheduler is not None:
        raise ValueError("workers: only for the local cluster; an existing cluster has its own")
    if robot is None:
        robot = Robot.default()
    elif not isinstance(robot, Robot):
        robot = Robot.from_toml(robot)

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
        "noise_model": "level = tracker position sd (mm); other channels in the proportions of "
                       "iwr.Noise.realistic(), which is level 0.02",
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
            failures = _run_synchronous(todo, _canonical(robot.to_dict()), runtime, on_done)
        else:
            failures = _run_dask(todo, _canonical(robot.to_dict()), runtime, on_done, scheduler,
                                 workers, retries)
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
        raise StudyError(
            f"{len(failures)} of {len(cells)} cells failed on every attempt (first: {cell.method}, "
            f"N={cell.n_poses}, noise={cell.noise}, draw={cell.draw}, seed={cell.seed}: "
            f"{type(exc).__name__}: {exc}); the others are in {table}; run the study again to "
            "retry the missing ones"
        )
    if report:
        from ._report import report as make_report

        result.plots = make_report(out)
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
            raise ValueError(f"budgets: method {m!r} is not one of the study's methods {methods}")
        if m in out:
            raise ValueError(f"budgets: two budget axes for method {m!r}")
        vals: list[int | None] = []
        for v in np.atleast_1d(np.asarray(values, dtype=object)).tolist():
            if isinstance(v, float) and v.is_integer():
                v = int(v)
            if v is None:
                vals.append(None)
            elif isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"budgets: {v!r} for method {m!r}; expected integers >= 1")
            else:
                vals.append(int(v))
        if not vals:
            raise ValueError(f"budgets: empty for method {m!r}")
        if option:
            if not _accepts(m, option) and not any(
                p.kind is inspect.Parameter.VAR_KEYWORD
                for p in inspect.signature(METHODS[m]).parameters.values()
            ):
                raise ValueError(f"budgets: {option!r} is not an option of method {m!r}")
            if option == budget_option(m):
                option = ""
        elif vals != [None]:
            budget_option(m)
        out[m] = (option or None, list(dict.fromkeys(vals)))
    return out


# -- command line -------------------------------------------------------------------------------


def _csv_items(text: str, kind: Callable[[str], Any], what: str) -> list[Any]:
    items = [t.strip() for t in text.split(",") if t.strip()]
    if not items:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a comma-separated list of {what}")
    try:
        return [kind(t) for t in items]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected a comma-separated list of {what}"
        ) from None


def _ints(text: str) -> list[int]:
    return _csv_items(text, int, "integers")


def _floats(text: str) -> list[float]:
    return _csv_items(text, float, "numbers")


def _count_or_list(text: str) -> Any:
    """'5' -> 5 (a count: 0..4); '0,3,7' -> [0, 3, 7] (the indices)."""
    values = _ints(text)
    return values[0] if len(values) == 1 and "," not in text else values


def _option_value(text: str) -> Any:
    try:
        return json.loads(text)
    except ValueError:
        return text


def _parse_options(items: list[str]) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for item in items:
        name, sep, value = item.partition("=")
        method, dot, option = name.partition(".")
        if not sep or not dot or not method or not option:
            raise ValueError(
                f"--option: {item!r}; expected METHOD.NAME=VALUE, e.g. de.strategy=jde"
            )
        out.setdefault(method, {})[option] = _option_value(value)
    return out


def _parse_budgets(items: list[str]) -> Any:
    """['100,1000'] -> [100, 1000] for every method; ['de=100,1000'] -> {'de': [100, 1000]};
    ['de.max_evaluations=1e5,1e6'] -> {'de.max_evaluations': [100000, 1000000]}."""
    if not items:
        return None
    per_method: dict[str, list[int]] = {}
    common: list[int] | None = None
    for item in items:
        method, sep, values = item.rpartition("=")
        try:
            parsed = [int(v) for v in _floats(values)]
            if any(v != f for v, f in zip(parsed, _floats(values), strict=True)):
                raise argparse.ArgumentTypeError(f"{values!r}: expected whole numbers")
        except (argparse.ArgumentTypeError, OverflowError, ValueError) as exc:
            raise ValueError(f"--budget: {exc}") from None
        if sep:
            per_method[method] = parsed
        else:
            common = parsed
    if common is not None and per_method:
        raise ValueError("--budget: give either one list for every method or METHOD=LIST items")
    return common if common is not None else per_method


def add_study_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``study`` command to an argparse subparsers object (the ``iwr`` CLI's hook).

    The parser's default ``func`` is :func:`run_study`.
    """
    parser = subparsers.add_parser(
        "study",
        help="Monte-Carlo study of identification over methods, poses, noise, draws and seeds",
        description=(
            "Run a grid of simulated calibrations (methods x poses x noise x error draws x seeds, "
            "and budgets) on Dask, validate each on fresh poses, and write a tidy table "
            "(OUT/results.csv), one JSON file per cell (OUT/runs/), figures and OUT/summary.md. "
            "Started again, it runs only the cells that have no result yet."
        ),
    )
    _add_arguments(parser)
    parser.set_defaults(func=run_study)
    return parser


def _add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--methods", default="lm",
                        help=f"comma-separated methods, of: {', '.join(sorted(METHODS))} "
                             "(default: lm)")
    parser.add_argument("--poses", type=_ints, default=[20, 50, 100],
                        help="comma-separated numbers of measurement poses (default: 20,50,100)")
    parser.add_argument("--noise", type=_floats, default=[0.0, 0.02],
                        help="comma-separated noise levels: tracker position sd in mm, the other "
                             "channels in proportion (0.02 = iwr.Noise.realistic()) (default: "
                             "0,0.02)")
    parser.add_argument("--draws", type=_count_or_list, default=3,
                        help="error draws (actual robots): a count, or comma-separated indices "
                             "(default: 3)")
    parser.add_argument("--seeds", type=_count_or_list, default=3,
                        help="seeds of poses, noise and method: a count, or comma-separated "
                             "indices (default: 3)")
    parser.add_argument("--budget", action="append", default=[],
                        metavar="[METHOD[.OPTION]=]LIST",
                        help="budget axis: generations (de) or evaluations (lm, crs2, bobyqa), "
                             "e.g. --budget de=100,300,1000; repeat for several methods; "
                             "de.max_evaluations=1e5,1e6 sets that option instead (jso, lshade)")
    parser.add_argument("--option", action="append", default=[], metavar="METHOD.NAME=VALUE",
                        help="a method option, e.g. --option de.strategy=lshade (repeatable)")
    parser.add_argument("--robot", default=None, help="robot TOML file (default: the built-in IWR)")
    parser.add_argument("--validation-poses", type=int, default=50,
                        help="fresh poses on which each calibration is validated (default: 50)")
    parser.add_argument("--base-seed", type=int, default=0,
                        help="root of every random stream (default: 0)")
    parser.add_argument("--out", default="study", help="study folder (default: study)")
    parser.add_argument("--scheduler", default=None,
                        help="address of an existing Dask scheduler (tcp://host:8786), or "
                             "'synchronous' for this process without Dask (default: a local "
                             "cluster)")
    parser.add_argument("--workers", type=int, default=None,
                        help="worker processes of the local cluster (default: one per core)")
    parser.add_argument("--retries", type=int, default=2,
                        help="extra attempts of a cell whose worker died (default: 2)")
    parser.add_argument("--report-only", action="store_true",
                        help="only redraw the figures and summary from OUT/results.csv")
    parser.add_argument("--no-report", action="store_true", help="no figures and no summary")
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                        help="progress bar (default: when standard error is a terminal)")


def run_study(args: argparse.Namespace) -> int:
    """Run the ``study`` command from parsed arguments; returns the exit code.

    Raises ValueError, OSError or :class:`StudyError` with a one-line message on bad input or a
    failed study (the caller prints it).
    """
    out = Path(args.out)
    if args.report_only:
        from ._report import report as make_report

        files = make_report(out)
        print(f"wrote {', '.join(str(f) for f in files)}")
        return 0
    result = study(
        methods=args.methods, poses=args.poses, noise=args.noise, draws=args.draws,
        seeds=args.seeds, budgets=_parse_budgets(args.budget), out=out, robot=args.robot,
        options=_parse_options(args.option), validation_poses=args.validation_poses,
        base_seed=args.base_seed, scheduler=args.scheduler, workers=args.workers,
        retries=args.retries, report=not args.no_report, progress=args.progress,
    )
    print(
        f"{len(result.rows)} cells ({result.executed} computed, {result.reused} reused, "
        f"{result.failed} failed) -> {result.table}"
    )
    for path in result.plots:
        print(f"wrote {path}")
    return 0


def report(out: str | os.PathLike[str]) -> list[Path]:
    """Write the figures and ``summary.md`` of the study in folder ``out``; their paths."""
    from ._report import report as make_report

    return make_report(out)


class _OneLineParser(argparse.ArgumentParser):
    def error(self, message: str) -> Any:  # argparse's usage + message, as one line
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m iwr.study``: the study command on its own."""
    parser = _OneLineParser(
        prog="iwr study",
        description=(
            "Monte-Carlo study of identification (methods x poses x noise x error draws x seeds) "
            "on Dask; writes OUT/results.csv, OUT/runs/, figures and OUT/summary.md."
        ),
    )
    _add_arguments(parser)
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    args = parser.parse_args(argv)
    try:
        return run_study(args)
    except KeyboardInterrupt:
        print("iwr study: interrupted; finished cells are kept in the study folder",
              file=sys.stderr)
        return 130
    except (ValueError, OSError, StudyError, ImportError) as exc:
        if args.debug:
            raise
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"iwr study: error: {msg}", file=sys.stderr)
        return 1

