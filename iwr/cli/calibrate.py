"""``iwr calibrate``: identify the errors of a robot from measurements, or run the built-in
example; print a summary and write the calibrated robot, the result and the report (HTML and
Markdown)."""

from __future__ import annotations

import argparse
import inspect
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

from ..kinds import VALIDATION_FRACTION, for_robot
from ..reporting.html import provenance
from ._base import (
    EXIT_INTERRUPTED,
    EXIT_OK,
    METHOD_ENV,
    QUICK_ENV,
    Footprint,
    UsageError,
    add_common,
    check_frame,
    check_memory,
    check_output,
    check_validation_file,
    check_validation_split,
    check_workers,
    default_method,
    fraction,
    load_robot,
    noise_spec,
    nonneg_int,
    not_held_out,
    one_line,
    overwritten_input,
    positive_int,
    progress_enabled,
    read_data,
)
from .robot_noise import OPTION_HELP, calibration_noise, describe, option_noise
from .simulate import write_truth
from .tracker import add_arguments as add_tracker_arguments
from .tracker import target_format

EXAMPLE_SEED = 2024
EXAMPLE_POSES = 125  # 100 for identification, 25 held out (validation fraction 0.2)
EXAMPLE_POSES_QUICK = 50
EXAMPLE_GENERATIONS_QUICK = 30  # of DE in the quick example (then polished by LM)
EXAMPLE_DIR = "iwr-example"
DEFAULT_OUT = "iwr-calibration"
#: Exit code of a calibration whose model does not fit the data (chi-square test failed, or
#: identified errors far beyond their plausible size): the files are written, but not as success.
EXIT_NO_FIT = 3
# The method stopped before converging (a budget, a limit) or failed; the files say so.
EXIT_NOT_CONVERGED = 4
# The method converged, but the data cannot identify the errors (too few distinct poses, a
# rank-deficient information matrix) or the calibrated robot is no better than the nominal one.
EXIT_NOT_CALIBRATED = 5

# CLI option -> keyword a method takes for it: first the known ones per method (for options taken
# through **options), then the first of the names below found in the method's signature.
_KNOWN_OPTIONS: dict[str, dict[str, str]] = {
    "de": {"budget": "max_evaluations"},
}
_METHOD_OPTIONS: dict[str, tuple[str, ...]] = {
    "budget": ("max_evaluations",),
    "generations": ("generations",),
    "preset": ("preset",),
    "polish": ("polish",),
    "workers": ("workers",),
    "strategy": ("strategy",),
}


def run_settings(args: argparse.Namespace, method: str, kwargs: dict[str, Any]) -> dict[str, Any]:
    """The settings of an ``iwr calibrate`` run, as its report and ``summary.json`` record them
    (leg and tracker data alike)."""
    settings = {"method": method, "bounds": args.bounds, "parameters": args.parameters,
                "seed": args.seed, "validation_fraction": args.validation_fraction,
                **{k: v for k, v in kwargs.items() if k not in ("callback", "active")}}
    if settings.get("noise") is not None:
        settings["noise"] = describe(settings["noise"])  # readable, not a repr
    if getattr(args, "noise_from", None):
        settings["noise_from"] = args.noise_from
    return settings


def add_parser(sub: Any) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "calibrate", help="identify the errors of a robot from measurements (or run the example)",
        description="Identify the error parameters of ROBOT.toml from DATA.csv, print a summary "
        "(cost, leg residuals, identifiability, accuracy before and after) and write the "
        "calibrated robot, the result and a report. Without arguments: the whole job on a "
        "built-in example, a simulated IWR with realistic noise, in ./iwr-example/.",
        epilog=f"The default method is 'efficient' (the efficient estimator, every instrument "
        f"weighted by its noise) when a noise model is known (--noise, or the built-in example's "
        f"realistic noise), else 'lm' (eq. (10) by Levenberg-Marquardt on the exact Jacobian from "
        f"the nominal robot); 'de' is the paper's differential evolution, polished by "
        f"Levenberg-Marquardt. Set ${METHOD_ENV} to change the default. Exit code "
        f"{EXIT_NO_FIT}: the model does not fit the data; {EXIT_NOT_CALIBRATED}: the data cannot "
        f"identify the errors, or the calibration did not improve the accuracy (the files are "
        f"written in both cases). "
        f"${QUICK_ENV}=1 makes the built-in example smaller (for tests).",
    )
    p.add_argument("robot", nargs="?", metavar="ROBOT.toml", help="the nominal robot")
    p.add_argument("data", nargs="?", metavar="DATA.csv", help="the measurements (docs/data.md)")
    add_tracker_arguments(p)  # --readings (docs/tracker.md)
    p.add_argument("--method", default=None,
                   help="identification method: efficient, lm, de, crs2, bobyqa (default: "
                   "$IWR_METHOD, else efficient when a noise model is known, else lm)")
    p.add_argument("--noise", type=_noise_arg, default=None, metavar="SPEC",
                   help="the instruments' noise: " + OPTION_HELP + " (legs > 0); or 'estimate' "
                   "(estimated from the data), or 'none' (no noise model). Default: the [noise] "
                   "table of ROBOT.toml (and [tracker.noise]) when it has one, else none; "
                   "realistic for the built-in example. With a noise model the fit is tested "
                   "(chi-square)")
    p.add_argument("--budget", type=positive_int, default=None, metavar="N",
                   help="largest number of objective evaluations of the method's run (a Jacobian "
                   "counts as one; the efficient estimator: iterations of each of its solves; "
                   "the outlier screen's re-fit is not counted); method's default if not given")
    p.add_argument("--generations", type=positive_int, default=None, metavar="G",
                   help="generations of an evolutionary method (de)")
    p.add_argument("--preset", default=None,
                   help="a method preset, e.g. 'paper' for the DE settings of Table 2")
    p.add_argument("--strategy", default=None, help="DE strategy, e.g. rand1bin, lshade")
    p.add_argument("--polish", action=argparse.BooleanOptionalAction, default=None,
                   help="refine a global method's result by Levenberg-Marquardt "
                   "(default: on for de)")
    p.add_argument("--workers", type=positive_int, default=None, metavar="N",
                   help="threads of a parallel method (default: all cores)")
    p.add_argument("--seed", type=nonneg_int, default=0,
                   help="seed of the validation split and of stochastic methods (default: "
                   "%(default)s; the example's data use seed 2024)")
    p.add_argument("--parameters", choices=("base", "all"), default="base",
                   help="identify the base parameters only, the unidentifiable ones held at "
                   "nominal, for a unique answer (base, the default), or all of them (all)")
    p.add_argument("--bounds", choices=("default", "paper"), default="default",
                   help="search bounds: +-0.5 mm and +-0.5 degree (default), or Table 2 literally "
                   "(+-0.5 for every parameter)")
    val = p.add_mutually_exclusive_group()
    val.add_argument("--validation-fraction", type=fraction, default=VALIDATION_FRACTION,
                     metavar="F",
                     help="fraction of the poses held out (at random, by --seed) for the accuracy "
                     "figure (default: %(default)s; 0: none, the accuracy is then optimistic)")
    val.add_argument("--validation", metavar="VALID.csv",
                     help="validation poses from a separate file; all of DATA.csv identifies")
    p.add_argument("-o", "--out", default=None, metavar="DIR",
                   help="folder of the calibrated robot, result and report (default: "
                   "iwr-calibration, or iwr-example for the example)")
    p.add_argument("--poses", type=positive_int, default=None, metavar="N",
                   help=f"built-in example only: number of simulated poses (default "
                   f"{EXAMPLE_POSES}, {EXAMPLE_POSES_QUICK} with ${QUICK_ENV}=1)")
    p.add_argument("--no-plots", action="store_true", help="write the report without figures")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    add_common(p)
    p.set_defaults(func=cmd_calibrate)
    return p


def _noise_arg(text: str) -> Any:
    """``--noise``: :func:`noise_spec`, ``estimate``, or ``none`` (no noise model)."""
    spec = text.strip().lower()
    if spec == "estimate":
        return "estimate"
    if spec in ("none", "0", "zero"):
        return "none"
    noise = noise_spec(text)
    if noise.legs <= 0:
        raise argparse.ArgumentTypeError(
            f"{text!r}: the leg sensors' noise must be > 0 (legs=SIGMA): the efficient estimator "
            "closes every loop through the legs")
    return noise


def _method_kwargs(method: str, args: argparse.Namespace) -> dict[str, Any]:
    """The method options given on the command line, under the names the method accepts."""
    from ..methods import METHODS, identify

    if method not in METHODS:
        raise UsageError(
            f"--method {method!r}: available methods: {', '.join(sorted(METHODS))}"
        )
    params = dict(inspect.signature(METHODS[method]).parameters)
    params.update(inspect.signature(identify).parameters)
    kwargs: dict[str, Any] = {}
    for option, names in _METHOD_OPTIONS.items():
        value = getattr(args, option, None)
        if value is None:
            if option == "polish" and method == "de" and "polish" in params:
                kwargs["polish"] = True  # the paper's DE, then a local refinement
            continue
        name = _KNOWN_OPTIONS.get(method, {}).get(option)
        if name is None:
            name = next((n for n in names if n in params), None)
        if name is None:
            raise UsageError(f"--{option} is not an option of method {method!r}")
        kwargs[name] = value
    if method == "de":  # its named choices: a usage error naming the option (exit 2)
        from ..methods.de import STRATEGIES

        if kwargs.get("strategy") not in (None, *STRATEGIES):
            raise UsageError(f"--strategy {kwargs['strategy']!r}: expected one of "
                             f"{', '.join(STRATEGIES)}")
        if kwargs.get("preset") not in (None, "paper"):
            raise UsageError(f"--preset {kwargs['preset']!r}: expected 'paper'")
    return kwargs


def _check_sizes(args: argparse.Namespace) -> None:
    """More ``--workers`` than the engine takes (a fixed cap), refused before any work; the
    example's ``--poses`` is checked by :func:`_run_example` (a budget is a cap, not an
    allocation: not checked, :mod:`iwr.cli._base`)."""
    check_workers(args.workers, "iwr calibrate")


def _budget_error(exc: ValueError, args: argparse.Namespace, method: str) -> UsageError | None:
    """The method's refusal of ``--budget`` (too small for it: LM's 2 evaluations, DE's initial
    population), which it makes as it starts, before any evaluation: a usage error (exit 2)
    naming the option, not a failed computation (exit 1). None for another error."""
    msg = one_line(exc)
    if args.budget is None or not msg.startswith("max_evaluations:"):
        return None
    return UsageError(f"--budget{msg[len('max_evaluations'):]} (method {method})")


def _check_budget(robot: Any, method: str, kwargs: dict[str, Any],
                  args: argparse.Namespace) -> None:
    """A ``--budget`` too small for the method refused before any work (the example's files,
    "identifying ..."): the method's own check, in a run stopped before it searches
    (:func:`iwr.experiments.executors.dry_run`); any other error is left to the run, which
    names it in its context."""
    if args.budget is None:
        return
    from ..experiments.executors import dry_run

    try:
        dry_run(robot, method, {k: v for k, v in kwargs.items() if k != "noise"})
    except ValueError as exc:
        usage = _budget_error(exc, args, method)
        if usage is not None:
            raise usage from None


def cmd_calibrate(args: argparse.Namespace) -> int:
    if args.robot is not None and args.data is None:
        raise UsageError("give both ROBOT.toml and DATA.csv, or neither (the built-in example)")
    noise = None if args.noise == "none" else args.noise
    args.noise_note = ""
    if args.robot is None and args.noise is None:
        from ..noise import Noise

        noise = Noise.realistic()
        args.noise_note = " (the built-in example knows its noise: iwr.Noise.realistic())"
    args.noise_from = "--noise" if args.noise not in (None, "none") else None
    if args.robot is not None and args.noise is None:  # the robot file's [noise], if any

        noise, args.noise_from = calibration_noise(args.robot)
        args.noise_note = f" (from {args.noise_from}; --noise overrides it)" if noise else ""
    method = args.method or (default_method() if (os.environ.get(METHOD_ENV, "").strip()
                                                   or noise is None) else "efficient")
    kwargs = _method_kwargs(method, args)
    _check_sizes(args)
    if noise is not None:
        kwargs["noise"] = noise
    elif method == "efficient":
        raise UsageError("--method efficient needs a noise model: --noise realistic, "
                         "--noise legs=SIGMA,..., or --noise estimate")
    if args.robot is None:
        return _run_example(args, method, kwargs)
    if args.poses is not None:
        raise UsageError("--poses applies to the built-in example only, not to ROBOT.toml DATA.csv")
    args.out = str(_out_folder(args))
    robot = load_robot(args.robot)
    _check_budget(robot, method, kwargs, args)
    kind = for_robot(robot)
    if not kind.report:
        raise UsageError(f"{args.robot}: {kind.name} data ({kind.description}): iwr calibrate "
                         "has no report for them yet; calibrate them from Python with "
                         "iwr.calibrate (docs/kinds.md)")
    if "noise" in kwargs:
        kwargs["noise"] = _reading_noise(kind, robot, kwargs["noise"], method, args)
    check_validation_file(args.validation, args.data, "iwr calibrate", _HOLD_OUT_INSTEAD)
    data = read_data(args.data, robot, args.readings, targets=target_format(args))
    validation = read_data(args.validation, robot) if args.validation else None
    if validation is None and args.validation_fraction > 0:
        check_validation_split(data, args.validation_fraction, args.seed)
    for path, m in ((args.data, data), (args.validation, validation)):
        if m is not None:
            check_frame(kind, robot, m, str(path))
    sources = {"readings": str(args.readings)} if args.readings else {}
    out = Path(args.out)
    try:
        cal = _calibrate(robot, data, validation, args, method, kwargs, out,
                         robot_name=str(args.robot), data_name=str(args.data), sources=sources)
    except _Interrupted:
        return EXIT_INTERRUPTED
    return _exit_code(cal)


def _reading_noise(kind: Any, robot: Any, noise: Any, method: str,
                   args: argparse.Namespace) -> Any:
    """The noise model in the form the data's kind takes (``--noise`` as
    :func:`~iwr.cli.robot_noise.option_noise` reads it for every command, the robot file's by
    :meth:`MeasurementKind.reading_noise`), and what is set aside: a noise model a kind cannot
    weigh method ``method`` by (refused when --noise gives it, set aside with a note when the
    robot file does), the orientation a pose measured in {0} has and these data have not."""
    from ..noise import Noise

    if method != "efficient" and not kind.weighted_objective:
        if getattr(args, "noise_from", None) in (None, "--noise"):
            raise UsageError(f"--method {method} with --noise: on {kind.description} data only "
                             "the efficient estimator weighs the instruments by a noise model "
                             "(the other methods minimise the unweighted residuals); use --method "
                             "efficient (the default with --noise) or leave --noise out")
        # The file's noise model is the estimator's, not a reason to refuse the method named.
        print(f"noise model of {args.noise_from}: not used by method {method} on "
              f"{kind.description} data (only by the efficient estimator)")
        args.noise_from = None
        return None
    option = getattr(args, "noise_from", None) == "--noise"
    converted = option_noise(noise, robot) if option else kind.reading_noise(noise)
    readings = converted[0] if isinstance(converted, tuple) else converted
    if (option and isinstance(noise, Noise) and isinstance(readings, Noise)
            and noise != Noise.realistic() and noise.orientation and not readings.orientation):
        # An orientation sigma given for a pose measured in {0} has no reading here (position
        # is the instrument's noise level).
        print(f"--noise orientation={noise.orientation:g}: a pose measured in {{0}}, not used "
              f"with {kind.description} data", flush=True)
    return converted


def _out_folder(args: argparse.Namespace) -> Path:
    """The output folder, checked before any work: writable, and writing no file over an input
    (robot, data, readings, validation), by any spelling or link. Without --out, when the
    default folder holds an input (the re-calibration flow: ``iwr calibrate
    iwr-calibration/calibrated.toml DATA.csv``), the first of iwr-calibration-2, -3, ... that
    does not exist."""
    from ..reporting.calibration import OUTPUT_FILES

    inputs = [args.robot, args.data, args.readings, args.validation]
    if args.out is not None:
        check_output(args.out, "--out", inputs=inputs, files=OUTPUT_FILES)
        return Path(args.out)
    out = Path(DEFAULT_OUT)
    clash = overwritten_input([out / name for name in OUTPUT_FILES], inputs)
    if clash is not None:
        n = 2
        while Path(f"{DEFAULT_OUT}-{n}").exists():
            n += 1
        out = Path(f"{DEFAULT_OUT}-{n}")
        print(f"output folder: {out}/ ({DEFAULT_OUT}/{clash[0].name} is {clash[1]}, an input of "
              "this run, kept; --out DIR chooses the folder)")
    check_output(out, "--out", inputs=inputs, files=OUTPUT_FILES)
    return out


def _exit_code(cal: Any, prog: str = "iwr calibrate", *, converged: bool = True) -> int:
    """The exit status of a calibration's verdict (``converged=False``: a run that stopped
    before converging is not an error, as for ``iwr report`` of a DE run)."""
    from ..calibration import NOT_CALIBRATED

    if cal.fit_ok is False and cal.status != NOT_CALIBRATED:  # degenerate data: no fit to test
        what = ("not converged, and its best point does not fit the data (run it longer first)"
                if cal.status == "stopped" else "the model does not fit the data")
        print(f"{prog}: {what} (exit {EXIT_NO_FIT}); the files are written, see the report",
              file=sys.stderr)
        return EXIT_NO_FIT
    if cal.status == NOT_CALIBRATED:
        reason = str(cal.result.message).removeprefix(f"{NOT_CALIBRATED}: ")
        print(f"{prog}: not calibrated (exit {EXIT_NOT_CALIBRATED}): "
              f"{' '.join(reason.split())}; the files are written, see the report",
              file=sys.stderr)
        return EXIT_NOT_CALIBRATED
    if converged and not cal.success:
        print(f"iwr calibrate: not converged (status {cal.status or 'stopped'}, exit "
              f"{EXIT_NOT_CONVERGED}); the files hold the best point so far", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return EXIT_OK


def _run_example(args: argparse.Namespace, method: str, kwargs: dict[str, Any]) -> int:
    from ..reporting.calibration import OUTPUT_FILES
    from ..robot import Robot
    from ..simulation import Noise, simulate

    if args.validation:
        raise UsageError("--validation needs ROBOT.toml and DATA.csv")
    quick = os.environ.get(QUICK_ENV, "").strip() not in ("", "0")
    n = args.poses or (EXAMPLE_POSES_QUICK if quick else EXAMPLE_POSES)
    robot = Robot.default()
    if args.poses is not None:
        check_memory("--poses", args.poses, Footprint.of(robot).job(args.poses),
                     "the example's simulated poses and their calibration", "iwr calibrate")
    if quick and method == "de" and args.generations is None and args.budget is None:
        kwargs = {**kwargs, "generations": EXAMPLE_GENERATIONS_QUICK}
    out = Path(args.out or EXAMPLE_DIR)
    check_output(out, "--out", files=OUTPUT_FILES)
    _check_budget(robot, method, kwargs, args)
    out.mkdir(parents=True, exist_ok=True)
    noise = Noise.realistic()
    data, truth = simulate(robot, n_poses=n, seed=EXAMPLE_SEED, noise=noise)
    robot_path, data_path = out / "robot.toml", out / "measurements.csv"
    robot.to_toml(robot_path)
    data.to_csv(data_path)
    write_truth(out / "true_errors.json", robot, truth, EXAMPLE_SEED, noise, n)
    print(
        f"built-in example: the IWR of docs/model.md with random errors (+-0.5 mm, +-0.5 deg), "
        f"{n} random poses (seed {EXAMPLE_SEED}) and realistic noise (iwr.Noise.realistic(): "
        "leg sensors 2 um, carriage joints 5 um and 5 urad, laser tracker 20 um and 20 urad)"
    )
    print(f"inputs: {robot_path}, {data_path}, {out / 'true_errors.json'} (the truth)")
    print()
    robot = load_robot(str(robot_path))
    data = read_data(str(data_path), robot)
    try:
        cal = _calibrate(robot, data, None, args, method, kwargs, out, robot_name=str(robot_path),
                         data_name=str(data_path), truth=truth)
    except _Interrupted:
        return EXIT_INTERRUPTED
    print(f"\nthe same on your own files: iwr calibrate ROBOT.toml DATA.csv (docs/data.md); "
          f"here: iwr calibrate {robot_path} {data_path}"
          + (" --noise realistic" if "noise" in kwargs else ""))
    return _exit_code(cal)


def _calibrate(robot: Any, data: Any, validation: Any, args: argparse.Namespace, method: str,
               kwargs: dict[str, Any], out: Path, *, robot_name: str, data_name: str,
               truth: np.ndarray | None = None, sources: dict[str, str] | None = None) -> Any:
    """The job (:func:`iwr.calibration.calibrate`), printed as it goes and written as its
    report (:func:`iwr.reporting.calibration.render`)."""
    from ..calibration import NotHeldOutError, calibrate
    from ..reporting.calibration import render

    noise = kwargs.get("noise")
    if noise is None:
        print("noise model: none given (--noise): the cost cannot be tested against the noise, "
              "only the size of the identified errors")
    else:
        if getattr(args, "noise_from", None) == "--noise":
            args.noise_note = " (from --noise)"
        print(f"noise model: {describe(noise)}{getattr(args, 'noise_note', '')}")
        if method == "efficient":
            print("method: the efficient estimator (every instrument weighted by its noise; "
                  "eq. (10) weighted by it is --method lm, unweighted --noise none)")
        elif not isinstance(noise, str):
            print(f"method: {method} on the objective weighted by the noise model (each pose's "
                  "residuals whitened by their propagated covariance; unweighted: --noise none)")
    inputs = {"robot": robot_name, "data": data_name, **(sources or {})}
    if getattr(args, "validation", None):
        inputs["validation"] = str(args.validation)
    options = {k: v for k, v in kwargs.items() if k != "noise"}
    try:
        cal = calibrate(
            robot, data, method, noise=noise, validation=validation,
            validation_fraction=args.validation_fraction, seed=args.seed,
            parameters=args.parameters, bounds=args.bounds, truth=truth,
            progress=progress_enabled(args), log=lambda line: print(line, flush=True),
            data_name=data_name, robot_name=robot_name, sources=sources,
            settings=run_settings(args, method, kwargs), provenance=provenance(inputs),
            **options)
    except NotHeldOutError as exc:  # before any work
        raise not_held_out(args.validation, args.data, "iwr calibrate", _HOLD_OUT_INSTEAD,
                           exc.shared) from None
    except ValueError as exc:
        usage = _budget_error(exc, args, method)
        if usage is None:
            raise
        raise usage from None
    report = render(cal)
    print(report.text())
    written = report.write(out, plots=not args.no_plots)
    print(f"\nwrote {out}/: " + ", ".join(p.name for p in written))
    if cal.interrupted:
        print("iwr calibrate: interrupted; the files hold the best point so far "
              "(success = false)", file=sys.stderr)
        raise _Interrupted
    return cal


_HOLD_OUT_INSTEAD = ("give another file, or leave --validation out to hold out "
                     "--validation-fraction of the data")


class _Interrupted(Exception):
    """The identification was interrupted; its best point so far has been written."""
