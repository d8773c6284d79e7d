"""The diagnosis of a geometric calibration on laser-tracker data (issue 23, docs/effects.md,
"Diagnosis of a geometric calibration"): whether the point (probe) residuals of a geometric fit
correlate with the change of the points the leg forces of the data's payloads, the carriage
joints' loads, the legs' temperatures or the slides' expansion with the machine's temperature
would make. The statistics and the regressors are those
of every instrument's objective with the effects (:func:`iwr.effects.job.problem_diagnosis`);
only the problem, gravity and the whitening are the tracker's."""

from __future__ import annotations

from typing import Any

import numpy as np

from .job import DIAGNOSIS_ALPHA, Candidates, Diagnosis, candidates, problem_diagnosis

__all__ = ["candidate_effects", "diagnose"]


def diagnose(robot: Any, data: Any, x: Any, *, active: Any = None, noise: Any = None,
             alpha: float = DIAGNOSIS_ALPHA) -> Diagnosis | None:
    """:func:`iwr.effects.job.diagnose` on tracker data: whether the point residuals of a
    geometric fit ``x`` (the robot's geometric errors, then the tracker setup's) of ``robot``
    (no effect on) to ``data`` correlate with the leg forces of the data's payloads, the
    carriage joints' loads or the legs' temperatures; None when the data carry neither payload
    nor temperature columns.

    The residuals ``r`` (predicted minus measured points in {T} at ``x``, pose-major, the hidden
    points left out) are regressed on their Jacobian in the ``active`` parameters (geometry and
    set-up) and on each candidate effect's change of the points (:func:`iwr.effects.job.
    candidates`): the derivative of the points predicted by the robot with that effect
    (:class:`iwr.effects.tracker.TrackerEffectProblem`, gravity the tracker's through the
    registration of ``x``) in the effect's parameters where the effect is zero (the legs' six
    compliances, um/N; the loaded carriage joints' compliances, urad/(N m) or um/N; one
    expansion coefficient, ppm/K, about the data's mean temperature; with the machine's
    temperature ``T_C``, the slides' one expansion coefficient, ppm/K). With a ``noise`` model
    (``(iwr.Noise, iwr.tracker.TrackerNoise)``) the residuals and regressors are whitened per
    pose by the points' covariance (:func:`iwr.tracker.problem.noise_whitening`; a probe's has
    six rows per pose) and each effect tested by the exact F test; without one, by the
    cluster-robust (per pose) Wald test. The platform's mass and centre: the robot's
    ``[effects.compliance]`` table's when it has one, else :func:`iwr.effects.api.realistic`'s
    (said in the assumptions)."""
    from ..tracker.problem import noise_whitening
    from ..tracker.start import _setup, objective_noise
    from .tracker import TrackerEffectProblem

    geometric = robot.with_effects()
    setup = _setup(geometric)
    ng = geometric.n_params
    cands = candidate_effects(robot, data, x)
    if cands is None:
        return None
    problem = TrackerEffectProblem(geometric.with_effects(*cands.effects), setup, data)

    def whitening(problem: Any, xf: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool, str]:
        n = len(data)
        weights = objective_noise(noise, data) if noise is not None else None
        if weights is not None:
            w = noise_whitening(problem, xf, *weights)
            return w, np.any(w != 0, axis=2), True, "whitened by the noise model"
        m = problem.seen.size // n
        return (np.broadcast_to(np.eye(m), (n, m, m)), problem.seen.reshape(n, m), False,
                "unweighted")

    return problem_diagnosis(problem, data, x, ng, cands, whitening, active=active, alpha=alpha,
                             residuals="probe-point" if setup.kind == "probe" else "point")


def candidate_effects(robot: Any, data: Any, x: Any) -> Candidates | None:
    """The effects :func:`diagnose` tests on tracker data at the geometric fit ``x``
    (:func:`iwr.effects.job.candidates`): the carriage's joints those loaded under the tracker's
    gravity carried into {0} by the registration of ``x``."""
    from ..tracker.start import _setup
    from .gravity import registration_gravity

    geometric = robot.with_effects()
    setup = _setup(geometric)
    xs = np.asarray(x, dtype=float)[geometric.n_params:]
    g = ", ".join(f"{v:.6g}" for v in setup.gravity)
    world = (registration_gravity(setup, xs)[0] if xs.shape == (setup.n_params,)
             and np.all(np.isfinite(xs)) else None)
    return candidates(robot, data, gravity_text=(
        f"gravity [{g}] m/s^2 in the tracker frame (the tracker set-up's) carried into {{0}} "
        "by the registration"), gravity_note="# in {0}: tracker data use the tracker's",
        load_gravity=world)
