"""Double-ballbar data in the C++ core and the engine (issue 21, item 4): the C++ ballbar
objective against :class:`iwr.ballbar.BallbarProblem`'s NumPy residuals, its threaded batch
costs, the problem file (weighted, round trip, what the engine builds from it), ``iwr-engine``
and ``iwr-calibrate`` on ballbar data against ``iwr.identify(method="de")`` bit for bit, and
``iwr report`` of such a run (its data file accepted, any other refused)."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from _ballbar import NOISE, ballbar_robot, with_offset

import iwr
from iwr import _core, kinds
from iwr.ballbar import BallbarProblem
from iwr.ballbar.api import ballbar_problem, weighted_problem
from iwr.problem_file import engine_result, read_problem

SETUPS = with_offset(0.3)
BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def case() -> tuple[iwr.Robot, object, np.ndarray]:
    """Two set-ups, 24 noisy poses, the truth."""
    robot = ballbar_robot(SETUPS)
    data, truth = iwr.simulate(robot, 24, seed=3, noise=NOISE)
    return robot, data, truth


def _points(problem: BallbarProblem, n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(problem.lower, problem.upper,
                                               (n, problem.n_params))


def test_the_cpp_residuals_are_the_numpy_ones(case) -> None:
    """At random points within the bounds, unweighted and noise-weighted: the C++ objective's
    residuals agree with BallbarProblem's NumPy ones to 1e-12 of the largest (measured: ~1e-15),
    its cost with theirs; the same bits from 1, 2 or 3 threads, and row by row."""
    robot, data, _ = case
    plain, start = ballbar_problem(robot, data)
    weighted = weighted_problem(plain, start, NOISE)
    assert weighted.whitening.shape == (len(data), 1, 1) and plain.whitening is None
    X = _points(plain, 6, 1)
    for problem in (plain, weighted):
        for x in X:
            py = problem.residuals(x)
            cpp = problem.objective.residuals(x)
            assert np.max(np.abs(cpp - py)) <= 1e-12 * np.max(np.abs(py)), problem
            assert abs(problem.cost(x) - py @ py) <= 1e-12 * (py @ py)
        costs = [problem.cost_batch(X, workers=w) for w in (1, 2, 3)]
        np.testing.assert_array_equal(costs[0], costs[1])
        np.testing.assert_array_equal(costs[0], costs[2])
        np.testing.assert_array_equal(costs[0], [problem.cost(x) for x in X])
    # The weighting is the reading sigmas': residual k over sigma_k.
    np.testing.assert_allclose(weighted.objective.residuals(X[0]),
                               plain.objective.residuals(X[0]) * weighted.weights, rtol=1e-15)


def test_the_kernel_variants_give_the_same_distances(case) -> None:
    """The distances run on the tracker kernel's platform frames: AVX2 and AVX-512 (fused
    multiply-adds) give the same bits; the SSE2 baseline (no FMA) the same to rounding: within
    2e-10 mm in a distance (the review measured 1.1e-10 at most: the frames differ by 2e-12 mm,
    magnified by the distance's cancellation) and 1e-10 relative in the costs at random points
    (measured 3.9e-12)."""
    robot, data, _ = case
    plain, start = ballbar_problem(robot, data)
    X = _points(plain, 6, 2)
    before = _core._active_kernel()
    out = {}
    try:
        for v in _core._supported_kernels():
            _core._select_kernel(v)
            out[v] = (np.array([plain.objective.residuals(x) for x in X]),
                      plain.cost_batch(X, workers=2))
    finally:
        _core._select_kernel(before)
    fused = [v for v in out if v != "baseline"]
    for v in fused[1:]:
        for a, b in zip(out[v], out[fused[0]], strict=True):
            np.testing.assert_array_equal(a, b)
    for v in fused:
        np.testing.assert_allclose(out["baseline"][0], out[v][0], rtol=0, atol=2e-10)
        np.testing.assert_allclose(out["baseline"][1], out[v][1], rtol=1e-10)


def test_a_failed_pose_is_the_penalty_in_both(case) -> None:
    robot, data, _ = case
    problem, _ = ballbar_problem(robot, data)
    x = np.zeros(problem.n_params)
    x[robot.parameter_names.index("leg1.dl0")] = -2000.0  # no pose closes
    np.testing.assert_array_equal(problem.objective.residuals(x), problem.residuals(x))
    assert problem.cost(x) == len(data) * 1e6
    assert len(problem.failures(x)) == len(data)


def test_weighted_problem_file_round_trip(case, tmp_path: Path) -> None:
    """The noise-weighted problem saved and loaded: the same problem (its data, set-ups, weights
    and noise text), its cost bit for bit, and the engine's objective (make_objective) too."""
    robot, data, _ = case
    plain, start = ballbar_problem(robot, data)
    problem = weighted_problem(plain, start, NOISE)
    problem.save(tmp_path / "w.iwrp")
    back = BallbarProblem.load(tmp_path / "w.iwrp")
    assert back.setup == problem.setup and back.robot.instruments["ballbar"] == problem.setup
    np.testing.assert_array_equal(back.weights, problem.weights)
    np.testing.assert_array_equal(back.measurements.setup, data.setup)
    d = read_problem(tmp_path / "w.iwrp")
    assert d["kind"] == "ballbar" and d["weighting"][1].shape == (len(data), 1)
    assert "BallbarNoise(distance=0.001)" in d["weighting"][0]
    assert d["data_fingerprint"] == kinds.of(data).fingerprint(robot, data)
    X = _points(problem, 5, 2)
    np.testing.assert_array_equal(back.cost_batch(X), problem.cost_batch(X))
    np.testing.assert_array_equal(_core._engine_costs(str(tmp_path / "w.iwrp"), X),
                                  problem.cost_batch(X))
    # Weighted and unweighted are two objectives of the same data.
    plain.save(tmp_path / "p.iwrp")
    p = read_problem(tmp_path / "p.iwrp")
    assert p["data_fingerprint"] == d["data_fingerprint"]
    assert p["robot_fingerprint"] != d["robot_fingerprint"]
    pose = iwr.Robot.default()
    iwr.Problem(pose, iwr.simulate(pose, 5, seed=1)[0]).save(tmp_path / "pose.iwrp")
    with pytest.raises(_core.FormatError,
                       match=r"pose.iwrp: holds leg data \(poses in \{0\}\), not ballbar data"):
        BallbarProblem.load(tmp_path / "pose.iwrp")


def test_the_data_fingerprint_ignores_the_order_of_the_set_ups(case) -> None:
    """Each pose's set-up is hashed by name: the data file's fingerprint is the same for a robot
    file listing its set-ups in another order; a moved reading changes it."""
    robot, data, _ = case
    kind = kinds.of(data)
    swapped = ballbar_robot(dict(reversed(SETUPS.items())))
    assert kind.fingerprint(swapped, data) == kind.fingerprint(robot, data)
    moved = iwr.ballbar.BallbarMeasurements(data.q, data.legs, data.setup,
                                            data.distance + np.eye(len(data))[4] * 1e-6,
                                            joint_types=data.joint_types)
    assert kind.fingerprint(robot, moved) != kind.fingerprint(robot, data)


# --- iwr-calibrate, iwr-engine and iwr report on ballbar files ---------------------------------

def _run(*args: object, prog: str) -> subprocess.CompletedProcess[str]:
    environ = {k: v for k, v in os.environ.items() if not k.startswith("IWR_")}
    cmd = [str(BIN / prog)] if prog != "iwr" else [sys.executable, "-m", "iwr"]
    return subprocess.run([*cmd, *map(str, args)], capture_output=True, text=True, timeout=600,
                          check=False, cwd=tempfile.gettempdir(), env=environ)


@pytest.fixture(scope="module")
def files(case, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    robot, data, _ = case
    d = tmp_path_factory.mktemp("bbengine")
    robot.to_toml(d / "robot.toml")
    data.to_csv(d / "bb.csv")
    other = iwr.ballbar.BallbarMeasurements(data.q, data.legs, data.setup,
                                            data.distance + np.eye(len(data))[0] * 1e-3,
                                            joint_types=data.joint_types)
    other.to_csv(d / "other.csv")
    return {"dir": d, "robot": d / "robot.toml", "data": d / "bb.csv", "other": d / "other.csv"}


DE = {"strategy": "jade", "population_size": 20, "generations": 40, "seed": 4}
DE_ARGS = ["--strategy", "jade", "--population-size", 20, "--generations", 40, "--seed", 4]


def _same_run(a: iwr.IdentificationResult, b: iwr.IdentificationResult) -> None:
    np.testing.assert_array_equal(a.x, b.x)
    assert a.fun == b.fun and (a.nfev, a.nit) == (b.nfev, b.nit)
    for key in ("generation", "nfev", "best", "mean", "spread"):
        np.testing.assert_array_equal(a.history[key], b.history[key], err_msg=key)


@pytest.mark.parametrize("noise", [None, "realistic"])
def test_iwr_calibrate_equals_identify(files: dict[str, Path], noise: str | None) -> None:
    """iwr-calibrate ROBOT.toml DATA.csv on ballbar data, unweighted and --noise realistic: the
    engine's DE run equals iwr.identify(method="de") with the same settings bit for bit (x, cost,
    evaluations, the per-generation log); its problem file loads as a BallbarProblem whose cost
    at x is the result's."""
    out = files["dir"] / f"run-{noise}.json"
    extra = [] if noise is None else ["--noise", noise]
    proc = _run(files["robot"], files["data"], *DE_ARGS, "--threads", 2, "--output", out, *extra,
                prog="iwr-calibrate")
    assert proc.returncode == 0, proc.stderr
    assert f"{58 + 14} parameters, 14 of them the ballbar set-ups', 24 poses (ballbar " \
           "distances)" in proc.stderr
    exe = iwr.load_result(out)
    robot = iwr.Robot.from_toml(files["robot"])
    kind = kinds.for_robot(robot)
    data = kind.read(files["data"], robot)
    weights = None if noise is None else kind.reading_noise(iwr.Noise.realistic())
    py = iwr.identify(robot, data, "de", polish=False, progress=False, workers=1, noise=weights,
                      **DE)
    _same_run(exe, py)
    problem = iwr.Problem.load(out.with_suffix(".json.iwrp"))
    assert isinstance(problem, BallbarProblem) and (problem.whitening is None) == (noise is None)
    assert exe.fun == problem.cost(exe.x) and exe.parameter_names == problem.parameter_names
    assert exe.settings["measurements"] == "ballbar"


def test_iwr_report_accepts_the_runs_data_and_refuses_another(files: dict[str, Path]) -> None:
    """One fingerprint scheme: the engine's (the problem file's) is the one iwr report computes
    from the data file."""
    out = files["dir"] / "rep.json"
    proc = _run(files["robot"], files["data"], "--generations", 3, "--population-size", 20,
                "--output", out, "-q", prog="iwr-calibrate")
    assert proc.returncode == 0, proc.stderr
    fp = iwr.load_result(out).settings["data_fingerprint"]
    assert fp == read_problem(out.with_suffix(".json.iwrp"))["data_fingerprint"]
    bad = _run("report", out, files["robot"], files["other"], "--out", files["dir"] / "bad",
               "--no-plots", prog="iwr")
    assert bad.returncode == 2 and "Traceback" not in bad.stderr, bad.stderr
    assert f"{files['other']} is not the data {out} was identified from" in bad.stderr
    assert not (files["dir"] / "bad").exists()
    good = _run("report", out, files["robot"], files["data"], "--out", files["dir"] / "good",
                "--no-plots", prog="iwr")
    assert good.returncode != 2 and "Traceback" not in good.stderr, good.stderr
    assert "records no fingerprint" not in (files["dir"] / "good" / "report.md").read_text()


def test_the_engine_alone_on_a_saved_problem(case, files: dict[str, Path]) -> None:
    """iwr-engine on a problem file saved by BallbarProblem.save with parameters held (one
    set-up's balls and offset at x0): it searches the others only, and its checkpoint converts
    with the set-ups' parameter names and the problem's cost."""
    robot, data, _ = case
    problem, _ = ballbar_problem(robot, data)
    x0 = np.zeros(problem.n_params)
    x0[-7:] = 0.01
    active = np.ones(problem.n_params, dtype=bool)
    active[-7:] = False
    path = files["dir"] / "alone.iwrp"
    problem.save(path, x0=x0, active=active)
    ckpt = files["dir"] / "alone.ckpt"
    proc = _run(path, "--generations", 2, "--population-size", 16, "--seed", 1,
                "--checkpoint", ckpt, prog="iwr-engine")
    assert proc.returncode == 0, proc.stderr
    assert "72 parameters, 14 of them the ballbar set-ups' (65 active)" in proc.stderr
    res = engine_result(ckpt, path)
    assert res.parameter_names[-7:] == [f"ballbar.B.{f}" for f in
                                        ("px", "py", "pz", "fx", "fy", "fz", "offset")]
    np.testing.assert_array_equal(res.x[-7:], x0[-7:])
    assert res.fun == problem.cost(res.x)
