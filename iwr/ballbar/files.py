"""Double-ballbar data files: one row per pose, the robot's readings, the set-up and the bar's
reading (docs/ballbar.md)."""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path

import numpy as np

from .._io import atomic_write_text
from ..measurements import _JOINT_RE, _LEG_COLUMNS, MeasurementFileError, _summarise
from ..tracker.files import (
    _effect_columns,
    _effect_header,
    _effect_table,
    _effect_values,
    _read_rows,
    _value,
)
from .data import BallbarMeasurements
from .setup import BallbarSetup

__all__ = ["read_ballbar", "write_ballbar", "HEADER_COMMENT"]

HEADER_COMMENT = """\
# iwr double-ballbar data (docs/ballbar.md). Lengths in mm, angles in rad.
# q<i>_<unit>: carriage joint readings; s1_mm .. s6_mm: leg sensor readings;
# setup: the bar set-up (a [ballbar.NAME] of the robot); distance_mm: the bar's reading
#   (the balls' centre distance plus the set-up's length offset).
"""
#: What the header says of the optional columns, when the data have them (issue 23).
EFFECTS_COMMENT = """\
# payload_kg .. payload_z_mm, T_C or T1_C .. T6_C: the payload (mass, centre of mass in {5})
#   and the temperatures of the non-geometric effects (docs/effects.md).
"""


def _columns(joint_types: str) -> list[str]:
    return [*(f"q{i + 1}_{'mm' if t == 'P' else 'rad'}" for i, t in enumerate(joint_types)),
            *_LEG_COLUMNS, "setup", "distance_mm"]


def is_ballbar_file(path: str | os.PathLike[str]) -> bool:
    """Whether a CSV file's header ends with the ballbar's ``setup`` and ``distance_mm``
    columns, without checking the rest."""
    try:
        header, _, _, _ = _read_rows(Path(path))
    except (MeasurementFileError, OSError):
        return False
    return _effect_header(header)[0][-2:] == ["setup", "distance_mm"]


def read_ballbar(path: str | os.PathLike[str], joint_types: str,
                 setup: BallbarSetup) -> BallbarMeasurements:
    """Read a ballbar CSV for a robot with ``joint_types`` and ``setup``; errors name the file,
    the line and the column (every bad cell of the file, summarised)."""
    path = Path(path)
    full, header_line, _, rows = _read_rows(path)
    # The optional payload and temperature columns (issue 23) after the bar's reading.
    header, n_effect = _effect_header(full)
    expected = _columns(joint_types)
    where = f"{path}, line {header_line}"
    order = "expected columns, in this order: " + ", ".join(expected) + " (docs/ballbar.md)"
    for k, (got, want) in enumerate(zip(header, expected, strict=False)):
        if got != want:
            hint = ""
            if _JOINT_RE.match(got) and _JOINT_RE.match(want):
                hint = " (the robot's joint types say the unit)"
            raise MeasurementFileError(f"{where}, column {k + 1}: {got!r}; {order}{hint}")
    if len(header) != len(expected):
        what = (f"missing column(s) {', '.join(expected[len(header):])}"
                if len(header) < len(expected) else
                f"unknown column(s) {', '.join(header[len(expected):])}")
        raise MeasurementFileError(f"{where}: {what}; {order}")
    n_joints = len(joint_types)
    units = [*("mm" if t == "P" else "rad" for t in joint_types), *["mm"] * 6]
    problems: list[tuple[int, str]] = []
    known = set(setup.names)
    values, names, lines = [], [], []
    for lineno, fields in rows:
        row = [_value(f, u, lineno, header[k], problems) for k, (f, u)
               in enumerate(zip(fields[: n_joints + 6], units, strict=True))]
        name = fields[n_joints + 6]
        if name not in known:
            problems.append((lineno, f"line {lineno}, column setup: {name!r} is not one of the "
                                     f"robot's [ballbar] set-ups ({', '.join(setup.names)})"))
        d = _value(fields[n_joints + 7], "mm", lineno, "distance_mm", problems)
        if d is not None and d <= 0:
            problems.append((lineno, f"line {lineno}, column distance_mm: {d!r}; a bar reading "
                                     "is a length > 0 (mm)"))
        values.append([*row, d])
        names.append(name)
        lines.append(lineno)
    loads = _effect_values(full, rows, n_effect, problems)
    if problems:
        raise MeasurementFileError(f"{path}, {_summarise(problems, 'bad value')}")
    arr = np.array(values, dtype=float)
    return BallbarMeasurements(arr[:, :n_joints], arr[:, n_joints:n_joints + 6], names,
                               arr[:, -1], joint_types=joint_types, lines=lines,
                               source=str(path),
                               **_effect_table(full, n_effect, loads, lines, str(path)))


def write_ballbar(path: str | os.PathLike[str], data: BallbarMeasurements) -> None:
    """Write ballbar data as :func:`read_ballbar` reads them (atomically)."""
    if data.joint_types is None:
        raise ValueError("joint_types: unknown, so the joint units cannot be written")
    buf = io.StringIO()
    buf.write(HEADER_COMMENT)
    effect_cols, effect_vals = _effect_columns(data)
    if effect_cols:
        buf.write(EFFECTS_COMMENT)
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(_columns(data.joint_types) + effect_cols)
    for k in range(len(data)):
        extra = [] if effect_vals is None else [repr(float(v)) for v in effect_vals[k]]
        w.writerow([*(repr(float(v)) for v in data.q[k]), *(repr(float(v)) for v in data.legs[k]),
                    str(data.setup[k]), repr(float(data.distance[k])), *extra])
    atomic_write_text(path, buf.getvalue())
