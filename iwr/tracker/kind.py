"""Laser-tracker data as measurement kinds (docs/tracker.md): reflector points, or a probe's
pose, measured in the tracker frame {T}; the registration {0} -> {T} and the reflector (probe)
offsets are identified beside the robot, and the data do not fix {0}."""

from __future__ import annotations

import os
from dataclasses import asdict
from typing import Any

import numpy as np

from ..analysis.identifiability import kind_parameter_error
from ..analysis.uncertainty import _tracker_uncertainty
from ..effects.gravity import registration_gravity
from ..fit_test import tracker_readings
from ..forward import forward_kinematics
from ..kinds import MeasurementKind, _where, data_fingerprint, position_rms
from ..measurements import Measurements
from ..noise import Noise, TrackerNoise, instrument_level, split_noise
from ..planning import measure_tracker, tracker_design
from .api import (
    registration_guess,
    tracker_accuracy,
    tracker_identifiability,
    tracker_identify,
    tracker_problem,
    tracker_simulate,
)
from .data import TrackerMeasurements
from .estimation import TrackerSpec, tracker_misclosures
from .files import read_tracker_data, tracker_file_format
from .problem import TrackerProblem, noise_whitening, observations
from .start import before_x0

__all__ = ["PointsKind", "ProbeKind"]

_GAUGE = ("Tracker data do not fix {0} nor {5} (docs/tracker.md): every figure here is "
          "gauge-invariant (the residuals, the tool pose aligned with the truth's and the "
          "projected parameter error do not move along the null directions); the raw parameter "
          "error is not.")


class _TrackerKind(MeasurementKind):
    frame = "{T}"
    frame_link = "tracker"
    determines_world_frame = False
    models_effects = True  # issue 23: the point (probe) objective with the effects (numpy)
    weighted_objective = True  # the points' covariance (a probe's: rank 6), noise_whitening
    chi2_fit_test = True
    report = "iwr.reporting.tracker_calibration:TrackerCalibrationReport"
    setup_words = "its tracker setup"
    #: The figures of iwr compare and iwr study on tracker data (MeasurementKind.experiment_text).
    experiment_text = {
        **MeasurementKind.experiment_text,  # the noise level's words (noise_panel, ...)
        "cost": "the sum of squared point residuals in {T}, predicted minus measured (mm^2)",
        "cost_label": "point residuals in {T}",
        "readings_short": "point ({T})",
        "tool_short": " modulo the gauge",
        "readings": "points in {T} predicted with the recovered parameters (robot, registration "
                    "and offsets) against their exact values (mm; the nominal robot's in the "
                    "closed-form registration guess the identification started from, as "
                    "iwr calibrate's 'before')",
        "gauge": _GAUGE,
        "tool": "tool pose error against the truth by forward kinematics of the readings, in {T}, "
                "modulo the gauge (iwr.tracker.tool_pose_errors, gauge='fit': the model's platform "
                "frame moved by the one rigid transform that best aligns it with the truth's over "
                "the validation poses); the nominal robot's in the registration guess the "
                "identification started from",
        "parameters": "x minus the parameter vector nearest to x that predicts exactly the truth's "
                      "points at the validation poses, projected onto the directions the points "
                      "see (the registration and the offsets included; the gauge and the robot's "
                      "unidentifiable combinations removed)",
        "noise_level": "the leg and joint readings' noise scaled from iwr.Noise.realistic() and "
                       "the tracker's from TrackerNoise.leica(), both by level / 0.02 (level 0.02 "
                       "is the realistic model)",
    }

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

    def measured(self, data: Any) -> np.ndarray:
        return np.asarray(data.points if data.points is not None else data.probe, dtype=float)

    def write(self, robot: Any, data: Any, path: str | os.PathLike[str]) -> list[str]:
        """The wide CSV (readings and points, or probe poses), and for points also the long pair
        (a table of points and a log of readings) beside it: ``STEM_long.csv`` and
        ``STEM_readings.csv``."""
        from pathlib import Path

        from .files import write_tracker_long, write_tracker_wide

        write_tracker_wide(path, robot.tracker, data)
        written = [f"{path} (wide: readings and points)"]
        if robot.tracker.kind == "points":
            stem = Path(path).with_suffix("")
            pts, rd = Path(f"{stem}_long.csv"), Path(f"{stem}_readings.csv")
            write_tracker_long(pts, rd, robot.tracker, data)
            written.append(f"{pts} + {rd} (the same as a long table of points and a log of "
                           "readings)")
        return written

    def diagnose(self, robot: Any, data: Any, x: Any, *, active: Any = None,
                 noise: Any = None) -> Any:
        from ..effects.tracker_diagnosis import diagnose

        return diagnose(robot, data, x, active=active, noise=noise)

    def noise_record(self, noise: Any) -> dict[str, Any]:
        readings, tracker = split_noise(noise)
        return {"noise": None if readings is None else asdict(readings),
                "tracker_noise": None if tracker is None else asdict(tracker)}

    def noise_from_record(self, record: dict[str, Any]) -> Any:
        readings, tracker = record.get("noise"), record.get("tracker_noise")
        if isinstance(readings, dict) and set(readings) == {"readings", "tracker"}:
            # A weighted result written before the kinds' one noise record (iwr 0.1, Nov 2026).
            readings, tracker = readings["readings"], readings["tracker"]
        return (None if readings is None else Noise(**readings),
                None if tracker is None else TrackerNoise(**tracker))

    def read(self, path: str | os.PathLike[str], robot: Any, **options: Any) -> Any:
        readings = options.pop("readings", None)
        targets = options.pop("targets", None)  # a target list's format (iwr.tracker.sa_export)
        given = sorted(k for k, v in options.items() if v is not None)
        if given:
            raise TypeError(f"--{given[0]}: not an option of {self.name} data")
        return read_tracker_data(path, robot.tracker, readings, targets)

    def recognises(self, path: str | os.PathLike[str]) -> bool:
        return tracker_file_format(path) is not None

    def simulate(self, robot: Any, n_poses: int, *, seed: int | None, x: Any = None,
                 noise: Any = None) -> tuple[Any, np.ndarray]:
        if robot.effects:  # issue 23: loads, temperatures, gravity through the registration
            from ..effects.tracker import simulate as simulate_effects

            return simulate_effects(robot, n_poses, seed=seed, x=x, noise=noise)
        return tracker_simulate(robot, n_poses, seed=seed, x=x, noise=noise)

    def problem(self, robot: Any, data: Any, bounds: Any = None, x0: Any = None,
                noise: Any = None) -> tuple[Any, np.ndarray]:
        if robot.effects:  # issue 23: the point objective with the effects (its cost in C++)
            from ..effects.tracker import effect_tracker_problem

            return effect_tracker_problem(robot, data, bounds, x0, noise=noise)
        return tracker_problem(robot, data, bounds, x0, noise=noise)

    def registration(self, robot: Any, x_setup: Any = None) -> np.ndarray:
        return robot.tracker.registration_matrix(x_setup)

    def calibrated_robot(self, robot: Any, x: Any) -> tuple[Any, dict[str, Any]]:
        """With the calibrated ``[tracker]`` table, and {5} moved to the frame the measured
        points fix (:func:`iwr.tracker.calibrated_robot`: the data do not fix {5}), named as
        the file's ``platform_frame``."""
        from .analysis import calibrated_robot

        out, frame = calibrated_robot(robot, x)
        return out, {"platform_frame": frame}

    def world_gravity(self, robot: Any) -> np.ndarray:
        """The tracker's gravity (``[tracker] gravity``, in {T}) carried into {0} by the robot
        file's registration (the effects' own ``gravity_m_s2`` in {0} is not used on tracker
        data): the statics of the legs and the carriage's joint loads alike."""
        return registration_gravity(robot.tracker, np.zeros(robot.tracker.n_params))[0]

    def whitened(self, robot: Any, data: Any, x: Any, noise: Any
                 ) -> tuple[np.ndarray, np.ndarray, int]:
        """The point residuals of each pose and their Jacobian, whitened by their covariance at
        ``x`` (:func:`iwr.tracker.problem.noise_whitening`: the tracker's noise of each point,
        or of the probe's pose, plus the leg and joint readings' propagated through the loop
        closure); the readings that carry data are the seen points' coordinates (a probe's:
        six per pose)."""
        readings, tracker = split_noise(noise)
        if tracker is None and data.point_sigma is None:
            raise ValueError("noise: the chi-square test on tracker data needs the tracker's "
                             "noise: give noise=(iwr.Noise(...), iwr.tracker.TrackerNoise(...))")
        x = np.asarray(x, dtype=float)
        tp, _ = self.problem(robot, data, None, x)  # with the effects, if any (issue 23)
        n = tp.n_poses
        w = noise_whitening(tp, x, readings, tracker)
        r, jac = tp.residuals_and_jacobian(x)
        rw = np.einsum("kij,kj->ki", w, r.reshape(n, -1)).reshape(-1)
        jw = np.einsum("kij,kjp->kip", w, jac.reshape(n, -1, jac.shape[1]))
        return rw, jw.reshape(-1, jac.shape[1]), observations(w, tp.n_observations)

    # -- the experiments ------------------------------------------------------------------------

    def experiment_noise(self, robot: Any, noise: Any) -> Any:
        """``(Noise, TrackerNoise)``: a pair as it is; an :class:`iwr.Noise` (an experiment's
        noise level, :func:`iwr.experiments.harness.noise_at`) keeps its leg and joint noise, and
        its ``position`` sets the tracker's: :meth:`TrackerNoise.leica` scaled by ``position /
        0.02`` (``Noise.realistic().position``), so that the realistic level is Leica's tracker."""
        if isinstance(noise, tuple):
            split_noise(noise)  # its types checked
            return noise
        if not isinstance(noise, Noise):
            raise TypeError(f"noise: expected an iwr.Noise or a pair (iwr.Noise, "
                            f"iwr.tracker.TrackerNoise), got {type(noise).__name__}")
        readings, scale = instrument_level(noise, "the tracker", "TrackerNoise.leica()")
        leica = TrackerNoise.leica()
        tracker = TrackerNoise(**{k: v * scale for k, v in asdict(leica).items()})
        return readings, tracker

    def draw_setup(self, robot: Any, rng: np.random.Generator) -> np.ndarray:
        """Uniform within the setup's default bounds about the nominal setup (as
        :func:`iwr.simulate` draws it)."""
        lo, hi = robot.tracker.default_bounds()
        return lo + (hi - lo) * rng.random(lo.size)

    def angle_parameters(self, robot: Any) -> np.ndarray:
        from ..effects import parameter_names as effect_names

        # The effects' parameters (issue 23) between the robot's and the setup's: none an angle.
        return np.concatenate([robot.angle_parameters,
                               np.zeros(len(effect_names(robot.effects)), dtype=bool),
                               robot.tracker.angle_parameters])

    def tool_accuracy(self, robot: Any, data: Any, x: Any, truth: Any, start: Any = None) -> Any:
        return self.accuracy(robot, data, x, truth=truth, start=start)

    def before(self, robot: Any, data: Any, start: Any = None) -> tuple[Any, np.ndarray]:
        """The nominal robot (and effects) in the registration guess ``start`` (a
        :class:`iwr.tracker.registration.RegistrationGuess`, no guess made on ``data``: one
        fitted to validation poses flatters the nominal robot, :func:`tracker_accuracy`), or in
        the guess on ``data`` when None."""
        from ..effects import parameter_names as effect_names

        n = robot.n_params + len(effect_names(robot.effects))
        return self.problem(robot, data, x0=before_x0(n, start))

    def parameter_error(self, robot: Any, data: Any, x: Any, truth: Any) -> Any:
        """Over the robot's and the setup's parameters, modulo the null directions of the point
        (probe) objective on ``data`` (the gauge among them)."""
        return kind_parameter_error(self, robot, data, x, truth)

    def identify(self, robot: Any, data: Any, method: str, **options: Any) -> Any:
        if robot.effects:  # issue 23: the point objective with the effects (its cost in C++)
            from ..effects.tracker import identify as identify_effects

            return identify_effects(robot, data, method, **options)
        return tracker_identify(robot, data, method, **options)

    def accuracy(self, robot: Any, data: Any, x: Any, **options: Any) -> Any:
        if robot.effects:  # issue 23: forward kinematics under each pose's load and temperature
            from ..effects.tracker import accuracy as accuracy_effects

            return accuracy_effects(robot, data, x, truth=options.get("truth"),
                                    tool=options.get("tool"), start=options.get("start"))
        return tracker_accuracy(robot, data, x, truth=options.get("truth"),
                                tool=options.get("tool"), start=options.get("start"))

    def identifiability(self, robot: Any, data: Any, x: Any = None, **options: Any) -> Any:
        if robot.effects:  # issue 23: the null directions of the objective with the effects
            from ..effects.tracker import identifiability as identifiability_effects

            return identifiability_effects(robot, data, x, rtol=options.get("rtol"))
        return tracker_identifiability(robot, data, x, rtol=options.get("rtol"))

    def uncertainty(self, robot: Any, data: Any, x: Any, noise: Any, **options: Any) -> Any:
        if robot.effects:  # issue 23: the loop closure with the effects
            from ..effects.tracker import uncertainty as uncertainty_effects

            return uncertainty_effects(robot, data, x, noise, options.get("active"),
                                       bool(options.get("weighted")))
        return _tracker_uncertainty(robot, data, x, noise, options.get("active"),
                                    bool(options.get("weighted")))

    def estimator(self, robot: Any, data: Any, noise: Any, **options: Any) -> Any:
        if robot.effects:  # issue 23: the loop closure with the effects (numpy solver)
            from ..effects.tracker import estimator as effect_estimator

            return effect_estimator(robot, data, noise, **options)
        return TrackerSpec(robot, data, noise, options["x0"], options["active"],
                           options["estimate"], options["bounds"], options["plausible"])

    def plausibility(self, robot: Any, data: Any, bounds: Any, plausible: float
                     ) -> tuple[list[str], np.ndarray, np.ndarray, Any]:
        from .registration import RegistrationError

        if robot.effects:  # issue 23: the effects' parameters beside the robot's and the setup's
            from ..effects.tracker import plausibility as plausibility_effects

            return plausibility_effects(robot, data, bounds, plausible)

        given = not (bounds is None or isinstance(bounds, str))
        try:  # the problem identify searched, its setup bounds about the registration guess
            tp, _ = tracker_problem(robot, data, None if given else bounds)
        except RegistrationError:  # data too few for a guess: about the nominal setup
            tp = TrackerProblem(robot, robot.tracker, data, bounds if given else None)
        lower, upper = ((np.asarray(bounds[0], dtype=float), np.asarray(bounds[1], dtype=float))
                        if given else (tp.lower, tp.upper))
        centre = 0.5 * (lower + upper)
        limit = plausible * 0.5 * (upper - lower)
        return tp.parameter_names, limit, centre, tracker_readings(tp)

    def misclosures(self, robot: Any, data: Any, x: Any, noise: Any = None) -> Any:
        if robot.effects:  # issue 23: the loop closure with the effects
            from ..effects.tracker import misclosures as misclosures_effects

            return misclosures_effects(robot, data, x, noise)
        return tracker_misclosures(robot, data, x, noise)

    def candidate_poses(self, robot: Any, data: Any) -> Any:
        # Tracker data hold no world pose: the nominal robot's forward kinematics gives it (the
        # geometry's; with effects the loads and temperatures kept for the design).
        poses = forward_kinematics(robot.with_effects(), np.zeros(robot.n_params), data.q,
                                   data.legs)
        return Measurements(data.q, poses, data.legs, joint_types=robot.joint_types,
                            payload=data.payload, temperatures=data.temperatures)

    def design(self, robot: Any, candidates: Any, x: Any, report: Any
               ) -> tuple[Any, np.ndarray, np.ndarray, int, str]:
        if robot.effects:  # issue 23: the point objective with the effects, under the loads
            from ..effects.tracker import design as design_effects

            return design_effects(robot, candidates, x, report)
        return tracker_design(robot, candidates, x, report)

    def measure(self, robot: Any, x: np.ndarray, q: np.ndarray, poses: np.ndarray, noise: Any,
                rng: np.random.Generator) -> Any:
        return measure_tracker(robot, x, q, poses, noise, rng)

    # -- the calibration job ----------------------------------------------------------------

    def reading_noise(self, noise: Any) -> Any:
        """An :class:`iwr.Noise` means its readings' noise here (its ``position`` and
        ``orientation``, a pose measured in {0}, have no reading) and
        ``TrackerNoise.leica()`` for the tracker (none when the whole noise is zero); a pair
        ``(Noise, TrackerNoise)``, a ``TrackerNoise`` and ``"estimate"`` stay."""
        import dataclasses

        from ..noise import Noise, TrackerNoise

        if not isinstance(noise, Noise):
            return noise
        readings = dataclasses.replace(noise, position=0.0, orientation=0.0)
        return readings, (TrackerNoise.none() if noise == Noise() else TrackerNoise.leica())

    def start(self, robot: Any, data: Any) -> Any:
        return registration_guess(robot, data)

    def job_lines(self, robot: Any, data: Any, n_identification: int, method: str) -> list[str]:
        from ..effects import parameter_names as effect_names

        setup = robot.tracker
        n_effects = len(effect_names(robot.effects))
        return [f"tracker data: {len(data)} poses, {setup.kind}"
                + (f" (K = {setup.n_reflectors})" if setup.kind == "points" else "")
                + f"; identifying {robot.n_params} robot + "
                + (f"{n_effects} effect + " if n_effects else "")
                + f"{setup.n_params} setup parameters with {method} ({n_identification} poses), "
                "from the nominal robot and the closed-form registration guess"]

    def weighting_note(self, data: Any, method: str, data_name: str) -> str:
        if data.point_sigma is None:
            return ""
        if method != "efficient":  # docs/data.md: "iwr calibrate says so" (it did not)
            return (f"note: the points' own uncertainties in {data_name} are not used by method "
                    f"{method}: only the efficient estimator weighs the points by them (--method "
                    "efficient, with a noise model; docs/data.md)")
        return (f"note: the points are weighted by their own uncertainties from {data_name}, "
                "not by the tracker noise model named above (docs/data.md)")

    def predicted_accuracy(self, robot: Any, data: Any, x: Any, covariance: Any, active: Any,
                           seed: int) -> Any:
        from .estimation import tracker_predicted_accuracy

        if robot.effects:  # issue 23: under each pose's load and temperature
            from ..effects.tracker import predicted_accuracy as predicted_effects

            return predicted_effects(robot, x, covariance, active, data, seed=seed)

        return tracker_predicted_accuracy(robot, x, covariance, active, data.q, data.legs,
                                          seed=seed)

    def improvement(self, accuracy: Any, held_out: bool) -> tuple[float, float, str, str]:
        # The RMS of the per-pose largest point residuals: the default per_pose_errors are
        # these residuals, which the job's paired test compares pose by pose.
        before, after = position_rms(accuracy)
        change = (f"the largest point residual per pose has an RMS of {before:.4g} mm before "
                  f"(nominal robot in the registration guess the identification started from) "
                  f"and {after:.4g} mm after, on "
                  f"{_where(accuracy.n_poses, held_out)}")
        return before, after, change, "the point residuals"


class PointsKind(_TrackerKind):
    """Reflector positions measured by a laser tracker in its frame {T}."""

    name = "points"
    description = "reflector points"


class ProbeKind(_TrackerKind):
    """The pose of a tracker probe (a 6-DOF target) measured in the tracker frame {T}."""

    name = "probe"
    description = "the probe's pose"
    experiment_text = {**_TrackerKind.experiment_text, "readings_short": "probe point ({T})",
                       "readings": (
        "the probe's four points in {T} (its origin and one probe_length along each axis) "
        "predicted with the recovered parameters against their exact values (mm; the nominal "
        "robot's in the closed-form registration guess the identification started from)")}

    def readings_per_pose(self, robot: Any, data: Any) -> float:
        """Six: a pose (its four points are twelve coordinates of one rigid pose)."""
        return 6.0
