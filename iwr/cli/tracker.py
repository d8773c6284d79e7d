"""``iwr calibrate`` and ``iwr simulate`` for a robot with a laser tracker (docs/tracker.md):
the robot's TOML has a ``[tracker]`` table and the data are points (or probe poses) in the
tracker's frame."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from ._base import EXIT_INTERRUPTED, EXIT_OK, CommandError, UsageError, progress_enabled


def add_arguments(p: argparse.ArgumentParser) -> None:
    """``--readings``: the robot's log of joint and leg readings beside a long table of points."""
    p.add_argument("--readings", default=None, metavar="READINGS.csv",
                   help="tracker data as a long table of points (DATA: pose, reflector, x_mm, "
                   "y_mm, z_mm): the robot's log of readings (pose, q1_mm, ..., s1_mm .. s6_mm) "
                   "joined to it by pose (docs/tracker.md)")


def refuse_tracker_data(args: argparse.Namespace) -> None:
    """For a robot without a [tracker] table: refuse --readings and tracker data files with a
    message that says what is missing."""
    from ..tracker.files import is_tracker_file

    if args.readings is not None:
        raise UsageError(f"--readings: only for a robot with a [tracker] table; {args.robot} has "
                         "none (docs/tracker.md)")
    if is_tracker_file(args.data):
        raise UsageError(f"{args.data}: laser-tracker data (a 'pose' column), but {args.robot} has "
                         "no [tracker] table describing the setup (registration, reflectors or "
                         "probe): add one (docs/tracker.md)")


def load_tracker_data(path: str, robot: Any, readings: str | None = None) -> Any:
    from ..tracker.files import read_tracker_data

    return read_tracker_data(path, robot.tracker, readings)


def _summary_line(label: str, e: Any) -> str:
    pos = np.asarray(e.position, dtype=float)
    ori = np.asarray(e.orientation, dtype=float)
    ori = ori[np.isfinite(ori)]  # poses with fewer than 3 points seen have no orientation
    o = (f"orientation RMS {math.sqrt(np.mean(ori**2)):.5f} deg ({ori.size} poses)" if ori.size
         else "no orientation (fewer than 3 points per pose)")
    return (f"  {label:<36} position RMS {math.sqrt(np.mean(pos**2)):.4f} mm, max "
            f"{pos.max():.4f} mm; {o}")


def calibrate_tracker(args: argparse.Namespace, robot: Any, method: str,
                      kwargs: dict[str, Any]) -> int:
    """Identify the robot, the registration and the reflector (or probe) offsets from tracker
    data; validate on held-out poses (point residuals); write calibrated.toml (the calibrated
    robot with its calibrated tracker setup), result.json and report.md."""
    from .._io import atomic_write_text, jsonable
    from ..accuracy import accuracy
    from ..identifiability import identifiability
    from ..methods import identify

    if args.poses is not None:
        raise CommandError("--poses applies to the built-in example only")
    data = load_tracker_data(args.data, robot, getattr(args, "readings", None))
    if args.validation:
        val = load_tracker_data(args.validation, robot)
        ident, held_out = data, True
    elif args.validation_fraction > 0 and len(data) > 1:
        n = len(data)
        n_val = max(1, int(round(args.validation_fraction * n)))
        if n - n_val < 1:
            raise CommandError(f"--validation-fraction {args.validation_fraction}: leaves no pose "
                               f"for identification out of {n}")
        order = np.random.default_rng(args.seed).permutation(n)
        ident, val = _subset(data, np.sort(order[n_val:])), _subset(data, np.sort(order[:n_val]))
        held_out = True
    else:
        ident = val = data
        held_out = False
    kwargs = {k: v for k, v in kwargs.items() if k not in ("callback",)}
    if args.parameters == "base":
        kwargs["active"] = "base"
    setup = robot.tracker
    print(f"tracker data: {len(data)} poses, {setup.kind}"
          + (f" (K = {setup.n_reflectors})" if setup.kind == "points" else "")
          + f"; identifying {robot.n_params} robot + {setup.n_params} setup parameters with "
          f"{method} ({len(ident)} poses), from the nominal robot and the closed-form "
          "registration guess", flush=True)
    result = identify(robot, ident, method=method, bounds=args.bounds, seed=args.seed,
                      progress=progress_enabled(args), **kwargs)
    ns = identifiability(robot, ident, result.x)
    acc = accuracy(robot, val, result.x)
    where = "held-out" if held_out else "identification (no poses held out)"
    lines = [
        f"{result.message} (status {result.status}, {result.nfev} evaluations, "
        f"cost {result.fun:.6g} mm^2)",
        f"identifiability: rank {ns.rank} of {len(ns.parameter_names)}, "
        f"{len(ns.left_out)} null directions (docs/tracker.md)",
        f"accuracy on {acc.n_poses} {where} poses: largest predicted-minus-measured point "
        "distance per pose, and the rotation between predicted and measured points:",
        _summary_line("nominal robot + registration guess", acc.nominal),
        _summary_line("calibrated", acc.calibrated),
    ]
    print("\n".join(lines))
    out = Path(args.out or "iwr-calibration")
    out.mkdir(parents=True, exist_ok=True)
    nr = robot.n_params
    calibrated = robot.with_errors(result.x[:nr]).with_tracker(
        setup=setup.with_parameters(result.x[nr:]))
    calibrated.to_toml(out / "calibrated.toml",
                       provenance={"method": method, "data": str(args.data),
                                   "cost_mm2": float(result.fun)})
    result.save(out / "result.json")
    atomic_write_text(out / "accuracy.json", json.dumps(jsonable(acc.to_dict()), indent=1) + "\n")
    report = ["# iwr calibration with laser-tracker data", "", f"- robot: `{args.robot}`",
              f"- data: `{args.data}`" + (f" + `{args.readings}`" if args.readings else ""),
              f"- method: {method}", "", *[f"    {line}" for line in lines], "",
              "Identified parameters (robot, then tracker setup):", "",
              *[f"    {name:<22} {value:+.6g}" for name, value in result.named().items()]]
    atomic_write_text(out / "report.md", "\n".join(report) + "\n")
    print(f"\nwrote {out}/: calibrated.toml, result.json, accuracy.json, report.md")
    if result.interrupted:
        return EXIT_INTERRUPTED
    from .calibrate import _exit_code  # exit 3 when the model does not fit, as for leg data

    return _exit_code(SimpleNamespace(result=result))


def _subset(data: Any, rows: np.ndarray) -> Any:
    from ..tracker.data import TrackerMeasurements

    lines = None if data.lines is None else data.lines[rows]
    if data.points is not None:
        return TrackerMeasurements(data.q[rows], data.legs[rows], points=data.points[rows],
                                   joint_types=data.joint_types, lines=lines, source=data.source)
    return TrackerMeasurements(data.q[rows], data.legs[rows], probe=data.probe[rows],
                               joint_types=data.joint_types, lines=lines, source=data.source)


def simulate_tracker_files(args: argparse.Namespace, robot: Any) -> int:
    """``iwr simulate --robot ROBOT.toml`` with a ``[tracker]`` table: the wide CSV of points (or
    probe poses), the long pair (points + readings) for point data, and the true errors."""
    from .._io import atomic_write_text
    from ..simulate import Noise, simulate
    from ..tracker.files import write_tracker_long, write_tracker_wide
    from ..tracker.simulate import TrackerNoise

    readings_noise = dataclasses.replace(args.noise, position=0.0, orientation=0.0)
    tracker_noise = (TrackerNoise.none() if args.noise == Noise() else TrackerNoise.leica())
    noise = (readings_noise, tracker_noise)
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
          f"{'none' if tracker_noise.is_zero else 'TrackerNoise.leica()'})")
    print(f"wrote {robot_path} (nominal robot with its [tracker] table), "
          + ", ".join(written) + f", {truth_path} (true errors)")
    print(f"next: iwr calibrate {robot_path} {data_path}")
    return EXIT_OK
