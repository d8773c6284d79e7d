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
    python benchmarks/bench_estimation.py --tracker {points,probe} [--seeds 20] [--repeat 7]

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


def crb(actual: np.ndarray, predicted: np.ndarray,
        rng: np.random.Generator) -> tuple[float, float, float]:
    """sqrt(mean actual^2 / mean predicted^2) over the seeds, and its bootstrap 90 % interval."""
    ratio = math.sqrt(np.mean(actual**2) / np.mean(predicted**2))
    boot = []
    for _ in range(2000):
        i = rng.integers(0, len(actual), len(actual))
        boot.append(math.sqrt(np.mean(actual[i] ** 2) / np.mean(predicted[i] ** 2)))
    lo, hi = np.quantile(boot, [0.05, 0.95])
    return ratio, float(lo), float(hi)


def comparison_tables(r: np.ndarray, other: str) -> None:
    """The tables of the rows (other's position, efficient's position, other's orientation,
    efficient's orientation, predicted position, predicted orientation) RMS, one row per seed:
    the ratios other / efficient, and the Cramer-Rao check."""
    pos_ratio, ori_ratio = r[:, 0] / r[:, 1], r[:, 2] / r[:, 3]
    rng = np.random.default_rng(0)
    pc, oc = crb(r[:, 1], r[:, 4], rng), crb(r[:, 3], r[:, 5], rng)
    print(f"| | {other} median | efficient median | ratio median | ratio min | ratio max |")
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
    print()
    print(f"Noise.realistic(), N = 100, {seeds} seeds (0..{seeds - 1}), 200 fresh noise-free poses "
          "per seed")
    print()
    comparison_tables(r, "eq. (10)")
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


TRACKER_REGISTRATION = (2000.0, 0.0, 0.0, math.pi / 2, 0.0, 0.0)
TRACKER_REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
TRACKER_PROBE = (30.0, -20.0, 60.0, 0.3, -0.2, 0.1)


def tracker_table(seeds: int, kind: str, repeat: int) -> None:
    """Tracker data (``--tracker points`` or ``probe``): per seed s, N = 100 poses
    (``iwr.simulate(robot, 100, seed=s, noise=(readings of Noise.realistic(),
    TrackerNoise.leica()))``, K = 3 reflectors or a probe, the registration 2 m away and turned 90
    degrees, truth drawn by the seed), 200 fresh noise-free poses (``seed=10000 + s``). The
    estimator against LM on the unweighted point objective (``iwr.identify(robot, data,
    active="base")``, the default without a noise model): tool position and orientation RMS error
    on the fresh poses modulo the gauge (``tool_pose_errors``), the Cramer-Rao check against
    ``tracker_predicted_accuracy`` on the same poses, the chi-square statistic (KS test of its
    p-values against the uniform law), the tracker's variance components (its sigmas started 2x
    too large, legs and joints known), and 5 of the 100 poses with 1 mm on one reflector (points
    only). Then the time of one solve (the C++ ``implicit_loop_tracker`` from the LM start, one
    thread) and of the whole ``identify`` call at N = 100."""
    from dataclasses import replace

    from scipy import stats

    from iwr.tracker import TrackerNoise, tool_pose_errors
    from iwr.tracker.estimation import tracker_predicted_accuracy

    base = iwr.Robot.default()
    robot = (base.with_tracker(registration=TRACKER_REGISTRATION, reflectors=TRACKER_REFLECTORS)
             if kind == "points" else
             base.with_tracker(registration=TRACKER_REGISTRATION, probe=TRACKER_PROBE))
    setup = robot.tracker
    real = iwr.Noise.realistic()
    readings = iwr.Noise(legs=real.legs, joint_lengths=real.joint_lengths,
                         joint_angles=real.joint_angles)
    tn = TrackerNoise.leica()
    noise = (readings, tn)
    wrong = replace(tn, distance=2 * tn.distance, distance_per_m=2 * tn.distance_per_m,
                    transverse=2 * tn.transverse, transverse_per_m=2 * tn.transverse_per_m,
                    orientation=2 * tn.orientation)

    def rms(v: np.ndarray) -> float:
        return math.sqrt(float(np.mean(np.square(v))))

    rows, chi, vce, outl = [], [], [], []
    for s in range(seeds):
        m, truth = iwr.simulate(robot, 100, seed=s, noise=noise)
        fresh, _ = iwr.simulate(robot, 200, seed=10000 + s, x=truth)
        lm = iwr.identify(robot, m, active="base")
        ef = iwr.identify(robot, m, noise=noise)
        e_lm = tool_pose_errors(robot, setup, lm.x, truth, fresh.q, fresh.legs)
        e_ef = tool_pose_errors(robot, setup, ef.x, truth, fresh.q, fresh.legs)
        pred = tracker_predicted_accuracy(robot, ef.x, ef.covariance, ef.active, fresh.q,
                                          fresh.legs)
        rows.append((rms(e_lm.position), rms(e_ef.position), rms(e_lm.orientation),
                     rms(e_ef.orientation), pred.position_rms, pred.orientation_rms))
        chi.append((ef.fit.statistic, ef.fit.dof, ef.fit.p_value, ef.success, len(ef.outliers)))
        v = iwr.identify(robot, m, noise=(readings, wrong), estimate=("tracker",))
        comp = {c.name: c.sigma / c.start * 2 for c in v.variance_components}  # est / truth
        vce.append(comp)
        line = (f"seed {s:2d}: position RMS LM {rows[-1][0]:.5f} mm, efficient "
                f"{rows[-1][1]:.5f} (predicted {rows[-1][4]:.5f}); orientation "
                f"{rows[-1][2]:.6f} / {rows[-1][3]:.6f} deg (predicted {rows[-1][5]:.6f}); "
                f"chi2 {chi[-1][0]:.1f} / {chi[-1][1]} dof, success {ef.success}, "
                f"{len(ef.outliers)} outlier(s); tracker sigma est/true "
                + ", ".join(f"{k[8:]} {val:.3f}" for k, val in comp.items()))
        if kind == "points":
            rng = np.random.default_rng(20000 + s)
            bad = rng.choice(100, 5, replace=False)
            pts = m.points.copy()
            for k in bad:
                d = rng.standard_normal(3)
                pts[k, rng.integers(0, 3)] += d / np.linalg.norm(d)
            mb = type(m)(m.q, m.legs, points=pts, joint_types=m.joint_types)
            ob = iwr.identify(robot, mb, noise=noise)
            flagged = {o.pose for o in ob.outliers}
            e_ob = tool_pose_errors(robot, setup, ob.x, truth, fresh.q, fresh.legs)
            outl.append((len(set(bad) & flagged), len(flagged - set(bad)),
                         rms(e_ob.position) / rms(e_ef.position)))
            line += (f"; outliers: {outl[-1][0]}/5 found, {outl[-1][1]} clean flagged, "
                     f"accuracy {outl[-1][2]:.3f}x clean")
        print(line, flush=True)
    r = np.array(rows)
    print()
    print(f"Tracker {kind} (K = {setup.n_reflectors if kind == 'points' else 'probe'}), "
          f"readings of Noise.realistic() + TrackerNoise.leica(), N = 100, {seeds} seeds "
          f"(0..{seeds - 1}), 200 fresh noise-free poses per seed")
    print()
    comparison_tables(r, "LM (unweighted points)")
    c = np.array([row[:3] for row in chi], dtype=float)
    ks = stats.kstest(c[:, 2], "uniform")
    print()
    print(f"chi-square: mean statistic / dof {np.mean(c[:, 0] / c[:, 1]):.4f} (dof "
          f"{int(np.median(c[:, 1]))} median); KS test of the p-values against U(0, 1): "
          f"p = {ks.pvalue:.3f}; success {sum(row[3] for row in chi)} of {seeds}; poses removed "
          f"as outliers (clean data) {sum(row[4] for row in chi)} in all")
    for name in vce[0]:
        vals = np.array([d[name] for d in vce])
        print(f"variance component {name}: estimate / truth median {np.median(vals):.3f}, "
              f"min {vals.min():.3f}, max {vals.max():.3f}; within 15 %: "
              f"{int(np.sum(np.abs(vals - 1) < 0.15))} of {seeds}")
    if outl:
        o = np.array(outl)
        print(f"outliers (5 poses of 100 with 1 mm on one reflector): found {int(o[:, 0].sum())} "
              f"of {5 * seeds}; clean poses flagged {int(o[:, 1].sum())} of {95 * seeds} "
              f"({100 * o[:, 1].sum() / (95 * seeds):.2f} %); tool position RMS after removal / "
              f"clean data's: median {np.median(o[:, 2]):.3f}, max {o[:, 2].max():.3f}")
    # Time of one solve.
    m, _ = iwr.simulate(robot, 100, seed=1, noise=noise)
    from iwr.tracker.estimation import TrackerSpec

    spec = TrackerSpec(robot, m, noise, None, None, None, None, 10.0)
    idx = [int(i) for i in np.flatnonzero(spec.mask)]
    used = np.ones(len(m), dtype=bool)
    times, full, out = [], [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = spec.solve(spec.x_start, idx, used, {}, np.zeros((len(m), spec.ny)), 200, None)
        times.append(time.perf_counter() - t)
        t = time.perf_counter()
        iwr.identify(robot, m, noise=noise)
        full.append(time.perf_counter() - t)
    print(f"time at N = 100 ({kind}), one thread, median of {repeat}: one solve (C++, statistics "
          f"included, from the LM start) {1e3 * np.median(times):.1f} ms, "
          f"{out['iterations']} iterations; the whole identify call (registration guess, LM "
          f"start, base parameters, solve, outlier tests, predicted accuracy) "
          f"{1e3 * np.median(full):.0f} ms")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--no-stats", action="store_true")
    ap.add_argument("--no-time", action="store_true")
    ap.add_argument("--vce", action="store_true", help="also the variance-component table")
    ap.add_argument("--outliers", action="store_true", help="also the outlier table")
    ap.add_argument("--tracker", choices=("points", "probe"), default=None,
                    help="only the tracker-data tables (docs/estimation.md, 'Tracker data')")
    args = ap.parse_args()
    if args.tracker:
        tracker_table(args.seeds, args.tracker, args.repeat)
        return
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
