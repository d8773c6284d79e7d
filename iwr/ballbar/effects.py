"""Double-ballbar data for a robot with non-geometric effects (issue 23; docs/effects.md,
"Ballbar data"; docs/ballbar.md).

A ballbar measures no pose: the platform pose in {0} follows from the joint and leg readings by
forward kinematics *with the effects* (each leg's true length is its reading plus its offset
plus the effects' change, which depends on the pose through the leg forces and lengths; the
carriage's joints are at their readings plus their compliance's change under the load), and
the bar reads ``|T_05 P_s - F_s| + o_s`` as without effects (:class:`BallbarProblem`). The
forward kinematics and its exact derivatives are the pose data's loop closure with the effects
(:func:`iwr.effects.loop.loop_jacobians`): Newton's method on it from the geometric forward
kinematics, and the platform pose's derivative in every parameter by implicit
differentiation, ``d pose / dx = -(d legs / d pose)^-1 d legs / dx``.

**Gravity is the effects' own, in {0}.** The fixed balls are in {0}, the robot's world frame, so
gravity is given there (``gravity_m_s2`` of ``[effects.compliance]``, as for pose data). The
ballbar's gauge (docs/ballbar.md: what moves {0} and {5} without changing a reading) changes:
translations of {0} move nothing of the loads and stay exactly null; a turn of {0} (the robot
and the fixed balls turned together about the first joint's axis) turns the robot against
gravity unless that axis is vertical, and moving {5} (the platform joints and the balls moved
back together) moves the loads' centres of mass against the legs, so the loads fix those
directions, weakly. As on tracker data (docs/effects.md, "Tracker data") they are held by
default (:func:`base_parameters`: the geometry's base parameters, and the effects' that add a
direction).

Unknowns: the robot's geometric errors, the effects' parameters, then the set-ups' (each
set-up's two balls and the bar's length offset): ``x = (x_geometric, x_effects, x_setup)``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import _core
from ..effects import bounds as effect_bounds
from ..effects import parameter_names as effect_names
from ..effects.loop import _skew, loop_jacobians
from ..effects.model import check_inputs, predicted_readings, without_singular
from ..problem_base import FAILED_RESIDUAL, ProblemBase, reference_error
from ..robot import Robot
from ..transforms import pose_from_matrix, pose_matrix, rotvec_matrix
from .data import BallbarMeasurements
from .problem import BallbarProblem, cpp_objective, pose_weights, setup_columns
from .setup import BallbarSetup

__all__ = ["BallbarEffectNullSpace", "BallbarEffectProblem", "FK_MAX_ITERATIONS",
           "FK_TOLERANCE_MM", "RANK_RTOL", "accuracy", "base_parameters", "effect_problem",
           "estimator", "design", "identifiability", "identify", "leg_commands", "measure",
           "misclosures", "plausibility", "predicted_accuracy", "simulate", "uncertainty"]

#: Newton's method for the forward kinematics with the effects: the largest leg residual (mm)
#: at which a pose is solved, and the iterations allowed.
FK_TOLERANCE_MM = 1e-11
FK_MAX_ITERATIONS = 30
#: The relative rank threshold of the objective with the effects (of its column-scaled
#: Jacobian's largest singular value): its Jacobian rests on forward kinematics solved to
#: :data:`FK_TOLERANCE_MM`, as on tracker data (:data:`iwr.effects.tracker.RANK_RTOL`).
RANK_RTOL = 1e-9


def _corrected(poses: np.ndarray, step: np.ndarray) -> np.ndarray:
    """The poses (N, 6) moved by ``step`` (N, 6) ``(dp, w)``: ``(p + dp, R exp([w]x))``, as the
    loop closure's corrections move them."""
    t5 = pose_matrix(poses)
    t5[:, :3, :3] = t5[:, :3, :3] @ rotvec_matrix(step[:, 3:])
    t5[:, :3, 3] += step[:, :3]
    return pose_from_matrix(t5)


class BallbarEffectProblem(ProblemBase):
    """The distance objective of ballbar data for a robot with effects: residual k is
    ``(|T_05,k P_s - F_s| + o_s - d_k) w_k`` (mm) as :class:`BallbarProblem`'s, with ``T_05,k``
    the platform pose by forward kinematics *with the effects* under pose k's load and
    temperature, and its exact Jacobian (implicit differentiation of the loop closure with the
    effects; checked against central differences). The residuals and the Jacobian are numpy;
    the cost and the batch costs (what DE, CRS2 and BOBYQA evaluate) are the C++ objective's
    (:attr:`objective`, ``cpp/include/iwr/effects_ballbar.hpp``: the one ``iwr-engine`` runs on
    the problem file, threaded across a population), checked against the numpy residuals.

    ``bounds``: None, ``"default"`` or ``"paper"`` (the robot's, the effects' own
    (:func:`iwr.effects.bounds`), the set-ups' default ones) or a pair over every parameter.
    ``reference``: the robot's geometric errors at which the geometric forward kinematics (the
    start of Newton's method) is solved once per pose, as :class:`BallbarProblem`'s.
    ``weights``: per pose (``1 / sigma_k``: :func:`iwr.ballbar.api.weighted_problem`).
    """

    data_type = BallbarMeasurements
    data_name = "iwr.ballbar.BallbarMeasurements"
    file_holds = "ballbar data"
    setup_type = BallbarSetup
    setup_name = "iwr.ballbar.BallbarSetup"
    setup_owner = "effects' and the set-ups'"
    effects_what = "ballbar data with effects (BallbarEffectProblem)"
    takes_effects = True

    def __init__(self, robot: Robot, setup: BallbarSetup, measurements: BallbarMeasurements,
                 bounds: Any = None, *, reference: Any = None, weights: Any = None,
                 noise: Any = None) -> None:
        self._accept(robot, measurements, setup)
        if not robot.effects:
            raise ValueError(f"robot {robot.name!r}: no effect on; use iwr.ballbar.BallbarProblem")
        check_inputs(robot, measurements)
        self.n_effects = len(effect_names(robot.effects))
        # The geometry's problem: the set-up index of each pose, the geometric forward
        # kinematics from the reference (Newton's start), its checks.
        self.geometric = BallbarProblem(robot.with_effects(), setup, measurements,
                                        reference=reference)
        self.bar = self.geometric.bar
        self.reference = self.geometric.reference
        lo_e, hi_e = effect_bounds(robot.effects)
        lo_s, hi_s = setup.default_bounds()
        self._set_bounds(bounds, (np.concatenate([lo_e, lo_s]), np.concatenate([hi_e, hi_s])))
        self.weights = w = pose_weights(weights, len(measurements))
        self.whitening = None if weights is None else w.reshape(-1, 1, 1)
        self.noise = noise
        self._objective: Any = None  # the C++ objective, made on first use

    def with_weights(self, weights: Any, noise: Any = None) -> BallbarEffectProblem:
        """The same problem with residual k multiplied by ``weights[k]`` (None: unweighted)."""
        return BallbarEffectProblem(self.robot, self.setup, self.measurements,
                                    (self.lower, self.upper), reference=self.reference,
                                    weights=weights, noise=noise)

    # -- the C++ objective and the problem file -------------------------------------------------
    @property
    def objective(self) -> Any:
        """The C++ objective of this problem (``iwr._core.BallbarEffectObjective``): what
        ``iwr-engine`` runs on the problem file, weighted alike."""
        if self._objective is None:
            from ..problem import effect_inputs

            try:
                self._objective = cpp_objective(
                    _core.BallbarEffectObjective, self, self.geometric.setup_fields(),
                    **effect_inputs(self.robot, self.measurements))
            except _core.ForwardKinematicsError as exc:
                raise reference_error(exc, self.measurements) from None
        return self._objective

    def cost(self, x: Any) -> float:
        """Sum of squared (weighted) residuals: the C++ objective's."""
        return float(self.objective.cost(self._x(x)))

    def engine_objective(self) -> Any:
        """:attr:`objective` (weighted or not)."""
        return self.objective

    def file_fields(self) -> dict[str, Any]:
        """The fields of the problem file (``iwr.problem_file``): the ballbar section
        (:meth:`BallbarProblem.file_fields`), then the effects' tables, the payload and the
        temperatures (gravity is the effects' own, in {0}: no field of its own)."""
        m = self.measurements
        return dict(self.geometric.file_fields(),
                    effects=[(e.name, e.to_dict()) for e in self.robot.effects],
                    payload=m.payload, temperatures=m.temperatures)

    @classmethod
    def from_file_fields(cls, d: dict[str, Any], robot: Robot, setup: BallbarSetup,
                         measurements: BallbarMeasurements, bounds: Any, weights: Any,
                         noise: Any, source: str) -> BallbarEffectProblem:
        """The problem of a problem file's fields ``d`` with effects
        (:meth:`BallbarProblem.from_file_fields` reads the ballbar section and dispatches here):
        the robot's effects from their tables, the data's loads and temperatures; ValueError on
        what the Python checks refuse."""
        from ..effects import read_table

        robot = robot.with_effects(*read_table(dict(d["effects"]), "effects"))
        m = BallbarMeasurements(measurements.q, measurements.legs, measurements.setup,
                                measurements.distance, joint_types=measurements.joint_types,
                                source=source, payload=d["payload"],
                                temperatures=d["temperatures"])
        return cls(robot.with_instrument("ballbar", setup), setup, m, bounds,
                   reference=d["reference"], weights=weights, noise=noise)

    # -- sizes and names ----------------------------------------------------------------------
    @property
    def n_params(self) -> int:
        return self.robot.n_params + self.n_effects + self.setup.n_params

    @property
    def n_residuals(self) -> int:
        return len(self.measurements)

    @property
    def parameter_names(self) -> list[str]:
        return (self.robot.parameter_names + effect_names(self.robot.effects)
                + self.setup.parameter_names)

    @property
    def angle_parameters(self) -> np.ndarray:
        return np.concatenate([np.asarray(self.robot.angle_parameters, dtype=bool),
                               np.zeros(self.n_effects, dtype=bool),
                               np.asarray(self.setup.angle_parameters, dtype=bool)])

    def split(self, x: Any) -> tuple[np.ndarray, np.ndarray]:
        """``(x_robot, x_setup)``: the robot's geometric and effect parameters, the set-ups'."""
        arr = self._x(x)
        k = self.robot.n_params + self.n_effects
        return arr[:k], arr[k:]

    def x0(self) -> np.ndarray:
        """The nominal robot and effects and the nominal set-ups: zeros."""
        return np.zeros(self.n_params)

    # -- the forward kinematics with the effects ----------------------------------------------
    def forward(self, x: Any, jacobians: bool = False) -> tuple[np.ndarray, np.ndarray, Any]:
        """``(poses, ok, d_pose)``: the platform poses in {0} (N, 6) at which the robot with
        ``x`` gives the data's readings under their loads and temperatures (NaN where not
        solved), the mask of the poses solved, and with ``jacobians`` the derivatives of each
        solved pose's correction ``(dp, w)`` (``p + dp``, ``R exp([w]x)``) in the robot's
        geometric and effect parameters (N, 6, n_geometric + n_effects; zero where not
        solved). Newton's method with the exact pose Jacobian of the loop closure with the
        effects, from the geometric forward kinematics; without ``jacobians``, the cheaper
        readings without their parameter derivatives and the geometry's pose Jacobian at the
        joints the carriage's compliance changed (:func:`iwr.effects.tracker._readings`, as
        tracker data solve it: the effects change it by a part in 1e5 at realistic values,
        about 1e-3 at the bounds, so the convergence is linear at that rate), to the same
        tolerance."""
        from ..effects.tracker import _readings

        xr, _ = self.split(x)
        robot, data = self.robot, self.measurements
        fast = not jacobians
        ng, nj, n = robot.n_params, robot.n_joints, len(data)
        frames = self.geometric.platform_frames(
            np.concatenate([xr[:ng], np.zeros(self.setup.n_params)]))
        ok = np.all(np.isfinite(frames.reshape(n, -1)), axis=1)
        poses = np.full((n, 6), np.nan)
        poses[ok] = pose_from_matrix(frames[ok])
        live = np.flatnonzero(ok)
        sub = data.subset(live) if 0 < live.size < n else data
        h = np.full((live.size, 6), np.inf)
        jx = jy = None
        def readings(idx: np.ndarray) -> tuple[np.ndarray, Any, Any]:
            s = sub if idx is live else data.subset(idx)
            if fast:
                pred, jp = _readings(robot, xr, s.q, poses[idx], s)
                return pred, jp, None
            pred, jx, jy = loop_jacobians(robot, xr, s.q, poses[idx], s)
            return pred, jx, jy

        for _ in range(FK_MAX_ITERATIONS + 1):
            if not live.size:
                break
            out, kept = without_singular(readings, live, ok, poses)
            if kept is not live:  # a singular hexapod: no forward kinematics there
                live = kept
                sub = data.subset(live) if 0 < live.size < n else data
                if not live.size:
                    break
            if fast:
                pred, jp, _ = out
            else:
                pred, jx, jy = out
                jp = jy[:, :, nj:]
            h = pred - sub.legs
            if np.abs(h).max() <= FK_TOLERANCE_MM:
                break
            try:
                step = -np.linalg.solve(jp, h[..., None])[..., 0]
            except np.linalg.LinAlgError:
                break
            poses[live] = _corrected(poses[live], step)
        if live.size:
            bad = ~(np.abs(h).max(axis=1) <= 1e3 * FK_TOLERANCE_MM)
            ok[live[bad]] = False
            poses[live[bad]] = np.nan
        if not jacobians:
            return poses, ok, None
        d_pose = np.zeros((n, 6, xr.size))
        if live.size:
            assert jx is not None and jy is not None
            sol = -np.linalg.solve(jy[:, :, nj:], jx)
            d_pose[live] = np.where(ok[live][:, None, None], sol, 0.0)
        return poses, ok, d_pose

    def platform_frames(self, x: Any) -> np.ndarray:
        """4x4 transforms (N, 4, 4) of {5} in {0} by forward kinematics with the effects; NaN
        where it fails."""
        poses, ok, _ = self.forward(x)
        t = np.full((len(poses), 4, 4), np.nan)
        t[ok] = pose_matrix(poses[ok])
        return t

    def pose_derivatives(self, x: Any) -> tuple[np.ndarray, np.ndarray]:
        """``(frames, d_pose)``: the platform frames (N, 4, 4) by forward kinematics with the
        effects (NaN where it fails) and the derivatives of each frame's correction ``(dp, w)``
        in every parameter (N, 6, n_params; the set-ups' move no frame), as
        :meth:`iwr.ballbar.BallbarProblem.pose_derivatives`."""
        poses, ok, d_pose = self.forward(x, jacobians=True)
        t = np.full((len(poses), 4, 4), np.nan)
        t[ok] = pose_matrix(poses[ok])
        g = np.zeros((len(poses), 6, self.n_params))
        g[:, :, : d_pose.shape[2]] = d_pose
        return t, g

    def failures(self, x: Any) -> list[tuple[int, str]]:
        """Poses whose forward kinematics with the effects fails at ``x``."""
        _, ok, _ = self.forward(x)
        return [(int(k), "no forward kinematics with the effects (the legs do not close at "
                 "these readings)") for k in np.flatnonzero(~ok)]

    # -- the objective ------------------------------------------------------------------------
    def _distances(self, x: np.ndarray, jacobian: bool) -> tuple[np.ndarray, Any]:
        """The predicted readings (N,) (NaN where the forward kinematics fails) and, with
        ``jacobian``, their derivatives (N, n_params) (zero rows there)."""
        robot = self.robot
        _, xs = self.split(x)
        nre = robot.n_params + self.n_effects
        p, f, o = self.setup.split(xs)
        poses, ok, d_pose = self.forward(x, jacobian)
        t5 = pose_matrix(np.where(ok[:, None], poses, 0.0))
        rot = t5[:, :3, :3]
        ball = p[self.bar]
        v = t5[:, :3, 3] + np.einsum("nij,nj->ni", rot, ball) - f[self.bar]
        dist = np.linalg.norm(v, axis=1)
        pred = np.where(ok, dist + o[self.bar], np.nan)
        if not jacobian:
            return pred, None
        n = len(pred)
        u = v / np.where(dist > 0, dist, 1.0)[:, None]
        # The ball moves with the pose's correction: dp - R [P]x w.
        d_ball = np.zeros((n, 3, 6))
        d_ball[:, :, :3] = np.eye(3)
        d_ball[:, :, 3:] = -rot @ _skew(ball)
        jac = np.zeros((n, self.n_params))
        jac[:, :nre] = np.einsum("nc,ncd,ndp->np", u, d_ball, d_pose)
        rot_u = np.einsum("nji,nj->ni", rot, u)  # R^T u: d dist / d platform ball
        setup_columns(jac, nre + 7 * self.bar, rot_u, u)
        jac[~ok] = 0.0
        return pred, jac

    def predicted(self, x: Any) -> np.ndarray:
        """The predicted bar readings (N,), mm; NaN where the forward kinematics fails."""
        return self._distances(self._x(x), False)[0]

    def residuals(self, x: Any) -> np.ndarray:
        """Predicted minus measured readings, weighted, (N,)."""
        r = self.predicted(x) - self.measurements.distance
        return self.weights * np.where(np.isnan(r), FAILED_RESIDUAL, r)

    def residuals_and_jacobian(self, x: Any) -> tuple[np.ndarray, np.ndarray]:
        """Residuals and their exact Jacobian (N, n_params)."""
        pred, jac = self._distances(self._x(x), True)
        r = pred - self.measurements.distance
        r = np.where(np.isnan(r), FAILED_RESIDUAL, r)
        return self.weights * r, jac * self.weights[:, None]

    def __repr__(self) -> str:
        return (f"BallbarEffectProblem(robot={self.robot.name!r}, "
                f"set-ups={self.setup.n_setups}, n_poses={self.n_poses}, "
                f"n_params={self.n_params})")


def _setup(robot: Robot) -> BallbarSetup:
    from .api import ballbar_setup

    return ballbar_setup(robot)


def effect_problem(robot: Robot, measurements: BallbarMeasurements, bounds: Any = None,
                   x0: Any = None, noise: Any = None) -> tuple[BallbarEffectProblem, np.ndarray]:
    """The problem of ballbar data for a robot with effects and its start (``x0``, default
    zeros: the nominal robot, effects and set-ups); weighted by ``noise`` (each distance by its
    first-order standard deviation at the start, :func:`iwr.ballbar.api.weighted_problem`)
    when given."""
    from .api import weighted_problem

    problem = BallbarEffectProblem(robot, _setup(robot), measurements, bounds)
    start = _full(problem, x0, "x0")
    return (problem if noise is None else weighted_problem(problem, start, noise)), start


def _full(problem: BallbarEffectProblem, x: Any, name: str) -> np.ndarray:
    n = problem.n_params
    arr = np.zeros(n) if x is None else np.array(x, dtype=float)
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        robot = problem.robot
        raise ValueError(f"{name}: expected {n} finite values (the robot's {robot.n_params}, "
                         f"the effects' {problem.n_effects} ("
                         + ", ".join(effect_names(robot.effects)) + "), then the ballbar "
                         f"set-ups' {problem.setup.n_params}), got shape {arr.shape}")
    return arr


# -- simulate -----------------------------------------------------------------------------------

def simulate(robot: Robot, n_poses: int, *, seed: int | None, x: Any = None, noise: Any = None,
             payloads: Any = None, temperatures: Any = None, max_batches: int = 200
             ) -> tuple[BallbarMeasurements, np.ndarray]:
    """:func:`iwr.simulate` on ballbar data for a robot with effects: ``x_true`` (geometric
    errors, the effects' parameters, the set-ups'; default uniform within their bounds), random
    poses of the true robot shared among the set-ups within their ranges
    (:func:`iwr.ballbar.simulate.simulate_ballbar`'s rule), each with a payload and temperatures
    (:func:`iwr.effects.api.simulate`'s: ``payloads`` taken in turn, default none and the 80 kg
    head alternating with an effect of the load on; with the thermal effect, temperatures one
    per pose over a day's drift), the leg readings the true robot gives there under them
    (:func:`iwr.effects.model.predicted_readings`, gravity in {0}), the bar's readings, and
    ``noise`` as :func:`simulate_ballbar` takes it. Draws from one generator in this order: x
    (when not given), the poses, the temperatures (when drawn), the reading noise, the bar's.
    Returns ``(measurements, x_true)``."""
    from ..effects.api import draw_conditions, true_parameters
    from .simulate import measured, sample_setup_poses, split_noise

    if not isinstance(robot, Robot):
        raise TypeError(f"robot: expected an iwr.Robot, got {type(robot).__name__}")
    if isinstance(n_poses, bool) or not isinstance(n_poses, (int, np.integer)) or n_poses < 1:
        raise ValueError(f"n_poses: {n_poses!r}; expected a positive integer")
    setup = _setup(robot)
    split_noise(noise)  # its types checked before anything is drawn
    rng = np.random.default_rng(seed)
    ng, ne = robot.n_params, len(effect_names(robot.effects))
    x = true_parameters(robot, rng, x, setup.default_bounds(),
                        f", then the ballbar set-ups' {setup.n_params}")
    n = int(n_poses)
    xs = x[ng + ne:]
    q, poses, _, bar = sample_setup_poses(robot.with_effects(), setup, x[:ng], xs, n, rng,
                                          max_batches)
    pay, temps = draw_conditions(robot, n, rng, payloads, temperatures)
    plain = BallbarMeasurements(q, np.zeros((n, 6)), np.array(setup.names, dtype=object)[bar],
                                np.ones(n), joint_types=robot.joint_types, payload=pay,
                                temperatures=temps)
    legs = predicted_readings(robot, x[: ng + ne], q, poses, plain)
    return measured(robot, setup, xs, bar, q, poses, legs, noise, rng, payload=plain.payload,
                    temperatures=plain.temperatures), x


# -- what the ballbar kind does with a robot with effects (iwr.ballbar.kind) -------------------

#: The methods that model the effects on ballbar data: LM and the efficient estimator (numpy
#: residuals and Jacobian), and DE, CRS2 and BOBYQA (the C++ cost of
#: :class:`BallbarEffectProblem`).
BALLBAR_METHODS = ("lm", "efficient", "de", "crs2", "bobyqa")


def identify(robot: Robot, measurements: BallbarMeasurements, method: str, *,
             noise: Any = None, weighted: bool | None = None, bounds: Any = None,
             x0: Any = None, active: Any = None, max_evaluations: int | None = None,
             seed: int | None = None, callback: Callable[..., Any] | None = None,
             progress: bool | None = None, **options: Any) -> Any:
    """:func:`iwr.identify` on ballbar data for a robot with effects: the methods of
    :func:`iwr.ballbar.api.ballbar_identify` on the distance objective with the effects
    (:class:`BallbarEffectProblem`), from the nominal robot, effects and set-ups (default
    ``x0``); ``active="base"``: :func:`base_parameters`. With a noise model the distances are
    weighted by their first-order standard deviations and the fit gets the chi-square test."""
    from .api import ballbar_identify_with

    if method not in BALLBAR_METHODS:
        raise ValueError(
            f"method {method!r}: robot {robot.name!r} has effects on ("
            + ", ".join(e.name for e in robot.effects) + "); on ballbar data the methods that "
            f"model them are {', '.join(BALLBAR_METHODS)} (docs/effects.md)")
    return ballbar_identify_with(
        robot, measurements, method,
        lambda: effect_problem(robot, measurements, bounds, x0),
        lambda problem, start: base_parameters(robot, measurements, start),
        noise=noise, weighted=weighted, bounds=bounds, x0=x0, active=active,
        max_evaluations=max_evaluations, seed=seed, callback=callback, progress=progress,
        **options)


def base_parameters(robot: Robot, measurements: BallbarMeasurements, x: Any = None
                    ) -> np.ndarray:
    """The parameters identified by default (``active="base"``, the efficient estimator's): the
    base parameters of the geometry's distance objective (one parameter held per null
    direction of ballbar data, docs/ballbar.md), and the effects' parameters but those the data
    cannot separate from the geometry (a parameter whose column does not raise the rank, at
    :data:`RANK_RTOL`). The directions of {0} and {5} that only the loads fix (the module's
    docstring) stay held: {0} and {5} where the held parameters put them, the loads read
    there."""
    problem, start = effect_problem(robot, measurements)
    x = start if x is None else _full(problem, x, "x")
    return _base_mask(problem, x, problem.jacobian(x))


def _base_mask(problem: BallbarEffectProblem, x: np.ndarray, jac: np.ndarray) -> np.ndarray:
    """:func:`base_parameters` of ``problem`` at ``x``, its Jacobian there ``jac``."""
    from ..analysis.identifiability import grow_active
    from ..tracker.analysis import null_space
    from .api import NULL_RTOL

    ng, ne = problem.robot.n_params, problem.n_effects
    geo_mask = null_space(problem.geometric, np.concatenate([x[:ng], x[ng + ne:]]),
                          NULL_RTOL).active
    mask = np.concatenate([geo_mask[:ng], np.zeros(ne, dtype=bool), geo_mask[ng:]])
    # each effect parameter kept if its column adds a direction
    return grow_active(jac, mask, range(ng, ng + ne), RANK_RTOL)


def _report_type() -> Any:
    from ..effects.tracker import EffectNullSpace

    return EffectNullSpace


@dataclass(frozen=True)
class BallbarEffectNullSpace(_report_type()):  # type: ignore[misc]
    """:func:`iwr.identifiability` of ballbar data for a robot with effects: the null
    directions of the distance objective with the effects (:class:`iwr.tracker.NullSpace`'s
    fields, ``left_out`` one parameter per direction), ``held`` the parameters its rank counts
    but iwr holds by default (:func:`base_parameters`: the directions of {0} and {5} that only
    the loads fix), and ``inseparable``: the effects' parameters whose columns add no direction
    to the geometry's at these poses, loads and temperatures (held at the robot file's value;
    e.g. a slide's compliance under one payload, docs/effects.md), each with its share of the
    null directions (the norm of its row of their column-scaled basis), as
    :class:`iwr.effects.api.EffectIdentifiability` has them. ``active`` leaves out
    ``left_out`` and ``held``."""

    inseparable: list[tuple[str, float]] = field(default_factory=list)

    @property
    def effects_identifiable(self) -> bool:
        return not self.inseparable

    def __str__(self) -> str:
        """The report of every kind (:class:`iwr.tracker.NullSpace`'s, the held parameters
        apart), then whether the effects are separable from the geometry."""
        text = super().__str__()
        if self.inseparable:
            return (text + "\nEffect parameters NOT separable from the geometry at these poses "
                    "and loads: " + ", ".join(n for n, _ in self.inseparable) + "; measure with "
                    "a second payload (docs/effects.md)")
        return text + "\nEvery effect parameter is separable from the geometry."


def identifiability(robot: Robot, measurements: BallbarMeasurements, x: Any = None, *,
                    rtol: float | None = None) -> BallbarEffectNullSpace:
    """:func:`iwr.identifiability` on ballbar data for a robot with effects: the null directions
    of the distance objective with the effects at ``x`` (default the nominal robot, effects and
    set-ups) at the relative threshold ``rtol`` (default :data:`RANK_RTOL`), one left-out
    parameter per direction among those :func:`base_parameters` holds, and the effects'
    parameters the data cannot separate from the geometry (:class:`BallbarEffectNullSpace`)."""
    from dataclasses import asdict

    from ..base_parameters import left_out_directions

    problem, start = effect_problem(robot, measurements)
    x = start if x is None else _full(problem, x, "x")
    jac = problem.jacobian(x)
    d = np.linalg.norm(jac, axis=0)
    d = np.where(d > 0, d, 1.0)
    _, s, vt = np.linalg.svd(jac / d, full_matrices=jac.shape[0] < jac.shape[1])
    thr = (RANK_RTOL if rtol is None else float(rtol)) * s[0]
    rank = int(np.sum(s > thr))
    null = vt[rank:]  # (k, n), scaled
    keep = _base_mask(problem, x, jac)
    names = problem.parameter_names
    cand = np.flatnonzero(~keep)
    left: np.ndarray = np.zeros(0, dtype=int)
    basis = null.T / d[:, None]
    if null.shape[0]:
        # One left-out parameter per null direction among the held ones (their columns span
        # what the base parameters' do not).
        # QR's pivoting, its ties broken by the fixed preference (iwr.base_parameters).
        left, basis = left_out_directions(null, basis, names, cand)
    ng, ne = robot.n_params, problem.n_effects
    ns = _null_space_type()(s, rank, thr, names, [names[i] for i in left], basis, d,
                            n_poses=len(measurements), n_readings=int(jac.shape[0]))
    return BallbarEffectNullSpace(
        **asdict(ns), held=[names[i] for i in cand if i not in set(left.tolist())],
        inseparable=[(names[i], float(np.linalg.norm(null[:, i])))
                     for i in range(ng, ng + ne) if not keep[i]])


def _null_space_type() -> Any:
    from ..tracker.analysis import NullSpace

    return NullSpace


def plausibility(robot: Robot, measurements: BallbarMeasurements, bounds: Any, plausible: float
                 ) -> tuple[list[str], np.ndarray, np.ndarray, Any]:
    """The ballbar kind's plausibility with the effects (:meth:`iwr.kinds.MeasurementKind.
    plausibility`): every parameter measured from the centre of its bounds against
    ``plausible`` times their half-width (the effects' own judged by their range instead,
    :func:`iwr.fit_test.size_test`), modulo the null directions of the objective with the
    effects."""
    from .api import plausible_limits

    problem, _ = effect_problem(robot, measurements, bounds)
    limit, centre = plausible_limits(problem, plausible)
    return (problem.parameter_names, limit, centre,
            lambda x: problem.residuals_and_jacobian(x))


def accuracy(robot: Robot, measurements: BallbarMeasurements, x: Any, *, truth: Any = None,
             tool: Any = None, **_: Any) -> Any:
    """:func:`iwr.ballbar.api.ballbar_accuracy` for a robot with effects: before (the nominal
    robot, effects and set-ups) and after (``x``); without ``truth`` each pose's absolute
    reading residual, with it the tool pose errors against the truth at the same readings
    under each pose's load and temperature (forward kinematics with the effects), after the
    rigid motions of {0} and {5} that best align them (:func:`iwr.ballbar.gauge_aligned`)."""
    from .api import accuracy_on

    problem, _ = effect_problem(robot, measurements)
    x = _full(problem, x, "x")
    truth = None if truth is None else _full(problem, truth, "truth")
    return accuracy_on(problem, x, truth, tool)


def leg_commands(robot: Robot, x: Any, targets: Any, q: Any, data: Any) -> np.ndarray:
    """The leg readings (N, 6) that put the platform frame at ``targets`` (N, 4, 4) in {0} with
    the model ``x`` (robot, effects, set-ups) at carriage readings ``q`` under ``data``'s loads
    and temperatures (an object with ``payload`` and ``temperatures``): the readings with the
    effects (:func:`iwr.effects.model.predicted_readings`). A ballbar does not register {0} or
    {5} (docs/ballbar.md): the targets are in the calibration's frames."""
    n_re = robot.n_params + len(effect_names(robot.effects))
    xr = np.asarray(x, dtype=float)[:n_re]
    return predicted_readings(robot, xr, np.asarray(q, dtype=float),
                              pose_from_matrix(np.asarray(targets, dtype=float)), data)


def uncertainty(robot: Robot, measurements: BallbarMeasurements, x: Any, noise: Any, *,
                active: Any = None, weighted: bool = False) -> Any:
    """:func:`iwr.ballbar.api.ballbar_uncertainty` for a robot with effects: the covariance of
    the geometric, effect and set-up parameters from the exact Jacobian of the distances with
    the effects at ``x``; ``active`` default :func:`base_parameters`."""
    from ..tracker.analysis import NullSpace
    from .api import uncertainty_on

    problem, _ = effect_problem(robot, measurements)
    x = _full(problem, x, "x")
    if isinstance(active, NullSpace):
        active = active.active
    return uncertainty_on(problem, x, noise, active=active, weighted=weighted,
                          base=lambda p, xx: _base_mask(problem, xx, problem.jacobian(xx)))


def misclosures(robot: Robot, measurements: BallbarMeasurements, x: Any, noise: Any = None
                ) -> Any:
    """:func:`iwr.ballbar.api.ballbar_misclosures` for a robot with effects: each pose's
    distance residual at ``x``, its derivatives in the parameters and in every reading (a leg
    reading's is its offset's column, a joint reading's its DH column's: exact with the effects
    too, which see the readings only through those sums)."""
    from .api import misclosures_on

    problem, _ = effect_problem(robot, measurements)
    return misclosures_on(problem, _full(problem, x, "x"), noise)


def predicted_accuracy(robot: Robot, measurements: BallbarMeasurements, x: Any, covariance: Any,
                       active: Any, *, tool: Any = None, n_samples: int = 500, seed: int = 0
                       ) -> Any:
    """:func:`iwr.ballbar.estimation.ballbar_predicted_accuracy` for a robot with effects: the
    tool pose error modulo the gauge that the covariance of the active parameters predicts at
    the poses of ``measurements`` under their loads and temperatures (the platform poses'
    derivatives by implicit differentiation of the loop closure with the effects)."""
    from .estimation import predicted_accuracy_on

    problem, _ = effect_problem(robot, measurements)
    return predicted_accuracy_on(problem, x, covariance, active, tool=tool,
                                 n_samples=n_samples, seed=seed)


def _spec_base() -> Any:
    from .estimation import BallbarSpec

    return BallbarSpec


class EffectBallbarSpec(_spec_base()):  # type: ignore[misc]
    """:class:`iwr.ballbar.estimation.BallbarSpec` for a robot with effects: the parameters are
    the geometric errors, the effects', then the set-ups'; the start is the noise-weighted LM on
    the distances with the effects over :func:`base_parameters`, the reference poses its
    forward kinematics with the effects, and the loop model's legs carry the effects under each
    pose's load and temperature (:func:`iwr.ballbar.estimation.ballbar_loop_model`)."""

    def _problem_and_start(self, bounds: Any, x0: Any) -> tuple[Any, np.ndarray]:
        return effect_problem(self.robot, self.measurements, bounds, x0)

    def _base(self, problem: Any, start: np.ndarray) -> np.ndarray:
        return _base_mask(problem, start, problem.jacobian(start))


def estimator(robot: Robot, data: BallbarMeasurements, noise: Any, **options: Any) -> Any:
    """The ballbar kind's estimation spec for a robot with effects (:class:`EffectBallbarSpec`)."""
    return EffectBallbarSpec(robot, data, noise, options["x0"], options["active"],
                             options["estimate"], options["bounds"], options["plausible"])


def design(robot: Robot, data: BallbarMeasurements, x: Any, report: Any
           ) -> tuple[BallbarEffectProblem, np.ndarray, np.ndarray, int]:
    """:func:`iwr.plan_poses`' problem for ballbar data with effects: the (pose, set-up) pairs
    as the nominal robot with its effects and the nominal set-ups measure them under each
    pair's load and temperature (``data``), ``x`` (default zeros; the robot's and effects' part
    alone: the nominal set-ups), the parameters identified by default (:func:`base_parameters`,
    or ``report``'s active ones), one reading per pair."""
    problem, _ = effect_problem(robot, data)
    ns = problem.setup.n_params
    if x is not None and np.shape(x) == (problem.n_params - ns,):
        x = np.concatenate([np.asarray(x, dtype=float), np.zeros(ns)])
    xf = _full(problem, x, "x")
    mask = _base_mask(problem, xf, problem.jacobian(xf)) if report is None else \
        np.asarray(report.active)
    return problem, xf, np.flatnonzero(mask), 1


def measure(robot: Robot, x: Any, pairs: Any, noise: Any = None, seed: Any = None
            ) -> BallbarMeasurements:
    """The readings of the actual robot, effects and set-ups ``x`` at planned (pose, set-up)
    pairs (``plan.measurements``: joint readings, platform poses in {0}, set-ups, and each
    pair's payload and temperatures): the legs with the effects under each load, the bar's
    distances, then the noise as :func:`simulate` adds it (``seed`` or a generator)."""
    from .simulate import measured

    setup = _setup(robot)
    index = np.array([setup.index(str(s)) for s in pairs.setup], dtype=np.intp)
    problem = BallbarEffectProblem(robot, setup, BallbarMeasurements(
        pairs.q, pairs.legs, pairs.setup, np.ones(len(pairs)), joint_types=robot.joint_types,
        payload=pairs.payload, temperatures=pairs.temperatures))
    x = _full(problem, x, "x")
    n_re = problem.n_params - setup.n_params
    legs = predicted_readings(robot, x[:n_re], pairs.q, pairs.poses, problem.measurements)
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    return measured(robot, setup, x[n_re:], index, pairs.q, pairs.poses, legs, noise, rng,
                    payload=pairs.payload, temperatures=pairs.temperatures)
