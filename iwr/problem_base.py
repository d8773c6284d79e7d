"""What every kind's least-squares problem is (:class:`LeastSquaresProblem`, the interface the
identification methods and the fit test rely on) and the plumbing they share
(:class:`ProblemBase`): input checks, bounds, the reference of the forward kinematics, parameter
names and sizes, the parameter vector's check, batch costs, failed poses.

:class:`iwr.Problem` (the platform pose in {0}, eq. (10)), :class:`iwr.tracker.TrackerProblem`
(points or a probe in the tracker frame) and :class:`iwr.ballbar.BallbarProblem` (a ballbar's
distances) subclass :class:`ProblemBase`; a new instrument's problem writes its residual model
(:meth:`ProblemBase.residuals_and_jacobian`, :attr:`ProblemBase.n_residuals`) and says what its
data and set-up are (docs/kinds.md, "Adding a kind").
"""

from __future__ import annotations

import abc
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from . import _core
from ._hooks import hook
from .effects import refuse as refuse_effects
from .robot import Robot

__all__ = ["FAILED_RESIDUAL", "LeastSquaresProblem", "ProblemBase", "bounds_kind", "bounds_record",
           "check_joint_types", "recorded_bounds", "reference_error"]

#: The residual (mm, times its weight) of each reading of a pose whose forward kinematics fails
#: at the parameters evaluated: huge but finite, so that every method sees a bad cost.
FAILED_RESIDUAL = 1e3


@runtime_checkable
class LeastSquaresProblem(Protocol):
    """The problem every identification method runs on (through
    :class:`iwr.methods.reduced.ReducedProblem`), the fit test (:func:`iwr.fit_test.fit_check`),
    the null-space analysis and the calibration job take, whatever the kind of data.

    ``x`` of every call holds the robot's ``n_params`` error parameters, then the kind's setup
    parameters (none for the pose in {0})."""

    #: The nominal robot (:class:`iwr.Robot`).
    robot: Any
    #: The data (a registered kind's type, :mod:`iwr.kinds`).
    measurements: Any
    #: Search bounds of every parameter, (n_params,) each, finite, ``lower < upper``.
    lower: np.ndarray
    upper: np.ndarray

    @property
    def n_params(self) -> int:
        """Length of ``x``: the robot's parameters, then the setup's."""

    @property
    def n_poses(self) -> int:
        """The poses of the data."""

    @property
    def n_residuals(self) -> int:
        """Length of :meth:`residuals` (pose-major)."""

    @property
    def n_observations(self) -> int:
        """The residuals that carry data (a tracker's unseen points are zeros, not data)."""

    @property
    def parameter_names(self) -> list[str]:
        """One name per entry of ``x``."""

    def cost(self, x: Any) -> float:
        """The sum of squared :meth:`residuals` at ``x``: what every method minimises."""

    def residuals(self, x: Any) -> np.ndarray:
        """Predicted minus measured readings (weighted, when the problem is), (n_residuals,)."""

    def jacobian(self, x: Any) -> np.ndarray:
        """The exact derivative of :meth:`residuals`, (n_residuals, n_params)."""

    def residuals_and_jacobian(self, x: Any) -> tuple[np.ndarray, np.ndarray]:
        """Both at once."""

    def cost_batch(self, X: Any, workers: int | None = None) -> np.ndarray:
        """The costs of the rows of ``X`` (M, n_params); the answer does not depend on
        ``workers`` (threads; None: all cores)."""

    def engine_objective(self) -> Any:
        """The C++ objective (an ``iwr._core`` objective: ``Objective``, ``TrackerObjective``,
        ...) whose costs :meth:`cost_batch` returns, or None for a problem without one. DE runs
        the engine on it (:func:`iwr.methods.de.de_method`), as ``iwr-engine`` does on the
        problem's file."""

    def failures(self, x: Any) -> list[tuple[int, str]]:
        """The poses whose model cannot be evaluated at ``x``: ``[(pose, message)]``; a result
        with failures is never a success."""

    def check(self, x: Any) -> None:
        """Raise naming the first pose of :meth:`failures`, if any."""


def check_joint_types(robot: Any, measurements: Any) -> None:
    """ValueError unless the data's joints are the robot's: as many, of the same types."""
    if measurements.n_joints != robot.n_joints:
        raise ValueError(
            f"measurements: {measurements.n_joints} joint readings per pose, but robot "
            f"{robot.name!r} has {robot.n_joints} joints ({robot.joint_types!r})")
    jt = measurements.joint_types
    if jt is not None and jt != robot.joint_types:
        raise ValueError(
            f"measurements: joint types {jt!r} (from the units of the q columns) do not match "
            f"robot {robot.name!r}, {robot.joint_types!r}")


def reference_error(exc: Exception, measurements: Any) -> Exception:
    """The :class:`iwr.ForwardKinematicsError` raised when the forward kinematics of a pose
    fails at a problem's reference parameters (made once, from the home pose), naming the data
    row (``measurements.where``)."""
    k = getattr(exc, "pose", None)
    where = measurements.where(k) if isinstance(k, int) else "a pose"
    err = _core.ForwardKinematicsError(
        f"{where}: the leg readings have no forward kinematics for the robot at the reference "
        f"parameters ({exc})")
    err.pose = k
    return err


def bounds_kind(problem: Any) -> str:
    """"default" or "paper" when ``problem``'s bounds (any kind's problem: ``robot``, ``lower``,
    ``upper``, an optional ``setup``) are the robot's (with its effects' own and, for a set-up,
    the set-up's widths about any centre: a tracker's are centred on a registration guess), else
    "custom"."""
    robot, lower, upper = problem.robot, np.asarray(problem.lower), np.asarray(problem.upper)
    nr = robot.n_params
    setup = getattr(problem, "setup", None)
    if setup is not None:
        lo_s, hi_s = setup.default_bounds()
        ns = setup.n_params
        if not np.allclose(upper[-ns:] - lower[-ns:], hi_s - lo_s, rtol=1e-12, atol=0):
            return "custom"
    if robot.effects:  # the effects' own bounds between the robot's and the setup's (if any)
        from .effects import bounds as effect_bounds

        lo_e, hi_e = effect_bounds(robot.effects)
        if not (np.array_equal(lo_e, lower[nr: nr + lo_e.size])
                and np.array_equal(hi_e, upper[nr: nr + hi_e.size])):
            return "custom"
    for kind in ("default", "paper"):
        lo, hi = robot.default_bounds(kind)
        if np.array_equal(lo, lower[:nr]) and np.array_equal(hi, upper[:nr]):
            return kind
    return "custom"


def bounds_record(problem: Any) -> dict[str, Any]:
    """What a result's settings say of the bounds it was identified within, so that a polish
    or a re-run uses them (:func:`iwr.calibration.polish`): ``bounds`` ("default", "paper" or
    "custom") and, for custom ones, ``lower`` and ``upper`` (every parameter's)."""
    kind = bounds_kind(problem)
    if kind != "custom":
        return {"bounds": kind}
    return {"bounds": kind, "lower": [float(v) for v in problem.lower],
            "upper": [float(v) for v in problem.upper]}


def recorded_bounds(settings: Any, n_params: int) -> dict[str, Any]:
    """The ``bounds`` option of :func:`iwr.identify` that a result's settings record
    (:func:`bounds_record`, and an ``iwr-calibrate`` run's): ``{"bounds": "default" or
    "paper"}``, the pair ``(lower, upper)`` of ``n_params`` values, or ``{}`` (none recorded:
    the default)."""
    bounds, lower, upper = settings.get("bounds"), settings.get("lower"), settings.get("upper")
    if isinstance(bounds, str) and bounds in ("default", "paper"):
        return {"bounds": bounds}
    if lower is not None and upper is not None and np.size(lower) == n_params:
        return {"bounds": (np.asarray(lower, dtype=float), np.asarray(upper, dtype=float))}
    return {}


class ProblemBase(abc.ABC):
    """The plumbing of a kind's least-squares problem (:class:`LeastSquaresProblem`).

    A subclass names its data type (:attr:`data_type`, :attr:`data_name`) and, when it
    identifies setup parameters beside the robot's, its set-up type (:attr:`setup_type`: an
    object with ``n_params``, ``parameter_names``, ``default_bounds()`` and
    ``angle_parameters``); in its ``__init__`` it calls :meth:`_accept`, :meth:`_set_bounds`
    and (with forward kinematics from a reference) :meth:`_set_reference`; it writes its
    residual model: :attr:`n_residuals`, :meth:`residuals_and_jacobian`, and, where they are
    cheaper than that, :meth:`residuals`, :meth:`cost`, :meth:`failures`, and the C++
    objective its costs are evaluated on (:meth:`engine_objective`: DE runs on it).
    """

    #: The data type the problem takes, and how messages name it.
    data_type: ClassVar[type]
    data_name: ClassVar[str]
    #: The set-up type (None: no setup parameters, the pose in {0}), and how messages name it.
    setup_type: ClassVar[type | None] = None
    setup_name: ClassVar[str] = ""
    #: Whose parameters follow the robot's in ``x``, for messages (``"setup's"``).
    setup_owner: ClassVar[str] = "setup's"
    #: What the problem is, for the refusal of a robot with effects (issue 23).
    effects_what: ClassVar[str]
    #: Whether the problem models a robot's effects (then it says their parameters, bounds and
    #: residual model itself: :class:`iwr.Problem`); else a robot with effects is refused.
    takes_effects: ClassVar[bool] = False
    #: The residual of a reading of a pose whose forward kinematics fails (:meth:`failures`).
    failed_residual: ClassVar[float] = FAILED_RESIDUAL
    #: What a problem file of this problem holds, in words (:meth:`load`'s refusal of another).
    file_holds: ClassVar[str] = "data"

    robot: Robot
    measurements: Any
    setup: Any = None
    lower: np.ndarray
    upper: np.ndarray
    #: Where forward kinematics is solved once per pose (each evaluation starts there).
    reference: np.ndarray
    #: A per-pose whitening of the residuals, or None (unweighted).
    whitening: np.ndarray | None = None

    # -- construction -----------------------------------------------------------------------
    def _accept(self, robot: Any, measurements: Any, setup: Any = None) -> None:
        """Check and keep the robot, the set-up and the data: their types, no effects on the
        robot, the data's joints the robot's."""
        if not isinstance(robot, Robot):
            raise TypeError(f"robot: expected an iwr.Robot, got {type(robot).__name__}")
        if not self.takes_effects:  # issue 23: the kinds that do not model them yet
            refuse_effects(robot, self.effects_what)
        if self.setup_type is not None and not isinstance(setup, self.setup_type):
            raise TypeError(f"setup: expected an {self.setup_name}, got {type(setup).__name__}")
        if not isinstance(measurements, self.data_type):
            raise TypeError(f"measurements: expected an {self.data_name}, got "
                            f"{type(measurements).__name__}")
        check_joint_types(robot, measurements)
        self.robot, self.setup, self.measurements = robot, setup, measurements

    def _set_bounds(self, bounds: Any, setup_bounds: Any = None) -> None:
        """``lower``, ``upper`` from ``bounds``: None, ``"default"`` or ``"paper"`` (the robot's,
        :meth:`iwr.Robot.default_bounds`, then ``setup_bounds``, default the set-up's
        ``default_bounds()``) or a pair (lower, upper) of every parameter (scalars broadcast);
        finite with lower < upper, else a ValueError naming the parameter."""
        n = self.n_params
        if bounds is None or isinstance(bounds, str):
            lo_r, hi_r = self.robot.default_bounds(bounds or "default")
            if self.setup is None:
                lower, upper = lo_r, hi_r
            else:
                lo_s, hi_s = self.setup.default_bounds() if setup_bounds is None else setup_bounds
                lower, upper = np.concatenate([lo_r, lo_s]), np.concatenate([hi_r, hi_s])
        else:
            try:
                lower, upper = (np.broadcast_to(np.array(b, dtype=float), (n,)).copy()
                                for b in bounds)
            except (TypeError, ValueError):
                raise ValueError(f"bounds: expected None, 'default', 'paper' or a pair (lower, "
                                 f"upper) of {n} values") from None
        names = self.parameter_names
        for i, (lo, hi) in enumerate(zip(lower, upper, strict=True)):
            if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
                raise ValueError(f"bounds: parameter {i} ({names[i]}) has lower {lo}, upper "
                                 f"{hi}; bounds must be finite with lower < upper")
        self.lower, self.upper = lower, upper

    def _set_reference(self, reference: Any) -> np.ndarray:
        """``reference``, the robot's parameters at which forward kinematics is solved once per
        pose (default zeros), checked and kept; a contiguous copy for the kernel."""
        nr = self.robot.n_params
        ref = np.zeros(nr) if reference is None else np.asarray(reference, float)
        if ref.shape != (nr,):
            raise ValueError(f"reference: shape {ref.shape}; expected ({nr},)")
        self.reference = ref
        return np.ascontiguousarray(ref)

    # -- sizes and names ----------------------------------------------------------------------
    @property
    def n_robot_params(self) -> int:
        """The robot's ``4 n + 42``; the setup's parameters follow."""
        return int(self.robot.n_params)

    @property
    def n_setup_params(self) -> int:
        return 0 if self.setup is None else int(self.setup.n_params)

    @property
    def n_params(self) -> int:
        return self.n_robot_params + self.n_setup_params

    @property
    def n_poses(self) -> int:
        return len(self.measurements)

    @property
    @abc.abstractmethod
    def n_residuals(self) -> int:
        """Length of :meth:`residuals`."""

    @property
    def n_observations(self) -> int:
        """The residuals that carry data: all of them unless a subclass says otherwise."""
        return self.n_residuals

    @property
    def parameter_names(self) -> list[str]:
        if self.setup is None:
            return self.robot.parameter_names
        return self.robot.parameter_names + self.setup.parameter_names

    @property
    def angle_parameters(self) -> np.ndarray:
        """Which parameters are angles (rad)."""
        robot = np.asarray(self.robot.angle_parameters, dtype=bool)
        if self.setup is None:
            return robot
        return np.concatenate([robot, np.asarray(self.setup.angle_parameters, dtype=bool)])

    @property
    def weighted(self) -> bool:
        """Whether the residuals are whitened by the instruments' noise."""
        return self.whitening is not None

    def split(self, x: Any) -> tuple[np.ndarray, np.ndarray]:
        """``(x_robot, x_setup)``."""
        arr = self._x(x)
        return arr[: self.n_robot_params], arr[self.n_robot_params:]

    def _x(self, x: Any) -> np.ndarray:
        arr = np.ascontiguousarray(x, dtype=float)
        if arr.shape != (self.n_params,):
            more = ("" if self.setup is None else f": the robot's {self.n_robot_params} then "
                    f"the {self.setup_owner} {self.n_setup_params}")
            raise ValueError(f"x: shape {arr.shape}; expected ({self.n_params},){more}")
        return arr

    # -- the objective ------------------------------------------------------------------------
    @abc.abstractmethod
    def residuals_and_jacobian(self, x: Any) -> tuple[np.ndarray, np.ndarray]:
        """The residuals at ``x`` and their exact Jacobian (n_residuals, n_params)."""

    def residuals(self, x: Any) -> np.ndarray:
        return self.residuals_and_jacobian(x)[0]

    def jacobian(self, x: Any) -> np.ndarray:
        return self.residuals_and_jacobian(x)[1]

    def cost(self, x: Any) -> float:
        r = self.residuals(x)
        return float(r @ r)

    def engine_objective(self) -> Any:
        """The C++ objective whose costs :meth:`cost` and :meth:`cost_batch` are (an
        ``iwr._core`` objective: ``Objective``, ``TrackerObjective``, ``BallbarObjective``, ...,
        weighted as the problem is), or None: a problem without one (then :meth:`cost_batch`
        calls :meth:`cost` row by row, and DE calls :meth:`cost_batch` once per generation).
        DE runs the engine on it with no Python in the loop (:func:`iwr.methods.de.de_method`),
        as ``iwr-engine`` runs the one it builds from the problem's file. Default: None."""
        return None

    def cost_batch(self, X: Any, workers: int | None = None) -> np.ndarray:
        """Costs of the rows of ``X`` (M, n_params) across ``workers`` threads (``None``: all
        cores) on the problem's C++ objective (:meth:`engine_objective`; without one,
        :meth:`cost` row by row); the result does not depend on the number of threads."""
        arr = np.ascontiguousarray(X, dtype=float)
        if arr.ndim != 2 or arr.shape[1] != self.n_params:
            raise ValueError(f"X: shape {arr.shape}; expected (M, {self.n_params})")
        if workers is not None and workers < 1:
            raise ValueError(f"workers: {workers}; expected a positive number of threads or None")
        objective = self.engine_objective()
        if objective is None:
            return np.array([self.cost(row) for row in arr])
        return objective.cost_batch(arr, 0 if workers is None else int(workers))

    # -- the problem file (iwr-engine's input) -------------------------------------------------
    def save(self, path: Any, *, sources: dict[str, Any] | None = None, x0: Any = None,
             active: Any = None) -> None:
        """Write the problem file that ``iwr-engine`` runs from, atomically (as
        :meth:`iwr.Problem.save`; ``docs/iwr-calibrate.md`` gives the layout): the robot, the
        kind's setup and data, the reference, the noise weighting if any, the bounds, and the
        search's starting point ``x0`` (default zeros: where the inactive parameters stay) and
        ``active`` set (default all). :meth:`load` reads it back."""
        hook("save_problem")(self, path, sources, x0=x0, active=active)  # a layer up

    @classmethod
    def load(cls, path: Any) -> Any:
        """Read a problem file written by :meth:`save` (``iwr._core.FormatError``, a ValueError
        naming the file and field, if it is malformed, truncated, of another version, or holds
        another kind of data than this class's)."""
        problem = hook("load_problem")(path)  # iwr.problem_file, a layer up
        if not isinstance(problem, cls):
            raise _core.FormatError(f"{path}: holds {problem.file_holds}, not {cls.file_holds}; "
                                    "read it with iwr.Problem.load")
        return problem

    # -- diagnostics --------------------------------------------------------------------------
    def failures(self, x: Any) -> list[tuple[int, str]]:
        """Poses whose model cannot be evaluated at ``x``: ``[(pose index, message)]``; default
        none."""
        self._x(x)
        return []

    def check(self, x: Any) -> None:
        """Raise :class:`iwr.ForwardKinematicsError` naming the first pose (and its line in the
        data file) whose forward kinematics fails at ``x``, if any: a result whose cost holds a
        penalty is not a calibration."""
        bad = self.failures(x)
        if bad:
            k, msg = bad[0]
            err = _core.ForwardKinematicsError(
                f"{self.measurements.where(k)}: {msg} ({len(bad)} of {self.n_poses} poses fail "
                "at this parameter vector; their residuals are the penalty "
                f"{self.failed_residual:g} mm)")
            err.pose = k
            raise err
