"""Measurement kinds: what one instrument's data are, and what every calibration step needs of
them, behind one protocol (:class:`MeasurementKind`).

A kind is a type, not a branch. The platform pose measured in the world frame {0} (the paper's
data, :class:`iwr.kinds.pose.PoseKind`), reflector points measured by a laser tracker in its
own frame {T} and a tracker probe's pose in {T} (:mod:`iwr.tracker.kind`) are implementations of
:class:`MeasurementKind`. :func:`of` finds the kind of a data set (its ``kind`` attribute names
it), :func:`for_robot` the kind a robot's description measures; the public functions
(:func:`iwr.simulate`, :func:`iwr.identify`, :func:`iwr.accuracy`, :func:`iwr.identifiability`,
:func:`iwr.uncertainty`, the efficient estimator, :func:`iwr.plan_poses`) call the kind's
methods and never test the type of their data. A new instrument is a new class in its own
module and one :func:`register` line (``register("name", "package.module:Class")``; the module
is imported on first use, so that it may import the modules of the public functions, where the
built-in kinds' implementations still live: docs/kinds.md).

What a kind says of its data: the frame they are given in and whether they fix the robot's world
frame (``frame``, ``determines_world_frame``), the setup parameters identified beside the
robot's (``setup_parameter_names``), its files (``read``), simulation (``simulate``), subsets
(``subset``), the fingerprint that ``iwr-calibrate``'s problem file records (``fingerprint``),
its problem and starting point (``problem``), and the per-kind part of each algorithm.
:func:`split` holds validation poses out by one rule for every kind.
"""

from __future__ import annotations

import abc
import importlib
import numbers
import os
import threading
from typing import Any, ClassVar

import numpy as np

__all__ = [
    "MeasurementKind",
    "available",
    "for_robot",
    "of",
    "register",
    "split",
    "split_rows",
]


class MeasurementKind(abc.ABC):
    """The protocol every kind of measurement implements (one instance per kind).

    ``x`` of every call holds the robot's ``n_params`` error parameters, then the kind's setup
    parameters (:meth:`setup_parameter_names`; none for poses in {0})."""

    #: The kind's name as data, problem files and reports say it (``"pose"``, ``"points"``, ...).
    name: ClassVar[str]
    #: What one pose's reading is, for messages and reports.
    description: ClassVar[str]
    #: The frame the data are given in: ``"{0}"`` (the robot's world frame), ``"{T}"`` (the
    #: tracker's).
    frame: ClassVar[str]
    #: Whether the data fix the robot's world frame {0}. Point data do not (the registration and
    #: a rigid motion of {5} are in the null space), so what is said in {0} after such a
    #: calibration is a gauge choice (docs/tracker.md).
    determines_world_frame: ClassVar[bool]
    #: Whether :func:`iwr.estimation.fit_check` can test an eq. (10)-type solution's cost with a
    #: noise model (else only the efficient estimator tests the fit of these data).
    chi2_fit_test: ClassVar[bool] = False
    #: Whether :func:`for_robot` chooses this kind only when no other applies (the pose in {0}:
    #: a robot describes no instrument for it).
    fallback: ClassVar[bool] = False

    # -- the data -----------------------------------------------------------------------------

    @abc.abstractmethod
    def owns(self, data: Any) -> bool:
        """Whether ``data`` (whose ``kind`` attribute names this kind) are of its data type."""

    @abc.abstractmethod
    def applies_to(self, robot: Any) -> bool:
        """Whether ``robot``'s description measures this kind (its setup, if any, says so)."""

    @abc.abstractmethod
    def setup_parameter_names(self, robot: Any) -> list[str]:
        """The setup parameters identified beside the robot's (registration, offsets, ...)."""

    def n_params(self, robot: Any) -> int:
        """Length of a parameter vector on these data: the robot's, then the setup's."""
        return int(robot.n_params) + len(self.setup_parameter_names(robot))

    def check(self, robot: Any, data: Any) -> None:
        """ValueError unless ``data`` can be calibrated with ``robot`` (its setup measures this
        kind)."""
        if not self.applies_to(robot):
            measured = for_robot(robot)
            raise ValueError(
                f"measurements: {self.description} in {self.frame} ({self.name} data), but robot "
                f"{getattr(robot, 'name', '?')!r} measures {measured.description} in "
                f"{measured.frame} ({measured.name} data): " + self._setup_hint())

    def _setup_hint(self) -> str:
        return "describe the instrument in the robot's TOML file (docs/data.md, docs/tracker.md)"

    def subset(self, data: Any, rows: Any) -> Any:
        """The poses at ``rows`` (indices or a boolean mask), lines and source kept."""
        return data.subset(rows)

    @abc.abstractmethod
    def fingerprint(self, robot: Any, data: Any) -> str:
        """16 hex digits: the data's fingerprint as the problem file records it (the C++
        ``ProblemData::data_fingerprint``), computed without building the problem."""

    @abc.abstractmethod
    def read(self, path: str | os.PathLike[str], robot: Any, **options: Any) -> Any:
        """Read a data file of this kind for ``robot``, with every check (errors name the file
        and line); TypeError naming an option the kind's files do not take."""

    @abc.abstractmethod
    def simulate(self, robot: Any, n_poses: int, *, seed: int | None, x: Any = None,
                 noise: Any = None) -> tuple[Any, np.ndarray]:
        """``(data, x_true)``: :func:`iwr.simulate` for this kind."""

    # -- the problem and the algorithms' per-kind part ---------------------------------------

    @abc.abstractmethod
    def problem(self, robot: Any, data: Any, bounds: Any = None, x0: Any = None
                ) -> tuple[Any, np.ndarray]:
        """The least-squares problem of these data (``cost``, ``residuals``, ``jacobian``,
        ``cost_batch``, ``lower``/``upper``, ``parameter_names``) and its default start."""

    @abc.abstractmethod
    def identify(self, robot: Any, data: Any, method: str, **options: Any) -> Any:
        """:func:`iwr.identify` for this kind (``method`` already checked)."""

    @abc.abstractmethod
    def accuracy(self, robot: Any, data: Any, x: Any, **options: Any) -> Any:
        """:func:`iwr.accuracy`: what accuracy means for this kind."""

    @abc.abstractmethod
    def identifiability(self, robot: Any, data: Any, x: Any = None, **options: Any) -> Any:
        """:func:`iwr.identifiability` for this kind."""

    @abc.abstractmethod
    def uncertainty(self, robot: Any, data: Any, x: Any, noise: Any, **options: Any) -> Any:
        """:func:`iwr.uncertainty` for this kind."""

    @abc.abstractmethod
    def estimator(self, robot: Any, data: Any, noise: Any, **options: Any) -> Any:
        """The efficient estimator's model of these data (:func:`iwr.estimation.efficient`):
        the readings, their noise and the nuisance unknowns per pose."""

    @abc.abstractmethod
    def plausibility(self, robot: Any, data: Any, bounds: Any, plausible: float
                     ) -> tuple[list[str], np.ndarray, np.ndarray, Any]:
        """For :func:`iwr.estimation.fit_check`: the parameter names, each parameter's plausible
        size and centre, and the readings model ``x -> (residuals, Jacobian)`` whose null
        directions the size test ignores."""

    def misclosures(self, robot: Any, data: Any, x: Any, noise: Any = None) -> Any:
        """For :mod:`iwr.gross_errors`: the linearised readings model at ``x``
        (:class:`iwr.misclosures.Misclosures`). This default: the residuals of :meth:`problem`
        per pose, their Jacobian, each residual its own reading with unit weight; no noise model
        (a kind that has one overrides this, with the derivatives in every reading)."""
        from ..misclosures import Misclosures

        if noise is not None:
            raise ValueError(f"noise: the gross-error test of {self.name} data has no noise "
                             "model; give noise=None (the noise is then estimated from the "
                             "residuals)")
        problem, _ = self.problem(robot, data)
        n = len(data)
        r = np.asarray(problem.residuals(x), dtype=float).reshape(n, -1)
        a = np.asarray(problem.jacobian(x), dtype=float).reshape(n, r.shape[1], -1)
        names = [f"residual{j + 1}" for j in range(r.shape[1])]
        b = np.broadcast_to(-np.eye(r.shape[1]), (n, r.shape[1], r.shape[1])).copy()
        return Misclosures(r, a, b, names, names)

    @abc.abstractmethod
    def candidate_poses(self, robot: Any, data: Any) -> Any:
        """For :func:`iwr.plan_poses`: the candidates as :class:`iwr.Measurements` with their
        platform poses in {0} (measured, or the nominal robot's forward kinematics)."""

    @abc.abstractmethod
    def design(self, robot: Any, candidates: Any, x: Any, report: Any
               ) -> tuple[Any, np.ndarray, np.ndarray, int, str]:
        """For :func:`iwr.plan_poses`: the problem of the candidate poses (measured by the nominal
        instrument), ``x``, the indices of the base parameters (``report``'s, or computed), the
        readings per pose and what they are called."""

    @abc.abstractmethod
    def measure(self, robot: Any, x: np.ndarray, q: np.ndarray, poses: np.ndarray, noise: Any,
                rng: np.random.Generator) -> Any:
        """For :func:`iwr.planning.measure`: this kind's readings of the actual robot ``x`` at
        joint readings ``q`` and platform poses ``poses`` in {0}, with ``noise``."""

    def __repr__(self) -> str:
        return f"<measurement kind {self.name!r}: {self.description} in {self.frame}>"


def data_fingerprint(kind: str, robot: Any, data: Any, *, poses: Any = None, weights: Any = None,
                     probe_poses: Any = None, points: Any = None) -> str:
    """The problem file's data fingerprint of these arrays (C++ ``ProblemData::data_fingerprint``
    through ``iwr._core._data_fingerprint``), for the kinds' :meth:`MeasurementKind.fingerprint`."""
    from .. import _core

    empty = np.zeros((0, 0))

    def arr(a: Any) -> np.ndarray:
        return empty if a is None else np.ascontiguousarray(a, dtype=float)

    return str(_core._data_fingerprint(
        kind, str(robot.joint_types), data.joint_types, arr(data.q), arr(data.legs), arr(poses),
        None if weights is None else arr(weights), arr(probe_poses), arr(points)))


# -- the registry -----------------------------------------------------------------------------

_SPECS: dict[str, str | MeasurementKind] = {}
_LOADED: dict[str, MeasurementKind] = {}
_LOCK = threading.RLock()  # one instance per kind, whichever thread asks first


def register(name: str, kind: str | MeasurementKind) -> None:
    """Make kind ``name`` known: ``kind`` is an instance, or ``"package.module:Class"`` imported
    (and instantiated) on first use. Data of the kind carry ``kind == name``."""
    if not isinstance(name, str) or not name.isidentifier():
        raise ValueError(f"name: {name!r}; expected an identifier")
    if name in _SPECS:
        raise ValueError(f"kind: {name!r} is already registered")
    if not isinstance(kind, (str, MeasurementKind)):
        raise TypeError(f"kind: expected a MeasurementKind or 'module:Class', got "
                        f"{type(kind).__name__}")
    if isinstance(kind, MeasurementKind) and kind.name != name:
        raise ValueError(f"kind: {type(kind).__name__} is named {kind.name!r}, not {name!r}")
    with _LOCK:
        if name in _SPECS:
            raise ValueError(f"kind: {name!r} is already registered")
        _SPECS[name] = kind


register("pose", "iwr.kinds.pose:PoseKind")
register("points", "iwr.tracker.kind:PointsKind")
register("probe", "iwr.tracker.kind:ProbeKind")


def _load(name: str) -> MeasurementKind:
    kind = _LOADED.get(name)
    if kind is not None:
        return kind
    with _LOCK:
        if name not in _LOADED:
            spec = _SPECS[name]
            if isinstance(spec, str):
                module, _, cls = spec.partition(":")
                spec = getattr(importlib.import_module(module), cls)()
            if not isinstance(spec, MeasurementKind) or spec.name != name:
                raise TypeError(f"kind {name!r}: {_SPECS[name]!r} is not a MeasurementKind "
                                f"named {name!r}")
            _LOADED[name] = spec
        return _LOADED[name]


def available() -> list[str]:
    """The registered kinds' names."""
    return list(_SPECS)


def of(data: Any) -> MeasurementKind:
    """The kind of ``data`` (its ``kind`` attribute); TypeError naming the type otherwise."""
    name = getattr(data, "kind", None)
    kind = _load(name) if isinstance(name, str) and name in _SPECS else None
    if kind is None or not kind.owns(data):
        raise TypeError(f"measurements: expected an iwr.Measurements or another registered kind "
                        f"of data ({', '.join(list(_SPECS))}), got {type(data).__name__}"
                        + (f" of unregistered kind {name!r}" if isinstance(name, str)
                           and kind is None else ""))
    return kind


def for_robot(robot: Any) -> MeasurementKind:
    """The kind of data ``robot``'s description measures (its ``[tracker]`` table, if any); a
    fallback kind (the pose in {0}) only when no other applies."""
    loaded = [_load(name) for name in list(_SPECS)]
    for kind in sorted(loaded, key=lambda k: k.fallback):
        if kind.applies_to(robot):
            return kind
    raise ValueError(f"robot {getattr(robot, 'name', robot)!r}: no registered kind of data "
                     "applies to it")


def split(data: Any, fraction: float, seed: int) -> tuple[Any, Any]:
    """``(identification, validation)``: ``round(fraction * N)`` poses (at least one) drawn by
    ``seed`` for validation, each part in file order (:func:`split_rows`); the same rule for
    every kind. ValueError when no pose would be left to identify from."""
    kind = of(data)
    ident, val = split_rows(len(data), fraction, seed)
    return kind.subset(data, ident), kind.subset(data, val)


def split_rows(n: int, fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The rows of :func:`split`: ``(identification, validation)`` indices of ``n`` poses."""
    if not (isinstance(fraction, numbers.Real) and not isinstance(fraction, bool)
            and 0 < float(fraction) < 1):
        raise ValueError(f"fraction: {fraction!r}; expected 0 < fraction < 1")
    n_val = max(1, int(round(float(fraction) * n)))
    if n - n_val < 1:
        raise ValueError(f"fraction {fraction}: leaves no pose for identification out of {n}")
    order = np.random.default_rng(seed).permutation(n)
    return np.sort(order[n_val:]), np.sort(order[:n_val])
