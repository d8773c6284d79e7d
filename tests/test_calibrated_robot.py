"""iwr.calibrated_robot: the one way a result becomes a robot, for every kind of data, the same
robot as the calibration job's calibrated.toml; and the leg commands of a tracker calibration's
robot checked against the measured data alone (no iwr kinematics on the reference side)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from _ballbar import BARS, ballbar_robot

import iwr
from iwr.compensation import leg_commands, with_measured_workspace
from iwr.reporting.calibration import render

REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
REGISTRATION = (2000.0, -300.0, 150.0, math.pi / 2, 0.05, -0.02)


def _tracker_robot() -> iwr.Robot:
    return iwr.Robot.default().with_tracker(registration=REGISTRATION, reflectors=REFLECTORS)


def _kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rigid 4x4 transform T with T a_i ~ b_i (least squares), from an SVD."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = r, cb - r @ ca
    return t


def _pose(t: np.ndarray) -> np.ndarray:
    """(x, y, z, alpha, beta, gamma) of a 4x4 transform, R = Rz(alpha) Ry(beta) Rx(gamma)
    (docs/model.md, eq. 6)."""
    r = t[:3, :3]
    beta = math.asin(-r[2, 0])
    return np.array([*t[:3, 3], math.atan2(r[1, 0], r[0, 0]), beta, math.atan2(r[2, 1], r[2, 2])])


@pytest.fixture(scope="module")
def tracker_job() -> tuple[iwr.Robot, Any, Any, Any]:
    robot = _tracker_robot()
    data, truth = iwr.simulate(robot, 50, seed=11)  # noise-free
    ident, fresh = data.subset(range(40)), data.subset(range(40, 50))
    result = iwr.identify(robot, ident)
    assert result.success
    return robot, result, fresh, truth


def test_tracker_commands_reproduce_the_measured_legs(tracker_job):
    """A target given as where the reflectors were measured in {T} (the frame that puts the
    measured points on their nominal positions on the platform: what a user's tracker software
    gives) is commanded with the legs the robot had there, on poses the identification did not
    see: to 1e-8 mm, noise-free (1.6e-12 to 1.6e-11 mm over seeds 11-13). The robot of the
    result's first 58 values (the geometric errors alone) keeps the nominal registration: off
    by millimetres."""
    robot, result, fresh, _ = tracker_job
    calibrated = iwr.calibrated_robot(robot, result)
    nominal = np.array(REFLECTORS)
    targets = np.array([_pose(_kabsch(nominal, pts)) for pts in fresh.points])
    cmd = leg_commands(calibrated, fresh.q, targets)
    assert cmd.frame == "T"
    np.testing.assert_allclose(cmd.legs, fresh.legs, rtol=0, atol=1e-8)
    naive = leg_commands(robot.with_errors(result.x[:robot.n_params]), fresh.q, targets)
    assert np.abs(naive.legs - fresh.legs).max() > 1.0


def test_pose_commands_reproduce_the_measured_legs():
    """Pose data: the measured poses of fresh poses are commanded with the measured legs."""
    robot = iwr.Robot.default()
    data, _ = iwr.simulate(robot, 50, seed=4)
    ident, fresh = data.subset(range(40)), data.subset(range(40, 50))
    calibrated = iwr.calibrated_robot(robot, iwr.identify(robot, ident))
    cmd = leg_commands(calibrated, fresh.q, fresh.poses)
    assert cmd.frame == "0"
    np.testing.assert_allclose(cmd.legs, fresh.legs, rtol=0, atol=1e-8)


def test_with_errors_names_calibrated_robot_for_a_longer_result(tracker_job):
    robot, result, _, _ = tracker_job
    with pytest.raises(ValueError, match=r"x: 73 values; expected 58.*iwr.calibrated_robot"):
        robot.with_errors(result.x)
    with pytest.raises(ValueError, match=r"x: shape \(57,\)"):  # shorter: the shape, as before
        robot.with_errors(result.x[:57])


def test_bad_results_are_refused_by_name(tracker_job):
    robot, result, fresh, _ = tracker_job
    with pytest.raises(ValueError, match=r"58 parameters, but robot 'IWR' with its tracker "
                                         r"setup has 73"):
        iwr.calibrated_robot(robot, result.x[:58])
    x = np.array(result.x)
    x[60] = np.nan
    with pytest.raises(ValueError, match=r"x\[60\] \(tracker\.z\) is nan"):
        iwr.calibrated_robot(robot, x)
    # Pose data on a robot with a [tracker] table: the data's kind decides what x holds.
    pose_data, _ = iwr.simulate(iwr.Robot.default(), 30, seed=2)
    fit = iwr.identify(iwr.Robot.default(), pose_data)
    geometric = iwr.calibrated_robot(robot, fit, pose_data)
    assert np.array_equal(geometric.dh, robot.with_errors(fit.x).dh)


@pytest.mark.parametrize("name", ["pose", "points", "ballbar"])
def test_the_same_robot_as_the_jobs_file(name, tmp_path):
    """The calibration job's calibrated.toml, read back, is Calibration.calibrated_robot() and
    iwr.calibrated_robot(robot, result, data), to the bit, for every kind."""
    if name == "pose":
        robot = iwr.Robot.default()
        data, _ = iwr.simulate(robot, 40, seed=5, noise=iwr.Noise.realistic())
    elif name == "points":
        robot = _tracker_robot()
        data, _ = iwr.simulate(robot, 40, seed=5)
    else:
        robot = ballbar_robot(BARS)
        data, _ = iwr.simulate(robot, 120, seed=5)
    cal = iwr.calibrate(robot, data, "lm", seed=1)
    assert cal.kind.name == name
    render(cal).write(tmp_path, plots=False)
    written = iwr.Robot.from_toml(tmp_path / "calibrated.toml")
    assert written == cal.calibrated_robot()
    assert written == iwr.calibrated_robot(robot, cal.result, data)
    assert written != robot


def test_the_measured_poses_are_within_the_calibrated_workspace():
    """The workspace box is the robot file's, about the nominal {4}; the calibrated {4} is
    placed by the data only up to the parameters held at nominal, and 4 of these 60 measured
    poses lay beyond the box there (iwr legs flagged them). The job's robot has its box widened
    to hold every measured pose, and no wider: it flags none of them."""
    robot = iwr.Robot.default()
    data, _ = iwr.simulate(robot, 60, seed=3, noise=iwr.Noise.realistic())
    cal = iwr.calibrate(robot, data, noise=iwr.Noise.realistic(), seed=1)
    assert cal.success
    plain = iwr.calibrated_robot(robot, cal.result)  # no data: the file's box as it is
    assert np.array_equal(plain.workspace, robot.workspace)
    assert leg_commands(plain, data.q, data.poses).out_of_workspace.sum() >= 1  # 4 here
    job = cal.calibrated_robot()
    assert job == iwr.calibrated_robot(robot, cal.result, data)
    assert not leg_commands(job, data.q, data.poses).out_of_workspace.any()
    widened = job.workspace > robot.workspace
    assert widened.any() and np.all(job.workspace >= robot.workspace)
    # No wider than the poses need: each widened half-width is a pose's deviation.
    local = [np.linalg.solve(job.carriage_transform(qk), t)
             for qk, t in zip(data.q, _world(job, data), strict=True)]
    dev = np.abs(np.array([_pose(m) for m in local]) - robot.home_pose)
    np.testing.assert_allclose(job.workspace[widened], dev.max(axis=0)[widened], rtol=1e-12)
    assert with_measured_workspace(plain) is plain


def _world(robot: iwr.Robot, data: Any) -> np.ndarray:
    """The platform's 4x4 poses in {0} by the robot's forward kinematics of the readings."""
    from iwr.transforms import pose_matrix

    return pose_matrix(iwr.forward_kinematics(robot, None, data.q, data.legs))


def test_the_workspace_leaves_out_the_poses_the_screen_left_out():
    """One pose with every leg reading 60 mm off: the job's screen leaves it out, and its box
    does not hold it; iwr.calibrated_robot(robot, result, data) leaves it out as the job does
    (it widened the box to hold it: the review)."""
    robot = iwr.Robot.default()
    data, _ = iwr.simulate(robot, 60, seed=3, noise=iwr.Noise.realistic())
    legs = data.legs.copy()
    legs[7] += 60.0
    bad = iwr.Measurements(data.q, data.poses, legs, joint_types=data.joint_types)
    cal = iwr.calibrate(robot, bad, noise=iwr.Noise.realistic(), seed=1)
    assert len(cal.result.left_out) == 1
    assert iwr.calibrated_robot(robot, cal.result, bad) == cal.calibrated_robot()
    everything = with_measured_workspace(iwr.calibrated_robot(robot, cal.result), bad)
    assert np.any(everything.workspace > cal.calibrated_robot().workspace)
