"""The problem file (``.iwrp``) and the engine's result.

A problem file holds everything the C++ engine (``iwr-engine``) needs after every Python check: the
robot (geometry, limits, workspace), the measurements (leg data with poses in {0} and their
weights; laser-tracker data: points or probe poses in the tracker frame, with the nominal
tracker setup and the reference of the forward kinematics; or a double ballbar's distances with
the bar's set-ups and the reference), the noise weighting if any (the
per-pose whitening of the residuals, ``Problem.whitening``), the search bounds, the
starting point ``x0`` and the active set, the parameter names, and where the data came from
(paths and SHA-256 of the TOML and CSV files). It is a versioned, checksummed little-endian
binary file (``docs/iwr-calibrate.md`` gives the layout), written and read by the one C++
writer and reader (``cpp/include/iwr/problem_file.hpp``) through ``iwr._core``, so Python and
the engine accept exactly the same files.

The engine writes its result into its checkpoint (binary, the same container); :func:`engine_result`
turns a checkpoint into an :class:`~iwr.methods.IdentificationResult`, whose ``save`` writes the one
JSON result format.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Any

import numpy as np

from . import _core
from ._hooks import hook
from ._io import atomic_write
from .measurements import Measurements
from .problem_base import bounds_kind
from .result import IdentificationResult, status_from_message
from .robot import Robot
from .robot_fingerprint import record as robot_model_record

__all__ = ["save_problem", "load_problem", "engine_result", "sha256_of", "FormatError"]

#: A malformed, truncated or foreign binary file (a ValueError).
FormatError = _core.FormatError


def sha256_of(path: str | os.PathLike[str]) -> str:
    """The SHA-256 of a file's bytes, in hex."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _search_start(problem: Any, x0: Any, active: Any) -> tuple[list[float], list[bool]]:
    n = problem.n_params
    x = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float)
    if x.shape != (n,) or not np.all(np.isfinite(x)):
        raise ValueError(f"x0: expected {n} finite values, got shape {x.shape}")
    a = np.ones(n, dtype=bool) if active is None else np.asarray(active)
    if a.shape != (n,) or a.dtype != bool:
        raise ValueError(f"active: expected {n} booleans, got {a.dtype} of shape {a.shape}")
    if not a.any():
        raise ValueError("active: no parameter is active")
    return [float(v) for v in x], [bool(v) for v in a]


def _weighting(problem: Any) -> tuple[str, np.ndarray] | None:
    """The problem's noise weighting as the file holds it: what it was made from (in words) and
    the whitening, (N, m^2) with m the residuals of a pose; None when unweighted."""
    wh = getattr(problem, "whitening", None)
    if wh is None:
        return None
    wh = np.asarray(wh, dtype=float)
    noise = getattr(problem, "noise", None)
    if noise is None:
        text = "a whitening given with the problem"
    elif isinstance(noise, tuple):  # tracker data: (readings' Noise or None, TrackerNoise)
        text = "; ".join(str(part) for part in noise if part is not None)
    else:
        text = str(noise)
    return text, np.ascontiguousarray(wh.reshape(len(wh), -1))


def encode_problem(problem: Any, sources: dict[str, str | os.PathLike[str]] | None = None, *,
                   x0: Any = None, active: Any = None) -> bytes:
    """The bytes of ``problem``'s file (an :class:`iwr.Problem`, an
    :class:`iwr.tracker.TrackerProblem` or an :class:`iwr.ballbar.BallbarProblem`); ``sources``
    maps a role (``"robot"``, ``"data"``) to the file it was read from (recorded with its
    SHA-256); ``x0`` (default zeros) and ``active`` (default all) are the search's starting
    point and active set."""
    robot, m = problem.robot, problem.measurements
    srcs = []
    for role, path in (sources or {}).items():
        p = Path(path)
        srcs.append((str(role), str(p.resolve()), sha256_of(p) if p.is_file() else ""))
    start, mask = _search_start(problem, x0, active)
    fields: dict[str, Any] = dict(
        robot_name=robot.name,
        joint_types=robot.joint_types,
        dh=np.ascontiguousarray(robot.dh, dtype=float),
        joint_limits=np.ascontiguousarray(robot.joint_limits, dtype=float),
        base_joints=robot.base_joints,
        platform_joints=robot.platform_joints,
        leg_offsets=robot.leg_offsets,
        leg_stroke=np.ascontiguousarray(robot.leg_stroke, dtype=float),
        home_pose=robot.home_pose,
        workspace=robot.workspace,
        measurement_joint_types=m.joint_types,
        q=np.ascontiguousarray(m.q, dtype=float),
        legs=np.ascontiguousarray(m.legs, dtype=float),
        lower=[float(v) for v in problem.lower],
        upper=[float(v) for v in problem.upper],
        bounds_kind=bounds_kind(problem),
        x0=start,
        active=mask,
        parameter_names=list(problem.parameter_names),
        sources=srcs,
        weighting=_weighting(problem),
    )
    setup = getattr(problem, "setup", None)
    own = getattr(problem, "file_fields", None)
    if own is not None:  # a kind with its own section (ballbar data: kind 3)
        fields.update(own())
    elif setup is None:
        # The effects (issue 23, version 4): their tables, the payload and the temperatures.
        fields.update(kind="pose", poses=m.poses, weights=m.weights,
                      effects=[(e.name, e.to_dict()) for e in robot.effects],
                      payload=m.payload, temperatures=m.temperatures)
    else:
        fields.update(kind=setup.kind, registration=setup.registration,
                      points=m.tracker_points(setup), reference=problem.reference)
        # issue 23: the effects on tracker data, their loads and temperatures, gravity in {T}
        fields.update(effects=[(e.name, e.to_dict()) for e in robot.effects],
                      payload=m.payload, temperatures=m.temperatures,
                      tracker_gravity=np.asarray(setup.gravity, dtype=float))
        if setup.kind == "points":
            fields.update(reflectors=setup.reflectors, reflector_names=list(setup.names))
        else:
            fields.update(probe=setup.probe, probe_length=setup.probe_length,
                          probe_poses=m.probe)
    return _core._encode_problem(fields)


def save_problem(problem: Any, path: str | os.PathLike[str],
                 sources: dict[str, str | os.PathLike[str]] | None = None, *, x0: Any = None,
                 active: Any = None) -> None:
    """Write ``problem``'s file atomically (see :meth:`iwr.Problem.save`)."""
    data = encode_problem(problem, sources, x0=x0, active=active)
    atomic_write(path, lambda fh: fh.write(data), binary=True)


def read_problem(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The fields of a problem file, checked; raises :class:`FormatError` naming the file and
    field. ``kind`` is ``"pose"`` (leg data, poses in {0}), ``"points"`` or ``"probe"`` (tracker
    data) or ``"ballbar"`` (the set-ups ``bar_names``, ``platform_balls``, ``fixed_balls``,
    ``offsets``, ``ranges``, each pose's set-up ``bar`` and reading ``distance``); ``x0`` and
    ``active`` are the search's starting point and active set; ``weighting`` is None
    (unweighted, and every file of version 2) or ``(text, whitening)``: what the noise
    weighting was made from and the whitening, (N, m^2) with m the residuals of a pose;
    ``effects`` is a list of ``(name, table)`` (empty: none, and every file before version 4),
    ``payload`` (N, 4) and ``temperatures`` (N, 1 or 6) are None when absent."""
    return _core._read_problem(os.fspath(path))


def load_problem(path: str | os.PathLike[str]) -> Any:
    """The problem of a problem file (see :meth:`iwr.Problem.load`): an :class:`iwr.Problem` for
    leg data, an :class:`iwr.tracker.TrackerProblem` for tracker data, an
    :class:`iwr.ballbar.BallbarProblem` for ballbar data. The search's ``x0`` and
    ``active`` are in :func:`read_problem`'s fields."""
    from .problem import Problem  # problem.py imports this module lazily: no cycle at import

    d = read_problem(path)
    robot = Robot(
        d["joint_types"], d["dh"], d["joint_limits"], d["base_joints"], d["platform_joints"],
        d["leg_offsets"], d["leg_stroke"], d["home_pose"], d["workspace"], name=d["robot_name"],
    )
    bounds = (np.array(d["lower"]), np.array(d["upper"]))
    n = len(d["legs"])
    whitening = None
    if d["weighting"] is not None:  # (N, m^2) -> (N, m, m)
        flat = d["weighting"][1]
        m_res = int(round(np.sqrt(flat.shape[1])))
        whitening = flat.reshape(n, m_res, m_res)
    if d["kind"] == "ballbar":  # iwr.ballbar's section, with the effects if any (issue 23)
        from .ballbar.problem import BallbarProblem

        try:
            return BallbarProblem.from_file_fields(d, robot, bounds, whitening, os.fspath(path))
        except ValueError as exc:  # what the Python checks refuse and the reader did not
            raise FormatError(f"{path}: {exc}") from None
    if d["effects"]:  # issue 23: the robot's effects, from their tables (checked again)
        from .effects import read_table

        try:
            robot = robot.with_effects(*read_table(dict(d["effects"]), f"{path}: effects"))
        except ValueError as exc:
            raise FormatError(str(exc)) from None
    if d["kind"] == "pose":
        m = Measurements(d["q"], d["poses"], d["legs"], joint_types=d["measurement_joint_types"],
                         weights=d["weights"], payload=d["payload"],
                         temperatures=d["temperatures"], source=os.fspath(path))
        return Problem(robot, m, bounds=bounds, whitening=whitening)
    from .tracker.data import TrackerMeasurements
    from .tracker.problem import TrackerProblem
    from .tracker.setup import TrackerSetup

    loads = {"payload": d["payload"], "temperatures": d["temperatures"]}
    gravity = d["tracker_gravity"]  # tracker data with effects: gravity in {T}
    if d["kind"] == "points":
        setup = TrackerSetup(d["registration"], reflectors=d["reflectors"],
                             names=d["reflector_names"], gravity=gravity)
        tm = TrackerMeasurements(d["q"], d["legs"], points=d["points"].reshape(n, -1, 3),
                                 joint_types=d["measurement_joint_types"], source=os.fspath(path),
                                 **loads)
    else:
        setup = TrackerSetup(d["registration"], probe=d["probe"], probe_length=d["probe_length"],
                             gravity=gravity)
        tm = TrackerMeasurements(d["q"], d["legs"], probe=d["probe_poses"],
                                 joint_types=d["measurement_joint_types"], source=os.fspath(path),
                                 **loads)
        # The engine runs on the stored virtual points: they must be those of the probe poses.
        if not np.array_equal(tm.tracker_points(setup), d["points"]):
            raise FormatError(f"{path}: points: not the virtual points of the probe poses")
    if robot.effects:  # issue 23: the point objective with the effects (C++ and numpy)
        problem = hook("tracker_effect_problem")(robot.with_tracker(setup=setup), setup, tm,
                                                 bounds, reference=d["reference"])
        problem.whitening = whitening
        return problem
    return TrackerProblem(robot.with_tracker(setup=setup), setup, tm, bounds,
                          reference=d["reference"], whitening=whitening)


def engine_result(checkpoint: str | os.PathLike[str],
                  problem: str | os.PathLike[str] | None = None) -> IdentificationResult:
    """The result an ``iwr-engine`` checkpoint holds (its final one is the run's result).

    Parameters
    ----------
    checkpoint : path
    problem : path, optional
        The problem file of the run, for the parameter names (checked against the checkpoint's
        fingerprints); without it the names are ``x0``, ``x1``, ...
    """
    c = _core._read_checkpoint(os.fspath(checkpoint))
    names = [f"x{i}" for i in range(len(c["x"]))]
    settings: dict[str, Any] = dict(c["settings"])
    if problem is not None:
        p = read_problem(problem)
        if (p["robot_fingerprint"], p["data_fingerprint"]) != (c["robot_fingerprint"],
                                                             c["data_fingerprint"]):
            raise FormatError(f"{checkpoint}: made for another problem than {problem}")
        names = list(p["parameter_names"])
        # The model of the robot the engine ran on, as every job records it (iwr report checks
        # its robot file against it); the problem file holds all of it.
        try:
            settings["robot_model"] = robot_model_record(load_problem(problem).robot)
        except ValueError:  # a file the Python checks refuse: no record (iwr report warns)
            pass
        settings["bounds"] = p["bounds_kind"]
        settings["n_poses"] = len(p["legs"])
        settings["measurements"] = p["kind"]
        settings["sources"] = {role: path for role, path, _ in p["sources"]}
        settings["sources_sha256"] = {role: sha for role, _, sha in p["sources"] if sha}
        if p["weighting"] is not None:
            settings["weighting"] = p["weighting"][0]
    settings.update(
        lower=c["lower"].tolist(), upper=c["upper"].tolist(), generations=c["generations"],
        max_evaluations=c["max_evaluations"], target_cost=c["target_cost"], tol=c["tol"],
        atol=c["atol"], stagnation_generations=c["stagnation_generations"],
        stagnation_tol=c["stagnation_tol"], preset=c["preset"],
        checkpoint=os.fspath(checkpoint), checkpoint_every=c["checkpoint_every"],
        resumed_from=c["resumed_from"], problem=c["problem_file"],
        robot_fingerprint=c["robot_fingerprint"], data_fingerprint=c["data_fingerprint"],
        settings_fingerprint=c["settings_fingerprint"], program=c["program"],
    )
    active = None if problem is None or all(p["active"]) else np.array(p["active"], dtype=bool)
    return IdentificationResult(
        active=active,
        x=np.asarray(c["x"], dtype=float),
        fun=float(c["fun"]),
        nfev=int(c["nfev"]),
        nit=int(c["nit"]),
        success=bool(c["success"]),
        message=str(c["message"]),
        status=status_from_message(bool(c["success"]), str(c["message"])),
        method="de",
        wall_time=float(c["wall_time"]),
        parameter_names=names,
        settings=settings,
        history={k: np.asarray(v) for k, v in c["history"].items()},
    )
