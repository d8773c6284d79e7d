"""Issue 13 through the public API: Robot.with_tracker, iwr.simulate, iwr.identify,
iwr.accuracy, iwr.identifiability and iwr.forward_kinematics on tracker data."""

from __future__ import annotations

import math

import numpy as np
import pytest

import iwr
from iwr.simulation import sample_poses
from iwr.tracker import TrackerMeasurements, TrackerNoise, TrackerSetup, tool_pose_errors
from iwr.transforms import pose_matrix

REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
REGISTRATION = (2000.0, 0.0, 0.0, math.pi / 2, 0.0, 0.0)  # 2 m away, turned 90 degrees


@pytest.fixture(scope="module")
def robot() -> iwr.Robot:
    return iwr.Robot.default().with_tracker(registration=REGISTRATION, reflectors=REFLECTORS)


def truth_vector(robot: iwr.Robot, seed: int) -> np.ndarray:
    """Robot errors as iwr.simulate draws them; the registration 5 mm and 1 degree off the
    nominal; each reflector 1 mm off."""
    rng = np.random.default_rng(seed)
    lo, hi = robot.default_bounds()
    xr = lo + (hi - lo) * rng.random(robot.n_params)

    def unit(n: int) -> np.ndarray:
        v = rng.standard_normal((n, 3))
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    reg = np.concatenate([5.0 * unit(1)[0], math.radians(1.0) * unit(1)[0]])
    return np.concatenate([xr, reg, unit(robot.tracker.n_reflectors).ravel()])


def test_with_tracker_carries_the_setup_and_keeps_n_params(robot, tmp_path):
    plain = iwr.Robot.default()
    assert robot.n_params == plain.n_params == 58
    assert robot.tracker == TrackerSetup(REGISTRATION, reflectors=REFLECTORS)
    assert plain.tracker is None and robot != plain
    assert robot.with_tracker(None) == plain
    assert robot.with_errors(np.zeros(58)).tracker == robot.tracker
    probe = plain.with_tracker(registration=REGISTRATION, probe=(0, 0, 60, 0, 0, 0))
    assert probe.tracker.kind == "probe" and probe != robot
    for r in (robot, probe):
        path = tmp_path / f"{r.tracker.kind}.toml"
        r.to_toml(path)
        assert "[tracker]" in path.read_text()
        assert iwr.Robot.from_toml(path) == r
    with pytest.raises(ValueError, match="either reflectors"):
        plain.with_tracker(registration=REGISTRATION)


def test_tracker_toml_errors_name_the_file_and_key(robot, tmp_path):
    path = tmp_path / "r.toml"
    robot.to_toml(path)
    text = path.read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("registration = [", "registraton = ["))
    with pytest.raises(iwr.RobotFileError,
                       match=r"bad\.toml: tracker: unknown key\(s\) registraton"):
        iwr.Robot.from_toml(bad)
    bad.write_text(text.replace("registration = [2000.0, ", "registration = ["))
    with pytest.raises(iwr.RobotFileError,
                       match=r"bad\.toml: tracker: registration: \[0\.0, 0\.0, 1\.57\d*, 0\.0, "
                             r"0\.0\]; expected 6 numbers \(x, y, z in mm, alpha, beta, gamma "
                             r"in rad\)"):
        iwr.Robot.from_toml(bad)


ALL_REFLECTORS = ("reflectors = [\n    [120.0, 0.0, 40.0],\n    [-60.0, 104.0, 40.0],\n"
                  "    [-60.0, -104.0, 40.0],\n]")


@pytest.mark.parametrize(("old", "new", "message"), [
    # Degrees written for radians.
    ("registration = [2000.0, 0.0, 0.0, 1.5707963267948966,",
     "registration = [2000.0, 0.0, 0.0, 90,",
     r"bad\.toml: tracker: registration alpha \(entry 3\) = 90: angles are in radians \(90 deg "
     r"= 1\.5708 rad\); expected \|angle\| <= 2 pi$"),
    ("probe = [0.0, 0.0, 60.0, 0.0, 0.0, 0.0]", "probe = [0.0, 0.0, 60.0, 0.0, 0.0, -45]",
     r"bad\.toml: tracker: probe gamma \(entry 5\) = -45: angles are in radians \(-45 deg = "
     r"-0\.7854 rad\)"),
    # A ragged, non-numeric or empty reflectors array.
    ("[-60.0, 104.0, 40.0]", "[-60.0, 104.0]",
     r"bad\.toml: tracker: reflectors: reflector 2: \[-60\.0, 104\.0\]; expected 3 numbers "
     r"\(x, y, z in mm\)$"),
    ("[-60.0, -104.0, 40.0]", '[-60.0, "-104", 40.0]',
     r"bad\.toml: tracker: reflectors: reflector 3: entry 1 is '-104'; expected a number "
     r"\(x, y, z in mm\)$"),
    ("[-60.0, -104.0, 40.0]", "[-60.0, [-104], 40.0]",
     r"bad\.toml: tracker: reflectors: reflector 3: entry 1 is \[-104\]; expected a number"),
    (ALL_REFLECTORS,
     "reflectors = []",
     r"bad\.toml: tracker: reflectors: empty; expected at least one reflector, 3 numbers "
     r"\(x, y, z in mm\)$"),
    (ALL_REFLECTORS,
     'reflectors = "120 0 40"', r"bad\.toml: tracker: reflectors: '120 0 40'; expected a list"),
])
def test_tracker_toml_names_a_bad_value(robot, tmp_path, old, new, message):
    """A bad value in [tracker]: one message naming the file, the table, the field and the
    entry (a reflector by its 1-based number), never NumPy's words."""
    path = tmp_path / "r.toml"
    if old.startswith("probe"):
        robot = robot.with_tracker(registration=REGISTRATION, probe=(0, 0, 60, 0, 0, 0))
    robot.to_toml(path)
    text = path.read_text()
    assert old in text
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace(old, new))
    with pytest.raises(iwr.RobotFileError, match=message):
        iwr.Robot.from_toml(bad)


def test_simulate_returns_point_data_and_a_truth_covering_the_setup(robot):
    data, truth = iwr.simulate(robot, 20, seed=3)
    assert isinstance(data, TrackerMeasurements) and data.kind == "points"
    assert data.points.shape == (20, 3, 3)
    assert truth.shape == (robot.n_params + robot.tracker.n_params,)
    again, truth2 = iwr.simulate(robot, 20, seed=3)
    np.testing.assert_array_equal(again.points, data.points)
    clean, _ = iwr.simulate(robot, 20, seed=4, x=truth)
    noisy, _ = iwr.simulate(robot, 20, seed=4, x=truth,
                            noise=(iwr.Noise(legs=0.002), TrackerNoise.leica()))
    d = np.abs(noisy.points - clean.points)
    assert 1e-4 < d.max() < 0.2
    with pytest.raises(ValueError, match="pose measured in"):
        iwr.simulate(robot, 5, seed=1, noise=iwr.Noise.realistic())


@pytest.mark.parametrize("hidden", [0.0, 0.2])
def test_identify_from_the_nominal_model_recovers_the_tool_pose(robot, hidden):
    truth = truth_vector(robot, 1)
    data, x_true = iwr.simulate(robot, 100, seed=1, x=truth)
    np.testing.assert_array_equal(x_true, truth)
    if hidden:  # one reflector hidden at 20 % of the poses
        rng = np.random.default_rng(5)
        pts = data.points.copy()
        rows = rng.choice(len(data), size=20, replace=False)
        pts[rows, rng.integers(0, 3, size=20)] = np.nan
        data = TrackerMeasurements(data.q, data.legs, points=pts, joint_types=data.joint_types)
        assert np.count_nonzero(~data.seen) == 20
    res = iwr.identify(robot, data)
    assert res.success, res.message
    assert res.x.shape == truth.shape and res.parameter_names[58] == "tracker.x"
    q, _, legs = sample_poses(robot, 50, np.random.default_rng(99), truth[: robot.n_params])
    after = tool_pose_errors(robot, robot.tracker, res.x, truth, q, legs)
    assert after.position.max() < 1e-6
    assert math.radians(after.orientation.max()) < 1e-9
    # iwr.accuracy with the truth: the same tool pose errors, and millimetres before.
    fresh_data, _ = iwr.simulate(robot, 50, seed=77, x=truth)
    acc = iwr.accuracy(robot, fresh_data, res.x, truth=truth)
    assert acc.calibrated.position.max() < 1e-6
    assert acc.nominal.position.max() > 0.1
    # Without the truth: point residuals on validation poses, round-off after, mm before.
    acc2 = iwr.accuracy(robot, fresh_data, res.x)
    assert acc2.calibrated.position.max() < 1e-6
    assert acc2.calibrated.orientation.max() < 1e-7
    assert acc2.nominal.position.max() > 0.1


def test_forward_kinematics_gives_poses_in_the_tracker_frame(robot):
    truth = truth_vector(robot, 2)
    data, _ = iwr.simulate(robot, 10, seed=2, x=truth)
    poses_t = iwr.forward_kinematics(robot, truth, data.q, data.legs)
    nr = robot.n_params
    poses_0 = iwr.forward_kinematics(robot, truth[:nr], data.q, data.legs)
    reg = robot.tracker.registration_matrix(truth[nr:])
    for pt, p0 in zip(poses_t, poses_0, strict=True):
        np.testing.assert_allclose(pose_matrix(pt), reg @ pose_matrix(p0), atol=1e-9)
    # The reflectors seen by the tracker are where those frames put the reflector offsets.
    refl = robot.tracker.platform_points(truth[nr:])
    pred = np.einsum("nij,kj->nki", np.array([pose_matrix(p)[:3, :3] for p in poses_t]), refl)
    pred += poses_t[:, None, :3]
    np.testing.assert_allclose(pred, data.points, atol=1e-8)


def test_identifiability_names_the_null_directions_of_point_data(robot):
    data, _ = iwr.simulate(robot, 40, seed=4)
    ns = iwr.identifiability(robot, data)
    assert len(ns.parameter_names) == 73 and ns.rank == 57 and len(ns.left_out) == 16
    assert ns.active.sum() == 57
    res = iwr.identify(robot, data, active="base")
    assert res.success and np.array_equal(res.active, ns.active)


def test_the_parameters_left_out_do_not_depend_on_round_off(robot):
    # The registration's translation and the carriage's base make exactly dependent columns
    # (tracker.x with joint1.da, tracker.z with joint1.dd, ...: docs/tracker.md); QR with column
    # pivoting chose between them by round-off, and so did the gauge of a calibration file (the
    # same data, another build: the registration held at the guess instead of identified). The
    # same 60 poses in 6 orders: the same parameters left out; 6 subsets of 48: the same ones
    # of the carriage and the registration (the platform frame's choice may follow the data),
    # the carriage's and not the registration's translation.
    data, _ = iwr.simulate(robot, 60, seed=3)
    rng = np.random.default_rng(1)
    every, base = set(), set()
    for trial in range(12):
        idx = rng.permutation(60)[: 60 if trial < 6 else 48]
        sub = TrackerMeasurements(data.q[idx], data.legs[idx], points=data.points[idx])
        left_out = iwr.identifiability(robot, sub).left_out
        if trial < 6:
            every.add(tuple(left_out))
        base.add(tuple(n for n in left_out if n.startswith(("joint", "tracker"))))
    assert len(every) == 1, every
    assert len(base) == 1, base
    left_out = set(base.pop())
    assert {"joint1.da", "joint1.dd", "joint2.dd"} <= left_out
    assert not left_out & {"tracker.x", "tracker.y", "tracker.z"}


@pytest.mark.parametrize("method", ["de", "crs2", "bobyqa"])
def test_every_method_runs_through_identify(robot, method):
    from iwr.tracker import tracker_problem

    data, _ = iwr.simulate(robot, 15, seed=6)
    problem, x0 = tracker_problem(robot, data)
    opts = {"generations": 3, "population_size": 20, "workers": 1} if method == "de" else \
        {"max_evaluations": 200}
    res = iwr.identify(robot, data, method=method, seed=1, **opts)
    assert res.method == method and np.isfinite(res.fun) and res.x.shape == (73,)
    assert res.fun == pytest.approx(problem.cost(res.x), rel=1e-12)
    if method != "crs2":  # DE is polished by LM; BOBYQA starts from the guess
        assert res.fun < problem.cost(x0)


def test_probe_data_through_the_public_api():
    robot = iwr.Robot.default().with_tracker(registration=REGISTRATION,
                                             probe=(10.0, 5.0, 60.0, 0.2, 0.0, 0.0))
    data, truth = iwr.simulate(robot, 60, seed=8)
    assert data.kind == "probe" and truth.shape == (70,)
    res = iwr.identify(robot, data)
    assert res.success
    fresh, _ = iwr.simulate(robot, 30, seed=9, x=truth)
    acc = iwr.accuracy(robot, fresh, res.x, truth=truth)
    assert acc.calibrated.position.max() < 1e-6


def test_accuracy_on_too_few_points_for_a_registration_guess(robot):
    one = iwr.Robot.default().with_tracker(registration=REGISTRATION, reflectors=REFLECTORS[:1])
    data, truth = iwr.simulate(one, 2, seed=3)  # 2 points: no guess of their own
    acc = iwr.accuracy(one, data, truth)
    assert acc.calibrated.position.max() < 1e-9
    assert acc.nominal.position.max() > 0.1  # the nominal robot in the true registration
    assert np.isnan(acc.calibrated.orientation).all()  # one point per pose: no orientation
