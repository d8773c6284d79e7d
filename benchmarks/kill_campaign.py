"""The kill campaign of iwr-engine: SIGKILL at random moments, resume, and the same answer.

Runs the engine on a small simulated problem, kills it (SIGKILL, or SIGINT/SIGTERM) at a random
moment, resumes from the last checkpoint, again and again until the run ends; then compares the
result with the same run never interrupted (bit for bit: x, cost, counters, log) and counts the
temporary files left behind. Prints: kills, resumes, mismatches, temporaries left, hangs.

Usage: python benchmarks/kill_campaign.py [--kills 100] [--seed 0]

Last run (2026-11-23, 2 cores shared): see docs/iwr-calibrate.md, "Hardening".
"""

from __future__ import annotations

import argparse
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import iwr
from iwr.problem_file import engine_result

ENGINE = str(Path(sys.executable).parent / "iwr-engine")
ARGS = ["--population-size", "24", "--seed", "3", "--generations", "4000", "--checkpoint-every",
        "50", "--quiet"]


def same(a: iwr.IdentificationResult, b: iwr.IdentificationResult) -> bool:
    return (np.array_equal(a.x, b.x) and a.fun == b.fun and (a.nfev, a.nit) == (b.nfev, b.nit)
            and all(np.array_equal(a.history[k], b.history[k])
                    for k in ("generation", "nfev", "best", "mean", "spread")))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kills", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = random.Random(args.seed)
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        robot = iwr.Robot.default()
        m, _ = iwr.simulate(robot, 12, seed=1)
        iwr.Problem(robot, m).save(d / "p.iwrp")
        subprocess.run([ENGINE, str(d / "p.iwrp"), *ARGS, "--checkpoint", str(d / "ref.ckpt")],
                       check=True)
        reference = engine_result(d / "ref.ckpt")

        kills = resumes = mismatches = hangs = runs = 0
        ckpt = d / "k.ckpt"
        while kills < args.kills:
            runs += 1
            cmd = [ENGINE, str(d / "p.iwrp"), *ARGS, "--checkpoint", str(ckpt)]
            if ckpt.exists():
                cmd += ["--resume", str(ckpt)]
                resumes += 1
            proc = subprocess.Popen(cmd)
            time.sleep(rng.uniform(0.0, 0.4))
            if proc.poll() is None:
                sig = rng.choice([signal.SIGKILL, signal.SIGKILL, signal.SIGTERM, signal.SIGINT])
                proc.send_signal(sig)
                kills += 1
            try:
                proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                hangs += 1
                proc.kill()
                proc.wait()
            if proc.returncode == 0:  # the run ended: check it, start another
                mismatches += not same(engine_result(ckpt), reference)
                ckpt.unlink()
        # Finish the last run and check it too.
        if ckpt.exists():
            subprocess.run([ENGINE, str(d / "p.iwrp"), *ARGS, "--checkpoint", str(ckpt),
                            "--resume", str(ckpt)], check=True)
            mismatches += not same(engine_result(ckpt), reference)
        left = [p.name for p in d.iterdir() if p.name.startswith(".k.ckpt.") and
                not p.name.endswith(".lock")]
        print(f"kills {kills}, engine starts {runs}, resumes {resumes}, mismatches {mismatches}, "
              f"hangs {hangs}, temporary files left {len(left)}")


if __name__ == "__main__":
    main()
