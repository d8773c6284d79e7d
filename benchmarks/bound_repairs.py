"""Why a DE run on the IWR problem speeds up as it goes: the share of DE/rand/1 mutant components
that leave the bounds (each needs a repair in the engine's trial loop) at several generations of
the paper's setting (NP = 600, F = 0.9, CR = 1, N = 100 poses). See BENCHMARKS.md.

Usage::

    python benchmarks/bound_repairs.py
"""

import numpy as np

import iwr

robot = iwr.Robot.default()
data, _ = iwr.simulate(robot, n_poses=100, seed=1)
p = iwr.Problem(robot, data)
bounds = list(zip(p.lower, p.upper, strict=True))
rng = np.random.default_rng(1)
for g in (1, 3500, 20000, 60000):
    r = iwr.differential_evolution(
        lambda X: p.cost_batch(X, workers=2),
        bounds,
        population_size=600,
        F=0.9,
        CR=1.0,
        generations=g,
        seed=1,
        workers=2,
    )
    X = r.population
    a, b, c = (X[rng.integers(0, 600, 100000)] for _ in range(3))
    v = a + 0.9 * (b - c)  # DE/rand/1 mutants; CR = 1 takes every component
    out = 100 * np.mean((v < p.lower) | (v > p.upper))
    print(f"generation {g:5d}: {out:.1f}% of mutant components out of bounds")
