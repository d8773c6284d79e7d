"""Identifiability, uncertainty and pose planning for the IWR: the figures of
docs/identifiability.md.

    python benchmarks/identifiability.py [--quick]

Prints four tables:
1. rank and indices of the IWR (58 parameters) and of the standalone hexapod (42), N = 100 poses;
2. the unidentifiable directions of the IWR;
3. predicted standard deviations against the spread over Monte-Carlo noise draws;
4. validation error of planned against random poses (realistic noise, averaged over seeds).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import iwr
from iwr.planning import measure
from iwr.simulation import sample_poses


def table_rank() -> None:
    print("## 1. Rank (N = 100 random poses, Jacobian at the nominal robot)\n")
    print("| robot | params | rank | unidentifiable | s_max | s_r (smallest kept) | s_r+1 | "
          "cond | O1 | O3 |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for robot in (iwr.Robot.default(), iwr.Robot.hexapod()):
        m, _ = iwr.simulate(robot, 100, seed=1)
        rep = iwr.identifiability(robot, m)
        s = rep.singular_values
        nxt = f"{s[rep.rank]:.1e}" if rep.rank < s.size else "-"
        print(f"| {robot.name} | {robot.n_params} | {rep.rank} | {rep.n_unidentifiable} | "
              f"{s[0]:.3f} | {s[rep.rank - 1]:.2e} | {nxt} | {rep.condition_number:.0f} | "
              f"{rep.O1:.4f} | {rep.O3:.2e} |")
    print()


def table_null() -> None:
    robot = iwr.Robot.default()
    m, _ = iwr.simulate(robot, 100, seed=1)
    rep = iwr.identifiability(robot, m)
    print("## 2. Unidentifiable directions of the IWR (coefficients in mm and rad)\n")
    for k, nd in enumerate(rep.null_directions, 1):
        print(f"{k}. {nd}")
    print()


def table_monte_carlo(n_draws: int) -> None:
    robot = iwr.Robot.default()
    print(f"## 3. Predicted std against {n_draws} Monte-Carlo draws (N = 20 poses, LM on the 52 "
          "base parameters)\n")
    print("| noise | prediction | ratio empirical/predicted: min | median | max |")
    print("|---|---|---|---|---|")
    m0, truth = iwr.simulate(robot, 20, seed=2)
    rep = iwr.identifiability(robot, m0, truth)
    x_star = iwr.identify(robot, m0, "lm", active=rep.active).x
    noises = (("legs 5 um", iwr.Noise(legs=0.005)), ("realistic", iwr.Noise.realistic()))
    for label, noise in noises:
        rng = np.random.default_rng(7)
        xs = np.array([
            iwr.identify(robot, measure(robot, truth, m0.q, m0.poses, noise, rng), "lm",
                         active=rep.active, x0=x_star).x
            for _ in range(n_draws)
        ])
        emp = xs.std(axis=0, ddof=1)[rep.active]
        preds = [("Noise propagated", noise)]
        if label == "realistic":
            preds.append(("legs only", noise.legs))
        for how, arg in preds:
            pred = iwr.uncertainty(robot, m0, x_star, noise=arg, active=rep.active)
            r = emp / pred.std[rep.active]
            print(f"| {label} | {how} | {r.min():.3f} | {np.median(r):.3f} | {r.max():.3f} |")
    print()


def table_planning(seeds: int, n_cand: int, ks: list[int]) -> None:
    robot = iwr.Robot.default()
    noise = iwr.Noise.realistic()
    q, poses, _ = sample_poses(robot, n_cand, np.random.default_rng(0))
    qv, pv, _ = sample_poses(robot, 200, np.random.default_rng(99))
    cand = iwr.Measurements(q, poses, np.zeros((n_cand, 6)), joint_types=robot.joint_types)
    rep = iwr.identifiability(robot, cand)
    print(f"## 4. Planned against random poses ({n_cand} candidates, realistic noise, LM on the "
          f"base parameters, {seeds} seeds)\n")
    print("Validation: RMS over 200 fresh poses of predicted minus true leg readings (mm, "
          "noise-free); parameter error modulo null directions (mm, RMS over lengths).\n")
    print("| K | poses | O1 | validation RMS mean | median | param. error RMS mean | plan time s |")
    print("|---|---|---|---|---|---|---|")

    def run(idx, truth, seed):
        m = measure(robot, truth, q[idx], poses[idx], noise, seed)
        x = iwr.identify(robot, m, "lm", active=rep.active).x
        d = iwr.predict_legs(robot, x, qv, pv) - iwr.predict_legs(robot, truth, qv, pv)
        pe = iwr.parameter_error(robot, m, x, truth)
        return np.sqrt(np.mean(d**2)), pe.rms_length

    for k in ks:
        rows = {}
        for crit in ("O1", "O3"):
            t0 = time.perf_counter()
            plan = iwr.plan_poses(robot, cand, k, crit, report=rep)
            rows[f"planned {crit}"] = (plan.indices, time.perf_counter() - t0)
        results = {name: [] for name in [*rows, "random"]}
        o1 = {name: [] for name in results}
        for s in range(seeds):
            truth = iwr.simulate(robot, 1, seed=100 + s)[1]
            for name, (idx, _) in rows.items():
                results[name].append(run(idx, truth, s))
            ridx = np.random.default_rng(1000 + s).choice(n_cand, k, replace=False)
            results["random"].append(run(ridx, truth, s))
            o1["random"].append(iwr.identifiability(robot, cand.subset(ridx)).O1)
        for name, (idx, _) in rows.items():
            o1[name].append(iwr.identifiability(robot, cand.subset(idx)).O1)
        for name, vals in results.items():
            v = np.array(vals)
            t = f"{rows[name][1]:.2f}" if name in rows else "-"
            print(f"| {k} | {name} | {np.mean(o1[name]):.4f} | {v[:, 0].mean():.4f} | "
                  f"{np.median(v[:, 0]):.4f} | {v[:, 1].mean():.4f} | {t} |")
    print()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer draws and seeds")
    args = ap.parse_args()
    table_rank()
    table_null()
    table_monte_carlo(50 if args.quick else 200)
    if args.quick:
        table_planning(seeds=4, n_cand=200, ks=[15])
    else:
        table_planning(seeds=20, n_cand=500, ks=[10, 15, 30, 60])


if __name__ == "__main__":
    main()
