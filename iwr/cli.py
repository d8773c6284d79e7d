"""The ``iwr`` command line: ``simulate``, ``calibrate``, ``analyze``, ``plan``, ``study``,
``compare``.

Every command has ``--help``. Exit codes: 0 success, 1 bad data or a failed computation, 2 bad
usage, 130 interrupted. Errors are one line, ``iwr: error: ...``, on standard error; ``--debug``
adds the Python traceback.
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import json
import math
import os
import sys
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from . import __version__

__all__ = ["main", "build_parser", "default_method"]

EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130

#: Environment variable that sets the default identification method of ``iwr calibrate``.
METHOD_ENV = "IWR_METHOD"
#: Environment variable: when set to 1, ``iwr calibrate`` without arguments runs a smaller example.
QUICK_ENV = "IWR_EXAMPLE_QUICK"

EXAMPLE_SEED = 2024
EXAMPLE_POSES = 125  # 100 for identification, 25 held out (validation fraction 0.2)
EXAMPLE_POSES_QUICK = 50
EXAMPLE_GENERATIONS_QUICK = 30  # of DE in the quick example (then polished by LM)
EXAMPLE_DIR = "iwr-example"

# CLI option -> keyword a method takes for it: first the known ones per method (for options taken
# through **options), then the first of the names below found in the method's signature.
_KNOWN_OPTIONS: dict[str, dict[str, str]] = {
    "de": {"budget": "max_evaluations"},
}
_METHOD_OPTIONS: dict[str, tuple[str, ...]] = {
    "budget": ("max_evaluations", "max_nfev", "max_evals", "maxeval", "budget"),
    "generations": ("generations",),
    "preset": ("preset",),
    "polish": ("polish",),
    "workers": ("workers",),
    "strategy": ("strategy",),
}


class UsageError(Exception):
    """Bad command-line usage: exit code 2. The message ends with where to find help."""

    def __init__(self, message: str, prog: str = "iwr calibrate") -> None:
        super().__init__(f"{message} (see '{prog} --help')")


class CommandError(Exception):
    """A command that cannot run (missing feature, inconsistent input): exit code 1."""


class _Parser(argparse.ArgumentParser):
    """argparse, with one-line errors raised to :func:`main` instead of a usage dump."""

    def error(self, message: str) -> Any:  # type: ignore[override]
        raise UsageError(message, self.prog)


def default_method() -> str:
    """The default method of ``iwr calibrate``.

    ``$IWR_METHOD`` when set; otherwise ``"de"`` (the paper's differential evolution, polished by
    Levenberg-Marquardt) when this build has it, else ``"lm"`` (Levenberg-Marquardt on the exact
    Jacobian).
    """
    from .identify import METHODS

    env = os.environ.get(METHOD_ENV, "").strip()
    if env:
        return env
    return "de" if "de" in METHODS else "lm"


# -- argument types ------------------------------------------------------------------------------


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"{v} must be a positive integer")
    return v


def _nonneg_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"{v} must be >= 0")
    return v


def _fraction(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0.0 <= v < 1.0:
        raise argparse.ArgumentTypeError(f"{v} must be in [0, 1)")
    return v


def _noise(text: str) -> Any:
    """``realistic``, ``none``, or ``key=sigma,...`` over the fields of :class:`iwr.Noise`."""
    from .simulate import Noise

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


# -- the parser ----------------------------------------------------------------------------------


def _common(p: argparse.ArgumentParser) -> None:
    # SUPPRESS: a subcommand must not reset a --debug given before it.
    p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                   help="show the Python traceback of an error")


def build_parser() -> argparse.ArgumentParser:
    """The ``iwr`` argument parser (subcommands ``simulate``, ``calibrate``, ``analyze``,
    ``plan``, and ``compare`` where available)."""
    parser = _Parser(
        prog="iwr",
        description="Kinematic calibration of the IWR robot (a 4-DOF carriage carrying a Stewart "
        "hexapod) and similar hybrid robots. Start with 'iwr calibrate', which runs the whole job "
        "on a built-in simulated example.",
        epilog="Units: mm and rad everywhere. File formats: docs/data.md. Exit codes: 0 success, "
        "1 bad data or failed computation, 2 bad usage, 130 interrupted.",
    )
    parser.add_argument("--version", action="version", version=f"iwr {__version__}")
    parser.add_argument("--debug", action="store_true",
                        help="show the Python traceback of an error")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    # simulate ----------------------------------------------------------------------------------
    p = sub.add_parser(
        "simulate", help="write a simulated robot and measurement file",
        description="Simulate a calibration experiment: an 'actual' robot (the nominal one plus "
        "random errors, uniform within +-0.5 mm and +-0.5 degree), reachable random poses, and "
        "noisy readings. Writes the nominal robot (TOML), the measurements (CSV) and the true "
        "errors (JSON).",
    )
    p.add_argument("--robot", metavar="ROBOT.toml",
                   help="the nominal robot (default: the built-in IWR, iwr.Robot.default())")
    p.add_argument("--poses", type=_positive_int, default=100, metavar="N",
                   help="number of measurement poses (default: %(default)s)")
    p.add_argument("--seed", type=_nonneg_int, default=1,
                   help="random seed: the same seed writes the same files (default: %(default)s)")
    p.add_argument("--noise", type=_noise, default="realistic", metavar="SPEC",
                   help="measurement noise: 'realistic' (iwr.Noise.realistic(): legs 0.002 mm, "
                   "joints 0.005 mm and 5e-6 rad, tracker 0.02 mm and 2e-5 rad), 'none' (the "
                   "paper's simulation), or standard deviations KEY=SIGMA,... with KEY among legs, "
                   "joint_lengths, joint_angles, position, orientation (mm, rad; others 0) "
                   "(default: realistic)")
    p.add_argument("--out-dir", default=".", metavar="DIR",
                   help="folder of the files written (created if needed; default: current)")
    p.add_argument("--robot-file", default="robot.toml", metavar="NAME",
                   help="name of the robot file in DIR (default: %(default)s)")
    p.add_argument("--data-file", default="measurements.csv", metavar="NAME",
                   help="name of the measurement file in DIR (default: %(default)s)")
    p.add_argument("--truth-file", default="true_errors.json", metavar="NAME",
                   help="name of the true-error file in DIR (default: %(default)s)")
    _common(p)
    p.set_defaults(func=cmd_simulate)

    # calibrate ---------------------------------------------------------------------------------
    p = sub.add_parser(
        "calibrate", help="identify the errors of a robot from measurements (or run the example)",
        description="Identify the error parameters of ROBOT.toml from DATA.csv, print a summary "
        "(cost, leg residuals, identifiability, accuracy before and after) and write the "
        "calibrated robot, the result and a report. Without arguments: the whole job on a "
        "built-in example, a simulated IWR with realistic noise, in ./iwr-example/.",
        epilog=f"The default method is 'de' (the paper's differential evolution, polished by "
        f"Levenberg-Marquardt) when this build has it, else 'lm'; set ${METHOD_ENV} to change it. "
        f"${QUICK_ENV}=1 makes the built-in example smaller (for tests).",
    )
    p.add_argument("robot", nargs="?", metavar="ROBOT.toml", help="the nominal robot")
    p.add_argument("data", nargs="?", metavar="DATA.csv", help="the measurements (docs/data.md)")
    p.add_argument("--method", default=None,
                   help="identification method: lm, de, crs2, bobyqa, ... as available "
                   "(default: $IWR_METHOD, else de if available, else lm)")
    p.add_argument("--budget", type=_positive_int, default=None, metavar="N",
                   help="largest number of objective evaluations (method's default if not given)")
    p.add_argument("--generations", type=_positive_int, default=None, metavar="G",
                   help="generations of an evolutionary method (de)")
    p.add_argument("--preset", default=None,
                   help="a method preset, e.g. 'paper' for the DE settings of Table 2")
    p.add_argument("--strategy", default=None, help="DE strategy, e.g. rand1bin, lshade")
    p.add_argument("--polish", action=argparse.BooleanOptionalAction, default=None,
                   help="refine a global method's result by Levenberg-Marquardt "
                   "(default: on for de)")
    p.add_argument("--workers", type=_positive_int, default=None, metavar="N",
                   help="threads of a parallel method (default: all cores)")
    p.add_argument("--seed", type=_nonneg_int, default=0,
                   help="seed of the validation split and of stochastic methods (default: "
                   "%(default)s; the example's data use seed 2024)")
    p.add_argument("--parameters", choices=("base", "all"), default="base",
                   help="identify the base parameters only, the unidentifiable ones held at "
                   "nominal, for a unique answer (base, the default), or all of them (all)")
    p.add_argument("--bounds", choices=("default", "paper"), default="default",
                   help="search bounds: +-0.5 mm and +-0.5 degree (default), or Table 2 literally "
                   "(+-0.5 for every parameter)")
    val = p.add_mutually_exclusive_group()
    val.add_argument("--validation-fraction", type=_fraction, default=0.2, metavar="F",
                     help="fraction of the poses held out (at random, by --seed) for the accuracy "
                     "figure (default: %(default)s; 0: none, the accuracy is then optimistic)")
    val.add_argument("--validation", metavar="VALID.csv",
                     help="validation poses from a separate file; all of DATA.csv identifies")
    p.add_argument("--out-dir", default=None, metavar="DIR",
                   help="folder of the calibrated robot, result and report (default: "
                   "iwr-calibration, or iwr-example for the example)")
    p.add_argument("--poses", type=_positive_int, default=None, metavar="N",
                   help=f"built-in example only: number of simulated poses (default "
                   f"{EXAMPLE_POSES}, {EXAMPLE_POSES_QUICK} with ${QUICK_ENV}=1)")
    p.add_argument("--no-plots", action="store_true", help="write the report without figures")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    _common(p)
    p.set_defaults(func=cmd_calibrate)

    # analyze -----------------------------------------------------------------------------------
    p = sub.add_parser(
        "analyze", help="which parameters the measurements can identify",
        description="Print the identifiability report of ROBOT.toml on the poses of DATA.csv "
        "(iwr.identifiability): the rank and conditioning of the identification Jacobian, "
        "observability indices, the unidentifiable combinations of parameters and a set of base "
        "parameters.",
    )
    p.add_argument("robot", metavar="ROBOT.toml", help="the nominal robot")
    p.add_argument("data", metavar="DATA.csv", help="the measurements")
    p.add_argument("--result", metavar="RESULT.json",
                   help="analyse at an identified error vector (default: the nominal robot)")
    _common(p)
    p.set_defaults(func=cmd_analyze)

    # plan --------------------------------------------------------------------------------------
    p = sub.add_parser(
        "plan", help="choose the poses to measure",
        description="Choose K poses to measure among candidate poses (from a file, or sampled "
        "at random in the workspace) that maximise an observability index of the base "
        "parameters (iwr.plan_poses: greedy, then exchanges).",
    )
    p.add_argument("robot", metavar="ROBOT.toml", help="the nominal robot")
    p.add_argument("--candidates", metavar="CANDIDATES.csv",
                   help="candidate poses (a measurement CSV; leg readings may be predicted ones)")
    p.add_argument("--n-candidates", type=_positive_int, default=1000, metavar="M",
                   help="without --candidates: candidates sampled in the workspace "
                   "(default: %(default)s)")
    p.add_argument("--poses", type=_positive_int, default=30, metavar="K",
                   help="number of poses to choose (default: %(default)s)")
    p.add_argument("--criterion", choices=("O1", "O2", "O3", "O4"), default="O1",
                   help="observability index to maximise (default: O1, D-optimal)")
    p.add_argument("--seed", type=_nonneg_int, default=0, help="random seed (default: 0)")
    p.add_argument("--out", default="plan.csv", metavar="FILE",
                   help="the chosen poses, as a measurement CSV (default: %(default)s)")
    _common(p)
    p.set_defaults(func=cmd_plan)

    # compare -----------------------------------------------------------------------------------
    # HOOK for `iwr compare` (issue 4, branch `baselines`): iwr/compare.py provides
    # add_compare_parser(subparsers) and run_compare(args). Wired automatically once that module
    # exists; a broken iwr.compare is an error, only its absence is tolerated.
    compare = _optional("iwr.compare")
    if compare is not None:
        cp = compare.add_compare_parser(sub)
        if not isinstance(cp, argparse.ArgumentParser):
            cp = sub.choices["compare"]
        if "--debug" not in cp._option_string_actions:
            _common(cp)
        cp.set_defaults(func=compare.run_compare)

    # study -------------------------------------------------------------------------------------
    # `iwr study` (issue 9): Monte-Carlo studies on Dask, from iwr/study (add_study_parser,
    # run_study); `python -m iwr.study` is the same command on its own.
    from .study import add_study_parser, run_study

    sp = add_study_parser(sub)
    if "--debug" not in sp._option_string_actions:
        _common(sp)
    sp.set_defaults(func=run_study)
    return parser


def _optional(module: str) -> Any:
    """``module`` if it exists, else None (an ImportError *inside* it is not swallowed)."""
    import importlib

    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name == module:
            return None
        raise


# -- helpers -------------------------------------------------------------------------------------


def _progress_enabled(args: argparse.Namespace) -> bool:
    return not getattr(args, "no_progress", False) and sys.stderr.isatty()


def _load_robot(path: str) -> Any:
    from .robot import Robot

    return Robot.from_toml(path)


def _load_data(path: str, robot: Any) -> Any:
    from .measurements import Measurements

    return Measurements.from_csv(path, robot=robot)


def _write_truth(path: Path, robot: Any, truth: np.ndarray, seed: int, noise: Any,
                 n_poses: int) -> None:
    from ._io import atomic_write_text

    doc = {
        "format": "iwr-true-errors",
        "version": 1,
        "robot": robot.name,
        "seed": seed,
        "n_poses": n_poses,
        "noise": dataclasses.asdict(noise),
        "parameter_names": robot.parameter_names,
        "errors": [float(v) for v in truth],
    }
    atomic_write_text(path, json.dumps(doc, indent=1) + "\n")


def _method_kwargs(method: str, args: argparse.Namespace) -> dict[str, Any]:
    """The method options given on the command line, under the names the method accepts."""
    from .identify import METHODS, identify

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
    return kwargs


class _EvalBar:
    """A tqdm counter of evaluations with the best cost so far, fed by a method's callback."""

    def __init__(self, desc: str, enabled: bool) -> None:
        from tqdm import tqdm

        self.best = math.inf
        self.bar = tqdm(desc=desc, unit=" eval", disable=not enabled, leave=False,
                        file=sys.stderr, dynamic_ncols=True)

    def __call__(self, x: Any, cost: float, *rest: Any) -> None:
        self.best = min(self.best, float(cost))
        self.bar.update(1)
        self.bar.set_postfix_str(f"best cost {self.best:.4g} mm^2", refresh=False)

    def close(self) -> None:
        self.bar.close()


# -- commands ------------------------------------------------------------------------------------


def cmd_simulate(args: argparse.Namespace) -> int:
    from .robot import Robot
    from .simulate import simulate

    robot = _load_robot(args.robot) if args.robot else Robot.default()
    data, truth = simulate(robot, n_poses=args.poses, seed=args.seed, noise=args.noise)
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    robot_path, data_path = out / args.robot_file, out / args.data_file
    truth_path = out / args.truth_file
    robot.to_toml(robot_path)
    data.to_csv(data_path)
    _write_truth(truth_path, robot, truth, args.seed, args.noise, len(data))
    noise = ", ".join(f"{k} {v:g}" for k, v in dataclasses.asdict(args.noise).items() if v)
    print(f"simulated {len(data)} poses of robot {robot.name!r} (seed {args.seed}, "
          f"noise: {noise or 'none'})")
    print(f"wrote {robot_path} (nominal robot), {data_path} (measurements), "
          f"{truth_path} (true errors)")
    print(f"next: iwr calibrate {robot_path} {data_path}")
    return EXIT_OK


def cmd_calibrate(args: argparse.Namespace) -> int:
    if args.robot is not None and args.data is None:
        raise UsageError("give both ROBOT.toml and DATA.csv, or neither (the built-in example)")
    method = args.method or default_method()
    kwargs = _method_kwargs(method, args)
    if args.robot is None:
        return _run_example(args, method, kwargs)
    if args.poses is not None:
        raise UsageError("--poses applies to the built-in example only, not to ROBOT.toml DATA.csv")
    robot = _load_robot(args.robot)
    data = _load_data(args.data, robot)
    validation = _load_data(args.validation, robot) if args.validation else None
    out = Path(args.out_dir or "iwr-calibration")
    _calibrate(robot, data, validation, args, method, kwargs, out,
               robot_name=str(args.robot), data_name=str(args.data))
    return EXIT_OK


def _run_example(args: argparse.Namespace, method: str, kwargs: dict[str, Any]) -> int:
    from .robot import Robot
    from .simulate import Noise, simulate

    if args.validation:
        raise UsageError("--validation needs ROBOT.toml and DATA.csv")
    quick = os.environ.get(QUICK_ENV, "").strip() not in ("", "0")
    n = args.poses or (EXAMPLE_POSES_QUICK if quick else EXAMPLE_POSES)
    if quick and method == "de" and args.generations is None and args.budget is None:
        kwargs = {**kwargs, "generations": EXAMPLE_GENERATIONS_QUICK}
    out = Path(args.out_dir or EXAMPLE_DIR)
    out.mkdir(parents=True, exist_ok=True)
    robot = Robot.default()
    noise = Noise.realistic()
    data, truth = simulate(robot, n_poses=n, seed=EXAMPLE_SEED, noise=noise)
    robot_path, data_path = out / "robot.toml", out / "measurements.csv"
    robot.to_toml(robot_path)
    data.to_csv(data_path)
    _write_truth(out / "true_errors.json", robot, truth, EXAMPLE_SEED, noise, n)
    print(
        f"built-in example: the IWR of docs/model.md with random errors (+-0.5 mm, +-0.5 deg), "
        f"{n} random poses (seed {EXAMPLE_SEED}) and realistic noise (iwr.Noise.realistic(): "
        "leg sensors 2 um, carriage joints 5 um and 5 urad, laser tracker 20 um and 20 urad)"
    )
    print(f"inputs: {robot_path}, {data_path}, {out / 'true_errors.json'} (the truth)")
    print()
    robot = _load_robot(str(robot_path))
    data = _load_data(str(data_path), robot)
    _calibrate(robot, data, None, args, method, kwargs, out, robot_name=str(robot_path),
               data_name=str(data_path), truth=truth)
    print(f"\nthe same on your own files: iwr calibrate ROBOT.toml DATA.csv (docs/data.md); "
          f"here: iwr calibrate {robot_path} {data_path}")
    return EXIT_OK


def _split(data: Any, fraction: float, seed: int) -> tuple[Any, Any]:
    n = len(data)
    n_val = int(round(fraction * n))
    if fraction > 0 and n_val == 0:
        n_val = 1
    if n - n_val < 1:
        raise CommandError(f"--validation-fraction {fraction}: leaves no pose for identification "
                           f"out of {n}")
    order = np.random.default_rng(seed).permutation(n)
    val, ident = np.sort(order[:n_val]), np.sort(order[n_val:])
    return data.subset(ident), data.subset(val)


def _calibrate(robot: Any, data: Any, validation: Any, args: argparse.Namespace, method: str,
               kwargs: dict[str, Any], out: Path, *, robot_name: str, data_name: str,
               truth: np.ndarray | None = None) -> Any:
    from .accuracy import accuracy
    from .identifiability import identifiability, parameter_error
    from .identify import identify
    from .report import Calibration
    from .uncertainty import uncertainty

    if validation is not None:
        ident, val, held_out = data, validation, True
    elif args.validation_fraction > 0:
        ident, val = _split(data, args.validation_fraction, args.seed)
        held_out = True
    else:
        ident, val, held_out = data, data, False
    notes: list[str] = []
    if args.parameters == "base":
        # Identify the base parameters only, the others held at nominal: a unique answer whose
        # values and standard deviations mean something.
        kwargs = {**kwargs, "active": identifiability(robot, ident).active}
    show = _progress_enabled(args)
    bar = None
    if method == "lm":  # LM reports no progress itself: count its evaluations
        bar = _EvalBar(f"identifying ({method})", show)
        kwargs = {**kwargs, "callback": bar}
    try:
        result = identify(robot, ident, method=method, bounds=args.bounds, seed=args.seed,
                          progress=show, **kwargs)
    finally:
        if bar is not None:
            bar.close()
    report = identifiability(robot, ident, result.x)
    try:
        active = result["active"] if args.parameters == "base" else report
        unc = uncertainty(robot, ident, result.x, active=active)
    except ValueError as exc:
        unc = None
        notes.append(f"note: no standard deviations: {_one_line(exc)}")
    acc = accuracy(robot, val, result.x)
    truth_acc = perr = None
    if truth is not None:
        truth_acc = accuracy(robot, val, truth)
        perr = parameter_error(robot, ident, result.x, truth)
    cal = Calibration(
        robot=robot, identification=ident, validation=val, held_out=held_out, result=result,
        accuracy=acc, data_name=data_name, robot_name=robot_name, identifiability=report,
        uncertainty=unc, parameter_error=perr, truth_accuracy=truth_acc, notes=notes,
    )
    print(cal.summary())
    written = cal.write(out, plots=not args.no_plots)
    print(f"\nwrote {out}/: " + ", ".join(p.name for p in written))
    return cal


def cmd_analyze(args: argparse.Namespace) -> int:
    from .identifiability import identifiability
    from .result import load_result

    robot = _load_robot(args.robot)
    data = _load_data(args.data, robot)
    x = None
    if args.result:
        x = np.asarray(load_result(args.result).x, dtype=float)
        if x.shape != (robot.n_params,):
            raise CommandError(f"{args.result}: {x.size} parameters, but robot {robot.name!r} "
                               f"has {robot.n_params}")
    print(identifiability(robot, data, x))
    return EXIT_OK


def cmd_plan(args: argparse.Namespace) -> int:
    from .measurements import Measurements
    from .planning import plan_poses
    from .simulate import sample_poses

    robot = _load_robot(args.robot)
    if args.candidates:
        cand = Measurements.from_csv(args.candidates, robot=robot)
        source = str(args.candidates)
    else:
        rng = np.random.default_rng(args.seed)
        q, poses, legs = sample_poses(robot, args.n_candidates, rng)
        cand = Measurements(q, poses, legs, joint_types=robot.joint_types)
        source = f"{args.n_candidates} reachable poses sampled at random (seed {args.seed})"
    if args.poses > len(cand):
        raise CommandError(f"--poses {args.poses}: more than the {len(cand)} candidates")
    try:
        plan = plan_poses(robot, cand, args.poses, criterion=args.criterion, seed=args.seed)
    except ValueError as exc:
        msg = str(exc)
        raise CommandError("--poses" + msg[7:] if msg.startswith("n_poses:") else msg) from None
    plan.measurements.to_csv(args.out)
    print(f"candidates: {source}")
    print(plan)
    print(f"wrote {args.out}: the chosen poses (joint readings and platform poses; its leg "
          "readings are the candidates', to be replaced by the readings measured there)")
    return EXIT_OK


# -- entry point ---------------------------------------------------------------------------------


def _one_line(exc: BaseException) -> str:
    msg = str(exc) if str(exc) else type(exc).__name__
    if isinstance(exc, KeyError):  # str(KeyError) is the quoted key
        msg = f"missing key {msg}"
    return " ".join(line.strip() for line in msg.splitlines() if line.strip())


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code (``iwr`` script: ``iwr.cli:main``)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    handlers: list[tuple[type[BaseException] | tuple[type[BaseException], ...], int, str]] = [
        (UsageError, EXIT_USAGE, ""),
        ((CommandError, ValueError, RuntimeError, OSError, ArithmeticError), EXIT_ERROR, ""),
    ]
    try:
        args = build_parser().parse_args(argv)
        func: Callable[[argparse.Namespace], int | None] = args.func
        code = func(args)
        return EXIT_OK if code is None else int(code)
    except KeyboardInterrupt:
        print("\niwr: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as exc:  # one line, never a traceback unless --debug
        if debug:
            traceback.print_exc()
        code, prefix = EXIT_ERROR, "internal error: " + type(exc).__name__ + ": "
        for types, c, p in handlers:
            if isinstance(exc, types):
                code, prefix = c, p
                break
        msg = _one_line(exc)
        if isinstance(exc, UsageError):
            print(f"iwr: error: {msg}", file=sys.stderr)
        else:
            hint = "" if debug or not prefix else " (run with --debug for the traceback)"
            print(f"iwr: error: {prefix}{msg}{hint}", file=sys.stderr)
        return code


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
