"""The weighted problem in the problem file and the engine (issue 21 item 3): a problem weighted by
the instruments' noise (its per-pose whitening) is saved (format version 3), read back exactly,
and the engine's objective of the file (iwr-engine's own, ``_core._engine_costs``) is the Python
weighted cost, for the pose in {0}, tracker points and a probe; other weights are another
problem; version 2 files (unweighted, written before) read as they did; ``iwr-calibrate --noise``
runs the weighted objective end to end.

The version 2 files in tests/data/problem_v2 were written by iwr 0.1.0 before this change::

    robot = iwr.Robot.default(); m = iwr.simulate(robot, 5, seed=5, noise=Noise.realistic())
    with leg weights linspace(0.5, 2, 30); Problem(robot, m, bounds="paper").save(pose_v2.iwrp)
    points: tracker_simulate(3 reflectors, 5 poses, seed=3, hidden=0.25), tracker_problem,
    save(points_v2.iwrp, x0=x0); expected.json: their fingerprints and costs at 5 random x.
"""

from __future__ import annotations

import dataclasses
import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import iwr
import iwr.kinds
from iwr import _core
from iwr.problem_file import FormatError, engine_result, read_problem
from iwr.tracker import TrackerNoise, TrackerProblem
from iwr.tracker.api import tracker_problem, tracker_simulate

REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
REGISTRATION = (2000.0, -150.0, 300.0, math.pi / 2, 0.01, -0.02)
READINGS = dataclasses.replace(iwr.Noise.realistic(), position=0.0, orientation=0.0)
DATA = Path(__file__).parent / "data" / "problem_v2"


def _random_x(problem: Any, n: int = 20, seed: int = 7) -> np.ndarray:
    lo, hi = np.asarray(problem.lower), np.asarray(problem.upper)
    return lo + (hi - lo) * np.random.default_rng(seed).random((n, len(lo)))


def _whitened_cost(whitening: np.ndarray, residuals: np.ndarray) -> float:
    """sum_k |W_k r_k|^2 from unweighted residuals (n_poses * m,), independently of any
    objective."""
    r = residuals.reshape(len(whitening), -1)
    return float(np.sum(np.einsum("kij,kj->ki", whitening, r) ** 2))


@pytest.fixture(scope="module")
def pose() -> tuple[iwr.Problem, iwr.Problem]:
    """(weighted, unweighted without leg weights) on the same readings; the leg weights are
    folded into the whitening."""
    robot = iwr.Robot.default()
    m, _ = iwr.simulate(robot, 30, seed=5, noise=iwr.Noise.realistic())
    w = np.linspace(0.5, 2.0, m.legs.size).reshape(m.legs.shape)
    mw = iwr.Measurements(m.q, m.poses, m.legs, joint_types=m.joint_types, weights=w)
    return iwr.Problem(robot, mw, noise=iwr.Noise.realistic()), iwr.Problem(robot, m)


@pytest.fixture(scope="module")
def points() -> tuple[TrackerProblem, np.ndarray]:
    robot = iwr.Robot.default().with_tracker(registration=REGISTRATION, reflectors=REFLECTORS)
    noise = (READINGS, TrackerNoise.leica())
    m, _ = tracker_simulate(robot, 30, seed=3, noise=noise, hidden=0.2)
    return tracker_problem(robot, m, noise=noise)


@pytest.fixture(scope="module")
def probe_noise() -> tuple[TrackerProblem, np.ndarray]:
    """A probe weighted by the noise model: its four points' covariance has rank 6 (one rigid
    pose), the whitening six rows a pose that are not zero."""
    robot = iwr.Robot.default().with_tracker(registration=REGISTRATION,
                                             probe=(10.0, -5.0, 60.0, 0.1, 0.0, 0.2))
    noise = (READINGS, TrackerNoise.leica())
    m, _ = tracker_simulate(robot, 30, seed=3, noise=noise)
    problem, x0 = tracker_problem(robot, m, noise=noise)
    assert problem.n_observations == 6 * len(m)
    return problem, x0


@pytest.fixture(scope="module")
def probe() -> tuple[TrackerProblem, np.ndarray]:
    """A probe weighted by a whitening of one's own (full rank)."""
    robot = iwr.Robot.default().with_tracker(registration=REGISTRATION,
                                             probe=(10.0, -5.0, 60.0, 0.1, 0.0, 0.2))
    m, _ = tracker_simulate(robot, 30, seed=3)
    plain, x0 = tracker_problem(robot, m)
    rng = np.random.default_rng(2)
    w = np.tril(rng.normal(size=(30, 12, 12))) + 3 * np.eye(12)
    return TrackerProblem(robot, robot.tracker, m, (plain.lower, plain.upper),
                          reference=plain.reference, whitening=w), x0


def test_engine_cost_is_the_python_weighted_cost_for_poses(pose, tmp_path: Path) -> None:
    weighted, plain = pose
    path = tmp_path / "w.iwrp"
    weighted.save(path)
    X = _random_x(weighted)
    engine = _core._engine_costs(str(path), X)
    python = np.array([weighted.cost(x) for x in X])
    independent = np.array([_whitened_cost(weighted.whitening, plain.residuals(x)) for x in X])
    np.testing.assert_allclose(engine, python, rtol=1e-12, atol=0)
    np.testing.assert_allclose(engine, independent, rtol=1e-12, atol=0)
    # Weighted is another objective: not the unweighted cost of the same data.
    assert not np.allclose(engine, [plain.cost(x) for x in X], rtol=1e-3)


@pytest.mark.parametrize("name", ["points", "probe", "probe_noise"])
def test_engine_cost_is_the_python_weighted_cost_for_tracker_data(name: str, request: Any,
                                                                  tmp_path: Path) -> None:
    problem, x0 = request.getfixturevalue(name)
    path = tmp_path / f"{name}.iwrp"
    problem.save(path, x0=x0)
    X = _random_x(problem)
    engine = _core._engine_costs(str(path), X)
    python = np.array([problem.cost(x) for x in X])
    unweighted = np.array([problem.cost_unweighted(x) for x in X])
    independent = np.array([_whitened_cost(problem.whitening, problem._objective.residuals(x))
                            for x in X])
    np.testing.assert_allclose(engine, python, rtol=1e-12, atol=0)
    np.testing.assert_allclose(engine, independent, rtol=1e-12, atol=0)
    assert not np.allclose(engine, unweighted, rtol=1e-3)
    if name == "points":  # hidden reflectors went through (zero columns of the whitening)
        assert np.isnan(problem.measurements.points).any()


@pytest.mark.parametrize("name", ["pose", "points", "probe"])
def test_round_trip_keeps_the_weighting_exactly(name: str, request: Any, tmp_path: Path) -> None:
    problem = request.getfixturevalue(name)[0]
    path = tmp_path / "p.iwrp"
    problem.save(path)
    d = read_problem(path)
    assert d["version"] == 4
    text, flat = d["weighting"]
    n = problem.n_poses
    np.testing.assert_array_equal(flat, problem.whitening.reshape(n, -1))
    if name == "pose":
        assert text == str(iwr.Noise.realistic())
    elif name == "points":
        assert text == f"{READINGS}; {TrackerNoise.leica()}"
    else:
        assert text == "a whitening given with the problem"
    back = iwr.Problem.load(path)
    assert type(back) is type(problem) and back.weighted
    np.testing.assert_array_equal(back.whitening, problem.whitening)
    x = _random_x(problem, 1)[0]
    assert back.cost(x) == problem.cost(x)
    # Saved again, the same whitening.
    back.save(tmp_path / "again.iwrp")
    again = read_problem(tmp_path / "again.iwrp")
    np.testing.assert_array_equal(again["weighting"][1], flat)


def test_other_weights_are_another_problem(pose, tmp_path: Path) -> None:
    weighted, plain = pose
    other = iwr.Problem(weighted.robot, weighted.measurements,
                        noise=dataclasses.replace(iwr.Noise.realistic(), legs=0.01))
    for p, name in ((weighted, "a"), (other, "b"), (plain, "c")):
        p.save(tmp_path / f"{name}.iwrp")
    a, b, c = (read_problem(tmp_path / f"{n}.iwrp") for n in "abc")
    assert a["robot_fingerprint"] != b["robot_fingerprint"]
    assert a["robot_fingerprint"] != c["robot_fingerprint"]
    # The data fingerprint is the data file's alone (what `iwr report` checks a file against):
    # the same readings and leg weights whatever the weighting.
    assert a["data_fingerprint"] == b["data_fingerprint"]
    unweighted_same_data = iwr.Problem(weighted.robot, weighted.measurements)
    unweighted_same_data.save(tmp_path / "d.iwrp")
    assert read_problem(tmp_path / "d.iwrp")["data_fingerprint"] == a["data_fingerprint"]
    assert read_problem(tmp_path / "d.iwrp")["weighting"] is None


def test_the_reader_refuses_a_bad_whitening(points, tmp_path: Path) -> None:
    problem, x0 = points
    fields = read_problem(_saved(problem, tmp_path, x0))
    fields = {k: v for k, v in fields.items()
              if not k.endswith("_fingerprint") and k != "version"}
    text, flat = fields["weighting"]
    upper = flat.copy()
    upper[3, 1] = 0.25  # entry (0, 1) of pose 3: above the diagonal
    with pytest.raises(ValueError, match=r"whitening: pose 3, entry \(0, 1\) is 0.25.*lower "
                                         "triangular"):
        _core._encode_problem({**fields, "weighting": (text, upper)})
    bad = flat.copy()
    bad[2, 0] = math.nan
    with pytest.raises(ValueError, match="whitening: row 2, column 0 is nan, not finite"):
        _core._encode_problem({**fields, "weighting": (text, bad)})
    with pytest.raises(ValueError, match=r"whitening: shape \(30, 80\); expected \(30, 81\)"):
        _core._encode_problem({**fields, "weighting": (text, flat[:, :80])})
    with pytest.raises(ValueError, match="noise, whitening: give one or the other"):
        TrackerProblem(problem.robot, problem.setup, problem.measurements,
                       noise=(READINGS, TrackerNoise.leica()), whitening=problem.whitening)
    with pytest.raises(ValueError, match=r"whitening: pose 0, entry \(0, 2\)"):
        w = problem.whitening.copy()
        w[0, 0, 2] = 1.0
        TrackerProblem(problem.robot, problem.setup, problem.measurements, whitening=w)


def _saved(problem: Any, tmp_path: Path, x0: Any = None) -> Path:
    path = tmp_path / "saved.iwrp"
    problem.save(path, x0=x0)
    return path


@pytest.mark.parametrize("name", ["pose_v2.iwrp", "points_v2.iwrp"])
def test_version_2_files_read_as_before(name: str) -> None:
    """A file of the previous version: unweighted, the fingerprints its writer computed, the
    costs its writer's objective gave."""
    expected = json.loads((DATA / "expected.json").read_text())[name]
    d = read_problem(DATA / name)
    assert d["version"] == 2 and d["weighting"] is None
    assert d["robot_fingerprint"] == expected["robot_fingerprint"]
    assert d["data_fingerprint"] == expected["data_fingerprint"]
    X = np.array(expected["x"])
    # The same objective code as its writer's (a tolerance only for later kernel work).
    np.testing.assert_allclose(_core._engine_costs(str(DATA / name), X), expected["cost"],
                               rtol=1e-13, atol=0)
    back = iwr.Problem.load(DATA / name)
    assert not back.weighted
    np.testing.assert_allclose([back.cost(x) for x in X], expected["cost"], rtol=1e-13, atol=0)


def test_a_version_2_file_and_its_version_3_copy_are_one_problem(tmp_path: Path) -> None:
    """Saved again (version 3, unweighted), an old file keeps its fingerprints: checkpoints of
    runs on it stay valid."""
    for name in ("pose_v2.iwrp", "points_v2.iwrp"):
        old = read_problem(DATA / name)
        problem = iwr.Problem.load(DATA / name)
        path = tmp_path / name
        problem.save(path, x0=old["x0"], active=old["active"])
        new = read_problem(path)
        assert new["version"] == 4
        for key in ("robot_fingerprint", "data_fingerprint"):
            assert new[key] == old[key], (name, key)


def test_resuming_a_run_whose_problem_file_is_of_version_2(tmp_path: Path) -> None:
    """The launcher keeps a resumed run's problem file when the problem is the same: a file of
    the previous version is the same problem (its version is not a difference), another weighting
    is not."""
    from iwr.cli.calibrate_exe import _keep_the_run_problem

    for name in ("pose_v2.iwrp", "points_v2.iwrp"):
        old = read_problem(DATA / name)
        problem = iwr.Problem.load(DATA / name)
        _keep_the_run_problem(problem, str(DATA / name), "robot.toml", "data.csv",
                              x0=np.array(old["x0"]))
    problem = iwr.Problem.load(DATA / "pose_v2.iwrp")
    weighted = iwr.Problem(problem.robot, problem.measurements, bounds="paper",
                           noise=iwr.Noise.realistic())
    with pytest.raises(ValueError, match="differs from robot.toml data.csv in weighting"):
        _keep_the_run_problem(weighted, str(DATA / "pose_v2.iwrp"), "robot.toml", "data.csv")


def _tracker_files(tmp_path: Path, kind: str = "points") -> tuple[Path, Path]:
    target = ({"reflectors": REFLECTORS} if kind == "points"
              else {"probe": (10.0, -5.0, 60.0, 0.1, 0.0, 0.2)})
    robot = iwr.Robot.default().with_tracker(registration=REGISTRATION, **target)
    m, _ = iwr.simulate(robot, 20, seed=4, noise=(READINGS, TrackerNoise.leica()))
    from iwr.tracker.files import write_tracker_wide

    robot_path, data_path = tmp_path / "robot.toml", tmp_path / f"{kind}.csv"
    robot.to_toml(robot_path)
    write_tracker_wide(data_path, robot.tracker, m)
    return robot_path, data_path


def _calibrate(*args: Any, cwd: Path) -> subprocess.CompletedProcess[str]:
    """The installed iwr-calibrate (next to python, as pip puts it)."""
    launcher = Path(sys.executable).parent / "iwr-calibrate"
    return subprocess.run([str(launcher), *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=600, check=False)


@pytest.mark.parametrize("kind", ["points", "probe"])
def test_iwr_calibrate_runs_the_weighted_objective_on_tracker_data(kind: str,
                                                                   tmp_path: Path) -> None:
    robot_path, data_path = _tracker_files(tmp_path, kind)
    out = tmp_path / "run.json"
    proc = _calibrate(robot_path, data_path, "--noise", "realistic", "--output", out,
                      "--population-size", 20, "--generations", 3, "--threads", 2, "--quiet",
                      cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    d = read_problem(tmp_path / "run.json.iwrp")
    assert d["kind"] == kind and d["weighting"] is not None
    # The weighted problem iwr calibrate --noise realistic means on these data.
    robot = iwr.Robot.from_toml(robot_path)
    data = iwr.kinds.for_robot(robot).read(data_path, robot)
    noise = iwr.kinds.for_robot(robot).reading_noise(iwr.Noise.realistic())
    problem, _ = tracker_problem(robot, data, noise=noise)
    np.testing.assert_array_equal(d["weighting"][1], problem.whitening.reshape(len(data), -1))
    res = engine_result(tmp_path / "run.json.ckpt", tmp_path / "run.json.iwrp")
    assert res.settings["weighting"] == d["weighting"][0]
    # The engine's best cost is the Python weighted cost at its best point.
    assert res.fun == pytest.approx(problem.cost(res.x), rel=1e-12)
    assert res.fun != pytest.approx(problem.cost_unweighted(res.x), rel=1e-3)
    loaded = iwr.load_result(out)
    assert loaded.fun == res.fun


def test_iwr_calibrate_noise_is_checked(tmp_path: Path) -> None:
    robot_path, data_path = _tracker_files(tmp_path)
    proc = _calibrate(robot_path, data_path, "--noise", "estimate", "--output", "r.json",
                      cwd=tmp_path)
    assert proc.returncode == 2 and "--noise estimate" in proc.stderr
    proc = _calibrate(robot_path, data_path, "--noise", "robot", "--output", "r.json",
                      cwd=tmp_path)
    assert proc.returncode == 2 and "has no [noise] table" in proc.stderr
    proc = _calibrate(robot_path, data_path, "--noise", "legs=x", "--output", "r.json",
                      cwd=tmp_path)
    assert proc.returncode == 2 and "--noise: " in proc.stderr and "not a number" in proc.stderr
    (tmp_path / "p.iwrp").write_bytes(b"")
    proc = _calibrate(tmp_path / "p.iwrp", "--noise", "realistic", cwd=tmp_path)
    assert proc.returncode == 2 and "--noise: the noise weighting of a problem file" in proc.stderr


def test_a_weighted_file_refuses_a_checkpoint_of_the_unweighted_run(tmp_path: Path) -> None:
    robot_path, data_path = _tracker_files(tmp_path)
    common = ["--population-size", 12, "--generations", 2, "--threads", 1, "--quiet"]
    proc = _calibrate(robot_path, data_path, "--output", "plain.json", *common, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    proc = _calibrate(robot_path, data_path, "--noise", "realistic", "--output", "w.json",
                      "--problem", "w.iwrp", "--resume", "plain.json.ckpt", *common,
                      cwd=tmp_path)
    assert proc.returncode == 1
    assert "made for another robot" in proc.stderr and "noise weighting" in proc.stderr
    with pytest.raises(FormatError, match="made for another problem"):
        engine_result(tmp_path / "plain.json.ckpt", tmp_path / "w.iwrp")
