"""The ``iwr`` command line: ``calibrate``, ``simulate``, ``analyze``, ``plan``, ``compare``,
``study``, ``report``, ``legs`` and ``export``, one module per command (each with
``add_parser(subparsers)``; every argument parser of the package is here).

Every command has ``--help``. Exit codes: 0 success, 1 bad data or a failed computation, 2 bad
usage, 3 the model does not fit the data, 4 not converged and 5 not calibrated (``iwr
calibrate``), 130 interrupted. Errors are one line, ``iwr: error: ...``, on standard error;
``--debug`` adds the Python traceback.
"""

from __future__ import annotations

import argparse
import sys
import traceback
from collections.abc import Callable, Sequence

from .. import _startup
from ._base import (
    EXIT_ERROR,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_USAGE,
    CommandError,
    Parser,
    UsageError,
    add_common,
    default_method,
    one_line,
)

__all__ = ["main", "build_parser", "default_method"]


class _Version(argparse.Action):
    """``--version``: argparse's, with the version read when asked (importlib.metadata would cost
    every command some 30 ms)."""

    def __init__(self, option_strings: Sequence[str], dest: str = argparse.SUPPRESS,
                 default: str = argparse.SUPPRESS, help: str = "show the version and exit"
                 ) -> None:
        super().__init__(option_strings, dest, nargs=0, default=default, help=help)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: object, option_string: str | None = None) -> None:
        from .. import _core
        from ..reporting.html import iwr_version

        _command_kernel()
        print(f"iwr {iwr_version()} ({_core._kernel_summary()})")
        parser.exit()


def _command_kernel() -> None:
    """IWR_KERNEL applied; a bad value is a usage error (exit status 2)."""
    try:
        _startup.command_kernel()
    except ValueError as exc:
        raise UsageError(str(exc), "iwr") from None


def build_parser() -> argparse.ArgumentParser:
    """The ``iwr`` argument parser, with every command."""
    from . import analyze, calibrate, compare, export, legs, plan, report, simulate, study

    parser = Parser(
        prog="iwr",
        description="Kinematic calibration of the IWR robot (a 4-DOF carriage carrying a Stewart "
        "hexapod) and similar hybrid robots. Start with 'iwr calibrate', which runs the whole job "
        "on a built-in simulated example.",
        epilog="Units: mm and rad everywhere. File formats: docs/data.md. Exit codes: 0 success, "
        "1 bad data or failed computation, 2 bad usage, 3 the model does not fit the data, "
        "4 not converged and 5 not calibrated (iwr calibrate), 6 a target out of stroke or "
        "workspace (iwr legs), 130 interrupted. Environment: IWR_KERNEL picks the objective's "
        "SIMD variant (baseline, avx2, avx512 or auto; --version lists those this CPU runs).",
    )
    parser.add_argument("--version", action=_Version)
    parser.add_argument("--debug", action="store_true",
                        help="show the Python traceback of an error")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    sub.required = True
    for add in (calibrate.add_parser, simulate.add_parser, analyze.add_parser, plan.add_parser,
                compare.add_compare_parser, study.add_study_parser, report.add_parser,
                legs.add_parser, export.add_parser):
        p = add(sub)
        if "--debug" not in p._option_string_actions:
            add_common(p)
    return parser


def _interrupted() -> int:
    print("\niwr: interrupted", file=sys.stderr)
    return EXIT_INTERRUPTED


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code (``iwr`` script: ``iwr.cli:main``)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    handlers: list[tuple[type[BaseException] | tuple[type[BaseException], ...], int, str]] = [
        (UsageError, EXIT_USAGE, ""),
        ((CommandError, ValueError, RuntimeError, OSError, ArithmeticError), EXIT_ERROR, ""),
    ]
    command = None
    try:
        _startup.release()  # Ctrl-C is KeyboardInterrupt again, handled below
        args = build_parser().parse_args(argv)  # --help whatever IWR_KERNEL holds
        command = f"iwr {args.command}" if getattr(args, "command", None) else None
        _command_kernel()
        func: Callable[[argparse.Namespace], int | None] = args.func
        code = func(args)
        return EXIT_OK if code is None else int(code)
    except KeyboardInterrupt:
        return _interrupted()
    except Exception as exc:  # one line, never a traceback unless --debug
        if _startup.interrupted_by(exc):  # Ctrl-C in a module's initialisation: an ImportError
            return _interrupted()
        if debug:
            traceback.print_exc()
        code, prefix = EXIT_ERROR, "internal error: " + type(exc).__name__ + ": "
        for types, c, p in handlers:
            if isinstance(exc, types):
                code, prefix = c, p
                break
        if isinstance(exc, UsageError) and exc.prog is None:
            exc.prog = command  # the help of the command that ran
        msg = one_line(exc)
        if isinstance(exc, UsageError):
            print(f"iwr: error: {msg}", file=sys.stderr)
        else:
            hint = "" if debug or not prefix else " (run with --debug for the traceback)"
            print(f"iwr: error: {prefix}{msg}{hint}", file=sys.stderr)
        return code

