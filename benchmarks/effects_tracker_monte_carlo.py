"""Monte Carlo of the efficient estimator with the effects on laser-tracker data (issue 23,
docs/effects.md, "Tracker data"): per seed a true IWR with random geometric errors and a random
setup (within their default bounds), leg compliances of 0.01 um/N +-30 % (per leg), steel legs
(11.5 ppm/K) at 20 C -3 .. +5 K, the calibration's payloads none, an 80 kg head and a 60 kg
tool off-axis in turn (their centres not on one line: docs/effects.md), the instruments' noise
(legs 2 um, joints 5 um and 5 urad, Leica's tracker model), reflector points (K = 3, one hidden
at 10 % of the poses) or a probe; calibrated with the effects (per-leg compliances, a shared
alpha) and geometric-only, both by the efficient estimator with its defaults; each judged on
fresh poses with other loads (40 kg off-axis, 120 kg 250 mm out) at 14 .. 30 C: the tool
position in {T} modulo the gauge that the model's forward kinematics gives from the true,
noise-free readings, against the truth's (iwr.accuracy with truth=).

    python benchmarks/effects_tracker_monte_carlo.py [--kind points|probe] [--seeds 20]
        [--poses 60] [--fresh 50] [--json out.json]

Prints per seed the extended model's actual and predicted tool accuracy (RMS over the fresh
poses; predicted there, under their loads and temperatures, by
iwr.effects.tracker.predicted_accuracy from the estimator's covariance) and their ratio, its fit
test, the geometric-only model's fit test and actual error, and the summary over the seeds.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np
from tqdm import tqdm

import iwr
from iwr.effects import api
from iwr.effects.tracker_study import trial

REGISTRATION = (2000.0, -150.0, 300.0, 1.5, 0.01, -0.02)
REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
PROBE = (10.0, -5.0, 60.0, 0.1, 0.0, 0.2)


def _rms(v: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(v))))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--kind", choices=("points", "probe"), default="points")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--poses", type=int, default=60)
    ap.add_argument("--fresh", type=int, default=50)
    ap.add_argument("--json", default=None, help="write every trial's figures there")
    a = ap.parse_args()
    base = iwr.Robot.default()
    robot = (base.with_tracker(registration=REGISTRATION, reflectors=REFLECTORS)
             if a.kind == "points" else base.with_tracker(registration=REGISTRATION, probe=PROBE))
    robot = robot.with_effects(*api.realistic(robot))
    start = time.time()
    runs = [trial(robot, seed, a.poses, a.fresh)
            for seed in tqdm(range(a.seeds), desc=a.kind, file=sys.stderr)]
    print(f"IWR, tracker {a.kind}, {a.poses} calibration poses (payloads none / 80 kg / 60 kg "
          f"in turn), {a.fresh} fresh poses (40 kg / 120 kg, 14 .. 30 C); "
          f"{time.time() - start:.0f} s")
    print("seed  ext.actual  ext.predicted  ratio  ext.fit(p)  geo.actual  geo.fit(p)  "
          "compl.err(um/N)  alpha.err/sd")
    for r in runs:
        ratio = r["extended_tool_rms"] / r["extended_predicted_rms"]
        print(f"{r['seed']:4d}  {1e3 * r['extended_tool_rms']:8.2f} um  "
              f"{1e3 * r['extended_predicted_rms']:9.2f} um  {ratio:5.2f}  "
              f"{'ok' if r['extended_fit_ok'] else 'FAIL'}({r['extended_p_value']:.2g})  "
              f"{1e3 * r['geometric_tool_rms']:8.2f} um  "
              f"{'ok' if r['geometric_fit_ok'] else 'FAIL'}({r['geometric_p_value']:.2g})  "
              f"{r['compliance_error_rms']:.4f}  {r['alpha_error'] / r['alpha_sd']:+.2f}")
    ratios = np.array([r["extended_tool_rms"] / r["extended_predicted_rms"] for r in runs])
    act = np.array([r["extended_tool_rms"] for r in runs])
    pred = np.array([r["extended_predicted_rms"] for r in runs])
    geo = np.array([r["geometric_tool_rms"] for r in runs])
    print(f"\nextended: actual / predicted, RMS over the seeds {_rms(act) / _rms(pred):.3f}; "
          f"per seed median {np.median(ratios):.3f} (10-90 %: "
          f"{np.quantile(ratios, 0.1):.3f} .. {np.quantile(ratios, 0.9):.3f}; "
          f"min {ratios.min():.3f}, max {ratios.max():.3f})")
    print(f"extended fit test passed {sum(r['extended_fit_ok'] for r in runs)}/{len(runs)}; "
          f"geometric-only passed {sum(r['geometric_fit_ok'] for r in runs)}/{len(runs)}")
    print(f"tool error on the fresh poses, RMS over the seeds: extended {1e3 * _rms(act):.2f} um "
          f"(predicted {1e3 * _rms(pred):.2f}), geometric-only {1e3 * _rms(geo):.2f} um; "
          f"geometric / extended per seed median {np.median(geo / act):.2f} "
          f"(min {np.min(geo / act):.2f}, max {np.max(geo / act):.2f})")
    if a.json:
        from iwr._io import atomic_write_text

        atomic_write_text(a.json, json.dumps(
            {"kind": a.kind, "poses": a.poses, "fresh": a.fresh, "runs": runs}, indent=1,
            default=lambda v: None if isinstance(v, float) and not math.isfinite(v) else v))


if __name__ == "__main__":
    main()
