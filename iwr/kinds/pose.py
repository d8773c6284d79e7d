"""The paper's data as a measurement kind: the platform pose measured in the world frame {0}
beside the joint and leg readings (:class:`iwr.Measurements`, docs/data.md)."""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from ..accuracy_prediction import predicted_accuracy
from ..analysis.accuracy import pose_accuracy
from ..analysis.identifiability import parameter_error, pose_identifiability
from ..analysis.uncertainty import pose_uncertainty
from ..effects.job import diagnose
from ..estimation import _PoseSpec, pose_misclosures
from ..fit_test import _plausible_limit, leg_readings
from ..implicit_loop import _check_noise, loop_jacobians, sigma_matrix
from ..measurements import Measurements
from ..methods import pose_identify
from ..planning import measure_poses, pose_design
from ..pose_frame import check_pose_frame
from ..problem import Problem
from ..simulation import simulate_poses
from ..tracker.files import tracker_file_format
from . import MeasurementKind, data_fingerprint

__all__ = ["PoseKind"]


class PoseKind(MeasurementKind):
    """The platform pose measured in {0}: six leg residuals per pose (eq. 10), no setup
    parameters, and the world frame fixed by the data."""

    name = "pose"
    description = "the platform pose"
    frame = "{0}"
    determines_world_frame = True
    chi2_fit_test = True
    fallback = True
    weighted_objective = True
    models_effects = True
    #: The figures of iwr compare and iwr study on pose data (MeasurementKind.experiment_text).
    experiment_text = {
        "cost": "eq. (10), the sum of squared leg residuals (mm^2)",
        "cost_label": "eq. (10)",
        "readings_short": "leg",
        "tool_short": "",
        "readings": "leg readings predicted with the recovered parameters against their exact "
                    "(noise-free) values (mm)",
        "tool": "tool pose error by forward kinematics of the readings against the exact platform "
                "pose in {0} (iwr.accuracy)",
        "parameters": "x minus the parameter vector nearest to x that predicts exactly the truth's "
                      "readings at the validation poses (the yardstick of what is identifiable), "
                      "projected onto the identifiable directions (iwr.parameter_error)",
        "noise_panel": "noise {level:g} mm",  # the level is the tracker's position sd
        "noise_axis": "noise level: tracker sd (mm)",
        "noise_unit": " mm",
        "noise_level": "the tracker's position sd (mm), the other channels in the proportions of "
                       "iwr.Noise.realistic() (level 0.02)",
        "gauge": "",
    }

    def owns(self, data: Any) -> bool:
        return isinstance(data, Measurements)

    def applies_to(self, robot: Any) -> bool:
        # No instrument described: neither a tracker nor another kind's set-up.
        return getattr(robot, "tracker", None) is None and not getattr(robot, "instruments", {})

    def setup_parameter_names(self, robot: Any) -> list[str]:
        return []

    def fingerprint(self, robot: Any, data: Any) -> str:
        return data_fingerprint(self.name, robot, data, poses=data.poses, weights=data.weights)

    def measured(self, data: Any) -> np.ndarray:
        return np.asarray(data.poses, dtype=float)

    def read(self, path: str | os.PathLike[str], robot: Any, **options: Any) -> Any:
        given = sorted(k for k, v in options.items() if v is not None)
        if given:
            option = {"targets": "target-names, --target-columns, --target-units"}.get(
                given[0], given[0])
            raise TypeError(f"--{option}: only for a robot with a [tracker] table; robot "
                            f"{robot.name!r} measures the platform pose in {{0}}")
        what = tracker_file_format(path)
        if what is not None:
            # TypeError: data of another kind for this robot, a usage mistake (as an option the
            # kind's files do not take), not a bad file.
            raise TypeError(
                f"{path}: laser-tracker data ({what}), but robot {robot.name!r} has no "
                "[tracker] table describing the setup (registration, reflectors or probe): add "
                "one (docs/tracker.md)")
        return Measurements.from_csv(path, robot=robot)

    def simulate(self, robot: Any, n_poses: int, *, seed: int | None, x: Any = None,
                 noise: Any = None) -> tuple[Any, np.ndarray]:
        if robot.effects:  # issue 23: loads, temperatures and the effects (docs/effects.md)
            from ..effects.api import simulate as simulate_effects

            return simulate_effects(robot, n_poses, seed=seed, x=x, noise=noise)
        return simulate_poses(robot, n_poses, seed=seed, x=x, noise=noise)

    def problem(self, robot: Any, data: Any, bounds: Any = None, x0: Any = None,
                noise: Any = None) -> tuple[Any, np.ndarray]:
        problem = Problem(robot, data, bounds, noise=noise)
        start = np.zeros(problem.n_params) if x0 is None else np.array(x0, dtype=float)
        return problem, start

    def identify(self, robot: Any, data: Any, method: str, **options: Any) -> Any:
        return pose_identify(robot, data, method, **options)

    def accuracy(self, robot: Any, data: Any, x: Any, **options: Any) -> Any:
        options.pop("start", None)  # pose data's "before" is the nominal robot
        if robot.effects:  # issue 23: the forward kinematics under each pose's load and temperature
            from ..effects.job import accuracy as effect_accuracy

            if options.pop("truth", None) is not None:
                raise ValueError("truth: only for tracker data (iwr.tracker.TrackerMeasurements)")
            return effect_accuracy(robot, data, x, **options)
        return pose_accuracy(robot, data, x, **options)

    def identifiability(self, robot: Any, data: Any, x: Any = None, **options: Any) -> Any:
        if robot.effects:  # issue 23: the geometry and the effects' parameters together
            from ..effects.api import identifiability as effect_identifiability

            if options.get("selection", "ordered") != "ordered":
                raise ValueError(f"selection: {options['selection']!r}; a robot with effects "
                                 "has the 'ordered' rule only")
            return effect_identifiability(robot, data, x, rtol=options.get("rtol"))
        return pose_identifiability(robot, data, x, **options)

    def uncertainty(self, robot: Any, data: Any, x: Any, noise: Any, **options: Any) -> Any:
        return pose_uncertainty(robot, data, x, noise, **options)

    def estimator(self, robot: Any, data: Any, noise: Any, **options: Any) -> Any:
        if robot.effects:  # issue 23: the loop closure with the effects (numpy solver)
            from ..effects.estimation import EffectPoseSpec

            return EffectPoseSpec(robot, data, noise, options["x0"], options["active"],
                                  options["estimate"], options["bounds"], options["plausible"])
        return _PoseSpec(robot, data, noise, options["x0"], options["active"],
                         options["estimate"], options["bounds"], options["plausible"])

    def plausibility(self, robot: Any, data: Any, bounds: Any, plausible: float
                     ) -> tuple[list[str], np.ndarray, Any, Any]:
        if robot.effects:  # issue 23: the effects' parameters judged against their own bounds
            from ..effects.problem import EffectProblem

            problem = EffectProblem(robot, data, bounds)
            limit = plausible * np.maximum(np.abs(problem.lower), np.abs(problem.upper))
            return (problem.parameter_names, limit, None,
                    lambda x: problem.residuals_and_jacobian(x))
        return (robot.parameter_names, _plausible_limit(robot, plausible, bounds), None,
                leg_readings(robot, data))

    def whitened(self, robot: Any, data: Any, x: Any, noise: Any
                 ) -> tuple[np.ndarray, np.ndarray, int]:
        """The six leg residuals of each pose and their Jacobian, whitened by their covariance
        ``C_k = diag(sigma_legs^2) + J_y diag(sigma_y^2) J_y^T`` (every other reading's noise
        propagated through the loop closure, :func:`iwr.estimation.loop_jacobians`)."""
        _check_noise(noise)
        legs, jx, jy = loop_jacobians(robot, x, data.q, data.poses, data=data)
        sig = sigma_matrix(robot, data, noise)
        cov = np.einsum("kij,kj,klj->kil", jy, sig[:, 6:] ** 2, jy)
        cov[:, np.arange(6), np.arange(6)] += sig[:, :6] ** 2
        chol = np.linalg.cholesky(cov)
        rw = np.linalg.solve(chol, (legs - data.legs)[..., None])[..., 0].reshape(-1)
        jw = np.linalg.solve(chol, jx).reshape(-1, jx.shape[2])
        return rw, jw, rw.size

    def misclosures(self, robot: Any, data: Any, x: Any, noise: Any = None) -> Any:
        # With effects (issue 23) too: loop_jacobians' exact derivatives under each pose's load
        # and temperature.
        return pose_misclosures(robot, data, x, noise)

    def candidate_poses(self, robot: Any, data: Any) -> Any:
        return data

    def readings_per_pose(self, robot: Any, data: Any) -> float:
        return 6.0

    def parameter_error(self, robot: Any, data: Any, x: Any, truth: Any) -> Any:
        """:func:`iwr.parameter_error` (the robot's parameters; the truth's legs recomputed, so
        any poses will do)."""
        return parameter_error(robot, data, x, truth)

    def design(self, robot: Any, candidates: Any, x: Any, report: Any
               ) -> tuple[Any, np.ndarray, np.ndarray, int, str]:
        return pose_design(robot, candidates, x, report)

    def measure(self, robot: Any, x: np.ndarray, q: np.ndarray, poses: np.ndarray, noise: Any,
                rng: np.random.Generator) -> Any:
        return measure_poses(robot, x, q, poses, noise, rng)

    def diagnose(self, robot: Any, data: Any, x: Any, *, active: Any = None,
                 noise: Any = None) -> Any:
        return diagnose(robot, data, x, active=active, noise=noise)

    def frame_check(self, robot: Any, data: Any) -> Any:
        return check_pose_frame(robot, data)

    def predicted_accuracy(self, robot: Any, data: Any, x: Any, covariance: Any, active: Any,
                           seed: int) -> Any:
        return predicted_accuracy(robot, data, x, covariance, active=active, seed=seed)
