"""One seed of the Monte Carlo of issue 23's "Checked by" (realistic noise, realistic compliance and
temperature drift; ``benchmarks/effects_monte_carlo.py`` runs the seeds, docs/effects.md gives
the figures): a true machine with the effects, calibration data from it with every instrument's
noise, a geometric-only and an extended (geometry + effects) calibration by the efficient
estimator, each judged on fresh poses with other loads and temperatures against the
simulation's truth (the tool position that each calibrated model's forward kinematics gives
from the true, noise-free readings), and the extended model's predicted tool accuracy there."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..transforms import pose_matrix
from . import parameter_names
from .api import DEFAULT_PAYLOADS, forward_kinematics, realistic, simulate
from .problem import out_of_range

__all__ = ["FRESH_PAYLOADS", "Trial", "trial"]

#: The loads of the fresh poses (kg, centre of mass in {5} mm): other than the calibration's
#: (none and an 80 kg head): a 40 kg torch off-axis and a 120 kg spindle far out.
FRESH_PAYLOADS = np.array([[40.0, 0.0, 60.0, 100.0], [120.0, -30.0, 0.0, 250.0]])


@dataclasses.dataclass
class Trial:
    """The figures of one seed (positions in mm, RMS over the fresh poses)."""

    seed: int
    scale: float
    geometric_fit_ok: bool
    geometric_p_value: float
    geometric_tool_rms: float
    geometric_predicted_rms: float
    extended_fit_ok: bool | None = None
    extended_p_value: float | None = None
    extended_tool_rms: float | None = None
    extended_predicted_rms: float | None = None
    effects_rms: float = 0.0  # how much the effects change the calibration's readings (RMS)
    geometric_outliers: int = 0  # poses the geometric calibration left out as gross errors
    #: The extended calibration's effect parameters its fit check failed as outside their
    #: plausible range by more than the noise explains (:func:`iwr.effects.problem.out_of_range`
    #: with the estimator's standard deviations), by name ...
    extended_out_of_range: list[str] = dataclasses.field(default_factory=list)
    #: ... and those outside it at all (within the noise: not failed), by name.
    extended_past_bound: list[str] = dataclasses.field(default_factory=list)


def _tool_rms(robot: Any, x: np.ndarray, fresh: Any, truth: np.ndarray, tool: np.ndarray
              ) -> float:
    """RMS over the fresh poses of the distance between the tool point where ``robot`` with
    ``x`` puts it (forward kinematics of the true readings) and where it truly is."""
    poses = forward_kinematics(robot, x, fresh.q, fresh.legs, fresh, truth)
    a, b = pose_matrix(poses), pose_matrix(truth)
    pa = a[:, :3, 3] + a[:, :3, :3] @ tool
    pb = b[:, :3, 3] + b[:, :3, :3] @ tool
    return float(np.sqrt(np.mean(np.sum((pa - pb) ** 2, axis=1))))


def trial(robot: Any, seed: int, *, scale: float = 1.0, n_poses: int = 80, n_fresh: int = 50,
          noise: Any = None, tool: Any = (0.0, 0.0, 0.0), extended: bool = True) -> Trial:
    """One seed: ``robot`` the nominal geometric robot; the true machine has random geometric
    errors within the default bounds, leg compliances ``scale`` times 0.01 um/N +-30 % (per
    leg), steel legs (11.5 ppm/K) at temperatures ``20 + scale (-3 .. +5)`` C, the
    calibration's loads alternating none and an 80 kg head (:data:`api.DEFAULT_PAYLOADS`), the
    fresh poses' :data:`FRESH_PAYLOADS`. ``noise``: the instruments' (default
    :meth:`iwr.Noise.realistic`). ``extended``: also calibrate with the effects (the slower
    part). Both calibrations by the efficient estimator with its defaults."""
    from ..methods import identify
    from ..noise import Noise

    noise = Noise.realistic() if noise is None else noise
    tool = np.asarray(tool, dtype=float)
    comp, therm = realistic(robot)
    model = robot.with_effects(comp, therm)
    rng = np.random.default_rng(seed)
    lo, hi = robot.default_bounds()
    x_geo = lo + (hi - lo) * rng.random(robot.n_params)
    compliance = scale * comp.compliance * (1.0 + 0.3 * (2.0 * rng.random(6) - 1.0))
    x_true = np.concatenate([x_geo, compliance - comp.compliance, [0.0]])
    t_cal = therm.reference + scale * (-3.0 + 8.0 * rng.random(n_poses))
    t_new = therm.reference + scale * (-3.0 + 8.0 * rng.random(n_fresh))
    seeds = rng.integers(2**31, size=2)
    data, _ = simulate(model, n_poses, seed=int(seeds[0]), x=x_true, noise=noise,
                       payloads=DEFAULT_PAYLOADS, temperatures=t_cal)
    fresh, _ = simulate(model, n_fresh, seed=int(seeds[1]), x=x_true,
                        payloads=FRESH_PAYLOADS, temperatures=t_new)
    truth = fresh.poses
    # How much the effects move the calibration's readings (noise-free, at the true poses).
    from .model import predicted_readings

    change = (predicted_readings(robot, x_geo, data.q, data.poses, data)
              - predicted_readings(model, x_true, data.q, data.poses, data))
    effects_rms = float(np.sqrt(np.mean(change**2)))
    geo = identify(robot, data, "efficient", noise=noise)
    out = Trial(seed, scale, bool(geo.fit_ok), float(geo.fit.p_value),
                _tool_rms(robot, geo.x, fresh, truth, tool),
                _predicted(robot, fresh, geo, tool), effects_rms=effects_rms,
                geometric_outliers=int(np.sum(~geo.used)))
    if extended:
        ext = identify(model, data, "efficient", noise=noise)
        out.extended_fit_ok = bool(ext.fit_ok)
        out.extended_p_value = float(ext.fit.p_value)
        out.extended_tool_rms = _tool_rms(model, ext.x, fresh, truth, tool)
        out.extended_predicted_rms = _predicted(model, fresh, ext, tool)
        own = set(parameter_names(model.effects))
        out.extended_out_of_range = [t[0] for t in ext.fit.implausible if t[0] in own]
        out.extended_past_bound = [t[0] for t in out_of_range(model, ext.x)]
    return out


def _predicted(robot: Any, fresh: Any, result: Any, tool: np.ndarray) -> float:
    """The tool position RMS that ``result``'s covariance predicts at the fresh poses."""
    from ..accuracy_prediction import predicted_accuracy

    return float(predicted_accuracy(robot, fresh, result.x, result.covariance,
                                    active=result.active, tool=tool).position_rms)
