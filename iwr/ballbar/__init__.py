"""The double ballbar as a measurement kind (docs/ballbar.md): a telescoping bar between a ball
on the platform (centre in {5}) and a ball in a cup fixed on the base or the table (centre in
{0}) reads one distance per pose. Each bar set-up's two ball centres and its length offset are
identified beside the robot's errors."""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._hooks import lazy_package

if TYPE_CHECKING:  # the same names for type checkers (and for tools/layers.py)
    from .api import (
        ballbar_accuracy,
        ballbar_identifiability,
        ballbar_identify,
        ballbar_problem,
        ballbar_uncertainty,
        gauge_aligned,
        reading_sigmas,
        reading_std,
    )
    from .data import BallbarMeasurements
    from .files import read_ballbar, write_ballbar
    from .problem import BallbarProblem
    from .setup import BallbarSetup, BarSetup
    from .simulate import BallbarNoise, simulate_ballbar

# Imported on first use (PEP 562): the data modules of this package sit in a low layer
# (iwr.robot imports iwr.tracker.setup), its public functions in a high one (tools/layers.py).
_LAZY = {
    "ballbar_accuracy": ".api",
    "ballbar_identifiability": ".api",
    "ballbar_identify": ".api",
    "ballbar_problem": ".api",
    "ballbar_uncertainty": ".api",
    "gauge_aligned": ".api",
    "reading_sigmas": ".api",
    "reading_std": ".api",
    "BallbarMeasurements": ".data",
    "read_ballbar": ".files",
    "write_ballbar": ".files",
    "BallbarProblem": ".problem",
    "BallbarSetup": ".setup",
    "BarSetup": ".setup",
    "BallbarNoise": ".simulate",
    "simulate_ballbar": ".simulate",
}

_SUBMODULES = (
    "api", "data", "effects", "estimation", "files", "kind", "problem", "setup", "simulate",
)

__getattr__, __dir__ = lazy_package(__name__, _LAZY, _SUBMODULES)

__all__ = [
    "BallbarMeasurements",
    "BallbarNoise",
    "BallbarProblem",
    "BallbarSetup",
    "BarSetup",
    "ballbar_accuracy",
    "ballbar_identifiability",
    "ballbar_identify",
    "ballbar_problem",
    "ballbar_uncertainty",
    "gauge_aligned",
    "read_ballbar",
    "reading_sigmas",
    "reading_std",
    "simulate_ballbar",
    "write_ballbar",
]
