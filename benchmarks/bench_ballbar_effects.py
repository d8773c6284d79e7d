"""What ballbar data with effects cost per evaluation (issue 23; docs/effects.md, "Ballbar data").

Two set-ups, the realistic effects (``iwr.effects.api.realistic``: the legs' compliance and
temperature, then with the carriage's compliance too), payloads in turn
(``iwr.ballbar.effects.simulate``, seed 5) at 60 and 100 poses; 8 random vectors within the
bounds. Per evaluation, CPU time of one thread (``process_time``): the numpy cost (the residuals
of :class:`iwr.ballbar.effects.BallbarEffectProblem`: what DE, CRS2 and BOBYQA ran on before the
C++ objective), the C++ ``BallbarEffectObjective`` (``problem.objective``: what they run on now)
and the geometric C++ ``BallbarObjective`` of the same data (the robot without effects). Then,
at 60 poses, one DE generation of the default population (NP = 10 D rows within the bounds, as
DE evaluates them): before (numpy, one row after the other, timed on NP / 10 rows), after
(``problem.cost_batch``, 1 and 2 threads, wall time).

The C++ objective with effects is scalar code, the same on every SIMD variant; the geometric
objective runs the tracker SIMD kernel of the variant this CPU runs, which the first line names
(``iwr._core._active_kernel``), with the load of other processes meanwhile.

Usage::

    python benchmarks/bench_ballbar_effects.py
"""
from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np
from _load import OtherLoad
from threadpoolctl import threadpool_limits

import iwr
from iwr import _core
from iwr.ballbar import effects as be
from iwr.effects import api
from iwr.effects.tracker_study import PAYLOADS
from iwr.problem_base import ProblemBase

BARS = {
    "A": {"platform_ball": [0.0, 0.0, -60.0], "fixed_ball": [800.0, -800.0, 1500.0],
          "range": [300.0, 700.0]},
    "B": {"platform_ball": [100.0, 50.0, -60.0], "fixed_ball": [900.0, -200.0, 2400.0],
          "range": [300.0, 700.0]},
}


def per_eval(f: Callable[[np.ndarray], Any], X: np.ndarray, min_time: float) -> float:
    """CPU seconds per call of ``f`` on the rows of ``X``, repeated for at least ``min_time``."""
    n, t0 = 0, time.process_time()
    while True:
        for x in X:
            f(x)
            n += 1
        dt = time.process_time() - t0
        if dt > min_time:
            return dt / n


def numpy_cost(problem: Any, x: np.ndarray) -> float:
    """The cost before the C++ objective: ProblemBase.cost on the numpy residuals."""
    return ProblemBase.cost(problem, x)


def generation(problem: Any, rng: np.random.Generator) -> str:
    """One DE generation of the default population at this problem: before and after."""
    np_rows = 10 * problem.n_params
    P = rng.uniform(problem.lower, problem.upper, (np_rows, problem.n_params))
    t0 = time.perf_counter()
    for x in P[:np_rows // 10]:
        numpy_cost(problem, x)
    before = (time.perf_counter() - t0) * 10
    after = {}
    for w in (1, 2):
        t0 = time.perf_counter()
        problem.cost_batch(P, workers=w)
        after[w] = time.perf_counter() - t0
    return (f"| {np_rows} | {before:.1f} (timed on {np_rows // 10} rows) | {after[1]:.3f} | "
            f"{after[2]:.3f} |")


def main() -> None:
    rows, generations = [], []
    with threadpool_limits(1), OtherLoad() as load:
        for carriage in (False, True):
            plain = iwr.Robot.default().with_instrument("ballbar", BARS)
            robot = plain.with_effects(*api.realistic(plain, carriage=carriage))
            label = "legs' effects" + (" + carriage" if carriage else "")
            for n in (60, 100):
                data, _ = be.simulate(robot, n, seed=5, payloads=PAYLOADS)
                problem, _ = be.effect_problem(robot, data)
                rng = np.random.default_rng(0)
                X = rng.uniform(problem.lower, problem.upper, (8, problem.n_params))
                geo = iwr.ballbar.BallbarProblem(robot.with_effects(), problem.setup, data)
                ng, ne = robot.n_params, problem.n_effects
                Xg = np.concatenate([X[:, :ng], X[:, ng + ne:]], axis=1)
                t_np = per_eval(lambda x, p=problem: numpy_cost(p, x), X[:4], 3.0)
                t_cpp = per_eval(problem.objective.cost, X, 2.0)
                t_geo = per_eval(geo.objective.cost, Xg, 1.0)
                rel = max(abs(numpy_cost(problem, x) - problem.objective.cost(x))
                          / numpy_cost(problem, x) for x in X[:3])
                rows.append(f"| {label} | {n} | {problem.n_params} | {t_np * 1e3:.2f} | "
                            f"{t_cpp * 1e3:.3f} ({t_np / t_cpp:.0f}x) | {t_geo * 1e3:.4f} | "
                            f"{t_cpp / t_geo:.0f}x | {rel:.1e} |")
                if n == 60:
                    generations.append(f"| {label} " + generation(problem, rng))
    print(f"variant this CPU runs: {_core._active_kernel()} (the geometric objective's; the "
          f"objective with effects is scalar); other processes meanwhile: "
          + ("n/a" if load.cores is None else f"{load.cores:.2f} cores"))
    print("\nper evaluation, one thread, CPU time (ms):")
    print("| effects | N | D | numpy (before) | C++ with the effects | geometric C++ | "
          "effects / geometric | cost rel. diff |")
    print("|---|---|---|---|---|---|---|---|")
    print("\n".join(rows))
    print("\na DE generation of the default population at 60 poses, wall time (s):")
    print("| effects | NP | numpy, one row after the other | C++, 1 thread | C++, 2 threads |")
    print("|---|---|---|---|---|")
    print("\n".join(generations))


if __name__ == "__main__":
    main()
