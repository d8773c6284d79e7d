"""Robot descriptions: a DH carriage carrying a six-legged Stewart hexapod."""

from __future__ import annotations

import copy
import dataclasses
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from . import _core, kinds
from . import effects as _effects
from .measurements import MAX_ANGLE_RAD, MAX_LENGTH_MM
from .noise import Noise, TrackerNoise
from .robot_file import (
    _DH_ANGLE,
    _DH_COLUMNS,
    _POSE_UNITS,
    MAX_DH_ANGLE_RAD,
    RobotFileError,
    _provenance,
    dh_degrees_problem,
    read_toml,
    robot_arguments,
    write_toml,
)

__all__ = ["Robot", "RobotFileError"]


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


def _check_pose_angles(home_pose: np.ndarray, workspace: np.ndarray) -> None:
    """ValueError for an angle of ``home_pose`` beyond +-2 pi or a workspace half-width of an
    angle beyond pi: radians are expected, and these look like degrees (``gamma = 90.0`` in a
    robot file made forward kinematics stall later, blamed on the data)."""
    for k, name in ((3, "alpha"), (4, "beta"), (5, "gamma")):
        for what, v, limit, bound in (("home_pose", home_pose[k], MAX_DH_ANGLE_RAD, "+-2 pi"),
                                      ("workspace", workspace[k], math.pi, "pi")):
            if abs(v) > limit:
                raise ValueError(
                    f"{what}: {name} {v:g} is beyond {bound}: angles are in radians, and this "
                    f"looks like degrees ({v:g} deg = {math.radians(v):.4f} rad)")


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

    Lengths beyond 1e5 mm (100 m) or angles beyond 1e3 rad are refused: no robot has them. A DH
    angle (``alpha``, ``theta``) beyond 2 pi is refused too: it was written in degrees.
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
        for i, row in enumerate(self.dh):
            for c, col in enumerate(_DH_COLUMNS):
                why = dh_degrees_problem(float(row[c])) if _DH_ANGLE[col] else None
                if why:
                    raise ValueError(f"dh: joint {i + 1} (row {i}) {col}: {why}")
        joint_units = np.array([["mm"] if c == "P" else ["rad"] for c in joint_types]).reshape(n, 1)
        self.joint_limits = (
            _as_array(joint_limits, (n, 2), "joint_limits", joint_units) if n
            else np.zeros((0, 2))
        )
        for i, (lo, hi) in enumerate(self.joint_limits):
            if not lo < hi:
                raise ValueError(f"joint_limits: joint {i + 1} has lower {lo} >= upper {hi}")
            if joint_types[i] == "R" and max(abs(lo), abs(hi)) > MAX_DH_ANGLE_RAD:
                v = lo if abs(lo) > abs(hi) else hi
                raise ValueError(
                    f"joint_limits: joint {i + 1} (revolute) limit {v:g} is beyond +-2 pi: a "
                    f"revolute joint's limits are in radians, and this looks like degrees "
                    f"({v:g} deg = {math.radians(v):.4f} rad)")
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
        _check_pose_angles(self.home_pose, self.workspace)
        self.provenance = _provenance(provenance or {}, "provenance")
        if tracker is not None:
            # Here, not at the top: iwr.tracker.setup imports SciPy, which ``import iwr`` must not.
            from .tracker.setup import TrackerSetup

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
        self.effects = _effects.read_table(effects, robot=self)
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
        calibrated robot): geometric errors alone (:func:`iwr.calibrated_robot` makes the
        robot of any result)."""
        if np.ndim(x) == 1 and np.size(x) > self.n_params:
            raise ValueError(
                f"x: {np.size(x)} values; expected {self.n_params}, the robot's geometric errors "
                "alone. A result with more parameters (its effects', a tracker's or a ballbar's "
                "set-up) becomes a robot by iwr.calibrated_robot(robot, result): with its first "
                f"{self.n_params} values alone the nominal set-up would stay (and for tracker "
                "data a platform frame {5} the data do not fix)")
        x = _as_array(x, (self.n_params,), "x")
        n = self.n_joints
        dh = self.dh + x[: 4 * n].reshape(n, 4)
        # A nominal angle near +-2 pi plus its error may pass 2 pi, which the constructor refuses
        # as degrees: there, the same rotation within +-pi (any other angle is kept as it is).
        angles = dh[:, [0, 3]]
        dh[:, [0, 3]] = np.where(np.abs(angles) > MAX_DH_ANGLE_RAD,
                                 np.remainder(angles + math.pi, 2 * math.pi) - math.pi, angles)
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

    def with_workspace(self, workspace: Any) -> Robot:
        """This robot with the half-widths ``workspace`` of its sampled workspace around
        ``home_pose`` (mm, rad) in place of its own."""
        out = copy.copy(self)
        out.workspace = _as_array(workspace, (6,), "workspace", _POSE_UNITS)
        if np.any(out.workspace < 0):
            raise ValueError(f"workspace: half-widths must be >= 0, got {out.workspace}")
        _check_pose_angles(out.home_pose, out.workspace)
        return out

    def with_effects(self, *effects: Any) -> Robot:
        """This robot with the non-geometric effects ``effects`` (:class:`iwr.effects.Effect`
        objects, or one mapping: the ``[effects]`` table) switched on, in place of its own;
        ``with_effects()`` switches every effect off (docs/effects.md)."""
        out = copy.copy(self)
        out.effects = _effects.read_table(
            effects[0] if len(effects) == 1 and isinstance(effects[0], Mapping) else effects,
            robot=out)
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
        from .tracker.setup import TrackerSetup  # here: it imports SciPy (see __init__)

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
        write_toml(self, path, provenance)

    @classmethod
    def from_toml(cls, path: str | os.PathLike[str]) -> Robot:
        """Read a robot written by :meth:`to_toml` (or by hand); errors name the file and key."""
        path = Path(path)
        data = read_toml(path)
        try:
            return cls.from_dict(data)
        except (KeyError, ValueError, TypeError) as exc:
            msg = exc.args[0] if exc.args else str(exc)
            raise RobotFileError(f"{path}: {msg}") from None

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Robot:
        """Build a robot from the dictionary form of :meth:`to_dict`; strict about keys."""
        args, kwargs = robot_arguments(data)
        return cls(*args, **kwargs)

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


