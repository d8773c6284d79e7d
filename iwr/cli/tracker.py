"""``iwr calibrate`` and ``iwr simulate`` for a robot with a laser tracker (docs/tracker.md):
the robot's TOML has a ``[tracker]`` table and the data are points (or probe poses) in the
tracker's frame."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import Any

from ._base import (
    EXIT_OK,
    UsageError,
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


def tracker_noise_of(noise: Any) -> Any:
    """What ``--noise`` means for a robot with a tracker, in ``iwr simulate`` and ``iwr
    calibrate`` alike (:meth:`iwr.tracker.kind.PointsKind.reading_noise`): the reading noise of
    the :class:`iwr.Noise` and ``TrackerNoise.leica()`` (none when the whole noise is zero)."""
    from ..kinds import named

    return named("points").reading_noise(noise)


def simulate_tracker_files(args: argparse.Namespace, robot: Any) -> int:
    """``iwr simulate --robot ROBOT.toml`` with a ``[tracker]`` table: the wide CSV of points (or
    probe poses), the long pair (points + readings) for point data, and the true errors."""
    from .._io import atomic_write_text
    from ..simulation import simulate
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
