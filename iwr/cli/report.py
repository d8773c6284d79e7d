"""``iwr report RUN.json ROBOT.toml DATA.csv``: a result of ``iwr-calibrate`` (or of
``iwr calibrate``, or ``IdentificationResult.save``) turned into the calibrated robot and the
report, as ``iwr calibrate`` writes them."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from ._base import EXIT_OK, CommandError, add_common, load_data, load_robot, one_line

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
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help="output folder (created if needed; default: %(default)s)")
    p.add_argument("--no-plots", action="store_true", help="write the report without figures")
    add_common(p)
    p.set_defaults(func=cmd_report)
    return p


def cmd_report(args: argparse.Namespace) -> int:
    from ..accuracy import accuracy
    from ..identifiability import identifiability
    from ..methods import load_result
    from ..reporting.calibration import Calibration
    from ..reporting.html import provenance
    from ..uncertainty import uncertainty

    result = load_result(args.run)
    robot = load_robot(args.robot)
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
    validation = load_data(args.validation, robot) if args.validation else None
    val = validation if validation is not None else data
    notes: list[str] = []
    rep = identifiability(robot, data, x)
    active = result.get("active")
    try:
        unc = uncertainty(robot, data, x, active=rep if active is None else active)
    except ValueError as exc:
        unc = None
        notes.append(f"note: no standard deviations: {one_line(exc)}")
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
