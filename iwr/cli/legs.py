"""``iwr legs ROBOT.toml TARGETS.csv``: the leg commands that put the platform at given poses, for
given carriage readings, with a (calibrated) robot: the hexapod's inverse kinematics
(:func:`iwr.predict_legs`), the compensation a controller needs."""

from __future__ import annotations

import argparse
import csv
import io
import math
from pathlib import Path
from typing import Any

import numpy as np

from ._base import EXIT_OK, CommandError, add_common, load_robot

DEFAULT_OUT = "legs.csv"
_POSE_COLUMNS = ("x_mm", "y_mm", "z_mm", "alpha_rad", "beta_rad", "gamma_rad")
_LEG_COLUMNS = tuple(f"s{j}_mm" for j in range(1, 7))


def add_parser(sub: Any) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "legs", help="leg commands for target poses with a calibrated robot",
        description="For each row of TARGETS.csv (carriage joint readings q1.. and the wanted "
        "platform pose x_mm .. gamma_rad, as in a measurement file; other columns are ignored), "
        "compute the six leg lengths that put the platform there with the robot of ROBOT.toml "
        "(normally calibrated.toml from iwr calibrate): the inverse kinematics of the hexapod. "
        "Writes the targets with the leg columns s1_mm .. s6_mm.",
    )
    p.add_argument("robot", metavar="ROBOT.toml", help="the (calibrated) robot")
    p.add_argument("targets", metavar="TARGETS.csv",
                   help="carriage readings and platform poses, one target per row")
    p.add_argument("-o", "--out", default=DEFAULT_OUT, metavar="FILE",
                   help="the leg commands, CSV (default: %(default)s)")
    add_common(p)
    p.set_defaults(func=cmd_legs)
    return p


def read_targets(path: str, robot: Any) -> tuple[list[str], np.ndarray, np.ndarray]:
    """The joint columns, joint readings (N, n_joints) and poses (N, 6) of a targets file. Lines
    starting with ``#`` are comments. Errors name the file, line and column."""
    q_cols = _joint_columns(robot)
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise CommandError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    rows = [(n, line) for n, line in enumerate(text.splitlines(), 1)
            if line.strip() and not line.lstrip().startswith("#")]
    if not rows:
        raise CommandError(f"{path}: no header line (expected columns {', '.join(q_cols)}, "
                           f"{', '.join(_POSE_COLUMNS)})")
    reader = csv.reader(io.StringIO("\n".join(line for _, line in rows)))
    header = [h.strip() for h in next(reader)]
    need = q_cols + list(_POSE_COLUMNS)
    missing = [c for c in need if c not in header]
    if missing:
        hint = " (is the file separated by ';' or tabs? use commas)" if len(header) == 1 else ""
        raise CommandError(f"{path}, line {rows[0][0]}: missing columns {missing}; expected "
                           f"{', '.join(need)}{hint}")
    index = [header.index(c) for c in need]
    values = []
    for (n, _), fields in zip(rows[1:], reader, strict=True):
        if len(fields) != len(header):
            raise CommandError(f"{path}, line {n}: {len(fields)} fields; the header has "
                               f"{len(header)}")
        row = []
        for c, i in zip(need, index, strict=True):
            try:
                v = float(fields[i])
            except ValueError:
                raise CommandError(f"{path}, line {n}, column {c!r}: {fields[i]!r} is not a "
                                   "number") from None
            if not math.isfinite(v):
                raise CommandError(f"{path}, line {n}, column {c!r}: {fields[i]!r} is not finite")
            row.append(v)
        values.append(row)
    if not values:
        raise CommandError(f"{path}: no targets (only a header)")
    a = np.array(values)
    nj = len(q_cols)
    return q_cols, a[:, :nj], a[:, nj:]


def _joint_columns(robot: Any) -> list[str]:
    units = {"P": "mm", "R": "rad"}
    return [f"q{i + 1}_{units[t]}" for i, t in enumerate(robot.joint_types)]


def cmd_legs(args: argparse.Namespace) -> int:
    from .._io import atomic_write_text
    from ..problem import predict_legs
    from ._base import check_output

    check_output(args.out, "-o", inputs=[args.robot, args.targets], prog="iwr legs")
    robot = load_robot(args.robot)
    q_cols, q, poses = read_targets(args.targets, robot)
    # ROBOT.toml is the calibrated robot: its errors are part of its geometry.
    legs = predict_legs(robot, np.zeros(robot.n_params), q, poses)
    lo, hi = robot.leg_stroke[:, 0], robot.leg_stroke[:, 1]
    outside = np.any((legs < lo) | (legs > hi), axis=1)
    buf = io.StringIO()
    name = " ".join(f"{robot.name} ({args.robot})".splitlines())
    buf.write(f"# iwr legs: leg sensor readings s1..s6 (mm; leg length = reading + l0) that put "
              f"the platform at each target pose, by the inverse kinematics of {name}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([*q_cols, *_POSE_COLUMNS, *_LEG_COLUMNS])
    for qi, pi, li in zip(q, poses, legs, strict=True):
        w.writerow([repr(float(v)) for v in (*qi, *pi, *li)])
    atomic_write_text(args.out, buf.getvalue())
    print(f"wrote {args.out}: leg commands for {len(legs)} targets")
    if outside.any():
        first = int(np.flatnonzero(outside)[0])
        print(f"warning: {int(outside.sum())} targets need a leg outside its stroke "
              f"(first: target {first + 1}); the robot cannot reach them", flush=True)
    return EXIT_OK
