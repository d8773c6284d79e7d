"""One seed of the Monte Carlo of the efficient estimator with effects on laser-tracker data
(``benchmarks/effects_tracker_monte_carlo.py`` runs the seeds, docs/effects.md gives the
figures, "Tracker data"): a true machine with the effects and a random tracker setup,
calibration data with every instrument's noise under three payloads, an extended (geometry +
effects) and a geometric-only calibration by the efficient estimator, each judged on fresh
poses with other loads and temperatures against the simulation's truth."""

from __future__ import annotations

from typing import Any

import numpy as np

from . import tracker as et

__all__ = ["FRESH_PAYLOADS", "PAYLOADS", "job_trial", "trial"]

#: The calibration's payloads (kg, centre of mass in {5} mm), taken in turn: none, an 80 kg head
#: and a 60 kg tool off-axis, their centres not on one line with the platform's (so that the
#: loads fix the platform frame: docs/effects.md, "Tracker data").
PAYLOADS = np.array([[0.0, 0.0, 0.0, 0.0], [80.0, 50.0, 0.0, 150.0], [60.0, -40.0, 90.0, 120.0]])
#: The fresh poses' loads: a 40 kg torch off-axis and a 120 kg spindle far out.
FRESH_PAYLOADS = np.array([[40.0, 80.0, -60.0, 100.0], [120.0, 0.0, 250.0, 60.0]])


def _rms(v: Any) -> float:
    return float(np.sqrt(np.mean(np.square(v))))


def _noise() -> Any:
    """The instruments' noise of the study: legs 2 um, joints 5 um and 5 urad, Leica's
    tracker."""
    from ..noise import Noise, TrackerNoise

    return (Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6), TrackerNoise.leica())


def _case(robot: Any, seed: int, n_poses: int, n_fresh: int) -> tuple[np.ndarray, Any, Any]:
    """Seed ``seed``'s true machine (:func:`_truth`), its calibration data with every
    instrument's noise under :data:`PAYLOADS` (one reflector hidden at 10 % of the poses), and
    its fresh poses without noise under :data:`FRESH_PAYLOADS` at 14 .. 30 C."""
    rng = np.random.default_rng(seed)
    truth = _truth(robot, rng)
    seeds = rng.integers(2**31, size=2)
    hidden = 0.1 if robot.tracker.kind == "points" else 0.0
    data, _ = et.simulate(robot, n_poses, seed=int(seeds[0]), x=truth, noise=_noise(),
                          payloads=PAYLOADS, hidden=hidden)
    fresh, _ = et.simulate(robot, n_fresh, seed=int(seeds[1]), x=truth,
                           payloads=FRESH_PAYLOADS, temperatures=14.0 + 16.0 * rng.random(n_fresh))
    return truth, data, fresh


def _truth(robot: Any, rng: np.random.Generator) -> np.ndarray:
    """A true machine: geometric errors and setup uniform within their default bounds, leg
    compliances of the file's value +-30 % per leg, the file's expansion coefficient."""
    setup = robot.tracker
    comp = robot.effects[0]
    lo_g, hi_g = robot.default_bounds()
    lo_s, hi_s = setup.default_bounds()
    compliance = comp.compliance * (1.0 + 0.3 * (2.0 * rng.random(6) - 1.0))
    return np.concatenate([lo_g + (hi_g - lo_g) * rng.random(robot.n_params),
                           compliance - comp.compliance, [0.0],
                           lo_s + (hi_s - lo_s) * rng.random(setup.n_params)])


def job_trial(robot: Any, seed: int, method: str = "efficient", n_poses: int = 60,
              n_fresh: int = 50) -> dict[str, Any]:
    """One seed of the calibration job (:func:`iwr.calibrate` with the noise model, a fifth of
    the poses held out) on clean data (no gross error) of a true machine as :func:`trial`
    draws it: whether the job calibrated (fit test, the effects' range, the gross-error
    screen), how many poses its outlier tests flagged (false alarms: the data have none), and
    the tool position error on fresh poses with other loads and temperatures against the
    truth, actual and predicted there by the job's covariance (the estimator's; for LM the
    weighted objective's, :func:`iwr.uncertainty` with ``weighted=True``). Returns the figures
    (mm)."""
    from ..analysis.accuracy import accuracy
    from ..calibration import calibrate

    truth, data, fresh = _case(robot, seed, n_poses, n_fresh)
    cal = calibrate(robot, data, method, noise=_noise(), seed=seed)
    r = cal.result
    unc = cal.uncertainty
    cov = r.covariance if r.covariance is not None else unc.covariance
    active = r.active if r.covariance is not None else unc.active
    return {
        "seed": seed, "method": method, "success": bool(cal.success),
        "fit_ok": bool(cal.fit_ok), "p_value": float(r.fit.p_value),
        "flagged": len(r.outliers or []),
        "tool_rms": _rms(accuracy(robot, fresh, r.x, truth=truth).calibrated.position),
        "predicted_rms": float(et.predicted_accuracy(robot, r.x, cov, active, fresh)
                               .position_rms),
        "validation_rms": _rms(cal.accuracy.calibrated.position),
    }


def trial(robot: Any, seed: int, n_poses: int = 60, n_fresh: int = 50) -> dict[str, Any]:
    """One seed: ``robot`` the nominal robot with a tracker and the realistic effects
    (:func:`iwr.effects.api.realistic`); the truth has random geometric errors and setup
    (within their default bounds), leg compliances of the file's value +-30 % per leg, the
    file's expansion coefficient; the calibration's temperatures a day's drift, the fresh
    poses' 14 .. 30 C. Noise: legs 2 um, joints 5 um and 5 urad, Leica's tracker model;
    reflector points have one hidden at 10 % of the poses. Returns the figures (mm, um/N,
    ppm/K)."""
    from ..analysis.accuracy import accuracy
    from ..methods import identify
    from ..tracker.analysis import tool_frames as geometric_frames
    from ..tracker.gauge import _align

    noise = _noise()
    setup = robot.tracker
    truth, data, fresh = _case(robot, seed, n_poses, n_fresh)
    out: dict[str, Any] = {"seed": seed}
    ext = identify(robot, data, "efficient", noise=noise)
    out["extended_fit_ok"] = bool(ext.success)
    out["extended_p_value"] = float(ext.fit.p_value)
    out["extended_outliers"] = int(len(data) - np.sum(ext.used))
    out["extended_tool_rms"] = _rms(accuracy(robot, fresh, ext.x, truth=truth)
                                    .calibrated.position)
    # Predicted where the actual error is measured: at the fresh poses, under their loads and
    # temperatures (the estimator's own prediction is at the calibration poses).
    out["extended_predicted_rms"] = float(et.predicted_accuracy(
        robot, ext.x, ext.covariance, ext.active, fresh).position_rms)
    out["extended_predicted_at_calibration_rms"] = float(ext.predicted.position_rms)
    ng = robot.n_params
    out["compliance_error_rms"] = _rms(ext.x[ng: ng + 6] - truth[ng: ng + 6])
    out["alpha_error"] = float(ext.x[ng + 6] - truth[ng + 6])
    k = int(np.sum(ext.active[: ng + 6]))  # alpha's place among the active parameters
    out["alpha_sd"] = float(np.sqrt(ext.covariance[k, k]))
    # Geometric-only on the same data (the payload and temperature columns unused).
    plain = robot.with_effects()
    geo = identify(plain, data, "efficient", noise=noise)
    out["geometric_fit_ok"] = bool(geo.success)
    out["geometric_p_value"] = float(geo.fit.p_value)
    b = et.tool_frames(robot, truth, fresh)
    a = geometric_frames(plain, setup, geo.x, fresh.q, fresh.legs)
    a = a @ _align(a, b)
    out["geometric_tool_rms"] = _rms(np.linalg.norm(a[:, :3, 3] - b[:, :3, 3], axis=1))
    out["geometric_predicted_rms"] = float(geo.predicted.position_rms)
    return out
