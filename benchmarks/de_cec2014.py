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
    print("| function | mean error | std | min | max | seconds/run |")
    print("|---|---|---|---|---|---|")
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
        print(f"| F{fid} | {e.mean():.2e} | {e.std(ddof=1) if e.size > 1 else 0:.2e} | "
              f"{e.min():.2e} | {e.max():.2e} | {secs:.1f} |", flush=True)
    sys.stdout.flush()


if __name__ == "__main__":
    main()
