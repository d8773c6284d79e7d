"""iwr.experiments.harness: one seeding scheme (common random numbers), one row schema, failures
recorded in the row."""

from __future__ import annotations

import math

import numpy as np
import pytest

import iwr
from iwr.experiments.harness import (
    COLUMNS,
    Cell,
    Scenario,
    canonical,
    check_n_poses,
    evaluate,
    min_poses,
    noise_at,
    rms,
    robot_hash,
    stream_seed,
)

ROBOT = iwr.Robot.default()


def test_streams_are_independent_and_reproducible():
    assert stream_seed(0, 1, 2) == stream_seed(0, 1, 2)
    assert len({stream_seed(0, p, 2, 3) for p in (1, 2, 3, 4)}) == 4
    assert 0 <= stream_seed(5, 1) < 2**63


def test_common_random_numbers():
    """The truth depends on the draw only; the validation poses on (draw, seed), not on the pose
    count or the noise; the bad scenario's truth is the near one's uniform draws, rescaled."""
    a = Scenario(12, noise_at(0.0), draw=1, seed=0).build(ROBOT)
    b = Scenario(20, noise_at(0.02), draw=1, seed=0).build(ROBOT)
    c = Scenario(12, noise_at(0.0), draw=1, seed=1).build(ROBOT)
    d = Scenario(12, noise_at(0.0), draw=2, seed=0).build(ROBOT)
    np.testing.assert_array_equal(a.truth, b.truth)
    np.testing.assert_array_equal(a.truth, c.truth)
    assert not np.array_equal(a.truth, d.truth)
    np.testing.assert_array_equal(a.validation.q, b.validation.q)
    assert not np.array_equal(a.validation.q, c.validation.q)
    assert a.method_seed == b.method_seed != c.method_seed
    lo, hi = ROBOT.default_bounds("default")
    plo, phi = ROBOT.default_bounds("paper")
    bad = Scenario(12, noise_at(0.0), draw=1, kind="bad").truth(ROBOT)
    np.testing.assert_allclose((bad - plo) / (phi - plo), (a.truth - lo) / (hi - lo), rtol=1e-12)
    # Noise of the same shape, scaled: the same poses, every reading off by twice as much (to
    # first order for the orientation, whose noise is a rotation).
    e = Scenario(20, noise_at(0.04), draw=1, seed=0).build(ROBOT)
    z = Scenario(20, noise_at(0.0), draw=1, seed=0).build(ROBOT)
    for f, rtol, atol in (("q", 1e-9, 1e-15), ("legs", 1e-9, 1e-12), ("poses", 1e-3, 1e-8)):
        exact = getattr(z.data, f)
        np.testing.assert_allclose(getattr(e.data, f) - exact, 2 * (getattr(b.data, f) - exact),
                                   rtol=rtol, atol=atol)
        assert np.any(getattr(b.data, f) != exact)


def test_a_row_has_every_column_and_a_failure_is_recorded():
    rh = robot_hash(ROBOT)
    ok = evaluate(Cell("lm", "{}", None, 12, 0.02, 0, 0, 0, 10, rh), ROBOT)
    assert set(COLUMNS) - {"notes", "within_budget", "budget_option"} <= set(ok)
    assert ok["status"] == "ok" and ok["within_budget"] is None
    assert ok["val_rms"] < 0.1 * ok["val_rms_nominal"] and ok["at_floor"]
    assert ok["rms_fit"] == pytest.approx(math.sqrt(ok["cost"] / 72), rel=1e-12)
    bad = evaluate(Cell("de", canonical({"population_size": 3}), None, 12, 0.0, 0, 0, 0, 10, rh),
                   ROBOT)
    assert bad["status"] == "failed" and "population_size: 3" in bad["message"]


def test_rms():
    assert rms([3.0, 4.0]) == pytest.approx(math.sqrt(12.5))
    assert math.isnan(rms([]))


def test_bad_scenario_plausibility_follows_the_curved_null_directions():
    """The bad scenario's truth has angle errors up to 0.5 rad. On its noise-free data LM from the
    bad start reaches the truth's readings exactly (cost ~1e-22) hundreds of mm away from it along
    the unidentifiable directions, two of which are rotations of frame {4}: the straight removal
    of the null component named such a solution implausible. The smallest equivalent vector,
    found on the curved set of equivalents, is the truth's own smallest equivalent (an
    independent yardstick: both are the minimum of one set), so the fit is plausible; LM's local
    minimum of draw 2 stays implausible."""
    from iwr.fit_test import _nearest_plausible, fit_check, leg_readings
    from iwr.implicit_loop import loop_jacobians

    lower, upper = ROBOT.default_bounds("paper")
    limit = 10 * upper
    all_active = np.ones(ROBOT.n_params, dtype=bool)
    sc = Scenario(30, noise_at(0.0), draw=0, kind="bad").build(ROBOT)
    res = iwr.identify(ROBOT, sc.data, "lm", bounds="paper", x0=sc.x0, seed=0, progress=False)
    assert res.fun < 1e-15 and np.max(np.abs(res.x - sc.truth)) > 100  # mm, along null directions
    assert res.success and res.fit.implausible == []
    fit = fit_check(ROBOT, sc.data, res.x, active=all_active, bounds=(lower, upper))
    assert fit.fit_ok and fit.implausible == []
    model = leg_readings(ROBOT, sc.data)
    smallest = _nearest_plausible(model, res.x, limit)
    np.testing.assert_allclose(smallest, _nearest_plausible(model, sc.truth, limit),
                               atol=1e-6)
    assert np.linalg.norm(smallest / limit) <= np.linalg.norm(sc.truth / limit)
    legs = [loop_jacobians(ROBOT, v, sc.data.q, sc.data.poses)[0] for v in (res.x, smallest)]
    np.testing.assert_allclose(legs[1], legs[0], atol=1e-8)
    # The straight removal, for contrast: it leaves the set and names parameters.
    jac = loop_jacobians(ROBOT, res.x, sc.data.q, sc.data.poses)[1].reshape(-1, ROBOT.n_params)
    d = np.linalg.norm(jac, axis=0)
    _, s, vt = np.linalg.svd(jac / d, full_matrices=False)
    null = vt[int(np.sum(s > 1e-10 * s[0])):].T / d[:, None] / limit[:, None]
    y = res.x / limit
    straight = y - null @ np.linalg.lstsq(null, y, rcond=None)[0]
    assert np.max(np.abs(straight)) > 1

    stuck = Scenario(30, noise_at(0.0), draw=2, kind="bad").build(ROBOT)
    res = iwr.identify(ROBOT, stuck.data, "lm", bounds="paper", x0=stuck.x0, seed=0,
                       progress=False)
    assert res.fun > 1e3 and not res.success and len(res.fit.implausible) > 10


def test_the_size_test_stops_at_a_plausible_equivalent_and_names_the_smallest_otherwise():
    """beyond_plausible: an x within every limit is plausible at once (the readings model called
    once, for the readings to hold); a vector pushed far along the null directions (the bad
    scenario's noise-free LM answer, 270 mm from the truth) is plausible on the way to its
    smallest equivalent; and LM's local minimum names exactly what the full minimisation
    (``_nearest_plausible`` without the stop) names, with its values."""
    from iwr.fit_test import _nearest_plausible, beyond_plausible, leg_readings

    names = ROBOT.parameter_names
    limit = 10 * ROBOT.default_bounds("paper")[1]
    sc = Scenario(30, noise_at(0.0), draw=0, kind="bad").build(ROBOT)
    calls = []

    def counted(v):
        calls.append(1)
        return leg_readings(ROBOT, sc.data)(v)

    assert np.max(np.abs(sc.truth / limit)) <= 1
    assert beyond_plausible(counted, sc.truth, limit, None, names) == [] and len(calls) == 1
    far = iwr.identify(ROBOT, sc.data, "lm", bounds="paper", x0=sc.x0, seed=0, progress=False).x
    assert np.max(np.abs(far / limit)) > 1  # beyond at the start: the search runs
    assert beyond_plausible(counted, far, limit, None, names) == [] and len(calls) > 2

    stuck = Scenario(30, noise_at(0.0), draw=2, kind="bad").build(ROBOT)
    x = iwr.identify(ROBOT, stuck.data, "lm", bounds="paper", x0=stuck.x0, seed=0,
                     progress=False).x
    model = leg_readings(ROBOT, stuck.data)
    smallest = _nearest_plausible(model, x, limit)
    named = beyond_plausible(model, x, limit, None, names)
    assert len(named) > 10
    # without a covariance each one is significant, with no standard deviation
    assert [(b.name, b.value, b.limit) for b in named] == [
        (names[i], float(smallest[i]), float(limit[i]))
        for i in np.flatnonzero(np.abs(smallest) > limit)]
    assert all(b.significant and np.isnan(b.sd) for b in named)


def test_min_poses_is_what_the_identifiable_parameters_need():
    """9 poses (54 leg readings) determine the IWR's 52 identifiable parameters, 8 (48) cannot:
    checked on the rank of the Jacobian at random poses, independently of min_poses."""
    assert min_poses(ROBOT) == 9
    for n, rank in ((9, 52), (8, 48)):
        m, truth = iwr.simulate(ROBOT, n, seed=3)
        assert iwr.identifiability(ROBOT, m, truth).rank == rank
    assert check_n_poses(ROBOT, 9) == 9
    with pytest.raises(ValueError, match="n_poses: 8 poses are too few: the 52 identifiable "
                                         "parameters of robot 'IWR' need at least 9 poses"):
        check_n_poses(ROBOT, 8)
    with pytest.raises(ValueError, match="n_poses: 8 poses are too few"):
        Scenario(8, noise_at(0.0)).build(ROBOT)
    row = evaluate(Cell("lm", "{}", None, 3, 0.0, 0, 0, 0, 10, robot_hash(ROBOT)), ROBOT)
    assert row["status"] == "failed" and "n_poses: 3 poses are too few" in row["message"]
