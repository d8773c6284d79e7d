"""Identifiability, parameter error and uncertainty of pose data, checked against independent
computations: central finite differences of ``iwr.predict_legs``, exact rigid motions written out
here, Monte-Carlo noise draws."""

from __future__ import annotations

import numpy as np
import pytest

import iwr
from iwr import transforms
from iwr.analysis.uncertainty import measurement_jacobians
from iwr.planning import measure

N_POSES = 30


@pytest.fixture(scope="module")
def robot() -> iwr.Robot:
    return iwr.Robot.default()


@pytest.fixture(scope="module")
def data(robot: iwr.Robot) -> tuple[iwr.Measurements, np.ndarray]:
    return iwr.simulate(robot, N_POSES, seed=11)


@pytest.fixture(scope="module")
def report(robot: iwr.Robot, data: tuple) -> iwr.IdentifiabilityReport:
    return iwr.identifiability(robot, data[0])


def fd_jacobian(robot: iwr.Robot, x: np.ndarray, m: iwr.Measurements) -> np.ndarray:
    """Central differences of predict_legs, independent of the analytic Jacobian. Steps 1e-4 mm
    and 1e-7 rad: truncation ~h^2 f''' and round-off ~1e-13 mm / h both stay below 1e-8 relative."""
    h = np.where(robot.angle_parameters, 1e-7, 1e-4)
    cols = []
    for i in range(robot.n_params):
        e = np.zeros(robot.n_params)
        e[i] = h[i]
        up = iwr.predict_legs(robot, x + e, m.q, m.poses)
        dn = iwr.predict_legs(robot, x - e, m.q, m.poses)
        cols.append(((up - dn) / (2 * h[i])).ravel())
    return np.array(cols).T


def fd_rank(jac: np.ndarray) -> int:
    """Rank with a threshold suited to finite-difference error, after asserting a clear gap."""
    s = np.linalg.svd(jac / np.linalg.norm(jac, axis=0), compute_uv=False)
    rel = s / s[0]
    rank = int(np.sum(rel > 1e-6))
    # The gap must be unmistakable, or the rank would depend on the threshold.
    assert rel[rank - 1] > 1e-4
    assert rank == rel.size or rel[rank] < 1e-8
    return rank


# -- 1. identifiability ------------------------------------------------------------------------


def test_iwr_rank_matches_finite_differences(robot, data, report) -> None:
    m, truth = data
    assert fd_rank(fd_jacobian(robot, np.zeros(robot.n_params), m)) == report.rank
    # also away from the nominal robot
    assert fd_rank(fd_jacobian(robot, truth, m)) == iwr.identifiability(robot, m, truth).rank
    assert report.rank == 52
    assert len(report.base_parameters) == 52
    assert len(report.null_directions) == len(report.left_out) == 6
    assert report.active.sum() == 52 and report.active.dtype == bool


def test_hexapod_rank_is_full(robot) -> None:
    """The pose of {5} is measured in the base frame {4} itself, which the a_i are defined in, so no
    rigid motion of the base is free, and each leg's length |P + R b - a| - l0, seen over poses
    with independent positions and orientations, fixes its own a, b and l0: rank 42."""
    hexa = iwr.Robot.hexapod()
    m, _ = iwr.simulate(hexa, N_POSES, seed=5)
    rep = iwr.identifiability(hexa, m)
    assert rep.rank == 42 == fd_rank(fd_jacobian(hexa, np.zeros(42), m))
    assert rep.left_out == [] and rep.null_directions == []


def test_null_directions_are_null_for_finite_differences(robot, data, report) -> None:
    jac = fd_jacobian(robot, np.zeros(robot.n_params), data[0])
    d = np.linalg.norm(jac, axis=0)
    for nd in report.null_directions:
        v = nd.vector * d  # scaled, so the ratio below is unit-free
        assert np.linalg.norm((jac / d) @ v) < 1e-7 * np.linalg.norm(v) * np.linalg.norm(jac / d, 2)


def test_named_null_directions(report) -> None:
    """The six directions the geometry predicts (docs/identifiability.md)."""
    assert report.left_out == [
        "joint2.da", "joint3.dd", "joint4.dalpha", "joint4.da", "joint4.dd", "joint4.dtheta"
    ]
    by = {nd.parameter: nd for nd in report.null_directions}
    # d of joint 3 and a of joint 1 both translate the carriage along world x
    assert dict(by["joint3.dd"].terms()) == pytest.approx({"joint3.dd": 1.0, "joint1.da": -1.0})
    # a of joint 2 and d of joint 1 both translate it along world z
    assert dict(by["joint2.da"].terms()) == pytest.approx({"joint2.da": 1.0, "joint1.dd": -1.0})
    # a4: frame {4} shifts along its x axis; the six base joints shift back by the same amount
    t = dict(by["joint4.da"].terms())
    assert t == pytest.approx({"joint4.da": 1.0, **{f"leg{j}.da_x": -1.0 for j in range(1, 7)}})
    assert {nd.parameter for nd in report.null_directions if nd.exact} == {
        "joint2.da", "joint3.dd", "joint4.da", "joint4.dd"
    }
    text = str(report)
    assert "rank 52 of 58" in text and "joint4.dtheta" in text


def _max_change(robot, m, x, y) -> float:
    return float(np.max(np.abs(iwr.predict_legs(robot, y, m.q, m.poses)
                               - iwr.predict_legs(robot, x, m.q, m.poses))))


def test_null_directions_leave_readings_unchanged(robot, data, report) -> None:
    """Exact directions (translations absorbed by translations): unchanged to 1e-9 mm along the
    straight line, for small and large steps. First-order directions (a rotation of frame {4}
    absorbed by the base joints a_i, which a straight line moves along the tangent of a circle):
    the change is quadratic in the step (checked: ten times smaller step, a hundred times smaller
    change) and below 1e-9 mm once the rotation is below ~1e-6 rad (lever ~700 mm:
    700 * t^2 / 2)."""
    m, truth = data
    # A null direction belongs to the point where it was computed: the axes it combines (e.g.
    # joint 3's z axis and joint 1's x axis) tilt with the angle errors, so take each report at x.
    for x in (np.zeros(robot.n_params), truth):
        rep = report if not x.any() else iwr.identifiability(robot, m, x)
        assert [nd.parameter for nd in rep.null_directions] == report.left_out
        for nd in rep.null_directions:
            v = nd.vector
            if nd.exact:
                for t in (1e-3 / np.max(np.abs(v)), 1e-3, 0.5):
                    assert _max_change(robot, m, x, x + t * v) < 1e-9, nd.parameter
            else:
                t = 1e-3  # rad of the joint-4 angle
                big = _max_change(robot, m, x, x + t * v)
                small = _max_change(robot, m, x, x + t / 10 * v)
                assert 1e-7 < big < 1e-3
                assert small == pytest.approx(big / 100, rel=0.05)
                assert _max_change(robot, m, x, x + 1e-6 * v) < 1e-9


def _rigid_base_motion(robot, x, which: int, angle: float) -> np.ndarray:
    """Change joint-4 parameter ``which`` (0 alpha, 1 a, 2 d, 3 theta) by ``angle`` and move the
    base joints a_i by the exact inverse of the resulting constant displacement of frame {4}."""
    y = x.copy()
    y[12 + which] += angle
    q = np.array([100.0, 200.0, 0.3, -0.2])  # any q: the displacement does not depend on it
    t_old = robot.carriage_transform(q, x)
    t_new = robot.carriage_transform(q, y)
    disp = np.linalg.solve(t_new, t_old)  # T_new^-1 T_old: maps old {4} coordinates to new ones
    a = robot.base_joints + x[16:34].reshape(6, 3)
    a_new = a @ disp[:3, :3].T + disp[:3, 3]
    y[16:34] = (a_new - robot.base_joints).ravel()
    return y


def test_rotation_null_directions_are_exact_along_the_rigid_motion(robot, data, report) -> None:
    """The curved path behind the first-order directions: a finite rotation of frame {4} by a
    joint-4 angle, with the a_i moved rigidly, leaves the readings unchanged to 1e-9 mm, and its
    tangent is the reported direction."""
    m, truth = data
    by = {nd.parameter: nd for nd in report.null_directions}
    for which, name in ((0, "joint4.dalpha"), (3, "joint4.dtheta")):
        for angle in (1e-3, np.radians(0.5)):
            y = _rigid_base_motion(robot, truth, which, angle)
            assert _max_change(robot, m, truth, y) < 1e-9
        y = _rigid_base_motion(robot, np.zeros(robot.n_params), which, 1e-7)
        v = by[name].vector
        np.testing.assert_allclose(y / 1e-7, v, atol=1e-4 * np.abs(v).max())


# -- 2. parameter error and identification on the base parameters ---------------------------------


def test_parameter_error_ignores_exact_null_motions(robot, data, report) -> None:
    m, truth = data
    by = {nd.parameter: nd for nd in report.null_directions}
    # an equivalent of the truth: rotated and shifted frame {4}, carriage shifted along x and z
    y = truth
    for which, amount in ((3, np.radians(0.5)), (0, np.radians(-0.4)), (2, 0.4), (1, -0.3)):
        y = _rigid_base_motion(robot, y, which, amount)
    # the carriage translations: straight lines, exact at the point where they are computed
    by = {nd.parameter: nd for nd in iwr.identifiability(robot, m, y).null_directions}
    y = y + 0.5 * by["joint3.dd"].vector - 0.2 * by["joint2.da"].vector
    assert _max_change(robot, m, truth, y) < 1e-9
    pe = iwr.parameter_error(robot, m, y, truth)
    assert pe.converged
    assert pe.raw_rms_length > 0.05
    assert pe.max_abs_length < 1e-9 and pe.max_abs_angle < 1e-12
    # the first-order projection leaves a second-order residue (why "nonlinear" is the default)
    lin = iwr.parameter_error(robot, m, y, truth, method="linear")
    assert lin.max_abs_length > 1e-5
    # a small error e added on top of the equivalent y is seen as the projection of e at y (the
    # frame {4} of y is rotated, so the same vector e at the truth would be a different error)
    rng = np.random.default_rng(3)
    e = np.where(robot.angle_parameters, 1e-6, 1e-3) * rng.standard_normal(robot.n_params)
    pe = iwr.parameter_error(robot, m, y + e, truth)
    ref = iwr.parameter_error(robot, m, y + e, y, method="linear").projected
    np.testing.assert_allclose(pe.projected, ref, atol=1e-4 * np.abs(ref).max())
    assert np.abs(pe.projected).max() > 1e-4
    assert pe.reading_rms == pytest.approx(
        np.sqrt(np.mean((iwr.Problem(robot, m).jacobian(y) @ e) ** 2)), rel=1e-3)


def test_pivoted_base_selection(robot, data, report) -> None:
    """QR with column pivoting gives a base set of the same size whose columns are independent."""
    m, _ = data
    rep = iwr.identifiability(robot, m, selection="pivoted")
    assert rep.rank == report.rank
    jac = iwr.Problem(robot, m).jacobian(np.zeros(robot.n_params))[:, rep.active]
    assert np.linalg.matrix_rank(jac / np.linalg.norm(jac, axis=0)) == rep.rank
    # the left-out set is one parameter from each dependent group of the ordered choice
    assert {p for p in rep.left_out if p.startswith("joint4")} == {
        "joint4.dalpha", "joint4.da", "joint4.dd", "joint4.dtheta"
    }


def test_base_parameter_identification_is_unique(robot, data, report) -> None:
    """LM on the base parameters from two different starts gives the same x; on all 58 it does
    not (it stops wherever the null directions leave it), but the parameter error agrees."""
    m, truth = data
    rng = np.random.default_rng(0)
    lo, hi = robot.default_bounds()
    starts = [np.zeros(robot.n_params), lo + (hi - lo) * rng.random(robot.n_params)]
    starts[1][~report.active] = 0.0  # the held parameters are held at x0: same value for both
    base = [iwr.identify(robot, m, "lm", x0=x0, active=report.active).x for x0 in starts]
    np.testing.assert_allclose(base[0], base[1], atol=1e-8)
    by_name = iwr.identify(robot, m, "lm", active="base")
    np.testing.assert_array_equal(by_name.active, report.active)
    np.testing.assert_allclose(by_name.x, base[0], atol=1e-8)
    full = [iwr.identify(robot, m, "lm", x0=x0).x for x0 in starts]
    assert np.max(np.abs(full[0] - full[1])) > 1e-3
    for x in base + full:
        pe = iwr.parameter_error(robot, m, x, truth)
        assert pe.max_abs_length < 1e-7 and pe.max_abs_angle < 1e-9


# -- 3. uncertainty: predicted spread against Monte-Carlo noise draws ---------------------------


def _monte_carlo(robot, noise, n_draws=200, n_poses=20):
    """Spread of LM estimates of the base parameters over noise draws at fixed true poses."""
    m0, truth = iwr.simulate(robot, n_poses, seed=2)
    rep = iwr.identifiability(robot, m0, truth)
    x_star = iwr.identify(robot, m0, "lm", active=rep.active).x  # the base-parameter truth
    rng = np.random.default_rng(7)
    xs = []
    for _ in range(n_draws):
        m = measure(robot, truth, m0.q, m0.poses, noise, rng)
        xs.append(iwr.identify(robot, m, "lm", active=rep.active, x0=x_star).x)
    xs = np.array(xs)
    return m0, x_star, rep, xs, m


def test_predicted_std_matches_monte_carlo_leg_noise(robot) -> None:
    """Leg noise only (the model is then exactly right): the predicted standard deviations match
    the spread over 200 draws within 20 % for every base parameter (the sampling error of a
    standard deviation from 200 draws is 5 %)."""
    sigma = 0.005
    m0, x_star, rep, xs, m_last = _monte_carlo(robot, iwr.Noise(legs=sigma))
    pred = iwr.uncertainty(robot, m0, x_star, noise=sigma, active=rep.active)
    ratio = xs.std(axis=0, ddof=1)[rep.active] / pred.std[rep.active]
    assert ratio.min() > 0.8 and ratio.max() < 1.2, (ratio.min(), ratio.max())
    assert np.all(np.isnan(pred.std[~rep.active]))
    # the noise estimated from one draw's residuals is close to the truth (68 dof: +-9 %)
    x_last = xs[-1]
    est = iwr.uncertainty(robot, m_last, x_last, active=rep.active)
    assert est.source == "residuals" and est.sigma == pytest.approx(sigma, rel=0.3)


def test_measurement_jacobians_match_the_noise_model(robot) -> None:
    """d(readings)/d(rotation) against the rotation applied exactly as simulate() applies it."""
    m, _ = iwr.simulate(robot, 5, seed=4)
    x = np.zeros(robot.n_params)
    _, dp, dr = measurement_jacobians(robot, x, m.q, m.poses)
    w = np.array([2e-5, -1e-5, 3e-5])

    def rotated(v):
        t = transforms.pose_matrix(m.poses)
        t[:, :3, :3] = t[:, :3, :3] @ transforms.rotvec_matrix(v)
        return iwr.predict_legs(robot, x, m.q, transforms.pose_from_matrix(t))

    # a symmetric difference cancels the second-order term (~250 mm * |w|^2 ~ 2e-7 mm)
    np.testing.assert_allclose((rotated(w) - rotated(-w)) / 2, dr @ w, atol=1e-10)
    # position: the leg reading moves by the leg's unit vector (length 1)
    np.testing.assert_allclose(np.linalg.norm(dp, axis=2), 1.0, atol=1e-8)


def test_uncertainty_refuses_rank_deficient_active_set(robot, data) -> None:
    m, truth = data
    with pytest.raises(ValueError, match="rank deficient"):
        iwr.uncertainty(robot, m, truth, noise=0.01, active=np.ones(robot.n_params, dtype=bool))
