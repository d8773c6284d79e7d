"""The weighted tracker objective's whitening in the SIMD kernel (issue 24, ninth round): the C++
cost of a whitened ``TrackerProblem`` (``cost_batch``, the engine's objective) whitens each pose's
residuals inside the kernel's block (tracker_kernel_body.inl, ``points_chain``). Pinned here
against the whitening computed independently in numpy from the unweighted residuals, for every
variant (``_select_kernel``), every path of the kernel (3 reflectors and a probe in registers,
any other size or row pattern through memory), hidden points, the probe's zero rows, failed
poses, the padded last block, and several threads (the same bits)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import iwr
from iwr import _core
from iwr.tracker import TrackerMeasurements, TrackerNoise, TrackerProblem
from iwr.tracker.api import tracker_problem, tracker_simulate

REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0),
              (0.0, 0.0, 90.0)]
REGISTRATION = (2000.0, -150.0, 300.0, math.pi / 2, 0.01, -0.02)
READINGS = dataclasses.replace(iwr.Noise.realistic(), position=0.0, orientation=0.0)
NOISE = (READINGS, TrackerNoise.leica())
N = 21  # three blocks of 8 poses, the last padded


@pytest.fixture
def restore_kernel():
    before = _core._active_kernel()
    yield
    _core._select_kernel(before)


def _robot(kind: str, k: int = 3) -> iwr.Robot:
    if kind == "probe":
        return iwr.Robot.default().with_tracker(registration=REGISTRATION,
                                                probe=(10.0, -5.0, 60.0, 0.1, 0.0, 0.2))
    return iwr.Robot.default().with_tracker(registration=REGISTRATION, reflectors=REFLECTORS[:k])


def _noise_weighted(kind: str, k: int = 3) -> TrackerProblem:
    """Weighted by the noise model: reflectors with a fifth hidden (zero rows and columns), or a
    probe (rank 6: its first six rows zero at every pose)."""
    robot = _robot(kind, k)
    m, _ = tracker_simulate(robot, N, seed=3, noise=NOISE,
                            hidden=0.2 if kind == "points" else 0.0)
    return tracker_problem(robot, m, noise=NOISE)[0]


def _own_whitening(kind: str, k: int, pattern: str) -> TrackerProblem:
    """A whitening of one's own: "full" (every row), "gaps" (rows 1 and 4 zero at every pose, a
    row zero at one pose only), "zero" (zero everywhere)."""
    robot = _robot(kind, k)
    m, _ = tracker_simulate(robot, N, seed=4, hidden=0.2 if kind == "points" else 0.0)
    plain, _ = tracker_problem(robot, m)
    n = 12 if kind == "probe" else 3 * k
    rng = np.random.default_rng(8)
    w = np.tril(rng.normal(size=(N, n, n))) + 3 * np.eye(n)
    if pattern == "gaps":
        w[:, [1, 4], :] = 0.0
        w[5, 2, :] = 0.0
    elif pattern == "zero":
        w[:] = 0.0
    return TrackerProblem(robot, robot.tracker, m, (plain.lower, plain.upper),
                          reference=plain.reference, whitening=w)


def _vectors(problem: TrackerProblem) -> np.ndarray:
    """Across the search box, one far beyond it (the damped Newton fallback), one where some
    poses fail and one where every pose fails (the penalty, whitened)."""
    rng = np.random.default_rng(1)
    lo, hi = problem.lower, problem.upper
    X = lo + (hi - lo) * rng.random((6, problem.n_params))
    names = problem.parameter_names
    robot = problem.robot
    far = X[0].copy()
    far[: robot.n_params] += np.where(robot.angle_parameters, 0.05, 40.0)
    some = np.zeros(problem.n_params)
    some[names.index("leg2.dl0")] = 300.0  # some poses cannot close
    dead = X[1].copy()
    dead[names.index("leg1.dl0")] = -2000.0  # no pose can
    return np.vstack([X, far, some, dead])


def _independent(problem: TrackerProblem, x: np.ndarray) -> float:
    """sum_k |W_k r_k|^2 from the unweighted residuals, in numpy."""
    r = problem._objective.residuals(problem._x(x)).reshape(problem.n_poses, -1)
    return float(np.sum(np.einsum("kij,kj->ki", problem.whitening, r) ** 2))


CASES = [
    ("3 reflectors, noise", lambda: _noise_weighted("points")),
    ("probe, noise", lambda: _noise_weighted("probe")),
    ("probe, own", lambda: _own_whitening("probe", 0, "full")),
    ("1 reflector, noise", lambda: _noise_weighted("points", 1)),
    ("4 reflectors, own", lambda: _own_whitening("points", 4, "full")),
    ("3 reflectors, rows zero", lambda: _own_whitening("points", 3, "gaps")),
    ("probe, zero", lambda: _own_whitening("probe", 0, "zero")),
]


@pytest.mark.parametrize("name, make", CASES, ids=[c[0] for c in CASES])
def test_the_kernel_whitening_is_the_numpy_one_in_every_variant(name, make, restore_kernel):
    problem = make()
    X = _vectors(problem)
    some = X[-2]
    assert 0 < len(problem.failures(some)) < N
    assert len(problem.failures(X[-1])) == N
    independent = np.array([_independent(problem, x) for x in X])
    if name == "probe, noise":  # six rows a pose carry data, the first six are zero
        assert not problem.whitening[:, :6, :].any()
        assert problem.whitening[:, 6:, :].any(axis=2).all()
    if name == "probe, zero":
        assert not independent.any()
    results = {}
    for v in _core._supported_kernels():
        _core._select_kernel(v)
        one = problem.cost_batch(X, workers=1)
        results[v] = one
        for threads in (2, 3):  # the same bits whatever the threads
            np.testing.assert_array_equal(problem.cost_batch(X, workers=threads), one,
                                          err_msg=f"{v}, {threads} threads")
        # The kernel's cost against the whitening done apart: to rounding (the kernel sums in
        # another order, and the AVX2 and AVX-512 variants fuse the multiply-adds).
        np.testing.assert_allclose(one, independent, rtol=1e-12, atol=0, err_msg=v)
        # and against the whitened residuals (C++, Eigen's triangular product), squared in numpy
        for x, c in zip(X[[0, 6, 7, 8]], one[[0, 6, 7, 8]], strict=True):
            assert c == pytest.approx(float(np.sum(problem.residuals(x) ** 2)), rel=1e-12, abs=0)
    fused = [v for v in results if v != "baseline"]
    for v in fused[1:]:  # AVX2 and AVX-512: the same operations on each lane, the same bits
        np.testing.assert_array_equal(results[v], results[fused[0]], err_msg=v)


def test_the_poses_whitened_alone_cost_what_they_cost_together(restore_kernel):
    # A pose's whitened cost must not depend on which poses share its block of 8 (nor on the
    # padding lanes): the 13 poses' weighted cost against the sum of each pose's alone (N = 1,
    # its block its own copies), equal but for the order of the sum.
    robot = _robot("points")
    m, _ = tracker_simulate(robot, 13, seed=21, noise=NOISE, hidden=0.3)
    full, _ = tracker_problem(robot, m, noise=NOISE)
    X = _vectors(full)
    for v in _core._supported_kernels():
        _core._select_kernel(v)
        together = full.cost_batch(X, workers=1)
        alone = np.zeros(len(X))
        for k in range(13):
            one = TrackerProblem(robot, robot.tracker,
                                 TrackerMeasurements(m.q[k:k + 1], m.legs[k:k + 1],
                                                     points=m.points[k:k + 1]),
                                 (full.lower, full.upper), reference=full.reference,
                                 whitening=full.whitening[k:k + 1])
            alone += one.cost_batch(X, workers=1)
        np.testing.assert_allclose(together, alone, rtol=1e-13, atol=0, err_msg=v)
