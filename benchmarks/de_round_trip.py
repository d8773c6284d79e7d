"""DE's own work on two threads against the core-to-core round trip (issue 24, item 2).

On a virtual machine the host may run the two vCPUs on one die or on two, and move them from one
minute to the next: the round trip of a cache line between them then moves by a factor of 4-5,
and a DE generation's own work on two threads (its trials read rows the other core wrote, the
log's pass reads every row) moves with it (BENCHMARKS.md, twenty-ninth round). This script samples
both, alternately, for ``--seconds``: each sample is the round trip
(``iwr._core._bench.measure_core_round_trip_ns`` of the installed iwr), one run of each driver
(``benchmarks/de_overhead.cpp``, built as its header says, on 2 threads: a generation against one
``cost_batch``, and a generation of an objective that costs nothing), and the round trip again.
Several ``--driver`` (e.g. two builds of the library, or one with an environment variable set)
are run in turn in every sample, in an order that alternates, so that they meet the same states.

Usage (Linux; the drivers built beforehand)::

    cd /tmp && python /path/to/benchmarks/de_round_trip.py --problem leg.iwrp \\
        --driver main=/tmp/de_overhead --seconds 600 --plot de_round_trip.png --json out.json

It prints, per driver, the generation / ``cost_batch`` ratio and the trivial generation in the
samples whose round trips (before and after) were both below and both above ``--split`` ns.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import shlex
import statistics
import subprocess
import sys
import time
from pathlib import Path

_LINE = re.compile(r"cost_batch ([0-9.]+) ms, generation ([0-9.]+) ms, ratio ([0-9.]+)x")
_TRIVIAL = re.compile(r"trivial objective: generation ([0-9.]+) ms")


def fail(message: str) -> None:
    print(f"de_round_trip.py: error: {message}", file=sys.stderr)
    raise SystemExit(2)


def run_driver(cmd: list[str], problem: Path, generations: int, runs: int) -> dict:
    p = subprocess.run([*cmd, str(problem), "2", str(generations), "both", str(runs)],
                       capture_output=True, text=True)
    m, t = _LINE.search(p.stdout), _TRIVIAL.search(p.stdout)
    if p.returncode != 0 or not m or not t:
        fail(f"{' '.join(cmd)} (exit {p.returncode}) printed no timing line:\n"
             f"{p.stdout[-1500:]}{p.stderr[-1500:]}")
    return {"batch_ms": float(m[1]), "generation_ms": float(m[2]), "ratio": float(m[3]),
            "trivial_ms": float(t[1])}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--driver", action="append", required=True, metavar="NAME=COMMAND",
                    help="a de_overhead program (a command line: 'env VAR=1 /path' works)")
    ap.add_argument("--problem", type=Path, required=True, help="a leg problem file (.iwrp)")
    ap.add_argument("--seconds", type=float, default=600.0, help="how long to sample")
    ap.add_argument("--generations", type=int, default=300)
    ap.add_argument("--runs", type=int, default=3, help="de_overhead's runs a sample")
    ap.add_argument("--split", type=float, default=150.0,
                    help="round trip (ns) between the two states of the summary")
    ap.add_argument("--plot", type=Path, default=None,
                    help="PNG: each sample's ratio and round trip")
    ap.add_argument("--json", type=Path, default=None,
                    help="the samples as JSON: {columns, rows}")
    args = ap.parse_args()
    if not args.seconds > 0:
        fail(f"--seconds: {args.seconds}; expected a positive number")
    if not args.problem.is_file():
        fail(f"--problem: {str(args.problem)!r} is not a file")
    drivers = []
    for spec in args.driver:
        name, sep, cmd = spec.partition("=")
        if not sep or not name or not cmd:
            fail(f"--driver: {spec!r}; expected NAME=COMMAND")
        drivers.append((name, shlex.split(cmd)))

    from iwr import _core

    trip = _core._bench.measure_core_round_trip_ns
    samples: list[dict] = []
    t_end = time.monotonic() + args.seconds
    k = 0
    while time.monotonic() < t_end:
        order = drivers if k % 2 == 0 else drivers[::-1]
        before = trip(0.02)
        got = {name: run_driver(cmd, args.problem, args.generations, args.runs)
               for name, cmd in order}
        after = trip(0.02)
        samples.append({"t": time.time(), "trip_before_ns": before, "trip_after_ns": after,
                        **{f"{n}:{key}": v for n, r in got.items() for key, v in r.items()}})
        k += 1
        print(f"\rsamples: {k}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)

    trips = [s["trip_before_ns"] for s in samples if math.isfinite(s["trip_before_ns"])]
    print(f"{len(samples)} samples over {args.seconds:g} s; round trip "
          + (f"{min(trips):.0f}-{max(trips):.0f} ns" if trips else "not measured (one core)"))
    print("| driver | state (round trip) | samples | generation / batch, median (range) "
          "| trivial generation, median (us) |")
    print("|---|---|---|---|---|")
    # Each sample's state: both round trips below the split, both at or above it, or neither
    # (a switch during the sample, or no second core: NaN compares false), left out.
    state = ["fast" if max(s["trip_before_ns"], s["trip_after_ns"]) < args.split else
             "slow" if min(s["trip_before_ns"], s["trip_after_ns"]) >= args.split else None
             for s in samples]
    for name, _ in drivers:
        for label, which in ((f"< {args.split:g} ns", "fast"), (f">= {args.split:g} ns", "slow")):
            sel = [s for s, st in zip(samples, state, strict=True) if st == which]
            if not sel:
                print(f"| {name} | {label} | 0 | | |")
                continue
            r = [s[f"{name}:ratio"] for s in sel]
            tr = [1e3 * s[f"{name}:trivial_ms"] for s in sel]
            print(f"| {name} | {label} | {len(sel)} | {statistics.median(r):.3f}x "
                  f"({min(r):.3f}-{max(r):.3f}) | {statistics.median(tr):.1f} |")
    if args.json:  # by columns: a thousand samples in a few tens of kB
        cols = list(samples[0])
        args.json.write_text(json.dumps(
            {"columns": cols, "rows": [[round(s[c], 4) if math.isfinite(s[c]) else None
                                        for c in cols] for s in samples]},
            separators=(",", ":")))
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, 2, figsize=(11, 4), layout="constrained")
        x = [0.5 * (s["trip_before_ns"] + s["trip_after_ns"]) for s in samples]
        for name, _ in drivers:
            axes[0].scatter(x, [s[f"{name}:ratio"] for s in samples], s=8, label=name)
            axes[1].scatter(x, [1e3 * s[f"{name}:trivial_ms"] for s in samples], s=8, label=name)
        axes[0].axhline(1.1, color="k", lw=0.8, ls="--")
        axes[0].set_ylabel("a generation / one cost_batch, 2 threads")
        axes[1].set_ylabel("a generation, objective that costs nothing (us)")
        for ax in axes:
            ax.set_xlabel("core-to-core round trip (ns)")
            ax.set_xscale("log")
            if len(drivers) > 1:
                ax.legend()
        fig.suptitle("DE/rand/1/bin, NP 600, leg data N = 100, 2 threads "
                     f"({len(samples)} samples over {args.seconds:g} s)")
        fig.savefig(args.plot, dpi=110)
        print(f"plot: {args.plot}")


if __name__ == "__main__":
    main()
