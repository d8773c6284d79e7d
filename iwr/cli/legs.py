"""``iwr legs ROBOT.toml TARGETS.csv``: the leg commands that put the platform (or a tool on it)
at given poses, for given carriage readings, with a calibrated robot, in the frame its calibration
data determine (:func:`iwr.compensation.leg_commands`): the compensation a controller needs."""

from __future__ import annotations

import argparse
import csv
import io
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..measurements import CellError, effect_columns, effect_inputs
from ._base import EXIT_OK, CommandError, UsageError, add_common, load_robot

DEFAULT_OUT = "legs.csv"
#: The first characters of a file ``iwr legs`` writes (``-o`` writes over no other file).
LEGS_MARKER = "# iwr legs:"
_POSE_COLUMNS = ("x_mm", "y_mm", "z_mm", "alpha_rad", "beta_rad", "gamma_rad")
_LEG_COLUMNS = tuple(f"s{j}_mm" for j in range(1, 7))
_FLAG_COLUMNS = ("out_of_stroke", "out_of_workspace")
#: Exit code of ``iwr legs`` when a target is out of stroke or out of workspace (the file is
#: written, with the flags).
EXIT_FLAGGED = 6


def add_parser(sub: Any) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "legs", help="leg commands for target poses with a calibrated robot",
        description="For each row of TARGETS.csv (carriage joint readings q1.. and the wanted "
        "pose x_mm .. gamma_rad, as in a measurement file; other columns are ignored), compute "
        "the six leg readings that put the platform (or the --tool frame) there with the robot "
        "of ROBOT.toml (normally calibrated.toml from iwr calibrate): the compensation. Targets "
        "are in the frame the calibration's data determine: the world frame {0} for pose data, "
        "the laser tracker's frame {T} for tracker data (through the calibrated registration); "
        "another frame is refused. A calibration whose [provenance] status is not 'success' is "
        "refused unless --allow-unverified. Writes the targets with s1_mm .. s6_mm and the flags "
        f"{' and '.join(_FLAG_COLUMNS)}; exit {EXIT_FLAGGED} when any target is flagged.",
    )
    p.add_argument("robot", metavar="ROBOT.toml", help="the (calibrated) robot")
    p.add_argument("targets", metavar="TARGETS.csv",
                   help="carriage readings and target poses, one target per row")
    p.add_argument("-o", "--out", default=DEFAULT_OUT, metavar="FILE",
                   help="the leg commands, CSV (default: %(default)s)")
    p.add_argument("--frame", choices=("0", "T"), default=None,
                   help="the frame of the target poses: 0 (world frame, pose data) or T "
                   "(tracker frame, tracker data); default and only allowed: the one the "
                   "calibration's data determine (T for a robot with a [tracker] table); "
                   "ballbar data determine none: 0 given explicitly accepts the nominal "
                   "placement of {0} and {5}")
    p.add_argument("--user-frame", metavar="POINTS.csv", default=None,
                   help="the targets are in a user frame given by three points measured in the "
                   "calibration's frame (columns point,x_mm,y_mm,z_mm; rows origin, x: a point "
                   "on its +x axis, xy: a point in its xy plane on the +y side), as tracker "
                   "software builds a frame from 3 points")
    p.add_argument("--tool", metavar="X,Y,Z,ALPHA,BETA,GAMMA", type=_pose_arg, default=None,
                   help="the tool frame's pose in the platform frame {5} (mm, rad): the targets "
                   "are then the tool's poses (default: {5} itself; for tracker data {5} is "
                   "where the reflectors sit at their nominal positions, or the probe at its "
                   "nominal pose: give the probe's pose from the [tracker] table to target the "
                   "probe)")
    p.add_argument("--allow-unverified", action="store_true",
                   help="use a calibration whose [provenance] status is not 'success' (a failed "
                   "fit test, an interrupted or unconverged run)")
    add_common(p)
    p.set_defaults(func=cmd_legs)
    return p


def _pose_arg(text: str) -> np.ndarray:
    try:
        v = np.array([float(t) for t in text.split(",")])
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected 6 numbers X,Y,Z,ALPHA,BETA,GAMMA "
                                         "(mm, rad)") from None
    if v.shape != (6,) or not np.all(np.isfinite(v)):
        raise argparse.ArgumentTypeError(f"{text!r}: expected 6 finite numbers "
                                         "X,Y,Z,ALPHA,BETA,GAMMA (mm, rad)")
    if np.any(np.abs(v[3:]) > 2 * math.pi):
        raise argparse.ArgumentTypeError(f"{text!r}: an angle beyond 2 pi; angles are in radians")
    return v


def read_targets(path: str, robot: Any, optional: Any = ()
                 ) -> tuple[list[str], np.ndarray, np.ndarray, list[int], dict[str, np.ndarray]]:
    """The joint columns, joint readings (N, n_joints), poses (N, 6), file lines (N) and the
    columns of ``optional`` that the file has (name -> (N,) values; issue 23: a move's load and
    temperature) of a targets file. Lines starting with ``#`` are comments. Errors name the
    file, line and column."""
    q_cols = _joint_columns(robot)
    text = _read_text(path)
    rows = [(n, line) for n, line in enumerate(text.splitlines(), 1)
            if line.strip() and not line.lstrip().startswith("#")]
    if not rows:
        raise CommandError(f"{path}: no header line (expected columns {', '.join(q_cols)}, "
                           f"{', '.join(_POSE_COLUMNS)})")
    reader = csv.reader(io.StringIO("\n".join(line for _, line in rows)))
    header = [h.strip() for h in next(reader)]
    need = q_cols + list(_POSE_COLUMNS)
    missing = [c for c in need if c not in header]
    extra = [c for c in optional if c in header]
    if missing:
        hint = " (is the file separated by ';' or tabs? use commas)" if len(header) == 1 else ""
        raise CommandError(f"{path}, line {rows[0][0]}: missing columns {missing}; expected "
                           f"{', '.join(need)}{hint}")
    index = [header.index(c) for c in need + extra]
    values, lines = [], []
    for (n, _), fields in zip(rows[1:], reader, strict=True):
        if len(fields) != len(header):
            raise CommandError(f"{path}, line {n}: {len(fields)} fields; the header has "
                               f"{len(header)}")
        row = []
        for c, i in zip(need + extra, index, strict=True):
            try:
                v = float(fields[i])
            except ValueError:
                raise CommandError(f"{path}, line {n}, column {c!r}: {fields[i]!r} is not a "
                                   "number") from None
            if not math.isfinite(v):
                raise CommandError(f"{path}, line {n}, column {c!r}: {fields[i]!r} is not finite")
            row.append(v)
        values.append(row)
        lines.append(n)
    if not values:
        raise CommandError(f"{path}: no targets (only a header)")
    a = np.array(values)
    nj = len(q_cols)
    return (q_cols, a[:, :nj], a[:, nj: nj + 6], lines,
            {c: a[:, len(need) + k] for k, c in enumerate(extra)})


_USER_POINTS = ("origin", "x", "xy")


def read_user_frame(path: str) -> np.ndarray:
    """``--user-frame``: the 4x4 pose of the user frame of three points
    (:func:`iwr.compensation.frame_from_points`); errors name the file, line and column."""
    from ..compensation import frame_from_points

    text = _read_text(path)
    rows = [(n, line) for n, line in enumerate(text.splitlines(), 1)
            if line.strip() and not line.lstrip().startswith("#")]
    need = ["point", "x_mm", "y_mm", "z_mm"]
    if not rows:
        raise CommandError(f"{path}: no header line (expected columns {', '.join(need)})")
    reader = csv.reader(io.StringIO("\n".join(line for _, line in rows)))
    header = [h.strip() for h in next(reader)]
    missing = [c for c in need if c not in header]
    if missing:
        raise CommandError(f"{path}, line {rows[0][0]}: missing columns {missing}; expected "
                           f"{', '.join(need)}")
    points: dict[str, np.ndarray] = {}
    for (n, _), fields in zip(rows[1:], reader, strict=True):
        if len(fields) != len(header):
            raise CommandError(f"{path}, line {n}: {len(fields)} fields; the header has "
                               f"{len(header)}")
        name = fields[header.index("point")].strip().lower()
        if name not in _USER_POINTS:
            raise CommandError(f"{path}, line {n}, column 'point': {name!r}; expected one of "
                               f"{', '.join(_USER_POINTS)}")
        if name in points:
            raise CommandError(f"{path}, line {n}: point {name!r} given twice")
        xyz = []
        for c in need[1:]:
            text_value = fields[header.index(c)]
            try:
                v = float(text_value)
            except ValueError:
                raise CommandError(f"{path}, line {n}, column {c!r}: {text_value!r} is not a "
                                   "number") from None
            if not math.isfinite(v):
                raise CommandError(f"{path}, line {n}, column {c!r}: {text_value!r} is not "
                                   "finite")
            xyz.append(v)
        points[name] = np.array(xyz)
    absent = [p for p in _USER_POINTS if p not in points]
    if absent:
        raise CommandError(f"{path}: no point {', '.join(map(repr, absent))} (rows origin, x, "
                           "xy)")
    try:
        return frame_from_points(points["origin"], points["x"], points["xy"])
    except ValueError as exc:
        raise CommandError(f"{path}: {exc}") from None


def _read_text(path: str) -> str:
    """A targets or points file's text, read as a data file is
    (:func:`iwr.measurements.read_csv_text`: a named pipe or a device refused, bounded, UTF-8;
    a plan of ``iwr plan`` taken: its poses are targets)."""
    from ..measurements import MeasurementFileError, read_csv_text

    try:
        return read_csv_text(Path(path), plans=True)
    except MeasurementFileError as exc:
        raise CommandError(str(exc)) from None


def _joint_columns(robot: Any) -> list[str]:
    units = {"P": "mm", "R": "rad"}
    return [f"q{i + 1}_{units[t]}" for i, t in enumerate(robot.joint_types)]


def cmd_legs(args: argparse.Namespace) -> int:
    from .._io import atomic_write_text
    from ..compensation import (
        FRAMES,
        CalibrationStatusError,
        FrameError,
        TargetError,
        check_calibration,
        determined_frame,
        gauge_note,
        leg_commands,
    )
    from ._base import check_output

    check_output(args.out, "-o", inputs=[args.robot, args.targets, args.user_frame],
                 prog="iwr legs", own=LEGS_MARKER, in_existing_folder=True)
    robot = load_robot(args.robot)
    try:
        note = check_calibration(robot, allow_unverified=args.allow_unverified,
                                 where=str(args.robot))
    except CalibrationStatusError as exc:
        raise CommandError(str(exc)) from None
    conditions = effect_columns() if robot.effects else ()
    q_cols, q, poses, lines, extra = read_targets(args.targets, robot, conditions)
    user = read_user_frame(args.user_frame) if args.user_frame else None
    try:
        options = dict(frame=args.frame, tool=args.tool, user_frame=user,
                       joint_columns=q_cols, where=str(args.robot))
        if robot.effects:  # issue 23: the move's load and temperature (docs/effects.md)
            import types

            from ..effects.api import leg_commands as effect_commands
            from ..effects.model import check_inputs

            inputs = effect_inputs(extra, args.targets)
            try:  # a column the effects need, missing from the targets file: named there
                check_inputs(robot, types.SimpleNamespace(**inputs), where=str(args.targets))
            except ValueError as exc:
                raise CommandError(str(exc)) from None
            loads = ", ".join(e.name for e in robot.effects if "forces" in e.needs)
            if inputs["payload"] is None and loads:
                cols = ", ".join(effect_columns()[:4])
                unloaded = (f"note: {args.targets} has no payload columns ({cols}): the commands "
                            f"are for no payload, the platform's own weight alone ({loads})")
                note = f"{note}\n{unloaded}" if note else unloaded
            cmd = effect_commands(robot, q, poses, **inputs, **options)
        else:
            cmd = leg_commands(robot, q, poses, **options)
    except FrameError as exc:
        raise UsageError(str(exc), "iwr legs") from None
    except TargetError as exc:
        raise CommandError(f"{args.targets}, line {lines[exc.index]}, column {exc.column!r}: "
                           f"{exc.detail}") from None
    except CellError as exc:  # a load or a temperature out of its range: the file's place
        place = exc.in_file(args.targets, lines, {
            "payload": effect_columns()[:4],
            "temperatures": [c for c in effect_columns()[4:] if c in extra]}, quoted=True)
        if place is None:
            raise
        raise CommandError(place) from None
    if note:
        print(note)
    if determined_frame(robot) is None:
        print(f"note: {gauge_note(robot, str(args.robot))}")
    stroke, workspace = cmd.unreachable, cmd.out_of_workspace
    buf = io.StringIO()
    name = " ".join(f"{robot.name} ({args.robot})".splitlines())
    frame_text = FRAMES[cmd.frame] if user is None else (
        f"the user frame of {args.user_frame} (three points measured in {FRAMES[cmd.frame]})")
    tool = "" if args.tool is None else (
        "; targets are the poses of the tool frame at "
        + ",".join(repr(float(v)) for v in args.tool) + " in {5}")
    # The targets' load and temperature columns (a robot with effects) are kept, after the legs
    # as in a measurement file: the commands hold for them, and the file is read back as the
    # targets were (iwr legs of it gives the same commands).
    kept = list(extra)
    under = f" under each target's {', '.join(kept)} (kept)" if kept else ""
    buf.write(f"{LEGS_MARKER} leg sensor readings s1..s6 (mm; leg length = reading + l0) that put "
              f"the platform at each target pose{under}, by the inverse kinematics of {name}; "
              f"targets in {frame_text}{tool}; flags 1 where a leg is outside its stroke or the "
              "target outside the workspace (joint limits, home_pose +- workspace)\n")
    w = csv.writer(buf, lineterminator="\n")
    conditions = (np.column_stack([extra[c] for c in kept]) if kept
                  else np.zeros((len(q), 0)))
    w.writerow([*q_cols, *_POSE_COLUMNS, *_LEG_COLUMNS, *kept, *_FLAG_COLUMNS])
    for qi, pi, li, ci, fs, fw in zip(q, poses, cmd.legs, conditions, stroke, workspace,
                                      strict=True):
        w.writerow([repr(float(v)) for v in (*qi, *pi, *li, *ci)] + [int(fs), int(fw)])
    atomic_write_text(args.out, buf.getvalue())
    print(f"wrote {args.out}: leg commands for {len(cmd.legs)} targets in {frame_text}")
    flagged = False
    for what, mask, column in (("need a leg outside its stroke", stroke, _FLAG_COLUMNS[0]),
                               ("are outside the workspace", workspace, _FLAG_COLUMNS[1])):
        if mask.any():
            flagged = True
            where = [lines[k] for k in np.flatnonzero(mask)]
            shown = ", ".join(map(str, where[:10])) + (" ..." if len(where) > 10 else "")
            print(f"warning: {len(where)} of {len(lines)} targets {what} ({args.targets}, "
                  f"lines {shown}; column {column})",
                  flush=True)
    if flagged:
        # Out of stroke or beyond a joint's limit: the robot cannot reach the target. Only
        # outside the workspace box: it can, but the commands extrapolate the calibration there
        # (the job's calibrated.toml holds every measured pose within its box:
        # iwr.compensation.with_measured_workspace).
        cannot = stroke | cmd.beyond_joint_limits
        why = "; ".join(w for w, n in (
            ("the robot cannot reach those out of stroke or beyond a joint's limit as commanded",
             int(cannot.sum())),
            ("those only outside the workspace box are within every leg's stroke and joint's "
             "limit, but the commands extrapolate the calibration there",
             int((workspace & ~cannot).sum())))
            if n)
        print(f"iwr legs: {cmd.n_flagged} targets flagged (exit {EXIT_FLAGGED}); {why}",
              flush=True)
        return EXIT_FLAGGED
    return EXIT_OK
