"""The one method interface (``iwr.methods``): the registry, ``identify``, and what every method
shares: budget, re-evaluated cost, SciPy's callback convention, Ctrl-C, progress, finite results."""

from __future__ import annotations

import inspect

import numpy as np
import pytest
from scipy.optimize import OptimizeResult

import iwr
from iwr.methods import DEFAULT_METHOD, METHODS, IdentificationResult, ReducedProblem

# Cheap settings of each method, for the tests that only need it to run.
QUICK = {
    "lm": {},
    "de": {"population_size": 20, "generations": 5},
    "crs2": {"max_evaluations": 2000},
    "bobyqa": {"max_evaluations": 2000},
    # The efficient estimator needs a noise model (its only difference in the interface).
    "efficient": {"noise": iwr.Noise.realistic()},
}


# The methods of eq. (10): the efficient estimator minimises its own objective (``fun`` is its
# chi-square statistic), counts iterations, not evaluations, and has no progress bar (it takes
# milliseconds); tests/test_estimation.py and tests/test_estimation_wired.py cover it.
EQ10 = sorted(m for m in METHODS if m != "efficient")


def test_registry_is_explicit_and_every_method_has_the_one_call():
    assert set(METHODS) == {"lm", "de", "crs2", "bobyqa", "efficient"} == set(QUICK)
    for name, fn in METHODS.items():
        params = inspect.signature(fn).parameters
        first = next(iter(params.values()))
        assert first.kind is inspect.Parameter.POSITIONAL_OR_KEYWORD, name
        for common in ("max_evaluations", "seed", "callback", "progress"):
            assert params[common].kind is inspect.Parameter.KEYWORD_ONLY, (name, common)
        assert not {"max_nfev", "x0", "active"} & set(params), name


def test_default_method_is_lm_from_the_nominal_robot(robot, data):
    m, _ = data
    assert DEFAULT_METHOD == "lm"
    # No method named: eq. (10) without a noise model, the efficient estimator with one.
    assert inspect.signature(iwr.identify).parameters["method"].default is None
    res = iwr.identify(robot, m, progress=False)
    assert res.method == "lm" and res.success and res.status == "converged"
    assert res.fun == iwr.identify(robot, m, "lm", x0=np.zeros(58), progress=False).fun


def test_methods_take_a_reduced_problem(robot, data, subset):
    m, truth = data
    active, x0 = subset
    problem = ReducedProblem(iwr.Problem(robot, m), active, x0)
    for name, fn in METHODS.items():
        res = fn(problem, seed=0, callback=None, progress=False, **QUICK[name])
        assert isinstance(res, IdentificationResult), name
        np.testing.assert_array_equal(res.x[~active], x0[~active])


@pytest.mark.parametrize("method", sorted(METHODS))
@pytest.mark.parametrize("stop", ["np.True_", "StopIteration"])
def test_callback_stops_on_its_first_call_with_the_best_point_so_far(robot, data, method, stop):
    m, _ = data
    calls = []

    def callback(intermediate_result):
        assert isinstance(intermediate_result, OptimizeResult)
        calls.append(OptimizeResult(intermediate_result))
        if stop == "StopIteration":
            raise StopIteration
        return np.True_

    res = iwr.identify(robot, m, method, seed=0, progress=False, callback=callback,
                       **QUICK[method])
    assert len(calls) == 1
    info = calls[0]
    for key in ("x", "fun", "nfev", "nit"):
        assert key in info, key
    assert info.x.shape == (58,)
    # Stopped there: the best point so far, not a success, and said so.
    assert not res.success and res.status == "callback" and "callback" in res.message
    np.testing.assert_array_equal(res.x, info.x)
    assert res.fun == pytest.approx(info.fun, rel=1e-12)
    if method == "efficient":  # called after its first iteration; nfev counts iterations
        return
    assert res.nfev == info.nfev
    if method != "de":  # a local method's first evaluation is at the start
        assert res.nfev == 1 and np.array_equal(res.x, np.zeros(58))
    else:  # DE's first call comes after the initial population
        assert res.nit == 1 and "polish_result" not in res.settings


@pytest.mark.parametrize("method", sorted(METHODS))
def test_falsy_callback_returns_do_not_stop(robot, data, method):
    m, _ = data
    calls = []
    res = iwr.identify(robot, m, method, seed=0, progress=False,
                       callback=lambda r: calls.append(r.fun) or np.False_, **QUICK[method])
    assert len(calls) > 1 and res.status != "callback"
    assert all(b <= a for a, b in zip(calls, calls[1:], strict=False))  # the best so far


@pytest.mark.parametrize("method", EQ10)
@pytest.mark.parametrize("budget", [7, 150])
def test_budget_is_respected(robot, data, method, budget, monkeypatch):
    """``max_evaluations`` is every method's budget (DE: its evolution; lm, crs2, bobyqa: all
    of it), counted independently of the methods."""
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
    # The fit check's rank of the data (one Jacobian at the nominal robot) is not the method's.
    check = {"n": 0}
    degenerate = iwr.fit_test._degenerate

    def counted_apart(*args, **kw):
        before = calls["n"]
        try:
            return degenerate(*args, **kw)
        finally:
            check["n"] += calls["n"] - before
            calls["n"] = before

    monkeypatch.setattr(iwr.fit_test, "_degenerate", counted_apart)
    options = {"population_size": 5, "polish": False} if method == "de" else {}
    res = iwr.identify(robot, m, method, max_evaluations=budget, seed=1, progress=False,
                       callback=lambda r: seen.append(r.fun), **options)
    assert res.nfev <= budget
    assert np.max(res.history["nfev"]) <= budget
    if method != "de":  # DE evaluates in C++, out of the Python objective's sight
        # Independent count: the budget, plus at most three re-evaluations of returned points
        # (the method's and identify()'s), never more.
        assert calls["n"] <= budget + 3
        assert len(seen) <= budget
        assert check["n"] <= 2  # the data's Jacobian (and the varied poses', once a robot)
    assert res.status == "stopped" or res.nfev < budget
    assert not res.success or res.nfev < budget


@pytest.mark.parametrize("method", EQ10)
def test_fun_is_the_cost_at_x(robot, data, method):
    m, _ = data
    res = iwr.identify(robot, m, method, seed=2, progress=False,
                       **{"max_evaluations": 400, **QUICK[method]})
    assert res.fun == iwr.Problem(robot, m).cost(res.x)


@pytest.mark.parametrize("method", EQ10)  # the estimator: tests/test_estimation.py
def test_keyboard_interrupt_returns_best_so_far_marked_interrupted(robot, data, method):
    m, _ = data
    seen = []

    def callback(r):
        seen.append(r.fun)
        if len(seen) == 3:
            raise KeyboardInterrupt

    options = {"population_size": 20, "generations": 100} if method == "de" else {}
    res = iwr.identify(robot, m, method, max_evaluations=10_000, seed=0, progress=False,
                       callback=callback, **options)
    assert res.interrupted and res.status == "interrupted" and not res.success
    assert "interrupted" in res.message
    assert res.fun == pytest.approx(min(seen), rel=1e-12)
    assert len(seen) == 3


def test_keyboard_interrupt_in_the_polish(robot, data, monkeypatch):
    """Ctrl-C while DE's Levenberg-Marquardt polish runs: the better of DE's point and the
    polish's best so far, marked interrupted."""
    m, _ = data
    original = iwr.Problem.residuals
    count = {"n": 0}

    def residuals(self, x):
        count["n"] += 1
        if count["n"] == 4:
            raise KeyboardInterrupt
        return original(self, x)

    monkeypatch.setattr(iwr.Problem, "residuals", residuals)
    res = iwr.identify(robot, m, "de", population_size=20, generations=5, seed=0,
                       progress=False)
    assert res.interrupted and not res.success and "interrupted" in res.message
    assert res.fun <= res.settings["polish_result"]["fun_before"]


@pytest.mark.parametrize("method", EQ10)
def test_every_method_shows_progress(robot, data, method, capsys):
    m, _ = data
    iwr.identify(robot, m, method, seed=0, progress=True, **QUICK[method])
    err = capsys.readouterr().err
    label = "DE" if method == "de" else method
    assert label in err and ("eval" in err or "gen" in err), err
    iwr.identify(robot, m, method, seed=0, progress=False, **QUICK[method])
    assert capsys.readouterr().err == ""


def test_a_result_that_is_not_finite_is_never_a_success(robot, data, monkeypatch):
    m, _ = data
    monkeypatch.setattr(iwr.Problem, "cost", lambda self, x: float("inf"))
    res = iwr.identify(robot, m, "lm", progress=False)
    assert not res.success and res.status == "failed" and "not finite" in res.message
    direct = IdentificationResult(x=[np.nan, 0.0], fun=1.0, nfev=1, success=True, message="ok")
    assert not direct.success and direct.status == "failed"


@pytest.mark.parametrize("method", ["lm", "crs2", "bobyqa"])
def test_bad_budget_is_named(robot, data, method):
    m, _ = data
    for bad in (0, 2.5, True):
        with pytest.raises(ValueError, match="max_evaluations"):
            iwr.identify(robot, m, method, max_evaluations=bad, progress=False)


def test_unknown_method(robot, data):
    m, _ = data
    with pytest.raises(ValueError,
                       match="method: 'nope'; available: bobyqa, crs2, de, efficient, lm"):
        iwr.identify(robot, m, "nope")


def test_ctrl_c_while_identify_re_evaluates_the_cost_keeps_the_result(robot, data, monkeypatch):
    m, _ = data
    original = iwr.Problem.cost
    calls = []

    def cost(self, x):
        calls.append(1)
        if len(calls) == 2:  # LM's own final evaluation is the first; identify()'s the second
            raise KeyboardInterrupt
        return original(self, x)

    monkeypatch.setattr(iwr.Problem, "cost", cost)
    res = iwr.identify(robot, m, "lm", progress=False)
    assert res.interrupted and not res.success and len(calls) == 2
    assert res.fun == original(iwr.Problem(robot, m), res.x)


@pytest.mark.parametrize("method", sorted(QUICK))
@pytest.mark.parametrize("rows", ["one pose", "one pose 30 times", "eight poses"])
def test_data_that_cannot_identify_the_robot_are_no_success(method: str, rows: str) -> None:
    """One pose's six readings fit the 58 parameters exactly (LM said "converged", success True,
    and the "calibrated" robot was worse than the nominal on other poses); copies of it add no
    information (the efficient estimator said "converged" on 30 copies); eight poses identify 48
    of the 52 identifiable parameters. Each method's result is a failure that says why, as
    iwr.calibrate's "not calibrated" does; twelve varied poses pass (LM)."""
    robot = iwr.Robot.default()
    data, _ = iwr.simulate(robot, 30, seed=1, noise=iwr.Noise.realistic())
    sub = {"one pose": [0], "one pose 30 times": [0] * 30, "eight poses": list(range(8))}[rows]
    res = iwr.identify(robot, data.subset(sub), method, seed=0, progress=False, **QUICK[method])
    assert not res.success and not res.fit.fit_ok
    assert res.fit.verdict == "THE DATA CANNOT IDENTIFY THE ROBOT"
    distinct = 8 if rows == "eight poses" else 1
    assert res.fit.causes[0].startswith(f"degenerate data: the {distinct} distinct "
                                        "identification poses"), res.fit.causes
    if res.status != "stopped":  # a global method's QUICK budget: stopped, whatever the data
        assert res.status == "failed" and "degenerate data" in res.message, res.message
    if method == "lm" and rows == "eight poses":
        assert iwr.identify(robot, data.subset(range(12)), "lm", progress=False).success


def test_a_subset_of_the_parameters_is_judged_on_its_own() -> None:
    """Six leg offsets from six poses (36 readings): not the whole robot's identifiable set, so
    the data's rank over every parameter (36 of 52) says nothing about this fit (the review of
    the degeneracy check found it refused)."""
    robot = iwr.Robot.default()
    data, _ = iwr.simulate(robot, 6, seed=2, noise=iwr.Noise.realistic())
    active = np.array([n.endswith(".dl0") for n in robot.parameter_names])
    for method, options in (("lm", {}), ("efficient", {"noise": iwr.Noise.realistic()})):
        res = iwr.identify(robot, data, method, active=active, progress=False, **options)
        assert res.fit.verdict != "THE DATA CANNOT IDENTIFY THE ROBOT", (method, res.message)
        assert not any(c.startswith("degenerate data") for c in res.fit.causes), method


@pytest.mark.parametrize("budget, shown", [(2.5, "2.5"), (True, "True"), (2**40, "1099511627776")])
def test_efficient_budget_is_an_integer_within_its_cpp_type(robot, data, budget, shown):
    """The efficient estimator's ``max_evaluations`` (its C++ loop's ``max_iterations``, an int):
    2.5 was truncated to 2 and True taken as 1, silently; 2**40 gave pybind11's dump of the
    binding's signature. Each is a ValueError naming it."""
    m, _ = data
    with pytest.raises(ValueError, match=rf"^max_evaluations: {shown}; expected an integer from 1 "
                                         r"to 2147483647$"):
        iwr.identify(robot, m, "efficient", noise=iwr.Noise.realistic(), max_evaluations=budget,
                     progress=False)
