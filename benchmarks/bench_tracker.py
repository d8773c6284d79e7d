"""Cost of one evaluation of the tracker point objective against the leg objective (eq. 10).

What is timed: ``cost_batch(X, workers=1)`` on M random parameter vectors within the default
bounds (as DE draws them), divided by M, in CPU time of the calling thread (the machine may be
shared); the median of several repetitions. Both objectives see the same robot, the same
N poses (from ``iwr.tracker.simulate_tracker``, noise-free) and the same robot errors; the
point objective has K reflectors and 6 + 3 K more parameters. The point objective does more by
construction: per pose, the forward kinematics of the hexapod (chord iterations from a
reference solve, each one the six leg lengths and a 6x6 matrix-vector product) before the K
points, where the leg objective evaluates the six leg lengths once, in a SIMD kernel over 8 poses.

``--accuracy`` prints instead the tool accuracy before and after calibration (Levenberg-Marquardt
from the nominal model, with the registration guess for tracker data) on 50 fresh noise-free poses
of the true robot, for each kind of data at N = 25, 50, 100, with realistic noise: leg and joint
readings as ``iwr.Noise.realistic()``; a pose in {0} with its 20 um / 20 urad; tracker points and
the probe's origin with ``TrackerNoise.leica()``, the probe's orientation 0.005 degree. Tracker
data are compared modulo their gauge (``iwr.tracker.tool_pose_errors``), a pose in {0} directly.

Usage::

    python benchmarks/bench_tracker.py [--quick] [--n 100] [--k 3] [--repeat 7] [--kernels]
    python benchmarks/bench_tracker.py --accuracy [--seed 1]
    python benchmarks/bench_tracker.py --accuracy --seeds 10
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np
from _load import OtherLoad

import iwr
from iwr import _core
from iwr.tracker import TrackerProblem, TrackerSetup, simulate_tracker

REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0), (0.0, 0.0, 80.0),
              (0.0, 150.0, 20.0), (0.0, -150.0, 20.0)]


def per_eval_us(fn, X: np.ndarray, reps: int) -> float:
    """Median CPU time of the calling thread per row of X (us); X made C-contiguous first, so
    no copy is timed."""
    X = np.ascontiguousarray(X)
    fn(X[:4])  # warm-up
    times = []
    for _ in range(reps):
        t = time.thread_time()
        fn(X)
        times.append((time.thread_time() - t) / X.shape[0] * 1e6)
    return statistics.median(times)


def accuracy_table(seed: int) -> None:
    from iwr.methods import ReducedProblem
    from iwr.methods.lm import levenberg_marquardt
    from iwr.simulation import sample_poses
    from iwr.tracker import TrackerNoise, guess_registration, tool_pose_errors

    robot = iwr.Robot.default()
    reg = (2000.0, 0.0, 0.0, math.pi / 2, 0.0, 0.0)
    kinds = [("pose in {0}", None), ("pose in {T} (probe)",
                                     TrackerSetup(reg, probe=(0.0, 0.0, 60.0, 0.0, 0.0, 0.0)))]
    kinds += [(f"points, K = {k}", TrackerSetup(reg, reflectors=REFLECTORS[:k])) for k in (1, 2, 3)]
    readings = iwr.Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6)
    print(f"seed {seed}; tool position / orientation RMS on 50 fresh poses, before -> after")
    print()
    print("| data | N | position (mm) | orientation (deg) | LM evaluations |")
    print("|---|---|---|---|---|")
    for name, setup in kinds:
        for n in (25, 50, 100):
            if setup is None:
                m, truth = iwr.simulate(robot, n, seed=seed, noise=iwr.Noise.realistic())
                problem = iwr.Problem(robot, m)
                x0 = np.zeros(robot.n_params)
            else:
                m, truth = simulate_tracker(robot, setup, n, seed=seed, noise=readings,
                                            tracker_noise=TrackerNoise.leica())
                g = guess_registration(robot, setup, m)
                problem = TrackerProblem(robot, setup, m, center=g.x_setup)
                x0 = np.concatenate([np.zeros(robot.n_params), g.x_setup])
            res = levenberg_marquardt(
                ReducedProblem(problem, np.ones(problem.n_params, bool), x0), progress=False)
            q, poses, legs = sample_poses(robot, 50, np.random.default_rng(seed + 1000),
                                          truth[: robot.n_params])
            out = []
            for x in (x0, res["x"]):
                if setup is None:
                    from iwr.analysis.accuracy import pose_errors
                    from iwr.forward import forward_kinematics

                    fk = forward_kinematics(robot, x[: robot.n_params], q, legs)
                    pos, ang = pose_errors(fk, poses)
                else:
                    e = tool_pose_errors(robot, setup, x, truth, q, legs)
                    pos, ang = e.position, e.orientation
                out.append((math.sqrt(np.mean(pos**2)), math.sqrt(np.mean(ang**2))))
            (p0, a0), (p1, a1) = out
            print(f"| {name} | {n} | {p0:.3g} -> {p1:.3g} | {a0:.3g} -> {a1:.3g} "
                  f"| {res['nfev']} |")


def accuracy_table_seeds(seeds: int) -> None:
    """The same table through the public API (``Robot.with_tracker``, ``iwr.simulate``,
    ``iwr.identify``, ``iwr.accuracy(truth=)``) over seeds 1..``seeds``: the median over the
    seeds of the tool RMS on 50 fresh noise-free poses, and the range of the "after" figures."""
    robot0 = iwr.Robot.default()
    reg = (2000.0, 0.0, 0.0, math.pi / 2, 0.0, 0.0)
    kinds = [("pose in {0}", robot0),
             ("pose in {T} (probe)", robot0.with_tracker(registration=reg,
                                                          probe=(0.0, 0.0, 60.0, 0, 0, 0)))]
    kinds += [(f"points, K = {k}", robot0.with_tracker(registration=reg,
                                                        reflectors=REFLECTORS[:k]))
              for k in (1, 2, 3)]
    from iwr.tracker import TrackerNoise

    readings = iwr.Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6)
    print(f"seeds 1..{seeds}; tool RMS on 50 fresh noise-free poses: median over the seeds of "
          "before -> after [range of after]; LM from the nominal robot (and the registration "
          "guess)")
    print()
    print("| data | N | position (mm) | orientation (deg) |")
    print("|---|---|---|---|")
    for name, robot in kinds:
        for n in (25, 50, 100):
            rows = []
            for seed in range(1, seeds + 1):
                if robot.tracker is None:
                    m, truth = iwr.simulate(robot, n, seed=seed, noise=iwr.Noise.realistic())
                    fresh, _ = iwr.simulate(robot, 50, seed=seed + 1000, x=truth)
                    res = iwr.identify(robot, m)
                    acc = iwr.accuracy(robot, fresh, res.x)
                else:
                    m, truth = iwr.simulate(robot, n, seed=seed,
                                            noise=(readings, TrackerNoise.leica()))
                    fresh, _ = iwr.simulate(robot, 50, seed=seed + 1000, x=truth)
                    res = iwr.identify(robot, m)
                    acc = iwr.accuracy(robot, fresh, res.x, truth=truth)
                rows.append([math.sqrt(np.mean(e**2)) for e in (
                    acc.nominal.position, acc.calibrated.position, acc.nominal.orientation,
                    acc.calibrated.orientation)])
            a = np.array(rows)
            med = np.median(a, axis=0)
            print(f"| {name} | {n} | {med[0]:.3g} -> {med[1]:.3g} [{a[:, 1].min():.3g}, "
                  f"{a[:, 1].max():.3g}] | {med[2]:.3g} -> {med[3]:.3g} [{a[:, 3].min():.3g}, "
                  f"{a[:, 3].max():.3g}] |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a smoke test: few rows, 2 repetitions")
    ap.add_argument("--n", type=int, default=100, help="poses N (default 100)")
    ap.add_argument("--k", type=int, default=3, help="reflectors K (default 3, at most 6)")
    ap.add_argument("--repeat", type=int, default=7, help="repetitions, the median (default 7)")
    ap.add_argument("--kernels", action="store_true",
                    help="every instruction-set variant this CPU runs, not only the fastest")
    ap.add_argument("--accuracy", action="store_true", help="the accuracy table instead")
    ap.add_argument("--seed", type=int, default=1, help="seed of --accuracy (default 1)")
    ap.add_argument("--seeds", type=int, default=None,
                    help="--accuracy through the public API over seeds 1..SEEDS (medians)")
    args = ap.parse_args()
    if args.accuracy and args.seeds:
        accuracy_table_seeds(args.seeds)
        return
    if args.accuracy:
        accuracy_table(args.seed)
        return
    m, reps = (50, 2) if args.quick else (600, args.repeat)
    kernels = _core._supported_kernels() if args.kernels else [_core._active_kernel()]
    robot = iwr.Robot.default()
    rows = []
    for k in sorted({1, args.k}):
        setup = TrackerSetup((2000.0, 0.0, 0.0, math.pi / 2, 0.0, 0.0), reflectors=REFLECTORS[:k])
        data, truth = simulate_tracker(robot, setup, args.n, seed=1)
        tracker = TrackerProblem(robot, setup, data)
        poses = tracker.platform_poses(truth)
        legs_problem = iwr.Problem(robot, iwr.Measurements(data.q, poses, data.legs,
                                                           joint_types=robot.joint_types))
        rng = np.random.default_rng(0)
        X = tracker.lower + (tracker.upper - tracker.lower) * rng.random((m, tracker.n_params))
        base = _core._bench.EigenBaseline(robot._geometry, data.q, poses, data.legs)
        def points_cost(A, p=tracker):
            return p.cost_batch(A, workers=1)

        def legs_cost(A, p=legs_problem):
            return p.cost_batch(A, workers=1)

        def baseline_cost(A, b=base):
            return b.cost_batch(A)

        XL = X[:, :robot.n_params]  # the robot's parameters: what the leg objective takes
        before = _core._active_kernel()
        try:
            for variant in kernels:
                _core._select_kernel(variant)
                with OtherLoad() as load:
                    t_pts = per_eval_us(points_cost, X, reps)
                    t_leg = per_eval_us(legs_cost, XL, reps)
                    t_base = per_eval_us(baseline_cost, XL, reps)
                rows.append((variant, k, t_pts, t_leg, t_base, load.cores))
        finally:
            _core._select_kernel(before)
    print(f"N = {args.n} poses, one thread, CPU time per evaluation (median of {reps} x {m}); "
          "kernel variant: the instruction set of both objectives' SIMD kernels")
    print()
    print("| kernel | K | point objective (us) | leg objective, SIMD kernel (us) | ratio "
          "| leg objective, Eigen baseline (us) | ratio | other processes (cores) |")
    print("|---|---|---|---|---|---|---|---|")
    for variant, k, tp, tl, tb, cores in rows:
        other = "?" if cores is None else f"{cores:.2f}"
        print(f"| {variant} | {k} | {tp:.2f} | {tl:.3f} | {tp / tl:.1f}x | {tb:.2f} "
              f"| {tp / tb:.2f}x "
              f"| {other} |")


if __name__ == "__main__":
    main()
