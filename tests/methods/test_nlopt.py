"""The NLopt baselines (CRS2, BOBYQA): recovery, the best point seen, seeds, bounds, a real SIGINT
and argument checks."""

from __future__ import annotations

import os
import signal
import threading

import nlopt
import numpy as np
import pytest

import iwr

from .conftest import validation_rms


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


@pytest.mark.parametrize("method", ["crs2", "bobyqa"])
def test_history_ends_at_the_returned_cost(robot, data, method):
    m, _ = data
    res = iwr.identify(robot, m, method, max_evaluations=400, seed=2, progress=False)
    # The NLopt methods return the best point seen: the history ends at the returned cost.
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
                       callback=lambda r: seen.append(r.fun))
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


def test_real_sigint_stops_crs2_cleanly(robot, data, sigint_handler):
    """A real SIGINT, delivered asynchronously while CRS2 runs, ends the run with the best point."""
    m, _ = data
    timer = []

    def callback(r):
        if not timer:  # the run is under way: send Ctrl-C shortly
            t = threading.Timer(0.2, os.kill, (os.getpid(), signal.SIGINT))
            t.start()
            timer.append(t)

    res = iwr.identify(robot, m, "crs2", max_evaluations=3 * 10**6, seed=0, progress=False,
                       callback=callback)
    timer[0].join()
    assert res.interrupted and "interrupted" in res.message and not res.success
    assert 1 < res.nfev < 3 * 10**6
    assert res.fun == iwr.Problem(robot, m).cost(res.x)


@pytest.mark.parametrize(
    "method, options, name",
    [
        ("crs2", {"population": 10}, "population"),
        ("crs2", {"xtol": -1.0}, "xtol"),
        ("crs2", {"ftol": float("nan")}, "ftol"),
        ("crs2", {"seed": -3}, "seed"),
        ("bobyqa", {"initial_step": 0.0}, "initial_step"),
        ("bobyqa", {"initial_step": 0.8}, "initial_step"),
        ("bobyqa", {"stopval": "low"}, "stopval"),
    ],
)
def test_bad_arguments_name_the_argument(robot, data, method, options, name):
    m, _ = data
    with pytest.raises(ValueError, match=name):
        iwr.identify(robot, m, method, progress=False, **options)


@pytest.mark.parametrize(
    "method, options, shown",
    [
        ("crs2", {"max_evaluations": 2**40}, "max_evaluations: 1099511627776; "),
        ("bobyqa", {"max_evaluations": 2**31}, "max_evaluations: 2147483648; "),
        ("crs2", {"max_evaluations": 50, "population": 2**40}, "population: 1099511627776; "),
    ],
)
def test_integers_beyond_nlopts_int_are_named(robot, data, method, options, shown):
    """NLopt takes the budget as a C int: a larger one was an OverflowError from its wrapper
    ("in method 'opt_set_maxeval', argument 2 of type 'int'"), not naming the argument."""
    m, _ = data
    with pytest.raises(ValueError) as info:
        iwr.identify(robot, m, method, progress=False, **options)
    msg = str(info.value)
    assert msg.startswith(shown) and msg.endswith(" to 2147483647") and "\n" not in msg, msg


def test_progress_bar_counts_evaluations_against_the_budget(robot, data, capsys):
    m, _ = data
    res = iwr.identify(robot, m, "crs2", max_evaluations=1200, seed=0, progress=True)
    assert res.nfev == 1200
    err = capsys.readouterr().err
    assert "crs2" in err and "/1.20k" in err  # evaluations against the budget
