"""The efficient estimator (:func:`iwr.estimation.efficient`) on laser-tracker data: what its
estimation loop needs to know of point and probe data (docs/estimation.md, "Tracker data").

Per pose the unknowns are the true joint readings and the true platform pose in {0} (about a
reference pose, the forward kinematics at the starting point); the readings are the six legs, the
joints, and the K reflector points (3 each, in {T}) or the probe pose (6). Each point is whitened
by its own anisotropic covariance (:meth:`TrackerNoise.whitening`: the distance sigma along the
line of sight, the transverse sigma across it), evaluated at the measured point: the covariance
depends on the true point only through its distance from the tracker, which the measurement
gives to a few micrometres in metres (a relative change of 1e-8), the usual choice in
errors-in-variables adjustment.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from .. import _core
from ..estimator_spec import EstimatorSpec
from ..noise import Noise, TrackerNoise, axis_whitening, split_noise
from ..robot import Robot
from ..transforms import skew as _skew
from .data import TrackerMeasurements
from .gauge import _align, _fk, null_space
from .start import _setup, tracker_problem

__all__ = ["TRACKER_COMPONENTS", "TrackerSpec", "tracker_misclosures",
           "tracker_predicted_accuracy", "tracker_reading_names"]

#: The variance components on tracker data: the reading noise (as :class:`iwr.Noise`'s fields)
#: and one factor each on the tracker's distance sigma (``distance`` and ``distance_per_m``
#: together), transverse sigma (``transverse`` and ``transverse_per_m``) and, for a probe, its
#: orientation sigma. ``"tracker"`` in ``estimate=`` names all of the tracker's.
TRACKER_COMPONENTS = ("legs", "joint_lengths", "joint_angles", "tracker_distance",
                      "tracker_transverse", "tracker_orientation")


def tracker_reading_names(robot: Robot) -> list[str]:
    """Names of the normalised residuals of one pose on tracker data: ``leg1 .. leg6``, ``q1 ..
    qn``, then per reflector ``reflector<name>.radial`` (along the line of sight),
    ``.across1``, ``.across2`` (the two directions across it, :meth:`TrackerNoise.basis`); for a
    probe ``probe.radial .. probe.across2`` and ``probe.rx .. probe.rz`` (its orientation error,
    a rotation vector in {T})."""
    setup = _setup(robot)
    head = [f"leg{j + 1}" for j in range(6)] + [f"q{i + 1}" for i in range(robot.n_joints)]
    parts = ("radial", "across1", "across2")
    if setup.kind == "probe":
        return head + [f"probe.{c}" for c in parts] + [f"probe.r{c}" for c in "xyz"]
    return head + [f"reflector{nm}.{c}" for nm in setup.names for c in parts]


def _noise(noise: Any) -> tuple[Noise, TrackerNoise, tuple[str, ...]]:
    """(reading noise, tracker noise, components to estimate) from ``noise=``: the convention of
    :func:`iwr.simulate` on a robot with a tracker (a pair ``(Noise, TrackerNoise)``), or
    ``"estimate"``."""
    if isinstance(noise, str):
        if noise != "estimate":
            raise ValueError(f"noise: {noise!r}; expected (iwr.Noise, TrackerNoise) or 'estimate'")
        r = Noise.realistic()
        return replace(r, position=0.0, orientation=0.0), TrackerNoise.leica(), TRACKER_COMPONENTS
    readings, tracker = split_noise(noise)
    if readings is None or tracker is None:
        raise ValueError(
            "noise: the efficient estimator on tracker data weighs the leg and joint readings and "
            "the tracker: give both, noise=(iwr.Noise(legs=..., joint_lengths=..., "
            "joint_angles=...), iwr.tracker.TrackerNoise.leica()) (as iwr.simulate takes it), "
            "or noise='estimate'")
    return readings, tracker, ()


class TrackerSpec(EstimatorSpec):
    """The tracker kinds' part of the estimation loop (the pose kind's is
    ``iwr.estimation._PoseSpec``; the same base, :class:`iwr.estimator_spec.EstimatorSpec`)."""

    kind = "tracker"
    instrument = "tracker"

    def __init__(self, robot: Robot, measurements: TrackerMeasurements, noise: Any, x0: Any,
                 active: Any, estimate: Any, bounds: Any, plausible: float) -> None:
        from ..estimation import _active_mask
        from ..methods.lm import levenberg_marquardt
        from ..methods.reduced import ReducedProblem

        self._readings(robot, measurements, noise, estimate)
        setup = self.setup
        problem, start = tracker_problem(robot, measurements, bounds, x0)
        self.problem = problem
        nr = robot.n_params
        self.mask = _active_mask(active, problem.n_params,
                                 lambda: null_space(problem, start).active)
        # The start: eq. (10)'s analogue on points (LM, unweighted), from the nominal robot and
        # the registration guess; the estimator then only refines (its first steps from a frame
        # 2 m off would put radians into the pose corrections, far from linear).
        lm = levenberg_marquardt(ReducedProblem(problem, self.mask, start), progress=False)
        self.x_start = np.array(lm.x, dtype=float)
        ref = problem.platform_poses(self.x_start)
        bad = np.flatnonzero(~np.all(np.isfinite(ref), axis=1))
        if bad.size:
            raise _core.ForwardKinematicsError(
                f"{measurements.where(int(bad[0]))}: the leg readings have no forward kinematics "
                f"at the starting point ({bad.size} poses)")
        self.reference = np.ascontiguousarray(ref)
        self.parameter_names = problem.parameter_names
        # Plausible size: about the nominal robot and the set-up's centre, the data's
        # registration guess (also from an x0: tracker_problem; it was x0's set-up, so a start
        # from the file's registration 2 m off failed what LM's test passes), x0's set-up only
        # where there is none (bounds given).
        self.center = np.concatenate([np.zeros(nr), start[nr:] if problem.setup_center is None
                                      else problem.setup_center])
        if bounds is None or isinstance(bounds, str):
            half = np.concatenate([robot.default_bounds("default")[1], setup.default_bounds()[1]])
        else:
            lo, hi = (np.asarray(b, dtype=float) for b in (problem.lower, problem.upper))
            half = np.maximum(np.abs(lo - self.center), np.abs(hi - self.center))
        self.limit = plausible * half

    def _readings(self, robot: Robot, measurements: TrackerMeasurements, noise: Any,
                  estimate: Any) -> None:
        """The readings' part: the noise model, the legs' and joints' sigmas, the tracker's
        whitening per block, the variance components and the readings' names."""
        from ..estimation import _check_estimate
        from ..implicit_loop import _check_noise

        setup = _setup(robot)
        readings, tnoise, est = _noise(noise)
        extra = ("tracker_orientation",) if setup.kind == "probe" else ()
        aliases = {"tracker": ("tracker_distance", "tracker_transverse") + extra}
        est = _check_estimate(estimate, est, TRACKER_COMPONENTS, aliases)
        _check_noise(readings)
        self.robot, self.setup, self.measurements = robot, setup, measurements
        self.noise0 = (readings, tnoise)
        self.n = len(measurements)
        nj = robot.n_joints
        # Readings: sigma of the legs and joints.
        prism = np.array([c == "P" for c in robot.joint_types], dtype=bool)
        self.sigma_all = np.empty((self.n, 6 + nj))
        self.sigma_all[:, :6] = readings.legs
        self.sigma_all[:, 6:] = np.where(prism, readings.joint_lengths, readings.joint_angles)
        # The tracker: whitening per block (reflectors; or the probe's position and orientation).
        if setup.kind == "points":
            assert measurements.points is not None
            pts = measurements.points
            self.measured = np.ascontiguousarray(pts.reshape(self.n, -1))
            seen = ~np.isnan(pts[:, :, 0])
            w = np.zeros(pts.shape + (3,))
            if measurements.point_sigma is None:
                w[seen] = tnoise.whitening(pts[seen])
            else:  # each point's own uncertainties (tracker software's), taken as given
                w[seen] = axis_whitening(pts[seen], measurements.point_sigma[seen])
                est = tuple(c for c in est if not c.startswith("tracker_"))
            nb = pts.shape[1]
        else:
            assert measurements.probe is not None
            if not tnoise.orientation > 0:
                raise ValueError("noise: TrackerNoise.orientation is 0; a probe's orientation "
                                 "reading needs a standard deviation > 0")
            self.measured = np.ascontiguousarray(measurements.probe)
            w = np.zeros((self.n, 2, 3, 3))
            w[:, 0] = tnoise.whitening(measurements.probe[:, :3])
            w[:, 1] = np.eye(3) / tnoise.orientation
            nb = 2
        self.whitening_all = w
        base = 6 + nj
        pos_blocks = range(nb) if setup.kind == "points" else range(1)
        self.cols = {
            "legs": np.arange(6),
            "joint_lengths": 6 + np.flatnonzero(prism),
            "joint_angles": 6 + np.flatnonzero(~prism),
            "tracker_distance": np.array([base + 3 * b for b in pos_blocks], dtype=int),
            "tracker_transverse": np.array([base + 3 * b + c for b in pos_blocks for c in (1, 2)],
                                           dtype=int),
            "tracker_orientation": (np.arange(base + 3, base + 6) if setup.kind == "probe"
                                    else np.zeros(0, dtype=int)),
        }
        self.est = tuple(c for c in est if self.cols[c].size and self.start_sigma(c) > 0)
        self.names = tracker_reading_names(robot)
        self.ny = nj + 6

    def start_sigma(self, c: str) -> float:
        readings, tn = self.noise0
        if c.startswith("tracker_"):
            return float(getattr(tn, c[len("tracker_"):]))
        return float(getattr(readings, c))

    def scaled(self, scale: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """The readings' sigmas (N, 6 + n_joints) and the tracker's whitening (N, blocks, 3, 3)
        with the variance components' factors ``scale`` applied."""
        s = self.sigma_all.copy()
        w = self.whitening_all.copy()
        nj = self.robot.n_joints
        for c, f in scale.items():
            if c.startswith("tracker_"):
                for col in self.cols[c]:
                    b, row = divmod(int(col) - 6 - nj, 3)
                    w[:, b, row, :] /= f
            else:
                s[:, self.cols[c]] *= f
        return s, w

    def solve(self, x: np.ndarray, idx: list[int], used: np.ndarray, scale: dict[str, float],
              corr: np.ndarray, max_iterations: int, cb: Any) -> dict[str, Any]:
        s, w = self.scaled(scale)
        m, st = self.measurements, self.setup
        return _core.implicit_loop_tracker(
            self.robot._geometry, st.kind, st.registration,
            st.reflectors if st.reflectors is not None else np.zeros((1, 3)),
            st.probe if st.probe is not None else np.zeros(6), st.probe_length,
            np.ascontiguousarray(self.measured[used]),
            np.ascontiguousarray(w[used].reshape(int(used.sum()), -1)),
            np.ascontiguousarray(self.reference[used]), x, idx,
            np.ascontiguousarray(m.q[used]), np.ascontiguousarray(m.legs[used]),
            np.ascontiguousarray(s[used]), np.ascontiguousarray(corr),
            max_iterations=int(max_iterations), callback=cb)

    def plausibility_model(self, used: np.ndarray) -> Any:
        # All the poses, the rejected ones too (as it always was: the ballbar's and the pose
        # kind's take the poses in use).
        from ..fit_test import tracker_readings

        return tracker_readings(self.problem)

    def noise_used(self, sigmas: dict[str, float]) -> tuple[Noise, TrackerNoise]:
        readings, tn = self.noise0
        f = {c: sigmas[c] / self.start_sigma(c) for c in sigmas if c.startswith("tracker_")}
        readings = replace(readings, **{c: v for c, v in sigmas.items()
                                        if not c.startswith("tracker_")})
        fd, ft = f.get("tracker_distance", 1.0), f.get("tracker_transverse", 1.0)
        tn = replace(tn, distance=tn.distance * fd, distance_per_m=tn.distance_per_m * fd,
                     transverse=tn.transverse * ft, transverse_per_m=tn.transverse_per_m * ft,
                     orientation=tn.orientation * f.get("tracker_orientation", 1.0))
        return readings, tn

    def predicted(self, x: np.ndarray, cov: np.ndarray, used: np.ndarray, tool: Any) -> Any:
        m = self.measurements
        return tracker_predicted_accuracy(self.robot, x, cov, self.mask, m.q[used], m.legs[used],
                                          tool=tool)



def _aligned_errors(a: np.ndarray, b: np.ndarray, tool: np.ndarray) -> np.ndarray:
    """Per pose the tool error vector (position in {T}, mm; orientation, a rotation vector in the
    tool frame, rad), (N, 6), of the frames ``a`` against ``b`` modulo the gauge, as
    :func:`tool_pose_errors` (``gauge="fit"``) measures its norms."""
    a = a @ _align(a, b)
    dp = a[:, :3, :3] @ tool + a[:, :3, 3] - (b[:, :3, :3] @ tool + b[:, :3, 3])
    r = np.swapaxes(b[:, :3, :3], 1, 2) @ a[:, :3, :3]
    w = 0.5 * np.stack([r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0],
                        r[:, 1, 0] - r[:, 0, 1]], axis=1)
    return np.concatenate([dp, w], axis=1)


def _frames(robot: Robot, x: np.ndarray, t05: np.ndarray, dpose: np.ndarray) -> np.ndarray:
    """:func:`tool_frames` (the joints' gauge, in {T}) with the platform poses ``t05`` (N, 4, 4)
    moved by ``dpose`` (N, 6): ``p + dp``, ``R exp([w]x)``."""
    from scipy.spatial.transform import Rotation

    from .registration import kabsch

    nj = robot.n_joints
    t = t05.copy()
    t[:, :3, 3] += dpose[:, :3]
    t[:, :3, :3] = t[:, :3, :3] @ Rotation.from_rotvec(dpose[:, 3:]).as_matrix()
    b = robot.platform_joints + x[4 * nj + 18: 4 * nj + 36].reshape(6, 3)
    r, c = kabsch(robot.platform_joints, b)
    k = np.eye(4)
    k[:3, :3], k[:3, 3] = r, c
    return _setup(robot).registration_matrix(x[robot.n_params:]) @ t @ k


def tracker_predicted_accuracy(robot: Robot, x: Any, covariance: Any, active: Any, q: Any,
                               legs: Any, *, tool: Any = None, n_samples: int = 500,
                               seed: int = 0, step: float = 1e-6) -> Any:
    """Predicted tool pose error (:class:`iwr.estimation.PredictedAccuracy`) of the model ``x``
    (robot then setup parameters) at the readings ``q``, ``legs``, from the covariance of its
    active parameters: ``G C G^T`` per pose, ``G`` the derivative of the tool error vector modulo
    the gauge (what :func:`tool_pose_errors` measures against a truth, with ``gauge="fit"``).
    The platform pose's derivative is exact (implicit differentiation of the loop closure,
    :func:`iwr.estimation.loop_jacobians`); the frame's composition with the registration, the
    joints' gauge and the gauge alignment is differentiated by central differences of step
    ``step`` (mm, rad; no forward kinematics in them). The orientation error is in the tool
    frame."""
    from ..accuracy_prediction import accuracy_from_covariances
    from ..implicit_loop import loop_jacobians
    from ..transforms import pose_matrix

    x = np.asarray(x, dtype=float)
    mask = np.asarray(active, dtype=bool)
    cov = np.asarray(covariance, dtype=float)
    q = np.asarray(q, dtype=float)
    legs = np.asarray(legs, dtype=float)
    t = np.zeros(3) if tool is None else np.asarray(tool, dtype=float).reshape(3)
    nr, nj = robot.n_params, robot.n_joints
    poses = _fk(robot, x[:nr], q, legs)
    _, jx, jy = loop_jacobians(robot, x[:nr], q, poses)
    g_pose = -np.linalg.solve(jy[:, :, nj:], jx)  # (N, 6, nr): d (dp, w) / d x_robot
    t05 = pose_matrix(poses)
    zero = np.zeros((len(poses), 6))
    base = _frames(robot, x, t05, zero)
    cols = []
    for i in np.flatnonzero(mask):
        e = np.zeros_like(x)
        e[i] = step
        d = g_pose[:, :, i] * step if i < nr else zero
        cols.append((_aligned_errors(_frames(robot, x + e, t05, d), base, t)
                     - _aligned_errors(_frames(robot, x - e, t05, -d), base, t)) / (2 * step))
    g = np.stack(cols, axis=2)  # (N, 6, p)
    cp = np.einsum("kip,pq,kjq->kij", g[:, :3], cov, g[:, :3])
    co = np.einsum("kip,pq,kjq->kij", g[:, 3:], cov, g[:, 3:])
    return accuracy_from_covariances(cp, co, n_samples=n_samples, seed=seed)


def tracker_misclosures(robot: Robot, measurements: TrackerMeasurements, x: Any,
                        noise: Any = None, problem: Any = None) -> Any:
    """:class:`iwr.misclosures.Misclosures` of tracker data at ``x`` (robot then setup
    parameters): per pose the predicted minus measured points in {T} (the reflectors, or the
    probe's four virtual points; NaN where unseen or where the forward kinematics fails), their
    derivatives in the parameters (:meth:`TrackerProblem.jacobian`) and in every reading: the leg
    and joint readings through the forward kinematics (the platform pose's derivative by implicit
    differentiation of the loop closure, :func:`iwr.estimation.loop_jacobians`), each point's x,
    y, z in {T} (a probe's position and its rotation about the axes of {T}). With ``noise`` (the
    pair ``(Noise, TrackerNoise)``) the readings' covariance: the legs and joints, each point's
    anisotropic covariance (:meth:`TrackerNoise.whitening`, or the file's own uncertainties);
    without, the unweighted point objective's identity metric. ``problem``: the tracker
    problem of ``measurements`` (default :func:`tracker_problem`'s; a robot with effects:
    :class:`iwr.effects.tracker.TrackerEffectProblem`, ``x`` its robot's, effects' then setup's
    parameters)."""
    from ..implicit_loop import _core_rotations
    from ..misclosures import Misclosures

    setup = _setup(robot)
    x = np.asarray(x, dtype=float)
    if problem is None:
        # The problem identify evaluated (within a calibration job: the same object,
        # iwr.kinds.reuse).
        problem, _ = tracker_problem(robot, measurements, x0=x)
    nr, nj, n = problem.n_params - setup.n_params, robot.n_joints, len(measurements)
    m = problem.n_residuals // n
    measured = measurements.tracker_points(setup).reshape(n, m)
    r = problem.residuals(x).reshape(n, m)
    a = problem.jacobian(x).reshape(n, m, -1)
    poses = problem.platform_poses(x)
    ok = np.all(np.isfinite(poses), axis=1)
    r = np.where(np.isfinite(measured) & ok[:, None], r, np.nan)
    safe = np.where(ok[:, None], poses, robot.home_pose)
    jy = problem.loop_jacobian(x, safe)
    g_legs = np.linalg.inv(jy[:, :, nj:])  # d (dp, w) / d legs
    g_q = -g_legs @ jy[:, :, :nj]
    reg = setup.registration_matrix(x[nr:])
    rr, tr = reg[:3, :3], reg[:3, 3]
    rot = _core_rotations(safe)
    pred = problem.predicted_points(x)  # (n, P, 3)
    npts = pred.shape[1]
    # Each predicted point in {5}: p_T = R_reg (p + R r5) + t_reg; d p_T = R_reg (dp - R [r5]x w).
    r5 = np.einsum("kji,kpj->kpi", rot, np.einsum("ji,kpj->kpi", rr, pred - tr) - safe[:, None, :3])
    r5 = np.nan_to_num(r5)
    skew = _skew(r5)
    d_pose = np.zeros((n, npts, 3, 6))
    d_pose[..., :3] = rr
    d_pose[..., 3:] = -np.einsum("ij,kjl,kplm->kpim", rr, rot, skew)
    b_legs = np.einsum("kpij,kjl->kpil", d_pose, g_legs).reshape(n, m, 6)
    b_q = np.einsum("kpij,kjl->kpil", d_pose, g_q).reshape(n, m, nj)
    head = [f"leg{j + 1}" for j in range(6)] + [f"q{i + 1}" for i in range(nj)]
    if setup.kind == "points":
        names = head + [f"reflector{nm}.{c}" for nm in setup.names for c in "xyz"]
        b_t = np.broadcast_to(-np.eye(m), (n, m, m))
    else:
        names = head + [f"probe.{c}" for c in "xyz"] + [f"probe.r{c}" for c in "xyz"]
        # The arms of the predicted points, as the readings' columns above take them: the two
        # rigid motions then span the same six directions (the measured points' arms tilted
        # them apart by misclosure / arm, and the covariance had a seventh direction at 1e-10).
        arms = pred - pred[:, :1]
        b_t = np.zeros((n, npts, 3, 6))
        b_t[..., :3] = -np.eye(3)
        # m_j = p + exp([w]x) (m_j - p): d r = -d m_j = [m_j - p]x w
        b_t[..., 3:] = np.nan_to_num(_skew(arms))
        b_t = b_t.reshape(n, m, 6)
    b = np.concatenate([b_legs, b_q, b_t], axis=2)
    # Each point's misclosure along the line of sight and across it (TrackerNoise.basis: an
    # orthonormal change of coordinates, which changes no test with a noise model), so that
    # without one the distance meter's and the angle encoders' noise, 2 to 3 times apart, each
    # get their own sigma (Misclosures.groups).
    rot = TrackerNoise.basis(np.where(np.isfinite(measured), measured, 1.0).reshape(n, npts, 3))
    rot_all = np.zeros((n, m, m))
    for i in range(npts):
        rot_all[:, 3 * i:3 * i + 3, 3 * i:3 * i + 3] = rot[:, i]
    r = np.einsum("kij,kj->ki", rot_all, np.nan_to_num(r)) + np.where(np.isnan(r), np.nan, 0.0)
    a = np.einsum("kij,kjp->kip", rot_all, a)
    b = np.einsum("kij,kjp->kip", rot_all, b)
    parts = ("radial", "across1", "across2")
    components = ([f"reflector{nm}.{c}" for nm in setup.names for c in parts]
                  if setup.kind == "points" else
                  [f"probe.{p}.{c}" for p in ("origin", "x", "y", "z") for c in parts])
    groups = np.tile([0, 1, 1], npts)
    if noise is None:
        return Misclosures(r, a, b, names, components, groups=groups)
    readings, tnoise, _ = _noise(noise)
    prism = np.array([c == "P" for c in robot.joint_types], dtype=bool)
    nread = len(names)
    cov = np.zeros((n, nread, nread))
    idx = np.arange(6 + nj)
    cov[:, idx[:6], idx[:6]] = readings.legs ** 2
    cov[:, 6 + np.arange(nj), 6 + np.arange(nj)] = np.where(
        prism, readings.joint_lengths, readings.joint_angles) ** 2
    base = 6 + nj
    if setup.kind == "points":
        pts = measurements.points
        assert pts is not None
        seen = ~np.isnan(pts[..., 0])
        w = np.zeros(pts.shape + (3,))
        w[seen] = (tnoise.whitening(pts[seen]) if measurements.point_sigma is None
                   else axis_whitening(pts[seen], measurements.point_sigma[seen]))
        w[~seen] = np.eye(3)
        pc = np.linalg.inv(np.swapaxes(w, -1, -2) @ w)  # (n, K, 3, 3)
        for i in range(pts.shape[1]):
            sl = slice(base + 3 * i, base + 3 * i + 3)
            cov[:, sl, sl] = pc[:, i]
    else:
        assert measurements.probe is not None
        wp = tnoise.whitening(measurements.probe[:, :3])
        cov[:, base:base + 3, base:base + 3] = np.linalg.inv(np.swapaxes(wp, -1, -2) @ wp)
        cov[:, base + 3:base + 6, base + 3:base + 6] = tnoise.orientation ** 2 * np.eye(3)
    return Misclosures(r, a, b, names, components, reading_cov=cov, groups=groups)
