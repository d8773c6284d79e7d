"""The identification problem for tracker data: residuals in tracker space, in C++."""

from __future__ import annotations

from typing import Any

import numpy as np

from .. import _core
from ..problem_base import FAILED_RESIDUAL, ProblemBase, reference_error
from ..robot import Robot
from ..transforms import pose_matrix, skew
from .data import TrackerMeasurements
from .setup import TrackerSetup

__all__ = ["TrackerProblem", "FAILED_RESIDUAL", "noise_whitening", "point_covariances"]


class TrackerProblem(ProblemBase):
    """The identification problem for reflector points or probe poses in the tracker frame.

    A :class:`iwr.problem_base.ProblemBase`, as :class:`iwr.Problem`: every method runs on it
    through :class:`iwr.ReducedProblem`.

    Parameters
    ----------
    robot : Robot
        The nominal robot.
    setup : TrackerSetup
        The nominal measurement setup.
    measurements : TrackerMeasurements
    bounds : None or (lower, upper)
        Search bounds of all ``n_params`` parameters; default the robot's default bounds, then
        the setup's (:meth:`TrackerSetup.default_bounds`, about ``center``).
    center : array_like, shape (setup.n_params,), optional
        Centre of the setup's default bounds, for example the parameters of a registration
        guess (:attr:`RegistrationGuess.x_setup`); default zeros (the nominal setup).
    reference : array_like, shape (robot.n_params,), optional
        The robot error vector at which forward kinematics is solved once per pose, from
        ``robot.home_pose``; every evaluation starts its solve there. Default zeros.
    noise : (iwr.Noise or None, TrackerNoise), optional
        Weigh the residuals by the instruments' noise (generalised least squares with fixed
        weights, as :class:`iwr.Problem` with ``noise=``): each pose's point residuals whitened
        by their covariance (:func:`point_covariances`: the tracker's noise of each point, plus
        the leg and joint readings' noise propagated through the loop closure into the
        predicted points), evaluated at the nominal robot with the setup at ``weights_at``
        (default ``center``, else the nominal setup) and then held fixed. ``cost`` is then
        dimensionless (a chi-square statistic), ``cost_unweighted`` the sum of squared point
        residuals. A probe's four points move as one rigid pose: their covariance has rank 6
        and they are whitened by its pseudo-inverse (:func:`noise_whitening`; six whitened
        residuals per pose carry data). Without it: unweighted (mm).
    weights_at : array_like, shape (setup.n_params,), optional
        The setup's parameters at which the weights are evaluated (see ``noise``).
    whitening : array_like, shape (N, 3 n_points, 3 n_points), optional
        A whitening of one's own instead of ``noise`` (lower triangular per pose; any kind, a
        probe's four points too): residuals ``W_k r_k`` per pose, as with ``noise``. What
        :meth:`load` gives a weighted problem file.

    Notes
    -----
    Residual ``3 (K k + i) + c`` (pose k, point i, coordinate c) is predicted minus measured, in
    mm, in the tracker frame; K is the number of reflectors, or 4 for a probe (its origin and
    three points ``probe_length`` along its axes). A point not seen has residuals 0. A pose whose
    forward kinematics fails at ``x`` gets the finite residual ``FAILED_RESIDUAL`` (1000 mm) on
    each seen coordinate and zero Jacobian rows, so every method sees a huge but finite cost;
    :meth:`failures` names those poses and :meth:`check` raises on them.
    """

    data_type = TrackerMeasurements
    data_name = "iwr.tracker.TrackerMeasurements"
    file_holds = "tracker data"
    setup_type = TrackerSetup
    setup_name = "iwr.tracker.TrackerSetup"
    # issue 23: the C++ point objective models the geometry only; tracker data with effects run
    # on iwr.effects.tracker.TrackerEffectProblem (numpy; docs/effects.md)
    effects_what = ("the C++ point objective of tracker data (TrackerProblem, which DE, CRS2, "
                    "BOBYQA, the uncertainty, pose planning and the calibration job use)")

    def __init__(self, robot: Robot, setup: TrackerSetup, measurements: TrackerMeasurements,
                 bounds: Any = None, *, center: Any = None, reference: Any = None,
                 noise: Any = None, weights_at: Any = None, whitening: Any = None) -> None:
        self._accept(robot, measurements, setup)
        measurements.check_setup(setup)
        setup_bounds = None
        #: The set-up's centre (the registration guess): the plausible size is measured from it.
        self.setup_center: np.ndarray | None = (None if center is None
                                                else np.asarray(center, dtype=float))
        if bounds is None or isinstance(bounds, str):
            lo_s, hi_s = setup.default_bounds()
            c = np.zeros(setup.n_params) if center is None else np.asarray(center, dtype=float)
            if c.shape != (setup.n_params,) or not np.all(np.isfinite(c)):
                raise ValueError(f"center: expected {setup.n_params} finite values")
            setup_bounds = (lo_s + c, hi_s + c)
            self.setup_center = c
        self._set_bounds(bounds, setup_bounds)
        ref = self._set_reference(reference)
        try:
            self._objective = self._kernel(ref)
        except _core.ForwardKinematicsError as exc:
            # The reference solve (at `reference`, from the home pose) failed: name the data row.
            raise reference_error(exc, measurements) from None
        #: The per-pose whitening (N, 3 K, 3 K), lower triangular on the seen coordinates (zero
        #: rows and columns for unseen points), or None: unweighted.
        self.whitening = None
        self._weighted: Any = None  # the C++ objective with the whitening, made on first use
        self.noise = noise
        if whitening is not None:
            if noise is not None:
                raise ValueError("noise, whitening: give one or the other")
            self.whitening = _given_whitening(whitening, self.n_poses, self.n_residuals // max(
                self.n_poses, 1))
        if noise is not None:
            at = weights_at if weights_at is not None else center
            xs = np.zeros(setup.n_params) if at is None else np.asarray(at, dtype=float)
            if xs.shape != (setup.n_params,):
                raise ValueError(f"weights_at: expected {setup.n_params} setup parameters")
            self.whitening = noise_whitening(
                self, np.concatenate([np.zeros(robot.n_params), xs]), *noise)

    def _kernel(self, reference: np.ndarray) -> Any:
        """The C++ objective of these data (unweighted), its solves started at ``reference``."""
        setup, m = self.setup, self.measurements
        return _core.TrackerObjective(
            self.robot._geometry, setup.kind,
            setup.registration,
            setup.reflectors if setup.reflectors is not None else np.zeros((1, 3)),
            setup.probe if setup.probe is not None else np.zeros(6),
            setup.probe_length,
            m.q, m.legs, m.tracker_points(setup),
            reference, self.robot.home_pose,
        )

    # -- sizes and names ------------------------------------------------------------------------
    @property
    def n_residuals(self) -> int:
        """``3 N n_points`` (unseen points included, as zeros)."""
        return int(self._objective.n_residuals)

    @property
    def n_observations(self) -> int:
        """Residuals that carry data: 3 per seen point; weighted, the whitening's rows that are
        not zero (a probe's: 6 per pose, one rigid pose)."""
        return observations(self.whitening, 3 * int(self._objective.n_seen))

    @property
    def seen(self) -> np.ndarray:
        """Which residuals carry data, (n_residuals,) booleans: the coordinates of seen points
        (an unseen point's residuals are zeros)."""
        pts = self.measurements.tracker_points(self.setup).reshape(self.n_poses, -1, 3)
        return np.repeat(~np.isnan(pts[:, :, 0]).ravel(), 3)

    def x0(self, guess: Any = None) -> np.ndarray:
        """A starting point: the nominal robot (zeros), the setup's parameters of a
        :class:`RegistrationGuess` (or zeros: the nominal setup)."""
        xs = np.zeros(self.setup.n_params) if guess is None else np.asarray(guess.x_setup, float)
        if xs.shape != (self.setup.n_params,):
            raise ValueError(f"guess: {xs.size} setup parameters; expected {self.setup.n_params}")
        return np.concatenate([np.zeros(self.robot.n_params), xs])

    # -- the objective --------------------------------------------------------------------------
    def _whiten(self, r: np.ndarray) -> np.ndarray:
        """``W_k r_k`` per pose of residuals (or Jacobian rows) ``r`` (n_residuals, ...)."""
        return whiten(self.whitening, r)

    def cost(self, x: Any) -> float:
        """Sum of squared residuals (mm^2; weighted: dimensionless)."""
        if self.whitening is None:
            return float(self._objective.cost(self._x(x)))
        return float(np.sum(np.square(self.residuals(x))))

    def cost_unweighted(self, x: Any) -> float:
        """Sum of squared point residuals (mm^2), weighted or not."""
        return float(self._objective.cost(self._x(x)))

    def residuals(self, x: Any) -> np.ndarray:
        """Predicted minus measured points in {T} (weighted: whitened per pose), shape
        (n_residuals,), pose-major."""
        return self._whiten(self._objective.residuals(self._x(x)))

    def jacobian(self, x: Any) -> np.ndarray:
        """Exact Jacobian of :meth:`residuals` (implicit differentiation of the forward
        kinematics), shape (n_residuals, n_params)."""
        return self._whiten(self._objective.jacobian(self._x(x))[1])

    def residuals_and_jacobian(self, x: Any) -> tuple[np.ndarray, np.ndarray]:
        r, jac = self._objective.jacobian(self._x(x))
        return self._whiten(r), self._whiten(jac)

    def engine_objective(self) -> Any:
        """The C++ point objective (``iwr._core.TrackerObjective``); weighted, a second one that
        carries the whitening (made on first use: the residuals whitened per pose in C++, the
        engine's weighted cost)."""
        if self.whitening is None:
            return self._objective
        if self._weighted is None:
            n, m = self.whitening.shape[:2]
            kernel = self._kernel(self.reference)
            kernel.set_whitening(np.ascontiguousarray(self.whitening.reshape(n, m * m)))
            self._weighted = kernel
        return self._weighted

    # -- diagnostics ----------------------------------------------------------------------------
    def loop_jacobian(self, x: Any, poses: np.ndarray) -> np.ndarray:
        """The derivative (N, 6, n_joints + 6) of the predicted leg readings in the joint
        readings and the platform pose's correction ``(dp, w)`` at ``poses`` (the loop closure,
        :func:`iwr.implicit_loop.loop_jacobians`): what the readings' noise is propagated
        through (:func:`point_covariances`, the gross-error screen's misclosures)."""
        from ..implicit_loop import loop_jacobians

        x = self._x(x)
        return loop_jacobians(self.robot, x[:self.robot.n_params], self.measurements.q, poses)[2]

    def failures(self, x: Any) -> list[tuple[int, str]]:
        """Poses whose forward kinematics fails at ``x``: ``[(pose index, message)]``."""
        return [(int(k), str(m)) for k, m in self._objective.failures(self._x(x))]

    def platform_poses(self, x: Any) -> np.ndarray:
        """World poses of {5} (N, 6) by forward kinematics at ``x``; NaN rows where it fails."""
        return self._objective.platform_poses(self._x(x))

    def predicted_points(self, x: Any) -> np.ndarray:
        """Predicted points in {T}, shape (N, n_points, 3); NaN rows where it fails."""
        return self._objective.predicted_points(self._x(x)).reshape(self.n_poses, -1, 3)

    def __repr__(self) -> str:
        return (f"TrackerProblem(robot={self.robot.name!r}, kind={self.setup.kind!r}, "
                f"n_poses={self.n_poses}, n_params={self.n_params})")


def point_covariances(problem: TrackerProblem, x: Any, readings: Any, tracker: Any
                      ) -> np.ndarray:
    """Per pose the covariance (N, 3 K, 3 K) (mm^2) of the point residuals of ``problem`` at
    ``x`` (robot then setup), to first order: the tracker's noise of each measured point
    (``tracker``, a :class:`TrackerNoise`: its anisotropic covariance at the measured point; or
    the data's own ``point_sigma`` along the axes of {T}), plus the leg and joint readings' noise
    (``readings``, an :class:`iwr.Noise`, or None for none) propagated into the predicted points:
    ``G diag(sigma_q^2, sigma_legs^2) G^T``, ``G`` the derivative of the predicted points with
    respect to the joint and leg readings by implicit differentiation of the loop closure
    (:func:`iwr.estimation.loop_jacobians`). Rows and columns of unseen points are zero.

    A probe's four points are one reading, its pose: the tracker's part is its position's
    covariance (at the measured origin) and its orientation's (``tracker.orientation`` about
    each axis of {T}) carried to the four points as one rigid motion about the origin, with the
    predicted points' arms (as the readings' part moves them): the covariance has rank 6.
    ``problem``: any tracker problem with ``loop_jacobian`` (a robot with effects:
    :class:`iwr.effects.tracker.TrackerEffectProblem`, ``x`` its robot's, effects' then setup's
    parameters)."""
    robot, setup, m = problem.robot, problem.setup, problem.measurements
    x = problem._x(x)
    nr, n = problem.n_params - setup.n_params, problem.n_poses
    local = setup.platform_points(x[nr:])
    npt = len(local)
    cov = np.zeros((n, 3 * npt, 3 * npt))
    pts = m.tracker_points(setup).reshape(n, npt, 3)
    seen = ~np.isnan(pts[:, :, 0])
    if setup.kind == "probe":
        if tracker is not None:
            cov += _probe_covariance(problem, x, tracker)
    else:
        for i in range(npt):
            block = slice(3 * i, 3 * i + 3)
            if m.point_sigma is not None:
                cov[seen[:, i], block, block] = np.einsum(
                    "ki,ij->kij", np.square(m.point_sigma[seen[:, i], i]), np.eye(3))
            elif tracker is not None:
                cov[seen[:, i], block, block] = tracker.covariance(pts[seen[:, i], i])
    if readings is not None and not readings.is_zero:
        g = reading_jacobian(problem, x)
        prism = np.array([c == "P" for c in robot.joint_types], dtype=bool)
        var = np.concatenate([np.where(prism, readings.joint_lengths, readings.joint_angles),
                              np.full(6, readings.legs)]) ** 2
        mask = np.repeat(seen, 3, axis=1).astype(float)
        cov += np.einsum("kip,p,kjp->kij", g, var, g) * mask[:, :, None] * mask[:, None, :]
    return cov


def _probe_covariance(problem: Any, x: np.ndarray, tracker: Any) -> np.ndarray:
    """The probe reading's covariance (N, 12, 12) carried to its four points: ``T C T^T`` with
    ``C`` its position's (``tracker.covariance`` at the measured origin) and orientation's
    (``tracker.orientation^2`` about each axis of {T}) and ``T`` the points' change under a
    rigid motion ``(dp, w)`` about the origin, ``dp + w x arm``, the arms the predicted points'
    (ValueError naming a pose whose forward kinematics fails at ``x``)."""
    m = problem.measurements
    pred = np.asarray(problem.predicted_points(x), dtype=float)
    bad = np.flatnonzero(~np.all(np.isfinite(pred.reshape(len(pred), -1)), axis=1))
    if bad.size:
        raise ValueError(f"noise: {m.where(int(bad[0]))}: no forward kinematics at the point "
                         "where the weights are evaluated")
    n, npt = pred.shape[:2]
    arms = pred - pred[:, :1]
    t = np.zeros((n, npt, 3, 6))
    t[..., :3] = np.eye(3)
    t[..., 3:] = -skew(arms)  # dp + w x a = dp - [a]x w
    t = t.reshape(n, 3 * npt, 6)
    c = np.zeros((n, 6, 6))
    c[:, :3, :3] = tracker.covariance(m.probe[:, :3])
    c[:, 3:, 3:] = tracker.orientation ** 2 * np.eye(3)
    return np.einsum("kip,kpq,kjq->kij", t, c, t)


def noise_whitening(problem: Any, x: Any, readings: Any, tracker: Any) -> np.ndarray:
    """The per-pose whitening (N, 3 K, 3 K) of ``problem``'s point residuals by their
    covariance at ``x`` (:func:`point_covariances`): reflector points by the inverse of its
    Cholesky factor on the seen coordinates; a probe's four points, whose covariance has rank 6
    (one rigid pose), by a factor of its pseudo-inverse with six rows, ``W^T W = C^+``, lower
    triangular as every whitening is (six rows that carry data per pose)."""
    cov = point_covariances(problem, x, readings, tracker)
    if problem.setup.kind == "probe":
        return _rank_whitening(cov, 6, problem.measurements)
    return _whitening(cov, problem.seen, problem.measurements)


def observations(whitening: np.ndarray | None, unweighted: int) -> int:
    """The residuals that carry data: ``unweighted`` without a whitening, else its rows that
    are not zero (a probe's whitening has six per pose)."""
    if whitening is None:
        return unweighted
    return int(np.count_nonzero(np.any(whitening != 0, axis=2)))


def reading_jacobian(problem: Any, x: Any,
                     what: str = "noise: the point where the weights are evaluated") -> np.ndarray:
    """The derivative (N, 3 K, n_joints + 6) of the predicted points of ``problem`` (a tracker
    problem with ``loop_jacobian``) at ``x`` in the joint readings, then the leg readings: the
    platform pose's change per reading by implicit differentiation of the loop closure
    ``f(q + dq, pose (+) (dp, w)) = legs``, moving the points in {5} into {T}. ValueError
    naming the first pose whose forward kinematics fails at ``x`` (``what``: the argument at
    fault and what ``x`` is)."""
    robot, setup, m = problem.robot, problem.setup, problem.measurements
    x = problem._x(x)
    nr, nj, n = problem.n_params - setup.n_params, robot.n_joints, problem.n_poses
    local = setup.platform_points(x[nr:])
    poses = problem.platform_poses(x)
    bad = np.flatnonzero(~np.all(np.isfinite(poses), axis=1))
    if bad.size:
        head, _, at = what.partition(": ")
        raise ValueError(f"{head}: {m.where(int(bad[0]))}: no forward kinematics at {at}")
    jy = problem.loop_jacobian(x, poses)
    # Loop closure f(q + dq, pose (+) (dp, w)) = legs: the pose's change per reading.
    rhs = np.concatenate([-jy[:, :, :nj], np.broadcast_to(np.eye(6), (n, 6, 6))], axis=2)
    d_pose = np.linalg.solve(jy[:, :, nj:], rhs)  # (N, 6, nj + 6): d (dp, w) / d (q, legs)
    r0 = setup.registration_matrix(x[nr:])[:3, :3]
    rot = pose_matrix(poses)[:, :3, :3]
    d_pts = np.zeros((n, 3 * len(local), 6))
    for i, r in enumerate(local):
        d_pts[:, 3 * i:3 * i + 3, :3] = r0
        d_pts[:, 3 * i:3 * i + 3, 3:] = -r0 @ rot @ skew(r)  # R exp([w]x) r = R r - R [r]x w
    return d_pts @ d_pose


def whiten(whitening: np.ndarray | None, r: np.ndarray) -> np.ndarray:
    """``W_k r_k`` per pose of residuals (or Jacobian rows) ``r`` (n_residuals, ...), pose-major,
    with ``whitening`` (N, m, m); ``r`` itself when None (unweighted)."""
    if whitening is None:
        return r
    blocks = r.reshape(len(whitening), -1, *r.shape[1:])
    return np.einsum("kij,kj...->ki...", whitening, blocks).reshape(r.shape)


def _given_whitening(whitening: Any, n: int, m: int) -> np.ndarray:
    """A whitening given with the problem, checked: (n, m, m), finite, lower triangular."""
    wh = np.array(whitening, dtype=float)
    if wh.shape != (n, m, m):
        raise ValueError(f"whitening: shape {wh.shape}; expected ({n}, {m}, {m})")
    if not np.all(np.isfinite(wh)):
        raise ValueError("whitening: not every value is finite")
    upper = np.argwhere(np.triu(wh, 1) != 0)
    if upper.size:
        k, i, j = (int(v) for v in upper[0])
        raise ValueError(f"whitening: pose {k}, entry ({i}, {j}) is {wh[k, i, j]!r}; the "
                         "whitening of a pose must be lower triangular")
    return wh


def _whitening(cov: np.ndarray, seen: np.ndarray, measurements: Any) -> np.ndarray:
    """Per pose ``W_k = L_k^-1`` (zero rows and columns for unseen points) with ``L_k L_k^T``
    the covariance of its seen coordinates; ValueError naming a pose whose covariance is
    singular."""
    n = cov.shape[0]
    seen = seen.reshape(n, -1)
    w = np.zeros_like(cov)
    for k in range(n):
        idx = np.flatnonzero(seen[k])
        try:
            chol = np.linalg.cholesky(cov[k][np.ix_(idx, idx)])
        except np.linalg.LinAlgError:
            raise ValueError(
                f"noise: {measurements.where(k)}: the covariance of its point residuals is "
                "singular (a tracker without noise and no reading noise to spread it?): give the "
                "tracker a sigma > 0") from None
        w[k][np.ix_(idx, idx)] = np.tril(np.linalg.solve(chol, np.eye(idx.size)))
    return w


#: A covariance whose ``rank``-th largest eigenvalue is below this fraction of its largest has
#: lost a direction the noise should reach (a tracker without noise?).
_SINGULAR = 1e-8


def _rank_whitening(cov: np.ndarray, rank: int, measurements: Any) -> np.ndarray:
    """Per pose a lower-triangular ``W_k`` (m x m, its first ``m - rank`` rows zero) with
    ``W_k^T W_k`` the pseudo-inverse of the rank-``rank`` covariance ``cov[k]`` (its ``rank``
    eigen-directions of largest variance): ``B = diag(lambda)^-1/2 U^T`` (rank x m) made lower
    trapezoidal by an orthogonal change of its rows (a QR factorisation of ``B`` with rows and
    columns reversed), which changes no ``|W r|``. ValueError naming a pose whose covariance
    has fewer than ``rank`` directions of noise."""
    n, m = cov.shape[:2]
    vals, vecs = np.linalg.eigh(cov)  # ascending
    lost = np.flatnonzero(~(vals[:, m - rank] > _SINGULAR * vals[:, -1]))
    if lost.size:
        raise ValueError(
            f"noise: {measurements.where(int(lost[0]))}: the covariance of its probe residuals "
            f"has fewer than {rank} directions of noise (a tracker without noise and no reading "
            "noise to spread it?): give the tracker a sigma > 0 and an orientation > 0")
    b = np.swapaxes(vecs[:, :, m - rank:] / np.sqrt(vals[:, None, m - rank:]), 1, 2)
    r = np.linalg.qr(b[:, ::-1, ::-1], mode="r")  # (n, rank, m), upper trapezoidal
    w = np.zeros_like(cov)
    w[:, m - rank:, :] = np.tril(r[:, ::-1, ::-1], m - rank)
    return w
