"""The efficient estimator (iwr.estimation): exact derivatives, exact recovery, the chi-square law
of its fit statistic, variance components, outliers, a model that does not fit, and its predicted
covariance against Monte-Carlo."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

import iwr
from iwr import estimation as est
from iwr.simulation import add_noise, sample_poses
from iwr.transforms import euler_zyx, pose_from_matrix, pose_matrix

ROBOT = iwr.Robot.default()
NOISE = iwr.Noise.realistic()


@pytest.fixture(scope="module")
def base_mask() -> np.ndarray:
    # The base parameters of the IWR are the same for every random data set (ordered selection):
    # computed once, so the Monte-Carlo loops do not repeat the analysis.
    m, _ = iwr.simulate(ROBOT, 30, seed=0, noise=NOISE)
    return iwr.identifiability(ROBOT, m).active


def _tool_errors(x: np.ndarray, truth: np.ndarray, seed: int, n: int = 50) -> tuple[float, float]:
    fresh, _ = iwr.simulate(ROBOT, n, seed=seed, x=truth)
    a = iwr.accuracy(ROBOT, fresh, x).calibrated
    return float(np.sqrt(np.mean(a.position**2))), float(np.sqrt(np.mean(a.orientation**2)))


@pytest.mark.parametrize("size", [0.3, 1e-6])
def test_loop_jacobians_match_central_differences(size: float) -> None:
    # 0.3 rad rotation corrections use the closed forms of exp and J_r, 1e-6 rad their series.
    rng = np.random.default_rng(5)
    m, truth = iwr.simulate(ROBOT, 6, seed=4)
    nj = ROBOT.n_joints
    corr = rng.uniform(-size, size, (6, nj + 6))
    legs, jx, jy = est.loop_jacobians(ROBOT, truth, m.q, m.poses, corr)
    h = 1e-5
    num_x = np.empty_like(jx)
    for i in range(ROBOT.n_params):
        e = np.zeros(ROBOT.n_params)
        e[i] = h
        num_x[:, :, i] = (est.loop_jacobians(ROBOT, truth + e, m.q, m.poses, corr)[0]
                          - est.loop_jacobians(ROBOT, truth - e, m.q, m.poses, corr)[0]) / (2 * h)
    num_y = np.empty_like(jy)
    for c in range(nj + 6):
        e = np.zeros_like(corr)
        e[:, c] = h
        num_y[:, :, c] = (est.loop_jacobians(ROBOT, truth, m.q, m.poses, corr + e)[0]
                          - est.loop_jacobians(ROBOT, truth, m.q, m.poses, corr - e)[0]) / (2 * h)
    assert np.max(np.abs(num_x - jx)) < 1e-6
    assert np.max(np.abs(num_y - jy)) < 1e-6
    # Zero corrections: the model's predicted legs; the rotation correction is applied as
    # iwr.simulate applies orientation noise, R exp([w]x).
    legs0 = est.loop_jacobians(ROBOT, truth, m.q, m.poses)[0]
    assert np.max(np.abs(legs0 - iwr.predict_legs(ROBOT, truth, m.q, m.poses))) < 1e-9
    w = corr[:, nj + 3:]
    from iwr.transforms import rotvec_matrix

    t = pose_matrix(m.poses)
    t[:, :3, :3] = t[:, :3, :3] @ rotvec_matrix(w)
    t[:, :3, 3] += corr[:, nj:nj + 3]
    expected = iwr.predict_legs(ROBOT, truth, m.q + corr[:, :nj], pose_from_matrix(t))
    assert np.max(np.abs(legs - expected)) < 1e-9


@pytest.mark.slow
def test_fit_statistic_follows_its_chi_square_law(base_mask: np.ndarray) -> None:
    values, dof = [], None
    for s in range(200):
        m, _ = iwr.simulate(ROBOT, 30, seed=s, noise=NOISE)
        res = est.efficient(ROBOT, m, NOISE, active=base_mask, outliers="off")
        values.append(res.fit.statistic)
        dof = res.fit.dof
    t = np.array(values)
    assert dof == 6 * 30 - int(base_mask.sum())
    # Mean within 3 standard errors of dof (the standard error of the mean is sqrt(2 dof / 200)).
    assert abs(t.mean() - dof) < 3 * math.sqrt(2 * dof / 200)
    assert stats.kstest(t, stats.chi2(dof).cdf).pvalue > 0.01


def test_variance_components_estimate_the_tracker_noise(base_mask: np.ndarray) -> None:
    # Legs and joints known, the tracker's noise unknown (started 2.5 times too large).
    start = iwr.Noise(legs=NOISE.legs, joint_lengths=NOISE.joint_lengths,
                      joint_angles=NOISE.joint_angles, position=0.05, orientation=5e-5)
    for seed in (0, 1, 2):
        m, _ = iwr.simulate(ROBOT, 100, seed=seed, noise=NOISE)
        res = est.efficient(ROBOT, m, start, active=base_mask,
                            estimate=("position", "orientation"))
        comps = {c.name: c for c in res.variance_components}
        assert set(comps) == {"position", "orientation"}
        for name in comps:
            assert comps[name].identified
            assert abs(comps[name].sigma / getattr(NOISE, name) - 1) < 0.15, (seed, comps[name])
        assert res.noise.position == comps["position"].sigma
        assert res.noise.legs == NOISE.legs


def test_variance_components_unidentifiable_without_redundancy() -> None:
    # A prismatic-only carriage has no revolute joint: "joint_angles" has no reading and is not
    # estimated; with every component free, each is reported with its redundancy.
    m, _ = iwr.simulate(ROBOT, 40, seed=3, noise=NOISE)
    res = est.efficient(ROBOT, m, "estimate")
    names = [c.name for c in res.variance_components]
    assert names == list(est.COMPONENTS)
    for c in res.variance_components:
        assert c.redundancy >= 0 and c.sigma > 0
        if not c.identified:
            assert c.sigma == c.start


def _with_gross_errors(m: iwr.Measurements, rows: np.ndarray, kind: str,
                       rng: np.random.Generator) -> iwr.Measurements:
    legs, poses = m.legs.copy(), m.poses.copy()
    for k in rows:
        sign = rng.choice([-1.0, 1.0])
        if kind == "leg":
            legs[k, rng.integers(6)] += sign * 1.0
        else:
            poses[k, rng.integers(3)] += sign * 1.0
    return iwr.Measurements(m.q, poses, legs, joint_types=m.joint_types)


@pytest.mark.slow
def test_outliers_found_and_removed(base_mask: np.ndarray) -> None:
    clean_flags, clean_total = 0, 0
    for seed in range(6):
        rng = np.random.default_rng(100 + seed)
        m, truth = iwr.simulate(ROBOT, 100, seed=seed, noise=NOISE)
        bad = rng.choice(100, 5, replace=False)
        kind = "leg" if seed % 2 == 0 else "position"
        mb = _with_gross_errors(m, bad, kind, rng)
        res = est.efficient(ROBOT, mb, NOISE, active=base_mask)
        flagged = {o.pose for o in res.outliers}
        assert set(bad.tolist()) <= flagged, (seed, sorted(bad), res.outliers)
        for o in res.outliers:
            assert o.removed and o.statistic > stats.chi2.isf(1e-3, o.dof)
            if o.pose in bad:
                # Baarda's w-test names the reading; q1 (the rail, along z0) and position.z
                # move the legs alike and are reported as confounded.
                named = (o.instrument,) + o.confounded
                assert any(n.startswith(kind) for n in named), o
        assert not res.used[bad].any() and res.used.sum() == 100 - len(flagged)
        assert res.success, res.message
        clean_flags += len(flagged - set(bad.tolist()))
        clean_total += 95
        clean = est.efficient(ROBOT, m, NOISE, active=base_mask)
        clean_flags += len(clean.outliers)
        clean_total += 100
        acc_bad = _tool_errors(res.x, truth, seed=500 + seed, n=100)
        acc_clean = _tool_errors(clean.x, truth, seed=500 + seed, n=100)
        assert acc_bad[0] < 1.2 * acc_clean[0], (seed, acc_bad, acc_clean)
    assert clean_flags / clean_total < 0.01


def test_outliers_report_only_keeps_every_pose(base_mask: np.ndarray) -> None:
    rng = np.random.default_rng(7)
    m, _ = iwr.simulate(ROBOT, 60, seed=7, noise=NOISE)
    mb = _with_gross_errors(m, np.array([3, 40]), "leg", rng)
    res = est.efficient(ROBOT, mb, NOISE, active=base_mask, outliers="report")
    assert {3, 40} <= {o.pose for o in res.outliers}
    assert all(not o.removed for o in res.outliers) and res.used.all()
    assert not res.success and not res.fit_ok  # two 1 mm errors in the fit: chi-square fails
    # Without removal the two gross errors distort the fit and clean poses fail too (swamping),
    # but the two stand out by far.
    worst = sorted(res.outliers, key=lambda o: -o.statistic)[:2]
    assert {o.pose for o in worst} == {3, 40}
    assert "pose 3" in str([o for o in res.outliers if o.pose == 3][0])


def test_unregistered_frame_is_reported(base_mask: np.ndarray) -> None:
    m, _ = iwr.simulate(ROBOT, 100, seed=3, noise=NOISE)
    t = np.eye(4)
    t[:3, :3] = euler_zyx(math.radians(30), 0.0, 0.0)
    t[:3, 3] = [2000.0, 0.0, 0.0]
    moved = iwr.Measurements(m.q, pose_from_matrix(t @ pose_matrix(m.poses)), m.legs,
                             joint_types=m.joint_types)
    res = est.efficient(ROBOT, moved, NOISE, active=base_mask)
    assert not res.success and not res.fit_ok
    assert res.status == "failed" and "does not fit" in res.message.lower()
    assert "DOES NOT FIT" in res.verdict
    assert res.fit.implausible or res.fit.p_value < 1e-3


def test_pure_translation_of_the_frame_is_named_implausible(base_mask: np.ndarray) -> None:
    # A 2 m shift along z0 is absorbed exactly by joint 1's d: it fits, but 2 m is no assembly
    # error.
    m, _ = iwr.simulate(ROBOT, 60, seed=4, noise=NOISE)
    moved = iwr.Measurements(m.q, m.poses + [0, 0, 2000.0, 0, 0, 0], m.legs,
                             joint_types=m.joint_types)
    res = est.efficient(ROBOT, moved, NOISE, active=base_mask)
    assert not res.success and not res.fit_ok
    assert res.fit.p_value > 1e-3  # the chi-square test alone would pass
    # Issue 26: the verdict said "does not fit (p = 0.14)"; it now names what failed.
    assert res.fit.verdict.startswith("THE MODEL DOES NOT FIT THE DATA: identified errors "
                                      "beyond their plausible size (the chi-square test alone "
                                      "passes: chi2 = ")
    # joint1.dd and joint2.da both move along z0 (a null direction): the smallest equivalent
    # vector shares the 2 m between them.
    named = {name: v for name, v, _ in res.fit.implausible}
    assert abs(named["joint1.dd"] + named["joint2.da"] - 2000) < 1



def _scaled_noise(factor: float) -> iwr.Noise:
    return iwr.Noise(**{k: factor * v for k, v in NOISE.__dict__.items()})


def test_a_poorly_determined_parameter_beyond_its_size_is_no_misfit(base_mask: np.ndarray
                                                                     ) -> None:
    """Noise ten times the realistic one on 60 poses: leg 1's offset, the truth 0.1 mm, is
    identified at 7.2 +- 3.3 mm, beyond its 5 mm plausible size but within what the noise
    explains. The fit passes with a note (it failed: "THE MODEL DOES NOT FIT"; 66 of 200 seeds
    did, none now: benchmarks/size_test_mc.py), and a 12 mm shift of the frame along z0,
    absorbed by joint 1's d and joint 2's a (6 mm each, well determined), still fails it."""
    from iwr.fit_test import _plausible_limit, beyond_plausible, leg_readings

    noise = _scaled_noise(10.0)
    m, truth = iwr.simulate(ROBOT, 60, seed=0, noise=noise)
    res = est.efficient(ROBOT, m, noise, active=base_mask)
    assert res.success and res.fit_ok and res.fit.implausible == [], res.fit.verdict
    note = [c for c in res.fit.causes if "within what the noise explains" in c]
    assert len(note) == 1 and "leg1.dl0 = 7.16" in note[0], res.fit.causes
    limit = _plausible_limit(ROBOT, 10.0, None)
    plain = beyond_plausible(leg_readings(ROBOT, m), res.x, limit, None, ROBOT.parameter_names)
    assert [b.name for b in plain] == ["leg1.dl0"] and abs(truth[ROBOT.parameter_names.index(
        "leg1.dl0")]) < 1  # beyond its size, the truth well within

    moved = iwr.Measurements(m.q, m.poses + [0, 0, 12.0, 0, 0, 0], m.legs,
                             joint_types=m.joint_types)
    res = est.efficient(ROBOT, moved, noise, active=base_mask)
    assert not res.fit_ok and res.fit.p_value > 1e-3  # the chi-square test alone passes
    assert {"joint1.dd", "joint2.da"} <= {name for name, _, _ in res.fit.implausible}


def test_a_weighted_result_read_back_weighs_the_size_by_its_spread(base_mask: np.ndarray
                                                                   ) -> None:
    """The same data as above, identified by weighted LM: the job passes its fit with a note on
    leg 1's offset. The same result read back as one identified elsewhere (``iwr-calibrate
    --noise``: its ``weighting`` setting, no fit test; ``iwr report`` and the launcher test it)
    was tested without the estimate's spread and failed as a misfit; the recorded noise model
    now gives it the spread, and it passes with the same note and the same statistic."""
    from iwr.calibration import from_result

    noise = _scaled_noise(10.0)
    m, _ = iwr.simulate(ROBOT, 60, seed=0, noise=noise)
    job = iwr.identify(ROBOT, m, "lm", noise=noise, weighted=True, active=base_mask)
    assert job.success and job.fit.fit_ok, job.fit.verdict
    note = [c for c in job.fit.causes if "within what the noise explains" in c]
    assert len(note) == 1 and "leg1.dl0 = 7.0" in note[0], job.fit.causes
    elsewhere = iwr.IdentificationResult(**dict(job))
    elsewhere.update(fit=None, settings={**job.settings, "weighting": "the noise model"})
    read = from_result(ROBOT, m, elsewhere).result
    assert read.success and read.fit.fit_ok, read.fit.verdict
    assert read.fit.statistic == pytest.approx(job.fun, rel=1e-12)
    assert [c for c in read.fit.causes if "within what the noise explains" in c] == note
    elsewhere.update(fun=1.3 * job.fun)  # the chi-square test still fails a cost too large
    assert not from_result(ROBOT, m, elsewhere).result.fit.fit_ok


def test_the_smallest_equivalent_s_spread_is_the_pseudo_inverse_of_the_information(
        base_mask: np.ndarray) -> None:
    """The standard deviations the size test weighs a departure by, from the covariance of the
    active parameters projected off the null directions, against an independent formula: the
    smallest equivalent vector (in units of the limits) is the minimum-norm solution, whose
    covariance is the pseudo-inverse of the information matrix of every parameter in those
    units."""
    from iwr import kinds
    from iwr.fit_test import _plain_sd, _plausible_limit, leg_readings

    m, truth = iwr.simulate(ROBOT, 40, seed=2, noise=NOISE)
    limit = _plausible_limit(ROBOT, 10.0, None)
    _, jw, _ = kinds.of(m).whitened(ROBOT, m, truth, NOISE)
    ja = jw[:, base_mask]
    cov = np.zeros((ROBOT.n_params, ROBOT.n_params))
    cov[np.ix_(base_mask, base_mask)] = np.linalg.inv(ja.T @ ja)
    got = _plain_sd(leg_readings(ROBOT, m), truth, limit, None, cov)
    js = jw * limit
    want = limit * np.sqrt(np.diag(np.linalg.pinv(js.T @ js, rcond=1e-10)))
    np.testing.assert_allclose(got, want, rtol=1e-5)
    assert np.all(got > 0)  # every entry moves: the null directions spread the held ones'


@pytest.mark.parametrize("what", ["legs", "poses"])
def test_swapped_columns_are_reported(base_mask: np.ndarray, what: str) -> None:
    # Legs 1 and 2 swapped: the model moves the joints of legs 1 and 2 onto each other's and fits
    # (chi2 passes), with errors of hundreds of mm; x and y of the poses swapped: no fit at all.
    m, _ = iwr.simulate(ROBOT, 60, seed=21, noise=NOISE)
    legs, poses = m.legs, m.poses
    if what == "legs":
        legs = legs[:, [1, 0, 2, 3, 4, 5]]
    else:
        poses = poses[:, [1, 0, 2, 3, 4, 5]]
    res = est.efficient(ROBOT, iwr.Measurements(m.q, poses, legs, joint_types=m.joint_types),
                        NOISE, active=base_mask)
    assert not res.success and not res.fit_ok
    assert res.fit.implausible or res.fit.p_value < 1e-3
    assert "DOES NOT FIT" in str(res.fit)


def test_forgotten_tool_offset_is_named_implausible(base_mask: np.ndarray) -> None:
    # The instrument measured a frame 80 mm above {5}: the six b_i absorb it exactly (each moves
    # by -80 mm along z of {5}), so the fit passes, but 80 mm is no assembly error.
    m, _ = iwr.simulate(ROBOT, 60, seed=22, noise=NOISE)
    t = pose_matrix(m.poses)
    t[:, :3, 3] += t[:, :3, 2] * 80.0
    moved = iwr.Measurements(m.q, pose_from_matrix(t), m.legs, joint_types=m.joint_types)
    res = est.efficient(ROBOT, moved, NOISE, active=base_mask)
    assert not res.success and not res.fit_ok
    named = {name: v for name, v, _ in res.fit.implausible}
    assert all(abs(named[f"leg{j}.db_z"] + 80) < 1 for j in range(1, 7)), named


def test_plausible_truth_with_null_directions_is_not_named(base_mask: np.ndarray) -> None:
    # joint 4's rotation about its axis is held fixed at 0 and absorbed by legs 1, 2 moving
    # 694 mm/rad: a true 0.5 degree makes the base parameters 6 mm, beyond 10 x 0.5 mm, but the
    # smallest equivalent vector is plausible.
    names = ROBOT.parameter_names
    truth = np.zeros(ROBOT.n_params)
    truth[names.index("joint4.dtheta")] = math.radians(0.5)
    m, _ = iwr.simulate(ROBOT, 60, seed=5, x=truth, noise=NOISE)
    res = est.efficient(ROBOT, m, NOISE, active=base_mask)
    assert np.max(np.abs(res.x[[names.index("leg1.da_z"), names.index("leg2.da_z")]])) > 5
    assert res.fit.implausible == [] and res.success


def test_predicted_covariance_matches_monte_carlo(base_mask: np.ndarray) -> None:
    # Same true robot and poses, 150 noise draws: the spread of the estimates against the
    # predicted covariance (first order, the Cramer-Rao bound of Gaussian noise).
    rng = np.random.default_rng(11)
    lo, hi = ROBOT.default_bounds()
    truth = lo + (hi - lo) * rng.random(ROBOT.n_params)
    q, poses, legs = sample_poses(ROBOT, 30, rng, truth)
    xs, res = [], None
    for _ in range(150):
        m = add_noise(ROBOT, q, poses, legs, NOISE, rng)
        res = est.efficient(ROBOT, m, NOISE, active=base_mask, outliers="off")
        xs.append(res.x[base_mask])
    xs = np.array(xs)
    emp = np.std(xs, axis=0, ddof=1)
    pred = np.sqrt(np.diag(res.covariance))
    ratio = emp / pred
    # 150 draws: the standard deviation of a standard deviation estimate is ~6 %.
    assert 0.9 < np.median(ratio) < 1.1, ratio
    assert ratio.min() > 0.7 and ratio.max() < 1.3, ratio
    # Tool error: predicted RMS against the spread of the calibrated model's tool pose.
    fresh, _ = iwr.simulate(ROBOT, 40, seed=12, x=truth)
    pa = est.predicted_accuracy(ROBOT, fresh, res.x, res.covariance, active=base_mask)
    assert pa.position_95 > pa.position_rms > 0 and pa.orientation_95 > pa.orientation_rms > 0
    errs = []
    for xa in xs[:60]:
        x = truth.copy()
        x[base_mask] = xa
        x[~base_mask] = 0.0
        errs.append(iwr.accuracy(ROBOT, fresh, x).calibrated.position)
    # Every estimate is compared with the truth through forward kinematics; the null directions
    # (held at 0 while the truth is not) leave the tool pose unchanged.
    actual = math.sqrt(float(np.mean(np.array(errs) ** 2)))
    assert 0.85 < actual / pa.position_rms < 1.15, (actual, pa.position_rms)


def test_result_carries_the_identification_result_fields() -> None:
    m, _ = iwr.simulate(ROBOT, 30, seed=8, noise=NOISE)
    res = est.efficient(ROBOT, m, NOISE)
    for key in ("x", "fun", "nfev", "nit", "success", "status", "message", "fit", "outliers",
                "covariance", "std", "predicted", "active", "noise"):
        assert key in res
    assert isinstance(res, iwr.IdentificationResult)
    assert res.fun == pytest.approx(res.fit.statistic)
    assert res.cost_eq10 == pytest.approx(iwr.Problem(ROBOT, m).cost(res.x))
    assert np.all(np.isnan(res.std[~res.active])) and np.all(res.std[res.active] > 0)
    d = res.to_dict()
    assert d["method"] == "efficient" and d["settings"]["noise"]["legs"] == NOISE.legs
    assert str(res.fit).startswith("the model fits")
    import json

    summ = est.summary(res)
    assert json.loads(json.dumps(summ)) == summ
    assert summ["fit"]["dof"] == res.fit.dof and summ["n_poses_used"] == 30
    assert summ["std"][5] is None and summ["predicted"]["position_rms_mm"] > 0
    assert str(res.predicted).startswith("predicted tool error")


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"noise": iwr.Noise()}, "every standard deviation is 0"),
        ({"noise": iwr.Noise(position=0.02)}, "noise.legs"),
        ({"noise": "guess"}, "'estimate'"),
        ({"noise": NOISE, "estimate": ("tracker",)}, "unknown component"),
        ({"noise": NOISE, "outliers": "drop"}, "outliers"),
        ({"noise": NOISE, "outlier_alpha": 0.0}, "outlier_alpha"),
        ({"noise": NOISE, "active": np.ones(3, dtype=bool)}, "active"),
        ({"noise": NOISE, "x0": np.full(58, np.nan)}, "x0"),
        ({"noise": NOISE, "max_iterations": 0}, "max_iterations"),
    ],
)
def test_bad_arguments_are_named(kwargs: dict, match: str) -> None:
    m, _ = iwr.simulate(ROBOT, 10, seed=1)
    with pytest.raises(ValueError, match=match):
        est.efficient(ROBOT, m, **kwargs)


def test_zero_weight_is_refused_with_its_place() -> None:
    m, _ = iwr.simulate(ROBOT, 10, seed=1)
    w = np.ones((10, 6))
    w[4, 2] = 0.0
    mw = iwr.Measurements(m.q, m.poses, m.legs, joint_types=m.joint_types, weights=w)
    with pytest.raises(ValueError, match="row 4, column 2"):
        est.efficient(ROBOT, mw, NOISE)


def test_all_parameters_active_is_reported_not_identifiable() -> None:
    m, _ = iwr.simulate(ROBOT, 30, seed=9, noise=NOISE)
    res = est.efficient(ROBOT, m, NOISE, active=np.ones(ROBOT.n_params, dtype=bool),
                        outliers="off")
    assert not res.success and not res.fit_ok
    assert any("not all identifiable" in c for c in res.fit.causes)


def test_exact_instruments_reduce_to_weighted_eq10(base_mask: np.ndarray) -> None:
    # With every non-leg reading exact there is no nuisance unknown: the estimate is eq. (10)'s.
    m, _ = iwr.simulate(ROBOT, 40, seed=10, noise=NOISE)
    res = est.efficient(ROBOT, m, iwr.Noise(legs=0.002), active=base_mask, outliers="off")
    lm = iwr.identify(ROBOT, m, "lm", active=base_mask)
    # Both converged to 1e-12 in the cost; the weakest directions (s ~ 3e-3) then agree to a
    # thousandth of their standard deviation.
    assert np.max(np.abs(res.x - lm.x)[base_mask] / res.std[base_mask]) < 1e-3
    assert res.fun == pytest.approx(iwr.Problem(ROBOT, m).cost(lm.x) / 0.002**2, rel=1e-9)
    assert np.all(res.corrections == 0)


def test_same_input_same_answer_bit_for_bit(base_mask: np.ndarray) -> None:
    m, _ = iwr.simulate(ROBOT, 40, seed=13, noise=NOISE)
    a = est.efficient(ROBOT, m, NOISE, active=base_mask)
    b = est.efficient(ROBOT, m, NOISE, active=base_mask)
    assert np.array_equal(a.x, b.x) and a.fun == b.fun
    assert np.array_equal(a.covariance, b.covariance)


def test_core_solver_checks_its_arguments() -> None:
    from iwr import _core

    m, _ = iwr.simulate(ROBOT, 5, seed=1)
    sigma = est.sigma_matrix(ROBOT, m, NOISE)
    x0 = np.zeros(ROBOT.n_params)
    bad = sigma.copy()
    bad[2, 0] = 0.0
    with pytest.raises(ValueError, match=r"sigma: entry \(2, 0\)"):
        _core.implicit_loop(ROBOT._geometry, x0, [0, 1], m.q, m.poses, m.legs, bad,
                            np.zeros((0, 0)))
    with pytest.raises(ValueError, match="sigma: shape"):
        _core.implicit_loop(ROBOT._geometry, x0, [0, 1], m.q, m.poses, m.legs, sigma[:, :6],
                            np.zeros((0, 0)))
    with pytest.raises(ValueError, match="active: index 58"):
        _core.implicit_loop(ROBOT._geometry, x0, [58], m.q, m.poses, m.legs, sigma,
                            np.zeros((0, 0)))
    legs = m.legs.copy()
    legs[1, 1] = np.nan
    with pytest.raises(ValueError, match="legs"):
        _core.implicit_loop(ROBOT._geometry, x0, [0], m.q, m.poses, legs, sigma, np.zeros((0, 0)))


def test_ctrl_c_returns_the_last_completed_solve_marked_interrupted(base_mask: np.ndarray) -> None:
    # KeyboardInterrupt from inside a later solve (here raised by the callback during the
    # variance-component iterations): the result of the last completed solve, status
    # "interrupted", never success. Before the first solve has finished there is nothing to return.
    m, _ = iwr.simulate(ROBOT, 40, seed=14, noise=NOISE)
    calls = []

    def late(r):
        calls.append(r.nit)
        if len(calls) > 12:
            raise KeyboardInterrupt

    res = est.efficient(ROBOT, m, NOISE, active=base_mask, callback=late,
                        estimate=("position", "orientation"))
    assert res.status == "interrupted" and not res.success and "Ctrl-C" in res.message
    assert np.all(np.isfinite(res.x)) and res.fit.dof == 6 * 40 - int(base_mask.sum())
    assert all(not c.identified for c in res.variance_components)

    def early(r):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        est.efficient(ROBOT, m, NOISE, active=base_mask, callback=early)


@pytest.mark.parametrize("name", ["max_iterations", "max_variance_iterations"])
@pytest.mark.parametrize("value", [0, 2**40, 2.5, True])
def test_the_efficient_estimator_s_iteration_limits_are_checked(name: str, value: object) -> None:
    """An iteration limit beyond the C++ int it is passed as gave pybind11's dump of the
    signature (2**40), after the data's analysis; every bad value is now refused before it,
    naming the argument."""
    m, _ = iwr.simulate(ROBOT, 12, seed=1, noise=NOISE)
    with pytest.raises(ValueError, match=rf"^{name}: {value!r}; expected an integer from 1 to "):
        est.efficient(ROBOT, m, NOISE, **{name: value})
