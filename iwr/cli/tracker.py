"""``iwr calibrate`` and ``iwr simulate`` for a robot with a laser tracker (docs/tracker.md):
the robot's TOML has a ``[tracker]`` table and the data are points (or probe poses) in the
tracker's frame."""

from __future__ import annotations

import argparse
from typing import Any

from ._base import (
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
