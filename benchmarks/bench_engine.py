"""The DE engine's generation rate on 1 and 2 threads, build against build (issue 24, item 2).

``iwr-engine`` (named ``iwr-calibrate`` at ``aa02662``, which then read the robot and data files
itself) on the leg example (``examples/iwr.toml``, ``examples/iwr_example.csv``: N = 100, 58
parameters), DE/rand/1/bin, NP 600, F 0.9, CR 1, seed 1, no periodic checkpoint. The rate is
(G2 - G1) / (t(G2) - t(G1)) from runs of G1 and G2 generations, wall time of the whole process
(reading and set-up cancel), the builds and thread counts alternated, the best of ``--repeat``.
The engine runs the kernel variant the machine selects (no option chooses another).

Usage::

    cd /tmp && python /path/to/benchmarks/bench_engine.py \\
        --build old=/work/venvs/perf-old/bin --build new=/work/venvs/perf/bin
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ROBOT, DATA = REPO / "examples" / "iwr.toml", REPO / "examples" / "iwr_example.csv"
SETTINGS = ["--population-size", "600", "--F", "0.9", "--CR", "1", "--seed", "1",
            "--checkpoint-every", "0", "--quiet"]


class Engine:
    """One build's engine: ``bin`` is its virtualenv's bin folder."""

    def __init__(self, name: str, bin_dir: str, tmp: Path) -> None:
        self.name, self.tmp, self.output = name, tmp / name, True
        self.tmp.mkdir()
        b = Path(bin_dir)
        if (b / "iwr-engine").exists():  # the engine reads a problem file its Python writes
            self.cmd = [str(b / "iwr-engine"), str(self.tmp / "leg.iwrp")]
            self.output = False  # the engine writes its checkpoint only
            subprocess.run([str(b / "python"), "-c",
                            "import sys, iwr; r = iwr.Robot.from_toml(sys.argv[1]); "
                            "m = iwr.Measurements.from_csv(sys.argv[2], robot=r); "
                            "iwr.Problem(r, m).save(sys.argv[3])",
                            str(ROBOT), str(DATA), str(self.tmp / "leg.iwrp")],
                           check=True, cwd=self.tmp)
        else:  # aa02662: the C++ program read the robot and data files
            self.cmd = [str(b / "iwr-calibrate"), str(ROBOT), str(DATA)]

    def wall(self, generations: int, threads: int) -> float:
        out = self.tmp / "r.json"
        t0 = time.perf_counter()
        subprocess.run([*self.cmd, *SETTINGS, "--generations", str(generations), "--threads",
                        str(threads), *(["--output", str(out)] if self.output else []),
                        "--checkpoint", str(self.tmp / "r.ckpt")], check=True, cwd=self.tmp,
                       stdout=subprocess.DEVNULL)
        return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--build", action="append", default=[], metavar="NAME=BINDIR")
    ap.add_argument("--generations", default="100,1100", help="G1,G2")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    g1, g2 = (int(g) for g in args.generations.split(","))
    threads = [int(t) for t in args.threads.split(",")]
    specs = args.build or [f"this={Path(sys.executable).parent}"]
    print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at start; "
          f"generations/s from runs of {g1} and {g2} generations, best of {args.repeat}")
    with tempfile.TemporaryDirectory() as tmp:
        engines = [Engine(*s.split("=", 1), Path(tmp)) for s in specs]
        rates: dict[tuple[str, int], list[float]] = {}
        for r in range(args.repeat):
            for e in engines if r % 2 == 0 else engines[::-1]:
                for t in threads if r % 2 == 0 else threads[::-1]:
                    a, b = e.wall(g1, t), e.wall(g2, t)
                    rates.setdefault((e.name, t), []).append((g2 - g1) / max(b - a, 1e-9))
    print("| build | threads | generations/s | ms/generation |")
    print("|---|---|---|---|")
    for (name, t), v in rates.items():
        print(f"| {name} | {t} | {max(v):.0f} | {1e3 / max(v):.3f} |")
    for e in engines:
        if 1 in threads and 2 in threads:
            ratio = max(rates[(e.name, 2)]) / max(rates[(e.name, 1)])
            print(f"{e.name}: 2 threads / 1: {ratio:.2f}x")
    print(f"load average {os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    main()
