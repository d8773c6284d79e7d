"""Laser-tracker data (reflector points or a probe in the tracker frame {T}) for a robot with
non-geometric effects (issue 23, docs/effects.md, "Tracker data").

The platform pose in {0} is not measured: it follows from the joint and leg readings by forward
kinematics *with the effects* (each leg's true length is its reading plus the leg offset plus
the effects' change, which depends on the pose through the leg forces and lengths; the carriage's
joints are first changed by the effects on them, the carriage's compliance under the load of the
hexapod and of the platform's bodies where the pose puts them), and the points are
``T_T0 0T5 r_i`` as without effects (:mod:`iwr.tracker`).

**Gravity comes through the registration.** The leg forces need gravity relative to the robot.
Tracker data do not fix {0}: a turn of the whole robot about its first joint's axis, and its
translations, are absorbed by the registration (the gauge of docs/tracker.md). A gravity vector
given in {0} would turn with that gauge, so that two parameter vectors the points cannot tell
apart would load the legs differently: the gauge would be decided by the compliance alone,
through a signal a million times smaller than the geometry's. Gravity is therefore given where
it is known, in the tracker frame (:attr:`iwr.tracker.TrackerSetup.gravity`, a levelled tracker's
``-z`` by default), and carried into {0} by the identified registration:
``g_0 = R_T0(x_setup)^T g_T`` (:func:`registration_gravity`). Every gauge motion then moves
{0} and gravity in it together, and the objective is exactly invariant along it (a test checks
it); the registration's two tilts, which the geometry identifies (docs/tracker.md), fix gravity
relative to the robot. The same gravity loads the carriage's joints. The effects' own
``gravity_m_s2`` (in {0}) is for pose data, which measure in {0}; on tracker data it is not
used.

Unknowns: the robot's geometric errors, the effects' parameters, then the setup's (registration
and reflector or probe offsets): ``x = (x_geometric, x_effects, x_setup)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np

from .. import _core
from ..problem_base import FAILED_RESIDUAL, check_joint_types
from ..tracker.problem import whiten
from ..transforms import pose_from_matrix, pose_matrix, rotvec_matrix
from . import LegState
from . import bounds as effect_bounds
from . import parameter_names as effect_names
from .gravity import registration_gravity, with_gravity
from .loop import _skew, loop_jacobians, right_jacobian
from .model import (
    _compliance,
    check_inputs,
    joint_changes,
    joint_effects,
    leg_forces,
    leg_vectors_at,
    loads,
    without_singular,
)

__all__ = ["EffectNullSpace", "EffectTrackerSpec", "TrackerEffectModel", "TrackerEffectProblem",
           "accuracy", "base_parameters", "design", "effect_tracker_problem", "gravity_jacobian",
           "identifiability", "identify", "leg_commands", "loop_model", "misclosures",
           "predicted_accuracy", "simulate", "tool_frames", "uncertainty"]

#: The relative rank threshold of the objective with effects (of its column-scaled Jacobian's
#: largest singular value): the Jacobian rests on forward kinematics solved to
#: :data:`FK_TOLERANCE_MM`, so directions the geometry cannot see show singular values up to
#: about 1e-11 instead of round-off's 1e-15; the weakest the data do see are above 1e-7 (the
#: platform frame relative to the loads, docs/effects.md).
RANK_RTOL = 1e-9
#: Newton's method for the forward kinematics with effects: the largest leg residual (mm) at
#: which a pose is solved, and the iterations allowed.
FK_TOLERANCE_MM = 1e-11
FK_MAX_ITERATIONS = 30


def _needs(robot: Any) -> set[str]:
    out: set[str] = set()
    for e in robot.effects:
        out |= e.needs
    return out


def _corrected(poses: np.ndarray, corr: np.ndarray | None, nj: int) -> np.ndarray:
    """The platform transforms (N, 4, 4) at poses moved by corrections ``(dq, dp, w)``."""
    t5 = pose_matrix(poses)
    if corr is not None:
        t5[:, :3, :3] = t5[:, :3, :3] @ rotvec_matrix(corr[:, nj + 3:])
        t5[:, :3, 3] += corr[:, nj: nj + 3]
    return t5


def gravity_jacobian(robot: Any, x: np.ndarray, q: np.ndarray, poses: np.ndarray, data: Any,
                     corrections: Any = None, joint_derivative: Any = None) -> np.ndarray:
    """The derivative (N, 6, 3) of the predicted leg readings in the gravity vector (in {0}),
    at the same point as :func:`iwr.effects.loop.loop_jacobians`. The loads are linear in
    gravity: the leg forces ``f = sum_c g_c f(e_c)``, each leg effect's change differentiated
    through its :class:`LegState` in the three components
    (:meth:`iwr.effects.Effect.leg_change`); the carriage's joint loads likewise, so the joints'
    change (:meth:`iwr.effects.Effect.joint_change`, linear in its loads) under gravity ``e_c``
    is its derivative in ``g_c``, which reaches the readings through their derivative in the true
    joint values (``joint_derivative`` (N, 6, n_joints), :func:`iwr.effects.loop.loop_jacobians`'
    with ``joint_derivative=True``; computed when not given). The leg forces' part is taken at
    the true joint values."""
    n, nj, ng = len(poses), robot.n_joints, robot.n_params
    out = np.zeros((n, 6, 3))
    xg, xe = x[:ng], x[ng:]
    corr = None if corrections is None else np.asarray(corrections, dtype=float)
    q_c = q if corr is None else q + corr[:, :nj]
    t5 = _corrected(poses, corr, nj)
    if joint_effects(robot):
        jq = joint_derivative
        if jq is None:
            jq = loop_jacobians(robot, x, q, poses, data, corr, joint_derivative=True)[3]
        for c, e in enumerate(np.eye(3)):  # the joints' change under gravity e_c
            change = joint_changes(with_gravity(robot, e), xg, xe, q_c, t5, data,
                                   loads_only=True)[0]
            out[..., c] = np.einsum("kji,ki->kj", jq, change)
        q_c = q_c + joint_changes(robot, xg, xe, q_c, t5, data)[0]
    if "forces" not in _needs(robot):
        return out
    v, _, r = leg_vectors_at(robot, xg, q_c, t5, derivatives=False)
    comp = _compliance(robot)
    masses, centres = loads(comp, data, n)
    rot = t5[:, :3, :3]
    unit = np.stack([leg_forces(v, None, r, None, rot, masses, centres, e)[0]
                     for e in np.eye(3)], axis=2)  # (N, 6, 3)
    length = np.linalg.norm(v, axis=2)
    temps = None
    if "temperatures" in _needs(robot):
        temps = np.broadcast_to(data.temperatures, (n, 6))
    state = LegState(length, np.zeros((n, 6, 3)), unit @ comp.gravity, unit, temps)
    col = 0
    for e in robot.effects:
        k = len(e.parameter_names())
        if "legs" in e.changes:
            _, d_g, _ = e.leg_change(state, e.values() + xe[col: col + k])
            out -= d_g
        col += k
    return out


def _loop(robot: Any, xr: np.ndarray, xs: np.ndarray, setup: Any, q: np.ndarray,
          poses: np.ndarray, data: Any, corrections: Any = None
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`iwr.effects.loop.loop_jacobians` on tracker data: the predicted leg readings
    (N, 6) with the effects under gravity through the registration of ``xs``, their
    derivatives in ``x = (xr, xs)`` (N, 6, len(xr) + setup.n_params: the setup's through
    gravity, :func:`gravity_jacobian`) and in the corrections ``(dq, dp, w)``."""
    g0, dg0 = registration_gravity(setup, xs)
    rg = with_gravity(robot, g0)
    legs, jx, jy, jq = loop_jacobians(rg, xr, q, poses, data, corrections, joint_derivative=True)
    jg = gravity_jacobian(rg, xr, q, poses, data, corrections, jq)
    return legs, np.concatenate([jx, jg @ dg0], axis=2), jy


def _readings(robot: Any, xr: np.ndarray, q: np.ndarray, poses: np.ndarray, data: Any
              ) -> tuple[np.ndarray, np.ndarray]:
    """The leg readings (N, 6) the robot with ``xr`` (geometric, effects) predicts at platform
    poses ``poses`` under ``data``'s loads and temperatures (the carriage's joints changed by
    the effects on them first), without their derivatives in the parameters, and the geometry's
    derivative in the pose corrections ``(dp, w)`` (N, 6, 6)."""
    ng, nj = robot.n_params, robot.n_joints
    xg, xe = np.ascontiguousarray(xr[:ng]), xr[ng:]
    if joint_effects(robot):  # the carriage at its true joint values (loads at the readings)
        q = np.ascontiguousarray(q + joint_changes(robot, xg, xe, q, pose_matrix(poses), data)[0])
    legs, _, jy = _core.loop_jacobians(robot._geometry, xg, q, poses, np.zeros((0, 0)))
    n = len(poses)
    lengths = legs + robot.leg_offsets + xg[4 * nj + 36: 4 * nj + 42]
    needs = _needs(robot)
    forces = temps = None
    if "forces" in needs:
        t5 = pose_matrix(poses)
        v, _, r = leg_vectors_at(robot, xg, q, t5, derivatives=False)
        comp = _compliance(robot)
        masses, centres = loads(comp, data, n)
        forces = leg_forces(v, None, r, None, t5[:, :3, :3], masses, centres, comp.gravity)[0]
    if "temperatures" in needs:
        temps = np.broadcast_to(data.temperatures, (n, 6))
    state = LegState(lengths, np.zeros((n, 6, 0)), forces, np.zeros((n, 6, 0)), temps)
    out = legs.copy()
    col = 0
    for e in robot.effects:
        k = len(e.parameter_names())
        if "legs" in e.changes:
            out -= e.leg_change(state, e.values() + xe[col: col + k])[0]
        col += k
    return out, jy.reshape(n, 6, nj + 6)[:, :, nj:]


def _platform_points(setup: Any, xs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The points in {5} (P, 3) and their derivatives in the setup's parameters (P, 3, ns)."""
    local = setup.platform_points(xs)
    d = np.zeros((len(local), 3, setup.n_params))
    if setup.kind == "points":
        for i in range(len(local)):
            d[i, :, 6 + 3 * i: 9 + 3 * i] = np.eye(3)
        return local, d
    d[:, :, 6:9] = np.eye(3)
    # R_probe = Exp(r) R_nom: d (Exp(r) v) / dr = -[Exp(r) v]x J_l(r), J_l(r) = J_r(-r).
    jl = right_jacobian(-xs[9:12])
    for i in range(1, 4):
        d[i, :, 9:12] = -_skew(local[i] - local[0]) @ jl
    return local, d


class TrackerEffectModel:
    """The model of tracker data for a robot with effects: forward kinematics with the effects
    from the readings, the predicted points in {T}, and their exact derivatives in
    ``x = (x_geometric, x_effects, x_setup)`` (implicit differentiation of the loop closure with
    the effects, gravity through the registration)."""

    def __init__(self, robot: Any, setup: Any, data: Any) -> None:
        self.robot, self.setup, self.data = robot, setup, data
        self.n_geometric = robot.n_params
        self.n_effects = len(effect_names(robot.effects))
        self.n_params = self.n_geometric + self.n_effects + setup.n_params
        self.geometric = robot.with_effects()

    def split(self, x: Any) -> tuple[np.ndarray, np.ndarray]:
        """``x`` as (robot's geometric and effect parameters, setup's)."""
        x = np.asarray(x, dtype=float)
        if x.shape != (self.n_params,):
            raise ValueError(
                f"x: shape {x.shape}; expected ({self.n_params},): {self.n_geometric} geometric "
                f"errors, {self.n_effects} effect parameters ("
                + ", ".join(effect_names(self.robot.effects)) + f"), then the tracker setup's "
                f"{self.setup.n_params}")
        return x[: self.n_geometric + self.n_effects], x[self.n_geometric + self.n_effects:]

    def forward(self, x: Any, q: Any = None, legs: Any = None, data: Any = None
                ) -> tuple[np.ndarray, np.ndarray]:
        """The platform poses in {0} (N, 6) at which the robot with ``x`` gives the readings
        (default the data's) under the loads and temperatures of ``data`` (default the data's),
        and a mask of the poses solved (the others NaN): Newton's method with the exact pose
        Jacobian of the loop closure, from the geometric forward kinematics of the C++ core."""
        xr, xs = self.split(x)
        data = self.data if data is None else data
        q = np.ascontiguousarray(data.q if q is None else q, dtype=float)
        legs = np.asarray(data.legs if legs is None else legs, dtype=float)
        robot = with_gravity(self.robot, registration_gravity(self.setup, xs)[0])
        nj, ng = robot.n_joints, robot.n_params
        n = len(legs)
        poses = np.full((n, 6), np.nan)
        for k in range(n):  # pose by pose, so that one failure is not fatal
            try:
                poses[k] = _core.forward_kinematics(
                    robot._geometry, np.ascontiguousarray(xr[:ng]), q[k:k + 1],
                    np.ascontiguousarray(legs[k:k + 1]), np.zeros((0, 6)), robot.home_pose)[0][0]
            except _core.ForwardKinematicsError:
                pass
        ok = np.all(np.isfinite(poses), axis=1)
        live = np.flatnonzero(ok)
        sub = data.subset(live) if live.size < n and live.size else data
        # Newton's method with the geometry's pose Jacobian (the effects change it by a part
        # in 1e5: the convergence is linear at that rate), the readings with the effects.
        h = np.full((live.size, 6), np.inf)

        def readings(idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return _readings(robot, xr, q[idx], poses[idx],
                             sub if idx is live else data.subset(idx))

        for _ in range(FK_MAX_ITERATIONS + 1):
            if not live.size:
                break
            out, kept = without_singular(readings, live, ok, poses)
            if kept is not live:  # a singular hexapod: no forward kinematics there
                live = kept
                sub = data.subset(live) if live.size < n and live.size else data
                if not live.size:
                    break
            pred, jy = out
            h = pred - legs[live]
            if np.abs(h).max() <= FK_TOLERANCE_MM:
                break
            try:
                step = -np.linalg.solve(jy, h[..., None])[..., 0]
            except np.linalg.LinAlgError:
                break
            t5 = _corrected(poses[live], np.concatenate([np.zeros((live.size, nj)), step],
                                                        axis=1), nj)
            poses[live] = pose_from_matrix(t5)
        if live.size:
            bad = ~(np.abs(h).max(axis=1) <= 1e3 * FK_TOLERANCE_MM)
            ok[live[bad]] = False
            poses[live[bad]] = np.nan
        return poses, ok

    def points(self, x: Any, jacobian: bool = False) -> tuple[np.ndarray, Any, np.ndarray]:
        """The predicted points in {T} (N, P, 3), their derivatives in ``x`` (N, P, 3, n_params)
        when ``jacobian``, and the mask of the poses whose forward kinematics was solved (the
        others NaN, zero derivatives)."""
        xr, xs = self.split(x)
        data, setup = self.data, self.setup
        poses, ok = self.forward(x)
        local, dlocal = _platform_points(setup, xs)
        reg = setup.registration_matrix(xs)
        t5 = pose_matrix(np.where(ok[:, None], poses, 0.0))
        world = np.einsum("kab,pb->kpa", t5[:, :3, :3], local) + t5[:, None, :3, 3]  # in {0}
        pts = world @ reg[:3, :3].T + reg[:3, 3]
        pts[~ok] = np.nan
        if not jacobian:
            return pts, None, ok
        n, npt, nj = len(data), len(local), self.robot.n_joints
        nr = xr.size
        jac = np.zeros((n, npt, 3, self.n_params))
        live = np.flatnonzero(ok)
        if not live.size:
            return pts, jac, ok
        sub = data.subset(live) if live.size < n else data
        _, jx, jy = _loop(self.robot, xr, xs, setup, data.q[live], poses[live], sub)
        # The loop closure legs(x, pose (+) d) = readings: d d / d x = -J_pose^-1 d legs / d x.
        d_pose = -np.linalg.solve(jy[:, :, nj:], jx)  # (n, 6, nr + ns): (dp, w)
        r_reg = reg[:3, :3]
        rot = t5[live, :3, :3]
        # A point moves with the pose: R_T0 (dp + R [w]x r) = R_T0 (dp - R [r]x w).
        d_pt = np.zeros((live.size, npt, 3, 6))
        d_pt[..., :3] = r_reg
        d_pt[..., 3:] = -np.einsum("ab,kbc,pcd->kpad", r_reg, rot, _skew(local))
        jac[live] = np.einsum("kpad,kdx->kpax", d_pt, d_pose)
        # The setup's own: T_T0 = T_nom [Exp(r), t] (t in the nominal frame's axes), the points
        # in {5} (offsets).
        r_nom = pose_matrix(setup.registration)[:3, :3]
        c_rot = r_nom.T @ r_reg  # Exp(r)
        ns = slice(nr, self.n_params)
        jac[live, :, :, nr: nr + 3] += r_nom
        jac[live, :, :, nr + 3: nr + 6] -= np.einsum(
            "ab,bc,kpcd,de->kpae", r_nom, c_rot, _skew(world[live]), right_jacobian(xs[3:6]))
        jac[live, :, :, ns] += np.einsum("ab,kbc,pcx->kpax", r_reg, rot, dlocal)
        return pts, jac, ok


class TrackerEffectProblem:
    """The point (or probe) objective of tracker data for a robot with effects, a
    :class:`iwr.problem_base.LeastSquaresProblem`: residual ``3 (K k + i) + c`` is predicted minus
    measured point ``i`` of pose ``k`` in {T} (mm), zero where a point was not seen, as
    :class:`iwr.tracker.TrackerProblem`'s; the predicted points follow from forward kinematics
    with the effects (:class:`TrackerEffectModel`), and the Jacobian is exact (implicit
    differentiation; checked against central differences). The residuals and the Jacobian in
    numpy (LM, the identifiability analysis and the fit check); :meth:`cost` and
    :meth:`cost_batch` on the C++ objective with the effects
    (:func:`iwr.effects.tracker_objective.cpp_objective`, which DE, CRS2, BOBYQA and
    ``iwr-engine`` minimise; it agrees with the numpy model to round-off).

    ``bounds``: None or ``"default"`` (the robot's default bounds, the effects' own, the setup's
    about ``center``), ``"paper"``, or a pair over every parameter. ``reference``: the robot's
    geometric errors at which the C++ objective solves each pose's forward kinematics once
    (default zeros), as :class:`iwr.tracker.TrackerProblem`'s.

    ``noise`` ``(iwr.Noise or None, TrackerNoise)``: the noise-weighted objective, as
    :class:`iwr.tracker.TrackerProblem`'s: each pose's point residuals whitened by their
    covariance (:func:`iwr.tracker.problem.noise_whitening`, a probe's of rank 6: the tracker's
    noise of each point, plus the leg and joint readings' noise propagated through the loop
    closure *with the effects*, :meth:`loop_jacobian`), evaluated at the nominal robot and
    effects with the setup at ``weights_at`` (default ``center``) and then held fixed; ``cost``
    (in C++, the same whitening) is then a chi-square statistic, ``cost_unweighted`` the sum of
    squared point residuals."""

    def __init__(self, robot: Any, setup: Any, measurements: Any, bounds: Any = None, *,
                 center: Any = None, reference: Any = None, noise: Any = None,
                 weights_at: Any = None) -> None:
        from ..tracker.data import TrackerMeasurements

        if not robot.effects:
            raise ValueError(f"robot {robot.name!r}: no effect on; use iwr.tracker.TrackerProblem")
        if not isinstance(measurements, TrackerMeasurements):
            raise TypeError(f"measurements: expected an iwr.tracker.TrackerMeasurements, got "
                            f"{type(measurements).__name__}")
        measurements.check_setup(setup)
        check_joint_types(robot, measurements)
        check_inputs(robot, measurements)
        self.robot, self.setup, self.measurements = robot, setup, measurements
        self.model = TrackerEffectModel(robot, setup, measurements)
        n_all = self.model.n_params
        #: The set-up's centre (the registration guess): the plausible size is measured from it.
        self.setup_center: np.ndarray | None = (None if center is None
                                                else np.asarray(center, dtype=float))
        if bounds is None or isinstance(bounds, str):
            lo_r, hi_r = robot.default_bounds(bounds or "default")
            lo_e, hi_e = effect_bounds(robot.effects)
            lo_s, hi_s = setup.default_bounds()
            c = np.zeros(setup.n_params) if center is None else np.asarray(center, dtype=float)
            if c.shape != (setup.n_params,) or not np.all(np.isfinite(c)):
                raise ValueError(f"center: expected {setup.n_params} finite values")
            self.setup_center = c
            self.lower = np.concatenate([lo_r, lo_e, lo_s + c])
            self.upper = np.concatenate([hi_r, hi_e, hi_s + c])
        else:
            lo, hi = (np.broadcast_to(np.asarray(b, dtype=float), (n_all,)).copy()
                      for b in bounds)
            for i in range(n_all):
                if not (np.isfinite(lo[i]) and np.isfinite(hi[i]) and lo[i] < hi[i]):
                    raise ValueError(f"bounds: parameter {i} ({self.parameter_names[i]}) has "
                                     f"lower {lo[i]}, upper {hi[i]}")
            self.lower, self.upper = lo, hi
        meas = measurements.tracker_points(setup)
        self._measured = meas.reshape(len(measurements), -1, 3)
        self._seen = ~np.isnan(self._measured[:, :, 0])
        #: The per-pose whitening (N, 3 K, 3 K) or None (unweighted), and the noise it is of.
        self.whitening = None
        self.noise = None
        ref = np.zeros(robot.n_params) if reference is None else np.asarray(reference, float)
        if ref.shape != (robot.n_params,) or not np.all(np.isfinite(ref)):
            raise ValueError(f"reference: shape {ref.shape}; expected {robot.n_params} finite "
                             "geometric errors")
        self.reference = ref
        self._cpp: Any = None  # the C++ objective, made on first use (cpp_objective)
        if noise is not None:
            from ..tracker.problem import noise_whitening

            readings, tracker = noise
            at = weights_at if weights_at is not None else center
            xs = np.zeros(setup.n_params) if at is None else np.asarray(at, dtype=float)
            if xs.shape != (setup.n_params,):
                raise ValueError(f"weights_at: expected {setup.n_params} setup parameters")
            x_at = np.concatenate([np.zeros(n_all - setup.n_params), xs])
            self.whitening = noise_whitening(self, x_at, readings, tracker)
            self.noise = (readings, tracker)

    # -- sizes and names ----------------------------------------------------------------------
    @property
    def n_params(self) -> int:
        return self.model.n_params

    @property
    def n_poses(self) -> int:
        return len(self.measurements)

    @property
    def n_residuals(self) -> int:
        return int(self._measured[:, :, 0].size * 3)

    @property
    def n_observations(self) -> int:
        from ..tracker.problem import observations

        return observations(self.whitening, 3 * int(self._seen.sum()))

    @property
    def seen(self) -> np.ndarray:
        return np.repeat(self._seen.ravel(), 3)

    @property
    def parameter_names(self) -> list[str]:
        return (self.robot.parameter_names + effect_names(self.robot.effects)
                + list(self.setup.parameter_names))

    def _x(self, x: Any) -> np.ndarray:
        self.model.split(x)
        return np.asarray(x, dtype=float)

    def x0(self, guess: Any = None) -> np.ndarray:
        """The nominal robot and effects (zeros), the setup's parameters of a registration
        guess (or zeros)."""
        xs = np.zeros(self.setup.n_params) if guess is None else np.asarray(guess.x_setup, float)
        return np.concatenate([np.zeros(self.n_params - self.setup.n_params), xs])

    # -- the objective ------------------------------------------------------------------------
    def _residuals(self, pts: np.ndarray, ok: np.ndarray) -> np.ndarray:
        r = pts - self._measured
        r[~ok] = FAILED_RESIDUAL
        r[~self._seen] = 0.0
        return r.reshape(-1)

    def residuals(self, x: Any) -> np.ndarray:
        """Predicted minus measured points in {T} (weighted: whitened per pose), pose-major."""
        pts, _, ok = self.model.points(self._x(x))
        return whiten(self.whitening, self._residuals(pts, ok))

    def residuals_and_jacobian(self, x: Any) -> tuple[np.ndarray, np.ndarray]:
        pts, jac, ok = self.model.points(self._x(x), jacobian=True)
        jac[~self._seen] = 0.0
        return (whiten(self.whitening, self._residuals(pts, ok)),
                whiten(self.whitening, jac.reshape(-1, self.n_params)))

    def jacobian(self, x: Any) -> np.ndarray:
        return self.residuals_and_jacobian(x)[1]

    def _objective(self) -> Any:
        """The C++ objective with the effects (made once, with the whitening if any)."""
        if self._cpp is None:
            from .tracker_objective import cpp_objective

            self._cpp = cpp_objective(self.robot, self.setup, self.measurements, self.reference,
                                      self.whitening)
        return self._cpp

    def cost(self, x: Any) -> float:
        """Sum of squared residuals in C++ (the cost DE minimises; mm^2, weighted:
        dimensionless, whitened as :meth:`residuals`)."""
        return float(self._objective().cost(self._x(x)))

    def cost_unweighted(self, x: Any) -> float:
        """Sum of squared point residuals (mm^2), weighted or not."""
        pts, _, ok = self.model.points(self._x(x))
        r = self._residuals(pts, ok)
        return float(r @ r)

    def loop_jacobian(self, x: Any, poses: np.ndarray) -> np.ndarray:
        """The derivative (N, 6, n_joints + 6) of the predicted leg readings with the effects in
        the joint readings and the platform pose's correction ``(dp, w)`` at ``poses`` (gravity
        through the registration of ``x``; :func:`iwr.effects.loop.loop_jacobians`): what the
        readings' noise is propagated through (the weights, the uncertainty, the gross-error
        screen), as :meth:`iwr.tracker.TrackerProblem.loop_jacobian`."""
        xr, xs = self.model.split(x)
        robot = with_gravity(self.robot, registration_gravity(self.setup, xs)[0])
        return loop_jacobians(robot, xr, self.measurements.q, np.asarray(poses, dtype=float),
                              self.measurements)[2]

    def engine_objective(self) -> Any:
        """The C++ objective with the effects (``iwr._core.TrackerEffectObjective``, weighted as
        the problem is): what DE runs on."""
        return self._objective()

    def cost_batch(self, X: Any, workers: int | None = None) -> np.ndarray:
        """The costs of the rows of ``X`` in C++ across ``workers`` threads (None: all cores);
        the same bits whatever their number."""
        arr = np.ascontiguousarray(X, dtype=float)
        if arr.ndim != 2 or arr.shape[1] != self.n_params:
            raise ValueError(f"X: shape {arr.shape}; expected (M, {self.n_params})")
        if workers is not None and workers < 1:
            raise ValueError(f"workers: {workers}; expected a positive number of threads or None")
        return self._objective().cost_batch(arr, 0 if workers is None else int(workers))

    def save(self, path: Any, *, sources: dict[str, Any] | None = None, x0: Any = None,
             active: Any = None) -> None:
        """Write the problem file that ``iwr-engine`` runs from, atomically (as
        :meth:`iwr.tracker.TrackerProblem.save`, with the effects' tables, the loads and
        temperatures, and gravity in {T}); :meth:`iwr.Problem.load` reads it back."""
        from .._hooks import hook

        hook("save_problem")(self, path, sources, x0=x0, active=active)

    # -- diagnostics --------------------------------------------------------------------------
    def failures(self, x: Any) -> list[tuple[int, str]]:
        """Poses whose forward kinematics with the effects fails at ``x``."""
        _, ok = self.model.forward(self._x(x))
        return [(int(k), "no forward kinematics with the effects (the legs do not close at "
                 "these readings)") for k in np.flatnonzero(~ok)]

    def check(self, x: Any) -> None:
        bad = self.failures(x)
        if bad:
            k, msg = bad[0]
            raise ValueError(f"{self.measurements.where(k)}: {msg} ({len(bad)} poses)")

    def platform_poses(self, x: Any) -> np.ndarray:
        """World poses of {5} (N, 6) by forward kinematics with the effects; NaN where it
        fails."""
        return self.model.forward(self._x(x))[0]

    def predicted_points(self, x: Any) -> np.ndarray:
        return self.model.points(self._x(x))[0]

    def __repr__(self) -> str:
        return (f"TrackerEffectProblem(robot={self.robot.name!r}, kind={self.setup.kind!r}, "
                f"n_poses={self.n_poses}, n_params={self.n_params})")


def effect_tracker_problem(robot: Any, measurements: Any, bounds: Any = None, x0: Any = None,
                           noise: Any = None) -> tuple[TrackerEffectProblem, np.ndarray]:
    """The problem of tracker data for a robot with effects and its start: the nominal robot and
    effects with the closed-form registration guess (of the geometry alone: the effects move
    the points by micrometres), the setup's bounds about it; or ``x0``. With a ``noise`` model
    ``(iwr.Noise, TrackerNoise)`` the problem is weighted by it (:class:`TrackerEffectProblem`'s
    ``noise``), its weights evaluated at the nominal robot and effects with the start's setup.
    Inside :func:`iwr.kinds.reuse` (one calibration job) the guess and the unweighted problem
    are made once per data set, as :func:`iwr.tracker.start.tracker_problem` makes them."""
    from ..kinds import memo
    from ..tracker.start import _bounds, _setup, guess_centre, objective_noise, registration_guess

    setup = _setup(robot)
    n_eff = len(effect_names(robot.effects))
    n = robot.n_params + n_eff + setup.n_params
    if isinstance(bounds, str) and bounds == "default":
        bounds = None
    weights = objective_noise(noise, measurements)
    center, guessed = None, True
    if x0 is None:
        # The geometry's guess (the effects move the points by micrometres), made once per data
        # set with the kind's start (iwr.kinds.MeasurementKind.start).
        guess = registration_guess(robot, measurements)
        center = guess.x_setup
        start = np.concatenate([np.zeros(robot.n_params + n_eff), guess.x_setup])
    else:
        start = np.array(x0, dtype=float)
        if start.shape != (n,) or not np.all(np.isfinite(start)):
            raise ValueError(f"x0: expected {n} finite values (the robot's {robot.n_params}, "
                             f"{n_eff} effect parameters, then the tracker setup's "
                             f"{setup.n_params}), got shape {start.shape}")
        # The bounds about the data's guess, as without x0 (about the nominal setup, a tracker
        # far from it failed the fit test of the job's outlier refit: tracker_problem's fix).
        center, guessed = guess_centre(robot, measurements, start[n - setup.n_params:])
    problem_bounds = bounds
    if isinstance(bounds, str) and bounds == "paper":
        lo, hi = _bounds(robot, setup, bounds, np.zeros(setup.n_params) if center is None
                         else center)
        lo_e, hi_e = effect_bounds(robot.effects)
        ng = robot.n_params
        problem_bounds = (np.concatenate([lo[:ng], lo_e, lo[ng:]]),
                          np.concatenate([hi[:ng], hi_e, hi[ng:]]))

    def build() -> TrackerEffectProblem:
        return TrackerEffectProblem(robot, setup, measurements, problem_bounds, center=center,
                                    noise=weights, weights_at=None if weights is None or x0 is None
                                    else start[n - setup.n_params:])

    if weights is not None:  # weighted: its own problem
        return build(), start
    given = not (bounds is None or isinstance(bounds, str))
    held = (robot, measurements, bounds) if given else (robot, measurements)
    key = ("effects tracker problem", "given" if given else bounds)
    if guessed:  # the problem made once for the data, its bounds about their guess
        return memo((*key, "guess"), held, build), start
    return build(), start  # about x0's setup: the nominal model too poor for the guess


def simulate(robot: Any, n_poses: int, *, seed: int | None, x: Any = None, noise: Any = None,
             payloads: Any = None, temperatures: Any = None, hidden: float = 0.0
             ) -> tuple[Any, np.ndarray]:
    """:func:`iwr.simulate` on tracker data for a robot with effects: ``x_true`` (geometric
    errors, the effects' parameters, the setup's; default uniform within their bounds), random
    poses of the true robot each with a payload and temperatures (as
    :func:`iwr.effects.api.simulate`: ``payloads`` taken in turn, default none and the 80 kg
    head alternating when the compliance effect is on; temperatures one per pose over a day's
    drift with the thermal effect on), the leg readings the true robot gives there under them
    (gravity in {0} through the true registration), the points in {T}, and ``noise`` as
    :func:`iwr.tracker.api.tracker_simulate` takes it. Returns ``(measurements, x_true)``."""
    from ..noise import Noise, TrackerNoise, split_noise
    from ..simulation import sample_poses
    from ..tracker.simulate import perturb_measurements, true_points
    from ..tracker.start import _setup
    from .api import draw_conditions, true_parameters

    setup = _setup(robot)
    if isinstance(n_poses, bool) or not isinstance(n_poses, (int, np.integer)) or n_poses < 1:
        raise ValueError(f"n_poses: {n_poses!r}; expected a positive integer")
    readings, tracker = split_noise(noise)
    readings = Noise() if readings is None else readings
    tracker = TrackerNoise.none() if tracker is None else tracker
    if readings.position or readings.orientation:
        raise ValueError("noise: position and orientation are the noise of a pose measured in "
                         "{0}; for tracker data give (iwr.Noise(legs=..., joint_...), "
                         "iwr.tracker.TrackerNoise(...))")
    if isinstance(hidden, bool) or not (isinstance(hidden, (int, float)) and 0 <= hidden <= 1):
        raise ValueError(f"hidden: {hidden!r}; expected a fraction in [0, 1]")
    if hidden and setup.kind == "probe":
        raise ValueError("hidden: a probe pose is measured whole or not at all")
    rng = np.random.default_rng(seed)
    ng = robot.n_params
    x = true_parameters(robot, rng, x, setup.default_bounds(),
                        f", then the tracker setup's {setup.n_params}")
    n = int(n_poses)
    xs = x[ng + len(effect_names(robot.effects)):]
    q, poses, _ = sample_poses(robot.with_effects(), n, rng, x[:ng])
    pay, temperatures = draw_conditions(robot, n, rng, payloads, temperatures)
    pts = true_points(robot, setup, np.concatenate([x[:ng], xs]), poses)
    hide = rng.random(n) < hidden
    which = rng.integers(0, setup.n_points, size=n)
    pts[hide, which[hide]] = np.nan
    clean = _exact(robot, x, q, poses, pts, pay, temperatures)
    if readings.is_zero and tracker.is_zero:
        return clean, x
    return perturb_measurements(robot, clean, readings, tracker, rng), x


def _exact(robot: Any, x: np.ndarray, q: np.ndarray, poses: np.ndarray, pts: np.ndarray,
           payload: Any, temperatures: Any) -> Any:
    """The noise-free tracker data of the robot ``x`` (geometry, effects, setup) at joint
    readings ``q`` and platform poses ``poses`` in {0} under the loads and temperatures given:
    the points ``pts`` (N, P, 3) in {T} (a probe's pose from its four points), and the leg
    readings with the effects (gravity in {0} through the registration of ``x``)."""
    from ..tracker.data import TrackerMeasurements
    from .model import predicted_readings

    setup = robot.tracker
    n, ns = len(q), setup.n_params
    xr, xs = x[: x.size - ns], x[x.size - ns:]
    if setup.kind == "points":
        clean = TrackerMeasurements(q, np.zeros((n, 6)), points=pts, joint_types=robot.joint_types,
                                    payload=payload, temperatures=temperatures)
    else:
        probe = np.array([pose_from_matrix(m) for m in _probe_frames(setup, xs, pts)])
        clean = TrackerMeasurements(q, np.zeros((n, 6)), probe=probe,
                                    joint_types=robot.joint_types, payload=payload,
                                    temperatures=temperatures)
    true = with_gravity(robot, registration_gravity(setup, xs)[0])
    clean.legs = predicted_readings(true, xr, q, poses, clean)
    return clean


def _probe_frames(setup: Any, xs: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """The probe frames (N, 4, 4) in {T} of its four virtual points (origin, then along its
    axes), as :func:`iwr.tracker.simulate.simulate_tracker` makes them."""
    origin, axes = pts[:, 0], (pts[:, 1:] - pts[:, :1]) / setup.probe_length
    mats = np.tile(np.eye(4), (len(pts), 1, 1))
    mats[:, :3, :3], mats[:, :3, 3] = np.swapaxes(axes, 1, 2), origin
    return mats


# -- what the tracker kinds do with a robot with effects (iwr.tracker.kind) -------------------

#: The methods that model the effects on tracker data: LM and the efficient estimator in numpy,
#: DE, CRS2 and BOBYQA on the C++ objective with the effects.
TRACKER_METHODS = ("lm", "efficient", "de", "crs2", "bobyqa")


def identify(robot: Any, measurements: Any, method: str, *, noise: Any = None,
             weighted: Any = None, bounds: Any = None, x0: Any = None, active: Any = None,
             max_evaluations: int | None = None, seed: int | None = None, callback: Any = None,
             progress: Any = None, **options: Any) -> Any:
    """:func:`iwr.identify` on tracker data for a robot with effects: LM, DE (polished by LM),
    CRS2 or BOBYQA on the point (probe) objective with the effects
    (:class:`TrackerEffectProblem`: DE, CRS2 and BOBYQA on its C++ cost) from the nominal robot
    and effects with the registration guess; ``active="base"`` the base parameters of its null
    space (:func:`identifiability`). With a ``noise`` model ``(iwr.Noise, TrackerNoise)`` they
    minimise the noise-weighted point objective (``weighted``, default True with a noise
    model) and the fit check adds the chi-square test, as
    :func:`iwr.tracker.api.tracker_identify` does without effects. The efficient estimator
    weighs every instrument by its noise. Other methods are refused, naming what models the
    effects."""
    from ..tracker.api import identify_with

    names = ", ".join(e.name for e in robot.effects)
    if method not in TRACKER_METHODS:
        raise ValueError(
            f"method {method!r}: robot {robot.name!r} has effects on ({names}); on tracker data "
            f"the methods that model them are {', '.join(TRACKER_METHODS)} (docs/effects.md)")
    return identify_with(
        robot, measurements, method,
        lambda noise: effect_tracker_problem(robot, measurements, bounds, x0, noise=noise),
        lambda problem, start: base_parameters(robot, measurements, start),
        noise=noise, weighted=weighted, x0=x0, active=active, bounds=bounds,
        max_evaluations=max_evaluations, seed=seed, callback=callback, progress=progress,
        **options)


def identifiability(robot: Any, measurements: Any, x: Any = None, *,
                    rtol: float | None = None) -> Any:
    """:func:`iwr.identifiability` on tracker data for a robot with effects: the null
    directions of the point (probe) objective with the effects at ``x`` (default the nominal
    robot and effects with the registration guess), one per left-out parameter
    (:class:`EffectNullSpace`); an effect parameter among ``left_out`` cannot be separated from
    the geometry at these poses and loads. ``rtol`` default :data:`RANK_RTOL`. The loads fix the
    platform frame {5} weakly: its directions count as identifiable here (``rank``), but with
    noise they are not, and the report's ``active`` (what :func:`iwr.identify` and the
    calibration job identify) holds them too (``held``: :func:`base_parameters`)."""
    from dataclasses import asdict

    from ..base_parameters import left_out_directions
    from ..tracker.gauge import null_space

    problem, start = effect_tracker_problem(robot, measurements)
    x = start if x is None else np.asarray(x, dtype=float)
    ns = null_space(problem, x, RANK_RTOL if rtol is None else rtol)
    keep = base_parameters(robot, measurements, x)
    # One left-out parameter per null direction among those held by default (the base
    # parameters' columns are independent, so the null directions have independent parts
    # there); the other held ones are the weakly fixed directions.
    cand = np.flatnonzero(~keep)
    k = ns.vectors.shape[1]
    fields = asdict(ns)
    if k:
        scaled = (ns.vectors * ns.scale[:, None]).T  # (k, n): in the column-scaled metric
        # QR's pivoting, its ties broken by the fixed preference (iwr.base_parameters).
        out, basis = left_out_directions(scaled, ns.vectors, ns.parameter_names, cand)
        fields.update(left_out=[ns.parameter_names[i] for i in out], vectors=basis)
    held = [ns.parameter_names[i] for i in cand if ns.parameter_names[i] not in
            fields["left_out"]]
    return EffectNullSpace(**fields, held=held)


def _null_space_type() -> Any:
    from ..tracker.gauge import NullSpace

    return NullSpace


@dataclass(frozen=True)
class EffectNullSpace(_null_space_type()):  # type: ignore[misc]
    """:class:`iwr.tracker.NullSpace` of the point (probe) objective with the effects, and
    ``held``: the parameters its rank counts but iwr holds by default (:func:`base_parameters`):
    one per direction of the platform frame {5} that only the loads fix (a part in 1e5 of the
    geometry's signal: with noise it would wander), and any effect parameter whose column adds
    no direction to the geometry's. ``active`` leaves out both."""

    held: list[str] = field(default_factory=list)

    @property
    def active(self) -> np.ndarray:
        out = set(self.left_out) | set(self.held)
        return np.array([n not in out for n in self.parameter_names], dtype=bool)


def base_parameters(robot: Any, measurements: Any, x: Any = None) -> np.ndarray:
    """The parameters identified by default (``active="base"``, and the efficient estimator's):
    the base parameters of the geometry's point (probe) objective, which leave out its 16 null
    directions (docs/tracker.md: the 6 of leg data, the registration's 4, the platform frame's
    6), and the effects' parameters but those the data cannot separate from the geometry (a
    parameter whose column does not raise the rank).

    The effects fix the platform frame {5} relative to the loads (their centres of mass are
    given in {5}), but only at a part in 1e5 or less of the geometry's signal: with noise those
    directions would wander by tens of millimetres. So {5} stays where the left-out parameters
    put it, as without effects, and the loads are read in that frame (docs/effects.md)."""
    from ..analysis.identifiability import grow_active
    from ..tracker.gauge import null_space
    from ..tracker.start import tracker_problem

    problem, start = effect_tracker_problem(robot, measurements)
    x = start if x is None else np.asarray(x, dtype=float)
    ng, ne = robot.n_params, problem.model.n_effects
    geometric, _ = tracker_problem(robot.with_effects(), measurements)
    geo_mask = null_space(geometric, np.concatenate([x[:ng], x[ng + ne:]]), RANK_RTOL).active
    mask = np.concatenate([geo_mask[:ng], np.zeros(ne, dtype=bool), geo_mask[ng:]])
    jac = problem.jacobian(x)
    # each effect parameter kept if its column adds a direction
    return grow_active(jac, mask, range(ng, ng + ne), RANK_RTOL)


def plausibility(robot: Any, measurements: Any, bounds: Any, plausible: float
                 ) -> tuple[list[str], np.ndarray, np.ndarray, Any]:
    """The tracker kinds' plausibility (:meth:`iwr.kinds.MeasurementKind.plausibility`) with the
    effects: every parameter measured from the centre of its bounds (the registration guess for
    the registration) against ``plausible`` times their half-width, modulo the null directions
    of the objective with the effects."""
    from ..tracker.registration import RegistrationError

    given = not (bounds is None or isinstance(bounds, str))
    try:
        problem, _ = effect_tracker_problem(robot, measurements, None if given else bounds)
    except RegistrationError:  # too few data for a guess: about the nominal setup
        problem = TrackerEffectProblem(robot, robot.tracker, measurements)
    lower, upper = ((np.asarray(bounds[0], dtype=float), np.asarray(bounds[1], dtype=float))
                    if given else (problem.lower, problem.upper))
    return (problem.parameter_names, plausible * 0.5 * (upper - lower), 0.5 * (lower + upper),
            lambda x: problem.residuals_and_jacobian(x))


def _joint_frame(robot: Any, xr: np.ndarray) -> np.ndarray:
    """The platform frame as its six spherical joints fix it, in {5} (4, 4): the frame in which
    the joints ``b_j(x)`` best match their nominal positions (Kabsch), as
    :func:`iwr.tracker.analysis.tool_frames` fixes it."""
    from ..tracker.registration import kabsch

    nj = robot.n_joints
    b = robot.platform_joints + xr[4 * nj + 18: 4 * nj + 36].reshape(6, 3)
    r, c = kabsch(robot.platform_joints, b)
    k4 = np.eye(4)
    k4[:3, :3], k4[:3, 3] = r, c
    return k4


def tool_frames(robot: Any, x: Any, data: Any) -> np.ndarray:
    """The platform frames (N, 4, 4) in {T} by forward kinematics with the effects of ``data``'s
    readings under its loads and temperatures, with the full ``x``; {5} fixed by the six
    spherical joints (as :func:`iwr.tracker.analysis.tool_frames`)."""
    model = TrackerEffectModel(robot, robot.tracker, data)
    xr, xs = model.split(x)
    poses, ok = model.forward(x)
    if not ok.all():
        k = int(np.flatnonzero(~ok)[0])
        raise ValueError(f"{data.where(k)}: no forward kinematics with the effects at x")
    return robot.tracker.registration_matrix(xs) @ pose_matrix(poses) @ _joint_frame(robot, xr)


def accuracy(robot: Any, measurements: Any, x: Any, *, truth: Any = None, tool: Any = None,
             start: Any = None) -> Any:
    """:func:`iwr.accuracy` on tracker data for a robot with effects: before (the nominal robot
    and effects with the registration guess; where the data have none, in ``x``'s identified
    registration, as :func:`iwr.tracker.tracker_accuracy`) and after (``x``: the robot's, the
    effects' then the setup's parameters). With ``truth``: the tool pose
    errors in {T} by forward kinematics with the effects under each pose's load and
    temperature, modulo the gauge (the model's frame moved by the one rigid transform that best
    aligns it with the truth's, as ``gauge="fit"`` of :func:`iwr.tracker.tool_pose_errors`).
    Without: per pose the largest point distance and the angle of the points' best rotation.
    ``start``: the registration guess "before" is in (as :func:`iwr.tracker.tracker_accuracy`)."""
    from ..analysis.accuracy import Accuracy, PoseErrors
    from ..tracker.api import _point_errors
    from ..tracker.gauge import _align
    from ..tracker.start import _setup, before_problem
    from ..transforms import rotation_angle

    n = robot.n_params + len(effect_names(robot.effects))
    x = np.asarray(x, dtype=float)
    n_setup = _setup(robot).n_params
    if x.shape != (n + n_setup,):
        raise ValueError(f"x: shape {x.shape}; expected ({n + n_setup},): the robot's "
                         f"{robot.n_params}, the effects' {n - robot.n_params} then the tracker "
                         f"setup's {n_setup}")
    problem, start = before_problem(partial(effect_tracker_problem, robot, measurements), n,
                                    start, x)
    if truth is None:
        return Accuracy(_point_errors(problem, start), _point_errors(problem, x))
    b = tool_frames(robot, truth, measurements)
    p = np.zeros(3) if tool is None else np.asarray(tool, dtype=float).reshape(3)

    def errors(xx: np.ndarray) -> Any:
        a = tool_frames(robot, xx, measurements)
        a = a @ _align(a, b)
        pos = np.linalg.norm((a[:, :3, :3] - b[:, :3, :3]) @ p + a[:, :3, 3] - b[:, :3, 3],
                             axis=1)
        ang = np.degrees(rotation_angle(np.swapaxes(a[:, :3, :3], 1, 2) @ b[:, :3, :3]))
        return PoseErrors(pos, ang, np.array([pose_from_matrix(m) for m in a]))

    return Accuracy(errors(start), errors(x))


def leg_commands(robot: Any, x: Any, targets: Any, q: Any, data: Any) -> np.ndarray:
    """The leg readings (N, 6) that put the platform at ``targets`` (N, 4, 4) in the tracker
    frame {T} (the platform frame fixed by its joints, as :func:`tool_frames` gives it) with the
    model ``x`` (robot, effects, setup), at carriage readings ``q``, under ``data``'s loads and
    temperatures (an object with ``payload`` and ``temperatures``): the target in {0} through
    the identified registration, the legs with the effects under the load (gravity in {0}
    through the same registration)."""
    from .model import predicted_readings

    model = TrackerEffectModel(robot, robot.tracker, data)
    xr, xs = model.split(x)
    reg = robot.tracker.registration_matrix(xs)
    world = np.linalg.solve(reg, np.asarray(targets, dtype=float)) @ np.linalg.inv(
        _joint_frame(robot, xr))
    true = with_gravity(robot, registration_gravity(robot.tracker, xs)[0])
    return predicted_readings(true, xr, np.asarray(q, dtype=float), pose_from_matrix(world), data)


# -- the efficient estimator (iwr.estimation.efficient) on tracker data with effects ----------

def loop_model(robot: Any, setup: Any, data: Any, reference: np.ndarray, measured: np.ndarray,
               whitening: np.ndarray, sigma: np.ndarray) -> Any:
    """The tracker estimator's normalised residuals for a robot with effects, a
    :data:`iwr.effects.solver.LoopModel`: per pose the legs ``(predicted - measured) / sigma``
    with the effects at the corrected readings (joints ``q + dq``, changed by the carriage's
    compliance when it is on; platform ``reference (+) (dp, w)``) under the pose's load and
    temperature (:func:`iwr.effects.loop.loop_jacobians`,
    gravity through the registration), the joints' corrections over their sigma, and the
    whitened points (or the probe's position and orientation) as the C++ tracker model has them
    (``_core.tracker_loop_jacobians``: the points do not depend on the effects at a given
    pose). ``x = (x_geometric, x_effects, x_setup)``."""
    ng, nj = robot.n_params, robot.n_joints
    ne = len(effect_names(robot.effects))
    n, ny = len(data), nj + 6
    q = np.ascontiguousarray(data.q)
    legs = np.ascontiguousarray(data.legs)
    sl = sigma[:, :6]

    def model(x: np.ndarray, corr: np.ndarray, jacobians: bool) -> tuple[np.ndarray, Any, Any]:
        xr, xs = x[: ng + ne], x[ng + ne:]
        r, jx_c, jy_c = _core.tracker_loop_jacobians(
            robot._geometry, setup.kind, setup.registration,
            setup.reflectors if setup.reflectors is not None else np.zeros((1, 3)),
            setup.probe if setup.probe is not None else np.zeros(6), setup.probe_length,
            measured, whitening, reference, np.concatenate([xr[:ng], xs]), q, legs,
            np.ascontiguousarray(sigma), np.ascontiguousarray(corr))
        pred, jx, jy = _loop(robot, xr, xs, setup, q, reference, data, corr)
        r = r.copy()
        r[:, :6] = (pred - legs) / sl
        if not jacobians:
            return r, None, None
        nr = r.shape[1]
        jx_c = jx_c.reshape(n, nr, ng + setup.n_params)
        rx = np.zeros((n, nr, x.size))
        rx[:, 6:, :ng] = jx_c[:, 6:, :ng]
        rx[:, 6:, ng + ne:] = jx_c[:, 6:, ng:]
        rx[:, :6] = jx / sl[..., None]
        ry = jy_c.reshape(n, nr, ny).copy()
        ry[:, :6] = jy / sl[..., None]
        return r, rx, ry

    return model


def predicted_accuracy(robot: Any, x: Any, covariance: Any, active: Any, data: Any, *,
                       tool: Any = None, n_samples: int = 500, seed: int = 0,
                       step: float = 1e-6) -> Any:
    """:func:`iwr.tracker.estimation.tracker_predicted_accuracy` for a robot with effects: the
    tool pose error modulo the gauge that the covariance of the active parameters predicts at
    ``data``'s readings under their loads and temperatures; the platform pose's derivative in
    every parameter by implicit differentiation of the loop closure with the effects (gravity
    through the registration), the frame's composition by central differences as there."""
    from ..accuracy_prediction import accuracy_from_covariances
    from ..tracker.estimation import _aligned_errors, _frames

    setup = robot.tracker
    model = TrackerEffectModel(robot, setup, data)
    x = np.asarray(x, dtype=float)
    xr, xs = model.split(x)
    ng, nj = robot.n_params, robot.n_joints
    ne = model.n_effects
    poses, ok = model.forward(x)
    if not ok.all():
        k = int(np.flatnonzero(~ok)[0])
        raise ValueError(f"{data.where(k)}: no forward kinematics with the effects at x")
    _, jx, jy = _loop(robot, xr, xs, setup, data.q, poses, data)
    g_pose = -np.linalg.solve(jy[:, :, nj:], jx)
    t05 = pose_matrix(poses)
    frame_x = np.concatenate([xr[:ng], xs])  # what the frames are made of: joints, registration
    zero = np.zeros((len(poses), 6))
    t = np.zeros(3) if tool is None else np.asarray(tool, dtype=float).reshape(3)
    base = _frames(robot, frame_x, t05, zero)
    cols = []
    for i in np.flatnonzero(np.asarray(active, dtype=bool)):
        e = np.zeros_like(frame_x)
        if i < ng:
            e[i] = step
        elif i >= ng + ne:
            e[i - ne] = step
        d = g_pose[:, :, i] * step
        cols.append((_aligned_errors(_frames(robot, frame_x + e, t05, d), base, t)
                     - _aligned_errors(_frames(robot, frame_x - e, t05, -d), base, t))
                    / (2 * step))
    g = np.stack(cols, axis=2)
    cov = np.asarray(covariance, dtype=float)
    cp = np.einsum("kip,pq,kjq->kij", g[:, :3], cov, g[:, :3])
    co = np.einsum("kip,pq,kjq->kij", g[:, 3:], cov, g[:, 3:])
    return accuracy_from_covariances(cp, co, n_samples=n_samples, seed=seed)


def estimator(robot: Any, data: Any, noise: Any, **options: Any) -> Any:
    """The tracker kinds' estimation spec for a robot with effects (:class:`EffectTrackerSpec`)."""
    return EffectTrackerSpec(robot, data, noise, options["x0"], options["active"],
                             options["estimate"], options["bounds"], options["plausible"])


def _spec_base() -> Any:
    from ..tracker.estimation import TrackerSpec

    return TrackerSpec


class EffectTrackerSpec(_spec_base()):  # type: ignore[misc]
    """:class:`iwr.tracker.estimation.TrackerSpec` for a robot with effects: the parameters are
    the geometric errors, the effects', then the setup's; the start is LM on the point (probe)
    objective with the effects, the reference poses its forward kinematics with the effects, and
    the solve is :func:`iwr.effects.solver.solve_loop` on :func:`loop_model` (the C++ tracker
    solver's method in numpy). The variance components, outlier test, chi-square test and
    result are :func:`iwr.estimation.efficient`'s."""

    def __init__(self, robot: Any, measurements: Any, noise: Any, x0: Any, active: Any,
                 estimate: Any, bounds: Any, plausible: float) -> None:
        from ..estimation import _active_mask
        from ..methods.lm import levenberg_marquardt
        from ..methods.reduced import ReducedProblem

        # The readings, their whitening and variance components: the geometric spec's.
        self._readings(robot, measurements, noise, estimate)
        problem, start = effect_tracker_problem(robot, measurements, bounds, x0)
        self.problem = problem
        self.mask = _active_mask(active, problem.n_params,
                                 lambda: base_parameters(robot, measurements, start))
        lm = levenberg_marquardt(ReducedProblem(problem, self.mask, start), progress=False)
        self.x_start = np.array(lm.x, dtype=float)
        ref, ok = problem.model.forward(self.x_start)
        if not ok.all():
            raise _core.ForwardKinematicsError(
                f"{measurements.where(int(np.flatnonzero(~ok)[0]))}: the leg readings have no "
                f"forward kinematics with the effects at the starting point")
        self.reference = np.ascontiguousarray(ref)
        self.parameter_names = problem.parameter_names
        ng, ne = robot.n_params, problem.model.n_effects
        # About the nominal robot and the set-up's centre: the data's registration guess (also
        # from an x0: tracker_problem), x0's set-up only where there is none (bounds given).
        self.center = np.concatenate([np.zeros(ng + ne), start[ng + ne:]
                                      if problem.setup_center is None else problem.setup_center])
        lo, hi = problem.lower, problem.upper
        self.limit = plausible * np.maximum(np.abs(lo - self.center), np.abs(hi - self.center))
        if measurements.points is not None and not measurements.seen.all():
            self._unseen = ~np.repeat(measurements.seen, 3, axis=1)
        else:
            self._unseen = None

    def solve(self, x: np.ndarray, idx: list[int], used: np.ndarray, scale: dict[str, float],
              corr: np.ndarray, max_iterations: int, cb: Any) -> dict[str, Any]:
        from .solver import solve_loop

        s, w = self.scaled(scale)
        rows_used = np.flatnonzero(used)
        sub = self.measurements.subset(rows_used) if not used.all() else self.measurements
        nu, nj = rows_used.size, self.robot.n_joints
        model = loop_model(self.robot, self.setup, sub, self.reference[used],
                           np.ascontiguousarray(self.measured[used]),
                           np.ascontiguousarray(w[used].reshape(nu, -1)), s[used])
        joints = np.flatnonzero(s[0, 6:] > 0)  # the same at every pose (one sigma per joint)
        free = np.concatenate([joints, nj + np.arange(6)])
        n_tracker = self.measured.shape[1] if self.setup.kind == "points" else 6
        rows = np.concatenate([np.arange(6), 6 + joints, 6 + nj + np.arange(n_tracker)])
        start = np.array(corr, dtype=float)
        start[:, np.setdiff1d(np.arange(nj), joints)] = 0.0  # an exact reading: no correction
        out = solve_loop(model, x, idx, start, rows, free, max_iterations=int(max_iterations),
                         callback=cb)
        if self._unseen is not None:  # a point not seen: rows of zeros, not readings
            unseen = self._unseen[used]
            out["pose_dof"] = out["pose_dof"] - unseen.sum(axis=1)
            out["dof"] = int(out["dof"] - unseen.sum())
            out["redundancy"][:, 6 + nj:][unseen] = 0.0
        return out

    def implausible(self, x: np.ndarray, used: np.ndarray, covariance: Any = None,
                    alpha: float = 1e-3) -> list[Any]:
        from ..fit_test import beyond_plausible

        sub = self.measurements.subset(np.flatnonzero(used)) if not used.all() \
            else self.measurements
        problem = TrackerEffectProblem(self.robot, self.setup, sub,
                                       (self.problem.lower, self.problem.upper))
        return beyond_plausible(problem.residuals_and_jacobian, x, self.limit, self.center,
                                self.parameter_names, covariance, alpha)

    def predicted(self, x: np.ndarray, cov: np.ndarray, used: np.ndarray, tool: Any) -> Any:
        sub = self.measurements.subset(np.flatnonzero(used)) if not used.all() \
            else self.measurements
        return predicted_accuracy(self.robot, x, cov, self.mask, sub, tool=tool)

    def cost_eq10(self, x: np.ndarray) -> float:
        """The unweighted point objective with the effects (mm^2)."""
        return self.problem.cost(x)


# -- the calibration job's other steps on tracker data with effects (iwr.tracker.kind) ---------

def uncertainty(robot: Any, measurements: Any, x: Any, noise: Any, active: Any = None,
                weighted: bool = False) -> Any:
    """:func:`iwr.uncertainty` on tracker data for a robot with effects: the covariance of the
    active parameters (geometry, effects, setup) as
    :func:`iwr.analysis.uncertainty.tracker_covariance` computes it on the point (probe)
    objective with the effects, the
    readings' noise propagated to the points through the loop closure with the effects (exact
    derivatives, :func:`iwr.tracker.problem.reading_jacobian`); ``weighted``: ``x`` minimises
    the noise-weighted point objective (the weights :func:`iwr.identify` used: at the nominal
    robot and effects with the registration guess). ``active`` default: the parameters
    identified by default (:func:`base_parameters` at ``x``)."""
    from ..analysis.uncertainty import tracker_covariance
    from ..tracker.problem import reading_jacobian

    problem, _ = effect_tracker_problem(robot, measurements, x0=x)
    x = problem._x(x)
    wp = effect_tracker_problem(robot, measurements, noise=noise)[0] if weighted else None
    mask = base_parameters(robot, measurements, x) if active is None else active
    return tracker_covariance(
        problem, x, noise, mask, weighted=wp,
        gradients=lambda: reading_jacobian(problem, x, "x: the parameters given"))


def misclosures(robot: Any, measurements: Any, x: Any, noise: Any = None) -> Any:
    """:func:`iwr.tracker.estimation.tracker_misclosures` (the gross-error screen's linearised
    readings model) on the point (probe) objective with the effects: the points' derivatives in
    the parameters and in every reading through the loop closure with the effects."""
    from ..tracker.estimation import tracker_misclosures

    problem, _ = effect_tracker_problem(robot, measurements, x0=x)
    return tracker_misclosures(robot, measurements, x, noise, problem=problem)


def design(robot: Any, candidates: Any, x: Any, report: Any
           ) -> tuple[TrackerEffectProblem, np.ndarray, np.ndarray, int, str]:
    """:func:`iwr.plan_poses`'s problem for tracker data with effects: the candidates (joint
    readings, platform poses in {0}, and each one's payload and temperatures) measured by the
    nominal setup, the leg readings of the nominal robot with its effects under each load
    (gravity through the nominal registration), the information of the point (probe) objective
    with the effects at ``x`` (default the nominal robot, effects and setup; the robot's and
    effects' part alone: the nominal setup) over the parameters identified by default
    (:func:`base_parameters`, or ``report``'s active ones)."""
    from ..tracker.simulate import true_points

    setup = robot.tracker
    ng, ne, ns = robot.n_params, len(effect_names(robot.effects)), setup.n_params
    xf = np.zeros(ng + ne + ns) if x is None else np.asarray(x, dtype=float)
    if xf.shape == (ng + ne,):
        xf = np.concatenate([xf, np.zeros(ns)])
    if xf.shape != (ng + ne + ns,) or not np.all(np.isfinite(xf)):
        raise ValueError(f"x: expected {ng + ne + ns} finite values (the robot's {ng}, {ne} "
                         f"effect parameters, then the tracker setup's {ns}), got shape "
                         f"{xf.shape}")
    nominal = np.zeros(ng + ne + ns)
    pts = true_points(robot, setup, np.zeros(ng + ns), candidates.poses)
    data = _exact(robot, nominal, candidates.q, candidates.poses, pts, candidates.payload,
                  candidates.temperatures)
    problem = TrackerEffectProblem(robot, setup, data)
    mask = base_parameters(robot, data, xf) if report is None else np.asarray(report.active)
    what = "point coordinates" if setup.kind == "points" else "probe coordinates"
    return problem, xf, np.flatnonzero(mask), 3 * setup.n_points, what
