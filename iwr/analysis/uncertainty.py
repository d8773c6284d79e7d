"""Uncertainty of identified parameters: their covariance from the Jacobian at the solution.

Linearising the residuals of eq. (10) at the solution, ``r(x + dx) ~ r(x) + J dx``, the
least-squares estimate of the identified (base) parameters responds to reading noise ``e`` by
``dx = -(J^T J)^-1 J^T e``, so its covariance is ``A Cov(e) A^T`` with ``A = (J^T J)^-1 J^T``. With
independent leg noise of standard deviation sigma this is the familiar ``sigma^2 (J^T J)^-1``.
Only the base parameters have a finite covariance: along the unidentifiable directions ``J^T J`` is
singular, which is why the analysis is done with the other parameters held fixed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import kinds
from ..measurements import Measurements
from ..noise import Noise
from ..problem import Problem, predict_legs
from ..robot import Robot
from ..transforms import pose_from_matrix, pose_matrix, rotvec_matrix
from .identifiability import IdentifiabilityReport, identifiability

if TYPE_CHECKING:  # scipy.optimize's OptimizeResult: not for `import iwr`
    from ..result import IdentificationResult

__all__ = ["Uncertainty", "uncertainty", "measurement_jacobians"]


@dataclass
class Uncertainty:
    """Covariance of identified parameters; see :func:`uncertainty`.

    Attributes
    ----------
    parameter_names : list of str
        All parameter names.
    active : ndarray of bool
        The parameters that were identified (the others were held fixed).
    covariance : ndarray, shape (n_active, n_active)
        Covariance of the active parameters (mm^2, mm rad, rad^2), in the order of the mask.
    std : ndarray, shape (n_params,)
        Standard deviation of every parameter; nan for parameters held fixed.
    sigma : float
        The leg noise standard deviation used (mm): given, or estimated from the residuals.
    source : str
        ``"residuals"`` (sigma^2 = cost / (6 N - n_active)), ``"legs"`` (given leg sigma),
        ``"noise"`` (an :class:`iwr.Noise` propagated through the joint, position and orientation
        readings as well), ``"weighted"`` (the noise-weighted objective's), or ``"estimator"``
        (the efficient estimator's own covariance, :meth:`from_result`).
    dof : int
        Residual degrees of freedom, ``6 N - n_active``.
    """

    parameter_names: list[str]
    active: np.ndarray
    covariance: np.ndarray
    std: np.ndarray
    sigma: float
    source: str
    dof: int

    @classmethod
    def from_result(cls, result: IdentificationResult) -> Uncertainty | None:
        """The efficient estimator's own covariance (``result.covariance``, over
        ``result.active``) as an :class:`Uncertainty` with ``source="estimator"``; None for a
        result without one (eq. (10)'s methods: use :func:`uncertainty`)."""
        cov = result.covariance
        active = result.active
        if cov is None or active is None:
            return None
        mask = np.asarray(active, dtype=bool)
        cov = np.asarray(cov, dtype=float)
        if cov.shape != (int(mask.sum()),) * 2:
            raise ValueError(f"result: covariance of shape {cov.shape} for {int(mask.sum())} "
                             "active parameters")
        std = np.full(mask.size, np.nan)
        std[mask] = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        noise = result.noise
        fit = result.fit
        return cls(list(result.parameter_names), mask, cov, std,
                   float(getattr(noise, "legs", np.nan)), "estimator",
                   int(getattr(fit, "dof", 0)))

    @property
    def correlation(self) -> np.ndarray:
        """Correlation matrix of the active parameters."""
        sd = np.sqrt(np.diag(self.covariance))
        return self.covariance / np.outer(sd, sd)

    def named(self) -> dict[str, float]:
        """Standard deviation of each active parameter, by name."""
        names = self.parameter_names
        return {names[i]: float(self.std[i]) for i in np.flatnonzero(self.active)}

    def describe(self) -> str:
        """Where the standard deviations come from, in one phrase (for reports)."""
        return {
            "residuals": "first-order, eq. (10)'s Jacobian at the solution, with the leg noise "
                         f"estimated from the residuals (sigma {self.sigma:.3g} mm)",
            "legs": f"first-order, eq. (10)'s Jacobian at the solution, with the given leg "
                    f"noise sigma {self.sigma:.3g} mm",
            "noise": "first-order, eq. (10)'s Jacobian at the solution, with the given noise of "
                     "legs, joints and measured poses propagated",
            "weighted": "first-order, the noise-weighted objective's whitened Jacobian at the "
                        "solution (generalised least squares with the given noise model)",
            "estimator": "the efficient estimator's covariance (its information matrix, every "
                         "instrument weighted by its noise model)",
            "point residuals": "first-order, the tracker problem's Jacobian at the solution, "
                               "with the point noise estimated from the residuals (sigma "
                               f"{self.sigma:.3g} mm per coordinate)",
            "point sigma": "first-order, the tracker problem's Jacobian at the solution, with "
                           f"the given point noise sigma {self.sigma:.3g} mm per coordinate",
            "tracker noise": "first-order, the tracker problem's Jacobian at the solution, with "
                             "the given tracker noise (along and across the line of sight) and "
                             "reading noise propagated",
        }.get(self.source, self.source)

    def __str__(self) -> str:
        lines = [
            f"Standard deviations of {int(self.active.sum())} identified parameters "
            f"({self.describe()}; {self.dof} residual degrees of freedom):"
        ]
        for name, sd in self.named().items():
            unit = "rad" if name.endswith(("dalpha", "dtheta", ".rx", ".ry", ".rz")) else "mm"
            lines.append(f"  {name:16s} {sd:.3g} {unit}")
        return "\n".join(lines)


def measurement_jacobians(
    robot: Robot, x: Any, q: Any, poses: Any, h: float = 1e-4
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Derivatives of the predicted leg readings with respect to the measured quantities.

    Returns ``(d/dq, d/dposition, d/drotation)``, shapes (N, 6, n_joints), (N, 6, 3), (N, 6, 3):
    the rotation is a small rotation vector applied in the platform frame,
    ``R -> R exp([w]x)``, as :func:`iwr.simulate` applies orientation noise. Central differences
    with step ``h`` (mm or rad): round-off ~1e-13 mm / h and truncation ~h^2 (lever ~1e3 mm
    for rotations) are both ~1e-9 relative, far below what a covariance needs.
    """
    x = np.asarray(x, dtype=float)
    q = np.asarray(q, dtype=float)
    poses = np.asarray(poses, dtype=float)
    n = len(poses)

    def legs(qq: np.ndarray, pp: np.ndarray) -> np.ndarray:
        return predict_legs(robot, x, qq, pp)

    dq = np.empty((n, 6, robot.n_joints))
    for i in range(robot.n_joints):
        e = np.zeros_like(q)
        e[:, i] = h
        dq[:, :, i] = (legs(q + e, poses) - legs(q - e, poses)) / (2 * h)
    dp = np.empty((n, 6, 3))
    for i in range(3):
        e = np.zeros_like(poses)
        e[:, i] = h
        dp[:, :, i] = (legs(q, poses + e) - legs(q, poses - e)) / (2 * h)
    dr = np.empty((n, 6, 3))
    t = pose_matrix(poses)
    for i in range(3):
        w = np.zeros(3)
        w[i] = h
        up, dn = t.copy(), t.copy()
        up[:, :3, :3] = t[:, :3, :3] @ rotvec_matrix(w)
        dn[:, :3, :3] = t[:, :3, :3] @ rotvec_matrix(-w)
        dr[:, :, i] = (legs(q, pose_from_matrix(up)) - legs(q, pose_from_matrix(dn))) / (2 * h)
    return dq, dp, dr


def uncertainty(
    robot: Robot,
    measurements: Measurements,
    x: Any,
    noise: float | Noise | None = None,
    *,
    active: Any = None,
    weighted: bool = False,
) -> Uncertainty:
    """Covariance and standard deviations of identified parameters.

    Parameters
    ----------
    robot : Robot
        The nominal robot.
    measurements : Measurements
        The calibration data.
    x : array_like, shape (n_params,)
        The identified error vector (the least-squares solution).
    noise : None, float or Noise
        ``None``: estimate the leg noise from the residuals at ``x``,
        ``sigma^2 = cost / (6 N - n_active)``. A float: the leg noise sigma (mm). An
        :class:`iwr.Noise`: its leg noise plus its joint, position and orientation noise
        propagated to the readings through :func:`measurement_jacobians` (per pose, the six legs
        share the pose noise, so their errors are correlated).
    active : array_like of bool or IdentifiabilityReport, optional
        The parameters that were identified; default: the base parameters of
        :func:`iwr.identifiability` at ``x``. The matrix ``J^T J`` of the active parameters must
        be nonsingular.
    weighted : bool
        ``x`` minimises the noise-weighted objective (``iwr.identify(method=..., noise=Noise)``,
        :func:`iwr.problem.gls_whitening`), not eq. (10): the covariance is ``(J_w^T J_w)^-1``
        of the whitened Jacobian (the noise known: no scaling). Needs ``noise`` an
        :class:`iwr.Noise`.

    Returns
    -------
    Uncertainty

    Notes
    -----
    First-order (the Cramer-Rao bound for Gaussian leg noise): valid while the noise moves the
    solution little compared with the curvature of the model, which holds by orders of magnitude
    for micrometre noise. Errors in the measured poses make the estimate slightly biased (errors in
    variables); the covariance does not include that bias.
    """
    return kinds.of(measurements).uncertainty(robot, measurements, x, noise, active=active,
                                              weighted=weighted)


def pose_uncertainty(robot: Robot, measurements: Measurements, x: Any,
                     noise: float | Noise | None = None, *, active: Any = None,
                     weighted: bool = False) -> Uncertainty:
    """:func:`uncertainty` on pose data (the platform pose measured in {0})."""
    if weighted and not isinstance(noise, Noise):
        raise ValueError(f"weighted=True needs noise an iwr.Noise, got {noise!r}")
    problem: Any
    if robot.effects:  # issue 23: the geometric errors, then the effects' parameters
        from ..effects.api import EffectIdentifiability
        from ..effects.problem import EffectProblem

        problem = EffectProblem(robot, measurements, noise=noise if weighted else None)
        reports: tuple[type, ...] = (IdentifiabilityReport, EffectIdentifiability)
    else:
        problem = Problem(robot, measurements, noise=noise if weighted else None)
        reports = (IdentifiabilityReport,)
    n_all = problem.n_params
    x = np.array(x, dtype=float)
    if x.shape != (n_all,) or not np.all(np.isfinite(x)):
        raise ValueError(f"x: expected {n_all} finite values, got shape {x.shape}")
    if active is None:
        mask = identifiability(robot, measurements, x).active
    elif isinstance(active, reports):
        mask = active.active
    else:
        mask = np.asarray(active, dtype=bool)
        if mask.shape != (n_all,):
            raise ValueError(f"active: boolean mask of shape {mask.shape}; expected "
                             f"({n_all},)")
    r, jac = problem.residuals_and_jacobian(x)
    jb = jac[:, mask]
    m, p = jb.shape
    dof = m - p
    # (J^T J)^-1 J^T through the SVD of the column-scaled Jacobian: the scaling keeps the
    # conditioning of mm against rad columns out of the way.
    d = np.linalg.norm(jb, axis=0)
    d = np.where(d > 0, d, 1.0)
    u, s, vt = np.linalg.svd(jb / d, full_matrices=False)
    if s.size < p or s[-1] <= s[0] * max(m, p) * np.finfo(float).eps:
        raise ValueError(
            "active: the Jacobian of the active parameters is rank deficient; hold the "
            "unidentifiable ones fixed (active=iwr.identifiability(...).active)"
        )
    a = (vt.T / s) @ u.T / d[:, None]  # (p, m): dx = -a @ e
    if weighted:  # whitened residuals have unit variance
        sigma = float(noise.legs)  # type: ignore[union-attr]
        cov = a @ a.T
        source = "weighted"
    elif noise is None:
        if dof <= 0:
            raise ValueError(f"measurements: {m} readings for {p} parameters; cannot estimate "
                             "the noise from the residuals (pass noise=)")
        sigma = float(np.sqrt(r @ r / dof))
        cov = sigma**2 * (a @ a.T)
        source = "residuals"
    elif isinstance(noise, Noise):
        sigma = float(noise.legs)
        cov = _propagated(robot, measurements, x, noise, a)
        source = "noise"
    else:
        sigma = float(noise)
        if not (np.isfinite(sigma) and sigma >= 0):
            raise ValueError(f"noise: {noise!r}; expected None, a leg sigma >= 0 (mm) or an "
                             "iwr.Noise")
        w = _sqrt_weights(measurements, m)
        cov = sigma**2 * ((a * w**2) @ a.T)
        source = "legs"
    std = np.full(n_all, np.nan)
    std[mask] = np.sqrt(np.diag(cov))
    return Uncertainty(problem.parameter_names, mask, cov, std, sigma, source, dof)


def _sqrt_weights(measurements: Measurements, m: int) -> np.ndarray:
    """sqrt of the residual weights, pose-major (residual = sqrt(w) (predicted - measured))."""
    if measurements.weights is None:
        return np.ones(m)
    return np.sqrt(measurements.weights).ravel()


def _propagated(
    robot: Robot, measurements: Measurements, x: np.ndarray, noise: Noise, a: np.ndarray
) -> np.ndarray:
    """``A Cov(residuals) A^T`` with the per-pose 6x6 reading covariance
    ``sigma_legs^2 I + G diag(sigma_q^2, sigma_p^2, sigma_o^2) G^T``."""
    mm = measurements
    if robot.effects:  # the exact derivatives of the loop closure with the effects
        from ..implicit_loop import loop_jacobians

        _, _, jy = loop_jacobians(robot, x, mm.q, mm.poses, data=mm)
        nj = robot.n_joints
        dq, dp, dr = jy[..., :nj], jy[..., nj: nj + 3], jy[..., nj + 3:]
    else:
        dq, dp, dr = measurement_jacobians(robot, x, mm.q, mm.poses)
    sq = np.array([noise.joint_lengths if c == "P" else noise.joint_angles
                   for c in robot.joint_types])
    g = np.concatenate([dq * sq, dp * noise.position, dr * noise.orientation], axis=2)
    c = np.einsum("kij,klj->kil", g, g) + noise.legs**2 * np.eye(6)  # (N, 6, 6)
    w = _sqrt_weights(mm, a.shape[1]).reshape(-1, 6)
    c = c * w[:, :, None] * w[:, None, :]
    ak = a.reshape(a.shape[0], -1, 6)  # (p, N, 6)
    return np.einsum("pki,kij,qkj->pq", ak, c, ak)


# -- laser-tracker data ---------------------------------------------------------------------------
def _tracker_uncertainty(robot: Robot, measurements: Any, x: Any, noise: Any,
                         active: Any, weighted: bool = False) -> Uncertainty:
    """:func:`uncertainty` on tracker data (docs/tracker.md): the covariance of the unweighted
    least-squares estimate (what :func:`iwr.identify` computes on these data) of the active
    parameters, robot's and setup's, ``A Cov(r) A^T`` with ``A = (J^T J)^-1 J^T`` and ``J`` the
    tracker problem's exact Jacobian over the seen points.

    ``noise``: None (isotropic point noise estimated from the residuals,
    ``sigma^2 = cost / (3 n_seen - n_active)``), a float (that point sigma, mm per coordinate),
    a :class:`iwr.tracker.TrackerNoise` (each point's covariance, long across the line of sight
    from the tracker's origin; a probe's orientation noise on its axis points), an
    :class:`iwr.Noise` (reading noise: legs and carriage joints, propagated to the points through
    the forward kinematics) or a pair of both. ``active``: a mask, a NullSpace, or None (one
    parameter per null direction held: :func:`iwr.tracker.null_space` at ``x``). ``weighted``:
    ``x`` minimises the noise-weighted point objective (``iwr.identify(..., noise=)`` on
    reflector points): ``(J_w^T J_w)^-1`` of its whitened Jacobian, ``noise`` the pair it was
    weighted by."""
    from ..tracker.start import tracker_problem

    problem, _ = tracker_problem(robot, measurements, x0=x)
    wp = tracker_problem(robot, measurements, noise=noise)[0] if weighted else None
    return tracker_covariance(problem, x, noise, active, weighted=wp)


def tracker_covariance(problem: Any, x: Any, noise: Any, active: Any, *, weighted: Any = None,
                       gradients: Any = None) -> Uncertainty:
    """:func:`_tracker_uncertainty` on ``problem`` (any tracker problem: the geometry's, or
    :class:`iwr.effects.tracker.TrackerEffectProblem` with the effects' parameters between the
    robot's and the setup's): ``active`` a mask, a NullSpace, or None (:func:`null_space` of
    ``problem`` at ``x``); ``weighted`` the noise-weighted problem ``x`` minimises (its
    whitened Jacobian's ``(J_w^T J_w)^-1``), or None; ``gradients`` the derivatives (N, 3 K,
    n_joints + 6) of the predicted points in the joint and leg readings (default: central
    differences of the geometric forward kinematics)."""
    from ..noise import split_noise
    from ..tracker.analysis import NullSpace, null_space

    x = np.array(x, dtype=float)
    n = problem.n_params
    if active is None:
        mask = null_space(problem, x).active
    elif isinstance(active, NullSpace):
        mask = active.active
    else:
        mask = np.asarray(active, dtype=bool)
        if mask.shape != (n,):
            raise ValueError(f"active: boolean mask of shape {mask.shape}; expected ({n},) ("
                             + ", ".join(_parts(problem)) + ")")
    r, jac = (weighted if weighted is not None else problem).residuals_and_jacobian(x)
    jb = jac[:, mask]
    # Weighted: the whitened residuals that carry data (a probe's: six a pose).
    m = (weighted if weighted is not None else problem).n_observations
    p = int(mask.sum())
    dof = m - p
    d = np.linalg.norm(jb, axis=0)
    d = np.where(d > 0, d, 1.0)
    u, s, vt = np.linalg.svd(jb / d, full_matrices=False)
    if s.size < p or s[-1] <= s[0] * max(jb.shape) * np.finfo(float).eps:
        raise ValueError("active: the tracker problem's Jacobian of the active parameters is "
                         "rank deficient; hold one parameter per null direction "
                         "(active=iwr.identifiability(robot, data).active)")
    a = (vt.T / s) @ u.T / d[:, None]  # (p, 3 N P); zero columns for unseen points
    if weighted is not None:  # whitened residuals have unit variance
        cov = a @ a.T
        sigma, source = float("nan"), "weighted"
    elif noise is None or isinstance(noise, (int, float)) and not isinstance(noise, bool):
        if noise is None:
            if dof <= 0:
                raise ValueError(f"measurements: {m} point coordinates for {p} parameters; "
                                 "cannot estimate the noise from the residuals (pass noise=)")
            sigma, source = float(np.sqrt(r @ r / dof)), "point residuals"
        else:
            sigma, source = float(noise), "point sigma"
            if not (np.isfinite(sigma) and sigma >= 0):
                raise ValueError(f"noise: {noise!r}; expected None, a point sigma >= 0 (mm), "
                                 "an iwr.tracker.TrackerNoise, an iwr.Noise or a pair")
        cov = sigma**2 * (a @ a.T)
    else:
        readings, tracker = split_noise(noise)
        c = _point_covariance(problem, x, readings, tracker, gradients)  # (N, 3P, 3P)
        ak = a.reshape(p, problem.n_poses, -1)
        cov = np.einsum("pki,kij,qkj->pq", ak, c, ak)
        sigma, source = float("nan"), "tracker noise"
    std = np.full(n, np.nan)
    std[mask] = np.sqrt(np.diag(cov))
    return Uncertainty(problem.parameter_names, mask, cov, std, sigma, source, dof)


def _parts(problem: Any) -> list[str]:
    """What a tracker problem's parameters are, for messages."""
    robot, ns = problem.robot, problem.setup.n_params
    n_effects = problem.n_params - robot.n_params - ns
    return ([f"the robot's {robot.n_params}"]
            + ([f"{n_effects} effect parameters"] if n_effects else [])
            + [f"then the setup's {ns}"])


def _point_covariance(problem: Any, x: np.ndarray, readings: Noise | None,
                      tracker: Any, gradients: Any = None) -> np.ndarray:
    """Per pose, the covariance (3P, 3P) of the residuals (predicted minus measured points) from
    the tracker's noise (on the measured points) and the readings' (through the predicted ones;
    ``gradients``, a function giving their derivatives (N, 3P, n_joints + 6) in the joint and
    leg readings, default central differences of the forward kinematics, as
    :func:`measurement_jacobians`)."""
    from ..tracker.data import TrackerMeasurements
    from ..tracker.problem import TrackerProblem

    m, setup = problem.measurements, problem.setup
    n, npts = problem.n_poses, setup.n_points
    c = np.zeros((n, 3 * npts, 3 * npts))
    meas = m.tracker_points(setup).reshape(n, npts, 3)
    if tracker is not None:
        def point_cov(p: np.ndarray) -> np.ndarray:  # (..., 3) -> (..., 3, 3)
            dist = np.linalg.norm(p, axis=-1)
            e = p / np.where(dist > 0, dist, 1.0)[..., None]
            sr, st = tracker.sigmas(dist)
            outer = e[..., :, None] * e[..., None, :]
            return (sr**2)[..., None, None] * outer + (st**2)[..., None, None] * (
                np.eye(3) - outer)

        if setup.kind == "points":
            blocks = point_cov(np.nan_to_num(meas))
            for i in range(npts):
                c[:, 3 * i:3 * i + 3, 3 * i:3 * i + 3] = blocks[:, i]
        else:
            # The probe's origin has the point noise; its axis points also turn with its
            # orientation error w (a rotation in {T}): a_c + L w x a_c, i.e. -L [a_c]x w.
            co = point_cov(meas[:, 0])
            g = np.zeros((n, 12, 6))
            g[:, :, :3] = np.tile(np.eye(3), (4, 1))
            axes = (meas[:, 1:] - meas[:, :1]) / setup.probe_length
            for k in range(3):
                ax = axes[:, k]
                skew = np.zeros((n, 3, 3))
                skew[:, 0, 1], skew[:, 0, 2] = -ax[:, 2], ax[:, 1]
                skew[:, 1, 0], skew[:, 1, 2] = ax[:, 2], -ax[:, 0]
                skew[:, 2, 0], skew[:, 2, 1] = -ax[:, 1], ax[:, 0]
                g[:, 3 * k + 3:3 * k + 6, 3:] = -setup.probe_length * skew
            src = np.zeros((n, 6, 6))
            src[:, :3, :3] = co
            src[:, 3:, 3:] = tracker.orientation**2 * np.eye(3)
            c += g @ src @ np.swapaxes(g, 1, 2)
    if readings is not None and not readings.is_zero:
        robot = problem.robot
        sig = np.concatenate([np.where([t == "P" for t in robot.joint_types],
                                       readings.joint_lengths, readings.joint_angles),
                              np.full(6, readings.legs)])
        h = 1e-4
        base_q, base_legs = m.q, m.legs
        grads = np.zeros((n, 3 * npts, sig.size)) if gradients is None else gradients()
        for j in range(sig.size if gradients is None else 0):
            if sig[j] == 0:
                continue
            pred = []
            for sign in (1.0, -1.0):
                q, legs = base_q.copy(), base_legs.copy()
                if j < robot.n_joints:
                    q[:, j] += sign * h
                else:
                    legs[:, j - robot.n_joints] += sign * h
                pm = TrackerMeasurements(q, legs, points=m.points, probe=m.probe,
                                         joint_types=m.joint_types)
                pred.append(TrackerProblem(robot, setup, pm, reference=x[:robot.n_params])
                            .predicted_points(x).reshape(n, -1))
            grads[:, :, j] = (pred[0] - pred[1]) / (2 * h)
        gs = grads * sig
        c += gs @ np.swapaxes(gs, 1, 2)
    seen = ~np.isnan(meas[:, :, 0])
    rows = np.repeat(seen, 3, axis=1)
    c[~rows] = 0.0  # unseen points: no residual (their columns of A are zero anyway)
    c[np.repeat(~rows[:, None, :], 3 * npts, axis=1)] = 0.0
    return c
