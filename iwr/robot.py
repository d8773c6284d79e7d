"""Robot descriptions: a DH carriage carrying a six-legged Stewart hexapod."""

from __future__ import annotations

import copy
import dataclasses
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

from . import _core, kinds
from . import effects as _effects
from ._io import NotRegularFileError, atomic_write_text, open_regular
from .measurements import MAX_ANGLE_RAD, MAX_LENGTH_MM
from .noise import MIN_SIGMA, Noise, TrackerNoise

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["Robot", "RobotFileError"]

_DH_COLUMNS = ("alpha", "a", "d", "theta")
_DH_ANGLE = {"alpha": True, "a": False, "d": False, "theta": True}


class RobotFileError(ValueError):
    """A robot TOML file is missing, malformed, or has a missing, unknown or ill-typed key."""


def _as_array(value: Any, shape: tuple[int, ...], name: str, units: Any = None) -> np.ndarray:
    """``value`` as finite floats of ``shape``; with ``units`` ("mm"/"rad", broadcast along the
    last axis), also within the physical limits (:data:`iwr.measurements.MAX_LENGTH_MM`,
    :data:`~iwr.measurements.MAX_ANGLE_RAD`)."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: cannot be read as numbers ({exc})") from None
    if arr.shape != shape:
        raise ValueError(f"{name}: shape {arr.shape}; expected {shape}")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{name}: entry {tuple(int(i) for i in bad)} is not finite")
    if units is not None and arr.size:
        limit = np.where(np.asarray(units) == "mm", MAX_LENGTH_MM, MAX_ANGLE_RAD)
        over = np.abs(arr) > np.broadcast_to(limit, arr.shape)
        if over.any():
            bad = tuple(int(i) for i in np.argwhere(over)[0])
            unit = np.broadcast_to(np.asarray(units), arr.shape)[bad]
            raise ValueError(
                f"{name}: entry {bad} is {float(arr[bad])!r} {unit}, beyond any robot "
                f"(|value| <= {MAX_LENGTH_MM if unit == 'mm' else MAX_ANGLE_RAD:g} {unit})"
            )
    return arr


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


class Robot:
    """A hybrid robot: a serial carriage (DH chain) carrying a Stewart hexapod.

    Parameters
    ----------
    joint_types : str
        One letter per carriage joint, ``"P"`` (prismatic) or ``"R"`` (revolute), base first.
        An empty string describes a standalone hexapod.
    dh : array_like, shape (n_joints, 4)
        Nominal standard DH parameters, columns ``alpha, a, d, theta`` (rad, mm). A joint reading
        adds to ``d`` (prismatic) or ``theta`` (revolute), so the nominal value is the joint's zero.
    joint_limits : array_like, shape (n_joints, 2)
        Lower and upper limit of each joint reading (mm or rad).
    base_joints : array_like, shape (6, 3)
        U-joint centres ``a_i`` in the hexapod base frame {4} (mm).
    platform_joints : array_like, shape (6, 3)
        S-joint centres ``b_i`` in the platform frame {5} (mm).
    leg_offsets : array_like, shape (6,)
        Nominal leg length at a sensor reading of zero, ``l0_i`` (mm): ``length = reading + l0``.
    leg_stroke : array_like, shape (2,) or (6, 2)
        Lower and upper limit of the leg sensor readings (mm).
    home_pose : array_like, shape (6,)
        A representative platform pose in frame {4}, ``(x, y, z, alpha, beta, gamma)``: the centre
        of the sampled workspace.
    workspace : array_like, shape (6,)
        Half-widths of the sampled hexapod workspace around ``home_pose`` (mm, rad).
    name : str
        A label.
    provenance : mapping, optional
        Where the description comes from (date, iwr version, method, data file, cost...): plain
        values written by :meth:`to_toml` as a ``[provenance]`` table and kept by
        :meth:`from_toml`. Not part of the geometry (``==`` ignores it).
    tracker : iwr.tracker.TrackerSetup, optional
        The laser-tracker measurement setup (docs/tracker.md); see also :meth:`with_tracker`.
    noise : iwr.Noise, optional
        The instruments' noise (standard deviations, mm and rad), the ``[noise]`` table of the
        TOML file (docs/data.md). For a robot with a tracker only its reading noise (``legs``,
        ``joint_lengths``, ``joint_angles``) applies: ``position`` and ``orientation`` must be 0.
    tracker_noise : iwr.tracker.TrackerNoise, optional
        The tracker's noise, the ``[tracker.noise]`` table; only with ``tracker``.
    instruments : mapping, optional
        The set-ups of other instruments, by the name of their measurement kind (its table in
        the TOML file, e.g. ``{"ballbar": iwr.ballbar.BallbarSetup(...)}``, the ``[ballbar]``
        table: docs/ballbar.md); see :meth:`with_instrument`. Each is read and checked by its
        kind (:meth:`iwr.kinds.MeasurementKind.read_setup`). A robot is measured by one
        instrument: not with ``tracker``.
    effects : mapping or sequence, optional
        Non-geometric effects switched on (issue 23, docs/effects.md): ``iwr.effects.Effect``
        objects, or the ``[effects]`` table (effect name -> its table); see
        :meth:`with_effects`. None (the default): the geometry alone, as before.

    ``noise`` and ``tracker_noise`` describe the bench, not the geometry; they are kept by
    :meth:`with_errors` and written by :meth:`to_toml`. ``iwr calibrate`` and ``iwr simulate``
    use them when ``--noise`` is not given; the Python API never does on its own: pass
    ``noise=robot.noise_model`` (docs/estimation.md).

    Lengths beyond 1e5 mm (100 m) or angles beyond 1e3 rad are refused: no robot has them.
    """

    def __init__(
        self,
        joint_types: str,
        dh: Any,
        joint_limits: Any,
        base_joints: Any,
        platform_joints: Any,
        leg_offsets: Any,
        leg_stroke: Any,
        home_pose: Any = (0.0, 0.0, 600.0, 0.0, 0.0, 0.0),
        workspace: Any = (100.0, 100.0, 60.0, 0.15, 0.15, 0.15),
        name: str = "robot",
        provenance: Mapping[str, Any] | None = None,
        tracker: Any = None,
        noise: Any = None,
        tracker_noise: Any = None,
        instruments: Mapping[str, Any] | None = None,
        effects: Any = None,
    ) -> None:
        if not isinstance(joint_types, str) or any(c not in "PR" for c in joint_types):
            raise ValueError(
                f"joint_types: {joint_types!r}; expected a string of 'P' and 'R', one per joint"
            )
        n = len(joint_types)
        self.name = str(name)
        self.joint_types = joint_types
        self.dh = _as_array(dh, (n, 4), "dh", ["rad", "mm", "mm", "rad"]) if n else np.zeros((0, 4))
        joint_units = np.array([["mm"] if c == "P" else ["rad"] for c in joint_types]).reshape(n, 1)
        self.joint_limits = (
            _as_array(joint_limits, (n, 2), "joint_limits", joint_units) if n
            else np.zeros((0, 2))
        )
        for i, (lo, hi) in enumerate(self.joint_limits):
            if not lo < hi:
                raise ValueError(f"joint_limits: joint {i + 1} has lower {lo} >= upper {hi}")
        self.base_joints = _as_array(base_joints, (6, 3), "base_joints", "mm")
        self.platform_joints = _as_array(platform_joints, (6, 3), "platform_joints", "mm")
        self.leg_offsets = _as_array(leg_offsets, (6,), "leg_offsets", "mm")
        stroke = np.array(leg_stroke, dtype=float)
        if stroke.shape == (2,):
            stroke = np.tile(stroke, (6, 1))
        self.leg_stroke = _as_array(stroke, (6, 2), "leg_stroke", "mm")
        for i, (lo, hi) in enumerate(self.leg_stroke):
            if not lo < hi:
                raise ValueError(f"leg_stroke: leg {i + 1} has lower {lo} >= upper {hi}")
        self.home_pose = _as_array(home_pose, (6,), "home_pose", _POSE_UNITS)
        self.workspace = _as_array(workspace, (6,), "workspace", _POSE_UNITS)
        self.provenance = _provenance(provenance or {}, "provenance")
        if tracker is not None:
            from .tracker.setup import TrackerSetup  # here: iwr.tracker imports this module

            if not isinstance(tracker, TrackerSetup):
                raise TypeError(f"tracker: expected an iwr.tracker.TrackerSetup or None, got "
                                f"{type(tracker).__name__}")
        #: The laser-tracker measurement setup (:class:`iwr.tracker.TrackerSetup`) or None: the
        #: data are then poses in {0}. Its parameters are not in :attr:`n_params`
        #: (docs/tracker.md).
        self.tracker = tracker
        self.noise, self.tracker_noise = _check_noise_model(noise, tracker_noise, tracker)
        #: The set-ups of the instruments described by a kind's own table (docs/kinds.md), by
        #: kind name; empty for poses in {0} and for the tracker (:attr:`tracker`).
        self.instruments = _instruments(instruments or {}, tracker)
        #: The non-geometric effects switched on (issue 23): a tuple of iwr.effects.Effect,
        #: empty for the geometry alone. Their parameters are not in :attr:`n_params`.
        self.effects = _effects.read_table(effects)
        if np.any(self.workspace < 0):
            raise ValueError(f"workspace: half-widths must be >= 0, got {self.workspace}")
        self._geometry = _core.Geometry(
            self.joint_types,
            np.ascontiguousarray(self.dh),
            self.base_joints,
            self.platform_joints,
            self.leg_offsets,
        )

    # -- derived ---------------------------------------------------------------------------
    @property
    def n_joints(self) -> int:
        """Number of carriage joints."""
        return len(self.joint_types)

    @property
    def n_params(self) -> int:
        """Number of error parameters, ``4 * n_joints + 42``."""
        return 4 * self.n_joints + 42

    @property
    def parameter_names(self) -> list[str]:
        """Names of the error parameters, in the public order of ``docs/model.md``."""
        names = [f"joint{i + 1}.d{col}" for i in range(self.n_joints) for col in _DH_COLUMNS]
        names += [f"leg{j + 1}.da_{c}" for j in range(6) for c in "xyz"]
        names += [f"leg{j + 1}.db_{c}" for j in range(6) for c in "xyz"]
        names += [f"leg{j + 1}.dl0" for j in range(6)]
        return names

    @property
    def angle_parameters(self) -> np.ndarray:
        """Boolean mask, True where an error parameter is an angle (rad), False for lengths (mm)."""
        mask = [_DH_ANGLE[col] for _ in range(self.n_joints) for col in _DH_COLUMNS]
        return np.array(mask + [False] * 42, dtype=bool)

    @property
    def joint_units(self) -> list[str]:
        """Unit of each joint reading: ``"mm"`` for prismatic, ``"rad"`` for revolute joints."""
        return ["mm" if c == "P" else "rad" for c in self.joint_types]

    def default_bounds(self, kind: str = "default") -> tuple[np.ndarray, np.ndarray]:
        """Bounds of the error parameters.

        ``"default"``: +-0.5 mm for lengths and +-0.5 degree for angles. ``"paper"``: Table 2 read
        literally, +-0.5 for every parameter (so +-0.5 rad for angles).
        """
        if kind == "paper":
            half = np.full(self.n_params, 0.5)
        elif kind == "default":
            half = np.where(self.angle_parameters, math.radians(0.5), 0.5)
        else:
            raise ValueError(f"bounds: unknown preset {kind!r}; expected 'default' or 'paper'")
        return -half, half

    def with_errors(self, x: Any) -> Robot:
        """The robot whose nominal geometry is this one's plus the error vector ``x`` (a
        calibrated robot)."""
        x = _as_array(x, (self.n_params,), "x")
        n = self.n_joints
        dh = self.dh + x[: 4 * n].reshape(n, 4)
        return Robot(
            self.joint_types,
            dh,
            self.joint_limits,
            self.base_joints + x[4 * n : 4 * n + 18].reshape(6, 3),
            self.platform_joints + x[4 * n + 18 : 4 * n + 36].reshape(6, 3),
            self.leg_offsets + x[4 * n + 36 :],
            self.leg_stroke,
            self.home_pose,
            self.workspace,
            name=self.name,
            tracker=self.tracker,
            noise=self.noise,
            tracker_noise=self.tracker_noise,
            instruments=self.instruments,
            effects=self.effects,
        )

    def with_effects(self, *effects: Any) -> Robot:
        """This robot with the non-geometric effects ``effects`` (:class:`iwr.effects.Effect`
        objects, or one mapping: the ``[effects]`` table) switched on, in place of its own;
        ``with_effects()`` switches every effect off (docs/effects.md)."""
        out = copy.copy(self)
        out.effects = _effects.read_table(
            effects[0] if len(effects) == 1 and isinstance(effects[0], Mapping) else effects)
        return out

    def with_instrument(self, name: str, setup: Any) -> Robot:
        """This robot measured by the instrument of measurement kind ``name`` (for example
        ``"ballbar"``), described by ``setup`` (the kind's set-up object, or its TOML table as a
        mapping); ``setup=None`` removes it."""
        out = copy.copy(self)
        instruments = {k: v for k, v in self.instruments.items() if k != name}
        if setup is not None:
            instruments[name] = setup
        out.instruments = _instruments(instruments, self.tracker)
        return out

    def with_tracker(self, registration: Any = None, *, reflectors: Any = None, probe: Any = None,
                     probe_length: float = 100.0, names: Any = None, setup: Any = None) -> Robot:
        """This robot measured by a laser tracker (docs/tracker.md): ``registration`` the nominal
        pose ``(x, y, z, alpha, beta, gamma)`` of {0} in the tracker frame {T}, and either
        ``reflectors=[(x, y, z), ...]`` (nominal reflector positions in {5}) or ``probe=(x, y, z,
        alpha, beta, gamma)`` (a 6-DOF probe's nominal pose in {5}); or a ready ``setup``
        (:class:`iwr.tracker.TrackerSetup`). ``with_tracker(None)`` removes it.

        :attr:`n_params` stays the robot's own ``4 n + 42``; the setup's parameters are appended
        after them in the problems built for tracker data (``iwr.tracker.TrackerProblem``'s
        ``n_params`` and ``parameter_names``), and in every ``x`` of the public API for them.
        """
        from .tracker.setup import TrackerSetup  # here: iwr.tracker imports this module

        if setup is None and registration is not None:
            setup = TrackerSetup(registration, reflectors=reflectors, probe=probe,
                                 probe_length=probe_length, names=names)
        elif setup is not None and (registration is not None or reflectors is not None
                                    or probe is not None):
            raise ValueError("with_tracker: give either setup= or registration= with "
                             "reflectors= or probe=, not both")
        out = copy.copy(self)
        out.tracker = setup
        if setup is not None and not isinstance(setup, TrackerSetup):
            raise TypeError(f"setup: expected an iwr.tracker.TrackerSetup, got "
                            f"{type(setup).__name__}")
        out.instruments = _instruments(self.instruments, setup)  # one instrument per robot
        # The tracker's noise goes with the tracker; a pose-in-{0} noise does not fit one.
        out.noise, out.tracker_noise = _check_noise_model(
            self.noise, self.tracker_noise if setup is not None else None, setup)
        return out

    def with_noise(self, noise: Any = None, tracker_noise: Any = None) -> Robot:
        """This robot with the instruments' noise model ``noise`` (an :class:`iwr.Noise`) and,
        for a robot with a tracker, ``tracker_noise`` (an :class:`iwr.tracker.TrackerNoise`);
        ``with_noise()`` removes both. Written by :meth:`to_toml` as ``[noise]`` and
        ``[tracker.noise]``."""
        out = copy.copy(self)
        out.noise, out.tracker_noise = _check_noise_model(noise, tracker_noise, self.tracker)
        return out

    @property
    def noise_model(self) -> Any:
        """What ``noise=`` of :func:`iwr.identify` and :func:`iwr.simulate` takes for this
        robot's data, from :attr:`noise` and :attr:`tracker_noise`: None when neither is given;
        the :class:`iwr.Noise` for a robot without a tracker; the pair ``(Noise, TrackerNoise)``
        (either may be None) for a robot with one."""
        if self.noise is None and self.tracker_noise is None:
            return None
        if self.tracker is None:
            return self.noise
        return (self.noise, self.tracker_noise)

    def carriage_transform(self, q: Any, x: Any = None) -> np.ndarray:
        """The 4x4 transform 0T4 of the carriage at joint readings ``q`` (eq. 2), with the error
        vector ``x`` (default: the nominal robot)."""
        x = np.zeros(self.n_params) if x is None else np.asarray(x, dtype=float)
        return _core.carriage_transform(self._geometry, x, np.asarray(q, dtype=float))

    # -- presets ------------------------------------------------------------------------------
    @classmethod
    def default(cls) -> Robot:
        """The IWR of the paper's Table 1, with representative dimensions.

        The paper gives the DH structure but not the lengths. These are IWR-scale values:

        - joint 1, prismatic ``d1`` (travel along the rail), 0..2000 mm, alpha = pi/2, zero offset
          500 mm;
        - joint 2, prismatic ``d2``, 0..1000 mm, alpha = theta = pi/2, zero offset 300 mm;
        - joint 3, revolute ``theta3``, +-90 degrees, alpha = pi/2, a3 = 400 mm, d3 = 250 mm;
        - joint 4, revolute ``theta4``, +-60 degrees, alpha = -pi/2, a4 = 300 mm;
        - hexapod: U-joints on a 400 mm radius in frame {4}, in pairs 20 degrees apart about
          0, 120 and 240 degrees; S-joints on a 250 mm radius in frame {5}, pairs about 60, 180
          and 300 degrees; leg j joins the U-joint at angle phi_j to the S-joint at phi_j -+ 40
          degrees (legs 1..6: -10 -> -50, 10 -> 50, 110 -> 70, 130 -> 170, 230 -> 190,
          250 -> 290 degrees); leg length = reading + 600 mm, readings 0..400 mm; home platform
          height 750 mm above the base plate.
        """
        h = math.pi / 2
        dh = [
            [h, 0.0, 500.0, 0.0],
            [h, 0.0, 300.0, h],
            [h, 400.0, 250.0, 0.0],
            [-h, 300.0, 0.0, 0.0],
        ]
        limits = [
            [0.0, 2000.0],
            [0.0, 1000.0],
            [-math.radians(90), math.radians(90)],
            [-math.radians(60), math.radians(60)],
        ]
        return cls(
            "PPRR",
            dh,
            limits,
            _ring(400.0, 0.0, 20.0),
            # Leg j joins base point j to the platform point 40 degrees away, alternately ahead and
            # behind (the usual Gough-Stewart triangulation). Joining each base pair to the platform
            # pair 60 degrees ahead would put all six legs on one regulus (each leg the image of one
            # line under a rotation about z): an architecturally singular hexapod whose leg lengths
            # leave three platform motions free at every pose.
            np.roll(_ring(250.0, 60.0, 20.0), 1, axis=0),
            np.full(6, 600.0),
            [0.0, 400.0],
            home_pose=(0.0, 0.0, 750.0, 0.0, 0.0, 0.0),
            workspace=(120.0, 120.0, 80.0, math.radians(10), math.radians(10), math.radians(10)),
            name="IWR",
        )

    @classmethod
    def hexapod(cls) -> Robot:
        """The IWR's hexapod alone (no carriage, 42 error parameters): frame {4} is the world."""
        iwr = cls.default()
        return cls(
            "",
            np.zeros((0, 4)),
            np.zeros((0, 2)),
            iwr.base_joints,
            iwr.platform_joints,
            iwr.leg_offsets,
            iwr.leg_stroke,
            iwr.home_pose,
            iwr.workspace,
            name="hexapod",
        )

    # -- files ----------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """A plain dictionary, the content of the TOML file."""
        return {
            "name": self.name,
            "units": {"length": "mm", "angle": "rad"},
            "carriage": {
                "joints": [
                    {
                        "type": "prismatic" if t == "P" else "revolute",
                        "alpha": float(row[0]),
                        "a": float(row[1]),
                        "d": float(row[2]),
                        "theta": float(row[3]),
                        "limits": [float(v) for v in lim],
                    }
                    for t, row, lim in zip(self.joint_types, self.dh, self.joint_limits,
                                           strict=True)
                ]
            },
            "hexapod": {
                "base_joints": self.base_joints.tolist(),
                "platform_joints": self.platform_joints.tolist(),
                "leg_offsets": self.leg_offsets.tolist(),
                "leg_stroke": self.leg_stroke.tolist(),
                "home_pose": self.home_pose.tolist(),
                "workspace": self.workspace.tolist(),
            },
            **({"noise": dataclasses.asdict(self.noise)} if self.noise is not None else {}),
            **({"tracker": self._tracker_dict()} if self.tracker is not None else {}),
            **{name: setup.to_dict() for name, setup in self.instruments.items()},
            **({"effects": {e.name: e.to_dict() for e in self.effects}} if self.effects else {}),
        }

    def _tracker_dict(self) -> dict[str, Any]:
        out = dict(self.tracker.to_dict())
        if self.tracker_noise is not None:
            out["noise"] = dataclasses.asdict(self.tracker_noise)
        return out

    def to_toml(self, path: str | os.PathLike[str],
                provenance: Mapping[str, Any] | None = None) -> None:
        """Write the robot as TOML (atomically: a temporary file, then a rename).

        Laid out to be read and edited by hand: one key per line, vectors and the rows of
        matrices on one line each, full double precision. ``provenance`` (default: the robot's
        own, :attr:`provenance`) is written as a ``[provenance]`` table, for example
        ``{"date": ..., "iwr_version": ..., "method": "lm", "data": "measurements.csv",
        "cost_mm2": 1.2e-4}``; values are strings, numbers, booleans or dates.
        """
        prov = _provenance(self.provenance if provenance is None else provenance, "provenance")
        d = self.to_dict()
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
        if self.noise is not None:
            out += ["", "[noise]  # standard deviations: legs, joint_lengths, position (mm); "
                    "joint_angles, orientation (rad)"]
            out += [f"{k} = {_toml_value(float(v))}" for k, v in d["noise"].items()]
        if self.tracker is not None:
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
        for name in self.instruments:
            out += _toml_table(name, d[name])
        if self.effects:  # issue 23: the non-geometric effects (docs/effects.md)
            out += _toml_table("effects", d["effects"])
        atomic_write_text(path, "\n".join(out) + "\n")

    @classmethod
    def from_toml(cls, path: str | os.PathLike[str]) -> Robot:
        """Read a robot written by :meth:`to_toml` (or by hand); errors name the file and key."""
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
        try:
            return cls.from_dict(data)
        except (KeyError, ValueError, TypeError) as exc:
            msg = exc.args[0] if exc.args else str(exc)
            raise RobotFileError(f"{path}: {msg}") from None

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Robot:
        """Build a robot from the dictionary form of :meth:`to_dict`; strict about keys."""
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
            from .tracker.setup import TrackerSetup  # here: iwr.tracker imports this module

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
        return cls(
            types,
            np.array(dh, dtype=float).reshape(len(types), 4),
            np.array(limits, dtype=float).reshape(len(types), 2),
            _matrix(hexa["base_joints"], 6, 3, "hexapod.base_joints"),
            _matrix(hexa["platform_joints"], 6, 3, "hexapod.platform_joints"),
            _numbers(hexa["leg_offsets"], 6, "hexapod.leg_offsets", ["mm"] * 6),
            _stroke(hexa["leg_stroke"]),
            name=name,
            provenance=_provenance(data.get("provenance", {}), "provenance"),
            instruments={name: data[name] for name in tables},
            effects=data.get("effects"),
            **kwargs,
        )

    def __repr__(self) -> str:
        return (
            f"Robot(name={self.name!r}, joint_types={self.joint_types!r}, "
            f"n_params={self.n_params})"
        )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Robot):
            return NotImplemented
        a, b = self.to_dict(), other.to_dict()
        return a == b


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


def _instruments(instruments: Mapping[str, Any], tracker: Any) -> dict[str, Any]:
    """Each instrument's set-up read and checked by its kind (a table or a set-up object)."""
    if not isinstance(instruments, Mapping):
        raise TypeError(f"instruments: expected a mapping of kind names to set-ups, got "
                        f"{type(instruments).__name__}")
    out = {}
    for name, setup in instruments.items():
        if name not in kinds.available():
            raise ValueError(f"{name}: not a registered measurement kind "
                             f"({', '.join(kinds.available())})")
        out[name] = kinds.named(name).read_setup(setup, name)
    if len(out) + (tracker is not None) > 1:
        described = (["tracker"] if tracker is not None else []) + list(out)
        raise ValueError(f"{' and '.join(described)}: a robot is measured by one instrument; "
                         "describe one")
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


def _check_noise_model(noise: Any, tracker_noise: Any, tracker: Any) -> tuple[Any, Any]:

    if noise is not None and not isinstance(noise, Noise):
        raise TypeError(f"noise: expected an iwr.Noise or None, got {type(noise).__name__}")
    if tracker_noise is not None:
        if not isinstance(tracker_noise, TrackerNoise):
            raise TypeError(f"tracker_noise: expected an iwr.tracker.TrackerNoise or None, got "
                            f"{type(tracker_noise).__name__}")
        if tracker is None:
            raise ValueError("tracker_noise: only for a robot with a tracker ([tracker] table, "
                             "Robot.with_tracker)")
    if tracker is not None and noise is not None and (noise.position or noise.orientation):
        raise ValueError(
            f"noise: position {noise.position!r} mm, orientation {noise.orientation!r} rad: the "
            "noise of a pose measured in {0}; a robot with a tracker measures in the tracker's "
            "frame, whose noise is [tracker.noise] (tracker_noise=): give position = orientation "
            "= 0")
    return noise, tracker_noise


def _ring(radius: float, centre_deg: float, spread_deg: float) -> np.ndarray:
    """Six points on a circle in z = 0, in pairs +-spread/2 about centre, centre + 120, + 240."""
    pts = []
    for k in range(3):
        c = centre_deg + 120.0 * k
        for sign in (-1.0, 1.0):
            ang = math.radians(c + sign * spread_deg / 2.0)
            pts.append([radius * math.cos(ang), radius * math.sin(ang), 0.0])
    return np.array(pts)


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
