"""The experiment harness: a *scenario* (one simulated calibration problem), a *cell* (one
identification of a scenario and its row of figures) and its evaluation; the *executors* that run
grids of cells, in this process or on Dask, are :mod:`iwr.experiments.executors`. ``iwr compare``
and ``iwr study`` are two uses of it.

Seeding, one scheme for every experiment: each random stream is drawn from
``SeedSequence([base_seed, purpose, draw(, seed)])`` (:func:`stream_seed`), with one purpose per
stream: the true error vector depends on ``(base_seed, draw)`` only; the poses and noise of the
identification data, the validation poses and the method's random stream on
``(base_seed, draw, seed)``. So every method, pose count and noise level of a (draw, seed) pair
sees the same actual robot and validation poses, and every noise level the same poses with noise
of the same shape, scaled (common random numbers: differences between cells are not sampling
noise).

Every kind of data (:mod:`iwr.kinds`: the platform pose in {0}, tracker points or a probe in
{T}) runs through the same harness: the robot's kind says what a scenario simulates (its noise at
a noise level, the actual set-up beside the robot's errors) and what the validation figures
measure (:attr:`iwr.kinds.MeasurementKind.experiment_text`).

The row of a cell has one schema (:data:`SETTING_COLUMNS` then :data:`FIGURE_COLUMNS`), whatever
runs it; every call into the identification and analysis API is in :func:`evaluate`.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import kinds
from ..robot import Robot
from ..simulation import Noise, simulate

__all__ = [
    "ArgumentError",
    "Cell",
    "Scenario",
    "check_n_poses",
    "check_robot",
    "identifiable",
    "min_poses",
    "ScenarioData",
    "SETTING_COLUMNS",
    "FIGURE_COLUMNS",
    "TIMING_COLUMNS",
    "COLUMNS",
    "SCENARIOS",
    "evaluate",
    "noise_at",
    "rms",
    "split_method",
    "stream_seed",
]

#: Version of what a cell computes: part of every cell's key, so that a study resumed by a
#: version that computes a cell's figures differently computes its cells again instead of
#: reusing the rows of the old computation. Raise it with any such change in a release. 2: the
#: nominal figures on tracker data in the identification's start
#: (:meth:`iwr.kinds.MeasurementKind.before`), none without one, and the calibrated figures of a
#: robot with effects on tracker data without a registration guess (all since the last release).
CELL_FORMAT = 2


class ArgumentError(ValueError):
    """A bad argument of an experiment (:func:`iwr.compare_methods`, :func:`iwr.study`), found
    before anything runs. The message starts with the argument's name and a colon (``seeds:
    ...``); :attr:`name` is that name, so that a command line can name its own option instead
    (``iwr compare --seeds``: a usage error, exit 2)."""

    @property
    def name(self) -> str:
        return str(self).split(":", 1)[0].split(".", 1)[0].strip()

#: Scenarios: where the truth is drawn, the bounds searched, and where the methods start.
SCENARIOS: dict[str, str] = {
    "near": (
        "errors uniform within the default bounds (+-0.5 mm, +-0.5 degree); every method starts "
        "from the nominal robot (all errors zero; a set-up, if any, as the kind guesses it from "
        "the data), the usual calibration situation"
    ),
    "bad": (
        "large errors, uniform within the paper's Table 2 bounds taken literally (+-0.5 mm for "
        "lengths, +-0.5 rad for angles), searched within those bounds; every parameter starts at "
        "90% of its bound on the side opposite to its true value (a set-up's too, within its "
        "default bounds about the nominal set-up)"
    ),
}
_BOUNDS = {"near": "default", "bad": "paper"}
_BAD_START_FRACTION = 0.9

# The table: one row per cell. Settings first, then figures; missing figures are empty.
SETTING_COLUMNS = (
    "key", "scenario", "method", "options", "budget", "budget_option", "n_poses", "noise", "draw",
    "seed", "base_seed", "validation_poses", "robot",
)
FIGURE_COLUMNS = (
    "status", "message", "cost", "noise_floor", "at_floor", "rms_fit", "val_rms", "val_max",
    "val_rms_nominal", "param_error_length", "param_error_angle", "raw_error_length",
    "raw_error_angle", "max_raw_error_length", "tool_position_rms", "tool_orientation_rms",
    "tool_position_rms_nominal", "nfev", "nit", "within_budget", "success", "wall_time", "notes",
)
# Figures that depend on the machine, not on the settings: left out when tables are compared.
TIMING_COLUMNS = ("wall_time",)
COLUMNS = SETTING_COLUMNS + FIGURE_COLUMNS

#: A cell is *at the floor* when its cost is at most ``(1 + rtol) floor + 6 N atol^2``, the floor
#: being the cost of the true parameters on the same noisy data.
FLOOR_RTOL, FLOOR_ATOL = 0.1, 1e-3

# Purposes of the random streams, the second entropy word of stream_seed.
_ERRORS, _DATA, _VALIDATION, _METHOD = 1, 2, 3, 4

# Exceptions that a cell's computation raises deterministically: recorded in its row as a failure
# (running it again would fail again). Anything else (a lost connection, memory) propagates, so
# that an executor may retry the cell.
RECORDED_ERRORS = (ValueError, ArithmeticError, RuntimeError, np.linalg.LinAlgError)


def stream_seed(*entropy: int) -> int:
    """A 63-bit seed drawn from the given integers: independent streams for independent uses."""
    return int(np.random.SeedSequence(list(entropy)).generate_state(1, np.uint64)[0] >> 1)


def rms(v: Any) -> float:
    """Root mean square of ``v``; nan for an empty array."""
    a = np.asarray(v, dtype=float)
    return float(np.sqrt(np.mean(np.square(a)))) if a.size else math.nan


def percentiles_worst(values: Any, qs: Any) -> np.ndarray:
    """Percentiles ``qs`` (0-100, NumPy's linear interpolation) of an error or a cost over a set
    of runs, a run without the figure (nan: it failed, or the model has no forward kinematics
    at its result) counted as the worst, inf: so that every figure of a row or a cell is over
    the same runs (the median of the others alone is of better runs). A percentile that
    interpolates towards such a run is inf; none of nothing is nan."""
    v = np.sort(np.array([math.inf if math.isnan(x) else x for x in values], dtype=float))
    qs = np.atleast_1d(np.asarray(qs, dtype=float))
    if v.size == 0:
        return np.full(qs.shape, math.nan)
    if np.all(np.isfinite(v)):
        return np.asarray(np.percentile(v, qs), dtype=float)
    # NumPy's linear interpolation between the order statistics around (n - 1) q / 100, by
    # hand: its 0 * inf is nan.
    h = (v.size - 1) * qs / 100.0
    lo = np.floor(h).astype(int)
    hi = np.minimum(lo + 1, v.size - 1)
    w = h - lo
    with np.errstate(invalid="ignore"):
        inner = v[lo] + w * (v[hi] - v[lo])
    return np.where(w == 0, v[lo], np.where(np.isinf(v[hi]), math.inf, inner))


def noise_at(level: float) -> Noise:
    """The measurement noise of a noise level: ``level`` is the laser tracker's position standard
    deviation (mm); the other channels keep the proportions of :meth:`Noise.realistic`.

    So ``noise_at(0.02) == Noise.realistic()`` (legs 2 um, joints 5 um and 5 urad, tracker 20 um
    and 20 urad) and ``noise_at(0)`` is the paper's noise-free simulation.
    """
    level = float(level)
    if not (math.isfinite(level) and level >= 0):
        raise ArgumentError(f"noise: {level!r}; expected a finite level >= 0 (mm)")
    ref = Noise.realistic()
    scale = level / ref.position
    return Noise(
        legs=ref.legs * scale,
        joint_lengths=ref.joint_lengths * scale,
        joint_angles=ref.joint_angles * scale,
        position=ref.position * scale,
        orientation=ref.orientation * scale,
    )


def registered_methods() -> dict[str, Any]:
    """:data:`iwr.methods.METHODS`, imported on first use: the methods import SciPy's optimize,
    which a command's ``--help`` should not pay for."""
    from ..methods import METHODS

    return METHODS


def _de_strategies() -> tuple[str, ...]:
    from ..methods.de import STRATEGIES

    return tuple(STRATEGIES)


def available_methods() -> str:
    """The method specs accepted, as text for a message."""
    return (", ".join(sorted(registered_methods())) + "; or de:STRATEGY with STRATEGY one of "
            + ", ".join(_de_strategies()))


def split_method(spec: Any) -> tuple[str, dict[str, Any]]:
    """The registered method and its fixed options of a method spec: a registered name as it is
    (``"lm"`` -> ``("lm", {})``), or ``"de:STRATEGY"``, differential evolution with that strategy
    (``"de:jso"`` -> ``("de", {"strategy": "jso"})``). Raises ValueError naming a bad spec."""
    if not isinstance(spec, str):
        raise ArgumentError(f"methods: {spec!r}; expected a method name; available: "
                         f"{available_methods()}")
    if spec in registered_methods():
        return spec, {}
    base, sep, variant = spec.partition(":")
    if sep and base == "de":
        strategies = _de_strategies()
        if variant not in strategies:
            raise ArgumentError(f"methods: {spec!r}: unknown DE strategy {variant!r}; available: "
                             + ", ".join(strategies))
        return "de", {"strategy": variant}
    if sep and base in registered_methods():
        raise ArgumentError(f"methods: {spec!r}: only de takes a variant (de:STRATEGY)")
    raise ArgumentError(f"methods: {spec!r} is not registered; available: {available_methods()}")


# -- how many poses -----------------------------------------------------------------------------

_IDENTIFIABLE: dict[str, int] = {}


_READINGS: dict[str, float] = {}


def _scaled_null_basis(problem: Any, x: np.ndarray, kind: Any) -> tuple[int, np.ndarray]:
    """``(rank, basis)`` of the column-scaled Jacobian of ``problem`` at ``x`` (each column
    divided by its norm; rank threshold numpy's, or the ``kind``'s
    :attr:`iwr.kinds.MeasurementKind.null_rtol`, as :func:`iwr.identifiability`): an
    orthonormal basis of its null space in the scaled metric, (n_params, n_null)."""
    jac = problem.jacobian(x)
    d = np.linalg.norm(jac, axis=0)
    d = np.where(d > 0, d, 1.0)
    # The whole of V (the null space), not of U: a square U of the readings, (6 N)^2 doubles,
    # took 2.4 GB at 2000 poses (full V needed only with fewer readings than parameters).
    _, s, vt = np.linalg.svd(jac / d, full_matrices=jac.shape[0] < jac.shape[1])
    rtol = max(max(jac.shape) * np.finfo(float).eps, kind.null_rtol or 0.0)
    rank = int(np.sum(s > rtol * s[0]))
    return rank, vt[rank:].T


def identifiable(robot: Robot) -> int:
    """The number of identifiable parameters of ``robot`` on its kind of data (the rank of the
    column-scaled Jacobian on generic poses: 52 of 58 for the IWR's poses in {0}), computed once
    per robot."""
    key = robot_hash(robot)
    if key not in _IDENTIFIABLE:
        kind = kinds.for_robot(robot)
        data, x = simulate(robot, max(60, kind.n_params(robot)), seed=0)
        problem, _ = kind.problem(robot, data, x0=x)
        _IDENTIFIABLE[key] = _scaled_null_basis(problem, x, kind)[0]
        _READINGS[key] = kind.readings_per_pose(robot, data)
    return _IDENTIFIABLE[key]


def min_poses(robot: Robot) -> int:
    """The fewest measurement poses whose readings can determine the identifiable parameters of
    ``robot``: 9 for the IWR measured in {0} (six leg readings a pose: 54 readings for 52
    identifiable parameters). Below it the identification is underdetermined whatever the
    method, and its figures mean nothing."""
    need = identifiable(robot)
    return max(1, math.ceil(need / _READINGS[robot_hash(robot)] - 1e-9))


def check_robot(robot: Robot) -> kinds.MeasurementKind:
    """The kind of data ``robot`` measures (:func:`iwr.kinds.for_robot`), which the experiments
    simulate; ValueError when no registered kind applies to it."""
    if not isinstance(robot, Robot):
        raise ValueError(f"robot: expected an iwr.Robot, got {type(robot).__name__}")
    return kinds.for_robot(robot)


def check_n_poses(robot: Robot, n_poses: Any, name: str = "n_poses") -> int:
    """``n_poses`` as an int, or ValueError naming ``name``, the value and the minimum
    (:func:`min_poses`)."""
    if isinstance(n_poses, bool) or not isinstance(n_poses, (int, np.integer)) or n_poses < 1:
        raise ArgumentError(f"{name}: {n_poses!r}; expected an integer >= 1")
    need = min_poses(robot)
    if n_poses < need:
        raise ArgumentError(
            f"{name}: {int(n_poses)} poses are too few: the {identifiable(robot)} identifiable "
            f"parameters of robot {robot.name!r} need at least {need} poses "
            f"({_READINGS[robot_hash(robot)]:g} independent readings each, "
            f"{kinds.for_robot(robot).description}); give at least that"
        )
    return int(n_poses)


# -- the scenario ---------------------------------------------------------------------------------


@dataclass
class ScenarioData:
    """What a scenario simulates: the truth, the identification data, the start, the bounds and
    the validation poses (exact readings, no noise), and the method's seed."""

    truth: np.ndarray
    data: Any
    x0: np.ndarray
    bounds: str
    validation: Any
    method_seed: int


@dataclass(frozen=True)
class Scenario:
    """One simulated calibration problem (see the module's doc for the seeding).

    Attributes
    ----------
    n_poses : int
        Measurement poses of the identification data.
    noise : Noise or the robot's kind's noise model
        Their measurement noise (an :class:`iwr.Noise` is converted by the kind,
        :meth:`iwr.kinds.MeasurementKind.experiment_noise`).
    draw, seed, base_seed : int
        The error draw (the actual robot), the seed of the data, validation poses and method,
        and the root of every stream.
    validation_poses : int
        Fresh, noise-free poses of the actual robot for the validation figures.
    kind : {"near", "bad"}
        See :data:`SCENARIOS`.
    """

    n_poses: int
    noise: Any
    draw: int = 0
    seed: int = 0
    base_seed: int = 0
    validation_poses: int = 50
    kind: str = "near"

    def truth(self, robot: Robot) -> np.ndarray:
        """The actual robot's error vector, uniform within the scenario's bounds, then the actual
        set-up's parameters (:meth:`iwr.kinds.MeasurementKind.draw_setup`; none for poses in
        {0})."""
        if self.kind not in SCENARIOS:
            raise ValueError(f"scenario: {self.kind!r}; expected one of {', '.join(SCENARIOS)}")
        rng = np.random.default_rng(stream_seed(self.base_seed, _ERRORS, self.draw))
        lower, upper = robot.default_bounds(_BOUNDS[self.kind])
        errors = lower + (upper - lower) * rng.random(robot.n_params)
        if robot.effects:  # issue 23: the effects' parameters, uniform within their bounds
            from ..effects import bounds as effect_bounds

            lo_e, hi_e = effect_bounds(robot.effects)
            errors = np.concatenate([errors, lo_e + (hi_e - lo_e) * rng.random(lo_e.size)])
        return np.concatenate([errors, kinds.for_robot(robot).draw_setup(robot, rng)])

    def build(self, robot: Robot) -> ScenarioData:
        """Simulate the scenario for ``robot`` (deterministic). ValueError when ``n_poses`` is
        below :func:`min_poses`."""
        check_n_poses(robot, self.n_poses)
        kind = kinds.for_robot(robot)
        truth = self.truth(robot)
        data, _ = kind.simulate(robot, self.n_poses,
                                seed=stream_seed(self.base_seed, _DATA, self.draw, self.seed),
                                x=truth, noise=kind.experiment_noise(robot, self.noise))
        bounds = _BOUNDS[self.kind]
        if self.kind == "near":
            # The kind's start: the nominal robot (with the set-up guessed from the data, for a
            # kind that identifies one).
            _, x0 = kind.problem(robot, data, bounds)
        else:
            # The opposite side of each parameter's range (the robot's and the set-up's about
            # the nominal one), near its bound.
            problem, _ = kind.problem(robot, data, bounds, x0=np.zeros(truth.size))
            lower, upper = problem.lower, problem.upper
            half, mid = 0.5 * (upper - lower), 0.5 * (upper + lower)
            x0 = mid + np.where(truth >= mid, -1.0, 1.0) * _BAD_START_FRACTION * half
        # Fresh poses of the actual robot, read without noise.
        validation, _ = kind.simulate(
            robot, self.validation_poses,
            seed=stream_seed(self.base_seed, _VALIDATION, self.draw, self.seed), x=truth)
        return ScenarioData(truth, data, x0, bounds, validation,
                            stream_seed(self.base_seed, _METHOD, self.draw, self.seed))


# -- the cell -------------------------------------------------------------------------------------


def canonical(value: Any) -> str:
    """``value`` as canonical JSON (sorted keys, no spaces): the text that keys are hashes of."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)


def robot_hash(robot: Robot) -> str:
    """A short hash of the robot's description, part of every cell's key."""
    return hashlib.sha256(canonical(robot.to_dict()).encode()).hexdigest()[:12]


@dataclass(frozen=True)
class Cell:
    """The settings of one identification: a scenario, a method spec, its options and budget;
    ``key`` identifies its result.

    ``noise`` is a noise level (:func:`noise_at`) or an :class:`iwr.Noise`; ``budget`` sets the
    method's option ``budget_option`` (``None``: the method's evaluation budget, see
    :func:`budget_option`); ``robot`` is the :func:`robot_hash` of the nominal robot.
    """

    method: str
    options: str  # canonical JSON of the method's options (runtime-only options left out)
    budget: int | None
    n_poses: int
    noise: Any
    draw: int
    seed: int
    base_seed: int
    validation_poses: int
    robot: str
    budget_option: str | None = None
    scenario: str = "near"

    @property
    def settings(self) -> dict[str, Any]:
        """What the result depends on: the text of the key."""
        extra: dict[str, Any] = {}
        if self.budget_option is not None:
            extra["budget_option"] = self.budget_option
        if self.scenario != "near":  # a near cell keeps the key it had before scenarios
            extra["scenario"] = self.scenario
        noise = self.noise
        if isinstance(noise, Noise):  # a level when it is one, so that equal cells share a key
            noise = noise.position if noise == noise_at(noise.position) else _noise_dict(noise)
        elif isinstance(noise, tuple):  # a kind's own model, e.g. (Noise, TrackerNoise)
            noise = [_noise_dict(part) for part in noise]
        return {
            **extra,
            "format": CELL_FORMAT,
            "method": self.method,
            "options": json.loads(self.options),
            "budget": self.budget,
            "n_poses": self.n_poses,
            "noise": noise,
            "noise_model": "tracker position sd (mm), realistic proportions",
            "draw": self.draw,
            "seed": self.seed,
            "base_seed": self.base_seed,
            "validation_poses": self.validation_poses,
            "robot": self.robot,
        }

    @property
    def key(self) -> str:
        return hashlib.sha256(canonical(self.settings).encode()).hexdigest()[:20]

    def noise_model(self) -> Any:
        """The cell's noise: :func:`noise_at` of a level, else the model given."""
        if isinstance(self.noise, (Noise, tuple)):
            return self.noise
        return noise_at(self.noise)

    def scenario_problem(self) -> Scenario:
        """The cell's scenario."""
        return Scenario(self.n_poses, self.noise_model(), self.draw, self.seed, self.base_seed,
                        self.validation_poses, self.scenario)

    def method_options(self) -> tuple[str, dict[str, Any]]:
        """The registered method and every option it runs with (budget included)."""
        method, fixed = split_method(self.method)
        options = {**fixed, **json.loads(self.options)}
        if method == "de":
            # DE alone: a Levenberg-Marquardt polish would spend evaluations that are not DE's.
            options.setdefault("polish", False)
        if self.budget is not None:
            options[self.budget_option or budget_option(method)] = self.budget
        return method, options

    def columns(self) -> dict[str, Any]:
        """The setting columns of the cell's row in the table."""
        row: dict[str, Any] = {c: getattr(self, c) for c in SETTING_COLUMNS if c != "key"}
        row["key"] = self.key
        if isinstance(self.noise, Noise):
            row["noise"] = self.noise.position
        elif isinstance(self.noise, tuple):  # no level: the model is in the settings
            row["noise"] = math.nan
        if self.budget is not None and self.budget_option is None:
            row["budget_option"] = budget_option(split_method(self.method)[0])
        return row


def _noise_dict(noise: Any) -> dict[str, float]:
    """A noise model's fields (an :class:`iwr.Noise` or another kind's dataclass)."""
    import dataclasses

    return {k: float(v) for k, v in dataclasses.asdict(noise).items()}


# The option that a budget sets: every method takes ``max_evaluations``; DE's budget axis in the
# study and the comparison is counted in generations, as the paper counts it.
BUDGET_OPTIONS = {"de": "generations"}


def budget_option(method: str) -> str:
    """The option of ``method`` that a budget sets (``generations`` for DE, else
    ``max_evaluations``, the budget every method takes)."""
    methods = registered_methods()
    if method not in methods:
        raise ValueError(f"method: {method!r}; available: {', '.join(sorted(methods))}")
    return BUDGET_OPTIONS.get(method, "max_evaluations")


def accepts(method: str, option: str) -> bool:
    """Whether the registered ``method`` takes ``option`` by name."""
    import inspect

    return option in inspect.signature(registered_methods()[method]).parameters


def unidentifiable_mask(robot: Robot, data: Any, x: np.ndarray) -> np.ndarray:
    """The parameters (the robot's, then its kind's set-up) that take part in an unidentifiable
    combination at ``x`` on ``data``'s poses (a nonzero coefficient in the null space of the
    column-scaled Jacobian): they cannot be judged one by one."""
    kind = kinds.of(data)
    problem, _ = kind.problem(robot, data, x0=x)
    # An orthonormal basis of the null space in the scaled metric: its rows measure each
    # parameter's part in it.
    _, basis = _scaled_null_basis(problem, np.asarray(x, dtype=float), kind)
    return np.linalg.norm(basis, axis=1) > 1e-6


def evaluate(
    cell: Cell,
    robot: Robot,
    runtime_options: Mapping[str, Any] | None = None,
    *,
    floor_rtol: float = FLOOR_RTOL,
    floor_atol: float = FLOOR_ATOL,
    details: bool = False,
) -> dict[str, Any]:
    """Simulate, identify and validate one cell; its row (a plain dict, :data:`COLUMNS` and
    ``x``; with ``details`` also ``truth``, ``x0``, ``unidentifiable`` and the convergence
    history ``history_nfev``, ``history_best``).

    Deterministic: the same cell gives the same row (``wall_time`` aside), in any process.
    ``runtime_options`` are options that change the speed only (``workers``): given to the method
    when it takes them. The figures on the validation poses (what each measures for the robot's
    kind: :attr:`iwr.kinds.MeasurementKind.experiment_text`): ``val_rms``, ``val_max`` (the readings
    predicted by the calibrated model against the exact ones, mm) and ``val_rms_nominal`` (the
    nominal model's, in the identification's start: the same "before" as :func:`iwr.calibrate`'s,
    :meth:`iwr.kinds.MeasurementKind.before`); the parameter error modulo the unidentifiable
    directions (:meth:`iwr.kinds.MeasurementKind.parameter_error`, :func:`iwr.parameter_error` for
    poses in {0}, with the validation poses as the yardstick of what is identifiable: the same
    generic set for every pose count, so that small calibration sets do not hide errors in
    directions they happen not to see) and raw; the tool pose error by forward kinematics against
    the truth (:meth:`iwr.kinds.MeasurementKind.tool_accuracy`).
    """
    row = cell.columns()
    try:
        kind = kinds.for_robot(robot)
        sc = cell.scenario_problem().build(robot)
        method, options = cell.method_options()
        for name, value in (runtime_options or {}).items():
            if accepts(method, name):
                options.setdefault(name, value)
        noise = kind.experiment_noise(robot, cell.noise_model())
        if method == "efficient" or (kind.chi2_fit_test and leg_sigma(noise) > 0):
            # The efficient estimator weighs every instrument by the scenario's noise model; the
            # other methods' success then includes the chi-square test of their fit (for the
            # kinds that have one).
            options.setdefault("noise", noise)
            if method != "efficient":  # eq. (10), not its noise-weighted form (iwr.identify)
                options.setdefault("weighted", False)
        from ..methods import identify

        start = time.perf_counter()
        result = identify(robot, sc.data, method, bounds=sc.bounds, x0=sc.x0,
                          seed=sc.method_seed, progress=False, **options)
        row["wall_time"] = time.perf_counter() - start
        x = np.asarray(result.x, dtype=float)
        # The unweighted cost (eq. (10)), for every method.
        cost = float(result.fun if result.cost_eq10 is None else result.cost_eq10)
        floor_problem, _ = kind.problem(robot, sc.data, sc.bounds, x0=sc.truth)
        floor = floor_problem.cost(sc.truth)
        n_obs = int(np.count_nonzero(kinds.observed(floor_problem)))
        threshold = (1 + floor_rtol) * floor + n_obs * floor_atol**2
        row.update(
            cost=cost,
            noise_floor=floor,
            at_floor=bool(cost <= threshold),
            rms_fit=math.sqrt(max(cost, 0.0) / n_obs),
            nfev=int(result.nfev),
            nit=int(result.nit),
            within_budget=_within_budget(cell, method, int(result.nfev)),
            success=bool(result.success),
        )
        row.update(_validate(kind, robot, x, sc))
        row.update(status="ok", message=str(result.message))
        row["x"] = x.tolist()
        if details:
            hist = dict(result.history)
            row.update(
                truth=sc.truth.tolist(),
                x0=sc.x0.tolist(),
                floor_threshold=threshold,
                unidentifiable=unidentifiable_mask(robot, sc.data, sc.truth).tolist(),
                history_nfev=np.asarray(hist.get("nfev", []), dtype=float).tolist(),
                history_best=np.asarray(hist.get("best", []), dtype=float).tolist(),
                # What history_best is: eq. (10)'s cost, or the method's own objective (the
                # efficient estimator's chi-square, a weighted cost: those results carry
                # cost_eq10 beside fun). The convergence plot puts only eq. (10) on its axis.
                history_objective="own" if result.cost_eq10 is not None else "eq10",
            )
    except RECORDED_ERRORS as exc:
        row.update(status="failed", message=f"{type(exc).__name__}: {exc}")
    row.setdefault("wall_time", math.nan)
    return row


_EVALUATION_OPTIONS = ("max_evaluations",)


def _within_budget(cell: Cell, method: str, nfev: int) -> bool | None:
    """Whether the evaluations stayed within the budget, when it counts evaluations."""
    if cell.budget is None:
        return None
    option = cell.budget_option or budget_option(method)
    return bool(nfev <= cell.budget) if option in _EVALUATION_OPTIONS else None


def leg_sigma(noise: Any) -> float:
    """The leg sensors' sigma of a noise model (an :class:`iwr.Noise`, or a pair whose first
    part is one): the efficient estimator closes every loop through the legs."""
    readings = noise[0] if isinstance(noise, tuple) else noise
    return float(getattr(readings, "legs", 0.0) or 0.0)


def _validate(kind: kinds.MeasurementKind, robot: Robot, x: np.ndarray,
              sc: ScenarioData) -> dict[str, Any]:
    """Figures of an identified vector ``x`` on the scenario's validation poses (the kind's
    yardsticks)."""
    val = sc.validation
    raw = x - sc.truth
    ang = kind.angle_parameters(robot)
    out: dict[str, Any] = {
        "raw_error_length": rms(raw[~ang]),
        "raw_error_angle": rms(raw[ang]),
        "max_raw_error_length": float(np.max(np.abs(raw[~ang]))),
        # nan where a figure cannot be computed (the notes say why)
        "param_error_length": math.nan,
        "param_error_angle": math.nan,
    }
    notes = []
    try:
        pe = kind.parameter_error(robot, val, x, sc.truth)
        out["param_error_length"] = float(pe.rms_length)
        out["param_error_angle"] = float(pe.rms_angle)
    except (*RECORDED_ERRORS, NotImplementedError) as exc:
        notes.append(f"parameter_error: {type(exc).__name__}: {exc}")
    # "Before" is the nominal robot in the identification's start, as iwr.calibrate's: a
    # set-up guessed on the validation poses themselves would flatter it. Where the kind has no
    # start on these data (the 'bad' scenario's nominal robot, hundreds of mm from the truth,
    # has no registration guess), there is no "before": its figures nan, the calibrated ones
    # computed (the cell failed on it, whatever the identification did).
    try:
        start, nominal = kind.start(robot, sc.data), True
    except RECORDED_ERRORS as exc:
        start, nominal = None, False
        notes.append(f"nominal: no start of the kind's own: {type(exc).__name__}: {exc}")
    figures = kind.validate(robot, val, x, sc.truth, start, nominal=nominal)
    if figures.get("notes"):
        notes.append(figures.pop("notes"))
    out.update(figures)
    if notes:
        out["notes"] = "; ".join(notes)
    return out
