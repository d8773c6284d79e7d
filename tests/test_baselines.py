"""The baselines (NLopt CRS2 and BOBYQA, Levenberg-Marquardt): recovery, budgets, re-evaluated
costs, seeds, bounds, Ctrl-C and argument checks."""

from __future__ import annotations

import os
import signal
import threading

import nlopt
import numpy as np
import pytest

import iwr
from iwr.identify import METHODS

BASELINES = ["lm", "crs2", "bobyqa"]


@pytest.fixture(scope="module")
def robot() -> iwr.Robot:
    return iwr.Robot.default()


@pytest.fixture(scope="module")
def data(robot):
    """Noise-free data of 30 poses and the true errors."""
    return iwr.simulate(robot, n_poses=30, seed=5)


@pytest.fixture(scope="module")
def validation(robot, data):
    """Fresh poses of the same actual robot, exact readings."""
    _, truth = data
    m, _ = iwr.simulate(robot, n_poses=40, seed=77, x=truth)
    return m


@pytest.fixture(scope="module")
def subset(robot, data):
    """12 parameters (leg offsets and the z of the base joints), the others held at the truth:
    identifiable, and small enough for the derivative-free methods to converge in a test."""
    _, truth = data
    names = robot.parameter_names
    active = np.array([n.endswith(".dl0") or n.endswith(".da_z") for n in names])
    x0 = truth.copy()
    x0[active] = 0.0
    return active, x0


def validation_rms(robot, x, m) -> float:
    return float(np.sqrt(np.mean((iwr.predict_legs(robot, x, m.q, m.poses) - m.legs) ** 2)))


def test_methods_are_registered():
    assert {"lm", "crs2", "bobyqa"} <= set(METHODS)


# Expected accuracy from the near start (noise-free): cost, largest parameter error, validation RMS.
@pytest.mark.parametrize(
    "method, options, max_cost, max_param_err, max_val_rms",
    [
        ("bobyqa", {"max_evaluations": 5000}, 1e-16, 1e-6, 1e-7),
        ("crs2", {"max_evaluations": 30000}, 1e-9, 1e-3, 1e-4),
        ("lm", {}, 1e-16, 1e-6, 1e-7),
    ],
)
def test_recovers_noise_free_subset(robot, data, validation, subset, method, options, max_cost,
                                    max_param_err, max_val_rms):
    m, truth = data
    active, x0 = subset
    # (CRS2 is stochastic: with some seeds its population collapses early, e.g. seed 3 stalls at
    # a cost of 2e-3 with this budget; seeds 0, 1, 2 all reach 1e-11.)
    res = iwr.identify(robot, m, method, x0=x0, active=active, seed=0, progress=False, **options)
    assert res.fun < max_cost
    assert np.max(np.abs(res.x - truth)) < max_param_err
    assert validation_rms(robot, res.x, validation) < max_val_rms
    # inactive parameters stay where they were put
    np.testing.assert_array_equal(res.x[~active], x0[~active])


def test_lm_recovers_all_58_despite_rank_deficiency(robot, data, validation):
    m, truth = data
    jac = iwr.Problem(robot, m).jacobian(truth)
    assert np.linalg.matrix_rank(jac / np.linalg.norm(jac, axis=0)) < 58  # really rank deficient
    res = iwr.identify(robot, m, "lm", progress=False)
    assert res.success and res.fun < 1e-16
    assert validation_rms(robot, res.x, validation) < 1e-7
    # The regularisation keeps the unidentifiable combinations near the start: no sliding away.
    assert np.max(np.abs(res.x)) < 5.0
    assert res.nfev < 300


def test_lm_with_fewer_readings_than_parameters(robot):
    m, _ = iwr.simulate(robot, n_poses=5, seed=2)  # 30 readings, 58 parameters
    res = iwr.identify(robot, m, "lm", progress=False)
    assert res.fun < 1e-12
    with pytest.raises(ValueError, match="residuals"):
        iwr.identify(robot, m, "lm", regularization=0.0)


@pytest.mark.parametrize("method", BASELINES)
@pytest.mark.parametrize("budget", [7, 150])
def test_budget_is_respected(robot, data, method, budget, monkeypatch):
    m, _ = data
    calls = {"n": 0}
    seen = []
    problem_cls = iwr.Problem

    def counting(name, weight=lambda args: 1):
        orig = getattr(problem_cls, name)

        def wrapper(self, *args, **kw):
            calls["n"] += weight(args)
            return orig(self, *args, **kw)

        monkeypatch.setattr(problem_cls, name, wrapper)

    for name in ("cost", "residuals", "jacobian", "residuals_and_jacobian"):
        counting(name)
    counting("cost_batch", lambda args: len(args[0]))
    res = iwr.identify(robot, m, method, max_evaluations=budget, seed=1, progress=False,
                       callback=lambda x, c: seen.append(c))
    assert res.nfev <= budget
    assert np.max(res.history["nfev"]) <= budget
    # Independent count of the objective calls: the budget, plus at most three re-evaluations of
    # returned points (the method's and identify()'s), never more.
    assert calls["n"] <= budget + 3
    assert len(seen) <= budget
    assert "budget" in res.message or res.nfev < budget


@pytest.mark.parametrize("method", BASELINES)
def test_fun_is_the_cost_at_x(robot, data, method):
    m, _ = data
    res = iwr.identify(robot, m, method, max_evaluations=400, seed=2, progress=False)
    assert res.fun == iwr.Problem(robot, m).cost(res.x)
    if method != "lm":
        # The NLopt methods return the best point seen: the history ends at the returned cost.
        # (LM returns its last iterate, of the regularised problem: within round-off of the best.)
        assert res.history["best"][-1] == res.fun


def test_returned_point_is_the_best_seen(robot, data, monkeypatch):
    """If NLopt returns a worse point than one it evaluated, the best one is returned."""
    m, _ = data
    original = nlopt.opt.optimize

    def worse(self, x0):
        original(self, x0)
        return np.asarray(x0) + 0.3 * (self.get_upper_bounds() - np.asarray(x0))

    monkeypatch.setattr(nlopt.opt, "optimize", worse)
    seen = []
    res = iwr.identify(robot, m, "bobyqa", max_evaluations=300, progress=False,
                       callback=lambda x, c: seen.append(c))
    assert res.fun == pytest.approx(min(seen), rel=1e-12)
    assert "best seen was better" in res.message


@pytest.mark.parametrize("method", ["crs2", "bobyqa"])
def test_same_seed_same_answer(robot, data, method):
    m, _ = data
    a = iwr.identify(robot, m, method, max_evaluations=1500, seed=11, progress=False)
    b = iwr.identify(robot, m, method, max_evaluations=1500, seed=11, progress=False)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.history["best"], b.history["best"])
    if method == "crs2":
        c = iwr.identify(robot, m, method, max_evaluations=1500, seed=12, progress=False)
        assert not np.array_equal(a.x, c.x)
    assert a.settings["seed"] == 11


@pytest.mark.parametrize("method", ["crs2", "bobyqa"])
def test_bounds_and_clipped_start(robot, data, method):
    m, _ = data
    problem = iwr.Problem(robot, m)
    x0 = np.full(58, 3.0)  # far outside the bounds (+-0.5 mm, +-0.0087 rad)
    res = iwr.identify(robot, m, method, x0=x0, max_evaluations=800, seed=0, progress=False)
    assert np.all(res.x >= problem.lower) and np.all(res.x <= problem.upper)
    assert res.settings["x0_clipped_to_bounds"] == 58


@pytest.mark.parametrize("method", BASELINES)
def test_keyboard_interrupt_in_callback_returns_best_so_far(robot, data, method):
    m, _ = data
    seen = []

    def callback(x, c):
        seen.append(c)
        if len(seen) == 20:
            raise KeyboardInterrupt

    res = iwr.identify(robot, m, method, max_evaluations=10_000, seed=0, progress=False,
                       callback=callback)
    assert "interrupted" in res.message and not res.success
    assert res.nfev <= 2 * len(seen) + 1  # LM: a Jacobian per residual evaluation at most
    assert res.fun == pytest.approx(min(seen), rel=1e-12)


def test_real_sigint_stops_crs2_cleanly(robot, data, sigint_handler):
    """A real SIGINT, delivered asynchronously while CRS2 runs, ends the run with the best point."""
    m, _ = data
    timer = []

    def callback(x, c):
        if not timer:  # the run is under way: send Ctrl-C shortly
            t = threading.Timer(0.2, os.kill, (os.getpid(), signal.SIGINT))
            t.start()
            timer.append(t)

    res = iwr.identify(robot, m, "crs2", max_evaluations=3 * 10**6, seed=0, progress=False,
                       callback=callback)
    timer[0].join()
    assert "interrupted" in res.message
    assert 1 < res.nfev < 3 * 10**6
    assert res.fun == iwr.Problem(robot, m).cost(res.x)


def test_callback_true_stops(robot, data):
    m, _ = data
    res = iwr.identify(robot, m, "crs2", max_evaluations=5000, seed=0, progress=False,
                       callback=lambda x, c: True)
    assert res.nfev == 1 and "callback" in res.message


@pytest.mark.parametrize(
    "method, options, name",
    [
        ("crs2", {"max_evaluations": 0}, "max_evaluations"),
        ("crs2", {"max_evaluations": 2.5}, "max_evaluations"),
        ("crs2", {"population": 10}, "population"),
        ("crs2", {"xtol": -1.0}, "xtol"),
        ("crs2", {"ftol": float("nan")}, "ftol"),
        ("crs2", {"seed": -3}, "seed"),
        ("bobyqa", {"initial_step": 0.0}, "initial_step"),
        ("bobyqa", {"initial_step": 0.8}, "initial_step"),
        ("bobyqa", {"stopval": "low"}, "stopval"),
        ("lm", {"regularization": -1.0}, "regularization"),
        ("lm", {"regularization": "on"}, "regularization"),
        ("lm", {"max_evaluations": 1}, "max_evaluations"),
        ("lm", {"max_nfev": 0}, "max_nfev"),
    ],
)
def test_bad_arguments_name_the_argument(robot, data, method, options, name):
    m, _ = data
    with pytest.raises(ValueError, match=name):
        iwr.identify(robot, m, method, progress=False, **options)


def test_progress_bar_runs(robot, data, capsys):
    m, _ = data
    res = iwr.identify(robot, m, "crs2", max_evaluations=1200, seed=0, progress=True)
    assert res.nfev == 1200
    assert "crs2" in capsys.readouterr().err
