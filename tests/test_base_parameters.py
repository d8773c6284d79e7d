"""iwr.base_parameters: the preference by parameter name, and QR's pivoting with its ties broken
by it, against SciPy's QR with column pivoting."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg

import iwr
from iwr.base_parameters import candidate_order, pivoted_columns, preference


def test_preference_groups_every_geometric_name_and_no_other():
    # The hexapod's 42 first, the carriage's 4 n_joints last, whatever else (a tracker's set-up,
    # effects such as leg1.compliance or joint2.compliance) between, each group in its order.
    robot = iwr.Robot.default().with_tracker(registration=(2000.0, 0, 0, math.pi / 2, 0, 0),
                                             reflectors=[(120.0, 0.0, 40.0)])
    names = robot.parameter_names + ["tracker.x", "reflector1.z", "leg1.compliance",
                                     "joint2.compliance", "legs.alpha"]
    order = preference(names)
    assert sorted(order) == list(range(len(names)))
    nc = 4 * robot.n_joints
    assert list(order[:42]) == list(range(nc, robot.n_params))
    assert list(order[-nc:]) == list(range(nc))
    assert list(order[42:-nc]) == list(range(robot.n_params, len(names)))


def test_pivoted_columns_are_scipys_without_ties_and_the_least_preferred_on_one():
    rng = np.random.default_rng(2)
    for _ in range(50):
        k, n = rng.integers(1, 6), rng.integers(6, 12)
        v = np.linalg.qr(rng.standard_normal((n, k)))[0].T  # orthonormal rows
        _, _, piv = scipy.linalg.qr(v, pivoting=True, mode="economic")
        assert np.array_equal(pivoted_columns(v, rng.permutation(n)), np.sort(piv[:k]))
    # Two exactly equal columns (a parameter pair of equal scaled norms): the one later in the
    # order is left out, whichever it is, also when round-off makes it the smaller by an ulp
    # (where QR takes the other).
    v = rng.standard_normal((1, 5))
    v[0, 3] = v[0, 1] = 2 * np.abs(v).max()
    assert list(pivoted_columns(v, np.arange(5))) == [3]
    assert list(pivoted_columns(v, np.array([3, 0, 2, 4, 1]))) == [1]
    w = v.copy()
    w[0, 3] = np.nextafter(w[0, 3], 0)
    assert scipy.linalg.qr(w, pivoting=True, mode="economic")[2][0] == 1
    assert list(pivoted_columns(w, np.arange(5))) == [3]
    with pytest.raises(ValueError, match="permutation"):
        pivoted_columns(v, np.array([0, 1, 2, 3, 3]))


def test_candidate_order_is_the_preference_among_the_candidates():
    names = ["joint1.da", "leg1.da_x", "tracker.x", "joint2.dd", "leg2.dl0"]
    cand = np.array([0, 2, 3, 4])
    # preference: leg1.da_x, leg2.dl0, tracker.x, joint1.da, joint2.dd -> among cand:
    # leg2.dl0 (position 3), tracker.x (1), joint1.da (0), joint2.dd (2)
    assert list(candidate_order(names, cand)) == [3, 1, 0, 2]
