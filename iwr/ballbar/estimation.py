"""The efficient (implicit loop) estimator on double-ballbar data (docs/ballbar.md, "The
efficient estimator"): what the estimation loop of :func:`iwr.estimation.efficient` needs to
know of a ballbar's readings.

Per pose the readings are the six leg sensors, the carriage joints and the bar's distance; the
nuisance unknowns are the true joint readings (corrections ``dq``, each with its prior) and the
platform pose {5} in {0} (corrections ``dp``, ``w`` about a reference pose, the forward
kinematics at the start; no prior: a ballbar measures no pose). The normalised residuals of a
pose are the legs predicted at the corrected joints and pose minus the leg readings (over their
sigma), the joint corrections over theirs, and the bar predicted at the corrected pose (the
centre distance plus the set-up's length offset) minus its reading, over the bar's sigma:
``7 + n_joints`` residuals for ``n_joints + 6`` nuisance unknowns, one degree of freedom per pose.
The derivatives are exact (the loop closure's from ``cpp/src/implicit_loop.cpp``, the bar's in
closed form here, the rotation's through the right Jacobian of SO(3)); the solve is the numpy
Levenberg-Marquardt method with the per-pose blocks eliminated by the Schur complement
(:func:`iwr.effects.solver.solve_loop`), from the noise-weighted LM on the distances
(:func:`iwr.ballbar.api.weighted_problem`).

The predicted accuracy (:func:`ballbar_predicted_accuracy`) is the tool pose error modulo what a
ballbar cannot see: the parameters' covariance through the forward kinematics, then the rigid
motions of the world frame and of the platform frame that :func:`iwr.ballbar.gauge_aligned`
removes, to first order.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from ..accuracy_prediction import PredictedAccuracy, accuracy_from_covariances
from ..estimator_spec import EstimatorSpec
from ..implicit_loop import _core_rotations, loop_jacobians
from ..noise import Noise
from ..robot import Robot
from ..tracker.estimation import _skew
from ..transforms import pose_from_matrix, rotvec_matrix
from .api import (
    NULL_RTOL,
    ballbar_problem,
    ballbar_reading_names,
    ballbar_setup,
    plausible_limits,
    weighted_problem,
)
from .data import BallbarMeasurements
from .problem import BallbarProblem
from .setup import MISFIT_CAUSES
from .simulate import BallbarNoise, split_noise

__all__ = ["BALLBAR_COMPONENTS", "BallbarSpec", "ballbar_loop_model",
           "ballbar_predicted_accuracy", "ballbar_reading_names", "predicted_accuracy_on"]

#: The variance components on ballbar data: the leg and joint readings' (as :class:`iwr.Noise`'s
#: fields) and the bar's (``ballbar_distance``, :class:`BallbarNoise`'s ``distance``;
#: ``"ballbar"`` in ``estimate=`` names it too).
BALLBAR_COMPONENTS = ("legs", "joint_lengths", "joint_angles", "ballbar_distance")




def _noise(noise: Any) -> tuple[Noise, BallbarNoise, tuple[str, ...]]:
    """(reading noise, bar noise, components to estimate) from ``noise=``: the pair
    ``(iwr.Noise, BallbarNoise)`` (:func:`iwr.ballbar.simulate.split_noise`), or ``"estimate"``
    (from :meth:`iwr.Noise.realistic`'s leg and joint noise and the bar's default)."""
    if isinstance(noise, str):
        if noise != "estimate":
            raise ValueError(f"noise: {noise!r}; expected (iwr.Noise, "
                             "iwr.ballbar.BallbarNoise) or 'estimate'")
        r = Noise.realistic()
        return (Noise(legs=r.legs, joint_lengths=r.joint_lengths, joint_angles=r.joint_angles),
                BallbarNoise(), BALLBAR_COMPONENTS)
    readings, bar = split_noise(noise)
    if readings is None or bar is None:
        raise ValueError(
            f"noise: {noise!r}; the efficient estimator on ballbar data weighs the leg, joint "
            "and bar readings: give both, noise=(iwr.Noise(legs=..., joint_lengths=..., "
            "joint_angles=...), iwr.ballbar.BallbarNoise(distance=...)), or noise='estimate'")
    if not readings.legs > 0:
        raise ValueError("noise.legs: 0; the leg readings close the loop and need a standard "
                         "deviation > 0 (at least their resolution, e.g. 0.001 mm)")
    if not bar.distance > 0:
        raise ValueError("BallbarNoise.distance: 0; the bar's reading needs a standard "
                         "deviation > 0 (at least its resolution, e.g. 0.0001 mm)")
    return readings, bar, ()


def _right_jacobian(w: np.ndarray) -> np.ndarray:
    """The right Jacobian of SO(3) at rotation vectors ``w`` (N, 3): ``exp([w + d]x) =
    exp([w]x) exp([J_r(w) d]x)`` to first order in ``d``."""
    theta2 = np.sum(w * w, axis=1)
    theta = np.sqrt(theta2)
    small = theta < 1e-4
    t = np.where(small, 1.0, theta)
    b = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(t)) / t**2)
    c = np.where(small, 1.0 / 6.0 - theta2 / 120.0, (t - np.sin(t)) / t**3)
    k = _skew(w)
    return np.eye(3) - b[:, None, None] * k + c[:, None, None] * (k @ k)


def ballbar_loop_model(robot: Robot, problem: BallbarProblem, reference: np.ndarray,
                       sigma: np.ndarray) -> Any:
    """The per-pose normalised residuals of ballbar data and their exact derivatives, a
    :data:`iwr.effects.solver.LoopModel` ``model(x, corrections, jacobians) -> (r, r_x, r_y)``.

    ``reference`` (N, 6): the platform poses the corrections ``(dq, dp, w)`` move (``p + dp``,
    ``R exp([w]x)``, as :func:`iwr.implicit_loop.loop_jacobians`); ``sigma`` (N, 7 + n_joints):
    the standard deviations of the legs, the joints (0: exact) and the bar, in the columns of
    :func:`ballbar_reading_names`. ``x`` holds the robot's parameters (a robot with effects:
    the geometric errors then the effects', the legs under each pose's load and temperature,
    :func:`iwr.implicit_loop.loop_jacobians`) then the set-ups'."""
    data = problem.measurements
    n, nj = len(data), robot.n_joints
    nr = problem.n_params - problem.setup.n_params
    sl, sq, sd = sigma[:, :6], sigma[:, 6:6 + nj], sigma[:, 6 + nj]
    inv_q = np.where(sq > 0, 1.0 / np.where(sq > 0, sq, 1.0), 0.0)
    r_ref = _core_rotations(reference)
    bar = problem.bar
    rows = np.arange(n)

    def model(x: np.ndarray, corr: np.ndarray, jacobians: bool) -> tuple[np.ndarray, Any, Any]:
        legs, jx, jy = loop_jacobians(robot, x[:nr], data.q, reference, corr, data=data)
        p, f, o = problem.setup.split(x[nr:])
        w = corr[:, nj + 3:]
        rot = r_ref @ rotvec_matrix(w)
        v = reference[:, :3] + corr[:, nj:nj + 3] + np.einsum("kij,kj->ki", rot, p[bar]) - f[bar]
        dist = np.linalg.norm(v, axis=1)
        r = np.concatenate([(legs - data.legs) / sl, corr[:, :nj] * inv_q,
                            ((dist + o[bar] - data.distance) / sd)[:, None]], axis=1)
        if not jacobians:
            return r, None, None
        u = v / dist[:, None]
        rx = np.zeros((n, 7 + nj, x.size))
        rx[:, :6, :nr] = jx / sl[..., None]
        cols = nr + 7 * bar
        rot_u = np.einsum("kji,kj->ki", rot, u)  # R^T u: d dist / d platform ball
        for c in range(3):
            rx[rows, 6 + nj, cols + c] = rot_u[:, c] / sd
            rx[rows, 6 + nj, cols + 3 + c] = -u[:, c] / sd
        rx[rows, 6 + nj, cols + 6] = 1.0 / sd
        ry = np.zeros((n, 7 + nj, nj + 6))
        ry[:, :6] = jy / sl[..., None]
        ry[:, 6 + np.arange(nj), np.arange(nj)] = inv_q
        ry[:, 6 + nj, nj:nj + 3] = u / sd[:, None]
        # d (R_ref exp([w]x) P) / d w = -R [P]x J_r(w)
        d_w = -np.einsum("kij,kjl,klm->kim", rot, _skew(p[bar]), _right_jacobian(w))
        ry[:, 6 + nj, nj + 3:] = np.einsum("ki,kim->km", u, d_w) / sd[:, None]
        return r, rx, ry

    return model


class BallbarSpec(EstimatorSpec):
    """The ballbar's part of the estimation loop of :func:`iwr.estimation.efficient` (the pose
    kind's is ``iwr.estimation._PoseSpec``, the tracker kinds' ``iwr.tracker.estimation.
    TrackerSpec``; the same base, :class:`iwr.estimator_spec.EstimatorSpec`). The start: the
    noise-weighted LM on the distances (the base parameters), from ``x0`` (default the nominal
    robot and set-ups)."""

    kind = "ballbar"
    instrument = "ballbar"
    misfit_causes = MISFIT_CAUSES

    def __init__(self, robot: Robot, measurements: BallbarMeasurements, noise: Any, x0: Any,
                 active: Any, estimate: Any, bounds: Any, plausible: float) -> None:
        from ..estimation import _active_mask, _check_estimate
        from ..methods.lm import levenberg_marquardt
        from ..methods.reduced import ReducedProblem

        readings, bar, est = _noise(noise)
        est = _check_estimate(estimate, est, BALLBAR_COMPONENTS,
                              {"ballbar": ("ballbar_distance",)})
        self.robot, self.measurements = robot, measurements
        self.setup = ballbar_setup(robot)
        self.noise0 = (readings, bar)
        problem, start = self._problem_and_start(bounds, x0)
        self.problem = problem
        self.n = len(measurements)
        nj = robot.n_joints
        self.mask = _active_mask(active, problem.n_params, lambda: self._base(problem, start))
        lm = levenberg_marquardt(ReducedProblem(weighted_problem(problem, start, self.noise0),
                                                self.mask, start), progress=False)
        self.x_start = np.array(lm.x, dtype=float)
        frames = problem.platform_frames(self.x_start)
        bad = np.flatnonzero(~np.all(np.isfinite(frames.reshape(self.n, -1)), axis=1))
        if bad.size:
            raise ValueError(f"{measurements.where(int(bad[0]))}: the leg readings have no "
                             f"forward kinematics at the starting point ({bad.size} poses)")
        self.reference = np.ascontiguousarray(pose_from_matrix(frames))
        prism = np.array([c == "P" for c in robot.joint_types], dtype=bool)
        self.sigma_all = np.empty((self.n, 7 + nj))
        self.sigma_all[:, :6] = readings.legs
        self.sigma_all[:, 6:6 + nj] = np.where(prism, readings.joint_lengths,
                                               readings.joint_angles)
        self.sigma_all[:, 6 + nj] = bar.distance
        self.cols = {"legs": np.arange(6), "joint_lengths": 6 + np.flatnonzero(prism),
                     "joint_angles": 6 + np.flatnonzero(~prism),
                     "ballbar_distance": np.array([6 + nj])}
        self.est = tuple(c for c in est if self.cols[c].size and self.start_sigma(c) > 0)
        self.names = ballbar_reading_names(robot)
        self.parameter_names = problem.parameter_names
        self.ny = nj + 6
        self.limit, self.center = plausible_limits(problem, plausible)

    def _problem_and_start(self, bounds: Any, x0: Any) -> tuple[Any, np.ndarray]:
        """The distance objective of the data and its start (:func:`ballbar_problem`)."""
        return ballbar_problem(self.robot, self.measurements, bounds, x0)

    def _base(self, problem: Any, start: np.ndarray) -> np.ndarray:
        """The base parameters' mask (one parameter held per null direction)."""
        from ..tracker.analysis import null_space

        return null_space(problem, start, NULL_RTOL).active

    def start_sigma(self, c: str) -> float:
        readings, bar = self.noise0
        return float(bar.distance if c == "ballbar_distance" else getattr(readings, c))

    def _problem(self, used: np.ndarray) -> Any:
        if used.all():
            return self.problem
        return type(self.problem)(self.robot, self.setup, self.subset(used),
                                  (self.problem.lower, self.problem.upper),
                                  reference=self.problem.reference)

    def solve(self, x: np.ndarray, idx: list[int], used: np.ndarray, scale: dict[str, float],
              corr: np.ndarray, max_iterations: int, cb: Any) -> dict[str, Any]:
        from ..effects.solver import solve_loop

        s = self.sigma_all.copy()
        for c, f in scale.items():
            s[:, self.cols[c]] *= f
        nj = self.robot.n_joints
        live = np.flatnonzero(s[0, 6:6 + nj] > 0)
        rows = np.concatenate([np.arange(6), 6 + live, [6 + nj]])
        free = np.concatenate([live, nj + np.arange(6)])
        model = ballbar_loop_model(self.robot, self._problem(used), self.reference[used], s[used])
        return solve_loop(model, x, idx, np.where(np.isin(np.arange(nj + 6), free), corr, 0.0),
                          rows, free, max_iterations=int(max_iterations), callback=cb)

    def plausibility_model(self, used: np.ndarray) -> Any:
        return self._problem(used).residuals_and_jacobian

    def noise_used(self, sigmas: dict[str, float]) -> tuple[Noise, BallbarNoise]:
        readings, bar = self.noise0
        readings = replace(readings, **{c: v for c, v in sigmas.items()
                                        if c != "ballbar_distance"})
        return readings, BallbarNoise(sigmas.get("ballbar_distance", bar.distance))

    def predicted(self, x: np.ndarray, cov: np.ndarray, used: np.ndarray,
                  tool: Any) -> PredictedAccuracy:
        return predicted_accuracy_on(self._problem(used), x, cov, self.mask, tool=tool)



def _gauge_basis(t05: np.ndarray) -> np.ndarray:
    """Per pose (N, 6, 12): the change of the platform frame's ``(dp, w)`` (position in {0},
    rotation vector in {5}) under small rigid motions of the world frame ``(a, alpha)`` and of
    the platform frame ``(b, beta)``: ``G T H`` with ``G = (I + [alpha]x, a)``, ``H = (I +
    [beta]x, b)`` gives ``dp = a + alpha x p + R b``, ``w = R^T alpha + beta``."""
    n = len(t05)
    rot, pos = t05[:, :3, :3], t05[:, :3, 3]
    m = np.zeros((n, 6, 12))
    m[:, :3, :3] = np.eye(3)
    m[:, :3, 3:6] = -_skew(pos)
    m[:, :3, 6:9] = rot
    m[:, 3:, 3:6] = np.swapaxes(rot, 1, 2)
    m[:, 3:, 9:] = np.eye(3)
    return m


def _frame_metric(t05: np.ndarray, length: float = 100.0) -> np.ndarray:
    """Per pose (N, 12, 6): the frame's origin and the tips of its axes ``length`` mm long moved
    by ``(dp, w)``: :func:`iwr.ballbar.gauge_aligned`'s least-squares metric."""
    n = len(t05)
    a = np.zeros((n, 4, 3, 6))
    a[:, :, :, :3] = np.eye(3)
    for i in range(3):
        tip = np.zeros(3)
        tip[i] = length
        a[:, i + 1, :, 3:] = -t05[:, :3, :3] @ _skew(tip)
    return a.reshape(n, 12, 6)


def ballbar_predicted_accuracy(robot: Robot, measurements: BallbarMeasurements, x: Any,
                               covariance: Any, active: Any, *, tool: Any = None,
                               n_samples: int = 500, seed: int = 0) -> PredictedAccuracy:
    """The tool pose error that the covariance of the active parameters (robot then set-ups)
    predicts at the poses of ``measurements``, modulo what ballbars cannot see: what
    ``iwr.accuracy(robot, measurements, x, truth=...)`` measures against a truth (the frames
    aligned by :func:`iwr.ballbar.gauge_aligned` over these poses), to first order.

    Per pose the platform frame's error ``(dp, w)`` is ``G_k dx`` (the forward kinematics of the
    readings by the implicit function theorem, :func:`iwr.implicit_loop.loop_jacobians`; the
    set-ups' parameters move no frame); the alignment's rigid motions of {0} and {5} remove
    its projection on their 12 directions in the alignment's metric (the frames' origins and axis
    tips), which couples the poses; the tool point's error follows. RMS and 95th percentiles by
    :func:`iwr.accuracy_prediction.accuracy_from_covariances`."""
    return predicted_accuracy_on(BallbarProblem(robot, ballbar_setup(robot), measurements), x,
                                 covariance, active, tool=tool, n_samples=n_samples, seed=seed)


def predicted_accuracy_on(problem: Any, x: Any, covariance: Any, active: Any, *,
                          tool: Any = None, n_samples: int = 500, seed: int = 0
                          ) -> PredictedAccuracy:
    """:func:`ballbar_predicted_accuracy` at the poses of ``problem`` (a :class:`BallbarProblem`,
    or the objective with the effects, :class:`iwr.ballbar.effects.BallbarEffectProblem`: the
    platform frames and their derivatives from its ``pose_derivatives``)."""
    x = problem._x(x)
    measurements = problem.measurements
    mask = np.asarray(active, dtype=bool)
    cov = np.asarray(covariance, dtype=float)
    p = int(mask.sum())
    if mask.shape != (problem.n_params,):
        raise ValueError(f"active: shape {mask.shape}; expected ({problem.n_params},)")
    if cov.shape != (p, p):
        raise ValueError(f"covariance: shape {cov.shape}; expected ({p}, {p}) for {p} active "
                         "parameters")
    t = np.zeros(3) if tool is None else np.asarray(tool, dtype=float).reshape(3)
    n = len(measurements)
    t05, g = problem.pose_derivatives(x)
    bad = np.flatnonzero(~np.all(np.isfinite(t05.reshape(n, -1)), axis=1))
    if bad.size:
        raise ValueError(f"{measurements.where(int(bad[0]))}: the readings have no forward "
                         "kinematics at x")
    g = g[:, :, mask]
    m = _gauge_basis(t05)
    a = _frame_metric(t05)
    ata = np.swapaxes(a, 1, 2) @ a  # (N, 6, 6)
    normal = np.einsum("kia,kij,kjb->ab", m, ata, m)
    fit = np.linalg.lstsq(normal, np.einsum("kia,kij,kjp->ap", m, ata, g), rcond=None)[0]
    e = g - np.einsum("kia,ap->kip", m, fit)  # the aligned frame errors' derivatives
    gp = e[:, :3] - np.einsum("kij,jl,klp->kip", t05[:, :3, :3], _skew(t), e[:, 3:])
    go = e[:, 3:]
    cp = np.einsum("kip,pq,kjq->kij", gp, cov, gp)
    co = np.einsum("kip,pq,kjq->kij", go, cov, go)
    return accuracy_from_covariances(cp, co, n_samples=n_samples, seed=seed)
