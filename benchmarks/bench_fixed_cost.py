"""Where an evaluation of the leg objective goes: the cost of a block of 8 poses and the fixed cost
of an evaluation (the carriage's constants, the kernel's prologue and end), every kernel variant,
one or more builds alternated. ``--data tracker``: the same for the tracker point objective.

``Problem.cost_batch(X, workers=1)`` of 600 random vectors within the default bounds, thread CPU
time per evaluation, the minimum of ``--repeat`` calls, at N = 8, 96, 100 and 800 poses
(``iwr.simulate(Robot.default(), N, seed=1)``; ``--data tracker``: ``simulate_tracker`` with
bench_regression.py's three reflectors, seed 1). A block is (t(800) - t(96)) / 88; the fixed cost
is t(8) less one block; N = 100 is 12 blocks and a half-empty 13th, whose cost t(100) - t(96) the
last column gives (the tracker's AVX-512 chord solves blocks in pairs: there the 13th is solved
alone, and t(8) is one block alone, not a block of a pair). Each build runs in its own
interpreter (``--python NAME=PATH``), the builds alternated round by round; the table gives each
cell's minimum over the rounds.

Usage::

    cd /tmp && python /path/to/benchmarks/bench_fixed_cost.py \\
        --python main=/work/venv/bin/python --python new=/work/venvs/leg/bin/python [--data tracker]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

from _load import OtherLoad  # benchmarks/ is on sys.path when this script runs

SIZES = (8, 96, 100, 800)

WORKER = r"""
import json, sys, time
import numpy as np
import iwr
from iwr import _core
robot = iwr.Robot.default()
repeat, data = int(sys.argv[1]), sys.argv[2]
if data == "tracker":
    sys.path.insert(0, sys.argv[3])  # benchmarks/
    from bench_regression import tracker_setup
    from iwr.tracker import TrackerProblem, simulate_tracker
    setup = tracker_setup()
out = {}
for n in (8, 96, 100, 800):
    if data == "tracker":
        measured, _ = simulate_tracker(robot, setup, n, seed=1)
        p = TrackerProblem(robot, setup, measured)
    else:
        measured, _ = iwr.simulate(robot, n_poses=n, seed=1)
        p = iwr.Problem(robot, measured)
    rng = np.random.default_rng(0)
    X = p.lower + (p.upper - p.lower) * rng.random((600, p.n_params))
    for v in _core._supported_kernels():
        _core._select_kernel(v)
        best = float("inf")
        for _ in range(repeat if n < 200 else max(3, repeat // 5)):
            t = time.thread_time()
            p.cost_batch(X, workers=1)
            best = min(best, time.thread_time() - t)
        out[f"{v} {n}"] = best / 600 * 1e6
print(json.dumps(out))
"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--python", action="append", default=[], metavar="NAME=PATH",
                    help="a build's interpreter (default: this one, as 'this')")
    ap.add_argument("--rounds", type=int, default=3, help="rounds, builds alternated (3)")
    ap.add_argument("--repeat", type=int, default=100, help="calls a cell per round (100)")
    ap.add_argument("--data", choices=("leg", "tracker"), default="leg",
                    help="the leg objective (default) or the tracker point objective")
    args = ap.parse_args()
    builds = [b.split("=", 1) for b in args.python] or [["this", sys.executable]]
    best: dict[str, dict[str, float]] = {name: {} for name, _ in builds}
    with OtherLoad() as load:
        for r in range(args.rounds):
            order = builds if r % 2 == 0 else builds[::-1]
            for name, exe in order:
                cmd = [exe, "-c", WORKER, str(args.repeat), args.data, str(Path(__file__).parent)]
                res = json.loads(subprocess.run(cmd, check=True, capture_output=True,
                                                text=True).stdout)
                for k, v in res.items():
                    best[name][k] = min(best[name].get(k, v), v)
    variants = sorted({k.split()[0] for b in best.values() for k in b},
                      key=["baseline", "avx2", "avx512"].index)
    what = "tracker point objective" if args.data == "tracker" else "leg objective"
    print(f"{what}, cost_batch(X, workers=1) of 600 vectors, thread CPU time per evaluation "
          f"(us), the minimum of {args.repeat} calls x {args.rounds} rounds; a block = (t(800) - "
          "t(96)) / 88, fixed = t(8) - a block, the 13th = t(100) - t(96)")
    print("| build | variant | N = 8 | N = 96 | N = 100 | N = 800 | a block (ns) | fixed (us) "
          "| the 13th (us) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, _ in builds:
        for v in variants:
            t = {n: best[name][f"{v} {n}"] for n in SIZES}
            block = (t[800] - t[96]) / 88
            print(f"| {name} | {v} | " + " | ".join(f"{t[n]:.4f}" for n in SIZES)
                  + f" | {block * 1e3:.2f} | {t[8] - block:.4f} | {t[100] - t[96]:.4f} |")
    print(f"other processes meanwhile {load.cores:.2f} cores" if load.cores is not None else "")
    return 0


if __name__ == "__main__":
    sys.exit(main())
