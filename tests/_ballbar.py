"""The ballbar tests' one set-up (pyproject's ``pythonpath = ["tests"]`` makes it importable:
``from _ballbar import BARS, NOISE``): two set-ups of a double ballbar whose fixed balls stand on
the table within reach of the IWR's platform, the platform balls below it, the bar telescoping
from 300 to 700 mm; a third set-up; the leg and joint readings' noise and the bar's 1 um."""

from __future__ import annotations

from typing import Any

import iwr
from iwr.ballbar import BallbarNoise

#: Set-ups A and B (every ballbar test file's).
BARS: dict[str, dict[str, Any]] = {
    "A": {"platform_ball": [0.0, 0.0, -60.0], "fixed_ball": [800.0, -800.0, 1500.0],
          "range": [300.0, 700.0]},
    "B": {"platform_ball": [100.0, 50.0, -60.0], "fixed_ball": [900.0, -200.0, 2400.0],
          "range": [300.0, 700.0]},
}
#: A third set-up, C (tests/test_ballbar.py's three-bar robot).
BAR_C: dict[str, Any] = {"platform_ball": [-80.0, 60.0, -40.0],
                         "fixed_ball": [700.0, -1500.0, 1200.0], "range": [300.0, 700.0]}
#: The leg and joint readings' noise (iwr.Noise.realistic()'s, no pose measured in {0}).
READINGS = iwr.Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6)
#: The readings' noise and the bar's 1 um.
NOISE = (READINGS, BallbarNoise(0.001))


def with_offset(offset: float, bars: dict[str, dict[str, Any]] = BARS) -> dict[str, Any]:
    """``bars`` with set-up B's length offset ``offset`` (mm) (a bar whose nominal offset is not
    0: the engine files' tests)."""
    return {**bars, "B": {**bars["B"], "offset": offset}}


def ballbar_robot(bars: dict[str, dict[str, Any]] = BARS,
                  base: iwr.Robot | None = None) -> iwr.Robot:
    """``base`` (default: the default IWR) measured by a double ballbar in ``bars``."""
    return (iwr.Robot.default() if base is None else base).with_instrument("ballbar", bars)
