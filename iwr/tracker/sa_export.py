"""Target lists exported by metrology software (SpatialAnalyzer's ASCII point export with the
"Collection Group Target" name option, and any software that writes the same), read as tracker
point data (docs/data.md, "Tracker-software exports").

One target per line, ``Collection Group Target x y z`` then optional columns (uncertainties, a
time stamp, an RMS), separated by spaces or by commas; lines starting with ``//`` are comments
(the software's version, the working frame, the units). The target names say at which pose and
on which reflector each point was measured, through a pattern the user gives, e.g.
``P{pose}_R{reflector}``. The points are joined to the robot's log of readings exactly as the long
table of points is (:func:`iwr.tracker.files.read_tracker_data`): the same checks, the same
:class:`~iwr.tracker.TrackerMeasurements`.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Iterator
from pathlib import Path

from ..measurements import MAX_LINE_CHARS, MeasurementFileError, _limit_problem, read_csv_text

__all__ = ["DEFAULT_PATTERN", "TargetFormat", "TargetLine", "is_target_export",
           "read_target_lines", "target_values"]

#: The default name pattern: targets named ``P<pose>_R<reflector>``.
DEFAULT_PATTERN = "P{pose}_R{reflector}"
#: Units a target list may be in, and their size in mm.
UNITS_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "um": 1e-3, "in": 25.4, "ft": 304.8}
_UNIT_WORDS = {
    "mm": "mm", "millimeter": "mm", "millimeters": "mm", "millimetre": "mm", "millimetres": "mm",
    "cm": "cm", "centimeter": "cm", "centimeters": "cm", "centimetre": "cm", "centimetres": "cm",
    "m": "m", "meter": "m", "meters": "m", "metre": "m", "metres": "m",
    "um": "um", "micron": "um", "microns": "um", "micrometer": "um", "micrometers": "um",
    "in": "in", "inch": "in", "inches": "in", "ft": "ft", "feet": "ft", "foot": "ft",
}
#: Columns a target list may have after its three names: the point (x, y, z, required), its
#: standard uncertainty (one ``u`` for all three axes, or ``ux uy uz``), and columns read and
#: left aside (``time``, ``rms``, ``-``).
COLUMN_NAMES = ("x", "y", "z", "u", "ux", "uy", "uz", "time", "rms", "-")
_UNITS_COMMENT = re.compile(r"\bunits?\b\W*([A-Za-z]+)", re.IGNORECASE)
_FRAME_COMMENT = re.compile(r"\bframe\b\W*(.+)$", re.IGNORECASE)
_NUMBER_HEAD = re.compile(r"^[+-]?(\d|\.\d)")


@dataclasses.dataclass(frozen=True)
class TargetFormat:
    """How to read a target list.

    ``names``: the pattern of the target names, with ``{pose}`` and ``{reflector}`` once each
    (other text literal); matched against the target name, or against ``Group::Target`` or
    ``Collection::Group::Target`` when it has one or two ``::``. ``columns``: the columns after
    the three names (:data:`COLUMN_NAMES`; x, y, z required). ``units``: the file's length unit
    (:data:`UNITS_MM`), or None to take it from a ``//`` comment that names it (``// Units:
    Millimeters``)."""

    names: str = DEFAULT_PATTERN
    columns: tuple[str, ...] = ("x", "y", "z")
    units: str | None = None

    def __post_init__(self) -> None:
        cols = tuple(self.columns)
        object.__setattr__(self, "columns", cols)
        for c in cols:
            if c not in COLUMN_NAMES:
                raise ValueError(f"target columns: {c!r} is not a column iwr knows; expected "
                                 f"some of {', '.join(COLUMN_NAMES)}")
        named = [c for c in cols if c != "-"]
        if len(named) != len(set(named)):
            raise ValueError(f"target columns: {' '.join(cols)}: a column is named twice")
        if not {"x", "y", "z"} <= set(cols):
            raise ValueError(f"target columns: {' '.join(cols)}: x, y and z are required")
        axes = {"ux", "uy", "uz"} & set(cols)
        if axes and axes != {"ux", "uy", "uz"} or (axes and "u" in cols):
            raise ValueError(f"target columns: {' '.join(cols)}: give the uncertainty as u "
                             "(one for all axes) or as ux, uy and uz")
        if self.units is not None and self.units not in UNITS_MM:
            raise ValueError(f"target units: {self.units!r}; expected one of "
                             f"{', '.join(UNITS_MM)}")
        _compile(self.names)

    @property
    def has_uncertainty(self) -> bool:
        return "u" in self.columns or "ux" in self.columns


def _compile(pattern: str) -> tuple[re.Pattern[str], re.Pattern[str], int]:
    """The lazy and the greedy regular expressions of a name pattern, and its number of
    ``::`` (how many of the three names it matches)."""
    if not isinstance(pattern, str):
        raise ValueError(f"target names: {pattern!r}; expected a pattern such as "
                         f"{DEFAULT_PATTERN!r}")
    parts = re.split(r"(\{[^{}]*\})", pattern)
    fields = [p for p in parts if p.startswith("{")]
    if sorted(fields) != ["{pose}", "{reflector}"]:
        raise ValueError(f"target names: {pattern!r}; expected {{pose}} and {{reflector}} once "
                         f"each (and no other {{...}}), e.g. {DEFAULT_PATTERN!r}")
    depth = pattern.count("::")
    if depth > 2:
        raise ValueError(f"target names: {pattern!r}: at most two '::' (Collection::Group::"
                         "Target)")

    def regex(quant: str) -> re.Pattern[str]:
        out = "".join(f"(?P<{p[1:-1]}>.+{quant})" if p.startswith("{") else re.escape(p)
                      for p in parts)
        return re.compile(out, re.DOTALL)

    return regex("?"), regex(""), depth


@dataclasses.dataclass(frozen=True)
class TargetLine:
    """One target of the list: its line, pose id and reflector name, the raw value fields by
    column (``None`` when the line is malformed: ``problem`` says why)."""

    line: int
    pose: str
    reflector: str
    values: dict[str, str]
    problem: str | None = None


def _comments_and_lines(text: str) -> Iterator[tuple[int, str, bool]]:
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped:
            continue
        yield lineno, stripped, stripped.startswith(("//", "#"))


def _split(line: str) -> list[str]:
    """Fields of a line: comma separated when it has a comma, else by whitespace."""
    if "," in line:
        return [f.strip() for f in line.split(",")]
    return line.split()


def is_target_export(path: str | Path) -> bool:
    """Whether a file looks like a target list: its first line a ``//`` comment, or its first
    line three names then at least three numbers."""
    try:
        text = read_csv_text(Path(path))
    except MeasurementFileError:
        return False
    for _, line, comment in _comments_and_lines(text[:100_000]):
        if line.startswith("//"):
            return True
        if comment:
            continue
        fields = _split(line)
        return len(fields) >= 6 and not _NUMBER_HEAD.match(fields[0]) and all(
            _is_number(f) for f in fields[3:6])
    return False


def _is_number(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False


def read_target_lines(path: str | Path, fmt: TargetFormat) -> tuple[list[TargetLine], str,
                                                                     str | None]:
    """The targets of a list (bounded read; every line checked), its unit (mm per unit, from
    ``fmt.units`` or a ``//`` comment) and its working frame (from a ``//`` comment naming it,
    or None). Malformed lines come back with their ``problem``; a file whose unit is unknown,
    or stated twice differently, raises :class:`iwr.MeasurementFileError`."""
    path = Path(path)
    text = read_csv_text(path)
    lazy, greedy, depth = _compile(fmt.names)
    units, units_line = fmt.units, None
    frame = None
    out: list[TargetLine] = []
    n_fields = 3 + len(fmt.columns)
    expected = f"Collection Group Target {' '.join(fmt.columns)}"
    for lineno, line, comment in _comments_and_lines(text):
        if comment:
            body = line.lstrip("/#").strip()
            m = _UNITS_COMMENT.search(body)
            if m:
                unit = _UNIT_WORDS.get(m.group(1).lower())
                if unit is None:
                    raise MeasurementFileError(
                        f"{path}, line {lineno}: units {m.group(1)!r}: not a length unit iwr "
                        f"knows ({', '.join(UNITS_MM)})")
                if units is not None and unit != units:
                    by = (f"line {units_line}" if units_line is not None
                          else "--target-units")
                    raise MeasurementFileError(
                        f"{path}, line {lineno}: units {m.group(1)!r} ({unit}), but {by} says "
                        f"{units}")
                units, units_line = unit, lineno
            f = _FRAME_COMMENT.search(body)
            if f and frame is None:
                frame = f.group(1).strip()
            continue
        if len(line) > MAX_LINE_CHARS:
            out.append(TargetLine(lineno, "", "", {}, f"line {lineno}: {len(line):,} characters; "
                                  f"a target line has at most {MAX_LINE_CHARS:,}"))
            continue
        fields = _split(line)
        if len(fields) != n_fields:
            more = (" (names with spaces need the comma separator)"
                    if len(fields) > n_fields and "," not in line else "")
            out.append(TargetLine(lineno, "", "", {}, f"line {lineno}: {len(fields)} fields; "
                                  f"expected {n_fields}: {expected}{more}"))
            continue
        names = fields[:3]
        if not all(names):
            out.append(TargetLine(lineno, "", "", {}, f"line {lineno}: an empty name "
                                  "(collection, group and target are all needed)"))
            continue
        name = "::".join(names[2 - depth:])
        a, b = lazy.fullmatch(name), greedy.fullmatch(name)
        if a is None or b is None:
            out.append(TargetLine(lineno, "", "", {}, f"line {lineno}: target {name!r} does not "
                                  f"match the name pattern {fmt.names!r} (--target-names)"))
            continue
        if a.groupdict() != b.groupdict():
            out.append(TargetLine(lineno, "", "", {}, (
                f"line {lineno}: target {name!r} matches the name pattern {fmt.names!r} in "
                f"more than one way (pose {a['pose']!r}, reflector {a['reflector']!r} or pose "
                f"{b['pose']!r}, reflector {b['reflector']!r}): make the pattern's separators "
                "unique")))
            continue
        out.append(TargetLine(lineno, a["pose"], a["reflector"],
                              dict(zip(fmt.columns, fields[3:], strict=True))))
    if units is None:
        raise MeasurementFileError(
            f"{path}: the length unit is not stated: no '// ... Units: ...' comment; give it "
            f"(--target-units {', '.join(UNITS_MM)})")
    if not out:
        raise MeasurementFileError(f"{path}: no target lines ({expected})")
    return out, units, frame


def target_values(t: TargetLine, fmt: TargetFormat, unit: str, problems: list[tuple[int, str]]
                  ) -> tuple[list[float], list[float] | None] | None:
    """The point (mm) and its three standard uncertainties (mm; None without uncertainty
    columns) of a target line; None when a value is bad, each problem recorded with its line in
    ``problems``."""
    scale = UNITS_MM[unit]
    bad = False

    def number(col: str, positive: bool = False) -> float:
        nonlocal bad
        field = t.values[col]
        where = f"line {t.line}, column {col}"
        try:
            v = float(field)
        except ValueError:
            v = math.nan
        if not field or not math.isfinite(v):
            problems.append((t.line, f"{where}: {field!r} is not a number"
                             if field else f"{where}: is empty"))
            bad = True
            return math.nan
        v *= scale
        beyond = _limit_problem(v, "mm")
        if positive and not v > 0:
            beyond = f"{field!r} is not > 0 (a standard uncertainty)"
        if beyond:
            problems.append((t.line, f"{where}: {beyond}"))
            bad = True
        return v

    xyz = [number(c) for c in ("x", "y", "z")]
    sigma = None
    if fmt.has_uncertainty:
        sigma = ([number("u", True)] * 3 if "u" in fmt.columns
                 else [number(c, True) for c in ("ux", "uy", "uz")])
    if "rms" in fmt.columns:
        number("rms")
    return None if bad else (xyz, sigma)
