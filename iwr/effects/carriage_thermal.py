"""The thermal expansion of the carriage's prismatic axes: each slide's scale grows with the
machine's temperature, so the true travel is the reading scaled by it (docs/effects.md, "The
carriage's slides").

A prismatic joint whose reading ``q`` is measured from its scale's zero travels
``q (1 + alpha (T - T_ref))``: its true value is the reading plus ``1e-6 alpha (T - T_ref) q``
(mm; ``alpha`` in ppm/K). ``T`` is the machine's temperature at the pose (the data's ``T_C``
column): the slides have no temperature columns of their own, and the legs' (``T1_C .. T6_C``)
say nothing of them, so data with those only are refused.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any

import numpy as np

from . import Effect, JointState
from .builtin import STEEL_ALPHA, _bool, _check_keys, _joint_numbers, _number, _plain, _vector

__all__ = ["CarriageThermal"]


class CarriageThermal(Effect):
    """Thermal expansion of the carriage's prismatic axes (their scales, with the machine's
    temperature): joint ``i`` is ``1e-6 alpha_i (T - T_ref) q_i`` beyond its reading ``q_i``
    (mm), ``T`` the machine's temperature at the pose, ``alpha_i`` in ppm/K, given (no
    parameter) or identified (one shared by the listed joints, or one per joint).

    Parameters
    ----------
    joints : sequence of int, optional
        The prismatic joints whose scale expands (1-based); default every prismatic joint of
        the robot. A revolute joint listed is refused.
    alpha : float or array_like
        The expansion coefficient(s), ppm/K (default: steel, :data:`STEEL_ALPHA`): one, or one
        per listed joint (with ``per_joint``).
    reference : float
        The temperature at which the scales read true (degrees C).
    identify : bool
        Identify the coefficient(s) (parameters), or take them as given (none).
    per_joint : bool
        One coefficient per listed joint, or one shared.
    max_alpha : float
        The largest plausible coefficient (ppm/K): the bounds of the corrections put the total
        in ``[0, max_alpha]``.
    """

    name = "carriage_thermal"
    description = "the thermal expansion of the carriage's prismatic axes"
    #: The machine's temperature per pose (the data's T_C column; not the legs' T1_C .. T6_C).
    needs = frozenset({"machine_temperature"})
    changes = frozenset({"joints"})
    _KEYS = {"joints": "prismatic joint numbers from 1",
             "alpha_ppm_per_K": "ppm/K, one or one per listed joint",
             "reference_C": "degrees C", "identify": "true or false",
             "per_joint": "true or false", "max_ppm_per_K": "ppm/K"}

    def __init__(self, alpha: Any = STEEL_ALPHA, reference: float = 20.0, joints: Any = None, *,
                 identify: bool = False, per_joint: bool = False, max_alpha: float = 30.0,
                 where: str = "effects.carriage_thermal") -> None:
        self.where = where
        self.identify = _bool(identify, f"{where}.identify")
        self.per_joint = _bool(per_joint, f"{where}.per_joint")
        self.reference = _number(reference, f"{where}.reference_C", -50.0, 150.0, "degrees C")
        self.max_alpha = _number(max_alpha, f"{where}.max_ppm_per_K", 1e-3, 1000.0, "ppm/K")
        self.joints: tuple[int, ...] | None = None if joints is None else _joint_numbers(
            joints, f"{where}.joints")
        if isinstance(alpha, (list, tuple, np.ndarray)):
            if not self.per_joint and len(alpha) != 1:
                raise ValueError(f"{where}.alpha_ppm_per_K: {len(alpha)} values; expected one "
                                 f"(shared: {where}.per_joint is false)")
            given = [_number(v, f"{where}.alpha_ppm_per_K[{i}]", -self.max_alpha,
                             self.max_alpha, "ppm/K") for i, v in enumerate(alpha)]
            self._given: Any = given
        else:
            self._given = _number(alpha, f"{where}.alpha_ppm_per_K", -self.max_alpha,
                                  self.max_alpha, "ppm/K")
        #: Set by :meth:`for_robot` (the listed joints are the robot's prismatic ones): the
        #: coefficient(s), one shared or one per joint.
        self.alpha: np.ndarray | None = None
        if self.joints is not None or not self.per_joint:
            self.alpha = self._resolve(self.joints)

    def _resolve(self, joints: tuple[int, ...] | None) -> np.ndarray:
        n = 1 if not self.per_joint else len(joints or ())
        given = self._given
        if isinstance(given, list):
            if len(given) != n:
                raise ValueError(f"{self.where}.alpha_ppm_per_K: {len(given)} values; expected "
                                 f"{n}, one per joint of {self.where}.joints "
                                 f"({list(joints or ())})")
            return np.array(given, dtype=float)
        return np.full(n, float(given))

    # -- binding to the robot ---------------------------------------------------------------

    def for_robot(self, robot: Any) -> CarriageThermal:
        where, types = self.where, robot.joint_types
        if self.joints is None:
            joints = tuple(i + 1 for i, t in enumerate(types) if t == "P")
            if not joints:
                raise ValueError(f"{where}: robot {robot.name!r} has no prismatic carriage "
                                 f"joint (joint types {types!r}); switch the carriage's "
                                 "thermal expansion off")
        else:
            joints = self.joints
            for i, j in enumerate(joints):
                if j > robot.n_joints:
                    raise ValueError(f"{where}.joints[{i}]: joint {j}; robot {robot.name!r} "
                                     f"has {robot.n_joints} joints")
                if types[j - 1] != "P":
                    raise ValueError(f"{where}.joints[{i}]: joint {j} of robot {robot.name!r} "
                                     "is revolute; the thermal expansion of a scale applies to "
                                     "prismatic joints only (joint types " f"{types!r})")
        out = copy.copy(self)
        out.joints = joints
        out.alpha = out._resolve(joints)
        return out

    def _bound(self) -> tuple[tuple[int, ...], np.ndarray]:
        if self.joints is None or self.alpha is None:
            raise ValueError(f"{self.where}: not switched on for a robot yet (its prismatic "
                             "joints are the default joints): robot.with_effects(...)")
        return self.joints, self.alpha

    # -- the protocol ------------------------------------------------------------------------

    def parameter_names(self) -> list[str]:
        if not self.identify:
            return []
        joints, _ = self._bound()
        return [f"joint{j}.alpha" for j in joints] if self.per_joint else ["carriage.alpha"]

    def units(self) -> list[str]:
        return ["ppm/K"] * len(self.parameter_names())

    def values(self) -> np.ndarray:
        return self._bound()[1].copy() if self.identify else np.zeros(0)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        if not self.identify:
            return np.zeros(0), np.zeros(0)
        a = self._bound()[1]
        lo = -np.maximum(a, 0.0)
        return lo, np.maximum(self.max_alpha - a, lo + 1e-9)

    def with_values(self, values: np.ndarray) -> CarriageThermal:
        out = copy.copy(self)
        if self.identify:
            a = self._bound()[1]
            out.alpha = _vector(np.asarray(values, dtype=float).tolist(), len(a), "alpha",
                                -1000.0, 1000.0, "ppm/K")
            out._given = out.alpha.tolist()
            # beyond the plausible range (or below -max_alpha): widened to hold it
            # (LegCompliance.with_values)
            out.max_alpha = max(self.max_alpha, float(np.max(np.abs(out.alpha))))
        return out

    def joint_change(self, state: JointState, values: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        joints, alpha = self._bound()
        q, temps = state.readings, state.temperatures
        if q is None or temps is None:
            raise ValueError(f"{self.where}: the joint state holds no readings or machine "
                             "temperature")
        idx = np.array(joints) - 1
        n, nj = q.shape
        k = len(idx)
        a = np.broadcast_to(np.asarray(values if self.identify else alpha, dtype=float), (k,))
        dt = np.asarray(temps, dtype=float).reshape(n) - self.reference  # (N,)
        own = 1e-6 * dt[:, None] * q[:, idx]  # (N, k): d change / d alpha_i
        change = np.zeros((n, nj))
        change[:, idx] = a * own
        d_z = np.zeros((n, nj) + state.d_loads.shape[2:])
        if state.d_readings is not None:
            d_z[:, idx] = (1e-6 * a * dt[:, None])[..., None] * state.d_readings[:, idx]
        if not self.identify:
            d_own = np.zeros((n, nj, 0))
        elif self.per_joint:
            d_own = np.zeros((n, nj, k))
            d_own[:, idx, np.arange(k)] = own
        else:
            d_own = np.zeros((n, nj, 1))
            d_own[:, idx, 0] = own
        return change, d_z, d_own

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        if self.joints is not None:
            out["joints"] = list(self.joints)
        given = self.alpha if self.alpha is not None else np.atleast_1d(self._given)
        out.update({"alpha_ppm_per_K": _plain(np.asarray(given, dtype=float)),
                    "reference_C": self.reference, "identify": self.identify,
                    "per_joint": self.per_joint, "max_ppm_per_K": self.max_alpha})
        return out

    @classmethod
    def from_dict(cls, table: Mapping[str, Any], where: str) -> CarriageThermal:
        _check_keys(table, cls._KEYS, set(), where)
        return cls(table.get("alpha_ppm_per_K", STEEL_ALPHA), table.get("reference_C", 20.0),
                   table.get("joints"), identify=table.get("identify", False),
                   per_joint=table.get("per_joint", False),
                   max_alpha=table.get("max_ppm_per_K", 30.0), where=where)

