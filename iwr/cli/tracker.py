"""``iwr calibrate`` and ``iwr simulate`` for a robot with a laser tracker (docs/tracker.md):
the robot's TOML has a ``[tracker]`` table and the data are points (or probe poses) in the
tracker's frame."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np

from ._base import (
    EXIT_INTERRUPTED,
    EXIT_OK,
    CommandError,
    UsageError,
    progress_enabled,
    read_data,
    run_settings,
    validation_split,
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """``--readings``: the robot's log of joint and leg readings beside a long table of points."""
    p.add_argument("--readings", default=None, metavar="READINGS.csv",
                   help="tracker data as a long table of points (DATA: pose, reflector, x_mm, "
                   "y_mm, z_mm): the robot's log of readings (pose, q1_mm, ..., s1_mm .. s6_mm) "
                   "joined to it by pose (docs/tracker.md)")
    p.add_argument("--target-names", default=None, metavar="PATTERN",
                   help="DATA is a target list exported by tracker software (Collection Group "
                   "Target x y z ..., docs/data.md): the pattern of its target names, with "
                   "{pose} and {reflector} (default P{pose}_R{reflector}; Group::Target or "
                   "Collection::Group::Target patterns match those names)")
    p.add_argument("--target-columns", default=None, metavar="COLUMNS",
                   help="the columns of the target list after its three names, space "
                   "separated, among x y z u ux uy uz time rms - (default 'x y z'; u or ux uy "
                   "uz: the points' standard uncertainties)")
    p.add_argument("--target-units", default=None, metavar="UNIT",
                   help="the target list's length unit (mm, cm, m, um, in, ft), when no '// "
                   "Units: ...' comment line states it")


def target_format(args: argparse.Namespace) -> Any:
    """The :class:`iwr.tracker.sa_export.TargetFormat` of ``--target-*``, or None when none is
    given (a target list is then read with the defaults)."""
    from ..tracker.sa_export import TargetFormat

    given = {k: getattr(args, f"target_{k}", None) for k in ("names", "columns", "units")}
    if all(v is None for v in given.values()):
        return None
    kw = {k: v for k, v in given.items() if v is not None}
    if "columns" in kw:
        kw["columns"] = tuple(kw["columns"].replace(",", " ").split())
    try:
        return TargetFormat(**kw)
    except ValueError as exc:
        raise UsageError(str(exc).replace("target ", "--target-", 1)) from None


def refuse_tracker_data(args: argparse.Namespace) -> None:
    """For a robot without a [tracker] table: refuse --readings and tracker data files with a
    message that says what is missing."""
    from ..tracker.files import tracker_file_format

    if args.readings is not None:
        raise UsageError(f"--readings: only for a robot with a [tracker] table; {args.robot} has "
                         "none (docs/tracker.md)")
    if target_format(args) is not None:
        raise UsageError(f"--target-names, --target-columns, --target-units: only for a robot "
                         f"with a [tracker] table; {args.robot} has none (docs/tracker.md)")
    what = tracker_file_format(args.data)
    if what is not None:
        raise UsageError(f"{args.data}: laser-tracker data ({what}), but {args.robot} has "
                         "no [tracker] table describing the setup (registration, reflectors or "
                         "probe): add one (docs/tracker.md)")


def tracker_noise_of(noise: Any) -> Any:
    """What ``--noise`` means for a robot with a tracker, in ``iwr simulate`` and ``iwr
    calibrate`` alike: the reading noise of the :class:`iwr.Noise` (its ``position`` and
    ``orientation``, a pose measured in {0}, do not apply) and ``TrackerNoise.leica()`` (none
    when the whole noise is zero); ``"estimate"`` stays."""
    from ..simulate import Noise
    from ..tracker.simulate import TrackerNoise

    if isinstance(noise, (str, tuple)):  # a tuple: the robot file's (Noise, TrackerNoise)
        return noise
    readings = dataclasses.replace(noise, position=0.0, orientation=0.0)
    return readings, (TrackerNoise.none() if noise == Noise() else TrackerNoise.leica())


def calibrate_tracker(args: argparse.Namespace, robot: Any, method: str,
                      kwargs: dict[str, Any]) -> int:
    """Identify the robot, the registration and the reflector (or probe) offsets from tracker
    data; validate on held-out poses (point residuals); write the calibrated robot (with its
    calibrated tracker setup), the result and the report (HTML and Markdown) as for leg data."""
    from ..accuracy import accuracy
    from ..gross_errors import screen as screen_gross_errors
    from ..identifiability import identifiability
    from ..methods import identify
    from ..reporting.calibration import TrackerCalibration
    from ..reporting.html import provenance
    from ..tracker.registration import guess_registration

    if args.poses is not None:
        raise CommandError("--poses applies to the built-in example only")
    if (kwargs.get("noise") is not None and method != "efficient"
            and getattr(args, "noise_from", "--noise") == "--noise"):
        # Checked before the data are read: iwr.identify refuses it too, in the API's words. (A
        # noise model from the robot file is set aside below, with a note.)
        raise UsageError(f"--method {method} with --noise: on laser-tracker data only the "
                         "efficient estimator weighs the instruments by a noise model (the other "
                         "methods minimise the unweighted point residuals); use --method "
                         "efficient (the default with --noise) or leave --noise out")
    data = read_data(args.data, robot, getattr(args, "readings", None),
                     targets=target_format(args))
    if data.point_sigma is not None:
        print(f"{args.data}: each point's standard uncertainties, as the file gives them, weigh "
              "the points in the efficient estimator (the tracker's noise model is not used); "
              "other methods do not weigh the points")
    if args.validation:
        val = read_data(args.validation, robot)
        ident, held_out = data, True
    elif args.validation_fraction > 0:
        ident, val = validation_split(data, args.validation_fraction, args.seed)
        held_out = True
    else:
        ident = val = data
        held_out = False
    kwargs = {k: v for k, v in kwargs.items() if k not in ("callback",)}
    if method != "efficient" and "noise" in kwargs and getattr(args, "noise_from", None) not in (
            None, "--noise"):
        # The other methods take no noise model on tracker data: the file's is the estimator's,
        # not a reason to refuse the method named (--noise with them is refused, as it says).
        print(f"noise model of {args.noise_from}: not used by method {method} on tracker data "
              "(only by the efficient estimator)")
        kwargs.pop("noise")
        args.noise_from = None
    if args.parameters == "base":
        kwargs["active"] = "base"
    setup = robot.tracker
    print(f"tracker data: {len(data)} poses, {setup.kind}"
          + (f" (K = {setup.n_reflectors})" if setup.kind == "points" else "")
          + f"; identifying {robot.n_params} robot + {setup.n_params} setup parameters with "
          f"{method} ({len(ident)} poses), from the nominal robot and the closed-form "
          "registration guess", flush=True)
    if "noise" in kwargs:
        from .robot_noise import describe

        print(f"noise model: {describe(kwargs['noise'])} (from "
              f"{getattr(args, 'noise_from', None) or '--noise'})")
    guess = guess_registration(robot, setup, ident)
    print(str(guess), flush=True)
    from ..simulate import Noise

    given = getattr(args, "noise", None)
    if isinstance(kwargs.get("noise"), tuple) and getattr(args, "noise_from", None) == "--noise":
        # A position or orientation sigma given for a pose measured in {0} has no reading here.
        dropped = [f"{k}={getattr(given, k):g}" for k in ("position", "orientation")
                   if getattr(given, k, 0.0)] if given != Noise.realistic() else []
        if dropped:
            print(f"--noise {', '.join(dropped)}: a pose measured in {{0}}, not used with tracker "
                  "data", flush=True)
    result = identify(robot, ident, method=method, bounds=args.bounds, seed=args.seed,
                      progress=progress_enabled(args), **kwargs)
    # Issue 22: gross errors in every pose, held-out ones too, with or without a noise model.
    result, ident, val = screen_gross_errors(robot, ident, val, result, kwargs.get("noise"),
                                             held_out=held_out, bounds=args.bounds)
    notes: list[str] = []
    if data.point_sigma is not None and method == "efficient":
        notes.append(f"note: the points are weighted by their own uncertainties from {args.data}, "
                     "not by the tracker noise model named above (docs/data.md)")
    # At the start, as identify(active="base") chose the parameters it holds: the report's
    # "held" and "null direction" then agree with what was done.
    ns = identifiability(robot, ident)
    unc = None
    try:
        from ..uncertainty import Uncertainty, uncertainty

        # The efficient estimator's own covariance when it has one (as for leg data): the
        # unweighted point objective's first-order covariance is not the estimate's.
        unc = Uncertainty.from_result(result)
        if unc is None:
            unc = uncertainty(robot, ident, result.x, active=result["active"])
    except (ValueError, TypeError) as exc:
        notes.append(f"note: no standard deviations: {' '.join(str(exc).split())}")
    predicted = None
    if result.get("covariance") is not None and not result.interrupted:
        # On the poses the measured figures are on (result["predicted"] is on the identification
        # poses), as for leg data.
        from ..tracker.estimation import tracker_predicted_accuracy

        try:
            predicted = tracker_predicted_accuracy(robot, result.x, result["covariance"],
                                                   result["active"], val.q, val.legs,
                                                   seed=args.seed)
        except (ValueError, np.linalg.LinAlgError) as exc:
            notes.append(f"note: no predicted accuracy: {' '.join(str(exc).split())}")
    # What `iwr report` checks its DATA.csv against, as for leg data.
    from .report import data_fingerprint

    result["settings"] = {**dict(result.get("settings") or {}), "data_file": str(args.data),
                          "data_fingerprint": data_fingerprint(robot, data)}
    inputs = {"robot": str(args.robot), "data": str(args.data)}
    if args.readings:
        inputs["readings"] = str(args.readings)
    if args.validation:
        inputs["validation"] = str(args.validation)
    settings = run_settings(args, method, kwargs)
    cal = TrackerCalibration(
        robot=robot, identification=ident, validation=val, held_out=held_out, result=result,
        accuracy=accuracy(robot, val, result.x), data_name=str(args.data),
        robot_name=str(args.robot), identifiability=ns, uncertainty=unc, notes=notes,
        settings=settings, provenance=provenance(inputs), guess=guess,
        readings_name=str(args.readings or ""), predicted=predicted)
    print(cal.summary())
    out = Path(args.out)  # checked before the work (calibrate._out_folder)
    written = cal.write(out, plots=not args.no_plots)
    print(f"\nwrote {out}/: " + ", ".join(p.name for p in written))
    if result.interrupted:
        return EXIT_INTERRUPTED
    from .calibrate import _exit_code  # exit 3 when the model does not fit, as for leg data

    return _exit_code(cal)


def simulate_tracker_files(args: argparse.Namespace, robot: Any) -> int:
    """``iwr simulate --robot ROBOT.toml`` with a ``[tracker]`` table: the wide CSV of points (or
    probe poses), the long pair (points + readings) for point data, and the true errors."""
    from .._io import atomic_write_text
    from ..simulate import simulate
    from ..tracker.files import write_tracker_long, write_tracker_wide

    noise = tracker_noise_of(args.noise)
    readings_noise, tracker_noise = noise
    data, truth = simulate(robot, args.poses, seed=args.seed, noise=noise)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    robot_path, data_path = out / args.robot_file, out / args.data_file
    robot.to_toml(robot_path)
    write_tracker_wide(data_path, robot.tracker, data)
    written = [f"{data_path} (wide: readings and points)"]
    if robot.tracker.kind == "points":
        stem = data_path.with_suffix("")
        pts, rd = Path(f"{stem}_long.csv"), Path(f"{stem}_readings.csv")
        write_tracker_long(pts, rd, robot.tracker, data)
        written.append(f"{pts} + {rd} (the same as a long table of points and a log of readings)")
    names = robot.parameter_names + robot.tracker.parameter_names
    doc = {"format": "iwr-true-errors", "version": 1, "robot": robot.name, "seed": args.seed,
           "n_poses": len(data), "noise": dataclasses.asdict(readings_noise),
           "tracker_noise": dataclasses.asdict(tracker_noise), "parameter_names": names,
           "errors": [float(v) for v in truth]}
    truth_path = out / args.truth_file
    atomic_write_text(truth_path, json.dumps(doc, indent=1) + "\n")
    print(f"simulated {len(data)} poses of robot {robot.name!r} measured by a laser tracker "
          f"({robot.tracker.kind}; seed {args.seed}; tracker noise "
          + ("none" if tracker_noise.is_zero else f"{tracker_noise} from {args.noise_from}"
             if getattr(args, "noise_from", None) else "TrackerNoise.leica()") + ")")
    print(f"wrote {robot_path} (nominal robot with its [tracker] table), "
          + ", ".join(written) + f", {truth_path} (true errors)")
    print(f"next: iwr calibrate {robot_path} {data_path}")
    return EXIT_OK
