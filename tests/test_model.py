"""The kinematic model and the objective of eq. (10), checked against independent computations."""

from __future__ import annotations

import math

import numpy as np
import pytest

import iwr
from iwr import _core

# -- independent plain-NumPy model, written from the paper's equations ----------------------------


def np_dh(alpha: float, a: float, d: float, theta: float) -> np.ndarray:
    """Eq. (1)."""
    ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
    return np.array(
        [[ct, -ca * st, sa * st, a * ct], [st, ca * ct, -sa * ct, a * st], [0, sa, ca, d],
         [0, 0, 0, 1]]
    )


def np_euler(a: float, b: float, g: float) -> np.ndarray:
    """Rz(a) Ry(b) Rx(g) as three elementary rotations (not eq. 6 written out)."""
    rz = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    rx = np.array([[1, 0, 0], [0, math.cos(g), -math.sin(g)], [0, math.sin(g), math.cos(g)]])
    return rz @ ry @ rx


def np_predict(robot: iwr.Robot, x: np.ndarray, q: np.ndarray, poses: np.ndarray) -> np.ndarray:
    n = robot.n_joints
    dh = robot.dh + x[: 4 * n].reshape(n, 4)
    a = robot.base_joints + x[4 * n : 4 * n + 18].reshape(6, 3)
    b = robot.platform_joints + x[4 * n + 18 : 4 * n + 36].reshape(6, 3)
    l0 = robot.leg_offsets + x[4 * n + 36 :]
    out = np.empty((len(poses), 6))
    for k in range(len(poses)):
        t = np.eye(4)
        for i in range(n):
            alpha, aa, d, theta = dh[i]
            if robot.joint_types[i] == "P":
                d += q[k, i]
            else:
                theta += q[k, i]
            t = t @ np_dh(alpha, aa, d, theta)
        r5 = np_euler(*poses[k, 3:])
        for j in range(6):
            leg = poses[k, :3] + r5 @ b[j] - t[:3, 3] - t[:3, :3] @ a[j]
            out[k, j] = np.linalg.norm(leg) - l0[j]
    return out


@pytest.fixture(scope="module")
def robot() -> iwr.Robot:
    return iwr.Robot.default()


@pytest.fixture(scope="module")
def data(robot):
    return iwr.simulate(robot, n_poses=40, seed=7)


# -- carriage ------------------------------------------------------------------------------------


def test_eq2_is_the_dh_product_symbolically():
    import sympy as sp
    d1, d2, d3, a3, a4, t3, t4 = sp.symbols("d1 d2 d3 a3 a4 theta3 theta4")

    def A(al, a, d, th):
        return sp.Matrix(
            [
                [sp.cos(th), -sp.cos(al) * sp.sin(th), sp.sin(al) * sp.sin(th), a * sp.cos(th)],
                [sp.sin(th), sp.cos(al) * sp.cos(th), -sp.sin(al) * sp.cos(th), a * sp.sin(th)],
                [0, sp.sin(al), sp.cos(al), d],
                [0, 0, 0, 1],
            ]
        )

    h = sp.pi / 2
    product = A(h, 0, d1, 0) * A(h, 0, d2, h) * A(h, a3, d3, t3) * A(-h, a4, 0, t4)
    s3, c3, s4, c4 = sp.sin(t3), sp.cos(t3), sp.sin(t4), sp.cos(t4)
    # Eq. (2) with a1 = 0 (Table 1).
    eq2 = sp.Matrix(
        [
            [s4, 0, c4, d3 + a4 * s4],
            [-s3 * c4, -c3, s3 * s4, -d2 - a3 * s3 - a4 * s3 * c4],
            [c3 * c4, -s3, -c3 * s4, d1 + a3 * c3 + a4 * c3 * c4],
            [0, 0, 0, 1],
        ]
    )
    assert sp.simplify(product - eq2) == sp.zeros(4, 4)


def test_carriage_matches_eq2_numerically(robot):
    rng = np.random.default_rng(1)
    d3, a3, a4 = robot.dh[2, 2], robot.dh[2, 1], robot.dh[3, 1]
    for _ in range(200):
        q = robot.joint_limits[:, 0] + np.ptp(robot.joint_limits, axis=1) * rng.random(4)
        d1, d2 = robot.dh[0, 2] + q[0], robot.dh[1, 2] + q[1]
        s3, c3, s4, c4 = math.sin(q[2]), math.cos(q[2]), math.sin(q[3]), math.cos(q[3])
        eq2 = np.array(
            [
                [s4, 0, c4, d3 + a4 * s4],
                [-s3 * c4, -c3, s3 * s4, -d2 - a3 * s3 - a4 * s3 * c4],
                [c3 * c4, -s3, -c3 * s4, d1 + a3 * c3 + a4 * c3 * c4],
                [0, 0, 0, 1],
            ]
        )
        np.testing.assert_allclose(robot.carriage_transform(q), eq2, atol=1e-9)


def test_dh_transform_is_eq1():
    rng = np.random.default_rng(2)
    for _ in range(20):
        args = rng.normal(size=4) * [1, 100, 100, 1]
        np.testing.assert_allclose(_core.dh_transform(*args), np_dh(*args), atol=1e-12)
        # eq. (1) is Rot_z(theta) Trans_z(d) Trans_x(a) Rot_x(alpha)
        alpha, a, d, theta = args
        rz = np.eye(4)
        rz[:3, :3] = np_euler(theta, 0, 0)
        tz, tx = np.eye(4), np.eye(4)
        tz[2, 3], tx[0, 3] = d, a
        rx = np.eye(4)
        rx[:3, :3] = np_euler(0, 0, alpha)
        np.testing.assert_allclose(_core.dh_transform(*args), rz @ tz @ tx @ rx, atol=1e-12)


def test_euler_matrix_is_eq6():
    rng = np.random.default_rng(3)
    for a, b, g in rng.uniform(-3, 3, size=(20, 3)):
        np.testing.assert_allclose(_core.euler_zyx(a, b, g), np_euler(a, b, g), atol=1e-14)
        np.testing.assert_allclose(iwr.transforms.euler_zyx(a, b, g), np_euler(a, b, g), atol=1e-14)
        r = np_euler(a, b, g)
        np.testing.assert_allclose(
            iwr.transforms.euler_zyx(*iwr.transforms.euler_from_matrix(r)), r, atol=1e-12
        )


def test_euler_angles_agree_with_scipy_and_survive_the_gimbal_lock():
    """One pose conversion for the package: iwr.transforms.euler_from_matrix is SciPy's intrinsic
    Z-Y-X decomposition away from the lock, and at beta = +-pi/2 (where SciPy warns and only
    gamma -+ alpha is defined) it still gives angles whose matrix is the input."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(11)
    rots = Rotation.random(200, random_state=rng)
    np.testing.assert_allclose(iwr.transforms.euler_from_matrix(rots.as_matrix()),
                               rots.as_euler("ZYX"), atol=1e-12)
    for beta in (np.pi / 2, -np.pi / 2, np.pi / 2 - 1e-9, -np.pi / 2 + 3e-10):
        for a, g in rng.uniform(-3, 3, size=(20, 2)):
            r = np_euler(a, beta, g)
            angles = iwr.transforms.euler_from_matrix(r)
            assert abs(angles[1] - beta) < 1e-7
            np.testing.assert_allclose(iwr.transforms.euler_zyx(*angles), r, atol=1e-14)
            if abs(beta) != np.pi / 2:
                continue
            # At the lock itself (cos beta exactly 0) alpha is 0 and gamma carries the turn.
            locked = r.copy()
            locked[:2, 0] = 0.0
            locked[2, 0] = -np.sign(beta)
            angles = iwr.transforms.euler_from_matrix(locked)
            assert angles[0] == 0.0 and abs(angles[1] - np.sign(beta) * np.pi / 2) < 1e-15
            np.testing.assert_allclose(iwr.transforms.euler_zyx(*angles), locked, atol=1e-14)
            t = np.eye(4)
            t[:3, :3], t[:3, 3] = r, (1.0, -2.0, 3.0)
            np.testing.assert_allclose(
                iwr.transforms.pose_matrix(iwr.transforms.pose_from_matrix(t)), t, atol=1e-12)


def test_rotation_angle_and_pose_errors_at_and_near_the_gimbal_lock():
    """The one rotation angle of the package (iwr.transforms.rotation_angle: pose errors, the
    tracker's, the frame check, the report) against SciPy's rotation vector; and pose errors at
    beta = +-90 degrees, where Z-Y-X angles (alpha, gamma) and (alpha + d, gamma +- d) are one
    orientation, and next to it, against the angle of the relative rotation built by SciPy."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(12)
    rots = Rotation.random(300, random_state=rng)
    axes = rng.normal(size=(50, 3))
    axes /= np.linalg.norm(axes, axis=1)[:, None]
    near_pi = Rotation.from_rotvec(axes * (np.pi - 1e-9))
    tiny = Rotation.from_rotvec(axes * 1e-9)  # where arccos((trace - 1) / 2) gives 0 or 2e-8
    for r in (rots, near_pi, tiny, Rotation.identity(3)):
        np.testing.assert_allclose(iwr.transforms.rotation_angle(r.as_matrix()), r.magnitude(),
                                   rtol=1e-12, atol=1e-15)
    for beta in (np.pi / 2, -np.pi / 2):
        for a, g, d in rng.uniform(-3, 3, size=(20, 3)):
            # Rz(a) Ry(+-pi/2) Rx(g) depends on g - a (beta = +pi/2) or g + a (beta = -pi/2) only.
            same = (a + d, beta, g + d * np.sign(beta))
            np.testing.assert_allclose(np_euler(*same), np_euler(a, beta, g), atol=1e-12)
            p = np.array([[10.0, -20.0, 30.0, a, beta, g]])
            q = np.array([[10.0, -20.0, 30.0, *same]])
            pos, ori = iwr.pose_errors(p, q, tool=(5.0, 0.0, 100.0))
            assert pos[0] < 1e-9 and ori[0] < 1e-6, (pos, ori)
            for step in (1e-7, 1e-4, 0.01):  # next to the lock, on either side of it
                near = (a + d, beta - np.sign(beta) * step, g - d)
                expected = (Rotation.from_euler("ZYX", [a, beta, g]).inv()
                            * Rotation.from_euler("ZYX", near)).magnitude()
                _, ori = iwr.pose_errors(p, np.array([[10.0, -20.0, 30.0, *near]]))
                np.testing.assert_allclose(np.radians(ori[0]), expected, rtol=1e-9, atol=1e-12)
                # and the round trip through the one Euler decomposition
                r = np_euler(*near)
                back = iwr.transforms.euler_zyx(*iwr.transforms.euler_from_matrix(r))
                np.testing.assert_allclose(back, r, atol=1e-13)


# -- hexapod -------------------------------------------------------------------------------------


def test_symmetric_home_pose_has_equal_legs_of_known_length():
    hexa = iwr.Robot.hexapod()
    # Base joints on radius 400 at -10, 10, 110, ...; platform on 250 at -50, 50, 70, ...: every leg
    # spans 40 degrees, so all six have length sqrt(400^2 + 250^2 - 2 400 250 cos 40 + h^2).
    for h in (650.0, 750.0, 850.0):
        legs = iwr.predict_legs(hexa, np.zeros(42), np.zeros((1, 0)), [[0, 0, h, 0, 0, 0]])
        expected = math.sqrt(400**2 + 250**2 - 2 * 400 * 250 * math.cos(math.radians(40)) + h**2)
        np.testing.assert_allclose(legs, np.full((1, 6), expected - 600.0), atol=1e-10)
    # A yaw phi of the platform turns every S-joint by phi: legs 1, 3, 5 (S-joint 40 degrees behind)
    # then span 40 - phi degrees, legs 2, 4, 6 (40 degrees ahead) span 40 + phi.
    phi = math.radians(20)
    legs = iwr.predict_legs(hexa, np.zeros(42), np.zeros((1, 0)), [[0, 0, 700, phi, 0, 0]])
    spans = math.radians(40) + np.array([-phi, phi, -phi, phi, -phi, phi])
    expected = np.sqrt(400**2 + 250**2 - 2 * 400 * 250 * np.cos(spans) + 700**2) - 600.0
    np.testing.assert_allclose(legs, expected[None, :], atol=1e-10)


def test_predict_legs_matches_independent_numpy(robot):
    rng = np.random.default_rng(4)
    lo, hi = robot.default_bounds()
    for _ in range(5):
        x = rng.uniform(lo, hi)
        q = robot.joint_limits[:, 0] + np.ptp(robot.joint_limits, axis=1) * rng.random((9, 4))
        poses = np.column_stack(
            [rng.uniform(-2000, 2000, (9, 3)), rng.uniform(-math.pi, math.pi, (9, 3))]
        )
        np.testing.assert_allclose(
            iwr.predict_legs(robot, x, q, poses), np_predict(robot, x, q, poses), atol=1e-9
        )


def test_simulate_then_predict_agrees(robot, data):
    m, x = data
    assert len(m) == 40 and m.joint_types == "PPRR"
    np.testing.assert_allclose(iwr.predict_legs(robot, x, m.q, m.poses), m.legs, atol=1e-9)
    # every pose is reachable: joints within limits, legs within stroke
    assert np.all((m.q >= robot.joint_limits[:, 0]) & (m.q <= robot.joint_limits[:, 1]))
    assert np.all((m.legs >= robot.leg_stroke[:, 0]) & (m.legs <= robot.leg_stroke[:, 1]))
    lo, hi = robot.default_bounds()
    assert np.all((x >= lo) & (x <= hi))
    assert iwr.Problem(robot, m).cost(x) < 1e-15


def test_simulate_is_seeded(robot):
    a, xa = iwr.simulate(robot, 10, seed=3, noise=iwr.Noise.realistic())
    b, xb = iwr.simulate(robot, 10, seed=3, noise=iwr.Noise.realistic())
    c, _ = iwr.simulate(robot, 10, seed=4)
    np.testing.assert_array_equal(a.legs, b.legs)
    np.testing.assert_array_equal(xa, xb)
    assert not np.array_equal(a.poses, c.poses)


def test_noise_has_the_requested_spread(robot):
    x = np.zeros(robot.n_params)
    clean, _ = iwr.simulate(robot, 400, seed=5, x=x)
    noisy, _ = iwr.simulate(robot, 400, seed=5, x=x, noise=iwr.Noise(legs=0.01, position=0.05))
    assert np.std(noisy.legs - clean.legs) == pytest.approx(0.01, rel=0.1)
    assert np.std(noisy.poses[:, :3] - clean.poses[:, :3]) == pytest.approx(0.05, rel=0.1)
    np.testing.assert_array_equal(noisy.q, clean.q)


# -- objective -----------------------------------------------------------------------------------


def _fd_jacobian(problem, x, h=1e-6):
    cols = []
    for i in range(x.size):
        e = np.zeros_like(x)
        e[i] = h
        cols.append((problem.residuals(x + e) - problem.residuals(x - e)) / (2 * h))
    return np.column_stack(cols)


@pytest.mark.parametrize("which", ["iwr", "hexapod", "weighted"])
def test_jacobian_matches_central_differences(which, robot):
    r = iwr.Robot.hexapod() if which == "hexapod" else robot
    m, x = iwr.simulate(r, 12, seed=11)
    if which == "weighted":
        w = np.random.default_rng(0).uniform(0.2, 3.0, (12, 6))
        m = iwr.Measurements(m.q, m.poses, m.legs, joint_types=m.joint_types, weights=w)
    p = iwr.Problem(r, m)
    x0 = 0.4 * x + np.random.default_rng(1).uniform(p.lower, p.upper) * 0.5
    res, jac = p.residuals_and_jacobian(x0)
    np.testing.assert_allclose(res, p.residuals(x0), rtol=0, atol=0)
    fd = _fd_jacobian(p, x0)
    scale = np.abs(fd).max(axis=0) + 1.0
    assert np.max(np.abs(jac - fd) / scale) < 1e-6


def test_cost_is_sum_of_squared_residuals_and_weights(robot, data):
    m, x = data
    p = iwr.Problem(robot, m)
    rng = np.random.default_rng(8)
    for _ in range(5):
        z = rng.uniform(p.lower, p.upper)
        r = p.residuals(z)
        pred = iwr.predict_legs(robot, z, m.q, m.poses)
        np.testing.assert_allclose(r, (pred - m.legs).ravel(), atol=1e-9)
        assert p.cost(z) == pytest.approx(float(r @ r), rel=1e-12)
    w = rng.uniform(0.5, 2.0, (len(m), 6))
    pw = iwr.Problem(robot, iwr.Measurements(m.q, m.poses, m.legs, weights=w))
    z = rng.uniform(p.lower, p.upper)
    pred = iwr.predict_legs(robot, z, m.q, m.poses)
    # Weights are relative: the cost uses them divided by the largest.
    wn = w / w.max()
    assert pw.cost(z) == pytest.approx(float(np.sum(wn * (pred - m.legs) ** 2)), rel=1e-12)


def test_cost_batch_is_thread_independent(robot, data):
    m, _ = data
    p = iwr.Problem(robot, m)
    X = np.random.default_rng(9).uniform(p.lower, p.upper, (97, robot.n_params))
    one, two = p.cost_batch(X, workers=1), p.cost_batch(X, workers=2)
    np.testing.assert_array_equal(one, two)
    np.testing.assert_allclose(one, [p.cost(x) for x in X], rtol=1e-13)


def test_bounds(robot, data):
    m, _ = data
    p = iwr.Problem(robot, m)
    assert p.upper[3] == pytest.approx(math.radians(0.5)) and p.upper[1] == 0.5
    paper = iwr.Problem(robot, m, bounds="paper")
    np.testing.assert_array_equal(paper.upper, np.full(58, 0.5))
    with pytest.raises(ValueError, match="parameter 2"):
        lo, hi = robot.default_bounds()
        lo[2] = hi[2]
        iwr.Problem(robot, m, bounds=(lo, hi))
    with pytest.raises(ValueError, match="unknown preset"):
        iwr.Problem(robot, m, bounds="wide")


def test_lm_recovers_noise_free_problem(robot):
    m, x = iwr.simulate(robot, 60, seed=12)
    res = iwr.identify(robot, m, method="lm")
    assert res.success and res.fun < 1e-16
    val, _ = iwr.simulate(robot, 30, seed=99, x=x)
    pred = iwr.predict_legs(robot, res.x, val.q, val.poses)
    assert np.sqrt(np.mean((pred - val.legs) ** 2)) < 1e-7


# -- robot description ---------------------------------------------------------------------------


def test_parameter_names(robot):
    names = robot.parameter_names
    assert len(names) == 58 and len(set(names)) == 58
    assert names[:4] == ["joint1.dalpha", "joint1.da", "joint1.dd", "joint1.dtheta"]
    assert names[16] == "leg1.da_x" and names[34] == "leg1.db_x" and names[52] == "leg1.dl0"
    assert len(iwr.Robot.hexapod().parameter_names) == 42
    assert robot.dh.shape == (4, 4) and robot.joint_types == "PPRR"
    assert robot.base_joints.shape == (6, 3) and robot.leg_offsets.shape == (6,)


def test_with_errors_is_the_same_model(robot, data):
    m, x = data
    calibrated = robot.with_errors(x)
    np.testing.assert_allclose(
        iwr.predict_legs(calibrated, np.zeros(58), m.q, m.poses), m.legs, atol=1e-9
    )


def test_toml_round_trip(tmp_path, robot):
    path = tmp_path / "robot.toml"
    robot.to_toml(path)
    back = iwr.Robot.from_toml(path)
    assert back == robot
    np.testing.assert_array_equal(back.dh, robot.dh)
    np.testing.assert_array_equal(back.platform_joints, robot.platform_joints)
    hexa = iwr.Robot.hexapod()
    hexa.to_toml(tmp_path / "hexa.toml")
    assert iwr.Robot.from_toml(tmp_path / "hexa.toml").n_params == 42


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda t: t.replace('name = "IWR"', 'name = "IWR"\ncolour = "red"'),
         "colour: unknown key"),
        (lambda t: t.replace("leg_offsets = [", "leg_offset = ["), "leg_offset: unknown key"),
        (lambda t: t.replace('type = "prismatic"', 'type = "helical"', 1), r"joints\[0\].type"),
        (lambda t: t.replace('type = "prismatic"\n', "", 1), r"joints\[0\].type: missing key"),
        (lambda t: t.replace("alpha = 1.5707963267948966", 'alpha = "90deg"', 1),
         r"joints\[0\].alpha"),
        (lambda t: t.replace("[hexapod]", "[hexapod\n"), "not valid TOML"),
        (lambda t: t.replace("alpha = 1.5707963267948966", "alpha = " + "9" * 400, 1),
         r"joints\[0\].alpha: an integer of 1329 bits is not a finite double"),
        (lambda t: t.replace("alpha = 1.5707963267948966", "alpha = -inf", 1),
         r"joints\[0\].alpha: -inf is not a finite double"),
    ],
)
def test_bad_toml_names_the_key(tmp_path, robot, edit, message):
    path = tmp_path / "robot.toml"
    robot.to_toml(path)
    path.write_text(edit(path.read_text()))
    with pytest.raises(iwr.RobotFileError, match=message) as info:
        iwr.Robot.from_toml(path)
    assert str(path) in str(info.value)


def test_missing_toml():
    with pytest.raises(iwr.RobotFileError, match="no such file"):
        iwr.Robot.from_toml("/nonexistent/robot.toml")


def test_unreadable_toml_names_the_file(tmp_path, robot):
    with pytest.raises(iwr.RobotFileError, match="is a folder"):
        iwr.Robot.from_toml(tmp_path)
    path = tmp_path / "robot.toml"
    robot.to_toml(path)
    text = path.read_bytes().replace(b'name = "IWR"', b'name = "IWR\xe9"')  # Latin-1
    path.write_bytes(text)
    line = text[: text.index(b"\xe9")].count(b"\n") + 1
    with pytest.raises(iwr.RobotFileError,
                       match=rf"robot.toml, line {line}: not UTF-8 \(byte 0xe9\)"):
        iwr.Robot.from_toml(path)


# -- measurements --------------------------------------------------------------------------------


def test_csv_round_trip(tmp_path, data):
    m, _ = data
    path = tmp_path / "data.csv"
    m.to_csv(path)
    back = iwr.Measurements.from_csv(path)
    assert back.joint_types == "PPRR"
    np.testing.assert_array_equal(back.q, m.q)
    np.testing.assert_array_equal(back.poses, m.poses)
    np.testing.assert_array_equal(back.legs, m.legs)
    header = [line for line in path.read_text().splitlines() if not line.startswith("#")][0]
    assert header.startswith("q1_mm,q2_mm,q3_rad,q4_rad,x_mm")
    w = np.ones((len(m), 6))
    iwr.Measurements(m.q, m.poses, m.legs, joint_types="PPRR", weights=w).to_csv(path)
    np.testing.assert_array_equal(iwr.Measurements.from_csv(path).weights, w)


def test_bad_csv_names_line_and_column(tmp_path, data):
    m, _ = data
    path = tmp_path / "data.csv"
    m.to_csv(path)
    lines = path.read_text().splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith("q1"))
    bad = lines.copy()
    bad[first + 3] = bad[first + 3].replace(bad[first + 3].split(",")[5], "nan", 1)
    path.write_text("\n".join(bad))
    with pytest.raises(iwr.MeasurementFileError, match=rf"line {first + 4}, column y_mm"):
        iwr.Measurements.from_csv(path)
    bad = lines.copy()
    bad[first + 2] = bad[first + 2].rsplit(",", 1)[0]
    path.write_text("\n".join(bad))
    with pytest.raises(iwr.MeasurementFileError, match=rf"line {first + 3}: 15 fields"):
        iwr.Measurements.from_csv(path)
    bad = lines.copy()
    bad[first] = bad[first].replace("s6_mm", "s7_mm")
    path.write_text("\n".join(bad))
    with pytest.raises(iwr.MeasurementFileError, match="expected 's6_mm'"):
        iwr.Measurements.from_csv(path)
    path.write_text("")
    with pytest.raises(iwr.MeasurementFileError, match="empty file"):
        iwr.Measurements.from_csv(path)
    with pytest.raises(iwr.MeasurementFileError, match="no such file"):
        iwr.Measurements.from_csv(tmp_path / "missing.csv")


# -- bad input -----------------------------------------------------------------------------------


def test_bad_shapes_and_values(robot, data):
    m, x = data
    p = iwr.Problem(robot, m)
    with pytest.raises(ValueError, match=r"x: shape \(57,\)"):
        p.cost(np.zeros(57))
    with pytest.raises(ValueError, match="entry 3 is nan"):
        p.cost(np.where(np.arange(58) == 3, np.nan, 0.0))
    with pytest.raises(ValueError, match=r"X: shape"):
        p.cost_batch(np.zeros((3, 5)))
    with pytest.raises(ValueError, match="X: entry"):
        p.cost_batch(np.full((2, 58), np.inf))
    with pytest.raises(ValueError, match=r"poses: shape \(40, 5\)"):
        iwr.Measurements(m.q, m.poses[:, :5], m.legs)
    with pytest.raises(ValueError, match="legs: row 2, column 1 is nan"):
        legs = m.legs.copy()
        legs[2, 1] = np.nan
        iwr.Measurements(m.q, m.poses, legs)
    with pytest.raises(ValueError, match=r"q: shape \(40, 3\)"):
        iwr.predict_legs(robot, x, m.q[:, :3], m.poses)
    with pytest.raises(ValueError, match="joints"):
        iwr.Problem(iwr.Robot.hexapod(), m)
    with pytest.raises(ValueError, match="joint_types"):
        iwr.Robot("PX", np.zeros((2, 4)), [[0, 1], [0, 1]], robot.base_joints,
                  robot.platform_joints, robot.leg_offsets, [0, 1])
    with pytest.raises(ValueError, match=r"dh: shape"):
        iwr.Robot("PP", np.zeros((3, 4)), [[0, 1], [0, 1]], robot.base_joints,
                  robot.platform_joints, robot.leg_offsets, [0, 1])
    with pytest.raises(ValueError, match="weights: row 0, column 0 is negative"):
        iwr.Measurements(m.q, m.poses, m.legs, weights=-np.ones((40, 6)))
    with pytest.raises(ValueError, match="n_poses"):
        iwr.simulate(robot, 0, seed=0)


def test_unreachable_workspace_is_reported():
    r = iwr.Robot.default()
    tight = iwr.Robot(r.joint_types, r.dh, r.joint_limits, r.base_joints, r.platform_joints,
                      r.leg_offsets, [0.0, 1.0], r.home_pose, r.workspace)
    with pytest.raises(iwr.UnreachableError, match="reachable"):
        iwr.simulate(tight, 10, seed=0)


def test_cpp_validates_too(robot):
    with pytest.raises(ValueError, match="joint_types: letter 1"):
        _core.Geometry("PQ", np.zeros((2, 4)), np.zeros((6, 3)), np.zeros((6, 3)), np.zeros(6))
    with pytest.raises(ValueError, match="base_joints: entry 4"):
        base = np.zeros((6, 3))
        base[1, 1] = np.inf
        _core.Geometry("", np.zeros((0, 4)), base, np.zeros((6, 3)), np.zeros(6))
    with pytest.raises(ValueError, match="errors: 3 values"):
        _core.predict_legs(robot._geometry, np.zeros(3), np.zeros((1, 4)), np.zeros((1, 6)))
