"""``iwr compare``: the identification methods on simulated problems, one budget, a report
(:func:`iwr.compare_methods`)."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from typing import Any

from ..experiments.compare import (
    DEFAULT_BUDGET,
    DEFAULT_OUT,
    DEFAULT_SEEDS,
    compare_methods,
    default_methods,
)
from ..experiments.harness import ArgumentError, check_n_poses, check_robot
from ..robot import Robot
from ._base import (
    CELL_BYTES,
    WORKER_PROCESS_BYTES,
    Footprint,
    LazyHelp,
    UsageError,
    check_memory,
    check_output,
    integer,
    noise_spec,
    option_error,
)
from .robot_noise import OPTION_HELP, describe, simulation_noise

__all__ = ["add_compare_parser", "run_compare"]


def _methods() -> Any:
    from ..methods import METHODS

    return METHODS


# compare_methods' arguments -> the options that give them
_OPTIONS = {"n_poses": "--poses", "n_validation": "--validation-poses", "out": "--out"}


def _parse_ints(text: str, name: str) -> Sequence[int]:
    """'0,1,2' -> [0, 1, 2]; '0..4' -> range(0, 5), not made into a list here: a range
    '0..1000000000000' is counted (len) and refused for its memory before a list is built."""
    try:
        if ".." in text:
            a, b = text.split("..")
            return range(int(a), int(b) + 1)
        return [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise UsageError(f"{name}: {text!r}; expected integers like '0,1,2' or '0..4'",
                         "iwr compare") from None


def _check_sizes(args: argparse.Namespace, robot: Robot) -> None:
    """Refuse, before any work, sizes whose memory would not fit
    (:func:`iwr.cli._base.check_memory`): every run's row and parameter vectors, kept for the
    report (``--seeds`` x methods x starts), then one run (``--poses``, its
    ``--validation-poses``) on each process that runs one at a time (this one, or each worker of
    ``--scheduler local``; an existing cluster's machines are not this one's). The budget is a
    cap, not an allocation: not checked."""
    prog = "iwr compare"
    footprint = Footprint.of(robot)
    n_methods = (len(default_methods()) if args.methods is None else
                 len({m.strip() for m in args.methods.split(",") if m.strip()}))
    runs = len(_parse_ints(args.seeds, "--seeds")) * n_methods * (2 if args.start == "both" else 1)
    row = CELL_BYTES + 4 * 32 * footprint.params  # x, truth, x0, unidentifiable: Python lists
    check_memory("--seeds", args.seeds, runs * row,
                 f"the {runs} runs' rows (seeds x methods x starts)", prog)
    if args.scheduler not in ("synchronous", "local"):
        return
    run = footprint.check_run(args.poses, args.validation_poses,
                              "one run (its poses' Jacobians and validation poses)", prog)
    if args.scheduler == "local":
        # One run a process fits (above): too many processes for the memory is the scheduler's
        # doing, not a size's.
        workers = os.cpu_count() or 1
        check_memory("--scheduler", "local", workers * (run + WORKER_PROCESS_BYTES),
                     f"a run on each of its {workers} worker processes (one per core)", prog,
                     advice="run them one after the other (--scheduler synchronous) or on a "
                     "cluster's address")


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
    p.add_argument("--poses", type=integer, default=100, metavar="N",
                   help="measurement poses per identification (default: %(default)s)")
    p.add_argument("--noise", type=noise_spec, default=None, metavar="SPEC",
                   help="measurement noise of the simulated problems: " + OPTION_HELP
                        + ". Default: the --robot file's [noise] (and [tracker.noise]) table, "
                        "else 'realistic'")
    p.add_argument("--seeds", default=",".join(map(str, DEFAULT_SEEDS)),
                   help="seeds, '0,1,2' or '0..4' (default: %(default)s)")
    p.add_argument("--methods", default=None, help=LazyHelp(lambda: (
        "comma-separated methods: registered names (" + ", ".join(sorted(_methods()))
        + "; de is the paper's DE/rand/1/bin) or de:STRATEGY (e.g. de:jso, de:lshade); default: "
        + ",".join(default_methods()) + " (without efficient for --noise none)")))
    p.add_argument("--budget", type=integer, default=DEFAULT_BUDGET, metavar="EVALS",
                   help="evaluation budget per run (default: %(default)s)")
    p.add_argument("--start", choices=["near", "bad", "both"], default="both",
                   help="scenario(s) (default: %(default)s)")
    p.add_argument("--validation-poses", type=integer, default=200, metavar="N",
                   help="fresh poses for the validation RMS (default: %(default)s)")
    p.add_argument("--scheduler", default="synchronous",
                   help="where the runs execute: 'synchronous' (default: this process), 'local' "
                        "(a local Dask cluster) or a Dask scheduler's address, tcp://HOST:8786; "
                        "the rows are the same")
    p.add_argument("-o", "--out", default=DEFAULT_OUT, metavar="DIR",
                   help="output folder (default: %(default)s)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def run_compare(args: argparse.Namespace) -> int:
    """Run ``iwr compare`` with parsed arguments; print the summary table; return the exit code
    (0 ok, 1 an input file or run error, 130 interrupted; a bad option's value raises
    :class:`UsageError`, exit 2)."""
    try:
        if args.out:  # the output folder, made if needed: one that cannot be is refused, exit 2
            check_output(args.out, "--out", files=(), prog="iwr compare")
        robot = Robot.from_toml(args.robot) if args.robot else Robot.default()
        check_robot(robot)
        _check_sizes(args, robot)
        check_n_poses(robot, args.poses, "--poses")  # named as the command line spells it
        methods = None if args.methods is None else [
            m.strip() for m in args.methods.split(",") if m.strip()]
        # As iwr simulate: --noise (read as robot_noise.option_noise reads it for every
        # command), else the robot file's model, else realistic; in the form the kind takes.
        noise, source = simulation_noise(args.noise, robot, args.robot)
        given = "--noise" if args.noise is not None else "the default, realistic"
        print(f"noise model: {describe(noise)} (from {source or given})")
        comp = compare_methods(
            robot=robot,
            n_poses=args.poses,
            noise=noise,
            seeds=list(_parse_ints(args.seeds, "--seeds")),
            methods=methods,
            budget=args.budget,
            start=args.start,
            out=args.out,
            n_validation=args.validation_poses,
            scheduler=None if args.scheduler == "local" else args.scheduler,
            progress=False if args.no_progress else None,
        )
    except KeyboardInterrupt:
        print("iwr compare: interrupted", file=sys.stderr)
        return 130
    except ArgumentError as exc:  # an option's value, before anything ran: exit 2
        raise option_error(exc, _OPTIONS, "iwr compare") from None
    except (ValueError, TypeError, OSError, RuntimeError) as exc:
        print(f"iwr compare: error: {exc}", file=sys.stderr)
        return 1
    print(comp.summary_markdown())
    print(f"wrote {args.out}/: " + ", ".join(sorted(comp.files)))
    return 0
