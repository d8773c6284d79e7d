"""Monte Carlo of issue 23's "Checked by", item 2 (docs/effects.md, "The Monte Carlo"): realistic
noise on every instrument (iwr.Noise.realistic()) and realistic compliance and temperature drift
(iwr.effects.api.realistic: 0.01 um/N +-30 % per leg, steel legs, 20 C -3 .. +5 K), the
calibration's loads none and an 80 kg head, fresh poses with a 40 kg and a 120 kg load at other
temperatures; both calibrations by the efficient estimator, judged on the fresh poses against
the simulation's truth (iwr.effects.study.trial).

    python benchmarks/effects_monte_carlo.py [--seeds 20] [--poses 80] [--fresh 50]
        [--scales 0,0.1,0.25,0.5,0.75,1] [--sweep-seeds 20] [--json out.json]

(a) the sweep: the share of seeds whose geometric-only calibration fails its fit test, at the
compliance and temperature spread scaled by each factor; (b) at scale 1, the geometric model's
tool error on the fresh poses over the extended model's; (c) the extended model's actual over
predicted tool accuracy, per seed and over the seeds (RMS over RMS).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import tempfile
import time

import numpy as np
from tqdm import tqdm

import iwr
from iwr.effects.study import trial


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--poses", type=int, default=80)
    ap.add_argument("--fresh", type=int, default=50)
    ap.add_argument("--scales", default="0,0.1,0.25,0.5,0.75,1")
    ap.add_argument("--sweep-seeds", type=int, default=20)
    ap.add_argument("--json", default=None, help="write every trial's figures there")
    a = ap.parse_args()
    robot = iwr.Robot.default()
    scales = [float(s) for s in a.scales.split(",") if s]
    start = time.time()
    main_runs = [trial(robot, seed, n_poses=a.poses, n_fresh=a.fresh)
                 for seed in tqdm(range(a.seeds), desc="scale 1, both models", file=sys.stderr)]
    sweep: dict[float, list] = {}
    for s in scales:
        if s == 1.0 and a.sweep_seeds <= a.seeds:
            sweep[s] = main_runs[: a.sweep_seeds]
            continue
        sweep[s] = [trial(robot, seed, scale=s, n_poses=a.poses, n_fresh=a.fresh,
                          extended=False)
                    for seed in tqdm(range(a.sweep_seeds), desc=f"scale {s:g}, geometric",
                                     file=sys.stderr)]
    print(f"IWR, {a.poses} calibration poses, {a.fresh} fresh poses, iwr.Noise.realistic(); "
          f"{time.time() - start:.0f} s")
    print("\n(a) geometric-only calibration's fit test (efficient estimator, alpha 1e-3, its "
          "outlier removal on)")
    print("scale | effects on the readings (RMS um) | fit test failed | median p | median "
          "poses left out")
    for s, runs in sweep.items():
        fails = sum(not r.geometric_fit_ok for r in runs)
        print(f"{s:5g} | {1e3 * np.mean([r.effects_rms for r in runs]):6.1f} | "
              f"{fails}/{len(runs)} | {np.median([r.geometric_p_value for r in runs]):.2g} | "
              f"{np.median([r.geometric_outliers for r in runs]):g}")
    geo = np.array([r.geometric_tool_rms for r in main_runs])
    ext = np.array([r.extended_tool_rms for r in main_runs])
    pred = np.array([r.extended_predicted_rms for r in main_runs])
    gpred = np.array([r.geometric_predicted_rms for r in main_runs])
    ratio = geo / ext
    print(f"\n(b) tool position error on the fresh poses (RMS, um), {len(main_runs)} seeds")
    print(f"geometric-only: mean {1e3 * geo.mean():.1f} (its own prediction "
          f"{1e3 * gpred.mean():.1f}); extended: mean {1e3 * ext.mean():.1f}; ratio per seed: "
          f"median {np.median(ratio):.2f}, min {ratio.min():.2f}, max {ratio.max():.2f}; "
          f"ratio of the RMS over the seeds {math.sqrt(np.mean(geo**2) / np.mean(ext**2)):.2f}")
    print(f"extended model's fit test passed: {sum(bool(r.extended_fit_ok) for r in main_runs)}"
          f"/{len(main_runs)}")
    for what, key in (("failed by its fit check's range test (beyond the noise)",
                       "extended_out_of_range"),
                      ("outside the range at all (within the noise)", "extended_past_bound")):
        ranged = [(r.seed, getattr(r, key)) for r in main_runs if getattr(r, key)]
        print(f"extended model's effects {what}: {len(ranged)}/{len(main_runs)} seeds"
              + "".join(f"; seed {s}: {', '.join(n)}" for s, n in ranged))
    act = ext / pred
    print("\n(c) extended model: actual / predicted tool position RMS on the fresh poses")
    print(f"over the seeds (RMS of the actual / RMS of the predicted): "
          f"{math.sqrt(np.mean(ext**2) / np.mean(pred**2)):.3f}; per seed: median "
          f"{np.median(act):.2f}, 10-90 % {np.percentile(act, 10):.2f}-"
          f"{np.percentile(act, 90):.2f}, min {act.min():.2f}, max {act.max():.2f}")
    if a.json:
        out = {"settings": vars(a), "main": [dataclasses.asdict(r) for r in main_runs],
               "sweep": {str(s): [dataclasses.asdict(r) for r in runs]
                         for s, runs in sweep.items()}}
        d = os.path.dirname(os.path.abspath(a.json))
        with tempfile.NamedTemporaryFile("w", dir=d, delete=False, suffix=".tmp") as f:
            json.dump(out, f, indent=1)
        os.replace(f.name, a.json)


if __name__ == "__main__":
    main()
