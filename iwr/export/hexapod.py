"""The calibrated hexapod as controllers take it: LinuxCNC ``genhexkins`` parameters (a HAL file of
``setp`` lines), the same numbers as plain JSON, and a table of leg corrections over a grid of
platform poses for controllers that compensate by table (docs/cli.md, ``iwr export``).

Frames and conventions (docs/model.md): the base joints ``a_i`` are in the hexapod's base frame
{4} (the carriage's last frame), the platform joints ``b_i`` in the platform frame {5}; a pose of
{5} in {4} is ``(x, y, z, alpha, beta, gamma)`` with ``R = Rz(alpha) Ry(beta) Rx(gamma)``; the
leg length is ``l_i = |p + R b_i - a_i| = s_i + l0_i``, ``s_i`` the leg sensor's reading and
``l0_i`` the leg offset.

``genhexkins`` (LinuxCNC, src/emc/kinematics/genhexkins.c) computes its joint ``i`` (0-based) as
the strut length ``|p + R platform_i - base_i|`` with ``base_i`` in its world frame (here {4}),
``platform_i`` in the platform frame (here {5}) and ``R`` its roll-pitch-yaw matrix
``Rz(C) Ry(B) Rx(A)`` of the pose words A, B, C in degrees: so A = gamma, B = beta, C = alpha, and
its joint ``i`` is iwr's whole leg length ``l_{i+1}``, the sensor reading plus ``l0``.
"""

from __future__ import annotations

import csv
import io
import itertools
import json
import os
from typing import Any, NamedTuple

import numpy as np

from .. import kinds
from .._io import atomic_write_text
from ..problem import predict_legs
from ..robot import Robot
from ..transforms import pose_from_matrix

__all__ = ["FRAMES", "TableWritten", "data_frame", "effects_note", "genhexkins_hal",
           "hexapod_dict", "hexapod_readings", "interpolation_error", "leg_correction_table",
           "leg_corrections_csv", "pose_grid", "write_genhexkins_hal", "write_hexapod_json",
           "write_leg_corrections"]

#: The frame convention every hexapod export states.
FRAMES = (
    "base joints a_i in the hexapod base frame {4} (the carriage's last frame, the hexapod's "
    "base plate); platform joints b_i in the platform frame {5}; a platform pose is {5} in {4}, "
    "(x, y, z, alpha, beta, gamma) with R = Rz(alpha) Ry(beta) Rx(gamma); leg length "
    "l_i = |p + R b_i - a_i| = s_i + l0_i (s_i the leg sensor's reading, l0_i the leg offset); "
    "lengths in mm, angles in rad")

_POSE_COLUMNS = ("x_mm", "y_mm", "z_mm", "alpha_rad", "beta_rad", "gamma_rad")


def _origin(robot: Robot, source: str | None) -> str:
    """One line saying which robot the numbers are of."""
    prov = ", ".join(f"{k} {v}" for k, v in robot.provenance.items())
    where = f" ({source})" if source else ""
    return " ".join(f"robot {robot.name!r}{where}{'; ' + prov if prov else ''}".split())


def effects_note(robot: Robot) -> str | None:
    """What a file that holds the geometry alone says of a robot with non-geometric effects
    (issue 23): its leg lengths are not those under load and temperature. None without effects."""
    if not robot.effects:
        return None
    names = ", ".join(e.name for e in robot.effects)
    return (f"GEOMETRY ONLY: robot {robot.name!r} has non-geometric effects ({names}) that "
            "change its leg lengths under load and temperature; this file does not hold them "
            "(hexapod.json records them, and `iwr legs` gives leg commands that include them: "
            "docs/effects.md)")


def data_frame(robot: Robot) -> tuple[str, np.ndarray] | None:
    """For a robot calibrated from data measured in another frame than {0} (a laser tracker's
    {T}): that frame's name and the calibrated registration ``T_D0`` (4x4, mm: the world frame
    {0} in it, ``p_D = T_D0 p_0``), which places {0}, a gauge choice of such a calibration
    (docs/tracker.md); None for data in {0}."""
    kind = kinds.for_robot(robot)
    if kind.frame == "{0}":
        return None
    return kind.frame.strip("{}"), np.asarray(kind.registration(robot), dtype=float)


def genhexkins_hal(robot: Robot, source: str | None = None) -> str:
    """The text of a HAL file that sets LinuxCNC ``genhexkins``'s joint coordinates to ``robot``'s
    (``setp genhexkins.base.N.x ...``, N = 0..5 for iwr's legs 1..6), with comments stating the
    frames, the pose convention and how to apply the leg offsets."""
    lines = [
        "# LinuxCNC genhexkins parameters of the hexapod of " + _origin(robot, source)
        + ", written by iwr export.",
        "# Load after 'loadrt genhexkins' (or switchkins with genhexkins) in the HAL files of the "
        "machine.",
        "#",
        "# Frames: genhexkins.base.N.* are the base joint centres a_{N+1} in the hexapod base "
        "frame {4}",
        "# (genhexkins's world frame); genhexkins.platform.N.* are the platform joint centres "
        "b_{N+1} in the",
        "# platform frame {5}. Lengths in mm. genhexkins's pose words: X, Y, Z (mm) and A, B, C "
        "(degrees),",
        "# R = Rz(C) Ry(B) Rx(A); iwr's pose (x, y, z, alpha, beta, gamma) with R = Rz(alpha) "
        "Ry(beta) Rx(gamma)",
        "# is A = gamma, B = beta, C = alpha (converted to degrees).",
        "#",
        "# Joint N of genhexkins is the whole length of leg N+1, |p + R b - a|. iwr's leg sensor "
        "reading is",
        "# that length less the leg offset l0: s = joint - l0. A controller whose joint feedback "
        "is the",
        "# sensor reading adds l0 to it (in the joint's home position, or by a HAL offset "
        "component):",
    ]
    lines += [f"#   leg {j + 1} (joint {j}): l0 = {float(robot.leg_offsets[j])!r} mm, stroke of "
              f"the reading {float(robot.leg_stroke[j, 0])!r} .. "
              f"{float(robot.leg_stroke[j, 1])!r} mm" for j in range(6)]
    lines += ["# genhexkins.spindle-offset and genhexkins.tool-offset must stay 0 for these "
              "numbers (both move the", "# z of every joint), and genhexkins.screw-lead 0 (its "
              "default: iwr's legs have no screw-lead", "# correction).", ""]
    note = effects_note(robot)
    if note:
        lines[-1:-1] = ["#", "# " + note + "."]
    for j in range(6):
        for c, k in zip("xyz", range(3), strict=True):
            lines.append(f"setp genhexkins.base.{j}.{c} {float(robot.base_joints[j, k])!r}")
        for c, k in zip("xyz", range(3), strict=True):
            lines.append(f"setp genhexkins.platform.{j}.{c} "
                         f"{float(robot.platform_joints[j, k])!r}")
    return "\n".join(lines) + "\n"


def hexapod_dict(robot: Robot, source: str | None = None) -> dict[str, Any]:
    """The hexapod's calibrated numbers as a plain dictionary (the JSON export); with the
    effects (their gravity in {0} as the calibration used it) and, for a robot calibrated from
    data in another frame, that frame's registration (:func:`data_frame`)."""
    from ..effects.gravity import in_world_gravity

    extra: dict[str, Any] = {}
    if robot.effects:
        # The effects as they load the robot: on tracker data the tracker's gravity (in {T})
        # carried into {0} by the calibrated registration, not the file's own gravity_m_s2.
        loaded = in_world_gravity(robot)  # robot itself where its own gravity stands
        extra["effects"] = {e.name: e.to_dict() for e in loaded.effects}
        extra["effects_note"] = (
            "with these effects a leg's reading at a given pose also depends on the load and "
            "the temperature (docs/effects.md gives their model): the relation of 'frames' is "
            "the geometry's alone; gravity_m_s2 is in {0}"
            + (", carried from the tracker's gravity in {T} by the calibrated registration"
               if loaded is not robot else ""))
    frame = data_frame(robot)
    if frame is not None:
        name, t = frame
        extra["registration"] = {
            "frame": f"{{{name}}}",
            f"T_{name}0": [[float(v) for v in row] for row in t],
            "pose": [float(v) for v in pose_from_matrix(t)],
            "meaning": f"the world frame {{0}} in the frame {{{name}}} the calibration data were "
                       f"measured in, as calibrated: p_{name} = T_{name}0 p_0 (mm), pose (x, y, "
                       "z, alpha, beta, gamma) with R = Rz(alpha) Ry(beta) Rx(gamma); such data "
                       "do not fix {0} (a gauge choice, docs/tracker.md): a target measured in "
                       f"{{{name}}} is carried into {{0}} by the inverse",
        }
    return {
        "format": "iwr-hexapod",
        "version": 1,
        "robot": robot.name,
        "source": _origin(robot, source),
        "units": {"length": "mm", "angle": "rad"},
        "frames": FRAMES,
        "genhexkins": "base.N = legs[N].base_joint, platform.N = legs[N].platform_joint; "
                      "genhexkins's joint N = leg length = reading + leg_offset; its pose words "
                      "A, B, C (degrees) = gamma, beta, alpha",
        "legs": [
            {"leg": j + 1,
             "base_joint": [float(v) for v in robot.base_joints[j]],
             "platform_joint": [float(v) for v in robot.platform_joints[j]],
             "leg_offset": float(robot.leg_offsets[j]),
             "reading_stroke": [float(v) for v in robot.leg_stroke[j]]}
            for j in range(6)],
        "home_pose": [float(v) for v in robot.home_pose],
        # The non-geometric effects (issue 23, docs/effects.md): what a controller must add to
        # the geometry's leg lengths under each move's load and temperature.
        **extra,
    }


def _hexapod_only(robot: Robot) -> Robot:
    """The hexapod of ``robot`` alone: frame {4} is its world, so iwr's own model
    (:func:`iwr.predict_legs`) gives the leg readings of poses in {4}."""
    return Robot("", np.zeros((0, 4)), np.zeros((0, 2)), robot.base_joints,
                 robot.platform_joints, robot.leg_offsets, robot.leg_stroke, robot.home_pose,
                 robot.workspace, name=robot.name)


def hexapod_readings(robot: Robot, poses: Any) -> np.ndarray:
    """The leg sensor readings (N, 6) of ``robot``'s hexapod at platform poses (N, 6) of {5} in
    {4} (mm, rad), by iwr's model."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    hexa = _hexapod_only(robot)
    return predict_legs(hexa, None, np.zeros((len(poses), 0)), poses)


def pose_grid(robot: Robot, n_per_axis: int) -> np.ndarray:
    """The grid of platform poses in {4}: ``n_per_axis`` values per coordinate, evenly over the
    robot's sampled workspace (``home_pose`` +- ``workspace``), all combinations (``n^6``)."""
    if isinstance(n_per_axis, bool) or not isinstance(n_per_axis, int) or n_per_axis < 1:
        raise ValueError(f"n_per_axis: {n_per_axis!r}; expected an integer >= 1")
    return np.array(list(itertools.product(*_axes(robot, n_per_axis))), dtype=float)


def leg_correction_table(calibrated: Robot, nominal: Robot, n_per_axis: int = 5
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Over :func:`pose_grid` of the calibrated robot: the poses (M, 6), the nominal robot's leg
    readings (M, 6) and the calibrated robot's (M, 6) at each. A controller that commands the
    nominal model's reading ``s_nominal`` adds ``s_calibrated - s_nominal``."""
    poses = pose_grid(calibrated, n_per_axis)
    return poses, hexapod_readings(nominal, poses), hexapod_readings(calibrated, poses)


def _axes(robot: Robot, n_per_axis: int) -> list[np.ndarray]:
    """The values of each pose coordinate in :func:`pose_grid`: one (``home_pose``) where the
    workspace has no width or ``n_per_axis`` is 1, else ``n_per_axis`` evenly over +-
    ``workspace``."""
    return [np.array([c]) if n_per_axis == 1 or w == 0 else np.linspace(c - w, c + w, n_per_axis)
            for c, w in zip(robot.home_pose, robot.workspace, strict=True)]


def interpolation_error(calibrated: Robot, nominal: Robot, n_per_axis: int, samples: int = 2000,
                        seed: int = 0) -> tuple[float, float]:
    """How far the corrections ``dsN`` read from :func:`leg_correction_table` by multilinear
    interpolation between its poses (SciPy's ``RegularGridInterpolator``) are from the models'
    own, at ``samples`` poses drawn uniformly over ``home_pose`` +- ``workspace`` (seeded): the
    largest and the RMS difference over every leg (mm). A table is only as good as that between
    its poses; a finer grid is closer."""
    poses, s_nom, s_cal = leg_correction_table(calibrated, nominal, n_per_axis)
    return _interpolation_error(calibrated, nominal, n_per_axis, poses, s_cal - s_nom, samples,
                                seed)


def _interpolation_error(calibrated: Robot, nominal: Robot, n_per_axis: int, poses: np.ndarray,
                         ds: np.ndarray, samples: int = 2000, seed: int = 0
                         ) -> tuple[float, float]:
    from scipy.interpolate import RegularGridInterpolator

    axes = _axes(calibrated, n_per_axis)
    centre, half = calibrated.home_pose, calibrated.workspace
    rng = np.random.default_rng(seed)
    at = np.tile(np.asarray(centre, dtype=float), (samples, 1))
    for k in range(6):  # every coordinate the workspace spans, a table's single value or not
        if half[k] != 0:
            at[:, k] = rng.uniform(centre[k] - half[k], centre[k] + half[k], size=samples)
    moving = [k for k, a in enumerate(axes) if a.size > 1]
    if moving:
        table = ds.reshape(*[axes[k].size for k in moving], 6)  # itertools.product's order
        got = RegularGridInterpolator([axes[k] for k in moving], table)(at[:, moving])
    else:  # one pose (--grid 1): the table says the same everywhere
        got = np.broadcast_to(ds[0], (samples, 6))
    err = np.abs(got - (hexapod_readings(calibrated, at) - hexapod_readings(nominal, at)))
    return float(err.max()), float(np.sqrt(np.mean(err**2)))


class TableWritten(NamedTuple):
    """What :func:`write_leg_corrections` wrote: the table's poses and how far its corrections
    interpolated between them are from the models' own (:func:`interpolation_error`, mm)."""

    poses: int
    interpolation_max_mm: float
    interpolation_rms_mm: float


def leg_corrections_csv(calibrated: Robot, nominal: Robot, n_per_axis: int = 5,
                        source: str | None = None, nominal_source: str | None = None, *,
                        check: bool = True) -> str:
    """The text of the leg-correction table (CSV with ``#`` comments stating the frame and the
    table's interpolation error, :func:`interpolation_error`). Raises
    :class:`iwr.compensation.NominalMismatchError` for a ``nominal`` that is not a model the
    calibration can be relative to (:func:`iwr.compensation.check_nominal`; ``check`` False: the
    caller has checked it)."""
    return _corrections(calibrated, nominal, n_per_axis, source, nominal_source, check)[0]


def _corrections(calibrated: Robot, nominal: Robot, n_per_axis: int, source: str | None,
                 nominal_source: str | None, check: bool) -> tuple[str, TableWritten]:
    if check:
        from ..compensation import check_nominal

        check_nominal(calibrated, nominal, where=source or "calibrated",
                      nominal_where=nominal_source or "nominal")
    poses, s_nom, s_cal = leg_correction_table(calibrated, nominal, n_per_axis)
    worst, rms = _interpolation_error(calibrated, nominal, n_per_axis, poses, s_cal - s_nom)
    lo, hi = calibrated.leg_stroke[:, 0], calibrated.leg_stroke[:, 1]
    inside = np.all((s_cal >= lo) & (s_cal <= hi), axis=1)
    buf = io.StringIO()
    for line in (
        f"iwr leg corrections: {len(poses)} platform poses ({n_per_axis} per coordinate over "
        "home_pose +- workspace), calibrated " + _origin(calibrated, source) + ", nominal "
        + _origin(nominal, nominal_source) + ".",
        "Pose: the platform frame {5} in the hexapod base frame {4}, x_mm .. gamma_rad with "
        "R = Rz(alpha) Ry(beta) Rx(gamma)",
        "(genhexkins's A, B, C are gamma, beta, alpha in degrees).",
        "sN_nominal_mm: leg N's sensor reading by the nominal model; sN_calibrated_mm: by the "
        "calibrated model;",
        "dsN_mm = sN_calibrated_mm - sN_nominal_mm: what a controller that computes the nominal "
        "reading adds to it.",
        "Leg length = reading + leg offset l0 (each model's own). within_stroke: 1 if every "
        "calibrated reading is within the stroke.",
        "Frame {4} is the calibrated carriage's: what the data cannot tell apart between the "
        "carriage's last joint and the base joints sits in one or the other, so use this table "
        "with the calibrated carriage (carriage.urdf of the same export), not the nominal one.",
        ("Between its poses, dsN_mm interpolated multilinearly" if len(poses) > 1 else
         "Its one dsN_mm used over the workspace")
        + f" is off the models' own by up to {worst * 1000:.3g} um ({rms * 1000:.3g} um RMS; "
        "2000 random poses of the workspace): a finer grid (iwr export --grid) is closer.",
        *([effects_note(calibrated) + "."] if calibrated.effects else []),
    ):
        buf.write(f"# {line}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([*_POSE_COLUMNS, *[f"s{j}_nominal_mm" for j in range(1, 7)],
                *[f"s{j}_calibrated_mm" for j in range(1, 7)],
                *[f"ds{j}_mm" for j in range(1, 7)], "within_stroke"])
    for p, a, b, ok in zip(poses, s_nom, s_cal, inside, strict=True):
        w.writerow([*(repr(float(v)) for v in (*p, *a, *b, *(b - a))), int(ok)])
    return buf.getvalue(), TableWritten(len(poses), worst, rms)


def write_genhexkins_hal(path: str | os.PathLike[str], robot: Robot,
                         source: str | None = None) -> None:
    """Write :func:`genhexkins_hal` atomically."""
    atomic_write_text(path, genhexkins_hal(robot, source))


def write_hexapod_json(path: str | os.PathLike[str], robot: Robot,
                       source: str | None = None) -> None:
    """Write :func:`hexapod_dict` as JSON atomically (full double precision)."""
    atomic_write_text(path, json.dumps(hexapod_dict(robot, source), indent=1) + "\n")


def write_leg_corrections(path: str | os.PathLike[str], calibrated: Robot, nominal: Robot,
                          n_per_axis: int = 5, source: str | None = None,
                          nominal_source: str | None = None, *, check: bool = True
                          ) -> TableWritten:
    """Write :func:`leg_corrections_csv` atomically; returns its poses and interpolation
    error."""
    text, written = _corrections(calibrated, nominal, n_per_axis, source, nominal_source, check)
    atomic_write_text(path, text)
    return written
