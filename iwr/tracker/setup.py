"""The nominal laser-tracker setup: where the tracker stands, what it measures on the platform."""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from ..effects.builtin import STANDARD_GRAVITY
from ..measurements import MAX_LENGTH_MM
from ..transforms import euler_zyx, pose_from_matrix, pose_matrix

__all__ = ["TrackerSetup"]

#: Default half-widths of the search bounds of the setup's parameters (mm, rad).
REGISTRATION_BOUND_MM = 10.0
REGISTRATION_BOUND_RAD = math.radians(2.0)
OFFSET_BOUND_MM = 2.0
PROBE_BOUND_RAD = math.radians(2.0)


_POSE_FIELDS = ("x", "y", "z", "alpha", "beta", "gamma")
_POSE_UNITS = "x, y, z in mm, alpha, beta, gamma in rad"
#: The largest angle of a pose accepted (rad): a larger one is degrees written for radians.
MAX_SETUP_ANGLE_RAD = 2.0 * math.pi


def _shown(value: Any) -> str:
    return repr(value.tolist() if isinstance(value, np.ndarray) else value)


def _vector(value: Any, n: int, name: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: cannot be read as numbers ({exc})") from None
    if arr.shape != (n,):
        raise ValueError(f"{name}: shape {arr.shape}; expected ({n},)")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: entry {int(np.flatnonzero(~np.isfinite(arr))[0])} is not finite")
    return arr


def _numbers(value: Any, n: int, name: str, what: str) -> np.ndarray:
    """``n`` finite numbers (a list, tuple or 1-D array), else an error naming ``name`` and
    saying ``what`` they are. Strings are refused, not converted as NumPy would."""
    items: list[Any] | None
    if isinstance(value, (str, bytes, Mapping)) or (isinstance(value, np.ndarray)
                                                    and value.ndim != 1):
        items = None
    else:
        try:
            items = list(value)
        except TypeError:
            items = None
    if items is None or len(items) != n:
        raise ValueError(f"{name}: {_shown(value)}; expected {n} numbers ({what})")
    for i, v in enumerate(items):
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real):
            raise ValueError(f"{name}: entry {i} is {_shown(v)}; expected a number ({what})")
    arr = np.array(items, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: entry {int(np.flatnonzero(~np.isfinite(arr))[0])} is "
                         "not finite")
    big = np.flatnonzero(np.abs(arr) > MAX_LENGTH_MM)
    if big.size:
        raise ValueError(f"{name}: entry {int(big[0])} is {arr[big[0]]:g}, beyond any tracker "
                         f"setup (|value| <= {MAX_LENGTH_MM:g}; {what})")
    return arr


def _pose(value: Any, name: str) -> np.ndarray:
    """A pose ``(x, y, z, alpha, beta, gamma)``; an angle beyond 2 pi is refused: it was meant in
    degrees, and a setup 90 rad off can still be fitted, to a wrong registration."""
    arr = _numbers(value, 6, name, _POSE_UNITS)
    for i in range(3, 6):
        if abs(arr[i]) > MAX_SETUP_ANGLE_RAD:
            raise ValueError(
                f"{name} {_POSE_FIELDS[i]} (entry {i}) = {arr[i]:g}: angles are in radians "
                f"({arr[i]:g} deg = {math.radians(arr[i]):.4f} rad); expected |angle| <= 2 pi")
    return arr


def _reflectors(value: Any) -> np.ndarray:
    """The (K, 3) nominal reflector positions, K >= 1; errors name the reflector (1-based)."""
    what = "x, y, z in mm"
    if isinstance(value, np.ndarray) and value.ndim == 2 and value.dtype.kind in "iuf":
        rows: list[Any] = list(value)
    elif isinstance(value, (str, bytes, Mapping)) or not hasattr(value, "__iter__"):
        raise ValueError(f"reflectors: {_shown(value)}; expected a list of reflectors, 3 numbers "
                         f"each ({what})")
    else:
        rows = list(value)
    if not rows:
        raise ValueError(f"reflectors: empty; expected at least one reflector, 3 numbers ({what})")
    return np.array([_numbers(row, 3, f"reflectors: reflector {k}", what)
                     for k, row in enumerate(rows, 1)])


#: Gravity in a levelled tracker's frame {T} (m/s^2): along its -z axis, standard gravity.
LEVEL_GRAVITY = np.array([0.0, 0.0, -STANDARD_GRAVITY])


def _gravity(value: Any) -> np.ndarray:
    """Gravity in {T} (m/s^2), default :data:`LEVEL_GRAVITY`; its norm within 1 % of standard
    gravity (a wrong direction is a sign or an axis, not a scale)."""
    if value is None:
        return LEVEL_GRAVITY.copy()
    g = _numbers(value, 3, "gravity_m_s2", "m/s^2 in the tracker frame {T}")
    norm = float(np.linalg.norm(g))
    if abs(norm / STANDARD_GRAVITY - 1.0) > 0.01:
        raise ValueError(f"gravity_m_s2: {g.tolist()} has norm {norm:.6g} m/s^2; expected "
                         f"{STANDARD_GRAVITY} within 1 % (gravity in the tracker frame {{T}}, "
                         "m/s^2; a levelled tracker's is [0, 0, -9.80665])")
    return g


class TrackerSetup:
    """A laser tracker's measurement setup, nominal values (docs/tracker.md).

    Parameters
    ----------
    registration : array_like, shape (6,)
        Nominal pose of the robot's world frame {0} in the tracker frame {T}, ``(x, y, z, alpha,
        beta, gamma)`` like every pose in iwr (mm; Z-Y-X Euler angles of eq. 6, rad): a point
        ``p`` in {0} is at ``T_T0 p`` in tracker coordinates. Anything goes (2 m and 90 degrees
        is normal); :func:`iwr.tracker.guess_registration` finds it from the data. An angle
        beyond 2 pi is refused, as degrees written for radians.
    reflectors : array_like, shape (K, 3), optional
        Nominal positions of the K >= 1 reflectors (SMR nests) in the platform frame {5} (mm).
    probe : array_like, shape (6,), optional
        Instead of reflectors: nominal pose of a 6-DOF probe's frame in {5} (angles as above).
    probe_length : float
        The probe's orientation residual is its rotation-matrix error times this length (mm):
        four virtual points, the probe's origin and points this far along its three axes.
    names : list of str, optional
        Reflector names (as the tracker software exports them); default ``"1", "2", ...``.
    gravity : array_like, shape (3,), optional
        The acceleration of gravity in the tracker frame {T} (m/s^2; its norm within 1 % of
        9.80665), what the effects' leg forces take on tracker data (docs/effects.md, "Tracker
        data"): it reaches the robot through the identified registration. Default
        ``(0, 0, -9.80665)``: a levelled tracker, gravity along -z of {T}.

    Exactly one of ``reflectors`` and ``probe`` is given.

    Notes
    -----
    The unknowns appended to the robot's ``4 n + 42`` error parameters, in this order:
    ``tracker.x, tracker.y, tracker.z`` (mm) and ``tracker.rx, tracker.ry, tracker.rz`` (rad):
    the correction ``C = [Exp(r), t]`` in ``T_T0 = T_nom C``, a translation and a rotation vector
    in {0} about {0}'s origin; then ``reflector1.x, reflector1.y, reflector1.z, ...,
    reflectorK.z`` (mm, added to the nominal offsets in {5}) or ``probe.x, probe.y, probe.z``
    (mm, in {5}) and ``probe.rx, probe.ry, probe.rz`` (rad: ``R_probe = Exp(r) R_nom``, a
    rotation about the probe's origin, in {5}'s axes).
    """

    def __init__(
        self,
        registration: Any,
        *,
        reflectors: Any = None,
        probe: Any = None,
        probe_length: float = 100.0,
        names: Any = None,
        gravity: Any = None,
    ) -> None:
        self.registration = _pose(registration, "registration")
        self.gravity = _gravity(gravity)
        if (reflectors is None) == (probe is None):
            raise ValueError("TrackerSetup: give either reflectors=[(x, y, z), ...] or probe="
                             "(x, y, z, alpha, beta, gamma), not both or neither")
        if reflectors is not None:
            refl = _reflectors(reflectors)
            self.kind = "points"
            self.reflectors: np.ndarray | None = refl
            self.probe: np.ndarray | None = None
            k = refl.shape[0]
            names = [str(i + 1) for i in range(k)] if names is None else [str(n) for n in names]
            if len(names) != k or len(set(names)) != k:
                raise ValueError(f"names: {names!r}; expected {k} distinct reflector names")
            self.names = names
        else:
            self.kind = "probe"
            self.reflectors = None
            self.probe = _pose(probe, "probe")
            self.names = ["probe"]
        if (isinstance(probe_length, bool) or not isinstance(probe_length, (int, float))
                or not math.isfinite(probe_length) or probe_length <= 0):
            raise ValueError(f"probe_length: {probe_length!r}; expected a finite length > 0 (mm)")
        self.probe_length = float(probe_length)

    # -- sizes and names ------------------------------------------------------------------------
    @property
    def n_reflectors(self) -> int:
        """K, the reflectors per pose (1 for a probe)."""
        return 1 if self.reflectors is None else int(self.reflectors.shape[0])

    @property
    def n_points(self) -> int:
        """Points per pose in the objective: K reflectors, or the probe's 4 virtual points."""
        return 4 if self.kind == "probe" else self.n_reflectors

    @property
    def n_params(self) -> int:
        """Parameters of the setup: 6 + 3 K, or 12 for a probe."""
        return 12 if self.kind == "probe" else 6 + 3 * self.n_reflectors

    @property
    def parameter_names(self) -> list[str]:
        names = [f"tracker.{c}" for c in ("x", "y", "z", "rx", "ry", "rz")]
        if self.kind == "probe":
            return names + [f"probe.{c}" for c in ("x", "y", "z", "rx", "ry", "rz")]
        return names + [f"reflector{i + 1}.{c}" for i in range(self.n_reflectors) for c in "xyz"]

    @property
    def angle_parameters(self) -> np.ndarray:
        """True where a setup parameter is an angle (rad)."""
        mask = [False] * 3 + [True] * 3
        if self.kind == "probe":
            mask += [False] * 3 + [True] * 3
        else:
            mask += [False] * 3 * self.n_reflectors
        return np.array(mask, dtype=bool)

    def default_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Search bounds of the setup's parameters: +-10 mm and +-2 degrees for the registration's
        correction (about the nominal, or about a registration guess), +-2 mm for reflector
        offsets, +-2 mm and +-2 degrees for a probe."""
        half = np.full(self.n_params, OFFSET_BOUND_MM)
        half[:3] = REGISTRATION_BOUND_MM
        half[3:6] = REGISTRATION_BOUND_RAD
        if self.kind == "probe":
            half[9:12] = PROBE_BOUND_RAD
        return -half, half

    # -- transforms -----------------------------------------------------------------------------
    def _xs(self, x_setup: Any) -> np.ndarray:
        if x_setup is None:
            return np.zeros(self.n_params)
        return _vector(x_setup, self.n_params, "x (setup part)")

    def registration_matrix(self, x_setup: Any = None) -> np.ndarray:
        """``T_T0 = T_nom [Exp(r), t]``, 4x4, for the setup's parameters (default: nominal)."""
        xs = self._xs(x_setup)
        c = np.eye(4)
        c[:3, :3] = Rotation.from_rotvec(xs[3:6]).as_matrix()
        c[:3, 3] = xs[:3]
        return pose_matrix(self.registration) @ c

    def correction_for(self, registration_matrix: Any) -> np.ndarray:
        """The 6 registration parameters ``(t, r)`` with ``T_nom [Exp(r), t]`` equal to the given
        4x4 ``T_T0`` (for example a :func:`guess_registration`), rotation angle below pi."""
        t = np.asarray(registration_matrix, dtype=float)
        c = np.linalg.solve(pose_matrix(self.registration), t)
        return np.concatenate([c[:3, 3], Rotation.from_matrix(c[:3, :3]).as_rotvec()])

    def platform_points(self, x_setup: Any = None) -> np.ndarray:
        """The points measured on the platform, in {5}, shape (n_points, 3): the reflectors, or
        the probe's origin and the points ``probe_length`` along its x, y, z axes."""
        xs = self._xs(x_setup)
        if self.kind == "points":
            assert self.reflectors is not None
            return self.reflectors + xs[6:].reshape(-1, 3)
        assert self.probe is not None
        t = self.probe[:3] + xs[6:9]
        r = Rotation.from_rotvec(xs[9:12]).as_matrix() @ euler_zyx(*self.probe[3:])
        return np.vstack([t, t + self.probe_length * r.T])

    def with_registration(self, registration: Any) -> TrackerSetup:
        """The same setup with another nominal registration (a pose, or a 4x4 transform)."""
        reg = np.asarray(registration, dtype=float)
        if reg.shape == (4, 4):
            reg = pose_from_matrix(reg)
        return TrackerSetup(reg, reflectors=self.reflectors, probe=self.probe,
                            probe_length=self.probe_length,
                            names=self.names if self.kind == "points" else None,
                            gravity=self.gravity)

    def with_parameters(self, x_setup: Any) -> TrackerSetup:
        """The setup whose nominal values are this one's corrected by ``x_setup`` (the setup's
        part of an identified ``x``): the calibrated registration and offsets, to write with
        the calibrated robot."""
        xs = self._xs(x_setup)
        reg = pose_from_matrix(self.registration_matrix(xs))
        if self.kind == "points":
            return TrackerSetup(reg, reflectors=self.platform_points(xs),
                                probe_length=self.probe_length, names=self.names,
                                gravity=self.gravity)
        assert self.probe is not None
        t = np.eye(4)
        t[:3, :3] = Rotation.from_rotvec(xs[9:12]).as_matrix() @ euler_zyx(*self.probe[3:])
        t[:3, 3] = self.probe[:3] + xs[6:9]
        return TrackerSetup(reg, probe=pose_from_matrix(t), probe_length=self.probe_length,
                            gravity=self.gravity)

    # -- TOML -----------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """A TOML-able table: ``registration``, then ``reflectors`` (and ``names``) or ``probe``
        and ``probe_length``."""
        d: dict[str, Any] = {"registration": [float(v) for v in self.registration]}
        if self.kind == "points":
            assert self.reflectors is not None
            d["reflectors"] = [[float(v) for v in row] for row in self.reflectors]
            d["names"] = list(self.names)
        else:
            assert self.probe is not None
            d["probe"] = [float(v) for v in self.probe]
            d["probe_length"] = self.probe_length
        if not np.array_equal(self.gravity, LEVEL_GRAVITY):  # written only when not levelled
            d["gravity_m_s2"] = [float(v) for v in self.gravity]
        return d

    @classmethod
    def from_dict(cls, table: Mapping[str, Any], where: str = "tracker") -> TrackerSetup:
        """Read :meth:`to_dict`'s table; errors name the key (``where.key``)."""
        if not isinstance(table, Mapping):
            raise ValueError(f"{where}: expected a table, got {type(table).__name__}")
        known = {"registration", "reflectors", "names", "probe", "probe_length", "gravity_m_s2"}
        unknown = sorted(set(table) - known)
        if unknown:
            raise ValueError(f"{where}: unknown key(s) {', '.join(unknown)}; expected "
                             f"{', '.join(sorted(known))}")
        if "registration" not in table:
            raise ValueError(f"{where}.registration: missing (x, y, z, alpha, beta, gamma)")
        for key in ("registration", "probe"):
            if key in table and not isinstance(table[key], list):
                raise ValueError(f"{where}.{key}: expected an array of 6 numbers")
        try:
            return cls(table["registration"], reflectors=table.get("reflectors"),
                       probe=table.get("probe"), probe_length=table.get("probe_length", 100.0),
                       names=table.get("names"), gravity=table.get("gravity_m_s2"))
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None

    def __eq__(self, other: object) -> bool:
        return isinstance(other, TrackerSetup) and self.to_dict() == other.to_dict()

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        what = (f"reflectors={self.n_reflectors}" if self.kind == "points"
                else f"probe={self.probe.tolist()}")  # type: ignore[union-attr]
        return f"TrackerSetup(registration={self.registration.tolist()}, {what})"
