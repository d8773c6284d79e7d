"""Monte-Carlo check of the noise-weighted ballbar identification (docs/ballbar.md): the true robot,
set-ups and poses fixed, fresh reading and bar noise per seed; the actual accuracy against the
predicted one (first order, eq. (10)-style weighted covariance).

    python benchmarks/ballbar_mc.py [N] [SEEDS] [SETUPS]

Per seed: the weighted LM on the base parameters; on 100 fresh noise-free poses, the error of
each predicted bar reading against the true one (actual) and its predicted standard deviation
``sqrt(g^T C g)`` (:func:`iwr.ballbar.reading_std`); the Mahalanobis distance of the identified
base parameters from the noise-free solution (in the same gauge) per parameter; the
gauge-aligned tool pose errors (actual only).
"""

from __future__ import annotations

import sys
import time
from typing import Any

import numpy as np

import iwr
from iwr.ballbar import BallbarMeasurements, BallbarNoise, ballbar_problem, reading_std

BARS = {
    "A": {"platform_ball": [0.0, 0.0, -60.0], "fixed_ball": [800.0, -800.0, 1500.0],
          "range": [300.0, 700.0]},
    "B": {"platform_ball": [100.0, 50.0, -60.0], "fixed_ball": [900.0, -200.0, 2400.0],
          "range": [300.0, 700.0]},
    "C": {"platform_ball": [-80.0, 60.0, -40.0], "fixed_ball": [700.0, -1500.0, 1200.0],
          "range": [300.0, 700.0]},
}
READINGS = iwr.Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6)
BAR = BallbarNoise(0.001)
NOISE = (READINGS, BAR)


def perturbed(robot: iwr.Robot, clean: BallbarMeasurements,
              rng: np.random.Generator) -> BallbarMeasurements:
    """The same poses with fresh noise: joint, leg and bar readings (as the simulation draws)."""
    sigma_q = np.where([c == "P" for c in robot.joint_types], READINGS.joint_lengths,
                       READINGS.joint_angles)
    q = clean.q + sigma_q * rng.standard_normal(clean.q.shape)
    legs = clean.legs + READINGS.legs * rng.standard_normal(clean.legs.shape)
    d = clean.distance + BAR.distance * rng.standard_normal(len(clean))
    return BallbarMeasurements(q, legs, clean.setup, d, joint_types=clean.joint_types)


def run(n: int = 200, seeds: int = 20, names: str = "AB") -> dict[str, Any]:
    """The Monte Carlo; its figures as a dictionary (``ratio``: actual / predicted RMS error of
    the fresh readings over all seeds)."""
    robot = iwr.Robot.default().with_instrument("ballbar", {k: BARS[k] for k in names})
    clean, truth = iwr.simulate(robot, n, seed=1)
    fresh, _ = iwr.simulate(robot, 100, seed=2, x=truth)
    fresh_problem, _ = ballbar_problem(robot, fresh)
    true_fresh = fresh_problem.predicted(truth)
    mask = iwr.identifiability(robot, clean).active
    ref = iwr.identify(robot, clean, "lm", noise=NOISE, active=mask).x  # truth, in the gauge
    start = time.time()
    actual, predicted, maha, tool, chi2_p = [], [], [], [], []
    for seed in range(seeds):
        data = perturbed(robot, clean, np.random.default_rng(1000 + seed))
        res = iwr.identify(robot, data, "lm", noise=NOISE, active=mask)
        assert res.success, res.message
        unc = iwr.uncertainty(robot, data, res.x, NOISE, active=mask, weighted=True)
        err = fresh_problem.predicted(res.x) - true_fresh
        actual.append(float(np.mean(err**2)))
        predicted.append(float(np.mean(reading_std(robot, fresh, res.x, unc) ** 2)))
        dev = res.x[mask] - ref[mask]
        maha.append(float(dev @ np.linalg.solve(unc.covariance, dev)) / int(mask.sum()))
        tool.append(iwr.accuracy(robot, fresh, res.x, truth=truth).calibrated.position)
        chi2_p.append(res.fit.p_value)
    per_seed = np.sqrt(np.array(actual) / np.array(predicted))
    return {"names": names, "n": n, "seeds": seeds, "n_base": int(mask.sum()),
            "n_params": mask.size, "actual": float(np.sqrt(np.mean(actual))),
            "predicted": float(np.sqrt(np.mean(predicted))),
            "ratio": float(np.sqrt(np.mean(actual) / np.mean(predicted))), "per_seed": per_seed,
            "maha": np.array(maha), "chi2_p": np.array(chi2_p), "tool": np.concatenate(tool),
            "elapsed": time.time() - start}


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 200
    seeds = int(sys.argv[2]) if len(sys.argv) > 2 else 20
    out = run(n, seeds, sys.argv[3] if len(sys.argv) > 3 else "AB")
    per_seed, maha, tool = out["per_seed"], out["maha"], out["tool"]
    print(f"ballbar Monte Carlo: IWR, set-ups {', '.join(out['names'])}, N = {n}, {seeds} seeds, "
          f"{out['n_base']} base parameters of {out['n_params']}; noise legs {READINGS.legs} mm, "
          f"joints {READINGS.joint_lengths} mm / {READINGS.joint_angles} rad, bar "
          f"{BAR.distance} mm")
    print(f"fresh readings (100 poses): actual RMS error {out['actual'] * 1e3:.3f} um, "
          f"predicted {out['predicted'] * 1e3:.3f} um, actual/predicted {out['ratio']:.3f}")
    print(f"  per seed actual/predicted: mean {per_seed.mean():.3f}, std "
          f"{per_seed.std(ddof=1):.3f}, min {per_seed.min():.3f}, max {per_seed.max():.3f}")
    print(f"base parameters: Mahalanobis distance / p from the noise-free solution: mean "
          f"{maha.mean():.3f} (1 expected; std of the mean over seeds "
          f"{maha.std(ddof=1) / np.sqrt(seeds):.3f})")
    print(f"chi-square p-values: min {out['chi2_p'].min():.3f}, median "
          f"{np.median(out['chi2_p']):.3f}")
    print(f"tool position error, gauge-aligned (actual): RMS "
          f"{np.sqrt(np.mean(tool**2)) * 1e3:.2f} um, max {tool.max() * 1e3:.2f} um")
    print(f"{out['elapsed']:.1f} s ({out['elapsed'] / seeds:.2f} s per seed)")

if __name__ == "__main__":
    main()
