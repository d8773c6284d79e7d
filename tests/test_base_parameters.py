"""iwr.base_parameters: the preference by parameter name, and QR's pivoting with its ties broken
by it, against SciPy's QR with column pivoting."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg

import iwr
from iwr.base_parameters import candidate_order, left_out_directions, pivoted_columns, preference


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


def test_left_out_directions_span_the_null_space_one_parameter_each():
    """For a Jacobian with known null directions (columns made dependent at random): the
    left-out parameters are SciPy's QR pivots among the candidates, and the basis spans the
    null space (J basis = 0, rank k) with each direction moving its own left-out parameter by 1
    and no other left-out one; in the units of ``physical`` (columns scaled back)."""
    rng = np.random.default_rng(7)
    names = [f"leg{i + 1}.dl0" for i in range(6)] + ["tracker.x", "tracker.y", "joint1.da",
                                                      "joint2.dd"]
    n = len(names)
    for trial in range(20):
        k = int(rng.integers(1, 4))
        jac = rng.standard_normal((30, n - k)) @ rng.standard_normal((n - k, n))
        d = np.linalg.norm(jac, axis=0) * rng.uniform(0.5, 2.0)  # any column scale
        _, s, vt = np.linalg.svd(jac / d)
        scaled = vt[n - k:]
        physical = scaled.T / d[:, None]
        cand = None if trial % 2 else np.sort(rng.choice(n, size=k + 3, replace=False))
        left, basis = left_out_directions(scaled, physical, names, cand)
        pool = np.arange(n) if cand is None else cand
        _, _, piv = scipy.linalg.qr(scaled[:, pool], pivoting=True, mode="economic")
        assert np.array_equal(left, np.sort(pool[piv[:k]]))
        assert np.allclose(basis[left], np.eye(k), atol=0)
        assert np.abs(jac @ basis).max() < 1e-9 * np.abs(jac).max() * np.abs(basis).max()
        assert np.linalg.matrix_rank(basis) == k
    # An exact tie (two equal columns: equal scaled norms in the null direction): the parameter
    # later in the preference is left out, whichever column it is, with or without candidates.
    rank_of = list(preference(names))
    for first, second in ((8, 6), (6, 8), (0, 9)):
        jac = rng.standard_normal((30, n))
        jac[:, second] = jac[:, first]
        d = np.linalg.norm(jac, axis=0)
        _, s, vt = np.linalg.svd(jac / d)
        scaled, physical = vt[n - 1:], vt[n - 1:].T / d[:, None]
        loser = max(first, second, key=rank_of.index)
        for cand in (None, np.array(sorted({first, second, 2}))):
            left, basis = left_out_directions(scaled, physical, names, cand)
            assert list(left) == [loser], (first, second, cand, left)
            assert basis[loser, 0] == 1.0
            assert basis[first + second - loser, 0] == pytest.approx(-1.0, abs=1e-12)

