"""The leg (pose-data) objective of a robot with effects: eq. (10) with the effects' change of
each leg's length, its exact Jacobian, and the methods that can minimise it (docs/effects.md)."""

from __future__ import annotations

from typing import Any

import numpy as np

from . import bounds as effect_bounds
from . import parameter_names as effect_names
from .model import check_inputs, predicted_readings

__all__ = ["EffectProblem", "METHODS", "RANGE_FAILED", "check_method", "out_of_range",
           "parameter_sd", "range_cause"]

#: The identification methods that minimise the objective with effects: Levenberg-Marquardt on
#: eq. (10) or its noise-weighted form (this numpy model), the efficient estimator (its numpy
#: solver, :mod:`iwr.effects.solver`), and DE, CRS2 and BOBYQA on eq. (10) or its
#: noise-weighted form (the C++ objective with effects and the whitening of
#: :func:`iwr.problem.gls_whitening`: :class:`iwr.Problem`, ``cpp/src/effects.cpp``).
METHODS = ("lm", "efficient", "de", "crs2", "bobyqa")


def check_method(robot: Any, method: str) -> None:
    """ValueError unless ``method`` models ``robot``'s effects."""
    names = ", ".join(e.name for e in robot.effects)
    if method not in METHODS:
        raise ValueError(
            f"method {method!r}: robot {robot.name!r} has effects on ({names}), which method "
            f"{method!r} does not model yet; the methods that do: {', '.join(METHODS)} "
            "(docs/effects.md)")


#: What failed, in a fit's verdict, when an effect's identified value is outside its range.
RANGE_FAILED = "an effect's identified value outside its plausible range"


def out_of_range(robot: Any, x: Any, names: Any = None, sd: Any = None, alpha: float = 1e-3
                 ) -> list[tuple[str, float, float, float]]:
    """The effects' parameters of ``x`` outside their plausible range
    (:meth:`iwr.effects.Effect.bounds`: a compliance in 0 .. max, a negative one is no
    machine), each ``(name, identified correction, the bound it passes, its standard
    deviation)``: the effects' part of the fit check's size test, on the values themselves (an
    effect the data cannot separate from the geometry is held at the robot file's value, so an
    identified one has no null direction to be judged modulo). ``names``: the names of ``x``'s
    entries (default the robot's geometric errors then the effects'), where the effects'
    parameters are found by name.

    ``sd``: the standard deviations of ``x``'s entries (nan where not known). The range is then
    tested as a hypothesis, as the chi-square test tests the noise model: an effect fails when
    its value is outside the range by more than ``z`` standard deviations, ``z`` the normal
    quantile of ``1 - alpha / k`` over the ``k`` effect parameters with one (Bonferroni: a
    machine at a bound fails with probability at most ``alpha``); a value outside by less is
    what the noise does to a machine near its bound (a compliance of 0.007 um/N identified at
    -0.0003 +- 0.004). Without one (nan, or ``sd`` None), any departure beyond round-off
    fails. The methods that do not bound their search (LM, the efficient estimator) can leave
    the range; ten times its width, the geometric errors' yardstick, is none for an effect's."""
    from scipy import special

    effects = getattr(robot, "effects", ())
    if not effects:
        return []
    x = np.asarray(x, dtype=float)
    names = list(robot.parameter_names + effect_names(effects) if names is None else names)
    sds = np.full(x.size, np.nan) if sd is None else np.asarray(sd, dtype=float)
    lo, hi = effect_bounds(effects)
    where = [(i, names.index(name)) for i, name in enumerate(effect_names(effects))
             if name in names]
    k = sum(1 for _, c in where if np.isfinite(sds[c]) and sds[c] > 0)
    z = float(special.ndtri(1.0 - alpha / max(k, 1)))
    out = []
    for i, c in where:
        v, s = float(x[c]), float(sds[c])
        span = 1e-9 * max(hi[i] - lo[i], 1e-12)  # round-off at a bound is in the range
        allowed = span + (z * s if np.isfinite(s) and s > 0 else 0.0)
        if np.isfinite(v) and (v < lo[i] - allowed or v > hi[i] + allowed):
            out.append((names[c], v, float(hi[i] if v > hi[i] else lo[i]), s))
    return out


def range_cause(robot: Any, entries: list[tuple[str, float, float, float]]) -> str:
    """The fit's cause for ``entries`` of :func:`out_of_range`: each effect's value (the robot
    file's plus the correction), its standard deviation where known, and its plausible range,
    in its unit, and what to do."""
    effects = robot.effects
    names = effect_names(effects)
    units = [u for e in effects for u in e.units()]
    values = np.concatenate([np.asarray(e.values(), dtype=float) for e in effects])
    lo, hi = effect_bounds(effects)
    parts = []
    for name, v, bound, s in entries:
        i = names.index(name)
        sd = (f" (sd {s:.2g}: {abs(v - bound) / s:.3g} sd beyond it)"
              if np.isfinite(s) and s > 0 else "")
        parts.append(f"{name} = {values[i] + v:.4g} {units[i]}, outside its plausible range "
                     f"{values[i] + lo[i]:.4g} .. {values[i] + hi[i]:.4g} {units[i]}{sd}")
    return (f"{len(entries)} effect parameter(s) outside their plausible range: "
            + "; ".join(parts) + ". The data do not determine these effects (too few loads or "
            "temperatures: iwr.identifiability), or the model lacks another effect "
            "(docs/effects.md)")


def parameter_sd(robot: Any, data: Any, x: Any, active: Any, noise: Any = None,
                 readings: Any = None) -> np.ndarray:
    """First-order standard deviations of ``x``'s entries (nan where not active) from the
    Jacobian of eq. (10) with the effects at ``x`` over the ``active`` parameters: weighted by
    ``noise`` (an :class:`iwr.Noise`: the residuals whitened by it, unit variance), else with
    the leg noise estimated from the residuals (``r.r / (m - rank)``). Data of another kind
    (tracker data) need ``readings``, their kind's residuals and Jacobian at ``x`` (what
    :meth:`iwr.kinds.MeasurementKind.plausibility` gives; unweighted: the readings' noise
    estimated from them, rows without data left out). What the fit check's range test
    (:func:`out_of_range`) weighs an effect's departure from its range by."""
    from ..measurements import Measurements
    from ..noise import Noise

    if isinstance(data, Measurements):
        p = EffectProblem(robot, data, noise=noise if isinstance(noise, Noise) else None)
        r, jac = p.residuals_and_jacobian(np.asarray(x, dtype=float))
        rows = (np.ones(r.size, dtype=bool) if data.weights is None
                else (np.asarray(data.weights) > 0).reshape(-1))  # a leg weighted 0: not counted
    elif readings is not None:
        r, jac = readings(np.asarray(x, dtype=float))
        r, jac = np.asarray(r, dtype=float), np.asarray(jac, dtype=float)
        rows = np.any(jac != 0, axis=1)  # an unseen point: zero residual, zero derivatives
        noise = None
    else:
        raise ValueError(f"data: {type(data).__name__}; give their readings' residuals and "
                         "Jacobian (readings=) for the standard deviations of the effects")
    act = np.asarray(active, dtype=bool)
    ja = jac[rows][:, act]
    d = np.linalg.norm(ja, axis=0)
    d = np.where(d > 0, d, 1.0)
    _, s, vt = np.linalg.svd(ja / d, full_matrices=False)
    rank = int(np.sum(s > max(ja.shape) * np.finfo(float).eps * (s[0] if s.size else 0.0)))
    var = np.sum((vt[:rank] / s[:rank, None]) ** 2, axis=0) / d**2
    if not isinstance(noise, Noise):
        m = int(np.sum(rows))
        var = var * (float(r[rows] @ r[rows]) / (m - rank) if m > rank else np.nan)
    out = np.full(act.size, np.nan)
    out[act] = np.sqrt(var)
    return out


class EffectProblem:
    """Eq. (10) for a robot with effects: the unknowns are the geometric errors then the
    effects' parameters (:func:`iwr.effects.parameter_names`); each predicted reading is the
    geometry's minus the effects' change of the leg at that pose's load and temperature
    (:func:`iwr.effects.model.predicted_readings`). The residuals, their Jacobian and the cost
    are computed in numpy: the independent model that :class:`iwr.Problem`'s C++ objective with
    effects is checked against (the global methods run that one).

    Parameters
    ----------
    robot : Robot
        The nominal robot, with its effects.
    measurements : Measurements
        With the payload and temperature columns the effects need.
    bounds : None, "default", "paper" or (lower, upper)
        The geometric errors' as :class:`iwr.Problem`'s, or a pair over every parameter; the
        effects' parameters get their own (:func:`iwr.effects.bounds`) unless the pair covers
        them.
    noise : Noise, optional
        The instruments' noise: each pose's six residuals whitened by their covariance
        (:func:`iwr.problem.gls_whitening` with the effects: every reading's noise propagated
        through the loop closure with the effects, at the nominal robot, then held fixed), the
        cost the generalised least squares statistic, as :class:`iwr.Problem`'s.
    """

    def __init__(self, robot: Any, measurements: Any, bounds: Any = None, *,
                 noise: Any = None) -> None:
        from ..problem import Problem

        if not robot.effects:
            raise ValueError(f"robot {robot.name!r}: no effect on; use iwr.Problem")
        self.robot = robot
        self.measurements = measurements
        self.geometric = robot.with_effects()
        check_inputs(robot, measurements)
        names = effect_names(robot.effects)
        n_all = robot.n_params + len(names)
        lo_e, hi_e = effect_bounds(robot.effects)
        if bounds is None or isinstance(bounds, str):
            base = Problem(self.geometric, measurements, bounds)
            self.lower = np.concatenate([base.lower, lo_e])
            self.upper = np.concatenate([base.upper, hi_e])
        else:
            lo, hi = (np.asarray(b, dtype=float) for b in bounds)
            if lo.size == robot.n_params and hi.size == robot.n_params:
                lo, hi = np.concatenate([lo, lo_e]), np.concatenate([hi, hi_e])
            self.lower = np.broadcast_to(lo, (n_all,)).copy()
            self.upper = np.broadcast_to(hi, (n_all,)).copy()
            for i in range(n_all):
                if not (np.isfinite(self.lower[i]) and np.isfinite(self.upper[i])
                        and self.lower[i] < self.upper[i]):
                    raise ValueError(f"bounds: parameter {i} ({self.parameter_names[i]}) has "
                                     f"lower {self.lower[i]}, upper {self.upper[i]}")
        w = measurements.weights
        self._sqrt_w = None if w is None else np.sqrt(w)
        self.noise = noise
        self.whitening = None
        if noise is not None:
            from ..problem import gls_whitening

            # Measurement weights are folded into the whitening (gls_whitening does).
            self.whitening = gls_whitening(robot, measurements, noise)
            self._sqrt_w = None

    @property
    def weighted(self) -> bool:
        """Whether the residuals are whitened (generalised least squares)."""
        return self.whitening is not None

    #: The residuals that carry data: every leg reading.
    @property
    def n_observations(self) -> int:
        return self.n_residuals

    @property
    def n_params(self) -> int:
        return self.robot.n_params + len(effect_names(self.robot.effects))

    @property
    def n_poses(self) -> int:
        return len(self.measurements)

    @property
    def n_residuals(self) -> int:
        return 6 * self.n_poses

    @property
    def parameter_names(self) -> list[str]:
        return self.robot.parameter_names + effect_names(self.robot.effects)

    def _x(self, x: Any) -> np.ndarray:
        arr = np.asarray(x, dtype=float)
        if arr.shape != (self.n_params,):
            raise ValueError(f"x: shape {arr.shape}; expected ({self.n_params},): "
                             f"{self.robot.n_params} geometric errors, then "
                             + ", ".join(effect_names(self.robot.effects)))
        return arr

    def residuals_and_jacobian(self, x: Any) -> tuple[np.ndarray, np.ndarray]:
        m = self.measurements
        s, jac = predicted_readings(self.robot, self._x(x), m.q, m.poses, m, derivatives=True)
        r = s - m.legs
        if self._sqrt_w is not None:
            r = r * self._sqrt_w
            jac = jac * self._sqrt_w[..., None]
        if self.whitening is not None:
            r = np.einsum("kij,kj->ki", self.whitening, r)
            jac = np.einsum("kij,kjp->kip", self.whitening, jac)
        return r.reshape(-1), jac.reshape(-1, self.n_params)

    def residuals(self, x: Any) -> np.ndarray:
        m = self.measurements
        r = predicted_readings(self.robot, self._x(x), m.q, m.poses, m) - m.legs
        if self._sqrt_w is not None:
            r = r * self._sqrt_w
        if self.whitening is not None:
            r = np.einsum("kij,kj->ki", self.whitening, r)
        return r.reshape(-1)

    def jacobian(self, x: Any) -> np.ndarray:
        return self.residuals_and_jacobian(x)[1]

    def cost(self, x: Any) -> float:
        r = self.residuals(x)
        return float(r @ r)

    def engine_objective(self) -> None:
        """None: the numpy model has no C++ objective (DE on a robot with effects runs on
        :class:`iwr.Problem`'s, ``iwr._core.EffectObjective``)."""
        return None

    def cost_batch(self, X: Any, workers: int | None = None) -> np.ndarray:
        """The costs of the rows of ``X`` (M, n_params), one by one in numpy (``workers``
        unused): the reference for :meth:`iwr.Problem.cost_batch`, not a fast path."""
        arr = np.asarray(X, dtype=float)
        if arr.ndim != 2 or arr.shape[1] != self.n_params:
            raise ValueError(f"X: shape {arr.shape}; expected (M, {self.n_params})")
        return np.array([self.cost(x) for x in arr])

    def save(self, path: Any, **options: Any) -> None:
        """The problem file of :meth:`iwr.Problem.save` (the same robot, data, bounds and noise
        weighting: the engine's C++ objective with effects takes the whitening)."""
        from ..problem import Problem

        Problem(self.robot, self.measurements, (self.lower, self.upper),
                noise=self.noise).save(path, **options)

    def __repr__(self) -> str:
        return (f"EffectProblem(robot={self.robot.name!r}, n_poses={self.n_poses}, "
                f"n_params={self.n_params})")
