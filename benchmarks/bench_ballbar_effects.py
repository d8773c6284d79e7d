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

Usage::

    python benchmarks/bench_ballbar_effects.py
"""
import time
import numpy as np
import iwr
from threadpoolctl import threadpool_limits
from iwr.ballbar import effects as be
from iwr.effects import api
from iwr.effects.tracker_study import PAYLOADS
from iwr.problem_base import ProblemBase

BARS = {
    "A": {"platform_ball": [0.0, 0.0, -60.0], "fixed_ball": [800.0, -800.0, 1500.0], "range": [300.0, 700.0]},
    "B": {"platform_ball": [100.0, 50.0, -60.0], "fixed_ball": [900.0, -200.0, 2400.0], "range": [300.0, 700.0]},
}

def per_eval(f, X, min_time):
    n, t0 = 0, time.process_time()
    while True:
        for x in X:
            f(x)
            n += 1
        dt = time.process_time() - t0
        if dt > min_time:
            return dt / n

def numpy_cost(problem, x):  # the cost before: ProblemBase.cost on the numpy residuals
    return ProblemBase.cost(problem, x)

with threadpool_limits(1):
    for carriage in (False, True):
        plain = iwr.Robot.default().with_instrument("ballbar", BARS)
        robot = plain.with_effects(*api.realistic(plain, carriage=carriage))
        label = "legs' compliance + temperature" + (" + carriage" if carriage else "")
        for n in (60, 100):
            data, truth = be.simulate(robot, n, seed=5, payloads=PAYLOADS)
            problem, _ = be.effect_problem(robot, data)
            rng = np.random.default_rng(0)
            X = rng.uniform(problem.lower, problem.upper, (8, problem.n_params))
            geo = iwr.ballbar.BallbarProblem(robot.with_effects(), problem.setup, data)
            ng, ne = robot.n_params, problem.n_effects
            Xg = np.concatenate([X[:, :ng], X[:, ng + ne:]], axis=1)
            t_np = per_eval(lambda x: numpy_cost(problem, x), X[:4], 3.0)
            t_cpp = per_eval(problem.objective.cost, X, 2.0)
            t_geo = per_eval(geo.objective.cost, Xg, 1.0)
            c = [numpy_cost(problem, x) for x in X[:3]]
            d = [problem.objective.cost(x) for x in X[:3]]
            rel = max(abs(a - b) / a for a, b in zip(c, d))
            print(f"{label}, N={n}, D={problem.n_params}: numpy {t_np*1e3:.2f} ms, C++ {t_cpp*1e3:.3f} ms "
                  f"({t_np/t_cpp:.0f}x), geometric C++ {t_geo*1e3:.4f} ms (effects {t_cpp/t_geo:.0f}x it); "
                  f"cost rel. diff {rel:.1e}", flush=True)
            if n == 60:
                NP = 10 * problem.n_params
                P = rng.uniform(problem.lower, problem.upper, (NP, problem.n_params))
                t0 = time.perf_counter()
                for x in P[:NP // 10]:
                    numpy_cost(problem, x)
                before = (time.perf_counter() - t0) * 10
                after = {}
                for w in (1, 2):
                    t0 = time.perf_counter()
                    problem.cost_batch(P, workers=w)
                    after[w] = time.perf_counter() - t0
                print(f"  a DE generation, NP={NP}: before (numpy, one row after the other) ~{before:.1f} s "
                      f"(timed on {NP // 10} rows), after {after[1]:.3f} s (1 thread), {after[2]:.3f} s (2 threads)",
                      flush=True)
