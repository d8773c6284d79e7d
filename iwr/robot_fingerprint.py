"""The semantic fingerprint of a robot model: what determines a calibration's numbers.

A run (``iwr calibrate``, ``iwr-calibrate``, :func:`iwr.calibrate`) records the model of the
robot it was identified for in its result (the settings' ``robot_model``, :func:`record`), and
``iwr report`` checks that the robot file it is given is that robot (:func:`differences`): a
report rendered against another robot (other nominal geometry, other effects, another tracker
or ballbar set-up) would show wrong numbers without a word.

The model is made of sections, each compared on its own so that a message can say which one
differs and how:

- ``geometry``: the nominal carriage (joint types, DH parameters) and hexapod (joint centres,
  leg offsets): what the error parameters are errors of;
- ``parameters``: the names, in order, of the parameters a result holds (the geometric errors,
  the effects', the instrument set-up's);
- ``effects``: the non-geometric effects switched on and their tables (fixed values, plausible
  ranges, loads);
- ``setup``: the measurement kind and its instrument's nominal set-up (the tracker's
  registration and reflectors or probe, the ballbar's set-ups).

What does not change the numbers is left out: the robot's name, comments and layout of its
file, its ``[provenance]`` and ``[noise]`` tables (a run records the noise model it weighted
by), its joint limits, leg stroke and workspace. Numbers are compared as floats, so ``1200``,
``1200.0`` and ``1.2e3`` are the same value, and a reformatted file the same model; values that
differ by round-off only (:data:`RELATIVE_TOLERANCE`: pi/2 written with 15 significant digits)
are the same too.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from . import kinds
from .effects import parameter_names as effect_parameter_names

__all__ = ["FORMAT", "RELATIVE_TOLERANCE", "SECTIONS", "differences", "fingerprint", "model",
           "record"]

#: The record's format (the settings' ``robot_model.format``).
FORMAT = "iwr-robot-model-1"
#: The sections of the model, in the order messages name them.
SECTIONS = ("geometry", "parameters", "effects", "setup")
#: Two numbers within this of each other relative to the larger (and to 1: mm, rad, ppm/K, ...)
#: are the same value: a file that writes a value with fewer digits (15 significant ones, 2e-16
#: of pi/2 off its double) is the same model; 1e-12 of a 2 m slide is 2 pm.
RELATIVE_TOLERANCE = 1e-12
#: Units of the geometry's values, by key, for messages.
_UNITS = {"alpha": "rad", "theta": "rad", "a": "mm", "d": "mm", "base_joints": "mm",
          "platform_joints": "mm", "leg_offsets": "mm"}


def _plain(value: Any) -> Any:
    """``value`` as JSON values: arrays as lists, every number a float (bools stay bools)."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, float, np.integer, np.floating)):
        return float(value)
    return value


def model(robot: Any) -> dict[str, Any]:
    """The sections of ``robot``'s model (see the module's description), as plain JSON values."""
    kind = kinds.for_robot(robot)
    geometry = {
        "carriage": [{"type": t, "alpha": row[0], "a": row[1], "d": row[2], "theta": row[3]}
                     for t, row in zip(robot.joint_types, robot.dh, strict=True)],
        "base_joints": robot.base_joints, "platform_joints": robot.platform_joints,
        "leg_offsets": robot.leg_offsets,
    }
    setup: dict[str, Any] = {"kind": kind.name}
    if robot.tracker is not None:
        setup.update(robot.tracker.to_dict())
    for name, instrument in robot.instruments.items():
        setup[name] = instrument.to_dict()
    return _plain({
        "geometry": geometry,
        "parameters": (list(robot.parameter_names) + effect_parameter_names(robot.effects)
                       + list(kind.setup_parameter_names(robot))),
        "effects": {e.name: e.to_dict() for e in robot.effects},
        "setup": setup,
    })


def _digest(value: Any) -> str:
    text = json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def fingerprint(robot: Any) -> str:
    """16 hex digits: the fingerprint of ``robot``'s model (:func:`model`)."""
    return _digest(model(robot))


def geometry_fingerprint(robot: Any) -> str:
    """16 hex digits: the fingerprint of ``robot``'s nominal geometry alone (the ``geometry``
    section): what a calibration file records of the robot its errors are relative to
    (``[provenance] nominal_geometry``), for ``iwr export --nominal``'s check."""
    return _digest(model(robot)["geometry"])


def record(robot: Any) -> dict[str, Any]:
    """What a run records of its robot (the settings' ``robot_model``): the fingerprint, each
    section's, and the model itself (for :func:`differences`' message)."""
    m = model(robot)
    return {"format": FORMAT, "fingerprint": _digest(m),
            "sections": {s: _digest(m[s]) for s in SECTIONS}, "model": m}


def differences(recorded: Mapping[str, Any], robot: Any, *, limit: int = 3) -> list[str]:
    """How ``robot`` differs from the model a run ``recorded`` (:func:`record`): one line per
    difference, ``"<section>: <where> = <robot's value>, the run's robot had <value>"``, at
    most ``limit`` of them per section (then how many more); empty when it is the same model.
    A record without the model itself (only the fingerprints) names the sections that differ."""
    mine = record(robot)
    if recorded.get("fingerprint") == mine["fingerprint"]:
        return []
    theirs = recorded.get("model")
    sections = recorded.get("sections") or {}
    out: list[str] = []
    for s in SECTIONS:
        if isinstance(theirs, Mapping) and s in theirs:
            found: list[str] = []
            if not isinstance(theirs[s], type(mine["model"][s])):  # an edited record
                found.append("differs (the run's record of it is not a model's)")
            elif s == "parameters":
                _names(mine["model"][s], [str(n) for n in theirs[s]], found)
            elif s == "setup" and mine["model"][s].get("kind") != theirs[s].get("kind"):
                found.append(f"{mine['model'][s].get('kind')} data, the run's robot measured "
                             f"{theirs[s].get('kind')} data")  # the rest differs with it
            else:
                _diff(mine["model"][s], _plain(theirs[s]), s, found)
            if not found:
                continue
            more = len(found) - limit
            out.extend(f"{s}: {line}" for line in found[:limit])
            if more > 0:
                out.append(f"{s}: and {more} other difference(s)")
        elif s in sections and sections[s] != mine["sections"][s]:
            out.append(f"{s}: differs (the run recorded only its fingerprint)")
    whole = isinstance(theirs, Mapping) and all(s in theirs for s in SECTIONS)
    if not out and not whole:  # the same sections' fingerprints: a record of another format
        out.append(f"fingerprint {mine['fingerprint']}, the run's robot had "
                   f"{recorded.get('fingerprint')}")
    return out  # empty with the whole model compared: the same values, within round-off


def _names(mine: list[str], theirs: list[str], out: list[str]) -> None:
    """The difference between two lists of parameter names: their lengths, the first name."""
    if mine == theirs:
        return
    first = next((i for i, (a, b) in enumerate(zip(mine, theirs, strict=False)) if a != b),
                 min(len(mine), len(theirs)))
    where = (f"parameter {first + 1} is {mine[first]!r}, the run's robot had "
             f"{theirs[first]!r}" if first < min(len(mine), len(theirs))
             else f"parameter {first + 1} is {mine[first] if first < len(mine) else 'none'!r}"
             f", the run's robot had {theirs[first] if first < len(theirs) else 'none'!r}")
    out.append(f"{len(mine)} parameters, the run's robot had {len(theirs)}; {where}")


def _where(path: str) -> str:
    """A model path as a message says it: ``geometry.carriage[2].a`` -> ``carriage joint 2
    a``."""
    path = path.split(".", 1)[1] if "." in path else path
    if path.startswith("carriage["):
        joint, _, rest = path[len("carriage["):].partition("]")
        return f"carriage joint {joint} {rest.lstrip('.')}".rstrip()
    return path


def _show(value: Any, key: str, digits: int = 12) -> str:
    if isinstance(value, float):
        unit = _UNITS.get(key, "")
        text = f"{value:.{digits}g}"
        return f"{text} {unit}" if unit and math.isfinite(value) else text
    if isinstance(value, list) and len(value) <= 6 and all(isinstance(v, float) for v in value):
        unit = _UNITS.get(key, "")
        return ("[" + ", ".join(f"{v:.{digits}g}" for v in value) + "]"
                + (f" {unit}" if unit else ""))
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        return f"{len(value)} values"
    return json.dumps(value) if not isinstance(value, str) else repr(value)


def _diff(a: Any, b: Any, path: str, out: list[str], key: str = "") -> None:
    """The differences between ``a`` (the robot given) and ``b`` (the run's), as lines."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in list(a) + [k for k in b if k not in a]:
            if path == "effects" and (k in a) != (k in b):
                out.append(f"{k} is {'on' if k in a else 'off'}, the run's robot had it "
                           f"{'on' if k in b else 'off'}")
            elif k not in b:
                out.append(f"{_where(path + '.' + k)} = {_show(a[k], k)}, the run's robot had "
                           "none")
            elif k not in a:
                out.append(f"{_where(path + '.' + k)}: none, the run's robot had "
                           f"{_show(b[k], k)}")
            else:
                _diff(a[k], b[k], f"{path}.{k}", out, k)
        return
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b) and not (
            len(a) <= 6 and all(isinstance(v, float) for v in a + b)):
        for i, (u, v) in enumerate(zip(a, b, strict=True)):
            _diff(u, v, f"{path}[{i + 1}]", out, key)
        return
    if _same(a, b):
        return
    if isinstance(a, list) and isinstance(b, list) and len(a) != len(b):
        out.append(f"{_where(path)}: {len(a)} entries, the run's robot had {len(b)}")
        return
    mine, theirs = _show(a, key), _show(b, key)
    if mine == theirs:  # apart in the last digits only: as many as tell them apart
        mine, theirs = _show(a, key, 17), _show(b, key, 17)
    out.append(f"{_where(path)} = {mine}, the run's robot had {theirs}")


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return (a == b or (math.isnan(a) and math.isnan(b))
                or abs(a - b) <= RELATIVE_TOLERANCE * max(abs(a), abs(b), 1.0))
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(u, v) for u, v in zip(a, b, strict=True))
    return bool(a == b)
