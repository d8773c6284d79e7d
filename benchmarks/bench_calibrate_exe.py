"""Throughput of the iwr-engine executable (behind iwr-calibrate): evaluations per second of DE.

Runs ``iwr-engine`` on the problem file of a simulated IWR data set (no noise) for a few hundred
generations at each thread count and prints a table. The rate is ``nfev / wall_time`` from the
final checkpoint, where ``wall_time`` is the engine's time (initialisation and generations), not
the file writing.

Usage: python benchmarks/bench_calibrate_exe.py [--poses 100] [--population-size 600]
                                                 [--generations 300] [--threads 1 2]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import iwr
from iwr.problem_file import engine_result


def find_exe() -> str:
    exe = shutil.which("iwr-engine")
    if exe is None:
        cand = Path(sys.executable).parent / "iwr-engine"
        exe = str(cand) if cand.exists() else None
    if exe is None:
        sys.exit("iwr-engine is not installed (pip install .)")
    return exe


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=100)
    ap.add_argument("--population-size", type=int, default=600)
    ap.add_argument("--generations", type=int, default=300)
    ap.add_argument("--threads", type=int, nargs="+", default=[1, os.cpu_count() or 1])
    args = ap.parse_args()
    exe = find_exe()
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        robot = iwr.Robot.default()
        data, _ = iwr.simulate(robot, args.poses, seed=1)
        iwr.Problem(robot, data).save(d / "run.iwrp")
        print(f"iwr-engine, rand1bin, N = {args.poses} poses, NP = {args.population_size}, "
              f"{args.generations} generations; {os.cpu_count()} CPUs, load average "
              f"{os.getloadavg()[0]:.1f}")
        print(f"{'threads':>8} {'evaluations':>12} {'seconds':>9} {'evals/s':>10} {'us/eval':>8}")
        for t in args.threads:
            out = d / f"r{t}.ckpt"
            subprocess.run(
                [exe, str(d / "run.iwrp"), "--population-size", str(args.population_size),
                 "--generations", str(args.generations), "--threads", str(t), "--checkpoint",
                 str(out), "--checkpoint-every", "0", "--quiet"],
                check=True,
            )
            r = engine_result(out)
            rate = r.nfev / r.wall_time
            print(f"{t:>8} {r.nfev:>12} {r.wall_time:>9.2f} {rate:>10.0f} {1e6 / rate:>8.2f}")


if __name__ == "__main__":
    main()
