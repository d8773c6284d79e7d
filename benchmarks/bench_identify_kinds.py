"""One identification per kind of data: CPU time of ``iwr.identify`` (the efficient estimator
and noise-weighted LM, each with its fit check) on realistic simulated data, one thread.

Per kind (pose data, tracker points, a double ballbar: ``recalibration_verdict.robot_of``'s
robots), ``--seeds`` data sets of 40 poses (120 ballbar readings), each identified by both
methods; the table gives the median and range of the CPU time of one call, and the fit check's
share is what ``--full-size-search`` changes: with it the size test runs its search for the
smallest equivalent vector to the end, as it did before it stopped at the first plausible one
(``iwr.fit_test.beyond_plausible``), so that the two can be compared in one build.

Usage::

    python benchmarks/bench_identify_kinds.py [--seeds 5] [--full-size-search]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from recalibration_verdict import robot_of  # noqa: E402

import iwr  # noqa: E402
from iwr import _core, fit_test, kinds  # noqa: E402

#: Readings per data set: 40 poses, or 120 of a ballbar's single distances.
SIZES = {"pose": 40, "points": 40, "ballbar": 120}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--full-size-search", action="store_true",
                    help="the size test's search to the smallest equivalent, without the stop")
    args = ap.parse_args()
    if args.full_size_search:
        search = fit_test._nearest_plausible
        fit_test._nearest_plausible = (  # type: ignore[assignment]
            lambda *a, stop_within=False, **k: search(*a, **k))
    print(f"# {platform.processor() or platform.machine()}, kernel {_core._active_kernel()}, "
          f"1 thread, CPU time; size test: "
          f"{'full search' if args.full_size_search else 'stops at a plausible equivalent'}")
    print("| data | readings | efficient (s), median [range] | LM (s), median [range] |")
    print("|---|---|---|---|")
    for name, n in SIZES.items():
        robot = robot_of(name)
        noise = kinds.for_robot(robot).experiment_noise(robot, iwr.Noise.realistic())
        warm, _ = iwr.simulate(robot, n, seed=99, noise=noise)
        iwr.identify(robot, warm, "lm", noise=noise)  # imports and first calls, untimed
        times: dict[str, list[float]] = {"efficient": [], "lm": []}
        for seed in range(args.seeds):
            data, _ = iwr.simulate(robot, n, seed=100 + seed, noise=noise)
            for method, cell in times.items():
                options = {"outliers": "off"} if method == "efficient" else {}
                start = time.process_time()
                iwr.identify(robot, data, method, noise=noise, **options)
                cell.append(time.process_time() - start)
        row = [f"{np.median(t):.3f} [{min(t):.3f}, {max(t):.3f}]" for t in times.values()]
        print(f"| {name} | {n} | {row[0]} | {row[1]} |", flush=True)


if __name__ == "__main__":
    main()
