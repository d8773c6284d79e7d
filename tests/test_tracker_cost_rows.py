"""The tracker objective's costs of several parameter vectors at once (issue 24:
``TrackerObjective::cost_rows``): ``cost_batch`` and DE take the vectors in groups of up to
eight, whose blocks run block after block (AVX-512: pair after pair) for the whole group, and
solve a group's last, partly filled blocks of poses together where the last block is alone (two
vectors' lanes in one block when it is at most half full, two blocks a call), each lane with its
own vector's hexapod. Pinned
here: every row's cost is ``cost`` of that row alone, bit for bit, for every number of poses in
the last block (1-8, an odd and an even number of blocks), every variant, weighted or not,
hidden points, vectors whose forward kinematics fails or falls back to damped Newton inside a
group, leftovers that do not fill a group, 1 and 2 threads, and through DE's reduced vectors
(parameters held)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import iwr
from iwr import _core
from iwr.tracker import TrackerNoise
from iwr.tracker.api import tracker_problem, tracker_simulate

REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
REGISTRATION = (2000.0, -150.0, 300.0, math.pi / 2, 0.01, -0.02)
READINGS = dataclasses.replace(iwr.Noise.realistic(), position=0.0, orientation=0.0)
NOISE = (READINGS, TrackerNoise.leica())


@pytest.fixture
def restore_kernel():
    before = _core._active_kernel()
    yield
    _core._select_kernel(before)


def _problem(n: int, weighted: bool, seed: int = 3):
    robot = iwr.Robot.default().with_tracker(registration=REGISTRATION, reflectors=REFLECTORS)
    m, _ = tracker_simulate(robot, n, seed=seed, noise=NOISE if weighted else None, hidden=0.2)
    return tracker_problem(robot, m, noise=NOISE if weighted else None)[0]


def _rows(problem, count: int, seed: int) -> np.ndarray:
    """count vectors across the search box, with one far outside it and one where every pose
    fails, inside the first groups."""
    rng = np.random.default_rng(seed)
    lo, hi = problem.lower, problem.upper
    X = lo + (hi - lo) * rng.random((count, problem.n_params))
    X[2] = hi + 40.0 * (hi - lo)
    X[5] = 0.0
    X[5, problem.parameter_names.index("leg1.dl0")] = -2000.0
    return X


# N = 8 (b - 1) + t: t poses in the last block (1-8), b blocks (odd: the last block alone on
# AVX-512; even: the second of a pair there; alone on AVX2 and the baseline, which do not pair).
SIZES = [1, 2, 3, 4, 5, 6, 7, 8, 9, 12, 14, 15, 16, 19, 20, 21, 22, 23, 24, 28, 29, 31, 32]


@pytest.mark.parametrize("n", SIZES)
def test_every_row_costs_what_it_costs_alone_bit_for_bit(n, restore_kernel):
    # The C++ objective's own cost of one vector (a weighted problem's Python cost is NumPy's).
    problem = _problem(n, weighted=n % 2 == 1)
    obj = problem.engine_objective()
    # 37 rows: more than the 16 that batch_costs hands over at a time on one thread, groups of 2,
    # 4 and 8, and leftovers.
    X = _rows(problem, 37, seed=n)
    assert len(obj.failures(X[5])) == n  # every pose of that vector fails
    for v in _core._supported_kernels():
        _core._select_kernel(v)
        alone = np.array([obj.cost(x) for x in X])
        assert np.isfinite(alone).all()
        for threads in (1, 2):
            got = obj.cost_batch(X, threads)
            assert got.view(np.uint64).tolist() == alone.view(np.uint64).tolist(), (v, threads)
        # Every count of rows up to a group of 8 and one more: the groups filled and not.
        for m in range(1, 10):
            got = obj.cost_batch(X[:m], 1)
            assert got.view(np.uint64).tolist() == alone[:m].view(np.uint64).tolist(), (v, m)


@pytest.mark.parametrize("n", [20, 21])
def test_de_population_costs_are_their_vectors_costs(n, restore_kernel):
    """DE's engine (de::ReducedObjective, its own buffers for the held parameters) evaluates the
    trials through the same grouped path: its population's costs are ``cost`` of its vectors."""
    from iwr.methods.de import _Run

    problem = _problem(n, weighted=False)
    obj = problem.engine_objective()
    active = np.ones(problem.n_params, dtype=bool)
    active[[3, problem.n_params - 2]] = False
    x0 = np.zeros(problem.n_params)
    x0[3] = 1e-3
    # 70 vectors a generation: chunks of the pool past the 16 full vectors a thread keeps.
    run = _Run(int(active.sum()), strategy="jade", population_size=70, F=None, CR=None,
               generations=4, seed=5, workers=2, options={})
    box = run.core_args(np.ascontiguousarray(problem.lower[active]),
                        np.ascontiguousarray(problem.upper[active]))
    for v in _core._supported_kernels():
        _core._select_kernel(v)
        raw = _core.de_kernel(kernel=obj, active=active.tolist(), x0=x0, **box, monitor=None,
                              every_generation=False)
        pop = np.asarray(raw["population"])
        full = np.tile(x0, (len(pop), 1))
        full[:, active] = pop
        alone = np.array([obj.cost(x) for x in full])
        got = np.asarray(raw["population_costs"])
        assert got.view(np.uint64).tolist() == alone.view(np.uint64).tolist(), v
