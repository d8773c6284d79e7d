"""L-SHADE (iwr's engine) on the CEC 2014 benchmark functions, as pygmo implements them.

Mean and standard deviation of the final error f(x_best) - f* over several runs, with the
competition's rules: search box [-100, 100]^D, a budget of 10000 D evaluations, errors below 1e-8
counted as 0. The strategy runs with its published defaults (NP_init = 18 D, H = 6, p = 0.11,
archive rate 2.6). pygmo is a test-only dependency: ``pip install pygmo``.

Usage::

    python benchmarks/de_cec2014.py --dim 10 --runs 10 [--strategy lshade] [--functions 1-30]
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

import iwr

# Published L-SHADE mean errors (standard deviations) at D = 10, 51 runs, the same rules: X. Wang,
# Y. Li, Y. Liang, B. Wu, Y. Xuan, "A novel ensemble estimation of distribution algorithm with
# distribution modification strategies", Complex & Intelligent Systems 9 (2023), Table 8.
PUBLISHED_LSHADE_D10 = {
    1: (0.0, 0.0), 2: (0.0, 0.0), 3: (0.0, 0.0), 4: (2.83e1, 1.40e1), 5: (1.43e1, 6.71),
    6: (0.0, 0.0), 7: (2.31e-3, 4.26e-3), 8: (0.0, 0.0), 9: (2.06, 8.44e-1),
    10: (1.56e-2, 3.61e-2), 11: (2.20e1, 2.14e1), 12: (6.33e-2, 5.18e-2), 13: (2.25e-2, 9.05e-3),
    14: (7.51e-2, 3.39e-2), 15: (5.18e-1, 1.85e-1), 16: (6.62e-1, 3.41e-1), 17: (6.36e-1, 6.31e-1),
    18: (2.49e-1, 3.62e-1), 19: (6.32e-2, 3.07e-2), 20: (3.50e-1, 2.10e-1), 21: (4.70e-1, 2.83e-1),
    22: (5.68e-2, 4.25e-2), 23: (3.29e2, 0.0), 24: (1.08e2, 1.38), 25: (1.37e2, 4.52e1),
    26: (1.00e2, 7.93e-3), 27: (1.22, 3.08e-1), 28: (3.80e2, 3.54e1), 29: (2.22e2, 2.24e-1),
    30: (4.63e2, 7.00e-1),
}


def parse_functions(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        if "-" in part:
            a, b = part.split("-")
            out += list(range(int(a), int(b) + 1))
        else:
            out.append(int(part))
    bad = [f for f in out if not 1 <= f <= 30]
    if bad:
        raise SystemExit(f"--functions: {bad} outside 1..30")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--dim", type=int, default=10, choices=(10, 20, 30, 50, 100))
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--strategy", default="lshade")
    ap.add_argument("--functions", default="1-30")
    ap.add_argument("--workers", type=int, default=1)
    args = ap.parse_args()
    try:
        import pygmo
    except ImportError:
        raise SystemExit("this benchmark needs pygmo: pip install pygmo") from None

    dim = args.dim
    budget = 10000 * dim
    print(f"# {args.strategy} on CEC 2014, D = {dim}, budget {budget} evaluations, "
          f"{args.runs} runs (seeds 0..{args.runs - 1})")
    published = PUBLISHED_LSHADE_D10 if (dim, args.strategy) == (10, "lshade") else {}
    extra = " published L-SHADE mean (std) |" if published else ""
    print("| function | mean error | std | min | max | seconds/run |" + extra)
    print("|---|---|---|---|---|---|" + ("---|" if published else ""))
    for fid in parse_functions(args.functions):
        prob = pygmo.problem(pygmo.cec2014(prob_id=fid, dim=dim))

        def func(X: np.ndarray, prob=prob) -> np.ndarray:
            return np.array([prob.fitness(x)[0] for x in X])

        errors = []
        start = time.perf_counter()
        for seed in range(args.runs):
            res = iwr.differential_evolution(
                func, [(-100.0, 100.0)] * dim, strategy=args.strategy, seed=seed,
                max_evaluations=budget, workers=args.workers,
            )
            err = res.fun - 100.0 * fid  # CEC 2014: f* = 100 i for function i
            errors.append(0.0 if err < 1e-8 else err)
        secs = (time.perf_counter() - start) / args.runs
        e = np.array(errors)
        pub = f" {published[fid][0]:.2e} ({published[fid][1]:.2e}) |" if published else ""
        print(f"| F{fid} | {e.mean():.2e} | {e.std(ddof=1) if e.size > 1 else 0:.2e} | "
              f"{e.min():.2e} | {e.max():.2e} | {secs:.1f} |{pub}", flush=True)
    sys.stdout.flush()


if __name__ == "__main__":
    main()
