"""Double-ballbar measurements: the robot's joint and leg readings with one bar reading per pose."""

from __future__ import annotations

from typing import Any

import numpy as np

from .._hooks import hook
from ..measurements import MAX_LENGTH_MM, RobotReadings, _effect_inputs, as_matrix
from .setup import BallbarSetup

__all__ = ["BallbarMeasurements"]


class BallbarMeasurements(RobotReadings):
    """A calibration data set measured with a double ballbar, N poses (docs/ballbar.md).

    Parameters
    ----------
    q : array_like, shape (N, n_joints)
        Carriage joint readings (mm, rad).
    legs : array_like, shape (N, 6)
        Leg sensor readings (mm).
    setup : sequence of str, length N
        The bar set-up each pose was measured in (a name of the robot's ``[ballbar]`` set-ups).
    distance : array_like, shape (N,)
        The bar's reading: the distance between the two balls' centres plus the set-up's length
        offset (mm).
    joint_types, lines, source : optional
        As :class:`iwr.Measurements`.
    payload : array_like, shape (N, 4), optional
        The payload at each pose, mass (kg) and centre of mass in {5} (mm), as
        :class:`iwr.Measurements` holds it (issue 23, docs/effects.md). None: no payload.
    temperatures : array_like, shape (N,), (N, 1) or (N, 6), optional
        Degrees C, one per pose or one per leg (docs/effects.md). None: not measured.
    """

    kind = "ballbar"

    def __init__(self, q: Any, legs: Any, setup: Any, distance: Any, *,
                 joint_types: str | None = None, lines: Any = None,
                 source: str | None = None, payload: Any = None,
                 temperatures: Any = None) -> None:
        n = self._set_readings(q, legs, joint_types, lines, source)
        d = as_matrix(np.asarray(distance, dtype=float).reshape(-1, 1)
                      if np.ndim(distance) == 1 else distance, 1, "distance", rows=n)[:, 0]
        bad = np.flatnonzero(~((d > 0) & (d < MAX_LENGTH_MM)))
        if bad.size:
            raise ValueError(f"distance: pose {int(bad[0])} is {float(d[bad[0]])!r}; a bar "
                             f"reading is a length in mm, > 0 and below {MAX_LENGTH_MM:g}")
        self.distance = np.ascontiguousarray(d)
        if isinstance(setup, str):
            raise ValueError("setup: expected one set-up name per pose, got one string")
        names = np.array([str(s) for s in setup], dtype=object)
        if names.shape != (n,):
            raise ValueError(f"setup: {names.size} names; expected {n}, one per pose")
        self.setup = names
        # Issue 23: the loads and temperatures of the non-geometric effects (docs/effects.md).
        self.payload, self.temperatures = _effect_inputs(payload, temperatures, n)

    def subset(self, rows: Any) -> BallbarMeasurements:
        """The poses ``rows`` (indices or a mask), in that order, lines and source kept."""
        rows = self._rows(rows)
        return BallbarMeasurements(
            self.q[rows], self.legs[rows], self.setup[rows], self.distance[rows],
            joint_types=self.joint_types, lines=self._lines_at(rows), source=self.source,
            payload=None if self.payload is None else self.payload[rows],
            temperatures=None if self.temperatures is None else self.temperatures[rows])

    def to_csv(self, path: Any) -> None:
        """Write the data file (docs/ballbar.md), atomically: :func:`iwr.ballbar.write_ballbar`."""
        hook("write_ballbar")(path, self)  # iwr.ballbar.files, which reads into this class

    def setup_index(self, setup: BallbarSetup) -> np.ndarray:
        """Each pose's set-up as an index into ``setup.bars``; ValueError naming the first pose
        whose set-up the robot does not describe."""
        index = {name: i for i, name in enumerate(setup.names)}
        out = np.empty(len(self), dtype=np.intp)
        for k, name in enumerate(self.setup):
            if name not in index:
                raise ValueError(f"{self.where(k)}: set-up {name!r} is not one of the robot's "
                                 f"[ballbar] set-ups ({', '.join(setup.names)})")
            out[k] = index[name]
        return out

    def __repr__(self) -> str:
        return (f"BallbarMeasurements(n_poses={len(self)}, set-ups="
                f"{sorted(set(self.setup.tolist()))})")
