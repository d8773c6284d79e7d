"""iwr.uncertainty on laser-tracker data, the tracker's own parts: each point's covariance is the
tracker's noise model, and sigma from the point residuals without one. The Monte Carlo of the
predicted covariance, for every kind, is in tests/test_uncertainty_kinds.py."""

from __future__ import annotations

import math

import numpy as np
import pytest

import iwr
from iwr.tracker import TrackerNoise
from iwr.tracker.api import tracker_problem

REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
REGISTRATION = (2000.0, 0.0, 0.0, math.pi / 2, 0.0, 0.0)
READINGS = iwr.Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6)
TRACKER = TrackerNoise.leica()


def robot_for(kind: str) -> iwr.Robot:
    kw = {"reflectors": REFLECTORS} if kind == "points" else {"probe": (0, 0, 60, 0, 0, 0)}
    return iwr.Robot.default().with_tracker(registration=REGISTRATION, **kw)


def test_the_point_covariance_is_the_tracker_noise_model():
    """Each point's covariance, long across the line of sight, against samples of
    TrackerNoise.perturb (the simulation's noise)."""
    from iwr.analysis.uncertainty import _point_covariance

    robot = robot_for("points")
    clean, truth = iwr.simulate(robot, 3, seed=2)
    problem, _ = tracker_problem(robot, clean, x0=truth)
    c = _point_covariance(problem, truth, None, TRACKER)
    rng = np.random.default_rng(0)
    p = clean.points[1, 2]
    draws = TRACKER.perturb(np.tile(p, (40000, 1)), rng) - p
    np.testing.assert_allclose(np.cov(draws.T), c[1, 6:9, 6:9], rtol=0.05,
                               atol=0.05 * np.abs(c[1, 6:9, 6:9]).max())
    e = p / np.linalg.norm(p)
    along = e @ c[1, 6:9, 6:9] @ e
    sr, st = TRACKER.sigmas(np.linalg.norm(p))
    assert along == pytest.approx(sr**2) and np.trace(c[1, 6:9, 6:9]) == pytest.approx(
        sr**2 + 2 * st**2)
    assert np.all(c[:, :3, 3:] == 0)  # points independent


def test_without_a_noise_model_sigma_comes_from_the_residuals():
    robot = robot_for("points")
    from iwr.tracker.api import tracker_simulate

    data, _ = tracker_simulate(robot, 30, seed=3, noise=(READINGS, TRACKER), hidden=0.2)
    res = iwr.identify(robot, data, active="base")
    unc = iwr.uncertainty(robot, data, res.x, active=res["active"])
    problem, _ = tracker_problem(robot, data, x0=res.x)
    assert unc.dof == problem.n_observations - res["active"].sum()
    assert unc.sigma == pytest.approx(math.sqrt(problem.cost(res.x) / unc.dof))
    assert unc.source == "point residuals" and "tracker problem" in unc.describe()
    with pytest.raises(ValueError, match="rank deficient"):
        iwr.uncertainty(robot, data, res.x, active=np.ones(res.x.size, bool))
