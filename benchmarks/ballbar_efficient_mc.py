"""Monte-Carlo check of the efficient (implicit-loop) estimator on double-ballbar data
(docs/ballbar.md, "The efficient estimator"): the true robot, set-ups and poses fixed (those of
``ballbar_mc.py``), fresh leg, joint and bar noise per seed.

    python benchmarks/ballbar_efficient_mc.py [N] [SEEDS] [SETUPS] [FIRST_SEED]

Per seed, ``iwr.identify(robot, data, "efficient", noise=...)`` on the base parameters; on 100
fresh noise-free poses of the true robot:

- the tool pose error modulo what a ballbar cannot see (``iwr.accuracy(..., truth=...)``: the
  frames aligned by the best rigid motions of {0} and {5}), actual, against the estimator's
  prediction from its covariance (``result.predicted``'s computation,
  ``ballbar_predicted_accuracy``, on the fresh poses), position and orientation: the ratio
  ``sqrt(mean_s actual^2 / mean_s predicted^2)`` over the seeds, a bootstrap 90 % interval, and
  the per-seed ratios' spread;
- the same against the Cramer-Rao bound: the covariance of the estimator at the truth (its
  solution on the noise-free readings of the same poses), the same on every seed;
- each fresh bar reading's error against its predicted standard deviation;
- the Mahalanobis distance of the base parameters from the noise-free solution (same gauge), per
  parameter (1 expected), the chi-square p-values (KS test against the uniform law), the
  outliers removed (clean data: 0.1 % of poses expected), and the noise-weighted LM's tool
  position error on the same data (the first-order equivalent: ratio near 1).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import sys  # noqa: E402
import time  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
from ballbar_mc import BARS, NOISE, perturbed  # noqa: E402  (benchmarks/ is on sys.path)
from bench_estimation import crb  # noqa: E402
from scipy import stats  # noqa: E402

import iwr  # noqa: E402
from iwr.ballbar import ballbar_problem  # noqa: E402
from iwr.ballbar.estimation import ballbar_predicted_accuracy  # noqa: E402


def rms(v: Any) -> float:
    return float(np.sqrt(np.mean(np.square(v))))


def run(n: int = 200, seeds: int = 20, names: str = "AB", first: int = 1000) -> dict[str, Any]:
    """The Monte Carlo; per seed rows of figures (mm, degrees), and the fixed ones."""
    robot = iwr.Robot.default().with_instrument("ballbar", {k: BARS[k] for k in names})
    clean, truth = iwr.simulate(robot, n, seed=1)
    fresh, _ = iwr.simulate(robot, 100, seed=2, x=truth)
    fresh_problem, _ = ballbar_problem(robot, fresh)
    true_fresh = fresh_problem.predicted(truth)
    mask = iwr.identifiability(robot, clean).active
    # The estimator on the noise-free readings: the truth in the gauge of the base parameters,
    # and its covariance there (the noise model's, at the true poses): the Cramer-Rao bound.
    ref = iwr.identify(robot, clean, "efficient", noise=NOISE, active=mask)
    bound = ballbar_predicted_accuracy(robot, fresh, ref.x, ref.covariance, mask)
    rows, chi2_p, maha, removed, success = [], [], [], 0, 0
    start = time.time()
    for seed in range(seeds):
        data = perturbed(robot, clean, np.random.default_rng(first + seed))
        res = iwr.identify(robot, data, "efficient", noise=NOISE, active=mask)
        success += bool(res.success)
        removed += sum(o.removed for o in res.outliers)
        chi2_p.append(res.fit.p_value)
        acc = iwr.accuracy(robot, fresh, res.x, truth=truth).calibrated
        pred = ballbar_predicted_accuracy(robot, fresh, res.x, res.covariance, mask)
        g = fresh_problem.jacobian(res.x)[:, mask]
        reading_var = np.einsum("ki,ij,kj->k", g, res.covariance, g)
        err = fresh_problem.predicted(res.x) - true_fresh
        dev = res.x[mask] - ref.x[mask]
        maha.append(float(dev @ np.linalg.solve(res.covariance, dev)) / int(mask.sum()))
        lm = iwr.identify(robot, data, "lm", noise=NOISE, active=mask)
        lm_acc = iwr.accuracy(robot, fresh, lm.x, truth=truth).calibrated
        rows.append([rms(acc.position), pred.position_rms, rms(acc.orientation),
                     pred.orientation_rms, rms(err), float(np.sqrt(np.mean(reading_var))),
                     rms(lm_acc.position)])
    return {"names": names, "n": n, "seeds": seeds, "first": first, "n_base": int(mask.sum()),
            "n_params": mask.size, "rows": np.array(rows), "bound": bound,
            "chi2_p": np.array(chi2_p), "maha": np.array(maha), "removed": removed,
            "success": success, "dof": int(res.fit.dof), "elapsed": time.time() - start}


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 200
    seeds = int(sys.argv[2]) if len(sys.argv) > 2 else 20
    out = run(n, seeds, sys.argv[3] if len(sys.argv) > 3 else "AB",
              int(sys.argv[4]) if len(sys.argv) > 4 else 1000)
    r, bound = out["rows"], out["bound"]
    readings, bar = NOISE
    print(f"efficient estimator on ballbar data: IWR, set-ups {', '.join(out['names'])}, N = {n}, "
          f"{seeds} seeds from {out['first']}, {out['n_base']} base parameters of "
          f"{out['n_params']}; noise legs "
          f"{readings.legs} mm, joints {readings.joint_lengths} mm / {readings.joint_angles} rad, "
          f"bar {bar.distance} mm; 100 fresh noise-free poses")
    rng = np.random.default_rng(0)
    print("\n| on the fresh poses | actual RMS | predicted RMS | actual / predicted (90 % "
          "bootstrap) | per seed: mean, std, min-max | Cramer-Rao bound | actual / bound |")
    print("|---|---|---|---|---|---|---|")
    for what, a, p, b, unit, scale in (
            ("tool position (gauge-aligned)", r[:, 0], r[:, 1], bound.position_rms, "um", 1e3),
            ("tool orientation (gauge-aligned)", r[:, 2], r[:, 3], bound.orientation_rms,
             "mdeg", 1e3),
            ("bar reading", r[:, 4], r[:, 5], None, "um", 1e3)):
        ratio, lo, hi = crb(a, p, rng)
        per = a / p
        b_text = "" if b is None else f"{b * scale:.3f} {unit}"
        b_ratio = "" if b is None else f"{np.sqrt(np.mean(a**2)) / b:.3f}"
        print(f"| {what} | {rms(a) * scale:.3f} {unit} | {rms(p) * scale:.3f} {unit} | "
              f"**{ratio:.3f}** ({lo:.3f} .. {hi:.3f}) | {per.mean():.3f}, "
              f"{per.std(ddof=1):.3f}, {per.min():.3f}-{per.max():.3f} | {b_text} | {b_ratio} |")
    maha, p_values = out["maha"], out["chi2_p"]
    print(f"\nbase parameters: Mahalanobis distance / p from the noise-free solution: mean "
          f"{maha.mean():.3f} (1 expected; std of the mean "
          f"{maha.std(ddof=1) / np.sqrt(seeds):.3f})")
    print(f"chi-square ({out['dof']} dof): p-values min {p_values.min():.3f}, median "
          f"{np.median(p_values):.3f}, KS against uniform p = "
          f"{stats.kstest(p_values, 'uniform').pvalue:.2f}; {out['success']} of {seeds} success; "
          f"{out['removed']} clean poses removed as outliers in {seeds * n}")
    print(f"weighted LM / efficient, tool position RMS over the seeds: "
          f"{rms(r[:, 6]) / rms(r[:, 0]):.3f}")
    print(f"{out['elapsed']:.1f} s ({out['elapsed'] / seeds:.2f} s per seed, both methods)")


if __name__ == "__main__":
    main()
