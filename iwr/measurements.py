"""Measurements: joint readings, measured platform poses and leg sensor readings, and their CSV."""

from __future__ import annotations

import csv
import io
import math
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from ._io import atomic_write_text

__all__ = ["Measurements", "MeasurementFileError", "as_matrix"]

_POSE_COLUMNS = ("x_mm", "y_mm", "z_mm", "alpha_rad", "beta_rad", "gamma_rad")
_LEG_COLUMNS = tuple(f"s{j}_mm" for j in range(1, 7))
_WEIGHT_COLUMNS = tuple(f"w{j}" for j in range(1, 7))
_JOINT_RE = re.compile(r"^q(\d+)_(mm|rad)$")

CSV_HEADER_COMMENT = """\
# iwr measurements: one row per measurement pose. Lengths in mm, angles in rad.
# q<i>_<unit>: carriage joint readings (mm for prismatic, rad for revolute joints).
# x_mm .. gamma_rad: the measured platform pose 0T5 in the world frame {0}; orientation as Z-Y-X
#   Euler angles, R = Rz(alpha) Ry(beta) Rx(gamma) (the paper's eq. 6).
# s1_mm .. s6_mm: leg sensor readings (leg length = reading + leg offset l0).
# w1 .. w6 (optional): weights of the leg residuals (1 / variance, relative).
"""


class MeasurementFileError(ValueError):
    """A measurement CSV file is missing or malformed; the message names the file and line."""


def as_matrix(value: Any, cols: int, name: str, rows: int | None = None) -> np.ndarray:
    """``value`` as a C-contiguous (rows, cols) float array of finite numbers, else ValueError."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: cannot be read as numbers ({exc})") from None
    if cols == 0 and arr.ndim == 1 and rows is not None and arr.size == 0:
        arr = np.zeros((rows, 0))
    if arr.ndim != 2 or arr.shape[1] != cols or (rows is not None and arr.shape[0] != rows):
        want = f"({rows if rows is not None else 'N'}, {cols})"
        raise ValueError(f"{name}: shape {arr.shape}; expected {want}")
    bad = np.argwhere(~np.isfinite(arr))
    if bad.size:
        r, c = (int(i) for i in bad[0])
        raise ValueError(f"{name}: row {r}, column {c} is {arr[r, c]}; every value must be finite")
    return np.ascontiguousarray(arr)


class Measurements:
    """A calibration data set of N measurement poses.

    Parameters
    ----------
    q : array_like, shape (N, n_joints)
        Carriage joint readings (mm for prismatic joints, rad for revolute ones).
    poses : array_like, shape (N, 6)
        Measured platform poses in the world frame, rows ``(x, y, z, alpha, beta, gamma)``
        (mm, rad; Z-Y-X Euler angles of eq. 6).
    legs : array_like, shape (N, 6)
        Leg sensor readings (mm).
    joint_types : str, optional
        ``"P"``/``"R"`` per joint, which fixes the joint units in CSV files. Checked against the
        robot when both are known.
    weights : array_like, shape (N, 6), optional
        Non-negative weights of the leg residuals (for example inverse variances).
    """

    def __init__(
        self,
        q: Any,
        poses: Any,
        legs: Any,
        *,
        joint_types: str | None = None,
        weights: Any = None,
    ) -> None:
        self.poses = as_matrix(poses, 6, "poses")
        n = self.poses.shape[0]
        if n == 0:
            raise ValueError("poses: no measurements (0 rows)")
        q_arr = np.asarray(q, dtype=float)
        n_joints = q_arr.shape[1] if q_arr.ndim == 2 else (len(joint_types) if joint_types else 0)
        self.q = as_matrix(q, n_joints, "q", rows=n)
        self.legs = as_matrix(legs, 6, "legs", rows=n)
        if joint_types is not None:
            if len(joint_types) != self.q.shape[1] or any(c not in "PR" for c in joint_types):
                raise ValueError(
                    f"joint_types: {joint_types!r} does not describe {self.q.shape[1]} joints"
                )
        self.joint_types = joint_types
        self.weights = None if weights is None else as_matrix(weights, 6, "weights", rows=n)
        if self.weights is not None and np.any(self.weights < 0):
            r, c = (int(i) for i in np.argwhere(self.weights < 0)[0])
            raise ValueError(f"weights: row {r}, column {c} is negative")

    def __len__(self) -> int:
        return self.poses.shape[0]

    @property
    def n_joints(self) -> int:
        return self.q.shape[1]

    def subset(self, rows: Any) -> Measurements:
        """The measurements at the given row indices (or boolean mask)."""
        idx = np.asarray(rows)
        return Measurements(
            self.q[idx],
            self.poses[idx],
            self.legs[idx],
            joint_types=self.joint_types,
            weights=None if self.weights is None else self.weights[idx],
        )

    def columns(self) -> list[str]:
        """The CSV column names, each with its unit."""
        if self.joint_types is None:
            raise ValueError(
                "joint_types: unknown, so the joint units cannot be written; "
                "pass joint_types='PPRR' (for example) to Measurements"
            )
        cols = [f"q{i + 1}_{'mm' if t == 'P' else 'rad'}" for i, t in enumerate(self.joint_types)]
        cols += list(_POSE_COLUMNS) + list(_LEG_COLUMNS)
        if self.weights is not None:
            cols += list(_WEIGHT_COLUMNS)
        return cols

    def to_csv(self, path: str | os.PathLike[str]) -> None:
        """Write the CSV file (atomically), header first; full double precision."""
        cols = self.columns()
        parts = [self.q, self.poses, self.legs]
        if self.weights is not None:
            parts.append(self.weights)
        data = np.hstack(parts)
        buf = io.StringIO()
        buf.write(CSV_HEADER_COMMENT)
        writer = csv.writer(buf, lineterminator="\n")
        writer.writerow(cols)
        for row in data:
            writer.writerow([repr(float(v)) for v in row])
        atomic_write_text(path, buf.getvalue())

    @classmethod
    def from_csv(cls, path: str | os.PathLike[str]) -> Measurements:
        """Read a CSV written by :meth:`to_csv`. Errors name the file, line and column."""
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise MeasurementFileError(f"{path}: no such file") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise MeasurementFileError(f"{path}: cannot be read ({exc})") from None
        rows = []
        header: list[str] | None = None
        for lineno, line in enumerate(text.splitlines(), start=1):
            stripped = line.strip()
            if not stripped or stripped.startswith("#"):
                continue
            fields = [f.strip() for f in next(csv.reader([line]))]
            if header is None:
                header = fields
                joint_types, weights = _parse_header(header, path, lineno)
                continue
            if len(fields) != len(header):
                raise MeasurementFileError(
                    f"{path}, line {lineno}: {len(fields)} fields; the header has {len(header)}"
                )
            values = []
            for name, field in zip(header, fields):
                try:
                    v = float(field)
                except ValueError:
                    raise MeasurementFileError(
                        f"{path}, line {lineno}, column {name}: {field!r} is not a number"
                    ) from None
                if not math.isfinite(v):
                    raise MeasurementFileError(
                        f"{path}, line {lineno}, column {name}: {field!r} is not finite"
                    )
                values.append(v)
            rows.append(values)
        if header is None:
            raise MeasurementFileError(f"{path}: empty file (no header line)")
        if not rows:
            raise MeasurementFileError(f"{path}: no data rows after the header")
        data = np.array(rows)
        nj = len(joint_types)
        try:
            return cls(
                data[:, :nj],
                data[:, nj : nj + 6],
                data[:, nj + 6 : nj + 12],
                joint_types=joint_types,
                weights=data[:, nj + 12 : nj + 18] if weights else None,
            )
        except ValueError as exc:
            raise MeasurementFileError(f"{path}: {exc}") from None

    def __repr__(self) -> str:
        return f"Measurements(n_poses={len(self)}, joint_types={self.joint_types!r})"


def _parse_header(header: list[str], path: Path, lineno: int) -> tuple[str, bool]:
    joint_types = ""
    i = 0
    while i < len(header) and header[i].startswith("q"):
        m = _JOINT_RE.match(header[i])
        if not m or int(m.group(1)) != i + 1:
            raise MeasurementFileError(
                f"{path}, line {lineno}: column {i + 1} is {header[i]!r}; expected "
                f"'q{i + 1}_mm' or 'q{i + 1}_rad'"
            )
        joint_types += "P" if m.group(2) == "mm" else "R"
        i += 1
    expected = list(_POSE_COLUMNS) + list(_LEG_COLUMNS)
    rest = header[i:]
    weights = len(rest) == len(expected) + 6
    if weights:
        expected += list(_WEIGHT_COLUMNS)
    for k, (got, want) in enumerate(zip(rest, expected)):
        if got != want:
            raise MeasurementFileError(
                f"{path}, line {lineno}: column {i + k + 1} is {got!r}; expected {want!r}"
            )
    if len(rest) != len(expected):
        missing = expected[len(rest) :]
        extra = rest[len(expected) :]
        what = f"missing columns {missing}" if missing else f"unknown columns {extra}"
        raise MeasurementFileError(f"{path}, line {lineno}: {what}")
    return joint_types, weights
