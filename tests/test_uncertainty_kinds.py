"""iwr.uncertainty for every kind of data it takes, written once (the ``uncertain`` fixture),
checked by Monte Carlo: the true robot (and setup) and the poses fixed, fresh noise of every
instrument per seed, the spread of the parameters LM identifies against the predicted standard
deviations and covariance. Each kind's own parts (the tracker's point covariance, the pose data's
leg sigma) are in its own test file."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import iwr
from iwr.planning import measure
from iwr.simulation import sample_poses

#: The kinds checked here (the ballbar's Monte Carlo is in tests/test_ballbar.py).
UNCERTAIN = ("pose", "points", "probe")
N_SEEDS = 30


@pytest.fixture(scope="module", params=UNCERTAIN)
def uncertain(request: pytest.FixtureRequest, kind_case: Any) -> Any:
    return kind_case(request.param, n_poses=1, seed=3)


def test_predicted_covariance_matches_the_monte_carlo_spread(uncertain: Any) -> None:
    """40 poses, 30 seeds of realistic noise: the spread of each base parameter over the
    median of the predicted standard deviations within 15 % (the sampling error of one standard
    deviation from 30 draws is 13 %, of their median a few per cent), and the mean Mahalanobis
    distance per parameter within 15 % of 1 (its standard error is under 4 %)."""
    robot, truth, kind = uncertain.robot, uncertain.truth, uncertain.kind
    noise = kind.experiment_noise(robot, iwr.Noise.realistic())
    q, poses, _ = sample_poses(robot, 40, np.random.default_rng(1), x=truth[:robot.n_params])
    clean = measure(robot, truth, q, poses)
    mask = iwr.identifiability(robot, clean).active
    # The truth in the gauge of the held parameters (held at ref, as every run below holds them).
    ref = iwr.identify(robot, clean, "lm", active=mask).x
    pred = iwr.uncertainty(robot, clean, ref, noise=noise, active=mask)
    assert pred.covariance.shape == (mask.sum(),) * 2
    assert np.all(np.isnan(pred.std[~mask])) and np.all(pred.std[mask] > 0)
    runs = []
    for seed in range(N_SEEDS):
        data = measure(robot, truth, q, poses, noise=noise, seed=100 + seed)
        res = iwr.identify(robot, data, "lm", x0=ref, active=mask)
        assert res.success, res.message
        runs.append(res.x[mask])
    x = np.array(runs)
    ratio = x.std(axis=0, ddof=1) / pred.std[mask]
    assert 0.85 < np.median(ratio) < 1.15, np.median(ratio)
    dev = x - ref[mask]
    maha = np.einsum("si,ij,sj->s", dev, np.linalg.inv(pred.covariance), dev) / mask.sum()
    assert 0.85 < maha.mean() < 1.15, maha.mean()
