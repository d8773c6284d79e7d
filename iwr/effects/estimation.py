"""The efficient estimator on pose data for a robot with effects (docs/effects.md): the readings
model of :func:`iwr.estimation.efficient` with the effects' change of each leg in the loop
closure (:func:`iwr.effects.loop.loop_jacobians`), the unknowns the geometric errors, the
effects' parameters and each pose's corrections, solved by :func:`iwr.effects.solver.solve_loop`
(the C++ solver's method, in numpy). Everything after the solve (variance components, outliers,
the chi-square test, the result) is :func:`iwr.estimation.efficient`'s."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..estimation import (
    COMPONENTS,
    _active_mask,
    _as_noise,
    _check_estimate,
    _PoseSpec,
)
from ..implicit_loop import (
    _check_noise,
    _component_columns,
    loop_jacobians,
    reading_names,
    sigma_matrix,
)
from ..problem import _check_joint_types
from .model import check_inputs
from .problem import EffectProblem
from .solver import solve_in_stages

__all__ = ["EffectPoseSpec", "loop_residuals"]


def loop_residuals(robot: Any, data: Any, sigma: np.ndarray) -> Any:
    """The per-pose normalised residuals of the implicit loop (with the robot's effects, if
    any: :func:`iwr.implicit_loop.loop_jacobians`), as the C++ pose model's
    (``legs_and_priors``): ``(predicted - measured legs) / sigma_legs``, then each correction
    over its sigma (0 where the reading is exact), and their derivatives; a
    :data:`iwr.effects.solver.LoopModel`. ``sigma`` (N, 12 + n_joints) as
    :func:`iwr.implicit_loop.sigma_matrix`."""
    n, ny = len(data), robot.n_joints + 6
    sl, sy = sigma[:, :6], sigma[:, 6:]
    live = sy > 0
    inv_y = np.where(live, 1.0 / np.where(live, sy, 1.0), 0.0)

    def model(x: np.ndarray, corr: np.ndarray, jacobians: bool) -> tuple[np.ndarray, Any, Any]:
        legs, jx, jy = loop_jacobians(robot, x, data.q, data.poses, corr, data=data)
        r = np.concatenate([(legs - data.legs) / sl, corr * inv_y], axis=1)
        if not jacobians:
            return r, None, None
        rx = np.zeros((n, 6 + ny, x.size))
        rx[:, :6] = jx / sl[..., None]
        ry = np.zeros((n, 6 + ny, ny))
        ry[:, :6] = jy / sl[..., None]
        ry[:, 6 + np.arange(ny), np.arange(ny)] = inv_y
        return r, rx, ry

    return model


class EffectPoseSpec(_PoseSpec):
    """:class:`iwr.estimation._PoseSpec` for a robot with effects: the parameters are the
    geometric errors then the effects'; the solve, the plausibility test, eq. (10)'s cost and the
    predicted accuracy model the effects."""

    def __init__(self, robot: Any, measurements: Any, noise: Any, x0: Any, active: Any,
                 estimate: Any, bounds: Any, plausible: float) -> None:
        from .api import identifiability

        _check_joint_types(robot, measurements)
        check_inputs(robot, measurements)
        noise0, est = _as_noise(noise)
        est = _check_estimate(estimate, est, COMPONENTS)
        _check_noise(noise0)
        self.robot, self.measurements, self.noise0 = robot, measurements, noise0
        self.n = len(measurements)
        self.problem = EffectProblem(robot, measurements, bounds)
        n_all = self.problem.n_params
        x0_arr = np.zeros(n_all) if x0 is None else np.array(x0, dtype=float)
        if x0_arr.shape != (n_all,) or not np.all(np.isfinite(x0_arr)):
            raise ValueError(f"x0: expected {n_all} finite values ({robot.n_params} geometric, "
                             f"then the effects'), got shape {x0_arr.shape}")
        self.x_start = x0_arr
        self.mask = _active_mask(active, n_all, lambda: identifiability(
            robot, measurements, x0_arr).active)
        self.cols = _component_columns(robot)
        self.sigma_all = sigma_matrix(robot, measurements, noise0)
        self.est = tuple(c for c in est if self.cols[c].size and getattr(noise0, c) > 0)
        self.names = reading_names(robot)
        self.parameter_names = self.problem.parameter_names
        self.ny = robot.n_joints + 6
        self.limit = plausible * np.maximum(np.abs(self.problem.lower),
                                            np.abs(self.problem.upper))

    def solve(self, x: np.ndarray, idx: list[int], used: np.ndarray, scale: dict[str, float],
              corr: np.ndarray, max_iterations: int, cb: Any) -> dict[str, Any]:
        s = self.sigma_all.copy()
        for c, f in scale.items():
            s[:, self.cols[c]] *= f
        m = self.subset(used)
        return solve_in_stages(lambda sig: loop_residuals(self.robot, m, sig), x, idx, s[used],
                               corr, max_iterations=int(max_iterations), callback=cb)

    def plausibility_model(self, used: np.ndarray) -> Any:
        return EffectProblem(self.robot, self.subset(used)).residuals_and_jacobian

    def cost_eq10(self, x: np.ndarray) -> float:
        return self.problem.cost(x)
