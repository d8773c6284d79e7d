"""Laser-tracker data as measurement kinds (docs/tracker.md): reflector points, or a probe's
pose, measured in the tracker frame {T}; the registration {0} -> {T} and the reflector (probe)
offsets are identified beside the robot, and the data do not fix {0}."""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from ..estimation import tracker_readings
from ..forward import forward_kinematics
from ..kinds import MeasurementKind, data_fingerprint
from ..measurements import Measurements
from ..planning import measure_tracker, tracker_design
from ..uncertainty import _tracker_uncertainty
from .api import (
    tracker_accuracy,
    tracker_identifiability,
    tracker_identify,
    tracker_problem,
    tracker_simulate,
)
from .data import TrackerMeasurements
from .estimation import TrackerSpec, tracker_misclosures
from .files import read_tracker_data
from .problem import TrackerProblem

__all__ = ["PointsKind", "ProbeKind"]


class _TrackerKind(MeasurementKind):
    frame = "{T}"
    determines_world_frame = False

    def owns(self, data: Any) -> bool:
        return isinstance(data, TrackerMeasurements)

    def applies_to(self, robot: Any) -> bool:
        tracker = getattr(robot, "tracker", None)
        return tracker is not None and tracker.kind == self.name

    def _setup_hint(self) -> str:
        return ("describe the tracker setup with robot.with_tracker(...) or a [tracker] table in "
                "the robot's TOML file (docs/tracker.md)")

    def setup_parameter_names(self, robot: Any) -> list[str]:
        return list(robot.tracker.parameter_names)

    def fingerprint(self, robot: Any, data: Any) -> str:
        self.check(robot, data)
        return data_fingerprint(self.name, robot, data, probe_poses=data.probe,
                                points=data.tracker_points(robot.tracker))

    def read(self, path: str | os.PathLike[str], robot: Any, **options: Any) -> Any:
        readings = options.pop("readings", None)
        targets = options.pop("targets", None)  # a target list's format (iwr.tracker.sa_export)
        given = sorted(k for k, v in options.items() if v is not None)
        if given:
            raise TypeError(f"--{given[0]}: not an option of {self.name} data")
        return read_tracker_data(path, robot.tracker, readings, targets)

    def simulate(self, robot: Any, n_poses: int, *, seed: int | None, x: Any = None,
                 noise: Any = None) -> tuple[Any, np.ndarray]:
        return tracker_simulate(robot, n_poses, seed=seed, x=x, noise=noise)

    def problem(self, robot: Any, data: Any, bounds: Any = None, x0: Any = None
                ) -> tuple[Any, np.ndarray]:
        return tracker_problem(robot, data, bounds, x0)

    def identify(self, robot: Any, data: Any, method: str, **options: Any) -> Any:
        if options.pop("weighted", None):
            raise ValueError("weighted=True: the noise-weighted objective is for leg data "
                             "(poses in {0}); tracker data are weighted by the efficient "
                             "estimator (noise=..., docs/estimation.md)")
        return tracker_identify(robot, data, method, **options)

    def accuracy(self, robot: Any, data: Any, x: Any, **options: Any) -> Any:
        return tracker_accuracy(robot, data, x, truth=options.get("truth"),
                                tool=options.get("tool"))

    def identifiability(self, robot: Any, data: Any, x: Any = None, **options: Any) -> Any:
        return tracker_identifiability(robot, data, x, rtol=options.get("rtol"))

    def uncertainty(self, robot: Any, data: Any, x: Any, noise: Any, **options: Any) -> Any:
        return _tracker_uncertainty(robot, data, x, noise, options.get("active"))

    def estimator(self, robot: Any, data: Any, noise: Any, **options: Any) -> Any:
        return TrackerSpec(robot, data, noise, options["x0"], options["active"],
                           options["estimate"], options["bounds"], options["plausible"])

    def plausibility(self, robot: Any, data: Any, bounds: Any, plausible: float
                     ) -> tuple[list[str], np.ndarray, np.ndarray, Any]:
        tp = TrackerProblem(robot, robot.tracker, data, bounds)
        centre = 0.5 * (tp.lower + tp.upper)
        limit = plausible * 0.5 * (tp.upper - tp.lower)
        return tp.parameter_names, limit, centre, tracker_readings(tp)

    def misclosures(self, robot: Any, data: Any, x: Any, noise: Any = None) -> Any:
        return tracker_misclosures(robot, data, x, noise)

    def candidate_poses(self, robot: Any, data: Any) -> Any:
        # Tracker data hold no world pose: the nominal robot's forward kinematics gives it.
        poses = forward_kinematics(robot, np.zeros(robot.n_params), data.q, data.legs)
        return Measurements(data.q, poses, data.legs, joint_types=robot.joint_types)

    def design(self, robot: Any, candidates: Any, x: Any, report: Any
               ) -> tuple[Any, np.ndarray, np.ndarray, int, str]:
        return tracker_design(robot, candidates, x, report)

    def measure(self, robot: Any, x: np.ndarray, q: np.ndarray, poses: np.ndarray, noise: Any,
                rng: np.random.Generator) -> Any:
        return measure_tracker(robot, x, q, poses, noise, rng)


class PointsKind(_TrackerKind):
    """Reflector positions measured by a laser tracker in its frame {T}."""

    name = "points"
    description = "reflector points"


class ProbeKind(_TrackerKind):
    """The pose of a tracker probe (a 6-DOF target) measured in the tracker frame {T}."""

    name = "probe"
    description = "the probe's pose"
