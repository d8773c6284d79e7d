"""``iwr export ROBOT.toml``: the (calibrated) robot for the software that drives it: the hexapod
for LinuxCNC ``genhexkins`` (HAL), as plain JSON and as a table of leg corrections over a grid of
poses (with ``--nominal``); the carriage as URDF (:mod:`iwr.export`)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

from ._base import (
    EXIT_OK,
    CommandError,
    UsageError,
    add_common,
    check_memory,
    check_output,
    load_robot,
    positive_int,
    written_by,
)

DEFAULT_OUT = "iwr-export"
#: Poses per coordinate of the leg-correction grid by default (5^6 = 15625 poses, 6.5 MB): on
#: the built-in example a grid of 3 interpolated multilinearly is off by up to 27 um, more than
#: the calibration's own leg error on held-out poses (16.6 um at most, an outside check); 5 by
#: 7.8 um.
DEFAULT_GRID = 5
#: The largest grid accepted per coordinate (12^6 = 3 million poses, about 1 GB of CSV).
MAX_GRID = 12
#: Memory of one pose of the leg-correction grid while its table is made (the pose as a Python
#: tuple and an array, both models' readings, its CSV line as text and bytes): 0.9-1.1 kB
#: measured, so 12^6 poses take about 3.3 GB, refused where less is available.
GRID_POSE_BYTES = 1536
#: The files ``iwr export`` writes into ``--out``.
FILES = ("genhexkins.hal", "hexapod.json", "carriage.urdf", "leg_corrections.csv")
#: How a file of FILES that ``iwr export`` wrote begins (its first characters, and words within
#: its first 4 kB): it writes over those alone, not a hand-made file of the same name.
_OWN = {"genhexkins.hal": ("# LinuxCNC genhexkins parameters", "written by iwr export"),
        "hexapod.json": ('{\n "format": "iwr-hexapod"', ""),
        "carriage.urdf": ("<?xml", "written by iwr export"),
        "leg_corrections.csv": ("# iwr leg corrections:", "")}


def _not_ours(out: Path) -> list[str]:
    """The files of FILES in folder ``out`` that ``iwr export`` did not write (or that are not
    regular files): what it must not write over, nor remove as an earlier export's."""
    return [name for name, (start, words) in _OWN.items()
            if os.path.lexists(out / name) and not written_by(out / name, start, words)]


def add_parser(sub: Any) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "export", help="write a calibrated robot for controllers: genhexkins HAL, JSON, leg "
        "correction table, URDF",
        description="Write the robot of ROBOT.toml (normally calibrated.toml from iwr calibrate) "
        "for the software that drives it, into the folder --out: genhexkins.hal (LinuxCNC "
        "genhexkins's base and platform joint coordinates, setp lines), hexapod.json (the same "
        "numbers and the leg offsets, plain JSON), carriage.urdf (the carriage chain with its "
        "DH parameters, the hexapod base frame {4} as a fixed link) and, with --nominal, "
        "leg_corrections.csv (the leg readings of the nominal and the calibrated model over a "
        "grid of platform poses, and their difference). Each file states its frames; "
        "docs/cli.md describes them.",
    )
    p.add_argument("robot", metavar="ROBOT.toml", help="the (calibrated) robot")
    p.add_argument("-o", "--out", default=DEFAULT_OUT, metavar="DIR",
                   help="folder of the exported files (default: %(default)s)")
    p.add_argument("--nominal", default=None, metavar="NOMINAL.toml",
                   help="the nominal robot the controller's own model uses: writes "
                   "leg_corrections.csv, the calibrated minus nominal leg readings over a grid")
    p.add_argument("--grid", type=positive_int, default=DEFAULT_GRID, metavar="N",
                   help="poses per coordinate of the correction table, evenly over home_pose +- "
                   f"workspace (N^6 poses; default %(default)s, at most {MAX_GRID})")
    p.add_argument("--allow-unverified", action="store_true",
                   help="export a calibration whose [provenance] status is not 'success' (a "
                   "failed fit test, degenerate data, an interrupted or unconverged run), as "
                   "iwr legs uses one")
    add_common(p)
    p.set_defaults(func=cmd_export)
    return p


def cmd_export(args: argparse.Namespace) -> int:
    from .._io import write_folder
    from ..export import (
        data_frame,
        link_names,
        write_carriage_urdf,
        write_genhexkins_hal,
        write_hexapod_json,
        write_leg_corrections,
    )

    if args.grid > MAX_GRID:
        raise UsageError(f"--grid {args.grid}: at most {MAX_GRID} poses per coordinate "
                         f"({args.grid}^6 poses is too large a table)", "iwr export")
    if args.nominal is not None:  # the grid is made only for the leg corrections
        check_memory("--grid", args.grid, GRID_POSE_BYTES * args.grid**6,
                     f"the leg-correction table's {args.grid**6} poses", "iwr export")
    # A folder, made if needed: not an existing file, nor under one, nor where nothing can be
    # written, nor writing over an input (refused, exit 2, before anything is read).
    check_output(args.out, "--out", inputs=[args.robot, args.nominal], files=FILES,
                 prog="iwr export")
    foreign = _not_ours(Path(args.out))
    if foreign:  # the folder may be a machine's configuration: its own files stay
        raise UsageError(f"--out {args.out}: {', '.join(foreign)} "
                         f"{'is' if len(foreign) == 1 else 'are'} not written by iwr export (a "
                         "hand-made file, or not a regular file); it writes the set "
                         f"{', '.join(FILES)} as a whole, over an earlier export's only: move "
                         f"{'it' if len(foreign) == 1 else 'them'} away, or give another --out",
                         "iwr export")
    from ..compensation import (
        CalibrationStatusError,
        NominalMismatchError,
        check_calibration,
        check_nominal,
        determined_frame,
        gauge_note,
    )

    robot = load_robot(args.robot)
    try:  # as iwr legs: a controller's files only from a verified calibration
        note = check_calibration(robot, allow_unverified=args.allow_unverified,
                                 where=str(args.robot))
    except CalibrationStatusError as exc:
        raise CommandError(str(exc)) from None
    nominal = load_robot(args.nominal) if args.nominal else None
    if nominal is not None and nominal.joint_types != robot.joint_types:
        raise UsageError(f"--nominal {args.nominal}: joints {nominal.joint_types!r}, but "
                         f"{args.robot} has {robot.joint_types!r}: not the same robot",
                         "iwr export")
    nominal_note = ""
    if nominal is not None:
        try:
            nominal_note = check_nominal(robot, nominal, where=str(args.robot),
                                         nominal_where=f"--nominal {args.nominal}")
        except NominalMismatchError as exc:
            raise UsageError(str(exc), "iwr export") from None
    out = Path(args.out)
    frame = data_frame(robot)
    written = []

    def write(tmp: Path) -> list[Path]:
        # Into a temporary folder first, moved in as a whole (write_folder): a failure leaves
        # the folder as it was, and an earlier export's file this one does not write goes.
        files = [tmp / "genhexkins.hal", tmp / "hexapod.json"]
        write_genhexkins_hal(files[0], robot, args.robot)
        written.append("genhexkins.hal (LinuxCNC genhexkins: base joints in {4}, platform "
                       "joints in {5})")
        write_hexapod_json(files[1], robot, args.robot)
        written.append("hexapod.json (the same numbers and the leg offsets"
                       + (", the effects" if robot.effects else "")
                       + (f", the registration of {{{frame[0]}}}" if frame else "") + ")")
        if robot.n_joints:
            files.append(tmp / "carriage.urdf")
            write_carriage_urdf(files[-1], robot, args.robot)
            written.append(f"carriage.urdf ({robot.n_joints} joints, hexapod_base = {{4}}"
                           + (f", {link_names(robot)[-1]} = {{{frame[0]}}}" if frame else "")
                           + ")")
        else:
            written.append("no carriage.urdf: the robot has no carriage joints")
        if nominal is not None:
            files.append(tmp / "leg_corrections.csv")
            t = write_leg_corrections(files[-1], robot, nominal, args.grid, args.robot,
                                      args.nominal, check=False)  # checked above
            read = ("between them, interpolated multilinearly" if t.poses > 1
                    else "the one correction used everywhere")
            written.append(
                f"leg_corrections.csv ({t.poses} poses of {{5}} in {{4}}; {read}, off the models "
                f"by up to {t.interpolation_max_mm * 1000:.3g} um, "
                f"{t.interpolation_rms_mm * 1000:.3g} um RMS: a finer --grid is closer)")
        else:
            written.append("no leg_corrections.csv: give --nominal NOMINAL.toml (the model the "
                           "controller uses) for it")
        return files

    try:
        write_folder(out, write, FILES)
    except OSError as exc:
        raise CommandError(f"--out {exc.strerror or exc}") from None  # it names the folder
    print(f"wrote {out}/:")
    for line in written:
        print(f"  {line}")
    for line in (note, nominal_note):
        if line:
            print(line)
    if determined_frame(robot) is None:  # a ballbar's calibration: {0} and {5} nominal
        print(f"note: {gauge_note(robot, str(args.robot))}")
    if frame is not None:
        print(f"note: {args.robot} was calibrated from data measured in {{{frame[0]}}}, which do "
              "not fix the world frame {0}: the exported {0} is the calibration's gauge choice "
              "(docs/tracker.md). A target measured there is carried into {0} by the "
              "registration in hexapod.json"
              + (f" (and carriage.urdf's {link_names(robot)[-1]} link)" if robot.n_joints else "")
              + f", as `iwr legs --frame {frame[0]}` does")
    if robot.effects:
        names = ", ".join(e.name for e in robot.effects)
        print(f"note: {args.robot} has non-geometric effects ({names}): genhexkins.hal, "
              "carriage.urdf and leg_corrections.csv hold the geometry only (the leg lengths "
              "without the load and the temperature); hexapod.json records the effects; `iwr "
              "legs` gives leg commands that include them (docs/effects.md)")
    return EXIT_OK
