"""What every command of the ``iwr`` command line shares: exit codes, errors, the parser class,
argument types and file loading."""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

__all__ = ["UsageError", "CommandError", "option_error", "Parser", "EXIT_OK", "EXIT_ERROR",
           "EXIT_USAGE", "EXIT_INTERRUPTED", "one_line"]

EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130

#: Environment variable that sets the default identification method of ``iwr calibrate``.
METHOD_ENV = "IWR_METHOD"
#: Environment variable: when set to 1, ``iwr calibrate`` without arguments runs a smaller example.
QUICK_ENV = "IWR_EXAMPLE_QUICK"


class UsageError(Exception):
    """Bad command-line usage: exit code 2. The message ends with where to find help."""

    def __init__(self, message: str, prog: str = "iwr calibrate") -> None:
        super().__init__(f"{message} (see '{prog} --help')")


def option_error(exc: Any, options: dict[str, str], prog: str) -> UsageError:
    """A library's :class:`iwr.experiments.ArgumentError` as the command line's usage error
    (exit 2), its message naming the option (``options``: argument name -> option) instead of
    the argument."""
    text = str(exc)
    name = exc.name
    option = name if name.startswith("-") else options.get(name, "--" + name.replace("_", "-"))
    rest = text[len(name):]
    # An entry of the argument ("options.lm.max_evaluations: ..."), as the option takes it on
    # the command line: "--option lm.max_evaluations: ...".
    return UsageError(option + (" " + rest[1:] if rest.startswith(".") else rest), prog)


class CommandError(Exception):
    """A command that cannot run (missing feature, inconsistent input): exit code 1."""


class Parser(argparse.ArgumentParser):
    """argparse, with one-line errors raised to :func:`main` instead of a usage dump."""

    def error(self, message: str) -> Any:  # type: ignore[override]
        raise UsageError(message, self.prog)


class LazyHelp(str):
    """A help text made when argparse shows it (argparse formats every help text as ``help %
    params``), not when the parser is built: for the texts that list a registry whose import is
    slow (the methods import SciPy's optimize), which ``iwr --help`` and the commands that do not
    use it should not pay for."""

    _make: Callable[[], str]

    def __new__(cls, make: Callable[[], str]) -> LazyHelp:
        self = super().__new__(cls, "(made when shown)")  # not empty: argparse skips empty help
        self._make = make
        return self

    def __mod__(self, params: Any) -> str:
        return self._make() % params


def default_method() -> str:
    """The default method of ``iwr calibrate``: ``$IWR_METHOD`` when set, otherwise
    :data:`iwr.methods.DEFAULT_METHOD`, the default of :func:`iwr.identify` too."""
    from ..methods import DEFAULT_METHOD

    env = os.environ.get(METHOD_ENV, "").strip()
    return env or DEFAULT_METHOD


# -- argument types ------------------------------------------------------------------------------


def _integer(text: str, minimum: int, what: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if v < minimum:
        raise argparse.ArgumentTypeError(f"{v} must be {what}")
    return v


def positive_int(text: str) -> int:
    return _integer(text, 1, "a positive integer")


def nonneg_int(text: str) -> int:
    return _integer(text, 0, ">= 0")


def fraction(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0.0 <= v < 1.0:
        raise argparse.ArgumentTypeError(f"{v} must be in [0, 1)")
    return v


def noise_spec(text: str) -> Any:
    """``realistic``, ``none``, or ``key=sigma,...`` over the fields of :class:`iwr.Noise`."""
    from ..noise import Noise

    spec = text.strip().lower()
    if spec == "realistic":
        return Noise.realistic()
    if spec in ("none", "0", "zero"):
        return Noise()
    fields = [f.name for f in dataclasses.fields(Noise)]
    values: dict[str, float] = {}
    for item in spec.split(","):
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or key not in fields:
            raise argparse.ArgumentTypeError(
                f"{text!r}: expected 'realistic', 'none' or KEY=SIGMA,... with KEY among "
                f"{', '.join(fields)}"
            )
        try:
            values[key] = float(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{key}={value!r} is not a number") from None
    try:
        return Noise(**values)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_common(p: argparse.ArgumentParser) -> None:
    # SUPPRESS: a subcommand must not reset a --debug given before it.
    p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                   help="show the Python traceback of an error")


def progress_enabled(args: argparse.Namespace) -> bool:
    return not getattr(args, "no_progress", False) and sys.stderr.isatty()


def load_robot(path: str) -> Any:
    from ..robot import Robot

    return Robot.from_toml(path)


def load_data(path: str, robot: Any) -> Any:
    """Leg data (platform poses in {0}, docs/data.md) of ``robot``; laser-tracker data, or a
    robot with a ``[tracker]`` table, are refused by name (only ``iwr calibrate`` and
    ``iwr-calibrate`` read them), not with the leg reader's missing-column message."""
    from ..measurements import Measurements
    from ..tracker.files import is_tracker_file

    tracker = getattr(robot, "tracker", None) is not None
    try:
        tracker = tracker or is_tracker_file(path)
    except OSError:
        pass  # the reader below names the file
    if tracker:
        raise CommandError(
            f"{path}: laser-tracker data, or a robot description with a [tracker] table: this "
            "command reads data with the platform pose in {0} only (docs/data.md); tracker data "
            "are calibrated by iwr calibrate and iwr-calibrate (docs/tracker.md)")
    return Measurements.from_csv(path, robot=robot)



def read_data(path: str, robot: Any, readings: str | None = None, *, targets: Any = None,
              prog: str = "iwr calibrate", effects: bool = True) -> Any:
    """The data of the kind ``robot`` measures (:func:`iwr.kinds.for_robot`: poses in {0}, or
    the tracker data of its ``[tracker]`` table), read with every check of that kind's reader;
    ``readings`` (``--readings``) for tracker data given as a long table of points, ``targets``
    (``--target-*``) for a tracker software's target list. With ``effects``, data without the
    columns the robot's effects need (a thermal effect's temperatures) are refused naming
    ``path``, before any work (:func:`check_effect_inputs`)."""
    from ..kinds import for_robot

    try:
        data = for_robot(robot).read(path, robot, readings=readings, targets=targets)
    except TypeError as exc:  # an option this kind's files do not take
        msg = one_line(exc)
        raise UsageError(msg if "docs/tracker.md" in msg else f"{msg} (docs/tracker.md)",
                         prog) from None
    if effects:
        check_effect_inputs(robot, data, path)
    return data


def check_effect_inputs(robot: Any, data: Any, path: str | os.PathLike[str]) -> None:
    """CommandError naming ``path`` unless ``data`` hold what ``robot``'s effects need
    (:func:`iwr.effects.model.check_inputs`: the legs' expansion needs temperatures, the
    slides' the machine's ``T_C``); said before the work starts, not as "measurements: ..."
    once an identification has run (a validation file's only after the identification)."""
    if not getattr(robot, "effects", None):
        return
    from ..effects.model import check_inputs

    try:
        check_inputs(robot, data, where=str(path))
    except ValueError as exc:
        raise CommandError(one_line(exc)) from None


def _same_file(a: str | os.PathLike[str], b: str | os.PathLike[str]) -> bool:
    """Whether two paths name one existing file, by any spelling or link."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def overwritten_input(outputs: Iterable[str | os.PathLike[str]],
                      inputs: Iterable[str | os.PathLike[str] | None]) -> tuple[Path, str] | None:
    """The first output that is one of the inputs (by any spelling or link), and that input."""
    ins = [str(i) for i in inputs if i]
    for out in outputs:
        for inp in ins:
            if _same_file(out, inp):
                return Path(out), inp
    return None


def written_by(path: str | os.PathLike[str], own: str) -> bool:
    """Whether the regular file ``path`` starts with ``own``, the first characters of every file
    a command writes (``"# iwr plan:"``, a checkpoint's magic): how a file it wrote, which it
    may write over, is told from one it did not (a measurement file named by mistake). False
    for a file that cannot be read or is not a regular file (a named pipe is not waited on)."""
    from .._io import open_regular

    try:
        with open_regular(path) as f:
            head = f.read(len(own.encode()))
    except OSError:
        return False
    return head == own.encode()


def check_output(path: str | os.PathLike[str], option: str, *, inputs: Iterable[Any] = (),
                 files: Iterable[str] | None = None, prog: str = "iwr calibrate",
                 own: str | None = None, own_what: str | None = None) -> None:
    """Refuse, before any work, an output that cannot be written or would overwrite an input:
    ``path`` is a file, or with ``files`` (the names written in it) a folder. ``own``: the
    first characters of the files this command writes (``"# iwr plan:"``); an existing file
    that does not start so is not overwritten (a measurement file named by mistake).
    ``own_what``: what such a file is, for the message (default: its first characters)."""
    path = Path(path)
    if files is None:
        clash = overwritten_input([path], inputs)
        if path.is_dir():
            raise UsageError(f"{option} {path}: is a folder; expected a file name", prog)
        if own is not None and clash is None and path.exists():
            if not path.is_file():  # a named pipe would block the read below
                raise UsageError(f"{option} {path}: exists and is not a regular file", prog)
            if not written_by(path, own):
                why = f"not {own_what}" if own_what else f"it does not start with {own!r}"
                raise UsageError(f"{option} {path}: exists and is not a file {prog} wrote "
                                 f"({why}); remove it first, or give another {option}", prog)
    else:
        clash = overwritten_input([path / name for name in files], inputs)
        if path.exists() and not path.is_dir():
            raise UsageError(f"{option} {path}: exists and is not a folder", prog)
    if clash is not None:
        raise UsageError(f"{option} {path}: would overwrite {clash[1]}, an input of this run "
                         f"({clash[0]}); give another {option}", prog)
    # The nearest folder that exists must be writable: the files or folders are made there.
    folder = path if files is not None else path.parent
    folder = Path(os.path.abspath(folder))
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir() or not os.access(folder, os.W_OK | os.X_OK):
        raise UsageError(f"{option} {path}: cannot write there: {folder} is not a writable "
                         "folder", prog)


def not_held_out(validation: Any, data: Any, prog: str, instead: str,
                 shared: int | None = None) -> UsageError:
    """The usage error (exit 2) of a ``--validation`` file that is DATA itself (by any spelling
    or link), or, given ``shared`` (:class:`iwr.calibration.NotHeldOutError`), whose every pose
    is in DATA: accuracy on those poses would be called held out. ``instead``: what to do
    instead, for the message."""
    why = (f"every one of its {shared} poses is also in {data}" if shared is not None
           else f"is the data file {data} itself")
    return UsageError(f"--validation {validation}: {why}; held-out poses must be poses not used "
                      f"for identification ({instead})", prog)


def check_validation_file(validation: Any, data: Any, prog: str, instead: str) -> None:
    """``--validation`` naming DATA itself, refused before anything is read (:func:`not_held_out`;
    a file of DATA's poses under another name: :func:`iwr.calibrate` finds it)."""
    if validation is None:
        return
    try:
        same = os.path.samefile(validation, data)
    except OSError:
        return  # not there: the read names it
    if same:
        raise not_held_out(validation, data, prog, instead)


def one_line(exc: BaseException) -> str:
    msg = str(exc) if str(exc) else type(exc).__name__
    if isinstance(exc, KeyError):  # str(KeyError) is the quoted key
        msg = f"missing key {msg}"
    return " ".join(line.strip() for line in msg.splitlines() if line.strip())




def check_validation_split(data: Any, fraction: float, seed: int) -> None:
    """``--validation-fraction``, checked before the job: the split of :func:`iwr.kinds.split`
    (one rule for every kind) of the poses that count (:func:`iwr.kinds.without_weightless`:
    the job splits them, so every part has a weight > 0) exists; a command error naming the
    option otherwise."""
    from ..kinds import split_rows, without_weightless

    counted, _ = without_weightless(data)
    try:
        split_rows(len(counted), fraction, seed)
    except ValueError as exc:
        left = len(data) - len(counted)
        raise CommandError(f"--validation-{one_line(exc)}" + (
            f" (the poses with a weight > 0; {left} more have weight 0 for every reading and "
            "count in no set)" if left else "")) from None
