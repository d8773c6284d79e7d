"""What every command of the ``iwr`` command line shares: exit codes, errors, the parser class,
argument types and file loading."""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

__all__ = ["UsageError", "CommandError", "option_error", "Parser", "EXIT_OK", "EXIT_ERROR",
           "EXIT_USAGE", "EXIT_INTERRUPTED", "one_line", "available_memory", "check_memory",
           "Footprint"]

EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130

#: Environment variable that sets the default identification method of ``iwr calibrate``.
METHOD_ENV = "IWR_METHOD"
#: Environment variable: when set to 1, ``iwr calibrate`` without arguments runs a smaller example.
QUICK_ENV = "IWR_EXAMPLE_QUICK"


class UsageError(Exception):
    """Bad command-line usage: exit code 2. The message ends with where to find help: ``prog``'s,
    by default the command that ran (``iwr`` sets it; it said "iwr calibrate" of any)."""

    def __init__(self, message: str, prog: str | None = None) -> None:
        super().__init__(message)
        self.message, self.prog = message, prog

    def __str__(self) -> str:
        return f"{self.message} (see '{self.prog or 'iwr'} --help')"


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


_INT64_MAX = 2**63 - 1


def whole_number(text: str) -> int:
    """An integer as users write one on a command line, ``10000`` or ``1e4`` (``1.5e3``: any
    decimal of integral value, read exactly), for every count, budget and seed of every command
    (one reader: ``iwr compare --budget 1e4`` was refused where ``iwr study`` took ``1e5``).
    ValueError naming the text otherwise."""
    import decimal

    try:
        return int(text)
    except ValueError:
        pass
    try:
        d = decimal.Decimal(text.strip())
    except decimal.InvalidOperation:
        raise ValueError(f"{text!r} is not an integer") from None
    if not d.is_finite() or d != d.to_integral_value():
        raise ValueError(f"{text!r} is not a whole number")
    return int(d)


def integer(text: str) -> int:
    """:func:`whole_number` as an argparse type (its range checked where it is used)."""
    try:
        return whole_number(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _integer(text: str, minimum: int, what: str, maximum: int = _INT64_MAX) -> int:
    v = integer(text)
    # The text as given, not v: 1e9999's 10000 digits are past Python's int-to-str limit.
    shown = str(v) if abs(v) < 10**18 else text.strip()
    if v < minimum:
        raise argparse.ArgumentTypeError(f"{shown} must be {what}")
    if v > maximum:  # what the C++ core counts in: refused here, not after the work starts
        raise argparse.ArgumentTypeError(f"{shown} is beyond {maximum}")
    return v


def positive_int(text: str) -> int:
    return _integer(text, 1, "a positive integer")


def nonneg_int(text: str) -> int:
    """A seed: [0, 2**64), the range of the engine's and NumPy's seeds."""
    return _integer(text, 0, ">= 0", 2**64 - 1)


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
              prog: str | None = None, effects: bool = True) -> Any:
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


def check_frame(kind: Any, robot: Any, data: Any, path: str | os.PathLike[str]) -> None:
    """Refuse data that a frame or column mistake puts far from the robot
    (:meth:`iwr.kinds.MeasurementKind.frame_check`: ``refused``), before anything is identified
    or reported; warn when they are far and nothing explains it. ``iwr calibrate``, ``iwr
    report`` and ``iwr-calibrate`` alike: a result identified elsewhere on such data (the
    engine's DE stays in its box, so no fit test without a noise model can fail it) was
    reported as a calibration, ``status = "success"``, legs 1.5 m off."""
    check = kind.frame_check(robot, data)
    if check is None:
        return
    if check.refused:
        raise CommandError(f"{path}: {check.message}")
    if not check.ok:
        print(f"warning: {path}: {check.message}", flush=True)


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


def written_by(path: str | os.PathLike[str], own: str, words: str = "") -> bool:
    """Whether the regular file ``path`` starts with ``own``, the first characters of every file
    a command writes (``"# iwr plan:"``, a checkpoint's magic), and holds ``words`` within its
    first 4 kB (a format whose first characters are anyone's, as a URDF's): how a file it wrote,
    which it may write over, is told from one it did not (a measurement file named by mistake).
    False for a file that cannot be read or is not a regular file (a named pipe is not waited
    on)."""
    from .._io import open_regular

    start, mark = own.encode(), words.encode()
    try:
        with open_regular(path) as f:
            head = f.read(max(len(start), 4096 if mark else 0))
    except OSError:
        return False
    return head.startswith(start) and mark in head


def check_output(path: str | os.PathLike[str], option: str, *, inputs: Iterable[Any] = (),
                 files: Iterable[str] | None = None, prog: str | None = None,
                 own: str | None = None, own_what: str | None = None,
                 in_existing_folder: bool = False) -> None:
    """Refuse, before any work, an output that cannot be written or would overwrite an input:
    ``path`` is a file, or with ``files`` (the names written in it) a folder. ``own``: the
    first characters of the files this command writes (``"# iwr plan:"``); an existing file
    that does not start so is not overwritten (a measurement file named by mistake).
    ``own_what``: what such a file is, for the message (default: its first characters).
    ``in_existing_folder``: the file is written into its folder as it is (not one the command
    makes): a missing folder is refused too."""
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
    if in_existing_folder and not os.path.isdir(os.path.abspath(path.parent)):
        # A file is written into its folder, which is not made (a folder of files is).
        raise UsageError(f"{option} {path}: folder {path.parent} does not exist; make it first, "
                         f"or give another {option}", prog)
    # The nearest folder that exists must be writable: the files or folders are made there.
    folder = path if files is not None else path.parent
    folder = Path(os.path.abspath(folder))
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if folder.exists() and not folder.is_dir():  # a path under a file
        raise UsageError(f"{option} {path}: cannot write there: {folder} is a file, not a "
                         "folder", prog)
    if not folder.is_dir() or not os.access(folder, os.W_OK | os.X_OK):
        raise UsageError(f"{option} {path}: cannot write there: {folder} is not a writable "
                         "folder", prog)
    # Permissions do not say everything (a pseudo file system as /proc, a full disk, quotas,
    # root's access on a folder that takes no files): a file made and removed there does.
    try:
        fd, probe = tempfile.mkstemp(prefix=".iwr-probe-", dir=folder)
    except OSError as exc:
        raise UsageError(f"{option} {path}: cannot write there: {folder}: "
                         f"{exc.strerror or exc}", prog) from None
    os.close(fd)
    os.unlink(probe)


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


# -- sizes: a value whose memory would not fit, refused before any work ---------------------------
#
# Every size option of every command (poses, candidates, validation poses, grid, a study's lists,
# workers) is checked before the work against the memory it makes the command allocate
# (check_memory): a value the machine cannot hold is refused with exit 2 and a message naming it,
# instead of a process killed for memory (exit 137) or failing with MemoryError after minutes. The
# estimates are per unit of the option, from what the commands allocate (Footprint's comments say
# what dominates; the constants are measured peaks of the default IWR, rounded up), so that they
# err on the side of a refusal only for values within a factor of about 1.5 of the limit. A budget
# (--budget, --generations) is a cap, not an allocation: a method logs an entry an evaluation at
# most, and stops long before most budgets (LM on 100 poses: 83 evaluations of 20000), so it is
# not checked (an estimate from it refused `--method lm --budget 100000000`, which runs).

#: Bytes of one cell of ``iwr study`` / one run of ``iwr compare`` kept for the table and the
#: report (its settings, figures and JSON record), besides its parameter vectors.
CELL_BYTES = 16 * 1024
#: Resident memory of one worker process of a local Dask cluster (Python, NumPy, SciPy, iwr and
#: distributed imported), before its cell's arrays.
WORKER_PROCESS_BYTES = 256 * 1024**2
_F8 = 8  # bytes of a double


def _meminfo_available() -> int | None:
    """MemAvailable of /proc/meminfo (free memory and the page cache the kernel can drop: what
    can be allocated without swapping), else the free pages of ``os.sysconf``."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        pages, size = os.sysconf("SC_AVPHYS_PAGES"), os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None
    return pages * size if pages > 0 and size > 0 else None


def _read_int(path: Path) -> int | None:
    try:
        text = path.read_text(encoding="ascii").strip()
        return int(text) if text.isdigit() else None
    except (OSError, ValueError):
        return None


def _stat_value(path: Path, key: str) -> int:
    try:
        for line in path.read_text(encoding="ascii").splitlines():
            name, _, value = line.partition(" ")
            if name == key and value.strip().isdigit():
                return int(value)
    except OSError:
        pass
    return 0


def _cgroup_available() -> int | None:
    """What the memory limit of this process's control group (a container's) leaves: limit -
    usage + the page cache it can drop (cgroup v2 and v1; the group's own folder, else the
    mount's root, as a container sees its own group). None without a limit."""
    root = Path("/sys/fs/cgroup")
    try:
        lines = Path("/proc/self/cgroup").read_text(encoding="ascii").splitlines()
    except OSError:
        return None
    best: int | None = None
    for line in lines:
        if line.count(":") < 2:
            continue
        _, controllers, group = line.split(":", 2)
        if controllers == "":  # v2: memory.max, memory.current
            files = ("memory.max", "memory.current", "inactive_file")
            bases = [root / group.lstrip("/"), root]
        elif "memory" in controllers.split(","):  # v1
            files = ("memory.limit_in_bytes", "memory.usage_in_bytes", "total_inactive_file")
            bases = [root / "memory" / group.lstrip("/"), root / "memory"]
        else:
            continue
        for base in bases:
            limit, usage = _read_int(base / files[0]), _read_int(base / files[1])
            if limit is None or usage is None or limit >= 1 << 60:  # no limit ("max", 2^63)
                continue
            left = max(0, limit - usage + _stat_value(base / "memory.stat", files[2]))
            best = left if best is None else min(best, left)
            break
    return best


def _rlimit_available() -> int | None:
    """What ``ulimit -v`` (RLIMIT_AS) leaves of this process's address space, if set."""
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
        if soft == resource.RLIM_INFINITY or soft < 0:
            return None
        with open("/proc/self/status", encoding="ascii") as f:
            used = next((int(line.split()[1]) * 1024 for line in f
                         if line.startswith("VmSize:")), 0)
    except (ImportError, OSError, ValueError):
        return None
    return max(0, soft - used)


def available_memory() -> int | None:
    """Bytes this process can still allocate without being killed or refused: the machine's
    available memory (:func:`_meminfo_available`), and less when the memory limit of its control
    group (a container's) or ``ulimit -v`` leave less. None when it cannot be told (no check)."""
    found = [v for v in (_meminfo_available(), _cgroup_available(), _rlimit_available())
             if v is not None]
    return min(found) if found else None


def format_bytes(n: float) -> str:
    """``n`` bytes in decimal units: "3.8 TB", "512 MB"."""
    for unit in ("bytes", "kB", "MB", "GB", "TB", "PB", "EB", "ZB", "YB"):
        if abs(n) < 1000 or unit == "YB":
            return f"{n:.0f} bytes" if unit == "bytes" else f"{n:.3g} {unit}"
        n /= 1000
    raise AssertionError  # not reached


def check_memory(option: str, value: Any, need: float, what: str, prog: str,
                 advice: str | None = None) -> None:
    """Refuse, before any work, ``option``'s ``value`` when the ``need`` bytes it makes the command
    allocate (``what``: which arrays, for the message) exceed :func:`available_memory`: a usage
    error (exit 2), one line naming the option and the value, and ``advice`` (default: a smaller
    value of it)."""
    available = available_memory()
    if available is None or need <= available:
        return
    raise UsageError(f"{option} {value}: {what} would need about {format_bytes(need)} of "
                     f"memory, more than the {format_bytes(available)} available; "
                     + (advice or f"give a smaller {option}"), prog)


def largest(terms: dict[str, tuple[Any, float]]) -> tuple[str, Any]:
    """The option (and its value) of ``terms`` (option -> (value, bytes)) that needs the most: the
    one a refusal of their sum names."""
    option = max(terms, key=lambda k: terms[k][1])
    return option, terms[option][0]


def max_threads() -> int:
    """The most threads the engine's pool takes (``iwr._core.max_threads``: 4 per CPU this
    process may use, at least 16); more is refused by the engine once the method starts, so
    ``--workers`` is checked against it first."""
    from .. import _core  # the engine's own rule, not a copy of it

    return int(_core.max_threads())


def check_workers(workers: int | None, prog: str) -> None:
    """``--workers`` (threads of a parallel method): a fixed cap, the engine's
    (:func:`max_threads`), whose threads cost little memory but which refuses more."""
    cap = max_threads()
    if workers is not None and workers > cap:
        raise UsageError(f"--workers {workers}: at most {cap} threads (4 per CPU this process "
                         "may use, at least 16); more only slow the run down", prog)


@dataclasses.dataclass(frozen=True)
class Footprint:
    """What a pose of a robot's data costs in memory, for :func:`check_memory`'s estimates:
    ``params``, the parameters of a problem of its data (the robot's, its effects', its
    instrument's set-up's); ``rows``, residuals per pose and set-up (6 for a pose in {0}, 3 per
    tracker point, 1 for a ballbar's distance); ``setups``, the set-ups a pose is measured in
    (a ballbar's); ``effects``, whether the robot has effects on."""

    params: int
    rows: int
    setups: int = 1
    effects: bool = False

    #: A pose's readings, its line of text in a file and the Python objects of its sampling
    #: (``iwr simulate``: 1.9 kB a pose measured in {0} or by a tracker, 3.6 kB by a ballbar).
    POSE = 4096
    #: Jacobian-sized arrays (``rows x params`` doubles a pose) that a calibration holds at once
    #: (Jacobians, their scaled and whitened copies, the SVD's factor; the efficient estimator's
    #: per-pose blocks): ``iwr calibrate``'s example measured 25-32 kB a pose, 16 x 2.8 kB + 4 kB
    #: = 48 kB estimated.
    JOB = 16
    #: The same for the readings of a robot with effects, whose model computes their Jacobian
    #: with them (``iwr simulate`` of the realistic effects: 56 kB a pose).
    EFFECTS = 24
    #: The same for a validation pose (forward kinematics of the nominal and the calibrated robot:
    #: ``iwr compare --validation-poses``, 17 kB a pose measured).
    VALIDATION = 8
    #: Jacobian-sized arrays of ``iwr plan``'s candidates besides their information matrices
    #: (``params x params`` doubles each: 35 kB a candidate measured, 42 kB estimated).
    PLAN = 4

    @classmethod
    def of(cls, robot: Any) -> Footprint:
        from ..effects import parameter_names as effect_parameter_names
        from ..kinds import for_robot

        kind = for_robot(robot)
        params = (int(robot.n_params) + len(effect_parameter_names(robot.effects))
                  + len(kind.setup_parameter_names(robot)))
        tracker = getattr(robot, "tracker", None)
        rows, setups = (3 * int(tracker.n_points) if tracker is not None else 6), 1
        if kind.setups_per_pose:  # a ballbar's: one distance a pose in each set-up
            from ..ballbar.api import ballbar_setup

            rows, setups = 1, int(ballbar_setup(robot).n_setups)
        return cls(params, max(rows, 1), max(setups, 1), bool(robot.effects))

    @property
    def jacobian(self) -> int:
        """Bytes of one pose's rows of a Jacobian."""
        return _F8 * self.rows * self.params

    def _copies(self, n: int) -> int:
        return (n + (self.EFFECTS if self.effects else 0)) * self.jacobian

    def simulate(self, poses: int) -> float:
        """``poses`` simulated and written (``iwr simulate``)."""
        return max(float(poses), 0.0) * self.setups * (self.POSE + self._copies(0))

    def job(self, poses: int) -> float:
        """A calibration on ``poses`` poses (``iwr calibrate``'s example, simulated first)."""
        return max(float(poses), 0.0) * self.setups * (self.POSE + self._copies(self.JOB))

    def validation(self, poses: int) -> float:
        """``poses`` validation poses simulated and solved by forward kinematics."""
        return (max(float(poses), 0.0) * self.setups
                * (self.POSE + self._copies(self.VALIDATION)))

    def experiment(self, poses: int) -> float:
        """One run of ``iwr compare`` / ``iwr study`` on ``poses`` poses, its validation aside:
        :meth:`job` (the harness's SVD of the Jacobian for the parameters it cannot judge is the
        thin one, a Jacobian's size)."""
        return self.job(poses)

    def check_run(self, poses: int, validation_poses: int, what: str, prog: str) -> float:
        """Refuse (:func:`check_memory`, naming the larger of the two) one experiment's run on
        ``poses`` poses and its ``validation_poses`` (``iwr compare``'s run, ``iwr study``'s
        cell) when it does not fit; returns its bytes, for the checks of processes running one
        each."""
        terms = {"--poses": (poses, self.experiment(poses)),
                 "--validation-poses": (validation_poses, self.validation(validation_poses))}
        option, value = largest(terms)
        run = sum(need for _, need in terms.values())
        check_memory(option, value, run, what, prog)
        return run

    def candidates(self, count: int) -> float:
        """``iwr plan``'s ``count`` candidates (pose and payload pairs, each once per set-up):
        their Jacobians and per-candidate information matrices."""
        per = self.POSE + _F8 * self.params * self.params + self._copies(self.PLAN)
        return max(float(count), 0.0) * self.setups * per
