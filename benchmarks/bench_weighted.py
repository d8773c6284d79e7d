"""Eq. (10) weighted by the instruments' noise (issue 14, item 3): what it buys, what it costs.

Two tables:

1. **Accuracy** (``--seeds``, default 20): ``Noise.realistic()`` data, N = 100 poses per data set
   (``iwr.simulate(robot, 100, seed=s, noise=...)``, truth drawn by the seed), 200 fresh
   noise-free poses of the same true robot (``seed=10000 + s``), as ``bench_estimation.py``. Three
   estimates of the base parameters from the nominal robot: eq. (10) (``iwr.identify(method="lm",
   active="base")``), the weighted objective (``method="lm", noise=Noise.realistic()``:
   generalised least squares, each pose's six leg residuals whitened by their covariance
   propagated at the nominal robot) and the efficient estimator (``noise=`` alone). Per seed the
   tool position and orientation RMS error on the fresh poses against the simulation's truth
   (``iwr.accuracy``), and the ratios eq. (10) / weighted and eq. (10) / efficient: median, the
   quartiles and the range over the seeds.
2. **Hot path** (``--no-time`` to skip): DE's population evaluation, ``cost_batch`` of the
   objective on M random vectors within the default bounds, at N = 100, 1 and 2 threads,
   unweighted against whitened; the minimum over ``--repeat`` repetitions of the wall time per
   evaluation (the machine may be shared: the minimum is the least disturbed), with the other
   processes' load (``_load.OtherLoad``).

Usage::

    python benchmarks/bench_weighted.py [--seeds 20] [--no-stats] [--no-time] [--repeat 30]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from _load import OtherLoad  # noqa: E402

import iwr  # noqa: E402
from iwr import _core  # noqa: E402
from iwr.problem import Problem  # noqa: E402


def rms(a: np.ndarray) -> float:
    return math.sqrt(float(np.mean(np.square(a))))


def stats_table(seeds: int) -> None:
    robot = iwr.Robot.default()
    noise = iwr.Noise.realistic()
    rows = []
    for s in range(seeds):
        m, truth = iwr.simulate(robot, 100, seed=s, noise=noise)
        fresh, _ = iwr.simulate(robot, 200, seed=10000 + s, x=truth)
        runs = {
            "eq10": iwr.identify(robot, m, "lm", active="base", progress=False),
            "weighted": iwr.identify(robot, m, "lm", noise=noise, active="base", progress=False),
            "efficient": iwr.identify(robot, m, noise=noise, progress=False),
        }
        row = {}
        for name, r in runs.items():
            acc = iwr.accuracy(robot, fresh, r.x).calibrated
            row[name] = (rms(acc.position), rms(acc.orientation))
            row[name + "_ok"] = bool(r.success)
            if name == "weighted":
                row["chi2"] = (r.fit.statistic, r.fit.dof, r.fit.p_value)
        rows.append(row)
        print(f"seed {s}: position RMS (um) eq10 {1e3 * row['eq10'][0]:.2f}, weighted "
              f"{1e3 * row['weighted'][0]:.2f}, efficient {1e3 * row['efficient'][0]:.2f}; "
              f"weighted chi2 {row['chi2'][0]:.1f} / {row['chi2'][1]} (p = {row['chi2'][2]:.2f})",
              flush=True)
    print()
    print(f"{seeds} data sets, N = 100, Noise.realistic(); tool RMS error on 200 fresh poses")
    print()
    print("| quantity | median | quartiles | range |")
    print("|---|---|---|---|")
    for name in ("eq10", "weighted", "efficient"):
        for i, (what, unit, scale) in enumerate((("position", "um", 1e3),
                                                 ("orientation", "urad", 1e6 * math.pi / 180))):
            v = scale * np.array([r[name][i] for r in rows])
            q1, med, q3 = np.percentile(v, [25, 50, 75])
            print(f"| {name} {what} ({unit}) | {med:.3g} | {q1:.3g} - {q3:.3g} "
                  f"| {v.min():.3g} - {v.max():.3g} |")
    for other in ("weighted", "efficient"):
        for i, what in enumerate(("position", "orientation")):
            ratio = np.array([r["eq10"][i] / r[other][i] for r in rows])
            q1, med, q3 = np.percentile(ratio, [25, 50, 75])
            print(f"| eq. (10) / {other}, {what} | {med:.3g} | {q1:.3g} - {q3:.3g} "
                  f"| {ratio.min():.3g} - {ratio.max():.3g} |")
    for other in ("weighted",):
        ratio = np.array([r[other][0] / r["efficient"][0] for r in rows])
        print(f"| {other} / efficient, position | {np.median(ratio):.3g} | "
              f"{np.percentile(ratio, 25):.3g} - {np.percentile(ratio, 75):.3g} | "
              f"{ratio.min():.3g} - {ratio.max():.3g} |")
    ok = {k: sum(r[k + "_ok"] for r in rows) for k in ("eq10", "weighted", "efficient")}
    print()
    print(f"success: {ok}; weighted chi-square p-values: median "
          f"{np.median([r['chi2'][2] for r in rows]):.2f}, smallest "
          f"{min(r['chi2'][2] for r in rows):.3f}")


def per_eval_us(fn, X: np.ndarray, repeat: int) -> float:
    fn(X[:8])  # warm-up
    best = math.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn(X)
        best = min(best, (time.perf_counter() - t) / X.shape[0] * 1e6)
    return best


def time_table(repeat: int) -> None:
    robot = iwr.Robot.default()
    noise = iwr.Noise.realistic()
    m, _ = iwr.simulate(robot, 100, seed=1, noise=noise)
    plain, white = Problem(robot, m), Problem(robot, m, noise=noise)
    rng = np.random.default_rng(0)
    X = rng.uniform(plain.lower, plain.upper, (580, robot.n_params))  # NP = 10 D
    rows = []
    with OtherLoad() as load:
        for threads in (1, 2):
            t_plain = per_eval_us(lambda A, p=plain, k=threads: p.cost_batch(A, workers=k), X,
                                  repeat)
            t_white = per_eval_us(lambda A, p=white, k=threads: p.cost_batch(A, workers=k), X,
                                  repeat)
            rows.append((threads, t_plain, t_white))
    other = "?" if load.cores is None else f"{load.cores:.2f}"
    print(f"N = 100 poses, cost_batch of {X.shape[0]} vectors (one DE generation at NP = 10 D), "
          f"wall time per evaluation, minimum of {repeat}; kernel {_core._active_kernel()}; "
          f"other processes: {other} cores")
    print()
    print("| threads | eq. (10) (us) | whitened (us) | ratio | generation, whitened (ms) |")
    print("|---|---|---|---|---|")
    for threads, tp, tw in rows:
        print(f"| {threads} | {tp:.3f} | {tw:.3f} | {tw / tp:.2f}x | {tw * X.shape[0] / 1e3:.2f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=30)
    ap.add_argument("--no-stats", action="store_true")
    ap.add_argument("--no-time", action="store_true")
    args = ap.parse_args()
    if not args.no_time:
        time_table(args.repeat)
        print()
    if not args.no_stats:
        stats_table(args.seeds)


if __name__ == "__main__":
    main()
