"""The paper's run (DE/rand/1/bin, NP 600, F 0.9, CR 1, N = 100) per kernel variant, build against
build (issue 24: "the paper's full run on 2 threads no slower than at aa02662 on any variant").

``iwr.identify(method="de", polish=False)`` of ``--generations`` generations (60000 is the full
run) on ``--threads`` threads, each variant chosen with ``iwr._core._select_kernel``, the builds
alternated (``bench_regression.py``'s workers), wall time, the best of ``--repeat``. With fewer
than 60000 generations the table also gives the full run extrapolated linearly (a DE run speeds
up as it goes, ``bound_repairs.py``: the extrapolation overestimates both builds alike).

Usage::

    cd /tmp && python /path/to/benchmarks/bench_paper_run.py --generations 6000 \\
        --python old=/work/venvs/perf-old/bin/python --python new=/work/venvs/perf/bin/python
"""

from __future__ import annotations

import argparse
import os

from bench_regression import Build, Load, alternated  # benchmarks/ is on sys.path

FULL = 60000


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--python", action="append", required=True, metavar="NAME=PATH")
    ap.add_argument("--generations", type=int, default=FULL)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--kernels", default=None, help="variants, comma-separated (default: all)")
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args()
    builds = [Build(*s.split("=", 1)) for s in args.python]
    names = [b.name for b in builds]
    try:
        info = builds[0].ask("info")
        kernels = args.kernels.split(",") if args.kernels else info["kernels"]
        g = args.generations
        print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at start; this "
              f"machine runs the {info['default_kernel']} variant")
        print(f"DE/rand/1/bin, NP 600, N 100, {g} generations, {args.threads} threads, wall time, "
              f"best of {args.repeat}" + ("" if g == FULL else f"; full run = x {FULL / g:g}"))
        print("| variant | " + " | ".join(f"{n}: s" + ("" if g == FULL else f" | {n}: full run s")
                                          for n in names)
              + (f" | {names[1]} / {names[0]}" if len(names) == 2 else "") + " |")
        print("|---|" + "---|" * (len(names) * (1 if g == FULL else 2) + (len(names) == 2)))
        with Load(builds) as load:
            for k in kernels:
                r = alternated(builds, args.repeat, "de", k, args.threads, g)
                best = {n: min(x["wall"] for x in r[n]) for n in names}
                bits = {n: {x["fun"] for x in r[n]} for n in names}
                row = f"| {k} | " + " | ".join(
                    f"{best[n]:.2f}" + ("" if g == FULL else f" | {best[n] * FULL / g:.1f}")
                    for n in names)
                if len(names) == 2:
                    row += f" | {best[names[1]] / best[names[0]]:.2f}x"
                print(row + " |", flush=True)
                if len(names) == 2 and bits[names[0]] != bits[names[1]]:
                    print(f"  (best costs differ between the builds: {bits})")
        print(str(load))
    finally:
        for b in builds:
            b.close()


if __name__ == "__main__":
    main()
