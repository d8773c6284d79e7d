"""The robot TOML file (docs/data.md): read within its size and key limits and checked key by
key (errors name the file and the key) into the arguments of :class:`iwr.Robot`, and written
out laid out for hand editing. :meth:`iwr.Robot.from_toml`, :meth:`~iwr.Robot.from_dict` and
:meth:`~iwr.Robot.to_toml` are this module's entry points."""

from __future__ import annotations

import datetime
import json
import math
import os
import re
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from . import kinds
from ._io import NotRegularFileError, atomic_write_text, open_regular
from .measurements import MAX_ANGLE_RAD, MAX_LENGTH_MM, MAX_POSE_ANGLE_RAD, METRE_SUSPICION
from .noise import MIN_SIGMA, Noise, TrackerNoise

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["MAX_TOML_BYTES", "MAX_TOML_KEY_PARTS", "RobotFileError", "read_toml",
           "robot_arguments", "write_toml"]


_DH_COLUMNS = ("alpha", "a", "d", "theta")


_DH_ANGLE = {"alpha": True, "a": False, "d": False, "theta": True}


#: The largest magnitude of a nominal DH angle (alpha, theta; rad): a larger one was written in
#: degrees (alpha = 90), as the tracker's setup and the pose data refuse (any angle is within
#: +-2 pi of the same rotation).
MAX_DH_ANGLE_RAD = MAX_POSE_ANGLE_RAD


def dh_degrees_problem(value: float) -> str | None:
    """Why a DH angle ``value`` (rad) looks like degrees (beyond 2 pi), or None."""
    if abs(value) <= MAX_DH_ANGLE_RAD:
        return None
    wrapped = math.remainder(value, 2 * math.pi)
    radians = (f"; or, if it is in radians, write the same rotation within +-pi: {wrapped:.10g}"
               if abs(value) < 4 * math.pi else "")
    return (f"{value:g} is beyond +-2 pi: DH angles are in radians, and this looks like degrees "
            f"({value:g} deg = {math.radians(value):.4f} rad); convert the carriage's alpha and "
            f"theta{radians}")


class RobotFileError(ValueError):
    """A robot TOML file is missing, malformed, or has a missing, unknown or ill-typed key."""


_POSE_UNITS = ["mm"] * 3 + ["rad"] * 3


#: The largest robot TOML file read (a robot description is about 3 kB). The standard library's
#: TOML reader takes seconds per MB of even the simplest keys, so this also bounds its time.
MAX_TOML_BYTES = 256_000


#: The most parts of a dotted key or table header (``a.b.c`` has 3; a robot file needs 2): the
#: standard library's reader takes a time quadratic in them (50,000 parts: minutes).
MAX_TOML_KEY_PARTS = 16


# What may hold a dot that does not separate key parts: strings (multi-line ones first; an
# unterminated one runs to the end of its line or of the file) and comments. The other tokens are
# the characters that end a key (or separate a value from it).
_TOML_TOKENS = re.compile(
    r'"""(?:\\.|[^\\])*?(?:"""|\Z)'
    r"|'''.*?(?:'''|\Z)"
    r'|"(?:\\.|[^"\\\n])*"?'
    r"|'[^'\n]*'?"
    r"|#[^\n]*"
    r"|[.=,\[\]{}\n]",
    re.DOTALL,
)


def _toml_key_too_long(text: str) -> int | None:
    """The line of the first dotted key or table header of more than :data:`MAX_TOML_KEY_PARTS`
    parts in TOML ``text``, else None. A linear scan that skips strings and comments, run before
    the standard library's reader, whose time is quadratic in the parts. A float value (one dot)
    never counts as a long key."""
    parts = 1
    for m in _TOML_TOKENS.finditer(text):
        token = m.group()
        if token == ".":
            parts += 1
            if parts > MAX_TOML_KEY_PARTS:
                return text.count("\n", 0, m.start()) + 1
        elif token[0] not in "\"'#":
            parts = 1
    return None


#: Unit of each field of ``[noise]`` (:class:`iwr.Noise`) and of ``[tracker.noise]``
#: (:class:`iwr.tracker.TrackerNoise`): standard deviations.
_NOISE_UNITS = {"legs": "mm", "joint_lengths": "mm", "joint_angles": "rad", "position": "mm",
                "orientation": "rad"}


_TRACKER_NOISE_UNITS = {"distance": "mm", "distance_per_m": "mm/m", "transverse": "mm",
                        "transverse_per_m": "mm/m", "orientation": "rad"}


def _sigmas(table: Any, where: str, units: Mapping[str, str]) -> dict[str, float]:
    """A table of standard deviations: known keys only, each a finite number >= 0."""
    if not isinstance(table, Mapping):
        raise ValueError(f"{where}: expected a table of standard deviations "
                         f"({', '.join(units)}), got {type(table).__name__} {table!r:.60}")
    out = {}
    for key, value in table.items():
        if key not in units:
            raise ValueError(f"{where}.{key}: unknown key; known: {', '.join(units)} (units: "
                             + ", ".join(f"{k} {u}" for k, u in units.items()) + ")")
        unit = units[key]
        v = _number(value, f"{where}.{key}", "rad" if unit == "rad" else "mm")
        if v < 0:
            raise ValueError(f"{where}.{key}: {value!r} is negative; a standard deviation "
                             f"({unit}) is >= 0")
        if 0 < v < MIN_SIGMA:
            raise ValueError(f"{where}.{key}: {value!r} {unit} is below any instrument's noise; a "
                             f"standard deviation is 0 (none) or at least {MIN_SIGMA:g}")
        out[key] = v
    return out


def _toml_table(name: str, table: Mapping[str, Any]) -> list[str]:
    """Lines of a TOML table ``[name]`` with its sub-tables ``[name.key]``, one key a line."""
    out: list[str] = []
    plain = {k: v for k, v in table.items() if not isinstance(v, Mapping)}
    if plain:
        out += ["", f"[{_toml_key(name)}]"]
        out += [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in plain.items()]
    for key, sub in table.items():
        if isinstance(sub, Mapping):
            out += ["", f"[{_toml_key(name)}.{_toml_key(key)}]"]
            out += [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in sub.items()]
    return out


def _check_keys(table: Any, allowed: set[str], required: set[str], where: str) -> None:
    if not isinstance(table, Mapping):
        raise ValueError(f"{where or 'file'}: expected a table, got {type(table).__name__}")
    prefix = f"{where}." if where else ""
    for key in table:
        if key not in allowed:
            raise ValueError(f"{prefix}{key}: unknown key; allowed: {', '.join(sorted(allowed))}")
    for key in sorted(required):
        if key not in table:
            raise ValueError(f"{prefix}{key}: missing key")


def _number(value: Any, where: str, unit: str = "mm") -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where}: expected a number, got {type(value).__name__} {value!r}")
    try:
        finite = math.isfinite(value)  # an integer beyond a double's range raises
    except OverflowError:
        finite = False
    if not finite:
        shown = value if isinstance(value, float) else f"an integer of {value.bit_length()} bits"
        raise ValueError(f"{where}: {shown} is not a finite double")
    limit = MAX_LENGTH_MM if unit == "mm" else MAX_ANGLE_RAD
    if abs(value) > limit:
        raise ValueError(
            f"{where}: {float(value)!r} {unit} is beyond any robot (|value| <= {limit:g} {unit})"
        )
    return float(value)


def _numbers(value: Any, n: int, where: str, units: list[str] | None = None) -> list[float]:
    if not isinstance(value, list) or len(value) != n:
        raise ValueError(f"{where}: expected an array of {n} numbers, got {value!r}")
    units = units or ["mm"] * n
    return [_number(v, f"{where}[{i}]", u) for i, (v, u) in enumerate(zip(value, units,
                                                                          strict=True))]


def _matrix(value: Any, rows: int, cols: int, where: str) -> list[list[float]]:
    """A matrix of lengths (mm)."""
    if not isinstance(value, list) or len(value) != rows:
        raise ValueError(f"{where}: expected {rows} rows of {cols} numbers")
    return [_numbers(row, cols, f"{where}[{i}]") for i, row in enumerate(value)]


def _stroke(value: Any) -> list[Any]:
    if isinstance(value, list) and len(value) == 2 and not isinstance(value[0], list):
        return _numbers(value, 2, "hexapod.leg_stroke")
    return _matrix(value, 6, 2, "hexapod.leg_stroke")


_PROVENANCE_TYPES = (str, bool, int, float, datetime.date, datetime.time)


def _provenance(value: Any, where: str) -> dict[str, Any]:
    """A flat table of plain values (what TOML can write without nesting)."""
    if not isinstance(value, Mapping):
        raise ValueError(f"{where}: expected a table of values, got {type(value).__name__}")
    out = {}
    for k, v in value.items():
        if not isinstance(k, str) or not k:
            raise ValueError(f"{where}: key {k!r} is not a non-empty string")
        if isinstance(v, np.generic):
            v = v.item()
        if isinstance(v, os.PathLike):
            v = os.fspath(v)
        if not isinstance(v, _PROVENANCE_TYPES):
            raise ValueError(
                f"{where}.{k}: {type(v).__name__} {v!r:.60}; expected a string, number, boolean "
                "or date"
            )
        out[k] = v
    return out


def _toml_key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else _toml_value(key)


def _toml_value(value: Any) -> str:
    """One value in TOML: floats in full precision (repr), strings as basic strings, arrays on
    one line."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        # JSON's escapes are also TOML's; DEL must be escaped too in TOML.
        return json.dumps(value, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(value, (datetime.date, datetime.time)):
        return value.isoformat()
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} as TOML")



def read_toml(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The tables of a robot TOML file, read within :data:`MAX_TOML_BYTES` and
    :data:`MAX_TOML_KEY_PARTS`; :class:`RobotFileError` naming the file (and line) otherwise."""
    path = Path(path)
    try:
        with open_regular(path) as fh:
            # A robot is a few kB: read no more than the limit, so that a wrong file (a device,
            # a data dump) is refused at once instead of being read whole.
            raw = fh.read(MAX_TOML_BYTES + 1)
        if len(raw) > MAX_TOML_BYTES:
            raise RobotFileError(
                f"{path}: larger than {MAX_TOML_BYTES // 1000} kB; a robot description is a "
                "few kB (is this the right file?)"
            )
        text = raw.decode("utf-8")
        line = _toml_key_too_long(text)
        if line is not None:
            raise RobotFileError(
                f"{path}, line {line}: a dotted key or table header of more than "
                f"{MAX_TOML_KEY_PARTS} parts; a robot description needs 2 (is this the right "
                "file?)"
            )
        data = tomllib.loads(text)
    except RobotFileError:
        raise
    except RecursionError:
        raise RobotFileError(
            f"{path}: not a robot description: arrays or tables nested too deeply"
        ) from None
    except FileNotFoundError:
        raise RobotFileError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise RobotFileError(f"{path}: is a folder, not a robot TOML file") from None
    except NotRegularFileError as exc:
        raise RobotFileError(str(exc)) from None
    except UnicodeDecodeError as exc:
        line = exc.object[: exc.start].count(b"\n") + 1
        raise RobotFileError(
            f"{path}, line {line}: not UTF-8 (byte {exc.object[exc.start]:#04x}); TOML files "
            "are UTF-8"
        ) from None
    except tomllib.TOMLDecodeError as exc:
        raise RobotFileError(f"{path}: not valid TOML: {exc}") from None
    except ValueError as exc:  # e.g. an integer literal beyond Python's digit limit
        raise RobotFileError(f"{path}: not readable as TOML: {exc}") from None
    except OSError as exc:
        raise RobotFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    return data


def _arguments(*args: Any, **kwargs: Any) -> tuple[tuple[Any, ...], dict[str, Any]]:
    return args, kwargs


def robot_arguments(data: Mapping[str, Any]) -> tuple[tuple[Any, ...], dict[str, Any]]:
    """The positional and keyword arguments of :class:`iwr.Robot` from the dictionary form of a
    robot (:meth:`iwr.Robot.to_dict`, a TOML file's tables); strict about keys, errors name
    the key."""
    builtin = {"name", "units", "carriage", "hexapod", "provenance", "tracker", "noise",
               "effects"}
    # A table named after a registered measurement kind describes its instrument's set-up.
    tables = [k for k in data if k not in builtin and k in kinds.available()]
    _check_keys(data, builtin | set(tables), {"hexapod"}, "")
    units = data.get("units", {"length": "mm", "angle": "rad"})
    _check_keys(units, {"length", "angle"}, set(), "units")
    if units.get("length", "mm") != "mm" or units.get("angle", "rad") != "rad":
        raise ValueError(
            f"units: {dict(units)}; only length = 'mm', angle = 'rad' are supported"
        )
    name = data.get("name", "robot")
    if not isinstance(name, str):
        raise ValueError(f"name: expected a string, got {type(name).__name__}")
    carriage = data.get("carriage", {"joints": []})
    _check_keys(carriage, {"joints"}, set(), "carriage")
    joints = carriage.get("joints", [])
    if not isinstance(joints, list):
        raise ValueError("carriage.joints: expected an array of tables")
    types, dh, limits = "", [], []
    for i, joint in enumerate(joints):
        where = f"carriage.joints[{i}]"
        _check_keys(joint, {"type", "alpha", "a", "d", "theta", "limits"},
                    {"type", "alpha", "a", "d", "theta", "limits"}, where)
        kind = joint["type"]
        if kind not in ("prismatic", "revolute"):
            raise ValueError(f"{where}.type: {kind!r}; expected 'prismatic' or 'revolute'")
        types += "P" if kind == "prismatic" else "R"
        dh.append([_number(joint[c], f"{where}.{c}", "rad" if _DH_ANGLE[c] else "mm")
                   for c in _DH_COLUMNS])
        for c, v in zip(_DH_COLUMNS, dh[-1], strict=True):
            why = dh_degrees_problem(v) if _DH_ANGLE[c] else None
            if why:
                raise ValueError(f"{where}.{c} (joint {i + 1}): {why}")
        limits.append(_numbers(joint["limits"], 2, f"{where}.limits",
                               ["mm" if kind == "prismatic" else "rad"] * 2))
    hexa = data["hexapod"]
    required = {"base_joints", "platform_joints", "leg_offsets", "leg_stroke"}
    _check_keys(hexa, required | {"home_pose", "workspace"}, required, "hexapod")
    kwargs = {}
    for key in ("home_pose", "workspace"):
        if key in hexa:
            kwargs[key] = _numbers(hexa[key], 6, f"hexapod.{key}", _POSE_UNITS)
    if "noise" in data:
        kwargs["noise"] = Noise(**_sigmas(data["noise"], "noise", _NOISE_UNITS))
    if "tracker" in data:
        from .tracker.setup import TrackerSetup  # here: it imports SciPy, which import iwr must not

        table = data["tracker"]
        if isinstance(table, Mapping) and "noise" in table:
            table = {k: v for k, v in table.items() if k != "noise"}
            kwargs["tracker_noise"] = TrackerNoise(
                **_sigmas(data["tracker"]["noise"], "tracker.noise", _TRACKER_NOISE_UNITS))
        kwargs["tracker"] = TrackerSetup.from_dict(table, "tracker")
        # A bench's noise model is whole or absent: the efficient estimator weighs both.
        if ("noise" in kwargs) != ("tracker_noise" in kwargs):
            given, missing = (("[noise]", "[tracker.noise]") if "noise" in kwargs
                              else ("[tracker.noise]", "[noise]"))
            raise ValueError(
                f"{missing}: missing; a robot with a [tracker] table and a {given} table "
                "needs both: [noise] the leg and joint readings' (legs, joint_lengths, "
                "joint_angles), [tracker.noise] the tracker's (docs/data.md)")
    base = _matrix(hexa["base_joints"], 6, 3, "hexapod.base_joints")
    platform = _matrix(hexa["platform_joints"], 6, 3, "hexapod.platform_joints")
    offsets = _numbers(hexa["leg_offsets"], 6, "hexapod.leg_offsets", ["mm"] * 6)
    stroke = _stroke(hexa["leg_stroke"])
    _check_hexapod(np.array(base), np.array(platform), np.array(offsets), np.array(stroke))
    return _arguments(
        types,
        np.array(dh, dtype=float).reshape(len(types), 4),
        np.array(limits, dtype=float).reshape(len(types), 2),
        base,
        platform,
        offsets,
        stroke,
        name=name,
        provenance=_provenance(data.get("provenance", {}), "provenance"),
        instruments={name: data[name] for name in tables},
        effects=data.get("effects"),
        **kwargs,
    )


#: Joints closer than this fraction of the hexapod's size to a line (or two legs' joints to
#: each other's) make it singular everywhere: no real design is within 0.1 % of that.
DEGENERATE_FRACTION = 1e-3


def _check_hexapod(base: np.ndarray, platform: np.ndarray, offsets: np.ndarray,
                   stroke: np.ndarray) -> None:
    """The hexapod's physical sense, each error naming the key and value: lengths in mm, not
    metres; every leg longer than 0 at its shortest (``leg_offsets + leg_stroke`` lower); no two
    legs joining the same points; neither the base nor the platform joints on one line (the six
    leg lines then all meet that line: a singular hexapod at every pose). A stroke's lower >=
    upper is :class:`iwr.Robot`'s own check."""
    stroke = np.tile(stroke, (6, 1)) if stroke.shape == (2,) else stroke
    lengths = {"base_joints": base, "platform_joints": platform, "leg_offsets": offsets,
               "leg_stroke": stroke}
    largest = max(lengths, key=lambda k: float(np.abs(lengths[k]).max()))
    size = float(np.abs(lengths[largest]).max())
    if size < METRE_SUSPICION:
        raise ValueError(
            f"hexapod: every length (base_joints, platform_joints, leg_offsets, leg_stroke) is "
            f"below {METRE_SUSPICION:g} mm in magnitude (largest hexapod.{largest}: {size:g}): "
            "these look like metres; iwr reads millimetres (multiply them by 1000)")
    shortest = offsets + stroke[:, 0]
    for j in np.flatnonzero(~(shortest > 0)):
        raise ValueError(
            f"hexapod.leg_offsets[{j}]: {offsets[j]:g} mm with hexapod.leg_stroke's lower "
            f"{stroke[j, 0]:g} mm makes leg {j + 1} {shortest[j]:g} mm long at its shortest; a "
            "leg's length (reading + offset) must be > 0 over its stroke")
    tol = DEGENERATE_FRACTION * max(float(np.ptp(base, axis=0).max()),
                                    float(np.ptp(platform, axis=0).max()))
    for i in range(6):
        for j in range(i + 1, 6):
            if (np.linalg.norm(base[i] - base[j]) <= tol
                    and np.linalg.norm(platform[i] - platform[j]) <= tol):
                raise ValueError(
                    f"hexapod.base_joints[{j}] and platform_joints[{j}]: legs {i + 1} and "
                    f"{j + 1} join the same points ({base[j].tolist()} to "
                    f"{platform[j].tolist()}): a copied row? Six distinct legs are needed")
    for key, joints in (("base_joints", base), ("platform_joints", platform)):
        centred = joints - joints.mean(axis=0)
        vt = np.linalg.svd(centred)[2]
        off_line = float(np.linalg.norm(centred - np.outer(centred @ vt[0], vt[0]),
                                        axis=1).max())
        if off_line <= tol:
            raise ValueError(
                f"hexapod.{key}: the six joints lie on one line or coincide (within "
                f"{off_line:.3g} mm; {joints.tolist()}): every leg then meets that line and the "
                "hexapod is singular at every pose; give the six joint centres")


def write_toml(robot: Any, path: str | os.PathLike[str],
               provenance: Mapping[str, Any] | None = None) -> None:
    """Write ``robot`` (an :class:`iwr.Robot`) as TOML, atomically: :meth:`iwr.Robot.to_toml`."""
    prov = _provenance(robot.provenance if provenance is None else provenance, "provenance")
    d = robot.to_dict()
    out = [
        "# iwr robot description. Lengths in mm, angles in rad.",
        "# Carriage: standard DH, A_i = Rz(theta) Tz(d) Tx(a) Rx(alpha); a joint reading adds",
        "# to d (prismatic) or theta (revolute). Hexapod: base_joints a_i in frame {4},",
        "# platform_joints b_i in frame {5}, leg length = reading + leg_offset.",
        f"name = {_toml_value(d['name'])}",
        "",
    ]
    if prov:
        out.append("[provenance]  # where this description comes from; not read as geometry")
        out += [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in prov.items()]
        out.append("")
    out += ["[units]", 'length = "mm"', 'angle = "rad"', ""]
    for joint in d["carriage"]["joints"]:
        out.append("[[carriage.joints]]")
        out += [f"{k} = {_toml_value(v)}" for k, v in joint.items()]
        out.append("")
    out.append("[hexapod]")
    hexa = dict(d["hexapod"])
    stroke = hexa["leg_stroke"]
    if all(row == stroke[0] for row in stroke):
        hexa["leg_stroke"] = stroke[0]  # [lo, hi] for every leg
    for k, v in hexa.items():
        if v and isinstance(v[0], list):
            out.append(f"{k} = [")
            out += [f"    {_toml_value(row)}," for row in v]
            out.append("]")
        else:
            out.append(f"{k} = {_toml_value(v)}")
    if robot.noise is not None:
        out += ["", "[noise]  # standard deviations: legs, joint_lengths, position (mm); "
                "joint_angles, orientation (rad)"]
        out += [f"{k} = {_toml_value(float(v))}" for k, v in d["noise"].items()]
    if robot.tracker is not None:
        out += ["", "[tracker]  # laser tracker: registration = {0} in {T} (x, y, z, alpha, "
                "beta, gamma); reflectors (or probe) in {5}"]
        tnoise = d["tracker"].pop("noise", None)
        for k, v in d["tracker"].items():
            if v and isinstance(v, list) and isinstance(v[0], list):
                out.append(f"{k} = [")
                out += [f"    {_toml_value(row)}," for row in v]
                out.append("]")
            else:
                out.append(f"{k} = {_toml_value(v)}")
        if tnoise is not None:
            out += ["", "[tracker.noise]  # standard deviations: distance, transverse (mm), "
                    "distance_per_m, transverse_per_m (mm per m), orientation (rad)"]
            out += [f"{k} = {_toml_value(float(v))}" for k, v in tnoise.items()]
    for name in robot.instruments:
        out += _toml_table(name, d[name])
    if robot.effects:  # issue 23: the non-geometric effects (docs/effects.md)
        out += _toml_table("effects", d["effects"])
    atomic_write_text(path, "\n".join(out) + "\n")
