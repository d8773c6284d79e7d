"""The identification problem for double-ballbar data: one distance residual per pose."""

from __future__ import annotations

from typing import Any

import numpy as np

from .. import _core
from .._hooks import hook
from ..problem_base import FAILED_RESIDUAL, ProblemBase, reference_error
from ..robot import Robot
from .data import BallbarMeasurements
from .setup import BallbarSetup

__all__ = ["BallbarProblem", "FAILED_RESIDUAL"]



def setup_columns(jac: np.ndarray, first: np.ndarray, rot_u: np.ndarray, u: np.ndarray) -> None:
    """Fill in the distance Jacobian ``jac`` (N, n_params) the columns of each pose's set-up,
    seven from ``first[k]``: its platform ball in {5} (``R^T u``, ``rot_u``), its fixed ball in
    {0} (``-u``) and its bar's length offset (1), ``u`` the unit vector from the fixed ball to
    the platform ball."""
    rows = np.arange(len(jac))
    for c in range(3):
        jac[rows, first + c] = rot_u[:, c]
        jac[rows, first + 3 + c] = -u[:, c]
    jac[rows, first + 6] = 1.0

def pose_weights(weights: Any, n: int) -> np.ndarray:
    """The weight of each of ``n`` poses' one residual (all 1 when None), checked: finite, > 0."""
    w = np.ones(n) if weights is None else np.array(weights, dtype=float)
    if w.shape != (n,) or not np.all(np.isfinite(w) & (w > 0)):
        raise ValueError(f"weights: expected {n} finite values > 0, one per pose")
    return w

def cpp_objective(core_type: Any, problem: Any, bars: dict[str, Any], **more: Any) -> Any:
    """The C++ ballbar objective ``core_type`` (``_core.BallbarObjective``, or with the effects
    ``_core.BallbarEffectObjective``, whose inputs ``more`` adds) of ``problem``'s robot, data,
    set-ups ``bars`` (:meth:`BallbarProblem.setup_fields`), reference and weights."""
    m = problem.measurements
    wh = np.zeros((0, 0)) if problem.whitening is None else problem.weights.reshape(-1, 1)
    return core_type(problem.robot._geometry, bars=bars, q=np.ascontiguousarray(m.q, dtype=float),
                     legs=np.ascontiguousarray(m.legs, dtype=float), bar=problem.bar.tolist(),
                     distance=np.ascontiguousarray(m.distance, dtype=float),
                     reference=np.ascontiguousarray(problem.reference, dtype=float),
                     home=problem.robot.home_pose, whitening=wh, **more)


class BallbarProblem(ProblemBase):
    """The least-squares problem of ballbar data: a :class:`iwr.problem_base.ProblemBase` (its
    checks, bounds, names, batch costs and failed poses), so that every method runs on it
    through :class:`iwr.ReducedProblem`; what it adds is its residual model.

    Residual k is ``(|T_05,k P_s - F_s| + o_s - d_k) * w_k`` (mm): the predicted reading minus
    the measured one, for pose k measured in set-up s, with ``T_05,k`` the platform pose by
    forward kinematics of the readings, ``P_s`` the platform ball in {5}, ``F_s`` the fixed ball
    in {0}, ``o_s`` the length offset, and ``w_k`` the pose's weight (1 unweighted; ``1 /
    sigma_k`` for the noise-weighted objective, :meth:`with_weights`).

    The cost and the batch costs (what DE, CRS2 and BOBYQA evaluate) are the C++ ballbar
    objective's (``cpp/include/iwr/ballbar.hpp``, the objective ``iwr-engine`` runs on the
    problem file, threaded across a population); the residuals and the Jacobian are NumPy, on
    the same kinematics (they agree with the C++ residuals to ~1e-13 relative).

    The platform pose and its exact derivative with respect to the robot's parameters come from
    the C++ tracker kernel (``_core.TrackerObjective``) used as a kinematics kernel: a "probe"
    at the origin of {5} in a tracker frame equal to {0}, whose four virtual points (the origin
    and the tips of the unit axes) give ``T_05`` and its derivative by implicit differentiation
    of the forward kinematics. The distance, its chain rule and the set-ups' columns are NumPy.

    A pose whose forward kinematics fails at ``x`` gets the residual ``FAILED_RESIDUAL`` (times
    its weight) and a zero Jacobian row, so every method sees a huge but finite cost.
    """

    data_type = BallbarMeasurements
    data_name = "iwr.ballbar.BallbarMeasurements"
    file_holds = "ballbar data"
    setup_type = BallbarSetup
    setup_name = "iwr.ballbar.BallbarSetup"
    setup_owner = "set-ups'"
    # issue 23: the effects are modelled on pose data only so far (docs/effects.md)
    effects_what = "ballbar data (BallbarProblem)"

    def __init__(self, robot: Robot, setup: BallbarSetup, measurements: BallbarMeasurements,
                 bounds: Any = None, *, reference: Any = None, weights: Any = None,
                 noise: Any = None) -> None:
        self._accept(robot, measurements, setup)
        self.bar = measurements.setup_index(setup)
        self._set_bounds(bounds)
        ref = self._set_reference(reference)
        self.weights = w = pose_weights(weights, len(measurements))
        #: The noise weighting as the other kinds hold it (None: unweighted): per pose the 1 x 1
        #: whitening ``w_k`` of its one residual, and the noise model it was made from, if known.
        self.whitening = None if weights is None else w.reshape(-1, 1, 1)
        self.noise = noise
        self._objective: Any = None  # the C++ objective, made on first use
        try:
            self._kernel = _core.TrackerObjective(
                robot._geometry, "probe", np.zeros(6), np.zeros((1, 3)), np.zeros(6), 1.0,
                measurements.q, measurements.legs, np.zeros((len(measurements), 12)),
                ref, robot.home_pose)
        except _core.ForwardKinematicsError as exc:
            raise reference_error(exc, measurements) from None

    def with_weights(self, weights: Any, noise: Any = None) -> BallbarProblem:
        """The same problem with residual k multiplied by ``weights[k]`` (e.g. ``1 / sigma_k``;
        None: unweighted); ``noise``: the noise model the weights were made from (recorded in
        the problem file)."""
        return BallbarProblem(self.robot, self.setup, self.measurements,
                              (self.lower, self.upper), reference=self.reference, weights=weights,
                              noise=noise)

    # -- the C++ objective and the problem file -------------------------------------------------
    def setup_fields(self) -> dict[str, Any]:
        """The set-ups as the problem file and the C++ objective take them: ``bar_names``,
        ``platform_balls`` (S, 3), ``fixed_balls`` (S, 3), ``offsets`` (S,), ``ranges`` (S, 2;
        NaN rows: no range)."""
        p, f, o = self.setup.split(None)
        ranges = np.array([b.range if b.range is not None else (np.nan, np.nan)
                           for b in self.setup.bars], dtype=float).reshape(-1, 2)
        return dict(bar_names=list(self.setup.names), platform_balls=p, fixed_balls=f,
                    offsets=o, ranges=ranges)

    @property
    def objective(self) -> Any:
        """The C++ ballbar objective of this problem (``iwr._core.BallbarObjective``): what
        ``iwr-engine`` runs on the problem file, weighted alike."""
        if self._objective is None:
            self._objective = cpp_objective(_core.BallbarObjective, self, self.setup_fields())
        return self._objective

    def file_fields(self) -> dict[str, Any]:
        """The fields of this kind's section of the problem file (``iwr.problem_file``)."""
        return dict(kind="ballbar", **self.setup_fields(), bar=self.bar.tolist(),
                    distance=self.measurements.distance, reference=self.reference)

    @classmethod
    def from_file_fields(cls, d: dict[str, Any], robot: Robot, bounds: Any,
                         whitening: Any, source: str) -> BallbarProblem:
        """The problem of a problem file's fields ``d`` (:func:`iwr.problem_file.read_problem`)
        for ``robot`` (its geometry, read from the file), ``bounds`` and ``whitening`` (None or
        (N, 1, 1)): a :class:`iwr.ballbar.effects.BallbarEffectProblem` when the file has
        effects; ValueError on what the Python checks refuse."""
        from .setup import BarSetup

        ranges = np.asarray(d["ranges"], dtype=float)
        setup = BallbarSetup([
            BarSetup(name, tuple(map(float, d["platform_balls"][i])),  # type: ignore[arg-type]
                     tuple(map(float, d["fixed_balls"][i])),  # type: ignore[arg-type]
                     None if np.isnan(ranges[i, 0]) else (float(ranges[i, 0]), float(ranges[i, 1])),
                     float(d["offsets"][i]))
            for i, name in enumerate(d["bar_names"])])
        names = np.array(d["bar_names"], dtype=object)
        m = BallbarMeasurements(d["q"], d["legs"], names[np.asarray(d["bar"], dtype=np.intp)],
                                d["distance"], joint_types=d["measurement_joint_types"],
                                source=source)
        weights = None if whitening is None else np.asarray(whitening)[:, 0, 0]
        noise = None if d["weighting"] is None else d["weighting"][0]
        if d["effects"]:  # issue 23: the robot's effects, the data's loads and temperatures
            return hook("ballbar_effect_problem").from_file_fields(d, robot, setup, m, bounds,
                                                                    weights, noise, source)
        return cls(robot.with_instrument("ballbar", setup), setup, m, bounds,
                   reference=d["reference"], weights=weights, noise=noise)

    # -- sizes and names ----------------------------------------------------------------------
    @property
    def n_residuals(self) -> int:
        return len(self.measurements)

    def x0(self) -> np.ndarray:
        """The nominal robot and the nominal set-ups: zeros."""
        return np.zeros(self.n_params)

    def _kernel_x(self, x: np.ndarray) -> np.ndarray:
        return np.concatenate([x[: self.robot.n_params], np.zeros(12)])

    # -- the model ----------------------------------------------------------------------------
    def _frames(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Origins (N, 3) and rotations (N, 3, 3) of {5} in {0}; NaN where FK fails."""
        pts = self._kernel.predicted_points(self._kernel_x(x)).reshape(self.n_poses, 4, 3)
        origin = pts[:, 0]
        rot = np.swapaxes(pts[:, 1:] - origin[:, None, :], 1, 2)  # columns: the axes
        return origin, rot

    def ball_vectors(self, x: Any) -> tuple[np.ndarray, np.ndarray]:
        """``(P - F, |P - F|)`` per pose: the platform ball's centre minus the fixed ball's, in
        {0} (N, 3), and their distance (N,); NaN where forward kinematics fails."""
        x = self._x(x)
        p, f, _ = self.setup.split(x[self.robot.n_params:])
        origin, rot = self._frames(x)
        v = origin + np.einsum("nij,nj->ni", rot, p[self.bar]) - f[self.bar]
        return v, np.linalg.norm(v, axis=1)

    def predicted(self, x: Any) -> np.ndarray:
        """The predicted bar readings (N,), mm: centre distance plus length offset; NaN where
        forward kinematics fails."""
        x = self._x(x)
        _, _, o = self.setup.split(x[self.robot.n_params:])
        return self.ball_vectors(x)[1] + o[self.bar]

    def cost(self, x: Any) -> float:
        """Sum of squared (weighted) residuals: the C++ objective's."""
        return float(self.objective.cost(self._x(x)))

    def engine_objective(self) -> Any:
        """:attr:`objective` (weighted or not)."""
        return self.objective

    def residuals(self, x: Any) -> np.ndarray:
        """Predicted minus measured readings, weighted, (N,)."""
        r = self.predicted(x) - self.measurements.distance
        return self.weights * np.where(np.isnan(r), FAILED_RESIDUAL, r)

    def residuals_and_jacobian(self, x: Any) -> tuple[np.ndarray, np.ndarray]:
        """Residuals and their exact Jacobian (N, n_params)."""
        x = self._x(x)
        nr, n = self.robot.n_params, self.n_poses
        p, f, o = self.setup.split(x[nr:])
        res, jac_pts = self._kernel.jacobian(self._kernel_x(x))
        pts = res.reshape(n, 4, 3)  # the virtual points (their measured values are zero)
        dpts = jac_pts[:, :nr].reshape(n, 4, 3, nr)
        origin = pts[:, 0]
        axes = pts[:, 1:] - origin[:, None, :]  # (N, 3 axes, 3 coords)
        ball = p[self.bar]
        v = origin + np.einsum("nji,nj->ni", axes, ball) - f[self.bar]
        dist = np.linalg.norm(v, axis=1)
        bad = np.zeros(n, dtype=bool)
        for k, _ in self._kernel.failures(self._kernel_x(x)):
            bad[int(k)] = True
        u = v / np.where(dist > 0, dist, 1.0)[:, None]
        # d(ball point)/dx_robot = d origin + sum_j ball_j d(axis j)
        dball = dpts[:, 0] + np.einsum("nj,njcp->ncp", ball, dpts[:, 1:] - dpts[:, :1])
        jac = np.zeros((n, self.n_params))
        jac[:, :nr] = np.einsum("nc,ncp->np", u, dball)
        rot_u = np.einsum("njc,nc->nj", axes, u)  # R^T u: d dist / d platform ball
        setup_columns(jac, nr + 7 * self.bar, rot_u, u)
        r = dist + o[self.bar] - self.measurements.distance
        r[bad] = FAILED_RESIDUAL
        jac[bad] = 0.0
        return self.weights * r, jac * self.weights[:, None]

    # -- diagnostics --------------------------------------------------------------------------
    def failures(self, x: Any) -> list[tuple[int, str]]:
        """Poses whose forward kinematics fails at ``x``: ``[(pose index, message)]``."""
        return [(int(k), str(m)) for k, m in self._kernel.failures(self._kernel_x(self._x(x)))]

    def platform_frames(self, x: Any) -> np.ndarray:
        """4x4 transforms (N, 4, 4) of {5} in {0} by forward kinematics; NaN where it fails."""
        origin, rot = self._frames(self._x(x))
        t = np.tile(np.eye(4), (self.n_poses, 1, 1))
        t[:, :3, :3], t[:, :3, 3] = rot, origin
        return t

    def pose_derivatives(self, x: Any) -> tuple[np.ndarray, np.ndarray]:
        """``(frames, d_pose)``: the platform frames (N, 4, 4) in {0} by forward kinematics at
        ``x`` (NaN where it fails) and the derivatives of each frame's correction ``(dp, w)``
        (``p + dp``, ``R exp([w]x)``) in every parameter (N, 6, n_params; the set-ups' move
        no frame): the implicit function theorem on the loop closure,
        :func:`iwr.implicit_loop.loop_jacobians`."""
        from ..implicit_loop import loop_jacobians
        from ..transforms import pose_from_matrix

        x = self._x(x)
        nr, nj, n = self.robot.n_params, self.robot.n_joints, self.n_poses
        t05 = self.platform_frames(x)
        g = np.zeros((n, 6, self.n_params))
        ok = np.all(np.isfinite(t05.reshape(n, -1)), axis=1)
        if ok.any():
            _, jx, jy = loop_jacobians(self.robot, x[:nr], self.measurements.q[ok],
                                       pose_from_matrix(t05[ok]))
            g[ok, :, :nr] = -np.linalg.solve(jy[:, :, nj:], jx)
        return t05, g

    def __repr__(self) -> str:
        return (f"BallbarProblem(robot={self.robot.name!r}, set-ups={self.setup.n_setups}, "
                f"n_poses={self.n_poses}, n_params={self.n_params})")
