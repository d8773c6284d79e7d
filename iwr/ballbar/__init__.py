"""The double ballbar as a measurement kind (docs/ballbar.md): a telescoping bar between a ball
on the platform (centre in {5}) and a ball in a cup fixed on the base or the table (centre in
{0}) reads one distance per pose. Each bar set-up's two ball centres and its length offset are
identified beside the robot's errors."""

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
