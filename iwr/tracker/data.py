"""Tracker measurements: the robot's joint and leg readings with reflector points or probe poses
measured in the tracker frame {T}."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..measurements import RobotReadings, _effect_inputs, as_matrix
from ..transforms import euler_zyx
from .setup import TrackerSetup

__all__ = ["TrackerMeasurements"]


class TrackerMeasurements(RobotReadings):
    """A calibration data set measured with a laser tracker, N poses.

    Parameters
    ----------
    q : array_like, shape (N, n_joints)
        Carriage joint readings (mm, rad).
    legs : array_like, shape (N, 6)
        Leg sensor readings (mm).
    points : array_like, shape (N, K, 3), optional
        Reflector positions measured in the tracker frame {T} (mm); all three coordinates NaN
        where a reflector was not seen at a pose. Reflector k is the setup's reflector k.
    probe : array_like, shape (N, 6), optional
        Instead of points: the probe frame's measured pose in {T}, ``(x, y, z, alpha, beta,
        gamma)`` (mm; Z-Y-X Euler angles, rad).
    joint_types : str, optional
        ``"P"``/``"R"`` per joint, checked against the robot.
    lines, source : optional
        Where each pose comes from in a file (as :class:`iwr.Measurements`).
    point_sigma : array_like, shape (N, K, 3), optional
        With points: each point's standard uncertainties along the x, y and z axes of {T} (mm),
        as tracker software exports them; NaN where the point was not seen, > 0 where it was.
        The efficient estimator weighs each point by them instead of the
        :class:`~iwr.tracker.TrackerNoise` model (docs/data.md).
    payload : array_like, shape (N, 4), optional
        The payload at each pose, mass (kg) and centre of mass in {5} (mm), as
        :class:`iwr.Measurements` has it: what the compliance effect needs (docs/effects.md).
    temperatures : array_like, shape (N,), (N, 1) or (N, 6), optional
        The temperature at each pose, one or one per leg (degrees C): what the thermal effect
        needs.
    """

    def __init__(self, q: Any, legs: Any, *, points: Any = None, probe: Any = None,
                 joint_types: str | None = None, lines: Any = None,
                 source: str | None = None, point_sigma: Any = None, payload: Any = None,
                 temperatures: Any = None) -> None:
        if (points is None) == (probe is None):
            raise ValueError("TrackerMeasurements: give either points (N, K, 3) or probe (N, 6)")
        n = self._set_readings(q, legs, joint_types, lines, source)
        self.points: np.ndarray | None = None
        self.probe: np.ndarray | None = None
        if points is not None:
            try:
                pts = np.array(points, dtype=float)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"points: cannot be read as numbers ({exc})") from None
            if pts.ndim != 3 or pts.shape[0] != n or pts.shape[1] < 1 or pts.shape[2] != 3:
                raise ValueError(f"points: shape {pts.shape}; expected ({n}, K, 3) with K >= 1")
            nan = np.isnan(pts)
            partial = nan.any(axis=2) & ~nan.all(axis=2)
            if partial.any():
                k, i = (int(v) for v in np.argwhere(partial)[0])
                raise ValueError(f"points: pose {k}, reflector {i + 1} has some coordinates NaN "
                                 "and some not; a reflector not seen has all three NaN")
            if np.isinf(pts).any():
                k, i, _ = (int(v) for v in np.argwhere(np.isinf(pts))[0])
                raise ValueError(f"points: pose {k}, reflector {i + 1} is infinite")
            self.kind = "points"
            self.points = pts
        else:
            self.kind = "probe"
            self.probe = as_matrix(probe, 6, "probe", rows=n)
        self.point_sigma: np.ndarray | None = None
        if point_sigma is not None:
            self.point_sigma = self._check_sigma(point_sigma)
        # Issue 23: the loads and temperatures of the non-geometric effects (docs/effects.md).
        self.payload, self.temperatures = _effect_inputs(payload, temperatures, n)

    def _check_sigma(self, point_sigma: Any) -> np.ndarray:
        if self.points is None:
            raise ValueError("point_sigma: only with points, not with a probe")
        sig = np.array(point_sigma, dtype=float)
        if sig.shape != self.points.shape:
            raise ValueError(f"point_sigma: shape {sig.shape}; expected {self.points.shape}, "
                             "the points' shape")
        seen = self.seen
        bad = np.argwhere(seen[:, :, None] & ~(np.isfinite(sig) & (sig > 0)))
        if bad.size:
            k, i, c = (int(v) for v in bad[0])
            raise ValueError(f"point_sigma: pose {k}, reflector {i + 1}, axis {'xyz'[c]} is "
                             f"{float(sig[k, i, c])!r}; a seen point's uncertainty is finite "
                             "and > 0")
        if not np.all(np.isnan(sig[~seen])):
            k, i = (int(v) for v in np.argwhere(~seen & ~np.all(np.isnan(sig), axis=2))[0])
            raise ValueError(f"point_sigma: pose {k}, reflector {i + 1} was not seen, but has an "
                             "uncertainty; give NaN")
        return sig

    def subset(self, rows: Any) -> TrackerMeasurements:
        """The measurements of the poses ``rows`` (indices or a mask), in that order, lines,
        source and uncertainties kept."""
        rows = self._rows(rows)
        lines = self._lines_at(rows)
        sig = None if self.point_sigma is None else self.point_sigma[rows]
        effects = {"payload": None if self.payload is None else self.payload[rows],
                   "temperatures": None if self.temperatures is None else self.temperatures[rows]}
        if self.points is not None:
            return TrackerMeasurements(self.q[rows], self.legs[rows], points=self.points[rows],
                                       joint_types=self.joint_types, lines=lines,
                                       source=self.source, point_sigma=sig, **effects)
        assert self.probe is not None
        return TrackerMeasurements(self.q[rows], self.legs[rows], probe=self.probe[rows],
                                   joint_types=self.joint_types, lines=lines, source=self.source,
                                   **effects)

    @property
    def n_reflectors(self) -> int:
        """K (1 for a probe)."""
        return 1 if self.points is None else int(self.points.shape[1])

    @property
    def seen(self) -> np.ndarray:
        """(N, K) bool: the reflectors seen at each pose (all True for a probe)."""
        if self.points is None:
            return np.ones((len(self), 1), dtype=bool)
        return ~np.isnan(self.points[:, :, 0])

    def check_setup(self, setup: TrackerSetup) -> None:
        """Raise ValueError unless these data are of ``setup``'s kind and number of reflectors."""
        if setup.kind != self.kind:
            raise ValueError(f"measurements: {self.kind} data, but the tracker setup measures "
                             f"{setup.kind}")
        if self.kind == "points" and self.n_reflectors != setup.n_reflectors:
            raise ValueError(f"measurements: {self.n_reflectors} reflectors per pose, but the "
                             f"tracker setup has {setup.n_reflectors}")

    def tracker_points(self, setup: TrackerSetup) -> np.ndarray:
        """The measured points as the objective takes them, (N, 3 n_points), NaN where unseen: the
        reflectors, or the probe's four virtual points (origin, and ``setup.probe_length`` along
        its three axes)."""
        self.check_setup(setup)
        if self.points is not None:
            return np.ascontiguousarray(self.points.reshape(len(self), -1))
        assert self.probe is not None
        r = euler_zyx(self.probe[:, 3], self.probe[:, 4], self.probe[:, 5])
        p = self.probe[:, :3]
        virtual = np.concatenate([p[:, None, :], p[:, None, :] + setup.probe_length
                                  * np.swapaxes(r, 1, 2)], axis=1)
        return np.ascontiguousarray(virtual.reshape(len(self), -1))

    def __repr__(self) -> str:
        what = f"K={self.n_reflectors}" if self.kind == "points" else "probe"
        return f"TrackerMeasurements(n_poses={len(self)}, {what})"
