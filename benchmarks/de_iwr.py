"""Differential evolution on the IWR calibration problem: what each strategy needs to reach the
paper's final cost, and the paper preset's best-cost curve (the analogue of the paper's Fig. 5).

The problem: ``iwr.simulate(iwr.Robot.default(), 100, seed=s)`` (100 poses, no noise, errors
uniform within the default bounds), all 58 parameters, default bounds (+-0.5 mm, +-0.5 degree).

Prints three Markdown tables and writes a PNG:

1. evaluations and seconds for the best cost to reach ``--target`` (default 1e-4) per strategy and
   data seed, with a cap of ``--budget`` evaluations per run;
2. the same with polish: DE until the cost reaches ``--polish-from`` (default 1), then
   Levenberg-Marquardt on the exact Jacobian (``polish=True``); the final cost and the totals;
3. the paper preset (NP 600, F 0.9, CR 1.0) for ``--paper-seconds`` of wall time: its best cost
   against generations, plotted in ``--plot``.

Usage::

    python benchmarks/de_iwr.py [--seeds 1 2 3] [--budget 2000000] [--workers 2]
        [--paper-seconds 120] [--plot docs/figures/de_paper_preset.png]
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

import iwr

STRATEGIES = [
    ("rand1bin, paper (NP 600, F 0.9, CR 1)", "rand1bin",
     {"population_size": 600, "F": 0.9, "CR": 1.0}),
    ("rand1bin (NP 10 D, F 0.5, CR 0.9)", "rand1bin", {}),
    ("best1bin", "best1bin", {}),
    ("jade", "jade", {}),
    ("jde", "jde", {}),
    ("shade", "shade", {}),
    ("lshade", "lshade", {}),
    ("jso", "jso", {}),
]


def cpu_name() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def run(robot, data, strategy, kw, seed, budget, target, workers, polish=False, schedule=None):
    kw = dict(kw)
    if strategy in ("lshade", "jso"):
        # Their schedules (population reduction, parameter phases) run to a planned budget.
        kw["max_evaluations"] = min(schedule or budget, budget)
    else:
        kw["max_evaluations"] = budget
        kw["generations"] = None
    start = time.perf_counter()
    res = iwr.identify(robot, data, "de", strategy=strategy, seed=seed, target_cost=target,
                       workers=workers, polish=polish, progress=False, **kw)
    return res, time.perf_counter() - start


def fmt_reach(res, secs, target):
    if res.history["best"][-1] <= target:
        return f"{res.history['nfev'][-1]:,} / {secs:.1f} s"
    return f"not reached: {res.history['best'][-1]:.1e} at {res.history['nfev'][-1]:,}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--budget", type=int, default=2_000_000)
    ap.add_argument("--schedule", type=int, default=1_000_000,
                    help="planned evaluation budget of lshade and jso")
    ap.add_argument("--target", type=float, default=1e-4)
    ap.add_argument("--polish-from", type=float, default=1.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--paper-seconds", type=float, default=120.0)
    ap.add_argument("--plot", default="docs/figures/de_paper_preset.png")
    ap.add_argument("--skip", nargs="*", default=[], help="table numbers to skip (1, 2, 3)")
    args = ap.parse_args()

    robot = iwr.Robot.default()
    data = {s: iwr.simulate(robot, 100, seed=s)[0] for s in args.seeds}
    print(f"Machine: {cpu_name()}, {os.cpu_count()} hardware threads; workers = {args.workers}; "
          f"iwr {iwr.__version__}")
    print()

    curves = {}
    if "1" not in args.skip:
        print(f"## Evaluations / seconds to reach a cost of {args.target:g} "
              f"(cap {args.budget:,} evaluations; lshade and jso planned for {args.schedule:,})")
        print()
        print("| strategy | " + " | ".join(f"data seed {s}" for s in args.seeds) + " |")
        print("|---|" + "---|" * len(args.seeds))
        for label, strategy, kw in STRATEGIES:
            cells = []
            for s in args.seeds:
                res, secs = run(robot, data[s], strategy, kw, s, args.budget, args.target,
                                args.workers, schedule=args.schedule)
                cells.append(fmt_reach(res, secs, args.target))
                if s == args.seeds[0]:
                    curves[label] = (res.history["nfev"], res.history["best"])
            print(f"| {label} | " + " | ".join(cells) + " |", flush=True)
        print()

    if "2" not in args.skip:
        print(f"## With polish: DE to a cost of {args.polish_from:g}, then Levenberg-Marquardt")
        print()
        print("| strategy | " + " | ".join(f"data seed {s}: final cost, evaluations, s"
                                            for s in args.seeds) + " |")
        print("|---|" + "---|" * len(args.seeds))
        for label, strategy, kw in STRATEGIES:
            cells = []
            for s in args.seeds:
                res, secs = run(robot, data[s], strategy, kw, s, args.budget, args.polish_from,
                                args.workers, polish=True, schedule=args.schedule)
                cells.append(f"{res.fun:.1e}, {res.nfev:,}, {secs:.2f}")
            print(f"| {label} | " + " | ".join(cells) + " |", flush=True)
        cells = []
        for s in args.seeds:
            start = time.perf_counter()
            res = iwr.identify(robot, data[s], "lm")
            cells.append(f"{res.fun:.1e}, {res.nfev:,}, {time.perf_counter() - start:.2f}")
        print("| (Levenberg-Marquardt alone, from the nominal robot) | " + " | ".join(cells) + " |")
        print()

    if "3" not in args.skip:
        s = args.seeds[0]
        res = iwr.identify(robot, data[s], "de", preset="paper", seed=s, workers=args.workers,
                           max_seconds=args.paper_seconds, polish=False, progress=False)
        h = res.history
        print(f"## The paper preset for {args.paper_seconds:g} s (data seed {s})")
        print()
        print(f"{res.nit:,} generations, {res.nfev:,} evaluations in {res.wall_time:.1f} s "
              f"({res.wall_time / res.nfev * 1e6:.2f} us per evaluation, "
              f"{res.nit / res.wall_time:.0f} generations/s); final best cost {res.fun:.3e}.")
        print()
        print("| generation | evaluations | best cost |")
        print("|---|---|---|")
        marks = sorted({int(g) for g in np.unique(np.geomspace(1, res.nit, 12).astype(int))})
        for g in [0, *marks]:
            print(f"| {g:,} | {h['nfev'][g]:,} | {h['best'][g]:.3e} |")
        print()
        if args.plot:
            import matplotlib

            matplotlib.use("Agg")
            import matplotlib.pyplot as plt

            fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
            ax = axes[0]
            ax.semilogy(h["generation"], h["best"], lw=1.2)
            ax.set_xlabel("generation")
            ax.set_ylabel("best cost (mm$^2$)")
            ax.set_title(f"Paper preset (NP 600, F 0.9, CR 1): {res.nit:,} generations")
            ax.axhline(1e-4, color="grey", ls=":", lw=1)
            ax.grid(True, which="both", alpha=0.3)
            ax = axes[1]
            for label, (nfev, best) in curves.items():
                ax.loglog(nfev, best, lw=1.1, label=label)
            ax.axhline(1e-4, color="grey", ls=":", lw=1)
            ax.set_xlabel("evaluations")
            ax.set_ylabel("best cost (mm$^2$)")
            ax.set_title(f"All strategies, data seed {s}")
            ax.grid(True, which="both", alpha=0.3)
            if curves:
                ax.legend(fontsize=7)
            fig.tight_layout()
            os.makedirs(os.path.dirname(args.plot) or ".", exist_ok=True)
            fig.savefig(args.plot, dpi=130)
            print(f"(plot written to {args.plot})")


if __name__ == "__main__":
    main()
