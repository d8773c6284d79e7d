"""The compliance of the carriage's joints under the gravity load of what they carry: the hexapod,
its platform and the payload (docs/effects.md, "The carriage's joints").

A revolute joint whose axis carries the gravity torque ``tau`` (about its axis, of everything
distal to it) turns by ``c tau`` beyond its reading; a prismatic joint carrying the axial force
``F`` moves by ``c F``. The loads are those at the joint readings (first order in the
deflection: docs/effects.md says what the second order is worth).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any

import numpy as np

from . import Effect, JointState
from .builtin import _check_keys, _GravityLoad, _joint_numbers, _number, _plain, _vector

__all__ = ["CarriageCompliance", "UNIT_SCALE"]

#: Per joint type: the parameter's unit and its factor to the model's units (rad per N mm for a
#: revolute joint, mm per N for a prismatic one).
UNIT_SCALE = {"R": ("urad/(N m)", 1e-9), "P": ("um/N", 1e-3)}


#: The largest plausible compliance of a prismatic joint a robot file takes (um/N; the C++
#: reader's too).
_MAX_PRISMATIC = 10.0

class CarriageCompliance(_GravityLoad, Effect):
    """Compliance of the carriage's joints (drive, gearbox, bearings, the link's bending folded
    into the joint): joint ``i`` is ``c_i L_i`` beyond its reading, ``L_i`` the gravity load it
    holds of everything distal to it (:class:`iwr.effects.JointState`: the torque about a
    revolute joint's axis, the force along a prismatic joint's axis), ``c_i`` in urad/(N m)
    (revolute) or um/N (prismatic), one per joint listed in ``joints``.

    The bodies distal to every joint are the hexapod (its base and legs, with what is fixed to
    the carriage's last link: mass and centre of mass in {4}), the platform (mass and centre in
    {5}, as :class:`iwr.effects.builtin.LegCompliance` takes them: both effects, when on, must
    say the same) and the data's payload (per pose, centre in {5}). The carriage's own links are
    not among them: fold the last link's mass into the hexapod's; the others' (between two
    joints) are left out.

    Parameters
    ----------
    hexapod_mass : float
        kg.
    hexapod_centre : array_like (3,)
        mm in {4}.
    platform_mass, platform_centre, gravity
        As :class:`iwr.effects.builtin.LegCompliance`'s.
    joints : sequence of int, optional
        The joints that yield (1-based); default every joint of the robot.
    compliance : float or array_like
        The current value(s), one per listed joint (or one for all): urad/(N m) for a revolute
        joint, um/N for a prismatic one.
    max_revolute, max_prismatic : float
        The largest plausible compliance of a revolute (urad/(N m)) and a prismatic joint
        (um/N): the search bounds of the corrections put the total in ``[0, max]``.
    """

    name = "carriage_compliance"
    description = "the compliance of the carriage's joints under the gravity load they carry"
    needs = frozenset({"loads"})
    changes = frozenset({"joints"})
    _KEYS = {"joints": "joint numbers from 1", "compliance":
             "one per listed joint: urad/(N m) revolute, um/N prismatic",
             "max_urad_per_Nm": "urad/(N m), revolute joints",
             "max_um_per_N": "um/N, prismatic joints",
             "hexapod_mass_kg": "kg", "hexapod_centre_mm": "mm in {4}, three numbers",
             **_GravityLoad._LOAD_KEYS}

    def __init__(self, hexapod_mass: float, hexapod_centre: Any, platform_mass: float,
                 platform_centre: Any, gravity: Any, joints: Any = None, compliance: Any = 0.0,
                 *, max_revolute: float = 0.5, max_prismatic: float = 0.05,
                 where: str = "effects.carriage_compliance") -> None:
        self.where = where
        self.hexapod_mass = _number(hexapod_mass, f"{where}.hexapod_mass_kg", 0.0, 1e6, "kg")
        self.hexapod_centre = _vector(hexapod_centre, 3, f"{where}.hexapod_centre_mm", -1e5, 1e5,
                                      "mm")
        self._read_load(platform_mass, platform_centre, gravity, where)
        self.max_revolute = _number(max_revolute, f"{where}.max_urad_per_Nm", 1e-9, 1e3,
                                    "urad/(N m)")
        self.max_prismatic = _number(max_prismatic, f"{where}.max_um_per_N", 1e-9, _MAX_PRISMATIC,
                                     "um/N")
        self.joints: tuple[int, ...] | None = None if joints is None else _joint_numbers(
            joints, f"{where}.joints")
        if isinstance(compliance, (list, tuple, np.ndarray)):
            self._given = [_number(v, f"{where}.compliance[{i}]", -1e3, 1e3, "urad/(N m) or um/N")
                           for i, v in enumerate(compliance)]
        else:
            self._given = _number(compliance, f"{where}.compliance", -1e3, 1e3,
                                  "urad/(N m) or um/N")
        #: Set by :meth:`for_robot`: the listed joints' types ("P"/"R") and compliances.
        self.joint_types: str | None = None
        self.compliance: np.ndarray | None = None

    # -- binding to the robot ---------------------------------------------------------------

    def for_robot(self, robot: Any) -> CarriageCompliance:
        where, nj = self.where, robot.n_joints
        joints = self.joints if self.joints is not None else tuple(range(1, nj + 1))
        if not joints:
            raise ValueError(f"{where}: robot {robot.name!r} has no carriage joints; switch "
                             "the carriage compliance off")
        for i, j in enumerate(joints):
            if j > nj:
                raise ValueError(f"{where}.joints[{i}]: joint {j}; robot {robot.name!r} has "
                                 f"{nj} joints")
        types = "".join(robot.joint_types[j - 1] for j in joints)
        given = self._given
        if isinstance(given, list):
            if len(given) != len(joints):
                raise ValueError(f"{where}.compliance: {len(given)} values; expected "
                                 f"{len(joints)}, one per joint of {where}.joints "
                                 f"({list(joints)})")
            values = np.array(given)
        else:
            values = np.full(len(joints), given)
        for i, (v, t) in enumerate(zip(values, types, strict=True)):
            unit = UNIT_SCALE[t][0]
            hi = self._max(t)
            if not -hi <= v <= hi:
                kind = "revolute" if t == "R" else "prismatic"
                raise ValueError(f"{where}.compliance[{i}]: {float(v)!r} {unit} (joint "
                                 f"{joints[i]}, {kind}); expected {-hi:g} <= value <= {hi:g}")
        out = copy.copy(self)
        out.joints, out.joint_types, out.compliance = tuple(joints), types, values
        return out

    def _max(self, kind: str) -> float:
        return self.max_revolute if kind == "R" else self.max_prismatic

    def _bound(self) -> tuple[tuple[int, ...], str, np.ndarray]:
        if self.compliance is None or self.joint_types is None or self.joints is None:
            raise ValueError(f"{self.where}: not switched on for a robot yet (its joint types "
                             "decide the units): robot.with_effects(...)")
        return self.joints, self.joint_types, self.compliance

    # -- the protocol ------------------------------------------------------------------------

    def parameter_names(self) -> list[str]:
        return [f"joint{j}.compliance" for j in self._bound()[0]]

    def units(self) -> list[str]:
        return [UNIT_SCALE[t][0] for t in self._bound()[1]]

    def values(self) -> np.ndarray:
        return self._bound()[2].copy()

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        _, types, c = self._bound()
        top = np.array([self._max(t) for t in types])
        lo = -np.maximum(c, 0.0)
        return lo, np.maximum(top - c, lo + 1e-9)

    def with_values(self, values: np.ndarray) -> CarriageCompliance:
        _, _, c = self._bound()
        out = copy.copy(self)
        out.compliance = _vector(np.asarray(values, dtype=float).tolist(), len(c), "compliance",
                                 -1e3, 1e3, "urad/(N m) or um/N")
        joints, types_text, _ = self._bound()
        for i, (v, t) in enumerate(zip(out.compliance, types_text, strict=True)):
            if t == "P" and not abs(v) <= _MAX_PRISMATIC:  # the robot file's cap (C++ too)
                raise ValueError(f"{self.where}: joint{joints[i]}.compliance {float(v)!r} um/N; "
                                 f"expected {-_MAX_PRISMATIC:g} <= value <= {_MAX_PRISMATIC:g} "
                                 "(a prismatic joint's compliance a robot file can hold)")
        out._given = out.compliance.tolist()
        # beyond the plausible range: widened to hold it (LegCompliance.with_values)
        # (a negative value moves the lower end: bounds() starts the range at it; one below
        # -max_* widens max_* too, as a robot file holds values within +-max_*; one
        # max_um_per_N serves every slide, so a slide beyond it widens the others' range too)
        size = np.abs(out.compliance)
        types = np.array(list(self._bound()[1]))
        for kind, attr in (("R", "max_revolute"), ("P", "max_prismatic")):
            if np.any(types == kind):
                setattr(out, attr, max(getattr(self, attr), float(np.max(size[types == kind]))))
        return out

    def joint_change(self, state: JointState, values: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        joints, types, _ = self._bound()
        idx = np.array(joints) - 1
        scale = np.array([UNIT_SCALE[t][1] for t in types])
        n, nj = state.loads.shape
        k = len(idx)
        c = scale * np.asarray(values, dtype=float)
        change = np.zeros((n, nj))
        change[:, idx] = c * state.loads[:, idx]
        d_z = np.zeros((n, nj) + state.d_loads.shape[2:])
        d_z[:, idx] = c[None, :, None] * state.d_loads[:, idx]
        d_own = np.zeros((n, nj, k))
        d_own[:, idx, np.arange(k)] = scale * state.loads[:, idx]
        return change, d_z, d_own

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        if self.joints is not None:
            out["joints"] = list(self.joints)
        given = self.compliance if self.compliance is not None else np.atleast_1d(self._given)
        out.update({"compliance": _plain(np.asarray(given, dtype=float)),
                    "max_urad_per_Nm": self.max_revolute, "max_um_per_N": self.max_prismatic,
                    "hexapod_mass_kg": self.hexapod_mass,
                    "hexapod_centre_mm": [float(v) for v in self.hexapod_centre],
                    **self._load_dict()})
        return out

    @classmethod
    def from_dict(cls, table: Mapping[str, Any], where: str) -> CarriageCompliance:
        _check_keys(table, cls._KEYS, {"hexapod_mass_kg", "hexapod_centre_mm",
                                       *cls._LOAD_KEYS}, where)
        return cls(table["hexapod_mass_kg"], table["hexapod_centre_mm"],
                   table["platform_mass_kg"], table["platform_centre_mm"],
                   table["gravity_m_s2"], table.get("joints"), table.get("compliance", 0.0),
                   max_revolute=table.get("max_urad_per_Nm", 0.5),
                   max_prismatic=table.get("max_um_per_N", 0.05), where=where)

