"""The built-in effects: the legs' axial compliance under load and their thermal expansion
(docs/effects.md)."""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from . import Effect, LegState

__all__ = ["LegCompliance", "LegThermal", "PlatformCentre", "STANDARD_GRAVITY", "STEEL_ALPHA"]

#: Standard gravity (m/s^2), ISO 80000-3.
STANDARD_GRAVITY = 9.80665
#: Linear thermal expansion coefficient of carbon steel near 20 C (ppm/K, i.e. um per m per K).
STEEL_ALPHA = 11.5


def _check_keys(table: Mapping[str, Any], allowed: dict[str, str], required: set[str],
                where: str) -> None:
    for key in table:
        if key not in allowed:
            raise ValueError(f"{where}.{key}: unknown key; allowed: "
                             + ", ".join(f"{k} ({u})" for k, u in allowed.items()))
    for key in sorted(required):
        if key not in table:
            raise ValueError(f"{where}.{key}: missing key ({allowed[key]})")


def _number(value: Any, where: str, lo: float, hi: float, unit: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where}: expected a number ({unit}), got {type(value).__name__} "
                         f"{value!r:.60}")
    v = float(value)
    if not (math.isfinite(v) and lo <= v <= hi):
        raise ValueError(f"{where}: {value!r} {unit}; expected {lo:g} <= value <= {hi:g}")
    return v


def _vector(value: Any, n: int, where: str, lo: float, hi: float, unit: str) -> np.ndarray:
    if isinstance(value, (list, tuple, np.ndarray)):
        if len(value) != n:
            raise ValueError(f"{where}: {len(value)} values; expected {n} ({unit})")
        return np.array([_number(v, f"{where}[{i}]", lo, hi, unit)
                         for i, v in enumerate(value)])
    return np.full(n, _number(value, where, lo, hi, unit))


def _bool(value: Any, where: str) -> bool:
    if not isinstance(value, bool):
        raise ValueError(f"{where}: expected true or false, got {value!r:.60}")
    return value


def _joint_numbers(joints: Any, where: str) -> tuple[int, ...]:
    """Distinct joint numbers from 1 (ValueError naming ``where``): an effect's ``joints``."""
    if isinstance(joints, (str, bytes)) or not isinstance(joints, (list, tuple, np.ndarray)):
        raise ValueError(f"{where}: expected a list of joint numbers (from 1), got "
                         f"{joints!r:.60}")
    out = []
    for i, j in enumerate(joints):
        if (isinstance(j, bool) or not isinstance(j, (int, float, np.integer))
                or not float(j).is_integer() or j < 1):
            raise ValueError(f"{where}[{i}]: {j!r}; expected a joint number from 1")
        out.append(int(j))
    if not out or len(set(out)) != len(out):
        raise ValueError(f"{where}: {out}; expected distinct joint numbers, at least one")
    return tuple(out)


def _plain(values: np.ndarray) -> Any:
    """One number when every entry is equal and there is one, else a list (for the TOML)."""
    return float(values[0]) if values.size == 1 else [float(v) for v in values]


class PlatformCentre:
    """What an effect that holds the platform's centre of mass in {5} (``platform_centre``, mm)
    does when {5} moves (:meth:`iwr.effects.Effect.in_platform_frame`): the centre moves with
    it."""

    platform_centre: np.ndarray

    def in_platform_frame(self, rotation: np.ndarray, shift: np.ndarray) -> Any:
        out = copy.copy(self)
        out.platform_centre = (np.asarray(rotation, dtype=float) @ self.platform_centre
                               + np.asarray(shift, dtype=float))
        return out


class _GravityLoad(PlatformCentre):
    """What the effects under gravity read alike: the platform's own mass and centre (in {5})
    and the gravity vector in {0} (:class:`LegCompliance`, and the carriage's compliance)."""

    #: Their keys in an ``[effects.X]`` table.
    _LOAD_KEYS = {"gravity_m_s2": "m/s^2 in {0}, three numbers", "platform_mass_kg": "kg",
                  "platform_centre_mm": "mm in {5}, three numbers"}

    def _read_load(self, platform_mass: Any, platform_centre: Any, gravity: Any,
                   where: str) -> None:
        self.platform_mass = _number(platform_mass, f"{where}.platform_mass_kg", 0.0, 1e6, "kg")
        self.platform_centre = _vector(platform_centre, 3, f"{where}.platform_centre_mm",
                                       -1e5, 1e5, "mm")
        self.gravity = _vector(gravity, 3, f"{where}.gravity_m_s2", -20.0, 20.0, "m/s^2")
        g = float(np.linalg.norm(self.gravity))
        if abs(g / STANDARD_GRAVITY - 1.0) > 0.01:
            raise ValueError(f"{where}.gravity_m_s2: {self.gravity.tolist()} has norm {g:.6g} "
                             f"m/s^2; expected {STANDARD_GRAVITY} within 1 % (the vector of "
                             "gravity in {0}, m/s^2)")

    def _load_dict(self) -> dict[str, Any]:
        return {"gravity_m_s2": [float(v) for v in self.gravity],
                "platform_mass_kg": self.platform_mass,
                "platform_centre_mm": [float(v) for v in self.platform_centre]}


class LegCompliance(_GravityLoad, Effect):
    """Axial compliance of the legs (actuator, joints, structure): a leg carrying the axial force
    ``f`` (N, tension positive) is ``c f`` longer than its reading says, ``c`` in um/N, one per
    leg or one shared. The forces are those that hold the platform and the payload under
    gravity at each pose (:func:`iwr.effects.model.leg_forces`); the legs' own weight is left
    out (massless two-force members).

    Parameters
    ----------
    platform_mass : float
        The moving platform's own mass with what is fixed on it for good (kg).
    platform_centre : array_like (3,)
        Its centre of mass in the platform frame {5} (mm).
    gravity : array_like (3,)
        The acceleration of gravity in the world frame {0} (m/s^2); its norm within 1 % of
        :data:`STANDARD_GRAVITY` (a direction mistake is a sign, not a scale).
    compliance : float or array_like (6,)
        The current value(s), um/N (0: rigid legs).
    per_leg : bool
        Six parameters (one per leg) or one shared.
    max_compliance : float
        The largest plausible compliance (um/N): the search bounds of the corrections put the
        total in ``[0, max_compliance]``.
    """

    name = "compliance"
    description = "the legs' axial compliance under load"
    needs = frozenset({"forces"})
    _KEYS = {"per_leg": "true or false", "compliance_um_per_N": "um/N, one or six",
             "max_um_per_N": "um/N", **_GravityLoad._LOAD_KEYS}

    def __init__(self, platform_mass: float, platform_centre: Any, gravity: Any,
                 compliance: Any = 0.0, *, per_leg: bool = True,
                 max_compliance: float = 0.05, where: str = "effects.compliance") -> None:
        self.per_leg = _bool(per_leg, f"{where}.per_leg")
        self._read_load(platform_mass, platform_centre, gravity, where)
        self.max_compliance = _number(max_compliance, f"{where}.max_um_per_N", 1e-6, 10.0,
                                      "um/N")
        self.compliance = _vector(compliance, 6 if self.per_leg else 1,
                                  f"{where}.compliance_um_per_N", -self.max_compliance,
                                  self.max_compliance, "um/N")

    def parameter_names(self) -> list[str]:
        if self.per_leg:
            return [f"leg{j + 1}.compliance" for j in range(6)]
        return ["legs.compliance"]

    def units(self) -> list[str]:
        return ["um/N"] * len(self.compliance)

    def values(self) -> np.ndarray:
        return self.compliance.copy()

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo = -np.maximum(self.compliance, 0.0)
        hi = self.max_compliance - self.compliance
        return lo, np.maximum(hi, lo + 1e-9)

    def with_values(self, values: np.ndarray) -> LegCompliance:
        out = copy.copy(self)
        out.compliance = _vector(np.asarray(values, dtype=float).tolist(), len(self.compliance),
                                 "compliance", -10.0, 10.0, "um/N")
        # A value identified beyond the plausible range (passed by the fit's range test within
        # its standard deviation) widens it: a robot file must hold its own values.
        # A negative value moves the lower end (bounds() starts the range at it); one below
        # -max_compliance widens max_compliance too: a robot file holds values within +-max.
        out.max_compliance = max(self.max_compliance, float(np.max(np.abs(out.compliance))))
        return out

    def leg_change(self, state: LegState, values: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        f, df = state.forces, state.d_forces
        assert f is not None and df is not None
        c = np.broadcast_to(np.asarray(values, dtype=float), (6,)) * 1e-3  # mm/N
        change = c * f
        d_geo = c[None, :, None] * df
        if self.per_leg:
            d_own = 1e-3 * f[:, :, None] * np.eye(6)[None]
        else:
            d_own = 1e-3 * f[:, :, None]
        return change, d_geo, d_own

    def to_dict(self) -> dict[str, Any]:
        return {"per_leg": self.per_leg, "compliance_um_per_N": _plain(self.compliance),
                "max_um_per_N": self.max_compliance, **self._load_dict()}

    @classmethod
    def from_dict(cls, table: Mapping[str, Any], where: str) -> LegCompliance:
        _check_keys(table, cls._KEYS, set(cls._LOAD_KEYS), where)
        return cls(table["platform_mass_kg"], table["platform_centre_mm"],
                   table["gravity_m_s2"], table.get("compliance_um_per_N", 0.0),
                   per_leg=table.get("per_leg", True),
                   max_compliance=table.get("max_um_per_N", 0.05), where=where)


class LegThermal(Effect):
    """Thermal expansion of the legs: at temperature ``T`` a leg is ``alpha D (T - T_ref)``
    longer than its reading says (``D`` its length between the joint centres, ``alpha`` in
    ppm/K = um per m per K), with the coefficient given (no parameter) or identified (one
    shared or one per leg). The temperatures come with the data, per pose: one for the machine
    or one per leg (docs/effects.md).

    Parameters
    ----------
    alpha : float or array_like (6,)
        The expansion coefficient(s), ppm/K (default: steel, :data:`STEEL_ALPHA`).
    reference : float
        The temperature at which the geometry holds (degrees C): the calibration's leg offsets
        are the legs' at that temperature.
    identify : bool
        Identify the coefficient(s) (parameters), or take them as given (none).
    per_leg : bool
        One coefficient per leg, or one shared.
    max_alpha : float
        The largest plausible coefficient (ppm/K): the bounds of the corrections put the total
        in ``[0, max_alpha]``.
    """

    name = "thermal"
    description = "the legs' thermal expansion"
    needs = frozenset({"temperatures"})
    _KEYS = {"alpha_ppm_per_K": "ppm/K, one or six", "reference_C": "degrees C",
             "identify": "true or false", "per_leg": "true or false",
             "max_ppm_per_K": "ppm/K"}

    def __init__(self, alpha: Any = STEEL_ALPHA, reference: float = 20.0, *,
                 identify: bool = False, per_leg: bool = False, max_alpha: float = 30.0,
                 where: str = "effects.thermal") -> None:
        self.identify = _bool(identify, f"{where}.identify")
        self.per_leg = _bool(per_leg, f"{where}.per_leg")
        self.reference = _number(reference, f"{where}.reference_C", -50.0, 150.0, "degrees C")
        self.max_alpha = _number(max_alpha, f"{where}.max_ppm_per_K", 1e-3, 1000.0, "ppm/K")
        self.alpha = _vector(alpha, 6 if self.per_leg else 1, f"{where}.alpha_ppm_per_K",
                             -self.max_alpha, self.max_alpha, "ppm/K")

    def parameter_names(self) -> list[str]:
        if not self.identify:
            return []
        return [f"leg{j + 1}.alpha" for j in range(6)] if self.per_leg else ["legs.alpha"]

    def units(self) -> list[str]:
        return ["ppm/K"] * len(self.parameter_names())

    def values(self) -> np.ndarray:
        return self.alpha.copy() if self.identify else np.zeros(0)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        if not self.identify:
            return np.zeros(0), np.zeros(0)
        lo = -np.maximum(self.alpha, 0.0)
        return lo, np.maximum(self.max_alpha - self.alpha, lo + 1e-9)

    def with_values(self, values: np.ndarray) -> LegThermal:
        out = copy.copy(self)
        if self.identify:
            out.alpha = _vector(np.asarray(values, dtype=float).tolist(), len(self.alpha),
                                "alpha", -1000.0, 1000.0, "ppm/K")
            # beyond the plausible range (or below -max_alpha): widened to hold it
            # (LegCompliance.with_values)
            out.max_alpha = max(self.max_alpha, float(np.max(np.abs(out.alpha))))
        return out

    def leg_change(self, state: LegState, values: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        temps = state.temperatures
        assert temps is not None
        a = np.broadcast_to(values if self.identify else self.alpha, (6,)) * 1e-6  # 1/K
        dt = temps - self.reference
        change = a * state.lengths * dt
        d_geo = (a * dt)[..., None] * state.d_lengths
        own = 1e-6 * state.lengths * dt
        if not self.identify:
            d_own = np.zeros(own.shape + (0,))
        elif self.per_leg:
            d_own = own[:, :, None] * np.eye(6)[None]
        else:
            d_own = own[:, :, None]
        return change, d_geo, d_own

    def to_dict(self) -> dict[str, Any]:
        return {"alpha_ppm_per_K": _plain(self.alpha), "reference_C": self.reference,
                "identify": self.identify, "per_leg": self.per_leg,
                "max_ppm_per_K": self.max_alpha}

    @classmethod
    def from_dict(cls, table: Mapping[str, Any], where: str) -> LegThermal:
        _check_keys(table, cls._KEYS, set(), where)
        return cls(table.get("alpha_ppm_per_K", STEEL_ALPHA), table.get("reference_C", 20.0),
                   identify=table.get("identify", False), per_leg=table.get("per_leg", False),
                   max_alpha=table.get("max_ppm_per_K", 30.0), where=where)
