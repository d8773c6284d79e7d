"""The size test's false alarms and power over seeds: the efficient estimator on simulated pose
data, the size test with and without the estimate's spread (``iwr.fit_test.beyond_plausible``
with and without its covariance), on clean data (false alarms: the truth is within the plausible
size) and on data whose frame is shifted along z0 (power: the shift is absorbed by joint 1's d and
joint 2's a, beyond their plausible size; the chi-square test alone passes).

For each noise level (``--noise-factor``: times ``Noise.realistic()``, the data simulated and
weighted with it) and seed, the script counts a failure of the size test without the spread
("old": any entry of the smallest equivalent vector beyond its limit) and with it ("new": beyond
by more than its standard deviation explains at the fit test's level, what ``iwr`` does since the
change), and on the shifted data the same and the chi-square test's failures.

Usage::

    cd /tmp && python /path/to/iwr/benchmarks/size_test_mc.py --noise-factor 1 3 10 \\
        --poses 60 --seeds 200 --shift 12
"""

from __future__ import annotations

import argparse

import numpy as np
from tqdm import tqdm

import iwr
from iwr.fit_test import _plausible_limit, beyond_plausible, leg_readings


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--noise-factor", type=float, nargs="+", default=[1.0, 10.0])
    ap.add_argument("--poses", type=int, default=60)
    ap.add_argument("--seeds", type=int, default=200, help="seeds 0 .. SEEDS-1 (default 200)")
    ap.add_argument("--shift", type=float, default=12.0,
                    help="the frame's shift along z0 of the power runs, mm (default 12; 0: none)")
    args = ap.parse_args()
    robot = iwr.Robot.default()
    limit = _plausible_limit(robot, 10.0, None)
    active = iwr.identifiability(robot, iwr.simulate(robot, 60, seed=0)[0]).active
    print(f"efficient estimator, {args.poses} poses, seeds 0-{args.seeds - 1}; size test at "
          "10 times the default bounds, the fit test's alpha 1e-3\n")
    print("| noise | data | size test without the spread | with it (iwr) | chi-square fails |")
    print("|---|---|---|---|---|")
    for factor in args.noise_factor:
        noise = iwr.Noise(**{k: factor * v for k, v in vars(iwr.Noise.realistic()).items()})
        for shift in ([0.0, args.shift] if args.shift else [0.0]):
            old = new = chi = 0
            for seed in tqdm(range(args.seeds), desc=f"x{factor:g}, shift {shift:g}",
                             leave=False):
                m, _ = iwr.simulate(robot, args.poses, seed=seed, noise=noise)
                if shift:
                    m = iwr.Measurements(m.q, m.poses + [0, 0, shift, 0, 0, 0], m.legs,
                                         joint_types=m.joint_types)
                res = iwr.estimation.efficient(robot, m, noise, active=active)
                old += bool(beyond_plausible(leg_readings(robot, m), res.x, limit, None,
                                             robot.parameter_names))
                new += bool(res.fit.implausible)
                chi += bool(res.fit.p_value < 1e-3)
            data = f"frame shifted {shift:g} mm along z0" if shift else "clean"
            print(f"| x{factor:g} | {data} | {old} of {args.seeds} | {new} of {args.seeds} | "
                  f"{chi} of {args.seeds} |", flush=True)


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
