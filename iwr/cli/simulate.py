"""``iwr simulate``: a simulated robot, measurement file and true errors."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..effects import parameter_names as effect_parameter_names
from ..kinds import for_robot
from ._base import (
    EXIT_OK,
    Footprint,
    UsageError,
    add_common,
    check_memory,
    check_output,
    load_robot,
    noise_spec,
    nonneg_int,
    positive_int,
    written_by,
)
from .robot_noise import OPTION_HELP, simulation_noise

#: The first line of the robot and data files ``iwr simulate`` writes: how a file it wrote, which
#: it may write over, is told from one it did not (``iwr plan --out`` does so with "# iwr
#: plan:"). The readers' own header ("# iwr measurements:") is no such mark: ``iwr calibrate``'s
#: robot files and real data saved by the library start with it too (a QA run: ``iwr simulate``
#: in a folder replaced the measurements.csv a user had written, exit 0).
SIMULATE_MARKER = "# iwr simulate:"
#: The first characters of the true-error file (JSON, no comments: :func:`write_truth`'s format).
TRUTH_START = '{\n "format": "iwr-true-errors"'


def add_parser(sub: Any) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "simulate", help="write a simulated robot and measurement file",
        description="Simulate a calibration experiment: an 'actual' robot (the nominal one plus "
        "random errors, uniform within +-0.5 mm and +-0.5 degree), reachable random poses, and "
        "noisy readings. Writes the nominal robot (TOML), the measurements (CSV) and the true "
        "errors (JSON).",
    )
    p.add_argument("--robot", metavar="ROBOT.toml",
                   help="the nominal robot (default: the built-in IWR, iwr.Robot.default())")
    p.add_argument("--poses", type=positive_int, default=100, metavar="N",
                   help="number of measurement poses (default: %(default)s)")
    p.add_argument("--seed", type=nonneg_int, default=1,
                   help="random seed: the same seed writes the same files (default: %(default)s)")
    p.add_argument("--noise", type=noise_spec, default=None, metavar="SPEC",
                   help="measurement noise: " + OPTION_HELP + " (default: the --robot file's "
                   "[noise] table if it has one, else realistic)")
    p.add_argument("-o", "--out", default=".", metavar="DIR",
                   help="folder of the files written (created if needed; default: current)")
    p.add_argument("--robot-file", default="robot.toml", metavar="NAME",
                   help="name of the robot file in DIR (default: %(default)s)")
    p.add_argument("--data-file", default="measurements.csv", metavar="NAME",
                   help="name of the measurement file in DIR (default: %(default)s)")
    p.add_argument("--truth-file", default="true_errors.json", metavar="NAME",
                   help="name of the true-error file in DIR (default: %(default)s)")
    add_common(p)
    p.set_defaults(func=cmd_simulate)
    return p


def write_truth(path: Path, robot: Any, truth: np.ndarray, seed: int, noise: Any,
                n_poses: int) -> None:
    """The true errors of a simulation as JSON (atomically): the robot's parameters (the
    geometry's, then its effects'), then its instrument's set-up parameters, and the noise
    model in the kind's form (:meth:`iwr.kinds.MeasurementKind.noise_record`)."""
    from .._io import atomic_write_text

    kind = for_robot(robot)
    doc = {
        "format": "iwr-true-errors",
        "version": 1,
        "robot": robot.name,
        "seed": seed,
        "n_poses": n_poses,
        **kind.noise_record(noise),
        # the robot's (its geometry's, then its effects': issue 23, docs/effects.md), then its
        # instrument's set-up parameters (a tracker's registration, a ballbar's balls)
        "parameter_names": robot.parameter_names + effect_parameter_names(robot.effects)
        + kind.setup_parameter_names(robot),
        "errors": [float(v) for v in truth],
    }
    atomic_write_text(path, json.dumps(doc, indent=1) + "\n")


def _describe(record: dict[str, Any]) -> str:
    parts = []
    for name, part in record.items():  # "noise": the readings'; "tracker_noise": "tracker ..."
        prefix = "" if name == "noise" else name.removesuffix("_noise") + " "
        parts += [f"{prefix}{k} {v:g}" for k, v in (part or {}).items() if v]
    return ", ".join(parts) or "none"


def _mark(path: Path, seed: int, n_poses: int) -> None:
    """Put :data:`SIMULATE_MARKER`'s line first in the file ``path`` just written (a comment to
    every reader), saying it holds simulated data, not measurements."""
    from .._io import atomic_write_text

    text = path.read_text(encoding="utf-8")
    atomic_write_text(path, f"{SIMULATE_MARKER} written by a simulation (seed {seed}, {n_poses} "
                            "poses), not measured; iwr simulate may write over this file\n"
                            + text)


def cmd_simulate(args: argparse.Namespace) -> int:
    from ..robot import Robot
    from ..simulation import simulate

    for option in ("--robot-file", "--data-file", "--truth-file"):
        name = getattr(args, option[2:].replace("-", "_"))
        if Path(name).name in ("", ".", "..") or name.endswith(("/", os.sep)):
            raise UsageError(f"{option} {name!r}: not a file name (the name of the file "
                             "written in --out)", "iwr simulate")
    stem = Path(args.data_file).with_suffix("")
    names = {"--robot-file": args.robot_file, "--data-file": args.data_file,
             "--truth-file": args.truth_file,
             # tracker data's long form and readings, named after --data-file
             "--data-file's long form": f"{stem}_long.csv",
             "--data-file's readings": f"{stem}_readings.csv"}
    seen: dict[str, str] = {}
    for option, name in names.items():
        other = seen.setdefault(os.path.normcase(os.path.normpath(name)), option)
        if other != option:
            raise UsageError(f"{other} and {option} are both {name!r}: each file needs a name "
                             "of its own (one would overwrite the other)", "iwr simulate")
    check_output(args.out, "--out", inputs=[args.robot], prog="iwr simulate", files=[
        args.robot_file, args.data_file, args.truth_file, f"{stem}_long.csv",
        f"{stem}_readings.csv"])
    # Each file: not a folder, and written over only if this command wrote it (its first line).
    out = Path(args.out)
    texts = {"--robot-file": out / args.robot_file, "--data-file": out / args.data_file,
             "--data-file's long form": out / f"{stem}_long.csv",
             "--data-file's readings": out / f"{stem}_readings.csv"}
    for option, path in texts.items():
        check_output(path, option.split("'")[0], inputs=[args.robot], prog="iwr simulate",
                     own=SIMULATE_MARKER)
    check_output(out / args.truth_file, "--truth-file", inputs=[args.robot], prog="iwr simulate",
                 own=TRUTH_START, own_what="a true-error file of iwr simulate")
    robot = load_robot(args.robot) if args.robot else Robot.default()
    check_memory("--poses", args.poses, Footprint.of(robot).simulate(args.poses),
                 "the simulated poses and their files", "iwr simulate")
    # What --noise means for the robot's instrument (a tracker's: its readings' noise and the
    # tracker's own): robot_noise.option_noise, as iwr calibrate and iwr compare read it.
    noise, args.noise_from = simulation_noise(args.noise, robot, args.robot)
    kind = for_robot(robot)
    data, truth = simulate(robot, n_poses=args.poses, seed=args.seed, noise=noise)
    out.mkdir(parents=True, exist_ok=True)
    robot_path, data_path = out / args.robot_file, out / args.data_file
    truth_path = out / args.truth_file
    robot.to_toml(robot_path)
    written = kind.write(robot, data, data_path)
    # A file without the mark now was written just above (one there before had it, or was
    # refused); the long pair of tracker points only for such data.
    for path in texts.values():
        if path.is_file() and not written_by(path, SIMULATE_MARKER):
            _mark(path, args.seed, len(data))
    write_truth(truth_path, robot, truth, args.seed, noise, len(data))
    print(f"simulated {len(data)} poses of robot {robot.name!r}: {kind.description} measured in "
          f"{kind.frame} (seed {args.seed}, noise: {_describe(kind.noise_record(noise))}"
          f"{' from ' + args.noise_from if args.noise_from else ''})")
    print(f"wrote {robot_path} (nominal robot), {', '.join(written)}, {truth_path} (true errors)")
    print(f"next: iwr calibrate {robot_path} {data_path}")
    return EXIT_OK
