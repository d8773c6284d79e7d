"""Forward kinematics and the accuracy figure, against independent computations."""

from __future__ import annotations

import math

import numpy as np
import pytest

import iwr
from iwr import _core
from iwr.transforms import euler_zyx, pose_matrix, rotvec_matrix


@pytest.fixture(scope="module")
def robot() -> iwr.Robot:
    return iwr.Robot.default()


def np_leg_lengths(base: np.ndarray, platform: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Eq. (5) in plain NumPy: whole leg lengths at a local pose of {5} in {4}."""
    r = euler_zyx(*pose[3:])
    return np.linalg.norm(pose[:3] + platform @ r.T - base, axis=1)


def local_jacobian_fd(robot: iwr.Robot, pose: np.ndarray, h: float = 1e-6) -> np.ndarray:
    cols = []
    for e in np.eye(6):
        plus = np_leg_lengths(robot.base_joints, robot.platform_joints, pose + h * e)
        minus = np_leg_lengths(robot.base_joints, robot.platform_joints, pose - h * e)
        cols.append((plus - minus) / (2 * h))
    return np.column_stack(cols)


def random_local_poses(robot: iwr.Robot, n: int, rng: np.random.Generator) -> np.ndarray:
    return robot.home_pose + robot.workspace * (2 * rng.random((n, 6)) - 1)


def test_leg_length_jacobian_matches_central_differences(robot):
    rng = np.random.default_rng(0)
    for pose in random_local_poses(robot, 5, rng):
        lengths, jac = _core.hexapod_leg_lengths(robot.base_joints, robot.platform_joints, pose)
        np.testing.assert_allclose(
            lengths, np_leg_lengths(robot.base_joints, robot.platform_joints, pose), rtol=1e-14
        )
        np.testing.assert_allclose(jac, local_jacobian_fd(robot, pose), rtol=1e-6, atol=1e-6)


def test_default_hexapod_is_well_conditioned_across_its_workspace(robot):
    # An architecturally singular hexapod (all legs on one regulus) has a rank-3 leg Jacobian at
    # every pose; forward kinematics would be meaningless. Independent finite differences.
    rng = np.random.default_rng(1)
    radius = np.linalg.norm(robot.platform_joints, axis=1).max()
    worst = math.inf
    for pose in np.vstack([robot.home_pose, random_local_poses(robot, 20, rng)]):
        jac = local_jacobian_fd(robot, pose)
        jac[:, 3:] /= radius  # angles as arc lengths on the platform: every column in mm/mm
        s = np.linalg.svd(jac, compute_uv=False)
        worst = min(worst, s[-1] / s[0])
    assert worst > 0.1


def world_poses(robot: iwr.Robot, x: np.ndarray, q: np.ndarray, local: np.ndarray) -> np.ndarray:
    """World poses 0T4(q) 4T5(local) (eq. 7), as 4x4 matrices."""
    return np.array([robot.carriage_transform(qk, x) for qk in q]) @ pose_matrix(local)


def test_round_trip_through_the_inverse_model(robot):
    rng = np.random.default_rng(2)
    lo, hi = robot.default_bounds()
    x = rng.uniform(lo, hi)
    n = 40
    q = robot.joint_limits[:, 0] + np.ptp(robot.joint_limits, axis=1) * rng.random((n, 4))
    t = world_poses(robot, x, q, random_local_poses(robot, n, rng))
    poses = np.concatenate([t[:, :3, 3], iwr.transforms.euler_from_matrix(t[:, :3, :3])], axis=1)
    legs = iwr.predict_legs(robot, x, q, poses)
    back = iwr.forward_kinematics(robot, x, q, legs)
    # compare transforms, not Euler angles (the IWR's world angles are near their gimbal lock)
    tb = pose_matrix(back)
    np.testing.assert_allclose(tb[:, :3, 3], t[:, :3, 3], atol=1e-7)
    np.testing.assert_allclose(tb[:, :3, :3], t[:, :3, :3], atol=1e-10)
    # and the legs of the answer are the legs given
    np.testing.assert_allclose(iwr.predict_legs(robot, x, q, back), legs, atol=1e-8)


def test_equal_legs_give_the_symmetric_pose():
    # Base joints on a circle of 400 at -10, 10, 110, ...; each leg's platform joint 40 degrees
    # away on a circle of 250. Equal legs: by the three-fold and mirror symmetry the platform is
    # level and centred, z^2 = L^2 - (400^2 + 250^2 - 2 400 250 cos 40).
    hexa = iwr.Robot.hexapod()
    d2 = 400**2 + 250**2 - 2 * 400 * 250 * math.cos(math.radians(40))
    for reading in (100.0, 200.0, 350.0):
        length = reading + 600.0
        z = math.sqrt(length**2 - d2)
        pose = iwr.forward_kinematics(hexa, None, np.zeros((1, 0)), np.full((1, 6), reading))
        np.testing.assert_allclose(pose[0], [0, 0, z, 0, 0, 0], atol=1e-9)
        # the mirror assembly mode below the base plate, reached from a guess down there
        below = iwr.forward_kinematics(hexa, None, np.zeros((1, 0)), np.full((1, 6), reading),
                                       guess=[0, 0, -700, 0, 0, 0])
        np.testing.assert_allclose(below[0], [0, 0, -z, 0, 0, 0], atol=1e-9)


def test_equal_legs_on_the_carriage_follow_the_carriage(robot):
    q = np.array([[700.0, 250.0, 0.3, -0.4], [0.0, 1000.0, -1.2, 0.9]])
    reading = 150.0
    z = math.sqrt((reading + 600.0) ** 2 - (400**2 + 250**2 - 2e5 * math.cos(math.radians(40))))
    poses = iwr.forward_kinematics(robot, None, q, np.full((2, 6), reading))
    for k in range(2):
        expected = robot.carriage_transform(q[k]) @ pose_matrix([0, 0, z, 0, 0, 0])
        np.testing.assert_allclose(pose_matrix(poses[k]), expected, atol=1e-9)


def test_forward_kinematics_errors(robot):
    m, x = iwr.simulate(robot, n_poses=4, seed=3)
    legs = m.legs.copy()
    legs[2, 0] = -590.0  # a 10 mm leg among legs of ~800 mm: no pose closes the loop
    with pytest.raises(iwr.ForwardKinematicsError, match="pose 2") as info:
        iwr.forward_kinematics(robot, x, m.q, legs)
    assert info.value.pose == 2
    assert isinstance(info.value, RuntimeError)
    with pytest.raises(iwr.ForwardKinematicsError, match="no convergence in 1 Newton"):
        iwr.forward_kinematics(robot, x, m.q, m.legs, max_iterations=1)
    # a degenerate platform (all joints at one point) makes the Jacobian singular
    flat = iwr.Robot("", np.zeros((0, 4)), np.zeros((0, 2)), robot.base_joints, np.zeros((6, 3)),
                     robot.leg_offsets, robot.leg_stroke, robot.home_pose, robot.workspace)
    with pytest.raises(iwr.ForwardKinematicsError, match="singular"):
        iwr.forward_kinematics(flat, None, np.zeros((1, 0)), np.full((1, 6), 200.0))
    legs = m.legs.copy()
    legs[1, 3] = -700.0
    with pytest.raises(ValueError, match="pose 1: leg 4 has length -100"):
        iwr.forward_kinematics(robot, x, m.q, legs)
    with pytest.raises(ValueError, match=r"legs: shape \(4, 5\)"):
        iwr.forward_kinematics(robot, None, m.q, m.legs[:, :5])
    with pytest.raises(ValueError, match=r"q: shape \(3, 4\)"):
        iwr.forward_kinematics(robot, None, m.q[:3], m.legs)
    with pytest.raises(ValueError, match=r"x: shape \(3,\)"):
        iwr.forward_kinematics(robot, np.zeros(3), m.q, m.legs)
    with pytest.raises(ValueError, match="tolerance: -1"):
        iwr.forward_kinematics(robot, None, m.q, m.legs, tolerance=-1.0)
    with pytest.raises(ValueError, match=r"guess: shape \(2, 6\)"):
        iwr.forward_kinematics(robot, None, m.q, m.legs, guess=np.zeros((2, 6)))


# -- accuracy ------------------------------------------------------------------------------------


def test_pose_errors_of_known_displacements():
    rng = np.random.default_rng(4)
    n = 10
    ref = np.column_stack([rng.normal(0, 500, (n, 3)), rng.uniform(-1, 1, (n, 3))])
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1)[:, None]
    angle = np.radians(np.linspace(0.001, 170.0, n))
    shift = rng.normal(size=(n, 3))
    shift *= (np.arange(1, n + 1) / np.linalg.norm(shift, axis=1))[:, None]
    t = pose_matrix(ref)
    moved = t.copy()
    moved[:, :3, :3] = t[:, :3, :3] @ rotvec_matrix(axis * angle[:, None])
    moved[:, :3, 3] += shift
    poses = iwr.transforms.pose_from_matrix(moved)
    pos, ori = iwr.pose_errors(poses, ref)
    np.testing.assert_allclose(pos, np.arange(1, n + 1), rtol=1e-12)
    np.testing.assert_allclose(ori, np.degrees(angle), rtol=1e-9)
    # a tool 100 mm out along z of {5}: its position error also sees the rotation
    tool = np.array([0.0, 0.0, 100.0])
    pos_t, _ = iwr.pose_errors(poses, ref, tool=tool)
    expected = np.linalg.norm(
        moved[:, :3, 3] + moved[:, :3, :3] @ tool - t[:, :3, 3] - t[:, :3, :3] @ tool, axis=1)
    np.testing.assert_allclose(pos_t, expected, rtol=1e-12)


def test_accuracy_with_true_errors_is_exact_without_noise(robot):
    m, x = iwr.simulate(robot, n_poses=20, seed=5)
    acc = iwr.accuracy(robot, m, x)
    assert acc.n_poses == 20
    assert acc.calibrated.position.max() < 1e-6
    assert acc.calibrated.orientation.max() < 1e-8
    # the nominal robot is off by millimetres (errors of +-0.5 mm and +-0.5 degree)
    assert acc.nominal.summary()["position_mm"]["rms"] > 1.0
    s = acc.nominal.summary()["position_mm"]
    v = acc.nominal.position
    assert s["mean"] == pytest.approx(v.mean()) and s["max"] == pytest.approx(v.max())
    assert s["rms"] == pytest.approx(math.sqrt(np.mean(v**2)))
    assert "calibrated robot" in acc.table() and acc.to_dict()["n_poses"] == 20


def test_accuracy_after_calibration_is_better_on_held_out_noisy_poses(robot):
    data, truth = iwr.simulate(robot, n_poses=90, seed=6, noise=iwr.Noise.realistic())
    ident, valid = data.subset(np.arange(70)), data.subset(np.arange(70, 90))
    result = iwr.identify(robot, ident, method="lm")
    acc = iwr.accuracy(robot, valid, result.x)
    floor = iwr.accuracy(robot, valid, truth).calibrated.summary()["position_mm"]["rms"]
    before = acc.nominal.summary()["position_mm"]["rms"]
    after = acc.calibrated.summary()["position_mm"]["rms"]
    assert after < before / 50
    assert after < 2 * floor  # close to what the noise allows
    assert acc.calibrated.summary()["orientation_deg"]["rms"] < (
        acc.nominal.summary()["orientation_deg"]["rms"] / 20)


def test_accuracy_ignores_unidentifiable_directions(robot):
    # Directions in the null space of the identification Jacobian change no leg reading, hence
    # (to first order) no pose found by forward kinematics; a generic direction does.
    m, x = iwr.simulate(robot, n_poses=40, seed=7)
    jac = iwr.Problem(robot, m).jacobian(x)
    norms = np.linalg.norm(jac, axis=0)
    _, s, vt = np.linalg.svd(jac / norms)
    assert s[-1] < 1e-12 * s[0]
    base = iwr.accuracy(robot, m, x).calibrated.position
    null = vt[-1] / norms
    generic = np.random.default_rng(8).normal(size=robot.n_params) / norms
    for direction, small in ((null, True), (generic, False)):
        step = 0.05 * direction / np.abs(direction).max()
        moved = iwr.accuracy(robot, m, x + step).calibrated.position
        change = np.abs(moved - base).max()
        assert (change < 1e-4) if small else (change > 1e-3)


def test_accuracy_names_the_line_of_a_pose_that_does_not_converge(robot, tmp_path):
    m, x = iwr.simulate(robot, n_poses=5, seed=9)
    path = tmp_path / "d.csv"
    m.to_csv(path)
    back = iwr.Measurements.from_csv(path)
    back.legs[3, 2] = -595.0  # 5 mm: legal for from_csv without a robot, unreachable for FK
    with pytest.raises(iwr.ForwardKinematicsError, match=r"nominal robot at .*d\.csv, line 1[0-9]"):
        iwr.accuracy(robot, back, x)
