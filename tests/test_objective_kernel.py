"""The optimised cost kernel (blocked SIMD layout, runtime-dispatched instruction sets) against
independent computations: a plain vectorised NumPy formula of eq. (8)-(10), the residual vector,
and the other instruction-set variants of the kernel itself (AVX2 and AVX-512 bit for bit, the SSE2
baseline, which has no fused multiply-add, to rounding)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import iwr
from iwr import _core

# -- an independent plain-NumPy cost, vectorised over poses ------------------------------------


def np_rot(axis: str, angle: np.ndarray) -> np.ndarray:
    """Elementary rotations, shape (..., 3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(c), np.zeros_like(c)
    rows = {
        "x": [[o, z, z], [z, c, -s], [z, s, c]],
        "y": [[c, z, s], [z, o, z], [-s, z, c]],
        "z": [[c, -s, z], [s, c, z], [z, z, o]],
    }[axis]
    return np.moveaxis(np.array(rows), (0, 1), (-2, -1))


def np_homogeneous(r: np.ndarray, p: np.ndarray) -> np.ndarray:
    t = np.zeros(r.shape[:-2] + (4, 4))
    t[..., :3, :3] = r
    t[..., :3, 3] = p
    t[..., 3, 3] = 1
    return t


def np_cost(robot: iwr.Robot, x: np.ndarray, m: iwr.Measurements) -> tuple[float, np.ndarray]:
    """Eq. (10) with A_i = Rz(theta) Tz(d) Tx(a) Rx(alpha) (eq. 1) as products of elementary
    homogeneous transforms, 4R5 = Rz Ry Rx (eq. 6); returns the cost and the residuals (N, 6)."""
    n, nj = len(m), robot.n_joints
    dh = robot.dh + x[: 4 * nj].reshape(nj, 4)
    a = robot.base_joints + x[4 * nj : 4 * nj + 18].reshape(6, 3)
    b = robot.platform_joints + x[4 * nj + 18 : 4 * nj + 36].reshape(6, 3)
    l0 = robot.leg_offsets + x[4 * nj + 36 :]
    t = np.broadcast_to(np.eye(4), (n, 4, 4))
    eye, zero = np.broadcast_to(np.eye(3), (n, 3, 3)), np.zeros((n, 3))
    for i in range(nj):
        alpha, aa, d, theta = (np.full(n, v) for v in dh[i])
        if robot.joint_types[i] == "P":
            d = d + m.q[:, i]
        else:
            theta = theta + m.q[:, i]
        tz = np_homogeneous(np_rot("z", theta), zero) @ np_homogeneous(
            eye, np.stack([0 * d, 0 * d, d], 1)
        )
        tx = np_homogeneous(eye, np.stack([np.full(n, aa), 0 * d, 0 * d], 1)) @ np_homogeneous(
            np_rot("x", alpha), zero
        )
        t = t @ tz @ tx
    r5 = np_rot("z", m.poses[:, 3]) @ np_rot("y", m.poses[:, 4]) @ np_rot("x", m.poses[:, 5])
    leg = (
        m.poses[:, None, :3]
        + np.einsum("nij,lj->nli", r5, b)
        - t[:, None, :3, 3]
        - np.einsum("nij,lj->nli", t[:, :3, :3], a)
    )
    res = np.linalg.norm(leg, axis=2) - l0 - m.legs
    if m.weights is not None:
        res = res * np.sqrt(m.weights)
    return float(np.sum(res**2)), res


# -- robots: the IWR, a hexapod alone, carriages with mixed joint types -------------------------


def make_robot(joint_types: str) -> iwr.Robot:
    """"PPRR": the IWR; "PPRR*": a PPRR carriage with random DH values (the kernel folds every
    PPRR carriage into per-evaluation constants: objective_kernel.hpp, FoldedCarriage); other
    strings: carriages of those joint types with random DH values."""
    if joint_types == "PPRR":
        return iwr.Robot.default()
    seed_key = joint_types
    joint_types = joint_types.rstrip("*")
    if joint_types == "":
        return iwr.Robot.hexapod()
    hexapod = iwr.Robot.hexapod()
    rng = np.random.default_rng(len(seed_key) + 10 * seed_key.count("R") + 7 * seed_key.count("*"))
    n = len(joint_types)
    dh = np.column_stack(
        [
            rng.uniform(-math.pi, math.pi, n),
            rng.uniform(0, 400, n),
            rng.uniform(0, 400, n),
            rng.uniform(-math.pi, math.pi, n),
        ]
    )
    limits = [[0.0, 500.0] if c == "P" else [-1.0, 1.0] for c in joint_types]
    return iwr.Robot(
        joint_types,
        dh,
        limits,
        hexapod.base_joints,
        hexapod.platform_joints,
        hexapod.leg_offsets,
        hexapod.leg_stroke,
        name=f"mixed {joint_types}",
    )


def make_data(robot: iwr.Robot, n: int, weighted: bool, seed: int) -> iwr.Measurements:
    """Random readings (not consistent with any robot: the cost need not be small)."""
    rng = np.random.default_rng(seed)
    lo, hi = robot.joint_limits[:, 0], robot.joint_limits[:, 1]
    q = rng.uniform(lo, hi, (n, robot.n_joints))
    poses = np.column_stack(
        [rng.uniform(-300, 300, (n, 2)), rng.uniform(500, 900, n), rng.uniform(-0.3, 0.3, (n, 3))]
    )
    legs = rng.uniform(0, 400, (n, 6))
    w = rng.uniform(0.0, 3.0, (n, 6)) if weighted else None
    return iwr.Measurements(q, poses, legs, weights=w)


def random_x(problem: iwr.Problem, rng: np.random.Generator, angles: str) -> np.ndarray:
    """Within the default bounds (angle errors up to 0.5 degree), the paper's literal bounds
    (0.5 rad) or with angle errors up to 1.5 rad (the kernel takes sin and cos of those from the C
    library rather than from its angle-sum series)."""
    lower, upper = problem.robot.default_bounds("default" if angles == "default" else "paper")
    x = rng.uniform(lower, upper)
    if angles == "huge":
        x[problem.robot.angle_parameters] *= 3
    return x


CASES = [
    (jt, n, weighted)
    for jt in ["PPRR", "PPRR*", "", "RPRP", "RRPP", "PRRRP"]
    for n in [1, 7, 13, 100]
    for weighted in [False, True]
]


@pytest.fixture
def restore_kernel():
    before = _core._active_kernel()
    yield
    _core._select_kernel(before)


@pytest.mark.parametrize(("joint_types", "n", "weighted"), CASES)
def test_cost_matches_numpy_and_residuals(joint_types, n, weighted):
    robot = make_robot(joint_types)
    data = make_data(robot, n, weighted, seed=n + 3 * len(joint_types))
    p = iwr.Problem(robot, data)
    rng = np.random.default_rng(n)
    for angles in ("default", "paper", "huge"):
        x = random_x(p, rng, angles)
        ref_cost, ref_res = np_cost(robot, x, data)
        res = p.residuals(x)
        np.testing.assert_allclose(res, ref_res.ravel(), rtol=0, atol=1e-9)
        cost = p.cost(x)
        assert cost == pytest.approx(ref_cost, rel=1e-10)
        # the same kernel computes both: agreement up to the order of summation
        assert cost == pytest.approx(float(np.sum(res**2)), rel=1e-13)
        res2, _ = p.residuals_and_jacobian(x)
        np.testing.assert_array_equal(res2, res)


# The AVX2 and AVX-512 variants fuse the multiply-adds the kernel writes as fma/fms; the SSE2
# baseline (CPUs without FMA) rounds them twice, in the order of operations it had before the FMA
# variants (its bits unchanged). Measured over CASES (this module's random data, 18 vectors each
# across the default, paper and wide bounds): the costs differ by at most 2.4e-15 relative
# (1.2e-14 over 600 DE vectors at N = 100), the residuals by at most 1.8e-12 mm.
BASELINE_COST_RTOL = 1e-13
BASELINE_RESIDUAL_ATOL = 1e-10  # mm


def assert_same_to_rounding(got, base, err_msg):
    """The baseline against an FMA variant: (costs, costs, costs, residuals) of the test below."""
    for a, b in zip(got[:3], base[:3], strict=True):
        np.testing.assert_allclose(a, b, rtol=BASELINE_COST_RTOL, atol=0, err_msg=err_msg)
    np.testing.assert_allclose(got[3], base[3], rtol=0, atol=BASELINE_RESIDUAL_ATOL,
                               err_msg=err_msg)


@pytest.mark.parametrize(("joint_types", "n", "weighted"), CASES[::3])
def test_the_fma_variants_give_the_same_bits_and_the_baseline_the_same_to_rounding(
    joint_types, n, weighted, restore_kernel
):
    variants = _core._supported_kernels()
    assert variants[0] == "baseline"
    robot = make_robot(joint_types)
    data = make_data(robot, n, weighted, seed=1)
    p = iwr.Problem(robot, data)
    rng = np.random.default_rng(2)
    X = np.array([random_x(p, rng, a) for a in ["default", "paper", "huge"] * 6])
    results = {}
    for v in variants:
        _core._select_kernel(v)
        assert _core._active_kernel() == v
        results[v] = (
            p.cost_batch(X, workers=1),
            p.cost_batch(X, workers=2),
            np.array([p.cost(x) for x in X]),
            p.residuals(X[0]),
        )
    base = results["baseline"]
    fused = [v for v in variants if v != "baseline"]
    for v in fused[1:]:  # AVX-512 against AVX2: bit for bit
        for a, b in zip(results[v], results[fused[0]], strict=True):
            np.testing.assert_array_equal(a, b, err_msg=f"variant {v}")
    for v in fused:
        assert_same_to_rounding(results[v], base, f"variant {v}")
    for got in results.values():
        np.testing.assert_array_equal(got[0], got[1])  # thread count
        np.testing.assert_array_equal(got[0], got[2])  # batch == single


def test_kernel_selection_is_validated(restore_kernel):
    with pytest.raises(ValueError, match="kernel: 'sse9' is unknown"):
        _core._select_kernel("sse9")
    assert _core._active_kernel() in _core._supported_kernels()


def test_zero_weights_and_exact_data_give_zero():
    robot = iwr.Robot.default()
    data, x = iwr.simulate(robot, n_poses=13, seed=4)
    p = iwr.Problem(robot, data)
    assert p.cost(x) < 1e-18
    w = np.zeros((13, 6))
    w[0, 0] = 1.0  # not all zero: such weights are refused
    pw = iwr.Problem(robot, iwr.Measurements(data.q, data.poses, data.legs, weights=w))
    z = np.random.default_rng(0).uniform(p.lower, p.upper)
    r = pw.residuals(z)
    assert np.all(r[1:] == 0.0) and r[0] != 0.0
    assert pw.cost(z) == pytest.approx(r[0] ** 2, rel=1e-12)
