"""Eq. (10) weighted by the instruments' noise (issue 14, item 3): each pose's six leg residuals
whitened by their propagated covariance, in the C++ objective (cost, residuals, Jacobian,
cost_batch), so that LM, DE, CRS2 and BOBYQA all minimise it; and identify's routing."""

from __future__ import annotations

import numpy as np
import pytest

import iwr
from iwr import _core
from iwr.methods import ReducedProblem
from iwr.methods.de import de_method
from iwr.methods.lm import levenberg_marquardt
from iwr.problem import Problem, gls_whitening

ROBOT = iwr.Robot.default()
NOISE = iwr.Noise.realistic()


@pytest.fixture(scope="module")
def data40():
    return iwr.simulate(ROBOT, 40, seed=5, noise=NOISE)


def random_whitening(n: int, rng: np.random.Generator) -> np.ndarray:
    w = np.tril(rng.normal(size=(n, 6, 6)))
    w[:, np.arange(6), np.arange(6)] = rng.uniform(0.5, 2.0, (n, 6))
    return w


def test_whitened_residuals_cost_and_batch_are_w_times_eq10(data40) -> None:
    m, truth = data40
    rng = np.random.default_rng(1)
    w = random_whitening(len(m), rng)
    plain, white = Problem(ROBOT, m), Problem(ROBOT, m, whitening=w)
    assert white.weighted and not plain.weighted and white._objective.whitened
    X = rng.uniform(plain.lower, plain.upper, (17, ROBOT.n_params))
    for x in X[:3]:
        ref = np.einsum("kij,kj->ki", w, plain.residuals(x).reshape(-1, 6)).ravel()
        res = white.residuals(x)
        np.testing.assert_allclose(res, ref, rtol=1e-12, atol=1e-12)
        assert white.cost(x) == pytest.approx(float(ref @ ref), rel=1e-12)
        res2, _ = white.residuals_and_jacobian(x)
        np.testing.assert_array_equal(res2, res)
    one, two = white.cost_batch(X, workers=1), white.cost_batch(X, workers=2)
    np.testing.assert_array_equal(one, two)
    np.testing.assert_array_equal(one, [white.cost(x) for x in X])


def test_the_fma_variants_give_the_same_whitened_bits(data40) -> None:
    # AVX2 and AVX-512 bit for bit; the baseline (no fused multiply-add) to rounding (measured: at
    # most 6.1e-15 relative in the costs, 1.9e-12 mm in the residuals here).
    m, _ = data40
    rng = np.random.default_rng(2)
    white = Problem(ROBOT, m, whitening=random_whitening(len(m), rng))
    X = rng.uniform(white.lower, white.upper, (9, ROBOT.n_params))
    before = _core._active_kernel()
    try:
        got = {}
        for v in _core._supported_kernels():
            _core._select_kernel(v)
            got[v] = (white.cost_batch(X, workers=1), white.residuals(X[0]))
    finally:
        _core._select_kernel(before)
    fused = [v for v in got if v != "baseline"]
    for v in fused:
        c, r = got[v]
        np.testing.assert_array_equal(c, got[fused[0]][0], err_msg=v)
        np.testing.assert_array_equal(r, got[fused[0]][1], err_msg=v)
        np.testing.assert_allclose(c, got["baseline"][0], rtol=1e-13, atol=0, err_msg=v)
        np.testing.assert_allclose(r, got["baseline"][1], rtol=0, atol=1e-10, err_msg=v)


def test_weighted_jacobian_matches_central_differences(data40) -> None:
    m, truth = data40
    p = Problem(ROBOT, m, noise=NOISE)
    x = 0.7 * truth
    r, jac = p.residuals_and_jacobian(x)
    h = 1e-6
    num = np.empty_like(jac)
    for i in range(ROBOT.n_params):
        e = np.zeros(ROBOT.n_params)
        e[i] = h
        num[:, i] = (p.residuals(x + e) - p.residuals(x - e)) / (2 * h)
    assert np.abs(jac - num).max() <= 1e-6 * np.abs(jac).max()


def test_gls_whitening_whitens_the_propagated_covariance(data40) -> None:
    """W S W^T = I with S the covariance of the six leg residuals, propagated independently here
    by finite differences of the predicted legs in the pose and joint readings."""
    m, _ = data40
    w = gls_whitening(ROBOT, m, NOISE)
    assert np.all(np.triu(w, 1) == 0)
    k = 3
    from iwr.problem import predict_legs

    def legs(q, pose):
        return predict_legs(ROBOT, None, q[None], pose[None])[0]

    q, pose = m.q[k].copy(), m.poses[k].copy()
    # d legs / d(q, p, rotation vector in the platform frame): central differences.
    cols, sig = [], []
    nj = ROBOT.n_joints
    for i in range(nj):
        e = np.zeros(nj)
        e[i] = 1e-6
        cols.append((legs(q + e, pose) - legs(q - e, pose)) / 2e-6)
        sig.append(NOISE.joint_lengths if ROBOT.joint_types[i] == "P" else NOISE.joint_angles)
    for c in range(3):
        e = np.zeros(6)
        e[c] = 1e-6
        cols.append((legs(q, pose + e) - legs(q, pose - e)) / 2e-6)
        sig.append(NOISE.position)
    from scipy.spatial.transform import Rotation

    r0 = Rotation.from_euler("ZYX", pose[3:])
    for c in range(3):
        d = np.zeros(3)
        d[c] = 1e-6
        plus, minus = pose.copy(), pose.copy()
        plus[3:] = (r0 * Rotation.from_rotvec(d)).as_euler("ZYX")
        minus[3:] = (r0 * Rotation.from_rotvec(-d)).as_euler("ZYX")
        cols.append((legs(q, plus) - legs(q, minus)) / 2e-6)
        sig.append(NOISE.orientation)
    j = np.array(cols).T
    s = j @ np.diag(np.square(sig)) @ j.T + NOISE.legs**2 * np.eye(6)
    np.testing.assert_allclose(w[k] @ s @ w[k].T, np.eye(6), atol=1e-5)


def test_leg_noise_only_scales_eq10(data40) -> None:
    """With the noise all on the legs the whitening is I / sigma: the weighted cost is eq. (10)'s
    over sigma^2, and LM reaches the same x."""
    m, _ = data40
    legs_only = iwr.Noise(legs=0.004)
    w = gls_whitening(ROBOT, m, legs_only)
    np.testing.assert_allclose(w, np.broadcast_to(np.eye(6) / 0.004, w.shape), rtol=1e-14)
    plain = iwr.identify(ROBOT, m, "lm", active="base", progress=False)
    white = iwr.identify(ROBOT, m, "lm", noise=legs_only, active="base", progress=False)
    assert white.fun == pytest.approx(plain.fun / 0.004**2, rel=1e-9)
    assert white.cost_eq10 == pytest.approx(plain.fun, rel=1e-9)
    # The same minimum; LM's path differs in rounding (its steps see a cost 6e4 times larger),
    # which moves x by ~1e-7 mm along the worst-conditioned identifiable directions.
    np.testing.assert_allclose(white.x, plain.x, rtol=0, atol=1e-6)


def test_identify_routes_a_named_method_with_noise_to_the_weighted_objective(data40) -> None:
    m, _ = data40
    res = iwr.identify(ROBOT, m, "lm", noise=NOISE, active="base", progress=False)
    weighted = Problem(ROBOT, m, noise=NOISE)
    assert res.fun == pytest.approx(weighted.cost(res.x), rel=1e-14)
    assert res.cost_eq10 == pytest.approx(Problem(ROBOT, m).cost(res.x), rel=1e-14)
    objective = res.to_dict()["settings"]["objective"]
    assert objective["weighted"] and objective["noise"]["legs"] == NOISE.legs
    # The fit test applies, with dof = readings - identifiable parameters, and the weighted
    # minimum is what it tests (its linearised minimum: the same statistic).
    assert res.success and res.fit.fit_ok
    assert res.fit.dof == 6 * len(m) - int(res.active.sum())
    # (The test propagates the covariance at x, the objective at the nominal robot: 1 % apart.)
    assert res.fit.statistic == pytest.approx(res.fun, rel=0.02)
    # weighted=False: eq. (10), the noise model only for the test
    plain = iwr.identify(ROBOT, m, "lm", noise=NOISE, weighted=False, active="base",
                         progress=False)
    assert plain.fun == pytest.approx(Problem(ROBOT, m).cost(plain.x), rel=1e-14)
    assert "cost_eq10" not in plain and plain.fit.dof == res.fit.dof
    with pytest.raises(ValueError, match="weighted=True needs a noise model"):
        iwr.identify(ROBOT, m, "lm", weighted=True)
    with pytest.raises(ValueError, match="efficient estimator always"):
        iwr.identify(ROBOT, m, "efficient", noise=NOISE, weighted=False)


@pytest.mark.parametrize("method", ["crs2", "bobyqa"])
def test_nlopt_methods_minimise_the_weighted_cost(data40, method) -> None:
    m, _ = data40
    res = iwr.identify(ROBOT, m, method, noise=NOISE, max_evaluations=300, seed=3,
                       progress=False)
    assert res.fun == pytest.approx(Problem(ROBOT, m, noise=NOISE).cost(res.x), rel=1e-14)
    assert res.fun < Problem(ROBOT, m, noise=NOISE).cost(np.zeros(ROBOT.n_params))


def test_de_reaches_weighted_lms_minimum_on_a_small_problem(data40) -> None:
    """Six leg offsets free, the rest at the truth: DE on the whitened cost alone (no polish)
    finds the minimum that weighted LM finds, bit-identically with one or two threads."""
    m, truth = data40
    p = Problem(ROBOT, m, noise=NOISE)
    active = np.zeros(ROBOT.n_params, bool)
    active[ROBOT.n_params - 6:] = True
    x0 = truth.copy()
    x0[active] = 0.0
    lm = levenberg_marquardt(ReducedProblem(p, active, x0), progress=False)
    runs = [de_method(ReducedProblem(p, active, x0), seed=7, max_evaluations=20000,
                      polish=False, progress=False, workers=k) for k in (1, 2)]
    np.testing.assert_array_equal(runs[0].x, runs[1].x)
    de = runs[0]
    assert de.fun == pytest.approx(lm.fun, rel=1e-12)
    np.testing.assert_allclose(de.x[active], lm.x[active], atol=1e-7)


def test_bad_whitening_is_refused(data40, tmp_path) -> None:
    m, _ = data40
    n = len(m)
    upper = np.tile(np.eye(6), (n, 1, 1))
    upper[4, 1, 3] = 0.5
    with pytest.raises(ValueError, match="pose 4, entry \\(1, 3\\).*lower triangular"):
        Problem(ROBOT, m, whitening=upper)
    with pytest.raises(ValueError, match="whitening: shape"):
        Problem(ROBOT, m, whitening=np.ones((n - 1, 6, 6)))
    with pytest.raises(ValueError, match="noise, whitening"):
        Problem(ROBOT, m, noise=NOISE, whitening=np.tile(np.eye(6), (n, 1, 1)))
    nan = np.tile(np.eye(6), (n, 1, 1))
    nan[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="whitening"):
        Problem(ROBOT, m, whitening=nan)
    with pytest.raises(ValueError, match="noise: pose 0: .*singular"):
        gls_whitening(ROBOT, m, iwr.Noise(legs=0.0, position=0.0, orientation=0.0,
                                          joint_lengths=0.0, joint_angles=0.0))
    # The problem file carries the weighting (issue 21): saved, it loads back weighted.
    weighted = Problem(ROBOT, m, noise=NOISE)
    weighted.save(tmp_path / "p.iwrp")
    back = Problem.load(tmp_path / "p.iwrp")
    assert back.weighted
    np.testing.assert_array_equal(back.whitening, weighted.whitening)


def test_zero_leg_weights_leave_the_leg_out(data40) -> None:
    """A leg weighted 0 (eq. (10)'s way to leave it out) gets a zero column in the whitening:
    its reading no longer enters the weighted cost."""
    m, _ = data40
    w = np.ones((len(m), 6))
    w[2, 4] = 0.0
    mw = iwr.Measurements(m.q, m.poses, m.legs, weights=w, joint_types=m.joint_types)
    wh = gls_whitening(ROBOT, mw, NOISE)
    assert np.all(wh[2][:, 4] == 0) and np.all(np.isfinite(wh))
    legs = m.legs.copy()
    legs[2, 4] += 5.0
    moved = iwr.Measurements(m.q, m.poses, legs, weights=w, joint_types=m.joint_types)
    x = np.zeros(ROBOT.n_params)
    assert Problem(ROBOT, moved, noise=NOISE).cost(x) == pytest.approx(
        Problem(ROBOT, mw, noise=NOISE).cost(x), rel=1e-12)


def test_weighted_uncertainty(data40) -> None:
    """The covariance of the weighted fit: with the noise on the legs only it is eq. (10)'s
    with the given leg sigma; with every instrument noisy it is no larger than eq. (10)'s
    propagated (sandwich) covariance, parameter by parameter (Gauss-Markov: generalised least
    squares is the best linear unbiased estimator; 1 % slack for the whitening being computed at
    the nominal robot, the sandwich at x)."""
    m, truth = data40
    active = iwr.identifiability(ROBOT, m).active
    legs_only = iwr.Noise(legs=NOISE.legs)
    a = iwr.uncertainty(ROBOT, m, truth, legs_only, active=active, weighted=True)
    b = iwr.uncertainty(ROBOT, m, truth, NOISE.legs, active=active)
    assert a.source == "weighted" and "weighted" in a.describe()
    np.testing.assert_allclose(a.covariance, b.covariance, rtol=1e-6, atol=1e-18)
    gls = iwr.uncertainty(ROBOT, m, truth, NOISE, active=active, weighted=True)
    ols = iwr.uncertainty(ROBOT, m, truth, NOISE, active=active)
    assert np.all(gls.std[active] <= 1.01 * ols.std[active])
    assert np.median(ols.std[active] / gls.std[active]) > 1.05  # a real gain, not equality
    with pytest.raises(ValueError, match="weighted=True needs noise"):
        iwr.uncertainty(ROBOT, m, truth, 0.002, active=active, weighted=True)
