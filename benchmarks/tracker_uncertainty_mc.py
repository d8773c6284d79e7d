"""Monte-Carlo check of iwr.uncertainty on laser-tracker data (docs/tracker.md, "Uncertainty and
pose planning"): the true robot and poses fixed, fresh reading and tracker noise per seed; the
spread of the identified parameters against the predicted standard deviations.

    python benchmarks/tracker_uncertainty_mc.py [points|probe] [N] [SEEDS]
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np

import iwr
from iwr.tracker import TrackerNoise, perturb_measurements
from iwr.tracker.analysis import null_space
from iwr.tracker.api import tracker_problem

REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
REGISTRATION = (2000.0, 0.0, 0.0, math.pi / 2, 0.0, 0.0)
READINGS = iwr.Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6)
TRACKER = TrackerNoise.leica()


def main() -> None:
    kind = sys.argv[1] if len(sys.argv) > 1 else "points"
    n = int(sys.argv[2]) if len(sys.argv) > 2 else 60
    seeds = int(sys.argv[3]) if len(sys.argv) > 3 else 40
    kw = {"reflectors": REFLECTORS} if kind == "points" else {"probe": (0, 0, 60, 0, 0, 0)}
    robot = iwr.Robot.default().with_tracker(registration=REGISTRATION, **kw)
    clean, _ = iwr.simulate(robot, n, seed=1)
    problem, x0 = tracker_problem(robot, clean)
    mask = null_space(problem, x0).active
    # The truth in the gauge of the held parameters (held at x0, as in every run below).
    ref = iwr.identify(robot, clean, x0=x0, active=mask).x
    pred = iwr.uncertainty(robot, clean, ref, noise=(READINGS, TRACKER), active=mask)
    start = time.time()
    runs = []
    for seed in range(seeds):
        res = iwr.identify(robot, perturb_measurements(robot, clean, READINGS, TRACKER,
                                                     np.random.default_rng(1000 + seed)),
                           x0=x0, active=mask)
        assert res.success, res.message
        runs.append(res.x[mask])
    x = np.array(runs)
    ratio = x.std(axis=0, ddof=1) / pred.std[mask]
    dev = x - ref[mask]
    maha = np.einsum("si,ij,sj->s", dev, np.linalg.inv(pred.covariance), dev) / mask.sum()
    print(f"{kind} N={n} seeds={seeds} p={mask.sum()} ({time.time() - start:.1f} s)")
    print(f"std ratio empirical/predicted: median {np.median(ratio):.3f}, 10-90 % "
          f"{np.percentile(ratio, 10):.3f}-{np.percentile(ratio, 90):.3f}, min "
          f"{ratio.min():.3f}, max {ratio.max():.3f}")
    print(f"mean Mahalanobis / p of (x - x_ref): {maha.mean():.3f} (1 expected)")


if __name__ == "__main__":
    main()
