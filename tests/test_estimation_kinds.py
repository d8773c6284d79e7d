"""The efficient estimator for every kind of data it takes, written once (the ``estimable``
fixture; each kind's own derivatives, outliers and refusals are in its own test file): noise-free
readings recover the truth on fresh poses, a callback stops it as SciPy's do, and its fit
statistic is the noise-weighted LM's (two computations of the same weighted minimum: the
estimator solves for every reading's correction, LM's test linearises) and follows its
chi-square law over 20 seeds."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from scipy import stats

import iwr

#: The kinds the efficient estimator takes: all of them.
ESTIMABLE = ("pose", "points", "probe", "ballbar")


@pytest.fixture(scope="module", params=ESTIMABLE)
def estimable(request: pytest.FixtureRequest, kind_case: Any) -> Any:
    # one reading a pose for a ballbar: more poses than its 56 identifiable parameters
    case = kind_case(request.param, n_poses=160 if request.param == "ballbar" else 60, seed=1)
    case.noise = case.kind.experiment_noise(case.robot, iwr.Noise.realistic())
    case.n_law = 120 if request.param == "ballbar" else 40  # poses of the law's data sets
    return case


def test_noise_free_data_recover_the_truth(estimable: Any) -> None:
    robot, truth = estimable.robot, estimable.truth
    res = iwr.identify(robot, estimable.data, noise=estimable.noise)
    assert res.method == "efficient" and res.status == "converged", res.message
    assert res.success and res.fit_ok and res.outliers == []
    assert res.x.shape == truth.shape
    fresh, _ = iwr.simulate(robot, 50, seed=2, x=truth)
    err = estimable.kind.tool_accuracy(robot, fresh, res.x, truth).calibrated
    assert err.position.max() < 1e-9  # mm
    assert math.radians(err.orientation.max()) < 1e-9
    assert res.fit.statistic < 1e-12 and res.fun < 1e-12
    # far below its expectation: the chi-square test says the noise model is pessimistic
    assert any("pessimistic" in c for c in res.fit.causes), res.fit.causes


def test_a_callback_stops_the_estimator(estimable: Any) -> None:
    robot = estimable.robot
    data, _ = iwr.simulate(robot, 30, seed=6, noise=estimable.noise)
    seen = []

    def cb(r: Any) -> Any:
        seen.append((r.nit, float(r.fun), r.x.shape))
        return np.True_  # a NumPy bool, as a SciPy callback may return

    res = iwr.identify(robot, data, noise=estimable.noise, callback=cb)
    assert len(seen) == 1 and seen[0][2] == estimable.truth.shape
    assert not res.success and res.status == "callback" and "callback" in res.message

    def stop(r: Any) -> None:
        raise StopIteration

    res = iwr.identify(robot, data, noise=estimable.noise, callback=stop)
    assert not res.success and res.status == "callback"


def test_the_fit_statistic_is_weighted_lms_and_follows_its_law(estimable: Any) -> None:
    """20 seeds, 40 poses each (120 of a ballbar's single readings), realistic noise, every pose
    kept (no outlier test: a clean pose is flagged at alpha = 1e-3 per pose now and then): LM's
    linearised statistic at its weighted minimum is the estimator's to 1e-3 (a ballbar's to
    1e-2: its weights are its start's) with the same degrees of freedom (a probe's: six readings
    a pose, its four points whitened by the pseudo-inverse of their rank-6 covariance); over
    the seeds the estimator's statistic / dof
    averages 1 within 4 standard errors and the p-values are uniform (Kolmogorov-Smirnov)."""
    robot, noise = estimable.robot, estimable.noise
    ratios, p_values, dof = [], [], None
    for seed in range(20):
        m, _ = iwr.simulate(robot, estimable.n_law, seed=100 + seed, noise=noise)
        eff = iwr.identify(robot, m, "efficient", noise=noise, outliers="off")
        assert eff.success == (eff.fit.p_value >= eff.fit.alpha) and eff.fit.dof > 0
        if estimable.kind.weighted_objective:
            lm = iwr.identify(robot, m, "lm", noise=noise)
            assert lm.fit.dof == eff.fit.dof, (lm.fit.verdict, eff.fit.verdict)
            # a ballbar's weighted objective whitens by the sigmas at its start, not at the
            # minimum: the same statistic to first order only
            rel = 1e-2 if estimable.name == "ballbar" else 1e-3
            assert lm.fit.statistic == pytest.approx(eff.fit.statistic, rel=rel)
            assert lm.success == (lm.fit.p_value >= lm.fit.alpha)
        ratios.append(eff.fit.statistic / eff.fit.dof)
        p_values.append(eff.fit.p_value)
        dof = eff.fit.dof
    # the mean of 20 chi2(dof)/dof draws has sd sqrt(2 / dof / 20)
    assert abs(np.mean(ratios) - 1.0) < 4 * np.sqrt(2.0 / dof / 20), ratios
    assert stats.kstest(p_values, "uniform").pvalue > 1e-3, p_values
