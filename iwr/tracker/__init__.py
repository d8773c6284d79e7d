"""Laser-tracker data: reflector points (or a 6-DOF probe) measured in the tracker's own frame,
with the registration and the offsets identified beside the robot's errors (docs/tracker.md).

    setup = TrackerSetup(registration=(2000, 0, 0, pi / 2, 0, 0), reflectors=[(100, 0, 30), ...])
    data, truth = simulate_tracker(robot, setup, 100, seed=1, tracker_noise=TrackerNoise.leica())
    guess = guess_registration(robot, setup, data)             # Kabsch: no registration needed
    problem = TrackerProblem(robot, setup, data, center=guess.x_setup)
    x0 = problem.x0(guess)
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._hooks import lazy_package

if TYPE_CHECKING:  # the same names for type checkers (and for tools/layers.py)
    from .analysis import (
        NullSpace,
        calibrated_robot,
        fix_platform_frame,
        null_space,
        tool_frames,
        tool_pose_errors,
    )
    from .api import (
        tracker_accuracy,
        tracker_forward_kinematics,
        tracker_identifiability,
        tracker_identify,
        tracker_problem,
        tracker_simulate,
    )
    from .data import TrackerMeasurements
    from .files import is_tracker_file, read_tracker_data, write_tracker_long, write_tracker_wide
    from .problem import FAILED_RESIDUAL, TrackerProblem, point_covariances
    from .registration import RegistrationError, RegistrationGuess, guess_registration, kabsch
    from .setup import TrackerSetup
    from .simulate import TrackerNoise, perturb_measurements, simulate_tracker, true_points

# Imported on first use (PEP 562): the data modules of this package sit in a low layer
# (iwr.robot imports iwr.tracker.setup), its public functions in a high one (tools/layers.py).
_LAZY = {
    "NullSpace": ".analysis",
    "fix_platform_frame": ".analysis",
    "calibrated_robot": ".analysis",
    "null_space": ".analysis",
    "tool_frames": ".analysis",
    "tool_pose_errors": ".analysis",
    "tracker_accuracy": ".api",
    "tracker_forward_kinematics": ".api",
    "tracker_identifiability": ".api",
    "tracker_identify": ".api",
    "tracker_problem": ".api",
    "tracker_simulate": ".api",
    "TrackerMeasurements": ".data",
    "is_tracker_file": ".files",
    "read_tracker_data": ".files",
    "write_tracker_long": ".files",
    "write_tracker_wide": ".files",
    "FAILED_RESIDUAL": ".problem",
    "TrackerProblem": ".problem",
    "point_covariances": ".problem",
    "RegistrationError": ".registration",
    "RegistrationGuess": ".registration",
    "guess_registration": ".registration",
    "kabsch": ".registration",
    "TrackerSetup": ".setup",
    "TrackerNoise": ".simulate",
    "perturb_measurements": ".simulate",
    "simulate_tracker": ".simulate",
    "true_points": ".simulate",
}

_SUBMODULES = (
    "analysis", "api", "data", "estimation", "files", "gauge", "kind", "problem", "registration",
    "sa_export", "setup", "simulate", "start",
)

__getattr__, __dir__ = lazy_package(__name__, _LAZY, _SUBMODULES)

__all__ = [
    "FAILED_RESIDUAL",
    "NullSpace",
    "RegistrationError",
    "RegistrationGuess",
    "TrackerMeasurements",
    "TrackerNoise",
    "TrackerProblem",
    "TrackerSetup",
    "fix_platform_frame",
    "calibrated_robot",
    "guess_registration",
    "is_tracker_file",
    "read_tracker_data",
    "tracker_accuracy",
    "tracker_forward_kinematics",
    "tracker_identifiability",
    "tracker_identify",
    "tracker_problem",
    "tracker_simulate",
    "write_tracker_long",
    "write_tracker_wide",
    "kabsch",
    "null_space",
    "perturb_measurements",
    "point_covariances",
    "simulate_tracker",
    "tool_frames",
    "tool_pose_errors",
    "true_points",
]
