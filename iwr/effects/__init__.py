"""Non-geometric effects: what the robot's legs do beyond their geometry (issue 23), behind one
protocol (:class:`Effect`), parallel to the measurement kinds (:mod:`iwr.kinds`).

An effect changes the true length of each leg at each pose by an amount its own parameters
describe: the axial compliance of the legs under the load they carry
(:class:`iwr.effects.builtin.LegCompliance`, ``"compliance"``) and the thermal expansion of
the legs with their temperature (:class:`iwr.effects.builtin.LegThermal`, ``"thermal"``);
or it changes the true values of the carriage's joints (:attr:`Effect.changes`
``{"joints"}``, :meth:`Effect.joint_change`): the compliance of the carriage's joints under the
gravity load of what they carry (:class:`iwr.effects.carriage.CarriageCompliance`,
``"carriage_compliance"``) and the thermal expansion of its prismatic axes with the machine's
temperature (:class:`iwr.effects.carriage_thermal.CarriageThermal`,
``"carriage_thermal"``). The joint changes come first: the legs, their forces and their effects
are those of the carriage at its true joint values. The true leg length between the
joint centres is

    D = s + l0 + sum over the effects of their change  (e.g. c f + alpha D (T - T_ref)),

with ``s`` the leg sensor reading and ``l0`` the leg offset of the geometric model. A robot
carries its effects (:attr:`iwr.Robot.effects`, the ``[effects]`` table of the robot TOML, one
sub-table per effect, named after it); with none on, nothing changes. Each effect's parameters
are appended to the robot's geometric ones, in the order the effects are listed: ``x`` of a
problem with effects has ``robot.n_params`` geometric errors, then :func:`parameter_names`.
Like the geometric errors, they are corrections to the values the robot file holds
(:meth:`Effect.values`), so that a calibrated robot file holds the identified values.

A new effect is a class implementing :class:`Effect` in its own module and one
:func:`register` line (:class:`iwr._registry.Registry`, the kinds' registry type). This module
imports nothing of iwr but that registry (the implementations are imported on first use), so
that the robot description may use it.
"""

from __future__ import annotations

import abc
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np

from .._registry import Registry

__all__ = [
    "Effect",
    "JointState",
    "LegState",
    "available",
    "bounds",
    "named",
    "parameter_names",
    "read_table",
    "register",
    "refuse",
]


class LegState:
    """What an effect needs to know of the legs at the poses of a data set, at one geometric
    error vector: filled by :func:`iwr.effects.model.leg_state`.

    Attributes
    ----------
    lengths : ndarray (N, 6)
        The leg lengths between the joint centres (mm) predicted by the geometry.
    d_lengths : ndarray (N, 6, n_geometric)
        Their derivatives in the geometric error parameters.
    forces : ndarray (N, 6) or None
        The axial leg forces (N, tension positive) that hold the platform and its load
        (statics, ``f = J^-T w``), when an effect asked for them.
    d_forces : ndarray (N, 6, n_geometric) or None
        Their derivatives in the geometric error parameters.
    temperatures : ndarray (N, 6) or None
        Each leg's temperature at each pose (degrees C), from the data.
    """

    def __init__(self, lengths: np.ndarray, d_lengths: np.ndarray, forces: Any = None,
                 d_forces: Any = None, temperatures: Any = None) -> None:
        self.lengths = lengths
        self.d_lengths = d_lengths
        self.forces = forces
        self.d_forces = d_forces
        self.temperatures = temperatures


class JointState:
    """What an effect on the carriage's joints needs to know at the poses of a data set, at one
    geometric error vector: filled by :func:`iwr.effects.model.joint_state`.

    Attributes
    ----------
    loads : ndarray (N, n_joints)
        The gravity load each joint holds of everything distal to it (the hexapod, the platform
        and the payload), at the joint readings: the torque about a revolute joint's axis (N mm,
        positive about the axis: the direction the joint's value increases) or the force along a
        prismatic joint's axis (N, positive along it).
    d_loads : ndarray (N, n_joints, n_z)
        Their derivatives in the variables the caller differentiates in (the geometric errors,
        then, for the implicit loop, the readings' corrections).
    joint_types : str
        ``"P"`` or ``"R"`` per joint.
    readings : ndarray (N, n_joints)
        The joint readings (mm or rad) the changes are taken at.
    d_readings : ndarray (N, n_joints, n_z)
        Their derivatives in the same variables as ``d_loads`` (zero in the geometric errors,
        one in the implicit loop's correction of the same joint).
    temperatures : ndarray (N,) or None
        The machine's temperature at each pose (degrees C, the data's ``T_C`` column), when an
        effect needs it (``"machine_temperature"``).

    ``loads`` and ``d_loads`` are zero when no effect on the joints needs ``"loads"``.
    """

    def __init__(self, loads: np.ndarray, d_loads: np.ndarray, joint_types: str,
                 readings: Any = None, d_readings: Any = None, temperatures: Any = None) -> None:
        self.loads = loads
        self.d_loads = d_loads
        self.joint_types = joint_types
        self.readings = readings
        self.d_readings = d_readings
        self.temperatures = temperatures


class Effect(abc.ABC):
    """The protocol of a non-geometric effect on the legs (one instance per robot: it holds the
    effect's settings and the current values of its parameters).

    An effect with ``k`` parameters (:meth:`parameter_names`, possibly none: a coefficient
    given, not identified) changes the true leg lengths by :meth:`leg_change`, or the carriage's
    true joint values by :meth:`joint_change` (:attr:`changes`), and says what it needs of the
    data (:attr:`needs`)."""

    #: The effect's name: its table in the robot TOML (``[effects.<name>]``) and its registry key.
    name: ClassVar[str]
    #: What it is, for messages and reports.
    description: ClassVar[str]
    #: What :meth:`leg_change` needs in its :class:`LegState`: ``"forces"`` (the statics of
    #: the payload, platform and gravity), ``"temperatures"`` (the data's temperature columns),
    #: ``"machine_temperature"`` (the machine's one temperature per pose, the ``T_C`` column),
    #: ``"loads"`` (an effect on the joints: their gravity loads, the data's payload).
    needs: ClassVar[frozenset[str]] = frozenset()
    #: What it changes: ``"legs"`` (:meth:`leg_change`, the leg lengths) or ``"joints"``
    #: (:meth:`joint_change`, the carriage's joint values, before the legs are computed).
    #: An effect on the joints needs ``"loads"`` (the payload column of the data).
    changes: ClassVar[frozenset[str]] = frozenset({"legs"})

    @abc.abstractmethod
    def parameter_names(self) -> list[str]:
        """The names of the parameters identified (appended after the geometric ones)."""

    @abc.abstractmethod
    def units(self) -> list[str]:
        """The unit of each parameter."""

    @abc.abstractmethod
    def values(self) -> np.ndarray:
        """The current value of each parameter (what the robot file holds)."""

    @abc.abstractmethod
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Search bounds of the corrections to :meth:`values` (lower < upper): the range a
        plausible machine has, the yardstick of the fit check's size test and the range
        :func:`iwr.simulate` draws a true machine from."""

    @abc.abstractmethod
    def with_values(self, values: np.ndarray) -> Effect:
        """This effect with its parameters' values replaced by ``values`` (checked)."""

    def leg_change(self, state: LegState, values: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(change, d_geometric, d_own)``: the change of the true leg lengths (N, 6) (mm),
        at parameter values ``values``, its derivatives in the geometric errors
        (N, 6, n_geometric) and in its own parameters (N, 6, k). Called when ``"legs"`` is in
        :attr:`changes`."""
        raise NotImplementedError(f"effect {self.name!r} does not change the legs")

    def joint_change(self, state: JointState, values: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(change, d_z, d_own)``: the change of the carriage's true joint values (N,
        n_joints) (mm or rad: the true value is the reading plus it), at parameter values
        ``values``, its derivatives in the state's variables (N, n_joints, n_z) and in its own
        parameters (N, n_joints, k). Called when ``"joints"`` is in :attr:`changes`."""
        raise NotImplementedError(f"effect {self.name!r} does not change the joints")

    def in_platform_frame(self, rotation: np.ndarray, shift: np.ndarray) -> Effect:
        """This effect with what it holds in the platform frame {5} (a centre of mass)
        expressed in another platform frame, in which a point of {5} at ``c`` is at
        ``rotation @ c + shift``: what moves with the frame when a calibration chooses {5}
        (:func:`iwr.tracker.calibrated_robot`: tracker data do not fix it). Default: itself
        (nothing in {5})."""
        return self

    def for_robot(self, robot: Any) -> Effect:
        """This effect checked against (and told of) the robot it is switched on for: the
        robot calls it when it takes its effects. Default: itself."""
        return self

    @abc.abstractmethod
    def to_dict(self) -> dict[str, Any]:
        """The ``[effects.<name>]`` table (flat: numbers, booleans, arrays of numbers)."""

    @classmethod
    @abc.abstractmethod
    def from_dict(cls, table: Mapping[str, Any], where: str) -> Effect:
        """Read the table (errors name ``where`` and the key)."""

    def __eq__(self, other: object) -> bool:
        return type(self) is type(other) and self.to_dict() == other.to_dict()  # type: ignore

    def __hash__(self) -> int:
        return hash(self.name)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.to_dict()})"


# -- the registry ---------------------------------------------------------------------------

#: The effects' classes by name, imported on first use (one registry type with the kinds').
_EFFECTS: Registry[type[Effect]] = Registry(
    "effect", lambda obj: isinstance(obj, type) and issubclass(obj, Effect),
    "an Effect subclass")


def register(name: str, effect: str | type[Effect]) -> None:
    """Make effect ``name`` known: ``effect`` an :class:`Effect` subclass, or
    ``"package.module:Class"`` imported on first use."""
    _EFFECTS.register(name, effect)


register("compliance", "iwr.effects.builtin:LegCompliance")
register("thermal", "iwr.effects.builtin:LegThermal")
register("carriage_compliance", "iwr.effects.carriage:CarriageCompliance")
register("carriage_thermal", "iwr.effects.carriage_thermal:CarriageThermal")


def available() -> list[str]:
    """The registered effects' names."""
    return _EFFECTS.names()


def named(name: str) -> type[Effect]:
    """The class of the registered effect ``name``; ValueError naming the registered ones."""
    return _EFFECTS.get(name)


def read_table(effects: Any, where: str = "effects", robot: Any = None) -> tuple[Effect, ...]:
    """The robot's effects from the ``[effects]`` table (a mapping of effect name to its
    table), or from a sequence of :class:`Effect` objects; each at most once; checked against
    ``robot`` (:meth:`Effect.for_robot`) when it is given."""
    if effects is None:
        return ()
    if isinstance(effects, Mapping):
        out = []
        for name, table in effects.items():
            if name not in _EFFECTS:
                raise ValueError(f"{where}.{name}: unknown effect; known: "
                                 + ", ".join(_EFFECTS.names()))
            if isinstance(table, Effect):
                out.append(table)
                continue
            if not isinstance(table, Mapping):
                raise ValueError(f"{where}.{name}: expected a table, got "
                                 f"{type(table).__name__} {table!r:.60}")
            out.append(named(name).from_dict(table, f"{where}.{name}"))
    elif isinstance(effects, Sequence) and not isinstance(effects, str):
        out = list(effects)
        for e in out:
            if not isinstance(e, Effect):
                raise TypeError(f"{where}: expected iwr.effects.Effect objects, got "
                                f"{type(e).__name__}")
    else:
        raise TypeError(f"{where}: expected a table of effects or a sequence of "
                        f"iwr.effects.Effect, got {type(effects).__name__}")
    names = [e.name for e in out]
    for name in names:
        if names.count(name) > 1:
            raise ValueError(f"{where}: effect {name!r} given twice")
    _same_loads(out, where)
    if robot is not None:
        out = [e.for_robot(robot) for e in out]
    return tuple(out)


#: What the effects of the load say of it (each must say the same: one gravity, one platform).
_LOAD_KEYS = (("gravity", "gravity_m_s2"), ("platform_mass", "platform_mass_kg"),
              ("platform_centre", "platform_centre_mm"))


def _same_loads(effects: Sequence[Effect], where: str) -> None:
    """ValueError when two effects of the load (the leg and the carriage compliance) describe
    gravity or the platform differently."""
    loaded = [e for e in effects if hasattr(e, "gravity")]
    for e in loaded[1:]:
        for attr, key in _LOAD_KEYS:
            a, b = np.asarray(getattr(loaded[0], attr)), np.asarray(getattr(e, attr))
            if a.shape != b.shape or not np.array_equal(a, b):
                raise ValueError(
                    f"{where}.{e.name}.{key}: {b.tolist()}; {where}.{loaded[0].name}.{key} says "
                    f"{a.tolist()}: the effects of the load must describe the same gravity and "
                    "platform")


def parameter_names(effects: Sequence[Effect]) -> list[str]:
    """The names of the effects' parameters, in order."""
    return [n for e in effects for n in e.parameter_names()]


def bounds(effects: Sequence[Effect]) -> tuple[np.ndarray, np.ndarray]:
    """The effects' parameters' search bounds, in order."""
    lo = [np.asarray(e.bounds()[0], dtype=float) for e in effects]
    hi = [np.asarray(e.bounds()[1], dtype=float) for e in effects]
    return (np.concatenate(lo) if lo else np.zeros(0), np.concatenate(hi) if hi else np.zeros(0))


#: The methods and functions that model the effects (the others refuse a robot with effects).
SUPPORTED = ("iwr.identify with method 'lm', 'de', 'crs2', 'bobyqa' (eq. (10) or "
             "noise-weighted) or 'efficient' on pose data",
             "iwr.Problem (noise= too) and its problem file, iwr-engine, iwr-calibrate",
             "iwr.simulate", "iwr.identifiability", "iwr.uncertainty", "iwr.parameter_error",
             "iwr.predict_legs (data=)", "iwr.estimation.predicted_accuracy",
             "iwr.implicit_loop.loop_jacobians", "iwr.accuracy",
             "iwr.calibrate, iwr calibrate and iwr report (any of those methods, with or without "
             "a noise model)", "iwr.effects.api.leg_commands",
             "iwr.effects.api.forward_kinematics",
             "on tracker data (iwr.effects.tracker; the legs' effects, the carriage's "
             "compliance and its slides' expansion): iwr.simulate, "
             "iwr.identify with every method (noise-weighted too), "
             "iwr.identifiability, iwr.accuracy, iwr.uncertainty, iwr.plan_poses, the problem "
             "file, iwr-engine, iwr-calibrate, and the calibration job",
             "on ballbar data (iwr.ballbar.effects; the legs' effects, the carriage's "
             "compliance and its slides' expansion): iwr.simulate, iwr.identify with every "
             "method (DE, CRS2 and BOBYQA on the C++ objective), iwr.identifiability, "
             "iwr.accuracy, iwr.uncertainty, iwr.plan_poses, the problem file, iwr-engine, "
             "iwr-calibrate, and the calibration job")


def refuse(robot: Any, what: str) -> None:
    """ValueError when ``robot`` has effects on: ``what`` (a function, a method) models the
    geometry only and would silently leave them out."""
    effects = getattr(robot, "effects", ())
    if effects:
        names = ", ".join(e.name for e in effects)
        raise ValueError(
            f"robot {getattr(robot, 'name', '?')!r} has effects on ({names}): {what} models "
            "the geometry only and would leave them out; what models them: "
            + "; ".join(SUPPORTED) + " (docs/effects.md). Remove the [effects] table (or "
            "robot.with_effects()) for a geometric calibration")
