"""The double ballbar as a measurement kind (docs/ballbar.md): one distance per pose between a
ball on the platform and a ball fixed on the base or the table; the balls' centres and the
bar's length offset of every set-up are identified beside the robot, and the data fix no world
frame."""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import asdict
from typing import Any

import numpy as np

from ..analysis.identifiability import kind_parameter_error
from ..forward import forward_kinematics
from ..kinds import MeasurementKind, data_fingerprint
from ..noise import Noise, instrument_level
from .api import (
    NULL_RTOL,
    ballbar_accuracy,
    ballbar_identifiability,
    ballbar_identify,
    ballbar_misclosures,
    ballbar_problem,
    ballbar_setup,
    ballbar_uncertainty,
    plausible_limits,
    weighted_problem,
)
from .data import BallbarMeasurements
from .files import is_ballbar_file, read_ballbar
from .planning import BallbarCandidates, ballbar_candidates, ballbar_design, measure_ballbar
from .setup import BallbarSetup
from .simulate import BallbarNoise, simulate_ballbar, split_noise

__all__ = ["BallbarKind"]


class BallbarKind(MeasurementKind):
    """A double ballbar's readings: one centre distance (plus the bar's length offset) per
    pose, in set-ups of the robot's ``[ballbar]`` table."""

    name = "ballbar"
    verdict_error_dims = 1  # a distance residual per reading
    description = "a ballbar's distance"
    frame = "{0}"
    determines_world_frame = False
    #: The report of a calibration (``iwr calibrate``, ``iwr report``): the distance residuals
    #: per set-up, the balls and offsets, what a ballbar cannot see.
    report = "iwr.reporting.ballbar_calibration:BallbarCalibrationReport"
    setup_words = "its ballbar set-ups"
    #: The figures of iwr compare and iwr study on ballbar data (MeasurementKind.experiment_text).
    experiment_text = {
        **MeasurementKind.experiment_text,
        "cost": "the sum of squared distance residuals, predicted minus measured (mm^2)",
        "cost_label": "distance residuals",
        "readings_short": "distance",
        "tool_short": " modulo the gauge",
        "readings": "bar distances predicted with the recovered parameters (robot, ball centres "
                    "and length offsets) against their exact values (mm; the nominal robot's "
                    "with the nominal set-ups)",
        "gauge": "Ballbar data fix neither {0} nor {5} (docs/ballbar.md): the tool pose error is "
                 "modulo the rigid motions of both, the parameter error modulo the distances' "
                 "null directions.",
        "tool": "tool pose error against the truth at the same readings, after the rigid motions "
                "of {0} and {5} that best align the model's platform frames with the truth's "
                "(iwr.ballbar.api.gauge_aligned); the nominal robot's with the nominal set-ups",
        "parameters": "x minus the parameter vector nearest to x that predicts exactly the "
                      "truth's distances at the validation poses, projected onto the directions "
                      "the distances see (ball centres and offsets included)",
        "noise_level": "the leg and joint readings' noise scaled from iwr.Noise.realistic() and "
                       "the bar's from BallbarNoise() (1 um), both by level / 0.02 (level 0.02 "
                       "is the realistic model)",
    }

    def owns(self, data: Any) -> bool:
        return isinstance(data, BallbarMeasurements)

    def applies_to(self, robot: Any) -> bool:
        return "ballbar" in getattr(robot, "instruments", {})

    def check(self, robot: Any, data: Any) -> None:
        """As every kind's, and the bar's readings on the scale of the distances the nominal
        robot predicts at the same joint and leg readings: a file in metres or inches (its
        column says mm) is refused by name, not left to an identification that fails
        elsewhere (it reported the leg readings as having no forward kinematics)."""
        super().check(robot, data)
        problem, x0 = self.problem(robot, data)  # with the effects where the robot has them
        measured = np.asarray(data.distance, dtype=float)
        with np.errstate(invalid="ignore"):
            predicted = np.asarray(problem.residuals(x0), dtype=float) + measured
        ok = np.isfinite(predicted) & (predicted > 0)
        if not ok.any():
            return  # no forward kinematics anywhere: the identification says so, by pose
        ratio = float(np.median(measured[ok] / predicted[ok]))
        if not 0.5 <= ratio <= 2.0:
            source = getattr(data, "source", None)
            units = next((f": a file in {u}? " for u, f in
                          (("metres", 1e-3), ("centimetres", 0.1), ("inches", 1 / 25.4))
                          if abs(ratio / f - 1) < 0.2), ": ")
            raise ValueError(
                f"{source or 'measurements'}: column distance_mm: the bar's readings are "
                f"{ratio:.3g} times the distances the nominal robot predicts at the same joint "
                f"and leg readings (median over {int(ok.sum())} poses: "
                f"{float(np.median(measured[ok])):.4g} against "
                f"{float(np.median(predicted[ok])):.4g} mm){units}the readings are in mm, the "
                "centre distance plus the set-up's length offset (docs/ballbar.md)")

    def _setup_hint(self) -> str:
        return ("describe the bar's set-ups with a [ballbar] table in the robot's TOML file or "
                "robot.with_instrument('ballbar', iwr.ballbar.BallbarSetup(...)) "
                "(docs/ballbar.md)")

    def read_setup(self, setup: Any, where: str) -> Any:
        if isinstance(setup, BallbarSetup):
            return setup
        if isinstance(setup, Mapping):
            return BallbarSetup.from_dict(setup, where)
        raise TypeError(f"{where}: expected an iwr.ballbar.BallbarSetup or a table of set-ups, "
                        f"got {type(setup).__name__}")

    def setup_parameter_names(self, robot: Any) -> list[str]:
        return ballbar_setup(robot).parameter_names

    def calibrated_robot(self, robot: Any, x: Any) -> tuple[Any, dict[str, Any]]:
        """With its ``[ballbar]`` set-ups at their calibrated values."""
        out, extra = super().calibrated_robot(robot, x)
        setup = ballbar_setup(robot)
        x = np.asarray(x, dtype=float)
        calibrated = setup.with_parameters(x[x.size - setup.n_params:])
        return out.with_instrument("ballbar", calibrated), extra

    def fingerprint(self, robot: Any, data: Any) -> str:
        """The problem file's data fingerprint (C++ ``ProblemData::data_fingerprint``: the joint
        and leg readings, each pose's set-up by name and the bar's readings), so that ``iwr
        report`` checks an ``iwr-calibrate`` run's data file as every kind's."""
        self.check(robot, data)
        setup = ballbar_setup(robot)
        return data_fingerprint(self.name, robot, data, bar_names=list(setup.names),
                                bar=data.setup_index(setup).tolist(),
                                distance=np.ascontiguousarray(data.distance, dtype=float))

    def measured(self, data: Any) -> np.ndarray:
        # The bar's reading and its set-up: one robot pose in two set-ups is two rows of data.
        _, index = np.unique(np.asarray(data.setup, dtype=str), return_inverse=True)
        return np.column_stack([np.asarray(data.distance, dtype=float), index.astype(float)])

    def read(self, path: str | os.PathLike[str], robot: Any, **options: Any) -> Any:
        given = sorted(k for k, v in options.items() if v is not None)
        if given:
            raise TypeError(f"--{given[0]}: not an option of ballbar data")
        return read_ballbar(path, robot.joint_types, ballbar_setup(robot))

    def reading_noise(self, noise: Any) -> Any:
        """An :class:`iwr.Noise` (``--noise realistic``, a robot's ``[noise]`` table) is the leg
        and joint readings' noise (a ballbar measures no pose: its position and orientation
        noise does not apply) with the bar's default noise, none when ``noise`` is zero; a pair
        or a :class:`BallbarNoise` as it is."""
        if isinstance(noise, Noise):
            readings = Noise(legs=noise.legs, joint_lengths=noise.joint_lengths,
                             joint_angles=noise.joint_angles)
            return readings, BallbarNoise(0.0) if noise.is_zero else BallbarNoise()
        return noise

    def diagnose(self, robot: Any, data: Any, x: Any, *, active: Any = None,
                 noise: Any = None) -> Any:
        """Issue 23: the distance residuals of a geometric fit against the loads and
        temperatures (:func:`iwr.ballbar.diagnosis.diagnose`)."""
        from .diagnosis import diagnose

        return diagnose(robot, data, x, active=active, noise=noise)

    def tool_accuracy(self, robot: Any, data: Any, x: Any, truth: Any, start: Any = None) -> Any:
        """The tool pose errors against the truth at the same readings, modulo the rigid motions
        of {0} and {5} a ballbar cannot see (:func:`ballbar_accuracy` with ``truth``; without
        it, the experiments' "tool" figures were the distance residuals)."""
        return self.accuracy(robot, data, x, truth=truth, start=start)

    def parameter_error(self, robot: Any, data: Any, x: Any, truth: Any) -> Any:
        """Over the robot's and the set-ups' parameters, modulo the null directions of the
        distances on ``data`` (what a ballbar cannot see, docs/ballbar.md)."""
        return kind_parameter_error(self, robot, data, x, truth)

    def angle_parameters(self, robot: Any) -> np.ndarray:
        from ..effects import parameter_names as effect_names

        # The effects' parameters (issue 23) between the robot's and the set-ups': none an
        # angle (the set-ups' are lengths).
        return np.concatenate([np.asarray(robot.angle_parameters, dtype=bool),
                               np.zeros(len(effect_names(robot.effects)), dtype=bool),
                               ballbar_setup(robot).angle_parameters])

    def draw_setup(self, robot: Any, rng: np.random.Generator) -> np.ndarray:
        """Uniform within the set-ups' default bounds about the nominal (as :func:`iwr.simulate`
        draws them): an experiment identifies the ball centres and offsets from a wrong start."""
        lo, hi = ballbar_setup(robot).default_bounds()
        return lo + (hi - lo) * rng.random(lo.size)

    def experiment_noise(self, robot: Any, noise: Any) -> Any:
        """An :class:`iwr.Noise` (an experiment's noise level,
        :func:`iwr.experiments.harness.noise_at`) keeps its leg and joint noise, and its
        ``position`` sets the bar's: :class:`BallbarNoise`'s default scaled by ``position / 0.02``
        (``Noise.realistic().position``), so that the realistic level is the bar's 1 um; a pair or
        a :class:`BallbarNoise` as it is. (As it was, every noisy run of a study was refused.)
        Noisy readings with ``position`` 0 are refused (:func:`iwr.noise.instrument_level`): the
        bar would be exact."""
        if not isinstance(noise, Noise):
            split_noise(noise)  # its types checked
            return noise
        readings, scale = instrument_level(noise, "the bar",
                                           f"its {BallbarNoise().distance * 1000:g} um")
        return readings, BallbarNoise(BallbarNoise().distance * scale)

    def noise_record(self, noise: Any) -> dict[str, Any]:
        readings, bar = split_noise(noise)
        return {"noise": None if readings is None else asdict(readings),
                "ballbar_noise": None if bar is None else asdict(bar)}

    def noise_from_record(self, record: dict[str, Any]) -> Any:
        readings, bar = record.get("noise"), record.get("ballbar_noise")
        return (None if readings is None else Noise(**readings),
                None if bar is None else BallbarNoise(**bar))

    def recognises(self, path: str | os.PathLike[str]) -> bool:
        return is_ballbar_file(path)

    def simulate(self, robot: Any, n_poses: int, *, seed: int | None, x: Any = None,
                 noise: Any = None) -> tuple[Any, np.ndarray]:
        if robot.effects:  # issue 23: loads, temperatures, the legs with the effects
            from .effects import simulate as simulate_effects

            return simulate_effects(robot, n_poses, seed=seed, x=x, noise=noise)
        return simulate_ballbar(robot, ballbar_setup(robot), n_poses, seed=seed, x=x,
                                noise=noise)

    engine = True  # a problem file (kind 3) and a C++ objective: iwr-calibrate, iwr-engine
    #: Issue 23: the calibration job models a robot's effects on ballbar data (the distances by
    #: forward kinematics with the effects, iwr.ballbar.effects; their problem file and C++
    #: objective, iwr-engine and iwr-calibrate too).
    models_effects = True
    weighted_objective = True  # each distance by its propagated variance (ballbar_identify)
    null_rtol = NULL_RTOL  # structural null directions sit at ~5e-14, above NumPy's threshold

    def problem(self, robot: Any, data: Any, bounds: Any = None, x0: Any = None,
                noise: Any = None) -> tuple[Any, np.ndarray]:
        if robot.effects:  # issue 23: the distances by forward kinematics with the effects
            from .effects import effect_problem

            return effect_problem(robot, data, bounds, x0, noise)
        problem, start = ballbar_problem(robot, data, bounds, x0)
        return (problem if noise is None else weighted_problem(problem, start, noise)), start

    def identify(self, robot: Any, data: Any, method: str, **options: Any) -> Any:
        if robot.effects:  # issue 23: the distance objective with the effects
            from .effects import identify as identify_effects

            return identify_effects(robot, data, method, **options)
        return ballbar_identify(robot, data, method, **options)

    def accuracy(self, robot: Any, data: Any, x: Any, **options: Any) -> Any:
        options.pop("start", None)  # a ballbar's "before" is the nominal robot and ball centres
        if robot.effects:  # issue 23: forward kinematics under each pose's load and temperature
            from .effects import accuracy as accuracy_effects

            return accuracy_effects(robot, data, x, **options)
        return ballbar_accuracy(robot, data, x, **options)

    def improvement(self, accuracy: Any, held_out: bool) -> tuple[float, float, str, str]:
        from ..kinds import _where, position_rms

        # The RMS of the per-reading distance residuals: the default per_pose_errors are
        # these residuals, which the job's paired test compares reading by reading.
        before, after = position_rms(accuracy)
        change = (f"the distance residual has an RMS of {before:.4g} mm before (nominal robot "
                  f"and ball centres) and {after:.4g} mm after, on "
                  f"{_where(accuracy.n_poses, held_out)}")
        return before, after, change, "the distance residuals"

    def identifiability(self, robot: Any, data: Any, x: Any = None, **options: Any) -> Any:
        if robot.effects:  # issue 23: the null directions of the objective with the effects
            from .effects import identifiability as identifiability_effects

            return identifiability_effects(robot, data, x, rtol=options.get("rtol"))
        return ballbar_identifiability(robot, data, x, rtol=options.get("rtol"))

    def uncertainty(self, robot: Any, data: Any, x: Any, noise: Any, **options: Any) -> Any:
        if robot.effects:  # issue 23: the Jacobian of the distances with the effects
            from .effects import uncertainty as uncertainty_effects

            return uncertainty_effects(robot, data, x, noise, active=options.get("active"),
                                       weighted=bool(options.get("weighted")))
        return ballbar_uncertainty(robot, data, x, noise, active=options.get("active"),
                                   weighted=bool(options.get("weighted")))

    def estimator(self, robot: Any, data: Any, noise: Any, **options: Any) -> Any:
        if robot.effects:  # issue 23: the loop closure with the effects (numpy solver)
            from .effects import estimator as estimator_effects

            return estimator_effects(robot, data, noise, **options)
        from .estimation import BallbarSpec

        return BallbarSpec(robot, data, noise, options["x0"], options["active"],
                           options["estimate"], options["bounds"], options["plausible"])

    def predicted_accuracy(self, robot: Any, data: Any, x: Any, covariance: Any, active: Any,
                           seed: int) -> Any:
        """The tool pose error modulo what a ballbar cannot see
        (:func:`iwr.ballbar.estimation.ballbar_predicted_accuracy`)."""
        if robot.effects:  # issue 23: under each pose's load and temperature
            from .effects import predicted_accuracy as predicted_effects

            return predicted_effects(robot, data, x, covariance, active, seed=seed)
        from .estimation import ballbar_predicted_accuracy

        return ballbar_predicted_accuracy(robot, data, x, covariance, active, seed=seed)

    def misclosures(self, robot: Any, data: Any, x: Any, noise: Any = None) -> Any:
        if robot.effects:  # issue 23: the distances with the effects, exact derivatives
            from .effects import misclosures as misclosures_effects

            return misclosures_effects(robot, data, x, noise)
        return ballbar_misclosures(robot, data, x, noise)

    def plausibility(self, robot: Any, data: Any, bounds: Any, plausible: float
                     ) -> tuple[list[str], np.ndarray, np.ndarray, Any]:
        if robot.effects:  # issue 23: the effects' parameters beside the robot's and set-ups'
            from .effects import plausibility as plausibility_effects

            return plausibility_effects(robot, data, bounds, plausible)
        problem, _ = ballbar_problem(robot, data, bounds)
        limit, centre = plausible_limits(problem, plausible)
        return (problem.parameter_names, limit, centre,
                lambda x: problem.residuals_and_jacobian(x))

    # -- pose planning (iwr.plan_poses): (pose, set-up) pairs within the bar's range ---------
    setups_per_pose = True

    def candidate_poses(self, robot: Any, data: Any) -> Any:
        # Ballbar data hold no world pose: the nominal robot's forward kinematics gives it; each
        # pose stays a candidate in the set-up it was measured in.
        # With effects (issue 23) the geometry's poses, the loads and temperatures kept.
        geometric = robot.with_effects() if robot.effects else robot
        poses = forward_kinematics(geometric, np.zeros(robot.n_params), data.q, data.legs)
        return BallbarCandidates(data.q, poses, data.legs, data.setup,
                                 joint_types=robot.joint_types, lines=data.lines,
                                 source=data.source, payload=data.payload,
                                 temperatures=data.temperatures)

    def plan_candidates(self, robot: Any, candidates: Any, setup: Any) -> Any:
        return ballbar_candidates(robot, candidates, setup)

    def design(self, robot: Any, candidates: Any, x: Any, report: Any
               ) -> tuple[Any, np.ndarray, np.ndarray, int, str]:
        return ballbar_design(robot, candidates, x, report)

    def measure(self, robot: Any, x: np.ndarray, q: np.ndarray, poses: np.ndarray, noise: Any,
                rng: np.random.Generator, setup: Any = None) -> Any:
        return measure_ballbar(robot, x, q, poses, noise, rng, setup)
