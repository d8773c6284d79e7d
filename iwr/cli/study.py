"""``iwr study``: Monte-Carlo studies of identification on Dask (:func:`iwr.study`)."""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..experiments.harness import ArgumentError, check_n_poses, check_robot
from ..experiments.monte_carlo import study
from ..robot import Robot
from . import _base
from ._base import (
    CELL_BYTES,
    WORKER_PROCESS_BYTES,
    Footprint,
    LazyHelp,
    UsageError,
    check_memory,
    check_output,
    format_bytes,
    integer,
    largest,
    nonneg_int,
    option_error,
    whole_number,
)

__all__ = ["add_study_parser", "run_study"]


def _methods() -> Any:
    from ..methods import METHODS

    return METHODS


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
    return _csv_items(text, whole_number, "integers")


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
            raise UsageError(
                f"--option: {item!r}; expected METHOD.NAME=VALUE, e.g. de.strategy=jde", "iwr study"
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
            parsed = _csv_items(values, whole_number, "whole numbers")
        except argparse.ArgumentTypeError as exc:
            raise UsageError(f"--budget: {exc}", "iwr study") from None
        if sep:
            per_method[method] = parsed
        else:
            common = parsed
    if common is not None and per_method:
        raise UsageError("--budget: give either one list for every method or METHOD=LIST items",
                         "iwr study")
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
    parser.add_argument("--methods", default="lm", help=LazyHelp(
        lambda: f"comma-separated methods, of: {', '.join(sorted(_methods()))} (default: lm)"))
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
    parser.add_argument("--validation-poses", type=integer, default=50,
                        help="fresh poses on which each calibration is validated (default: 50)")
    parser.add_argument("--base-seed", type=nonneg_int, default=0,
                        help="root of every random stream (default: 0)")
    parser.add_argument("--out", default="study", help="study folder (default: study)")
    parser.add_argument("--scheduler", default=None,
                        help="address of an existing Dask scheduler (tcp://host:8786), or "
                             "'synchronous' for this process without Dask (default: a local "
                             "cluster)")
    parser.add_argument("--workers", type=integer, default=None,
                        help="worker processes of the local cluster (default: one per core)")
    parser.add_argument("--retries", type=integer, default=2,
                        help="extra attempts of a cell whose worker died (default: 2)")
    parser.add_argument("--report-only", action="store_true",
                        help="only redraw the figures and summary from OUT/results.csv")
    parser.add_argument("--no-report", action="store_true", help="no figures and no summary")
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                        help="progress bar (default: when standard error is a terminal)")


# study()'s arguments -> the options that give them
_OPTIONS = {"budgets": "--budget", "options": "--option"}


def run_study(args: argparse.Namespace) -> int:
    """Run the ``study`` command from parsed arguments; returns the exit code.

    A bad option's value: :class:`UsageError` (exit 2, ``iwr: error: --OPTION: ...``). A bad
    input file, a failed study or a scheduler that cannot be reached: a one-line message
    ``iwr study: error: ...`` on standard error and exit code 1 (``--debug``: the traceback).
    """
    try:
        return _run_study(args)
    except KeyboardInterrupt:
        print("iwr study: interrupted; finished cells are kept in the study folder",
              file=sys.stderr)
        return 130
    except ArgumentError as exc:  # an option's value, before anything ran: exit 2
        raise option_error(exc, _OPTIONS, "iwr study") from None
    except (ValueError, OSError, RuntimeError, ImportError) as exc:
        if getattr(args, "debug", False):
            raise
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"iwr study: error: {msg}", file=sys.stderr)
        return 1


def _count(value: Any) -> int:
    """The entries of ``--draws`` / ``--seeds``: a count, or a list of indices (duplicates once)."""
    return max(int(value), 0) if isinstance(value, int) else len(set(value))


def _check_sizes(args: argparse.Namespace, robot: Robot, budgets: Any) -> None:
    """Refuse, before any work, list and size options whose memory would not fit
    (:func:`iwr.cli._base.check_memory`): the cells' rows (their number is the product of the
    lists' lengths; counts of draws and seeds are checked before the library makes their lists),
    then one cell's run (its poses and validation poses; a budget is a cap, not an allocation) on
    each process that runs one at a time: this one with ``--scheduler synchronous``, each of the
    local cluster's workers by default (an existing cluster's machines are not this one's: not
    checked)."""
    prog = "iwr study"
    methods = list(dict.fromkeys(m.strip() for m in args.methods.split(",") if m.strip()))
    if isinstance(budgets, dict):
        per_method = {k.partition(".")[0]: len(set(v)) for k, v in budgets.items()}
    else:
        per_method = {m: len(set(budgets)) for m in methods} if budgets else {}
    counts = {
        "--poses": (",".join(map(str, args.poses)), len(set(args.poses))),
        "--noise": (",".join(map(str, args.noise)), len(set(args.noise))),
        "--draws": (args.draws if isinstance(args.draws, int) else ",".join(map(str, args.draws)),
                    _count(args.draws)),
        "--seeds": (args.seeds if isinstance(args.seeds, int) else ",".join(map(str, args.seeds)),
                    _count(args.seeds)),
        "--budget": (" ".join(args.budget), max(per_method.values(), default=1)),
        "--methods": (args.methods, len(methods)),
    }
    cells = (counts["--poses"][1] * counts["--noise"][1] * counts["--draws"][1]
             * counts["--seeds"][1] * sum(per_method.get(m, 1) for m in methods))
    option, value = largest({k: (v, float(c)) for k, (v, c) in counts.items()})
    check_memory(option, value, cells * CELL_BYTES,
                 f"the {cells} cells' rows (methods x budgets x poses x noise x draws x seeds)",
                 prog)
    if args.scheduler not in (None, "synchronous"):
        return
    footprint = Footprint.of(robot)
    run = footprint.check_run(max(args.poses), args.validation_poses,
                              "one cell's run (its poses' Jacobians and validation poses)", prog)
    if args.scheduler == "synchronous":
        return
    # One cell's run a process fits (above): too many processes for the memory is the worker
    # count's doing, given or not.
    workers = args.workers or os.cpu_count() or 1
    each = run + WORKER_PROCESS_BYTES
    check_memory("--workers", workers if args.workers is not None else
                 f"{workers} (one per core, the default)", workers * each,
                 f"{workers} worker processes of about {format_bytes(each)} each "
                 "(a cell's run each)", prog, advice=f"give fewer --workers (at most "
                 f"{max(1, int((_base.available_memory() or each) // each))})")


def _run_study(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if args.report_only:
        from ..reporting.study import report as make_report

        if out.exists() and not out.is_dir():
            raise UsageError(f"--out {out}: is a file, not a study folder", "iwr study")
        files = make_report(out)
        print(f"wrote {', '.join(str(f) for f in files)}")
        return 0
    # The study folder, made if needed: not an existing file, nor under one, nor where nothing
    # can be written (exit 2 before any work, not "[Errno 20] Not a directory" once it starts).
    check_output(out, "--out", files=(), prog="iwr study")
    robot = Robot.from_toml(args.robot) if args.robot else Robot.default()
    check_robot(robot)
    budgets = _parse_budgets(args.budget)
    _check_sizes(args, robot, budgets)
    for n in args.poses:  # named as the command line spells it
        check_n_poses(robot, n, "--poses")
    result = study(
        methods=args.methods, poses=args.poses, noise=args.noise, draws=args.draws,
        seeds=args.seeds, budgets=budgets, out=out, robot=robot,
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


