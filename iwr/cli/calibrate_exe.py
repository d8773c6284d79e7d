"""``iwr-calibrate``: a long DE run from ``ROBOT.toml DATA.csv`` (or a problem file) in one command.

The launcher of the C++ engine ``iwr-engine``. It reads and checks the robot TOML and the
measurement CSV with the package's readers (the same checks and messages as ``iwr calibrate``;
leg data, laser-tracker points or probe poses for a robot with a ``[tracker]`` table, searched
from the nominal robot and the closed-form registration guess as ``iwr.identify`` does, or a
double ballbar's distances for a robot with a ``[ballbar]`` table),
writes the problem file ``RESULT.iwrp`` next to the result, runs the engine on it (the engine needs
no Python: the problem file and the ``iwr-engine`` program can be copied to a compute node), and
turns the engine's final checkpoint into the JSON result that :func:`iwr.load_result` reads (the one
JSON writer, :meth:`iwr.IdentificationResult.save`).

The engine runs as a child process started as ``iwr-calibrate`` (so its messages name the command
the user typed). SIGINT, SIGTERM, SIGHUP and SIGUSR1 sent to the launcher are passed on to it (a
signal ignored when the launcher starts stays ignored, in both), and the launcher exits with the
engine's exit status (a child killed by signal N: 128 + N, as a shell says). If the launcher itself
is killed, the engine gets SIGTERM (Linux ``PR_SET_PDEATHSIG``) and writes its checkpoint.
"""

from __future__ import annotations

import os
import shlex
import shutil
import signal
import subprocess
import sys
import sysconfig
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .. import _startup

PROG = "iwr-calibrate"
ENGINE = "iwr-engine"
EXIT_OK, EXIT_ERROR, EXIT_USAGE = 0, 1, 2

# The engine's options that take a value (the others are flags): needed to tell the positional
# arguments from option values. The engine itself checks every one of them.
_ENGINE_VALUED = {
    "--strategy", "--population-size", "--F", "--CR", "--bound-rule", "--seed", "--preset",
    "--generations", "--max-evaluations", "--target-cost", "--tol", "--atol",
    "--stagnation-generations", "--stagnation-tol", "--threads", "--log", "--checkpoint",
    "--checkpoint-every", "--resume",
}
_OWN_VALUED = {"--bounds", "--output", "--problem", "--export", "--readings", "--noise"}
_FLAGS = {"--quiet", "-q", "--help", "-h", "--version"}

HELP = """\
usage: iwr-calibrate ROBOT.toml DATA.csv [--readings READINGS.csv] [--bounds B] [--noise SPEC]
                     [--output RESULT] [--problem PATH] [options]
       iwr-calibrate PROBLEM.iwrp [--output RESULT] [options]
       iwr-calibrate --export CHECKPOINT [--problem PROBLEM.iwrp] --output RESULT

Long differential-evolution runs with checkpoints and resume. Reads ROBOT.toml and DATA.csv with
the checks of `iwr calibrate` (or a problem file written by iwr.Problem.save), leg data or, for a
robot with a [tracker] table, laser-tracker points or probe poses in the tracker frame (the
registration and the reflector or probe offsets are identified too, searched about the closed-form
registration guess, as iwr.identify does; docs/tracker.md), or, for a robot with a [ballbar]
table, a double ballbar's distances (the set-ups' balls and length offsets identified too, from
their nominal values; docs/ballbar.md), writes the problem
file (default RESULT.iwrp), runs the engine iwr-engine on it, and writes the JSON result that
iwr.load_result reads. The engine needs no Python: to run on a compute node, copy iwr-engine and
the problem file there, run `iwr-engine PROBLEM.iwrp ...`, bring its checkpoint back and
convert it with --export.

options of iwr-calibrate (the others are the engine's, below):
  --bounds B               search bounds written into the problem file: default (+-0.5 mm for
                           lengths, +-0.5 degree for angles) or paper (+-0.5 for every parameter,
                           Table 2 literally); only with ROBOT.toml DATA.csv. The tracker
                           setup's bounds are its defaults about the registration guess
  --noise SPEC             weigh the residuals by the instruments' noise (generalised least
                           squares with fixed weights, as iwr.Problem(..., noise=...); the cost
                           is then the dimensionless chi-square statistic): realistic,
                           KEY=SIGMA,... over legs, joint_lengths, joint_angles, position,
                           orientation (mm, rad; as iwr calibrate --noise: for tracker data
                           the readings' noise, and position the tracker's noise level,
                           TrackerNoise.leica() x position / 0.02, without it the file's
                           [tracker.noise] or TrackerNoise.leica()), robot
                           (the [noise] and [tracker.noise] tables of ROBOT.toml), or none
                           (default: eq. (10) or the point residuals unweighted). Reflector
                           points, ballbar distances (each by its standard deviation: the
                           bar's 1 um and the leg and joint readings' propagated) and leg
                           data only (a probe's covariance is singular). The weighting goes
                           into the problem file; only with ROBOT.toml DATA.csv
  --readings READINGS.csv  with tracker data given as a long table of points (pose, reflector,
                           x_mm, y_mm, z_mm): the robot's log of joint and leg readings
  --output RESULT          the JSON result (default iwr-result.json; with --resume CKPT, CKPT
                           without its .ckpt). Its checkpoint is RESULT.ckpt unless --checkpoint
                           says otherwise
  --problem PATH           where the problem file goes (default RESULT.iwrp)
  --export CHECKPOINT      write the result that CHECKPOINT holds to --output, and stop

No output (result, problem file, checkpoint, log) may be one of the run's inputs (ROBOT.toml,
DATA.csv, READINGS.csv, PROBLEM.iwrp, the checkpoint resumed, or the files a problem file was made
from), a folder, or an existing file that iwr did not write (an iwr result, problem file,
checkpoint or iwr-engine log may be written over): refused with exit status 2 before any work.

The engine's help follows; its exit statuses are iwr-calibrate's.

"""


class _Usage(Exception):
    pass


#: The first characters of each kind of file iwr-calibrate writes, by the option naming it, and
#: what it is: the JSON result (:meth:`iwr.IdentificationResult.save` writes its format first),
#: the engine's checkpoint and the problem file (their magic), the engine's log (its header). An
#: existing file that does not start so is not written over: a robot or measurement file named
#: by mistake would be lost (a QA run: ``--output iwr_example.csv`` replaced the data, exit 0).
_OWN = {
    "--output": ('{\n "format": "iwr-result"', "an iwr result"),
    "--checkpoint": ("IWRCKPT\x1a", "an iwr-engine checkpoint"),
    "--problem": ("IWRPROB\x1a", "an iwr problem file"),
    "--log": ("generation,nfev,best,mean,spread,elapsed\n", "an iwr-engine log"),
}


def _recorded_sources(problem: str | None) -> list[tuple[str, str]]:
    """The files a problem file records it was made from (ROBOT.toml, DATA.csv), as inputs of a
    run on it, as the engine counts them; none when the file cannot be read (the engine, or the
    export, then says why)."""
    if problem is None:
        return []
    from ..problem_file import read_problem

    try:
        sources = read_problem(problem)["sources"]
    except (ValueError, OSError, RuntimeError):
        return []
    return [(path, f"the {role} file the problem was made from") for role, path, _ in sources
            if path]


def _check_outputs(outputs: list[tuple[str, str]], inputs: list[tuple[str, str]],
                   resume: str | None = None) -> None:
    """Refuse, before any work, an output that is an input (by any spelling or link), a folder,
    or an existing file iwr did not write (:data:`_OWN`). The checkpoint resumed is written
    back by design: the engine refuses it, before writing anything, if it is no checkpoint."""
    from ._base import written_by

    for opt, out in outputs:
        resumed = opt == "--checkpoint" and resume is not None and _same(out, resume)
        for path, what in inputs:
            if resumed and what == "the checkpoint resumed":
                continue
            if _same(out, path):
                raise _Usage(f"{opt}: {out} is {what}; an output may not overwrite an input")
        if os.path.isdir(out):
            raise _Usage(f"{opt}: {out} is a folder; expected a file name")
        if resumed or not os.path.exists(out):
            continue
        if not os.path.isfile(out):  # a named pipe, a device
            raise _Usage(f"{opt}: {out} exists and is not a regular file")
        own, what = _OWN[opt]
        if not written_by(out, own):
            raise _Usage(f"{opt}: {out} exists and is not a file iwr wrote (not {what}); remove "
                         f"it first, or give another {opt}")


def _error(msg: str, code: int) -> int:
    text = " ".join(line.strip() for line in str(msg).splitlines() if line.strip())
    hint = f" (see {PROG} --help)" if code == EXIT_USAGE else ""
    print(f"{PROG}: error: {text}{hint}", file=sys.stderr)
    return code


def engine_path() -> str:
    """The ``iwr-engine`` installed with this package (the scripts folder holding this command)."""
    candidates = []
    if sys.argv and sys.argv[0]:
        candidates.append(Path(sys.argv[0]).resolve().parent / ENGINE)
    candidates.append(Path(sysconfig.get_path("scripts")) / ENGINE)
    candidates.append(Path(sys.executable).parent / ENGINE)
    for c in candidates:
        if c.is_file() and os.access(c, os.X_OK):
            return str(c)
    found = shutil.which(ENGINE)
    if found:
        return found
    raise FileNotFoundError(f"{ENGINE} is not installed: `pip install .` puts it next to python")


def _split(argv: Sequence[str]) -> tuple[list[str], dict[str, str], list[str], set[str]]:
    """Positional arguments, the launcher's own options, the engine's arguments, flags seen."""
    positional: list[str] = []
    own: dict[str, str] = {}
    engine: list[str] = []
    flags: set[str] = set()
    args = list(argv)
    i = 0
    only_positional = False
    while i < len(args):
        a = args[i]
        i += 1
        if only_positional or len(a) < 2 or not a.startswith("-"):
            positional.append(a)
            continue
        if a == "--":
            only_positional = True
            continue
        name, eq, value = a.partition("=") if a.startswith("--") else (a, "", "")
        if name in _OWN_VALUED or name in _ENGINE_VALUED:
            if not eq:
                if i >= len(args):
                    raise _Usage(f"{name}: expected a value")
                value = args[i]
                i += 1
            if name in _OWN_VALUED:
                if name in own:
                    raise _Usage(f"{name}: given twice")
                own[name] = value
            else:
                engine += [name, value]
            continue
        if name not in _FLAGS:
            raise _Usage(f"unknown option '{name}'" + (" (the options are --F and --CR)"
                                                        if name in ("--f", "--cr") else ""))
        flags.add(name)
        engine.append(a)
    return positional, own, engine, flags


def _option(engine: list[str], name: str) -> str | None:
    value = None
    for k in range(0, len(engine) - 1):
        if engine[k] == name:
            value = engine[k + 1]
    return value


def _same(a: str | os.PathLike[str], b: str | os.PathLike[str]) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.abspath(a) == os.path.abspath(b)


def _lock_checkpoint(checkpoint: str, kind: str = "lock", holder: str = ENGINE) -> int:
    """Take the engine's lock of ``checkpoint`` (an exclusive flock on ``.NAME.lock`` beside it,
    as iwr-engine's CheckpointLock), or with ``kind="launch"`` the launcher's
    (``.NAME.launch.lock``, held by an iwr-calibrate for its whole run); returns its descriptor.
    Refuses while another process holds it."""
    import fcntl

    folder, base = os.path.split(checkpoint)
    path = os.path.join(folder, f".{base}.{'launch.lock' if kind == 'launch' else 'lock'}")
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
    except OSError as exc:
        raise ValueError(f"{checkpoint}: cannot create its lock file {path} "
                         f"({exc.strerror or exc})") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        os.close(fd)
        if isinstance(exc, BlockingIOError):
            raise ValueError(f"{checkpoint}: in use by another {holder} process (locked: "
                             f"{path}); wait for it to end or stop it (nothing was written)"
                             ) from None
        raise ValueError(f"{checkpoint}: cannot lock {path} ({exc.strerror or exc})") from None
    return fd


def _export(checkpoint: str, problem: str | None, output: str,
            objective: dict[str, Any] | None = None, resume: str | None = None) -> str:
    """The engine's result written to ``output``; ``objective``: the noise model of a weighted
    run (``--noise``), recorded as :func:`iwr.identify` records its own (the settings'
    ``objective``), so that ``iwr report`` tests the run's gross errors, its fit and its
    uncertainty under it. ``resume``: the command that continues the run, for a run that ended
    at its generation or evaluation limit (:func:`longer_run`, appended to the result's message
    and returned; else ""), and a weighted run's failed fit test (returned: the line to print).
    """
    from ..problem_file import engine_result

    result = engine_result(checkpoint, problem)
    if objective is not None:
        result["settings"] = {**dict(result.settings), "objective": objective}
        result = _fit_tested(result, problem)
    hint = longer_run(result, resume) if resume is not None else ""
    if hint:
        result["message"] = f"{result.message}; {hint}"
    result.save(output)
    if result.fit is not None and not result.fit.fit_ok:
        hint = (f"{hint}; " if hint else "") + f"{result.fit.verdict}: not a calibration"
    return hint


def _fit_tested(result: Any, problem: str | None) -> Any:
    """A weighted run's result with its fit tested, as ``iwr report`` tests it
    (:func:`iwr.calibration._weighted_fit`: its cost is the chi-square statistic): a DE run
    stopped far above the noise floor was written "converged", success true (chi2 2.25e5 for 308
    degrees of freedom), until ``iwr report`` refused it. Untested where the problem file cannot
    be read back (the engine read it; ``iwr report`` then tests the result)."""
    from ..analysis.identifiability import identifiability
    from ..calibration import _weighted_fit
    from ..problem_file import load_problem

    if problem is None:
        return result
    try:
        p = load_problem(problem)
        return _weighted_fit(p.robot, p.measurements, result,
                             identifiability(p.robot, p.measurements))
    except (ValueError, OSError, RuntimeError, np.linalg.LinAlgError) as exc:
        # Never lose a long run's result to its test: written untested, and why.
        print(f"{PROG}: the fit was not tested ({type(exc).__name__}: {exc}); iwr report "
              "tests it", file=sys.stderr)
        return result


#: A run whose population's mean or best cost fell by at least this much (%) over its last
#: tenth is still moving: :func:`longer_run` offers ten times its generations, else twice.
MOVING_PERCENT = 1.0
#: Strategies whose population and parameter schedules run to the evaluation budget: a longer
#: run of theirs is a new run with a larger budget, not a resumed one.
_BUDGETED = ("lshade", "jso")


def longer_run(result: Any, resume: str) -> str:
    """For a run that ended at its generation or evaluation limit (status ``stopped``, no signal:
    DE has no convergence test by default, so every run without ``--target-cost``, ``--tol`` or
    ``--stagnation-generations`` ends so), what to change: how much the population's mean cost and
    the best cost fell over the last tenth of the run, and the command that goes on exactly where
    it stopped with ten times the generations, twice when neither fell by :data:`MOVING_PERCENT`
    (``resume`` plus ``--generations``; the evaluations for a limit by ``--max-evaluations``), or
    for lshade and jso, whose schedules end at their budget, a new run with a larger one. ""
    otherwise."""

    settings = dict(result.settings)
    if result.status != "stopped" or "reached" not in str(result.message):
        return ""  # a signal (the engine gave its resume command), a failure, a success
    history = {k: np.asarray(result.history.get(k, []), dtype=float)
               for k in ("generation", "best", "mean")}
    trend, factor = "", 10
    if len({v.size for v in history.values()}) == 1 and history["best"].size > 10:
        # The mean too: rand/1/bin's best can stand still for generations while its
        # population closes in.
        back = (history["best"].size - 1) // 10
        fell = {k: 100 * (v[-1 - back] - v[-1]) / v[-1 - back] for k, v in history.items()
                if k != "generation" and np.isfinite(v[-1]) and np.isfinite(v[-1 - back])
                and v[-1 - back] > 0}
        if len(fell) == 2:
            span = int(history["generation"][-1] - history["generation"][-1 - back])
            moving = max(fell.values()) >= MOVING_PERCENT
            factor = 10 if moving else 2
            trend = (f"over its last {span} generations the population's mean cost fell "
                     f"{fell['mean']:.2g} % and the best {fell['best']:.2g} %"
                     + ("; " if moving else " (it has all but settled: more generations "
                        "will change the cost little); "))
    if settings.get("strategy") in _BUDGETED:
        budget = settings.get("max_evaluations") or result.nfev
        return (f"{trend}{settings['strategy']} plans its schedules over its budget: run it "
                f"again with a larger one (e.g. --max-evaluations {factor * int(budget)})")
    by_evaluations = "evaluations" in str(result.message)
    # A run of --generations 0 made none: ten times none is none (the advice repeated itself).
    generations = factor * (int(result.nit) or 100)
    more = (f"--max-evaluations {factor * int(result.nfev)}" if by_evaluations
            else f"--generations {generations}")
    # A resumed run keeps the checkpoint's other limit: raise it too, or the run stops at once.
    if by_evaluations and settings.get("generations"):
        more += f" --generations {generations}"
    elif not by_evaluations and settings.get("max_evaluations"):
        more += f" --max-evaluations {factor * int(result.nfev)}"
    return (f"{trend}run it longer, from where it stopped: {resume} {more}" if resume
            else f"{trend}run it longer ({more})")


def _same_value(a: Any, b: Any) -> bool:
    if isinstance(a, tuple) and isinstance(b, tuple):  # the weighting: (text, whitening)
        return len(a) == len(b) and all(_same_value(u, v) for u, v in zip(a, b, strict=True))
    if isinstance(a, tuple) or isinstance(b, tuple):
        return False
    try:
        return bool(np.array_equal(a, b, equal_nan=True))  # unseen reflectors are NaN
    except TypeError:  # strings, lists of names
        return bool(np.array_equal(a, b))


def _keep_the_run_problem(problem: Any, path: str, robot_path: str, data_path: str,
                          x0: Any = None) -> None:
    """When resuming, the problem file already there is the run's record: refuse to replace it by
    another problem (the engine would refuse the run anyway, after the record was lost)."""
    from .. import _core
    from ..problem_file import encode_problem, read_problem

    if not Path(path).exists():
        return
    old = read_problem(path)
    new = _core._decode_problem(encode_problem(problem, x0=x0), "")
    differ = [k for k in sorted(set(old) | set(new)) if k not in ("sources", "version")
              and not k.endswith("_fingerprint")
              and (k not in old or k not in new or not _same_value(old[k], new[k]))]
    if differ:
        made_from = ", ".join(p for _, p, _ in old["sources"]) or "unknown files"
        raise ValueError(
            f"{path}: the problem of the run being resumed (made from {made_from}) differs from "
            f"{robot_path} {data_path} in {', '.join(differ)}; resume with the files the run was "
            "made from, or give --problem NEW.iwrp")


def _noise(text: str | None, robot: Any, robot_path: str) -> Any:
    """The noise model of ``--noise`` for ``robot``'s data in the form its problem takes (an
    ``iwr.Noise``; for tracker data ``(Noise, TrackerNoise)``), or None: unweighted."""
    import argparse

    from ..kinds import for_robot
    from ._base import noise_spec
    from .robot_noise import option_noise

    if text is None or text.strip().lower() in ("none", "0", "zero"):
        return None
    spec = text.strip().lower()
    if spec == "estimate":
        raise _Usage("--noise estimate: the noise is estimated by the efficient estimator "
                     "(iwr calibrate --noise estimate); a DE run needs a noise model")
    if spec == "robot":
        noise = robot.noise_model
        if noise is None:
            raise _Usage(f"--noise robot: {robot_path} has no [noise] table (nor "
                         "[tracker.noise])")
    else:
        try:
            noise = noise_spec(text)
        except argparse.ArgumentTypeError as exc:
            raise _Usage(f"--noise: {exc}") from None
    kind = for_robot(robot)
    if not kind.weighted_objective:
        raise _Usage(f"--noise: {robot_path} measures {kind.description} ({kind.name} data), "
                     "which have no noise-weighted objective: leave --noise out, or use the "
                     "efficient estimator (iwr calibrate --noise ...)")
    if spec == "robot":
        return kind.reading_noise(noise)
    try:  # the option as every command reads it
        return option_noise(noise, robot)
    except ValueError as exc:
        raise _Usage(f"--noise: {exc}") from None


def _read_problem_files(robot_path: str, data_path: str, readings: str | None,
                        bounds: str, noise_text: str | None = None
                        ) -> tuple[Any, Any, dict[str, str]]:
    """The problem of ROBOT.toml DATA.csv (with the checks of ``iwr calibrate``), weighted by the
    noise model of ``--noise`` if any, the search's starting point (None: zeros) and the files
    it was made from."""
    from ..kinds import for_robot
    from ..robot import Robot

    robot = Robot.from_toml(robot_path)
    noise = _noise(noise_text, robot, robot_path)
    sources = {"robot": robot_path, "data": data_path}
    kind = for_robot(robot)
    if not kind.engine:
        raise _Usage(f"{data_path}: {kind.name} data ({robot_path} measures "
                     f"{kind.description}): iwr-calibrate's engine takes no problem of them; "
                     "use iwr.identify or iwr calibrate (the Python methods, DE included)")
    try:  # the checks of `iwr calibrate`; a file of another kind or an option it does not take
        data = kind.read(data_path, robot, readings=readings)
    except TypeError as exc:
        raise _Usage(str(exc)) from None
    if readings is not None:
        sources["readings"] = readings
    # As iwr calibrate and iwr report: data a frame or column mistake puts far from the robot
    # are refused before the engine runs (the engine's DE stays in its box, where no fit test
    # without a noise model can fail what it finds).
    from ._base import CommandError, check_frame

    try:
        check_frame(kind, robot, data, data_path)
    except CommandError as exc:
        raise ValueError(str(exc)) from None
    # As iwr.identify: the nominal robot and the kind's start (the tracker's closed-form
    # registration guess), the setup's bounds about it.
    problem, x0 = kind.problem(robot, data, bounds, noise=noise)
    return problem, (None if not np.any(x0) else x0), sources  # None: zeros


def _resume_command(positional: list[str], own: dict[str, str], output: str, checkpoint: str,
                    log: str | None) -> str:
    """The command that resumes this run, pasted into a shell where it was started: the engine
    gives it in the message of an interrupted run (it knows neither ROBOT.toml nor DATA.csv)."""
    words: list[str] = []
    for opt in ("--readings", "--bounds", "--noise", "--problem"):  # made again alike
        if opt in own:
            words += [opt, own[opt]]
    if checkpoint != output + ".ckpt":  # else --resume names the result
        words += ["--output", output]
    words += ["--resume", checkpoint]
    if log:
        words += ["--log", log]  # the engine rewrites the log from the checkpoint's history
    # IWR_KERNEL=K first where the run's variant came from the environment: the same variant on
    # resume, or the run would not end where an uninterrupted one does.
    from .. import _core

    env = _core._kernel_environment_prefix()
    if any(p.startswith("-") and len(p) > 1 for p in positional):  # a file named -x.csv
        return env + shlex.join([PROG, *words, "--", *positional])
    return env + shlex.join([PROG, *positional, *words])


def _run_engine(engine: str, args: list[str]) -> int:
    """Runs the engine, passing our signals on; returns its exit status, 128 + N for signal N."""
    handled = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGUSR1)
    proc: subprocess.Popen[bytes] | None = None
    pending: list[int] = []

    def forward(sig: int, _frame: Any) -> None:
        if proc is None:
            pending.append(sig)
        else:
            try:
                proc.send_signal(sig)
            except ProcessLookupError:
                pass

    previous = {}
    for sig in handled:
        if signal.getsignal(sig) is not signal.SIG_IGN:  # ignored at start (nohup): stays ignored
            previous[sig] = signal.signal(sig, forward)

    def child_setup() -> None:
        # If the launcher dies (kill -9), the engine gets SIGTERM and writes its checkpoint.
        try:
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM))  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass

    try:
        proc = subprocess.Popen([PROG, *args], executable=engine, preexec_fn=child_setup)  # noqa: PLW1509
        for sig in pending:
            proc.send_signal(sig)
        code = proc.wait()
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 128 - code if code < 0 else code


def main(argv: Sequence[str] | None = None) -> int:
    """The ``iwr-calibrate`` command; returns its exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        _startup.release()  # Ctrl-C is KeyboardInterrupt again, handled below
        return _main(argv)
    except _Usage as exc:
        return _error(str(exc), EXIT_USAGE)
    except KeyboardInterrupt:
        print(f"\n{PROG}: interrupted", file=sys.stderr)
        return 130
    except (ValueError, OSError, RuntimeError, ImportError) as exc:
        if _startup.interrupted_by(exc):  # Ctrl-C in a module's initialisation: an ImportError
            print(f"\n{PROG}: interrupted", file=sys.stderr)
            return 130
        return _error(str(exc), EXIT_ERROR)


def _main(argv: list[str]) -> int:
    positional, own, engine_args, flags = _split(argv)
    if flags & {"-h", "--help"}:
        sys.stdout.write(HELP)
        sys.stdout.flush()
        return subprocess.call([PROG, "--help"], executable=engine_path())
    try:  # the engine, started with this environment, reads it too
        _startup.command_kernel()
    except ValueError as exc:
        raise _Usage(str(exc)) from None
    if "--version" in flags:
        return subprocess.call([PROG, "--version"], executable=engine_path())
    if "--export" in own:
        if positional:
            raise _Usage(f"--export: unexpected argument '{positional[0]}'")
        if "--output" not in own:
            raise _Usage("--export: give the JSON result's name with --output")
        if not own["--output"] or own["--output"].endswith("/"):
            raise _Usage(f"--output: '{own['--output']}' is not a file name")
        inputs = [(own[opt], what) for opt, what in (("--export", "the checkpoint exported"),
                                                     ("--problem", "the problem file read"))
                  if opt in own]
        _check_outputs([("--output", own["--output"])],
                       inputs + _recorded_sources(own.get("--problem")))
        _export(own["--export"], own.get("--problem"), own["--output"])
        return EXIT_OK

    resume = _option(engine_args, "--resume")
    if len(positional) == 2:
        robot_path, data_path = positional
        problem_in = None
    elif len(positional) == 1:
        problem_in = positional[0]
        robot_path = data_path = None
        if "--bounds" in own:
            raise _Usage("--bounds: the bounds of a problem file are its own; set them when "
                         "writing it (iwr.Problem(..., bounds=...).save)")
        if "--problem" in own:
            raise _Usage("--problem: the problem file is the argument given")
        if "--noise" in own:
            raise _Usage("--noise: the noise weighting of a problem file is its own; set it when "
                         "writing it (iwr.Problem(..., noise=...).save)")
    else:
        raise _Usage("expected ROBOT.toml and DATA.csv, or PROBLEM.iwrp" if not positional
                     else f"unexpected argument '{positional[2]}'")
    if "--bounds" in own and own["--bounds"] not in ("default", "paper"):
        raise _Usage(f"--bounds: '{own['--bounds']}'; expected default or paper")

    # The outputs. No output path is ever taken from a checkpoint: with --resume CKPT the result
    # is named after CKPT itself.
    if "--output" in own:
        output = own["--output"]
    elif resume is not None:
        if not resume.endswith(".ckpt") or len(resume) <= len(".ckpt"):
            raise _Usage(f"--resume {resume}: give --output (the result is named after the "
                         "checkpoint only when its name ends in .ckpt)")
        output = resume[: -len(".ckpt")]
    else:
        output = "iwr-result.json"
    if not output or output.endswith("/"):
        raise _Usage(f"--output: '{output}' is not a file name")
    checkpoint = _option(engine_args, "--checkpoint") or resume or output + ".ckpt"
    problem_path = problem_in or own.get("--problem") or output + ".iwrp"
    log = _option(engine_args, "--log")

    inputs = [(p, what) for p, what in ((robot_path, "the robot file"),
                                         (data_path, "the data file"),
                                         (own.get("--readings"), "the readings file"),
                                         (problem_in, "the problem file"),
                                         (resume, "the checkpoint resumed")) if p]
    # A problem file's ROBOT.toml and DATA.csv are the run's inputs too: the engine refuses its
    # checkpoint and log over them, the launcher the result it writes.
    inputs += _recorded_sources(problem_in)
    outputs = [("--output", output), ("--checkpoint", checkpoint)]
    if problem_in is None:
        outputs.append(("--problem", problem_path))
    if log:
        outputs.append(("--log", log))
    _check_outputs(outputs, inputs, resume)
    for k, (opt_a, a) in enumerate(outputs):
        for opt_b, b in outputs[k + 1:]:
            if _same(a, b):
                raise _Usage(f"{opt_a} and {opt_b} name the same file, {a}")
    folder = Path(output).parent
    if not folder.is_dir():
        raise ValueError(f"{output}: cannot write the result here: folder {folder} does not exist")
    if not os.access(folder, os.W_OK):
        raise ValueError(f"{output}: cannot write the result here: folder {folder} is not writable")

    engine = engine_path()
    # The launcher's own lock, held to the end: the engine's lock below is released just before
    # the engine takes it, and another launcher must not come in between (issue 26's campaign).
    launch_lock = _lock_checkpoint(checkpoint, "launch", PROG)
    try:
        return _launch(engine, positional, own, engine_args, flags, robot_path, data_path,
                       problem_in, problem_path, output, checkpoint, resume, log)
    finally:
        os.close(launch_lock)


def _launch(engine: str, positional: list[str], own: dict[str, str], engine_args: list[str],
            flags: set[str], robot_path: str | None, data_path: str | None,
            problem_in: str | None, problem_path: str, output: str, checkpoint: str,
            resume: str | None, log: str | None) -> int:
    objective = None  # the noise model of a weighted run, for its result
    if problem_in is None:
        assert robot_path is not None and data_path is not None
        # The engine's lock first: a run going on with this checkpoint keeps its problem file
        # (its record) untouched; released just before the engine takes it.
        lock = _lock_checkpoint(checkpoint)
        try:
            problem, x0, sources = _read_problem_files(robot_path, data_path,
                                                       own.get("--readings"),
                                                       own.get("--bounds", "default"),
                                                       own.get("--noise"))
            if resume is not None:
                _keep_the_run_problem(problem, problem_path, robot_path, data_path, x0)
            problem.save(problem_path, sources=sources, x0=x0)
            if problem.noise is not None:
                from ..kinds import of

                objective = {"weighted": True,
                             **of(problem.measurements).noise_record(problem.noise)}
        finally:
            os.close(lock)
    elif "--readings" in own:
        raise _Usage("--readings: only with ROBOT.toml DATA.csv")

    pass_checkpoint = [] if _option(engine_args, "--checkpoint") else ["--checkpoint", checkpoint]
    hint = _resume_command(positional, own, output, checkpoint, log)
    code = _run_engine(engine, [problem_path, *pass_checkpoint, *engine_args,
                                "--resume-command", hint])
    if code in (EXIT_OK, 128 + signal.SIGHUP, 128 + signal.SIGINT, 128 + signal.SIGTERM) and \
            Path(checkpoint).is_file():
        # A run that reached its limit: the result says how to go on (a signal's resume
        # command is the engine's own message).
        longer = _export(checkpoint, problem_path, output, objective,
                         hint if code == EXIT_OK else None)
        if "--quiet" not in flags and "-q" not in flags:
            if longer:
                print(f"{PROG}: {longer}", file=sys.stderr)
            print(f"{PROG}: result in {output}", file=sys.stderr)
    return code


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
