"""The diagnosis of a geometric calibration on laser-tracker data (issue 23, docs/effects.md,
"Diagnosis of a geometric calibration"): whether the point (probe) residuals of a geometric fit
correlate with the change of the points the leg forces of the data's payloads or the legs'
temperatures would make. The statistics are the pose data's (:func:`iwr.effects.job.effect_tests`);
only the residuals and the regressors are the tracker's."""

from __future__ import annotations

from typing import Any

import numpy as np

from . import parameter_names as effect_names
from .builtin import LegCompliance, LegThermal
from .job import DIAGNOSIS_ALPHA, Diagnosis, _statics, effect_tests

__all__ = ["diagnose"]


def diagnose(robot: Any, data: Any, x: Any, *, active: Any = None, noise: Any = None,
             alpha: float = DIAGNOSIS_ALPHA) -> Diagnosis | None:
    """:func:`iwr.effects.job.diagnose` on tracker data: whether the point residuals of a
    geometric fit ``x`` (the robot's geometric errors, then the tracker setup's) of ``robot``
    (no effect on) to ``data`` correlate with the leg forces of the data's payloads or with the
    legs' temperatures; None when the data carry neither column.

    The residuals ``r`` (predicted minus measured points in {T} at ``x``, pose-major, the hidden
    points left out) are regressed on their Jacobian in the ``active`` parameters (geometry and
    set-up) and on each candidate effect's change of the points: the derivative of the points
    predicted by the robot with that effect (:class:`iwr.effects.tracker.TrackerEffectProblem`,
    gravity the tracker's through the registration of ``x``) in the effect's parameters where
    the effect is zero (the legs' six compliances, um/N; one expansion coefficient, ppm/K,
    about the data's mean temperature). With a ``noise`` model (``(iwr.Noise,
    iwr.tracker.TrackerNoise)``) the residuals and regressors are whitened per pose by the
    points' covariance (:func:`iwr.tracker.problem.noise_whitening`; a probe's has six rows per
    pose) and each effect tested by the exact F test; without one, by the cluster-robust (per
    pose) Wald test. The platform's mass and centre: the robot's ``[effects.compliance]``
    table's when it has one, else :func:`iwr.effects.api.realistic`'s (said in the
    assumptions)."""
    from ..tracker.problem import noise_whitening
    from ..tracker.start import _setup, objective_noise
    from .tracker import TrackerEffectProblem

    has_payload = getattr(data, "payload", None) is not None
    has_temps = getattr(data, "temperatures", None) is not None
    if not (has_payload or has_temps):
        return None
    geometric = robot.with_effects()
    setup = _setup(geometric)
    ng, ns, n = geometric.n_params, setup.n_params, len(data)
    x = np.asarray(x, dtype=float)
    if x.shape != (ng + ns,) or not np.all(np.isfinite(x)):
        raise ValueError(f"x: shape {x.shape}; expected {ng + ns} finite values (the robot's "
                         f"{ng} geometric errors, then the tracker setup's {ns})")
    mask = np.ones(ng + ns, bool) if active is None else np.asarray(active, bool)
    if mask.shape != (ng + ns,):
        raise ValueError(f"active: shape {mask.shape}; expected {ng + ns} flags")
    effects: list[Any] = []
    assumptions: list[str] = []
    table: list[str] = []
    if has_payload:
        statics = _statics(robot)
        effects.append(LegCompliance(statics.platform_mass, statics.platform_centre,
                                     statics.gravity, 0.0, per_leg=True))
        c = ", ".join(f"{v:.6g}" for v in statics.platform_centre)
        g = ", ".join(f"{v:.6g}" for v in setup.gravity)
        g0 = ", ".join(f"{v:.6g}" for v in statics.gravity)
        table = [f"gravity_m_s2 = [{g0}]        # in {{0}}: tracker data use the tracker's",
                 f"platform_mass_kg = {statics.platform_mass:g}       # the platform's: give yours",
                 f"platform_centre_mm = [{c}]   # its centre of mass in {{5}}: give yours"]
        source = ("the robot's [effects.compliance]" if any(
            isinstance(e, LegCompliance) for e in robot.effects) else
            "iwr.effects.api.realistic's defaults: the robot file has no [effects.compliance] "
            "table")
        assumptions = [f"the leg forces assume a platform of {statics.platform_mass:g} kg with "
                       f"its centre at [{c}] mm in {{5}} ({source}), and gravity [{g}] m/s^2 in "
                       "the tracker frame (the tracker set-up's) carried into {0} by the "
                       "registration"]
    if has_temps:
        temps = np.broadcast_to(np.asarray(data.temperatures, dtype=float), (n, 6))
        effects.append(LegThermal(0.0, float(temps.mean()), identify=True))
    probe = geometric.with_effects(*effects)
    ne = len(effect_names(probe.effects))
    problem = TrackerEffectProblem(probe, setup, data)
    xf = np.concatenate([x[:ng], np.zeros(ne), x[ng:]])
    bad = problem.failures(xf)
    if bad:
        raise ValueError(f"{data.where(bad[0][0])}: {bad[0][1]} at the fit")
    r, jac = problem.residuals_and_jacobian(xf)
    m = r.size // n
    r, jac = r.reshape(n, m), jac.reshape(n, m, -1)
    geo = np.concatenate([np.arange(ng), ng + ne + np.arange(ns)])[mask]
    a = jac[:, :, geo]
    # The residuals are predicted (no effect) minus measured (with it): -J_e c to first order,
    # so the regressors are -J_e for the coefficients to estimate the effect's size c.
    cols = {}
    first = ng
    for e in probe.effects:
        k = len(e.parameter_names())
        cols["compliance" if isinstance(e, LegCompliance) else "thermal"] = \
            -jac[:, :, first: first + k]
        first += k
    weights = objective_noise(noise, data) if noise is not None else None
    if weights is not None:
        w = noise_whitening(problem, xf, *weights)

        def whiten(v: np.ndarray) -> np.ndarray:
            return np.einsum("kij,kj...->ki...", w, v)

        rows = np.any(w != 0, axis=2)
        weighting = "whitened by the noise model"
    else:
        def whiten(v: np.ndarray) -> np.ndarray:
            return v

        rows = problem.seen.reshape(n, m)
        weighting = "unweighted"
    cluster = np.broadcast_to(np.arange(n)[:, None], (n, m))[rows]
    zw = {k: whiten(v)[rows] for k, v in cols.items()}
    return effect_tests(whiten(r)[rows], whiten(a)[rows], zw, cluster,
                        exact=weights is not None, alpha=alpha, weighting=weighting,
                        assumptions=assumptions, table=table,
                        residuals="probe-point" if setup.kind == "probe" else "point")
