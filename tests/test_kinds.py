"""Measurement kinds (iwr.kinds): one protocol for pose, points and probe data; one fingerprint
(the problem file's), one validation split, and the commands that rely on them."""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import iwr
from iwr import kinds
from iwr.problem_file import encode_problem

REPO = Path(__file__).resolve().parents[1]
REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
REGISTRATION = (2000.0, -150.0, 300.0, math.pi / 2, 0.01, -0.02)


def _robot(kind: str) -> iwr.Robot:
    base = iwr.Robot.default()
    if kind == "points":
        return base.with_tracker(registration=REGISTRATION, reflectors=REFLECTORS)
    if kind == "probe":
        return base.with_tracker(registration=REGISTRATION, probe=(10.0, -5.0, 60.0, 0.1, 0.0, 0.2))
    return base


def _file_fingerprint(robot: iwr.Robot, data: Any) -> str:
    problem, _ = kinds.of(data).problem(robot, data)
    return str(iwr._core._decode_problem(encode_problem(problem), "")["data_fingerprint"])


# The conftest's `kind` fixture gives every kind in turn (robot, noise-free data, the kind).
FRAMES = {"pose": ("{0}", True), "points": ("{T}", False), "probe": ("{T}", False),
          "ballbar": ("{0}", False)}


def test_kind_of_data_and_robot(kind):
    name, robot, data = kind.name, kind.robot, kind.data
    assert kinds.of(data).name == name and kinds.for_robot(robot).name == name
    assert kinds.of(data) is kinds.for_robot(robot)
    assert (kinds.of(data).frame, kinds.of(data).determines_world_frame) == FRAMES[name]
    n_setup = len(kinds.of(data).setup_parameter_names(robot))
    assert kinds.of(data).n_params(robot) == robot.n_params + n_setup
    assert (n_setup == 0) == (name == "pose")


def test_fingerprint_is_the_problem_files(kind):
    """The kind's fingerprint, computed from the data alone, is the one the problem file (and
    so iwr-engine's result) records, for every kind (the engine takes each); another data set,
    or one reading changed, has another."""
    robot, data = kind.robot, kind.data
    k = kinds.of(data)
    fp = k.fingerprint(robot, data)
    assert len(fp) == 16
    assert k.engine and fp == _file_fingerprint(robot, data)
    assert k.fingerprint(robot, k.subset(data, range(1, len(data)))) != fp
    legs = data.legs.copy()
    legs[3, 2] += 1e-9
    changed = k.subset(data, range(len(data)))
    changed.legs = legs
    assert k.fingerprint(robot, changed) != fp


def test_weighted_pose_fingerprint_is_the_problem_files():
    robot = iwr.Robot.default()
    data, _ = iwr.simulate(robot, 10, seed=2)
    w = np.ones((10, 6))
    w[2, 4] = 0.0
    weighted = iwr.Measurements(data.q, data.poses, data.legs, joint_types=robot.joint_types,
                                weights=w)
    fp = kinds.of(weighted).fingerprint(robot, weighted)
    assert fp == _file_fingerprint(robot, weighted) != kinds.of(data).fingerprint(robot, data)


def test_one_split_for_every_kind(kind):
    """The same poses held out for every kind (the rule depends on N, the fraction and the seed
    only), each part in file order, the two parts a partition of the data."""
    data = kind.data
    ident, val = kinds.split(data, 0.2, seed=7)
    pose = iwr.simulate(iwr.Robot.default(), len(data), seed=1)[0]
    pose_ident, pose_val = kinds.split(pose, 0.2, seed=7)
    assert len(val) == round(0.2 * len(data)) == len(pose_val)
    held, kept = _rows(data, val), _rows(data, ident)
    assert list(held) == sorted(held) and list(kept) == sorted(kept)
    assert sorted([*held, *kept]) == list(range(len(data)))
    np.testing.assert_array_equal(held, _rows(pose, pose_val))
    np.testing.assert_array_equal(kept, _rows(pose, pose_ident))


def _rows(data: Any, part: Any) -> np.ndarray:
    """Where each pose of ``part`` is in ``data`` (the leg readings of simulated data differ)."""
    return np.array([int(np.flatnonzero((data.legs == row).all(axis=1))[0]) for row in part.legs])


@pytest.mark.parametrize("fraction", [0.01, 0.5, 0.9])
def test_split_always_holds_one_out_and_keeps_one(kind, fraction):
    data = kind.data
    ident, val = kinds.split(data, fraction, seed=1)
    assert len(val) >= 1 and len(ident) >= 1 and len(ident) + len(val) == len(data)


def test_split_refuses_what_leaves_nothing(kind):
    data = kind.data
    one = kinds.of(data).subset(data, [0])
    with pytest.raises(ValueError, match="leaves no pose for identification out of 1"):
        kinds.split(one, 0.2, seed=0)
    for bad in (-0.1, 0, 0.0, 1.0, math.nan, True):
        with pytest.raises(ValueError, match="fraction"):
            kinds.split(data, bad, seed=0)
    a, b = kinds.split(data, np.float32(0.2), seed=3), kinds.split(data, 0.2, seed=3)
    np.testing.assert_array_equal(a[1].legs, b[1].legs)


def test_empty_subset_is_refused_by_name(kind):
    data = kind.data
    with pytest.raises(ValueError, match="no measurements"):
        kinds.of(data).subset(data, [])


def test_subset_keeps_lines_and_source(kind, tmp_path):
    path = tmp_path / "data.csv"
    kind.kind.write(kind.robot, kind.data, path)
    back = kind.kind.read(path, kind.robot)
    part = kinds.of(back).subset(back, [2, 5])
    assert part.where(1) == back.where(5) and str(path) in part.where(0)


def test_registry_refuses_unknown_data_and_duplicate_names():
    with pytest.raises(TypeError, match="expected an iwr.Measurements or another registered"):
        kinds.of(np.zeros((3, 6)))
    with pytest.raises(ValueError, match="already registered"):
        kinds.register("pose", "iwr.kinds.pose:PoseKind")
    with pytest.raises(ValueError, match="expected an identifier"):
        kinds.register("a b", "x:Y")
    assert kinds.available()[:3] == ["pose", "points", "probe"]
    robot = _robot("points")
    with pytest.raises(TypeError, match="got TrackerSetup"):  # it has a .kind, but is no data
        kinds.of(robot.tracker)
    with pytest.raises(TypeError, match="got TrackerSetup"):
        iwr.accuracy(robot, robot.tracker, np.zeros(robot.n_params + robot.tracker.n_params))
    from iwr.kinds.pose import PoseKind

    with pytest.raises(ValueError, match="is named 'pose', not 'other'"):
        kinds.register("other", PoseKind())


def test_for_robot_finds_a_new_instrument_before_the_pose_fallback():
    """A robot describing a new instrument gets that kind, not the pose in {0} (the fallback)."""
    from iwr.kinds.pose import PoseKind

    class BarKind(PoseKind):
        name = "bar_test"
        fallback = False

        def applies_to(self, robot):
            return getattr(robot, "bar", None) is not None

    if "bar_test" not in kinds.available():
        kinds.register("bar_test", BarKind())
    robot = iwr.Robot.default()
    assert kinds.for_robot(robot).name == "pose"
    robot.bar = "a bar"
    assert kinds.for_robot(robot).name == "bar_test"


def test_first_use_of_the_registry_from_threads_loads_one_instance_per_kind():
    code = (
        "import threading, iwr\n"
        "from iwr import kinds\n"
        "r = iwr.Robot.default()\n"
        "found = []\n"
        "barrier = threading.Barrier(8)\n"
        "def go():\n"
        "    barrier.wait()\n"
        "    found.append(kinds.for_robot(r))\n"
        "ts = [threading.Thread(target=go) for _ in range(8)]\n"
        "[t.start() for t in ts]; [t.join() for t in ts]\n"
        "print(len({id(k) for k in found}), len(found))\n")
    for _ in range(5):
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              cwd=tempfile.gettempdir(), timeout=300)
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout.split() == ["1", "8"]


class _Mirrored(iwr.Measurements):
    """Pose data whose platform pose was measured with y mirrored: a kind of its own."""

    kind = "mirrored_pose"


def test_a_new_kind_is_one_class_and_one_registration():
    """The public functions reach a new kind through the registry alone: identify, accuracy and
    identifiability of data of kind 'mirrored_pose' run the new class's methods (here:
    un-mirror, then the pose kind's)."""
    from iwr.kinds.pose import PoseKind

    calls: list[str] = []

    class MirroredKind(PoseKind):
        name = "mirrored_pose"
        description = "the platform pose, y mirrored"

        @staticmethod
        def _plain(data: Any) -> iwr.Measurements:
            poses = data.poses * np.array([1, -1, 1, -1, 1, -1])
            return iwr.Measurements(data.q, poses, data.legs, joint_types=data.joint_types)

        def identify(self, robot, data, method, **options):
            calls.append("identify")
            return super().identify(robot, self._plain(data), method, **options)

        def accuracy(self, robot, data, x, **options):
            calls.append("accuracy")
            return super().accuracy(robot, self._plain(data), x, **options)

        def identifiability(self, robot, data, x=None, **options):
            calls.append("identifiability")
            return super().identifiability(robot, self._plain(data), x, **options)

    if "mirrored_pose" not in kinds.available():
        kinds.register("mirrored_pose", MirroredKind())
    robot = iwr.Robot.default()
    data, truth = iwr.simulate(robot, 20, seed=3)
    m = data.poses * np.array([1, -1, 1, -1, 1, -1])
    mirrored = _Mirrored(data.q, m, data.legs, joint_types=data.joint_types)
    res = iwr.identify(robot, mirrored)
    direct = iwr.identify(robot, data)
    np.testing.assert_allclose(res.x, direct.x, atol=1e-9)
    acc = iwr.accuracy(robot, mirrored, res.x)
    assert acc.calibrated.position.max() < 1e-6 < acc.nominal.position.max()
    assert iwr.identifiability(robot, mirrored).rank == iwr.identifiability(robot, data).rank
    assert calls == ["identify", "accuracy", "identifiability"]


def _run(*args: str, prog: list[str] | None = None) -> subprocess.CompletedProcess[str]:
    environ = {k: v for k, v in os.environ.items() if not k.startswith("IWR_")}
    return subprocess.run([*(prog or [sys.executable, "-m", "iwr"]), *args], capture_output=True,
                          text=True, cwd=tempfile.gettempdir(), env=environ, timeout=600)


def test_report_accepts_the_data_of_an_engine_run_on_tracker_data(tmp_path):
    """iwr report checks DATA against an iwr-calibrate run on tracker data with the problem
    file's fingerprint: the run's own data (wide or long) are accepted, other data refused."""
    launcher = shutil.which("iwr-calibrate", path=str(Path(sys.executable).parent))
    assert launcher is not None
    robot = REPO / "examples" / "iwr_tracker.toml"
    wide = REPO / "examples" / "iwr_tracker_points.csv"
    long = [str(REPO / "examples" / "iwr_tracker_points_long.csv"), "--readings",
            str(REPO / "examples" / "iwr_tracker_readings.csv")]
    proc = _run(str(robot), str(wide), "--generations", "3", "--output", str(tmp_path / "e.json"),
                "-q", prog=[launcher])
    assert proc.returncode == 0, proc.stderr
    recorded = json.loads((tmp_path / "e.json").read_text())["settings"]["data_fingerprint"]
    r = iwr.Robot.from_toml(robot)
    assert recorded == kinds.for_robot(r).fingerprint(r, kinds.for_robot(r).read(wide, r))
    for data in ([str(wide)], long):
        out = tmp_path / f"r{len(data)}"
        proc = _run("report", str(tmp_path / "e.json"), str(robot), *data, "--out", str(out),
                    "--no-plots")
        assert proc.returncode == 0, proc.stdout + proc.stderr
        assert "records no fingerprint" not in (out / "report.md").read_text()
    sim, _ = iwr.simulate(r, 20, seed=9)
    from iwr.tracker.files import write_tracker_wide

    write_tracker_wide(tmp_path / "other.csv", r.tracker, sim)
    proc = _run("report", str(tmp_path / "e.json"), str(robot), str(tmp_path / "other.csv"),
                "--out", str(tmp_path / "bad"), "--no-plots")
    assert proc.returncode == 2 and "is not the data" in proc.stderr, proc.stderr
    # A result written before the one fingerprint (tracker data: "tracker-" and a SHA-256 of
    # the readings and points) is still checked by that scheme.
    from iwr.cli.report import _legacy_tracker_fingerprint

    saved = json.loads((tmp_path / "e.json").read_text())
    for data, code in ((wide, 0), (tmp_path / "other.csv", 2)):
        legacy = _legacy_tracker_fingerprint(kinds.for_robot(r).read(wide, r))
        saved["settings"]["data_fingerprint"] = legacy
        (tmp_path / "old.json").write_text(json.dumps(saved))
        proc = _run("report", str(tmp_path / "old.json"), str(robot), str(data), "--out",
                    str(tmp_path / f"old{code}"), "--no-plots")
        assert proc.returncode == code, proc.stdout + proc.stderr


def test_analyze_reads_the_data_of_the_robots_kind(tmp_path):
    """iwr analyze on tracker data (wide, or long with --readings): the point objective's null
    directions, the registration's among them; --readings refused for a pose robot."""
    robot = REPO / "examples" / "iwr_tracker.toml"
    wide = REPO / "examples" / "iwr_tracker_points.csv"
    long = [str(REPO / "examples" / "iwr_tracker_points_long.csv"), "--readings",
            str(REPO / "examples" / "iwr_tracker_readings.csv")]
    outs = []
    for data in ([str(wide)], long):
        proc = _run("analyze", str(robot), *data)
        assert proc.returncode == 0, proc.stderr
        outs.append(proc.stdout)
    assert outs[0] == outs[1] and "of 73" in outs[0] and "tracker.x" in outs[0]
    # The report pose data get (it gave the rank and the directions alone: an outside check),
    # its figures those of numpy's SVD of the column-scaled Jacobian.
    for line in ("Jacobian columns scaled to unit norm", "condition number (identifiable part)",
                 "observability: O1", "base parameters: 57; left out (hold fixed): "):
        assert line in outs[0], outs[0]
    tracker = iwr.Robot.from_toml(robot)
    data = kinds.for_robot(tracker).read(wide, tracker)
    ns = iwr.identifiability(tracker, data)
    from iwr.tracker.api import tracker_problem

    problem, start = tracker_problem(tracker, data)  # at the registration guess, as it is
    jac = problem.jacobian(start)
    s = np.linalg.svd(jac / np.linalg.norm(jac, axis=0), compute_uv=False)
    assert ns.rank == 57 and ns.condition_number == pytest.approx(s[0] / s[56], rel=1e-9)
    assert ns.observability["O3"] == pytest.approx(s[56], rel=1e-9)
    assert f"condition number (identifiable part) {ns.condition_number:.4g}" in outs[0]
    proc = _run("analyze", str(REPO / "examples" / "iwr.toml"),
                str(REPO / "examples" / "iwr_example.csv"), "--readings", str(wide))
    assert proc.returncode == 2 and "--readings: only for a robot with a [tracker]" in proc.stderr
    assert "iwr analyze --help" in proc.stderr
    proc = _run("analyze", str(REPO / "examples" / "iwr.toml"), str(wide))
    assert proc.returncode == 2 and "laser-tracker data" in proc.stderr  # a usage mistake


def test_each_kind_recognises_its_own_files(kind, tmp_path):
    """A file a kind writes is recognised by that kind alone (the pose kind, the fallback,
    claims no file): what lets `iwr plan` take either the robot's own data or poses in {0}."""
    from iwr import kinds

    path = tmp_path / "data.csv"
    kind.kind.write(kind.robot, kind.data, path)
    others = [kinds.named(name) for name in ("pose", "points", "probe", "ballbar")]
    claims = {k.name for k in others if k.recognises(path)}
    tracker = {"points", "probe"}  # one file format, the robot's [tracker] table tells which
    expected = set() if kind.kind.fallback else tracker if kind.name in tracker else {kind.name}
    assert claims == expected
    assert not kind.kind.recognises(tmp_path / "missing.csv")


def test_a_kind_without_a_weighted_objective_is_refused_or_noted_by_iwr_calibrate(capsys):
    """Every built-in kind has a noise-weighted objective; a kind of one's own may not: then
    ``--method lm --noise ...`` is a usage error, and the robot file's noise model is set aside
    with a note (it is the efficient estimator's)."""
    import argparse

    from iwr.cli._base import UsageError
    from iwr.cli.calibrate import _reading_noise
    from iwr.kinds.pose import PoseKind

    class Unweighted(PoseKind):
        weighted_objective = False

    assert all(kinds.named(name).weighted_objective
               for name in ("pose", "points", "probe", "ballbar"))
    robot = iwr.Robot.default()
    args = argparse.Namespace(noise_from="--noise")
    with pytest.raises(UsageError, match="--method lm with --noise: on .* data only the "
                                         "efficient estimator"):
        _reading_noise(Unweighted(), robot, iwr.Noise.realistic(), "lm", args)
    args = argparse.Namespace(noise_from="robot.toml [noise]")
    assert _reading_noise(Unweighted(), robot, iwr.Noise.realistic(), "lm", args) is None
    assert "noise model of robot.toml [noise]: not used by method lm" in capsys.readouterr().out
    assert args.noise_from is None
    # the efficient estimator takes it
    args = argparse.Namespace(noise_from="--noise")
    assert _reading_noise(Unweighted(), robot, iwr.Noise.realistic(), "efficient", args) is not None
