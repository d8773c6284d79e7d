"""Monte Carlo of the calibration job on laser-tracker data with effects (issue 23,
docs/effects.md, "The calibration job on tracker data"): per seed the true machine and data of
benchmarks/effects_tracker_monte_carlo.py (random geometric errors and setup, leg compliances
0.01 um/N +-30 %, steel legs, three payloads, every instrument's noise, reflector points with
one hidden at 10 % of the poses), no gross error; `iwr.calibrate(robot, data, METHOD,
noise=...)` holding a fifth of the poses out; judged on 50 fresh poses with other loads
(40 kg off-axis, 120 kg 250 mm out) at 14 .. 30 C against the truth.

    python benchmarks/effects_tracker_job_mc.py [--method efficient|lm] [--seeds 20]
        [--poses 60] [--fresh 50] [--json out.json]

Prints per seed whether the job calibrated (fit test, the effects' range, the gross-error
screen: on these clean data a failure is a false alarm), the poses its outlier tests flagged,
the tool position error on the fresh poses (RMS) actual and predicted there by the job's
covariance, and the summary over the seeds.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
from tqdm import tqdm

import iwr
from iwr.effects import api
from iwr.effects.tracker_study import job_trial

REGISTRATION = (2000.0, -150.0, 300.0, 1.5, 0.01, -0.02)
REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]


def _rms(v: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(v))))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--method", choices=("efficient", "lm"), default="efficient")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--poses", type=int, default=60)
    ap.add_argument("--fresh", type=int, default=50)
    ap.add_argument("--json", default=None, help="write every trial's figures there")
    a = ap.parse_args()
    robot = iwr.Robot.default().with_tracker(registration=REGISTRATION, reflectors=REFLECTORS)
    robot = robot.with_effects(*api.realistic(robot))
    start = time.time()
    runs = [job_trial(robot, seed, a.method, a.poses, a.fresh)
            for seed in tqdm(range(a.seeds), desc=a.method, file=sys.stderr)]
    print(f"IWR, tracker points (K = 3), iwr.calibrate(method={a.method!r}, noise=...), "
          f"{a.poses} poses (a fifth held out), {a.fresh} fresh poses; "
          f"{time.time() - start:.0f} s")
    print("seed  job      p-value  flagged  actual (um)  predicted (um)  ratio")
    for r in runs:
        print(f"{r['seed']:4d}  {'ok' if r['success'] else 'FAIL':7s}  {r['p_value']:7.3f}  "
              f"{r['flagged']:7d}  {1e3 * r['tool_rms']:11.2f}  {1e3 * r['predicted_rms']:14.2f}"
              f"  {r['tool_rms'] / r['predicted_rms']:5.2f}")
    act = np.array([r["tool_rms"] for r in runs])
    pred = np.array([r["predicted_rms"] for r in runs])
    ratios = act / pred
    failed = sum(not r["success"] for r in runs)
    flagged = sum(r["flagged"] for r in runs)
    print(f"\nactual / predicted tool accuracy: RMS over the seeds {_rms(act) / _rms(pred):.3f} "
          f"({1e3 * _rms(act):.2f} um / {1e3 * _rms(pred):.2f} um); per seed median "
          f"{np.median(ratios):.3f} (10-90 %: {np.quantile(ratios, 0.1):.3f} .. "
          f"{np.quantile(ratios, 0.9):.3f}; min .. max {ratios.min():.3f} .. "
          f"{ratios.max():.3f})")
    print(f"false alarms on clean data: the job failed {failed} of {len(runs)} seeds; its "
          f"outlier tests flagged {flagged} of {len(runs) * a.poses} poses; fit test p-values "
          f"median {np.median([r['p_value'] for r in runs]):.3f}")
    if a.json:
        from iwr._io import atomic_write_text

        atomic_write_text(a.json, json.dumps(runs, indent=1))


if __name__ == "__main__":
    main()
