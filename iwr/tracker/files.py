"""Tracker data files (docs/tracker.md, "Data files"), read and written in this one place.

- **Wide**: one CSV, one row per pose: ``pose, q1_mm|rad, ..., s1_mm .. s6_mm``, then per
  reflector ``reflector<name>_x_mm, reflector<name>_y_mm, reflector<name>_z_mm`` (empty cells: the
  reflector was not seen), or for a probe ``probe_x_mm .. probe_z_mm, probe_alpha_rad ..
  probe_gamma_rad``.
- **Target list** (as tracker software exports it, :mod:`iwr.tracker.sa_export`):
  ``Collection Group Target x y z ...`` lines, names mapped to pose and reflector by a pattern,
  joined to the log of readings as the long table is.
- **Long** (points as tracker software exports them): ``pose, reflector, x_mm, y_mm, z_mm``, one
  row per measured point, joined by pose id to the robot's log ``pose, q1_mm|rad, ..., s1_mm ..
  s6_mm`` (a second file).

Every bad row is named with its file and line; nothing is dropped silently.
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .._io import atomic_write_text
from ..measurements import (
    _JOINT_RE,
    _LEG_COLUMNS,
    _PAYLOAD_COLUMNS,
    _TEMPERATURE_COLUMNS,
    MAX_POSE_ANGLE_RAD,
    MeasurementFileError,
    _effect_inputs,
    _limit_problem,
    _strip_effect_columns,
    _summarise,
    csv_rows,
    effect_inputs,
    read_csv_text,
)
from .data import TrackerMeasurements
from .sa_export import TargetFormat, is_target_export, read_target_lines, target_values
from .setup import TrackerSetup

__all__ = ["read_tracker_data", "write_tracker_long", "write_tracker_wide", "is_tracker_file"]

_XYZ = ("x", "y", "z")
_PROBE_COLUMNS = tuple(f"probe_{c}_mm" for c in _XYZ) + tuple(
    f"probe_{c}_rad" for c in ("alpha", "beta", "gamma"))
_LONG_POINT_COLUMNS = ("pose", "reflector", "x_mm", "y_mm", "z_mm")
_UNIT_RE = re.compile(r"^(.*)_(m|cm|mm|um|in|deg|rad|mrad)$")

HEADER_COMMENT = """\
# iwr laser-tracker data (docs/tracker.md). Lengths in mm, angles in rad.
# pose: the pose id; q<i>_<unit>: carriage joint readings; s1_mm .. s6_mm: leg sensor readings.
"""


def _read_rows(path: Path) -> tuple[list[str], int, str, list[tuple[int, list[str]]]]:
    """The header, its line, the separator and the data rows ``(line, fields)`` of a CSV file;
    bounded reads, a byte order mark accepted, comments (``#``) and blank lines skipped."""
    text = read_csv_text(path)
    header: list[str] | None = None
    header_line = 0
    delimiter = ","
    rows: list[tuple[int, list[str]]] = []
    problems: list[tuple[int, str]] = []
    for lineno, fields, sep, problem in csv_rows(text):
        delimiter = sep
        if problem is not None:
            problems.append((lineno, problem))
            continue
        if header is None:
            header, header_line = fields, lineno
            continue
        if len(fields) != len(header):
            problems.append((lineno, f"line {lineno}: {len(fields)} fields; the header has "
                                     f"{len(header)}"))
            continue
        rows.append((lineno, fields))
    if problems:
        raise MeasurementFileError(f"{path}, {_summarise(problems, 'bad row')}")
    if header is None:
        raise MeasurementFileError(f"{path}: empty file (no header line)")
    if not rows:
        raise MeasurementFileError(f"{path}: no data rows after the header")
    return header, header_line, delimiter, rows


def is_tracker_file(path: str | os.PathLike[str]) -> bool:
    """Whether a CSV file's header is one of the tracker formats (starts with a ``pose``
    column), without checking the rest."""
    try:
        header, _, _, _ = _read_rows(Path(path))
    except MeasurementFileError:
        return False
    return bool(header) and header[0] == "pose"


def tracker_file_format(path: str | os.PathLike[str]) -> str | None:
    """What makes ``path`` laser-tracker data, for a message refusing it to a robot without a
    ``[tracker]`` table (``"a 'pose' column"``, ``"a target list of tracker software"``), or
    None; an unreadable file is None (its reader names the problem)."""
    try:
        if is_tracker_file(path):
            return "a 'pose' column"
        if is_target_export(path):
            return "a target list of tracker software"
    except OSError:
        pass
    return None


def _value(field: str, unit: str, lineno: int, name: str, problems: list[tuple[int, str]],
           allow_empty: bool = False) -> float | None:
    if not field:
        if allow_empty:
            return math.nan
        problems.append((lineno, f"line {lineno}, column {name}: is empty"))
        return None
    try:
        v = float(field)
    except ValueError:
        problems.append((lineno, f"line {lineno}, column {name}: {field!r} is not a number"))
        return None
    if not math.isfinite(v):
        problems.append((lineno, f"line {lineno}, column {name}: {field!r} is not finite"))
        return None
    beyond = _limit_problem(v, unit)
    if beyond:
        problems.append((lineno, f"line {lineno}, column {name}: {beyond}"))
        return None
    return v


def _probe_degrees(probe: np.ndarray, lineno: int, problems: list[tuple[int, str]]) -> bool:
    """Whether the probe pose of line ``lineno`` has an Euler angle beyond 2 pi, which was
    written in degrees (a problem naming the column); as the pose data's reader refuses."""
    big = np.flatnonzero(np.abs(probe[3:]) > MAX_POSE_ANGLE_RAD)
    if not big.size:
        return False
    c = int(big[0])
    problems.append((lineno, f"line {lineno}, column {_PROBE_COLUMNS[3 + c]}: "
                             f"{probe[3 + c]:g} is beyond 2 pi: angles are in radians, and this "
                             f"looks like degrees ({probe[3 + c]:g} deg = "
                             f"{math.radians(probe[3 + c]):.4f} rad); convert the angle columns"))
    return True


def _check_columns(got: list[str], expected: list[str], where: str, start: int = 0) -> None:
    order = "Expected columns, in this order: " + ", ".join(expected) + "; see docs/tracker.md"
    for k, (g, w) in enumerate(zip(got, expected, strict=False)):
        if g != w:
            mg, mw = _UNIT_RE.match(g), _UNIT_RE.match(w)
            if mg and mw and mg.group(1) == mw.group(1):
                raise MeasurementFileError(
                    f"{where}: column {start + k + 1} is {g!r}, in {mg.group(2)}; iwr reads "
                    f"{mw.group(2)} ({w!r}): convert the file's units. {order}")
            raise MeasurementFileError(
                f"{where}: column {start + k + 1} is {g!r}; expected {w!r}. {order}")
    if len(got) != len(expected):
        missing, extra = expected[len(got):], got[len(expected):]
        what = f"missing columns {missing}" if missing else f"unknown columns {extra}"
        raise MeasurementFileError(f"{where}: {what}. {order}")


def _joint_header(header: list[str], where: str) -> tuple[str, int]:
    """The joint types of the columns after ``pose``; the index of the first leg column."""
    if not header or header[0] != "pose":
        # Leg data (platform poses in {0}, docs/data.md) read for a robot with a [tracker] table:
        # say so, rather than only that a column is missing.
        legs = ("; this looks like data with the platform pose in {0} (x_mm .. gamma_rad, "
                "docs/data.md), which a robot with a [tracker] table does not take: calibrate it "
                "with a robot description without [tracker]"
                if {"x_mm", "gamma_rad"} <= set(header) else "")
        raise MeasurementFileError(
            f"{where}: column 1 is {header[0] if header else ''!r}; expected 'pose' (the pose "
            f"id), then q1_mm|rad, ..., s1_mm .. s6_mm; see docs/tracker.md{legs}")
    types = ""
    i = 1
    while i < len(header) and _JOINT_RE.match(header[i]):
        m = _JOINT_RE.match(header[i])
        assert m is not None
        if int(m.group(1)) != i:
            raise MeasurementFileError(f"{where}: column {i + 1} is {header[i]!r}; expected "
                                       f"'q{i}_mm' or 'q{i}_rad' (the joints in order)")
        types += "P" if m.group(2) == "mm" else "R"
        i += 1
    return types, i


def _readings(header: list[str], rows: list[tuple[int, list[str]]], types: str,
              problems: list[tuple[int, str]]) -> dict[int, tuple[str, list[float]]]:
    """Pose id and joint + leg values of each good row, by line."""
    units = ["mm" if c == "P" else "rad" for c in types] + ["mm"] * 6
    out: dict[int, tuple[str, list[float]]] = {}
    seen: dict[str, int] = {}
    for lineno, fields in rows:
        pose = fields[0]
        if not pose:
            problems.append((lineno, f"line {lineno}, column pose: is empty"))
            continue
        if pose in seen:
            problems.append((lineno, f"line {lineno}: pose {pose!r} again (first at line "
                                     f"{seen[pose]})"))
            continue
        seen[pose] = lineno
        vals = [_value(f, u, lineno, n, problems)
                for f, u, n in zip(fields[1:1 + len(units)], units,
                                   header[1:1 + len(units)], strict=True)]
        if all(v is not None for v in vals):
            out[lineno] = (pose, [float(v) for v in vals])  # type: ignore[arg-type]
    return out


def read_tracker_data(path: str | os.PathLike[str], setup: TrackerSetup,
                      readings: str | os.PathLike[str] | None = None,
                      targets: TargetFormat | None = None) -> TrackerMeasurements:
    """Read tracker data for ``setup``: a wide CSV, or a long table of points (``path``) with the
    robot's log of readings (``readings``), or a target list exported by tracker software
    (``Collection Group Target x y z ...``, :mod:`iwr.tracker.sa_export`; read as ``targets``
    says, else as the default :class:`~iwr.tracker.sa_export.TargetFormat` when the file looks
    like one) with the log of readings. Raises :class:`iwr.MeasurementFileError` naming the file
    and every bad line."""
    path = Path(path)
    if targets is not None or is_target_export(path):
        return _read_targets(path, setup, None if readings is None else Path(readings),
                             targets or TargetFormat())
    header, hline, _, rows = _read_rows(path)
    where = f"{path}, line {hline}"
    if len(header) > 1 and header[1] == "reflector":
        if readings is None:
            raise MeasurementFileError(
                f"{where}: a long table of points (pose, reflector, x_mm, y_mm, z_mm); give the "
                "robot's log of joint and leg readings with it (pose, q1_mm, ..., s1_mm .. "
                "s6_mm; iwr calibrate ROBOT POINTS --readings READINGS)")
        return _read_long(path, header, hline, rows, setup, Path(readings))
    if readings is not None:
        raise MeasurementFileError(f"{where}: readings were given, but this is not a long table "
                                   "of points (pose, reflector, x_mm, y_mm, z_mm)")
    types, i = _joint_header(header, where)
    if setup.kind == "points":
        extra = [f"reflector{n}_{c}_mm" for n in setup.names for c in _XYZ]
    else:
        extra = list(_PROBE_COLUMNS)
    columns, n_effect = _effect_header(header[i:])
    _check_columns(columns, list(_LEG_COLUMNS) + extra, where, i)
    problems: list[tuple[int, str]] = []
    good = _readings(header, rows, types, problems)
    loads = _effect_values(header, rows, n_effect, problems)
    nr = len(types) + 6
    ids, q, legs, meas, lines = [], [], [], [], []
    units = ["mm"] * len(extra) if setup.kind == "points" else ["mm"] * 3 + ["rad"] * 3
    for lineno, fields in rows:
        vals = [_value(f, u, lineno, n, problems, allow_empty=setup.kind == "points")
                for f, u, n in zip(fields[1 + nr: 1 + nr + len(extra)], units, extra,
                                   strict=True)]
        if lineno not in good or any(v is None for v in vals):
            continue
        arr = np.array(vals, dtype=float)
        if setup.kind == "probe" and _probe_degrees(arr, lineno, problems):
            continue
        if setup.kind == "points":
            pts = arr.reshape(-1, 3)
            partial = np.isnan(pts).any(axis=1) & ~np.isnan(pts).all(axis=1)
            if partial.any():
                name = setup.names[int(np.flatnonzero(partial)[0])]
                problems.append((lineno, f"line {lineno}: reflector {name} has some coordinates "
                                         "empty and some not; a reflector not seen has all three "
                                         "empty"))
                continue
            if np.isnan(pts).all():
                problems.append((lineno, f"line {lineno}: no reflector seen at pose "
                                         f"{fields[0]!r}; remove the row"))
                continue
        pose, values = good[lineno]
        ids.append(pose)
        q.append(values[: len(types)])
        legs.append(values[len(types):])
        meas.append(arr)
        lines.append(lineno)
    if problems:
        raise MeasurementFileError(f"{path}, {_summarise(problems, 'bad row')}")
    return _build(setup, types, q, legs, meas, lines, str(path), ids,
                  _effect_table(header, n_effect, loads, lines, str(path)))


def _effect_header(columns: list[str]) -> tuple[list[str], int]:
    """The columns without the optional payload and temperature columns at the end (issue 23,
    docs/effects.md), and how many there are."""
    stripped, (_, n_effect) = _strip_effect_columns(list(columns))
    return stripped, n_effect


def _effect_values(header: list[str], rows: list[tuple[int, list[str]]], n_effect: int,
                   problems: list[tuple[int, str]]) -> dict[int, list[float]]:
    """The payload and temperature values of each row (the last ``n_effect`` fields), by line;
    a bad value is a problem named by line and column."""
    out: dict[int, list[float]] = {}
    if not n_effect:
        return out
    names = header[len(header) - n_effect:]
    for lineno, fields in rows:
        vals = []
        for f, name in zip(fields[len(fields) - n_effect:], names, strict=True):
            try:
                v = float(f)
            except ValueError:
                problems.append((lineno, f"line {lineno}, column {name}: {f!r} is not a number"))
                break
            if not math.isfinite(v):
                problems.append((lineno, f"line {lineno}, column {name}: {f!r} is not finite"))
                break
            vals.append(v)
        else:
            out[lineno] = vals
    return out


def _effect_table(header: list[str], n_effect: int, values: dict[int, list[float]],
                  lines: list[int], source: str) -> dict[str, Any]:
    """``payload`` and ``temperatures`` of :class:`TrackerMeasurements` from the effect columns'
    values of the poses at ``lines`` (none: both None); a value out of range names its line."""
    if not n_effect:
        return {}
    names = header[len(header) - n_effect:]
    cols = {name: np.array([values[ln][c] for ln in lines]) for c, name in enumerate(names)}
    table = effect_inputs(cols, source)
    for k, ln in enumerate(lines):  # the range checks, line by line
        try:
            _effect_inputs(*(None if v is None else v[k:k + 1] for v in table.values()), 1)
        except ValueError as exc:
            raise MeasurementFileError(f"{source}, line {ln}: "
                                       + str(exc).replace("row 0, ", "")) from None
    return table


def _effect_columns(data: TrackerMeasurements) -> tuple[list[str], np.ndarray | None]:
    """The payload and temperature columns of ``data`` (issue 23), and their values."""
    parts = [a for a in (data.payload, data.temperatures) if a is not None]
    if not parts:
        return [], None
    cols = list(_PAYLOAD_COLUMNS) if data.payload is not None else []
    if data.temperatures is not None:
        cols += list(_TEMPERATURE_COLUMNS[data.temperatures.shape[1]])
    return cols, np.hstack(parts)


def _build(setup: TrackerSetup, types: str, q: list[Any], legs: list[Any], meas: list[Any],
           lines: list[int], source: str, ids: list[str],
           loads: dict[str, Any] | None = None) -> TrackerMeasurements:
    loads = loads or {}
    n = len(legs)
    q_arr = np.array(q, dtype=float).reshape(n, len(types))
    _refuse_repeats(np.hstack([q_arr, np.array(legs, dtype=float).reshape(n, 6),
                               np.array(meas, dtype=float).reshape(n, -1)]), lines, ids, source)
    try:
        if setup.kind == "points":
            out = TrackerMeasurements(q_arr, legs, points=np.array(meas).reshape(n, -1, 3),
                                      joint_types=types, lines=lines, source=source, **loads)
        else:
            out = TrackerMeasurements(q_arr, legs, probe=meas, joint_types=types, lines=lines,
                                      source=source, **loads)
    except ValueError as exc:
        raise MeasurementFileError(f"{source}: {exc}") from None
    out.pose_ids = list(ids)  # type: ignore[attr-defined]
    return out


def _refuse_repeats(rows: np.ndarray, lines: list[int], ids: list[str], source: str) -> None:
    """Refuse poses whose readings and measurements repeat another's exactly under another id:
    two real measurements never do, and a copy would count one pose twice (as the leg data's
    reader refuses repeated rows, docs/data.md)."""
    # A reflector not seen (NaN) is the same in both copies: compare it as a value none can have.
    key = np.where(np.isnan(rows), np.inf, rows)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    if not np.any(counts > 1):
        return
    groups = [np.flatnonzero(inverse.ravel() == g) for g in np.flatnonzero(counts > 1)]
    groups.sort(key=lambda rows: rows[0])
    desc = "; ".join(
        "lines " + ", ".join(f"{lines[k]} (pose {ids[k]!r})" for k in g[:5])
        + (f" and {len(g) - 5} more" if len(g) > 5 else "") for g in groups[:5])
    more = f" (and {len(groups) - 5} more groups)" if len(groups) > 5 else ""
    raise MeasurementFileError(
        f"{source}: {len(groups)} repeated pose(s): {desc}{more} have exactly the same joint and "
        "leg readings and measurements under other pose ids; remove the copies (or average "
        "repeated measurements)")


def _read_long(path: Path, header: list[str], hline: int, rows: list[tuple[int, list[str]]],
               setup: TrackerSetup, readings: Path) -> TrackerMeasurements:
    _check_columns(header, list(_LONG_POINT_COLUMNS), f"{path}, line {hline}")
    problems: list[tuple[int, str]] = []

    def parse(lineno: int, fields: list[str]) -> Callable[[], tuple[list[float], None] | None]:
        def values() -> tuple[list[float], None] | None:
            vals = [_value(f, "mm", lineno, n, problems)
                    for f, n in zip(fields[2:], _LONG_POINT_COLUMNS[2:], strict=True)]
            return None if any(v is None for v in vals) else (vals, None)  # type: ignore[misc]
        return values

    entries = [(lineno, fields[0], fields[1], parse(lineno, fields)) for lineno, fields in rows]
    return _join_points(path, entries, setup, readings, problems)


def _read_targets(path: Path, setup: TrackerSetup, readings: Path | None,
                  fmt: TargetFormat) -> TrackerMeasurements:
    """A target list of tracker software (:mod:`iwr.tracker.sa_export`), joined to the log of
    readings as the long table of points is."""
    if readings is None:
        raise MeasurementFileError(
            f"{path}: a target list of tracker software (Collection Group Target x y z); give "
            "the robot's log of joint and leg readings with it (pose, q1_mm, ..., s1_mm .. "
            "s6_mm; iwr calibrate ROBOT TARGETS --readings READINGS --target-names PATTERN)")
    lines, unit, frame = read_target_lines(path, fmt)
    problems = [(t.line, t.problem) for t in lines if t.problem is not None]
    entries = [(t.line, t.pose, t.reflector,
                (lambda t=t: target_values(t, fmt, unit, problems)))
               for t in lines if t.problem is None]
    out = _join_points(path, entries, setup, readings, problems)
    if frame:  # the software's working frame, which the points are in: {T} here
        out.source = f"{out.source} (working frame {frame})"
    return out


def _join_points(path: Path, entries: list[tuple[int, str, str, Callable[[], Any]]],
                 setup: TrackerSetup, readings: Path,
                 problems: list[tuple[int, str]]) -> TrackerMeasurements:
    """Points ``(line, pose, reflector, values)`` joined by pose to the log of readings:
    ``values()`` gives the point (mm) and its three standard uncertainties (or None), or None
    when a value is bad (its problem recorded in ``problems``). Every problem is named by line
    (the points' first, then the log's)."""
    if setup.kind != "points":
        raise MeasurementFileError(f"{path}: a long table of points, but the tracker setup "
                                   "measures a probe: give probe data as one wide CSV")
    rheader, rline, _, rrows = _read_rows(readings)
    rwhere = f"{readings}, line {rline}"
    types, i = _joint_header(rheader, rwhere)
    columns, n_effect = _effect_header(rheader[i:])
    _check_columns(columns, list(_LEG_COLUMNS), rwhere, i)
    rproblems: list[tuple[int, str]] = []
    good = _readings(rheader, rrows, types, rproblems)
    loads = _effect_values(rheader, rrows, n_effect, rproblems)
    if rproblems:
        raise MeasurementFileError(f"{readings}, {_summarise(rproblems, 'bad row')}")
    by_id = {pose: (lineno, vals) for lineno, (pose, vals) in good.items()}
    index = {name: k for k, name in enumerate(setup.names)}
    k_refl = setup.n_reflectors
    points = {pose: np.full((k_refl, 3), np.nan) for pose in by_id}
    sigmas: dict[str, np.ndarray] = {}
    first: dict[tuple[str, str], int] = {}
    for lineno, pose, name, values in entries:
        if pose not in by_id:
            problems.append((lineno, f"line {lineno}: pose {pose!r} is not in {readings}"))
            continue
        if name not in index:
            problems.append((lineno, f"line {lineno}: reflector {name!r} is not in the tracker "
                                     f"setup (reflectors {', '.join(setup.names)})"))
            continue
        if (pose, name) in first:
            problems.append((lineno, f"line {lineno}: reflector {name!r} at pose {pose!r} again "
                                     f"(first at line {first[(pose, name)]})"))
            continue
        first[(pose, name)] = lineno
        got = values()
        if got is not None:
            points[pose][index[name]] = got[0]
            if got[1] is not None:
                sigmas.setdefault(pose, np.full((k_refl, 3), np.nan))[index[name]] = got[1]
    if problems:
        problems.sort(key=lambda p: p[0])
        raise MeasurementFileError(f"{path}, {_summarise(problems, 'bad row')}")
    unseen = [(line, pose) for pose, (line, _) in by_id.items() if np.isnan(points[pose]).all()]
    if unseen:
        raise MeasurementFileError(
            f"{readings}, {_summarise([(ln, f'line {ln}: pose {p!r} has no point in {path}') for ln, p in sorted(unseen)], 'bad row')}")  # noqa: E501
    order = sorted(by_id.items(), key=lambda item: item[1][0])
    nj = len(types)
    rlines = [ln for _, (ln, _) in order]
    out = _build(setup, types, [v[:nj] for _, (_, v) in order],
                 [v[nj:] for _, (_, v) in order], [points[p] for p, _ in order],
                 rlines, f"{readings} + {path}", [p for p, _ in order],
                 _effect_table(rheader, n_effect, loads, rlines, str(readings)))
    if sigmas:
        try:
            out.point_sigma = out._check_sigma([sigmas.get(p, np.full((k_refl, 3), np.nan))
                                                for p, _ in order])
        except ValueError as exc:
            raise MeasurementFileError(f"{path}: {exc}") from None
    return out


def _reading_columns(data: TrackerMeasurements) -> list[str]:
    types = data.joint_types or ""
    if len(types) != data.n_joints:
        raise ValueError("joint_types: unknown, so the joint units cannot be written")
    return ["pose", *[f"q{i + 1}_{'mm' if t == 'P' else 'rad'}" for i, t in enumerate(types)],
            *_LEG_COLUMNS]


def _fmt(v: float) -> str:
    return "" if math.isnan(v) else repr(float(v))


def write_tracker_wide(path: str | os.PathLike[str], setup: TrackerSetup,
                       data: TrackerMeasurements) -> None:
    """Write the wide CSV (atomically); poses numbered 1..N, empty cells for unseen points."""
    data.check_setup(setup)
    cols = _reading_columns(data)
    if setup.kind == "points":
        cols += [f"reflector{n}_{c}_mm" for n in setup.names for c in _XYZ]
        extra = data.points.reshape(len(data), -1)  # type: ignore[union-attr]
    else:
        cols += list(_PROBE_COLUMNS)
        extra = data.probe
    effect_cols, effect_vals = _effect_columns(data)
    if effect_vals is not None:
        cols += effect_cols
        extra = np.hstack([extra, effect_vals])
    buf = io.StringIO()
    buf.write(HEADER_COMMENT)
    buf.write("# then the points measured in the tracker frame {T} (empty: not seen), or the "
              "probe's pose in {T}.\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for k in range(len(data)):
        w.writerow([str(k + 1), *[_fmt(v) for v in data.q[k]], *[_fmt(v) for v in data.legs[k]],
                    *[_fmt(v) for v in extra[k]]])  # type: ignore[index]
    atomic_write_text(path, buf.getvalue())


def write_tracker_long(points_path: str | os.PathLike[str],
                       readings_path: str | os.PathLike[str], setup: TrackerSetup,
                       data: TrackerMeasurements) -> None:
    """Write point data as a long table of points and the robot's log of readings."""
    data.check_setup(setup)
    if setup.kind != "points":
        raise ValueError("write_tracker_long: a probe's poses are written as one wide CSV")
    buf = io.StringIO()
    buf.write(HEADER_COMMENT)
    w = csv.writer(buf, lineterminator="\n")
    effect_cols, effect_vals = _effect_columns(data)
    w.writerow(_reading_columns(data) + effect_cols)
    for k in range(len(data)):
        w.writerow([str(k + 1), *[_fmt(v) for v in data.q[k]], *[_fmt(v) for v in data.legs[k]],
                    *([] if effect_vals is None else [_fmt(v) for v in effect_vals[k]])])
    readings_text = buf.getvalue()
    buf = io.StringIO()
    buf.write("# iwr laser-tracker points in the tracker frame {T} (mm), one row per point seen; "
              "joined by pose to the readings.\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(_LONG_POINT_COLUMNS)
    assert data.points is not None
    for k in range(len(data)):
        for i, name in enumerate(setup.names):
            p = data.points[k, i]
            if not np.isnan(p).any():
                w.writerow([str(k + 1), name, *[_fmt(v) for v in p]])
    atomic_write_text(readings_path, readings_text)
    atomic_write_text(points_path, buf.getvalue())
