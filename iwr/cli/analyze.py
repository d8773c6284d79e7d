"""``iwr analyze``: which parameters the measurements can identify."""

from __future__ import annotations

import argparse
from typing import Any

from ._base import EXIT_OK, add_common, load_robot, read_data
from .tracker import add_arguments as add_tracker_arguments
from .tracker import target_format


def add_parser(sub: Any) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "analyze", help="which parameters the measurements can identify",
        description="Print the identifiability report of ROBOT.toml on the poses of DATA.csv "
        "(iwr.identifiability): the rank and conditioning of the identification Jacobian, "
        "observability indices, the unidentifiable combinations of parameters and a set of base "
        "parameters. For a robot with a [tracker] table, DATA are its tracker data and the "
        "report covers the registration and the reflector (probe) offsets too, with one null "
        "direction per parameter held (docs/tracker.md).",
    )
    p.add_argument("robot", metavar="ROBOT.toml", help="the nominal robot")
    p.add_argument("data", metavar="DATA.csv", help="the measurements")
    add_tracker_arguments(p)  # --readings: tracker data as a long table
    p.add_argument("--result", metavar="RESULT.json",
                   help="analyse at an identified error vector (default: the nominal robot)")
    add_common(p)
    p.set_defaults(func=cmd_analyze)
    return p


def cmd_analyze(args: argparse.Namespace) -> int:
    from ..analysis.identifiability import identifiability
    from ..kinds import for_robot
    from ..methods import load_result

    robot = load_robot(args.robot)
    data = read_data(args.data, robot, args.readings, targets=target_format(args),
                     prog="iwr analyze")
    x = None
    if args.result:
        from .report import check_result_file

        # iwr report's check: the robot's parameters (its effects' and set-up's included), in
        # order, finite, a calibrated robot within the physical limits.
        x = check_result_file(args.result, load_result(args.result), args.robot, robot,
                              for_robot(robot))
    print(identifiability(robot, data, x))
    return EXIT_OK
