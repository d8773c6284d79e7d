"""What the library does with a robot's effects (docs/effects.md): simulate its data, apply
identified parameters, tell what the data can identify, solve its forward kinematics and
compensate its leg commands."""

from __future__ import annotations

import dataclasses
import types
from typing import Any

import numpy as np

from ..base_parameters import condition_number, direction_text, directions_of, report_lines
from ..transforms import pose_matrix as pose_matrix_of
from . import bounds as effect_bounds
from . import parameter_names as effect_names
from .builtin import STANDARD_GRAVITY, LegCompliance, LegThermal
from .model import check_inputs, predicted_readings, split

__all__ = ["EffectIdentifiability", "apply", "forward_kinematics", "identifiability",
           "leg_commands", "realistic", "simulate", "DEFAULT_PAYLOADS"]

#: The payloads :func:`simulate` alternates by default (mass kg, centre of mass in {5} mm): none,
#: and a welding/machining head of 80 kg whose centre is 150 mm out along the tool axis and 50 mm
#: off it (docs/effects.md). Two payloads, so that the compliances are separable from the
#: geometry (the design rule of docs/effects.md).
DEFAULT_PAYLOADS = np.array([[0.0, 0.0, 0.0, 0.0], [80.0, 50.0, 0.0, 150.0]])
#: The temperatures :func:`simulate` draws by default, about the reference (K): a day's drift.
DEFAULT_TEMPERATURE_SPREAD = (-3.0, 5.0)


#: The realistic carriage's loads and compliances (docs/effects.md, "Realistic magnitudes"): a
#: hexapod of 400 kg (base, legs, what the last link carries) with its centre 150 mm above {4}'s
#: origin; revolute joints of 5e7 N m/rad (0.02 urad/(N m)), prismatic drives of 200 N/um
#: (0.005 um/N).
REALISTIC_CARRIAGE = {"hexapod_mass": 400.0, "hexapod_centre": (0.0, 0.0, 150.0),
                      "R": 0.02, "P": 0.005}


def realistic(robot: Any, *, per_leg: bool = True, identify_alpha: bool = True,
              carriage: bool = False) -> tuple[Any, ...]:
    """Realistic effects for ``robot`` (docs/effects.md): legs of 100 N/um axial stiffness
    (0.01 um/N), a 120 kg platform with its centre 40 mm above {5}'s origin, gravity opposite
    the hexapod's z axis at the centre of the carriage's joint ranges; steel legs (11.5 ppm/K)
    about 20 C, the coefficient identified (one shared) when ``identify_alpha``; with
    ``carriage``, also the compliance of every carriage joint (:data:`REALISTIC_CARRIAGE`)."""
    t4 = robot.carriage_transform(robot.joint_limits.mean(axis=1)) if robot.n_joints else np.eye(4)
    gravity = -STANDARD_GRAVITY * t4[:3, 2]
    gravity[np.abs(gravity) < 1e-12] = 0.0  # round-off of the DH angles, not a tilt
    out: tuple[Any, ...] = (LegCompliance(120.0, [0.0, 0.0, 40.0], gravity, 0.01,
                                          per_leg=per_leg),
                            LegThermal(11.5, 20.0, identify=identify_alpha))
    if carriage:
        out += (_realistic_carriage(robot, gravity),)
    return out


def _realistic_carriage(robot: Any, gravity: np.ndarray) -> Any:
    """:data:`REALISTIC_CARRIAGE` for the joints of ``robot`` that carry a gravity load
    somewhere in their ranges (:func:`loaded_joints`): a joint that never does (a horizontal
    slide, a vertical axis) has no compliance the data could tell. The loads are those under
    gravity as the robot's data give it (:meth:`iwr.kinds.MeasurementKind.world_gravity`: on
    tracker data the tracker's, through the robot file's registration), ``gravity`` (the
    effect's own, in {0}) otherwise."""
    from .. import kinds
    from .carriage import CarriageCompliance

    rc = REALISTIC_CARRIAGE
    if not robot.n_joints:
        raise ValueError(f"robot {robot.name!r} has no carriage joints: no carriage compliance")
    world = kinds.for_robot(robot).world_gravity(robot)
    loaded = loaded_joints(robot, gravity if world is None else world)
    if not loaded:
        raise ValueError(f"robot {robot.name!r}: no carriage joint carries a gravity load")
    return CarriageCompliance(rc["hexapod_mass"], rc["hexapod_centre"], 120.0, [0.0, 0.0, 40.0],
                              gravity, loaded,
                              [rc[robot.joint_types[j - 1]] for j in loaded]).for_robot(robot)


def loaded_joints(robot: Any, gravity: Any) -> list[int]:
    """The carriage joints of ``robot`` (numbers from 1) that carry a gravity load somewhere in
    their ranges under ``gravity`` (in {0}, m/s^2): the loads of the realistic hexapod and
    platform (:data:`REALISTIC_CARRIAGE`) at the corners and the centre of the joint ranges,
    the hexapod at its home pose, the nominal geometry; a load below 1e-9 of the largest is
    round-off of the axes' directions. Empty for a robot without carriage joints."""
    import itertools

    from ..transforms import pose_from_matrix
    from .carriage import CarriageCompliance
    from .model import joint_loads, platform_moment

    nj = robot.n_joints
    if not nj:
        return []
    rc = REALISTIC_CARRIAGE
    every = CarriageCompliance(rc["hexapod_mass"], rc["hexapod_centre"], 120.0,
                               [0.0, 0.0, 40.0], np.asarray(gravity, dtype=float),
                               list(range(1, nj + 1)), 0.0).for_robot(robot)
    lim = robot.joint_limits
    q = np.array([lim.mean(axis=1)] + [lim[np.arange(nj), c]
                                       for c in itertools.product((0, 1), repeat=nj)])
    home = pose_matrix_of(robot.home_pose)
    t5 = np.array([robot.carriage_transform(qk) @ home for qk in q])
    poses = np.array([pose_from_matrix(t) for t in t5])
    data = types.SimpleNamespace(payload=None)
    moment, mass, _ = platform_moment(every, data, pose_matrix_of(poses))
    loads, _, _ = joint_loads(robot, np.zeros(robot.n_params), q, moment, mass, every)
    size = np.abs(loads).max(axis=0)
    return [i + 1 for i in range(nj) if size[i] > 1e-9 * size.max()]


def apply(robot: Any, x: Any) -> Any:
    """The robot whose geometry and effects are ``robot``'s corrected by ``x`` (geometric errors,
    then the effects' parameters): a calibrated robot, written with its effects' values."""
    xg, xe = split(robot, x)
    out = robot.with_errors(xg)
    effects, k = [], 0
    for e in robot.effects:
        n = len(e.parameter_names())
        effects.append(e.with_values(e.values() + xe[k: k + n]) if n else e)
        k += n
    return out.with_effects(*effects)


def widened_ranges(robot: Any, x: Any) -> list[str]:
    """What :func:`apply` widens: each effect's plausible range (``max_*`` in the robot file)
    that an identified value in ``x`` lies beyond, raised to hold it (a robot file holds its own
    values), as sentences naming the key, its old and new value."""
    calibrated = apply(robot, x)
    out = []
    for old, new in zip(robot.effects, calibrated.effects, strict=True):
        before, after = old.to_dict(), new.to_dict()
        for key, value in after.items():
            if key.startswith("max_") and value != before.get(key):
                out.append(f"[effects.{old.name}] {key} {before[key]:g} -> {value:.4g}")
        # Below the range's lower end (a negative compliance or coefficient): the calibrated
        # effect's range starts at the value (its bounds()), with no key to name.
        lowest = old.values() + old.bounds()[0]
        for name, unit, value, low in zip(new.parameter_names(), new.units(), new.values(),
                                          lowest, strict=True):
            if value < low:
                out.append(f"[effects.{old.name}] {name} {value:.4g} {unit}, below the plausible "
                           f"range's lower end {low:g}: the range starts at it")
    return out


def draw_conditions(robot: Any, n: int, rng: np.random.Generator, payloads: Any,
                    temperatures: Any) -> tuple[Any, Any]:
    """The loads and temperatures of ``n`` simulated poses (:func:`simulate`, and the tracker
    data's :func:`iwr.effects.tracker.simulate`): ``payloads`` (P, 4) taken in turn (default
    :data:`DEFAULT_PAYLOADS` when an effect of the load is on, else none); ``temperatures`` as
    given, else drawn from ``rng`` over :data:`DEFAULT_TEMPERATURE_SPREAD` about the thermal
    effect's reference when it is on (the legs' or the carriage's, the first listed; else none)."""
    loaded = any(e.needs & {"forces", "loads"} for e in robot.effects)
    pay = None
    if payloads is not None or loaded:
        pay = DEFAULT_PAYLOADS if payloads is None else np.asarray(payloads, dtype=float)
        if pay.ndim != 2 or pay.shape[1] != 4 or len(pay) == 0:
            raise ValueError(f"payloads: shape {pay.shape}; expected (P, 4): mass kg, centre "
                             "in {5} mm")
        pay = pay if len(pay) == n else pay[np.arange(n) % len(pay)]
    thermal = [e for e in robot.effects if e.needs & {"temperatures", "machine_temperature"}]
    if temperatures is None and thermal:
        lo, hi = DEFAULT_TEMPERATURE_SPREAD
        temperatures = thermal[0].reference + lo + (hi - lo) * rng.random(n)
    return pay, temperatures


def true_parameters(robot: Any, rng: np.random.Generator, x: Any, setup_bounds: Any = None,
                    setup_text: str = "") -> np.ndarray:
    """The true parameters of a simulation with the effects: ``x`` as given, checked (the
    robot's geometric errors, its effects' parameters, then the set-up's, ``setup_bounds``
    ``(lower, upper)``, if any: ``setup_text`` names them), or drawn uniformly within the
    default bounds by one call of ``rng`` (the same stream for every kind of data)."""
    lo_g, hi_g = robot.default_bounds()
    lo_e, hi_e = effect_bounds(robot.effects)
    lo_s, hi_s = (np.zeros(0), np.zeros(0)) if setup_bounds is None else setup_bounds
    lo, hi = np.concatenate([lo_g, lo_e, lo_s]), np.concatenate([hi_g, hi_e, hi_s])
    if x is None:
        return lo + (hi - lo) * rng.random(lo.size)
    x = np.array(x, dtype=float)
    if x.shape != (lo.size,) or not np.all(np.isfinite(x)):
        raise ValueError(f"x: expected {lo.size} finite values ({robot.n_params} geometric, "
                         f"then {', '.join(effect_names(robot.effects))}{setup_text}), got "
                         f"shape {x.shape}")
    return x


def simulate(robot: Any, n_poses: int, *, seed: int | None, x: Any = None, noise: Any = None,
             payloads: Any = None, temperatures: Any = None) -> tuple[Any, np.ndarray]:
    """:func:`iwr.simulate` for a robot with effects: random reachable poses of the actual robot
    (geometric errors and effect parameters ``x``, default uniform within their bounds), each
    with a payload (``payloads``: (P, 4) rows ``(kg, x, y, z mm in {5})`` taken in turn, or one
    row per pose; default :data:`DEFAULT_PAYLOADS` when the compliance effect is on, else none)
    and temperatures (``temperatures``: (N,), (N, 1) or (N, 6) degrees C; default, with the
    thermal effect on, one per pose uniform in its reference plus
    :data:`DEFAULT_TEMPERATURE_SPREAD`, else none), and the leg readings that the actual robot gives
    there (:func:`iwr.effects.model.predicted_readings`), with ``noise`` (an :class:`iwr.Noise`)
    as :func:`iwr.simulate`. Returns ``(measurements, x_true)``."""
    from ..measurements import Measurements
    from ..noise import Noise
    from ..simulation import add_noise, sample_poses

    if isinstance(n_poses, bool) or not isinstance(n_poses, (int, np.integer)) or n_poses < 1:
        raise ValueError(f"n_poses: {n_poses!r}; expected a positive integer")
    noise = noise if noise is not None else Noise()
    if not isinstance(noise, Noise):
        raise TypeError(f"noise: expected an iwr.Noise, got {type(noise).__name__}")
    geometric = robot.with_effects()
    rng = np.random.default_rng(seed)
    x = true_parameters(robot, rng, x)
    n = int(n_poses)
    q, poses, _ = sample_poses(geometric, n, rng, x[: robot.n_params])
    pay, temperatures = draw_conditions(robot, n, rng, payloads, temperatures)
    plain = Measurements(q, poses, np.zeros((n, 6)), joint_types=robot.joint_types,
                         payload=pay, temperatures=temperatures)
    legs = predicted_readings(robot, x, q, poses, plain)
    noisy = add_noise(geometric, q, poses, legs, noise, rng)
    return Measurements(noisy.q, noisy.poses, noisy.legs, joint_types=robot.joint_types,
                        payload=plain.payload, temperatures=plain.temperatures), x


@dataclasses.dataclass
class EffectIdentifiability:
    """What leg readings at a set of poses, loads and temperatures identify of a robot with
    effects (:func:`identifiability`).

    ``rank`` of the column-scaled Jacobian of every parameter (geometric, then the effects');
    ``geometric_rank`` of the geometric columns alone; ``inseparable``: the effect parameters
    that take part in an unidentifiable direction (a change of them that a change of the
    geometry, or of the other effect parameters, mimics at every reading), each with the size of
    its share; ``active`` the base parameters' mask for :func:`iwr.identify`."""

    parameter_names: list[str]
    singular_values: np.ndarray
    rank: int
    geometric_rank: int
    threshold: float
    null_space: np.ndarray
    inseparable: list[tuple[str, float]]
    active: np.ndarray
    n_poses: int
    x: np.ndarray
    n_geometric: int
    scale: np.ndarray | None = None  # the Jacobian's column norms (None: the directions unsaid)

    @property
    def effects_identifiable(self) -> bool:
        """Whether every effect parameter is separable from the geometry and the others."""
        return not self.inseparable

    @property
    def base_parameters(self) -> list[str]:
        return [n for n, a in zip(self.parameter_names, self.active, strict=True) if a]

    @property
    def left_out(self) -> list[str]:
        """The parameters not among the base ones (held at their value by :func:`iwr.identify`)."""
        return [n for n, a in zip(self.parameter_names, self.active, strict=True) if not a]

    @property
    def null_directions(self) -> list[tuple[str, str]]:
        """One unidentifiable direction per left-out parameter, ``(name, text)``: it moves that
        parameter by 1 and the other left-out ones not at all (the form of the tracker's and
        the ballbar's reports: :func:`iwr.base_parameters.directions_of`), ``text`` its
        components, largest (column-scaled) first."""
        left = np.flatnonzero(~self.active)
        if left.size == 0 or self.scale is None or self.null_space.shape[1] != left.size:
            return []
        try:
            basis = directions_of(self.null_space, left)
        except np.linalg.LinAlgError:  # the left-out rows dependent (a rank at the threshold)
            return []
        return [(self.parameter_names[j], direction_text(basis[:, i], self.scale,
                                                         self.parameter_names))
                for i, j in enumerate(left)]

    @property
    def condition_number(self) -> float:
        """Of the column-scaled Jacobian's identifiable part (as :func:`iwr.identifiability`)."""
        return condition_number(self.singular_values, self.rank)

    def __str__(self) -> str:
        """The report of every kind (:func:`iwr.base_parameters.report_lines`, the base
        parameters), then whether the effects are separable from the geometry."""
        n_eff = len(self.parameter_names) - self.n_geometric
        lines = [f"Identifiability with effects from {self.n_poses} poses: "
                 f"{len(self.parameter_names)} parameters ({self.n_geometric} of the geometry, "
                 f"rank {self.geometric_rank} alone; {n_eff} effect parameters)",
                 *report_lines(self.singular_values, self.rank, self.threshold, self.n_poses),
                 f"  base parameters: {len(self.base_parameters)}; left out (hold fixed): "
                 + (", ".join(self.left_out) or "none")]
        if self.null_directions:
            lines.append("  unidentifiable directions (coefficients in mm and rad):")
            lines += [f"    {k}. [{name}] {text}"
                      for k, (name, text) in enumerate(self.null_directions, 1)]
        if self.inseparable:
            lines.append("Effect parameters NOT separable from the geometry (or each other) at "
                         "these poses and loads: " + ", ".join(
                             f"{n} ({s:.2g})" for n, s in self.inseparable)
                         + "; measure with a second payload (docs/effects.md)")
        else:
            lines.append("Every effect parameter is separable from the geometry.")
        return "\n".join(lines)


def identifiability(robot: Any, measurements: Any, x: Any = None, *, rtol: float | None = None
                    ) -> EffectIdentifiability:
    """:func:`iwr.identifiability` for a robot with effects: the rank of the column-scaled
    Jacobian of eq. (10) with the effects (:class:`iwr.effects.problem.EffectProblem`) at ``x``
    (default the nominal robot), the effect parameters that cannot be separated from the
    geometry, and the base parameters (:func:`iwr.identifiability`'s ordered rule: the
    hexapod's, the effects', then the carriage's)."""
    from ..analysis.identifiability import _base_parameters, _rank_threshold, _scaled_svd
    from .problem import EffectProblem

    problem = EffectProblem(robot, measurements)
    x = np.zeros(problem.n_params) if x is None else np.asarray(x, dtype=float)
    jac = problem.jacobian(x)
    d, s, vt = _scaled_svd(jac)
    thr, _ = _rank_threshold(s, jac.shape, rtol)
    rank = int(np.sum(s > thr))
    ng = robot.n_params
    _, sg, _ = _scaled_svd(jac[:, :ng])
    thr_g, _ = _rank_threshold(sg, (jac.shape[0], ng), rtol)
    null = vt[rank:].T  # scaled coordinates: unit-free shares
    names = problem.parameter_names
    share = np.linalg.norm(null[ng:], axis=1) if null.size else np.zeros(len(names) - ng)
    # Inseparable: the parameter's column is in the span of the others (leaving it out does not
    # lower the rank). Its share of the null directions alone is not the test: where the
    # geometry's own null space is large, a null basis vector mixes in a small share of a
    # separable column near the rank threshold.
    inseparable = []
    for i, v in enumerate(share):
        if v <= 1e-6:
            continue
        _, s_i, _ = _scaled_svd(np.delete(jac, ng + i, axis=1))
        if int(np.sum(s_i > thr)) == rank:
            inseparable.append((names[ng + i], float(v)))
    # The ordered rule of iwr.identifiability (the effects' parameters after the hexapod's).
    base, _ = _base_parameters(jac / d, s, thr, rank, names, "ordered")
    active = np.zeros(len(names), dtype=bool)
    active[base] = True
    return EffectIdentifiability(names, s, rank, int(np.sum(sg > thr_g)), thr, null / d[:, None],
                                 inseparable, active, len(measurements), x, ng, d)


def forward_kinematics(robot: Any, x: Any, q: Any, legs: Any, data: Any, guess: Any, *,
                       tolerance: float = 1e-11, max_iterations: int = 50) -> np.ndarray:
    """The platform poses in {0} (N, 6) at which the robot with errors and effect parameters
    ``x`` gives leg readings ``legs`` at joint readings ``q``, under ``data``'s loads and
    temperatures (an object with ``payload`` and ``temperatures`` as :class:`iwr.Measurements`
    has): Newton's method on the pose from ``guess`` (N, 6), with the pose Jacobian of the
    predicted readings by central differences (the answer does not depend on it: the readings
    are matched to ``tolerance`` mm). RuntimeError naming the pose when one does not converge."""
    from ..transforms import pose_from_matrix, pose_matrix, rotvec_matrix

    q = np.asarray(q, dtype=float).reshape(-1, robot.n_joints)
    legs = np.asarray(legs, dtype=float).reshape(-1, 6)
    poses = np.array(guess, dtype=float).reshape(-1, 6)

    def moved(p: np.ndarray, dx: np.ndarray) -> np.ndarray:
        t = pose_matrix(p)
        t[..., :3, 3] += dx[..., :3]
        t[..., :3, :3] = rotvec_matrix(dx[..., 3:]) @ t[..., :3, :3]
        return pose_from_matrix(t)

    def readings(p: np.ndarray) -> np.ndarray:
        return predicted_readings(robot, x, q, p, data)

    h = np.array([1e-4] * 3 + [1e-7] * 3)
    for _ in range(max_iterations):
        r = readings(poses) - legs
        if np.abs(r).max() <= tolerance:
            return poses
        jac = np.empty((len(poses), 6, 6))
        for c in range(6):
            step = np.zeros((len(poses), 6))
            step[:, c] = h[c]
            jac[:, :, c] = (readings(moved(poses, step)) - readings(moved(poses, -step))) \
                / (2 * h[c])
        poses = moved(poses, -np.linalg.solve(jac, r[..., None])[..., 0])
    r = np.abs(readings(poses) - legs).max(axis=1)
    k = int(np.argmax(r))
    raise RuntimeError(f"forward kinematics with effects: pose {k} did not converge in "
                       f"{max_iterations} iterations (leg residual {r[k]:.3g} mm)")


def leg_commands(robot: Any, q: Any, poses: Any, *, payload: Any = None,
                 temperatures: Any = None, **options: Any) -> Any:
    """:func:`iwr.compensation.leg_commands` for a (calibrated) robot with effects: the leg
    commands that put the platform (or tool) at the targets with the legs compressed or
    stretched by the load of the move and grown or shrunk by its temperature. ``payload``:
    (4,) or (N, 4), mass kg and centre in {5} mm (default none); ``temperatures``: one per move
    (or (N, 6), one per leg), degrees C, needed by the thermal effect."""
    from ..compensation import leg_commands as geometric_commands
    from ..measurements import Measurements
    from .gravity import in_world_gravity

    robot = in_world_gravity(robot)  # tracker data's gravity: in {T}, through the registration
    base = geometric_commands(robot.with_effects(), q, poses, **options)
    world = base.platform_poses
    n = len(world)
    qa = np.asarray(q, dtype=float).reshape(n, robot.n_joints)
    pay = None if payload is None else np.broadcast_to(np.asarray(payload, dtype=float), (n, 4))
    temps = None if temperatures is None else np.asarray(temperatures, dtype=float)
    if temps is not None and temps.ndim == 0:
        temps = np.full(n, float(temps))
    cond = Measurements(qa, world, np.zeros((n, 6)), joint_types=robot.joint_types,
                        payload=pay, temperatures=temps)
    check_inputs(robot, cond, "temperatures")
    n_eff = len(effect_names(robot.effects))
    legs = predicted_readings(robot, np.zeros(robot.n_params + n_eff), qa, world, cond)
    lo, hi = robot.leg_stroke[:, 0], robot.leg_stroke[:, 1]
    return dataclasses.replace(base, legs=legs, out_of_stroke=(legs < lo) | (legs > hi))
