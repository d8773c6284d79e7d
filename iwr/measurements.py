"""Measurements: joint readings, measured platform poses and leg sensor readings, and their CSV."""

from __future__ import annotations

import csv
import io
import math
import os
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ._io import NotRegularFileError, atomic_write_text, available_memory, open_regular

__all__ = ["Measurements", "MeasurementFileError", "RobotReadings", "as_matrix", "joint_readings",
           "MAX_LENGTH_MM", "MAX_ANGLE_RAD", "PLAN_MARKER"]

_POSE_COLUMNS = ("x_mm", "y_mm", "z_mm", "alpha_rad", "beta_rad", "gamma_rad")
_LEG_COLUMNS = tuple(f"s{j}_mm" for j in range(1, 7))
_WEIGHT_COLUMNS = tuple(f"w{j}" for j in range(1, 7))
# Issue 23 (docs/effects.md): the loads and temperatures the non-geometric effects need, optional,
# last: the payload (mass and centre of mass in {5}) and one temperature per pose or per leg.
_PAYLOAD_COLUMNS = ("payload_kg", "payload_x_mm", "payload_y_mm", "payload_z_mm")
_TEMPERATURE_COLUMNS = {1: ("T_C",), 6: tuple(f"T{j}_C" for j in range(1, 7))}
#: The range of a temperature (degrees C) and of a payload's mass (kg) that a measurement can have.
TEMPERATURE_RANGE_C = (-60.0, 200.0)
MAX_PAYLOAD_KG = 1e5
_JOINT_RE = re.compile(r"^q(\d+)_(mm|rad)$")
# Lengths all below this (in what should be millimetres) look like metres.
METRE_SUSPICION = 5.0
#: The largest magnitude of a length (mm) and of an angle (rad) that any robot or instrument can
#: produce: 100 m, and a thousand radians (about 160 turns of a revolute joint). Beyond them a
#: value is a mistake (a wrong unit, a corrupted file), refused where it is read.
MAX_LENGTH_MM = 1e5
MAX_ANGLE_RAD = 1e3
#: The largest magnitude of a measured orientation angle (rad): Euler angles lie within +-pi, and
#: one beyond 2 pi was written in degrees.
MAX_POSE_ANGLE_RAD = 2 * math.pi
#: The largest measurement file read (a million poses take about 300 MB), whatever the memory.
MAX_CSV_BYTES = 1_000_000_000
#: The peak memory of ``iwr calibrate`` per byte of its data file, rounded up: measured 87 for
#: tracker data (3 reflectors; lm and the efficient estimator alike) and 57 for leg data, from
#: 2,000 to 8,000 poses (docs/data.md). A file is refused, before it is read, when this many
#: times its size exceeds the memory available (:func:`data_file_limit`).
MEMORY_PER_DATA_BYTE = 100
#: A measured platform position beyond this many times the hexapod's reach from its base frame
#: is unreachable (Measurements.check).
REACH_SLACK = 10.0
#: The longest line of a measurement file: a row is a few dozen numbers of at most ~25 characters.
MAX_LINE_CHARS = 10_000
#: The first line of a file written by ``iwr plan`` (:meth:`iwr.PosePlan.to_csv`).
PLAN_MARKER = "# iwr plan:"

CSV_HEADER_COMMENT = """\
# iwr measurements: one row per measurement pose. Lengths in mm, angles in rad.
# q<i>_<unit>: carriage joint readings (mm for prismatic, rad for revolute joints).
# x_mm .. gamma_rad: the measured platform pose 0T5 in the world frame {0}; orientation as Z-Y-X
#   Euler angles, R = Rz(alpha) Ry(beta) Rx(gamma) (the paper's eq. 6).
# s1_mm .. s6_mm: leg sensor readings (leg length = reading + leg offset l0).
# w1 .. w6 (optional): weights of the leg residuals (1 / variance, relative).
"""
# Written only when the data have these columns (a file without them stays as it was).
_EFFECT_HEADER_COMMENT = """\
# payload_kg, payload_x_mm .. payload_z_mm (optional): the payload and its centre in {5}.
# T_C or T1_C .. T6_C (optional): the machine's or each leg's temperature (degrees C).
"""


def _limit_problem(value: float, unit: str) -> str | None:
    """Why ``value`` (in ``unit``, "mm" or "rad") is beyond any robot or instrument, or None."""
    limit = MAX_LENGTH_MM if unit == "mm" else MAX_ANGLE_RAD
    if abs(value) <= limit:
        return None
    return f"{value!r} {unit} is beyond any robot or instrument (|value| <= {limit:g} {unit})"


class CellError(ValueError):
    """A value of an array at fault: the array's ``name``, its ``row`` and ``column`` (0-based)
    and ``detail``, what is wrong (the message after the place). The message names the array's
    row and column; a file reader names the file's line and column instead
    (:meth:`in_file`)."""

    def __init__(self, name: str, row: int, column: int, detail: str,
                 message: str | None = None) -> None:
        self.name, self.row, self.column, self.detail = name, row, column, detail
        super().__init__(message or f"{name}: row {row}, column {column}{detail}")

    def in_file(self, path: Any, lines: list[int], columns: dict[str, list[str]],
                quoted: bool = False) -> str | None:
        """The message with the file's place: ``path``, the line of the row (``lines``, a line
        per row) and the header name of the column (``columns``: per array name, its columns'
        names in the file; ``quoted`` as a Python string, as ``iwr legs`` names a targets
        file's columns); None where the array or the place is not in the file."""
        names = columns.get(self.name)
        if names is None or not (0 <= self.row < len(lines) and 0 <= self.column < len(names)):
            return None
        name = repr(names[self.column]) if quoted else names[self.column]
        return f"{path}, line {lines[self.row]}, column {name}{self.detail}"


def _check_limits(arr: np.ndarray, units: list[str], name: str, first: int = 0) -> None:
    """Every column of ``arr`` within the physical limit of its unit, else a ValueError naming the
    first row and column beyond it (``arr``'s column c is column ``first`` + c of the array
    ``name``)."""
    limits = np.array([MAX_LENGTH_MM if u == "mm" else MAX_ANGLE_RAD for u in units])
    bad = np.argwhere(np.abs(arr) > limits)
    if bad.size:
        r, c = (int(i) for i in bad[0])
        why = _limit_problem(float(arr[r, c]), units[c])
        raise CellError(name, r, first + c, f": {why}")


def normalised_weights(weights: np.ndarray, name: str = "weights") -> np.ndarray:
    """Weights checked (finite, >= 0, not all zero) and divided by the largest.

    Weights are relative (inverse variances up to a common factor), so their scale must not change
    the answer: every weight equal gives exactly the unweighted problem, whether it is 1e30 or
    5e-324, and a weight far below the others cannot underflow the cost to zero."""
    if np.any(weights < 0):
        r, c = (int(i) for i in np.argwhere(weights < 0)[0])
        raise CellError(name, r, c, f" is negative ({float(weights[r, c])!r}); weights must be "
                        ">= 0")
    top = float(weights.max())
    if not top > 0:
        raise ValueError(f"{name}: every weight is zero, so no reading counts; weights are "
                         "relative (1 / variance): give the readings that count a weight > 0")
    return weights / top



_ROWS = "expected row indices (integers), a boolean mask of the rows or a slice"


def _row_index(rows: Any, n: int) -> np.ndarray:
    """``rows`` of data of ``n`` rows as an index array: integer indices (negative ones from the
    end, as in NumPy), a boolean mask of exactly ``n`` values, or a slice; an empty list is no
    rows. Anything else is refused naming ``rows``: a fractional or float index (NumPy refuses
    them as indices; truncating 1.7 to 1 would pick another row), a string, booleans mixed with
    integers, a mask of another length, an index out of range, more than one dimension."""
    if isinstance(rows, slice):
        return np.arange(n)[rows]
    if isinstance(rows, (str, bytes)):
        raise ValueError(f"rows: {rows!r}; {_ROWS}")
    try:
        idx = np.asarray(rows)
    except (TypeError, ValueError):  # ragged nesting
        raise ValueError(f"rows: {rows!r:.80}; {_ROWS}") from None
    if idx.ndim != 1:
        one = f" (one row: [{rows!r}])" if idx.ndim == 0 and idx.dtype.kind in "iu" else ""
        raise ValueError(f"rows: {'shape ' + str(idx.shape) if idx.ndim else repr(rows)}; "
                         f"{_ROWS}{one}")
    if idx.dtype == bool:
        if idx.size != n:
            raise ValueError(f"rows: a boolean mask of {idx.size} values for {n} rows; a mask has "
                             "one value per row")
        return idx
    if idx.size == 0:
        return np.zeros(0, dtype=np.intp)
    if idx.dtype.kind not in "iu":  # floats, strings, objects: integers only, as NumPy indexes
        items = list(rows) if isinstance(rows, (list, tuple)) else idx.tolist()
        for k, v in enumerate(items):
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
                why = " (a float index is not rounded)" if isinstance(v, float) else ""
                raise ValueError(f"rows: entry {k} is {v!r}, not an integer index{why}; {_ROWS}")
        # Python integers: any size compares exactly.
        idx = np.array([int(v) for v in items], dtype=object)
    elif isinstance(rows, (list, tuple)):  # [True, 2] is an integer array to NumPy
        for k, v in enumerate(rows):
            if isinstance(v, (bool, np.bool_)):
                raise ValueError(f"rows: entry {k} is {v!r} among integers; {_ROWS} (a mask is "
                                 "all booleans)")
    out = np.flatnonzero((idx < -n) | (idx >= n))
    if out.size:
        k = int(out[0])
        raise IndexError(f"rows: entry {k} is {idx[k]}, beyond the {n} rows (0 to {n - 1}, or "
                         "negative from the end)")
    return idx.astype(np.intp)


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
        raise CellError(name, r, c, f" is {arr[r, c]}; every value must be finite")
    return np.ascontiguousarray(arr)


def as_vector(value: Any, size: int, name: str) -> np.ndarray:
    """``value`` as ``size`` finite numbers, else ValueError naming ``name`` (as
    :func:`as_matrix` names a row of one)."""
    return as_matrix(np.reshape(value, (1, -1)) if np.ndim(value) == 1 else value, size, name,
                     rows=1)[0]


def tool_point(tool: Any, name: str = "tool") -> np.ndarray:
    """``tool`` (None: the origin of {5}) as a point of three finite numbers (mm), else a
    ValueError naming ``name``."""
    return np.zeros(3) if tool is None else as_vector(tool, 3, name)


def joint_readings(q: Any, joint_types: str | None, n: int) -> np.ndarray:
    """The carriage joint readings ``q`` as an (n, n_joints) matrix (:func:`as_matrix`), the
    number of joints from ``q``'s columns (from ``joint_types`` when ``q`` is empty), checked
    against ``joint_types`` (``"P"``/``"R"`` per joint) when given; else ValueError."""
    try:
        shape = np.asarray(q, dtype=float).shape
    except (TypeError, ValueError):
        shape = ()  # not numbers: as_matrix names the problem
    n_joints = shape[1] if len(shape) == 2 else (len(joint_types) if joint_types else 0)
    out = as_matrix(q, n_joints, "q", rows=n)
    if joint_types is not None and (len(joint_types) != n_joints
                                    or any(c not in "PR" for c in joint_types)):
        raise ValueError(f"joint_types: {joint_types!r} does not describe {n_joints} joints")
    return out


class RobotReadings:
    """The robot's own readings at N poses, which every kind of data holds beside its
    instrument's: the carriage joint readings ``q`` (N, n_joints), the leg sensor readings
    ``legs`` (N, 6), the joint types their units were read with (or None), and where each pose
    comes from (``lines`` of the file ``source``), with what every kind's data type does with
    them: its length, :meth:`where` (for messages), the rows of a subset."""

    q: np.ndarray
    legs: np.ndarray
    joint_types: str | None
    lines: np.ndarray | None
    source: str | None

    def _set_readings(self, q: Any, legs: Any, joint_types: str | None, lines: Any,
                      source: str | None) -> int:
        """Check and keep the readings (the legs give N; no pose is an error), the lines and
        the source; returns N."""
        self.legs = as_matrix(legs, 6, "legs")
        n = self.legs.shape[0]
        if n == 0:
            raise ValueError("legs: no measurements (0 rows)")
        self.q = joint_readings(q, joint_types, n)
        self.joint_types = joint_types
        self._set_lines(lines, source, n)
        return n

    def _set_lines(self, lines: Any, source: str | None, n: int) -> None:
        self.lines = None if lines is None else np.asarray(lines, dtype=int).reshape(n)
        self.source = None if source is None else str(source)

    def __len__(self) -> int:
        return int(self.legs.shape[0])

    @property
    def n_poses(self) -> int:
        return len(self)

    @property
    def n_joints(self) -> int:
        return int(self.q.shape[1])

    def where(self, k: int) -> str:
        """Where pose ``k`` comes from: ``"data.csv, line 12"``, or ``"pose 3"``."""
        loc = self._loc(k)
        return f"{self.source}, {loc}" if self.source and self.lines is not None else loc

    def _loc(self, k: int) -> str:
        return f"pose {k}" if self.lines is None else f"line {int(self.lines[k])}"

    def _rows(self, rows: Any) -> np.ndarray:
        """The indices of ``rows`` (indices or a boolean mask), in that order; ValueError when
        none is selected."""
        out = np.arange(len(self))[_row_index(rows, len(self))]
        if out.size == 0:
            raise ValueError("rows: no measurements selected")
        return out

    def _lines_at(self, rows: np.ndarray) -> np.ndarray | None:
        return None if self.lines is None else self.lines[rows]

    def _lines_of(self, rows: Any) -> str:
        rows = [int(k) for k in rows]
        if self.lines is None:
            what = "poses " if len(rows) > 1 else "pose "
            return what + _enumerate([str(k) for k in rows])
        what = "lines " if len(rows) > 1 else "line "
        return what + _enumerate([str(int(self.lines[k])) for k in rows])

    def _error(self, message: str) -> ValueError:
        if self.source:
            return MeasurementFileError(f"{self.source}: {message}")
        return ValueError(message)

    def check_readings(self, robot: Any, tolerance: float = 0.01) -> None:
        """Check the robot's readings against ``robot``, as every kind's data need: the joint
        types; revolute joint readings in degrees (most outside the joint limits, all inside
        them once converted to radians), named by column; every joint reading within
        ``robot.joint_limits`` and leg reading within ``robot.leg_stroke``, each widened by
        ``tolerance`` times the range, for noise (an unreachable pose). Raises
        :class:`MeasurementFileError` (data from a file) or ValueError naming every offending
        line."""
        self._check_joint_types(robot)
        self._raise_unreachable(robot, self._reading_problems(robot, tolerance))

    def _check_joint_types(self, robot: Any) -> None:
        if self.n_joints != robot.n_joints or (
            self.joint_types is not None and self.joint_types != robot.joint_types
        ):
            have = self.joint_types if self.joint_types is not None else f"{self.n_joints} joints"
            raise self._error(
                f"joint types {have!r} (from the units of the q columns: _mm prismatic, _rad "
                f"revolute) do not match robot {robot.name!r}, {robot.joint_types!r}"
            )

    def _reading_problems(self, robot: Any, tolerance: float) -> list[tuple[int, str]]:
        """(pose, message) for every joint and leg reading outside the robot's range; a
        revolute joint's column in degrees is an error of its own."""
        problems: list[tuple[int, str]] = []
        for i in range(robot.n_joints):
            lo, hi = robot.joint_limits[i]
            slack = tolerance * (hi - lo)
            unit = robot.joint_units[i]
            q = self.q[:, i]
            outside = np.flatnonzero((q < lo - slack) | (q > hi + slack))
            # Most of the column outside, and all of it inside once converted: not one reading
            # out of range (that is an unreachable pose), a column in degrees.
            if 2 * outside.size > len(q) and unit == "rad" and np.all(
                    (np.radians(q) >= lo - slack) & (np.radians(q) <= hi + slack)):
                k = int(outside[np.argmax(np.abs(q[outside]))])
                raise self._error(
                    f"column q{i + 1}_rad: joint {i + 1}'s readings look like degrees: "
                    f"{outside.size} of them ({self._lines_of(outside[:3])}"
                    f"{', ...' if outside.size > 3 else ''}) are outside its limits "
                    f"[{lo:.6g}, {hi:.6g}] rad (at {self._loc(k)}: {q[k]:.6g}), and every one is "
                    "within them in degrees; iwr reads radians (multiply by pi / 180)")
            for k in outside:
                problems.append((k, f"{self._loc(k)}: joint {i + 1} reading {q[k]:.6g} "
                                    f"{unit} is outside the joint limits [{lo:.6g}, {hi:.6g}]"))
        for j in range(6):
            lo, hi = robot.leg_stroke[j]
            slack = tolerance * (hi - lo)
            outside = (self.legs[:, j] < lo - slack) | (self.legs[:, j] > hi + slack)
            for k in np.flatnonzero(outside):
                problems.append((k, f"{self._loc(k)}: leg {j + 1} reading {self.legs[k, j]:.6g} mm "
                                    f"is outside the stroke [{lo:.6g}, {hi:.6g}]"))
        return problems

    def _raise_unreachable(self, robot: Any, problems: list[tuple[int, str]]) -> None:
        if problems:
            problems.sort(key=lambda p: p[0])
            rows = sorted({k for k, _ in problems})
            raise self._error(
                f"{len(rows)} unreachable pose(s) for robot {robot.name!r} "
                f"({self._lines_of(rows)}; nothing dropped); first: {problems[0][1]}"
            )


class Measurements(RobotReadings):
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
        Weights of the leg residuals, relative (for example inverse variances): finite, >= 0,
        not all zero. Stored divided by the largest, so that their scale cannot change the
        answer.

    Values beyond any robot or instrument (a length above :data:`MAX_LENGTH_MM`, an angle above
    :data:`MAX_ANGLE_RAD` in magnitude) are refused, naming the row and column.
    lines : array_like of int, shape (N,), optional
        The line of each measurement in its source file (set by :meth:`from_csv`), so that
        messages about a measurement can name its line.
    source : str, optional
        The file the measurements come from.
    payload : array_like, shape (N, 4), optional
        The payload at each pose: its mass (kg, >= 0) and its centre of mass in the platform
        frame {5} (mm); what the compliance effect needs beside the robot's platform mass
        (docs/effects.md). None: no payload.
    temperatures : array_like, shape (N,), (N, 1) or (N, 6), optional
        The machine's temperature at each pose, or each leg's (degrees C): what the thermal
        effect needs.
    """

    #: The kind of these data (:mod:`iwr.kinds`): the platform pose measured in {0}.
    kind = "pose"

    def __init__(
        self,
        q: Any,
        poses: Any,
        legs: Any,
        *,
        joint_types: str | None = None,
        weights: Any = None,
        lines: Any = None,
        source: str | None = None,
        payload: Any = None,
        temperatures: Any = None,
    ) -> None:
        self.poses = as_matrix(poses, 6, "poses")
        n = self.poses.shape[0]
        if n == 0:
            raise ValueError("poses: no measurements (0 rows)")
        self.q = joint_readings(q, joint_types, n)
        self.legs = as_matrix(legs, 6, "legs", rows=n)
        self.joint_types = joint_types
        _check_limits(self.poses, ["mm"] * 3 + ["rad"] * 3, "poses")
        _check_limits(self.legs, ["mm"] * 6, "legs")
        # Joint units unknown: the looser limit (lengths) for every joint.
        _check_limits(self.q, [("mm" if c == "P" else "rad") for c in joint_types]
                      if joint_types else ["mm"] * self.q.shape[1], "q")
        self.weights = None
        if weights is not None:
            self.weights = normalised_weights(as_matrix(weights, 6, "weights", rows=n))
        self._set_lines(lines, source, n)
        self.payload, self.temperatures = _effect_inputs(payload, temperatures, n)

    def subset(self, rows: Any) -> Measurements:
        """The measurements at the given rows: integer indices (in that order; negative ones
        from the end), a boolean mask of one value per row, or a slice. A fractional index, a
        mask of another length or an index beyond the rows is refused, naming it."""
        idx = _row_index(rows, len(self))
        return Measurements(
            self.q[idx],
            self.poses[idx],
            self.legs[idx],
            joint_types=self.joint_types,
            weights=None if self.weights is None else self.weights[idx],
            lines=None if self.lines is None else self.lines[idx],
            source=self.source,
            payload=None if self.payload is None else self.payload[idx],
            temperatures=None if self.temperatures is None else self.temperatures[idx],
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
        if self.payload is not None:
            cols += list(_PAYLOAD_COLUMNS)
        if self.temperatures is not None:
            cols += list(_TEMPERATURE_COLUMNS[self.temperatures.shape[1]])
        return cols

    def to_csv(self, path: str | os.PathLike[str]) -> None:
        """Write the CSV file (atomically), header first; full double precision."""
        cols = self.columns()
        parts = [self.q, self.poses, self.legs]
        if self.weights is not None:
            parts.append(self.weights)
        parts += [a for a in (self.payload, self.temperatures) if a is not None]
        data = np.hstack(parts)
        buf = io.StringIO()
        buf.write(CSV_HEADER_COMMENT)
        if self.payload is not None or self.temperatures is not None:
            buf.write(_EFFECT_HEADER_COMMENT)
        writer = csv.writer(buf, lineterminator="\n")
        writer.writerow(cols)
        for row in data:
            writer.writerow([repr(float(v)) for v in row])
        atomic_write_text(path, buf.getvalue())

    @classmethod
    def from_csv(cls, path: str | os.PathLike[str], robot: Any = None) -> Measurements:
        """Read a measurement CSV file (format: ``docs/data.md``) and check it.

        Nothing is silently dropped: a file with any bad row is refused, and the error names
        the file and every bad line. Checked without a robot: the header (columns and their
        units), that every value is a finite number, exactly repeated poses, and lengths that
        look like metres. With ``robot`` (an :class:`iwr.Robot`), also :meth:`check`: joint
        types, the scale of the lengths against the robot, and joint and leg readings outside
        the robot's limits.

        Raises
        ------
        MeasurementFileError
            With the file, line and column of the problem.
        """
        path = Path(path)
        text = read_csv_text(path)
        rows: list[list[float]] = []
        lines: list[int] = []
        problems: list[tuple[int, str]] = []  # (line, message), every bad row
        header: list[str] | None = None
        units: list[str] = []
        delimiter = ","
        for lineno, fields, delimiter, problem in csv_rows(text, "a measurement row"):
            if problem is not None:
                problems.append((lineno, problem))
                continue
            if header is None:
                header = fields
                joint_types, weights, extra = _parse_header(header, path, lineno, delimiter)
                units = ["mm" if c == "P" else "rad" for c in joint_types]
                units += ["mm"] * 3 + ["rad"] * 3 + ["mm"] * 6 + ["1"] * (6 if weights else 0)
                units += ["1"] * extra[1]  # checked by Measurements (payload, temperatures)
                continue
            if len(fields) != len(header):
                problems.append(
                    (lineno, f"line {lineno}: {len(fields)} fields; the header has {len(header)}")
                )
                continue
            values = []
            for name, field, unit in zip(header, fields, units, strict=True):
                try:
                    v = float(field)
                except ValueError:
                    what = "is empty" if not field else "is not a number"
                    if delimiter != "," and "," in field:
                        what += " (a decimal comma? write numbers with a decimal point)"
                    problems.append((lineno, f"line {lineno}, column {name}: {field!r} {what}"))
                    break
                if not math.isfinite(v):
                    problems.append(
                        (lineno, f"line {lineno}, column {name}: {field!r} is not finite")
                    )
                    break
                beyond = _limit_problem(v, unit) if unit != "1" else None
                if beyond:
                    problems.append((lineno, f"line {lineno}, column {name}: {beyond}"))
                    break
                values.append(v)
            else:
                rows.append(values)
                lines.append(lineno)
        if header is None and not problems:
            raise MeasurementFileError(f"{path}: empty file (no header line)")
        if problems:
            raise MeasurementFileError(f"{path}, {_summarise(problems, 'bad row')}")
        if not rows:
            raise MeasurementFileError(f"{path}: no data rows after the header")
        data = np.array(rows)
        nj = len(joint_types)
        end = nj + 18 if weights else nj + 12
        n_payload, n_extra = extra
        try:
            out = cls(
                data[:, :nj],
                data[:, nj : nj + 6],
                data[:, nj + 6 : nj + 12],
                joint_types=joint_types,
                weights=data[:, nj + 12 : nj + 18] if weights else None,
                lines=lines,
                source=str(path),
                payload=data[:, end : end + 4] if n_payload else None,
                temperatures=(data[:, end + n_payload : end + n_extra]
                              if n_extra > n_payload else None),
            )
        except CellError as exc:
            # The file's line and column, not the array's row and column.
            place = exc.in_file(path, lines, {
                "weights": header[nj + 12 : nj + 18] if weights else [],
                "payload": header[end : end + n_payload],
                "temperatures": header[end + n_payload : end + n_extra]})
            raise MeasurementFileError(place or f"{path}: {exc}") from None
        except ValueError as exc:
            raise MeasurementFileError(f"{path}: {exc}") from None
        out._check_alone()
        if robot is not None:
            out.check(robot)
        return out

    def _check_alone(self) -> None:
        """The checks that need no robot: repeated poses, metres, degrees."""
        # Two real measurements never repeat every joint reading and pose coordinate exactly:
        # such a row is a copy, which would count one pose twice.
        key = np.hstack([self.q, self.poses])
        _, first, inverse, counts = np.unique(
            key, axis=0, return_index=True, return_inverse=True, return_counts=True
        )
        if np.any(counts > 1):
            groups = [np.flatnonzero(inverse.ravel() == g) for g in np.flatnonzero(counts > 1)]
            groups.sort(key=lambda rows: rows[0])
            desc = "; ".join(self._lines_of(rows) for rows in groups[:5])
            more = f" (and {len(groups) - 5} more groups)" if len(groups) > 5 else ""
            raise self._error(
                f"{len(groups)} repeated pose(s): {desc}{more} have exactly the same joint "
                "readings and measured pose; remove the copies (or average repeated measurements)"
            )
        ang = np.abs(self.poses[:, 3:])
        if np.any(ang > MAX_POSE_ANGLE_RAD):
            rows = np.flatnonzero(np.any(ang > MAX_POSE_ANGLE_RAD, axis=1))
            raise self._error(
                f"pose angles larger than 2 pi at {self._lines_of(rows)}: angles must be in "
                "radians, not degrees"
            )
        pos = np.linalg.norm(self.poses[:, :3], axis=1)
        if pos.max() < METRE_SUSPICION and np.abs(self.legs).max() < METRE_SUSPICION:
            raise self._error(
                f"every position and leg reading is below {METRE_SUSPICION} (largest position "
                f"{pos.max():.4g}, largest leg reading {np.abs(self.legs).max():.4g}): these look "
                "like metres; iwr expects millimetres (multiply the lengths by 1000)"
            )

    def check(self, robot: Any, tolerance: float = 0.01) -> None:
        """Check the measurements against a robot; raise naming every offending line.

        Checked: the joint types (from the units of the q columns); lengths that look like
        metres for a robot whose dimensions are in millimetres (every position, leg reading or
        prismatic joint reading below 5 while the robot's are in the hundreds); the readings
        (:meth:`RobotReadings.check_readings`: within the robot's joint limits and leg stroke,
        revolute joints not in degrees); the platform within reach.

        Raises
        ------
        MeasurementFileError or ValueError
            ``MeasurementFileError`` (a ``ValueError``) when the data come from a file.
        """
        self._check_joint_types(robot)
        # -- scale: metres where millimetres are expected --------------------------------------
        t4 = robot.carriage_transform(robot.joint_limits.mean(axis=1))
        p_home = t4[:3, 3] + t4[:3, :3] @ robot.home_pose[:3]
        scale_checks = [
            ("positions", np.linalg.norm(self.poses[:, :3], axis=1), np.linalg.norm(p_home)),
            ("leg readings", np.abs(self.legs).max(axis=1), float(np.ptp(robot.leg_stroke))),
        ]
        prismatic = np.array([c == "P" for c in robot.joint_types], dtype=bool)
        if prismatic.any():
            scale_checks.append((
                "prismatic joint readings",
                np.abs(self.q[:, prismatic]).max(axis=1),
                float(np.ptp(robot.joint_limits[prismatic], axis=1).max()),
            ))
        for what, values, robot_scale in scale_checks:
            if robot_scale > 10 * METRE_SUSPICION and values.max() < METRE_SUSPICION:
                raise self._error(
                    f"every one of the {what} is below {METRE_SUSPICION} (largest "
                    f"{values.max():.4g}) while robot {robot.name!r} is {robot_scale:.4g} mm in "
                    "size: these look like metres; iwr expects millimetres"
                )
        # -- reachability --------------------------------------------------------------------
        problems = self._reading_problems(robot, tolerance)
        # A measured platform farther from the hexapod's base frame {4} than ten times what its
        # joints and longest legs reach: a typo or a unit (issue 26: x_mm = 99999.9 was taken,
        # and reported only after the identification). A frame off by metres is within it: the
        # fit test names that cause.
        reach = float(np.linalg.norm(robot.base_joints, axis=1).max()
                      + np.linalg.norm(robot.platform_joints, axis=1).max()
                      + (robot.leg_offsets + robot.leg_stroke[:, 1]).max())
        origins = (np.array([robot.carriage_transform(qk)[:3, 3] for qk in self.q])
                   if robot.n_joints else np.zeros((len(self), 3)))
        far = np.linalg.norm(self.poses[:, :3] - origins, axis=1)
        for k in np.flatnonzero(far > REACH_SLACK * reach):
            problems.append((k, f"{self._loc(k)}: the measured platform position is "
                                f"{far[k]:.6g} mm from the hexapod's base, beyond its reach "
                                f"({reach:.6g} mm with the longest legs)"))
        self._raise_unreachable(robot, problems)

    def __repr__(self) -> str:
        return f"Measurements(n_poses={len(self)}, joint_types={self.joint_types!r})"


def _enumerate(items: list[str], limit: int = 10) -> str:
    if len(items) > limit:
        items = items[:limit] + [f"... ({len(items) - limit} more)"]
    if len(items) == 1:
        return items[0]
    return ", ".join(items[:-1]) + " and " + items[-1]


def _summarise(problems: list[tuple[int, str]], what: str) -> str:
    """One line: the first problem in full, then the lines of all of them."""
    lines = sorted({line for line, _ in problems})
    first = problems[0][1]
    if len(lines) == 1:
        return first
    return (f"{first} ({len(lines)} {what}s in all, none dropped: lines "
            f"{_enumerate([str(n) for n in lines])})")


def _mb(n: float) -> str:
    return f"{n / 1e6:,.1f} MB" if n < 1e8 else f"{n / 1e6:,.0f} MB"


def data_file_limit() -> tuple[int, str]:
    """The largest data file read, and why: :data:`MAX_CSV_BYTES`, or less when
    :data:`MEMORY_PER_DATA_BYTE` times a file would not fit in the memory available."""
    avail = available_memory()
    by_memory = avail // MEMORY_PER_DATA_BYTE if avail > 0 else MAX_CSV_BYTES
    if by_memory < MAX_CSV_BYTES:
        return int(by_memory), (
            f"the {_mb(avail)} of memory available process data files up to {_mb(by_memory)} "
            f"(calibrating takes about {MEMORY_PER_DATA_BYTE} times a file's size; docs/data.md)")
    return MAX_CSV_BYTES, "is this the right file? (docs/data.md)"


def decode_text(raw: bytes, path: Any) -> str:
    """``raw``, a file people wrote, as UTF-8 text (a byte order mark accepted: spreadsheets write
    one for "CSV UTF-8"); :class:`MeasurementFileError` naming the line and the byte where it is
    not, and what to do (a UTF-16 file, Excel's "Unicode text", named as such)."""
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        if raw[:2] in (b"\xff\xfe", b"\xfe\xff"):
            raise MeasurementFileError(
                f"{path}: a UTF-16 file (a spreadsheet's \"Unicode text\"); iwr reads UTF-8: "
                "save it as \"CSV UTF-8 (comma delimited)\"") from None
        at = exc.start + (3 if raw.startswith(b"\xef\xbb\xbf") else 0)  # after the mark
        line = raw.count(b"\n", 0, at) + 1
        raise MeasurementFileError(
            f"{path}, line {line}: byte 0x{raw[at]:02x} is not UTF-8 text (a file saved "
            "in a Windows or Latin-1 encoding?); iwr reads UTF-8: save it as \"CSV UTF-8\", or "
            "re-encode it (iconv -f latin1 -t utf-8)") from None


def read_csv_text(path: Path, *, plans: bool = False) -> str:
    """The text of a CSV file people wrote: a bounded read (a device or a dump is refused), a byte
    order mark accepted (spreadsheets write one for "CSV UTF-8"), a plan file of ``iwr plan``
    refused with what to do instead (unless ``plans``: ``iwr legs`` takes a plan's poses as
    targets)."""
    try:
        with open_regular(path) as fh:
            # Before reading: what the memory available can process (a file growing meanwhile
            # is cut at the limit and refused below).
            limit, why = data_file_limit()
            size = os.fstat(fh.fileno()).st_size
            if size > limit:
                raise MeasurementFileError(f"{path}: {_mb(size)}; {why}")
            raw = fh.read(limit + 1)
        if len(raw) > limit:
            raise MeasurementFileError(f"{path}: larger than {_mb(limit)}; {why}")
        text = decode_text(raw, path)
    except FileNotFoundError:
        raise MeasurementFileError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise MeasurementFileError(f"{path}: is a folder, not a CSV file") from None
    except NotRegularFileError as exc:
        raise MeasurementFileError(str(exc)) from None
    except OSError as exc:
        raise MeasurementFileError(f"{path}: cannot be read ({exc})") from None
    if not plans and text.lstrip().startswith(PLAN_MARKER):
        raise MeasurementFileError(
            f"{path}: a pose plan written by 'iwr plan' (the poses to measure), not "
            "measurements: drive the robot to each of its poses, record the joint readings, "
            "the six leg readings and what its comment lines say the instrument measures (the "
            "platform pose, reflector points or a probe pose measured by the tracker, or a "
            "ballbar's distance in the pose's set-up), and calibrate with that file (formats: "
            "docs/data.md, docs/tracker.md, docs/ballbar.md)"
        )
    return text


def csv_rows(text: str, row: str = "a row") -> Iterator[tuple[int, list[str], str, str | None]]:
    """The rows of a CSV text as ``(line, fields, separator, problem)``: blank lines and ``#``
    comments skipped, the separator detected on the header line (the first row), fields stripped.
    A line that is no row gives ``problem`` (a message naming the line) and no fields; a huge line
    before the header ends the file (a row is a few dozen numbers: a wrong file, refused before
    it is split into millions of fields)."""
    delimiter = ","
    header_seen = False
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        if len(line) > MAX_LINE_CHARS:
            yield lineno, [], delimiter, (f"line {lineno}: {len(line):,} characters; {row} has "
                                          f"at most {MAX_LINE_CHARS:,}")
            if not header_seen:
                return
            continue
        if not header_seen:
            delimiter = _delimiter(line)
        try:
            fields = [f.strip() for f in next(csv.reader([line], delimiter=delimiter))]
        except csv.Error as exc:
            yield lineno, [], delimiter, f"line {lineno}: not valid CSV ({exc})"
            continue
        header_seen = True
        yield lineno, fields, delimiter, None


def _delimiter(header_line: str) -> str:
    """The separator of a file, from its header line: a comma, or what ``csv.Sniffer`` finds
    among semicolon and tab (spreadsheets in many locales write those)."""
    if "," in header_line:
        return ","
    try:
        return csv.Sniffer().sniff(header_line, delimiters=";\t").delimiter
    except csv.Error:
        return ","


def _effect_inputs(payload: Any, temperatures: Any, n: int) -> tuple[Any, Any]:
    """The payload (N, 4) and temperatures (N, 1 or 6) of :class:`Measurements`, checked."""
    if payload is not None:
        payload = as_matrix(payload, 4, "payload", rows=n)
        bad = np.flatnonzero((payload[:, 0] < 0) | (payload[:, 0] > MAX_PAYLOAD_KG))
        if bad.size:
            mass = float(payload[bad[0], 0])
            expected = f"expected 0 <= mass <= {MAX_PAYLOAD_KG:g} kg"
            raise CellError("payload", int(bad[0]), 0, f" is {mass!r} kg; {expected}",
                            f"payload: row {int(bad[0])}, mass {mass!r} kg; {expected}")
        _check_limits(payload[:, 1:], ["mm"] * 3, "payload", first=1)  # its centre
    if temperatures is not None:
        t = np.array(temperatures, dtype=float)
        t = t.reshape(n, 1) if t.ndim == 1 else t
        cols = t.shape[1] if t.ndim == 2 else 0
        if cols not in (1, 6):
            raise ValueError(f"temperatures: shape {np.shape(temperatures)}; expected ({n},), "
                             f"({n}, 1) (one per pose) or ({n}, 6) (one per leg)")
        temperatures = as_matrix(t, cols, "temperatures", rows=n)
        lo, hi = TEMPERATURE_RANGE_C
        bad = np.argwhere((temperatures < lo) | (temperatures > hi))
        if bad.size:
            r, c = (int(i) for i in bad[0])
            value = float(temperatures[r, c])
            raise CellError("temperatures", r, c, f" is {value!r} degrees C; expected {lo:g} .. "
                            f"{hi:g} (degrees C, not K or F)")
    return payload, temperatures


def effect_columns() -> list[str]:
    """The optional columns of the effects' inputs (issue 23): payload, then temperatures."""
    return [*_PAYLOAD_COLUMNS, *_TEMPERATURE_COLUMNS[1], *_TEMPERATURE_COLUMNS[6]]


def effect_inputs(columns: dict[str, np.ndarray], where: str) -> dict[str, Any]:
    """``payload`` (N, 4) and ``temperatures`` (N, 1 or 6) from the columns of
    :func:`effect_columns` a file has (name -> values), for :class:`Measurements`'s arguments
    of those names (None when absent); ValueError naming ``where`` when a group is partial."""
    out: dict[str, Any] = {"payload": None, "temperatures": None}
    for key, groups in (("payload", [_PAYLOAD_COLUMNS]),
                        ("temperatures", list(_TEMPERATURE_COLUMNS.values()))):
        have = [c for g in groups for c in g if c in columns]
        for group in groups:
            if have and set(have) == set(group):
                out[key] = np.column_stack([columns[c] for c in group])
        if have and out[key] is None:
            raise ValueError(f"{where}: columns {have}: expected all of "
                             + " or ".join(", ".join(g) for g in groups) + " (docs/effects.md)")
    return out


def _strip_effect_columns(rest: list[str]) -> tuple[list[str], tuple[int, int]]:
    """The columns before the optional payload and temperature columns (issue 23), and
    ``(payload columns, payload + temperature columns)``."""
    n_temp = 0
    for cols in _TEMPERATURE_COLUMNS.values():
        if len(rest) >= len(cols) and tuple(rest[len(rest) - len(cols):]) == cols:
            n_temp = len(cols)
    rest = rest[: len(rest) - n_temp]
    n_payload = 4 if tuple(rest[-4:]) == _PAYLOAD_COLUMNS else 0
    return rest[: len(rest) - n_payload], (n_payload, n_payload + n_temp)


def _parse_header(header: list[str], path: Path, lineno: int,
                  delimiter: str = ",") -> tuple[str, bool, tuple[int, int]]:
    where = f"{path}, line {lineno}"
    if delimiter != ",":
        where += f" (separator {'tab' if delimiter == chr(9) else repr(delimiter)})"
    joint_types = ""
    i = 0
    while i < len(header) and _JOINT_RE.match(header[i]):
        m = _JOINT_RE.match(header[i])
        assert m is not None
        if int(m.group(1)) != i + 1:
            raise MeasurementFileError(
                f"{where}: column {i + 1} is {header[i]!r}; expected 'q{i + 1}_mm' or "
                f"'q{i + 1}_rad' (the joints in order, base first). {_expected_order(i)}"
            )
        joint_types += "P" if m.group(2) == "mm" else "R"
        i += 1
    expected = list(_POSE_COLUMNS) + list(_LEG_COLUMNS)
    rest, extra = _strip_effect_columns(header[i:])
    weights = len(rest) == len(expected) + 6 or any(c in _WEIGHT_COLUMNS for c in rest)
    if weights:
        expected += list(_WEIGHT_COLUMNS)
    order = _expected_order(i, weights)
    if len(header) == 1 and delimiter == ",":
        raise MeasurementFileError(
            f"{where}: one column, {header[0][:60]!r}: no separator found; iwr reads "
            f"comma-separated files (or semicolon- or tab-separated ones). {order}"
        )
    if sorted(rest) == sorted(expected) and rest != expected:
        raise MeasurementFileError(
            f"{where}: the columns are all there but in another order. {order}"
        )
    for k, (got, want) in enumerate(zip(rest, expected, strict=False)):
        if got != want:
            raise MeasurementFileError(
                f"{where}: column {i + k + 1} is {got!r}; expected {want!r}. {order}"
            )
    if len(rest) != len(expected):
        missing = expected[len(rest) :]
        extra = rest[len(expected) :]
        what = f"missing columns {missing}" if missing else f"unknown columns {extra}"
        raise MeasurementFileError(f"{where}: {what}. {order}")
    return joint_types, weights, extra


def _expected_order(n_joints: int, weights: bool = False) -> str:
    joints = (", ".join(f"q{i + 1}_mm|rad" for i in range(n_joints)) if n_joints
              else "q1_mm|rad, ...")
    cols = [joints, *_POSE_COLUMNS, *_LEG_COLUMNS]
    if weights:
        cols += list(_WEIGHT_COLUMNS)
    return ("Expected columns, in this order: " + ", ".join(cols)
            + ("" if weights else " (then w1 .. w6, optional)")
            + " (then payload_kg .. payload_z_mm and T_C or T1_C .. T6_C, optional: "
            "docs/effects.md); see docs/data.md")
