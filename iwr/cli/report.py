"""``iwr report RUN.json ROBOT.toml DATA.csv``: a result of ``iwr-calibrate`` (or of
``iwr calibrate``, or ``IdentificationResult.save``) turned into the calibrated robot and the
report, as ``iwr calibrate`` writes them."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from ._base import (
    EXIT_OK,
    CommandError,
    UsageError,
    add_common,
    check_output,
    load_data,
    load_robot,
    one_line,
    read_data,
)
from .tracker import add_arguments as add_tracker_arguments

DEFAULT_OUT = "iwr-report"


def add_parser(sub: Any) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "report",
        help="turn a result (iwr-calibrate's RUN.json) into a calibrated robot and a report",
        description="Read an identification result (the JSON file of iwr-calibrate, or "
        "result.json of iwr calibrate) with the robot and the measurements it was identified "
        "from, and write what iwr calibrate writes: calibrated.toml, report.html "
        "(self-contained), report.md with its figures, summary.json and a copy of the result.",
    )
    p.add_argument("run", metavar="RUN.json", help="the identification result")
    p.add_argument("robot", metavar="ROBOT.toml", help="the nominal robot it was identified for")
    p.add_argument("data", metavar="DATA.csv", help="the measurements it was identified from")
    p.add_argument("--validation", metavar="VALID.csv",
                   help="held-out poses for the accuracy figure (default: DATA.csv itself, an "
                   "optimistic figure)")
    add_tracker_arguments(p)  # --readings: tracker data as a long table (docs/tracker.md)
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help="output folder (created if needed; default: %(default)s)")
    p.add_argument("--no-plots", action="store_true", help="write the report without figures")
    add_common(p)
    p.set_defaults(func=cmd_report)
    return p


def data_fingerprint(robot: Any, data: Any) -> str:
    """The fingerprint of ``data`` that ``iwr-calibrate``'s problem file and result record, for
    every kind of data (:meth:`iwr.kinds.MeasurementKind.fingerprint`), as 16 hex digits."""
    from ..kinds import of

    return of(data).fingerprint(robot, data)


def _legacy_tracker_fingerprint(data: Any) -> str:
    """The fingerprint that ``iwr calibrate`` recorded for tracker data before there was one for
    every kind (``"tracker-"`` and 16 hex digits of a SHA-256): results written then stay
    checkable."""
    import hashlib

    h = hashlib.sha256(str(data.joint_types).encode())
    for arr in (data.q, data.legs, data.points if data.points is not None else data.probe):
        h.update(repr(arr.shape).encode())
        h.update(np.ascontiguousarray(arr, dtype="<f8").tobytes())
    return "tracker-" + h.hexdigest()[:16]


def _check_data(args: argparse.Namespace, result: Any, robot: Any, data: Any) -> str:
    """Refuse a DATA.csv that is not the one the result was identified from (exit 2); a note
    when the result records no fingerprint (a result saved by the API)."""
    settings = dict(result.get("settings") or {})
    expected = settings.get("data_fingerprint")
    if not expected:
        return (f"note: {args.run} records no fingerprint of its data, so {args.data} could not "
                "be checked to be the data it was identified from")
    found = (_legacy_tracker_fingerprint(data) if str(expected).startswith("tracker-")
             else data_fingerprint(robot, data))
    if str(expected) != found:
        made_from = (settings.get("sources") or {}).get("data") or settings.get("data_file")
        raise UsageError(
            f"{args.data} is not the data {args.run} was identified from: its fingerprint is "
            f"{found}, the result's {expected}"
            + (f" (made from {made_from})" if made_from else "")
            + "; give the data file of the run", "iwr report")
    return ""


def cmd_report(args: argparse.Namespace) -> int:
    from ..accuracy import accuracy
    from ..identifiability import identifiability
    from ..methods import load_result
    from ..reporting.calibration import OUTPUT_FILES, Calibration
    from ..reporting.html import provenance

    check_output(args.out, "--out", files=OUTPUT_FILES, prog="iwr report", inputs=[
        args.run, args.robot, args.data, args.validation, args.readings])
    result = load_result(args.run)
    robot = load_robot(args.robot)
    if robot.tracker is not None:
        return _report_tracker(args, result, robot)
    if args.readings is not None:
        raise UsageError(f"--readings: only for a robot with a [tracker] table; {args.robot} has "
                         "none (docs/tracker.md)", "iwr report")
    data = load_data(args.data, robot)
    x = np.asarray(result.x, dtype=float)
    if x.shape != (robot.n_params,):
        raise CommandError(f"{args.run}: {x.size} parameters, but robot {robot.name!r} "
                           f"({args.robot}) has {robot.n_params}")
    names = list(result.get("parameter_names") or [])
    if names and names != robot.parameter_names:
        first = next(a for a, b in zip(names, robot.parameter_names, strict=True) if a != b)
        raise CommandError(f"{args.run}: its parameters are not those of robot {robot.name!r} "
                           f"({args.robot}): first difference {first!r}")
    note = _check_data(args, result, robot, data)
    validation = load_data(args.validation, robot) if args.validation else None
    val = validation if validation is not None else data
    notes: list[str] = [note] if note else []
    rep = identifiability(robot, data, x)
    unc = _uncertainty(robot, data, x, result, rep, notes)
    if unc is not None and result.get("method") == "efficient":
        # A result file does not keep the estimator's covariance: say whose these are.
        notes.append("note: the standard deviations are eq. (10)'s first-order ones at the "
                     "result, not the efficient estimator's covariance (which `iwr calibrate` "
                     "reports; a result file does not keep it); they can differ by up to 2x")
    inputs = {"result": str(args.run), "robot": str(args.robot), "data": str(args.data)}
    if args.validation:
        inputs["validation"] = str(args.validation)
    settings = {"method": result.get("method", ""), **dict(result.get("settings", {}) or {})}
    cal = Calibration(
        robot=robot, identification=data, validation=val, held_out=validation is not None,
        result=result, accuracy=accuracy(robot, val, x), data_name=str(args.data),
        robot_name=str(args.robot), identifiability=rep, uncertainty=unc, notes=notes,
        settings=settings, provenance=provenance(inputs),
    )
    print(cal.summary())
    out = Path(args.out)
    written = cal.write(out, plots=not args.no_plots)
    print(f"\nwrote {out}/: " + ", ".join(p.name for p in written))
    return EXIT_OK


def _uncertainty(robot: Any, data: Any, x: Any, result: Any, report: Any,
                 notes: list[str]) -> Any:
    """eq. (10)'s (or the point objective's) standard deviations over the result's active
    parameters (``report``'s when it has none); None, with a note, where they do not exist."""
    from ..uncertainty import uncertainty

    active = result.get("active")
    try:
        return uncertainty(robot, data, x, active=report if active is None else active)
    except ValueError as exc:
        notes.append(f"note: no standard deviations: {one_line(exc)}")
        return None


def _report_tracker(args: argparse.Namespace, result: Any, robot: Any) -> int:
    """``iwr report`` for a robot with a ``[tracker]`` table: the report of ``iwr calibrate`` on
    tracker data (:class:`iwr.reporting.calibration.TrackerCalibration`)."""
    from ..accuracy import accuracy
    from ..identifiability import identifiability
    from ..reporting.calibration import TrackerCalibration
    from ..reporting.html import provenance
    from ..tracker.registration import RegistrationError, guess_registration
    from .tracker import target_format

    data = read_data(args.data, robot, args.readings, targets=target_format(args),
                     prog="iwr report")
    names = robot.parameter_names + robot.tracker.parameter_names
    x = np.asarray(result.x, dtype=float)
    if x.shape != (len(names),):
        raise CommandError(f"{args.run}: {x.size} parameters, but robot {robot.name!r} "
                           f"({args.robot}) with its tracker setup has {len(names)}")
    saved = list(result.get("parameter_names") or [])
    if saved and saved != names:
        first = next(a for a, b in zip(saved, names, strict=True) if a != b)
        raise CommandError(f"{args.run}: its parameters are not those of robot {robot.name!r} "
                           f"({args.robot}) and its tracker setup: first difference {first!r}")
    note = _check_data(args, result, robot, data)
    validation = read_data(args.validation, robot, prog="iwr report") if args.validation else None
    notes: list[str] = [note] if note else []
    ns = identifiability(robot, data)
    unc = _uncertainty(robot, data, x, result, ns, notes)
    try:
        guess = guess_registration(robot, robot.tracker, data)
    except RegistrationError:
        guess = None
    inputs = {"result": str(args.run), "robot": str(args.robot), "data": str(args.data)}
    for key in ("readings", "validation"):
        if getattr(args, key):
            inputs[key] = str(getattr(args, key))
    val = validation if validation is not None else data
    cal = TrackerCalibration(
        robot=robot, identification=data, validation=val, held_out=validation is not None,
        result=result, accuracy=accuracy(robot, val, x), data_name=str(args.data),
        robot_name=str(args.robot), identifiability=ns, uncertainty=unc, notes=notes,
        settings={"method": result.get("method", ""), **dict(result.get("settings", {}) or {})},
        provenance=provenance(inputs), guess=guess, readings_name=str(args.readings or ""))
    print(cal.summary())
    out = Path(args.out)
    written = cal.write(out, plots=not args.no_plots)
    print(f"\nwrote {out}/: " + ", ".join(p.name for p in written))
    return EXIT_OK
