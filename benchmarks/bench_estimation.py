"""The efficient estimator (implicit loop, ``iwr.estimation.efficient``) against eq. (10).

Two tables:

1. **Time** of one solve (the C++ Schur-complement Levenberg-Marquardt, ``iwr._core.implicit_loop``,
   one thread, statistics included) at N = 25 .. 200 poses, ``Noise.realistic()`` data, from the
   nominal robot; median of ``--repeat`` runs. The full ``efficient`` call (base parameters,
   outlier tests, predicted accuracy) is timed too.
2. **Statistics** (``--seeds``, default 20): ``Noise.realistic()`` data, N = 100 poses per data set
   (``iwr.simulate(robot, 100, seed=s, noise=...)``, truth drawn by the seed), 200 fresh noise-free
   poses of the same true robot (``seed=10000 + s``). For eq. (10) (``iwr.identify(method="lm")``)
   and the estimator: the tool position and orientation RMS error on the fresh poses, by forward
   kinematics of the identified model from the exact readings, against the simulation's true poses
   (``iwr.accuracy``). The Cramer-Rao bound is the estimator's predicted RMS tool error on the same
   fresh poses (``iwr.estimation.predicted_accuracy`` from its covariance); its Monte-Carlo check is
   ``sqrt(mean over seeds of actual^2) / sqrt(mean over seeds of predicted^2)``, with a bootstrap
   90 % interval over the seeds.

Usage::

    python benchmarks/bench_estimation.py [--seeds 20] [--repeat 7] [--no-stats] [--no-time]
                                          [--vce] [--outliers]

``--vce``: the variance components (tracker sigma unknown; every sigma unknown) over the seeds;
``--outliers``: 5 gross errors of 1 mm per data set, found, missed, clean poses flagged, and the
tool accuracy after their removal against the clean data's.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

import iwr  # noqa: E402
from iwr import _core  # noqa: E402
from iwr import estimation as est  # noqa: E402


def time_table(repeat: int) -> None:
    robot = iwr.Robot.default()
    noise = iwr.Noise.realistic()
    print("| N | one solve (ms), median | iterations | full `efficient` call (ms) |")
    print("|---|---|---|---|")
    for n in (25, 50, 100, 200):
        m, _ = iwr.simulate(robot, n, seed=1, noise=noise)
        active = iwr.identifiability(robot, m).active
        idx = [int(i) for i in np.flatnonzero(active)]
        sigma = est.sigma_matrix(robot, m, noise)
        times, full = [], []
        out = None
        for _ in range(repeat):
            t = time.perf_counter()
            out = _core.implicit_loop(robot._geometry, np.zeros(robot.n_params), idx, m.q,
                                      m.poses, m.legs, sigma, np.zeros((0, 0)))
            times.append(time.perf_counter() - t)
            t = time.perf_counter()
            est.efficient(robot, m, noise, active=active)
            full.append(time.perf_counter() - t)
        print(f"| {n} | {1e3 * np.median(times):.1f} | {out['iterations']} | "
              f"{1e3 * np.median(full):.0f} |")


def stats_table(seeds: int) -> None:
    robot = iwr.Robot.default()
    noise = iwr.Noise.realistic()
    rows = []
    for s in range(seeds):
        m, truth = iwr.simulate(robot, 100, seed=s, noise=noise)
        fresh, _ = iwr.simulate(robot, 200, seed=10000 + s, x=truth)
        lm = iwr.identify(robot, m, "lm")
        ef = est.efficient(robot, m, noise)
        a_lm = iwr.accuracy(robot, fresh, lm.x).calibrated
        a_ef = iwr.accuracy(robot, fresh, ef.x).calibrated
        pred = est.predicted_accuracy(robot, fresh, ef.x, ef.covariance, active=ef.active)

        def rms(v: np.ndarray) -> float:
            return math.sqrt(float(np.mean(v**2)))

        rows.append((rms(a_lm.position), rms(a_ef.position), rms(a_lm.orientation),
                     rms(a_ef.orientation), pred.position_rms, pred.orientation_rms,
                     ef.success, len(ef.outliers)))
        print(f"seed {s:2d}: position RMS eq.(10) {rows[-1][0]:.5f} mm, efficient "
              f"{rows[-1][1]:.5f} mm (predicted {rows[-1][4]:.5f}); orientation "
              f"{rows[-1][2]:.6f} / {rows[-1][3]:.6f} deg (predicted {rows[-1][5]:.6f}); "
              f"success {ef.success}, {len(ef.outliers)} outlier(s)", flush=True)
    r = np.array([row[:6] for row in rows])
    pos_ratio = r[:, 0] / r[:, 1]
    ori_ratio = r[:, 2] / r[:, 3]
    rng = np.random.default_rng(0)

    def crb(actual: np.ndarray, predicted: np.ndarray) -> tuple[float, float, float]:
        ratio = math.sqrt(np.mean(actual**2) / np.mean(predicted**2))
        boot = []
        for _ in range(2000):
            i = rng.integers(0, len(actual), len(actual))
            boot.append(math.sqrt(np.mean(actual[i] ** 2) / np.mean(predicted[i] ** 2)))
        lo, hi = np.quantile(boot, [0.05, 0.95])
        return ratio, float(lo), float(hi)

    pc = crb(r[:, 1], r[:, 4])
    oc = crb(r[:, 3], r[:, 5])
    print()
    print(f"Noise.realistic(), N = 100, {seeds} seeds (0..{seeds - 1}), 200 fresh noise-free poses "
          "per seed")
    print()
    print("| | eq. (10) median | efficient median | ratio median | ratio min | ratio max |")
    print("|---|---|---|---|---|---|")
    print(f"| tool position RMS (mm) | {np.median(r[:, 0]):.5f} | {np.median(r[:, 1]):.5f} | "
          f"{np.median(pos_ratio):.3f} | {pos_ratio.min():.3f} | {pos_ratio.max():.3f} |")
    print(f"| tool orientation RMS (deg) | {np.median(r[:, 2]):.6f} | {np.median(r[:, 3]):.6f} | "
          f"{np.median(ori_ratio):.3f} | {ori_ratio.min():.3f} | {ori_ratio.max():.3f} |")
    print()
    print("| Cramer-Rao check | actual / predicted RMS over seeds | bootstrap 90 % |")
    print("|---|---|---|")
    print(f"| tool position | {pc[0]:.3f} | {pc[1]:.3f} .. {pc[2]:.3f} |")
    print(f"| tool orientation | {oc[0]:.3f} | {oc[1]:.3f} .. {oc[2]:.3f} |")
    print()
    print(f"efficient: success {sum(row[6] for row in rows)} of {seeds}; outliers removed "
          f"{sum(row[7] for row in rows)} in all")


def vce_table(seeds: int) -> None:
    """Variance components: legs and joints known, the tracker's noise unknown (started 2.5 times
    too large); and every component unknown (``noise="estimate"``)."""
    robot = iwr.Robot.default()
    noise = iwr.Noise.realistic()
    start = iwr.Noise(legs=noise.legs, joint_lengths=noise.joint_lengths,
                      joint_angles=noise.joint_angles, position=0.05, orientation=5e-5)
    m0, _ = iwr.simulate(robot, 100, seed=0, noise=noise)
    active = iwr.identifiability(robot, m0).active
    tracker: dict[str, list[float]] = {"position": [], "orientation": []}
    every: dict[str, list[float]] = {c: [] for c in est.COMPONENTS}
    unidentified = dict.fromkeys(est.COMPONENTS, 0)
    for s in range(seeds):
        m, _ = iwr.simulate(robot, 100, seed=s, noise=noise)
        r = est.efficient(robot, m, start, active=active, estimate=("position", "orientation"))
        for c in r.variance_components:
            tracker[c.name].append(c.sigma / getattr(noise, c.name))
        r = est.efficient(robot, m, "estimate", active=active)
        for c in r.variance_components:
            if c.identified:
                every[c.name].append(c.sigma / getattr(noise, c.name))
            else:
                unidentified[c.name] += 1
    print(f"Variance components, Noise.realistic() data, N = 100, {seeds} seeds: estimated / true "
          "sigma")
    print()
    print("| case | component | median | min | max | not identified |")
    print("|---|---|---|---|---|---|")
    for name, v in tracker.items():
        a = np.array(v)
        print(f"| tracker unknown | {name} | {np.median(a):.3f} | {a.min():.3f} | {a.max():.3f} | "
              "0 |")
    for name, v in every.items():
        a = np.array(v) if v else np.array([math.nan])
        print(f"| all unknown | {name} | {np.median(a):.3f} | {np.min(a):.3f} | {np.max(a):.3f} | "
              f"{unidentified[name]} |")


def outlier_table(seeds: int) -> None:
    """5 % of the poses with a 1 mm gross error in one leg (even seeds) or in one coordinate of
    the measured position (odd seeds)."""
    robot = iwr.Robot.default()
    noise = iwr.Noise.realistic()
    m0, _ = iwr.simulate(robot, 100, seed=0, noise=noise)
    active = iwr.identifiability(robot, m0).active
    found = missed = false_bad = false_clean = 0
    ratios = []
    for s in range(seeds):
        rng = np.random.default_rng(100 + s)
        m, truth = iwr.simulate(robot, 100, seed=s, noise=noise)
        bad = rng.choice(100, 5, replace=False)
        legs, poses = m.legs.copy(), m.poses.copy()
        for k in bad:
            if s % 2 == 0:
                legs[k, rng.integers(6)] += rng.choice([-1.0, 1.0])
            else:
                poses[k, rng.integers(3)] += rng.choice([-1.0, 1.0])
        mb = iwr.Measurements(m.q, poses, legs, joint_types=m.joint_types)
        r = est.efficient(robot, mb, noise, active=active)
        c = est.efficient(robot, m, noise, active=active)
        flagged = {o.pose for o in r.outliers}
        found += len(flagged & set(bad.tolist()))
        missed += 5 - len(flagged & set(bad.tolist()))
        false_bad += len(flagged - set(bad.tolist()))
        false_clean += len(c.outliers)
        fresh, _ = iwr.simulate(robot, 200, seed=10000 + s, x=truth)
        pb = iwr.accuracy(robot, fresh, r.x).calibrated.position
        pc = iwr.accuracy(robot, fresh, c.x).calibrated.position
        ratios.append(math.sqrt(np.mean(pb**2) / np.mean(pc**2)))
    ratios_a = np.array(ratios)
    print(f"Outliers: N = 100, 5 gross errors of 1 mm per data set, {seeds} seeds")
    print()
    print(f"- gross errors flagged: {found} of {found + missed}")
    print(f"- clean poses flagged: {false_bad} of {95 * seeds} in the contaminated sets, "
          f"{false_clean} of {100 * seeds} in the clean sets "
          f"({100 * (false_bad + false_clean) / (195 * seeds):.2f} %)")
    print(f"- tool position RMS, contaminated (after removal) / clean: median "
          f"{np.median(ratios_a):.3f}, max {ratios_a.max():.3f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--no-stats", action="store_true")
    ap.add_argument("--no-time", action="store_true")
    ap.add_argument("--vce", action="store_true", help="also the variance-component table")
    ap.add_argument("--outliers", action="store_true", help="also the outlier table")
    args = ap.parse_args()
    if not args.no_time:
        time_table(args.repeat)
        print()
    if not args.no_stats:
        stats_table(args.seeds)
        print()
    if args.vce:
        vce_table(args.seeds)
        print()
    if args.outliers:
        outlier_table(args.seeds)


if __name__ == "__main__":
    main()
