"""The diagnosis of a geometric calibration on double-ballbar data (issue 23, docs/effects.md,
"Diagnosis of a geometric calibration"): whether the distance residuals of a geometric fit
correlate with the change of the distances the leg forces of the data's payloads, the carriage
joints' loads, the legs' temperatures or the slides' expansion with the machine's temperature
would make. The statistics and the regressors are those
of every instrument's objective with the effects (:func:`iwr.effects.job.problem_diagnosis`);
only the problem and the whitening are the ballbar's."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..effects.job import DIAGNOSIS_ALPHA, Diagnosis, _statics, candidates, problem_diagnosis

__all__ = ["diagnose"]


def diagnose(robot: Any, data: Any, x: Any, *, active: Any = None, noise: Any = None,
             alpha: float = DIAGNOSIS_ALPHA) -> Diagnosis | None:
    """:func:`iwr.effects.job.diagnose` on ballbar data: whether the distance residuals of a
    geometric fit ``x`` (the robot's geometric errors, then the set-ups' ball centres and
    length offsets) of ``robot`` (no effect on) to ``data`` correlate with the leg forces of the
    data's payloads, the carriage joints' loads or the legs' temperatures; None when the data
    carry neither payload nor temperature columns.

    The residuals (predicted minus measured bar readings at ``x``, one per pose) are regressed
    on their Jacobian in the ``active`` parameters (geometry and set-ups) and on each candidate
    effect's change of the distances (:func:`iwr.effects.job.candidates`): their derivative in
    the effect's parameters where it is zero, through the forward kinematics with the effects
    (:class:`iwr.ballbar.effects.BallbarEffectProblem`'s exact Jacobian). **Gravity is the
    effects' own, in {0}** (``gravity_m_s2`` of the robot's ``[effects.compliance]``, else
    :func:`iwr.effects.api.realistic`'s: opposite the hexapod's z axis at the middle of the
    carriage's joint ranges), as for pose data: a ballbar fixes no world frame of its own, so
    {0} is the robot's as its geometry puts it (the identity registration), and its gauge
    (docs/ballbar.md) turns the robot against that gravity only along directions the fit holds.
    With a ``noise`` model (an :class:`iwr.Noise`, or ``(iwr.Noise, iwr.ballbar.BallbarNoise)``)
    each distance is whitened by its first-order standard deviation
    (:func:`iwr.ballbar.api.reading_sigmas`: the bar's noise and the leg and joint readings'
    propagated through the model); without one, unweighted. Each effect is tested by the F test
    in both cases: one residual per pose, independent, leaves the cluster-robust test of the
    other kinds nothing to guard against but unequal variances (a factor of about 2 across a
    ballbar's poses), and with one residual per cluster it rejected too often
    (docs/effects.md)."""
    from .. import kinds
    from .api import reading_sigmas
    from .effects import BallbarEffectProblem, _setup

    geometric = robot.with_effects()
    g = ", ".join(f"{v:.6g}" for v in _statics(robot).gravity)
    cands = candidates(robot, data, gravity_text=(
        f"gravity [{g}] m/s^2 in {{0}} (the effects' own: a ballbar has no registration, and {{0}} "
        "is where the geometric fit holds the ballbar's gauge, the nominal base's direction to "
        "gravity)"))
    if cands is None:
        return None
    problem = BallbarEffectProblem(geometric.with_effects(*cands.effects), _setup(geometric),
                                   data)
    model = kinds.named("ballbar").reading_noise(noise) if noise is not None else None

    def whitening(problem: Any, xf: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool, str]:
        n = len(data)
        if model is not None:
            return ((1.0 / reading_sigmas(problem, xf, model)).reshape(n, 1, 1),
                    np.ones((n, 1), bool), True, "whitened by the noise model")
        return np.ones((n, 1, 1)), np.ones((n, 1), bool), False, "unweighted"

    return problem_diagnosis(problem, data, x, geometric.n_params, cands, whitening,
                             active=active, alpha=alpha, residuals="distance")
