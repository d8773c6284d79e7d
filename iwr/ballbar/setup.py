"""The nominal double-ballbar set-ups: for each, where its two balls are and how far the bar
telescopes (docs/ballbar.md)."""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..tracker.setup import _numbers

__all__ = ["BallbarSetup", "BarSetup", "MISFIT_CAUSES"]

#: What makes a model not fit ballbar data, most likely first (the fit test's causes: pose and
#: tracker data have theirs, :data:`iwr.fit_test.MISFIT_CAUSES`).
MISFIT_CAUSES = ("a set-up's balls or the bar's length offset far from their nominal values (a "
                 "set-up's rows labelled with another's name), columns swapped or in the wrong "
                 "unit, noise larger than stated, an effect of the loads or temperatures the "
                 "model leaves out, or a local minimum (try another method or start)")

#: Default half-widths of the search bounds of a set-up's parameters: the balls' centres (mm)
#: and the bar's length offset (mm).
BALL_BOUND_MM = 2.0
OFFSET_BOUND_MM = 1.0
#: The parameters of one set-up, after its name: the platform ball's offset in {5}, the fixed
#: ball's in {0}, the bar's length offset.
_FIELDS = ("px", "py", "pz", "fx", "fy", "fz", "offset")
_NAME_RE = re.compile(r"^[A-Za-z0-9_-]{1,40}$")
_KEYS = {"platform_ball", "fixed_ball", "range", "offset"}


@dataclass(frozen=True)
class BarSetup:
    """One placement of the bar: ``platform_ball`` (mm, in the platform frame {5}),
    ``fixed_ball`` (mm, in the world frame {0}: the cup on the base or the table), the bar's
    measuring ``range`` ``(shortest, longest)`` centre distance (mm; None: any) and the nominal
    length ``offset`` (mm: the reading minus the centre distance, the bar's zero error)."""

    name: str
    platform_ball: tuple[float, float, float]
    fixed_ball: tuple[float, float, float]
    range: tuple[float, float] | None = None
    offset: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"platform_ball": [float(v) for v in self.platform_ball],
                             "fixed_ball": [float(v) for v in self.fixed_ball]}
        if self.range is not None:
            d["range"] = [float(v) for v in self.range]
        d["offset"] = float(self.offset)
        return d


def _bar(name: Any, table: Any, where: str) -> BarSetup:
    if not isinstance(name, str) or not _NAME_RE.match(name):
        raise ValueError(f"{where}: set-up name {name!r}; expected 1 to 40 letters, digits, '_' "
                         "or '-'")
    if not isinstance(table, Mapping):
        raise ValueError(f"{where}: expected a table (platform_ball, fixed_ball, range, offset), "
                         f"got {type(table).__name__}")
    unknown = sorted(set(table) - _KEYS)
    if unknown:
        raise ValueError(f"{where}.{unknown[0]}: unknown key; allowed: {', '.join(sorted(_KEYS))}")
    for key in ("platform_ball", "fixed_ball"):
        if key not in table:
            raise ValueError(f"{where}.{key}: missing (x, y, z in mm, in "
                             f"{'{5}' if key == 'platform_ball' else '{0}'})")
    p = _numbers(table["platform_ball"], 3, f"{where}.platform_ball", "x, y, z in mm, in {5}")
    f = _numbers(table["fixed_ball"], 3, f"{where}.fixed_ball", "x, y, z in mm, in {0}")
    rng = None
    if "range" in table:
        r = _numbers(table["range"], 2, f"{where}.range", "shortest, longest centre distance "
                     "in mm")
        if not 0 <= r[0] < r[1]:
            raise ValueError(f"{where}.range: {r.tolist()}; expected 0 <= shortest < longest (mm)")
        rng = (float(r[0]), float(r[1]))
    off = _numbers([table.get("offset", 0.0)], 1, f"{where}.offset", "mm")[0]
    return BarSetup(name, tuple(float(v) for v in p), tuple(float(v) for v in f),  # type: ignore[arg-type]
                    rng, float(off))


class BallbarSetup:
    """The nominal set-ups of a double ballbar (docs/ballbar.md), the robot TOML's ``[ballbar]``
    table: one sub-table per set-up, ``[ballbar.NAME]`` with ``platform_ball`` (x, y, z in mm,
    in {5}), ``fixed_ball`` (in {0}), optional ``range`` (the bar's shortest and longest centre
    distance, mm; simulated poses stay within it) and ``offset`` (the nominal length offset, mm,
    default 0).

    Every set-up has its own unknowns, appended to the robot's ``4 n + 42`` error parameters in
    set-up order: ``ballbar.NAME.px, .py, .pz`` (the platform ball's correction in {5}, mm),
    ``.fx, .fy, .fz`` (the fixed ball's in {0}, mm) and ``.offset`` (the length offset's, mm). A
    reading is the centre distance plus the length offset."""

    def __init__(self, bars: Any) -> None:
        if isinstance(bars, Mapping):
            bars = [_bar(k, v, f"ballbar.{k}") for k, v in bars.items()]
        bars = list(bars)
        if not bars:
            raise ValueError("ballbar: no set-up; expected at least one [ballbar.NAME] table "
                             "(platform_ball, fixed_ball)")
        for b in bars:
            if not isinstance(b, BarSetup):
                raise TypeError(f"ballbar: expected BarSetup items, got {type(b).__name__}")
        names = [b.name for b in bars]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"ballbar: set-up name {dup[0]!r} given twice")
        self.bars: list[BarSetup] = bars

    @classmethod
    def from_dict(cls, table: Any, where: str = "ballbar") -> BallbarSetup:
        """Read the ``[ballbar]`` table (its sub-tables are the set-ups); errors name the key."""
        if not isinstance(table, Mapping):
            raise ValueError(f"{where}: expected a table of set-ups ([{where}.NAME]), got "
                             f"{type(table).__name__}")
        for key, value in table.items():
            if not isinstance(value, Mapping):
                raise ValueError(f"{where}.{key}: expected a set-up table [{where}.{key}] with "
                                 "platform_ball and fixed_ball, got a "
                                 f"{type(value).__name__}")
        return cls([_bar(k, v, f"{where}.{k}") for k, v in table.items()])

    def to_dict(self) -> dict[str, Any]:
        return {b.name: b.to_dict() for b in self.bars}

    def __eq__(self, other: object) -> bool:
        return isinstance(other, BallbarSetup) and self.to_dict() == other.to_dict()

    __hash__ = None  # type: ignore[assignment]

    # -- sizes and names ----------------------------------------------------------------------
    @property
    def n_setups(self) -> int:
        return len(self.bars)

    @property
    def names(self) -> list[str]:
        return [b.name for b in self.bars]

    @property
    def n_params(self) -> int:
        """7 per set-up."""
        return len(_FIELDS) * self.n_setups

    @property
    def parameter_names(self) -> list[str]:
        return [f"ballbar.{b.name}.{f}" for b in self.bars for f in _FIELDS]

    @property
    def angle_parameters(self) -> np.ndarray:
        """Which set-up parameters are angles: none (centres and offsets in mm)."""
        return np.zeros(self.n_params, dtype=bool)

    def default_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """+-2 mm for each ball's centre, +-1 mm for the length offset, about the nominal."""
        half = np.tile([BALL_BOUND_MM] * 6 + [OFFSET_BOUND_MM], self.n_setups)
        return -half, half

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"set-up {name!r}: not one of the robot's ballbar set-ups "
                             f"({', '.join(self.names)})") from None

    # -- values at a parameter vector ----------------------------------------------------------
    def split(self, x_setup: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(platform_balls (S, 3) in {5}, fixed_balls (S, 3) in {0}, offsets (S,))``: the
        nominal values corrected by the set-ups' part of ``x`` (None: nominal)."""
        p = np.array([b.platform_ball for b in self.bars], dtype=float)
        f = np.array([b.fixed_ball for b in self.bars], dtype=float)
        o = np.array([b.offset for b in self.bars], dtype=float)
        if x_setup is not None:
            xs = np.asarray(x_setup, dtype=float)
            if xs.shape != (self.n_params,):
                raise ValueError(f"x (set-up part): shape {xs.shape}; expected ({self.n_params},)")
            xs = xs.reshape(self.n_setups, len(_FIELDS))
            p, f, o = p + xs[:, :3], f + xs[:, 3:6], o + xs[:, 6]
        return p, f, o

    def with_parameters(self, x_setup: Any) -> BallbarSetup:
        """The set-ups whose nominal values are these corrected by ``x_setup`` (the calibrated
        balls and offsets, to write with the calibrated robot)."""
        p, f, o = self.split(x_setup)
        return BallbarSetup([BarSetup(b.name, tuple(map(float, p[i])), tuple(map(float, f[i])),
                                      b.range, float(o[i]))  # type: ignore[arg-type]
                             for i, b in enumerate(self.bars)])

    def __repr__(self) -> str:
        return f"BallbarSetup({', '.join(self.names)})"

