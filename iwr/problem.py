"""The calibration problem: a robot, its measurements, the objective of eq. (10) and its bounds."""

from __future__ import annotations

from typing import Any

import numpy as np

from . import _core
from ._hooks import hook
from .effects import bounds as effect_bounds
from .effects import parameter_names as effect_names
from .effects.model import check_inputs as check_effect_inputs
from .measurements import Measurements, as_matrix
from .problem_base import ProblemBase
from .problem_base import check_joint_types as _check_joint_types  # noqa: F401 (estimation)
from .robot import Robot

__all__ = ["Problem", "gls_whitening", "predict_legs"]


def effect_inputs(robot: Robot, measurements: Measurements) -> dict[str, Any]:
    """What the C++ objective with effects (``_core.EffectObjective``)
    takes of a robot's effects and the data's loads and temperatures: the effects' tables
    (:meth:`iwr.effects.Effect.to_dict`, in order), the payload (N, 4) and the temperatures
    (N, 1 or 6), each ``(0, 0)`` when absent."""
    empty = np.zeros((0, 0))

    def arr(a: Any) -> np.ndarray:
        return empty if a is None else np.ascontiguousarray(a, dtype=float)

    return dict(effects=[(e.name, e.to_dict()) for e in robot.effects],
                payload=arr(measurements.payload), temperatures=arr(measurements.temperatures))


def predict_legs(robot: Robot, x: Any, q: Any, poses: Any, *, data: Any = None) -> np.ndarray:
    """Predicted leg sensor readings, ``||0P5 + 0R5 b_j - 0P4 - 0R4 a_j|| - l0_j``.

    Parameters
    ----------
    robot : Robot
    x : array_like, shape (n_params,), or None
        Error parameters added to the robot's nominal geometry (None or zeros: the nominal
        robot); with effects, the geometric errors then the effects' parameters.
    q : array_like, shape (N, n_joints)
        Carriage joint readings (mm, rad).
    poses : array_like, shape (N, 6)
        Platform poses in the world frame, rows ``(x, y, z, alpha, beta, gamma)`` (mm, rad).
    data : Measurements, optional
        A robot with effects (docs/effects.md): each pose's load and temperature (its
        ``payload`` and ``temperatures``, N poses), the readings less the effects' change of
        each leg (:func:`iwr.effects.model.predicted_readings`). Not without effects.

    Returns
    -------
    ndarray, shape (N, 6)
    """
    poses = as_matrix(poses, 6, "poses")
    q = as_matrix(q, robot.n_joints, "q", rows=poses.shape[0])
    if robot.effects:  # issue 23: the legs under each pose's load and temperature
        return _predict_legs_with_effects(robot, x, q, poses, data)
    if data is not None:
        raise ValueError(f"data: robot {robot.name!r} has no effect on; the predicted readings "
                         "need no loads or temperatures (leave data out)")
    x = np.zeros(robot.n_params) if x is None else np.ascontiguousarray(x, dtype=float)
    if x.shape != (robot.n_params,):
        raise ValueError(f"x: shape {x.shape}; expected ({robot.n_params},)")
    return _core.predict_legs(robot._geometry, x, q, poses)


def _predict_legs_with_effects(robot: Robot, x: Any, q: np.ndarray, poses: np.ndarray,
                               data: Any) -> np.ndarray:
    from .effects.model import predicted_readings

    names = ", ".join(e.name for e in robot.effects)
    if data is None:
        raise ValueError(f"data: robot {robot.name!r} has effects on ({names}); give each "
                         "pose's load and temperature (data=an iwr.Measurements with the "
                         "payload and temperature columns its effects need)")
    if len(data) != len(poses):
        raise ValueError(f"data: {len(data)} poses, but poses has {len(poses)} rows")
    n_all = robot.n_params + len(effect_names(robot.effects))
    x = np.zeros(n_all) if x is None else np.ascontiguousarray(x, dtype=float)
    return predicted_readings(robot, x, q, poses, data)


def gls_whitening(robot: Robot, measurements: Measurements, noise: Any,
                  x: Any = None) -> np.ndarray:
    """Per-pose whitening of eq. (10)'s residuals by the instruments' noise (issue 14, item 3).

    The six leg residuals ``r_k`` of pose k have, to first order, the covariance
    ``S_k = sigma_legs^2 I + J_k Sigma_k J_k^T``: the leg sensors' own noise plus the carriage
    encoders' and the measured pose's noise (``Sigma_k``, diagonal, from
    :func:`iwr.estimation.sigma_matrix`) propagated through the loop (``J_k`` the derivatives of
    the predicted legs with respect to those readings, :func:`iwr.estimation.loop_jacobians`),
    evaluated at ``x`` (default: the nominal robot) and then held fixed. The whitening is
    ``W_k = L_k^-1`` with ``S_k = L_k L_k^T`` (Cholesky), so that
    ``||W_k r_k||^2 = r_k^T S_k^-1 r_k``: generalised least squares with fixed weights.

    Leg weights of the measurements (``w``, inverse relative variances of the legs) are folded
    in as ``W_k = L_k^-1 D_k^1/2`` with ``L_k L_k^T = sigma_legs^2 I + D_k^1/2 J_k Sigma_k J_k^T
    D_k^1/2`` and ``D_k = diag(w_k)``: ``r_k^T S_k^-1 r_k`` for the legs' variance divided by
    ``w``, and a weight of 0 leaves that leg out (as in eq. 10) rather than failing.

    A robot with effects (docs/effects.md): ``x`` holds the geometric errors then the effects'
    parameters (default zeros of that length), and ``J_k`` is the loop closure's with the
    effects under pose k's load and temperature (:func:`iwr.implicit_loop.loop_jacobians`).

    Returns
    -------
    ndarray, shape (N, 6, 6)
        Lower-triangular ``W_k`` (1/mm).

    Raises
    ------
    ValueError
        When a pose's covariance is singular (for example every sigma 0, or the leg sigma 0 with
        a leg weighted 0), naming the pose.
    """
    from .implicit_loop import loop_jacobians, sigma_matrix
    from .noise import Noise

    if not isinstance(noise, Noise):
        raise TypeError(f"noise: expected an iwr.Noise, got {type(noise).__name__}")
    # With effects (issue 23): x also holds the effects' parameters, and the loop closure
    # takes each pose's load and temperature (``data``; ignored without effects).
    x = (np.zeros(robot.n_params + len(effect_names(robot.effects))) if x is None
         else np.asarray(x, dtype=float))
    plain = Measurements(measurements.q, measurements.poses, measurements.legs,
                         joint_types=measurements.joint_types)
    sig = sigma_matrix(robot, plain, noise)
    _, _, jy = loop_jacobians(robot, x, measurements.q, measurements.poses, data=measurements)
    cov = np.einsum("kij,kj,klj->kil", jy, sig[:, 6:] ** 2, jy)
    if measurements.weights is not None:
        d = np.sqrt(measurements.weights)
        cov = d[:, :, None] * cov * d[:, None, :]
    cov[:, np.arange(6), np.arange(6)] += sig[:, :6] ** 2
    w = np.empty_like(cov)
    eye = np.eye(6)
    for k in range(cov.shape[0]):
        try:
            chol = np.linalg.cholesky(cov[k])
        except np.linalg.LinAlgError:
            raise ValueError(
                f"noise: {measurements.where(k)}: the covariance of its six leg residuals "
                f"is singular with {noise} (every reading that enters the pose without noise, "
                "or a leg weighted 0 with no leg noise): give the legs a sigma > 0") from None
        w[k] = np.linalg.solve(chol, eye)
        if measurements.weights is not None:
            w[k] = w[k] * np.sqrt(measurements.weights[k])[None, :]
        w[k] = np.tril(w[k])  # exactly lower triangular (the inverse of a lower-triangular L)
    return w


class Problem(ProblemBase):
    """The identification problem of eq. (10) for a robot and a data set (a
    :class:`iwr.problem_base.ProblemBase`: the kinds' problems share their interface).

    Parameters
    ----------
    robot : Robot
        The nominal robot; the unknowns are its error parameters.
    measurements : Measurements
    bounds : None, "default", "paper" or (lower, upper)
        Search bounds of the error parameters. ``None``/``"default"``: +-0.5 mm for lengths and
        +-0.5 degree for angles; ``"paper"``: Table 2 literally, +-0.5 everywhere.
    noise : Noise, optional
        The instruments' noise: the residuals are then whitened pose by pose
        (:func:`gls_whitening`, propagated at the nominal robot and held fixed), and the cost is
        the generalised least squares statistic ``sum_k r_k^T S_k^-1 r_k`` (dimensionless; a
        chi-square variable with ``6 N - rank`` degrees of freedom at the minimum when model and
        data agree). Default: eq. (10) unweighted.
    whitening : array_like, shape (N, 6, 6), optional
        A whitening of one's own instead (lower triangular per pose); not with ``noise``.

    Notes
    -----
    The cost is ``sum_k sum_j w_kj (s_pred_kj - s_meas_kj)^2`` (weights default to 1), in mm^2, so
    it compares directly with the paper's final value of about 1e-4; with ``noise`` or
    ``whitening`` it is ``sum_k ||W_k r_k||^2``. Every method (LM, DE and its strategies, CRS2,
    BOBYQA) minimises the cost of the problem it is given.
    """

    data_type = Measurements
    data_name = "iwr.Measurements"
    file_holds = "leg data (poses in {0})"
    effects_what = "iwr.Problem"
    #: Issue 23: a robot's effects are modelled (their parameters follow the geometric errors).
    takes_effects = True

    def __init__(self, robot: Robot, measurements: Measurements, bounds: Any = None, *,
                 noise: Any = None, whitening: Any = None) -> None:
        self._accept(robot, measurements)
        if robot.effects:
            check_effect_inputs(robot, measurements)
            lo_e, hi_e = effect_bounds(robot.effects)
            if bounds is None or isinstance(bounds, str):
                lo_r, hi_r = robot.default_bounds(bounds or "default")
                bounds = (np.concatenate([lo_r, lo_e]), np.concatenate([hi_r, hi_e]))
            else:  # a pair of the geometric errors' bounds: the effects' own after them
                try:
                    lower, upper = (np.atleast_1d(np.array(b, dtype=float)) for b in bounds)
                except (TypeError, ValueError):
                    raise ValueError("bounds: expected None, 'default', 'paper' or a pair "
                                     "(lower, upper)") from None
                if lower.size in (1, robot.n_params) and upper.size in (1, robot.n_params):
                    # The geometric errors' bounds (scalars broadcast over them: mm and rad,
                    # not the effects' units), the effects' own after them.
                    n = robot.n_params
                    bounds = (np.concatenate([np.broadcast_to(lower, (n,)), lo_e]),
                              np.concatenate([np.broadcast_to(upper, (n,)), hi_e]))
        self._set_bounds(bounds)
        if noise is not None and whitening is not None:
            raise ValueError("noise, whitening: give one or the other")
        self.noise = noise
        if noise is not None:
            whitening = gls_whitening(robot, measurements, noise)
        if whitening is not None:
            wh = np.asarray(whitening, dtype=float)
            if wh.shape != (len(measurements), 6, 6):
                raise ValueError(f"whitening: shape {wh.shape}; expected ({len(measurements)}, "
                                 "6, 6)")
            self.whitening = wh
            # Measurement weights are folded into the whitening (gls_whitening does).
            weights = np.zeros((0, 0))
        else:
            self.whitening = None
            weights = (measurements.weights if measurements.weights is not None
                       else np.zeros((0, 0)))
        if robot.effects:  # issue 23: the leg objective with the effects (cpp/src/effects.cpp)
            self._objective = _core.EffectObjective(
                robot._geometry, q=measurements.q, poses=measurements.poses,
                legs=measurements.legs, weights=weights, whitening=self.whitening_matrix(),
                **effect_inputs(robot, measurements))
        else:
            self._objective = _core.Objective(
                robot._geometry, measurements.q, measurements.poses, measurements.legs, weights,
                self.whitening_matrix(),
            )

    def whitening_matrix(self) -> np.ndarray:
        """The whitening as the C++ objective takes it: (N, 36), or (0, 0) when there is none."""
        if self.whitening is None:
            return np.zeros((0, 0))
        return np.ascontiguousarray(self.whitening.reshape(len(self.measurements), 36))

    @property
    def n_setup_params(self) -> int:
        """The effects' parameters (issue 23), after the robot's geometric errors."""
        return len(effect_names(self.robot.effects))

    @property
    def parameter_names(self) -> list[str]:
        return self.robot.parameter_names + effect_names(self.robot.effects)

    @property
    def angle_parameters(self) -> np.ndarray:
        return np.concatenate([np.asarray(self.robot.angle_parameters, dtype=bool),
                               np.zeros(self.n_setup_params, dtype=bool)])

    @property
    def n_residuals(self) -> int:
        """Six leg readings per pose."""
        return 6 * self.n_poses

    def cost(self, x: Any) -> float:
        """The cost of eq. (10) at error vector ``x`` (mm^2; whitened: dimensionless)."""
        return self._objective.cost(self._x(x))

    def residuals(self, x: Any) -> np.ndarray:
        """Residuals ``sqrt(w) (predicted - measured)`` (whitened: ``W_k (predicted -
        measured)``), shape (6 N,), pose-major."""
        return self._objective.residuals(self._x(x))

    def jacobian(self, x: Any) -> np.ndarray:
        """Exact (analytic) Jacobian of :meth:`residuals`, shape (6 N, n_params)."""
        return self._residuals_and_jacobian(x)[1]

    def residuals_and_jacobian(self, x: Any) -> tuple[np.ndarray, np.ndarray]:
        """Both at once (one pass). With effects: the residuals of the C++ objective and the
        exact Jacobian of the numpy model (:func:`iwr.effects.model.predicted_readings`, which
        the C++ objective's residuals agree with to round-off)."""
        return self._residuals_and_jacobian(x)

    def _residuals_and_jacobian(self, x: Any) -> tuple[np.ndarray, np.ndarray]:
        if not self.robot.effects:
            return self._objective.jacobian(self._x(x))
        from .effects.model import predicted_readings

        x = self._x(x)
        m = self.measurements
        _, jac = predicted_readings(self.robot, x, m.q, m.poses, m, derivatives=True)
        if self.whitening is not None:
            jac = np.einsum("kij,kjp->kip", self.whitening, jac)
        elif m.weights is not None:
            jac = jac * np.sqrt(m.weights)[..., None]
        return self._objective.residuals(x), jac.reshape(-1, self.n_params)

    def engine_objective(self) -> Any:
        """The C++ objective of eq. (10) (``iwr._core.Objective``; with effects
        ``iwr._core.EffectObjective``), weighted or whitened as the problem is."""
        return self._objective

    def __repr__(self) -> str:
        return (f"Problem(robot={self.robot.name!r}, n_poses={self.n_poses}, "
                f"n_params={self.n_params})")

    def save(self, path: Any, *, sources: dict[str, Any] | None = None, x0: Any = None,
             active: Any = None) -> None:
        """Write the problem file that ``iwr-engine`` runs from, atomically.

        A versioned, checksummed binary file (``docs/iwr-calibrate.md``) with the robot, the
        measurements and weights, the noise weighting (the whitening, when the problem has one:
        the engine then minimises the same weighted cost), the bounds and the parameter names;
        ``sources`` maps a role (``"robot"``, ``"data"``) to the file it came from, recorded with
        its SHA-256; ``x0``
        (default zeros: where the inactive parameters stay) and ``active`` (default all) are the
        search's starting point and active set. :meth:`load` reads it back; tracker and ballbar
        data are saved by :meth:`iwr.tracker.TrackerProblem.save` and
        :meth:`iwr.ballbar.BallbarProblem.save`, to the same format.
        """
        super().save(path, sources=sources, x0=x0, active=active)

    @classmethod
    def load(cls, path: Any) -> Any:
        """Read a problem file written by :meth:`save` (``iwr._core.FormatError``, a ValueError
        naming the file and field, if it is malformed, truncated or of another version). A file
        of tracker data gives an :class:`iwr.tracker.TrackerProblem`, one of ballbar data an
        :class:`iwr.ballbar.BallbarProblem`."""
        return hook("load_problem")(path)  # iwr.problem_file, a layer up
