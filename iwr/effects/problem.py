"""The leg (pose-data) objective of a robot with effects: eq. (10) with the effects' change of
each leg's length, its exact Jacobian, and the methods that can minimise it (docs/effects.md)."""

from __future__ import annotations

from typing import Any

import numpy as np

from . import bounds as effect_bounds
from . import parameter_names as effect_names
from .model import check_inputs, predicted_readings

__all__ = ["EffectProblem", "METHODS", "check_method"]

#: The identification methods that minimise the objective with effects: Levenberg-Marquardt on
#: eq. (10) or its noise-weighted form (this numpy model), the efficient estimator (its numpy
#: solver, :mod:`iwr.effects.solver`), and DE, CRS2 and BOBYQA on eq. (10) (the C++ objective
#: with effects: :class:`iwr.Problem`, ``cpp/src/effects.cpp``).
METHODS = ("lm", "efficient", "de", "crs2", "bobyqa")


def check_method(robot: Any, method: str, noise: Any, weighted: Any) -> None:
    """ValueError unless ``method`` models ``robot``'s effects."""
    names = ", ".join(e.name for e in robot.effects)
    if method not in METHODS:
        raise ValueError(
            f"method {method!r}: robot {robot.name!r} has effects on ({names}), which method "
            f"{method!r} does not model yet; the methods that do: {', '.join(METHODS)} "
            "(docs/effects.md)")
    if method not in ("lm", "efficient") and (noise is not None or weighted):
        raise ValueError(
            f"noise: robot {robot.name!r} has effects on ({names}); method {method!r} runs the "
            "C++ objective with the effects, which is eq. (10)'s, not its noise-weighted form: "
            "give noise=None, or use method 'lm' or 'efficient' (docs/effects.md)")


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

    def cost_batch(self, X: Any, workers: int | None = None) -> np.ndarray:
        """The costs of the rows of ``X`` (M, n_params), one by one in numpy (``workers``
        unused): the reference for :meth:`iwr.Problem.cost_batch`, not a fast path."""
        arr = np.asarray(X, dtype=float)
        if arr.ndim != 2 or arr.shape[1] != self.n_params:
            raise ValueError(f"X: shape {arr.shape}; expected (M, {self.n_params})")
        return np.array([self.cost(x) for x in arr])

    def save(self, path: Any, **options: Any) -> None:
        """The problem file of :meth:`iwr.Problem.save` (the same robot, data and bounds). A
        noise-weighted problem is refused: the file's objective with effects is eq. (10)'s."""
        from ..problem import Problem

        if self.whitening is not None:
            raise ValueError("save: a noise-weighted problem with effects has no problem file "
                             "(iwr-engine's objective with effects is eq. (10)'s, unweighted); "
                             "save the problem without noise=")
        Problem(self.robot, self.measurements, (self.lower, self.upper)).save(path, **options)

    def __repr__(self) -> str:
        return (f"EffectProblem(robot={self.robot.name!r}, n_poses={self.n_poses}, "
                f"n_params={self.n_params})")
