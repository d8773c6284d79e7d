"""The effects' range test (docs/effects.md, "The range check") on machines at the bound of
their range: legs with no compliance (0 of the plausible 0 .. 0.05 um/N), every instrument's
realistic noise, LM without a noise model (the standard deviations from the residuals) and the
efficient estimator with the true one. Half the identified compliances fall below 0 by the
noise; the test should fail at most alpha (0.001) of the seeds, and the standardised departures
``(c - 0) / sd`` should be standard normal (their share below -1.645: 5 %).

    python benchmarks/effects_range_test.py [--seeds 40] [--poses 60]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from scipy import special
from tqdm import tqdm

import iwr
from iwr.effects import api
from iwr.effects.problem import parameter_sd


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=40)
    ap.add_argument("--poses", type=int, default=60)
    a = ap.parse_args()
    base = iwr.Robot.default()
    robot = base.with_effects(*api.realistic(base))
    n = robot.n_params
    noise = iwr.Noise.realistic()
    x = np.zeros(n + 7)
    x[n: n + 6] = -0.01  # the file's 0.01 um/N: no compliance
    z = {"lm": [], "efficient": []}
    failed = {"lm": 0, "efficient": 0}
    below = {"lm": 0, "efficient": 0}
    for seed in tqdm(range(a.seeds), file=sys.stderr):
        m, _ = api.simulate(robot, a.poses, seed=seed, x=x, noise=noise)
        for method in ("lm", "efficient"):
            r = iwr.identify(robot, m, method, **({"noise": noise} if method == "efficient"
                                                   else {"active": "base"}))
            if method == "lm":
                sd = parameter_sd(robot, m, r.x, r.active)
            else:  # the estimator's covariance
                sd = np.asarray(r.std, dtype=float)
            c = r.x[n: n + 6] + 0.01
            z[method] += list(c / sd[n: n + 6])
            below[method] += int(np.any(c < 0))
            failed[method] += int(any("outside their plausible range" in t
                                      for t in r.fit.causes))
    zq = float(special.ndtri(1 - 1e-3 / 7))
    print(f"IWR, {a.poses} poses, iwr.Noise.realistic(), legs with no compliance, {a.seeds} "
          f"seeds; the test's z = {zq:.2f} (alpha 0.001 over 7 effect parameters)")
    for method in ("lm", "efficient"):
        zs = np.array(z[method])
        print(f"{method}: a compliance identified below 0 in {below[method]}/{a.seeds} seeds; "
              f"range test failed {failed[method]}/{a.seeds}; standardised compliances: mean "
              f"{zs.mean():+.2f}, sd {zs.std():.2f}, below -1.645: {np.mean(zs < -1.645):.3f}, "
              f"min {zs.min():.2f}")


if __name__ == "__main__":
    main()
