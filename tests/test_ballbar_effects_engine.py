"""Ballbar data with effects in the C++ core and the engine (issue 23): the C++ objective
(``cpp/include/iwr/effects_ballbar.hpp``, ``_core.BallbarEffectObjective``) against
:class:`iwr.ballbar.effects.BallbarEffectProblem`'s numpy residuals (within the bounds, at them,
failing poses, weighted and not, 1 and 2 threads), the problem file (round trip, what the engine
builds from it, a damaged file refused), and ``iwr-calibrate`` on a ballbar robot with effects
against ``iwr.identify(method="de")`` bit for bit."""

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
from iwr.ballbar import effects as be
from iwr.ballbar import write_ballbar
from iwr.effects import api
from iwr.effects import parameter_names as effect_names
from iwr.effects.tracker_study import PAYLOADS
from iwr.problem_file import read_problem

BARS = with_offset(0.3)
BIN = Path(sys.executable).parent


def _robot(carriage: bool) -> iwr.Robot:
    plain = ballbar_robot(BARS)
    return plain.with_effects(*api.realistic(plain, carriage=carriage))


@pytest.fixture(scope="module", params=[False, True], ids=["legs", "carriage"])
def case(request) -> tuple[iwr.Robot, object, np.ndarray]:
    """The legs' compliance and temperature (and the carriage's compliance): 14 noisy poses
    under three payloads, the truth."""
    robot = _robot(request.param)
    data, truth = be.simulate(robot, 14, seed=3, payloads=PAYLOADS, noise=NOISE)
    return robot, data, truth


def test_the_cpp_residuals_are_the_numpy_ones(case) -> None:
    """At random points within the bounds, at the bounds and at the truth, unweighted and
    noise-weighted: the C++ residuals agree with the numpy ones to 1e-9 mm (each solves the
    forward kinematics with the effects by its own Newton iterations to 1e-11 mm in the legs;
    measured: 3e-11), the cost with theirs; the batch costs are the same bits from 1 and 2
    threads, and row by row."""
    robot, data, truth = case
    plain, start = be.effect_problem(robot, data)
    weighted, _ = be.effect_problem(robot, data, noise=NOISE)
    assert weighted.whitening.shape == (len(data), 1, 1) and plain.whitening is None
    assert plain.objective.n_params == plain.n_params == robot.n_params + plain.n_effects + 14
    rng = np.random.default_rng(1)
    X = np.vstack([rng.uniform(plain.lower, plain.upper, (3, plain.n_params)), plain.lower,
                   plain.upper, truth])
    for problem in (plain, weighted):
        assert problem.objective.whitened == (problem is weighted)
        atol = 1e-9 * problem.weights.max()  # mm, weighted
        for x in X:
            py = problem.residuals(x)
            cpp = problem.objective.residuals(x)
            np.testing.assert_allclose(cpp, py, rtol=0, atol=atol)
            # |cost - py @ py| <= 2 |r| |dr| + |dr|^2, |dr| <= sqrt(N) atol
            dr = np.sqrt(py.size) * atol
            assert abs(problem.cost(x) - py @ py) <= 2 * np.sqrt(py @ py) * dr + dr * dr
        costs = [problem.cost_batch(X, workers=w) for w in (1, 2)]
        np.testing.assert_array_equal(costs[0], costs[1])
        np.testing.assert_array_equal(costs[0], [problem.cost(x) for x in X])
    np.testing.assert_allclose(weighted.objective.residuals(X[0]),
                               plain.objective.residuals(X[0]) * weighted.weights, rtol=1e-15)


def test_failed_poses_are_the_penalty_in_both(case) -> None:
    """A leg two metres short: no pose closes; both objectives give each pose the penalty (times
    its weight) and name every pose."""
    robot, data, _ = case
    problem, _ = be.effect_problem(robot, data, noise=NOISE)
    x = np.zeros(problem.n_params)
    x[problem.parameter_names.index("leg1.dl0")] = -2000.0
    np.testing.assert_array_equal(problem.objective.residuals(x), problem.residuals(x))
    np.testing.assert_array_equal(problem.residuals(x), 1e3 * problem.weights)
    assert [k for k, _ in problem.objective.failures(x)] == list(range(len(data)))
    assert len(problem.failures(x)) == len(data)


def test_a_singular_pose_is_a_failed_pose_not_an_abort(case, singular_at) -> None:
    """A robot at which the hexapod is singular at one pose (LM from iwr compare's bad start:
    ValueError "the legs cannot hold a load" stopped it): that pose gets the penalty, as in
    the C++ objective, the other residuals are unchanged, and failures() names it."""
    robot, data, truth = case
    problem, _ = be.effect_problem(robot, data)
    before = problem.residuals(truth)
    singular_at(len(data), 5)
    after = problem.residuals(truth)
    assert after[5] == 1e3
    np.testing.assert_array_equal(np.delete(after, 5), np.delete(before, 5))
    assert [k for k, _ in problem.failures(truth)] == [5]


def test_problem_file_round_trip(case, tmp_path: Path) -> None:
    """Saved and loaded (weighted and not): the same problem (robot, effects, set-ups, loads,
    temperatures, weights), its cost bit for bit, the engine's objective (make_objective) too;
    the data fingerprint the kind computes from the data file; the effects make another robot
    fingerprint of the same data."""
    robot, data, _ = case
    plain, start = be.effect_problem(robot, data)
    weighted, _ = be.effect_problem(robot, data, noise=NOISE)
    X = np.random.default_rng(2).uniform(plain.lower, plain.upper, (4, plain.n_params))
    for name, problem in (("p", plain), ("w", weighted)):
        path = tmp_path / f"{name}.iwrp"
        problem.save(path)
        back = iwr.Problem.load(path)
        assert isinstance(back, be.BallbarEffectProblem)
        assert back.setup == problem.setup and back.parameter_names == problem.parameter_names
        assert [e.to_dict() for e in back.robot.effects] == [e.to_dict()
                                                             for e in robot.effects]
        np.testing.assert_array_equal(back.measurements.payload, data.payload)
        np.testing.assert_array_equal(back.measurements.temperatures, data.temperatures)
        np.testing.assert_array_equal(back.weights, problem.weights)
        np.testing.assert_array_equal(back.cost_batch(X), problem.cost_batch(X))
        np.testing.assert_array_equal(_core._engine_costs(str(path), X), problem.cost_batch(X))
        d = read_problem(path)
        assert d["kind"] == "ballbar" and d["version"] == 4 and d["tracker_gravity"] is None
        assert d["data_fingerprint"] == kinds.of(data).fingerprint(robot, data)
    p, w = read_problem(tmp_path / "p.iwrp"), read_problem(tmp_path / "w.iwrp")
    assert p["data_fingerprint"] == w["data_fingerprint"]
    assert p["robot_fingerprint"] != w["robot_fingerprint"]
    geometric = iwr.ballbar.BallbarProblem(robot.with_effects(), plain.setup, data)
    geometric.save(tmp_path / "g.iwrp")
    g = read_problem(tmp_path / "g.iwrp")
    assert g["robot_fingerprint"] != p["robot_fingerprint"]
    assert len(g["lower"]) == plain.n_params - plain.n_effects


def test_a_damaged_problem_file_is_refused_naming_it(case, tmp_path: Path) -> None:
    """A truncated file and one with a flipped byte: Problem.load and iwr-engine refuse them
    with a message naming the file, never a traceback."""
    robot, data, _ = case
    problem, _ = be.effect_problem(robot, data)
    good = tmp_path / "good.iwrp"
    problem.save(good)
    raw = good.read_bytes()
    short, flipped = tmp_path / "short.iwrp", tmp_path / "flipped.iwrp"
    short.write_bytes(raw[: len(raw) - 40])
    flipped.write_bytes(raw[:-100] + bytes([raw[-100] ^ 0x5A]) + raw[-99:])
    for path in (short, flipped):
        with pytest.raises(_core.FormatError, match=str(path.name)):
            iwr.Problem.load(path)
        proc = _run(path, "--generations", 1, "--checkpoint", tmp_path / "x.ckpt",
                    prog="iwr-engine")
        assert proc.returncode != 0 and path.name in proc.stderr, proc.stderr
        assert "Traceback" not in proc.stderr


# --- iwr-calibrate on a ballbar robot with effects ----------------------------------------------

def _run(*args: object, prog: str) -> subprocess.CompletedProcess[str]:
    environ = {k: v for k, v in os.environ.items() if not k.startswith("IWR_")}
    return subprocess.run([str(BIN / prog), *map(str, args)], capture_output=True, text=True,
                          timeout=600, check=False, cwd=tempfile.gettempdir(), env=environ)


DE = {"strategy": "jade", "population_size": 20, "generations": 6, "seed": 4}
DE_ARGS = ["--strategy", "jade", "--population-size", 20, "--generations", 6, "--seed", 4]


@pytest.mark.parametrize("noise", [None, "realistic"])
def test_iwr_calibrate_equals_identify(case, tmp_path: Path, noise: str | None) -> None:
    """iwr-calibrate ROBOT.toml DATA.csv on ballbar data with effects (a short DE run),
    unweighted and --noise realistic: the engine's run equals iwr.identify(method="de") with the
    same settings bit for bit (x, cost, evaluations, the per-generation log); its problem file
    loads as a BallbarEffectProblem whose cost at x is the result's."""
    robot, data, _ = case
    robot.to_toml(tmp_path / "robot.toml")
    write_ballbar(tmp_path / "bb.csv", data)
    out = tmp_path / "run.json"
    extra = [] if noise is None else ["--noise", noise]
    proc = _run(tmp_path / "robot.toml", tmp_path / "bb.csv", *DE_ARGS, "--threads", 2,
                "--output", out, *extra, prog="iwr-calibrate")
    assert proc.returncode == 0, proc.stderr
    back = iwr.Robot.from_toml(tmp_path / "robot.toml")
    kind = kinds.for_robot(back)
    ne = len(effect_names(back.effects))
    assert f"{58 + ne + 14} parameters, {ne} of them the effects', 14 the ballbar set-ups'" \
        in proc.stderr, proc.stderr
    exe = iwr.load_result(out)
    read = kind.read(tmp_path / "bb.csv", back)
    weights = None if noise is None else kind.reading_noise(iwr.Noise.realistic())
    py = iwr.identify(back, read, "de", polish=False, progress=False, workers=1, noise=weights,
                      **DE)
    np.testing.assert_array_equal(exe.x, py.x)
    assert exe.fun == py.fun and (exe.nfev, exe.nit) == (py.nfev, py.nit)
    for key in ("generation", "nfev", "best", "mean", "spread"):
        np.testing.assert_array_equal(exe.history[key], py.history[key], err_msg=key)
    problem = iwr.Problem.load(out.with_suffix(".json.iwrp"))
    assert isinstance(problem, be.BallbarEffectProblem)
    assert (problem.whitening is None) == (noise is None)
    assert exe.fun == problem.cost(exe.x) and exe.parameter_names == problem.parameter_names
    assert exe.settings["measurements"] == "ballbar"


def test_a_result_of_another_size_is_refused_naming_the_ballbar_set_ups(case) -> None:
    """iwr report of a run whose parameters are not the robot's: the message counts the effects'
    and the ballbar set-ups' parameters, and names them so (it said "its tracker setup")."""
    from types import SimpleNamespace

    from iwr.calibration import from_result

    robot, data, _ = case
    n = 58 + len(effect_names(robot.effects)) + 14
    with pytest.raises(ValueError, match=rf"^3 parameters, but robot 'IWR' with its effects and "
                                         rf"its ballbar set-ups has {n}$"):
        from_result(robot, data, SimpleNamespace(x=np.zeros(3), parameter_names=[]))


# --- iwr compare and iwr study on a ballbar robot with effects -----------------------------------

def test_compare_methods_draws_and_identifies_the_effects() -> None:
    """iwr.compare_methods on a ballbar robot with effects (it failed on every robot with
    effects, pose, tracker and ballbar data: its actual robot lacked the effects' parameters):
    the truth has the geometric errors, the effects' parameters (within their bounds) and the
    set-ups'; DE runs on the C++ objective with the effects, and the comparison's parameter
    names are the runs' layout."""
    from iwr.effects import bounds as effect_bounds
    from iwr.experiments.harness import Scenario

    robot = _robot(False)
    ng, ne = robot.n_params, len(effect_names(robot.effects))
    truth = Scenario(80, None, kind="near").truth(robot)
    assert truth.size == ng + ne + 14
    lo, hi = effect_bounds(robot.effects)
    assert np.all((lo <= truth[ng: ng + ne]) & (truth[ng: ng + ne] <= hi))
    assert np.any(truth[ng: ng + ne] != 0)
    comp = iwr.compare_methods(robot, n_poses=80, noise="none", seeds=[0], methods=["de"],
                               budget=1600, start="near", out=None, n_validation=5,
                               progress=False)
    names = comp.settings["kind"]["parameter_names"]
    assert comp.settings["n_params"] == len(names) == ng + ne + 14
    assert names[ng: ng + ne] == effect_names(robot.effects)
    (run,) = comp.runs
    assert run["status"] == "ok", run["message"]
    assert len(run["x"]) == len(names) and np.isfinite(run["val_rms"])
    # The effects' draws come after the geometric errors': those are the same with or without.
    plain = Scenario(80, None, kind="near").truth(ballbar_robot(BARS))
    assert plain.size == ng + 14
    np.testing.assert_array_equal(plain[:ng], truth[:ng])
