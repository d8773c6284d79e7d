"""``iwr plan``: choose the poses to measure."""

from __future__ import annotations

import argparse
import sys
from typing import Any

import numpy as np

from ..measurements import PLAN_MARKER
from ._base import (
    EXIT_OK,
    CommandError,
    Footprint,
    UsageError,
    add_common,
    check_memory,
    check_output,
    load_robot,
    nonneg_int,
    positive_int,
)


def add_parser(sub: Any) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "plan", help="choose the poses to measure",
        description="Choose K poses to measure among candidate poses (from a file, or sampled "
        "at random in the workspace) that maximise an observability index of the base "
        "parameters (iwr.plan_poses: greedy, then exchanges).",
    )
    p.add_argument("robot", metavar="ROBOT.toml", help="the nominal robot")
    p.add_argument("--candidates", metavar="CANDIDATES.csv",
                   help="candidate poses (a measurement CSV, or laser-tracker data in the "
                   "wide form for a robot with a [tracker] table; leg readings may be "
                   "predicted ones)")
    p.add_argument("--n-candidates", type=positive_int, default=1000, metavar="M",
                   help="without --candidates: candidates sampled in the workspace "
                   "(default: %(default)s)")
    p.add_argument("--poses", type=positive_int, default=30, metavar="K",
                   help="number of poses to choose (default: %(default)s)")
    p.add_argument("--criterion", choices=("O1", "O2", "O3", "O4"), default="O1",
                   help="observability index to maximise (default: O1, D-optimal)")
    p.add_argument("--payload", action="append", type=_payload, default=None,
                   metavar="KG,X,Y,Z",
                   help="a robot with [effects.compliance]: a payload that can be mounted "
                   "(mass kg, centre of mass in {5} mm; 0,0,0,0 for none); repeat it: the plan "
                   "chooses poses and payloads together (docs/effects.md)")
    p.add_argument("--seed", type=nonneg_int, default=0, help="random seed (default: 0)")
    p.add_argument("--out", default="plan.csv", metavar="FILE",
                   help="the chosen poses, as a measurement CSV (default: %(default)s)")
    add_common(p)
    p.set_defaults(func=cmd_plan)
    return p


def _payload(text: str) -> list[float]:
    """``--payload KG,X,Y,Z``."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 4 or not all(np.isfinite(values)) or values[0] < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: expected KG,X,Y,Z (mass >= 0 kg, centre "
                                         "of mass in {5} mm), e.g. 80,50,0,150")
    return values


def cmd_plan(args: argparse.Namespace) -> int:
    from ..kinds import for_robot
    from ..measurements import Measurements
    from ..planning import plan_poses
    from ..simulation import sample_poses

    check_output(args.out, "--out", inputs=[args.robot, args.candidates], prog="iwr plan",
                 own=PLAN_MARKER, in_existing_folder=True)
    robot = load_robot(args.robot)
    kind = for_robot(robot)
    footprint = Footprint.of(robot)
    # Each candidate pose once per payload: the rows plan_poses chooses from (a ballbar's once
    # per set-up too, which Footprint counts).
    per_pose = len(args.payload) if args.payload else 1
    if not args.candidates:
        check_memory("--n-candidates", args.n_candidates,
                     footprint.candidates(args.n_candidates * per_pose),
                     "the candidates' Jacobians and information matrices", "iwr plan")
        if not kind.setups_per_pose and args.poses > args.n_candidates * per_pose:
            # Known before the candidates are drawn (a ballbar's (pose, set-up) pairs are not).
            raise UsageError(f"--poses {args.poses}: more than the {args.n_candidates * per_pose} "
                             f"candidates to choose from (--n-candidates {args.n_candidates}"
                             f"{f', each with {per_pose} payloads' if per_pose > 1 else ''}); "
                             "give more candidates or fewer poses", "iwr plan")
    if args.candidates:
        if kind.recognises(args.candidates):
            # plan_poses takes the robot's own data as candidates (tracker data: their poses by
            # forward kinematics); the pose reader would stop at their columns.
            from ._base import read_data

            cand = read_data(args.candidates, robot, prog="iwr plan", effects=False)
        else:
            cand = Measurements.from_csv(args.candidates, robot=robot)
        source = str(args.candidates)
        # The file's size is its own; what planning on all of it needs is checked before it runs.
        check_memory("--candidates", args.candidates, footprint.candidates(len(cand) * per_pose),
                     f"its {len(cand)} candidate poses' Jacobians and information matrices",
                     "iwr plan")
    else:
        rng = np.random.default_rng(args.seed)
        q, poses, legs = sample_poses(robot.with_effects() if robot.effects else robot,
                                      args.n_candidates, rng)
        cand = Measurements(q, poses, legs, joint_types=robot.joint_types)
        source = f"{args.n_candidates} reachable poses sampled at random (seed {args.seed})"
    payloads = None
    temperatures = None
    if args.payload:
        if not robot.effects:
            raise CommandError(f"--payload: robot {robot.name!r} has no [effects.compliance] "
                               "table; payloads change nothing its geometry models")
        payloads = np.array(args.payload)
    thermal = [e for e in robot.effects if e.needs & {"temperatures", "machine_temperature"}]
    if thermal and cand.temperatures is None:
        # The temperatures are not chosen but met: a day's drift about the reference, as
        # iwr.simulate draws them (docs/effects.md).
        from ..effects.api import DEFAULT_TEMPERATURE_SPREAD

        lo, hi = (thermal[0].reference + d for d in DEFAULT_TEMPERATURE_SPREAD)
        temperatures = np.random.default_rng(args.seed).uniform(lo, hi, len(cand))
        print(f"temperatures: the {thermal[0].name} effect needs them at the candidates; drawn "
              f"uniformly in {lo:g} .. {hi:g} C (seed {args.seed})")
    elif thermal and args.candidates:  # the file's own: the columns the effects need, named
        from ._base import check_effect_inputs

        check_effect_inputs(robot, cand, args.candidates)
    # plan_poses refuses a --poses above the candidates' number (each pose once per payload;
    # a ballbar's (pose, set-up) pairs within the bar's range), or below what determines the base
    # parameters, before it plans: a bad option's value (exit 2), named with the candidates'.
    try:
        plan = plan_poses(robot, cand, args.poses, criterion=args.criterion, seed=args.seed,
                          **({"payloads": payloads, "temperatures": temperatures}
                             if robot.effects else {}))
    except ValueError as exc:
        msg = str(exc)
        if not msg.startswith("n_poses:"):
            raise CommandError(msg) from None
        given = (f"--candidates {args.candidates}" if args.candidates
                 else f"--n-candidates {args.n_candidates}")
        raise UsageError("--poses" + msg[7:].replace(
            "(the number of candidates)", f"(the number of candidates, of {given})"),
            "iwr plan") from None
    if args.candidates and not robot.effects:
        # The candidates' own rank sets the base parameters plan_poses keeps: candidates that
        # see fewer combinations than the robot has (8 poses, 48 readings, for the IWR's 52)
        # would give a plan no calibration can determine the robot from. (With effects the
        # base parameters leave out what only the loads fix, and --payload adds loads the
        # candidates do not have: the geometry's count is not theirs.)
        from ..experiments.harness import identifiable

        need = identifiable(robot)
        if plan.base_indices.size < need:
            raise UsageError(
                f"--candidates {args.candidates}: its {len(cand)} poses determine "
                f"{plan.base_indices.size} combinations of the parameters, of the "
                f"{need} that robot {robot.name!r} has on {kind.description} data: no plan from "
                "them can calibrate it; give more (and more varied) candidate poses, or none "
                "(--n-candidates samples them)", "iwr plan")
    plan.to_csv(args.out, source)
    print(f"candidates: {source}")
    print(plan)
    if payloads is not None:
        chosen = plan.measurements.payload
        counts = ", ".join(f"{int(np.sum(np.all(chosen == p, axis=1)))} with {p[0]:g} kg"
                           for p in payloads)
        print(f"payloads: {counts}")
    setups = getattr(plan.measurements, "setup", None)
    if setups is not None:  # a ballbar's: where to mount the bar at each pose (docs/ballbar.md)
        names, counts = np.unique(setups.astype(str), return_counts=True)
        print("set-ups: " + ", ".join(f"{c} poses in {n}" for n, c in zip(names, counts,
                                                                         strict=True)))
    spare = plan.redundancy()  # with the calibration job's default hold-out of a fifth
    if spare <= 0:
        from ..kinds import VALIDATION_FRACTION

        base = plan.base_indices.size
        print(f"note: iwr calibrate holds out {VALIDATION_FRACTION:.0%} of the poses for "
              f"validation (--validation-fraction {VALIDATION_FRACTION:g}): the others give "
              f"{spare + base} readings for {base} base parameters, none to test the fit with "
              "(with a noise model the job says \"not calibrated: no redundancy\"); plan "
              f"{plan.poses_for_redundancy()} poses or more, or "
              "calibrate with a validation file of its own (--validation)")
    _warn_few_validation_poses(robot, len(plan.indices))
    print(f"wrote {args.out}: the chosen poses to measure (joint readings and platform poses"
          f"{', and the set-up of each' if setups is not None else ''}); measure them, then "
          "calibrate with the measured file")
    return EXIT_OK


def _warn_few_validation_poses(robot: Any, n_poses: int) -> None:
    """Warn when the poses ``iwr calibrate`` holds out of the plan (a fifth by default) are
    too few for the verdict to tell a calibration twice as bad from chance (docs/kinds.md,
    "The verdict")."""
    # Here, as plan_poses is: `iwr --help` loads no command's SciPy (tests/test_startup.py).
    from .. import kinds
    from ..calibration import DETECT_RATIO, LEVEL, POWER, validation_poses_needed

    fraction = kinds.VALIDATION_FRACTION
    needed = validation_poses_needed(kinds.for_robot(robot).verdict_error_dims)
    held = kinds.split_rows(n_poses, fraction, 0)[1].size if n_poses > 1 else 0
    if held >= needed:
        return
    enough = n_poses
    while kinds.split_rows(enough, fraction, 0)[1].size < needed:
        enough += 1
    print(f"warning: iwr calibrate holds out {held} of these {n_poses} poses for validation "
          f"(a fifth, --validation-fraction {fraction:g}); its verdict's paired t-test needs "
          f"{needed} to refuse a calibration {DETECT_RATIO:g} times worse with "
          f"{POWER:.0%} probability (at {LEVEL:.0%}), and with fewer lets more bad calibrations "
          f"through as 'Unchanged'; plan {enough} poses or more, or calibrate with validation "
          "poses measured apart (--validation)", file=sys.stderr)
