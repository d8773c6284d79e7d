"""False alarms of the gross-error tests on clean data (issue 22, item 3): Monte Carlo.

For each configuration and seed ``s`` (``--seeds``, default 200): a clean data set of ``--poses``
poses (default 50) with realistic noise (``iwr.simulate(robot, N, seed=s, noise=...)``, truth drawn
by the seed), split 80/20 by ``iwr.kinds.split(data, 0.2, seed=s)``, identified, and every pose
tested once at the identified parameters (no snooping: each test's own false-alarm rate):

- ``pose/none``: poses in {0}, eq. (10) by LM, no noise model: Pope's tau test
  (``iwr.gross_errors.find_gross_errors(..., noise=None)``) on identification and held-out poses;
- ``pose/model``: the efficient estimator with ``Noise.realistic()`` (``outliers="report"``: its
  per-pose chi-square test on the identification poses) and the held-out poses' chi-square test;
- ``points/none``, ``points/model``: the same on laser-tracker points (3 reflectors; the leg and
  joint noise of ``Noise.realistic()`` and ``TrackerNoise.leica()``).

Printed per configuration and data set (identification, validation): poses tested, poses failing,
the rate with its exact (Clopper-Pearson) 95 % interval, against the nominal ``--alpha`` (default
0.001 per pose), and the share of data sets with at least one false alarm.

Usage::

    python benchmarks/bench_gross_errors.py [--seeds 200] [--poses 50] [--alpha 0.001]
        [--configs pose/none,pose/model,points/none,points/model]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402

from scipy import stats  # noqa: E402

import iwr  # noqa: E402
from iwr import kinds  # noqa: E402
from iwr.gross_errors import find_gross_errors  # noqa: E402
from iwr.tracker import TrackerNoise  # noqa: E402

REGISTRATION = (2000.0, 0.0, 0.0, math.pi / 2, 0.0, 0.0)
REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    a = 1.0 - level
    lo = 0.0 if k == 0 else float(stats.beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(stats.beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


def one(config: str, seed: int, n_poses: int, alpha: float) -> dict[str, tuple[int, int]]:
    kind, model = config.split("/")
    real = iwr.Noise.realistic()
    if kind == "pose":
        robot = iwr.Robot.default()
        noise: object = real
    else:
        robot = iwr.Robot.default().with_tracker(registration=REGISTRATION, reflectors=REFLECTORS)
        noise = (iwr.Noise(legs=real.legs, joint_lengths=real.joint_lengths,
                           joint_angles=real.joint_angles), TrackerNoise.leica())
    data, _ = iwr.simulate(robot, n_poses, seed=seed, noise=noise)
    ident, val = kinds.split(data, 0.2, seed)
    if model == "none":
        res = iwr.identify(robot, ident, "lm", active="base")
        found = find_gross_errors(robot, ident, res.x, None, validation=val, active=res["active"],
                                  alpha=alpha)
        n_ident_bad = sum(o.data_set == "identification" for o in found.outliers)
    else:
        res = iwr.identify(robot, ident, "efficient", noise=noise, outliers="report",
                           outlier_alpha=alpha)
        found = find_gross_errors(robot, ident, res.x, res["noise"], validation=val,
                                  active=res["active"], alpha=alpha, test_identification=False)
        n_ident_bad = len(res["outliers"])
    n_val_bad = sum(o.data_set == "validation" for o in found.outliers)
    return {"identification": (n_ident_bad, len(ident)), "validation": (n_val_bad, len(val))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=200)
    ap.add_argument("--poses", type=int, default=50)
    ap.add_argument("--alpha", type=float, default=1e-3)
    ap.add_argument("--configs", default="pose/none,pose/model,points/none,points/model")
    args = ap.parse_args()
    print(f"clean data sets: {args.seeds} seeds, N = {args.poses} poses (80 % identification, "
          f"20 % held out), realistic noise; nominal rate alpha = {args.alpha:g} per pose")
    print("| configuration | poses | tested | failing | rate | 95 % interval | sets with a "
          "false alarm |")
    print("|---|---|---|---|---|---|---|")
    for config in args.configs.split(","):
        t0 = time.perf_counter()
        tot = {"identification": [0, 0, 0], "validation": [0, 0, 0]}
        for s in range(args.seeds):
            for what, (bad, n) in one(config, s, args.poses, args.alpha).items():
                tot[what][0] += bad
                tot[what][1] += n
                tot[what][2] += bad > 0
        for what, (bad, n, sets) in tot.items():
            lo, hi = clopper_pearson(bad, n)
            print(f"| {config} | {what} | {n} | {bad} | {bad / n:.5f} | {lo:.5f} .. {hi:.5f} | "
                  f"{sets} of {args.seeds} |", flush=True)
        print(f"<!-- {config}: {time.perf_counter() - t0:.0f} s -->", flush=True)


if __name__ == "__main__":
    main()
