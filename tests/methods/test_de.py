"""Differential evolution: faithfulness to SciPy's DE/rand/1/bin, the modern strategies,
determinism, control, argument checking, and the IWR problem."""

from __future__ import annotations

import functools
import itertools
import os
import signal
import threading

import numpy as np
import pytest
from scipy import stats
from scipy.optimize import differential_evolution as scipy_de

import iwr
from iwr.methods.de import STRATEGIES

# --- test functions (vectorised over the rows of X) -----------------------------------------------


def sphere(X):
    return (X**2).sum(-1)


def rosenbrock(X):
    return (100 * (X[..., 1:] - X[..., :-1] ** 2) ** 2 + (1 - X[..., :-1]) ** 2).sum(-1)


def rastrigin(X):
    return 10 * X.shape[-1] + (X**2 - 10 * np.cos(2 * np.pi * X)).sum(-1)


# name: (function, half-width of the box, CR, generations); D = 10, NP = 50, F = 0.5 throughout.
# CR = 0 makes each trial differ from its target in exactly the forced component j_r (eq. 13).
CASES = {
    "sphere": (sphere, 5.12, 0.9, 150),
    "sphere-CR0": (sphere, 5.12, 0.0, 150),
    "rosenbrock": (rosenbrock, 5.0, 0.9, 300),
    "rastrigin": (rastrigin, 5.12, 0.9, 150),
}
D, NP, F = 10, 50, 0.5
SEEDS = range(10)


@functools.cache
def scipy_finals(case: str) -> np.ndarray:
    """log10 of SciPy's final best costs over SEEDS. SciPy's popsize multiplies D: NP = 5 * 10."""
    f, b, cr, gens = CASES[case]
    out = []
    for seed in SEEDS:
        res = scipy_de(
            lambda x: f(x.T), [(-b, b)] * D, strategy="rand1bin", popsize=NP // D, mutation=F,
            recombination=cr, maxiter=gens, updating="deferred", polish=False, init="random",
            tol=0, atol=0, rng=1000 + seed, vectorized=True,
        )
        out.append(res.fun)
    return np.log10(np.maximum(out, 1e-300))


def our_finals(case: str) -> np.ndarray:
    f, b, cr, gens = CASES[case]
    out = []
    for seed in SEEDS:
        res = iwr.differential_evolution(
            f, [(-b, b)] * D, population_size=NP, F=F, CR=cr, generations=gens, seed=seed,
            bound_rule="reinit",  # SciPy's rule, so that only the algorithm differs
        )
        assert res.nit == gens and res.nfev == NP * (gens + 1)
        out.append(res.fun)
    return np.log10(np.maximum(out, 1e-300))


def same_distribution(a: np.ndarray, b: np.ndarray) -> bool:
    """The criterion: Welch's t of the mean log10 final costs below 4 (two-sided p ~ 1e-3 under the
    null). The cases are chosen so that each broken variant below moves the mean by many standard
    errors (see test_criterion_catches_broken_variants)."""
    t = stats.ttest_ind(a, b, equal_var=False).statistic
    return bool(abs(t) < 4)


@pytest.mark.parametrize("case", list(CASES))
def test_rand1bin_matches_scipy(case):
    ours, theirs = our_finals(case), scipy_finals(case)
    assert same_distribution(ours, theirs), (case, ours.mean(), theirs.mean())


# --- the criterion's power: an independent NumPy DE/rand/1/bin, correct and deliberately broken ---


def numpy_de(f, b, cr, gens, seed, broken=None):
    """DE/rand/1/bin, deferred update, SciPy's bound rule; `broken` injects one bug."""
    rng = np.random.default_rng(seed)
    lo, hi = -b, b
    pop = lo + (hi - lo) * rng.random((NP, D))
    cost = f(pop)
    rows = np.arange(NP)
    for _ in range(gens):
        # r1, r2, r3 distinct and != i: draw from the remaining values in increasing order.
        excl = rows[:, None]
        picks = []
        for k in range(3):
            r = rng.integers(0, NP - 1 - k, NP)
            for e in np.sort(excl, axis=1).T:
                r = r + (r >= e)
            picks.append(r)
            excl = np.column_stack([excl, r])
        r1, r2, r3 = picks
        if broken == "r1=i":
            r1 = rows
        mutant = pop[r1] + F * (pop[r2] - pop[r3])
        cross = rng.random((NP, D)) < cr
        if broken != "no forced index":
            cross[rows, rng.integers(0, D, NP)] = True
        if broken == "CR inverted":
            cross = ~cross
        trial = np.where(cross, mutant, pop)
        out = (trial < lo) | (trial > hi)
        trial[out] = lo + (hi - lo) * rng.random(out.sum())
        tcost = f(trial)
        better = tcost > cost if broken == "selection >" else tcost <= cost
        pop[better], cost[better] = trial[better], tcost[better]
    return np.log10(max(cost.min(), 1e-300))


@pytest.mark.parametrize(
    "broken, case",
    [
        (None, "sphere"),
        (None, "rosenbrock"),
        ("selection >", "sphere"),
        ("r1=i", "sphere"),
        ("r1=i", "rosenbrock"),
        ("no forced index", "sphere-CR0"),
        ("CR inverted", "sphere"),
        ("CR inverted", "rastrigin"),
    ],
)
def test_criterion_catches_broken_variants(broken, case):
    """The same criterion accepts a correct independent implementation and rejects each bug."""
    f, b, cr, gens = CASES[case]
    finals = np.array([numpy_de(f, b, cr, gens, 5000 + s, broken) for s in SEEDS])
    assert same_distribution(finals, scipy_finals(case)) == (broken is None)


def test_selection_accepts_equal_costs():
    """eq. (14) selects by <=: on a flat function every trial replaces its target."""
    kw = dict(population_size=8, F=0.5, CR=0.5, seed=3)
    start = iwr.differential_evolution(lambda X: np.ones(len(X)), [(0, 1)] * 4, generations=0, **kw)
    one = iwr.differential_evolution(lambda X: np.ones(len(X)), [(0, 1)] * 4, generations=1, **kw)
    assert np.all(np.any(one.population != start.population, axis=1))


def test_midpoint_bound_rule_keeps_the_box():
    """The optimum of sum(x) over [1, 2]^5 is the lower corner; the midpoint rule approaches it
    from inside and never leaves the box."""
    res = iwr.differential_evolution(
        lambda X: X.sum(1), [(1, 2)] * 5, strategy="jade", generations=300, seed=1
    )
    assert np.all(res.population >= 1) and np.all(res.population <= 2)
    assert res.fun == pytest.approx(5, abs=1e-8)


@pytest.mark.parametrize("strategy", ["rand1bin", "best1bin"])
@pytest.mark.parametrize("bound_rule", ["midpoint", "clip"])
def test_trials_without_crossover_are_the_repaired_mutants(strategy, bound_rule):
    """With CR = 1 (the paper's setting) a trial is the mutant x_r1 + F (x_r2 - x_r3), with r1,
    r2, r3 distinct and not i (eq. 12; best1bin: x_best + F (x_r1 - x_r2), the best the first of
    the lowest costs), each component outside the box repaired by the rule (midpoint: halfway
    between the parent's component and the bound crossed; clip: the bound). Checked bit for bit
    against NumPy for every trial of a short run: the population followed through the selection
    (eq. 14) from the costs returned, each trial's rows found among all the candidates. The C++
    builds such a trial and repairs it in one pass (de.cpp)."""
    lo = np.array([-1.0, -2.0, 0.0, -0.5, 10.0, 3.0, -7.0])
    hi = lo + np.array([2.0, 1.0, 3.0, 1.0, 0.5, 1e-3, 4.0])
    n, F = 7, 0.9
    calls = []

    def value(X):
        return ((X - lo) ** 2).sum(1)

    def cost(X):
        calls.append(np.array(X, copy=True))
        return value(X)

    iwr.differential_evolution(cost, list(zip(lo, hi, strict=True)), strategy=strategy,
                               population_size=n, F=F, CR=1.0, generations=6, seed=3,
                               bound_rule=bound_rule, workers=1)
    assert len(calls) == 7 and all(X.shape == (n, len(lo)) for X in calls)
    pop, fx = calls[0], value(calls[0])
    picks = np.array(list(itertools.permutations(range(n), 3 if strategy == "rand1bin" else 2)))
    repaired = 0
    for X in calls[1:]:
        for i in range(n):
            r = picks[(picks != i).all(1)]
            if strategy == "rand1bin":
                v = pop[r[:, 0]] + F * (pop[r[:, 1]] - pop[r[:, 2]])  # each candidate mutant
            else:
                v = pop[np.argmin(fx)] + F * (pop[r[:, 0]] - pop[r[:, 1]])
            bound = np.where(v < lo, lo, hi)
            fix = 0.5 * (pop[i] + bound) if bound_rule == "midpoint" else bound
            fix = np.minimum(np.maximum(fix, lo), hi)
            trial = np.where((v >= lo) & (v <= hi), v, fix)
            same = (trial.view(np.uint64) == X[i].view(np.uint64)).all(1)
            assert same.any(), (i, X[i])
            repaired += int(((v < lo) | (v > hi))[same][0].sum())
        tx = value(X)
        take = tx <= fx
        pop, fx = np.where(take[:, None], X, pop), np.where(take, tx, fx)
    assert repaired > 20  # the rule was exercised


# --- the modern strategies ------------------------------------------------------------------------


# best1bin converges prematurely on Rosenbrock, as is well known: not a case to test.
@pytest.mark.parametrize("strategy, func, half", [
    (s, f, h) for s in STRATEGIES if s != "rand1bin"
    for f, h in ((sphere, 5.12), (rosenbrock, 5.0)) if not (s == "best1bin" and f is rosenbrock)
])
def test_strategy_solves(strategy, func, half):
    budget = 200_000 if strategy == "jde" else 100_000
    res = iwr.differential_evolution(
        func, [(-half, half)] * 10, strategy=strategy, seed=2, max_evaluations=budget,
        target_cost=1e-8,
    )
    assert res.success and res.reason == "target", (res.fun, res.nfev, res.message)
    assert res.nfev <= budget
    assert np.allclose(res.x, 0 if func is sphere else 1, atol=1e-3)


def test_lshade_reduces_population():
    res = iwr.differential_evolution(
        sphere, [(-5, 5)] * 4, strategy="lshade", seed=0, max_evaluations=3000
    )
    assert res.settings["population_size"] == 72  # round(18 D)
    assert len(res.population) == 4  # NP_min at the end of the budget
    assert res.nfev == 3000 and res.reason == "evaluations"



@pytest.mark.parametrize("strategy", STRATEGIES)
def test_evaluation_budget_is_never_exceeded(strategy):
    """A budget that is not a whole number of generations: the last generation evaluates only the
    trials of its first slots, the others keep their parents; still the same on 1 or 2 threads."""
    kw = dict(strategy=strategy, population_size=24, seed=5, max_evaluations=1001)
    one = iwr.differential_evolution(rastrigin, [(-5, 5)] * 6, workers=1, **kw)
    two = iwr.differential_evolution(rastrigin, [(-5, 5)] * 6, workers=2, **kw)
    assert one.nfev == 1001 and one.reason == "evaluations"
    assert np.array_equal(one.x, two.x) and one.fun == two.fun and one.nit == two.nit
    assert one.history["nfev"][-1] == 1001 and np.all(np.diff(one.history["nfev"]) <= 24)


def test_budget_below_the_initial_population_is_refused():
    with pytest.raises(ValueError, match=r"max_evaluations: 300; the initial population alone "
                                         r"takes population_size \(400\)"):
        iwr.differential_evolution(sphere, [(-5, 5)] * 40, max_evaluations=300)

# --- the history, determinism, resume -------------------------------------------------------------


@pytest.fixture(scope="module")
def iwr_data():
    robot = iwr.Robot.default()
    measurements, truth = iwr.simulate(robot, 100, seed=1)
    return robot, measurements, truth


def _without_elapsed(history):
    return {k: v for k, v in history.items() if k != "elapsed"}


@pytest.mark.parametrize("strategy", ["rand1bin", "jade", "jde", "lshade"])
def test_same_seed_same_result_with_1_or_2_threads(iwr_data, strategy):
    robot, measurements, _ = iwr_data
    kw = dict(strategy=strategy, population_size=40, seed=11, polish=False, progress=False)
    if strategy == "lshade":
        kw["max_evaluations"] = 1200
    else:
        kw["generations"] = 30
    one = iwr.identify(robot, measurements, "de", workers=1, **kw)
    two = iwr.identify(robot, measurements, "de", workers=2, **kw)
    assert np.array_equal(one.x, two.x) and one.fun == two.fun
    h1, h2 = _without_elapsed(one.history), _without_elapsed(two.history)
    assert h1.keys() == h2.keys() == {"generation", "nfev", "best", "mean", "spread"}
    for k in h1:
        assert np.array_equal(h1[k], h2[k]), k
    other = iwr.identify(robot, measurements, "de", workers=2, **{**kw, "seed": 12})
    assert not np.array_equal(one.x, other.x)


@pytest.mark.parametrize("strategy, bound_rule", [
    ("rand1bin", "midpoint"), ("rand1bin", "clip"), ("rand1bin", "reflect"), ("jade", "midpoint"),
])
def test_one_pass_and_two_pass_generations_agree(iwr_data, strategy, bound_rule):
    """The C++ objective builds and evaluates each thread's trials in one pass of the pool; a
    Python function gets the whole population after the trials are built. Both give the same
    run, bit for bit, over a subset of the parameters (the reduced-to-full mapping)."""
    robot, measurements, _ = iwr_data
    p = iwr.Problem(robot, measurements)
    active = np.zeros(p.n_params, bool)
    active[:40] = True

    def cost(X):
        full = np.zeros((len(X), p.n_params))
        full[:, active] = X
        return p.cost_batch(full, workers=1)

    kw = dict(strategy=strategy, population_size=40, generations=25, seed=5, F=0.9, CR=1.0,
              bound_rule=bound_rule)
    one = iwr.identify(robot, measurements, "de", active=active, workers=2, polish=False,
                       progress=False, **kw)
    two = iwr.differential_evolution(cost, list(zip(p.lower[active], p.upper[active],
                                                    strict=True)), workers=2, **kw)
    assert np.array_equal(one.x[active], two.x) and np.all(one.x[~active] == 0)
    assert one.fun == two.fun
    for k in ("best", "mean", "spread"):
        assert np.array_equal(one.history[k], two.history[k]), k


# --- every kind of data on its C++ objective (issue 24, item 2) --------------------------------

#: A short jade run (its adaptive memories and archive make a parted trajectory show at once).
KIND_DE = dict(strategy="jade", population_size=24, generations=12, seed=9, polish=False,
               progress=False)


def _kind_problem(kind):
    """The kind's problem and start, two parameters held (one off its start): the reduced
    mapping is part of what each path must get right."""
    problem, start = kind.kind.problem(kind.robot, kind.data)
    active = np.ones(problem.n_params, dtype=bool)
    active[[3, problem.n_params - 2]] = False
    x0 = np.array(start, dtype=float)
    x0[3] += 1e-3
    return problem, active, x0


def _same_run(a, b, x_b=None):
    assert np.array_equal(a.x, b.x if x_b is None else x_b) and a.fun == b.fun
    assert (a.nfev, a.nit) == (b.nfev, b.nit)
    for k in ("generation", "nfev", "best", "mean", "spread"):
        assert np.array_equal(a.history[k], b.history[k]), k


def test_every_kind_same_bits_on_1_and_2_threads_and_workers_honoured(kind):
    """DE on each kind's C++ objective (``engine_objective``): the same seed gives the same run
    bit for bit on 1 and 2 threads, and the engine ran on the threads asked for (its own count,
    not a timing: tracker and ballbar data ran on every core whatever ``workers`` said)."""
    from iwr.methods import run_method

    problem, active, x0 = _kind_problem(kind)
    assert problem.engine_objective() is not None
    one = run_method(problem, "de", active, x0, workers=1, **KIND_DE)
    two = run_method(problem, "de", active, x0, workers=2, **KIND_DE)
    assert one.settings["threads"] == 1 and one.settings["workers"] == 1
    assert two.settings["threads"] == 2
    _same_run(one, two)
    assert np.all(one.x[~active] == x0[~active])
    other = run_method(problem, "de", active, x0, workers=2, **{**KIND_DE, "seed": 10})
    assert not np.array_equal(one.x, other.x)


def test_every_kind_same_run_as_de_on_its_cost_batch(kind):
    """The engine on the C++ objective evaluates what the problem's ``cost_batch`` does: the
    same run, bit for bit, as :func:`iwr.differential_evolution` on the reduced ``cost_batch``
    (the path tracker and ballbar data took before), with the same seed and settings."""
    from iwr.methods import ReducedProblem, run_method

    problem, active, x0 = _kind_problem(kind)
    reduced = ReducedProblem(problem, active, x0)
    new = run_method(problem, "de", active, x0, workers=2, **KIND_DE)
    kw = {k: v for k, v in KIND_DE.items() if k not in ("polish", "progress")}
    old = iwr.differential_evolution(lambda z: reduced.cost_batch(z, 1),
                                     np.column_stack([reduced.lower, reduced.upper]), workers=2,
                                     **kw)
    _same_run(new, old, reduced.full(old.x))


def test_a_problem_without_a_cpp_objective_runs_on_its_cost_batch(kind):
    """A problem whose ``engine_objective()`` is None: DE calls its ``cost_batch`` once per
    generation, with the ``workers`` given (it was called with None, all cores, before); the
    same run as on the C++ objective (its rows' costs are that objective's, one by one)."""
    from iwr.methods import run_method

    problem, active, x0 = _kind_problem(kind)
    ref = run_method(problem, "de", active, x0, workers=1, **KIND_DE)
    batch, asked = problem.cost_batch, []

    def cost_batch(X, workers=None):
        asked.append(workers)
        return batch(X, workers)

    problem.engine_objective = lambda: None
    problem.cost_batch = cost_batch
    res = run_method(problem, "de", active, x0, workers=1, **KIND_DE)
    assert len(asked) == KIND_DE["generations"] + 1 and set(asked) == {1}
    assert res.settings["threads"] == 1
    _same_run(res, ref)


def test_every_kind_resumes_bit_identically(kind):
    """``return_state`` and ``resume`` on every kind (tracker and ballbar runs dropped their
    state before): 5 generations, then resumed to 12, is the run of 12."""
    from iwr.methods import run_method

    problem, active, x0 = _kind_problem(kind)
    whole = run_method(problem, "de", active, x0, workers=2, **KIND_DE)
    half = run_method(problem, "de", active, x0, workers=2, return_state=True,
                      **{**KIND_DE, "generations": 5})
    assert half.nit == 5 and isinstance(half.state, bytes)
    rest = run_method(problem, "de", active, x0, workers=1, resume=half.state, **KIND_DE)
    _same_run(rest, whole)


@pytest.mark.parametrize("wrong", ["geometry", "text", "tracker kinematics"])
def test_what_is_not_a_cpp_objective_is_refused_by_name(iwr_data, wrong):
    """``_core.de_kernel`` takes the C++ objectives of AnyObjective only; anything else (a
    problem's ``engine_objective`` returning the wrong thing) is a TypeError naming its type and
    the types accepted, before any work."""
    from iwr import _core
    from iwr.methods import run_method

    robot, measurements, _ = iwr_data
    problem = iwr.Problem(robot, measurements)
    obj = {"geometry": robot._geometry, "text": "Objective",
           "tracker kinematics": None}[wrong]
    if obj is None:  # a Python class named like a C++ objective is not one either
        obj = type("TrackerObjective", (), {"cost_batch": lambda self, X, t: np.zeros(len(X))})()
    problem.engine_objective = lambda: obj
    name = type(obj).__name__
    with pytest.raises(TypeError, match=rf"kernel: {name} is not a C\+\+ objective; expected one "
                                        r"of iwr\._core\.Objective, iwr\._core\.TrackerObjective, "
                                        r"iwr\._core\.EffectObjective, .*BallbarEffectObjective"):
        run_method(problem, "de", np.ones(problem.n_params, dtype=bool),
                   np.zeros(problem.n_params), workers=1, **KIND_DE)
    assert hasattr(_core, "de_kernel") and not hasattr(_core, "de_objective")


def test_every_kind_same_run_as_iwr_engine_on_its_problem_file(kind, installed_command,
                                                                 tmp_path):
    """``iwr-engine`` on the problem's file (two parameters held, one off its start) runs the
    same search as ``iwr.identify``'s DE: the same x, cost and log, bit for bit (the engine on
    2 threads, Python on 1)."""
    import subprocess

    from iwr.methods import run_method
    from iwr.problem_file import engine_result

    problem, active, x0 = _kind_problem(kind)
    path, ckpt = tmp_path / "p.iwrp", tmp_path / "p.ckpt"
    problem.save(path, x0=x0, active=active)
    proc = subprocess.run(
        [installed_command("iwr-engine"), str(path), "--strategy", "jade", "--population-size",
         "24", "--generations", "12", "--seed", "9", "--threads", "2", "--checkpoint", str(ckpt)],
        capture_output=True, text=True, timeout=300, check=False, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    exe = engine_result(ckpt, path)
    py = run_method(problem, "de", active, x0, workers=1, **KIND_DE)
    _same_run(exe, py)


def test_history(iwr_data):
    robot, measurements, _ = iwr_data
    res = iwr.identify(robot, measurements, "de", population_size=30, generations=20, seed=1,
                       polish=False, progress=False)
    h = res.history
    assert set(h) == {"generation", "nfev", "best", "mean", "spread", "elapsed"}
    assert np.array_equal(h["generation"], np.arange(21))
    assert np.array_equal(h["nfev"], 30 * np.arange(1, 22))
    assert np.all(np.diff(h["best"]) <= 0) and np.all(h["mean"] >= h["best"])
    assert np.all(h["spread"] > 0) and np.all(np.diff(h["elapsed"]) >= 0)
    assert res.nit == 20 and res.nfev == 630 and h["best"][-1] == pytest.approx(res.fun)
    assert res.settings["seed"] == 1 and res.settings["strategy"] == "rand1bin"


@pytest.mark.parametrize("dim", [1, 7, 8, 13, 32, 33, 58, 71])
def test_history_spread_is_the_populations(dim):
    """The log's spread (the engine sums the columns in groups of vectors of 8, the last group of
    any width) against NumPy's from the final population: the root mean square over parameters of
    each column's standard deviation, in units of its bound width."""
    half = np.linspace(1.0, 3.0, dim)
    res = iwr.differential_evolution(sphere, list(zip(-half, half, strict=True)),
                                     population_size=40, generations=3, seed=dim, workers=2)
    rel = res.population.var(axis=0) / (2 * half) ** 2
    assert res.history["spread"][-1] == pytest.approx(np.sqrt(rel.mean()), rel=1e-12)


@pytest.mark.parametrize("generations", [300, 2000])
def test_history_spread_of_a_converged_population_is_exact(generations):
    """Populations converged around values near 500: after 300 generations each column's
    standard deviation is a few hundred units in the last place of its values, where a mean
    rounded before the deviations (two passes, NumPy's var) is off by 1e-5 relative; after 2000
    every row is the same, where that mean made a spread of 1e-16 out of nothing. The log's spread
    against exact rational arithmetic on the final population's doubles."""
    from fractions import Fraction

    lo, hi = np.array([-1000.0, -300.0, 0.0]), np.array([1000.0, 900.0, 2000.0])
    centre = np.array([517.3, 431.9, 1533.7])

    def bowl(x):
        return np.sum(((x - centre) / (hi - lo)) ** 2, axis=1)

    res = iwr.differential_evolution(bowl, np.c_[lo, hi], population_size=12,
                                     generations=generations, seed=5, workers=1)
    total = Fraction(0)
    for j in range(3):
        col = [Fraction(float(v)) for v in res.population[:, j]]
        mean = sum(col) / len(col)
        total += sum((v - mean) ** 2 for v in col) / len(col) / Fraction(float(hi[j] - lo[j])) ** 2
    exact = float(total / 3) ** 0.5
    assert exact < 1e-12  # converged: the case this test is about
    assert (exact == 0) == (generations == 2000)
    assert res.history["spread"][-1] == pytest.approx(exact, rel=1e-12, abs=0)


def test_history_spread_with_huge_bounds_is_right_or_nan():
    """Bounds of +-1e153: the sums of squares stay finite and the spread is NumPy's (a draft of the
    one-pass sums overflowed its (sum y)^2 np times sooner and logged 0, "collapsed"); +-1e154:
    (2e154)^2 overflows, and the spread is NaN, never 0."""
    def sphere_scaled(x):
        return np.sum((x * 1e-150) ** 2, axis=1)

    for bound, finite in ((1e153, True), (1e154, False)):
        res = iwr.differential_evolution(sphere_scaled, [(-bound, bound)] * 3, population_size=40,
                                         generations=3, seed=1, workers=1)
        spread = res.history["spread"]
        if finite:
            rel = (res.population / (2 * bound)).var(axis=0)
            assert spread[-1] == pytest.approx(np.sqrt(rel.mean()), rel=1e-12)
        else:
            assert np.all(np.isnan(spread))


def test_result_file_round_trip(iwr_data, tmp_path):
    robot, measurements, _ = iwr_data
    res = iwr.identify(robot, measurements, "de", strategy="jade", generations=5, seed=3,
                       progress=False)
    res.save(tmp_path / "de.json")
    text = (tmp_path / "de.json").read_text()
    assert "Infinity" not in text and "NaN" not in text
    back = iwr.load_result(tmp_path / "de.json")
    assert np.array_equal(back.x, res.x) and back.method == "de" and back.nit == 5
    assert back.settings["seed"] == 3 and back.settings["strategy"] == "jade"
    assert np.array_equal(back.history["best"], res.history["best"])


def test_resume_is_bit_identical():
    kw = dict(strategy="jso", seed=4, max_evaluations=4000, return_state=True)
    whole = iwr.differential_evolution(rosenbrock, [(-5, 5)] * 6, generations=40, **kw)
    half = iwr.differential_evolution(rosenbrock, [(-5, 5)] * 6, generations=15, **kw)
    rest = iwr.differential_evolution(
        rosenbrock, [(-5, 5)] * 6, generations=40, resume=half.state, **kw
    )
    assert np.array_equal(whole.x, rest.x) and whole.nfev == rest.nfev
    for k in ("generation", "nfev", "best", "mean", "spread"):
        assert np.array_equal(whole.history[k], rest.history[k])
    damaged = bytearray(half.state)
    damaged[len(damaged) // 2] ^= 1
    with pytest.raises(RuntimeError, match="checksum"):
        iwr.differential_evolution(rosenbrock, [(-5, 5)] * 6, resume=bytes(damaged), **kw)
    with pytest.raises(RuntimeError, match="truncated"):
        iwr.differential_evolution(rosenbrock, [(-5, 5)] * 6, resume=half.state[:10], **kw)
    with pytest.raises(ValueError, match="other settings"):
        iwr.differential_evolution(
            rosenbrock, [(-5, 5)] * 6, resume=half.state, **{**kw, "seed": 5}
        )


# --- control: callback, Ctrl-C, stopping criteria -------------------------------------------------


def test_callback_stops_the_run():
    seen = []

    def cb(info):
        seen.append((info.nit, info.fun, info.x.copy()))
        return info.nit >= 3

    res = iwr.differential_evolution(sphere, [(-5, 5)] * 3, generations=100, seed=0, callback=cb)
    assert res.nit == 3 and not res.success and "callback" in res.message
    assert [s[0] for s in seen] == [1, 2, 3] and seen[-1][1] == res.fun

    def stop_iteration(info):
        raise StopIteration

    res = iwr.differential_evolution(sphere, [(-5, 5)] * 3, generations=100, seed=0,
                                     callback=stop_iteration)
    assert res.nit == 1


def test_callback_errors_propagate():
    def cb(info):
        raise ZeroDivisionError("from the callback")

    with pytest.raises(ZeroDivisionError, match="from the callback"):
        iwr.differential_evolution(sphere, [(-5, 5)] * 3, generations=100, seed=0, callback=cb)

    def func(X):
        raise ZeroDivisionError("from the objective")

    with pytest.raises(ZeroDivisionError, match="from the objective"):
        iwr.differential_evolution(func, [(-5, 5)] * 3, generations=100, seed=0)


def test_ctrl_c_returns_the_best_so_far(kind, sigint_handler):
    """SIGINT while the C++ engine runs on each kind's objective: the run stops and returns the
    best point so far, interrupted, not polished."""
    timer = threading.Timer(0.5, lambda: os.kill(os.getpid(), signal.SIGINT))
    timer.start()
    try:
        res = iwr.identify(kind.robot, kind.data, "de", population_size=20, generations=10**6,
                           seed=0, progress=False)
    finally:
        timer.cancel()
    assert res.reason == "interrupted" and not res.success and "Ctrl-C" in res.message
    assert res.status == "interrupted" and "polish_result" not in res.settings
    assert 0 < res.nit < 10**6 and res.fun == pytest.approx(res.history["best"][-1])


def test_keyboard_interrupt_in_python_objective():
    calls = []

    def func(X):
        calls.append(1)
        if len(calls) == 5:
            raise KeyboardInterrupt
        return sphere(X)

    res = iwr.differential_evolution(func, [(-5, 5)] * 3, generations=100, seed=0)
    assert res.reason == "interrupted" and res.nit == 3  # generation 4 never completed


@pytest.mark.parametrize(
    "options, reason",
    [
        ({"generations": 7}, "generations"),
        ({"generations": None, "max_evaluations": 95}, "evaluations"),
        ({"target_cost": 1e-2}, "target"),
        ({"tol": 1e-2}, "converged"),
        ({"stagnation_generations": 5, "stagnation_tol": 1.0}, "stagnation"),
        ({"max_seconds": 1e-9}, "time"),
    ],
)
def test_stopping_criteria(options, reason):
    res = iwr.differential_evolution(sphere, [(-5, 5)] * 2, population_size=10, seed=0,
                                     **{"generations": 10_000, **options})
    assert res.reason == reason, res.message
    assert res.success == (reason in ("target", "converged", "stagnation"))
    if reason == "generations":
        assert res.nit == 7
    if reason == "evaluations":
        # The budget is never exceeded: the last generation evaluates 5 of its 10 trials.
        assert res.nfev == 95 and res.nit == 9 and res.history["nfev"][-1] == 95
    if reason == "target":
        assert res.fun <= 1e-2


def test_nan_costs_are_never_selected():
    def func(X):
        c = sphere(X)
        c[X[:, 0] > 0] = np.nan
        return c

    res = iwr.differential_evolution(func, [(-5, 5)] * 2, generations=200, seed=0)
    assert np.isfinite(res.fun) and res.x[0] <= 0 and res.fun < 1e-6


@pytest.mark.parametrize("where", ["initial population", "a later generation"])
def test_minus_infinite_cost_is_an_error_naming_the_vector(where):
    """A cost of -inf is no minimum (the engine took it as the best, and with the default target,
    -inf, no target at all, reported "the best cost -inf reached the target -inf", success): a
    ValueError naming the cost and the vector, as SciPy never calls an infinite population
    converged. NaN and +inf stay the worst cost."""
    calls = []

    def func(X):
        calls.append(len(X))
        c = sphere(X)
        if where == "initial population" or len(calls) > 3:
            c[1] = -np.inf
        return c

    row = "population" if where == "initial population" else "trial"
    with pytest.raises(ValueError, match=rf"objective: cost -inf at x = \[-?\d.*\] \({row} "
                                         r"row 1\).*-inf is no minimum"):
        iwr.differential_evolution(func, [(-5, 5)] * 3, generations=10, seed=0)


def test_minus_infinite_cost_through_identify_is_an_error():
    """The same through iwr.identify's DE on a problem whose cost is the user's (a Python
    ``cost_batch``, no C++ objective)."""
    from iwr.methods import run_method

    robot = iwr.Robot.default()
    m, _ = iwr.simulate(robot, n_poses=20, seed=3)
    problem = iwr.Problem(robot, m)
    batch = problem.cost_batch

    def cost_batch(X, workers=None):
        c = batch(X, workers)
        c[-1] = -np.inf
        return c

    problem.engine_objective = lambda: None
    problem.cost_batch = cost_batch
    active = np.ones(problem.n_params, dtype=bool)
    with pytest.raises(ValueError,
                       match=r"objective: cost -inf at x = \[.*, \.\.\. \(58 values\)\]"):
        run_method(problem, "de", active, np.zeros(problem.n_params), generations=3, seed=1,
                   population_size=20, polish=False, progress=False)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_no_finite_cost_is_no_success(bad):
    """Every cost NaN or +inf: the run ends at its budget, no success, saying so; a target of
    +inf is not reached by +inf."""
    for options in ({}, {"target_cost": np.inf}):
        res = iwr.differential_evolution(lambda X: np.full(len(X), bad), [(-1, 1)] * 2,
                                         generations=4, seed=0, **options)
        assert not res.success and res.reason == "generations", res.message
        assert "no finite cost was found" in res.message and res.fun == np.inf


@pytest.mark.parametrize(
    "kwargs, name, shown",
    [
        ({"workers": 2**40}, "workers", "1099511627776"),
        ({"workers": np.int64(2**40)}, "workers", "1099511627776"),
        ({"workers": 2.5}, "workers", "2.5"),
        ({"workers": True}, "workers", "True"),
        ({"workers": -1}, "workers", "-1"),
        ({"workers": 100_000}, "workers", "100000"),  # beyond the machine: the pool's refusal
        ({"generations": 2**70}, "generations", str(2**70)),
        ({"generations": 3.0}, "generations", "3.0"),
        ({"population_size": 2**40}, "population_size", "1099511627776"),
        ({"max_evaluations": 2**70}, "max_evaluations", str(2**70)),
        ({"stagnation_generations": 2**63}, "stagnation_generations", str(2**63)),
        ({"memory_size": 2**40, "strategy": "shade"}, "memory_size", "1099511627776"),
        ({"min_population_size": 2**31, "strategy": "lshade"}, "min_population_size",
         "2147483648"),
    ],
)
def test_integer_arguments_out_of_range_are_named(kwargs, name, shown):
    """An integer argument beyond its C++ type (or not an integer) is a one-line ValueError naming
    it and its value, not pybind11's dump of the binding's signature."""
    with pytest.raises(ValueError) as info:
        iwr.differential_evolution(sphere, [(-1, 1)] * 3, **{"generations": 2, **kwargs})
    msg = str(info.value)
    assert msg.startswith(f"{name}: {shown}; ") and "\n" not in msg, msg


@pytest.mark.parametrize("kwargs, name", [({"workers": 2**40}, "workers"),
                                          ({"generations": 2**64}, "generations"),
                                          ({"max_evaluations": 2**63}, "max_evaluations"),
                                          ({"population_size": 2**32}, "population_size")])
def test_integer_arguments_out_of_range_are_named_by_identify(iwr_data, kwargs, name):
    robot, measurements, _ = iwr_data
    with pytest.raises(ValueError, match=rf"^{name}: {list(kwargs.values())[0]}; expected an "
                                         r"integer from \d+ to \d+$"):
        iwr.identify(robot, measurements, "de", progress=False, **{"generations": 2, **kwargs})


# --- bad arguments --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"population_size": 3}, r"population_size: 3; strategy 'rand1bin' needs at least 4"),
        ({"population_size": 3, "strategy": "jade"}, r"population_size: 3"),
        ({"population_size": 2, "strategy": "best1bin"}, r"population_size: 2"),
        ({"population_size": 10.5}, r"population_size: 10.5"),
        ({"F": 0}, r"F: 0"),
        ({"F": -0.5}, r"F: -0.5"),
        ({"F": 1.5, "strategy": "shade"}, r"F: 1.5"),
        ({"CR": 1.5}, r"CR: 1.5"),
        ({"CR": -0.1}, r"CR: -0.1"),
        ({"strategy": "rand2bin"}, r"strategy: 'rand2bin'"),
        ({"generations": -1}, r"generations: -1"),
        ({"workers": 0}, r"workers: 0"),
        ({"seed": -1}, r"seed: -1"),
        ({"bound_rule": "bounce"}, r"bound_rule: 'bounce'"),
        ({"memory_size": 0, "strategy": "shade"}, r"memory_size: 0"),
        ({"p_best": 1.5, "strategy": "jade"}, r"p_best: 1.5"),
        ({"max_evaluations": 10, "strategy": "lshade"}, r"max_evaluations: 10"),
    ],
)
def test_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        iwr.differential_evolution(sphere, [(-1, 1)] * 3, **{"generations": 2, **kwargs})


@pytest.mark.parametrize(
    "bounds, match",
    [
        ([(1, -1), (0, 1)], r"bounds: parameter 0 has \(min, max\) = \(1.0, -1.0\)"),
        ([(0, 1), (0, np.inf)], r"bounds: parameter 1 has \(min, max\) = \(0.0, inf\)"),
        ([(0, 1, 2)], r"bounds: shape \(1, 3\)"),
        ([], r"bounds: shape \(0,\)"),
    ],
)
def test_bad_bounds(bounds, match):
    with pytest.raises(ValueError, match=match):
        iwr.differential_evolution(sphere, bounds, generations=2)


def test_bad_function_output():
    with pytest.raises(ValueError, match=r"func: returned an array of shape \(3,\) for a "
                                         r"population of 40; expected \(40,\)"):
        iwr.differential_evolution(lambda X: np.zeros(3), [(-1, 1)] * 4, generations=2)
    with pytest.raises(TypeError, match="unexpected option"):
        iwr.differential_evolution(sphere, [(-1, 1)] * 4, generations=2, mutation=0.5)


def test_bad_identify_arguments(iwr_data):
    robot, measurements, _ = iwr_data
    with pytest.raises(ValueError, match="preset: 'table2'"):
        iwr.identify(robot, measurements, "de", preset="table2")
    with pytest.raises(ValueError, match="preset: 'paper' is the paper's DE/rand/1/bin"):
        iwr.identify(robot, measurements, "de", preset="paper", strategy="jade")
    with pytest.raises(ValueError, match="population_size: 3"):
        iwr.identify(robot, measurements, "de", strategy="jso", population_size=3)


@pytest.mark.parametrize("active", [None, [0, 1, 2, 3, 6, 7]])
def test_polish_with_no_more_readings_than_parameters(iwr_data, active):
    """One pose, 6 readings: fewer than the 58 parameters, or exactly as many as 6 active ones
    (MINPACK alone would refuse both); the regularised Levenberg-Marquardt polishes anyway."""
    robot, measurements, _ = iwr_data
    one = measurements.subset([0])
    res = iwr.identify(robot, one, "de", polish=True, generations=3, seed=0, active=active,
                       population_size=20, progress=False)
    assert res.settings["polish_result"]["fun"] <= res.settings["polish_result"]["fun_before"]
    lm = iwr.identify(robot, one, "lm", active=active)
    assert np.isfinite(lm.fun) and lm.settings["regularization"] > 0


# --- the IWR problem ------------------------------------------------------------------------------


def test_paper_preset(iwr_data):
    robot, measurements, _ = iwr_data
    res = iwr.identify(robot, measurements, "de", preset="paper", generations=2, seed=0,
                       polish=False, progress=False)
    s = res.settings
    assert (s["population_size"], s["F"], s["CR"], s["strategy"]) == (600, 0.9, 1.0, "rand1bin")
    assert res.nfev == 600 * 3 and res.nit == 2 and s["preset"] == "paper"
    full = iwr.identify(robot, measurements, "de", preset="paper", generations=None, seed=0,
                        max_evaluations=1200, polish=False, progress=False)
    assert full.settings["generations"] == 60000


def test_active_subset_keeps_the_others_at_x0(iwr_data):
    robot, measurements, truth = iwr_data
    active = np.zeros(robot.n_params, dtype=bool)
    active[52:] = True  # the six leg offsets
    x0 = truth.copy()
    x0[52:] = 0
    res = iwr.identify(robot, measurements, "de", x0=x0, active=active, strategy="jade",
                       population_size=30, generations=300, seed=0, polish=False,
                       progress=False)
    assert np.array_equal(res.x[:52], truth[:52])
    assert np.allclose(res.x[52:], truth[52:], atol=1e-6) and res.fun < 1e-9


def test_iwr_noise_free_reaches_paper_cost(iwr_data):
    """jSO reaches the paper's final cost, 1e-4, in a fraction of the paper's 36 million
    evaluations."""
    robot, measurements, _ = iwr_data
    res = iwr.identify(robot, measurements, "de", strategy="jso", max_evaluations=1_000_000,
                       target_cost=1e-4, seed=1, polish=False, progress=False)
    assert res.fun < 1e-4 and res.success and res.nfev < 1_000_000
    assert res.fun == pytest.approx(iwr.Problem(robot, measurements).cost(res.x))


def test_iwr_polish(iwr_data):
    robot, measurements, _ = iwr_data
    res = iwr.identify(robot, measurements, "de", strategy="jade", population_size=60,
                       generations=50, seed=1, progress=False)  # polished by default
    assert res.settings["polish"] is True
    before = res.settings["polish_result"]["fun_before"]
    assert before > 1e-6 and res.fun < 1e-15 and res.success and res.status == "converged"
    assert res.nfev == 60 * 51 + res.settings["polish_result"]["nfev"]
    alone = iwr.identify(robot, measurements, "de", strategy="jade", population_size=60,
                         generations=50, seed=1, polish=False, progress=False)
    assert alone.fun == before and not alone.success and alone.status == "stopped"
    assert "polish_result" not in alone.settings
