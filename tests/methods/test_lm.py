"""Levenberg-Marquardt: recovery despite rank deficiency, few readings, the MINPACK guard column,
argument checks, and weights whose scale cannot change the answer."""

from __future__ import annotations

import numpy as np
import pytest

import iwr
from iwr.methods.lm import _guard_column

from .conftest import validation_rms


def test_lm_recovers_all_58_despite_rank_deficiency(robot, data, validation):
    m, truth = data
    jac = iwr.Problem(robot, m).jacobian(truth)
    assert np.linalg.matrix_rank(jac / np.linalg.norm(jac, axis=0)) < 58  # really rank deficient
    res = iwr.identify(robot, m, "lm", progress=False)
    assert res.success and res.fun < 1e-16
    assert "`" not in res.message and "termination condition" in res.message  # no Markdown quotes
    assert validation_rms(robot, res.x, validation) < 1e-7
    # The regularisation keeps the unidentifiable combinations near the start: no sliding away.
    assert np.max(np.abs(res.x)) < 5.0
    assert res.nfev < 300


def test_lm_with_fewer_readings_than_parameters(robot):
    m, _ = iwr.simulate(robot, n_poses=5, seed=2)  # 30 readings, 58 parameters
    res = iwr.identify(robot, m, "lm", progress=False)
    assert res.fun < 1e-12
    with pytest.raises(ValueError, match="residuals"):
        iwr.identify(robot, m, "lm", regularization=0.0)


def test_guard_column_is_a_zero_column():
    j = np.arange(6.0).reshape(3, 2)
    g = _guard_column(j)
    assert g.shape == (3, 3) and np.array_equal(g[:, :2], j) and not g[:, 2].any()


@pytest.mark.parametrize("options, name", [
    ({"regularization": -1.0}, "regularization"),
    ({"regularization": "on"}, "regularization"),
    ({"max_evaluations": 1}, "max_evaluations"),
    ({"max_nfev": 10}, "max_nfev"),  # one budget name: max_evaluations
])
def test_bad_arguments_name_the_argument(robot, data, options, name):
    m, _ = data
    with pytest.raises((ValueError, TypeError), match=name):
        iwr.identify(robot, m, "lm", progress=False, **options)


@pytest.mark.parametrize("scale", [1e30, 5e-324, 1e-300, 7.0])
def test_equal_weights_of_any_scale_give_the_unweighted_answer(robot, scale):
    """Weights are relative: every weight equal to 1e30 (which used to return the start as a
    success) or to the smallest double (which used to report cost 0 far from the answer) is the
    unweighted problem."""
    m, truth = iwr.simulate(robot, n_poses=30, seed=3, noise=iwr.Noise.realistic())
    plain = iwr.identify(robot, m, "lm", progress=False)
    w = iwr.Measurements(m.q, m.poses, m.legs, joint_types=m.joint_types,
                         weights=np.full((len(m), 6), scale))
    weighted = iwr.identify(robot, w, "lm", progress=False)
    assert weighted.success and plain.success
    np.testing.assert_array_equal(weighted.x, plain.x)
    assert weighted.fun == plain.fun and weighted.nfev == plain.nfev


def test_relative_weights_scale_free(robot):
    """Weights that differ only by a common factor give the same answer: the same cost and the
    same predicted readings (the parameters themselves move by round-off times the conditioning
    of the weakest directions)."""
    m, _ = iwr.simulate(robot, n_poses=30, seed=3, noise=iwr.Noise.realistic())
    w = np.random.default_rng(0).uniform(0.5, 2.0, (len(m), 6))
    results = []
    for factor in (1.0, 1e200, 1e-200):
        mw = iwr.Measurements(m.q, m.poses, m.legs, joint_types=m.joint_types,
                              weights=w * factor)
        results.append(iwr.identify(robot, mw, "lm", progress=False))
    legs = [iwr.predict_legs(robot, r.x, m.q, m.poses) for r in results]
    for r, pred in zip(results[1:], legs[1:], strict=True):
        assert r.success and r.fun == pytest.approx(results[0].fun, rel=1e-9)
        np.testing.assert_allclose(pred, legs[0], rtol=0, atol=1e-7)
