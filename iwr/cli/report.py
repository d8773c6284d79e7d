"""``iwr report RUN.json ROBOT.toml DATA.csv``: a result of ``iwr-calibrate`` (or of
``iwr calibrate``, or ``IdentificationResult.save``) turned into the calibrated robot and the
report, as ``iwr calibrate`` writes them."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from ._base import (
    CommandError,
    UsageError,
    add_common,
    check_effect_inputs,
    check_frame,
    check_output,
    check_validation_file,
    load_robot,
    not_held_out,
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
        "(self-contained), report.md with its figures, summary.json and a copy of the result. "
        "Exit status as iwr calibrate's verdict: 3 when the model does not fit the data, 5 when "
        "the data cannot calibrate the robot (the files are written either way).",
    )
    p.add_argument("run", metavar="RUN.json", help="the identification result")
    p.add_argument("robot", metavar="ROBOT.toml", help="the nominal robot it was identified for")
    p.add_argument("data", metavar="DATA.csv", help="the measurements it was identified from")
    p.add_argument("--validation", metavar="VALID.csv",
                   help="the run's held-out poses, when it held out a file of its own (default: "
                   "the split an iwr calibrate run records, made again; else DATA.csv itself, "
                   "an optimistic figure)")
    add_tracker_arguments(p)  # --readings: tracker data as a long table (docs/tracker.md)
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help="output folder (created if needed; default: %(default)s)")
    p.add_argument("--polish", action="store_true",
                   help="refine the result by Levenberg-Marquardt from its point first, as "
                        "iwr.identify(method='de') polishes (iwr-calibrate's DE run stops at "
                        "its generation limit, 'not converged', which iwr legs refuses)")
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
    settings = dict(result.settings)
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


def _check_robot(args: argparse.Namespace, result: Any, robot: Any) -> str:
    """Refuse a ROBOT.toml that is not the robot the result was identified for (exit 2),
    naming what differs (:func:`iwr.robot_fingerprint.differences`); a warning when the result
    records no model of its robot (written by an older iwr, or saved by the API)."""
    from collections.abc import Mapping

    from ..robot_fingerprint import differences

    settings = dict(result.settings)
    recorded = settings.get("robot_model")
    if not isinstance(recorded, Mapping) or not recorded.get("fingerprint"):
        return (f"warning: {args.run} records no model of the robot it was identified for "
                f"(written by an older iwr, or saved by the API), so {args.robot} could not be "
                "checked to be that robot: if it is another one, the figures of this report are "
                "wrong")
    found = differences(recorded, robot)
    if found:
        made_from = (settings.get("sources") or {}).get("robot") or settings.get("robot_file")
        prov = getattr(robot, "provenance", None) or {}
        what = "give the robot file of the run"
        if prov.get("method") is not None:  # a calibration's output, e.g. calibrated.toml
            what = (f"{args.robot} is a calibrated robot ([provenance] method "
                    f"{prov['method']!r}" + (f", from {prov['robot']}" if prov.get("robot")
                                             else "") + "): iwr report takes the nominal "
                    "robot the run identified the errors of"
                    + (f", {made_from}" if made_from else ""))
        raise UsageError(
            f"{args.robot} is not the robot {args.run} was identified for"
            + (f" (made from {made_from})" if made_from else "") + ": "
            + "; ".join(found) + "; " + what, "iwr report")
    return ""


def check_result_file(path: Any, result: Any, robot_path: Any, robot: Any, kind: Any
                      ) -> np.ndarray:
    """The error vector of ``result`` (read from ``path``), checked to be one of ``robot``
    (read from ``robot_path``) on ``kind``'s data (:func:`iwr.calibration.check_result`: its
    length, its parameters' names and order, finite values, a calibrated robot within the
    physical limits); else CommandError (exit 1) naming both files and the entry at fault. The
    one check of ``iwr report`` and ``iwr analyze --result``."""
    from ..calibration import check_result

    try:
        return check_result(robot, kind, result)
    except ValueError as exc:
        raise CommandError(f"{path}: {one_line(exc)} ({robot_path})") from None


def _shown_settings(result: Any) -> dict[str, Any]:
    """The result's settings as the report shows them: the robot's model by its fingerprint."""
    settings = {"method": result.method, **dict(result.settings)}
    model = settings.get("robot_model")
    if isinstance(model, dict) and "fingerprint" in model:
        settings["robot_model"] = model["fingerprint"]
    return settings


def cmd_report(args: argparse.Namespace) -> int:
    from ..calibration import LeftOutError, NotHeldOutError, from_result
    from ..kinds import for_robot
    from ..methods import load_result
    from ..reporting.calibration import OUTPUT_FILES, render
    from ..reporting.html import provenance
    from .calibrate import _exit_code
    from .tracker import target_format

    check_output(args.out, "--out", files=OUTPUT_FILES, prog="iwr report", inputs=[
        args.run, args.robot, args.data, args.validation, args.readings])
    result = load_result(args.run)
    robot = load_robot(args.robot)
    kind = for_robot(robot)
    if not kind.report:
        raise UsageError(f"{args.robot}: {kind.name} data ({kind.description}): no report for "
                         "them yet (docs/kinds.md)", "iwr report")
    data = read_data(args.data, robot, args.readings, targets=target_format(args),
                     prog="iwr report", effects=False)
    # The robot first: the data's fingerprint depends on its set-up (the tracker's points), and
    # the columns the data need on the robot's effects (another robot's effects: its message).
    warning = _check_robot(args, result, robot)
    check_result_file(args.run, result, args.robot, robot, kind)  # as iwr analyze --result
    check_effect_inputs(robot, data, args.data)
    note = _check_data(args, result, robot, data)
    check_frame(kind, robot, data, args.data)
    instead = ("give the run's validation file, or leave --validation out: the run's own split "
               "is made again")
    check_validation_file(args.validation, args.data, "iwr report", instead)
    validation = read_data(args.validation, robot, prog="iwr report") if args.validation else None
    if validation is not None:
        check_frame(kind, robot, validation, args.validation)
    inputs = {"result": str(args.run), "robot": str(args.robot), "data": str(args.data)}
    for key in ("readings", "validation"):
        if getattr(args, key):
            inputs[key] = str(getattr(args, key))
    if args.polish:
        from ..calibration import polish_refusal

        refusal = polish_refusal(result)
        if refusal:
            raise CommandError(f"{args.run}: --polish: {refusal}")
    try:
        cal = from_result(
            robot, data, result, validation=validation, data_name=str(args.data),
            polish=args.polish,
            robot_name=str(args.robot),
            sources={"readings": str(args.readings)} if args.readings else None,
            settings=_shown_settings(result),
            provenance=provenance(inputs))
    except NotHeldOutError as exc:  # every --validation pose is in DATA
        raise not_held_out(args.validation, args.data, "iwr report", instead,
                           exc.shared) from None
    except LeftOutError as exc:  # a pose the run left out is not in DATA: other data
        raise UsageError(f"{args.data}: {one_line(exc)} ({args.run})", "iwr report") from None
    except ValueError as exc:  # the result's parameters are not this robot's
        raise CommandError(f"{args.run}: {one_line(exc)} ({args.robot})") from None
    if args.polish:
        cal.settings = _shown_settings(cal.result)  # the polished result's (polish: True)
        done = cal.result.settings["polish_result"]
        print(f"polished by Levenberg-Marquardt: {cal.result.status} (cost "
              f"{done['fun_before']:.7g} -> {cal.result.fun:.7g})", flush=True)
    if warning:  # said once the report is made (a refusal above says what it is about)
        print(f"iwr report: {warning}", file=sys.stderr)
    for line in (note, warning):
        if line:
            cal.notes.insert(0, line)
    report = render(cal)
    print(report.text())
    out = Path(args.out)
    written = report.write(out, plots=not args.no_plots)
    print(f"\nwrote {out}/: " + ", ".join(p.name for p in written))
    # The verdict's exit status, as iwr calibrate's (3: no fit, 5: not calibrated).
    return _exit_code(cal, "iwr report", converged=False)
